"""The rope tracker's refusals compiled with numba: twins of
:mod:`skincap.tracking._refusals_numpy` (the reference; its docstrings say what each
step does and why), re-exported by :mod:`skincap.tracking._steps_numba`.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._numba_grid import cell_span, fill_grid, grid_rows
from skincap.tracking._numba_search import JIT, norm3

__all__ = [
    "frame_grid",
    "path_back_to_trace",
    "reject_odd_motion",
    "reject_overstretched",
    "rigid_with_body",
    "taken_in_frame",
]

_INF = np.inf
# a search bound's margin: the grid's cells come from (x - lo) * inv, whose rounding
# must not drop a row whose exact distance is within the bound
_PAD = 1.0 + 1e-9


@numba.njit(inline="always", **JIT)
def frame_grid(state, t, p):  # pragma: no cover - runs compiled
    """Frame t's points bucketed in cells γ wide (a
    :mod:`~skincap.tracking._numba_grid` grid), built on the first call for the frame
    into the state's ``grid_*`` buffers and returned from them afterwards."""
    info = state.grid_info
    _ensure_grid(state.points, state.offsets, info, state.grid_starts, state.grid_order, t, p.gamma)
    a, b = state.offsets[t], state.offsets[t + 1]
    s0 = a + 2 * t
    cells = np.int64(info[t, 3])
    return (
        np.int64(info[t, 0]),
        info[t, 1],
        info[t, 2],
        state.grid_starts[s0 : s0 + cells + 1],
        state.grid_order[a:b],
    )


@numba.njit(inline="always", **JIT)
def _ensure_grid(points, offsets, info, starts, order, f, gamma):  # pragma: no cover
    """Bucket frame f into the state's grid buffers (``grid_info``, ``grid_starts``,
    ``grid_order``) unless that was done already (:func:`frame_grid`; the check is
    inlined into the caller, the bucketing is not)."""
    if info[f, 0] < 0.0:
        _fill_frame_grid(points, offsets, info, starts, order, f, gamma)


@numba.njit(**JIT)
def _fill_frame_grid(points, offsets, info, starts, order, f, gamma):  # pragma: no cover
    """Bucket frame f into the state's grid buffers (:func:`_ensure_grid`)."""
    a, b = offsets[f], offsets[f + 1]
    axis, lo, inv, cells = fill_grid(
        points, a, b, gamma, starts[a + 2 * f : b + 2 * f + 2], order[a:b]
    )
    info[f, 0], info[f, 1], info[f, 2], info[f, 3] = axis, lo, inv, cells


@numba.njit(inline="always", **JIT)
def _grid_run(points, offsets, info, starts, order, f, gamma, x, y, z, bound):  # pragma: no cover
    """``(k0, k1)``: ``order[k0:k1]`` (the state's ``grid_order``) are frame f's rows in
    the cells a search ``bound`` metres around (x, y, z) reaches, as
    :func:`_rows_within` of :func:`frame_grid`; the grid is built on first use. Takes
    the state's arrays rather than the state: the backward scans call it for every
    frame of their window, and passing the whole state costs more than the search."""
    _ensure_grid(points, offsets, info, starts, order, f, gamma)
    axis = np.int64(info[f, 0])
    first, last = cell_span(
        info[f, 1],
        info[f, 2],
        np.int64(info[f, 3]),
        x if axis == 0 else (y if axis == 1 else z),
        bound,
    )
    if first > last:
        return 0, 0
    a = offsets[f]
    s0 = a + 2 * f
    return a + starts[s0 + first], a + starts[s0 + last + 1]


@numba.njit(inline="always", **JIT)
def grid_run_of(state, f, gamma, x, y, z, bound):  # pragma: no cover - runs compiled
    """:func:`_grid_run` on a tracker state's arrays, for callers that hold the state
    (inlined into them at compile time, so the state is not passed at run time)."""
    return _grid_run(
        state.points,
        state.offsets,
        state.grid_info,
        state.grid_starts,
        state.grid_order,
        f,
        gamma,
        x,
        y,
        z,
        bound,
    )


@numba.njit(**JIT)
def _rows_within(grid, x, y, z, bound):  # pragma: no cover - runs compiled
    """:func:`~skincap.tracking._numba_grid.grid_rows` around the point (x, y, z)."""
    axis = grid[0]
    return grid_rows(grid, x if axis == 0 else (y if axis == 1 else z), bound)


@numba.njit(**JIT)
def taken_in_frame(point_index, f, q):  # pragma: no cover - runs compiled
    """True when a trace took the point q in frame f."""
    for j in range(point_index.shape[1]):
        if point_index[f, j] == q:
            return True
    return False


@numba.njit(**JIT)
def path_back_to_trace(state, t, j, point, p):  # pragma: no cover - runs compiled
    """Twin of the reference's ``path_back_to_trace``: (point reached, its frame, its
    distance to the trace's own point) or (-1, -1, inf)."""
    points, offsets, point_index = state.points, state.offsets, state.point_index
    info, starts, order = state.grid_info, state.grid_starts, state.grid_order
    x0, x1, x2 = points[point, 0], points[point, 1], points[point, 2]
    v0 = 0.0
    v1 = 0.0
    v2 = 0.0
    reach = p.gamma * _PAD
    for f in range(t - 1, max(t - 1 - p.rigid_window, -1), -1):
        fa, fb = offsets[f], offsets[f + 1]
        if fb == fa:
            return np.int64(-1), np.int64(-1), _INF
        best = _INF
        n = -1
        # only a nearest point within γ counts: the grid's rows within γ of the
        # prediction, ties to the lower row as in a scan of the whole frame
        k0, k1 = _grid_run(
            points, offsets, info, starts, order, f, p.gamma, x0 - v0, x1 - v1, x2 - v2, reach
        )
        for k in range(k0, k1):
            q = order[k]
            dq = norm3(points[q, 0] - (x0 - v0), points[q, 1] - (x1 - v1), points[q, 2] - (x2 - v2))
            if dq < best or (dq == best and q < n):
                best = dq
                n = q
        if not best <= p.gamma:
            return np.int64(-1), np.int64(-1), _INF
        mine = point_index[f, j]
        if mine >= 0:
            apart = norm3(
                points[n, 0] - points[mine, 0],
                points[n, 1] - points[mine, 1],
                points[n, 2] - points[mine, 2],
            )
            return np.int64(n), np.int64(f), apart
        v0 = x0 - points[n, 0]
        v1 = x1 - points[n, 1]
        v2 = x2 - points[n, 2]
        x0, x1, x2 = points[n, 0], points[n, 1], points[n, 2]
    return np.int64(-1), np.int64(-1), _INF


@numba.njit(**JIT)
def _follow_back(points, offsets, grids, t, window, point, tol, traj):  # pragma: no cover
    """Fill ``traj`` (W + 1, 3) with the point's path back by unambiguous nearest points
    at constant velocity (last row the point); False where it is ambiguous.

    Each frame's search scans only its grid's rows within 4 ``tol`` of the prediction:
    the nearest point counts only within 2 ``tol`` and the second only when nearer
    than twice that, so the rows beyond decide nothing. Ties go to the lower row, the
    nearest and second nearest are those of a scan of the whole frame."""
    info, starts, order, gamma = grids
    traj[window] = points[point]
    vx = 0.0
    vy = 0.0
    vz = 0.0
    reach = 4.0 * tol * _PAD
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
        k0, k1 = _grid_run(points, offsets, info, starts, order, f, gamma, qx, qy, qz, reach)
        for k in range(k0, k1):
            q = order[k]
            dd = norm3(points[q, 0] - qx, points[q, 1] - qy, points[q, 2] - qz)
            if dd < d1 or (dd == d1 and q < n1):
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
def _keeps_distance(
    points, offsets, point_index, grids, t, window, traj, c, dq, tol
):  # pragma: no cover
    """True when the partner point ``c`` follows the path ``traj`` back through the
    window at a constant distance ``dq``.

    Each frame's search scans only its grid's rows within ``tol`` of the prediction
    (a nearest point farther refuses anyway); ties go to the lower row, as in a scan
    of the whole frame."""
    info, starts, order, gamma = grids
    qx = points[c, 0]
    qy = points[c, 1]
    qz = points[c, 2]
    reach = tol * _PAD
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
        k0, k1 = _grid_run(points, offsets, info, starts, order, f, gamma, px, py, pz, reach)
        for k in range(k0, k1):
            q = order[k]
            dd = norm3(points[q, 0] - px, points[q, 1] - py, points[q, 2] - pz)
            if (dd < best or (dd == best and q < n)) and not taken_in_frame(point_index, f, q):
                best = dd
                n = q
        if not best < tol:
            return False
        qx = points[n, 0]
        qy = points[n, 1]
        qz = points[n, 2]
        to_p = norm3(qx - traj[r, 0], qy - traj[r, 1], qz - traj[r, 2])
        if not abs(to_p - dq) < tol:
            return False
    return True


@numba.njit(**JIT)
def _near_hidden(state, t, x, y, z, gamma):  # pragma: no cover - runs compiled
    """True when (x, y, z) lies within γ of the prediction V of a trace hidden in frame
    t - 1 and not found yet (the reference's ``_hidden_predictions``)."""
    pos, vel = state.positions[t - 1], state.velocity
    for jj in range(state.known.size):
        if state.known[jj] or state.point_index[t - 1, jj] >= 0:
            continue
        dx = x - (pos[jj, 0] + vel[jj, 0])
        dy = y - (pos[jj, 1] + vel[jj, 1])
        dz = z - (pos[jj, 2] + vel[jj, 2])
        if dx * dx + dy * dy + dz * dz < gamma * gamma:
            return True
    return False


@numba.njit(**JIT)
def rigid_with_body(state, t, j, point, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._refusals_numpy.rigid_with_body`."""
    window = p.rigid_window
    if t < window:
        return False
    points, offsets, point_index = state.points, state.offsets, state.point_index
    # the grid buffers and γ (their cell width) for the scans of every frame
    grids = (state.grid_info, state.grid_starts, state.grid_order, p.gamma)
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
    elif not _follow_back(points, offsets, grids, t, window, point, tol, traj):
        return False
    far = 0.0
    for r in range(window):
        dd = norm3(
            traj[r, 0] - traj[window, 0], traj[r, 1] - traj[window, 1], traj[r, 2] - traj[window, 2]
        )
        far = max(far, dd)
    if far < p.rigid_move * spacing:
        return False
    # partners within rigid_radius of the point, through frame t's grid: the count,
    # not the order they are tried in, decides
    found = 0
    radius = p.rigid_radius * spacing
    info, starts, order, gamma = grids
    k0, k1 = _grid_run(
        points,
        offsets,
        info,
        starts,
        order,
        t,
        gamma,
        traj[window, 0],
        traj[window, 1],
        traj[window, 2],
        radius * _PAD,
    )
    for k in range(k0, k1):
        c = order[k]
        if c == point:
            continue
        dq = norm3(
            points[c, 0] - traj[window, 0],
            points[c, 1] - traj[window, 1],
            points[c, 2] - traj[window, 2],
        )
        if not dq < radius:
            continue
        mine = False
        for jj in range(state.taken.size):
            if state.taken[jj] == c:
                mine = True
        if mine or _near_hidden(state, t, points[c, 0], points[c, 1], points[c, 2], p.gamma):
            continue
        if _keeps_distance(points, offsets, point_index, grids, t, window, traj, c, dq, tol):
            found += 1
            if found >= p.rigid_partners:
                return True
    return False


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


@numba.njit(inline="always", **JIT)
def reject_overstretched(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._refusals_numpy.reject_overstretched`.

    The check that consecutive measured markers lie within their limits (most
    frames: nothing to drop) is inlined into the caller and allocates nothing; the
    chain is rebuilt in :func:`_keep_best_chain` only when one does not."""
    cur, s, gamma, known = state.cur, state.arclength, p.gamma, state.known
    a = -1
    for b in range(known.size):
        if not known[b]:
            continue
        if a >= 0:
            chord = norm3(cur[b, 0] - cur[a, 0], cur[b, 1] - cur[a, 1], cur[b, 2] - cur[a, 2])
            if not chord <= _link_limit(s, state.link_rest, a, b, gamma, p):
                _keep_best_chain(state, t, p)
                return
        a = b


@numba.njit(**JIT)
def _keep_best_chain(state, t, p):  # pragma: no cover - runs compiled
    """:func:`reject_overstretched` once a chord between consecutive measured markers
    is over its limit: keep the best chain, drop the rest."""
    cur, s, gamma = state.cur, state.arclength, p.gamma
    idx = _measured(state.known)
    n = idx.size
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
def _odd_jump(cur, prev, j, c):  # pragma: no cover - runs compiled
    """Coordinate c of marker j's jump minus the mean of its neighbours' (metres)."""
    return (cur[j, c] - prev[j, c]) - 0.5 * (
        (cur[j - 1, c] - prev[j - 1, c]) + (cur[j + 1, c] - prev[j + 1, c])
    )


@numba.njit(inline="always", **JIT)
def reject_odd_motion(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._refusals_numpy.reject_odd_motion` (inlined
    into the caller, nothing allocated)."""
    cur, prev, known = state.cur, state.positions[t - 1], state.known
    m = known.size
    # every marker is judged on the markers measured before any is dropped: marker
    # j - 1 is dropped only once j (the last to read it) has been judged
    pending = -1
    for j in range(1, m - 1):
        odd = False
        if known[j] and known[j - 1] and known[j + 1] and state.temp_count[j] == 0:
            e0 = _odd_jump(cur, prev, j, 0)
            e1 = _odd_jump(cur, prev, j, 1)
            e2 = _odd_jump(cur, prev, j, 2)
            odd = norm3(e0, e1, e2) > p.gamma
        if pending >= 0:
            known[pending] = False
            state.taken[pending] = -1
            pending = -1
        if odd:
            pending = j
    if pending >= 0:
        known[pending] = False
        state.taken[pending] = -1


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
