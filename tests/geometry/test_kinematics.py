"""Forward kinematics against a per-frame reference and analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.geometry.kinematics import (
    forward_kinematics,
    forward_kinematics_arrays,
    joint_positions,
    joint_positions_arrays,
    rest_positions,
)
from skincap.types import Motion, Skeleton


def reference_fk(parents: np.ndarray, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Straightforward per-frame, per-joint 4x4 products (independent of the library)."""
    n_frames, n_joints = q.shape[:2]
    out = np.zeros((n_frames, n_joints, 4, 4))
    for f in range(n_frames):
        for j in range(n_joints):
            local = np.eye(4)
            local[:3, :3] = Rotation.from_quat(q[f, j]).as_matrix()
            local[:3, 3] = t[f, j]
            out[f, j] = local if parents[j] < 0 else out[f, parents[j]] @ local
    return out


def random_case(
    seed: int, n_frames: int = 7, n_joints: int = 12
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    parents = np.array(
        [-1]
        + [
            int(rng.integers(-1, k)) if k % 5 == 0 else int(rng.integers(0, k))
            for k in range(1, n_joints)
        ]
    )
    q = (
        Rotation.random(n_frames * n_joints, random_state=seed)
        .as_quat()
        .reshape(n_frames, n_joints, 4)
    )
    t = rng.normal(size=(n_frames, n_joints, 3))
    return parents, q, t


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_matches_per_frame_reference(seed: int) -> None:
    parents, q, t = random_case(seed)
    ref = reference_fk(parents, q, t)
    got = forward_kinematics_arrays(parents, q, t)
    np.testing.assert_allclose(got, ref, atol=1e-12)
    np.testing.assert_allclose(joint_positions_arrays(parents, q, t), ref[..., :3, 3], atol=1e-12)


def test_analytic_chain() -> None:
    # three joints along x, each turning 90 degrees about z: an L then a U shape
    parents = np.array([-1, 0, 1])
    z90 = Rotation.from_euler("z", 90, degrees=True).as_quat()
    q = np.stack([z90, z90, np.array([0, 0, 0, 1.0])])[None]
    t = np.array([[[1.0, 2.0, 3.0], [1.0, 0, 0], [1.0, 0, 0]]])
    pos = joint_positions_arrays(parents, q, t)[0]
    np.testing.assert_allclose(pos, [[1, 2, 3], [1, 3, 3], [0, 3, 3]], atol=1e-15)
    w = forward_kinematics_arrays(parents, q, t)[0]
    # joint 2's frame is turned 180 degrees about z
    np.testing.assert_allclose(w[2, :3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-15)
    np.testing.assert_allclose(w[:, 3], [[0, 0, 0, 1]] * 3, atol=0)


def test_rest_pose_and_broadcast_offsets() -> None:
    sk = Skeleton(
        names=["a", "b", "c", "d"],
        parents=[-1, 0, 1, 0],
        offsets=[[0, 1, 0], [0, 2, 0], [1, 0, 0], [0, 0, 5]],
    )
    np.testing.assert_allclose(rest_positions(sk), [[0, 1, 0], [0, 3, 0], [1, 3, 0], [0, 1, 5]])
    q = np.tile([0, 0, 0, 1.0], (4, 4, 1))  # (T=4, J=4, 4)
    pos = joint_positions_arrays(sk, q, sk.offsets)  # (J, 3) translations broadcast
    assert pos.shape == (4, 4, 3)
    np.testing.assert_allclose(pos, np.broadcast_to(rest_positions(sk), (4, 4, 3)))


def test_motion_wrappers_and_multiple_roots() -> None:
    parents, q, t = random_case(5, n_frames=3, n_joints=6)
    parents[3] = -1
    sk = Skeleton(names=list("abcdef"), parents=parents, offsets=t[0])
    m = Motion(skeleton=sk, rotations=q, translations=t, rate=100.0)
    np.testing.assert_allclose(forward_kinematics(m), reference_fk(parents, q, t), atol=1e-12)
    np.testing.assert_allclose(
        joint_positions(m), reference_fk(parents, q, t)[..., :3, 3], atol=1e-12
    )


def test_nan_spreads_to_descendants_only() -> None:
    parents = np.array([-1, 0, 1, 0])
    q = np.tile([0, 0, 0, 1.0], (2, 4, 1))
    t = np.ones((2, 4, 3))
    q[1, 1, 0] = np.nan
    pos = joint_positions_arrays(parents, q, t)
    assert np.isfinite(pos[0]).all()
    assert np.isfinite(
        pos[1, [0, 1, 3]]
    ).all()  # joint 1's own position uses its parent's rotation only
    assert np.isnan(pos[1, 2]).all()
    w = forward_kinematics_arrays(parents, q, t)
    assert np.isnan(w[1, 1, :3, :3]).all() and np.isfinite(w[1, 3]).all()


def test_validation() -> None:
    with pytest.raises(ValidationError, match="parent"):
        joint_positions_arrays(np.array([0, 0]), np.zeros((1, 2, 4)), np.zeros((1, 2, 3)))
    with pytest.raises(ValidationError, match="rotations"):
        joint_positions_arrays(np.array([-1, 0]), np.zeros((1, 3, 4)), np.zeros((1, 2, 3)))
    with pytest.raises(ValidationError, match="broadcast"):
        joint_positions_arrays(np.array([-1, 0]), np.zeros((2, 2, 4)), np.zeros((3, 2, 3)))
