"""``skincap bench solve``'s measurements on a short real take (figures not asserted)."""

from __future__ import annotations

import warnings

from skincap.errors import SkincapWarning
from skincap.evaluate.bench.solve import one_minute, run_solve_benchmark
from skincap.io import read
from skincap.types import MarkerSet


def test_one_minute_plays_back_and_forth_without_a_jump(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        take = read(data_dir / "cmu_85_02.c3d")
    minute = one_minute(take, 10.0)
    assert minute.n_frames == 1200
    assert (minute.positions[809] == minute.positions[810]).all()  # the turn repeats a frame
    assert (minute.positions[810:1200] == take.positions[::-1][:390]).all()


def test_bench_reports_ratios(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        take = read(data_dir / "cmu_85_02.c3d")
        short = MarkerSet(take.positions[:240], take.labels, take.rate)
        res = run_solve_benchmark(
            short, template="cmu41", reference_frames=1, repeat=1, long_take_seconds=3.0
        )
    assert res["speedup_vs_per_frame"] > 1.0
    assert res["ik_frames_per_second"]["cpu"] > 0
    assert res["one_minute"]["frames"] == 360
    assert len(res["lines"]) == 3
