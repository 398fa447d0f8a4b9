"""Samples that jump off their segment: a swapped label, a ghost taken for a marker.

A marker rides its segment, so its residual vector ``e_t = y_t - x_t`` (measured minus
model marker) changes slowly from frame to frame: skin slides, the fit shifts. When the
labeller swaps it with a neighbour for a few frames, ``e`` jumps by centimetres in one
frame and jumps back (or the marker drops out). Such a piece of the marker's track is
not the marker: fitted like one, it drags its whole segment away and the segment's
other markers end up centimetres off too (AML PronetoRun01, frames 1248-1251: the
shank's LSHPA jumps 78 mm in a frame while its neighbours move 31 mm; the shank's
three remaining markers sat 2.4-4.1 cm off).

:func:`jumped_samples` finds those pieces from the residuals alone, for any template
and any take: a piece is a run of frames where the marker is seen and ``e`` moves less
than ``jump_m`` per frame; a piece that begins or ends with a jump and whose mean
residual is well above the marker's own median (and above ``min_residual_m``) is
flagged. A marker whose residual is large all through the take (a model misfit, not a
swap) has no jump and is never flagged.

:func:`off_body_samples` runs before any model exists: a sample far beyond where its
marker usually sits relative to the rest of the body (a corrupt value, a ghost kilometres
away) cannot be on the performer. One such sample in a calibration's averages moves every
joint centre: a single CMU 85_02 sample set to 5 km took the solve's RMS residual from
under 1 cm to 68 cm.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.off_body import OFF_BODY_REACH_M, off_body_samples

__all__ = [
    "JUMP_M",
    "MIN_RESIDUAL_M",
    "OFF_BODY_REACH_M",
    "RESIDUAL_RATIO",
    "jumped_samples",
    "off_body_samples",
]

#: Least change of a marker's residual vector between consecutive frames that splits
#: its track (metres): skin and fit move it by millimetres per frame at capture rates.
JUMP_M = 0.02
#: A piece is flagged only when its mean residual exceeds this (metres)...
MIN_RESIDUAL_M = 0.02
#: ... and this multiple of the marker's median residual over the take.
RESIDUAL_RATIO = 3.0


def jumped_samples(
    measured: np.ndarray,
    fitted: np.ndarray,
    *,
    jump_m: float = JUMP_M,
    min_residual_m: float = MIN_RESIDUAL_M,
    ratio: float = RESIDUAL_RATIO,
) -> np.ndarray:
    """(T, M) bool: the samples of pieces of track that jumped off their model marker.

    Parameters
    ----------
    measured : (T, M, 3) float, metres, NaN where a marker is missing
    fitted : (T, M, 3) float, metres: the model's markers for the solved poses
    jump_m : float
        A change of the residual vector ``measured - fitted`` above this between two
        consecutive frames that both see the marker starts a new piece.
    min_residual_m, ratio : float
        A piece next to a jump is flagged when its mean residual is above
        ``min_residual_m`` and above ``ratio`` times the marker's median residual.

    Returns
    -------
    (T, M) bool, False wherever the marker is missing.
    """
    y = np.asarray(measured, dtype=np.float64)
    x = np.asarray(fitted, dtype=np.float64)
    if y.ndim != 3 or y.shape[2] != 3 or x.shape != y.shape:
        raise ValidationError(
            f"measured/fitted: expected two (T, M, 3) arrays, got {y.shape} and {x.shape}"
        )
    t, m, _ = y.shape
    seen = np.asarray(np.isfinite(y).all(axis=2) & np.isfinite(x).all(axis=2))  # (T, M)
    if t < 2 or not seen.any():
        return np.zeros((t, m), dtype=bool)
    e = np.where(seen[..., None], y - np.where(np.isfinite(x), x, 0.0), 0.0)
    resid = np.linalg.norm(e, axis=2)  # (T, M), 0 where unseen
    both = seen[1:] & seen[:-1]
    jump = np.zeros((t, m), dtype=bool)
    jump[1:] = both & (np.linalg.norm(e[1:] - e[:-1], axis=2) > jump_m)
    prev_seen = np.zeros((t, m), dtype=bool)
    prev_seen[1:] = seen[:-1]
    start = seen & (jump | ~prev_seen)  # (T, M): a piece begins
    # piece ids numbered column by column (transpose: frames vary fastest)
    ids = np.cumsum(start.T.ravel()).reshape(m, t).T - 1  # (T, M)
    n_pieces = int(start.sum())
    sel = ids[seen]
    length = np.bincount(sel, minlength=n_pieces)
    mean = np.bincount(sel, weights=resid[seen], minlength=n_pieces) / np.maximum(length, 1)
    next_to_jump = np.zeros(n_pieces, dtype=bool)
    next_to_jump[ids[jump]] = True  # begins with a jump
    ends_before = np.zeros((t, m), dtype=bool)
    ends_before[:-1] = jump[1:]
    next_to_jump[ids[ends_before & seen]] = True  # the next frame jumps away from it
    with np.errstate(invalid="ignore"):
        median = np.nanmedian(np.where(seen, resid, np.nan), axis=0)  # (M,)
    column = np.broadcast_to(np.arange(m), (t, m))[start]  # each piece's marker, in id order
    order = np.argsort(ids[start], kind="stable")
    column = column[order]
    bad = next_to_jump & (mean > min_residual_m) & (mean > ratio * median[column])
    return seen & bad[np.where(seen, ids, 0)]
