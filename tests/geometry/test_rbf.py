"""Cubic B-spline RBF (eq. 7): the kernel, exact interpolation, masks, stability, the ridge fit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from skincap.errors import ValidationError
from skincap.geometry.rbf import (
    RIDGE_GRID,
    choose_ridge_gcv,
    cubic_bspline,
    dilation_from_spacing,
    evaluate_rbf,
    fit_rbf,
    fit_rbf_fixed_centres,
    fit_rbf_ridge,
    fit_rbf_ridge_nested,
    rbf_kernel_scale,
)


def _grid_points(rng: np.random.Generator, n: int = 30) -> np.ndarray:
    """Points spread like a marker grid: a jittered lattice, ~5 cm apart."""
    g = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(2), indexing="ij"), -1)
    pts = 0.05 * g.reshape(-1, 3).astype(float)[:n]
    return pts + 0.005 * rng.normal(size=pts.shape)


def test_kernel_values_and_support() -> None:
    u = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.5])
    expected = [2 / 3, 23 / 48, 1 / 6, 1 / 48, 0.0, 0.0]
    np.testing.assert_allclose(cubic_bspline(u), expected)
    # C2 at the knots: second differences small and continuous
    x = np.linspace(0, 1.25, 2501)
    d2 = np.diff(cubic_bspline(x), 2) / (x[1] - x[0]) ** 2
    assert np.abs(np.diff(d2)).max() < 0.05


def test_dilation_is_twice_the_largest_nearest_neighbour_distance() -> None:
    pts = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.3, 0]], dtype=float)
    assert dilation_from_spacing(pts) == pytest.approx(2 * 0.3)
    assert np.isnan(dilation_from_spacing(pts[:1]))


def test_interpolates_its_centres_exactly() -> None:
    rng = np.random.default_rng(0)
    c = _grid_points(rng)
    values = 0.003 * rng.normal(size=(c.shape[0], 3))
    sigma = dilation_from_spacing(c)
    w = fit_rbf(c, values, sigma)
    np.testing.assert_allclose(evaluate_rbf(c, w, sigma, c), values, atol=1e-12)
    # and decays to zero beyond the support
    far = c.mean(0) + np.array([[10.0, 0, 0]])
    assert np.abs(evaluate_rbf(c, w, sigma, far)).max() == 0.0


def test_masked_centres_get_zero_weight_and_do_not_constrain() -> None:
    rng = np.random.default_rng(1)
    c = _grid_points(rng)
    values = 0.003 * rng.normal(size=c.shape)
    mask = np.ones(c.shape[0], dtype=bool)
    mask[[2, 7]] = False
    sigma = dilation_from_spacing(c)
    w = fit_rbf(c, values, sigma, mask)
    assert (w[~mask] == 0).all()
    np.testing.assert_allclose(evaluate_rbf(c, w, sigma, c[mask]), values[mask], atol=1e-12)
    alone = fit_rbf(c[mask], values[mask], sigma)
    np.testing.assert_allclose(w[mask], alone, atol=1e-12)


def test_batched_fit_equals_separate_fits() -> None:
    rng = np.random.default_rng(2)
    c = np.stack([_grid_points(rng), _grid_points(rng)])
    values = 0.003 * rng.normal(size=c.shape)
    sigma = np.array([0.12, 0.2])
    w = fit_rbf(c, values, sigma)
    for b in range(2):
        np.testing.assert_allclose(w[b], fit_rbf(c[b], values[b], sigma[b]), atol=1e-12)


def test_near_singular_kernel_stays_bounded() -> None:
    # two nearly coincident centres with different values: a plain solve explodes
    c = np.array([[0, 0, 0], [1e-9, 0, 0], [0.05, 0, 0], [0, 0.05, 0]], dtype=float)
    values = np.array([[0.001, 0, 0], [-0.001, 0, 0], [0, 0, 0], [0, 0, 0]])
    w = fit_rbf(c, values, 0.1)
    assert np.abs(w).max() < 1.0
    got = evaluate_rbf(c, w, 0.1, c)
    np.testing.assert_allclose(got[:2].mean(0), 0.0, atol=1e-6)  # the average of the two


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValidationError, match="same K"):
        fit_rbf(np.zeros((4, 3)), np.zeros((5, 3)), 0.1)
    with pytest.raises(ValidationError, match="cutoff"):
        fit_rbf(np.zeros((4, 3)), np.zeros((4, 3)), 0.1, cutoff=2.0)


def test_inverse_and_eigen_paths_agree_and_a_batch_may_mix_them() -> None:
    """A well-conditioned system goes through the inverse, a near-singular one through
    the eigen-decomposition: in one batch each gets what it would get alone, and the
    inverse's weights equal the decomposition's (cutoff 0 forces it)."""
    rng = np.random.default_rng(3)
    good = _grid_points(rng, 4)
    bad = np.array([[0, 0, 0], [1e-9, 0, 0], [0.05, 0, 0], [0, 0.05, 0]], dtype=float)
    values = 0.003 * rng.normal(size=(2, 4, 3))
    w = fit_rbf(np.stack([good, bad]), values, 0.1)
    np.testing.assert_allclose(w[0], fit_rbf(good, values[0], 0.1), rtol=0, atol=1e-15)
    np.testing.assert_allclose(w[1], fit_rbf(bad, values[1], 0.1), rtol=0, atol=1e-15)
    np.testing.assert_allclose(w[0], fit_rbf(good, values[0], 0.1, cutoff=0.0), atol=1e-12)
    assert np.abs(w[1]).max() < 1.0  # the near-coincident pair is not inverted


def _fixed_centre_case(
    rng: np.random.Generator, n_frames: int, missing_rate: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Three systems of 32 lattice centres, values and random masks over the frames."""
    c = np.stack([_grid_points(rng, 32) for _ in range(3)])  # (P, K, 3)
    sigma = np.array([dilation_from_spacing(x) for x in c])
    values = 0.003 * rng.normal(size=(n_frames, 3, 32, 3))
    mask = rng.random((n_frames, 3, 32)) >= missing_rate
    return c, values, sigma, mask


def test_fixed_centres_equal_fit_rbf_on_every_frame_of_random_masks() -> None:
    """The downdated inverse gives fit_rbf's weights frame by frame (~1e-9 relative)."""
    rng = np.random.default_rng(11)
    c, values, sigma, mask = _fixed_centre_case(rng, 40, 0.08)
    mask[0] = True  # nothing missing
    values[5, 1, 7] = np.nan  # a non-finite value: excluded like a masked centre
    got = fit_rbf_fixed_centres(c, values, sigma, mask)
    want = fit_rbf(c[None], values, sigma[None], mask)
    assert got.shape == want.shape == values.shape
    scale = np.abs(want).max(axis=(-1, -2), keepdims=True)
    assert (np.abs(got - want) <= 1e-9 * scale).all()
    assert (got[~mask] == 0).all() and (got[5, 1, 7] == 0).all()
    # the weights interpolate the present values at the present centres
    fitted = evaluate_rbf(c[None], got, sigma[None], c[None])
    used = mask & np.isfinite(values).all(-1)
    np.testing.assert_allclose(fitted[used], values[used], atol=1e-10)


def test_fixed_centres_hand_what_they_cannot_downdate_to_fit_rbf() -> None:
    """Too many missing, a near-singular full matrix, a bad σ, a padding (NaN) centre:
    each gets what fit_rbf gives it."""
    rng = np.random.default_rng(12)
    c, values, sigma, mask = _fixed_centre_case(rng, 6, 0.0)
    mask[1, 0, :20] = False  # over a quarter missing: refitted
    c[1, 3] = c[1, 4] + 1e-10  # near-coincident pair: the full matrix fails the test
    sigma[2] = np.nan  # no field
    c[0, 31] = np.nan  # a padding slot
    got = fit_rbf_fixed_centres(c, values, sigma, mask)
    want = fit_rbf(c[None], values, sigma[None], mask)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    assert np.abs(got[:, 1]).max() < 1.0  # the near-coincident pair is not inverted
    assert (got[:, 2] == 0).all() and (got[:, 0, 31] == 0).all()
    # a downdate limit of 0 refits every frame with a missing centre: the same weights
    mask[2:, :, 5] = False
    np.testing.assert_allclose(
        fit_rbf_fixed_centres(c, values, sigma, mask, max_missing_share=0.0),
        fit_rbf_fixed_centres(c, values, sigma, mask),
        rtol=0,
        atol=1e-9 * np.abs(want).max(),
    )


def test_fixed_centres_refuse_bad_arguments() -> None:
    with pytest.raises(ValidationError, match="same K"):
        fit_rbf_fixed_centres(np.zeros((4, 3)), np.zeros((2, 5, 3)), 0.1)
    with pytest.raises(ValidationError, match="same K"):
        fit_rbf_fixed_centres(np.zeros((4, 3)), np.zeros((4, 3)), 0.1)  # no frame axis
    with pytest.raises(ValidationError, match="max_missing_share"):
        fit_rbf_fixed_centres(np.zeros((4, 3)), np.zeros((2, 4, 3)), 0.1, max_missing_share=2)


def _lattice(rng: np.random.Generator) -> np.ndarray:
    """90 centres of a jittered 6 x 5 x 3 lattice, 4 cm apart (a part's markers)."""
    g = np.stack(np.meshgrid(np.arange(6), np.arange(5), np.arange(3), indexing="ij"), -1)
    g = g.reshape(-1, 3).astype(float)
    return 0.04 * g + 0.006 * rng.normal(size=g.shape)


def _bulge(c: np.ndarray) -> np.ndarray:
    """A smooth 2 cm bulge along z over the centres (a residual soft tissue leaves)."""
    return 0.02 * np.exp(-((c - c.mean(0)) ** 2).sum(1) / 0.01)[:, None] * np.array([0, 0, 1.0])


def _indefinite_sigma(c: np.ndarray) -> float:
    """A σ just past where the kernel matrix's smallest eigenvalue crosses zero.

    The radial cubic B-spline is not positive definite in 3-D: as σ widens against the
    spacing an eigenvalue passes through zero (|λ| ~1e-6 of the largest here, kept by
    fit_rbf's cutoff), which is what the σ rule gives an irregular part.
    """

    def smallest(sigma: float) -> float:
        phi = evaluate_rbf(c, np.eye(len(c)), sigma, c)  # the kernel matrix
        return float(np.linalg.eigvalsh(phi)[0])

    grid = np.linspace(0.08, 0.3, 45)
    values = [smallest(x) for x in grid]
    i = next(i for i in range(len(grid) - 1) if values[i] > 0 > values[i + 1])
    return float(brentq(smallest, grid[i], grid[i + 1])) * (1 + 1e-4)


def test_ridge_zero_is_the_exact_fit() -> None:
    rng = np.random.default_rng(30)
    c = np.stack([_grid_points(rng, 32) for _ in range(3)])
    values = 0.003 * rng.normal(size=(4, 3, 32, 3))
    mask = rng.random((4, 3, 32)) > 0.1
    sigma = np.array([dilation_from_spacing(x) for x in c])
    sigma[2] = np.nan  # no field: zero weights in both
    want = fit_rbf(c[None], values, sigma[None], mask)
    got = fit_rbf_ridge(c[None], values, sigma[None], mask, ridge=0.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max())
    assert (got[~mask] == 0).all() and (got[:, 2] == 0).all()


def test_ridge_fit_stays_bounded_where_exact_interpolation_explodes() -> None:
    """The demo's failure in miniature: a kernel matrix with an eigenvalue near zero.
    Exact interpolation of a 2 cm residual swings the field by metres between its
    centres; the GCV-chosen ridge keeps it within the residuals' size and near them."""
    rng = np.random.default_rng(31)
    c = _lattice(rng)
    sigma = _indefinite_sigma(c)
    values = _bulge(c) + 0.001 * rng.normal(size=c.shape)
    size = np.abs(values).max()
    probe = c.min(0) + (c.max(0) - c.min(0)) * rng.random((4000, 3))  # between the centres
    exact = evaluate_rbf(c, fit_rbf(c, values, sigma), sigma, probe)
    assert np.abs(exact).max() > 20 * size  # measured: 0.91 m from 1.9 cm
    rho = choose_ridge_gcv(c[None], values[None], sigma)
    assert rho.shape == () and RIDGE_GRID[0] < rho < 1.0
    w = fit_rbf_ridge(c, values, sigma, ridge=rho)
    assert np.abs(evaluate_rbf(c, w, sigma, probe)).max() < 1.1 * size  # measured: 1.03
    # near its centres: within the noise and some of the bulge (measured 2.7 mm)
    assert np.abs(evaluate_rbf(c, w, sigma, c) - values).max() < 0.25 * size


def test_gcv_keeps_a_smooth_field_almost_interpolated() -> None:
    """Smooth values on a well-conditioned lattice: a small ridge, the centres matched
    to a small fraction of the values; the same values plus noise: a larger ridge."""
    rng = np.random.default_rng(32)
    c = _lattice(rng)
    sigma = dilation_from_spacing(c)
    smooth = _bulge(c)
    rho = choose_ridge_gcv(c[None], smooth[None], sigma)
    w = fit_rbf_ridge(c, smooth, sigma, ridge=rho)  # measured: ρ 5.6e-4, 0.5 % off
    assert np.abs(evaluate_rbf(c, w, sigma, c) - smooth).max() < 0.02 * np.abs(smooth).max()
    noisy = smooth + 0.002 * rng.normal(size=c.shape)
    assert choose_ridge_gcv(c[None], noisy[None], sigma) > rho


def test_gcv_pools_the_frames_of_each_system_and_respects_masks() -> None:
    rng = np.random.default_rng(33)
    c = np.stack([_lattice(rng), _lattice(rng)])  # two systems, (2, K, 3)
    sigma = np.array([dilation_from_spacing(x) for x in c])
    values = np.stack([np.stack([_bulge(x) for x in c])] * 3)  # (3 frames, 2, K, 3)
    values[:, 1] += 0.002 * rng.normal(size=values[:, 1].shape)  # noise on system 1 only
    rho = choose_ridge_gcv(c[None], values, sigma)
    assert rho.shape == (2,) and rho[1] > rho[0]
    # a frame whose values are all zero scores as nothing; a masked centre as absent
    with_zero = np.concatenate([values, np.zeros_like(values[:1])])
    np.testing.assert_allclose(choose_ridge_gcv(c[None], with_zero, sigma), rho)
    mask = np.ones(values.shape[:-1], dtype=bool)
    mask[1, 0, 4] = False
    nan = values.copy()
    nan[1, 0, 4] = np.nan
    np.testing.assert_allclose(
        choose_ridge_gcv(c[None], values, sigma, mask), choose_ridge_gcv(c[None], nan, sigma)
    )
    # moving centres, one set per frame, as the quadratic variants fit them
    moving = np.broadcast_to(c, (3, *c.shape))
    np.testing.assert_allclose(choose_ridge_gcv(moving, values, sigma), rho)


def test_ridge_functions_refuse_bad_arguments() -> None:
    c, v = np.zeros((4, 3)), np.zeros((4, 3))
    with pytest.raises(ValidationError, match="ridge"):
        fit_rbf_ridge(c, v, 0.1, ridge=-1.0)
    with pytest.raises(ValidationError, match="same K"):
        fit_rbf_ridge(c, np.zeros((5, 3)), 0.1, ridge=0.0)
    with pytest.raises(ValidationError, match="T or 1"):
        choose_ridge_gcv(c, v, 0.1)  # no frame axis
    with pytest.raises(ValidationError, match="grid"):
        choose_ridge_gcv(c[None], v[None], 0.1, grid=np.array([]))


def test_ridge_fit_with_fixed_centres_equals_frame_by_frame_fits() -> None:
    """Centres shared by every frame: the frames with all their centres share one
    operator per system; those with some missing are fitted alone. Same weights."""
    rng = np.random.default_rng(34)
    c, values, sigma, mask = _fixed_centre_case(rng, 20, 0.05)
    mask[:4] = True  # frames with every centre: the shared operator
    c[2, 30:] = np.nan  # padding slots of a smaller system
    for ridge in (0.0, 1e-5, np.array([1e-6, 1e-3, 0.0])):
        got = fit_rbf_ridge(c[None], values, sigma, mask, ridge=ridge)
        want = np.stack(
            [fit_rbf_ridge(c, values[t], sigma, mask[t], ridge=ridge) for t in range(20)]
        )
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
        assert (got[~mask] == 0).all() and (got[:, 2, 30:] == 0).all()


def _moving_case(rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Centres that move every frame (as the quadratic variants' do), three systems,
    random masks, one system without σ, one with a padding slot."""
    c = np.stack([_grid_points(rng, 32) for _ in range(3)])  # (P, K, 3)
    sigma = np.array([dilation_from_spacing(x) for x in c])
    moving = c[None] + 0.004 * rng.normal(size=(12, *c.shape))  # (T, P, K, 3)
    moving[:, 0, 31] = np.nan  # a padding slot
    sigma[2] = np.nan  # no field
    values = 0.003 * rng.normal(size=moving.shape)
    mask = rng.random(moving.shape[:-1]) > 0.1
    return moving, values, sigma, mask


def test_kernel_scale_is_the_largest_eigenvalue_of_each_masked_matrix() -> None:
    rng = np.random.default_rng(35)
    moving, _, sigma, mask = _moving_case(rng)
    got = rbf_kernel_scale(moving, sigma, mask)
    assert got.shape == (12, 3) and np.isnan(got[:, 2]).all()
    for t, p in ((0, 0), (7, 1)):
        use = mask[t, p] & np.isfinite(moving[t, p]).all(-1)
        c = moving[t, p, use]
        phi = evaluate_rbf(c, np.eye(len(c)), sigma[p], c)  # the kernel matrix
        assert got[t, p] == pytest.approx(np.abs(np.linalg.eigvalsh(phi)).max(), rel=1e-12)
    assert np.isnan(rbf_kernel_scale(np.zeros((2, 0, 3)), 1.0)).all()  # no centre slot


def test_ridge_fit_with_a_given_scale_equals_the_eigen_fit() -> None:
    """Given each system's own max|λ|, the shifted complex solve (no eigen-decomposition)
    gives the eigen-decomposition's weights to rounding, for moving and fixed centres;
    ρ = 0 systems stay exact interpolation."""
    rng = np.random.default_rng(36)
    moving, values, sigma, mask = _moving_case(rng)
    own = rbf_kernel_scale(moving, sigma, mask)
    for ridge in (1e-6, 1e-3, np.array([1e-6, 0.0, 1e-4])):
        want = fit_rbf_ridge(moving, values, sigma, mask, ridge=ridge)
        got = fit_rbf_ridge(moving, values, sigma, mask, ridge=ridge, kernel_scale=own)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
        assert (got[~mask] == 0).all() and (got[:, 2] == 0).all() and (got[:, 0, 31] == 0).all()
    # fixed centres: the frames with every centre share one operator; a scale that is
    # the same every frame keeps it
    c = moving[0]
    rest = rbf_kernel_scale(c, sigma)
    mask[:4] = True
    got = fit_rbf_ridge(c[None], values, sigma, mask, ridge=1e-5, kernel_scale=rest)
    want = np.stack(
        [
            fit_rbf_ridge(c, values[t], sigma, mask[t], ridge=1e-5, kernel_scale=rest)
            for t in range(12)
        ]
    )
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(  # the frames with every centre: their own scale is `rest`
        got[:4],
        fit_rbf_ridge(c[None], values[:4], sigma, ridge=1e-5),
        atol=1e-12 * np.abs(want).max(),
    )


def test_a_given_scale_sets_the_ridge_and_bounds_a_null_mode() -> None:
    """μ = ρ scale²: a scale twice the matrix's own is the fit with 4 ρ. Coincident
    centres (a null mode the eigen fit leaves out by its cutoff) get bounded weights
    that still pass near the values."""
    rng = np.random.default_rng(37)
    c = _lattice(rng)
    sigma = dilation_from_spacing(c)
    values = _bulge(c) + 0.001 * rng.normal(size=c.shape)
    own = rbf_kernel_scale(c, sigma)
    got = fit_rbf_ridge(c, values, sigma, ridge=1e-4, kernel_scale=2.0 * own)
    want = fit_rbf_ridge(c, values, sigma, ridge=4e-4)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    twin = np.concatenate([c, c[:1]])  # centre 0 twice
    doubled = np.concatenate([values, values[:1]])
    w = fit_rbf_ridge(twin, doubled, sigma, ridge=1e-6, kernel_scale=own)
    mu_bound = 1.0 / (2.0 * np.sqrt(1e-6) * own)  # the largest gain of any mode
    assert np.abs(w).max() <= mu_bound * np.linalg.norm(doubled, axis=0).max()
    np.testing.assert_allclose(w[0], w[-1], atol=1e-12)  # the twins share their weight
    fitted = evaluate_rbf(twin, w, sigma, twin)
    assert np.abs(fitted - doubled).max() < 0.05 * np.abs(values).max()


def test_gcv_with_a_given_scale_chooses_for_that_ridge() -> None:
    rng = np.random.default_rng(38)
    c = np.stack([_lattice(rng), _lattice(rng)])
    sigma = np.array([dilation_from_spacing(x) for x in c])
    values = np.stack([np.stack([_bulge(x) for x in c])] * 2)
    values[:, 1] += 0.002 * rng.normal(size=values[:, 1].shape)
    own = rbf_kernel_scale(c, sigma)
    rho = choose_ridge_gcv(c[None], values, sigma)
    np.testing.assert_allclose(choose_ridge_gcv(c[None], values, sigma, kernel_scale=own), rho)
    # a scale 10x the own one: the same μ is a ρ 100x smaller (the grid has 4 a decade;
    # the smooth system's ρ was near the grid's floor, where it stops)
    shifted = choose_ridge_gcv(c[None], values, sigma, kernel_scale=10.0 * own)
    np.testing.assert_allclose(shifted, np.maximum(rho / 100.0, RIDGE_GRID[0]), rtol=1e-9)


def test_nested_ridge_fits_equal_two_plain_fits() -> None:
    """The inner field's matrix taken from the outer one's: the same weights as two
    fit_rbf_ridge calls, for moving centres (shared matrix), fixed centres and ρ = 0
    (the plain fits), with an inner mask narrower than the outer one."""
    rng = np.random.default_rng(39)
    moving, values, sigma, mask = _moving_case(rng)
    inner = mask[..., :20] & (rng.random(mask[..., :20].shape) > 0.2)
    scale = np.stack(
        [rbf_kernel_scale(moving[0], sigma), rbf_kernel_scale(moving[0, :, :20], sigma)]
    )
    for centres, ridge in (
        (moving, np.array([[1e-6, 1e-3, 1e-5], [1e-4, 1e-6, 1e-6]])),
        (moving[:1], np.full((2, 3), 1e-5)),
        (moving, np.array([[1e-6, 0.0, 1e-5], [1e-6, 1e-6, 1e-6]])),
    ):
        got, got_in = fit_rbf_ridge_nested(
            centres, values, sigma, mask, inner, ridge=ridge, kernel_scale=scale
        )
        want = fit_rbf_ridge(centres, values, sigma, mask, ridge=ridge[0], kernel_scale=scale[0])
        want_in = fit_rbf_ridge(
            centres[..., :20, :], values[..., :20, :], sigma, inner,
            ridge=ridge[1], kernel_scale=scale[1],
        )  # fmt: skip
        assert got.shape == values.shape and got_in.shape == values[..., :20, :].shape
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * np.abs(want).max())
        np.testing.assert_allclose(got_in, want_in, rtol=0, atol=1e-13 * np.abs(want_in).max())
        assert (got_in[~inner] == 0).all()
    with pytest.raises(ValidationError, match="leading axis of 2"):
        fit_rbf_ridge_nested(moving, values, sigma, mask, inner, ridge=ridge[0], kernel_scale=scale)
