"""The vectorised running median and Δ⁴ smoother against plain per-sample loops."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.cleanup.robust_stats import running_median
from skincap.cleanup.smooth import smooth_trajectories


def _runs(valid: np.ndarray) -> list[tuple[int, int]]:
    """[start, end] (inclusive) of each run of True."""
    out, t = [], 0
    while t < valid.size:
        if valid[t]:
            s = t
            while t + 1 < valid.size and valid[t + 1]:
                t += 1
            out.append((s, t))
        t += 1
    return out


def _value(x: np.ndarray, s: int, e: int, j: int) -> np.ndarray:
    """x[j] inside the run [s, e], its odd reflection past either end (index clipped)."""
    if s <= j <= e:
        return x[j]
    anchor = s if j < s else e
    return 2 * x[anchor] - x[min(max(2 * anchor - j, s), e)]


def _naive_median(p: np.ndarray, window: int) -> np.ndarray:
    out = np.full_like(p, np.nan)
    half = window // 2
    for c in range(p.shape[1]):
        for s, e in _runs(~np.isnan(p[:, c, 0])):
            for t in range(s, e + 1):
                win = np.stack([_value(p[:, c], s, e, t + k) for k in range(-half, half + 1)])
                out[t, c] = np.sort(win, axis=0)[half]  # NaN sorts last, as in a partition
    return out


@pytest.mark.parametrize("window", [3, 9, 11])
def test_running_median_matches_the_per_sample_window(window: int) -> None:
    rng = np.random.default_rng(window)
    p = rng.normal(0.0, 1.0, (40, 7, 3)).cumsum(axis=0)
    p[rng.random((40, 7)) < 0.15] = np.nan  # runs of every length, 1 frame included
    p[:, 3] = np.nan  # a column never present
    p[5:9, 5] = p[5, 5]  # ties
    np.testing.assert_array_equal(running_median(p, window), _naive_median(p, window))


def _naive_smooth(x: np.ndarray, lam: float, iterations: int, mask: np.ndarray) -> np.ndarray:
    out = x.copy()
    for c in range(x.shape[1]):
        for s, e in _runs(~np.isnan(x[:, c, 0])):
            if e - s + 1 < 5:
                continue
            z = x[s : e + 1, c].copy()
            for _ in range(iterations):
                d4 = 6.0 * z
                for k, w in ((-2, 1.0), (-1, -4.0), (1, -4.0), (2, 1.0)):
                    d4 = d4 + w * np.stack([_value(z, 0, e - s, f + k) for f in range(e - s + 1)])
                z = np.where(mask[s : e + 1, c, None], z - lam * d4, z)
            out[s : e + 1, c] = z
    return out


@pytest.mark.parametrize("order", ["C", "F"])
def test_smooth_trajectories_matches_the_per_run_filter(order: str) -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(0.0, 1.0, (60, 6, 3)).cumsum(axis=0)
    x[rng.random((60, 6)) < 0.1] = np.nan
    x[:2, 0] = np.nan
    mask = rng.random((60, 6)) < 0.8
    x = np.asarray(x, order=order)
    got = smooth_trajectories(x, lam=0.05, iterations=4, mask=mask)
    np.testing.assert_allclose(got, _naive_smooth(x, 0.05, 4, mask), rtol=0, atol=1e-12)
