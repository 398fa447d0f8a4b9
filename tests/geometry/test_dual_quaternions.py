"""Algebraic properties of the dual-quaternion helpers, with near-singular samples."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from quaternion_samples import unit_quats
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.geometry.dual_quaternions import (
    dq_apply,
    dq_conjugate,
    dq_from_matrices,
    dq_from_quat_translation,
    dq_identity,
    dq_multiply,
    dq_normalize,
    dq_to_matrices,
    dq_to_quat_translation,
)

translations = arrays(np.float64, 3, elements=st.floats(-10, 10, allow_nan=False))
points = arrays(np.float64, 3, elements=st.floats(-10, 10, allow_nan=False))


def rigid(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix()
    m[:3, 3] = t
    return m


@settings(max_examples=200, deadline=None)
@given(unit_quats(), translations, points)
def test_apply_matches_matrix(q: np.ndarray, t: np.ndarray, p: np.ndarray) -> None:
    dq = dq_from_quat_translation(q, t)
    m = rigid(q, t)
    np.testing.assert_allclose(dq_apply(dq, p), m[:3, :3] @ p + t, atol=1e-12)
    # the antipodal dual quaternion is the same transform
    np.testing.assert_allclose(dq_apply(-dq, p), m[:3, :3] @ p + t, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(unit_quats(), translations)
def test_matrix_round_trip(q: np.ndarray, t: np.ndarray) -> None:
    m = rigid(q, t)
    dq = dq_from_matrices(m)
    assert dq[3] >= 0.0  # canonical real part
    np.testing.assert_allclose(np.linalg.norm(dq[:4]), 1.0, atol=1e-14)
    assert abs(np.dot(dq[:4], dq[4:])) < 1e-12  # unit dual quaternion
    np.testing.assert_allclose(dq_to_matrices(dq), m, atol=1e-12)
    q2, t2 = dq_to_quat_translation(dq)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    assert abs(abs(np.dot(q2, q)) - 1.0) < 1e-12


@settings(max_examples=200, deadline=None)
@given(unit_quats(), translations, unit_quats(), translations, points)
def test_multiply_is_composition(
    qa: np.ndarray, ta: np.ndarray, qb: np.ndarray, tb: np.ndarray, p: np.ndarray
) -> None:
    a = dq_from_quat_translation(qa, ta)
    b = dq_from_quat_translation(qb, tb)
    ab = dq_multiply(a, b)
    np.testing.assert_allclose(dq_to_matrices(ab), rigid(qa, ta) @ rigid(qb, tb), atol=1e-11)
    np.testing.assert_allclose(dq_apply(ab, p), dq_apply(a, dq_apply(b, p)), atol=1e-11)
    # conjugate is the inverse of a unit dual quaternion
    np.testing.assert_allclose(dq_multiply(a, dq_conjugate(a)), dq_identity(), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    unit_quats(),
    translations,
    st.floats(0.01, 100.0),
    arrays(np.float64, 4, elements=st.floats(-1, 1, allow_nan=False)),
    points,
)
def test_normalize(
    q: np.ndarray, t: np.ndarray, scale: float, drift: np.ndarray, p: np.ndarray
) -> None:
    dq = dq_from_quat_translation(q, t)
    # scaled, and with a dual part that leans along the real part
    raw = scale * dq + np.concatenate([np.zeros(4), 0.3 * np.dot(drift, q) * q])
    n = dq_normalize(raw)
    np.testing.assert_allclose(np.linalg.norm(n[:4]), 1.0, atol=1e-14)
    assert abs(np.dot(n[:4], n[4:])) < 1e-12
    np.testing.assert_allclose(dq_normalize(n), n, atol=1e-14)  # idempotent
    np.testing.assert_allclose(dq_apply(n, p), rigid(q, t)[:3, :3] @ p + t, atol=1e-11)
    # dq_apply on the real-part-normalised blend ignores the parallel dual component
    np.testing.assert_allclose(
        dq_apply(raw / np.linalg.norm(raw[:4]), p), rigid(q, t)[:3, :3] @ p + t, atol=1e-11
    )


def test_antipodal_blend_needs_the_sign_fix() -> None:
    """Blending q and -q (same transform) without the fix cancels; with it, it is exact."""
    q = Rotation.from_euler("x", 179.9, degrees=True).as_quat()
    a = dq_from_quat_translation(q, [0.0, 1.0, 0.0])
    b = -a
    naive = 0.5 * a + 0.5 * b
    assert np.linalg.norm(naive[:4]) < 1e-12
    fixed = 0.5 * a + 0.5 * (b if np.dot(a[:4], b[:4]) >= 0 else -b)
    np.testing.assert_allclose(
        dq_apply(dq_normalize(fixed), [1.0, 2.0, 3.0]), dq_apply(a, [1.0, 2.0, 3.0]), atol=1e-12
    )


def test_broadcast_and_shapes() -> None:
    rng = np.random.default_rng(3)
    q = Rotation.random(12, random_state=4).as_quat().reshape(3, 4, 4)
    t = rng.normal(size=(3, 4, 3))
    dq = dq_from_quat_translation(q, t)
    assert dq.shape == (3, 4, 8)
    m = dq_to_matrices(dq)
    assert m.shape == (3, 4, 4, 4)
    np.testing.assert_allclose(dq_to_matrices(dq_from_matrices(m)), m, atol=1e-12)
    # one point against all transforms
    p = np.array([0.5, -1.0, 2.0])
    np.testing.assert_allclose(
        dq_apply(dq, p), np.einsum("...ij,j->...i", m[..., :3, :3], p) + m[..., :3, 3], atol=1e-12
    )
    assert dq_identity((2, 5)).shape == (2, 5, 8)
    np.testing.assert_array_equal(dq_apply(dq_identity(), p), p)


def test_nan_propagates_without_warnings() -> None:
    m = np.stack([np.eye(4), np.full((4, 4), np.nan)])
    dq = dq_from_matrices(m)
    assert np.isfinite(dq[0]).all() and np.isnan(dq[1]).all()
    pts = dq_apply(dq, np.ones(3))
    assert np.isfinite(pts[0]).all() and np.isnan(pts[1]).all()
    assert np.isnan(dq_normalize(np.zeros(8))).all()


def test_rejects_bad_input() -> None:
    with pytest.raises(ValidationError, match="not a rigid transform"):
        dq_from_matrices(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValidationError, match="not a rigid transform"):
        dq_from_matrices(np.diag([-1.0, 1.0, 1.0, 1.0]))  # reflection
    with pytest.raises(ValidationError, match=r"\(\.\.\., 4, 4\)"):
        dq_from_matrices(np.eye(3))
    with pytest.raises(ValidationError, match=r"\(\.\.\., 8\)"):
        dq_apply(np.zeros(7), np.zeros(3))
    with pytest.raises(ValidationError, match="points"):
        dq_apply(dq_identity(), np.zeros(2))
    with pytest.raises(ValidationError, match="do not broadcast"):
        dq_from_quat_translation(np.zeros((2, 4)), np.zeros((3, 3)))
