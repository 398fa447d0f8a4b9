"""procedural_body: closed manifold swept body, sized, symmetric, skinned."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from skincap.deform.skeletal.deformers import skin_motion
from skincap.deform.skeletal.rig import rest_motion
from skincap.errors import UnitWarning, ValidationError
from skincap.geometry.kinematics import rest_positions
from skincap.geometry.rotations import euler_to_quat
from skincap.io.bvh import read_bvh
from skincap.synth.body import body_parts, procedural_body
from skincap.synth.skeleton import synth_skeleton
from skincap.types import Motion


@pytest.fixture(scope="module")
def skeleton():
    return synth_skeleton(1.75)


@pytest.fixture(scope="module")
def body(skeleton):
    return procedural_body(skeleton, n_vertices=20_000)


def _winding_numbers(vertices, faces, points):
    """Generalised winding number (van Oosterom & Strackee solid angles), (P,)."""
    a = vertices[faces[:, 0]][None] - points[:, None]
    b = vertices[faces[:, 1]][None] - points[:, None]
    c = vertices[faces[:, 2]][None] - points[:, None]
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = (
        la * lb * lc
        + np.einsum("pfi,pfi->pf", a, b) * lc
        + np.einsum("pfi,pfi->pf", b, c) * la
        + np.einsum("pfi,pfi->pf", c, a) * lb
    )
    return (2 * np.arctan2(det, den)).sum(axis=1) / (4 * np.pi)


def _check_closed_manifold(mesh, target):
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert tm.is_watertight
    assert tm.is_winding_consistent
    assert tm.euler_number == 2  # one closed genus-0 surface
    assert len(tm.split(only_watertight=False)) == 1
    assert tm.volume > 0  # outward-facing triangles
    assert abs(mesh.n_vertices / target - 1.0) < 0.2
    # no duplicate vertices left unwelded
    assert np.unique(np.round(mesh.vertices, 9), axis=0).shape[0] == mesh.n_vertices
    return tm


def test_20k_closed_manifold_and_sized(body):
    tm = _check_closed_manifold(body, 20_000)
    # a 1.75 m adult: ~60-80 litres, ~1.5-2 m² of skin
    assert 0.05 < tm.volume < 0.085
    assert 1.4 < tm.area < 2.1


@pytest.mark.parametrize("target", [5_000])
def test_5k_closed_manifold(skeleton, target):
    _check_closed_manifold(procedural_body(skeleton, n_vertices=target), target)


@pytest.mark.slow
def test_80k_closed_manifold(skeleton):
    _check_closed_manifold(procedural_body(skeleton, n_vertices=80_000), 80_000)


def test_timing_20k(skeleton):
    t0 = time.perf_counter()
    procedural_body(skeleton, n_vertices=20_000, seed=3)
    assert time.perf_counter() - t0 < 15.0  # a few seconds on one core


def test_height_and_feet(body, skeleton):
    lo, hi = body.bounds
    assert abs(lo[1]) < 0.01  # soles on the floor
    assert abs(hi[1] - 1.75) < 0.01  # top of the head at the stature
    # arm span (finger tip to finger tip) close to the stature
    assert 1.75 < hi[0] - lo[0] < 1.95
    # faces +Z: the toes are the front-most points
    front = body.vertices[np.argmax(body.vertices[:, 2])]
    assert front[1] < 0.05


def test_other_height_scales(skeleton):
    small = procedural_body(synth_skeleton(1.5), n_vertices=5_000)
    lo, hi = small.bounds
    assert abs(lo[1]) < 0.01 and abs(hi[1] - 1.5) < 0.01
    assert small.meta["height"] == pytest.approx(1.5)


def test_joints_inside(body, skeleton):
    p = rest_positions(skeleton)
    w = _winding_numbers(body.vertices, body.faces, p)
    tips = {
        "LFingers_end",
        "RFingers_end",
        "LThumb_end",
        "RThumb_end",
        "LeftToe_end",
        "RightToe_end",
    }
    for k, name in enumerate(skeleton.names):
        if name not in tips:
            assert w[k] == pytest.approx(1.0, abs=1e-6), name
    # and points well outside are outside
    out = np.array([[0.0, 1.0, 0.5], [0.5, 0.5, 0.0], [0.0, 1.9, 0.0]])
    np.testing.assert_allclose(_winding_numbers(body.vertices, body.faces, out), 0.0, atol=1e-6)
    # end sites are at least near the surface
    tree = cKDTree(body.vertices)
    tip_idx = [skeleton.index(n) for n in tips]
    inside_or_near = (w[tip_idx] > 0.5) | (tree.query(p[tip_idx])[0] < 0.02)
    assert inside_or_near.all()


def test_left_right_symmetric(body):
    tree = cKDTree(body.vertices)
    d, _ = tree.query(body.vertices * [-1.0, 1.0, 1.0])
    h = body.meta["grid_step"]
    assert np.percentile(d, 99) < 0.5 * h
    assert d.max() < 1.5 * h
    assert abs(body.vertices[:, 0].mean()) < 1e-3


def test_skin_weights(body, skeleton):
    skin = body.skin
    assert skin.joint_weights.shape == (body.n_vertices, 4)
    np.testing.assert_allclose(skin.joint_weights.sum(axis=1), 1.0, atol=1e-9)
    assert (skin.joint_weights >= 0).all()
    assert skin.skeleton is skeleton
    # bind pose: identity rotations at the rest positions
    np.testing.assert_allclose(skin.bind_matrices[:, :3, 3], rest_positions(skeleton), atol=1e-12)
    np.testing.assert_allclose(
        skin.bind_matrices[:, :3, :3], np.tile(np.eye(3), (38, 1, 1)), atol=1e-12
    )
    # the vertex nearest a bone's middle is bound mostly to that bone's head joint
    p = rest_positions(skeleton)
    tree = cKDTree(body.vertices)
    for joint, child in [
        ("LeftElbow", "LeftWrist"),
        ("RightHip", "RightKnee"),
        ("Head", "Head_end"),
    ]:
        mid = 0.5 * (p[skeleton.index(joint)] + p[skeleton.index(child)])
        _, v = tree.query(mid)
        top = skin.joint_indices[v, np.argmax(skin.joint_weights[v])]
        assert skeleton.names[top] == joint


def test_regions(body):
    reg = body.meta["regions"]
    for name in ("torso", "head", "arm_l", "leg_r", "belly", "chest", "upper_arm_l", "thigh_r"):
        assert reg[name].size > 50, name
    assert (body.vertices[reg["arm_l"], 0] > 0.12).all()
    assert (body.vertices[reg["belly"], 2] > 0).all()
    parts = np.concatenate(
        [
            reg[n]
            for n in (
                "torso",
                "neck",
                "head",
                "arm_l",
                "arm_r",
                "hand_l",
                "hand_r",
                "leg_l",
                "leg_r",
                "foot_l",
                "foot_r",
            )
        ]
    )
    np.testing.assert_array_equal(np.sort(parts), np.arange(body.n_vertices))


def test_elbow_flex_moves_forearm_not_legs(body, skeleton):
    rest = rest_motion(skeleton)
    rot = np.repeat(rest.rotations, 2, axis=0)
    rot[1, skeleton.index("LeftElbow")] = euler_to_quat(np.array([0.0, -90.0, 0.0]), "XYZ")
    motion = Motion(
        skeleton, rot, np.repeat(rest.translations, 2, axis=0), rate=120.0, channels=rest.channels
    )
    frames = np.concatenate(list(skin_motion(body, motion).frames))
    np.testing.assert_allclose(frames[0], body.vertices, atol=1e-9)
    move = np.linalg.norm(frames[1] - frames[0], axis=1)
    reg = body.meta["regions"]
    hand = reg["hand_l"]
    assert np.median(move[hand]) > 0.2  # the hand swings round with the forearm
    assert np.median(move[reg["forearm_l"]]) > 0.05
    for still in ("leg_l", "leg_r", "foot_l", "foot_r", "arm_r", "hand_r", "head"):
        assert move[reg[still]].max() < 1e-9, still
    # forearm length is kept: the finger tip ends up in front of the elbow
    tip = frames[1][hand][np.argmax(move[hand])]
    elbow = rest_positions(skeleton)[skeleton.index("LeftElbow")]
    assert tip[2] > elbow[2] + 0.2


def test_deterministic_by_seed(skeleton):
    a = procedural_body(skeleton, n_vertices=5_000, seed=7)
    b = procedural_body(skeleton, n_vertices=5_000, seed=7)
    c = procedural_body(skeleton, n_vertices=5_000, seed=8)
    assert a.vertices.tobytes() == b.vertices.tobytes()
    assert a.faces.tobytes() == b.faces.tobytes()
    assert a.skin.joint_weights.tobytes() == b.skin.joint_weights.tobytes()
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)


def test_parts_are_mirror_images(skeleton):
    parts = {p.name: p for p in body_parts(skeleton, seed=4)}
    pts = np.random.default_rng(0).uniform([-1, 0, -0.3], [1, 1.8, 0.3], (3000, 3))
    for left in ("arm_l", "hand_l", "leg_l", "foot_l"):
        right = parts[left[:-1] + "r"]
        np.testing.assert_allclose(
            right.sweep.signed_distance(pts * [-1, 1, 1]),
            parts[left].sweep.signed_distance(pts),
            atol=1e-9,
        )


def test_rejects_bad_input(skeleton, data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        cmu = read_bvh(data_dir / "cmu_131_01_bvh11.bvh").skeleton  # arms down, not a T-pose
    with pytest.raises(ValidationError, match="T-pose"):
        procedural_body(cmu)
    with pytest.raises(ValidationError, match="n_vertices"):
        procedural_body(skeleton, n_vertices=100)
    with pytest.raises(ValidationError, match="n_vertices"):
        procedural_body(skeleton, n_vertices=12.5)
    with pytest.raises(ValidationError, match="Skeleton"):
        procedural_body("body")
