"""Gap filling by interpolation in time: linear, PCHIP and not-a-knot cubic spline.

The baselines of :mod:`skincap.cleanup.fill` (methods ``linear``, ``pchip``,
``spline``): each trajectory is interpolated through its own present samples, so only
interior gaps (a present sample on both sides) are filled. Measured samples are never
changed.
"""

from __future__ import annotations

import numpy as np

__all__ = ["fill_linear", "fill_pchip", "fill_spline", "previous_next_present"]


def previous_next_present(present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the last present frame <= t and the first present frame >= t (-1 / T)."""
    t, n = present.shape
    frame = np.arange(t)[:, None]
    prev = np.maximum.accumulate(np.where(present, frame, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(present, frame, t)[::-1], axis=0)[::-1]
    return prev, nxt


def fill_linear(positions: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Linear interpolation in time across ``target`` samples (interior gaps).

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Missing samples to fill; a target without a present sample on both sides
        stays NaN.

    Returns
    -------
    (T, N, 3) float64 : a filled copy.
    """
    p = np.array(positions, dtype=np.float64)
    present = ~np.isnan(p[..., 0])
    prev, nxt = previous_next_present(present)
    t = p.shape[0]
    ok = target & (prev >= 0) & (nxt < t)
    tt, nn = np.nonzero(ok)
    a, b = prev[tt, nn], nxt[tt, nn]
    w = ((tt - a) / (b - a))[:, None]
    p[tt, nn] = (1 - w) * p[a, nn] + w * p[b, nn]
    return p


def _fill_scipy(positions: np.ndarray, target: np.ndarray, kind: str) -> np.ndarray:
    from scipy.interpolate import CubicSpline, PchipInterpolator

    p = np.array(positions, dtype=np.float64)
    present = ~np.isnan(p[..., 0])
    prev, nxt = previous_next_present(present)
    t = p.shape[0]
    ok = target & (prev >= 0) & (nxt < t)
    frames = np.arange(t)
    for n in np.nonzero(ok.any(axis=0))[0]:  # loop over markers; work over frames
        known = present[:, n]
        if known.sum() < 2:
            continue
        if kind == "pchip":
            f = PchipInterpolator(frames[known], p[known, n], axis=0)
        else:
            f = CubicSpline(frames[known], p[known, n], axis=0)
        rows = np.nonzero(ok[:, n])[0]
        p[rows, n] = f(rows)
    return p


def fill_pchip(positions: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Monotone cubic (scipy PCHIP) interpolation in time; same contract as
    :func:`fill_linear`."""
    return _fill_scipy(positions, target, "pchip")


def fill_spline(positions: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Not-a-knot cubic spline through all present samples of each trajectory (scipy
    ``CubicSpline``); same contract as :func:`fill_linear`."""
    return _fill_scipy(positions, target, "spline")
