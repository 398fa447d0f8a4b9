"""Batched weighted absolute orientation: exactness, optimality, reflections, NaN, degeneracy."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.geometry.rigid import apply_rigid, fit_rigid, invert_rigid

finite = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)


@st.composite
def point_sets(draw: st.DrawFn) -> np.ndarray:
    """(K, 3) points: general, nearly collinear, nearly coplanar or nearly coincident."""
    k = draw(st.integers(3, 9))
    kind = draw(st.sampled_from(["general", "collinear", "coplanar", "coincident"]))
    raw = draw(arrays(np.float64, (k, 3), elements=finite))
    eps = draw(st.sampled_from([0.0, 1e-9, 1e-6, 1e-3]))
    if kind == "collinear":
        direction = raw[0] if np.linalg.norm(raw[0]) > 1e-3 else np.array([1.0, 0.0, 0.0])
        pts = raw[:, :1] * direction + eps * raw[::-1]
    elif kind == "coplanar":
        pts = raw.copy()
        pts[:, 2] = eps * raw[:, 0]
    elif kind == "coincident":
        pts = np.ones((k, 3)) + eps * raw
    else:
        pts = raw
    return pts


def _rotation(seed: int) -> np.ndarray:
    return Rotation.random(random_state=seed).as_matrix()


def _residual(r: np.ndarray, t: np.ndarray, s: np.ndarray, d: np.ndarray, w: np.ndarray) -> float:
    return float(np.sum(w * np.sum((s @ r.T + t - d) ** 2, axis=-1)))


@settings(max_examples=150, deadline=None)
@given(point_sets(), st.integers(0, 2**31 - 1), arrays(np.float64, 3, elements=finite))
def test_exact_data_is_reproduced_with_a_proper_rotation(
    pts: np.ndarray, seed: int, shift: np.ndarray
) -> None:
    r_true = _rotation(seed)
    dst = pts @ r_true.T + shift
    r, t = fit_rigid(pts, dst)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-9)
    # even when degenerate (rotation about the line undetermined) the points map exactly
    assert np.allclose(apply_rigid(r, t, pts), dst, atol=1e-7)


@settings(max_examples=150, deadline=None)
@given(
    point_sets(),
    st.integers(0, 2**31 - 1),
    st.floats(0.0, 0.5),
    st.integers(0, 2**31 - 1),
)
def test_weighted_fit_is_no_worse_than_the_truth(
    pts: np.ndarray, seed: int, noise: float, noise_seed: int
) -> None:
    rng = np.random.default_rng(noise_seed)
    r_true = _rotation(seed)
    t_true = rng.normal(size=3)
    dst = pts @ r_true.T + t_true + noise * rng.normal(size=pts.shape)
    w = rng.uniform(0.1, 3.0, size=len(pts))
    r, t = fit_rigid(pts, dst, w)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-9)
    best = _residual(r, t, pts, dst, w)
    assert best <= _residual(r_true, t_true, pts, dst, w) + 1e-9
    # and no worse than small perturbations of itself (a local minimum)
    for dq in rng.normal(scale=1e-3, size=(4, 3)):
        r2 = Rotation.from_rotvec(dq).as_matrix() @ r
        t2 = t + rng.normal(scale=1e-3, size=3)
        assert best <= _residual(r2, t2, pts, dst, w) + 1e-12


def test_reflection_is_not_returned() -> None:
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    mirrored = pts * [1, 1, -1]  # an improper transform of a non-planar set
    r, t = fit_rigid(pts, mirrored)
    assert np.linalg.det(r) == pytest.approx(1.0)
    # planar set mirrored in its own plane: a proper rotation (180 deg flip) is exact
    planar = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [3, 1, 0]], dtype=float)
    r, t = fit_rigid(planar, planar * [1, -1, 1])
    assert np.linalg.det(r) == pytest.approx(1.0)
    assert np.allclose(apply_rigid(r, t, planar), planar * [1, -1, 1], atol=1e-12)


def test_batched_over_leading_axes_matches_single_fits() -> None:
    rng = np.random.default_rng(3)
    src = rng.normal(size=(4, 5, 6, 3))
    rots = Rotation.random(20, random_state=4).as_matrix().reshape(4, 5, 3, 3)
    dst = np.einsum("abij,abkj->abki", rots, src) + rng.normal(size=(4, 5, 1, 3))
    dst += 0.01 * rng.normal(size=dst.shape)
    w = rng.uniform(0.5, 2, size=(4, 5, 6))
    r, t = fit_rigid(src, dst, w)
    assert r.shape == (4, 5, 3, 3) and t.shape == (4, 5, 3)
    for a in range(4):
        for b in range(5):
            r1, t1 = fit_rigid(src[a, b], dst[a, b], w[a, b])
            assert np.allclose(r[a, b], r1) and np.allclose(t[a, b], t1)
    # the reference broadcast: one src set for all batches
    r_b, _ = fit_rigid(src[0, 0], dst)
    r_1, _ = fit_rigid(src[0, 0], dst[2, 3])
    assert np.allclose(r_b[2, 3], r_1)


def test_nan_points_and_mask_are_ignored() -> None:
    rng = np.random.default_rng(5)
    src = rng.normal(size=(7, 3))
    r_true = _rotation(9)
    dst = src @ r_true.T + [1.0, 2.0, 3.0]
    bad = dst.copy()
    bad[2] = [100.0, 100.0, 100.0]  # an outlier excluded by the mask
    bad[4, 1] = np.nan  # a missing point
    mask = np.ones(7, bool)
    mask[2] = False
    r, t = fit_rigid(src, bad, mask=mask)
    assert np.allclose(r, r_true) and np.allclose(t, [1, 2, 3])
    # zero and NaN weights exclude too
    w = np.ones(7)
    w[2] = 0.0
    w[5] = np.nan
    r, t = fit_rigid(src, bad, w)
    assert np.allclose(r, r_true) and np.allclose(t, [1, 2, 3])


def test_fewer_than_three_valid_points_give_nan_without_warnings() -> None:
    src = np.zeros((3, 4, 3))
    src[:] = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    dst = src.copy()
    dst[1, 1:] = np.nan  # one valid point
    dst[2, :2] = np.nan  # two valid points
    r, t = fit_rigid(src, dst)
    assert np.allclose(r[0], np.eye(3)) and np.allclose(t[0], 0)
    assert np.isnan(r[1]).all() and np.isnan(t[1]).all()
    assert np.isnan(r[2]).all() and np.isnan(t[2]).all()
    r, t = fit_rigid(src[0], dst[0], min_points=5)
    assert np.isnan(r).all()
    r, t = fit_rigid(np.full((0, 3), 1.0), np.full((0, 3), 1.0))
    assert np.isnan(r).all() and np.isnan(t).all()


def test_invert_and_apply() -> None:
    rng = np.random.default_rng(1)
    r = Rotation.random(3, random_state=2).as_matrix()
    t = rng.normal(size=(3, 3))
    p = rng.normal(size=(3, 5, 3))
    ri, ti = invert_rigid(r, t)
    assert np.allclose(apply_rigid(ri, ti, apply_rigid(r, t, p)), p)
    nan_r = np.full((3, 3), np.nan)
    assert np.isnan(apply_rigid(nan_r, np.zeros(3), p[0])).all()


def test_bad_arguments_raise_validation_error() -> None:
    pts = np.zeros((4, 3))
    with pytest.raises(ValidationError, match="src"):
        fit_rigid(np.zeros((4, 2)), pts)
    with pytest.raises(ValidationError, match="number of points"):
        fit_rigid(np.zeros((5, 3)), pts)
    with pytest.raises(ValidationError, match="weights"):
        fit_rigid(pts, pts, np.ones(3))
    with pytest.raises(ValidationError, match="non-negative"):
        fit_rigid(pts, pts, -np.ones(4))
    with pytest.raises(ValidationError, match="boolean"):
        fit_rigid(pts, pts, mask=np.ones(4))
    with pytest.raises(ValidationError, match="broadcast"):
        fit_rigid(np.zeros((2, 4, 3)), np.zeros((3, 4, 3)))
    # apply_rigid and invert_rigid check the transform alike, naming the bad array
    for transform in (lambda r, t: apply_rigid(r, t, pts), invert_rigid):
        with pytest.raises(
            ValidationError, match=r"rotation must have shape \(\.\.\., 3, 3\); got \(2, 2\)"
        ):
            transform(np.eye(2), np.zeros(3))
        with pytest.raises(
            ValidationError, match=r"translation must have shape \(\.\.\., 3\); got \(2,\)"
        ):
            transform(np.eye(3), np.zeros(2))


@settings(max_examples=150, deadline=None)
@given(
    point_sets(),
    st.integers(0, 2**31 - 1),
    st.sampled_from([0.0, 1e-6, 1e-3, 0.1]),
    st.integers(0, 2**31 - 1),
)
def test_quaternion_solver_matches_the_svd_reference(
    pts: np.ndarray, seed: int, noise: float, noise_seed: int
) -> None:
    rng = np.random.default_rng(noise_seed)
    dst = pts @ _rotation(seed).T + rng.normal(0.0, 1.0, 3) + noise * rng.normal(size=pts.shape)
    w = rng.uniform(0.2, 2.0, len(pts))
    r_q, t_q = fit_rigid(pts, dst, w)
    r_s, t_s = fit_rigid(pts, dst, w, method="svd")
    assert np.allclose(r_q @ r_q.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(r_q) == pytest.approx(1.0, abs=1e-9)
    # degenerate sets have many minimisers: the residuals agree, not the rotations
    res_q, res_s = _residual(r_q, t_q, pts, dst, w), _residual(r_s, t_s, pts, dst, w)
    scale = float(np.sum(w * np.sum((dst - dst.mean(0)) ** 2, axis=-1))) + 1e-300
    assert abs(res_q - res_s) <= 1e-9 * scale + 1e-12


def test_quaternion_solver_equals_svd_on_a_large_batch() -> None:
    rng = np.random.default_rng(7)
    src = rng.normal(0.0, 0.05, (2000, 7, 3)) + rng.normal(0.0, 1.0, (2000, 1, 3))
    rot = Rotation.random(2000, random_state=3).as_matrix()
    dst = np.einsum("bij,bkj->bki", rot, src) + rng.normal(0.0, 0.003, src.shape)
    mask = rng.random((2000, 7)) > 0.2
    r_q, t_q = fit_rigid(src, dst, mask=mask)
    r_s, t_s = fit_rigid(src, dst, mask=mask, method="svd")
    np.testing.assert_array_equal(np.isnan(t_q), np.isnan(t_s))
    assert np.isnan(t_q).any()  # some rows keep fewer than 3 points
    np.testing.assert_allclose(r_q, r_s, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(t_q, t_s, atol=1e-9, equal_nan=True)
    with pytest.raises(ValidationError, match="method"):
        fit_rigid(src, dst, method="eig")


@pytest.mark.parametrize(
    ("weights", "mask"),
    [
        (np.ones((3, 5)), None),  # 3 weight rows against 4 frames of points
        (None, np.ones((2, 5), dtype=bool)),
        (np.ones((4, 5)), np.ones((3, 5), dtype=bool)),
    ],
)
def test_weights_or_mask_that_do_not_broadcast_are_a_validation_error(weights, mask):
    src = np.random.default_rng(0).normal(size=(4, 5, 3))
    with pytest.raises(ValidationError, match=r"weights/mask leading axes do not broadcast"):
        fit_rigid(src, src, weights=weights, mask=mask)


def test_weights_with_leading_axes_broadcast_against_the_points():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(5, 3))
    rot = Rotation.random(4, random_state=2).as_matrix()  # (4, 3, 3)
    dst = np.einsum("fij,kj->fki", rot, src)  # (4, 5, 3)
    r, t = fit_rigid(src, dst, weights=np.ones((4, 5)))
    np.testing.assert_allclose(r, rot, atol=1e-9)
    np.testing.assert_allclose(t, 0.0, atol=1e-9)
