"""``summarize_point_cache``: what ``skincap info OUT.pc2`` reports, on analytic caches."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.evaluate.summary import summarize_point_cache


def _sliding_square(n_frames: int) -> np.ndarray:
    """Four points of a 1 m square, sliding 1 cm a frame along x; point 3 jumps 5 cm
    between frames 70 and 71 (past the first 64-frame chunk of the speed)."""
    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    frames = square[None] + np.arange(n_frames)[:, None, None] * [0.01, 0.0, 0.0]
    frames[71:, 3] += [0.0, 0.0, 0.04]  # 1 cm x and 4 cm z: a 4.12 cm step
    return frames


def test_bounds_sizes_and_the_fastest_point_of_a_sliding_square() -> None:
    got = summarize_point_cache(_sliding_square(100), start_frame=5.0, frame_step=1.0, rate=100.0)
    assert got["kind"] == "point_cache" and got["frames"] == 100 and got["points"] == 4
    assert got["duration_s"] == pytest.approx(1.0) and got["start_frame"] == 5.0
    assert got["bounds_min"] == pytest.approx([0.0, 0.0, 0.0])
    assert got["bounds_max"] == pytest.approx([1.99, 1.0, 0.04])
    assert got["largest_frame_size_m"] == pytest.approx(1.0)
    # the jump, found in the second chunk: sqrt(0.01² + 0.04²) m in 1/100 s
    assert got["max_point_speed"] == pytest.approx(np.hypot(0.01, 0.04) * 100.0)
    assert got["max_point_speed_unit"] == "m/s"


def test_without_a_rate_the_speed_is_per_frame_and_a_step_slows_it() -> None:
    frames = _sliding_square(100)
    per_frame = summarize_point_cache(frames, start_frame=0.0, frame_step=1.0, rate=None)
    assert per_frame["rate"] is None and per_frame["duration_s"] is None
    assert per_frame["max_point_speed"] == pytest.approx(np.hypot(0.01, 0.04))
    assert per_frame["max_point_speed_unit"] == "m/frame"
    # every second frame sampled: the same step takes twice as long
    halved = summarize_point_cache(frames, start_frame=0.0, frame_step=2.0, rate=100.0)
    assert halved["max_point_speed"] == pytest.approx(np.hypot(0.01, 0.04) * 50.0)
    assert halved["duration_s"] == pytest.approx(2.0)


def test_one_frame_has_no_speed_and_an_empty_cache_no_bounds() -> None:
    one = summarize_point_cache(_sliding_square(1), start_frame=0.0, frame_step=1.0, rate=30.0)
    assert one["max_point_speed"] == 0.0 and one["largest_frame_size_m"] == pytest.approx(1.0)
    empty = summarize_point_cache(np.zeros((0, 4, 3)), start_frame=0.0, frame_step=1.0, rate=30.0)
    assert empty["frames"] == 0 and "bounds_min" not in empty
