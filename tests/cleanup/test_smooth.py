from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.cleanup.neighbours import motion_neighbours
from skincap.cleanup.smooth import (
    butterworth_equivalent_cutoff,
    cutoff_frequency,
    frequency_response,
    lambda_for_cutoff,
    smooth_local,
    smooth_trajectories,
)
from skincap.errors import ValidationError


def _gain(freq, rate, lam, n, frames=2000):
    t = np.arange(frames)
    x = np.zeros((frames, 1, 3))
    x[:, 0, 0] = np.sin(2 * np.pi * freq * t / rate + 0.3)
    y = smooth_trajectories(x, lam=lam, iterations=n)[:, 0, 0]
    core = slice(200, frames - 200)  # away from the reflected ends
    basis = np.stack(
        [np.sin(2 * np.pi * freq * t / rate + 0.3), np.cos(2 * np.pi * freq * t / rate + 0.3)], 1
    )
    coef, *_ = np.linalg.lstsq(basis[core], y[core], rcond=None)
    return coef  # in-phase and quadrature gain


@pytest.mark.parametrize("freq", [1.0, 5.0, 12.0, 20.0, 35.0])
def test_measured_response_matches_formula(freq):
    rate, n = 120.0, 30
    lam = lambda_for_cutoff(12.0, rate, n)
    in_phase, quadrature = _gain(freq, rate, lam, n)
    assert in_phase == pytest.approx(
        float(frequency_response(freq, rate, lam=lam, iterations=n)), abs=1e-6
    )
    assert abs(quadrature) < 1e-6  # zero phase


def test_cutoff_round_trip_and_limits():
    for rate, fc, n in [(120.0, 12.0, 30), (240.0, 30.0, 10), (100.0, 6.0, 400)]:
        lam = lambda_for_cutoff(fc, rate, n)
        assert 0 < lam <= 0.125
        assert cutoff_frequency(lam, rate, n) == pytest.approx(fc, rel=1e-9)
        assert float(frequency_response(fc, rate, lam=lam, iterations=n)) == pytest.approx(2**-0.5)
    assert cutoff_frequency(0.02, 120.0, 10) == pytest.approx(23.22, abs=0.01)
    assert 0 < butterworth_equivalent_cutoff(0.02, 120.0, 10) < 60
    with pytest.raises(ValidationError, match="at least"):
        lambda_for_cutoff(6.0, 120.0, 10)
    with pytest.raises(ValidationError):
        smooth_trajectories(np.zeros((10, 1, 3)), lam=0.2, iterations=3)
    with pytest.raises(ValidationError):
        frequency_response(1.0, 100.0, lam=0.01, iterations=0)


def test_smoothing_keeps_lines_nan_and_mask():
    t = np.arange(60, dtype=float)
    x = np.stack([t, 2 * t, -t], 1)[:, None, :].repeat(2, 1)
    x[25:28, 0] = np.nan
    y = smooth_trajectories(x, lam=0.1, iterations=20)
    np.testing.assert_allclose(y, x, atol=1e-9, equal_nan=True)  # lines pass unchanged
    rng = np.random.default_rng(0)
    noisy = x + rng.normal(0, 1, x.shape)
    mask = np.ones((60, 2), bool)
    mask[:, 1] = False
    z = smooth_trajectories(noisy, lam=0.1, iterations=20, mask=mask)
    np.testing.assert_array_equal(z[:, 1], noisy[:, 1])
    assert np.isnan(z[25:28, 0]).all()
    assert np.nanstd(z[:, 0] - x[:, 0]) < 0.6 * np.nanstd(noisy[:, 0] - x[:, 0])


def _moving_body(frames=300, n=30, seed=0):
    rng = np.random.default_rng(seed)
    local = rng.normal(0, 0.1, (n, 3))
    t = np.arange(frames) / 120.0
    rot = Rotation.from_rotvec(np.stack([3 * np.sin(2 * t), 4 * t, np.cos(3 * t)], 1)).as_matrix()
    return np.einsum("tij,nj->tni", rot, local) + np.stack([2 * t, np.sin(5 * t), t], 1)[:, None]


def test_local_smoothing_keeps_fast_rigid_motion_and_removes_noise():
    truth = _moving_body()
    nb = motion_neighbours(truth, k=6)
    out = smooth_local(truth, nb, lam=0.1, iterations=30)
    np.testing.assert_allclose(out, truth, atol=1e-9)  # rigid motion is untouched
    # a global filter with the same settings bends the fast rotation
    glob = smooth_trajectories(truth, lam=0.1, iterations=30)
    assert np.abs(glob - truth).max() > 2e-4  # measured 0.39 mm
    rng = np.random.default_rng(1)
    noisy = truth + rng.normal(0, 0.001, truth.shape)
    noisy[50:60, 3] = np.nan
    sm = smooth_local(noisy, nb, lam=0.1, iterations=30)
    assert np.isnan(sm[50:60, 3]).all()
    before = np.sqrt(np.nanmean((noisy - truth) ** 2))
    after = np.sqrt(np.nanmean((sm - truth) ** 2))
    assert after < 0.75 * before, (before, after)
    mask = np.zeros(truth.shape[:2], bool)
    np.testing.assert_array_equal(smooth_local(noisy, nb, mask=mask), noisy)
    # both smoothers refuse a mask of the wrong shape, naming it and both shapes
    bad = np.ones((truth.shape[0], truth.shape[1] + 1), bool)
    want = rf"mask: expected shape \({truth.shape[0]}, {truth.shape[1]}\), got \({bad.shape[0]}, {bad.shape[1]}\)"
    with pytest.raises(ValidationError, match=want):
        smooth_local(noisy, nb, mask=bad)
    with pytest.raises(ValidationError, match=want):
        smooth_trajectories(noisy, lam=0.1, iterations=30, mask=bad)
