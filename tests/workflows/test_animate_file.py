"""``skincap animate`` (API and CLI) on a small analytic dense take with exact ground truth.

The take: an "arm" of two tubes (upper arm and forearm, 5 cm radius, 30 cm each)
with 60 markers 8 mm off the skin; the forearm bends at the elbow while the whole arm
turns and moves. Away from the elbow every skin vertex moves rigidly with its tube,
so every variant must reproduce it there; the rig is built on the take itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from dense_arm import ELBOW, arm_take  # noqa: E402  (tests/workflows helper)
from typer.testing import CliRunner

from skincap.cli import app
from skincap.deform.dense.rig import DenseRig
from skincap.errors import SkincapWarning
from skincap.io.dense_rig import read_dense_rig
from skincap.io.mesh import write_obj
from skincap.io.pc2 import read_pc2
from skincap.types import MarkerSet, Mesh
from skincap.workflows.animate_file import animate_file, animate_markers


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> tuple[Path, Path, np.ndarray, np.ndarray]:
    return arm_take(tmp_path_factory.mktemp("arm"))


def run(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("method", ["rigid", "quadratic_rbf"])
def test_the_api_reproduces_rigidly_moving_skin_away_from_the_joint(arm, tmp_path, method):
    mesh_path, take_path, truth, x = arm
    out = tmp_path / "arm.pc2"
    summary = animate_file(
        mesh_path, take_path, out, n_parts=2, reference_frame=0, surface=take_path.with_name("arm_surface.ply"), method=method,
        save_rig=tmp_path / "rig.npz", report=tmp_path / "r.json",
    )  # fmt: skip
    assert summary["parts"]["count"] == 2
    got = np.asarray(read_pc2(out).frames)
    assert got.shape == truth.shape and np.isfinite(got).all()
    far = np.abs(x - ELBOW) > 0.12
    err = np.linalg.norm(got - truth, axis=-1)
    assert err[:, far].max() < 2e-4  # rigid tubes: every variant exact up to noise-free fits
    assert err.mean() < 5e-3  # and near the elbow the blend stays within millimetres
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["method"] == method and len(report["deformation_ms_per_frame"]["frames"]) == 24
    assert report["rig"]["marker_to_mesh_m"]["mean"] == pytest.approx(0.008, abs=0.002)
    assert (out.with_suffix(".obj")).exists()


def test_a_saved_rig_round_trips_and_animates_another_take(arm, tmp_path):
    mesh_path, take_path, truth, _ = arm
    rig = tmp_path / "subject.npz"
    animate_file(
        mesh_path,
        take_path,
        tmp_path / "a.pc2",
        n_parts=2,
        reference_frame=0,
        surface=take_path.with_name("arm_surface.ply"),
        save_rig=rig,
    )
    arrays, labels, settings = read_dense_rig(rig)
    subject = DenseRig.from_arrays(arrays, labels, settings)
    assert subject.n_parts == 2 and settings["reference_frame"] == 0
    first = np.asarray(read_pc2(tmp_path / "a.pc2").frames)
    # the rig alone (no mesh) gives the same frames, from the file and from the API
    animate_file(None, take_path, tmp_path / "b.pc2", rig=rig)
    np.testing.assert_allclose(np.asarray(read_pc2(tmp_path / "b.pc2").frames), first, atol=1e-6)
    from skincap import io

    take = io.read(take_path)
    api = animate_markers(subject, take.positions[:, subject.columns_of(take.labels)])
    np.testing.assert_allclose(api, first, atol=1e-6)  # pc2 stores float32


def test_cli_writes_usd_and_obj_folder_and_says_one_line(arm, tmp_path):
    pytest.importorskip("pxr")
    mesh_path, take_path, _, _ = arm
    res = run("animate", mesh_path, take_path, "-o", tmp_path / "a.usda", "--parts", "2", "--surface", take_path.with_name("arm_surface.ply"),
              "--reference-frame", "0", "--method", "rigid")  # fmt: skip
    assert res.exit_code == 0, res.output
    assert res.output.count("\n") == 1 and "2 parts" in res.output and "24 frames" in res.output
    assert (tmp_path / "a.usda").exists()


def test_cli_obj_sequence_from_a_saved_rig(arm, tmp_path):
    mesh_path, take_path, _, _ = arm
    rig = tmp_path / "r.npz"
    res = run("animate", mesh_path, take_path, "-o", tmp_path / "a.pc2", "--parts", "2", "--surface", take_path.with_name("arm_surface.ply"),
              "--reference-frame", "0", "--save-rig", rig)  # fmt: skip
    assert res.exit_code == 0, res.output
    res = run("animate", "--rig", rig, take_path, "-o", tmp_path / "seq", "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["frames"] == 24
    assert len(list((tmp_path / "seq").glob("*.obj"))) == 24


def test_a_take_with_gaps_is_filled_with_a_warning(arm, tmp_path):
    from skincap import io

    mesh_path, take_path, truth, x = arm
    take = io.read(take_path)
    pos = take.positions.copy()
    pos[5:9, 3] = np.nan
    gappy = tmp_path / "gappy.c3d"
    io.write(MarkerSet(positions=pos, labels=take.labels, rate=take.rate), gappy)
    with pytest.warns(SkincapWarning, match="gaps"):
        summary = animate_file(
            mesh_path,
            gappy,
            tmp_path / "g.pc2",
            n_parts=2,
            reference_frame=0,
            surface=take_path.with_name("arm_surface.ply"),
        )
    assert summary["filled_samples"] == 4
    got = np.asarray(read_pc2(tmp_path / "g.pc2").frames)
    assert np.isfinite(got).all()
    far = np.abs(x - ELBOW) > 0.12
    assert np.linalg.norm(got - truth, axis=-1)[:, far].max() < 2e-3


def _nothing_written(folder: Path, before: set[Path]) -> bool:
    return set(folder.iterdir()) == before


def test_bad_inputs_exit_2_with_one_line_and_write_nothing(arm, tmp_path):
    from skincap import io

    mesh_path, take_path, _, _ = arm
    take = io.read(take_path)
    few = tmp_path / "few.c3d"
    io.write(MarkerSet(positions=take.positions[:, :20], labels=take.labels[:20], rate=100.0), few)
    flat = tmp_path / "points.ply"
    flat.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")  # fmt: skip
    other = tmp_path / "other.c3d"
    relabelled = [f"X{i:02d}" for i in range(take.n_markers)]
    io.write(MarkerSet(positions=take.positions, labels=relabelled, rate=100.0), other)
    rig = tmp_path / "r.npz"
    assert run("animate", mesh_path, take_path, "-o", tmp_path / "ok.pc2", "--parts", "2", "--surface", take_path.with_name("arm_surface.ply"),
               "--reference-frame", "0", "--save-rig", rig).exit_code == 0  # fmt: skip
    cases = [
        (("animate", mesh_path, few, "-o", tmp_path / "o.pc2"), "few.c3d", "labelled markers"),
        (("animate", flat, take_path, "-o", tmp_path / "o.pc2"), "points.ply", "no faces"),
        (("animate", "--rig", rig, other, "-o", tmp_path / "o.pc2"), "r.npz", "another marker set"),
        (("animate", mesh_path, take_path, "--rom", other, "-o", tmp_path / "o.pc2"), "other.c3d", "lacks"),
        (("animate", mesh_path, take_path, "-o", tmp_path / "o.abc"), "o.abc", "cannot write"),
        # an option at fault is named with the inputs, not the output it would have gone to
        (("animate", mesh_path, take_path, "--method", "cubic", "-o", tmp_path / "o.pc2"), take_path.name, "--method: expected one of"),
        (("animate", mesh_path, take_path, "--parts", "0", "-o", tmp_path / "o.pc2"), take_path.name, "--parts: expected 1..200, got 0"),
        (("animate", mesh_path, take_path, "--parts", "201", "-o", tmp_path / "o.pc2"), take_path.name, "--parts: expected 1..200"),
        (("animate", mesh_path, take_path, "--marker-radius", "nan", "-o", tmp_path / "o.pc2"), take_path.name, "--marker-radius: expected 0-50 mm"),
    ]  # fmt: skip
    for args, name, what in cases:
        before = set(tmp_path.iterdir())
        res = run(*args)
        assert res.exit_code == 2, (args, res.output)
        lines = [s for s in res.output.splitlines() if s.startswith("skincap: error:")]
        assert len(lines) == 1 and name in lines[0] and what in lines[0], res.output
        assert "o.pc2" not in lines[0] or name == "o.pc2", res.output
        assert _nothing_written(tmp_path, before), args


def test_a_saved_rig_animates_a_take_that_lost_a_marker(arm, tmp_path):
    """A marker lost for a whole take (fallen off: absent, or a column never seen) made
    the subject's rig refuse the take as "built for another marker set". Now its parts
    move by their other markers, with a warning; a take that leaves a part fewer than
    three markers is refused, naming the take; one lacking most markers still is."""
    from skincap import io

    mesh_path, take_path, truth, _ = arm
    take = io.read(take_path)
    rig = tmp_path / "r.npz"
    assert run("animate", mesh_path, take_path, "-o", tmp_path / "full.pc2", "--parts", "2",
               "--surface", take_path.with_name("arm_surface.ply"), "--reference-frame", "0",
               "--save-rig", rig).exit_code == 0  # fmt: skip
    full = np.asarray(read_pc2(tmp_path / "full.pc2").frames)
    lost = tmp_path / "lost.c3d"  # M00, on the upper arm's end ring, absent
    io.write(take.select(list(range(1, take.n_markers))), lost)
    unseen = tmp_path / "unseen.c3d"  # M00 present but never seen
    gone = take.positions.copy()
    gone[:, 0] = np.nan
    io.write(MarkerSet(positions=gone, labels=take.labels, rate=100.0), unseen)
    for name, path in (("lost", lost), ("unseen", unseen)):
        res = run("animate", "--rig", rig, path, "-o", tmp_path / f"{name}.pc2")
        assert res.exit_code == 0, res.output
        assert f"{path.name}: lacks 1 of the rig's 60 markers (M00)" in res.output
        got = np.asarray(read_pc2(tmp_path / f"{name}.pc2").frames)
        assert np.isfinite(got).all()
        # the upper arm keeps 29 of its 30 markers: the skin moves as with all of them
        assert np.linalg.norm(got - full, axis=-1).max() < 2e-3
        assert np.linalg.norm(got - truth, axis=-1).mean() < 2e-3
    # the forearm (x > 0.3 at rest) keeps 2 of its 30 markers: refused
    forearm = np.flatnonzero(take.positions[0, :, 0] > 0.3)
    bare = tmp_path / "bare.c3d"
    io.write(take.select(np.setdiff1d(np.arange(take.n_markers), forearm[2:])), bare)
    before = set(tmp_path.iterdir())
    res = run("animate", "--rig", rig, bare, "-o", tmp_path / "o.pc2")
    lines = [s for s in res.output.splitlines() if s.startswith("skincap: error:")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert "bare.c3d: lacks 28 of the rig's 60 markers" in lines[0]
    assert "1 of its parts keep fewer than 3" in lines[0]
    assert _nothing_written(tmp_path, before)


def test_a_saved_rig_with_bad_weights_is_blamed_not_the_take(arm, tmp_path):
    """NaN, negative or all-zero weights in R.npz: the rig file is named (was the take)."""
    mesh_path, take_path, _, _ = arm
    rig = tmp_path / "r.npz"
    assert run("animate", mesh_path, take_path, "-o", tmp_path / "ok.pc2", "--parts", "2", "--surface", take_path.with_name("arm_surface.ply"),
               "--reference-frame", "0", "--save-rig", rig).exit_code == 0  # fmt: skip
    good = dict(np.load(rig))
    sidecar = rig.with_suffix(".json").read_text()
    nan_alpha = good["marker_weights"].copy()
    nan_alpha[0, 0] = np.nan
    for name, change, what in [
        ("nan.npz", {"marker_weights": nan_alpha}, "marker_weights must be finite"),
        ("neg.npz", {"vertex_weights": -good["vertex_weights"]}, "vertex_weights must be finite"),
        ("nobody.npz", {"vertex_weights": 0 * good["vertex_weights"]}, "vertex_weights: 496"),
    ]:
        bad = tmp_path / name
        np.savez(bad, **{**good, **change})
        bad.with_suffix(".json").write_text(sidecar)
        before = set(tmp_path.iterdir())
        res = run("animate", "--rig", bad, take_path, "-o", tmp_path / "o.pc2")
        assert res.exit_code == 2, res.output
        lines = [s for s in res.output.splitlines() if s.startswith("skincap: error:")]
        assert len(lines) == 1 and f"{bad}: {what}" in lines[0], res.output
        assert _nothing_written(tmp_path, before)


def test_an_existing_output_needs_force(arm, tmp_path):
    mesh_path, take_path, _, _ = arm
    out = tmp_path / "a.pc2"
    out.write_bytes(b"keep")
    with pytest.raises(Exception, match="exists"):
        animate_file(
            mesh_path,
            take_path,
            out,
            n_parts=2,
            reference_frame=0,
            surface=take_path.with_name("arm_surface.ply"),
        )
    assert out.read_bytes() == b"keep"


@pytest.mark.parametrize("shift_m", [0.09, 0.5])
def test_a_mesh_off_the_markers_is_warned_about_and_one_far_off_refused(arm, tmp_path, shift_m):
    """An unregistered mesh a few cm off: a warning. Half a metre off (a T-pose body
    under a real take that starts lying down, aml_PronetoRun01: 49.5 cm): the fields
    extrapolated out there exploded (a 5 m body at 1,430 m/s); now one line, exit 2."""
    from skincap import io
    from skincap.geometry.raycast import closest_points_on_mesh

    mesh_path, take_path, _, _ = arm
    mesh, take = io.read_mesh(mesh_path), io.read(take_path)
    vertices = mesh.vertices + [0.0, shift_m, 0.0]
    mean = closest_points_on_mesh(vertices, mesh.faces, take.positions[0])[0].mean()
    moved = tmp_path / "moved.obj"
    write_obj(Mesh(vertices=vertices, faces=mesh.faces), moved, units="m", up="y")
    args = ("animate", moved, take_path, "-o", tmp_path / "m.pc2", "--parts", "2",
            "--reference-frame", "0", "--surface", take_path.with_name("arm_surface.ply"))  # fmt: skip
    res = run(*args)
    if shift_m < 0.15:
        assert 0.05 < mean < 0.15, mean  # the warning's band
        assert res.exit_code == 0, res.output
        assert "reference pose?" in res.output and "reference frame 0" in res.output
        return
    assert mean > 0.15, mean
    lines = [s for s in res.output.splitlines() if s.startswith("skincap: error:")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert "moved.obj" in lines[0] and "--register" in lines[0], res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["moved.obj"]
    assert run(*args, "--register").exit_code == 0  # the way out it names works


def test_landmarks_without_register_and_a_one_frame_range_of_motion_are_refused(arm, tmp_path):
    """--landmarks were ignored unchecked without --register (an unknown label passed);
    a one-frame take or --rom segmented 'parts' out of no motion at all."""
    from skincap import io

    mesh_path, take_path, _, _ = arm
    take = io.read(take_path)
    one = tmp_path / "one.c3d"
    io.write(MarkerSet(positions=take.positions[:1], labels=take.labels, rate=100.0), one)
    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps({"NOPE": 3}))
    surface = ("--surface", take_path.with_name("arm_surface.ply"), "--parts", "2")
    cases = [
        (("animate", mesh_path, take_path, "--landmarks", marks, *surface), "marks.json", "add --register"),
        (("animate", mesh_path, one, *surface), "one.c3d", "1 frame; the near-rigid parts"),
        (("animate", mesh_path, take_path, "--rom", one, *surface), "one.c3d", "at least 2 frames"),
    ]  # fmt: skip
    for args, name, what in cases:
        before = set(tmp_path.iterdir())
        res = run(*args, "-o", tmp_path / "o.pc2")
        lines = [s for s in res.output.splitlines() if s.startswith("skincap: error:")]
        assert res.exit_code == 2 and len(lines) == 1, (args, res.output)
        assert name in lines[0] and what in lines[0], res.output
        assert _nothing_written(tmp_path, before), args
    # the range of motion is judged before the mesh: a one-frame take under a mesh far
    # off is refused for its frames (fixing the mesh first would not have helped)
    mesh = io.read_mesh(mesh_path)
    write_obj(Mesh(vertices=mesh.vertices + [0.0, 0.5, 0.0], faces=mesh.faces), tmp_path / "far.obj",
              units="m", up="y")  # fmt: skip
    res = run("animate", tmp_path / "far.obj", one, *surface, "-o", tmp_path / "o.pc2")
    assert res.exit_code == 2 and "one.c3d: 1 frame" in res.output, res.output
    (tmp_path / "far.obj").unlink()
    # a one-frame take animates with a rig learnt elsewhere
    rig = tmp_path / "r.npz"
    assert run("animate", mesh_path, take_path, *surface, "--reference-frame", "0",
               "--save-rig", rig, "-o", tmp_path / "a.pc2").exit_code == 0  # fmt: skip
    res = run("animate", "--rig", rig, one, "-o", tmp_path / "one.pc2")
    assert res.exit_code == 0, res.output
    assert np.isfinite(read_pc2(tmp_path / "one.pc2").frames).all()


def test_register_fits_a_displaced_mesh_with_landmarks_and_marker_radius(arm, tmp_path):
    from scipy.spatial import cKDTree

    from skincap import io

    mesh_path, take_path, truth, _ = arm
    mesh, take = io.read_mesh(mesh_path), io.read(take_path)
    near = cKDTree(mesh.vertices).query(take.positions[0])[1]
    marks = {
        lab: int(i) for k, (lab, i) in enumerate(zip(take.labels, near, strict=True)) if k % 3 == 0
    }
    (tmp_path / "marks.json").write_text(json.dumps(marks))
    centre = mesh.vertices.mean(axis=0)
    shifted = centre + (mesh.vertices - centre) * [1.0, 1.1, 1.1] + [0.0, 0.01, 0.0]
    moved = tmp_path / "moved.obj"  # too wide and off to one side
    write_obj(Mesh(vertices=shifted, faces=mesh.faces), moved, units="m", up="y")
    res = run("animate", moved, take_path, "--register", "--landmarks", tmp_path / "marks.json",
              "--marker-radius", "8", "--parts", "2", "--reference-frame", "0",
              "--surface", take_path.with_name("arm_surface.ply"),
              "-o", tmp_path / "r.pc2", "--report", tmp_path / "r.json")  # fmt: skip
    assert res.exit_code == 0, res.output
    reg = json.loads((tmp_path / "r.json").read_text())["rig"]["registration"]
    assert reg["landmarks"] == len(marks)
    # the markers ride 8 mm above the true skin: the fitted surface is there too
    assert reg["marker_distance_mean_m"] == pytest.approx(0.008, abs=0.0015)
    from skincap.geometry.raycast import closest_points_on_mesh

    got = np.asarray(read_pc2(tmp_path / "r.pc2").frames)
    for t in (0, 12, 23):  # a registered template's vertices slide: compare with the surface
        d, _, _ = closest_points_on_mesh(truth[t], mesh.faces, got[t])
        # the displaced template was ~10 mm off; the open tube ends, with no marker
        # beyond them, stay a few mm out
        assert d.mean() < 4e-3 and np.median(d) < 3.5e-3, t


def test_a_landmark_file_naming_an_unknown_marker_is_refused(arm, tmp_path):
    mesh_path, take_path, _, _ = arm
    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps({"NOPE": 3}))
    res = run("animate", mesh_path, take_path, "--register", "--landmarks", marks,
              "-o", tmp_path / "o.pc2")  # fmt: skip
    assert res.exit_code == 2 and "marks.json" in res.output and "NOPE" in res.output
    assert not (tmp_path / "o.pc2").exists()


def test_info_reads_the_pc2_animate_wrote(arm, tmp_path):
    """``skincap info OUT.pc2`` said "unknown file type '.pc2'" on animate's own output;
    it now gives the frames, the take's rate (noted in OUT.obj) and the fastest vertex."""
    mesh_path, take_path, _, _ = arm
    out = tmp_path / "a.pc2"
    assert run("animate", mesh_path, take_path, "-o", out, "--parts", "2", "--reference-frame", "0",
               "--surface", take_path.with_name("arm_surface.ply")).exit_code == 0  # fmt: skip
    res = run("info", out, "--json")
    assert res.exit_code == 0, res.output
    seen = json.loads(res.stdout)
    frames = np.asarray(read_pc2(out).frames)
    assert seen["kind"] == "point_cache" and seen["frames"] == frames.shape[0] == 24
    assert seen["points"] == frames.shape[1] and seen["rate"] == 100.0
    speed = np.linalg.norm(np.diff(frames, axis=0), axis=-1).max() * 100.0
    assert seen["max_point_speed"] == pytest.approx(speed) and seen["max_point_speed_unit"] == "m/s"
    assert seen["bounds_max"] == pytest.approx(frames.max(axis=(0, 1)).tolist())


def test_the_report_gives_the_fastest_vertex_and_a_mesh_outrunning_its_markers_is_warned(
    arm, tmp_path
):
    """The arm on its own skin moves no faster than its markers; a triangle 3 m beyond
    the forearm (as a registration folded onto a lying subject leaves legs far from
    their markers: aml_PronetoRun01, 316 m/s under 18.6 m/s markers) is swung by the
    forearm's fields many times faster: a warning names the output and the frame."""
    from skincap import io

    mesh_path, take_path, _, _ = arm
    mesh, take = io.read_mesh(mesh_path), io.read(take_path)
    common = (
        "--parts",
        "2",
        "--reference-frame",
        "0",
        "--surface",
        take_path.with_name("arm_surface.ply"),
    )
    res = run(
        "animate",
        mesh_path,
        take_path,
        "-o",
        tmp_path / "a.pc2",
        "--report",
        tmp_path / "a.json",
        *common,
    )
    assert res.exit_code == 0 and "mesh moves up to" not in res.output, res.output
    speed = json.loads((tmp_path / "a.json").read_text())["speed"]
    frames = np.asarray(read_pc2(tmp_path / "a.pc2").frames)
    steps = np.linalg.norm(np.diff(frames, axis=0), axis=-1).max(axis=1)  # (T-1,)
    assert speed["max_vertex_speed_m_s"] == pytest.approx(steps.max() * 100.0)
    assert speed["max_vertex_speed_frame"] == int(np.argmax(steps)) + 1
    measured = np.linalg.norm(np.diff(take.positions, axis=0), axis=-1).max() * 100.0
    assert speed["max_marker_speed_m_s"] == pytest.approx(measured)
    assert speed["max_vertex_speed_m_s"] < 1.5 * measured  # skin rides with its markers

    tip = mesh.vertices[np.argmax(mesh.vertices[:, 0])]
    far = tip + np.array([[3.0, 0.0, 0.0], [3.0, 0.05, 0.0], [3.0, 0.0, 0.05]])
    n = mesh.n_vertices
    flung = Mesh(
        vertices=np.vstack([mesh.vertices, far]), faces=np.vstack([mesh.faces, [[n, n + 1, n + 2]]])
    )
    write_obj(flung, tmp_path / "flung.obj", units="m", up="y")
    res = run(
        "animate",
        tmp_path / "flung.obj",
        take_path,
        "-o",
        tmp_path / "f.pc2",
        "--report",
        tmp_path / "f.json",
        *common,
    )
    assert res.exit_code == 0, res.output
    fast = json.loads((tmp_path / "f.json").read_text())["speed"]
    assert fast["max_vertex_speed_m_s"] > 4.0 * max(measured, 1.0), fast
    assert "f.pc2: the mesh moves up to" in res.output and "times the fastest marker" in res.output


def test_the_fastest_step_counts_the_step_across_streamed_blocks() -> None:
    """The deformer streams 32-frame blocks: a jump from a block's last frame to the
    next block's first is found, with the later frame's number; NaN vertices skipped."""
    from skincap._arrays import track_largest_step

    frames = np.zeros((70, 5, 3))
    frames[:, :, 0] = np.arange(70)[:, None] * 0.01  # 1 cm a frame
    frames[32:, 2, 1] += 0.2  # vertex 2 jumps 20 cm between frames 31 and 32
    frames[40:45, 4] = np.nan  # an unseen part
    fastest: list[tuple[float, int]] = []
    blocks = [frames[i : i + 32] for i in range(0, 70, 32)]
    out = list(track_largest_step(iter(blocks), fastest))
    assert all(a is b for a, b in zip(out, blocks, strict=True))
    assert fastest == [(pytest.approx(np.hypot(0.01, 0.2)), 32)]
    one: list[tuple[float, int]] = []
    list(track_largest_step(iter([frames[:1]]), one))
    assert one == []  # one frame: no step


def test_a_run_stopped_while_deforming_leaves_no_saved_rig(arm, tmp_path, monkeypatch):
    """--save-rig was written before the deformation: Ctrl-C (or a failed write) there
    left R.npz + R.json beside no animation. Now nothing is written."""
    import skincap.workflows.animate_file as workflow

    mesh_path, take_path, _, _ = arm

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(workflow, "_write_animation", interrupted)
    with pytest.raises(KeyboardInterrupt):
        animate_file(mesh_path, take_path, tmp_path / "a.pc2", n_parts=2, reference_frame=0,
                     surface=take_path.with_name("arm_surface.ply"), save_rig=tmp_path / "r.npz")  # fmt: skip
    assert list(tmp_path.iterdir()) == []


def test_view_plays_the_result_beside_the_markers(arm, tmp_path):
    from skincap.viz.scene import load_scene

    mesh_path, take_path, _, _ = arm
    out = tmp_path / "arm.pc2"
    animate_file(mesh_path, take_path, out, n_parts=2, reference_frame=0,
                 surface=take_path.with_name("arm_surface.ply"))  # fmt: skip
    scene = load_scene([take_path, out])
    kinds = sorted(type(layer).__name__ for layer in scene.layers)
    assert any("Marker" in k for k in kinds) and any("Mesh" in k for k in kinds)


def test_gaps_are_filled_only_where_the_fill_moves_like_the_take() -> None:
    """A take with gaps is filled before animating, through clean's continuity guard:
    unguarded, local PCA filled aml_PronetoRun01's last frames at up to 71 m/s (its
    measured markers never pass 19 m/s) and the body leapt with them."""
    from skincap.io import read
    from skincap.workflows.animate_file import _filled

    data = Path(__file__).resolve().parents[1] / "data" / "aml_PronetoRun01_labeled.c3d"
    with pytest.warns(Warning):
        take = read(data)
    measured = ~np.isnan(take.positions[..., 0])
    with pytest.warns(SkincapWarning, match="filled by local PCA"):
        filled, count = _filled(take, data)
    assert count > 1000  # most gaps are filled
    np.testing.assert_array_equal(filled[measured], take.positions[measured])
    speed = np.linalg.norm(np.diff(filled, axis=0), axis=-1) * take.rate
    measured_speed = np.linalg.norm(np.diff(take.positions, axis=0), axis=-1) * take.rate
    assert np.nanmax(speed) < 1.5 * np.nanmax(measured_speed)  # 24.8 vs 18.6 m/s
