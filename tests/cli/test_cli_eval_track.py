"""``skincap eval track`` and ``skincap bench track`` end to end on a short synthetic take."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from skincap.cli import app


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def take_dir(tmp_path_factory):
    """A 200-frame jump-rope take with sparse body markers, written by skincap synth."""
    folder = tmp_path_factory.mktemp("eval_track") / "take"
    result = run(
        "synth",
        "--motion",
        "jumprope",
        "--rope",
        "jump",
        "--markers",
        "sparse",
        "--frames",
        "200",
        "--vertices",
        "3000",
        "-o",
        folder,
    )
    assert result.exit_code == 0, result.output
    return folder


def test_eval_track_on_a_synth_folder(take_dir, tmp_path):
    out = tmp_path / "ev"
    result = run("eval", "track", take_dir, "--gaps", "10,20", "--starts", "2", "-o", out)
    assert result.exit_code == 0, result.output
    data = json.loads((out / "track_eval.json").read_text())
    assert data["source"] == str(take_dir) and data["frames"] == 200
    assert data["rope_markers"] >= 20
    assert [r["gap"] for r in data["gap_repair"]["single"]] == [10, 20]
    assert all(r["trials"] == 2 for r in data["gap_repair"]["adjacent"])
    assert set(data["targets"]) == {
        "f1",
        "single_gap_error_10_30_m",
        "single_no_loss_up_to_60",
        "adjacent_gap_error_30_m",
    }
    assert (out / "track_eval.png").read_bytes()[:4] == b"\x89PNG"
    assert "gap repair" in result.stdout and "F1" in result.stdout
    assert "thesis < 0.1" in result.stdout
    # An existing output is refused without --force, replaced with it.
    again = run("eval", "track", take_dir, "--gaps", "10", "--starts", "1", "-o", out)
    assert again.exit_code == 2 and "track_eval.json" in again.stderr
    forced = run(
        "eval", "track", take_dir, "--gaps", "10", "--starts", "1", "--json", "--force", "-o", out
    )
    assert forced.exit_code == 0, forced.output
    assert json.loads(forced.stdout)["settings"]["gaps"] == [10]
    assert forced.stdout == (out / "track_eval.json").read_text()  # what it wrote


def test_eval_track_rejects_a_broken_truth_file(take_dir, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(take_dir, broken)
    points = broken / "truth" / "points.csv"
    lines = points.read_text().splitlines(keepends=True)
    points.write_text("".join(lines[: len(lines) // 2]))  # truncated
    result = run("eval", "track", broken, "--gaps", "10", "--starts", "1", "-o", tmp_path / "o")
    assert result.exit_code == 2
    assert result.stderr.startswith("skincap: error:") and "points.csv" in result.stderr
    lines[5] = "4,x,rope_00\n"
    points.write_text("".join(lines))
    result = run("eval", "track", broken, "--gaps", "10", "--starts", "1", "-o", tmp_path / "o")
    assert result.exit_code == 2 and "line 6" in result.stderr
    (broken / "truth" / "markers.c3d").write_bytes(b"not a c3d file")
    result = run("eval", "track", broken, "--gaps", "10", "--starts", "1", "-o", tmp_path / "o")
    assert result.exit_code == 2 and "markers.c3d" in result.stderr
    assert not (tmp_path / "o" / "track_eval.json").exists()


@pytest.mark.parametrize(
    "args",
    [
        [],  # neither a folder nor --synth
        ["--synth", "lasso"],
        ["--synth", "jump", "--gaps", "10,x"],
        ["--synth", "jump", "--gaps", "0,10"],
        ["--synth", "jump", "--markers", "lots"],
        ["--synth", "jump", "--starts", "0"],
    ],
)
def test_eval_track_rejects_bad_options(args, tmp_path):
    result = run("eval", "track", *args, "-o", tmp_path / "o")
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("skincap: error:")


def test_eval_track_rejects_folder_and_synth_together(take_dir, tmp_path):
    result = run("eval", "track", take_dir, "--synth", "jump", "-o", tmp_path / "o")
    assert result.exit_code == 2 and "one of them" in result.stderr


def test_eval_track_synth_in_memory(tmp_path):
    out = tmp_path / "ev"
    result = run(
        "eval",
        "track",
        "--synth",
        "whip",
        "--frames",
        "150",
        "--markers",
        "sparse",
        "--vertices",
        "3000",
        "--gaps",
        "10",
        "--starts",
        "1",
        "--json",
        "-o",
        out,
    )
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["source"].startswith("synth whip") and data["frames"] == 150
    assert json.loads((out / "track_eval.json").read_text()) == data


def test_bench_track_small():
    result = run(
        "bench",
        "track",
        "--frames",
        "200",
        "--points",
        "120",
        "--rope-markers",
        "10",
        "--repeat",
        "1",
    )
    assert result.exit_code == 0, result.output
    assert "real time" in result.stdout and "naive" in result.stdout
    bad = run("bench", "track", "--points", "5", "--rope-markers", "10")
    assert bad.exit_code == 2 and bad.stderr.startswith("skincap: error:")
