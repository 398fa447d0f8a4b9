"""The skinning benchmark runs, measures every available contender and checks agreement."""

from __future__ import annotations

import pytest

from skincap.deform.skeletal.deformers import numba_available
from skincap.errors import ValidationError
from skincap.evaluate.bench.skinning import run_skinning_benchmark


def test_small_benchmark_structure_and_agreement() -> None:
    r = run_skinning_benchmark(
        n_vertices=2000, n_influences=4, n_frames=4, repeat=1, n_joints=16, first_call=False
    )
    ms = r["ms_per_frame"]
    assert ms["lbs_numpy"] > 0 and ms["dqs_numpy"] > 0
    assert (ms["lbs_numba"] is not None) == numba_available()
    igl_present = ms["igl_lbs"] is not None
    if igl_present:
        assert r["max_abs_diff"]["lbs_numpy vs igl_lbs"] < 1e-12
        assert r["ratios"]["igl_lbs / lbs_numpy"] > 0
    if numba_available():
        assert r["max_abs_diff"]["dqs_numba vs dqs_numpy"] < 1e-12
        assert r["max_abs_diff"]["lbs_numba vs lbs_numpy"] < 1e-12
    if ms["usd_dqs"] is not None:
        assert r["max_abs_diff"]["dqs_numpy vs usd_dqs (float32)"] < 1e-5
    assert r["config"]["n_vertices"] == 2000
    assert any("ms/frame" in line for line in r["lines"])
    assert set(r["goals"]) == {"lbs_numba", "dqs_numba", "lbs_numpy", "dqs_numpy"}
    assert r["first_call"] == {"lbs": None, "dqs": None}
    assert r["config"]["default_backend"] == ("numba" if numba_available() else "numpy")


@pytest.mark.slow
def test_first_call_is_measured_in_fresh_processes() -> None:
    r = run_skinning_benchmark(n_vertices=500, n_influences=2, n_frames=2, repeat=1, n_joints=4)
    for method in ("lbs", "dqs"):
        times = r["first_call"][method]
        assert set(times) == {
            f"{label}_{what}" for label in ("cold", "warm") for what in ("s", "call_s", "cpu_s")
        }
        assert all(v > 0 for v in times.values())
        assert times["cold_call_s"] <= times["cold_s"]
    assert sum("first call" in line for line in r["lines"]) == 2


def test_first_call_helper_reports_a_child_error() -> None:
    from skincap.evaluate.bench.common import first_call_in_fresh_process

    with pytest.raises(RuntimeError, match="ZeroDivisionError"):
        first_call_in_fresh_process("import math", "", "1 / 0")


def test_benchmark_rejects_bad_sizes() -> None:
    with pytest.raises(ValidationError, match="n_vertices"):
        run_skinning_benchmark(n_vertices=0)
    with pytest.raises(ValidationError, match="n_influences"):
        run_skinning_benchmark(n_vertices=10, n_influences=8, n_joints=4)
