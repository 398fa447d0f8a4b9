"""Algebraic properties of the quaternion helpers, including near-singular samples."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from quaternion_samples import SPECIAL, SQ, unit_quats
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.geometry.rotations import (
    euler_to_quat,
    matrix_to_quat,
    quat_angle,
    quat_apply,
    quat_canonical,
    quat_conjugate,
    quat_identity,
    quat_inverse,
    quat_multiply,
    quat_normalize,
    quat_to_euler,
    quat_to_matrix,
)

vectors = arrays(np.float64, 3, elements=st.floats(-100, 100, allow_nan=False))


@settings(max_examples=200, deadline=None)
@given(unit_quats(), unit_quats(), vectors)
def test_multiply_composes_like_scipy_and_matrices(
    a: np.ndarray, b: np.ndarray, v: np.ndarray
) -> None:
    ab = quat_multiply(a, b)
    ref = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_matrix()
    np.testing.assert_allclose(quat_to_matrix(ab), ref, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(a) @ quat_to_matrix(b), ref, atol=1e-12)
    # applying the product = applying b then a
    np.testing.assert_allclose(quat_apply(ab, v), quat_apply(a, quat_apply(b, v)), atol=1e-10)
    assert abs(np.linalg.norm(ab) - 1.0) < 1e-12


@settings(max_examples=200, deadline=None)
@given(unit_quats(), vectors)
def test_apply_matches_matrix_and_scipy(q: np.ndarray, v: np.ndarray) -> None:
    np.testing.assert_allclose(quat_apply(q, v), quat_to_matrix(q) @ v, atol=1e-10)
    np.testing.assert_allclose(quat_apply(q, v), Rotation.from_quat(q).apply(v), atol=1e-10)
    # rotations keep lengths
    assert abs(np.linalg.norm(quat_apply(q, v)) - np.linalg.norm(v)) < 1e-9


@settings(max_examples=200, deadline=None)
@given(unit_quats())
def test_conjugate_inverts_and_antipodes_are_equal(q: np.ndarray) -> None:
    np.testing.assert_allclose(
        quat_canonical(quat_multiply(q, quat_conjugate(q))), [0, 0, 0, 1], atol=1e-12
    )
    np.testing.assert_allclose(quat_inverse(q), quat_conjugate(q), atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q), quat_to_matrix(-q), atol=1e-15)
    assert quat_angle(q, -q) < 1e-7
    np.testing.assert_allclose(quat_canonical(q), quat_canonical(-q), atol=0)


@settings(max_examples=300, deadline=None)
@given(unit_quats())
def test_matrix_round_trip(q: np.ndarray) -> None:
    back = matrix_to_quat(quat_to_matrix(q))
    assert back[3] >= 0
    assert quat_angle(back, q) < 1e-7
    np.testing.assert_allclose(quat_to_matrix(back), quat_to_matrix(q), atol=1e-12)
    # the same representative of {q, -q} (up to sign when w is ~0 and the tie is numerical)
    qc = quat_canonical(q)
    assert (
        min(np.abs(back - qc).max(), np.abs(back + qc).max() if abs(q[3]) < 1e-9 else np.inf)
        < 1e-12
    )


def test_matrix_to_quat_at_180_degrees_every_axis() -> None:
    # trace = -1: the w-based formula divides by ~0, Shepperd's branch must be used
    for axis in np.eye(3):
        m = Rotation.from_rotvec(np.pi * axis).as_matrix()
        q = matrix_to_quat(m)
        np.testing.assert_allclose(np.abs(q), np.r_[axis, 0.0], atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(unit_quats(), unit_quats())
def test_angle_is_a_metric_with_known_values(a: np.ndarray, b: np.ndarray) -> None:
    ang = quat_angle(a, b)
    assert 0.0 <= ang <= np.pi + 1e-12
    assert abs(ang - quat_angle(b, a)) < 1e-9
    ref = (Rotation.from_quat(a).inv() * Rotation.from_quat(b)).magnitude()
    assert abs(ang - ref) < 1e-7


def test_angle_analytic() -> None:
    z90 = np.array([0, 0, SQ, SQ])
    assert quat_angle(quat_identity(), z90) == pytest.approx(np.pi / 2, abs=1e-15)
    assert quat_angle(quat_identity(), [1.0, 0, 0, 0]) == pytest.approx(np.pi, abs=1e-15)
    # tiny angles keep their precision (arccos would give 0)
    assert quat_angle(quat_identity(), [np.sin(1e-10), 0, 0, np.cos(1e-10)]) == pytest.approx(
        2e-10, rel=1e-6
    )


def test_broadcasting_shapes_and_nan() -> None:
    a = np.tile(SPECIAL[:3], (5, 1, 1))  # (5, 3, 4)
    b = SPECIAL[3]  # (4,)
    assert quat_multiply(a, b).shape == (5, 3, 4)
    assert quat_to_matrix(a).shape == (5, 3, 3, 3)
    assert quat_apply(a, np.ones(3)).shape == (5, 3, 3)
    assert matrix_to_quat(quat_to_matrix(a)).shape == (5, 3, 4)
    assert quat_identity((2, 3)).shape == (2, 3, 4)
    q = SPECIAL[:3].copy()
    q[1, 2] = np.nan
    m = quat_to_matrix(q)
    assert np.isnan(m[1]).all() and np.isfinite(m[[0, 2]]).all()
    assert np.isnan(quat_multiply(q, b)[1]).all() and np.isfinite(quat_multiply(q, b)[[0, 2]]).all()
    assert np.isnan(quat_normalize(np.zeros(4))).all()
    assert np.isnan(quat_to_matrix(np.zeros(4))).all()
    assert np.isnan(matrix_to_quat(np.full((3, 3), np.nan))).all()


def test_shape_errors() -> None:
    with pytest.raises(ValidationError, match=r"\(\.\.\., 4\)"):
        quat_multiply(np.zeros(3), np.zeros(4))
    with pytest.raises(ValidationError, match=r"\(\.\.\., 3\)"):
        quat_apply(np.array([0, 0, 0, 1.0]), np.zeros(4))
    with pytest.raises(ValidationError, match=r"3, 3"):
        matrix_to_quat(np.eye(4))
    with pytest.raises(ValidationError, match="seq"):
        euler_to_quat(np.zeros(3), "XXY")
    with pytest.raises(ValidationError, match="finite"):
        euler_to_quat([np.nan, 0, 0], "ZYX")
    with pytest.raises(ValidationError, match="angles"):
        euler_to_quat(np.zeros(2), "ZYX")


def test_euler_is_intrinsic_bvh_order() -> None:
    # channels "Zrotation Yrotation Xrotation" = R = Rz @ Ry @ Rx
    z, y, x = 30.0, -50.0, 75.0
    rz = Rotation.from_euler("z", z, degrees=True).as_matrix()
    ry = Rotation.from_euler("y", y, degrees=True).as_matrix()
    rx = Rotation.from_euler("x", x, degrees=True).as_matrix()
    q = euler_to_quat([z, y, x], "ZYX")
    np.testing.assert_allclose(quat_to_matrix(q), rz @ ry @ rx, atol=1e-14)
    np.testing.assert_allclose(quat_to_euler(q, "ZYX"), [z, y, x], atol=1e-10)


@settings(max_examples=200, deadline=None)
@given(
    st.sampled_from(["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]),
    st.floats(-180, 180),
    st.sampled_from([-90.0, 90.0, -89.9999999, 89.99999, 0.0, 45.0]),
    st.floats(-180, 180),
)
def test_euler_round_trip_through_gimbal_lock(seq: str, a: float, b: float, c: float) -> None:
    q = euler_to_quat([a, b, c], seq)
    back = euler_to_quat(quat_to_euler(q, seq), seq)
    # scipy treats angles within ~1e-7 rad of the lock as locked: the rotation it gives
    # back is then off by at most about that much; exactly at and far from lock it is exact
    near_lock = 0 < abs(abs(b) - 90.0) < 1e-3
    assert quat_angle(q, back) < (5e-7 if near_lock else 1e-10)


def test_euler_batch_shapes() -> None:
    ang = np.zeros((4, 7, 2))
    assert euler_to_quat(ang, "ZX").shape == (4, 7, 4)
    assert quat_to_euler(quat_identity((4, 7)), "ZXY").shape == (4, 7, 3)
    assert euler_to_quat(np.zeros((0, 3)), "ZYX").shape == (0, 4)
