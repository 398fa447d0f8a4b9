"""Rigid-body gap filling from donor markers (the ``rigid`` and ``rigid_weighted`` methods).

Vicon-style: the rigid motion of at least three donor markers (the marker's
neighbours) from the last frame before a gap, and from the first frame after it, to
each gap frame carries the marker along; the two one-sided estimates are blended
linearly across the gap. ``rigid_weighted`` weighs each donor in the fit by how rigidly
it moved with the marker next to the gap, so donors across a joint hardly count. The
local-PCA methods blend with (and fall back to) this fill (:func:`skincap.cleanup.fill.fill_gaps`).
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import missing_runs
from skincap.cleanup.frame_continuity import (
    fit_rigid_with_prior,
    line_axis,
    take_noise,
    twist_prior,
)
from skincap.cleanup.neighbours import CSR, mean_neighbour_distance
from skincap.geometry.rigid import apply_rigid, fit_rigid

__all__ = ["fill_rigid"]


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
    frame_prior: float | None = 0.05,
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
    frame_prior : float, optional
        Donors nearly on a line leave their rotation about it to noise, and the
        marker off the line swings with it. Each gap frame's fit is then pulled
        towards temporal continuity (:mod:`~skincap.cleanup.frame_continuity`):
        no motion at its own reference end, the motion across the gap (donors and
        the marker itself, fitted between the two ends) at the other, swung onto
        the donors' present line, the twist interpolated in time, as far as the
        take's measurement noise leaves the twist less certain than the prior. The
        value is the prior's twist uncertainty, radians. None: each frame's fit
        alone (Vicon-style).

    Returns
    -------
    (T, N, 3) float64 : a filled copy; targets without three donors stay NaN.
    """
    p = np.array(positions, dtype=np.float64)
    t = p.shape[0]
    present = ~np.isnan(p[..., 0])
    marker, start, length = missing_runs(~present)
    end = start + length  # one past the run
    has_target = target[start, marker] if marker.size else np.zeros(0, dtype=bool)
    gaps = marker[has_target], start[has_target], end[has_target]
    if gaps[0].size == 0 or np.diff(neighbours[0]).max(initial=0) == 0:
        return p
    cand, donor, donor_w = _gap_donors(
        p, present, neighbours, gaps, max_donors, frame_donors, noise_floor if weighted else None
    )
    marker, start, end = gaps
    # one row per (run, gap frame)
    rep = np.repeat(np.arange(marker.size), end - start)
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
    sides = []
    span = (end - start + 1).astype(np.float64)
    w_before = (end[rep] - frame) / span[rep]  # 1 next to the frame before, ->0 at the end
    across = None
    noise = take_noise(p) if frame_prior is not None else 0.0
    if noise > 0:
        across = _motion_across(p, gaps, cand, donor, donor_w)[rep]  # (S, 3, 3)
    eye = np.broadcast_to(np.eye(3), (rep.size, 3, 3))
    for before_side, ref_frame, ok, w in (
        (True, start - 1, before_ok, w_before),
        (False, end, after_ok, 1.0 - w_before),
    ):
        if not ok.any():
            continue
        rf = np.clip(ref_frame[rep], 0, t - 1)
        ref = p[rf[:, None], donors]  # (S, K, 3)
        wts = np.where(dmask & ok[:, None], 1.0 if donor_w is None else donor_w[rep], 0.0)
        rot, tr = fit_rigid(ref, cur, weights=wts)
        if across is not None:
            # the motion from this side's reference frame: none there, the donors' and
            # the marker's motion across the gap at the other end
            far = across if before_side else np.swapaxes(across, 1, 2)
            r0, r1 = (eye, far) if before_side else (far, eye)
            axis, _ = line_axis(ref, wts)
            prior = twist_prior(rot, axis, r0, r1, 1.0 - w_before)
            rot, tr = fit_rigid_with_prior(
                ref, cur, wts, prior, noise=noise, twist_sd=float(frame_prior or 0.0)
            )
        moved = apply_rigid(rot, tr, p[rf, marker[rep]][:, None, :])[:, 0]
        sides.append((ok, np.where(ok, w, 0.0), moved))
    est, good = _blend_sides(sides, spread, frame, marker[rep])
    p[frame[good], marker[rep][good]] = est[good]
    return p


def _gap_donors(
    p: np.ndarray,
    present: np.ndarray,
    neighbours: CSR,
    gaps: tuple[np.ndarray, np.ndarray, np.ndarray],
    max_donors: int,
    frame_donors: bool,
    noise_floor: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Each gap's candidate donors (G, K) int (its neighbours, padded to K), which of
    them donate (G, K) bool and, with ``noise_floor`` (the weighted fill), their
    weights (G, K) (0 where not a donor; None otherwise). See :func:`fill_rigid`."""
    t, n = present.shape
    offsets, indices = neighbours
    marker, start, end = gaps
    deg = np.diff(offsets)
    slot = np.arange(int(deg.max()))
    cand_ok = slot[None, :] < deg[marker][:, None]  # (G, K)
    slot_edge = np.minimum(offsets[marker][:, None] + slot, len(indices) - 1)
    cand = np.where(cand_ok, indices[slot_edge], 0)
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
        seen = cs[hi[:, None], cand] - cs[lo[:, None], cand]  # (G, K)
        donor = cand_ok & (seen == (hi - lo)[:, None])
        # keep the first max_donors donors
        donor &= np.cumsum(donor, axis=1) <= max_donors
    if noise_floor is None:
        return cand, donor, None
    var = _donor_rigidity(p, present, neighbours, marker, start, end, slot_edge)
    donor_w = 1.0 / (var + (noise_floor * _mean_edge(p, neighbours)[marker])[:, None] ** 2)
    donor &= donor_w > 0
    return cand, donor, np.where(donor, donor_w, 0.0)


def _motion_across(
    p: np.ndarray,
    gaps: tuple[np.ndarray, np.ndarray, np.ndarray],
    cand: np.ndarray,
    donor: np.ndarray,
    donor_w: np.ndarray | None,
) -> np.ndarray:
    """(G, 3, 3) each gap's rigid motion from its frame before to its frame after,
    fitted to its donors seen at both ends and the marker itself (weighted as the
    mean donor); NaN for a gap at the take's start or end or with too few points."""
    t = p.shape[0]
    marker, start, end = gaps
    a, b = np.maximum(start - 1, 0), np.minimum(end, t - 1)
    pts = np.concatenate([cand, marker[:, None]], axis=1)  # (G, K + 1)
    w = np.where(donor, 1.0 if donor_w is None else donor_w, 0.0)
    mean_w = w.sum(axis=1) / np.maximum((w > 0).sum(axis=1), 1)
    w = np.concatenate([w, mean_w[:, None]], axis=1)
    w = np.where(((start > 0) & (end < t))[:, None], w, 0.0)
    rot, _ = fit_rigid(p[a[:, None], pts], p[b[:, None], pts], weights=w)
    return rot


def _blend_sides(
    sides: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    spread: np.ndarray | None,
    frame: np.ndarray,
    marker: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The one-sided estimates (usable (S,), weight (S,), position (S, 3)) blended per
    row; a row with one usable side takes it in full. Writes the two sides' distance
    into ``spread`` at (frame, marker) where both exist. Returns (S, 3) and (S,) ok."""
    est = np.zeros((frame.size, 3))
    wsum = np.zeros(frame.size)
    n_sides = sum(side[0].astype(np.int64) for side in sides)
    if spread is not None and len(sides) == 2:
        two = n_sides == 2
        spread[frame[two], marker[two]] = np.linalg.norm(
            sides[0][2][two] - sides[1][2][two], axis=1
        )
    for ok, w, moved in sides:
        w = np.where(n_sides == 1, ok.astype(np.float64), w)
        est += np.where(ok[:, None], moved, 0.0) * w[:, None]
        wsum += w
    good = wsum > 0
    return np.where(good[:, None], est / np.where(good, wsum, 1.0)[:, None], np.nan), good


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
