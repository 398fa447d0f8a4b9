"""``skincap bench sweep``: the sweep deformer's ms/frame against our LBS and DQS, same run."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.errors import ValidationError
from skincap.evaluate.bench.sweep import run_sweep_benchmark


def test_sweep_benchmark_reports_ratios_of_one_run() -> None:
    r = run_sweep_benchmark(n_frames=3, repeat=1)
    assert r["vertices"] == 13380 and r["frames"] == 3
    assert "numpy" in r["ms_per_frame"]
    for backend, row in r["ms_per_frame"].items():
        assert set(row) == {"lbs", "dqs", "sweep", "sweep_no_volume"}
        assert all(v > 0 for v in row.values())
        ratio = r["ratios"][backend]
        assert ratio["sweep / lbs"] == pytest.approx(row["sweep"] / row["lbs"])
    assert any("72712 vertices" in line for line in r["lines"])
    with pytest.raises(ValidationError, match="subdivide"):
        run_sweep_benchmark(subdivide=3)


def test_bench_sweep_cli_refuses_bad_counts() -> None:
    result = CliRunner().invoke(app, ["bench", "sweep", "--frames", "0"])
    assert result.exit_code == 2
    assert "n_frames" in result.stderr
