"""Points bucketed along one axis, for the compiled tracker's range searches (numba).

A frame holds a few hundred points and a step asks, for each of a few dozen rope
markers, which points lie within a gate of a few centimetres. Scanning every point
for every question was a third of the compiled tracker's time (``skincap bench
track``); bucketing the frame into cells one gate wide along the axis that spreads
it most evenly (fewest pairs of points sharing a cell), then scanning only the cells
a gate reaches, asks the same question of ~5 % of the points. The tracker buckets
each frame once (:func:`fill_grid` into buffers its state keeps) and every step of
that frame and of the next searches the same grid, as do the backward scans of the
rigidity refusal over the frames of their window.

A grid is the tuple ``(axis, lo, inv_width, starts, order)``: ``axis`` (0, 1, 2),
``lo`` the smallest coordinate along it (metres), ``inv_width`` one over the cell
width (1/metres; 0 for a single cell of infinite width), ``starts`` (C + 1,) int64 where cell c's rows are
``order[starts[c]:starts[c + 1]]``, and ``order`` (n,) int64 the rows of the
bucketed array (global row numbers ``a … b - 1``), cell by cell, ascending within a
cell. Every search here finds exactly what a scan of all the rows finds: the grid
only skips rows that cannot be within the bound.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._numba_search import JIT

__all__ = ["build_grid", "cell_span", "fill_grid", "grid_cells", "grid_nearest", "grid_rows"]

_INF = np.inf


@numba.njit(**JIT)
def build_grid(xyz, a, b, width):  # pragma: no cover - runs compiled
    """The grid of rows ``a … b - 1`` of ``xyz`` (P, 3) float64, cells ``width`` metres
    (wider where that would make more cells than rows). See the module docstring."""
    starts = np.empty(b - a + 2, np.int64)
    order = np.empty(b - a, np.int64)
    axis, lo, inv, n_cells = fill_grid(xyz, a, b, width, starts, order)
    return axis, lo, inv, starts[: n_cells + 1], order


@numba.njit(**JIT)
def fill_grid(xyz, a, b, width, starts, order):  # pragma: no cover - runs compiled
    """Bucket rows ``a … b - 1`` of ``xyz`` into ``starts`` (at least b - a + 2 slots)
    and ``order`` (b - a,) as :func:`build_grid` does, without allocating them;
    returns ``(axis, lo, inv_width, cells)``: the grid is ``(axis, lo, inv_width,
    starts[:cells + 1], order)``."""
    n = b - a
    best_axis = 0
    best_pairs = -1
    best_cells = np.int64(1)  # not a literal: _cell compiles once
    best_inv = 0.0
    best_lo = 0.0
    lows = np.full(3, _INF)
    highs = np.full(3, -_INF)
    for i in range(a, b):
        for ax in range(3):
            x = xyz[i, ax]
            if x < lows[ax]:
                lows[ax] = x
            if x > highs[ax]:
                highs[ax] = x
    counts = starts  # scratch while the axis is chosen: one count per cell
    for ax in range(3):
        lo = lows[ax]
        n_cells, inv = _cell_count(lo, highs[ax], width, n)
        counts[:n_cells] = 0
        for i in range(a, b):
            counts[_cell(xyz[i, ax], lo, inv, n_cells)] += 1
        pairs = 0
        for c in range(n_cells):
            pairs += counts[c] * counts[c]
        if best_pairs < 0 or pairs < best_pairs:
            best_axis, best_pairs, best_cells, best_inv, best_lo = ax, pairs, n_cells, inv, lo
    lo = best_lo if n else 0.0
    starts[: best_cells + 1] = 0
    for i in range(a, b):
        starts[_cell(xyz[i, best_axis], lo, best_inv, best_cells) + 1] += 1
    for c in range(best_cells):
        starts[c + 1] += starts[c]
    for i in range(a, b):  # ascending rows within each cell; starts[c] runs ahead meanwhile
        c = _cell(xyz[i, best_axis], lo, best_inv, best_cells)
        order[starts[c]] = i
        starts[c] += 1
    for c in range(best_cells, 0, -1):  # back to each cell's first slot
        starts[c] = starts[c - 1]
    starts[0] = 0
    return best_axis, lo, best_inv, best_cells


@numba.njit(**JIT)
def _cell_count(lo, hi, width, n):  # pragma: no cover - runs compiled
    """(cells, 1 / cell width): cells of ``width`` over [lo, hi], at most ``n`` (then
    wider); one cell, of infinite width (0), for no span, a NaN or an infinite one."""
    span = hi - lo
    if not (n > 0 and span > 0.0 and width > 0.0):
        return 1, 0.0
    cells = min(n, int(min(span / width, float(n))) + 1)
    return cells, 1.0 / max(width, span / cells)


@numba.njit(**JIT)
def _cell(x, lo, inv, n_cells):  # pragma: no cover - runs compiled
    """The cell holding coordinate x (clipped to the grid; NaN to cell 0)."""
    u = (x - lo) * inv
    if not u > 0.0:
        return 0
    if u >= n_cells - 1:
        return n_cells - 1
    return int(u)


@numba.njit(**JIT)
def grid_cells(grid, x, bound):  # pragma: no cover - runs compiled
    """(first, last) cells a search ``bound`` metres around coordinate ``x`` reaches
    along the grid's axis; first > last when none (or ``x`` is NaN)."""
    _, lo, inv, starts, _ = grid
    return cell_span(lo, inv, starts.size - 1, x, bound)


@numba.njit(**JIT)
def cell_span(lo, inv, n_cells, x, bound):  # pragma: no cover - runs compiled
    """:func:`grid_cells` of a grid given by its lowest coordinate ``lo`` (metres),
    ``inv`` (1 / cell width) and number of cells (for callers that keep a grid's
    numbers rather than the tuple)."""
    u0 = (x - bound - lo) * inv
    u1 = (x + bound - lo) * inv
    if inv == 0.0:  # every point is in cell 0 (_cell)
        return (0, 0) if x == x else (1, 0)
    if not (u1 >= 0.0 and u0 < n_cells):
        return 1, 0
    first = 0 if u0 <= 0.0 else int(u0)
    last = n_cells - 1 if u1 >= n_cells - 1 else int(u1)
    return first, last


@numba.njit(inline="always", **JIT)
def insert_nearest(d_kept, kept, n, k_max, d, q):  # pragma: no cover - runs compiled
    """Insert (d, q) among the first ``n`` entries of ``d_kept``/``kept``, kept ascending
    by (distance, index) and at most ``k_max`` long (the last one drops out when full;
    the caller has refused a (d, q) not below it). Returns the new count."""
    pos = n if n < k_max else k_max - 1
    while pos > 0 and (d_kept[pos - 1] > d or (d_kept[pos - 1] == d and kept[pos - 1] > q)):
        d_kept[pos] = d_kept[pos - 1]
        kept[pos] = kept[pos - 1]
        pos -= 1
    d_kept[pos] = d
    kept[pos] = q
    return n + 1 if n < k_max else n


@numba.njit(**JIT)
def grid_nearest(points, grid, b, q, kk, bound, d_out, i_out):  # pragma: no cover
    """The kk nearest of the grid's points (rows of ``points`` below ``b``) to q (3,)
    strictly within ``bound`` metres, ascending by (distance, index); inf and index
    ``b`` (cKDTree's "missing") beyond. The same answer as a scan of every point (the
    numba twin of a :class:`scipy.spatial.cKDTree` query)."""
    order = grid[4]
    bound2 = bound * bound
    for c in range(kk):
        d_out[c] = _INF
        i_out[c] = b
    n_found = 0
    k0, k1 = grid_rows(grid, q[grid[0]], bound)
    for k in range(k0, k1):
        p = order[k]
        dx = q[0] - points[p, 0]
        dy = q[1] - points[p, 1]
        dz = q[2] - points[p, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > bound2 * (1.0 + 1e-9):
            continue
        d = np.sqrt(d2)
        if not d < bound:
            continue
        if n_found == kk and (d > d_out[kk - 1] or (d == d_out[kk - 1] and p > i_out[kk - 1])):
            continue
        n_found = insert_nearest(d_out, i_out, n_found, kk, d, p)


@numba.njit(**JIT)
def grid_rows(grid, x, bound):  # pragma: no cover - runs compiled
    """``(k0, k1)``: ``grid[4][k0:k1]`` are the rows in the cells a search ``bound``
    metres around coordinate ``x`` reaches along the grid's axis (the cells are
    consecutive, so their rows are one run of ``order``); empty for none or NaN."""
    first, last = grid_cells(grid, x, bound)
    if first > last:
        return 0, 0
    return grid[3][first], grid[3][last + 1]


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
