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
    assert res["ik_frames_per_second"]["passes"] == 2  # a default solve: one refit round
    assert res["ik_frames_per_second"]["backend"] in ("numba", "numpy")
    assert res["one_minute"]["frames"] == 360
    assert len(res["lines"]) == 4


def test_ik_speed_times_the_solves_own_passes_with_its_options(data_dir, monkeypatch):
    from types import SimpleNamespace

    import skincap.evaluate.solve as evaluate_solve
    from skincap.evaluate.solve import ik_frames_per_second
    from skincap.solve.calibrate import calibrate
    from skincap.solve.templates import load_template

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        take = read(data_dir / "cmu_85_02.c3d")
        short = MarkerSet(take.positions[:30], take.labels, take.rate)
        model = calibrate(short, load_template("cmu41"))
    # what solve_markers(short, loss="huber", loss_scale=0.03, refine_offsets=2,
    # joint_limits=True) returns, as far as the speed measure reads it
    ik = {"loss": "huber", "loss_scale_m": 0.03, "refine_offsets": 2, "joint_limits": True}
    result = SimpleNamespace(model=model, ik=ik)
    calls = []
    real = evaluate_solve.solve_poses

    def spy(*args, **kwargs):
        calls.append((args, kwargs))
        return real(*args, **kwargs)

    monkeypatch.setattr(evaluate_solve, "solve_poses", spy)
    speed = ik_frames_per_second(result, short, repeat=1)
    assert speed["passes"] == 3 and len(calls) == 3
    args, kwargs = calls[0]
    assert args[4].shape[0] == 30  # every frame
    assert kwargs["loss"] == "huber" and kwargs["loss_scale"] == 0.03
    assert kwargs["joint_limits"] is result.model.joint_limits
    assert args[5] is result.model.init_rotations  # the first pass starts where the solve's did
    assert calls[1][0][5] is not result.model.init_rotations  # the next from the last's poses
    assert speed["solve_cpu"] <= speed["cpu"]
