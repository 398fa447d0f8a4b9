"""Skin weights fitted to marker motion, against ground truth: an arm tube skinned with
known weights (not bone heat's) under a known skeleton; the markers' fitted weights
recover the true ones, the vertices' carried weights come close to them between the
markers, and ``skeleton_rbf`` with the fitted weights follows the true skin better than
with bone heat."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mesh_grids import tube
from skincap.deform.dense.skeleton_rbf import build_skeleton_rbf, surface_point_weights
from skincap.deform.skeletal.deformers import DualQuaternionSkinning, LinearBlendSkinning
from skincap.deform.skeletal.fit_weights import (
    candidate_joints,
    carry_weight_corrections,
    dense_weights,
    fit_point_skin_weights,
)
from skincap.deform.skeletal.weights import bone_heat_weights
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics
from skincap.types import Motion, Skeleton


def _arm_motion(n_frames: int = 40) -> Motion:
    """Shoulder (root) swinging, elbow bending and unbending up to 90 degrees, wrist end."""
    skel = Skeleton(
        names=["shoulder", "elbow", "wrist"],
        parents=np.array([-1, 0, 1]),
        offsets=np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.0, 0.0]]),
    )
    t = np.linspace(0.0, 1.0, n_frames)
    rot = np.zeros((n_frames, 3, 4))
    rot[:, 0] = Rotation.from_rotvec(0.5 * np.sin(3 * t)[:, None] * [0.2, 1.0, 0.3]).as_quat()
    bend = np.radians(90) * np.sin(np.pi * t) ** 2
    rot[:, 1] = Rotation.from_rotvec(bend[:, None] * [0, 0.3, 1.0]).as_quat()
    # the wrist turns too, so it moves apart from the elbow (else any split between the
    # two would skin alike)
    rot[:, 2] = Rotation.from_rotvec(0.8 * t[:, None] * [1.0, 0.2, 0]).as_quat()
    trans = np.broadcast_to(skel.offsets, (n_frames, 3, 3)).copy()
    trans[:, 0] = np.stack([0.1 * t, 1.0 + 0.05 * t, -0.1 * t], 1)
    return Motion(skeleton=skel, rotations=rot, translations=trans, rate=60.0)


@pytest.fixture(scope="module")
def arm():
    """The tube at rest (frame 0 = the rest pose), true weights whose elbow transition
    sits 5 cm past the joint and is sharp (bone heat's is centred on it and wide), the
    vertices and 48 markers (6 mm off the skin) moved by them."""
    motion = _arm_motion()
    world = forward_kinematics(motion)
    rest, faces = tube(31, 12, 0.05)
    vertices = rest @ world[0, 0, :3, :3].T + world[0, 0, :3, 3]
    elbow = 1.0 / (1.0 + np.exp(-(rest[:, 0] - 0.35) / 0.01))  # the forearm's weight
    true_v = np.zeros((len(rest), 3))
    true_v[:, 0], true_v[:, 1] = 1.0 - elbow, elbow
    m_rest, _ = tube(12, 6, 0.056, length=0.56)
    m_rest[:, 0] += 0.02
    markers0 = m_rest @ world[0, 0, :3, :3].T + world[0, 0, :3, 3]
    idx_v = np.broadcast_to(np.arange(3), true_v.shape)
    m_idx, m_w = surface_point_weights(
        markers0, vertices, faces, idx_v, true_v, 3, max_influences=3
    )
    true_m = dense_weights(m_idx, m_w, 3)
    skinning = np.einsum("tjab,jbc->tjac", world, np.linalg.inv(world[0]))
    return motion, world, vertices, faces, true_v, markers0, true_m, skinning


def _heat(vertices, faces, world, markers0):
    idx, w = bone_heat_weights((vertices, faces), world[0, :, :3, 3], [-1, 0, 1], max_influences=3)
    m_idx, m_w = surface_point_weights(markers0, vertices, faces, idx, w, 3, max_influences=3)
    return dense_weights(idx, w, 3), dense_weights(m_idx, m_w, 3)


def test_fitted_marker_weights_recover_the_true_ones(arm) -> None:
    _, world, vertices, faces, _, markers0, true_m, skinning = arm
    idx = np.broadcast_to(np.arange(3), true_m.shape)
    markers = LinearBlendSkinning(markers0, idx, true_m).deform(skinning)  # (T, N, 3)
    markers[5:9, ::7] = np.nan  # a few missing samples change nothing
    _, heat_m = _heat(vertices, faces, world, markers0)
    assert np.abs(heat_m - true_m).sum(axis=1).max() > 0.5  # bone heat is far off
    fitted = fit_point_skin_weights(markers0, markers, skinning, heat_m, [-1, 0, 1])
    assert np.allclose(fitted.sum(axis=1), 1.0) and fitted.min() >= 0.0
    assert np.abs(fitted - true_m).max() < 0.02


def test_carried_vertex_weights_match_the_true_ones_between_markers(arm) -> None:
    _, world, vertices, faces, true_v, markers0, true_m, skinning = arm
    heat_v, heat_m = _heat(vertices, faces, world, markers0)
    idx, w = carry_weight_corrections(vertices, heat_v, markers0, heat_m, true_m, max_influences=3)
    carried = dense_weights(idx, w, 3)
    err_heat = np.abs(heat_v - true_v).sum(axis=1)
    err = np.abs(carried - true_v).sum(axis=1)
    assert np.allclose(carried.sum(axis=1), 1.0) and carried.min() >= 0.0
    # every vertex is between markers here (rings 5 cm apart): the transition is found
    assert err.mean() < 0.3 * err_heat.mean()
    far = np.abs(vertices[:, 0] - vertices[:, 0].min() - 0.35) > 0.08  # off the transition
    assert err[far].max() < 0.05


def test_skeleton_rbf_with_fitted_weights_beats_bone_heat(arm) -> None:
    """The true skin: DQS of the true weights plus a smooth soft-tissue wobble that the
    markers carry (the synthetic captures' model); the markers ride it."""
    motion, world, vertices, faces, true_v, markers0, true_m, skinning = arm
    idx3 = np.broadcast_to(np.arange(3), true_v.shape)
    skin = DualQuaternionSkinning(vertices, idx3, true_v).deform(skinning)
    marks = DualQuaternionSkinning(markers0, idx3[: len(markers0)], true_m).deform(skinning)
    t = np.linspace(0, 1, motion.n_frames)[:, None, None]
    wobble = lambda p: 0.001 * np.sin(8 * t + 20 * p[None, :, :1]) * [0, 1, 0]  # noqa: E731
    skin, marks = skin + wobble(vertices), marks + wobble(markers0)
    errors, weight_errors = {}, {}
    for kind in ("bone_heat", "fitted"):
        d = build_skeleton_rbf(
            vertices, faces, markers0 + wobble(markers0)[0], motion, 0, positions=marks,
            skin_weights=kind,
        )  # fmt: skip
        got = np.concatenate(list(d.deform(marks, motion)))
        errors[kind] = np.sqrt(np.mean(np.sum((got - skin) ** 2, axis=-1)))
        weights = dense_weights(d.joint_indices, d.joint_weights, 3)
        weight_errors[kind] = np.abs(weights - true_v).sum(axis=1).mean()
    # the residual interpolation already carries much of bone heat's error (2.13 mm RMS
    # with it, 1.55 mm fitted when this was written); the weights change most
    assert errors["fitted"] < 0.8 * errors["bone_heat"], errors
    assert weight_errors["fitted"] < 0.4 * weight_errors["bone_heat"], weight_errors


def test_candidates_and_bad_input(arm) -> None:
    _, world, vertices, faces, _, markers0, true_m, skinning = arm
    cand, valid = candidate_joints(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]), [-1, 0, 1], 2)
    assert cand[0].tolist() == [1, 0] and valid.all()  # the support, then its parent
    assert cand[1].tolist() == [0, 1]
    with pytest.raises(ValidationError, match="skinning: expected"):
        fit_point_skin_weights(markers0, markers0[None], skinning, true_m, [-1, 0, 1])
    with pytest.raises(ValidationError, match="prior_scale"):
        fit_point_skin_weights(
            markers0, np.repeat(markers0[None], len(skinning), 0), skinning, true_m, [-1, 0, 1],
            prior_scale=0.0,
        )  # fmt: skip
    with pytest.raises(ValidationError, match="skin_weights"):
        build_skeleton_rbf(vertices, faces, markers0, _arm_motion(), 0, skin_weights="heat")


def test_simplex_solver_meets_the_optimality_conditions() -> None:
    """Random small problems: the gradient 2(Gw - h) is equal on the support and no
    smaller off it (the KKT conditions of the convex problem on the simplex)."""
    from skincap.geometry.simplex import simplex_least_squares

    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 12, 5))
    gram = np.einsum("pik,pil->pkl", a, a) + 1e-3 * np.eye(5)
    rhs = rng.normal(size=(200, 5))
    valid = np.ones((200, 5), dtype=bool)
    valid[::3, 4] = False
    w = simplex_least_squares(gram, valid, rhs)
    assert np.allclose(w.sum(axis=1), 1.0) and w.min() >= 0.0 and (w[~valid] == 0).all()
    grad = 2.0 * (np.einsum("pkl,pl->pk", gram, w) - rhs)
    on = w > 1e-9
    level = np.where(on, grad, -np.inf).max(axis=1)
    # to 1e-7: the solver's tie-breaking ridge (1e-9 of the mean diagonal, ~12 here)
    assert np.abs(np.where(on, grad - level[:, None], 0.0)).max() < 1e-7
    assert (np.where(valid & ~on, grad - level[:, None], 0.0) > -1e-7).all()
    assert (on.sum(axis=1) < valid.sum(axis=1)).any()  # some constraints are active
