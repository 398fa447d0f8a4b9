"""Binding (§3.3), per-frame sweep motion and blending (§3.5, §4.1) of the sweep deformer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sweep_limbs import CYLINDER_CHAIN, elliptic_limb

from skincap.deform.skeletal.artefacts import _twist_and_bend, joint_pose_matrices
from skincap.deform.skeletal.deformers import make_deformer
from skincap.deform.sweep import SweepDeformer
from skincap.errors import ValidationError


def _rigid(angle_deg: float, axis, shift) -> np.ndarray:
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(axis, float)).as_matrix()
    g[:3, 3] = shift
    return g


@pytest.fixture(scope="module")
def limb():
    return elliptic_limb(0.05, 0.03)


@pytest.fixture(scope="module")
def body_sweep(body):
    return SweepDeformer(body, backend="numpy")


@pytest.mark.parametrize("volume", [True, False])
@pytest.mark.parametrize("skinning", ["dqs", "lbs"])
def test_rest_pose_is_reproduced_exactly(limb, volume, skinning) -> None:
    d = SweepDeformer(limb, chains=CYLINDER_CHAIN, volume=volume, skinning=skinning)
    identity = np.tile(np.eye(4), (2, 3, 1, 1))
    out = d.deform(identity)
    np.testing.assert_allclose(out, np.broadcast_to(limb.vertices, out.shape), atol=1e-9, rtol=0)
    np.testing.assert_allclose(d.deform(identity[0]), limb.vertices, atol=1e-9, rtol=0)


def test_body_rest_pose_is_reproduced_exactly(body, body_sweep) -> None:
    out = body_sweep.deform(np.tile(np.eye(4), (body.skin.skeleton.n_joints, 1, 1)))
    assert np.abs(out - body.vertices).max() < 1e-9
    # every limb binds its arm or leg: hundreds of vertices, weights in (0, 1]
    for bound in body_sweep.bindings:
        assert bound.vertices.size > 500
        assert (bound.weight > 0).all() and (bound.weight <= 1).all()


def test_binding_parameters_and_ellipse_coordinates(limb) -> None:
    d = SweepDeformer(limb, chains=CYLINDER_CHAIN)
    (bound,) = d.bindings
    x = limb.vertices[bound.vertices, 0]
    side = (x > 0.02) & (x < 0.48)  # the tube, away from the flat caps
    t = bound.basis.t[side]
    # t grows along the straight limb, and the vertices lie in their ellipse's plane
    order = np.argsort(x[side])
    assert np.all(np.diff(t[order]) >= -1e-9)
    assert np.abs(bound.local[side, 2]).max() < 1e-3
    # the side vertices are on the fitted ellipse (elliptic radius 1) to the fit's 2 %
    np.testing.assert_allclose(bound.rho[side], 1.0, atol=0.03)


def test_whole_body_rigid_motion_is_rigid(body, body_sweep) -> None:
    g = _rigid(70.0, [0.3, 1.0, -0.2], [0.4, -0.1, 2.0])
    m = np.tile(g, (2, body.skin.skeleton.n_joints, 1, 1))
    out = body_sweep.deform(m)
    want = body.vertices @ g[:3, :3].T + g[:3, 3]
    assert np.abs(out - want).max() < 1e-9


def test_limb_turned_at_its_root_moves_rigidly(limb) -> None:
    d = SweepDeformer(limb, chains=CYLINDER_CHAIN)
    g = _rigid(120.0, [0.0, 1.0, 1.0], [0.1, 0.2, 0.3])
    out = d.deform(np.tile(g, (3, 1, 1)))
    np.testing.assert_allclose(out, limb.vertices @ g[:3, :3].T + g[:3, 3], atol=1e-9)


def test_twist_is_spread_along_the_link_without_collapse(limb) -> None:
    """A 180-degree twist of the lower bone: the sweep turns the sections gradually."""
    d = SweepDeformer(limb, chains=CYLINDER_CHAIN)
    m = joint_pose_matrices(limb.skin, 1, Rotation.from_rotvec([np.pi, 0, 0]).as_matrix())
    out = d.deform(m)
    lbs = make_deformer("lbs", limb).deform(m)
    rings = limb.meta["rings"]  # (n_along, n_around) vertex indices

    def minor(points):  # smallest half-axis of each ring, sqrt(2 lambda_min)
        c = points - points.mean(axis=1, keepdims=True)
        lam = np.linalg.eigvalsh(np.einsum("rni,rnj->rij", c, c) / c.shape[1])
        return np.sqrt(2 * np.clip(lam[:, 1], 0, None))

    rest = minor(limb.vertices[rings])
    assert (minor(out[rings]) / rest).min() > 0.97  # no candy wrapper
    assert (minor(lbs[rings]) / rest).min() < 0.1  # where LBS collapses
    # the turn fades in along the bone that turns: the far end cap turned 180 degrees,
    # the upper bone, up to the joint, still; half way down the lower bone about 90
    x = limb.vertices[:, 0]
    far = x > 0.5 - 1e-9
    np.testing.assert_allclose(out[far, 1:], -limb.vertices[far, 1:], atol=1e-9)
    near = x < 0.25 - 1e-9
    np.testing.assert_allclose(out[near], limb.vertices[near], atol=1e-9)
    mid = rings[np.argmin(np.abs(limb.meta["ring_x"] - 0.375))]
    a0 = np.arctan2(limb.vertices[mid, 2] / 0.03, limb.vertices[mid, 1] / 0.05)
    a1 = np.arctan2(out[mid, 2] / 0.03, out[mid, 1] / 0.05)
    turned = np.degrees(np.angle(np.mean(np.exp(1j * (a1 - a0)))))
    assert 80.0 < abs(turned) < 100.0


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def test_no_seam_where_sweeps_meet_skinning(body, body_sweep) -> None:
    """Across the shoulder, hip, wrist and ankle blends the displacement field stays smooth.

    For each edge, |d_a - d_b| / rest length (d = posed - rest) is bounded by about
    2 sin(angle / 2) plus the stretch for a smooth deformation; a seam between the sweep
    and skinning would make it grow without bound on short edges.
    """
    skin = body.skin
    e = _edges(body.faces)
    w = np.zeros(body.n_vertices)
    for bound in body_sweep.bindings:
        w[bound.vertices] += bound.weight
    mixed = (w > 0.02) & (w < 0.98)
    across = mixed[e[:, 0]] | mixed[e[:, 1]] | ((w[e[:, 0]] > 0) != (w[e[:, 1]] > 0))
    assert across.sum() > 1000
    rest_len = np.linalg.norm(body.vertices[e[:, 0]] - body.vertices[e[:, 1]], axis=1)
    shoulder = skin.skeleton.index("upperarm01.R")
    elbow = skin.skeleton.index("lowerarm01.R")
    poses = [m for m, _ in _twist_and_bend(skin, elbow, 180.0, 150.0).values()]
    for angle in (90.0, -90.0):
        turn = Rotation.from_rotvec([0.0, 0.0, np.radians(angle)]).as_matrix()
        poses.append(joint_pose_matrices(skin, shoulder, turn))
    dqs = make_deformer("dqs", body)
    for m in poses:
        for d in (body_sweep, dqs):
            disp = d.deform(m) - body.vertices
            grad = np.linalg.norm(disp[e[:, 0]] - disp[e[:, 1]], axis=1) / rest_len
            if d is dqs:
                skinning_max = grad.max()
            else:
                sweep_max = grad[across].max()
        assert sweep_max < 4.5
        assert sweep_max <= skinning_max + 0.1


def test_chunks_match_whole_and_bad_input_is_refused(limb) -> None:
    d = SweepDeformer(limb, chains=CYLINDER_CHAIN)
    rng = np.random.default_rng(3)
    angles = rng.uniform(-1.5, 1.5, size=(7, 3))
    m = np.stack(
        [joint_pose_matrices(limb.skin, 1, Rotation.from_rotvec(a).as_matrix()) for a in angles]
    )
    whole = d.deform(m)
    chunks = np.concatenate(list(d.deform_chunks(m, chunk=3)))
    np.testing.assert_allclose(whole, chunks, rtol=0, atol=1e-12)
    assert np.isfinite(whole).all()
    with pytest.raises(ValidationError, match="skinning"):
        SweepDeformer(limb, chains=CYLINDER_CHAIN, skinning="sweep")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="matrices"):
        d.deform(np.eye(4))
