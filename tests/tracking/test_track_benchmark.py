"""Tests of the tracking benchmark's scene, baseline and result (no timing assertions)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.evaluate.bench.tracking import run_track_benchmark, track_greedy_nearest
from skincap.synth.scenes import jump_rope_scene


def test_scene_points_match_its_truth() -> None:
    cloud, rope, first = jump_rope_scene(frames=200, points_per_frame=150, rope_markers=10, seed=2)
    assert rope.shape == (200, 10, 3) and cloud.n_frames == 200
    assert cloud.rate == 120.0
    # About points_per_frame points per frame (dropouts and ghosts roughly cancel).
    assert 140 <= cloud.counts.mean() <= 155
    frame = cloud.frame_index
    is_rope = (cloud.ids >= 0) & (cloud.ids < 10)
    err = np.linalg.norm(cloud.points[is_rope] - rope[frame[is_rope], cloud.ids[is_rope]], axis=1)
    assert err.max() < 0.004  # 0.5 mm noise, 3-D: far below 4 mm
    # first lists the rope's points of frame 0 in rope order.
    assert np.array_equal(cloud.ids[cloud.offsets[0] : cloud.offsets[1]][first], np.arange(10))
    # The rope hangs still for 0.5 s, then turns; its length along the markers is kept.
    assert np.abs(rope[:60] - rope[:1]).max() == 0.0
    assert np.linalg.norm(rope[100] - rope[0], axis=1).max() > 0.1
    # No point is dropped in the hanging window.
    assert np.all(np.bincount(frame[is_rope], minlength=200)[:60] == 10)


def test_scene_is_seeded_and_validated() -> None:
    a = jump_rope_scene(frames=50, points_per_frame=60, rope_markers=6, seed=1)[0]
    b = jump_rope_scene(frames=50, points_per_frame=60, rope_markers=6, seed=1)[0]
    assert np.array_equal(a.points, b.points) and np.array_equal(a.offsets, b.offsets)
    with pytest.raises(ValidationError):
        jump_rope_scene(frames=10, points_per_frame=5, rope_markers=6)


def test_greedy_baseline_follows_a_slow_clean_rope() -> None:
    cloud, rope, first = jump_rope_scene(
        frames=240,
        points_per_frame=120,
        rope_markers=8,
        turns_per_second=0.3,
        dropout=0.0,
        ghosts_per_frame=0.0,
        seed=3,
    )
    pos, inv = track_greedy_nearest(cloud, first, gamma=0.03)
    assert pos.shape == (240, 8, 3) and not inv.any()
    assert np.linalg.norm(pos - rope, axis=2).max() < 0.004


def test_greedy_baseline_invents_through_a_dropout() -> None:
    cloud, rope, first = jump_rope_scene(
        frames=120, points_per_frame=40, rope_markers=5, dropout=0.0, ghosts_per_frame=0.0
    )
    # Remove rope marker 2 in frames 80..82: the baseline invents there.
    drop = (cloud.ids == 2) & (cloud.frame_index >= 80) & (cloud.frame_index < 83)
    keep = ~drop
    counts = np.bincount(cloud.frame_index[keep], minlength=120)
    held = type(cloud)(
        points=cloud.points[keep],
        offsets=np.concatenate([[0], np.cumsum(counts)]),
        rate=cloud.rate,
        ids=cloud.ids[keep],
    )
    _, inv = track_greedy_nearest(held, first)
    assert inv[80:83, 2].all()
    assert inv[:80].sum() == 0


def test_run_track_benchmark_small() -> None:
    res = run_track_benchmark(
        frames=240, points_per_frame=200, rope_markers=12, repeat=1, first_call=False
    )
    json.dumps({k: v for k, v in res.items()})
    for key in ("track_fps", "baseline_fps", "track_realtime", "baseline_realtime", "speedup"):
        assert res[key] > 0 and np.isfinite(res[key])
    assert res["track_realtime"] == pytest.approx(res["track_fps"] / 120.0)
    assert res["track_cpu_s"] > 0
    assert res["track_realtime_cpu"] == pytest.approx(2.0 / res["track_cpu_s"])  # 240 @ 120 Hz
    assert "per CPU second" in res["lines"][1]
    assert res["speedup"] == pytest.approx(res["baseline_s"] / res["track_s"])
    # The real tracker follows the analytic rope to within a few millimetres.
    assert res["track_error_m"] < 0.005
    assert len(res["lines"]) == 5 and "real time" in res["lines"][1]
    assert res["same_as_numpy"] and res["speedup_vs_numpy"] > 0
