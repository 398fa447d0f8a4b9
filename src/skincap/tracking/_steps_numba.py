"""The rope tracker's per-frame steps compiled with numba (numba is a core dependency).

Every public function here is the twin of the one of the same name and signature in
:mod:`skincap.tracking._steps_numpy` (the reference; its docstrings say what each
step does and why): the same ``(state, t, …, p)`` arguments, a
:class:`~skincap.tracking.state.TrackState` changed in place and the run's
:class:`~skincap.tracking.state.StepParams`. Loops replace the vectorised
expressions, the KD-tree queries become a k-nearest search over the frame's few
hundred points bucketed along one axis (:mod:`skincap.tracking._numba_grid`: each
frame is bucketed once, into buffers the state keeps (:func:`frame_grid`, compiled in
:mod:`skincap.tracking._refusals_numba`), and every search of that frame and of the
next scans only the cells within its gate: the matching passes, the body-point chains
and the "follows something slower" refusal; the refusals' backward scans search the
grids of the frames of their window),
and the leave-one-out curve is evaluated directly. It takes the same points and
invents the same markers; invented positions agree to rounding (the order of a few
additions differs).

Importing this module imports numba; :func:`track_frames` compiles on its first call
(one to two minutes of one core; cached on disk, loaded in about a second afterwards).
The steps that run once a frame and only orchestrate others (:func:`track_frame`,
:func:`match_measured`, :func:`match_missing`) are inlined into their caller
(``inline="always"``): numba links every callee's code into each compiled function,
so each separately compiled layer of the call tree compiled the whole tracker again
(a quarter of the compile time). So are the small helpers and the steps with one
caller that take the state, and the checks that let a step return at once (most
frames find every trace and hide no held end): a compiled call that passes the
state costs more than such a check, since the callee takes a reference to each of
the state's arrays on entry and drops it on return (about 0.2 µs a call). ``track_rope(backend="auto")`` never waits for it:
it runs the NumPy steps while :func:`skincap.tracking.tracker.warm_up_kernel`
compiles these in a background process (:mod:`skincap.backends`). The refusals and
the re-acquisition are compiled in :mod:`skincap.tracking._refusals_numba` and
:mod:`skincap.tracking._reacquire_numba`, the bridging in
:mod:`skincap.tracking._bridge_numba`, and re-exported here.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._bridge_numba import bridge_hidden_runs
from skincap.tracking._hand_numba import (
    follow_hand,
    place_with_hand,
    release_hand,
    search_with_hand,
    seat_hand,
    zip_with_hand,
)
from skincap.tracking._numba_curve import (
    carry_last_seen,
    curve_at,
    drag_free_ends,
    end_is_free,
    fill_interior,
    interp_along,
    known_span,
    neighbour_velocity,
    predict_ends,
    settle,
    side_neighbours,
)
from skincap.tracking._numba_grid import grid_nearest
from skincap.tracking._numba_search import JIT, gated_assignment, is_taken, norm3
from skincap.tracking._reacquire_numba import reacquire_on_shell
from skincap.tracking._refusals_numba import (
    _rows_within,
    frame_grid,
    reject_odd_motion,
    reject_overstretched,
    rigid_with_body,
    taken_in_frame,
)
from skincap.tracking.curve import HELD_END_REACH

__all__ = [
    "accelerated_prediction",
    "begin_frame",
    "bridge_hidden_runs",
    "commit_frame",
    "continue_body_chains",
    "gap_predictions",
    "learn_link_rest",
    "match_measured",
    "match_measured_best",
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
    "unshift_chain",
    "zipper_predictions",
]

_INF = np.inf
_PINNING_REACH = 2  # skincap.tracking._steps_numpy.PINNING_REACH
_END_VELOCITY_FRAMES = 3  # skincap.tracking._steps_numpy.END_VELOCITY_FRAMES
# the gate flags as NumPy bools, not literals: match_traces compiles once, not twice
_WIDE = np.bool_(True)
_NARROW = np.bool_(False)


@numba.njit(inline="always", **JIT)
def _steady(state):  # pragma: no cover - runs compiled
    """(M,) bool: traces measured in the previous frame (no temporary marker running)."""
    return state.temp_count == 0


# ------------------------------------------------------------------ frame start and end
@numba.njit(inline="always", **JIT)
def begin_frame(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.begin_frame`."""
    m = state.known.size
    for j in range(m):
        state.known[j] = False
        state.taken[j] = -1
        for c in range(3):
            state.cur[j, c] = 0.0
    return state.positions[t - 1] + state.velocity


@numba.njit(inline="always", **JIT)
def commit_frame(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.commit_frame`."""
    prev = state.positions[t - 1]
    # a trace back from temporary markers: its neighbours' velocity where the point is
    # confirmed as its marker, else its own jump (counted before temp_count moves on)
    m = state.known.size
    any_back, any_moving = False, False
    for j in range(m):
        if state.known[j]:
            if state.invented[t - 1, j]:
                any_back = True
            else:
                any_moving = True
    # most frames have no trace back from temporary markers: nothing to confirm
    returns = any_back and any_moving
    if returns:
        back = np.zeros(m, np.bool_)
        moving = np.zeros(m, np.bool_)
        for j in range(m):
            back[j] = state.known[j] and state.invented[t - 1, j]
            moving[j] = state.known[j] and not state.invented[t - 1, j]
        jump = state.cur - prev
        v_tilde = neighbour_velocity(moving, jump, jump)
        confirmed = _confirmed_returns(state, t, back, v_tilde, p)
    for j in range(state.known.size):
        known = state.known[j]
        state.temp_count[j] = 0 if known else state.temp_count[j] + 1
        state.invented[t, j] = not known
        pinned = False
        for k in range(max(0, j - _PINNING_REACH), min(state.known.size, j + _PINNING_REACH + 1)):
            pinned |= state.known[k]
        state.lost_frames[t, j] = state.temp_count[j] > p.max_temp_markers and not pinned
        state.point_index[t, j] = state.taken[j]
        for c in range(3):
            state.positions[t, j, c] = state.cur[j, c]
            state.velocity[j, c] = state.cur[j, c] - prev[j, c]
    if returns:
        for j in range(m):
            if confirmed[j]:
                for c in range(3):
                    state.velocity[j, c] = v_tilde[j, c]
    learn_link_rest(state, t, p)


@numba.njit(**JIT)
def _confirmed_returns(state, t, back, v_tilde, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy._confirmed_returns`."""
    m = back.size
    g2 = p.gamma * p.gamma
    pos = state.positions
    confirmed = np.zeros(m, np.bool_)
    for j in range(m):
        if not back[j]:
            continue
        e = state.cur[j] - (pos[t - 1, j] + v_tilde[j])
        if e[0] * e[0] + e[1] * e[1] + e[2] * e[2] <= g2:
            confirmed[j] = True
            continue
        f = t - 1 - state.temp_count[j]  # the frame j was last measured in
        if f < 0 or state.invented[f, j]:
            continue
        for k in (j - 1, j + 1):
            if 0 <= k < m and state.known[k] and not state.invented[f, k]:
                d = (state.cur[j] - state.cur[k]) - (pos[f, j] - pos[f, k])
                if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= g2:
                    confirmed[j] = True
    return confirmed


@numba.njit(inline="always", **JIT)
def learn_link_rest(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.learn_link_rest`."""
    known, cur = state.known, state.cur
    for j in range(known.size - 1):
        if known[j] and known[j + 1]:
            chord = norm3(
                cur[j + 1, 0] - cur[j, 0], cur[j + 1, 1] - cur[j, 1], cur[j + 1, 2] - cur[j, 2]
            )
            rest = state.spacing[j]
            if not (state.invented[t - 1, j] or state.invented[t - 1, j + 1]):
                rest = max(rest, p.median_spacing)
            chord = min(chord, p.stretch * rest)
            if chord > state.link_rest[j]:
                state.link_rest[j] = chord


# ------------------------------------------------------------------ body points
@numba.njit(inline="always", **JIT)
def continue_body_chains(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.continue_body_chains`."""
    points, body, body_vel = state.points, state.body, state.body_vel
    pa, a, b = state.offsets[t - 1], state.offsets[t], state.offsets[t + 1]
    for i in range(a, b):
        body[i] = False
        for c in range(3):
            body_vel[i, c] = 0.0
    if b == a:
        return
    eps = p.body_chain_gate * p.gamma
    # frame t's points near where each body point of frame t - 1 goes (its velocity)
    grid = frame_grid(state, t, p)
    q_count = np.zeros(a - pa, np.int64)
    p_q = np.full(b - a, -1, np.int64)
    p_count = np.zeros(b - a, np.int64)
    for q in range(pa, a):
        if not body[q]:
            continue
        x = points[q, 0] + body_vel[q, 0]
        y = points[q, 1] + body_vel[q, 1]
        z = points[q, 2] + body_vel[q, 2]
        k0, k1 = _rows_within(grid, x, y, z, eps)
        for k in range(k0, k1):
            i = grid[4][k]
            if _closer(points, i, x, y, z, eps):
                p_count[i - a] += 1
                q_count[q - pa] += 1
                p_q[i - a] = q
    # and near the predictions V of every trace, measured or hidden in frame t - 1
    near_rope = np.zeros(b - a, np.bool_)
    for j in range(v_pred.shape[0]):
        x, y, z = v_pred[j, 0], v_pred[j, 1], v_pred[j, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        k0, k1 = _rows_within(grid, x, y, z, eps)
        for k in range(k0, k1):
            i = grid[4][k]
            if _closer(points, i, x, y, z, eps):
                near_rope[i - a] = True
    for i in range(a, b):
        if p_count[i - a] != 1 or near_rope[i - a] or q_count[p_q[i - a] - pa] != 1:
            continue
        q = p_q[i - a]
        body[i] = True
        for c in range(3):
            body_vel[i, c] = points[i, c] - points[q, c]


@numba.njit(**JIT)
def _closer(points, i, x, y, z, bound):  # pragma: no cover - runs compiled
    """Point i lies strictly within ``bound`` metres of (x, y, z) (squared distances
    added per axis, as the NumPy twin adds them)."""
    ex = points[i, 0] - x
    ey = points[i, 1] - y
    ez = points[i, 2] - z
    return ex * ex + ey * ey + ez * ez < bound * bound


# ------------------------------------------------------------------ matching
@numba.njit(inline="always", **JIT)
def _follows_other(state, t, row, candidate, pred, gamma, prev_grid):  # pragma: no cover
    """The candidate point lies within ``min(γ, D - γ)`` of a point of frame t - 1 the
    rope did not take, ``D`` how far trace ``row`` is predicted to move; ``prev_grid``
    is frame t - 1's (:func:`frame_grid`)."""
    points = state.points
    lim = min(
        gamma,
        norm3(
            pred[row, 0] - state.positions[t - 1, row, 0],
            pred[row, 1] - state.positions[t - 1, row, 1],
            pred[row, 2] - state.positions[t - 1, row, 2],
        )
        - gamma,
    )
    if lim <= 0.0:
        return False
    x, y, z = points[candidate, 0], points[candidate, 1], points[candidate, 2]
    k0, k1 = _rows_within(prev_grid, x, y, z, lim)
    for k in range(k0, k1):
        q = prev_grid[4][k]
        # squared distances as the NumPy twin adds them (candidate minus q)
        if _closer(points, q, x, y, z, lim) and not taken_in_frame(state.point_index, t - 1, q):
            return True
    return False


@numba.njit(inline="always", **JIT)
def _continues_missed(state, t, candidate, dist, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy._continues_missed` for one
    candidate point at ``dist`` metres from the returning trace's prediction."""
    gate2 = (p.wide_gate * p.gamma) ** 2
    own2 = dist**2
    x, y, z = state.points[candidate, 0], state.points[candidate, 1], state.points[candidate, 2]
    for j in range(state.known.size):
        if state.temp_count[j] != 0 or state.known[j]:
            continue
        dx = x - (state.positions[t - 1, j, 0] + state.velocity[j, 0])
        dy = y - (state.positions[t - 1, j, 1] + state.velocity[j, 1])
        dz = z - (state.positions[t - 1, j, 2] + state.velocity[j, 2])
        d2 = dx * dx + dy * dy + dz * dz
        if d2 <= gate2 and d2 < own2:
            return True
    return False


@numba.njit(inline="always", **JIT)
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
    grid = frame_grid(state, t, p)
    for r in range(rows.size):
        grid_nearest(state.points, grid, b, pred[rows[r]], kk, gate, d[r], ii[r])
    if n_taken:
        for r in range(rows.size):
            for c in range(kk):
                if d[r, c] < _INF and is_taken(ii[r, c], known, taken):
                    d[r, c] = _INF
    return d, ii


@numba.njit(inline="always", **JIT)
def _loose(state):  # pragma: no cover - runs compiled
    """(M,) bool, all False: no trace held to γ in a wide search."""
    return np.zeros(state.known.size, np.bool_)


@numba.njit(inline="always", **JIT)
def _refuse_off_spacing(state, rows, d, ii, gamma):  # pragma: no cover - runs compiled
    """Refuse (inf) candidates more than γ beyond their rest spacing from a measured
    neighbour, or beyond γ of the prediction and more than γ short of it, or beyond
    γ with no measured neighbour."""
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
                if chord - rest > gamma or (rest - chord > gamma and d[r, c] >= gamma):
                    d[r, c] = _INF


@numba.njit(**JIT)
def match_traces(state, t, rows, pred, wide, tight, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_traces`; the refusals of
    each candidate are asked cheapest first, and none once one refuses."""
    a, b = state.offsets[t], state.offsets[t + 1]
    if rows.size == 0 or b == a:
        return False
    gamma = p.gamma
    gate = p.wide_gate * gamma if wide else gamma
    m = state.known.size
    d, ii = _candidates(state, t, rows, pred, gate, p)
    prev_grid = frame_grid(state, t - 1, p)
    for r in range(rows.size):
        row = rows[r]
        steady = state.temp_count[row] == 0
        slow = False  # a steady trace predicted to move at most γ: nothing beyond γ
        if wide and gate > gamma and steady:
            ex = pred[row, 0] - state.positions[t - 1, row, 0]
            ey = pred[row, 1] - state.positions[t - 1, row, 1]
            ez = pred[row, 2] - state.positions[t - 1, row, 2]
            slow = ex * ex + ey * ey + ez * ez <= gamma * gamma
        judged = not steady or 0 < row < m - 1  # the ends of a steady rope are exempt
        for c in range(d.shape[1]):
            if not d[r, c] < _INF:  # beyond the gate, or taken
                continue
            i = ii[r, c]
            if (
                (not steady and state.body[i])
                or ((slow or tight[row]) and d[r, c] >= gamma)
                or (judged and _follows_other(state, t, row, i, pred, gamma, prev_grid))
                or (wide and not steady and rigid_with_body(state, t, np.int64(-1), i, p))
                or (wide and not steady and _continues_missed(state, t, i, d[r, c], p))
            ):
                d[r, c] = _INF
    if wide:
        _refuse_off_spacing(state, rows, d, ii, gamma)
    hit_rows, pts = gated_assignment(d, ii, gate)
    for h in range(hit_rows.size):
        row = rows[hit_rows[h]]
        state.known[row] = True
        state.taken[row] = pts[h]
        for c in range(3):
            state.cur[row, c] = state.points[pts[h], c]
    return hit_rows.size > 0


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
def accelerated_prediction(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.accelerated_prediction`."""
    out = v_pred.copy()
    if t < 3:
        return out
    x, invented = state.positions, state.invented
    for j in range(out.shape[0]):
        if invented[t - 1, j] or invented[t - 2, j] or invented[t - 3, j]:
            continue
        for c in range(3):
            out[j, c] = v_pred[j, c] + ((x[t - 1, j, c] - 2.0 * x[t - 2, j, c]) + x[t - 3, j, c])
    return out


@numba.njit(inline="always", **JIT)
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
    seat_hand(state, t, p)
    search_with_hand(state, t, pred, p)
    return pred


@numba.njit(inline="always", **JIT)
def _carry_hidden(state, t, pred, rows_mask, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy._carry_hidden`."""
    m = state.known.size
    free_runs = _free_end_runs(state, t)
    for j in range(m):
        free_runs[j] = free_runs[j] and rows_mask[j]
    if free_runs.any():
        velocity = _end_velocity(state, t, free_runs)
        pred = drag_free_ends(
            pred, state.known, state.positions[t - 1], velocity, state.spacing, free_runs
        )
    if p.carry_tolerance <= 0.0:
        return pred
    before, after = side_neighbours(state.known)
    want = np.zeros(m, np.bool_)
    n = 0
    for j in range(m):
        inside = before[j] >= 0 and after[j] < m
        if rows_mask[j] and inside and not state.known[j] and t - 1 - state.temp_count[j] >= 0:
            want[j] = True
            n += 1
    if n == 0:
        return pred
    rows = np.empty(n, np.int64)
    then = np.empty((n, m, 3))
    then_measured = np.empty((n, m), np.bool_)
    u = 0
    for j in range(m):
        last = t - 1 - state.temp_count[j]
        if want[j]:
            rows[u] = j
            then[u] = state.positions[last]
            for k in range(m):
                then_measured[u, k] = not state.invented[last, k]
            u += 1
    tolerance = p.carry_tolerance * p.median_spacing
    return carry_last_seen(pred, state.cur, state.known, rows, then, then_measured, tolerance)


@numba.njit(inline="always", **JIT)
def _end_velocity(state, t, rows_mask):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy._end_velocity`."""
    out = state.velocity.copy()
    for j in range(rows_mask.size):
        if not rows_mask[j] or state.temp_count[j] != 0:
            continue
        out[j] = 0.0
        for f in range(max(t - 1 - _END_VELOCITY_FRAMES, 0), t - 1):
            if not state.invented[f, j]:
                for c in range(3):
                    out[j, c] = (state.positions[t - 1, j, c] - state.positions[f, j, c]) / (
                        t - 1 - f
                    )
                break
    return out


@numba.njit(inline="always", **JIT)
def _free_end_runs(state, t):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy._free_end_runs`."""
    known = state.known
    m = known.size
    runs = np.zeros(m, np.bool_)
    first, last = known_span(known)
    if first < 0:
        return runs
    for side in range(2):
        e = 0 if side == 0 else m - 1
        seen = t - 1 - state.temp_count[e]
        if known[e] or seen < 0:
            continue
        a, b = state.offsets[seen], state.offsets[seen + 1]
        is_rope = np.zeros(b - a, np.bool_)
        for k in range(m):
            i = state.point_index[seen, k]
            if i >= 0:
                is_rope[i - a] = True
        if end_is_free(state.positions[seen, e], state.points[a:b], is_rope, HELD_END_REACH):
            lo, hi = (0, first) if side == 0 else (last + 1, m)
            for j in range(lo, hi):
                runs[j] = True
    return runs


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


# ------------------------------------------------------------------ after matching
@numba.njit(inline="always", **JIT)
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
        # outside the markers that define it), into the next free row: kept if odd
        c = c_all[n_odd]
        curve_at(x, known, state.arclength, j, before[j], after[j], before, after, c)
        dev = norm3(cur[j, 0] - c[0], cur[j, 1] - c[1], cur[j, 2] - c[2])
        if dev > 2.0 * gamma:
            rows[n_odd] = j
            dev_all[n_odd] = dev
            n_odd += 1
    if n_odd == 0:
        return False
    kk = min(min(p.candidates, b - a) + n_taken, b - a)
    d = np.empty((n_odd, kk))
    ii = np.empty((n_odd, kk), np.int64)
    grid = frame_grid(state, t, p)
    for r in range(n_odd):
        grid_nearest(state.points, grid, b, c_all[r], kk, gamma, d[r], ii[r])
        for k in range(kk):
            if is_taken(ii[r, k], known, taken) or d[r, k] > dev_all[r] - gamma:
                d[r, k] = _INF
    hit_rows, pts = gated_assignment(d, ii, gamma)
    for h in range(hit_rows.size):
        row = rows[hit_rows[h]]
        taken[row] = pts[h]
        cur[row] = state.points[pts[h]]
    return hit_rows.size > 0


@numba.njit(inline="always", **JIT)
def unshift_chain(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.unshift_chain` (the check inlined
    into the caller: most frames find every trace, and the call is the cost)."""
    if state.offsets[t + 1] == state.offsets[t] or state.known.size < 3 or state.known.all():
        return False
    return _unshift_chain(state, t, p)


@numba.njit(**JIT)
def _unshift_chain(state, t, p):  # pragma: no cover - runs compiled
    """:func:`unshift_chain` once frame t has points and a trace is still hidden."""
    a, b = state.offsets[t], state.offsets[t + 1]
    known, taken, cur, gamma = state.known, state.taken, state.cur, p.gamma
    m = known.size
    for e in (0, m - 1):
        step = 1 if e == 0 else -1
        if not (known[e] and known[e + step]) or state.temp_count[e] != 0:
            continue
        v = state.positions[t - 1, e] + state.velocity[e]
        miss = norm3(cur[e, 0] - v[0], cur[e, 1] - v[1], cur[e, 2] - v[2])
        if miss <= 2.0 * gamma:
            continue
        q, best = -1, _INF
        for i in range(a, b):
            if state.body[i] or is_taken(i, known, taken):
                continue
            x = state.points[i]
            d = norm3(x[0] - v[0], x[1] - v[1], x[2] - v[2])
            if d < best:
                q, best = i, d
        if q < 0 or not best < gamma:
            continue
        x = state.points[q]
        gap = norm3(x[0] - cur[e, 0], x[1] - cur[e, 1], x[2] - cur[e, 2])
        link = state.link_rest[0 if e == 0 else m - 2]
        if abs(gap - link) > gamma:
            continue
        u = e  # the first trace not found from e
        while known[u]:
            u += step
        j = u
        while j != e:
            taken[j] = taken[j - step]
            cur[j] = cur[j - step]
            j -= step
        known[u] = True
        taken[e] = q
        cur[e] = state.points[q]
        return True
    return False


@numba.njit(inline="always", **JIT)
def place_invented(state, t, pred, refit, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.place_invented` (the check inlined
    into the caller: most frames find every trace, and the call is the cost)."""
    if not state.known.all():
        _place_invented(state, t, pred, refit, p)


@numba.njit(**JIT)
def _place_invented(state, t, pred, refit, p):  # pragma: no cover - runs compiled
    """:func:`place_invented` once a trace is still hidden."""
    known, cur = state.known, state.cur
    m = known.size
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
    carried = _carry_hidden(state, t, cur, ~known, p)
    for j in range(m):
        if not known[j]:
            cur[j] = carried[j]


# ------------------------------------------------------------------ a frame
@numba.njit(inline="always", **JIT)
def match_measured(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_measured`."""
    steady = _steady(state)
    match_traces(state, t, np.nonzero(steady)[0], v_pred, _NARROW, _loose(state), p)
    reject_overstretched(state, t, p)
    reject_odd_motion(state, t, p)
    tried = v_pred  # copied before its first change
    copied = False
    half_gamma2 = (0.5 * p.gamma) ** 2
    for _ in range(p.retry_rounds):
        # a steady trace found and one not (most frames find all): asked without
        # allocating the masks
        any_found, any_want = False, False
        for j in range(steady.size):
            if steady[j]:
                if state.known[j]:
                    any_found = True
                else:
                    any_want = True
        if not (any_found and any_want):
            break
        want = steady & ~state.known
        pred = residual_predictions(state, t, v_pred, p)
        for j in range(want.size):
            if want[j]:
                e0 = pred[j, 0] - tried[j, 0]
                e1 = pred[j, 1] - tried[j, 1]
                e2 = pred[j, 2] - tried[j, 2]
                if not (e0 * e0 + e1 * e1 + e2 * e2 > half_gamma2):
                    want[j] = False
        if not want.any():
            break
        if not match_traces(state, t, np.nonzero(want)[0], pred, _WIDE, _loose(state), p):
            break
        reject_overstretched(state, t, p)
        reject_odd_motion(state, t, p)
        if not copied:
            tried = v_pred.copy()
            copied = True
        for j in range(want.size):
            if want[j]:
                tried[j] = pred[j]


@numba.njit(inline="always", **JIT)
def _match_score(state, pred):  # pragma: no cover - runs compiled
    """Traces found this frame and their summed distance (metres) to ``pred``."""
    n, total = 0, 0.0
    for j in range(state.known.size):
        if state.known[j]:
            n += 1
            total += norm3(
                state.cur[j, 0] - pred[j, 0],
                state.cur[j, 1] - pred[j, 1],
                state.cur[j, 2] - pred[j, 2],
            )
    return n, total


@numba.njit(inline="always", **JIT)
def _is_blank(state):  # pragma: no cover - runs compiled
    """Nothing found this frame yet: ``known`` all False, ``taken`` all -1, ``cur`` all 0."""
    for j in range(state.known.size):
        if state.known[j] or state.taken[j] != -1:
            return False
        for c in range(3):
            if state.cur[j, c] != 0.0:
                return False
    return True


@numba.njit(inline="always", **JIT)
def match_measured_best(state, t, v_pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_measured_best`."""
    known, taken, cur = state.known, state.taken, state.cur
    # the frame as begin_frame left it (nothing found, nothing taken, cur zero) is not
    # copied: the second matching below resets to it instead (most frames never get there)
    blank = _is_blank(state)
    if blank:
        start_known, start_taken, start_cur = known[:0], taken[:0], cur[:0]
    else:
        start_known, start_taken, start_cur = known.copy(), taken.copy(), cur.copy()
    match_measured(state, t, v_pred, p)
    gate2 = (p.swing_gate * p.gamma) ** 2
    explained = True  # V found every steady trace near it
    for j in range(v_pred.shape[0]):
        if state.temp_count[j] != 0:
            continue
        ex = cur[j, 0] - v_pred[j, 0]
        ey = cur[j, 1] - v_pred[j, 1]
        ez = cur[j, 2] - v_pred[j, 2]
        if not known[j] or ex * ex + ey * ey + ez * ez > gate2:
            explained = False
    if explained:
        return
    v_acc = accelerated_prediction(state, t, v_pred, p)
    swings = False
    for j in range(v_acc.shape[0]):
        ex = v_acc[j, 0] - v_pred[j, 0]
        ey = v_acc[j, 1] - v_pred[j, 1]
        ez = v_acc[j, 2] - v_pred[j, 2]
        if ex * ex + ey * ey + ez * ez > gate2:
            swings = True
    if not swings:
        return
    v_known, v_taken, v_cur = known.copy(), taken.copy(), cur.copy()
    n_v, d_v = _match_score(state, v_pred)
    if blank:
        known[:] = False
        taken[:] = -1
        cur[:] = 0.0
    else:
        known[:] = start_known
        taken[:] = start_taken
        cur[:] = start_cur
    match_measured(state, t, v_acc, p)
    n_a, d_a = _match_score(state, v_acc)
    # traces both matchings found, on different points: the nearer ones win
    disputed_v, disputed_a, disputes = 0.0, 0.0, False
    for j in range(v_acc.shape[0]):
        if known[j] and v_known[j] and taken[j] != v_taken[j]:
            disputes = True
            disputed_v += norm3(
                v_cur[j, 0] - v_pred[j, 0], v_cur[j, 1] - v_pred[j, 1], v_cur[j, 2] - v_pred[j, 2]
            )
            disputed_a += norm3(
                cur[j, 0] - v_acc[j, 0], cur[j, 1] - v_acc[j, 1], cur[j, 2] - v_acc[j, 2]
            )
    if disputes:
        n_v, d_v, n_a, d_a = 0, disputed_v, 0, disputed_a
    if n_v > n_a or (n_v == n_a and d_v <= d_a):
        known[:] = v_known
        taken[:] = v_taken
        cur[:] = v_cur


@numba.njit(inline="always", **JIT)
def match_missing(state, t, pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.match_missing`."""
    found_more = match_traces(state, t, np.nonzero(~state.known)[0], pred, _WIDE, _loose(state), p)
    reject_overstretched(state, t, p)
    reject_odd_motion(state, t, p)
    for _ in range(p.zipper_rounds):
        rows, zpred = zipper_predictions(state, p)
        tight = zip_with_hand(state, t, rows, zpred, p)
        if rows.size == 0 or not match_traces(state, t, rows, zpred, _WIDE, tight, p):
            break
        found_more = True
        reject_overstretched(state, t, p)
        reject_odd_motion(state, t, p)
    return found_more


@numba.njit(inline="always", **JIT)
def track_frame(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.track_frame`."""
    has_points = state.offsets[t + 1] > state.offsets[t]
    v_pred = begin_frame(state, t, p)
    continue_body_chains(state, t, v_pred, p)
    follow_hand(state, t, p)
    if has_points:
        match_measured_best(state, t, v_pred, p)
    pred = state.positions[t - 1] + state.velocity
    found_more = False
    if not state.known.all():
        pred = gap_predictions(state, t, p)
        if has_points:
            found_more = match_missing(state, t, pred, p)
            if not state.known.all():
                if reacquire_on_shell(state, t, p):
                    found_more = True
            if not state.known.all():
                if bridge_hidden_runs(state, t, pred, p):
                    found_more = True
    swapped = unshift_chain(state, t, p)
    if swap_onto_curve(state, t, p):
        swapped = True
    place_invented(state, t, pred, found_more or swapped, p)
    seat_hand(state, t, p)
    place_with_hand(state, t, p)
    commit_frame(state, t, p)
    release_hand(state, t, p)


@numba.njit(**JIT)
def track_frames(state, t0, t1, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._steps_numpy.track_frames`."""
    for t in range(t0, t1):
        track_frame(state, t, p)


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
