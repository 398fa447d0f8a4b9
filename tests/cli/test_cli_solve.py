"""``skincap solve`` as a user runs it: real captures in, BVH out, skinned by ``skincap skin``."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.io import read
from skincap.io.bvh import read_bvh

DATA = Path(__file__).parents[1] / "data"
BLENDER = shutil.which("blender")
SCRIPTS = Path(__file__).parents[1] / "io" / "blender_scripts"


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    folder = tmp_path_factory.mktemp("solve")
    bvh = folder / "walk.bvh"
    fitted = folder / "fitted.c3d"
    report = folder / "report.json"
    result = run(
        "solve", DATA / "cmu_85_02.c3d", "-o", bvh, "--markers-out", fitted, "--report", report
    )
    return result, bvh, fitted, report


def test_solve_writes_bvh_markers_and_report(solved):
    result, bvh, fitted, report = solved
    assert result.exit_code == 0, result.output
    line = result.stdout.strip()
    assert "810 frames, 25 joints, 41 markers (cmu41), RMS residual" in " ".join(line.split())
    motion = read_bvh(bvh, units="cm")
    assert motion.n_frames == 810 and motion.skeleton.names[0] == "Hips"
    assert 1.5 < motion.translations[0, 0, 1] / 0.55 < 2.0  # hips ~1 m up: centimetres read back
    markers = read(fitted)
    assert markers.n_markers == 41 and markers.n_frames == 810
    rep = json.loads(report.read_text())
    assert rep["overall"]["rms_m"] < 0.012
    assert set(rep["joint_centres"]["LeftHip"]) == {
        "segment", "method", "range_of_motion_deg", "fit_singular_values",
        "parent_markers_left_out",
    }  # fmt: skip
    assert rep["joint_centres"]["LeftShoulder"]["parent_markers_left_out"] == []  # a rigid thorax
    # a shoulder between two framed segments: its SCoRE system's conditioning
    sv = rep["joint_centres"]["LeftShoulder"]["fit_singular_values"]
    assert len(sv) == 6 and sv == sorted(sv, reverse=True) and 0 < sv[5] < sv[0] < 1.5
    assert len(rep["per_frame_rms_m"]) == 810 and len(rep["per_marker"]) == 41
    assert rep["bone_lengths_m"]["LeftKnee"] > 0.3


def test_units_option_scales_the_file(tmp_path, solved):
    _, bvh, _, _ = solved
    metres = tmp_path / "m.bvh"
    result = run("solve", DATA / "cmu_85_02.c3d", "-o", metres, "--units", "m")
    assert result.exit_code == 0, result.output
    a = read_bvh(bvh, units="cm").skeleton.offsets
    b = read_bvh(metres, units="m").skeleton.offsets
    np.testing.assert_allclose(a, b, atol=1e-6)


@pytest.mark.slow
def test_skin_plays_the_solved_bvh_with_no_options(tmp_path):
    from skincap.io.c3d import write_c3d
    from skincap.io.pc2 import read_pc2
    from skincap.types import MarkerSet

    full = read(DATA / "cmu_85_02.c3d")
    cut = tmp_path / "cut.c3d"
    write_c3d(MarkerSet(full.positions[:240], full.labels, full.rate), cut)
    bvh = tmp_path / "cut.bvh"
    assert run("solve", cut, "-o", bvh).exit_code == 0
    mh = tmp_path / "mh"
    mh.mkdir()
    for name in ("makehuman_base.obj", "makehuman_default.mhskel", "makehuman_default_weights.mhw"):
        shutil.copy(DATA / name, mh / name)
    out = tmp_path / "body.pc2"
    result = run("skin", mh / "makehuman_base.obj", bvh, "-o", out)
    assert result.exit_code == 0, result.output
    frames = read_pc2(out).frames  # (T, V, 3) metres
    assert frames.shape[0] == 240 and np.isfinite(frames).all()
    # the body goes where the solved skeleton goes: its centre follows the hips
    root = read_bvh(bvh, units="cm").translations[:, 0]
    body = frames.mean(axis=1)
    for axis in (0, 1, 2):
        if np.ptp(root[:, axis]) > 0.05:
            assert np.corrcoef(body[:, axis], root[:, axis])[0, 1] > 0.8  # limbs move too
    height = np.ptp(frames[0, :, 1])
    assert 1.2 < height < 2.0


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["--template", "pig"],
            "segment pelvis has none of its template markers (LASI, RASI, LPSI, RPSI)",
        ),
        (["--template", "nosuch"], "is neither a file nor one of"),
        # a missing template file is named, not the take (the line blamed cmu_85_02.c3d)
        (["--template", "missing/walk.json"], "missing/walk.json: template: no such file"),
        (["--smooth-hz", "70"], "--smooth-hz: expected between 0 and 60 Hz"),
        (["--loss", "l1"], "--loss: expected one of squared, huber, cauchy, got 'l1'"),
        (["--loss", "huber", "--loss-scale-cm", "0"], "--loss-scale-cm: expected a positive"),
        (["--refine-offsets", "-1"], "--refine-offsets: expected a count 0..20, got -1"),
        # each round a full IK: 1e9 rounds ran until killed
        (["--refine-offsets", "1000000000"], "--refine-offsets: expected a count 0..20"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, args, message):
    out = tmp_path / "x.bvh"
    result = run("solve", DATA / "cmu_85_02.c3d", "-o", out, "--report", tmp_path / "r.json", *args)
    assert result.exit_code == 2
    lines = [s for s in result.stderr.splitlines() if s.startswith("skincap: error:")]
    assert len(lines) == 1 and message in " ".join(result.stderr.split())
    assert list(tmp_path.iterdir()) == []


def test_the_ik_options_reach_the_report(tmp_path):
    report = tmp_path / "r.json"
    result = run(
        "solve", DATA / "cmu_85_02.c3d", "-o", tmp_path / "x.bvh", "--report", report,
        "--joint-limits", "--loss", "huber", "--loss-scale-cm", "3", "--refine-offsets", "0",
        "--keep-jumps",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    ik = json.loads(report.read_text())["ik"]
    assert ik == {
        "loss": "huber", "loss_scale_m": 0.03, "refine_offsets": 0, "joint_limits": True,
        "reject_jumps": False,
    }  # fmt: skip


def test_unlabelled_capture_is_refused(tmp_path):
    result = run("solve", DATA / "aml_S09_KneeltoRun02_unlabeled.c3d", "-o", tmp_path / "x.bvh")
    assert result.exit_code == 2
    assert "has no labelled markers" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_existing_output_needs_force(tmp_path):
    out = tmp_path / "x.bvh"
    out.write_text("keep")
    result = run("solve", DATA / "cmu_85_02.c3d", "-o", out)
    assert result.exit_code == 2 and out.read_text() == "keep"


@pytest.mark.slow
@pytest.mark.skipif(BLENDER is None, reason="Blender is not on PATH")
def test_blender_imports_the_solved_bvh(tmp_path, solved):
    """Blender's own BVH importer puts every bone head where skincap's FK does."""
    from skincap.geometry.kinematics import joint_positions

    _, bvh, _, _ = solved
    out = tmp_path / "bvh.npz"
    frames = [0, 400, 809]
    cmd = [BLENDER, "-b", "--factory-startup", "--python-exit-code", "1",
           "--python", str(SCRIPTS / "import_bvh.py"), "--", str(bvh), str(out), *map(str, frames)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    r = np.load(out)
    assert r["frame_range"].tolist() == [1.0, 810.0]
    file_units = read_bvh(bvh, units="m")  # Blender works in the file's numbers
    ref = joint_positions(file_units)[frames]
    names = list(file_units.skeleton.names)
    cols = [names.index(n) for n in r["names"]]
    assert len(cols) >= 19
    heads = r["heads"]
    got = np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1)
    np.testing.assert_allclose(got, ref[:, cols], atol=1e-3)


def test_markers_never_seen_and_bad_markers_out_write_nothing(tmp_path):
    from skincap.io.c3d import write_c3d
    from skincap.types import MarkerSet

    full = read(DATA / "cmu_85_02.c3d")
    pos = full.positions.copy()
    for label in ("Male:LHEE", "Male:LMT5", "Male:LTOE"):
        pos[:, full.labels.index(label)] = np.nan
    hidden = tmp_path / "hidden.c3d"
    write_c3d(MarkerSet(pos, full.labels, full.rate), hidden)
    out = tmp_path / "out"
    out.mkdir()
    result = run("solve", hidden, "-o", out / "x.bvh")
    assert result.exit_code == 2
    assert "segment foot_l has none of its template markers (LHEE, LMT5, LTOE)" in " ".join(
        result.stderr.split()
    )
    result = run(
        "solve", DATA / "cmu_85_02.c3d", "-o", out / "x.bvh", "--markers-out", out / "m.xyz"
    )
    assert result.exit_code == 2 and "--markers-out: expected .c3d, .trc, .csv" in result.stderr
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("far_m, reach", [(3e35, "±1e+09 m"), (2e4, "±10000 m")])
def test_a_sample_far_beyond_any_capture_is_refused_naming_it(tmp_path, far_m, reach):
    """One marker sample at 3e35 m (a corrupt float in a C3D) ended in a traceback from
    SciPy (a null rotation in the calibration's rigid fits): now one line names the file,
    the marker and the frame, and nothing is written; the input is left as it was.
    Beyond 1e9 m reading refuses the sample (io.read), for every verb."""
    from skincap.io import write
    from skincap.types import MarkerSet

    take = read(DATA / "cmu_85_02.c3d")
    pos = take.positions[:60].copy()
    pos[5, 1] = [far_m, -far_m, 0.5]
    src = tmp_path / "far.c3d"
    write(MarkerSet(positions=pos, labels=list(take.labels), rate=take.rate), src)
    before = src.read_bytes()
    result = run("solve", src, "-o", tmp_path / "x.bvh", "--report", tmp_path / "r.json")
    assert result.exit_code == 2, result.output
    (line,) = [s for s in result.stderr.splitlines() if s.strip()]
    assert line.startswith(f"skincap: error: {src}: marker {take.labels[1]!r} in frame 5 lies at")
    assert f"beyond the {reach}" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.c3d"]
    assert src.read_bytes() == before
