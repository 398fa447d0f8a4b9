"""The one-to-one assignment and small helpers of the compiled tracker (numba).

The numba twin of :func:`skincap.tracking.init.gated_assignment` (the nearest-point
queries are in :mod:`skincap.tracking._numba_grid`), whose conflicts are resolved by the
same shortest-augmenting-path assignment as :func:`scipy.optimize.linear_sum_assignment`
(Crouse 2016, ported with its tie-breaking), so both backends take the same points.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package

__all__ = ["JIT", "gated_assignment", "is_taken", "linear_sum_assignment", "norm3"]

_INF = np.inf

#: Options of every compiled function of the tracker (cached on disk).
JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


@numba.njit(**JIT)
def _augmenting_path(nc, cost, u, v, path, row4col, spc, i, sr, sc, remaining):  # pragma: no cover
    min_val = 0.0
    num_remaining = nc
    for it in range(nc):
        remaining[it] = nc - it - 1
    sr[:] = False
    sc[:] = False
    spc[:] = _INF
    sink = -1
    while sink == -1:
        index = -1
        lowest = _INF
        sr[i] = True
        for it in range(num_remaining):
            j = remaining[it]
            r = min_val + cost[i, j] - u[i] - v[j]
            if r < spc[j]:
                path[j] = i
                spc[j] = r
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest = spc[j]
                index = it
        min_val = lowest
        if min_val == _INF:
            return -1, min_val
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
        sc[j] = True
        num_remaining -= 1
        remaining[index] = remaining[num_remaining]
    return sink, min_val


@numba.njit(**JIT)
def linear_sum_assignment(cost_in):  # pragma: no cover - runs compiled
    """(rows, cols) of the minimum-cost assignment, as scipy's linear_sum_assignment."""
    nr0, nc0 = cost_in.shape
    transpose = nc0 < nr0
    cost = cost_in.T.copy() if transpose else cost_in
    nr, nc = cost.shape
    u = np.zeros(nr)
    v = np.zeros(nc)
    spc = np.full(nc, _INF)
    path = np.full(nc, -1, np.int64)
    col4row = np.full(nr, -1, np.int64)
    row4col = np.full(nc, -1, np.int64)
    sr = np.zeros(nr, np.bool_)
    sc = np.zeros(nc, np.bool_)
    remaining = np.zeros(nc, np.int64)
    for cur_row in range(nr):
        sink, min_val = _augmenting_path(
            nc, cost, u, v, path, row4col, spc, cur_row, sr, sc, remaining
        )
        if sink < 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        u[cur_row] += min_val
        for i in range(nr):
            if sr[i] and i != cur_row:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if sc[j]:
                v[j] -= min_val - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            tmp = col4row[i]
            col4row[i] = j
            j = tmp
            if i == cur_row:
                break
    a = np.empty(nr, np.int64)
    b = np.empty(nr, np.int64)
    if transpose:
        order = np.argsort(col4row)
        for k in range(nr):
            a[k] = col4row[order[k]]
            b[k] = order[k]
    else:
        for k in range(nr):
            a[k] = k
            b[k] = col4row[k]
    return a, b


@numba.njit(**JIT)
def gated_assignment(dist, cand, gate):  # pragma: no cover - runs compiled
    """As :func:`skincap.tracking.init.gated_assignment`: (rows, points) one-to-one."""
    r_n, k_n = dist.shape
    rows_u = np.empty(r_n, np.int64)  # the rows with a candidate within the gate
    n_any = 0
    n_first = 0
    for r in range(r_n):
        for c in range(k_n):
            if dist[r, c] < gate:
                rows_u[n_any] = r
                n_any += 1
                break
        if dist[r, 0] < gate:
            n_first += 1
    if n_any == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # fast path: every row's nearest candidate is free of conflicts
    distinct = True
    for r in range(r_n):
        if not dist[r, 0] < gate:
            continue
        for r2 in range(r + 1, r_n):
            if dist[r2, 0] < gate and cand[r2, 0] == cand[r, 0]:
                distinct = False
    if distinct and n_first == n_any:
        pts = np.empty(n_first, np.int64)
        for n in range(n_first):
            pts[n] = cand[rows_u[n], 0]
        return rows_u[:n_first].copy(), pts
    # unique rows and unique points (sorted), as np.unique in the reference
    all_pts = np.empty(n_any * k_n, np.int64)
    n_p = 0
    for ri in range(n_any):
        for c in range(k_n):
            if dist[rows_u[ri], c] < gate:
                all_pts[n_p] = cand[rows_u[ri], c]
                n_p += 1
    pts_u = np.unique(all_pts[:n_p])
    big = 1e6 * max(gate, 1.0)
    cost = np.full((n_any, pts_u.size), big)
    for ri in range(n_any):
        r = rows_u[ri]
        for c in range(k_n):
            if dist[r, c] < gate:
                col = np.searchsorted(pts_u, cand[r, c])
                cost[ri, col] = dist[r, c]
    ri, ci = linear_sum_assignment(cost)
    keep = 0
    for k in range(ri.size):
        if cost[ri[k], ci[k]] < gate:
            keep += 1
    rows = np.empty(keep, np.int64)
    pts = np.empty(keep, np.int64)
    n = 0
    for k in range(ri.size):
        if cost[ri[k], ci[k]] < gate:
            rows[n] = rows_u[ri[k]]
            pts[n] = pts_u[ci[k]]
            n += 1
    return rows, pts


@numba.njit(**JIT)
def norm3(x, y, z):  # pragma: no cover - runs compiled
    return np.sqrt(x * x + y * y + z * z)


@numba.njit(**JIT)
def is_taken(p, known, taken):  # pragma: no cover - runs compiled
    for j in range(known.size):
        if known[j] and taken[j] == p:
            return True
    return False


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
