"""The rope tracker's bridging of short hidden runs compiled with numba: the twin of
:mod:`skincap.tracking._bridge_numpy` (the reference), re-exported by
:mod:`skincap.tracking._steps_numba`.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._numba_search import JIT, norm3
from skincap.tracking._refusals_numba import path_back_to_trace, rigid_with_body, taken_in_frame

__all__ = ["bridge_hidden_runs"]

_INF = np.inf
_BRIDGE_RUN = 2  # skincap.tracking._bridge_numpy.BRIDGE_RUN


@numba.njit(**JIT)
def bridge_hidden_runs(state, t, pred, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._bridge_numpy.bridge_hidden_runs`."""
    a, b = state.offsets[t], state.offsets[t + 1]
    known, cur = state.known, state.cur
    m = known.size
    n_known = 0
    for j in range(m):
        if known[j]:
            n_known += 1
    if b == a or n_known < 2:
        return False
    free = ~state.body[a:b]
    for j in range(m):
        if known[j]:
            free[state.taken[j] - a] = False
    reach = p.adjacent_stretch * p.gamma
    found = False
    j0 = 1
    while j0 < m - 1:
        if known[j0] or not known[j0 - 1]:
            j0 += 1
            continue
        j1 = j0
        while j1 < m - 1 and not known[j1 + 1]:
            j1 += 1
        steady = False
        for j in range(j0, j1 + 1):
            if state.temp_count[j] < 1:
                steady = True
        if 2 <= j0 and j1 <= m - 3 and j1 - j0 + 1 <= _BRIDGE_RUN and not steady and free.any():
            seat = _best_chain(state, t, j0, j1, free, pred, reach, p.gamma, p)
            ok = seat[0] >= 0
            for r in range(j1 - j0 + 1):
                if ok and rigid_with_body(state, t, np.int64(-1), a + seat[r], p):
                    ok = False
            if ok:
                for r in range(j1 - j0 + 1):
                    j = j0 + r
                    known[j] = True
                    state.taken[j] = a + seat[r]
                    for k in range(3):
                        cur[j, k] = state.points[a + seat[r], k]
                    free[seat[r]] = False
                found = True
        j0 = j1 + 1
    return found


@numba.njit(**JIT)
def _best_chain(state, t, j0, j1, free, pred, reach, gamma, p):  # pragma: no cover
    """Twin of the reference's ``_allowed`` and ``_best_chain``: (2,) frame indices of
    the run's chain (the second -1 for a run of one), ``[-1, -1]`` for none."""
    a, b = state.offsets[t], state.offsets[t + 1]
    points, cur, rest = state.points, state.cur, state.link_rest
    lo, hi = j0 - 1, j1 + 1
    n = b - a
    d_lo = np.empty(n)
    d_hi = np.empty(n)
    for c in range(n):
        q = a + c
        d_lo[c] = norm3(
            points[q, 0] - cur[lo, 0], points[q, 1] - cur[lo, 1], points[q, 2] - cur[lo, 2]
        )
        d_hi[c] = norm3(
            points[q, 0] - cur[hi, 0], points[q, 1] - cur[hi, 1], points[q, 2] - cur[hi, 2]
        )
    # each trace's candidates: within the rope's length of both ends, and its cost
    # (distance to its prediction, shortness of its link to the measured end)
    runs = j1 - j0 + 1
    ok = np.zeros((runs, n), np.bool_)
    cost = np.full((runs, n), _INF)
    for r in range(runs):
        j = j0 + r
        to_lo = 0.0
        for k in range(lo, j):
            to_lo += rest[k]
        to_hi = 0.0
        for k in range(j, hi):
            to_hi += rest[k]
        for c in range(n):
            ok[r, c] = free[c] and d_lo[c] <= to_lo + reach and d_hi[c] <= to_hi + reach
            if ok[r, c] and _seen_beside_as_other(state, t, j, a + c, p):
                ok[r, c] = False
    seat = np.full(2, -1, np.int64)
    first, last = rest[lo] + reach, rest[j1] + reach
    for c in range(n):
        q = a + c
        e = norm3(
            points[q, 0] - pred[j0, 0], points[q, 1] - pred[j0, 1], points[q, 2] - pred[j0, 2]
        )
        if ok[0, c] and d_lo[c] <= first:
            cost[0, c] = e + max(rest[lo] - d_lo[c], 0.0)
        if runs == 2:
            e = norm3(
                points[q, 0] - pred[j1, 0], points[q, 1] - pred[j1, 1], points[q, 2] - pred[j1, 2]
            )
            if ok[1, c] and d_hi[c] <= last:
                cost[1, c] = e + max(rest[j1] - d_hi[c], 0.0)
    best, second = _INF, _INF
    if runs == 1:
        for c in range(n):
            if cost[0, c] < _INF:
                total = cost[0, c] + max(rest[j0] - d_hi[c], 0.0)
                if d_hi[c] > last:
                    continue
                if total < best:
                    second, best, seat[0] = best, total, c
                elif total < second:
                    second = total
    else:
        middle = rest[j0] + reach
        for u in range(n):
            if not cost[0, u] < _INF:
                continue
            for v in range(n):
                if u == v or not cost[1, v] < _INF:
                    continue
                qu, qv = a + u, a + v
                d_uv = norm3(
                    points[qu, 0] - points[qv, 0],
                    points[qu, 1] - points[qv, 1],
                    points[qu, 2] - points[qv, 2],
                )
                if d_uv > middle:
                    continue
                total = cost[0, u] + cost[1, v] + max(rest[j0] - d_uv, 0.0)
                if total < best:
                    second, best = best, total
                    seat[0], seat[1] = u, v
                elif total < second:
                    second = total
    if not best < _INF or second < best + gamma:
        seat[0] = -1
        seat[1] = -1
    return seat


@numba.njit(**JIT)
def _seen_beside_as_other(state, t, j, point, p):  # pragma: no cover - runs compiled
    """Twin of the reference's ``_seen_beside_as_other``."""
    reached, f, apart = path_back_to_trace(state, t, j, point, p)
    return reached >= 0 and apart > p.gamma and not taken_in_frame(state.point_index, f, reached)


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
