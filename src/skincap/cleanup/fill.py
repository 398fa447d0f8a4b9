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

The local methods fall back to the ``rigid_weighted`` fill (``rigid`` with
``fill_gaps(rigid_weighted=False)``) for samples no group could estimate
(fewer than three present members); samples no method can reach stay NaN.

Blending with the rigid fill (beyond the paper; ``fill_gaps(rigid_blend=None)``, the
default): the anchored local-PCA fill and the rigid fill err in different ways, so
each gap takes ``(1 - w) * local PCA + w * rigid`` with ``w = s_pca² / (s_pca² +
s_rigid²)``. Each ``s`` measures, for this gap, how far the method strays: the
distance between its two one-sided versions (the local-PCA fill anchored at the
start alone vs at the end alone -- the change of its offset across the gap; the
rigid fill carried from the frame before vs from the frame after), averaged over the
gap. With a blend, ``local_pca`` also fits its local frames with the members
weighted by how rigidly they moved together (``fill_local_pca(rigid_frame=0.05)``),
so a member sliding over the body does not drag the frame; ``local_pca_missing``
keeps equal weights (kt_optitrack_walking 2.25 -> 2.35 mm with them). Punched
30-120-frame gaps, RMSE (``skincap eval fill``, seed 0, 10 gaps per length),
blended with the donor-weighted rigid fill (``rigid_weighted``):

=====================  =========  ======  ========  =========  =========  ==========
take                   local_pca  rigid   rigid_    adaptive   local_pca  local_pca
                       (w = 0)            weighted  local_pca  _missing   _window
                                                               adaptive   adaptive
=====================  =========  ======  ========  =========  =========  ==========
cmu_85_02              22.7 mm    25.2    17.9      15.8       15.5       11.6
kt_optitrack_walking   4.26       4.32    3.21      2.58       2.25       2.57
aml_PronetoRun01       5.44       6.71    3.65      2.89       3.73       3.30
synthetic jump rope    2.42       1.75    1.69      1.65       1.60       1.58
(300 frames, dense)    0.0225     0.0189  0.0185    0.0182     0.0180     0.0177 mean
                       0.272      0.146   0.143     0.125      0.102      0.096  max
=====================  =========  ======  ========  =========  =========  ==========

(mean / max over the spacing on the synthetic take.) Before the rigidity-weighted
frames the adaptive ``local_pca`` gave 16.8 / 2.64 / 3.50 mm; ``local_pca_window``
with equal-weight frames 10.6 / 2.44 / 3.96 mm, and with its rigidity floor at
0.001 / 0.03 / 0.2 / 0.4 of the spacing 13.4 / 13.1 / 10.8 / 10.6 mm on cmu_85_02,
2.90 / 2.87 / 2.48 / 2.45 on kt_optitrack_walking, 3.25 / 3.28 / 3.57 / 3.90 on
aml_PronetoRun01 (0.1 chosen). Its gain on cmu_85_02 (41 markers, pelvis and
shoulder clusters deforming by up to 40 mm) comes mostly from modelling the
marker's own group alone: trained on 16 gap lengths each side (nearly the whole
take) with equal-weight frames it scores 12.3 mm there; the window only trims it.

Blending with the equal-weight ``rigid`` fill instead (``rigid_weighted=False``)
gave 18.1 / 2.99 / 4.54 mm on the real takes. The synthetic take's floor: its
noise-free truth scored against its noisy measured samples (0.5 mm noise) already
gives 0.0106 / 0.040 (mean / max over the spacing) on the same punched gaps.
Against that noise-free truth instead of the measured samples: local_pca adaptive
0.0142 / 0.130, local_pca_missing adaptive 0.0140 / 0.108, rigid_weighted 0.0146 /
0.148, rigid 0.0151 / 0.150 (before the donor weighting: adaptive 0.0145 /
0.138). A fixed ``w = 0.5`` gave 18.8 / 3.50 / 5.27 mm on the real takes;
``rigid_blend=0`` restores the paper's estimate.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from skincap._arrays import Progress, missing_runs
from skincap.cleanup.methods import FILL_METHODS, FillMethod
from skincap.errors import SkincapWarning, ValidationError
from skincap.geometry.rigid import apply_rigid, fit_rigid
from skincap.types import MarkerSet

__all__ = [
    "FILL_METHODS",
    "fill_gaps",
    "fill_local_pca",
    "fill_local_window",
    "fill_linear",
    "fill_pchip",
    "fill_spline",
    "fill_rigid",
    "fill_pca",
    "motion_neighbours",
    "as_csr",
    "mean_neighbour_distance",
]


CSR = tuple[np.ndarray, np.ndarray]


# ------------------------------------------------------------------ neighbourhoods
def as_csr(neighbours: Any, n_markers: int) -> CSR:
    """Normalise a neighbour structure to CSR ``(offsets, indices)``.

    Parameters
    ----------
    neighbours : (offsets, indices) or an object with a ``neighbours`` attribute holding
        one (such as :class:`skincap.cleanup.surface.MarkerSurface`)
        ``offsets`` (N + 1,) int, non-decreasing from 0; marker ``i``'s neighbours are
        ``indices[offsets[i]:offsets[i + 1]]``, each in ``[0, N)`` and not ``i``.
    n_markers : int
        N.

    Returns
    -------
    offsets : (N + 1,) int64
    indices : (E,) int64
    """
    if hasattr(neighbours, "neighbours"):
        neighbours = neighbours.neighbours
    try:
        offsets, indices = neighbours
    except (TypeError, ValueError):
        raise ValidationError(
            "neighbours: expected a CSR pair (offsets, indices) or a MarkerSurface"
        ) from None
    offsets = np.asarray(offsets)
    indices = np.asarray(indices)
    if offsets.ndim != 1 or offsets.shape[0] != n_markers + 1:
        raise ValidationError(
            f"neighbours: offsets must have shape ({n_markers + 1},), got {offsets.shape}"
        )
    if not (np.issubdtype(offsets.dtype, np.integer) or offsets.size == 0):
        raise ValidationError(f"neighbours: offsets must be integers, got {offsets.dtype}")
    if indices.size and not np.issubdtype(indices.dtype, np.integer):
        raise ValidationError(f"neighbours: indices must be integers, got {indices.dtype}")
    offsets = offsets.astype(np.int64)
    indices = indices.astype(np.int64).reshape(-1)
    if offsets[0] != 0 or np.any(np.diff(offsets) < 0) or offsets[-1] != indices.size:
        raise ValidationError(
            "neighbours: offsets must start at 0, not decrease and end at len(indices)"
        )
    if indices.size and (indices.min() < 0 or indices.max() >= n_markers):
        raise ValidationError(f"neighbours: indices must lie in [0, {n_markers})")
    owner = np.repeat(np.arange(n_markers), np.diff(offsets))
    if np.any(owner == indices):
        raise ValidationError("neighbours: a marker cannot be its own neighbour")
    return offsets, indices


def motion_neighbours(positions: np.ndarray, k: int = 6, *, max_frames: int = 100) -> CSR:
    """Motion-consistent neighbours: for each marker the ``k`` markers whose distance
    to it stays most nearly constant through the take (skin and segment neighbours
    keep it; markers on other limbs do not), ties broken by closeness.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    k : int
        Neighbours per marker (capped at N - 1).
    max_frames : int
        Frames sampled evenly to measure the distances (bounds memory and time).

    Returns
    -------
    offsets : (N + 1,) int64
    indices : (N * k,) int64
        Each marker's neighbours, most consistent first. Pairs never seen together
        are never neighbours unless nothing else is left.
    """
    p = np.asarray(positions, dtype=np.float64)
    t, n, _ = p.shape
    k = int(min(k, n - 1))
    if k < 1:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    frames = np.unique(np.linspace(0, t - 1, min(t, max_frames)).round().astype(np.int64))
    q = p[frames]  # (F, N, 3)
    ok = ~np.isnan(q[..., 0])  # (F, N)
    qz = np.where(ok[..., None], q, 0.0)
    sq = (qz**2).sum(axis=-1)  # (F, N)
    # |a - b|² = |a|² + |b|² - 2 a·b, one matrix product per frame
    d2 = sq[:, :, None] + sq[:, None, :] - 2.0 * np.einsum("fnc,fmc->fnm", qz, qz)
    seen = ok[:, :, None] & ok[:, None, :]
    d = np.where(seen, np.sqrt(np.maximum(d2, 0.0)), np.nan)  # (F, N, N)
    count = seen.sum(axis=0)  # (N, N)
    dz = np.where(seen, d, 0.0)
    safe = np.maximum(count, 1)
    mean = dz.sum(axis=0) / safe
    var = np.maximum((dz**2).sum(axis=0) / safe - mean**2, 0.0)
    # score: distance variation plus a little of the distance itself (nearer preferred)
    score = np.sqrt(var) + 0.1 * mean
    score = np.where(count >= max(3, len(frames) // 10), score, np.inf)
    np.fill_diagonal(score, np.inf)
    order = np.argsort(score, axis=1, kind="stable")[:, :k]  # (N, k)
    offsets = np.arange(n + 1, dtype=np.int64) * k
    return offsets, order.reshape(-1).astype(np.int64)


def mean_neighbour_distance(positions: np.ndarray, neighbours: CSR) -> np.ndarray:
    """Each marker's mean distance to its neighbours, averaged over the take.

    Table 2's unit of Park & Hodgins (their "average distance to the neighbors").

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    neighbours : CSR (offsets (N + 1,), indices (E,))

    Returns
    -------
    (N,) float64, metres
        NaN for a marker without neighbours or never seen with one.
    """
    p = np.asarray(positions, dtype=np.float64)
    offsets, indices = neighbours
    n = p.shape[1]
    owner = np.repeat(np.arange(n), np.diff(offsets))
    d = np.linalg.norm(p[:, owner] - p[:, indices], axis=-1)  # (T, E)
    ok = np.isfinite(d)
    cnt = ok.sum(axis=0)
    edge = np.where(cnt > 0, np.where(ok, d, 0.0).sum(axis=0) / np.maximum(cnt, 1), np.nan)
    good = np.isfinite(edge)
    total = np.bincount(owner[good], weights=edge[good], minlength=n)
    num = np.bincount(owner[good], minlength=n)
    return np.where(num > 0, total / np.maximum(num, 1), np.nan)


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


# ------------------------------------------------------------------ temporal fills
def _prev_next(present: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    prev, nxt = _prev_next(present)
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
    prev, nxt = _prev_next(present)
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


# --------------------------------------------------------------------- rigid fill
def fill_rigid(
    positions: np.ndarray,
    target: np.ndarray,
    neighbours: CSR,
    *,
    max_donors: int = 6,
    spread: np.ndarray | None = None,
    weighted: bool = False,
    noise_floor: float = 0.001,
    frame_donors: bool = False,
) -> np.ndarray:
    """Vicon-style rigid-body fill from >= 3 donor markers.

    For a missing run ``[s, e)`` of marker ``i`` the donors are up to ``max_donors``
    of its neighbours present in frame ``s - 1``, in frame ``e`` and throughout the run.
    The donors' rigid motion (Kabsch) from frame ``s - 1`` to gap frame ``t`` carries
    ``x_i(s - 1)``; the same from frame ``e``; the two are blended linearly in time. A
    run at the start or end of the take uses its one side. All runs and frames are
    solved in one batched fit.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Samples to fill.
    neighbours : CSR (offsets (N + 1,), indices (E,))
        Donor candidates per marker, preferred first.
    max_donors : int
    spread : (T, N) float array, optional
        Written in place where a sample was filled from both sides: the distance
        (metres) between the two one-sided estimates, how much the donors' motion
        disagrees with the marker's at the far end; left unchanged elsewhere.
    weighted : bool
        Weigh each donor in the rigid fit (weighted Kabsch) by how rigidly it moved
        with the marker next to this gap: ``1 / (var_k + (noise_floor * d_i)²)``,
        ``var_k`` the variance of the marker-donor distance over the measured
        frames within one gap length before and after the gap (at least 10 frames
        each side), ``d_i`` the marker's mean neighbour distance. A donor across a
        joint or a crease bends away from the marker and hardly counts; donors
        seen in fewer than 3 of those frames get no weight. False (default): equal
        weights, the Vicon-style fill.
    noise_floor : float
        See ``weighted``: the distance spread, as a fraction of the mean neighbour
        distance, below which donors count as equally rigid (keeps measurement
        noise from deciding between near-rigid donors).
    frame_donors : bool
        Donors need only be measured at the gap's ends (where the gap has them) and in
        the gap frame being filled, instead of throughout the gap: a neighbour
        missing for part of the gap still serves in the frames it is seen, and each
        frame uses the first ``max_donors`` it sees. False (default): the
        Vicon-style fixed donor set.

    Returns
    -------
    (T, N, 3) float64 : a filled copy; targets without three donors stay NaN.
    """
    p = np.array(positions, dtype=np.float64)
    t, n, _ = p.shape
    present = ~np.isnan(p[..., 0])
    offsets, indices = neighbours
    marker, start, length = missing_runs(~present)
    end = start + length  # one past the run
    has_target = target[start, marker] if marker.size else np.zeros(0, dtype=bool)
    marker, start, end = marker[has_target], start[has_target], end[has_target]
    if marker.size == 0:
        return p
    g = marker.size
    # candidate donors per run, padded to K
    deg = np.diff(offsets)
    kmax = int(deg.max()) if deg.size else 0
    if kmax == 0:
        return p
    slot = np.arange(kmax)
    cand_ok = slot[None, :] < deg[marker][:, None]  # (G, K)
    cand = np.where(
        cand_ok, indices[np.minimum(offsets[marker][:, None] + slot, len(indices) - 1)], 0
    )
    if frame_donors:
        # candidates seen at the gap's ends; each gap frame uses those it sees
        donor = cand_ok.copy()
        donor &= np.where(
            (start > 0)[:, None], present[np.maximum(start - 1, 0)[:, None], cand], True
        )
        donor &= np.where((end < t)[:, None], present[np.minimum(end, t - 1)[:, None], cand], True)
    else:
        # presence counts over [s-1, e] via cumulative sums
        cs = np.vstack([np.zeros((1, n), dtype=np.int64), np.cumsum(present, axis=0)])
        lo = np.maximum(start - 1, 0)
        hi = np.minimum(end + 1, t)  # exclusive
        need = hi - lo
        seen = cs[hi[:, None], cand] - cs[lo[:, None], cand]  # (G, K)
        donor = cand_ok & (seen == need[:, None])
        # keep the first max_donors donors
        donor &= np.cumsum(donor, axis=1) <= max_donors
    donor_w = None
    if weighted:
        slot_edge = np.minimum(offsets[marker][:, None] + slot, len(indices) - 1)
        donor_w = _donor_rigidity(p, present, neighbours, marker, start, end, slot_edge)
        donor_w = 1.0 / (donor_w + (noise_floor * _mean_edge(p, neighbours)[marker])[:, None] ** 2)
        donor &= donor_w > 0
        donor_w = np.where(donor, donor_w, 0.0)
    # one row per (run, gap frame)
    rep = np.repeat(np.arange(g), end - start)
    frame = np.concatenate([np.arange(a, b) for a, b in zip(start, end, strict=True)])
    donors = cand[rep]  # (S, K)
    dmask = donor[rep]
    if frame_donors:
        dmask &= present[frame[:, None], donors]
        dmask &= np.cumsum(dmask, axis=1) <= max_donors
    enough = dmask.sum(axis=1) >= 3
    before_ok = (start[rep] > 0) & enough
    after_ok = (end[rep] < t) & enough
    keep = target[frame, marker[rep]] & (before_ok | after_ok)
    rep, frame, donors, dmask = rep[keep], frame[keep], donors[keep], dmask[keep]
    before_ok, after_ok = before_ok[keep], after_ok[keep]
    if rep.size == 0:
        return p
    cur = p[frame[:, None], donors]  # (S, K, 3)
    est = np.zeros((rep.size, 3))
    wsum = np.zeros(rep.size)
    sides = []
    span = (end - start + 1).astype(np.float64)
    w_before = (end[rep] - frame) / span[rep]  # 1 next to the frame before, ->0 at the end
    for ref_frame, ok, w in ((start - 1, before_ok, w_before), (end, after_ok, 1.0 - w_before)):
        okr = ok
        if not okr.any():
            continue
        rf = np.clip(ref_frame[rep], 0, t - 1)
        ref = p[rf[:, None], donors]  # (S, K, 3)
        if weighted:
            wts = np.where(dmask & okr[:, None], donor_w[rep], 0.0)
            rot, tr = fit_rigid(ref, cur, weights=wts)
        else:
            rot, tr = fit_rigid(ref, cur, mask=dmask & okr[:, None])
        moved = apply_rigid(rot, tr, p[rf, marker[rep]][:, None, :])[:, 0]
        sides.append((okr, np.where(okr, w, 0.0), moved))
    n_sides = sum(side[0].astype(np.int64) for side in sides)
    if spread is not None and len(sides) == 2:
        two = n_sides == 2
        spread[frame[two], marker[rep][two]] = np.linalg.norm(
            sides[0][2][two] - sides[1][2][two], axis=1
        )
    for okr, w, moved in sides:
        # a run with one usable side takes that side in full
        w = np.where(n_sides == 1, okr.astype(np.float64), w)
        est += np.where(okr[:, None], moved, 0.0) * w[:, None]
        wsum += w
    good = wsum > 0
    p[frame[good], marker[rep][good]] = est[good] / wsum[good][:, None]
    return p


def _mean_edge(p: np.ndarray, neighbours: CSR) -> np.ndarray:
    """(N,) each marker's mean neighbour distance (metres), 0 where unknown."""
    d = mean_neighbour_distance(p, neighbours)
    return np.where(np.isfinite(d), d, 0.0)


def _donor_rigidity(
    p: np.ndarray,
    present: np.ndarray,
    neighbours: CSR,
    marker: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    edge: np.ndarray,
    min_window: int = 10,
) -> np.ndarray:
    """Variance (m²) of the marker-donor distance next to each gap.

    p (T, N, 3), present (T, N); gaps ``marker, start, end`` (G,) with ``[start, end)``
    missing; edge (G, K) the CSR entry of each candidate donor. The variance is taken
    over the measured frames within ``max(end - start, min_window)`` frames before
    and after the gap (cumulative sums per edge, no loop over gaps). Returns (G, K),
    inf where fewer than 3 frames saw both.
    """
    offsets, indices = neighbours
    t, n = present.shape
    owner = np.repeat(np.arange(n), np.diff(offsets))
    d = np.linalg.norm(p[:, owner] - p[:, indices], axis=-1)  # (T, E)
    ok = np.isfinite(d)
    dz = np.where(ok, d, 0.0)
    zero = np.zeros((1, d.shape[1]))
    c0 = np.vstack([zero, np.cumsum(ok, axis=0)])
    c1 = np.vstack([zero, np.cumsum(dz, axis=0)])
    c2 = np.vstack([zero, np.cumsum(dz**2, axis=0)])
    w = np.maximum(end - start, min_window)
    a0, a1 = np.maximum(start - w, 0)[:, None], start[:, None]
    b0, b1 = end[:, None], np.minimum(end + w, t)[:, None]

    def window(c: np.ndarray) -> np.ndarray:
        return c[a1, edge] - c[a0, edge] + c[b1, edge] - c[b0, edge]

    cnt, s1, s2 = window(c0), window(c1), window(c2)
    mean = s1 / np.maximum(cnt, 1)
    var = np.maximum(s2 / np.maximum(cnt, 1) - mean**2, 0.0)
    return np.where(cnt >= 3, var, np.inf)


# ------------------------------------------------------------- whole-body PCA fill
def fill_pca(
    positions: np.ndarray,
    target: np.ndarray,
    *,
    variance: float = 0.99,
    max_iterations: int = 40,
    tol: float = 1e-4,
) -> np.ndarray:
    """Whole-body PCA fill (Gløersen & Federolf 2016).

    The body's travel is taken out first: each frame is shifted by the mean
    displacement of its present markers from their own temporal means (a centroid
    that does not jump when a marker drops out), and put back at the end. Without
    this, a walk's or a run's translation takes most of the variance and the kept
    components miss the limbs (RMSE on the real files, 30-120-frame gaps: kt walking
    58.8 -> 10.9 mm, cmu_85_02 151 -> 105 mm, aml run 76 -> 43 mm).

    The take is then a (T, 3N) matrix; columns are centred and scaled to unit variance
    over their present samples, missing entries are initialised by linear
    interpolation in time (nearest present sample at the ends), then repeatedly
    replaced by their reconstruction from the principal components that keep
    ``variance`` of the variance, until they move less than ``tol`` (in normalised
    units) or ``max_iterations`` is reached.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Samples to fill. Markers never present stay NaN.
    variance : float in (0, 1]
    max_iterations : int
    tol : float

    Returns
    -------
    (T, N, 3) float64 : a filled copy.
    """
    p = np.array(positions, dtype=np.float64)
    t, n, _ = p.shape
    present = ~np.isnan(p[..., 0])
    usable = present.sum(axis=0) >= 2
    if t < 3 or usable.sum() < 2:
        return p
    travel = _body_travel(p, present, usable)  # (T, 1, 3)
    p -= travel
    cols = np.nonzero(usable)[0]
    x = p[:, cols].reshape(t, -1)  # (T, 3M)
    obs = np.repeat(present[:, cols], 3, axis=1)
    mean = np.nanmean(np.where(obs, x, np.nan), axis=0)
    std = np.sqrt(np.nanmean(np.where(obs, (x - mean) ** 2, np.nan), axis=0))
    std = np.where(std > 1e-9, std, 1.0)
    z = (x - mean) / std
    # initialise: linear in time, then nearest sample at the ends
    zi = fill_linear(z.reshape(t, -1, 3), ~present[:, cols]).reshape(t, -1)
    prev, nxt = _prev_next(np.repeat(present[:, cols], 3, axis=1))
    col = np.arange(zi.shape[1])[None, :].repeat(t, 0)
    still = np.isnan(zi)
    src = np.where(prev >= 0, prev, nxt)
    zi[still] = z[src[still], col[still]]
    miss = ~obs
    for _ in range(max_iterations):
        mu = zi.mean(axis=0)
        c = zi - mu
        if c.shape[1] <= c.shape[0]:  # principal axes from the (3M, 3M) covariance
            ev, vec = np.linalg.eigh(c.T @ c)
        else:  # or from the (T, T) Gram matrix: axes c^T u / |c^T u|
            ev, u = np.linalg.eigh(c @ c.T)
            vec = c.T @ u
            vec /= np.maximum(np.linalg.norm(vec, axis=0), 1e-300)
        ev, vec = np.maximum(ev[::-1], 0.0), vec[:, ::-1]
        frac = np.cumsum(ev) / max(float(ev.sum()), 1e-300)
        q = int(min(np.searchsorted(frac, variance) + 1, len(ev)))
        v = vec[:, :q]  # (3M, q)
        recon = mu + (c @ v) @ v.T
        change = np.abs(recon[miss] - zi[miss]).max() if miss.any() else 0.0
        zi[miss] = recon[miss]
        if change < tol:
            break
    filled = (zi * std + mean).reshape(t, -1, 3)
    sub = target[:, cols]
    block = p[:, cols]
    block[sub] = filled[sub]
    p[:, cols] = block
    return p + travel


def _body_travel(p: np.ndarray, present: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(T, 1, 3) per-frame mean displacement of the present markers from their means.

    Frames where no usable marker is present take the nearest frames' value (linear).
    """
    sub = p[:, usable]
    ok = present[:, usable]
    mean = np.nanmean(np.where(ok[..., None], sub, np.nan), axis=0)  # (M, 3)
    disp = np.where(ok[..., None], sub - mean, 0.0)
    count = ok.sum(axis=1)
    travel = disp.sum(axis=1) / np.maximum(count, 1)[:, None]  # (T, 3)
    seen = count > 0
    if not seen.all():
        frames = np.arange(p.shape[0])
        for a in range(3):  # three coordinates, each interpolated over all frames at once
            travel[~seen, a] = np.interp(frames[~seen], frames[seen], travel[seen, a])
    return travel[:, None, :]


# ---------------------------------------------------------------- local PCA fill
def _reference_shape(pos: np.ndarray, present: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Procrustes mean shape (m, 3) of a group over ``rows``, tolerating missing members.

    pos (T, m, 3), present (T, m). Starts from the row with most members present and
    alternates rigid alignment to the current mean with re-averaging (members absent
    in the start row are added when aligned rows see them). NaN for never-seen members.
    """
    if rows.size > 150:  # the mean shape needs no more than a spread of frames
        rows = rows[np.linspace(0, rows.size - 1, 150).round().astype(np.int64)]
    sub = pos[rows]
    ok = present[rows]
    start = int(np.argmax(ok.sum(axis=1)))
    ref = np.where(ok[start][:, None], sub[start], np.nan)
    for _ in range(3):
        known = ~np.isnan(ref[:, 0])
        use = ok & known[None, :]
        rot, tr = fit_rigid(sub, np.where(known[:, None], ref, 0.0)[None], mask=use)
        # align every row onto the reference: inverse map current -> reference
        fine = ~np.isnan(tr[:, 0])
        if not fine.any():
            break
        aligned = apply_rigid(rot[fine], tr[fine], sub[fine])  # rows in the reference pose
        w = ok[fine]
        cnt = w.sum(axis=0)
        total = np.where(w[..., None], aligned, 0.0).sum(axis=0)
        ref = np.where(cnt[:, None] > 0, total / np.maximum(cnt, 1)[:, None], np.nan)
        ref = ref - np.nanmean(ref, axis=0) if np.isfinite(ref).any() else ref
    return ref


def _pca(y: np.ndarray, variance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """PCA of complete rows y (F, D): mean (D,), basis (D, q), eigenvalues (q,), noise σ²."""
    mu = y.mean(axis=0)
    c = y - mu
    # eigen-decomposition of the small (D, D) covariance: far cheaper than an SVD of
    # the (F, D) data for the few-dozen-dimensional neighbourhoods
    ev, vec = np.linalg.eigh(c.T @ c / max(y.shape[0] - 1, 1))
    ev, vec = np.maximum(ev[::-1], 0.0), vec[:, ::-1]
    total = ev.sum()
    if total <= 0:
        return mu, np.zeros((y.shape[1], 0)), np.zeros(0), 1e-10
    frac = np.cumsum(ev) / total
    q = int(min(np.searchsorted(frac, variance) + 1, len(ev)))
    rest = ev[q:]
    noise = float(rest.mean()) if rest.size else float(ev[-1]) * 0.01
    return mu, vec[:, :q], np.maximum(ev[:q], 1e-12), max(noise, 1e-10)


def _pca_solve(
    basis: np.ndarray, evals: np.ndarray, noise: float, resid: np.ndarray, obs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients fitting the observed entries with a PPCA prior, batched.

    basis (D, q), resid (F, D) (NaN-free where obs), obs (F, D) bool.
    Returns coefficients (F, q) and the posterior covariance (F, q, q) / noise.
    """
    q = basis.shape[1]
    ow = obs.astype(np.float64)
    a = np.einsum("dq,fd,dr->fqr", basis, ow, basis)  # (F, q, q)
    a += np.diag(noise / evals)[None]
    b = np.einsum("dq,fd->fq", basis, np.where(obs, resid, 0.0))
    ainv = np.linalg.inv(a)
    coef = np.einsum("fqr,fr->fq", ainv, b)
    del q
    return coef, ainv


def _group_estimates(
    pos: np.ndarray,
    present: np.ndarray,
    want: np.ndarray,
    *,
    variance: float,
    missing_data: bool,
    refits: int = 1,
    em_iterations: int = 15,
    max_train: int = 400,
    query_frame: np.ndarray | None = None,
    query_member: np.ndarray | None = None,
    member_weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Estimates of the missing members of one group.

    pos (T, m, 3) with NaN, present (T, m), want (T, m) targets. ``query_frame`` /
    ``query_member`` (Q,) int: measured samples to estimate as if that member alone
    were missing in that frame (the anchors at a gap's ends). ``member_weights`` (m,)
    float >= 0, optional: the members' weights in the local-frame fits (default 1).

    Returns (rows (F + Q,), estimates (F + Q, m, 3) NaN where not estimated, variance
    (F + Q, m), centre observed (F + Q,) bool, local-frame rotations (F + Q, 3, 3)),
    the Q query rows last (``rows`` holds their frames), or None when the group has no
    model.
    """
    t, m, _ = pos.shape
    count = present.sum(axis=1)
    complete = count == m
    if missing_data:
        train = count >= max(3, m // 2 + 1)
    else:
        train = complete
    if train.sum() < 4:
        return None
    ref = _reference_shape(pos, present, np.nonzero(train)[0])
    if np.isnan(ref).any():
        return None
    d = 3 * m
    # local coordinates of training rows (eqs. 4-5)
    rows_tr = np.nonzero(train)[0]
    if rows_tr.size > max_train:  # an even spread of frames trains the model as well
        rows_tr = rows_tr[np.linspace(0, rows_tr.size - 1, max_train).round().astype(np.int64)]
    mw = np.ones(m) if member_weights is None else member_weights
    rot, tr = fit_rigid(ref[None], pos[rows_tr], weights=present[rows_tr] * mw)
    local = np.einsum("fji,fkj->fki", rot, pos[rows_tr] - tr[:, None, :])  # R^T (x - t)
    y = local.reshape(len(rows_tr), d)
    yobs = np.repeat(present[rows_tr], 3, axis=1)
    if missing_data and not yobs.all():
        y = _em_pca_impute(y, yobs, variance, em_iterations)
    mu, basis, evals, noise = _pca(y, variance)
    if basis.shape[1] == 0:
        return None
    # rows to estimate: a wanted member missing and >= 3 members present
    rows = np.nonzero(want.any(axis=1) & (count >= 3))[0]
    if query_frame is None or query_member is None:
        query_frame = query_member = np.zeros(0, dtype=np.int64)
    n_rows = rows.size
    rows = np.concatenate([rows, query_frame])
    if rows.size == 0:
        return None
    cur = pos[rows]  # (F + Q, m, 3)
    obs = present[rows].copy()
    obs[n_rows + np.arange(query_frame.size), query_member] = False  # as if missing
    cur[~obs] = np.nan
    # a query row left with fewer than three members gets NaN from the rigid fit
    fit_pts = cur.copy()
    fit_mask = obs.copy()
    est = cur.copy()
    for _ in range(refits + 1):
        rot, tr = fit_rigid(ref[None], fit_pts, weights=fit_mask * mw)
        yl = np.einsum("fji,fkj->fki", rot, cur - tr[:, None, :]).reshape(len(rows), d)
        o = np.repeat(obs, 3, axis=1)
        coef, ainv = _pca_solve(basis, evals, noise, yl - mu, o)
        yhat = (mu + coef @ basis.T).reshape(len(rows), m, 3)
        est = apply_rigid(rot, tr, yhat)  # (F, m, 3)
        fit_pts = np.where(obs[..., None], cur, est)
        fit_mask = np.ones_like(obs)
    # predictive variance per member: noise * (1 + trace(U_j A^-1 U_j^T))
    bj = basis.reshape(m, 3, -1)
    var = noise * (3.0 + np.einsum("jcq,fqr,jcr->fj", bj, ainv, bj))
    est = np.where(obs[..., None], np.nan, est)
    return rows, est, var, obs[:, 0], rot


def _em_pca_impute(y: np.ndarray, obs: np.ndarray, variance: float, iterations: int) -> np.ndarray:
    """Missing-data PCA (EM / alternating least squares): fill the unobserved entries
    of y (F, D) by repeated PCA and per-row least-squares fits of the observed entries."""
    mu = np.nanmean(np.where(obs, y, np.nan), axis=0)
    z = np.where(obs, y, mu)
    complete = obs.all(axis=1)
    for _ in range(iterations):
        mu_i, basis, evals, noise = _pca(z, variance)
        if basis.shape[1] == 0:
            break
        part = ~complete
        coef, _ = _pca_solve(basis, evals, noise, z[part] - mu_i, obs[part])
        recon = mu_i + coef @ basis.T
        zp = z[part]
        new = np.where(obs[part], zp, recon)
        change = float(np.abs(new - zp).max()) if new.size else 0.0
        z[part] = new
        if change < 1e-7:
            break
    return z


def fill_local_pca(
    positions: np.ndarray,
    target: np.ndarray,
    neighbours: CSR,
    *,
    weighted: bool = False,
    missing_data: bool = False,
    variance: float = 0.99,
    estimated_centre_weight: float = 0.5,
    anchor_ends: bool = True,
    anchor_window: int = 1,
    rigid_frame: float | None = None,
    spread: np.ndarray | None = None,
    progress: Progress | None = None,
) -> np.ndarray:
    """Local-PCA hole filling (Park & Hodgins 2006, §4.3, eqs. 4-5).

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Missing samples to fill.
    neighbours : CSR (offsets (N + 1,), indices (E,))
        Each marker's neighbourhood (one-ring on a dense surface, motion-consistent
        cluster on a sparse set).
    weighted : bool
        Average the group estimates with inverse-predictive-variance weights, and
        ``estimated_centre_weight`` times less for groups whose centre marker is
        missing in that frame (the discussion's first improvement).
    missing_data : bool
        Train each group's PCA with its partial frames too (EM PCA; the discussion's
        second improvement).
    variance : float
        Fraction of the variance each model keeps (the paper: 0.99).
    estimated_centre_weight : float
        See ``weighted``.
    anchor_ends : bool
        Join each gap to its measured ends. For every run of missing frames of a
        marker, the model also estimates the marker in the last measured frame before
        the run and the first measured frame after it, as if it were missing there;
        the offsets ``measured - estimate`` at the two ends, expressed in the marker's
        local frame (the rotation of its own group's eq. 5 fit; world axes when that
        group has no model), are interpolated linearly across the run, turned back
        into world axes frame by frame and added to the estimates. A run at the start
        or end of the take (or whose other end has no estimate) takes the one end's
        offset unchanged. This removes the slow drift the neighbourhood model cannot
        explain and makes the filled trajectory continuous with the measured one.
    anchor_window : int
        Each end's offset is a weighted mean over up to this many measured frames next
        to the gap (as many as are measured in a row; weights falling linearly with
        the distance to the gap). 1 (the default) uses the frame next to the gap
        only. Wider windows damp the measurement noise of a single frame (better on
        the synthetic takes: 3 frames cut the mean error by a sixth) but follow fast
        real motion less closely (worse on the real takes).
    rigid_frame : float, optional
        Fit each group's local frame (training and estimation alike) with its members
        weighted by how rigidly they moved with the others over the take: ``1 /
        (v_j + (rigid_frame * d)²)``, ``v_j`` the mean variance of member ``j``'s
        distances to the other members (over at most about 400 frames sampled
        evenly), ``d`` the group's mean member distance; a member sliding over the
        body then hardly moves the frame. None (default): equal weights, the paper's
        frame.
    spread : (T, N) float array, optional
        With ``anchor_ends``, written in place on the samples of a gap anchored at
        both ends: the distance (metres) between the two end offsets, i.e. between
        the fill anchored at the start alone and the one anchored at the end alone;
        left unchanged elsewhere.
    progress : callable(fraction, label), optional

    Returns
    -------
    (T, N, 3) float64
        A filled copy; targets no group can estimate stay NaN (see :func:`fill_gaps`
        for the rigid fallback).
    """
    p = np.array(positions, dtype=np.float64)
    t, n, _ = p.shape
    present = ~np.isnan(p[..., 0])
    offsets, indices = neighbours
    acc = np.zeros((t, n, 3))
    wacc = np.zeros((t, n))
    # the gaps (runs of missing frames holding a target) and their measured ends
    g_marker, g_start, g_len = missing_runs(~present)
    hit = target[g_start, g_marker] if g_marker.size else np.zeros(0, dtype=bool)
    g_marker, g_start, g_end = g_marker[hit], g_start[hit], (g_start + g_len)[hit]
    if not anchor_ends:
        g_marker = g_start = g_end = np.zeros(0, dtype=np.int64)
    # anchor queries: up to anchor_window measured frames next to each end of each gap
    # (end e = gap for the before end, G + gap for the after end)
    g = g_marker.size
    frame = np.arange(t)[:, None]
    last_missing = np.maximum.accumulate(np.where(present, -1, frame), axis=0)
    next_missing = np.minimum.accumulate(np.where(present, t, frame)[::-1], axis=0)[::-1]
    before = np.maximum(g_start - 1, 0)
    after = np.minimum(g_end, t - 1)
    avail = np.concatenate(
        [
            np.where(g_start > 0, before - last_missing[before, g_marker], 0),
            np.where(g_end < t, next_missing[after, g_marker] - after, 0),
        ]
    )  # (2G,) measured frames in a row next to each end
    k = np.arange(max(int(anchor_window), 1))
    q_end = np.repeat(np.arange(2 * g), k.size)
    q_k = np.tile(k, 2 * g)
    q_ok = q_k < avail[q_end]
    q_end, q_k = q_end[q_ok], q_k[q_ok]
    side_after = q_end >= g
    gap_of = np.where(side_after, q_end - g, q_end)
    q_frame = np.where(side_after, g_end[gap_of] + q_k, g_start[gap_of] - 1 - q_k)
    q_marker = g_marker[gap_of]
    q_acc = np.zeros((q_frame.size, 3))
    q_w = np.zeros(q_frame.size)
    q_rot = np.full((q_frame.size, 3, 3), np.nan)
    # each marker's own group's local rotation in the frames it is estimated in
    # (stored per target sample: sample_id (T, N) -> rot_at (S, 3, 3))
    sample_id = np.full((t, n), -1, dtype=np.int64)
    sample_id[target] = np.arange(int(target.sum()))
    rot_at = np.full((int(target.sum()) if q_frame.size else 0, 3, 3), np.nan)
    # groups worth modelling: those containing a target
    has_target = target.any(axis=0)
    groups = []
    for i in range(n):
        members = np.concatenate([[i], indices[offsets[i] : offsets[i + 1]]])
        if members.size >= 4 and has_target[members].any():
            groups.append(members)
    where = np.full(n, -1, dtype=np.int64)
    for gi, members in enumerate(groups):
        where[members] = np.arange(members.size)
        mine = np.nonzero(where[q_marker] >= 0)[0]
        q_member = where[q_marker[mine]]
        where[members] = -1
        res = _group_estimates(
            p[:, members],
            present[:, members],
            target[:, members],
            variance=variance,
            missing_data=missing_data,
            query_frame=q_frame[mine],
            query_member=q_member,
            member_weights=(
                None
                if rigid_frame is None
                else _member_rigidity(p[:: max(1, t // 400), members], rigid_frame)
            ),
        )
        if progress is not None:
            progress((gi + 1) / len(groups), "local PCA")
        if res is None:
            continue
        rows, est, var, centre_obs, rot = res
        if weighted:
            w = 1.0 / var
            w = w * np.where(centre_obs, 1.0, estimated_centre_weight)[:, None]
        else:
            w = np.ones(var.shape)
        nq = mine.size
        nr = rows.size - nq
        sel = target[rows[:nr]][:, members] & ~np.isnan(est[:nr, :, 0])  # (F, m)
        fr, mj = np.nonzero(sel)
        tt, nn = rows[fr], members[mj]
        np.add.at(acc, (tt, nn), est[fr, mj] * w[fr, mj][:, None])
        np.add.at(wacc, (tt, nn), w[fr, mj])
        if nq:
            qe = est[nr + np.arange(nq), q_member]  # (Q', 3)
            qwt = w[nr + np.arange(nq), q_member]
            good = ~np.isnan(qe[:, 0])
            np.add.at(q_acc, mine[good], qe[good] * qwt[good, None])
            np.add.at(q_w, mine[good], qwt[good])
            # the centre's own group gives the marker's local frame
            own = q_marker[mine] == members[0]
            q_rot[mine[own]] = rot[nr:][own]
            sid = sample_id[rows[:nr], members[0]]
            rot_at[sid[sid >= 0]] = rot[:nr][sid >= 0]
    done = wacc > 0
    p[done] = acc[done] / wacc[done][:, None]
    if q_frame.size:
        _anchor_gaps(
            p,
            done,
            (g_marker, g_start, g_end),
            (q_end, q_frame, (k.size - q_k).astype(np.float64), q_acc, q_w, q_rot),
            rot_at,
            sample_id,
            spread,
        )
    return p


def _member_rigidity(pos: np.ndarray, floor: float) -> np.ndarray:
    """Weights (m,) for a group's members in its local-frame fit: ``1 / (v_j + (floor
    d)²)``, ``v_j`` the mean over the other members of the variance of their distance
    to member ``j`` over the frames both are seen (pos (F, m, 3) metres, NaN where
    missing), ``d`` the mean member distance; members never seen with another get
    the smallest weight found."""
    diff = pos[:, :, None, :] - pos[:, None, :, :]
    dist = np.sqrt((diff**2).sum(axis=-1))  # (F, m, m), NaN where either is missing
    ok = np.isfinite(dist)
    cnt = ok.sum(axis=0)
    dz = np.where(ok, dist, 0.0)
    mean = dz.sum(axis=0) / np.maximum(cnt, 1)
    var = np.maximum((dz**2).sum(axis=0) / np.maximum(cnt, 1) - mean**2, 0.0)
    m = pos.shape[1]
    pair = (cnt >= 3) & ~np.eye(m, dtype=bool)
    n_pair = pair.sum(axis=1)
    v = np.where(pair, var, 0.0).sum(axis=1) / np.maximum(n_pair, 1)
    d = mean[pair].mean() if pair.any() else 0.0
    w = 1.0 / (v + (floor * d) ** 2 + 1e-18)
    return np.where(n_pair > 0, w, w[n_pair > 0].min() if (n_pair > 0).any() else 1.0)


def fill_local_window(
    positions: np.ndarray,
    target: np.ndarray,
    neighbours: CSR,
    *,
    window: float = 8.0,
    variance: float = 0.99,
    rigid_frame: bool = True,
    rigidity_floor: float = 0.1,
    spread: np.ndarray | None = None,
) -> np.ndarray:
    """Own-group local PCA trained around each gap (the ``local_pca_window`` method).

    For each missing run ``[s, e)`` of marker ``i`` (length ``L``) one local-PCA model
    (eqs. 4-5, missing-data PCA) of ``i`` and its neighbours is trained on the frames
    ``[s - window * L, e + window * L)`` only, and only ``i``'s own group estimates
    it (no averaging over the neighbours' groups). The estimate is joined to the
    measured samples at the run's ends: the model re-estimates ``x_i(s - 1)`` and
    ``x_i(e)`` as if missing, and the two offsets (measured - estimate) are
    interpolated linearly across the run. The local frame (the Kabsch fit of the
    group's reference shape, in training and in estimation alike) weighs each member
    by how rigidly it moved with the others in the window (``rigid_frame``), so a
    member sliding over the body does not drag the frame. One loop over runs; all
    frames of a run are solved in one batch.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Samples to fill.
    neighbours : CSR (offsets (N + 1,), indices (E,))
    window : float
        Training frames each side of a run, in run lengths (at least 10 frames).
    variance : float
        Fraction of the variance the PCA keeps.
    rigid_frame : bool
        Weigh the members in the local-frame fit by ``1 / (v_j + (rigidity_floor *
        d)²)``, ``v_j`` the mean variance (over the window) of member ``j``'s
        distances to the other members, ``d`` the mean member distance. False:
        equal weights, as the other local methods.
    rigidity_floor : float
        See ``rigid_frame``: distance spread, as a fraction of the mean member
        distance, below which members count as equally rigid. 0.1 measured best
        over 0.001-0.4 on the three real takes' punched gaps (smaller helps
        aml_PronetoRun01 a little and costs cmu_85_02 and kt_optitrack_walking).
    spread : (T, N) float array, optional
        Written in place on the filled samples of runs anchored at both ends: the
        distance (metres) between the two end offsets, how far the model strays
        across the run; left unchanged elsewhere.

    Returns
    -------
    (T, N, 3) float64 : a filled copy; samples with fewer than three present group
    members (or a group without a model) stay NaN.
    """
    p = np.array(positions, dtype=np.float64)
    t = p.shape[0]
    present = ~np.isnan(p[..., 0])
    offsets, indices = neighbours
    marker, start, length = missing_runs(~present)
    keep = target[start, marker] if marker.size else np.zeros(0, dtype=bool)
    for i, s, ln in zip(marker[keep], start[keep], length[keep], strict=True):
        members = np.concatenate([[i], indices[offsets[i] : offsets[i + 1]]])
        if members.size < 4:
            continue
        e = s + ln
        w = max(10, int(round(window * ln)))
        lo, hi = max(0, s - w), min(t, e + w)
        ends = [f for f in (s - 1, e) if 0 <= f < t]
        want = np.zeros((hi - lo, members.size), dtype=bool)
        want[s - lo : e - lo, 0] = target[s:e, i]
        res = _group_estimates(
            p[lo:hi, members],
            present[lo:hi, members],
            want,
            variance=variance,
            missing_data=True,
            query_frame=np.asarray(ends, dtype=np.int64) - lo,
            query_member=np.zeros(len(ends), dtype=np.int64),
            member_weights=(
                _member_rigidity(p[lo:hi, members], rigidity_floor) if rigid_frame else None
            ),
        )
        if res is None:
            continue
        rows, est, _, _, _ = res
        nr = rows.size - len(ends)
        frames = rows[:nr] + lo
        val = est[:nr, 0]
        ok = (frames >= s) & (frames < e) & ~np.isnan(val[:, 0]) & target[frames, i]
        frames, val = frames[ok], val[ok]
        off = {f: p[f, i] - est[nr + k, 0] for k, f in enumerate(ends)}
        off = {f: o for f, o in off.items() if np.isfinite(o).all()}
        before, after = off.get(s - 1), off.get(e)
        wa = ((frames - s + 1) / (ln + 1.0))[:, None]
        if before is not None and after is not None:
            val = val + (1.0 - wa) * before + wa * after
            if spread is not None:
                spread[frames, i] = np.linalg.norm(after - before)
        elif before is not None or after is not None:
            val = val + (before if before is not None else after)
        p[frames, i] = val
    return p


def _anchor_gaps(
    p: np.ndarray,
    done: np.ndarray,
    gaps: tuple[np.ndarray, np.ndarray, np.ndarray],
    queries: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    rot_at: np.ndarray,
    sample_id: np.ndarray,
    spread: np.ndarray | None = None,
) -> None:
    """Add to each gap's estimates the end offsets (measured - estimate), interpolated
    linearly across the gap in the marker's local frame; in place on p (T, N, 3).

    gaps: (marker, start, end) (G,) each. queries (Q,) each: the end they belong to
    (gap index for the before end, G + gap for the after end), frame, weight in the
    end's mean (falling linearly with the distance to the gap), summed weighted
    estimates (Q, 3), summed weights (Q,), the marker's local rotation (Q, 3, 3) NaN
    where unknown. An end's offset is the weighted mean over its queries. rot_at (S, 3, 3): the
    local rotation of each target sample (its row in sample_id (T, N), -1 off target),
    NaN where unknown; done (T, N): the samples the model estimated. spread (T, N),
    optional: receives |after offset - before offset| on two-sided gap samples.
    """
    g_marker, g_start, g_end = gaps
    q_end, q_frame, q_weight, q_acc, q_w, q_rot = queries
    g = g_marker.size
    est = np.where((q_w > 0)[:, None], q_acc / np.maximum(q_w, 1e-300)[:, None], np.nan)
    marker_of = np.concatenate([g_marker, g_marker])[q_end]
    off = p[q_frame, marker_of] - est  # (Q, 3) world; NaN where unestimated
    q_has = ~np.isnan(q_rot[:, 0, 0])
    rot0 = np.where(q_has[:, None, None], q_rot, 0.0)
    off_l = np.einsum("qji,qj->qi", rot0, np.nan_to_num(off))  # R^T off: local axes
    good = ~np.isnan(off[:, 0])
    # per end: mean world offset over its estimated queries, and mean local offset
    # when every one of them has the marker's local frame
    n_ok = np.bincount(q_end[good], minlength=2 * g)
    n_rot = np.bincount(q_end[good & q_has], minlength=2 * g)
    ok = n_ok > 0
    has_rot = ok & (n_rot == n_ok)
    w_ok = np.bincount(q_end[good], weights=q_weight[good], minlength=2 * g)
    wq = q_weight[good]
    off_w, off_local = (
        np.stack(
            [np.bincount(q_end[good], weights=wq * v[good, c], minlength=2 * g) for c in range(3)],
            1,
        )
        / np.maximum(w_ok, 1e-300)[:, None]
        for v in (np.nan_to_num(off), off_l)
    )
    off = np.where(ok[:, None], off_w, np.nan)
    before_ok, after_ok = ok[:g], ok[g:]
    # one row per (gap, gap frame)
    length = g_end - g_start
    rep = np.repeat(np.arange(g), length)
    first = np.cumsum(length) - length
    frame = g_start[rep] + np.arange(rep.size) - first[rep]
    mk = g_marker[rep]
    sel = done[frame, mk] & (before_ok | after_ok)[rep]
    rep, frame, mk = rep[sel], frame[sel], mk[sel]
    if rep.size == 0:
        return
    # weight of the after end: 0 next to the before end, 1 next to the after end
    w_after = (frame - g_start[rep] + 1) / (length[rep] + 1.0)
    w_after = np.where(before_ok[rep], np.where(after_ok[rep], w_after, 0.0), 1.0)
    rot = rot_at[sample_id[frame, mk]]  # (S, 3, 3); done samples are targets
    # local axes only when the gap frame's rotation and every end used have one
    local = (
        ~np.isnan(rot[:, 0, 0])
        & (~before_ok[rep] | has_rot[rep])
        & (~after_ok[rep] | has_rot[g + rep])
    )
    ob = np.where(
        before_ok[rep][:, None],
        np.nan_to_num(np.where(local[:, None], off_local[rep], off[rep])),
        0.0,
    )
    oa = np.where(
        after_ok[rep][:, None],
        np.nan_to_num(np.where(local[:, None], off_local[g + rep], off[g + rep])),
        0.0,
    )
    o = (1.0 - w_after)[:, None] * ob + w_after[:, None] * oa
    world = np.where(
        local[:, None], np.einsum("sij,sj->si", np.where(local[:, None, None], rot, 0), o), o
    )
    p[frame, mk] += world
    if spread is not None:
        two = before_ok[rep] & after_ok[rep]
        spread[frame[two], mk[two]] = np.linalg.norm(off[rep[two]] - off[g + rep[two]], axis=1)


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


# ------------------------------------------------------------------------ facade
def fill_gaps(
    markers: MarkerSet,
    *,
    method: FillMethod = "local_pca",
    neighbours: Any = None,
    max_gap: int | None = None,
    anchor_ends: bool = True,
    rigid_blend: float | None = None,
    rigid_weighted: bool = True,
    only: np.ndarray | None = None,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fill the missing samples of ``markers`` with one of :data:`FILL_METHODS`.

    Parameters
    ----------
    markers : MarkerSet
        ``positions`` (T, N, 3) metres, NaN where missing. Usually labelled markers
        after merging (fragment columns are filled like any other column).
    method : str
        ``local_pca`` (the paper), ``local_pca_weighted``, ``local_pca_missing`` (the
        discussion's improvements), or a baseline: ``linear``, ``pchip``, ``spline``,
        ``rigid``, ``pca``. See the module docstring.
    neighbours : (offsets, indices) CSR, a MarkerSurface, or None
        Each marker's neighbourhood (used by the local methods and as rigid-fill
        donors). None: :func:`motion_neighbours` with 6 neighbours per marker.
    max_gap : int, optional
        Leave missing runs longer than this many frames unfilled.
    anchor_ends : bool
        Local methods only: join each filled gap continuously to the measured samples
        at its ends (see :func:`fill_local_pca`). Default True.
    rigid_blend : float in [0, 1], optional
        Local methods only: the weight of the rigid fill (``rigid_weighted`` unless
        ``rigid_weighted=False``) in the final estimate, ``(1 - w) * local PCA + w *
        rigid``, where both exist. 0 gives the local-PCA estimate alone (the paper).
        The two err in different ways (the PCA model misses deformations it never
        saw; the rigid fill ignores deformation and drifts with the donors). None
        (the default) weighs them per gap by their spreads (see the module
        docstring), which beats either alone on all three real takes and on the
        synthetic one. With a blend, ``local_pca`` also fits its local frames with
        the members weighted by rigidity (:func:`fill_local_pca` ``rigid_frame=0.05``;
        measured better on all three real takes, neutral on the synthetic one, worse
        for ``local_pca_missing`` on kt_optitrack_walking, which keeps equal weights).
    rigid_weighted : bool
        Local methods only: the rigid fill they blend with (and fall back to) weighs
        its donors by how rigidly they moved with the marker next to the gap
        (:func:`fill_rigid` ``weighted=True``, the ``rigid_weighted`` method).
        Default True; False blends with the equal-weight ``rigid`` fill.
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
    if method not in FILL_METHODS:
        raise ValidationError(f"method: expected one of {', '.join(FILL_METHODS)}, got {method!r}")
    if rigid_blend is not None and not 0.0 <= rigid_blend <= 1.0:
        raise ValidationError(f"rigid_blend: expected a weight in [0, 1], got {rigid_blend!r}")
    if max_gap is not None and (not isinstance(max_gap, int | np.integer) or max_gap < 1):
        raise ValidationError(f"max_gap: expected a positive integer, got {max_gap!r}")
    p = markers.positions
    t, n, _ = p.shape
    missing = np.isnan(p[..., 0])
    interior = method in ("linear", "pchip", "spline")
    target = _targets(missing, max_gap, interior_only=interior)
    if only is not None:
        only = np.asarray(only, dtype=bool)
        if only.shape != (t, n):
            raise ValidationError(f"only: expected a ({t}, {n}) boolean mask, got {only.shape}")
        target &= only
    if not target.any():
        return p.copy(), np.zeros((t, n), dtype=bool)
    csr = motion_neighbours(p) if neighbours is None else as_csr(neighbours, n)
    if method == "linear":
        out = fill_linear(p, target)
    elif method == "pchip":
        out = fill_pchip(p, target)
    elif method == "spline":
        out = fill_spline(p, target)
    elif method == "rigid":
        out = fill_rigid(p, target, csr)
    elif method == "rigid_weighted":
        out = fill_rigid(p, target, csr, weighted=True, frame_donors=True)
    elif method == "pca":
        out = fill_pca(p, target)
    else:
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
                anchor_ends=anchor_ends,
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
                weighted=rigid_weighted,
                frame_donors=rigid_weighted,
            )
            both = target & ~left & ~np.isnan(back[..., 0])
            if blend:
                w = _rigid_weights(missing, both, spread_pca, spread_rigid, rigid_blend)
                out[both] = (1.0 - w)[:, None] * out[both] + w[:, None] * back[both]
            out[left] = back[left]
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
