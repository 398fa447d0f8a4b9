"""Samples too far from the rest of the body to be on the performer.

A corrupt value or a ghost kilometres away cannot be a marker on the subject; one such
sample in an average (a calibration's, a pair distance's spread) outweighs the whole
take. :func:`off_body_samples` finds them before any model exists, from the markers of
each frame alone; ``skincap solve`` leaves them out of the fit and ``skincap clean``
replaces them like any other outlier.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError

__all__ = ["MIN_MARKERS_FOR_CENTRE", "OFF_BODY_REACH_M", "off_body_samples"]

#: How much farther than its usual distance from the body's centre a marker may be seen
#: (metres): a limb swings a marker by well under a metre about that distance.
OFF_BODY_REACH_M = 1.0
#: Fewest markers a frame must see for its centre (their median) to be trusted.
MIN_MARKERS_FOR_CENTRE = 3


def off_body_samples(positions: np.ndarray, *, reach_m: float = OFF_BODY_REACH_M) -> np.ndarray:
    """(T, M) bool: samples too far from the rest of the body to be on the performer.

    The body's centre in a frame is the per-axis median of the markers it sees (a few
    wild samples cannot move it); a marker's usual distance from it is the median of
    that distance over the take. A sample farther than its usual distance plus
    ``reach_m`` is flagged. Frames that see fewer than three markers are not judged.

    Parameters
    ----------
    positions : (T, M, 3) float, metres, NaN where a marker is missing
    reach_m : float
        Metres beyond the marker's usual distance from the centre.

    Returns
    -------
    (T, M) bool, False wherever the marker is missing.
    """
    y = np.asarray(positions, dtype=np.float64)
    if y.ndim != 3 or y.shape[2] != 3:
        raise ValidationError(f"positions: expected (T, M, 3), got {y.shape}")
    seen = np.asarray(np.isfinite(y).all(axis=2))  # (T, M)
    judged = seen.sum(axis=1) >= MIN_MARKERS_FOR_CENTRE  # (T,)
    if not judged.any():
        return np.zeros(seen.shape, dtype=bool)
    masked = np.where(seen[..., None], y, np.nan)
    centre = np.full((y.shape[0], 3), np.nan)
    centre[judged] = np.nanmedian(masked[judged], axis=1)
    dist = np.linalg.norm(masked - centre[:, None, :], axis=2)  # (T, M), NaN unseen/unjudged
    usual = np.full(y.shape[1], np.nan)
    has = np.isfinite(dist).any(axis=0)
    usual[has] = np.nanmedian(dist[:, has], axis=0)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.isfinite(dist) & (dist > usual[None, :] + reach_m))
