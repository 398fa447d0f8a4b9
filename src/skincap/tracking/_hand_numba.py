"""A hidden held end carried by the hand that holds it, compiled with numba.

Twins of :mod:`skincap.tracking._hand_numpy` (the reference, where the method is
told): same names, signatures and results.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._numba_grid import insert_nearest
from skincap.tracking._numba_search import JIT
from skincap.tracking._refusals_numba import (
    _PAD,
    _link_limit,
    grid_run_of,
    rigid_with_body,
    taken_in_frame,
)
from skincap.tracking.curve import HELD_END_REACH

__all__ = [
    "carry_with_hand",
    "follow_hand",
    "place_with_hand",
    "release_hand",
    "search_with_hand",
    "seat_hand",
    "zip_with_hand",
]

_INF = np.inf


@numba.njit(inline="always", **JIT)
def seat_hand(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.seat_hand`."""
    if t < 1:
        return
    f = t - 1
    a, b = state.offsets[f], state.offsets[f + 1]
    m = state.known.size
    k_max = state.hand_index.shape[1]
    for row in range(2):
        e = 0 if row == 0 else m - 1
        if state.known[e] or state.temp_count[e] > 0 or b == a:
            continue
        seated = False
        for k in range(k_max):
            seated |= state.hand_index[row, k] >= 0
        if seated:
            continue
        _seat_row(state, f, row, e, p)
        _follow_row(state, t, row, p)


@numba.njit(**JIT)
def _seat_row(state, f, row, e, p):  # pragma: no cover - runs compiled
    """Row ``row`` of the hand: the ``K`` points of frame f nearest to trace ``e``'s
    position there (no trace's point, within ``HELD_END_REACH``; by (distance, row) as
    the reference's stable sort orders them), their positions and ``e``'s velocity.

    Scans only frame f's grid rows within the reach
    (:func:`~skincap.tracking._refusals_numba.frame_grid`), not the whole frame."""
    points, order = state.points, state.grid_order
    k_max = state.hand_index.shape[1]
    reach2 = HELD_END_REACH * HELD_END_REACH
    x0, x1, x2 = state.positions[f, e, 0], state.positions[f, e, 1], state.positions[f, e, 2]
    k0, k1 = grid_run_of(state, f, p.gamma, x0, x1, x2, HELD_END_REACH * _PAD)
    kept = state.hand_index[row]  # all -1 here (the caller seats an empty row only)
    d_kept = np.empty(k_max)
    n = 0
    for k in range(k0, k1):
        q = order[k]
        dx = points[q, 0] - x0
        dy = points[q, 1] - x1
        dz = points[q, 2] - x2
        d = dx * dx + dy * dy + dz * dz  # squared, summed x, y, z
        if not d <= reach2:
            continue
        if n == k_max and (d > d_kept[n - 1] or (d == d_kept[n - 1] and q > kept[n - 1])):
            continue
        if taken_in_frame(state.point_index, f, q):
            continue
        n = insert_nearest(d_kept, kept, n, k_max, d, q)
    for u in range(n):
        for c in range(3):
            state.hand_then[row, u, c] = points[kept[u], c]
            state.hand_vel[row, u, c] = state.velocity[e, c]


@numba.njit(inline="always", **JIT)
def release_hand(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.release_hand`."""
    m = state.known.size
    for row in range(2):
        if state.known[0 if row == 0 else m - 1]:
            for k in range(state.hand_index.shape[1]):
                state.hand_index[row, k] = -1


@numba.njit(inline="always", **JIT)
def follow_hand(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.follow_hand`."""
    for row in range(2):
        if _has_anchors(state, row):
            _follow_row(state, t, row, p)


@numba.njit(inline="always", **JIT)
def _has_anchors(state, row):  # pragma: no cover - runs compiled
    """Row ``row`` of ``hand_index`` holds an anchor (most frames it holds none)."""
    for k in range(state.hand_index.shape[1]):
        if state.hand_index[row, k] >= 0:
            return True
    return False


@numba.njit(inline="always", **JIT)
def _carries(state):  # pragma: no cover - runs compiled
    """An end hidden so far this frame has anchors: :func:`carry_with_hand` moves it."""
    m = state.known.size
    for row in range(2):
        if not state.known[0 if row == 0 else m - 1] and _has_anchors(state, row):
            return True
    return False


@numba.njit(**JIT)
def _follow_row(state, t, row, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy._follow_row`."""
    a, b = state.offsets[t], state.offsets[t + 1]
    g2 = p.gamma * p.gamma
    points, order = state.points, state.grid_order
    pred = np.empty(3)
    end = 0 if row == 0 else state.known.size - 1
    for k in range(state.hand_index.shape[1]):
        q = state.hand_index[row, k]
        if q < 0:
            continue
        state.hand_index[row, k] = -1
        if b - a < 1:
            continue
        for c in range(3):
            pred[c] = state.points[q, c] + state.hand_vel[row, k, c]
        # the nearest point must lie within γ and the next beyond twice its distance,
        # so only frame t's grid rows within 2γ of the prediction can decide
        k0, k1 = grid_run_of(state, t, p.gamma, pred[0], pred[1], pred[2], 2.0 * p.gamma * _PAD)
        best, second, new = _INF, _INF, -1
        for u in range(k0, k1):
            i = order[u]
            dx = points[i, 0] - pred[0]
            dy = points[i, 1] - pred[1]
            dz = points[i, 2] - pred[2]
            d = dx * dx + dy * dy + dz * dz  # squared, summed x, y, z
            if d < best or (d == best and i < new):  # ties to the lower row, as a scan
                second = best
                best = d
                new = i
            elif d < second:
                second = d
        if best > g2 or second <= 4.0 * best:
            continue
        dup = False
        for u in range(k):
            if state.hand_index[row, u] == new:
                dup = True
        if dup:
            continue
        state.hand_index[row, k] = new
        for c in range(3):
            state.hand_vel[row, k, c] = state.points[new, c] - state.points[q, c]
        if state.temp_count[end] > 0:
            state.body[new] = True
            for c in range(3):
                state.body_vel[new, c] = state.hand_vel[row, k, c]


@numba.njit(**JIT)
def carry_with_hand(state, t, cur, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.carry_with_hand`."""
    m = state.known.size
    k_max = state.hand_index.shape[1]
    for row in range(2):
        e = 0 if row == 0 else m - 1
        if state.known[e]:
            continue
        last = t - 1 - state.temp_count[e]
        n = 0
        for k in range(k_max):
            if state.hand_index[row, k] >= 0:
                n += 1
        if last < 0 or n == 0:
            continue
        if state.invented[last, e]:
            continue
        now = np.empty((n, 3))
        then = np.empty((n, 3))
        u = 0
        for k in range(k_max):
            q = state.hand_index[row, k]
            if q >= 0:
                now[u] = state.points[q]
                then[u] = state.hand_then[row, k]
                u += 1
        c_then = np.zeros(3)
        c_now = np.zeros(3)
        for u in range(n):
            c_then += then[u] / n
            c_now += now[u] / n
        x = state.positions[last, e]
        moved = x + (c_now - c_then)
        if n >= 3:
            a_m = then - c_then
            b_m = now - c_now
            h = np.ascontiguousarray(a_m.T) @ b_m  # (3, 3)
            u_svd, _, vt = np.linalg.svd(h)
            d = np.eye(3)
            v_m = np.ascontiguousarray(vt.T)
            u_t = np.ascontiguousarray(u_svd.T)
            d[2, 2] = np.sign(np.linalg.det(v_m @ u_t))
            rot = v_m @ d @ u_t
            fit = a_m @ np.ascontiguousarray(rot.T)
            ss = 0.0
            for u in range(n):
                for c in range(3):
                    r = b_m[u, c] - fit[u, c]
                    ss += r * r
            if np.sqrt(ss / n) <= p.rigid_range * p.median_spacing:
                moved = rot @ (x - c_then) + c_now
        if _carry_keeps_rope(state, last, t, e, moved, p):
            for c in range(3):
                cur[e, c] = moved[c]


@numba.njit(**JIT)
def _carry_keeps_rope(state, last, t, e, moved, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy._carry_keeps_rope`."""
    m = state.known.size
    j = -1
    if e == 0:
        for i in range(m):
            if state.known[i]:
                j = i
                break
    else:
        for i in range(m - 1, -1, -1):
            if state.known[i]:
                j = i
                break
    if j < 0:
        return True
    for f in range(last, t):
        if state.invented[f, j]:
            return True
    lim = _link_limit(state.arclength, state.link_rest, min(e, j), max(e, j), p.gamma, p)
    d2 = 0.0
    for c in range(3):
        r = moved[c] - state.cur[j, c]
        d2 += r * r
    return d2 <= lim * lim


@numba.njit(inline="always", **JIT)
def search_with_hand(state, t, pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.search_with_hand` (the check inlined
    into the caller: most frames no hidden end has a hand, and the call is the cost)."""
    if _carries(state):
        _search_with_hand(state, t, pred, p)


@numba.njit(**JIT)
def _search_with_hand(state, t, pred, p):  # pragma: no cover - runs compiled
    """:func:`search_with_hand` once an end hidden so far has anchors."""
    carried = pred.copy()
    carry_with_hand(state, t, carried, p)
    a, b = state.offsets[t], state.offsets[t + 1]
    if b == a:
        return
    m = state.known.size
    free = np.empty(b - a, np.bool_)
    for i in range(b - a):
        free[i] = not state.body[a + i]
    for j in range(m):
        if state.known[j]:
            free[state.taken[j] - a] = False
    near = (0.5 * p.gamma) ** 2
    for row in range(2):
        e = 0 if row == 0 else m - 1
        if state.known[e]:
            continue
        best = _INF
        at = -1
        for i in range(b - a):
            if free[i]:
                d = 0.0
                for c in range(3):
                    x = state.points[a + i, c] - carried[e, c]
                    d += x * x
                if d < best:
                    best = d
                    at = i
        if at < 0:
            continue
        if best <= near:
            for c in range(3):
                pred[e, c] = carried[e, c]
        elif _may_take(state, t, e, a + at, best, p):
            for c in range(3):
                pred[e, c] = state.points[a + at, c]


@numba.njit(**JIT)
def _may_take(state, t, e, q, d2, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy._may_take`."""
    reach = (p.wide_gate * p.gamma) ** 2
    last = t - 1
    if d2 > reach or state.temp_count[e] != 0 or state.invented[last, e]:
        return False
    dv = 0.0
    for c in range(3):
        x = state.points[q, c] - (state.positions[last, e, c] + state.velocity[e, c])
        dv += x * x
    if dv > reach:
        return False
    if not _carry_keeps_rope(state, last, t, e, state.points[q], p):
        return False
    a0, a1 = state.offsets[last], state.offsets[t]
    untaken = np.ones(a1 - a0, np.bool_)
    for j in range(state.known.size):
        i = state.point_index[last, j]
        if a0 <= i < a1:
            untaken[i - a0] = False
    own = 0.0
    for c in range(3):
        x = state.points[q, c] - state.positions[last, e, c]
        own += x * x
    for i in range(a1 - a0):
        if untaken[i]:
            d = 0.0
            for c in range(3):
                x = state.points[a0 + i, c] - state.points[q, c]
                d += x * x
            if d <= own:
                return False
    return not rigid_with_body(state, t, -1, q, p)


@numba.njit(inline="always", **JIT)
def place_with_hand(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.place_with_hand`."""
    if _carries(state):
        carry_with_hand(state, t, state.cur, p)


@numba.njit(inline="always", **JIT)
def zip_with_hand(state, t, rows, pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._hand_numpy.zip_with_hand` (the check inlined
    into the caller, as :func:`search_with_hand`'s)."""
    tight = np.zeros(state.known.size, np.bool_)
    if rows.size > 0 and _carries(state):
        _zip_with_hand(state, t, rows, pred, tight, p)
    return tight


@numba.njit(**JIT)
def _zip_with_hand(state, t, rows, pred, tight, p):  # pragma: no cover - runs compiled
    """:func:`zip_with_hand` once an end hidden so far has anchors."""
    m = state.known.size
    carried = np.full((m, 3), np.nan)
    carry_with_hand(state, t, carried, p)
    for r in range(rows.size):
        e = rows[r]
        if (e == 0 or e == m - 1) and state.temp_count[e] > 0 and not np.isnan(carried[e, 0]):
            for c in range(3):
                pred[e, c] = carried[e, c]
            tight[e] = True


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
