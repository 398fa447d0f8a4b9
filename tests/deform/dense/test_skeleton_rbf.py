"""``skeleton_rbf`` against analytic cases: a pure skeletal motion is DQS exactly; the
markers are reproduced exactly under any added displacement; a missing marker is left
out of its frame's fit, never NaN."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mesh_grids import tube
from skincap.deform.dense.skeleton_rbf import (
    KERNELS,
    blend_dual_quaternions,
    build_skeleton_rbf,
    surface_point_weights,
)
from skincap.deform.skeletal.deformers import DualQuaternionSkinning
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics
from skincap.types import Motion, Skeleton


def _arm_motion(n_frames: int = 12) -> Motion:
    """Shoulder (root, moving and turning), elbow bending to 80°, wrist end site."""
    skel = Skeleton(
        names=["shoulder", "elbow", "wrist"],
        parents=np.array([-1, 0, 1]),
        offsets=np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.0, 0.0]]),
    )
    t = np.linspace(0.0, 1.0, n_frames)
    rot = np.zeros((n_frames, 3, 4))
    rot[:, 0] = Rotation.from_rotvec(0.7 * t[:, None] * [0.2, 1.0, 0.3]).as_quat()
    rot[:, 1] = Rotation.from_rotvec(np.radians(80) * t[:, None] * [0, 0, 1.0]).as_quat()
    rot[:, 2] = [0, 0, 0, 1.0]
    trans = np.broadcast_to(skel.offsets, (n_frames, 3, 3)).copy()
    trans[:, 0] = np.stack([0.2 * t, 1.0 + 0.1 * t, -0.1 * t], 1)
    return Motion(skeleton=skel, rotations=rot, translations=trans, rate=60.0)


@pytest.fixture(scope="module")
def scene():
    """The tube in frame 0's pose, 48 markers 6 mm off the skin skinned like the skin
    under them (pure skeletal motion), and the deformer bound to the solved-like motion."""
    motion = _arm_motion()
    world = forward_kinematics(motion)
    vertices, faces = tube(25, 12, 0.05)
    # the mesh stands in frame 0's pose: move the x-axis tube onto the posed bones
    vertices = vertices @ world[0, 0, :3, :3].T + world[0, 0, :3, 3]
    marker_rest, _ = tube(8, 6, 0.056)
    marker_rest[:, 0] += 0.013
    markers0 = marker_rest @ world[0, 0, :3, :3].T + world[0, 0, :3, 3]
    deformer = build_skeleton_rbf(vertices, faces, markers0, motion, 0, kernel="linear")
    # the markers' motion: their own skin weights (the surface under them), DQS
    skin = np.einsum("tjab,jbc->tjac", world, np.linalg.inv(world[0]))
    markers = DualQuaternionSkinning(
        markers0, deformer.marker_joint_indices, deformer.marker_joint_weights
    ).deform(skin)
    return motion, world, vertices, faces, markers, deformer, skin


def test_pure_skeletal_motion_has_zero_residual_and_is_dqs_exactly(scene) -> None:
    motion, world, vertices, _, markers, deformer, skin = scene
    residual = deformer.local_residuals(markers, world)
    assert np.abs(residual).max() < 1e-12
    got = np.concatenate(list(deformer.deform(markers, motion, chunk=5)))
    # an independent DQS (the skeletal deformer) of the same weights and transforms
    want = DualQuaternionSkinning(vertices, deformer.joint_indices, deformer.joint_weights).deform(
        skin
    )
    assert np.abs(got - want).max() < 1e-10
    moved = np.linalg.norm(want[-1] - want[0], axis=-1)
    assert moved.max() > 0.2  # the arm really moved and bent


@pytest.mark.parametrize("kernel", KERNELS)
def test_markers_are_reproduced_exactly_under_added_soft_tissue(scene, kernel) -> None:
    motion, world, vertices, faces, markers, deformer, _ = scene
    d = build_skeleton_rbf(vertices, faces, markers[0], motion, 0, kernel=kernel)
    rng = np.random.default_rng(3)
    wobble = 0.01 * np.sin(np.linspace(0, 6, markers.shape[0]))[:, None, None]
    soft = markers + wobble * rng.normal(size=markers.shape[1:])[None]  # up to ~2.5 cm
    soft[0] = markers[0]
    at_markers = d.deform_frames(
        soft, world, points=markers[0], point_joint_indices=d.marker_joint_indices,
        point_joint_weights=d.marker_joint_weights,
    )  # fmt: skip
    assert np.abs(at_markers - soft).max() < 1e-9
    frames = d.deform_frames(soft, world)
    assert np.isfinite(frames).all()
    # the vertices follow the soft tissue: nearer the displaced markers than plain DQS
    plain = d.deform_frames(markers, world)
    assert np.abs(frames - plain).max() > 1e-3


def test_a_missing_marker_is_left_out_of_its_frame_and_no_vertex_is_nan(scene) -> None:
    motion, world, vertices, faces, markers, deformer, _ = scene
    rng = np.random.default_rng(0)
    soft = markers + 0.004 * rng.normal(size=markers.shape)
    gappy = soft.copy()
    gappy[3, [0, 5, 17]] = np.nan  # three markers missing in one frame
    gappy[7, :] = np.nan  # every marker missing: the skinning alone
    frames = deformer.deform_frames(gappy, world)
    assert np.isfinite(frames).all()
    at = deformer.deform_frames(
        gappy, world, points=markers[0], point_joint_indices=deformer.marker_joint_indices,
        point_joint_weights=deformer.marker_joint_weights,
    )  # fmt: skip
    seen = np.isfinite(gappy).all(axis=-1)
    assert np.abs(at[seen] - gappy[seen]).max() < 1e-9  # the seen ones still exact
    dqs = deformer.deform_frames(markers, world)  # zero residual: plain DQS
    assert np.abs(frames[7] - dqs[7]).max() < 1e-12
    # the frame with gaps is the fit of the other markers, not the full one
    full = deformer.deform_frames(soft, world)
    assert np.abs(frames[3] - full[3]).max() > 1e-4
    assert np.abs(np.delete(frames, [3, 7], 0) - np.delete(full, [3, 7], 0)).max() < 1e-12


def test_surface_point_weights_blend_the_triangle_corners() -> None:
    vertices = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]])
    faces = np.array([[0, 1, 2]])
    idx = np.array([[0, 1], [1, 0], [2, 0]])
    w = np.array([[1.0, 0.0], [1.0, 0.0], [0.5, 0.5]])
    i, got = surface_point_weights(np.array([[0.25, 0.25, 0.01]]), vertices, faces, idx, w, 3)
    dense = np.zeros(3)
    dense[i[0]] = got[0]
    # barycentric (0.5, 0.25, 0.25): joint 0 gets 0.5 + 0.125, joint 1 0.25, joint 2 0.125
    assert dense == pytest.approx([0.625, 0.25, 0.125])


def test_blended_dual_quaternions_take_the_short_way_round() -> None:
    q = Rotation.from_rotvec([[0, 0, 0.1], [0, 0, -0.1]]).as_quat()
    dq = np.zeros((1, 2, 8))
    dq[0, :, :4] = q
    dq[0, 1, :4] *= -1  # the same rotation, the other hemisphere
    b = blend_dual_quaternions(dq, np.array([[0, 1]]), np.array([[0.5, 0.5]]))
    assert np.abs(b[0, 0, :4] - [0, 0, 0, 1.0]).max() < 1e-12


def test_bad_shapes_are_refused(scene) -> None:
    motion, world, vertices, faces, markers, deformer, _ = scene
    with pytest.raises(ValidationError, match="positions"):
        deformer.deform_frames(markers[:, :5], world)
    with pytest.raises(ValidationError, match="kernel"):
        build_skeleton_rbf(vertices, faces, markers[0], motion, 0, kernel="gauss")
    with pytest.raises(ValidationError, match="reference_frame"):
        build_skeleton_rbf(vertices, faces, markers[0], motion, 99)
