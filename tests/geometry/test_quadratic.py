"""Quadratic deformation fields (eq. 6): exactness, regularisation, NaN, shapes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skincap.errors import ValidationError
from skincap.geometry.quadratic import (
    QUADRATIC_TERMS,
    apply_quadratic,
    fit_quadratic,
    quadratic_basis,
)


def _field(rng: np.random.Generator, quadratic_scale: float = 0.5) -> np.ndarray:
    a = np.zeros((3, QUADRATIC_TERMS))
    a[:, :3] = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    a[:, 3:9] = quadratic_scale * rng.normal(size=(3, 6))
    a[:, 9] = 0.01 * rng.normal(size=3)
    return a


def test_basis_terms_in_order() -> None:
    q = quadratic_basis(np.array([2.0, 3.0, 5.0]))
    np.testing.assert_array_equal(q, [2, 3, 5, 4, 9, 25, 6, 15, 10, 1])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), k=st.integers(10, 40))
def test_pure_quadratic_field_is_recovered_exactly(seed: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    ref = 0.1 * rng.normal(size=(k, 3))
    a = _field(rng)
    got = fit_quadratic(
        ref, apply_quadratic(a, ref), linear_regularisation=0, quadratic_regularisation=0
    )
    np.testing.assert_allclose(got, a, atol=1e-7 * np.abs(a).max())


def test_default_regularisation_biases_a_well_spread_part_little() -> None:
    rng = np.random.default_rng(1)
    ref = 0.1 * rng.normal(size=(40, 3))
    a = _field(rng, 0.3)
    target = apply_quadratic(a, ref)
    got = apply_quadratic(fit_quadratic(ref, target), ref)
    # relative to the quadratic part of the displacement
    shift = np.abs(target - ref).max()
    assert np.abs(got - target).max() < 1e-3 * shift


def test_few_points_fall_back_to_identity_not_wild_terms() -> None:
    rng = np.random.default_rng(2)
    ref = 0.1 * rng.normal(size=(4, 3))  # far fewer than 10 terms
    cur = ref + 0.001 * rng.normal(size=(4, 3))
    a = fit_quadratic(ref, cur, quadratic_regularisation=1e-2)
    assert np.abs(a[:, 3:9]).max() < 1.0  # bounded quadratic terms (1/m)
    probe = 0.15 * rng.normal(size=(50, 3))
    assert np.abs(apply_quadratic(a, probe) - probe).max() < 0.02


def test_batched_with_missing_points_equals_one_by_one() -> None:
    rng = np.random.default_rng(3)
    ref = 0.1 * rng.normal(size=(2, 20, 3))
    fields = np.stack([_field(rng), _field(rng)])
    cur = apply_quadratic(fields, ref)
    cur[0, 3] = np.nan
    cur[1, [0, 5, 7]] = np.nan
    got = fit_quadratic(ref, cur, linear_regularisation=0, quadratic_regularisation=0)
    for b in range(2):
        keep = np.isfinite(cur[b]).all(1)
        one = fit_quadratic(
            ref[b, keep], cur[b, keep], linear_regularisation=0, quadratic_regularisation=0
        )
        np.testing.assert_allclose(got[b], one, atol=1e-9)
        np.testing.assert_allclose(got[b], fields[b], atol=1e-7)


def test_no_valid_point_gives_nan() -> None:
    got = fit_quadratic(np.zeros((3, 3)), np.full((3, 3), np.nan))
    assert np.isnan(got).all()


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValidationError, match="same K"):
        fit_quadratic(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValidationError, match="non-negative"):
        fit_quadratic(np.zeros((4, 3)), np.zeros((4, 3)), -np.ones(4))
    with pytest.raises(ValidationError, match="matrix"):
        apply_quadratic(np.zeros((3, 9)), np.zeros((4, 3)))
