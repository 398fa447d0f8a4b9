"""Fill and smooth the labelled markers without harming what was measured.

:func:`guarded_fill_smooth` is the middle of ``skincap clean`` (after merging):

1. **Label swaps** between neighbouring markers (:func:`~skincap.cleanup.outliers.find_label_swaps`)
   are exchanged back; the moved samples are flagged invented and counted as relabelled.
2. **Spikes** (:func:`~skincap.cleanup.outliers.find_spikes`) are removed; the hole
   filler replaces them like any other missing sample (flagged invented, counted as
   replaced outliers) or they stay missing (counted as unfilled).
3. **Filling** by :func:`~skincap.cleanup.fill.fill_gaps`.
4. **Smoothing** in local frames (:func:`~skincap.cleanup.smooth.smooth_local`) moves a
   measured sample by at most ``min(MAX_MOVE_NOISE σ, MAX_MOVE)``, σ the marker's
   measurement noise estimated from the take
   (:func:`~skincap.cleanup.outliers.measurement_noise`: a robust MAD of the residual
   against the cubic through the four neighbouring frames); its local frames drop an
   outlying neighbour, so nothing spreads.
5. **Continuity** (:func:`~skincap.cleanup.continuity.condition_fills`): every filled run
   joins its measured ends in value and slope, and a run whose second differences
   exceed ``ACCELERATION_FACTOR`` times the 99.9th percentile of the measured
   samples' is made smoother or, failing that, left unfilled and counted.

Every sample the result does not take from the input unchanged (up to the bounded
smoothing) is flagged ``invented``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.cleanup.continuity import condition_fills, measured_acceleration_limit
from skincap.cleanup.outliers import find_label_swaps, find_spikes, measurement_noise
from skincap.cleanup.settings import CleanSettings
from skincap.errors import SkincapWarning
from skincap.types import MarkerSet

__all__ = [
    "ACCELERATION_FACTOR",
    "MAX_MOVE",
    "MAX_MOVE_NOISE",
    "UNFILLED_WARNING",
    "GuardSummary",
    "GuardedFill",
    "guarded_fill_smooth",
]

#: Smoothing moves a measured sample by at most this multiple of its marker's noise σ ...
MAX_MOVE_NOISE = 3.0
#: ... and never more than this (metres).
MAX_MOVE = 0.0015
#: Filled samples keep their second difference within this multiple of the measured
#: samples' 99.9th percentile (below the 3x promised, for the C3D's storage rounding).
ACCELERATION_FACTOR = 2.5
#: Warn when more than this fraction of the markers' samples is left unfilled.
UNFILLED_WARNING = 0.01


@dataclass(frozen=True)
class GuardSummary:
    """Take-wide counts of :func:`guarded_fill_smooth` (the ``guard`` part of the clean report).

    Attributes
    ----------
    filled_samples, unfilled_samples : int
        Marker samples filled; left missing (after the continuity check).
    unfilled_warning : bool
        Whether more than :data:`UNFILLED_WARNING` of the samples are left unfilled.
    outlier_samples, outliers_replaced : int
        Spikes found (and removed); those of them filled again.
    relabelled_fragments : int
        Fragments merged into markers plus two per repaired label swap.
    label_swaps_repaired, relabelled_samples : int
        Label swaps exchanged back; samples they moved.
    largest_move_mm : float
        Largest move of a kept (unflagged) measured sample, mm.
    noise_median_mm : float or None
        Median of the markers' measurement noise σ, mm (None when none is known).
    """

    filled_samples: int
    unfilled_samples: int
    unfilled_warning: bool
    outlier_samples: int
    outliers_replaced: int
    relabelled_fragments: int
    label_swaps_repaired: int
    relabelled_samples: int
    largest_move_mm: float
    noise_median_mm: float | None


@dataclass
class GuardedFill:
    """The filled and smoothed markers and what was done to every sample.

    Attributes
    ----------
    positions : (T, N, 3) float64, metres; NaN where left unfilled
    invented : (T, N) bool
        Every sample not measured as it stands: fills, replaced spikes, swapped-back
        samples, and what the input already flagged.
    residuals : (T, N) float64 or None
        The input's residuals, following swapped samples.
    camera_masks : (T, N) uint8 or None
        The input's camera masks, following swapped samples.
    labels : N str
    holes : int
        Missing samples before filling (spikes included).
    filled, unfilled, outliers, relabelled, dropped : (T, N) bool
        Samples filled; left missing; found as spikes (removed); exchanged back from
        a label swap; filled then dropped as unstable (and so unfilled).
    moved : (T, N) float64, metres
        How far each unflagged measured sample moved (NaN elsewhere).
    noise : (N,) float64, metres
        Each marker's estimated measurement noise σ.
    swaps : int
        Label swaps repaired (one per pair and swapped run).
    limit_mm : float or None
        The second-difference bound on fills, mm per frame².
    """

    positions: np.ndarray
    invented: np.ndarray
    residuals: np.ndarray | None
    camera_masks: np.ndarray | None
    labels: list[str]
    holes: int
    filled: np.ndarray
    unfilled: np.ndarray
    outliers: np.ndarray
    relabelled: np.ndarray
    dropped: np.ndarray
    moved: np.ndarray
    noise: np.ndarray
    swaps: int
    limit_mm: float | None

    @property
    def counts(self) -> dict[str, Any]:
        total = self.unfilled.size
        return {
            "filled": int(self.filled.sum()),
            "unfilled": int(self.unfilled.sum()),
            "unfilled_fraction": float(self.unfilled.sum() / total) if total else 0.0,
            "dropped": int(self.dropped.sum()),
        }

    def largest_move_mm(self) -> float:
        return float(1000 * np.nanmax(self.moved)) if np.isfinite(self.moved).any() else 0.0

    def summary(self, merged_fragments: int) -> GuardSummary:
        """Take-wide counts: what ``clean`` prints and ``--json`` gives."""
        return GuardSummary(
            filled_samples=int(self.filled.sum()),
            unfilled_samples=int(self.unfilled.sum()),
            unfilled_warning=bool(self.unfilled.sum() > UNFILLED_WARNING * self.unfilled.size),
            outlier_samples=int(self.outliers.sum()),
            outliers_replaced=int((self.outliers & self.filled).sum()),
            relabelled_fragments=int(merged_fragments + 2 * self.swaps),
            label_swaps_repaired=int(self.swaps),
            relabelled_samples=int(self.relabelled.sum()),
            largest_move_mm=self.largest_move_mm(),
            noise_median_mm=(
                float(1000 * np.median(self.noise[np.isfinite(self.noise)]))
                if np.isfinite(self.noise).any()
                else None
            ),
        )

    def per_marker(self) -> dict[str, dict[str, Any]]:
        """Per marker: filled, unfilled, replaced outliers, relabelled, largest move."""
        moved = np.where(np.isfinite(self.moved), self.moved, -1.0).max(axis=0)
        out: dict[str, dict[str, Any]] = {}
        for c, lab in enumerate(self.labels):
            out[lab] = {
                "filled": int(self.filled[:, c].sum()),
                "unfilled": int(self.unfilled[:, c].sum()),
                "outliers": int(self.outliers[:, c].sum()),
                "outliers_replaced": int((self.outliers[:, c] & self.filled[:, c]).sum()),
                "relabelled": int(self.relabelled[:, c].sum()),
                "largest_move_mm": float(1000 * moved[c]) if moved[c] >= 0 else None,
                "noise_mm": float(1000 * self.noise[c]) if np.isfinite(self.noise[c]) else None,
            }
        return out


def _noise_bound(noise: np.ndarray) -> np.ndarray:
    """(N,) metres: how far smoothing may move each marker's measured samples."""
    sigma = noise.copy()
    known = np.isfinite(sigma)
    # a marker too short to estimate takes the take's median noise (0 if none known)
    sigma[~known] = np.median(sigma[known]) if known.any() else 0.0
    return np.minimum(MAX_MOVE_NOISE * sigma, MAX_MOVE)


def guarded_fill_smooth(
    body: MarkerSet,
    neighbours: Any,
    settings: CleanSettings = CleanSettings(),
    *,
    removed: np.ndarray | None = None,
    progress: Progress | None = None,
) -> GuardedFill:
    """Repair swaps, remove spikes, fill, smooth within the noise and keep fills continuous.

    Parameters
    ----------
    body : MarkerSet
        The marker columns after merging, positions (T, N, 3) metres, NaN where missing;
        ``invented`` (if any) marks samples an earlier cleanup made up: they are kept
        as they are and never counted as measured.
    neighbours : MarkerSurface or CSR (offsets, indices)
    settings : CleanSettings
        ``repair_swaps`` and ``remove_spikes`` (steps 1 and 2 of the module
        docstring), ``fill`` (:func:`skincap.cleanup.fill.fill_gaps`) and ``smooth``
        (:func:`skincap.cleanup.smooth.smooth_local`); the merge settings are not used.
    removed : (T, N) bool, optional
        Samples the caller already took out of ``body`` as outliers (NaN there, e.g.
        :func:`skincap.cleanup.off_body.off_body_leaps`): counted and filled as the
        spikes step 2 removes.
    progress : callable(fraction, label), optional

    Returns
    -------
    GuardedFill
    """
    from skincap.cleanup.fill import fill_gaps
    from skincap.cleanup.smooth import smooth_local

    p0 = np.array(body.positions, dtype=np.float64)
    t, n, _ = p0.shape
    prior = (
        np.zeros((t, n), dtype=bool) if body.invented is None else np.asarray(body.invented, bool)
    )
    present0 = ~np.isnan(p0[..., 0])
    measured = present0 & ~prior
    pos = p0.copy()
    res = None if body.residuals is None else np.array(body.residuals, dtype=np.float64)
    cam = None if body.camera_masks is None else np.array(body.camera_masks)
    relabelled = np.zeros((t, n), dtype=bool)
    swaps = []
    if settings.repair_swaps and n >= 2:
        swaps = find_label_swaps(pos, neighbours, candidates=measured)
        for i, j, frames in swaps:
            pos[frames, i], pos[frames, j] = p0[frames, j], p0[frames, i]
            if res is not None:
                res[frames, i], res[frames, j] = (
                    body.residuals[frames, j],
                    body.residuals[frames, i],
                )
            if cam is not None and body.camera_masks is not None:
                cam[frames, i], cam[frames, j] = (
                    body.camera_masks[frames, j],
                    body.camera_masks[frames, i],
                )
            relabelled[frames, i] = ~np.isnan(pos[frames, i, 0])
            relabelled[frames, j] = ~np.isnan(pos[frames, j, 0])
        # a swapped-in sample is measured data, not the column's own
        measured = ~np.isnan(pos[..., 0]) & ~prior & ~relabelled
    outliers = np.zeros((t, n), dtype=bool)
    if removed is not None:
        outliers |= np.asarray(removed, dtype=bool) & np.isnan(p0[..., 0])
    if settings.remove_spikes:
        spikes = find_spikes(pos, neighbours, candidates=measured)
        pos[spikes] = np.nan
        measured &= ~spikes
        outliers |= spikes
    holes = int(np.isnan(pos[..., 0]).sum())
    work = MarkerSet(positions=pos, labels=list(body.labels), rate=body.rate, meta=body.meta)
    with warnings.catch_warnings():
        # the final unfilled count (after continuity) is what the caller reports
        warnings.simplefilter("ignore", SkincapWarning)
        filled_pos, fill_mask = fill_gaps(
            work, settings.fill, neighbours=neighbours, progress=progress
        )
    noise = measurement_noise(np.where(measured[..., None], pos, np.nan))
    if settings.smooth.enabled:
        filled_pos = smooth_local(
            filled_pos,
            neighbours,
            lam=settings.smooth.lam,
            iterations=settings.smooth.iterations,
            mask=measured,
            max_move=_noise_bound(noise),
        )
    # at least 1 µm/frame²: a take that never moves still lets a fill hold still
    limit = max(measured_acceleration_limit(filled_pos, measured, factor=ACCELERATION_FACTOR), 1e-6)
    final, dropped = condition_fills(filled_pos, fill_mask, limit=limit)
    filled = fill_mask & ~dropped
    unfilled = np.isnan(final[..., 0])
    invented = filled | relabelled | (prior & ~unfilled)
    moved = np.where(measured, np.linalg.norm(final - pos, axis=-1), np.nan)
    result = GuardedFill(
        positions=final,
        invented=invented,
        residuals=res,
        camera_masks=cam,
        labels=[str(lab) for lab in body.labels],
        holes=holes,
        filled=filled,
        unfilled=unfilled,
        outliers=outliers,
        relabelled=relabelled,
        dropped=dropped,
        moved=moved,
        noise=noise,
        swaps=len(swaps),
        limit_mm=float(1000 * limit) if np.isfinite(limit) else None,
    )
    if unfilled.sum() > UNFILLED_WARNING * unfilled.size:
        warnings.warn(
            f"clean: {int(unfilled.sum())} of {unfilled.size} marker samples "
            f"({100 * unfilled.sum() / unfilled.size:.1f} %) left unfilled: no trustworthy "
            "fill there (too few neighbours, or no fill stayed continuous and within the "
            "take's accelerations)",
            SkincapWarning,
            stacklevel=3,
        )
    return result
