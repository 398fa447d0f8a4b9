"""Gap filling: local-PCA hole filling after Park & Hodgins (2006) §4.3, the two
improvements their discussion proposes, and the baselines it is measured against.

Every method has the same interface (:func:`fill_gaps`) and the same contract: it
returns the filled positions and a mask of the samples it invented; measured samples
are never changed.

Methods
-------
``local_pca`` (eqs. 4-5)
    For every marker ``i`` a *group* made of ``i`` and its neighbours. In every frame
    the group is expressed in a local frame: the rigid transform (Kabsch/Horn, eq. 5)
    that carries the group's reference shape (its Procrustes mean shape) onto the
    present members. A PCA of the local coordinates over the frames where the whole
    group is present keeps 99% of the variance. A missing member is estimated by
    choosing the PCA coefficients that best reproduce the present members (a least
    squares fit with a small PPCA prior on the coefficients so that few observations
    never make it ill-posed), mapped back through the local frame; the local frame is
    then refitted with the estimate and the fit repeated. Every group that contains a
    missing marker (its own and its neighbours') gives an estimate; they are averaged,
    as the paper does.
``local_pca_weighted``
    As ``local_pca``, but the estimates are averaged with weights: the inverse of the
    PCA model's predictive variance for the sample (which grows when few members were
    measured) and, following the paper's discussion, a lower weight for groups whose
    centre marker was itself estimated rather than measured.
``local_pca_missing``
    Both improvements of the discussion: the weighting above, and a PCA that tolerates
    missing data (EM / iterative least-squares imputation, after Shum et al. 1995), so
    the frames where a member is missing still train the model, and the reference
    shape is a Procrustes mean computed with missing members.
``local_pca_window`` (beyond the paper)
    One missing-data local-PCA model per gap, of the marker's own group only (no
    averaging over the neighbours' groups), trained on the frames within eight gap
    lengths of the gap, its local frame fitted with the members weighted by how
    rigidly they moved together there; joined to the measured ends like the other
    local methods (see :func:`fill_local_window`).
``linear``, ``pchip``, ``spline``
    Interpolation in time of each trajectory (linear; scipy's PCHIP; scipy's not-a-knot
    cubic spline). Interior gaps only.
``rigid``
    Vicon-style rigid-body fill from >= 3 donor markers: the donors' rigid motion from
    the last frame before the gap to each gap frame carries the marker along; the same
    from the first frame after the gap, the two blended linearly across the gap.
``rigid_weighted``
    The rigid fill with each donor weighted in the fit (weighted Kabsch) by how
    rigidly it moved with the marker within one gap length before and after the gap:
    ``1 / (var(distance) + (0.001 d)²)``, ``d`` the mean neighbour distance. Donors
    across a joint or a crease hardly count. Donors need only be seen at the gap's
    ends and in the frame being filled (a neighbour missing for part of the gap still
    serves where it is seen). The local methods blend with (and fall back to) this
    fill by default.
``pca``
    Whole-body PCA fill (Gløersen & Federolf 2016): PCA of all markers' normalised
    coordinates over the take, missing values reconstructed iteratively.

Nearly collinear neighbours (beyond the paper): where the members or donors seen in a
frame lie nearly on a line, the rotation about that line is left to noise and the
marker off it swings with it. The local frames of the local methods and the fits of
``rigid_weighted`` and of the rigid fill they blend with (not the Vicon-style
``rigid`` method) then take that twist from
temporal continuity: the well-determined fits at the nearest frames where the whole
group (or the marker with its donors) is seen, interpolated in time
(:mod:`~skincap.cleanup.frame_continuity`; ``frame_prior`` of :func:`fill_local_pca`
and :func:`fill_rigid`).

The local methods fall back to the ``rigid_weighted`` fill (``rigid`` with
``FillSettings(rigid_weighted=False)``) for samples no group could estimate
(fewer than three present members); samples no method can reach stay NaN.

Blending with the rigid fill (beyond the paper; ``FillSettings.rigid_blend=None``, the
default): the anchored local-PCA fill and the rigid fill err in different ways (the PCA
model misses deformations it never saw; the rigid fill ignores deformation and drifts
with its donors), so each gap takes ``(1 - w) * local PCA + w * rigid`` with ``w =
s_pca² / (s_pca² + s_rigid²)``. Each ``s`` measures, for this gap, how far the method
strays: the distance between its two one-sided versions (the local-PCA fill anchored
at the start alone vs at the end alone -- the change of its offset across the gap; the
rigid fill carried from the frame before vs from the frame after), averaged over the
gap. With a blend, ``local_pca`` also fits its local frames with the members weighted
by how rigidly they moved together (``fill_local_pca(rigid_frame=0.05)``), so a member
sliding over the body does not drag the frame; ``local_pca_missing`` keeps equal
weights. A fixed ``rigid_blend`` gives every gap that weight; 0 restores the paper's
estimate.

The modules: :mod:`~skincap.cleanup.fill_local` (the local-PCA family),
:mod:`~skincap.cleanup.fill_rigid`, :mod:`~skincap.cleanup.fill_temporal` (linear,
PCHIP, spline), :mod:`~skincap.cleanup.fill_pca` (whole-body PCA); this module chooses
among them and blends. The measured errors of every method on punched gaps, and the
commands that measure them (``skincap eval fill``), are in ``docs/results.md``.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from skincap._arrays import Progress, missing_runs
from skincap.cleanup.fill_local import fill_local_pca, fill_local_window
from skincap.cleanup.fill_pca import fill_pca
from skincap.cleanup.fill_rigid import fill_rigid
from skincap.cleanup.fill_temporal import fill_linear, fill_pchip, fill_spline
from skincap.cleanup.methods import FILL_METHODS
from skincap.cleanup.neighbours import as_csr, motion_neighbours
from skincap.cleanup.settings import FillSettings
from skincap.errors import SkincapWarning, ValidationError
from skincap.types import MarkerSet

__all__ = ["FILL_METHODS", "fill_gaps"]


# ----------------------------------------------------------------------- targets
def _targets(missing: np.ndarray, max_gap: int | None, *, interior_only: bool) -> np.ndarray:
    """(T, N) bool: the missing samples a method should fill."""
    t, n = missing.shape
    marker, start, length = missing_runs(missing)
    keep = np.ones(marker.shape, dtype=bool)
    if interior_only:
        keep &= (start > 0) & (start + length < t)
    if max_gap is not None:
        keep &= length <= max_gap
    # a marker never seen cannot be filled by anything
    keep &= length < t
    marker, start, length = marker[keep], start[keep], length[keep]
    target = np.zeros((t + 1, n), dtype=np.int32)
    np.add.at(target, (start, marker), 1)
    np.add.at(target, (start + length, marker), -1)
    return np.cumsum(target, axis=0)[:t] > 0


def _rigid_weights(
    missing: np.ndarray,
    both: np.ndarray,
    spread_pca: np.ndarray,
    spread_rigid: np.ndarray,
    fixed: float | None,
) -> np.ndarray:
    """Weight of the rigid fill on each ``both`` sample (row-major order).

    ``fixed`` when given; otherwise per gap ``s_pca² / (s_pca² + s_rigid²)`` from the
    mean spreads over the gap (each method's disagreement between its two one-sided
    versions: a measure of how far it strays across this gap), 0.5 where a gap lacks
    either spread.
    """
    tt, nn = np.nonzero(both)
    if fixed is not None:
        return np.full(tt.size, float(fixed))
    t, n = missing.shape
    # one id per missing run: runs are numbered by marker, then frame
    marker, start, length = missing_runs(missing)
    run_id = np.full((t, n), -1, dtype=np.int64)
    rep = np.repeat(np.arange(marker.size), length)
    first = np.cumsum(length) - length
    run_id[start[rep] + np.arange(rep.size) - first[rep], marker[rep]] = rep
    rid = run_id[tt, nn]

    def per_run(v: np.ndarray) -> np.ndarray:
        val = v[tt, nn]
        ok = np.isfinite(val)
        cnt = np.bincount(rid[ok], minlength=marker.size)
        tot = np.bincount(rid[ok], weights=val[ok], minlength=marker.size)
        return np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)[rid]

    sp, sr = per_run(spread_pca), per_run(spread_rigid)
    ok = np.isfinite(sp) & np.isfinite(sr) & (sp**2 + sr**2 > 0)
    return np.where(ok, sp**2 / np.where(ok, sp**2 + sr**2, 1.0), 0.5)


def _fill_local(
    p: np.ndarray,
    target: np.ndarray,
    csr: tuple[np.ndarray, np.ndarray],
    settings: FillSettings,
    progress: Progress | None,
) -> np.ndarray:
    """A local method's fill, blended with (and completed by) the rigid fill.

    p (T, N, 3) metres, NaN where missing; target (T, N) bool. See :func:`fill_gaps`.
    """
    t, n, _ = p.shape
    method, rigid_blend = settings.method, settings.rigid_blend
    spread_pca = np.full((t, n), np.nan)
    blend = rigid_blend is None or rigid_blend > 0
    if method == "local_pca_window":
        out = fill_local_window(p, target, csr, spread=spread_pca)
    else:
        out = fill_local_pca(
            p,
            target,
            csr,
            weighted=method in ("local_pca_weighted", "local_pca_missing"),
            missing_data=method == "local_pca_missing",
            anchor_ends=settings.anchor_ends,
            rigid_frame=0.05 if method == "local_pca" and blend else None,
            spread=spread_pca,
            progress=progress,
        )
    left = target & np.isnan(out[..., 0])
    if blend or left.any():
        spread_rigid = np.full((t, n), np.nan)
        back = fill_rigid(
            p,
            target if blend else left,
            csr,
            spread=spread_rigid,
            weighted=settings.rigid_weighted,
            frame_donors=settings.rigid_weighted,
        )
        both = target & ~left & ~np.isnan(back[..., 0])
        if blend:
            missing = np.isnan(p[..., 0])
            w = _rigid_weights(missing, both, spread_pca, spread_rigid, rigid_blend)
            out[both] = (1.0 - w)[:, None] * out[both] + w[:, None] * back[both]
        out[left] = back[left]
    return out


def _fill_by_method(
    p: np.ndarray,
    target: np.ndarray,
    csr: tuple[np.ndarray, np.ndarray],
    settings: FillSettings,
    progress: Progress | None,
) -> np.ndarray:
    """The filled copy of p (T, N, 3) by ``settings.method``; targets it cannot reach stay NaN."""
    method = settings.method
    if method == "linear":
        return fill_linear(p, target)
    if method == "pchip":
        return fill_pchip(p, target)
    if method == "spline":
        return fill_spline(p, target)
    if method == "rigid":  # the Vicon-style baseline: each frame's fit alone
        return fill_rigid(p, target, csr, frame_prior=None)
    if method == "rigid_weighted":
        return fill_rigid(p, target, csr, weighted=True, frame_donors=True)
    if method == "pca":
        return fill_pca(p, target)
    return _fill_local(p, target, csr, settings, progress)


def fill_gaps(
    markers: MarkerSet,
    settings: FillSettings = FillSettings(),
    *,
    neighbours: Any = None,
    only: np.ndarray | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fill the missing samples of ``markers`` by ``settings.method``.

    Parameters
    ----------
    markers : MarkerSet
        ``positions`` (T, N, 3) metres, NaN where missing. Usually labelled markers
        after merging (fragment columns are filled like any other column).
    settings : FillSettings
        The method (see the module docstring) and its options: ``max_gap`` (longer
        missing runs stay unfilled), ``anchor_ends`` (local methods: join each fill
        continuously to its measured ends, :func:`fill_local_pca`), ``rigid_blend``
        (local methods: the rigid fill's weight ``w`` in ``(1 - w) * local PCA + w *
        rigid`` where both exist; 0 the paper's estimate; None, the default, per gap
        from the two methods' spreads) and ``rigid_weighted`` (the rigid fill they
        blend with and fall back to weighs its donors by rigidity, the
        ``rigid_weighted`` method; False: the equal-weight ``rigid`` fill). With a
        blend, ``local_pca`` also fits its local frames with the members weighted by
        rigidity (:func:`fill_local_pca` ``rigid_frame=0.05``); ``local_pca_missing``
        keeps equal weights.
    neighbours : (offsets, indices) CSR, a MarkerSurface, or None
        Each marker's neighbourhood (used by the local methods and as rigid-fill
        donors). None: :func:`motion_neighbours` with 6 neighbours per marker.
    only : (T, N) bool, optional
        Fill only these missing samples; the other missing samples stay NaN and are
        not used as estimated neighbours either. Default: every missing sample.
    progress : callable(fraction, label), optional

    Returns
    -------
    positions : (T, N, 3) float64, metres
        Measured samples unchanged; filled samples added; NaN where nothing could be
        filled (interpolation methods leave runs at the start or end of the take; the
        spatial methods need three present neighbours).
    invented : (T, N) bool
        True exactly where a sample was missing and is now filled.

    Warns
    -----
    SkincapWarning
        When some targeted samples could not be filled.
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    if not isinstance(settings, FillSettings):
        raise ValidationError(f"settings: expected FillSettings, got {type(settings).__name__}")
    method = settings.method
    p = markers.positions
    t, n, _ = p.shape
    missing = np.isnan(p[..., 0])
    interior = method in ("linear", "pchip", "spline")
    target = _targets(missing, settings.max_gap, interior_only=interior)
    if only is not None:
        only = np.asarray(only, dtype=bool)
        if only.shape != (t, n):
            raise ValidationError(f"only: expected a ({t}, {n}) boolean mask, got {only.shape}")
        target &= only
    if not target.any():
        return p.copy(), np.zeros((t, n), dtype=bool)
    csr = motion_neighbours(p) if neighbours is None else as_csr(neighbours, n)
    out = _fill_by_method(p, target, csr, settings, progress)
    out[~missing] = p[~missing]  # measured samples never change
    invented = missing & ~np.isnan(out[..., 0])
    unfilled = int((target & ~invented).sum())
    if unfilled:
        warnings.warn(
            f"fill_gaps({method}): {unfilled} of {int(target.sum())} missing samples left unfilled",
            SkincapWarning,
            stacklevel=2,
        )
    if progress is not None:
        progress(1.0, method)
    return out, invented
