from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap import io
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


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--vertices", "0"], "--vertices: expected 2000..200000 for the procedural body, got 0"),
        (["--vertices", "999999"], "--vertices: expected 2000..200000"),
        (["--noise-mm", "-1"], "--noise-mm: expected a finite number >= 0, got -1"),
        (["--noise-mm", "nan"], "--noise-mm: expected a finite number >= 0, got nan"),
        (["--soft-tissue", "-0.5"], "--soft-tissue: expected a finite number >= 0"),
        (["--swaps", "-2"], "--swaps: expected a finite number >= 0, got -2"),
        (["--seconds", "nan"], "--seconds: expected a positive number, got nan"),
        (["--rope", "lasso"], "--rope: expected none, jump or whip, got 'lasso'"),
        (["--real-markers", "{c3d}", "--rope", "whip", "--noise-mm", "-1"], "--noise-mm: expected"),
        (
            ["--real-markers", "{c3d}", "--rope", "none"],
            "--rope: --real-markers needs whip or jump",
        ),
    ],
)
def test_synth_bad_option_is_named_not_the_output(tmp_path, data_dir, extra, message):
    c3d = data_dir / "cmu_85_02.c3d"
    out = tmp_path / "take"
    result = run("synth", *[a.format(c3d=c3d) for a in extra], "-o", out)
    assert result.exit_code == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"skincap: error: {message}"), result.stderr
    assert not out.exists()


def test_synth_makehuman_body_ignores_vertices(tmp_path):
    # --vertices sizes the procedural body only: the shipped rig is taken as it is
    out = tmp_path / "take"
    result = run("synth", "--body", "makehuman", "--vertices", "0", "--motion", "tpose",
                 "--markers", "sparse", "--frames", "2", "-o", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads((out / "summary.json").read_text())["frames"] == 2


@pytest.mark.slow
def test_synth_corruption_is_recorded_and_clean_repairs_it(tmp_path):
    """--spikes/--swaps/--prop land in capture.c3d as corruption.json says, and clean
    flags every spiked sample, puts swapped samples back on their own label, keeps the prop."""
    out = tmp_path / "take"
    result = run(
        "synth", "--motion", "punch", "--markers", "sparse", "--frames", "240",
        "--vertices", "5000", "--spikes", "4", "--swaps", "2", "--prop", "-o", out,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    record = json.loads((out / "truth" / "corruption.json").read_text())
    assert len(record["swaps"]) == 2 and len(record["prop"]) == 4
    assert 4 <= len(record["spikes"]) <= 12
    capture, truth = io.read(out / "capture.c3d"), io.read(out / "truth" / "markers.c3d")
    column = {label: k for k, label in enumerate(capture.labels)}
    true_column = {label: k for k, label in enumerate(truth.labels)}
    for frame, label in record["spikes"]:
        if label in true_column:  # the prop has no truth column
            off = (
                capture.positions[frame, column[label]] - truth.positions[frame, true_column[label]]
            )
            assert np.linalg.norm(off) > 0.035

    cleaned_path = tmp_path / "clean.c3d"
    cleaned = run("clean", out / "capture.c3d", "-o", cleaned_path, "--json")
    assert cleaned.exit_code == 0, cleaned.output
    counts = json.loads(cleaned.stdout)
    assert counts["label_swaps_repaired"] >= 2
    assert counts["outliers_replaced"] >= len(record["spikes"])
    clean = io.read(cleaned_path)
    at = {label: k for k, label in enumerate(clean.labels)}
    assert all(label in at for label in record["prop"])
    for frame, label in record["spikes"]:
        assert clean.invented[frame, at[label]] or np.isnan(clean.positions[frame, at[label], 0])
    for swap in record["swaps"]:
        for label in swap["labels"]:
            got = clean.positions[swap["start"] : swap["end"], at[label]]
            want = truth.positions[swap["start"] : swap["end"], true_column[label]]
            err = np.linalg.norm(got - want, axis=-1)
            assert np.nanmax(err) < 0.01, (label, np.nanmax(err))


_CMU = Path(__file__).resolve().parents[1] / "data" / "cmu_85_02.c3d"


@pytest.mark.parametrize(
    "verb",
    [
        ["synth", "--motion", "tpose", "--frames", "2"],
        ["synth", "--real-markers", str(_CMU), "--rope", "whip"],
        ["eval", "animate", "--synth", "jumprope", "--frames", "4"],
        ["eval", "solve", "--synth", "squat", "--frames", "4"],
        ["eval", "track", "--synth", "jump"],
        ["eval", "fill", str(_CMU)],
    ],
)
def test_negative_seed_is_one_line_and_writes_nothing(tmp_path, verb):
    """NumPy's generators refuse a negative seed; every verb with --seed says so first."""
    out = tmp_path / "out"
    result = run(*verb, "--seed", "-1", "-o", out)
    assert result.exit_code == 2, result.output
    assert "--seed: expected a non-negative integer, got -1" in result.output
    assert "Traceback" not in result.output and not out.exists()


def test_bench_animate_refuses_negative_rom_frames():
    result = run("bench", "animate", "--rom-frames", "-1")
    assert result.exit_code == 2, result.output
    assert "--rom-frames: expected 0 (skip) or a frame count, got -1" in result.output


def test_out_of_memory_is_one_line(tmp_path, monkeypatch):
    """A request too large for the machine ends as one line and exit 2, not a traceback."""
    import skincap.workflows.synth_folder as synth_folder

    def too_big(*args, **kwargs):
        raise MemoryError("Unable to allocate 113. GiB for an array with shape (100000000, 38, 4)")

    monkeypatch.setattr(synth_folder, "synth_folder", too_big)
    out = tmp_path / "take"
    result = run("synth", "--motion", "tpose", "--frames", "100000000", "-o", out)
    assert result.exit_code == 2, result.output
    assert "skincap: error: not enough memory: Unable to allocate 113. GiB" in result.output
    assert "Traceback" not in result.output and not out.exists()


def test_a_bvh_motion_retarget_cannot_pair_is_blamed_by_name(tmp_path):
    """A BVH of one 1000-joint chain shares no joint name with the body: the one error
    line named no file (it came from the retarget); now it names the BVH."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "fuzz"))
    from cli_fuzz_cases import bvh_deep_chain

    src = tmp_path / "deep.bvh"
    src.write_bytes(bvh_deep_chain(1000))
    result = run("synth", "--motion", src, "--markers", "sparse", "--vertices", "5000",
                 "--frames", "1", "-o", tmp_path / "out")  # fmt: skip
    assert result.exit_code == 2, result.output
    lines = [s for s in result.stderr.splitlines() if s.strip()]
    assert all(s.startswith("skincap: warning: ") for s in lines[:-1])  # the guessed unit
    assert lines[-1].startswith(f"skincap: error: {src}: no joints to pair")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["deep.bvh"]


@pytest.mark.parametrize(
    "args, message",
    [
        # each asked NumPy for terabytes ("not enough memory") or ran for ever
        (
            ["skin", "--vertices", "100000000000000"],
            "n_vertices: expected an integer in 1..2000000",
        ),
        (["skin", "--frames", "100000000000"], "n_frames: expected an integer in 1..4096"),
        (
            ["animate", "--vertices", "100000000000"],
            "n_vertices: expected an integer in 1..2000000",
        ),
        (["animate", "--frames", "100000000000"], "n_frames: expected an integer in 1..4096"),
        (
            ["animate", "--rom-frames", "100000000000"],
            "rom_frames: expected an integer in 0..20000",
        ),
        # a repeat of 0 or -1 was taken silently (and still printed timings)
        (["io", "--repeat", "0"], "repeat: expected an integer in 1..1000, got 0"),
        (["io", "--repeat", "-1"], "repeat: expected an integer in 1..1000, got -1"),
    ],
)
def test_bench_sizes_beyond_any_scene_are_one_line(args, message):
    result = run("bench", *args)
    assert result.exit_code == 2, result.output
    (line,) = [s for s in result.stderr.splitlines() if s.strip()]
    assert line.startswith(f"skincap: error: {message}")
