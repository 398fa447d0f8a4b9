from __future__ import annotations

import json

from typer.testing import CliRunner

from skincap.cli import app


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_eval_fill_writes_json_png_and_table(data_dir, tmp_path):
    out = tmp_path / "ev"
    args = [
        "eval",
        "fill",
        data_dir / "kt_optitrack_walking.c3d",
        "--methods",
        "local_pca,linear,rigid",
        "--gap-lengths",
        "30,60",
        "--gaps",
        "2",
        "--seed",
        "3",
        "-o",
        out,
    ]
    result = run(*args)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "fill_eval.json").read_text())
    assert data["methods"] == ["local_pca", "linear", "rigid"] and data["gap_lengths"] == [30, 60]
    assert data["results"]["rigid"]["30"]["gaps"] == 2
    assert (out / "fill_eval.png").read_bytes()[:4] == b"\x89PNG"
    assert "best:" in result.output
    again = run(*args)
    assert again.exit_code == 2 and "exists" in again.output
    assert run(*args, "--force").exit_code == 0


def test_eval_fill_bad_options(data_dir, tmp_path):
    src = data_dir / "kt_optitrack_walking.c3d"
    r = run("eval", "fill", src, "--methods", "cubic", "-o", tmp_path / "a")
    assert r.exit_code == 2 and "cubic" in r.output
    r = run("eval", "fill", src, "--gap-lengths", "30,x", "-o", tmp_path / "b")
    assert r.exit_code == 2 and "gap-lengths" in r.output
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x00garbage")
    r = run("eval", "fill", bad, "-o", tmp_path / "c")
    assert r.exit_code == 2 and "skincap: error:" in r.output
    assert "Example: skincap eval fill" in run("eval", "fill", "--help").output
