"""The whole synthetic capture: truth consistency, determinism, files that read back."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from skincap.deform.skeletal.deformers import skin_motion
from skincap.geometry.raycast import closest_points_on_mesh
from skincap.io.synth_truth import read_marker_parts
from skincap.synth.generate import generate_capture
from skincap.synth.inputs import build_body, build_motion
from skincap.synth.marker_parts import PART_NAMES
from skincap.workflows.synth_folder import OUTPUT_FILES, write_synth_outputs


@pytest.fixture(scope="module")
def body():
    return build_body("procedural", n_vertices=6000)


@pytest.fixture(scope="module")
def take(body):
    motion = build_motion(body, "jumprope", frames=150)
    return generate_capture(body, motion, markers="dense", rope="jump", seed=3)


def test_truth_markers_ride_on_the_skin(take):
    """Every true body marker is at most its radius (1.5 mm) + 1 mm from the posed skin.

    (Less than the radius happens legitimately in creases, where the other side of
    the fold is nearer than the marker's own attachment point.)"""
    n_body = take.summary["markers"]
    faces = take.skin.rest.faces
    for t in (0, 75, 149):
        distance, _, _ = closest_points_on_mesh(
            take.skin.frames[t], faces, take.truth.positions[t, :n_body]
        )
        assert distance.max() < 0.0015 + 1e-3
        assert np.median(distance) == pytest.approx(0.0015, abs=2e-4)


def test_fragments_and_points_map_back_to_truth(take):
    truth_labels = set(take.truth.labels)
    capture = take.capture
    assert set(take.fragment_truth) == set(capture.labels)
    assert set(take.fragment_truth.values()) <= truth_labels | {"ghost"}
    for label in capture.labels:
        if not label.startswith("*"):
            assert take.fragment_truth[label] == label  # first-frame labels are true
    # a point's truth is its fragment's truth except around label swaps
    frag_truth = np.array([take.fragment_truth[label] for label in capture.labels])
    agree = frag_truth[take.points.ids] == take.point_truth
    assert agree.mean() > 0.97
    # non-ghost points lie within a few noise sigmas of the true marker
    frame = take.points.frame_index
    real = take.point_truth != "ghost"
    index = {label: i for i, label in enumerate(take.truth.labels)}
    cols = np.array([index[s] for s in take.point_truth[real]])
    err = np.linalg.norm(take.points.points[real] - take.truth.positions[frame[real], cols], axis=1)
    assert np.median(err) < 0.002 and np.percentile(err, 99) < 0.005


def test_capture_is_broken_like_a_real_one(take):
    s = take.summary
    assert s["markers"] > 300 and s["rope_markers"] >= 18
    assert s["fragments"] > s["markers"]  # trajectories break
    assert 0.01 < s["missing_fraction"] < 0.3
    assert s["rope_max_length_error"] < 0.02


def test_same_seed_same_bytes(body, tmp_path):
    motion = build_motion(body, "flex", frames=40)
    digests = []
    for k in range(2):
        result = generate_capture(body, motion, markers="sparse", seed=11)
        folder = tmp_path / f"run{k}"
        write_synth_outputs(result, folder)
        digests.append(
            {
                name: hashlib.sha256((folder / name).read_bytes()).hexdigest()
                for name in OUTPUT_FILES
                if (folder / name).exists()
            }
        )
    assert digests[0] == digests[1]
    other = generate_capture(body, motion, markers="sparse", seed=12)
    assert not np.array_equal(
        np.nan_to_num(other.capture.positions[:5]), np.nan_to_num(result.capture.positions[:5])
    )


def test_skin_uses_the_numpy_reference_whatever_numba_has_compiled(body, monkeypatch):
    # the numba DQS kernel differs in the last bits (contracted multiply-adds) and
    # backend="auto" picks it only once compiled: synth pins NumPy so bytes never move
    import skincap.synth.generate as generate

    asked = []

    def recording_skin_motion(*args, **kwargs):
        asked.append(kwargs.get("backend", "auto"))
        return skin_motion(*args, **kwargs)

    monkeypatch.setattr(generate, "skin_motion", recording_skin_motion)
    motion = build_motion(body, "flex", frames=4)
    generate_capture(body, motion, markers="sparse", seed=1)
    assert asked == ["numpy"]


def test_outputs_read_back(take, tmp_path):
    from skincap import io
    from skincap.io.pc2 import read_pc2

    written = write_synth_outputs(take, tmp_path)
    assert {p.relative_to(tmp_path).as_posix() for p in written} == set(OUTPUT_FILES)
    capture = io.read(tmp_path / "capture.c3d")
    assert capture.labels == take.capture.labels
    np.testing.assert_allclose(capture.positions, take.capture.positions, atol=1e-5, equal_nan=True)
    raw = ezc3d.c3d(str(tmp_path / "capture.c3d"))
    assert raw["data"]["points"].shape[1:] == (take.capture.n_markers, take.capture.n_frames)
    points = io.read(tmp_path / "capture_points.csv")
    assert points.points.shape == take.points.points.shape
    rows = (tmp_path / "truth" / "points.csv").read_text().splitlines()
    assert len(rows) == 1 + points.points.shape[0]
    truth = io.read(tmp_path / "truth" / "markers.c3d")
    assert truth.labels[-1].startswith("rope_") and not truth.missing.any()
    surface = io.read(tmp_path / "truth" / "marker_surface.ply")
    assert surface.n_vertices == take.summary["markers"] and surface.n_faces > surface.n_vertices
    motion = io.read(tmp_path / "truth" / "motion.bvh", units="m")
    assert motion.n_frames == 150
    cache = read_pc2(tmp_path / "truth" / "mesh.pc2")
    np.testing.assert_allclose(cache.frames[100], take.skin.frames[100], atol=1e-5)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["fragments"] == take.capture.n_markers
    parts = read_marker_parts(tmp_path / "truth" / "marker_parts.csv")
    assert list(parts) == truth.labels[: take.summary["markers"]]  # body markers, no rope
    assert list(parts.values()) == take.marker_parts


def test_true_marker_parts_are_anatomical(take):
    """17 parts, each with markers, where the anatomy says they are (body faces +Z, left +X)."""
    parts = np.array(take.marker_parts)
    start = take.truth.positions[0, : parts.size]  # T-pose
    assert set(parts.tolist()) == set(PART_NAMES)
    assert min((parts == name).sum() for name in PART_NAMES) >= 2
    assert (start[parts == "thigh_l", 0] > 0).all() and (start[parts == "thigh_r", 0] < 0).all()
    assert (start[parts == "forearm_l", 0] > start[parts == "upperarm_l", 0].max() - 0.05).all()
    assert start[parts == "head", 1].min() > start[parts == "upper_chest", 1].mean()
    assert start[parts == "foot_l", 1].max() < start[parts == "shin_l", 1].mean()
    assert start[parts == "pelvis", 1].mean() < start[parts == "abdomen", 1].mean()


def test_makehuman_body_with_a_real_bvh(tmp_path):
    data = Path(__file__).parents[1] / "data"
    body = build_body("makehuman")
    motion = build_motion(body, str(data / "cmu_131_01_bvh11.bvh"), units="cmu", frames=60)
    result = generate_capture(body, motion, markers="sparse", seed=0)
    assert result.capture.n_frames == 60
    assert result.summary["markers"] == 41


@pytest.mark.slow
def test_sparse_pelvis_markers_ride_the_pelvis_bone_at_its_landmarks(body):
    """The iliac-spine markers move rigidly with the pelvis joint, over the pelvis's
    real width; every other marker stays where the skin carries it."""
    from skincap.geometry.kinematics import forward_kinematics
    from skincap.synth.markers import place_markers, sparse_marker_layout

    motion = build_motion(body, "squat", frames=30)
    result = generate_capture(body, motion, markers="sparse", seed=5)
    labels = list(result.truth.labels)
    pelvis = [labels.index(x) for x in ("LASI", "RASI", "LPSI", "RPSI")]
    pos = result.truth.positions
    # rigid: every distance between them constant (the squat flexes the hips ~90 deg)
    d = np.linalg.norm(pos[:, pelvis, None] - pos[:, None, pelvis], axis=-1)
    assert np.ptp(d, axis=0).max() < 1e-9
    # in the pelvis joint's frame they do not move at all
    layout = sparse_marker_layout(body, body.skin)
    joint = layout.meta["rigid"]["joint"]
    assert body.skin.skeleton.names[joint] == "Hips"  # both hips hang from it
    world = forward_kinematics(motion)[:, motion.skeleton.index(body.skin.skeleton.names[joint])]
    local = np.einsum("tji,tkj->tki", world[:, :3, :3], pos[:, pelvis] - world[:, None, :3, 3])
    assert np.ptp(local, axis=0).max() < 1e-9
    # the real width: ASIS about 2 x 12 cm apart (the skin the body binds to its
    # pelvis is a strip near the midline, ASIS +-4 cm)
    asis = d[0, 0, 1]
    assert 0.18 < asis < 0.32, asis
    assert d[0, 2, 3] < asis  # the PSIS closer together than the ASIS
    # the other markers: exactly the skin's
    skin_pos, _ = place_markers(layout, result.skin.frames, body.faces)
    others = [k for k in range(len(layout.labels)) if k not in pelvis]
    np.testing.assert_array_equal(pos[:, others], skin_pos[:, others])
