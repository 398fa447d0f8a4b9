"""The command line as a user runs it: info, convert, demo, and bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app

DATA = Path(__file__).parents[1] / "data"
DATA_FILES = sorted(
    p for p in DATA.iterdir() if p.suffix in {".c3d", ".csv", ".bvh", ".obj", ".mhskel", ".mhw"}
)


def run(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


def info_json(path: Path) -> dict:
    result = run("info", path, "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


@pytest.mark.parametrize("path", DATA_FILES, ids=lambda p: p.name)
def test_info_json_succeeds_on_every_real_file(path):
    summary = info_json(path)
    assert summary["kind"] in {"markers", "points", "motion", "mesh", "rig", "weights"}
    if summary["kind"] == "markers":
        for key in (
            "frames",
            "rate",
            "markers",
            "labelled",
            "unlabelled",
            "missing_fraction",
            "gaps",
            "longest_gap",
        ):
            assert key in summary
    elif summary["kind"] == "motion":
        assert summary["joints"] > 0 and summary["frames"] > 0 and summary["rate"] > 0
    elif summary["kind"] == "mesh":
        assert summary["vertices"] > 0 and summary["faces"] > 0


_MODEL_GROUPS = ("ANGLES", "FORCES", "POWERS", "MOMENTS", "SCALARS", "REACTIONS")


@pytest.mark.parametrize("path", sorted(DATA.glob("*.c3d")), ids=lambda p: p.name)
def test_info_counts_match_ezc3d(path):
    summary = info_json(path)
    raw = ezc3d.c3d(str(path))
    header = raw["header"]["points"]
    assert summary["frames"] == header["last_frame"] - header["first_frame"] + 1
    assert summary["rate"] == pytest.approx(header["frame_rate"], rel=1e-12)
    params = raw["parameters"]["POINT"]
    used = int(params["USED"]["value"][0])
    labels = []
    for key in ["LABELS"] + [f"LABELS{i}" for i in range(2, 10)]:
        if key in params:
            labels += [s.strip() for s in params[key]["value"]]
    labels = labels[:used]
    model = {s.strip() for g in _MODEL_GROUPS if g in params for s in params[g]["value"]}
    # Plug-in Gait segment axes: four virtual points <segment>O/A/L/P (origin,
    # anterior, lateral, proximal) listed in no parameter; they are model output.
    names = set(labels)
    model |= {
        s
        for s in labels
        if len(s) > 1 and s[-1] in "OALP" and all(s[:-1] + c in names for c in "OALP")
    }
    marker_cols = [i for i, s in enumerate(labels) if s not in model]
    assert summary["markers"] == len(marker_cols)
    assert summary["unlabelled"] == sum(labels[i].startswith("*") for i in marker_cols)
    points = raw["data"]["points"][:3, marker_cols]  # (3, N, T)
    residuals = raw["data"]["meta_points"]["residuals"][0, marker_cols]
    missing = (residuals < 0) | np.isnan(points).any(axis=0) | (points == 0).all(axis=0)
    assert summary["missing_fraction"] == pytest.approx(missing.mean(), abs=1e-12)


def test_info_bvh_reports_joints_frames_rate(data_dir):
    s = info_json(data_dir / "cmu_131_01_bvh11.bvh")
    assert (s["kind"], s["joints"], s["frames"]) == ("motion", 31, 994)
    assert s["rate"] == pytest.approx(120.0, rel=1e-4)


def test_info_human_readable(data_dir):
    result = run("info", data_dir / "cmu_85_02.c3d")
    assert result.exit_code == 0
    assert "frames" in result.stdout and "810" in result.stdout


@pytest.mark.parametrize("ext", [".trc", ".csv", ".c3d"])
def test_convert_markers_round_trip(tmp_path, data_dir, ext):
    from skincap import io

    src = data_dir / "pyomeca_markers_analogs.c3d"
    dst = tmp_path / f"out{ext}"
    result = run("convert", src, dst)
    assert result.exit_code == 0, result.output
    a, b = io.read(src), io.read(dst)
    assert a.labels == b.labels
    assert a.rate == pytest.approx(b.rate, rel=1e-9)
    np.testing.assert_array_equal(np.isnan(a.positions), np.isnan(b.positions))
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-6, equal_nan=True)


def test_convert_refuses_to_overwrite_without_force(tmp_path, data_dir):
    dst = tmp_path / "out.trc"
    dst.write_text("keep me")
    result = run("convert", data_dir / "cmu_85_02.c3d", dst)
    assert result.exit_code == 2
    assert "--force" in result.stderr
    assert dst.read_text() == "keep me"
    assert run("convert", data_dir / "cmu_85_02.c3d", dst, "--force").exit_code == 0
    assert dst.read_text().startswith("PathFileType")


def test_convert_bvh_to_joint_positions_csv(tmp_path, data_dir):
    from skincap.geometry.kinematics import joint_positions
    from skincap.io.bvh import read_bvh

    src = data_dir / "cmu_131_01_bvh11.bvh"
    dst = tmp_path / "joints.csv"
    result = run("convert", src, dst, "--units", "cmu")
    assert result.exit_code == 0, result.output
    header = dst.read_text().splitlines()[0].split(",")
    table = np.loadtxt(dst, delimiter=",", skiprows=1)
    motion = read_bvh(src, units="cmu")
    assert table.shape == (994, 2 + 3 * motion.skeleton.n_joints)
    assert header[2:5] == [f"{motion.skeleton.names[0]}_{a}" for a in "xyz"]
    np.testing.assert_allclose(table[:, 2:].reshape(994, -1, 3), joint_positions(motion), atol=1e-6)


def test_convert_mesh_obj_to_ply(tmp_path, data_dir):
    dst = tmp_path / "body.ply"
    result = run("convert", data_dir / "makehuman_base.obj", dst)
    assert result.exit_code == 0, result.output
    # convert copies the whole OBJ file (MakeHuman's helper geometry included); info
    # and skin see the rigged body, without the helpers (test_info_sees_makehuman_rig)
    from skincap import io

    assert info_json(dst)["vertices"] == io.read(data_dir / "makehuman_base.obj").n_vertices


def test_convert_markers_to_points_and_back(tmp_path, data_dir):
    from skincap import io

    pts = tmp_path / "points.csv"
    assert run("convert", data_dir / "kt_optitrack_walking.c3d", pts, "--points").exit_code == 0
    assert info_json(pts)["kind"] == "points"
    back = tmp_path / "back.c3d"
    assert run("convert", pts, back).exit_code == 0
    a, b = io.read(data_dir / "kt_optitrack_walking.c3d"), io.read(back)
    present = ~a.missing.all(axis=0)
    np.testing.assert_allclose(a.positions[:, present], b.positions, atol=1e-6, equal_nan=True)


# ------------------------------------------------------------------ bad input
def _bad_files(tmp: Path, data: Path) -> dict[str, Path]:
    files: dict[str, Path] = {}

    def put(name: str, content: bytes) -> None:
        (tmp / name).write_bytes(content)
        files[name] = tmp / name

    c3d = (data / "cmu_85_02.c3d").read_bytes()
    bvh = (data / "bvhtoolbox_test_mocapbank.bvh").read_bytes()
    put("empty.c3d", b"")
    put("empty.bvh", b"")
    put("truncated.c3d", c3d[:2000])
    put("garbage.c3d", bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8)))
    broken = bytearray(c3d)
    broken[512:1024] = b"\xff" * 512  # the parameter section
    put("broken_params.c3d", bytes(broken))
    put("really_a_bvh.c3d", bvh)
    put("truncated.bvh", bvh[: len(bvh) // 2 - 7])
    lines = bvh.decode().splitlines()
    motion_at = next(i for i, s in enumerate(lines) if s.startswith("Frame Time")) + 1
    lines[motion_at + 3] = " ".join(lines[motion_at + 3].split()[:-2])
    put("short_row.bvh", "\n".join(lines).encode())
    put("garbage.bvh", b"HIERARCHY\nROOT Hips\n{\n OFFSET a b c\n")
    csv = (data / "pyomeca_vicon_nexus_trajectories.csv").read_text().splitlines()
    csv[10] = csv[10] + ",1,2,3,4"
    put("ragged.csv", "\n".join(csv).encode())
    put("garbage.csv", b"hello,world\n1,2\n")
    put("not_a_mesh.obj", b"v 1 2\nf 1 2 3\n")
    put("no_such_ext.xyz", b"123")
    return files


def test_every_bad_input_gives_one_line_and_status_2(tmp_path, data_dir):
    inputs = tmp_path / "in"
    inputs.mkdir()
    files = _bad_files(inputs, data_dir)
    for name, path in files.items():
        before = path.read_bytes()
        result = run("info", path)
        assert result.exit_code == 2, (name, result.output)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, (name, result.stderr)
        assert lines[0].startswith(f"skincap: error: {path}"), (name, lines[0])
        assert path.read_bytes() == before
        out_dir = tmp_path / f"out_{name}"
        out_dir.mkdir()
        target = out_dir / ("x.bvh" if path.suffix == ".bvh" else "x.trc")
        result = run("convert", path, target)
        assert result.exit_code == 2, (name, result.output)
        assert list(out_dir.iterdir()) == [], name  # no partial or temporary output


def test_missing_input_file(tmp_path):
    result = run("info", tmp_path / "nope.c3d")
    assert result.exit_code == 2
    assert "no such file" in result.stderr


def test_console_script_exit_status(tmp_path):
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x00" * 10)
    proc = subprocess.run(
        [sys.executable, "-m", "skincap", "info", str(bad)],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert "Traceback" not in proc.stderr


def test_demo_runs_the_chain_and_writes_the_report(tmp_path):
    import ezc3d

    from skincap import io
    from skincap.io.gltf.reader import read_gltf
    from skincap.io.pc2 import read_pc2

    folder = tmp_path / "demo"
    result = run("demo", "-o", folder, "--frames", "240")
    assert result.exit_code == 0, result.output
    assert "skincap view" in result.stdout and "report.html" in result.stdout
    page = (folder / "report.html").read_text(encoding="utf-8")
    for heading in ("Cleanup", "Hole filling", "Rope tracking", "Skinning", "Timings"):
        assert heading in page
    assert page.count("data:image/png;base64,") >= 12  # maps, plots and rendered frames
    results = json.loads((folder / "results.json").read_text())
    figures = results["figures"]
    assert figures["synthetic"]["frames"] == 240
    # CPU seconds of every step beside its wall-clock seconds, in the report too
    assert results["cpu_timings"].keys() == results["timings"].keys()
    assert 0 < figures["total_cpu_seconds"] and "CPU seconds" in page
    assert f"{figures['total_cpu_seconds']:.0f} s of CPU" in result.stdout
    # the gap-fill evaluation punches every length into shared rounds, and says so
    fill_json = json.loads((folder / "fill_evaluation.json").read_text())
    assert fill_json["lengths_together"] is True and "punched together" in page
    assert figures["cleanup"]["merged"] > 0 and figures["cleanup"]["wrong_rate"] < 0.1
    assert figures["tracking"]["f1"] > 0.7
    fill = figures["fill"]
    assert fill["local_pca"]["mean_normalised"] < fill["spline"]["mean_normalised"]
    # one number wherever it appears: the labelled-trajectory missing fraction in the
    # table is the one the figure draws (both from labelled_missing_maps), and the CLI
    # line says it too
    cl = figures["cleanup"]
    said = " ".join(result.stdout.split())
    before, after = cl["labelled_missing_before"] * 100, cl["labelled_missing_after"] * 100
    assert f"{before:.1f} % → {after:.1f} %" in page
    assert f"labelled trajectories {before:.1f} % -> {after:.1f} % missing" in said
    # the CLI's gap-fill verdict is the report's mark for that method's average
    verdict = figures["fill_verdict"]
    mark = "met" if verdict["meets_mean"] else "missed"
    mean_cell = f'<span class="{mark}">{verdict["mean_normalised"]:.4g}</span>'
    assert mean_cell in page
    assert ("meets the targets" if verdict["meets_targets"] else "misses the targets") in said
    assert "best gap fill" not in said
    # outputs other programs read: ezc3d re-reads our C3Ds
    for c3d in (folder / "cleaned.c3d", folder / "track" / "rope.c3d"):
        assert ezc3d.c3d(str(c3d))["data"]["points"].shape[2] == 240
    cleaned = io.read(folder / "cleaned.c3d")
    assert cleaned.invented is not None and cleaned.invented.any()
    assert read_gltf(folder / "walk.glb").skin.skeleton.n_joints == 163
    assert read_pc2(folder / "walk_dqs.pc2").frames.shape == (240, 13380, 3)
    assert io.read(folder / "formats" / "walking.c3d").n_markers == 12
    # real capture -> clean -> solve -> skin: the solved BVH plays on the body
    solve = figures["solve"]
    assert solve["joints"] > 15 and solve["rms_cm"] < 1.5 and solve["max_cm"] < 8.0
    solved = io.read(folder / "real" / "solved.bvh")
    assert solved.n_frames == solve["frames"] == 810
    assert np.isfinite(solved.rotations).all()
    assert read_gltf(folder / "real" / "solved_body.glb").skin.skeleton.n_joints == 163
    assert "A real capture: clean, solve the skeleton, skin" in page
    # the dense chain: the four variants and one global RBF against the true skin
    dense = {r["method"]: r for r in figures["dense"]["rows"]}
    assert set(dense) == {"rigid", "quadratic", "rigid_rbf", "quadratic_rbf", "global_rbf"}
    assert all(r["nan_fraction"] == 0 for r in dense.values())
    # parts learnt on a 240-frame range of motion, as the paper did; measured at 240
    # frames: rigid 5.5, quadratic 5.1, rigid_rbf 2.1, quadratic_rbf 2.3, global_rbf 2.3 mm
    assert figures["dense"]["rom_frames"] == 240 and "range-of-motion take" in page
    assert all(0 < dense[m]["rms_m"] < 0.005 for m in ("rigid_rbf", "quadratic_rbf", "global_rbf"))
    assert all(0 < dense[m]["rms_m"] < 0.010 for m in ("rigid", "quadratic"))
    # the paper's Fig. 7: the RBF of the residual takes most of the rigid error away
    assert dense["quadratic_rbf"]["rms_m"] < 0.6 * dense["rigid"]["rms_m"]
    # no RBF field throws a vertex: the per-part RBF variants' worst vertex stays within
    # the rigid variant's (measured 37 and 36 mm against 52; 354 and 323 mm unregularised)
    assert all(dense[m]["max_m"] < 0.06 for m in ("rigid_rbf", "quadratic_rbf"))
    assert "Dense skin" in page and (folder / "figures" / "dense_errors.png").is_file()
    assert run("demo", "-o", folder, "--frames", "240").exit_code == 2  # outputs exist


def _all_verbs():
    import typer

    def walk(command, prefix):
        if hasattr(command, "commands"):  # a group of sub-commands
            for name, sub in command.commands.items():
                yield from walk(sub, [*prefix, name])
        else:
            yield prefix

    return list(walk(typer.main.get_command(app), []))


def test_every_verb_has_help_with_an_example():
    verbs = _all_verbs()
    assert ["info"] in verbs and ["skin"] in verbs and ["bench", "io"] in verbs
    for verb in verbs:
        result = run(*verb, "--help")
        assert result.exit_code == 0, verb
        assert "Example: skincap" in result.stdout, verb


def test_help_paragraphs_wrap_at_the_terminal_width_not_the_source_width():
    """A docstring wrapped at 88 columns broke into orphan words on an 80-column terminal
    (typer keeps single line breaks); the help is now reflowed paragraph by paragraph."""
    import inspect

    from skincap.cli._app import _reflowed

    doc = """First line.

    A paragraph wrapped
    in the source.

    - a list item
    - another

    Example: skincap x"""
    assert _reflowed(doc).split("\n\n") == [
        "First line.",
        "A paragraph wrapped in the source.",
        "- a list item\n- another",
        "Example: skincap x",
    ]
    for verb in _all_verbs():
        result = CliRunner().invoke(app, [*verb, "--help"], env={"COLUMNS": "80"})
        text = result.stdout.split("╭")[0]  # the prose above the option panels
        lines = [line.strip() for line in text.splitlines()]
        for line, after in zip(lines, lines[1:], strict=False):
            # an orphan: a lone word inside a paragraph, the sentence going on below it
            lone = len(line.split()) == 1 and not line.startswith(("-", "*", "|"))
            assert not (lone and after[:1].islower() or lone and after[:1] == "("), (
                verb,
                line,
                after,
            )
    assert inspect.cleandoc(_reflowed("a\nb")) == "a b"
