"""The compiled tracker's bucketed search finds exactly what a scan of every point finds."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from skincap.tracking._numba_grid import build_grid, grid_cells, grid_nearest  # noqa: E402
from skincap.tracking._numba_search import query_nearest  # noqa: E402


def _frames(rng: np.random.Generator) -> list[np.ndarray]:
    body = rng.normal(0.0, 0.3, (300, 3)) + [0.0, 1.0, 0.0]
    spread = rng.uniform(-1.0, 1.0, (200, 3))
    ties = np.repeat(rng.uniform(-0.1, 0.1, (20, 3)), 3, axis=0)  # equal distances
    level = np.c_[rng.uniform(-1, 1, 50), np.zeros(50), rng.uniform(-1, 1, 50)]  # y all 0
    hostile = spread.copy()
    hostile[::17] = np.nan  # NaN points are never found
    hostile[5] = [1e6, 0.0, 0.0]  # a far ghost stretches the range
    return [body, spread, ties, level, hostile, spread[:1], spread[:0]]


@pytest.mark.parametrize("bound", [0.005, 0.05, 0.3, 5.0])
def test_grid_nearest_equals_a_scan_of_every_point(bound: float) -> None:
    rng = np.random.default_rng(3)
    for frame in _frames(rng):
        pad = rng.normal(size=(7, 3))  # the frame sits inside a larger array, as in a take
        points = np.ascontiguousarray(np.concatenate([pad, frame, pad]))
        a, b = 7, 7 + frame.shape[0]
        if b == a:
            continue
        grid = build_grid(points, a, b, 0.05)
        order, starts = grid[4], grid[3]
        assert sorted(order.tolist()) == list(range(a, b))  # every row once
        assert starts[0] == 0 and starts[-1] == b - a and np.all(np.diff(starts) >= 0)
        queries = np.concatenate([frame[:: max(1, frame.shape[0] // 25)], rng.normal(size=(10, 3))])
        queries = np.concatenate([queries, [[np.nan, 0.0, 0.0], [0.0, 1e9, 0.0]]])
        kk = min(4, b - a)
        for q in np.ascontiguousarray(queries):
            d_scan, i_scan = np.empty(kk), np.empty(kk, np.int64)
            d_grid, i_grid = np.empty(kk), np.empty(kk, np.int64)
            query_nearest(points, a, b, q, kk, bound, d_scan, i_scan)
            grid_nearest(points, grid, b, q, kk, bound, d_grid, i_grid)
            np.testing.assert_array_equal(d_grid, d_scan)
            np.testing.assert_array_equal(i_grid, i_scan)


def test_grid_cells_reach_every_point_within_the_bound() -> None:
    rng = np.random.default_rng(4)
    points = np.ascontiguousarray(rng.uniform(-1.0, 1.0, (400, 3)))
    grid = build_grid(points, 0, 400, 0.02)
    axis, starts, order = grid[0], grid[3], grid[4]
    cell_of = np.empty(400, np.int64)
    for c in range(starts.size - 1):
        cell_of[order[starts[c] : starts[c + 1]]] = c
    for x in rng.uniform(-1.2, 1.2, 50):
        first, last = grid_cells(grid, x, 0.03)
        near = np.abs(points[:, axis] - x) <= 0.03
        assert np.all((cell_of[near] >= first) & (cell_of[near] <= last))
    assert grid_cells(grid, np.nan, 0.03)[0] > grid_cells(grid, np.nan, 0.03)[1]


def test_the_axis_is_the_one_that_spreads_the_points_most_evenly() -> None:
    rng = np.random.default_rng(5)
    # wide in x but in two tight clumps; evenly spread in z
    x = np.where(rng.random(300) < 0.5, -1.0, 1.0) + rng.normal(0, 0.001, 300)
    points = np.ascontiguousarray(np.c_[x, np.zeros(300), rng.uniform(-0.5, 0.5, 300)])
    assert build_grid(points, 0, 300, 0.02)[0] == 2


def test_the_whole_frame_as_one_cell_scans_every_point() -> None:
    from skincap.tracking._numba_grid import whole_frame

    rng = np.random.default_rng(6)
    points = np.ascontiguousarray(rng.uniform(-1.0, 1.0, (120, 3)))
    grid = whole_frame(10, 110)
    for q in np.ascontiguousarray(rng.uniform(-1.0, 1.0, (20, 3))):
        d_scan, i_scan = np.empty(3), np.empty(3, np.int64)
        d_grid, i_grid = np.empty(3), np.empty(3, np.int64)
        query_nearest(points, 10, 110, q, 3, 0.4, d_scan, i_scan)
        grid_nearest(points, grid, 110, q, 3, 0.4, d_grid, i_grid)
        np.testing.assert_array_equal(d_grid, d_scan)
        np.testing.assert_array_equal(i_grid, i_scan)
