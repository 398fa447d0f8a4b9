from __future__ import annotations

import json

from typer.testing import CliRunner

from skincap.cli import app


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_synth_cli_writes_capture_and_truth(tmp_path):
    out = tmp_path / "take"
    result = run(
        "synth",
        "--motion",
        "punch",
        "--markers",
        "sparse",
        "--frames",
        "60",
        "--vertices",
        "5000",
        "-o",
        out,
    )
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 60 and summary["markers"] == 41
    assert (out / "truth" / "fragments.csv").read_text().startswith("fragment,truth\n")
    again = run(
        "synth",
        "--motion",
        "punch",
        "--markers",
        "sparse",
        "--frames",
        "60",
        "--vertices",
        "5000",
        "-o",
        out,
    )
    assert again.exit_code == 2 and "--force" in again.stderr


def test_synth_cli_rejects_bad_options(tmp_path):
    for extra in (
        ["--frames", "0"],
        ["--markers", "lots"],
        ["--motion", "moonwalk"],
        ["--frames", "5", "--seconds", "1"],
    ):
        result = run("synth", *extra, "-o", tmp_path / "x")
        assert result.exit_code == 2, (extra, result.output)
        assert result.stderr.startswith("skincap: error:")
    assert not (tmp_path / "x").exists()
