"""The compiled tracker's bucketed search finds exactly what a scan of every point finds."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from skincap.tracking._numba_grid import build_grid, grid_cells, grid_nearest  # noqa: E402


def _scan(
    points: np.ndarray, a: int, b: int, q: np.ndarray, kk: int, bound: float
) -> tuple[np.ndarray, np.ndarray]:
    """The kk nearest of points[a:b] to q strictly within ``bound``, by every distance:
    ascending by (distance, index), inf and index b beyond (as cKDTree)."""
    dx, dy, dz = q[0] - points[a:b, 0], q[1] - points[a:b, 1], q[2] - points[a:b, 2]
    d = np.sqrt(dx * dx + dy * dy + dz * dz)
    rows = np.flatnonzero(d < bound)
    rows = rows[np.lexsort((rows, d[rows]))][:kk]
    d_out, i_out = np.full(kk, np.inf), np.full(kk, b, np.int64)
    d_out[: rows.size], i_out[: rows.size] = d[rows], rows + a
    return d_out, i_out


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
            d_scan, i_scan = _scan(points, a, b, q, kk, bound)
            d_grid, i_grid = np.empty(kk), np.empty(kk, np.int64)
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


def test_each_frame_is_bucketed_once_into_the_state_as_build_grid_buckets_it() -> None:
    from skincap.synth.scenes import jump_rope_scene
    from skincap.tracking._steps_numba import frame_grid
    from skincap.tracking.init import init_rope
    from skincap.tracking.settings import TrackSettings
    from skincap.tracking.state import start_tracking

    cloud, _, first = jump_rope_scene(frames=40, points_per_frame=60, rope_markers=6, seed=2)
    state, params = start_tracking(cloud, init_rope(cloud, markers=first), TrackSettings())
    assert (state.grid_info[:, 0] < 0).all()  # nothing bucketed before a frame is searched
    for t in (0, 17, 39):
        a, b = cloud.offsets[t], cloud.offsets[t + 1]
        want = build_grid(state.points, a, b, params.gamma)
        for _ in range(2):  # built on the first call, read back on the second
            got = frame_grid(state, t, params)
            assert got[:3] == want[:3]
            np.testing.assert_array_equal(got[3], want[3])
            np.testing.assert_array_equal(got[4], want[4])
    assert (state.grid_info[:, 0] >= 0).sum() == 3
