"""``skincap clean``: a synthetic take written to C3D, a real unlabelled file, user surfaces, errors."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.errors import SkincapWarning
from skincap.io import read, write


def run(*args: object):  # noqa: ANN201
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def synth_c3d(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """A 60-frame dense jump-rope capture written as C3D, with its fragment truth."""
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=5000)
    motion = build_motion(body, "jumprope", frames=60)
    take = generate_capture(body, motion, markers="dense", rope="jump", seed=1)
    path = tmp_path_factory.mktemp("clean") / "capture.c3d"
    write(take.capture, path)
    return path, take.fragment_truth


def _read(path: Path):  # noqa: ANN202
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        return read(path)


def test_clean_synthetic_capture(synth_c3d, tmp_path: Path) -> None:  # noqa: ANN001
    src, _ = synth_c3d
    out = tmp_path / "clean.c3d"
    rep = tmp_path / "clean.json"
    result = run("clean", src, "-o", out, "--method", "linear", "--report", rep)
    assert result.exit_code == 0, result.output
    assert "trajectories" in result.output
    report = json.loads(rep.read_text())
    before = _read(src)
    after = _read(out)
    merge = report["merge"]
    assert merge["trajectories_before"] == before.n_markers
    assert after.n_markers == merge["trajectories_after"] < before.n_markers
    labelled = [lab for lab in before.labels if not lab.startswith("*")]
    n_surface = report["surface"]["markers"]
    assert after.labels[: len(labelled)] == labelled
    # markers hidden in the reference frame follow the labelled ones, named U<n>
    assert n_surface == len(labelled) + report["hidden"]["new_markers"]
    assert all(lab.startswith("U") for lab in after.labels[len(labelled) : n_surface])
    # invented samples survive the C3D round trip and match the report's runs
    assert after.invented is not None
    assert int(after.invented.sum()) == report["fill"]["invented_samples"] > 0
    for label, spans in report["invented"].items():
        col = after.labels.index(label)
        for start, end in spans:
            assert after.invented[start:end, col].all()
    assert np.isfinite(after.positions[after.invented]).all()
    # existing outputs are refused without --force, replaced with it
    again = run("clean", src, "-o", out, "--method", "linear")
    assert again.exit_code == 2 and "exists" in again.output
    forced = run("clean", src, "-o", out, "--method", "linear", "--force", "--no-smooth")
    assert forced.exit_code == 0, forced.output


def test_clean_with_a_user_edge_list(synth_c3d, tmp_path: Path) -> None:  # noqa: ANN001
    src, _ = synth_c3d
    cap = _read(src)
    labels = [lab for lab in cap.labels if not lab.startswith("*")]
    ref = cap.positions[0, : len(labels)]
    dist = np.linalg.norm(ref[:, None] - ref[None], axis=2)
    np.fill_diagonal(dist, np.inf)
    near = np.argsort(dist, axis=1)[:, :5]
    lines = ["a,b"] + [f"{labels[i]},{labels[j]}" for i in range(len(labels)) for j in near[i]]
    edges = tmp_path / "edges.csv"
    edges.write_text("\n".join(lines) + "\n")
    rep = tmp_path / "r.json"
    result = run("clean", src, "-o", tmp_path / "o.c3d", "--surface", edges, "--report", rep)
    assert result.exit_code == 0, result.output
    report = json.loads(rep.read_text())
    assert report["surface"]["faces"] == 0 and report["surface"]["edges"] > len(labels)
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\nD000,NOPE\n")
    result = run("clean", src, "-o", tmp_path / "p.c3d", "--surface", bad)
    assert result.exit_code == 2 and "line 2" in result.output and "NOPE" in result.output


def test_clean_real_unlabelled_file(data_dir: Path, tmp_path: Path) -> None:
    src = tmp_path / "in.c3d"
    shutil.copy(data_dir / "aml_S09_KneeltoRun02_unlabeled.c3d", src)
    out = tmp_path / "out.c3d"
    rep = tmp_path / "out.json"
    result = run("clean", src, "-o", out, "--method", "rigid", "--report", rep)
    assert result.exit_code == 0, result.output
    report = json.loads(rep.read_text())
    merge = report["merge"]
    assert merge["merged"] > 0 and merge["fragments_after"] < merge["fragments_before"]
    after = _read(out)
    before = _read(src)
    assert after.n_frames == before.n_frames
    # every measured sample survives (merged or not), filled ones are flagged
    measured = np.isfinite(after.positions[..., 0]) & ~after.invented
    assert measured.sum() >= 0.99 * np.isfinite(before.positions[..., 0]).sum()


def test_clean_errors(synth_c3d, tmp_path: Path) -> None:  # noqa: ANN001
    src, _ = synth_c3d
    result = run("clean", src, "-o", tmp_path / "x.c3d", "--method", "magic")
    assert result.exit_code == 2 and "--method: expected one of" in result.output
    assert (
        "x.c3d" not in result.output and "got 'magic'" in result.output
    )  # the option, not the output
    for blend in ("5", "nan", "-0.1"):
        result = run("clean", src, "-o", tmp_path / "x.c3d", "--rigid-blend", blend)
        assert (
            result.exit_code == 2 and "--rigid-blend: expected a weight in [0, 1]" in result.output
        )
    # a billion smoothing iterations ran until killed; none is no smoothing (--no-smooth)
    for count in ("1000000000", "0"):
        result = run("clean", src, "-o", tmp_path / "x.c3d", "--iterations", count)
        assert result.exit_code == 2 and f"--iterations: expected 1..1000, got {count}" in (
            result.output
        )
    assert not (tmp_path / "x.c3d").exists()
    result = run("clean", src, "-o", tmp_path / "x.trc")
    assert result.exit_code == 2 and ".c3d" in result.output
    result = run("clean", src, "-o", tmp_path / "x.c3d", "--reference-frame", "100000")
    assert result.exit_code == 2 and "reference-frame" in result.output
    garbage = tmp_path / "g.c3d"
    garbage.write_bytes(b"\x00garbage" * 10)
    result = run("clean", garbage, "-o", tmp_path / "y.c3d")
    assert result.exit_code == 2 and "skincap: error:" in result.output
    assert not (tmp_path / "y.c3d").exists()
    result = run("clean", "--help")
    assert result.exit_code == 0 and "Example: skincap clean" in result.output


def test_clean_no_hidden_keeps_only_the_labelled_markers(synth_c3d, tmp_path: Path) -> None:  # noqa: ANN001
    src, _ = synth_c3d
    with_hidden = tmp_path / "with.json"
    without = tmp_path / "without.json"
    a = run("clean", src, "-o", tmp_path / "a.c3d", "--method", "linear", "--report", with_hidden)
    b = run(
        "clean",
        src,
        "-o",
        tmp_path / "b.c3d",
        "--method",
        "linear",
        "--no-hidden",
        "--report",
        without,
    )
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    ra, rb = json.loads(with_hidden.read_text()), json.loads(without.read_text())
    labelled = sum(not lab.startswith("*") for lab in _read(src).labels)
    assert rb["hidden"]["enabled"] is False and rb["surface"]["markers"] == labelled
    assert ra["surface"]["markers"] == labelled + ra["hidden"]["new_markers"]
    after = _read(tmp_path / "b.c3d")
    assert not any(lab.startswith("U") for lab in after.labels)


@pytest.mark.slow
def test_clean_json_summary_and_report_counts(data_dir: Path, tmp_path: Path) -> None:
    """--json prints the summary line's figures; --report has them per marker."""
    out = tmp_path / "kt.c3d"
    rep = tmp_path / "kt.json"
    src = data_dir / "kt_optitrack_walking.c3d"
    result = run("clean", src, "-o", out, "--report", rep, "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout[result.stdout.index("{") :])
    for key in ("filled_samples", "unfilled_samples", "outlier_samples", "outliers_replaced",
                "relabelled_fragments", "largest_move_mm"):  # fmt: skip
        assert key in summary
    assert summary["largest_move_mm"] <= 2.0
    report = json.loads(rep.read_text())
    per_marker = report["markers"]
    assert sum(m["filled"] for m in per_marker.values()) == summary["filled_samples"]
    assert sum(m["unfilled"] for m in per_marker.values()) == summary["unfilled_samples"]
    assert max(m["largest_move_mm"] or 0.0 for m in per_marker.values()) == pytest.approx(
        summary["largest_move_mm"]
    )
    # kt_optitrack_walking swaps Foot_Marker3 and Foot_Marker5 for one frame (1952)
    assert summary["label_swaps_repaired"] == 1
    assert per_marker["Foot_Marker3"]["relabelled"] == per_marker["Foot_Marker5"]["relabelled"] == 1
    line = run("clean", src, "-o", tmp_path / "kt2.c3d")
    assert line.exit_code == 0, line.output
    text = line.stdout.strip().splitlines()[-1]
    for words in ("samples filled", "left unfilled", "outliers replaced", "fragments relabelled",
                  "largest move of a kept measured sample"):  # fmt: skip
        assert words in text


def test_clean_two_markers_and_a_motive_csv_exit_cleanly(tmp_path: Path) -> None:
    """Issue 13 item 5: no traceback on a 2-marker capture or the OptiTrack sample text."""
    from skincap.io import write
    from skincap.types import MarkerSet

    rng = np.random.default_rng(0)
    pos = rng.normal(size=(50, 2, 3)) * 0.01 + np.array([[0.0, 1.0, 0.0], [0.1, 1.0, 0.0]])
    pos[10:15, 0] = np.nan
    two = tmp_path / "two.c3d"
    write(MarkerSet(positions=pos, labels=["A", "B"], rate=100.0), two)
    result = run("clean", two, "-o", tmp_path / "two_clean.c3d")
    assert result.exit_code == 0, result.output
    after = _read(tmp_path / "two_clean.c3d")
    np.testing.assert_allclose(
        after.positions, pos, atol=1e-6, equal_nan=True
    )  # nothing to fill from

    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "csvtests", Path(__file__).parents[1] / "io" / "test_csv.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    motive = tmp_path / "take.csv"
    motive.write_text(module._motive_text())
    result = run("clean", motive, "-o", tmp_path / "take.c3d")
    assert result.exit_code in (0, 2), result.output
    if result.exit_code == 2:
        assert (
            result.output.startswith("skincap: error:")
            and len(result.output.strip().splitlines()) == 1
        )
    else:
        assert _read(tmp_path / "take.c3d").n_frames == 4


def test_clean_refuses_a_capture_of_model_outputs_only(data_dir: Path, tmp_path: Path) -> None:
    """A Vicon analysis C3D holds angles, forces and analogs but no marker trajectory:
    clean died in measurement_noise with a reshape traceback; now one line, exit 2."""
    src = data_dir / "external" / "btk_vicon_analysis_model_outputs.c3d"
    out = tmp_path / "out.c3d"
    result = run("clean", src, "-o", out)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and src.name in lines[0], result.output
    assert "no marker trajectories" in lines[0] and "10 angles" in lines[0]
    assert not out.exists()
