"""The rope tracker's per-frame steps compiled with numba (numba is a core dependency).

Every public function here is the twin of the one of the same name and signature in
:mod:`skincap.tracking._steps_numpy` (the reference; its docstrings say what each
step does and why): the same ``(state, t, …, p)`` arguments, a
:class:`~skincap.tracking.state.TrackState` changed in place and the run's
:class:`~skincap.tracking.state.StepParams`. Loops replace the vectorised
expressions, the KD-tree queries become a brute-force k-nearest search over the
frame's few hundred points (:mod:`skincap.tracking._numba_search`), and the
leave-one-out curve is evaluated directly. It takes the same points and invents the
same markers; invented positions agree to rounding (the order of a few additions
differs).

Importing this module imports numba; :func:`track_frames` compiles on its first call
(about a minute of one core; cached on disk, loaded in about a second afterwards).
``track_rope(backend="auto")`` never waits for it: it runs the NumPy steps while
:func:`skincap.tracking.tracker.warm_up_kernel` compiles these in a background
process (:mod:`skincap.backends`).
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.tracking._numba_curve import (
    curve_at,
    fill_interior,
    interp_along,
    neighbour_velocity,
    predict_ends,
    settle,
    side_neighbours,
)
from skincap.tracking._numba_search import JIT, gated_assignment, is_taken, norm3, query_nearest

__all__ = [
    "begin_frame",
    "commit_frame",
    "continue_body_chains",
    "gap_predictions",
    "learn_link_rest",
    "match_measured",
    "match_missing",
    "match_traces",
    "place_invented",
    "reacquire_on_shell",
    "reject_odd_motion",
    "reject_overstretched",
    "residual_predictions",
    "rigid_with_body",
    "swap_onto_curve",
    "track_frame",
    "track_frames",
    "zipper_predictions",
]

_INF = np.inf


@numba.njit(**JIT)
def _steady(state):  # pragma: no cover - runs compiled
    """(M,) bool: traces measured in the previous frame (no temporary marker running)."""
    return state.temp_count == 0


# ------------------------------------------------------------------ frame start and end
@numba.njit(**JIT)
def begin_frame(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.begin_frame`."""
    m = state.known.size
    for j in range(m):
        state.known[j] = False
        state.taken[j] = -1
        for c in range(3):
            state.cur[j, c] = 0.0
    return state.positions[t - 1] + state.velocity


@numba.njit(**JIT)
def commit_frame(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.commit_frame`."""
    prev = state.positions[t - 1]
    for j in range(state.known.size):
        known = state.known[j]
        state.temp_count[j] = 0 if known else state.temp_count[j] + 1
        state.invented[t, j] = not known
        state.lost_frames[t, j] = state.temp_count[j] > p.max_temp_markers
        state.point_index[t, j] = state.taken[j]
        for c in range(3):
            state.positions[t, j, c] = state.cur[j, c]
            state.velocity[j, c] = state.cur[j, c] - prev[j, c]
    learn_link_rest(state, p)


@numba.njit(**JIT)
def learn_link_rest(state, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.learn_link_rest`."""
    known, cur = state.known, state.cur
    for j in range(known.size - 1):
        if known[j] and known[j + 1]:
            chord = norm3(
                cur[j + 1, 0] - cur[j, 0], cur[j + 1, 1] - cur[j, 1], cur[j + 1, 2] - cur[j, 2]
            )
            chord = min(chord, p.stretch * state.spacing[j])
            if chord > state.link_rest[j]:
                state.link_rest[j] = chord


# ------------------------------------------------------------------ body points
@numba.njit(**JIT)
def continue_body_chains(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.continue_body_chains`."""
    points, body, body_vel = state.points, state.body, state.body_vel
    pa, a, b = state.offsets[t - 1], state.offsets[t], state.offsets[t + 1]
    eps = p.body_chain_gate * p.gamma
    eps2 = eps * eps
    q_count = np.zeros(a - pa, np.int64)
    p_q = np.full(b - a, -1, np.int64)
    p_count = np.zeros(b - a, np.int64)
    # the previous body points' predictions sorted by x: only those within eps in x
    n_body = 0
    for q in range(pa, a):
        if body[q]:
            n_body += 1
    qs = np.empty(n_body, np.int64)
    n_body = 0
    for q in range(pa, a):
        if body[q]:
            qs[n_body] = q
            n_body += 1
    px = np.empty(n_body)
    for r in range(n_body):
        px[r] = points[qs[r], 0] + body_vel[qs[r], 0]
    order = np.argsort(px)
    xs = px[order]
    for i in range(a, b):
        body[i] = False
        for c in range(3):
            body_vel[i, c] = 0.0
        lo = np.searchsorted(xs, points[i, 0] - eps)
        hi = np.searchsorted(xs, points[i, 0] + eps, side="right")
        for r in range(lo, hi):
            q = qs[order[r]]
            ex = points[i, 0] - (points[q, 0] + body_vel[q, 0])
            ey = points[i, 1] - (points[q, 1] + body_vel[q, 1])
            ez = points[i, 2] - (points[q, 2] + body_vel[q, 2])
            if ex * ex + ey * ey + ez * ez < eps2:
                p_count[i - a] += 1
                q_count[q - pa] += 1
                p_q[i - a] = q
    measured_before = state.point_index[t - 1]
    for i in range(a, b):
        if p_count[i - a] != 1 or q_count[p_q[i - a] - pa] != 1:
            continue
        near_rope = False
        for j in range(measured_before.size):
            if measured_before[j] < 0:
                continue
            ex = points[i, 0] - v_pred[j, 0]
            ey = points[i, 1] - v_pred[j, 1]
            ez = points[i, 2] - v_pred[j, 2]
            if ex * ex + ey * ey + ez * ez < eps2:
                near_rope = True
        if near_rope:
            continue
        q = p_q[i - a]
        body[i] = True
        for c in range(3):
            body_vel[i, c] = points[i, c] - points[q, c]


@numba.njit(**JIT)
def _rope_taken_at(point_index, f, q):  # pragma: no cover - runs compiled
    """True when a trace took the point q in frame f."""
    for j in range(point_index.shape[1]):
        if point_index[f, j] == q:
            return True
    return False


@numba.njit(**JIT)
def _follow_back(points, offsets, t, window, point, tol, traj):  # pragma: no cover
    """Fill ``traj`` (W + 1, 3) with the point's path back by unambiguous nearest points
    at constant velocity (last row the point); False where it is ambiguous."""
    traj[window] = points[point]
    vx = 0.0
    vy = 0.0
    vz = 0.0
    for f in range(t - 1, t - window - 1, -1):
        fa, fb = offsets[f], offsets[f + 1]
        if fb - fa < 2:
            return False
        r = f - t + window
        qx = traj[r + 1, 0] - vx
        qy = traj[r + 1, 1] - vy
        qz = traj[r + 1, 2] - vz
        d1 = _INF
        d2 = _INF
        n1 = -1
        for q in range(fa, fb):
            dd = norm3(points[q, 0] - qx, points[q, 1] - qy, points[q, 2] - qz)
            if dd < d1:
                d2 = d1
                d1 = dd
                n1 = q
            elif dd < d2:
                d2 = dd
        if not (d1 < 2.0 * tol and d2 > 2.0 * d1):
            return False
        traj[r] = points[n1]
        vx = traj[r + 1, 0] - traj[r, 0]
        vy = traj[r + 1, 1] - traj[r, 1]
        vz = traj[r + 1, 2] - traj[r, 2]
    return True


@numba.njit(**JIT)
def _keeps_distance(points, offsets, point_index, t, window, traj, c, dq, tol):  # pragma: no cover
    """True when the partner point ``c`` follows the path ``traj`` back through the
    window at a constant distance ``dq``."""
    qx = points[c, 0]
    qy = points[c, 1]
    qz = points[c, 2]
    for f in range(t - 1, t - window - 1, -1):
        fa, fb = offsets[f], offsets[f + 1]
        if fb == fa:
            return False
        r = f - t + window
        px = qx + traj[r, 0] - traj[r + 1, 0]
        py = qy + traj[r, 1] - traj[r + 1, 1]
        pz = qz + traj[r, 2] - traj[r + 1, 2]
        best = _INF
        n = fa
        for q in range(fa, fb):
            dd = norm3(points[q, 0] - px, points[q, 1] - py, points[q, 2] - pz)
            if dd < best and not _rope_taken_at(point_index, f, q):
                best = dd
                n = q
        qx = points[n, 0]
        qy = points[n, 1]
        qz = points[n, 2]
        to_p = norm3(qx - traj[r, 0], qy - traj[r, 1], qz - traj[r, 2])
        if not (best < tol and abs(to_p - dq) < tol):
            return False
    return True


@numba.njit(**JIT)
def rigid_with_body(state, t, j, point, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.rigid_with_body`."""
    window = p.rigid_window
    if t < window:
        return False
    points, offsets, point_index = state.points, state.offsets, state.point_index
    spacing = p.median_spacing
    tol = p.rigid_range * spacing
    traj = np.empty((window + 1, 3))
    whole = j >= 0
    if whole:
        for f in range(t - window, t):
            if point_index[f, j] < 0:
                whole = False
                break
    if whole:
        traj[window] = points[point]
        for f in range(t - window, t):
            traj[f - t + window] = points[point_index[f, j]]
    elif not _follow_back(points, offsets, t, window, point, tol, traj):
        return False
    far = 0.0
    for r in range(window):
        dd = norm3(
            traj[r, 0] - traj[window, 0], traj[r, 1] - traj[window, 1], traj[r, 2] - traj[window, 2]
        )
        far = max(far, dd)
    if far < p.rigid_move * spacing:
        return False
    found = 0
    for c in range(offsets[t], offsets[t + 1]):
        if c == point:
            continue
        dq = norm3(
            points[c, 0] - traj[window, 0],
            points[c, 1] - traj[window, 1],
            points[c, 2] - traj[window, 2],
        )
        if not dq < p.rigid_radius * spacing:
            continue
        mine = False
        for jj in range(state.taken.size):
            if state.taken[jj] == c:
                mine = True
        if mine:
            continue
        if _keeps_distance(points, offsets, point_index, t, window, traj, c, dq, tol):
            found += 1
            if found >= p.rigid_partners:
                return True
    return False


# ------------------------------------------------------------------ matching
@numba.njit(**JIT)
def _follows_other(state, t, row, candidate, pred, gamma):  # pragma: no cover
    """The candidate point lies within ``min(γ, D - γ)`` of a point of frame t - 1 the
    rope did not take, ``D`` how far trace ``row`` is predicted to move."""
    points = state.points
    last = state.positions[t - 1, row]
    lim = min(gamma, norm3(pred[0] - last[0], pred[1] - last[1], pred[2] - last[2]) - gamma)
    if lim <= 0.0:
        return False
    lim2 = lim * lim
    prev_taken = state.point_index[t - 1]
    for q in range(state.offsets[t - 1], state.offsets[t]):
        ex = points[candidate, 0] - points[q, 0]
        ey = points[candidate, 1] - points[q, 1]
        ez = points[candidate, 2] - points[q, 2]
        if ex * ex + ey * ey + ez * ez < lim2:
            mine = False
            for j in range(prev_taken.size):
                if prev_taken[j] == q:
                    mine = True
            if not mine:
                return True
    return False


@numba.njit(**JIT)
def _candidates(state, t, rows, pred, gate, p):  # pragma: no cover - runs compiled
    """(R, kk) distances (inf beyond the gate or taken) and global indices of the
    nearest free points of frame t to each row's prediction."""
    a, b = state.offsets[t], state.offsets[t + 1]
    known, taken = state.known, state.taken
    n_taken = 0
    for j in range(known.size):
        if known[j]:
            n_taken += 1
    kk = min(min(p.candidates, b - a) + n_taken, b - a)
    d = np.empty((rows.size, kk))
    ii = np.empty((rows.size, kk), np.int64)
    for r in range(rows.size):
        query_nearest(state.points, a, b, pred[rows[r]], kk, gate, d[r], ii[r])
    if n_taken:
        for r in range(rows.size):
            for c in range(kk):
                if d[r, c] < _INF and is_taken(ii[r, c], known, taken):
                    d[r, c] = _INF
    return d, ii


@numba.njit(**JIT)
def _refuse_off_spacing(state, rows, d, ii, gamma):  # pragma: no cover - runs compiled
    """Refuse (inf) candidates not within γ of their rest spacing from a measured
    neighbour, or beyond γ with no measured neighbour."""
    known, cur, spacing, points = state.known, state.cur, state.spacing, state.points
    m = known.size
    for r in range(rows.size):
        row = rows[r]
        has_lo = row > 0 and known[row - 1]
        has_hi = row < m - 1 and known[row + 1]
        for c in range(d.shape[1]):
            if d[r, c] == _INF:
                continue
            if not has_lo and not has_hi and d[r, c] >= gamma:
                d[r, c] = _INF
                continue
            i = ii[r, c]
            for step in (-1, 1):
                nb = row + step
                if nb < 0 or nb >= m or not known[nb]:
                    continue
                rest = spacing[min(min(row, nb), m - 2)]
                chord = norm3(
                    points[i, 0] - cur[nb, 0], points[i, 1] - cur[nb, 1], points[i, 2] - cur[nb, 2]
                )
                if abs(chord - rest) > gamma:
                    d[r, c] = _INF


@numba.njit(**JIT)
def match_traces(state, t, rows, pred, wide, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_traces`."""
    a, b = state.offsets[t], state.offsets[t + 1]
    if rows.size == 0 or b == a:
        return False
    gamma = p.gamma
    gate = p.wide_gate * gamma if wide else gamma
    m = state.known.size
    steady = _steady(state)
    prev = state.positions[t - 1]
    d, ii = _candidates(state, t, rows, pred, gate, p)
    kk = d.shape[1]
    for r in range(rows.size):
        if steady[rows[r]]:
            continue
        for c in range(kk):
            if d[r, c] < _INF and state.body[ii[r, c]]:
                d[r, c] = _INF
    if wide and gate > gamma:
        for r in range(rows.size):
            row = rows[r]
            if not steady[row]:
                continue
            ex = pred[row, 0] - prev[row, 0]
            ey = pred[row, 1] - prev[row, 1]
            ez = pred[row, 2] - prev[row, 2]
            if ex * ex + ey * ey + ez * ez <= gamma * gamma:
                for c in range(kk):
                    if d[r, c] >= gamma:
                        d[r, c] = _INF
    for r in range(rows.size):
        row = rows[r]
        if steady[row] and not 0 < row < m - 1:
            continue
        for c in range(kk):
            if d[r, c] < _INF and _follows_other(state, t, row, ii[r, c], pred[row], gamma):
                d[r, c] = _INF
    if wide:
        for r in range(rows.size):
            if steady[rows[r]]:
                continue
            for c in range(kk):
                if d[r, c] < gate and rigid_with_body(state, t, -1, ii[r, c], p):
                    d[r, c] = _INF
        _refuse_off_spacing(state, rows, d, ii, gamma)
    hit_rows, pts = gated_assignment(d, ii, gate)
    for h in range(hit_rows.size):
        row = rows[hit_rows[h]]
        state.known[row] = True
        state.taken[row] = pts[h]
        state.cur[row] = state.points[pts[h]]
    return hit_rows.size > 0


# ------------------------------------------------------------------ refusals
@numba.njit(**JIT)
def _measured(known):  # pragma: no cover - runs compiled
    """(n,) int64 the measured markers, in order."""
    return np.nonzero(known)[0]


@numba.njit(**JIT)
def _link_limit(s, link_rest, ja, jb, gamma, p):  # pragma: no cover - runs compiled
    """Largest chord between measured markers ja < jb, metres (neighbours: from the
    larger of the rest arc length and the learnt ``link_rest``)."""
    ds = s[jb] - s[ja]
    if jb - ja == 1:
        return max(ds, link_rest[ja]) + p.adjacent_stretch * gamma
    return p.stretch * ds + gamma


@numba.njit(**JIT)
def reject_overstretched(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.reject_overstretched`."""
    cur, s, gamma = state.cur, state.arclength, p.gamma
    idx = _measured(state.known)
    n = idx.size
    if n < 2:
        return
    ok = True
    for q in range(n - 1):
        a, b = idx[q], idx[q + 1]
        chord = norm3(cur[b, 0] - cur[a, 0], cur[b, 1] - cur[a, 1], cur[b, 2] - cur[a, 2])
        if not chord <= _link_limit(s, state.link_rest, a, b, gamma, p):
            ok = False
            break
    if ok:
        return
    w = np.ones(n)
    for q in range(n):
        if rigid_with_body(state, t, idx[q], state.taken[idx[q]], p):
            w[q] = -1.0
    # the best chain by dynamic programming (as the reference's _keep_best_chain)
    score = w.copy()
    back = np.full(n, -1, np.int64)
    for b in range(1, n):
        best = -_INF
        best_a = 0
        for a in range(b):
            ja, jb = idx[a], idx[b]
            ds = s[jb] - s[ja]
            dist = norm3(cur[ja, 0] - cur[jb, 0], cur[ja, 1] - cur[jb, 1], cur[ja, 2] - cur[jb, 2])
            if dist <= _link_limit(s, state.link_rest, ja, jb, gamma, p):
                dev = (ds - dist) / (ds if ds > 0 else 1.0)
                squeeze = min(max(dev, 0.0), 1.0) + min(max(-dev, 0.0), 1.0)
                gain = w[b] - 0.5 * squeeze
            else:
                gain = -_INF
            cand = score[a] + gain
            if cand > best:
                best = cand
                best_a = a
        if best > score[b]:
            score[b] = best
            back[b] = best_a
    keep = np.zeros(n, np.bool_)
    b = int(np.argmax(score))
    while b >= 0:
        keep[b] = True
        b = back[b]
    for q in range(n):
        if not keep[q]:
            state.known[idx[q]] = False
            state.taken[idx[q]] = -1


@numba.njit(**JIT)
def reject_odd_motion(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.reject_odd_motion`."""
    cur, prev, known = state.cur, state.positions[t - 1], state.known
    m = known.size
    odd = np.zeros(m, np.bool_)
    for j in range(1, m - 1):
        if not (known[j] and known[j - 1] and known[j + 1]):
            continue
        if state.temp_count[j] != 0:
            continue
        e = np.empty(3)
        for c in range(3):
            e[c] = (cur[j, c] - prev[j, c]) - 0.5 * (
                (cur[j - 1, c] - prev[j - 1, c]) + (cur[j + 1, c] - prev[j + 1, c])
            )
        if norm3(e[0], e[1], e[2]) > p.gamma:
            odd[j] = True
    for j in range(m):
        if odd[j]:
            known[j] = False
            state.taken[j] = -1


# ------------------------------------------------------------------ predictions
@numba.njit(**JIT)
def residual_predictions(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.residual_predictions`."""
    m = state.known.size
    found = state.known & _steady(state)
    resid = np.zeros((m, 3))
    for j in range(m):
        if found[j]:
            resid[j] = state.cur[j] - v_pred[j]
    return v_pred + interp_along(found, resid, state.arclength)


@numba.njit(**JIT)
def gap_predictions(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.gap_predictions`."""
    known, cur = state.known, state.cur
    m = known.size
    prev = state.positions[t - 1]
    pred = prev + state.velocity
    if not known.any():
        return pred
    meas_vel = np.zeros((m, 3))
    x = np.zeros((m, 3))
    count = np.empty(m, np.int64)
    for j in range(m):
        count[j] = 0 if known[j] else state.temp_count[j] + 1
        if known[j]:
            meas_vel[j] = cur[j] - prev[j]
            x[j] = cur[j]
    v_tilde = neighbour_velocity(known, meas_vel, state.velocity)
    fill_interior(x, known, state.arclength, pred)
    settle(pred, known, state.spacing, p.settle)
    predict_ends(pred, known, prev, v_tilde, count, state.spacing)
    return pred


@numba.njit(**JIT)
def zipper_predictions(state, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.zipper_predictions`."""
    cur, known, spacing = state.cur, state.known, state.spacing
    m = known.size
    pred = np.zeros((m, 3))
    want = np.zeros(m, np.bool_)
    if m < 4:
        return np.nonzero(want)[0], pred
    before, after = side_neighbours(known)
    for j in range(m):
        if known[j]:
            continue
        if 0 < j < m - 1 and (before[j] < 0 or after[j] >= m):
            continue  # an inner run at an end of the measured part: left to F
        for step in (-1, 1):
            j1, j2, j3 = j + step, j + 2 * step, j + 3 * step
            if not (0 <= j2 < m and known[j1] and known[j2]):
                continue
            jo = j - step
            if 0 <= jo < m and known[jo]:
                continue
            third = 0 <= j3 < m and known[j3]
            e = np.empty(3)
            for c in range(3):
                if third:
                    e[c] = 3.0 * cur[j1, c] - 3.0 * cur[j2, c] + cur[j3, c]
                else:
                    e[c] = 2.0 * cur[j1, c] - cur[j2, c]
                e[c] -= cur[j1, c]
            norm = norm3(e[0], e[1], e[2])
            if norm > 0:
                rest = spacing[min(j, j1)]
                for c in range(3):
                    pred[j, c] = cur[j1, c] + (rest / norm) * e[c]
                want[j] = True
    return np.nonzero(want)[0], pred


# ------------------------------------------------------------------ re-acquisition
@numba.njit(**JIT)
def reacquire_on_shell(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.reacquire_on_shell`."""
    a, b = state.offsets[t], state.offsets[t + 1]
    known, cur, link_rest = state.known, state.cur, state.link_rest
    m = known.size
    if b == a:
        return False
    prev = state.positions[t - 1]
    free = ~state.body[a:b]
    for j in range(m):
        if known[j]:
            free[state.taken[j] - a] = False
    if not free.any():  # nothing left to take: the passes below would find nothing
        return False
    found = False
    if not known.any():
        for j in (0, m - 1):
            rest = link_rest[min(j, m - 2)]
            want = prev[j] + state.velocity[j]
            if _seat_nearest(state, t, j, want, rest, False, 0.0, 0.0, want, free, p):
                found = True
    for _ in range(m):
        grew = False
        for j in range(m):
            for k in (j - 1, j + 1):
                if known[j] or not (0 <= k < m and known[k]):
                    continue
                rest = link_rest[min(j, k)]
                want = cur[k] + (prev[j] - prev[k])
                inner = rest - p.gamma
                outer = rest + p.adjacent_stretch * p.gamma
                if _seat_nearest(
                    state, t, j, want, rest, True, inner, outer, cur[k].copy(), free, p
                ):
                    grew = True
        if not grew:
            break
        found = True
    if found:
        reject_overstretched(state, t, p)
    return found


@numba.njit(**JIT)
def _seat_nearest(
    state, t, j, want, gate, use_shell, inner, outer, centre, free, p
):  # pragma: no cover
    """Twin of the reference's ``_seat_nearest``: the shell is (``inner``, ``outer``,
    ``centre``) when ``use_shell``."""
    a, b = state.offsets[t], state.offsets[t + 1]
    points = state.points
    n = b - a
    d = np.full(n, _INF)
    n_ok = 0
    for c in range(n):
        if not free[c]:
            continue
        q = a + c
        dc = norm3(points[q, 0] - want[0], points[q, 1] - want[1], points[q, 2] - want[2])
        if not dc <= gate:
            continue
        if use_shell:
            r = norm3(points[q, 0] - centre[0], points[q, 1] - centre[1], points[q, 2] - centre[2])
            if not (r >= inner and r <= outer):
                continue
        d[c] = dc
        n_ok += 1
    if n_ok == 0:  # the usual case for a trace still hidden
        return False
    while True:
        best = -1
        for c in range(n):
            if d[c] < _INF and (best < 0 or d[c] < d[best]):
                best = c
        if best < 0:
            return False
        d[best] = _INF
        if _beside_trace(state, t, j, a + best, p) or rigid_with_body(state, t, -1, a + best, p):
            continue
        state.known[j] = True
        state.taken[j] = a + best
        for c in range(3):
            state.cur[j, c] = points[a + best, c]
        free[best] = False
        return True


@numba.njit(**JIT)
def _beside_trace(state, t, j, point, p):  # pragma: no cover - runs compiled
    """Twin of the reference's ``_beside_trace``."""
    points, offsets, point_index = state.points, state.offsets, state.point_index
    x0, x1, x2 = points[point, 0], points[point, 1], points[point, 2]
    v0 = 0.0
    v1 = 0.0
    v2 = 0.0
    for f in range(t - 1, max(t - 1 - p.rigid_window, -1), -1):
        fa, fb = offsets[f], offsets[f + 1]
        if fb == fa:
            return False
        best = _INF
        n = -1
        for q in range(fa, fb):
            dq = norm3(points[q, 0] - (x0 - v0), points[q, 1] - (x1 - v1), points[q, 2] - (x2 - v2))
            if dq < best:
                best = dq
                n = q
        if not best <= p.gamma:
            return False
        mine = point_index[f, j]
        if mine >= 0:
            e = norm3(
                points[n, 0] - points[mine, 0],
                points[n, 1] - points[mine, 1],
                points[n, 2] - points[mine, 2],
            )
            return n != mine and e > p.gamma
        v0 = x0 - points[n, 0]
        v1 = x1 - points[n, 1]
        v2 = x2 - points[n, 2]
        x0, x1, x2 = points[n, 0], points[n, 1], points[n, 2]
    return False


# ------------------------------------------------------------------ after matching
@numba.njit(**JIT)
def swap_onto_curve(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.swap_onto_curve`."""
    a, b = state.offsets[t], state.offsets[t + 1]
    known, cur, taken, gamma = state.known, state.cur, state.taken, p.gamma
    m = known.size
    n_taken = 0
    for j in range(m):
        if known[j]:
            n_taken += 1
    if b == a or n_taken < 3:
        return False
    before, after = side_neighbours(known)
    x = np.zeros((m, 3))
    for j in range(m):
        if known[j]:
            x[j] = cur[j]
    rows = np.empty(m, np.int64)
    c_all = np.empty((m, 3))
    dev_all = np.empty(m)
    n_odd = 0
    for j in range(m):
        if not (known[j] and before[j] >= 0 and after[j] < m):
            continue
        # the curve through every other measured marker, at s_j (marker j lies
        # outside the markers that define it)
        c = np.empty(3)
        curve_at(x, known, state.arclength, j, before[j], after[j], before, after, c)
        dev = norm3(cur[j, 0] - c[0], cur[j, 1] - c[1], cur[j, 2] - c[2])
        if dev > 2.0 * gamma:
            rows[n_odd] = j
            c_all[n_odd] = c
            dev_all[n_odd] = dev
            n_odd += 1
    if n_odd == 0:
        return False
    kk = min(min(p.candidates, b - a) + n_taken, b - a)
    d = np.empty((n_odd, kk))
    ii = np.empty((n_odd, kk), np.int64)
    for r in range(n_odd):
        query_nearest(state.points, a, b, c_all[r], kk, gamma, d[r], ii[r])
        for c in range(kk):
            if is_taken(ii[r, c], known, taken) or d[r, c] > dev_all[r] - gamma:
                d[r, c] = _INF
    hit_rows, pts = gated_assignment(d, ii, gamma)
    for h in range(hit_rows.size):
        row = rows[hit_rows[h]]
        taken[row] = pts[h]
        cur[row] = state.points[pts[h]]
    return hit_rows.size > 0


@numba.njit(**JIT)
def place_invented(state, t, pred, refit, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.place_invented`."""
    known, cur = state.known, state.cur
    m = known.size
    if known.all():
        return
    if known.any() and refit:
        x = np.zeros((m, 3))
        for j in range(m):
            if known[j]:
                x[j] = cur[j]
        curve = np.empty((m, 3))
        interior = fill_interior(x, known, state.arclength, curve)
        settle(curve, known, state.spacing, p.settle)
        for j in range(m):
            if not known[j]:
                cur[j] = curve[j] if interior[j] else pred[j]
    else:
        for j in range(m):
            if not known[j]:
                cur[j] = pred[j]


# ------------------------------------------------------------------ a frame
@numba.njit(**JIT)
def match_measured(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_measured`."""
    steady = _steady(state)
    match_traces(state, t, np.nonzero(steady)[0], v_pred, False, p)
    reject_overstretched(state, t, p)
    reject_odd_motion(state, t, p)
    tried = v_pred.copy()
    half_gamma2 = (0.5 * p.gamma) ** 2
    for _ in range(p.retry_rounds):
        found = state.known & steady
        want = steady & ~state.known
        if not (found.any() and want.any()):
            break
        pred = residual_predictions(state, t, v_pred, p)
        for j in range(want.size):
            if want[j]:
                e = pred[j] - tried[j]
                if not (e[0] * e[0] + e[1] * e[1] + e[2] * e[2] > half_gamma2):
                    want[j] = False
        if not want.any():
            break
        if not match_traces(state, t, np.nonzero(want)[0], pred, True, p):
            break
        reject_overstretched(state, t, p)
        reject_odd_motion(state, t, p)
        for j in range(want.size):
            if want[j]:
                tried[j] = pred[j]


@numba.njit(**JIT)
def match_missing(state, t, pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_missing`."""
    found_more = match_traces(state, t, np.nonzero(~state.known)[0], pred, True, p)
    reject_overstretched(state, t, p)
    reject_odd_motion(state, t, p)
    for _ in range(p.zipper_rounds):
        rows, zpred = zipper_predictions(state, p)
        if rows.size == 0 or not match_traces(state, t, rows, zpred, True, p):
            break
        found_more = True
        reject_overstretched(state, t, p)
        reject_odd_motion(state, t, p)
    return found_more


@numba.njit(**JIT)
def track_frame(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.track_frame`."""
    has_points = state.offsets[t + 1] > state.offsets[t]
    v_pred = begin_frame(state, t, p)
    continue_body_chains(state, t, v_pred, p)
    if has_points:
        match_measured(state, t, v_pred, p)
    pred = state.positions[t - 1] + state.velocity
    found_more = False
    if not state.known.all():
        pred = gap_predictions(state, t, p)
        if has_points:
            found_more = match_missing(state, t, pred, p)
            if not state.known.all():
                if reacquire_on_shell(state, t, p):
                    found_more = True
    swapped = swap_onto_curve(state, t, p)
    place_invented(state, t, pred, found_more or swapped, p)
    commit_frame(state, t, p)


@numba.njit(**JIT)
def track_frames(state, t0, t1, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.track_frames`."""
    for t in range(t0, t1):
        track_frame(state, t, p)
