"""Markers hidden in the reference frame: leftover fragments that are skin markers.

Park & Hodgins (2006) label markers from a complete reference frame; a marker hidden
there has no label, and its fragments either stay unlabelled or join a neighbour.
:func:`find_hidden_markers` finds them among the fragments a first merge
(:func:`~skincap.cleanup.merge.merge_fragments`) left over: a fragment that rides with
a skin neighbourhood over its whole span, never comes near a known marker, could not
belong to a missing known marker and is not a link of an unlabelled chain (a rope)
starts a new marker; fragments that continue it in time join it.
:func:`~skincap.cleanup.pipeline.clean_markers` adds them as ``U<n>`` columns and merges
again.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skincap.cleanup.local_frames import estimate_missing
from skincap.cleanup.merge import neighbour_spacing
from skincap.cleanup.settings import HiddenSettings
from skincap.cleanup.surface import MarkerSurface
from skincap.errors import ValidationError
from skincap.geometry.rigid import fit_rigid
from skincap.types import MarkerSet

__all__ = ["find_hidden_markers"]


def _in_chain(
    left: np.ndarray,
    present: np.ndarray,
    cols: np.ndarray,
    mid: np.ndarray,
    spacing: np.ndarray,
    min_frames: int,
    *,
    reach: float = 4.0,
    max_cv: float = 0.05,
) -> np.ndarray:
    """(G,) bool: whether each unlabelled column sits inside a chain of unlabelled
    points -- a rope's markers, not skin.

    A chain link has two other unlabelled columns between 1 and ``reach`` spacings
    from it in its middle frame (a skin marker's own neighbours are nearer), seen
    with it for at least ``min_frames`` frames, each at a nearly constant distance
    from it (coefficient of variation below ``max_cv``: an
    inextensible rope), at similar distances (ratio within 0.75-1.33) and on
    opposite sides (the angle between them above 120 degrees); a column steadily tied
    (same distance test) to a link is part of the chain too (its ends, the handle
    next to a hand). A skin marker hidden
    in the reference frame has labelled markers around it, not a row of unlabelled
    ones.

    Parameters
    ----------
    left : (T, L, 3) float, metres, NaN where missing
        The unlabelled columns.
    present : (T, L) bool
    cols : (G,) int
        Columns of ``left`` to test; ``mid`` (G,) int their middle frames and
        ``spacing`` (G,) float their neighbourhoods' spacing, metres.
    """
    here = left[mid, cols]  # (G, 3)
    rel = left[mid] - here[:, None, :]  # (G, L, 3)
    d = np.linalg.norm(rel, axis=2)
    d = np.where(np.isfinite(d), d, np.inf)
    d[np.arange(cols.size), cols] = np.inf
    close = (d <= reach * spacing[:, None]) & (d >= spacing[:, None])
    gi, li = np.nonzero(close)
    if gi.size == 0:
        return np.zeros(cols.size, dtype=bool)
    both = present[:, cols[gi]] & present[:, li]  # (T, P)
    dist = np.linalg.norm(left[:, cols[gi]] - left[:, li], axis=2)  # (T, P)
    cnt = both.sum(axis=0)
    dz = np.where(both, dist, 0.0)
    mean = dz.sum(axis=0) / np.maximum(cnt, 1)
    var = np.where(both, (dz - mean) ** 2, 0.0).sum(axis=0) / np.maximum(cnt, 1)
    steady = (cnt >= min_frames) & (np.sqrt(var) <= max_cv * np.maximum(mean, 1e-12))
    gi, li = gi[steady], li[steady]
    if gi.size < 2:
        return np.zeros(cols.size, dtype=bool)
    # pairs of steady partners of the same column
    a, b = np.nonzero((gi[:, None] == gi[None, :]) & (li[:, None] < li[None, :]))
    if a.size == 0:
        return np.zeros(cols.size, dtype=bool)
    ua, ub = rel[gi[a], li[a]], rel[gi[b], li[b]]
    na, nb = np.linalg.norm(ua, axis=1), np.linalg.norm(ub, axis=1)
    cos = np.einsum("pi,pi->p", ua, ub) / (na * nb)
    link = (na <= 1.33 * nb) & (nb <= 1.33 * na) & (cos < -0.5)
    out = np.zeros(cols.size, dtype=bool)
    out[gi[a][link]] = True
    # the chain's ends: steadily tied to a link (repeat along the chain)
    while True:
        grow = np.zeros(cols.size, dtype=bool)
        grow[gi[np.isin(li, cols[out])]] = True
        if not (grow & ~out).any():
            return out
        out |= grow


def _time_link(
    est: np.ndarray,
    frag: np.ndarray,
    group: np.ndarray,
    nb: np.ndarray,
) -> tuple[int, float]:
    """How far in time and space a fragment is from another track where they come
    nearest in time.

    The fragment's sample next to the track's nearest sample is carried to that
    frame by the rigid fit of its skin neighbourhood ``nb`` between the two frames.
    Over a few frames the skin barely deforms, unlike the way to the reference
    pose, where two hidden markers a spacing apart can land together.

    Parameters
    ----------
    est : (T, N, 3) float, metres
        The markers, measured or estimated (NaN where neither).
    frag, group : (T, 3) float, metres, NaN where missing
        The fragment and the other track's samples (no common frame).
    nb : (k,) int
        The fragment's neighbourhood (columns of ``est``).

    Returns
    -------
    gap : int
        Frames between the two samples compared (-1 when either track is empty).
    distance : float
        Metres between the carried sample and the track's (inf when either track
        is empty, NaN when the neighbourhood is unknown in either frame).
    """
    tf = np.flatnonzero(np.isfinite(frag).all(axis=1))
    tg = np.flatnonzero(np.isfinite(group).all(axis=1))
    if tf.size == 0 or tg.size == 0:
        return -1, np.inf
    at = np.clip(np.searchsorted(tg, tf), 1, tg.size) - 1
    nxt = np.minimum(at + 1, tg.size - 1)
    cand = np.stack([tg[at], tg[nxt]])  # (2, F) track frames either side
    gap = np.abs(cand - tf[None, :])
    k = np.unravel_index(np.argmin(gap), gap.shape)
    a, b = int(tf[k[1]]), int(cand[k])
    rot, tr = fit_rigid(est[a, nb], est[b, nb])
    moved = rot @ frag[a] + tr
    return abs(b - a), float(np.linalg.norm(moved - group[b]))


def _joins_in_time(
    est: np.ndarray,
    frag: np.ndarray,
    group: np.ndarray,
    nb: np.ndarray,
    radius: float,
) -> bool:
    """Whether a fragment continues a group of fragments of one hidden marker where
    they come nearest in time: carried there (:func:`_time_link`), it lands within
    ``radius`` metres of the group's sample. Arrays as in :func:`_time_link`."""
    gap, dist = _time_link(est, frag, group, nb)
    return gap >= 0 and bool(dist <= radius)


def _ruled_out(
    est: np.ndarray,
    track: np.ndarray,
    frag: np.ndarray,
    nb: np.ndarray,
    max_gap: int,
    radius: float,
) -> bool:
    """Whether continuity in time rules out that a fragment belongs to a track.

    A rival (a known marker never measured while the fragment is, or another
    hidden marker's group) may own the fragment where its estimate is off; but
    where it is measured within ``max_gap`` frames of the fragment, the fragment
    carried to that frame by its neighbourhood (:func:`_time_link`) must land on
    it. Landing ``radius`` metres or more away rules it out.

    Parameters
    ----------
    est : (T, N, 3) float, metres
        The known markers, measured or estimated (NaN where neither).
    track : (T, 3) float, metres
        The rival's measured samples (NaN elsewhere; no frame in common with
        ``frag``).
    frag : (T, 3) float, metres, NaN where missing
    nb : (k,) int
        The fragment's neighbourhood (columns of ``est``).
    max_gap : int
    radius : float, metres
    """
    gap, dist = _time_link(est, frag, track, nb)
    return 0 <= gap <= max_gap and bool(dist >= radius)


def _continues_known(
    est: np.ndarray,
    pos: np.ndarray,
    measured: np.ndarray,
    frag: np.ndarray,
    nb: np.ndarray,
    max_gap: int,
    radius: float,
) -> bool:
    """Whether a fragment continues a known marker's measured track in time.

    For every known marker unmeasured through the fragment's span, its last measured
    sample before the fragment and its first after (each within ``max_gap`` frames)
    are compared with the fragment's first or last sample carried to that frame by
    the rigid fit of the fragment's neighbourhood ``nb``. A landing within
    ``radius`` metres says the fragment is that marker, come back where its estimate
    was too far off for the merge to take it.

    Parameters
    ----------
    est : (T, N, 3) float, metres
        The known markers, measured or estimated (NaN where neither).
    pos : (T, N, 3) float, metres
        The known markers' samples; only the ``measured`` ones are used.
    measured : (T, N) bool
    frag : (T, 3) float, metres, NaN where missing
    nb : (k,) int
    max_gap : int
    radius : float, metres
    """
    tf = np.flatnonzero(np.isfinite(frag).all(axis=1))
    if tf.size == 0 or max_gap < 1:
        return False
    t0, t1 = int(tf[0]), int(tf[-1])
    t_count = measured.shape[0]
    free = ~measured[t0 : t1 + 1].any(axis=0)  # (N,) unmeasured through the span
    lo = max(t0 - max_gap, 0)
    hi = min(t1 + max_gap + 1, t_count)
    before = measured[lo:t0] & free  # (b, N)
    after = measured[t1 + 1 : hi] & free  # (a, N)
    frames, cols, ends = [], [], []
    if before.size and before.any():
        has = before.any(axis=0)
        last = lo + before.shape[0] - 1 - np.argmax(before[::-1], axis=0)
        frames.append(last[has])
        cols.append(np.flatnonzero(has))
        ends.append(np.full(int(has.sum()), t0))
    if after.size and after.any():
        has = after.any(axis=0)
        first = t1 + 1 + np.argmax(after, axis=0)
        frames.append(first[has])
        cols.append(np.flatnonzero(has))
        ends.append(np.full(int(has.sum()), t1))
    if not frames:
        return False
    p, j, e = np.concatenate(frames), np.concatenate(cols), np.concatenate(ends)
    rot, tr = fit_rigid(est[e[:, None], nb[None, :]], est[p[:, None], nb[None, :]])
    moved = np.einsum("rij,rj->ri", rot, frag[e]) + tr
    dist = np.linalg.norm(moved - pos[p, j], axis=1)
    return bool(np.any(dist <= radius))


class _Leftovers(NamedTuple):
    """The leftover columns of the first merge: ``left`` (T, L, 3) metres (NaN where
    missing), ``present`` (T, L) bool, ``frames`` (L,) frames present."""

    left: np.ndarray
    present: np.ndarray
    frames: np.ndarray


class _Candidates(NamedTuple):
    """Leftover columns long enough to judge, with their skin neighbourhood.

    ``cols`` (C,) columns of ``left``; ``mid`` (C,) middle present frame; ``here``
    (C, 3) metres, the sample there; ``nb`` (C, k) the ``k`` markers nearest to it
    there (measured or estimated); ``spacing`` (C,) metres, their median spacing;
    ``d_nb`` (C, k) metres, their distances to it there.
    """

    cols: np.ndarray
    mid: np.ndarray
    here: np.ndarray
    nb: np.ndarray
    spacing: np.ndarray
    d_nb: np.ndarray


def _neighbourhoods(
    frags: _Leftovers, est: np.ndarray, spacing: np.ndarray, settings: HiddenSettings
) -> _Candidates | None:
    """Step 1: the candidates (at least ``min_frames`` frames) and their neighbourhoods;
    None when none has ``k`` known neighbours."""
    left, present, count = frags
    k = settings.k
    cand = np.flatnonzero(count >= settings.min_frames)
    if cand.size == 0 or est.shape[1] < k:
        return None
    order = np.cumsum(present[:, cand], axis=0)  # (T, Cc)
    mid = np.argmax(order >= ((count[cand] + 1) // 2)[None, :], axis=0)  # (Cc,)
    here = left[mid, cand]  # (Cc, 3)
    d_mid = np.linalg.norm(est[mid] - here[:, None, :], axis=2)  # (Cc, N)
    d_mid = np.where(np.isfinite(d_mid), d_mid, np.inf)
    nb = np.argsort(d_mid, axis=1, kind="stable")[:, :k]  # (Cc, k)
    has_k = np.isfinite(np.take_along_axis(d_mid, nb, axis=1)).all(axis=1)
    s = np.nanmedian(np.where(np.isfinite(spacing[nb]), spacing[nb], np.nan), axis=1)
    has_k &= np.isfinite(s) & (s > 0)
    if not has_k.any():
        return None
    d_nb = np.take_along_axis(d_mid[has_k], nb[has_k], axis=1)  # (C, k)
    return _Candidates(cand[has_k], mid[has_k], here[has_k], nb[has_k], s[has_k], d_nb)


def _ride_with_skin(
    frags: _Leftovers, est: np.ndarray, c: _Candidates
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step 2: how each candidate rides with its neighbourhood over its whole span.

    Every frame's neighbourhood is fitted rigidly to the middle frame's. Returns, per
    candidate (C,): the worst spread (metres the carried fragment strays from its
    middle-frame sample), the worst fit residual (metres), the clearance (nearest
    approach to a neighbour, metres) and the frames fitted.
    """
    rc, rt = np.nonzero(frags.present[:, c.cols].T)  # rows (candidate, frame)
    src = est[rt[:, None], c.nb[rc]]  # (R, k, 3), NaN where the neighbour is unknown
    dst = est[c.mid[rc][:, None], c.nb[rc]]  # (R, k, 3)
    rot, tr = fit_rigid(src, dst)
    moved = np.einsum("rij,rkj->rki", rot, src) + tr[:, None]
    resid = np.nanmean(np.linalg.norm(moved - dst, axis=2), axis=1) if src.size else np.zeros(0)
    frag = frags.left[rt, c.cols[rc]]  # (R, 3)
    carried = np.einsum("rij,rj->ri", rot, frag) + tr
    dev = np.linalg.norm(carried - c.here[rc], axis=1)
    near = np.linalg.norm(src - frag[:, None], axis=2)
    near = np.min(np.where(np.isfinite(near), near, np.inf), axis=1)
    bad = ~np.isfinite(dev) | ~np.isfinite(resid)
    worst = np.zeros((2, c.cols.size))
    np.maximum.at(worst[0], rc, np.where(bad, np.inf, dev))
    np.maximum.at(worst[1], rc, np.where(bad, np.inf, resid))
    clearance = np.full(c.cols.size, np.inf)
    np.minimum.at(clearance, rc, near)
    fitted = np.bincount(rc[~bad], minlength=c.cols.size)
    return worst[0], worst[1], clearance, fitted


def _has_unmeasured_rival(
    frags: _Leftovers,
    est: np.ndarray,
    meas_pos: np.ndarray,
    measured: np.ndarray,
    c: _Candidates,
    settings: HiddenSettings,
) -> np.ndarray:
    """Step 3: (C,) bool, a known marker within ``rival_radius`` in the middle frame,
    never measured while the candidate is and not ruled out in time, could own it."""
    rc, rt = np.nonzero(frags.present[:, c.cols].T)
    seen_with = np.zeros(c.nb.shape, dtype=bool)
    np.logical_or.at(seen_with, rc, measured[rt[:, None], c.nb[rc]])
    riv_c, riv_j = np.nonzero(~seen_with & (c.d_nb <= settings.rival_radius * c.spacing[:, None]))
    if settings.rule_out_gap > 0 and riv_c.size:
        # a rival measured next to the fragment in time and elsewhere is not its owner
        out = np.array(
            [
                _ruled_out(
                    est,
                    meas_pos[:, c.nb[i, j]],
                    frags.left[:, c.cols[i]],
                    c.nb[i],
                    settings.rule_out_gap,
                    settings.rule_out_radius * c.spacing[i],
                )
                for i, j in zip(riv_c.tolist(), riv_j.tolist(), strict=True)
            ],
            dtype=bool,
        )
        riv_c = riv_c[~out]
    rival = np.zeros(c.cols.size, dtype=bool)
    rival[riv_c] = True
    return rival


def _accepted(
    frags: _Leftovers,
    est: np.ndarray,
    known: np.ndarray,
    measured: np.ndarray,
    c: _Candidates,
    ride: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    rival: np.ndarray,
    settings: HiddenSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 4: the candidates taken for skin markers (strict test and not a rope link,
    or the loose test), clear of known markers, without a rival and not continuing a
    known marker. Returns their indices into ``c`` (G,), and (C,) bool ``strict`` and
    ``common`` (passed clearance and rivals; False where it continues a known marker)."""
    spread, fit, clearance, fitted = ride
    s, count = c.spacing, frags.frames[c.cols]
    strict = (spread <= settings.max_spread * s) & (fit <= settings.max_fit * s)
    loose = (
        ~strict
        & (spread <= settings.loose_spread * s)
        & (fit <= settings.loose_spread * s)
        & (spread <= settings.spread_ratio * fit)
        & (count >= settings.loose_min_frames)
    )
    common = (clearance >= settings.min_clearance * s) & (2 * fitted >= count) & ~rival
    if not ((strict | loose) & common).any():
        return np.zeros(0, dtype=np.int64), strict, common
    g = np.flatnonzero(strict & common)
    chain = _in_chain(frags.left, frags.present, c.cols[g], c.mid[g], s[g], settings.min_frames)
    g = np.sort(np.concatenate([g[~chain], np.flatnonzero(loose & common)]))
    if settings.rule_out_gap > 0 and g.size:
        cont = np.array(
            [
                _continues_known(
                    est,
                    known,
                    measured,
                    frags.left[:, c.cols[i]],
                    c.nb[i],
                    settings.rule_out_gap,
                    settings.rule_out_radius * s[i],
                )
                for i in g.tolist()
            ],
            dtype=bool,
        )
        common[g[cont]] = False  # never grown into a group either
        g = g[~cont]
    return g, strict, common


def _clear_in_reference(
    frags: _Leftovers,
    est: np.ndarray,
    meas_pos: np.ndarray,
    measured: np.ndarray,
    surface: MarkerSurface,
    c: _Candidates,
    g: np.ndarray,
    settings: HiddenSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Step 5: each accepted fragment carried into the reference pose by its
    neighbourhood, and dropped when a known marker never measured with it sits within
    ``rival_radius`` there (unless ruled out in time). Returns the kept ``g`` (G',)
    and their reference-pose positions (G', 3) metres."""
    ref = surface.reference
    r_rot, r_tr = fit_rigid(est[c.mid[g][:, None], c.nb[g]], ref[c.nb[g]])
    at_ref = np.einsum("gij,gj->gi", r_rot, c.here[g]) + r_tr
    keep = np.isfinite(at_ref).all(axis=1)
    g, at_ref = g[keep], at_ref[keep]
    present = frags.present[:, c.cols[g]]
    with_g = present.T.astype(np.float64) @ measured.astype(np.float64)  # (G, N)
    d_ref = np.linalg.norm(ref[None, :, :] - at_ref[:, None, :], axis=2)  # (G, N), NaN unknown
    radius = settings.rival_radius * c.spacing[g][:, None]
    near_ref = np.where(np.isfinite(d_ref), d_ref, np.inf) <= radius
    rg, rn = np.nonzero(near_ref & (with_g == 0))
    if settings.rule_out_gap > 0 and rg.size:
        out = np.array(
            [
                _ruled_out(
                    est,
                    meas_pos[:, b],
                    frags.left[:, c.cols[g[a]]],
                    c.nb[g[a]],
                    settings.rule_out_gap,
                    settings.rule_out_radius * c.spacing[g[a]],
                )
                for a, b in zip(rg.tolist(), rn.tolist(), strict=True)
            ],
            dtype=bool,
        )
        rg = rg[~out]
    keep = np.ones(g.size, dtype=bool)
    keep[rg] = False
    return g[keep], at_ref[keep]


class _Groups(NamedTuple):
    """One entry per new marker: member columns of the merged capture (>= N, seed
    first), the frames taken (T,) bool and the samples so far (T, 3) metres."""

    members: list[list[int]]
    taken: list[np.ndarray]
    track: list[np.ndarray]


def _group_into_markers(
    frags: _Leftovers,
    est: np.ndarray,
    c: _Candidates,
    g: np.ndarray,
    at_ref: np.ndarray,
    strict: np.ndarray,
    n: int,
    settings: HiddenSettings,
) -> _Groups:
    """Step 6: the accepted fragments grouped into markers, seeds first (strict ones,
    each kind longest first); see :func:`find_hidden_markers`."""
    left, present, count = frags
    cols = c.cols[g]
    s = c.spacing
    seeds: list[int] = []
    groups = _Groups([], [], [])
    order = np.lexsort((-count[cols], ~strict[g]))
    for j in order.tolist():
        dist = [float(np.linalg.norm(at_ref[j] - at_ref[sd])) / s[g[sd]] for sd in seeds]
        apart = [not np.any(groups.taken[q] & present[:, cols[j]]) for q in range(len(seeds))]
        near_seed = [q for q, d in enumerate(dist) if d <= settings.group_radius]
        if (
            len(near_seed) == 1
            and apart[near_seed[0]]
            and _joins_in_time(
                est,
                left[:, cols[j]],
                groups.track[near_seed[0]],
                c.nb[g[j]],
                settings.group_radius * s[g[j]],
            )
        ):
            q = near_seed[0]
            groups.members[q].append(int(cols[j]) + n)
            groups.taken[q] |= present[:, cols[j]]
            groups.track[q] = np.where(present[:, cols[j], None], left[:, cols[j]], groups.track[q])
        elif (
            count[cols[j]] >= settings.min_seed_frames
            and not near_seed
            and not any(
                d <= settings.rival_radius
                and a
                and not _ruled_out(
                    est,
                    groups.track[q],
                    left[:, cols[j]],
                    c.nb[g[j]],
                    settings.rule_out_gap,
                    settings.rule_out_radius * s[g[j]],
                )
                for q, (d, a) in enumerate(zip(dist, apart, strict=True))
            )
        ):
            seeds.append(j)
            groups.members.append([int(cols[j]) + n])
            groups.taken.append(present[:, cols[j]].copy())
            groups.track.append(left[:, cols[j]].copy())
        # else ambiguous: it could be a seed's marker or a new one; left over
    return groups


def find_hidden_markers(
    merged: MarkerSet,
    surface: MarkerSurface,
    settings: HiddenSettings = HiddenSettings(),
) -> list[list[int]]:
    """Leftover fragments that are skin markers hidden in the reference frame.

    The paper assumed every marker is seen in the reference pose; a marker hidden
    there has no label, and its fragments either stay unlabelled or -- worse -- join
    a neighbour. After a first merge, a leftover fragment is taken for such a marker
    when, over its **whole** span,

    * it rides with a skin neighbourhood: the ``k`` markers nearest to it in its
      middle frame (measured, else estimated by eq. 2) are fitted rigidly from every
      frame to the middle one; the fit's mean residual stays below ``max_fit`` and
      the fragment, carried by the same fit, stays within ``max_spread`` of where it
      is in the middle frame (both in units of the neighbours' spacing). A rope's
      marker next to a hand moves with the hand for a while but not over a whole
      fragment of a dynamic take, and a ghost jumps. Skin that creases through a
      long span (a hand, a shoulder) fails that test; a fragment of at least
      ``loose_min_frames`` frames is still taken when both stay within
      ``loose_spread`` and the spread is at most ``spread_ratio`` times the fit's
      residual: the fragment strays no more than its neighbourhood deforms. A
      rope's handle riding with a rigid hand strays far beyond the hand's residual
      (spread 0.11-0.16, residual 0.01-0.02 on the synthetic takes), and a ghost
      is short. These fragments skip the chain test (:func:`_in_chain`), which
      takes neighbouring hidden skin markers for a rope;
    * it never comes within ``min_clearance`` spacings of one of those markers
      (measured or estimated): a fragment of a labelled marker that the merge left
      over sits on that marker's estimate;
    * none of those markers within ``rival_radius`` spacings of it (in the middle
      frame) goes unmeasured through its whole span: such a marker could own it,
      its estimate being off (a crease, a hand), and the merge's stricter tests
      left it over. The same test runs in the reference pose, where the fragment
      is carried by its neighbourhood's rigid fit, against every known marker.
      A rival measured within ``rule_out_gap`` frames of the fragment is ruled
      out when the fragment, carried to that frame by its neighbourhood, lands
      ``rule_out_radius`` spacings or more from it: a trajectory does not jump;
    * it does not continue a known marker in time: carried to the frame where a
      known marker unmeasured through its span was last (or is next) measured,
      within ``rule_out_gap`` frames, it lands farther than ``rule_out_radius``
      spacings from it (:func:`_continues_known`).

    The accepted fragments are grouped into markers, longest first: a fragment joins
    a group when it lies within ``group_radius`` spacings of the group's seed in the
    reference pose (both carried there by their neighbourhood's rigid fit) and does
    not overlap it in time. A fragment within ``rival_radius`` of another group
    starts a group of its own only when that group is ruled out in time as above.
    With ``grow``, a candidate that passed the clearance and rival tests and does
    not continue a known marker then joins the one group whose samples it continues within ``grow_gap`` frames
    (:func:`_grow_in_time`). Only a fragment of at least ``min_seed_frames``
    frames starts a group: a
    ghost riding a marker a few centimetres off passes the tests above while it
    lasts, but ghosts are short (geometric, about three frames on average).
    A fragment near a group that it overlaps is dropped
    (two things cannot be one marker), as is anything ambiguous: a fragment left
    unlabelled costs a filled hole, a wrong label a wrong trajectory.

    Parameters
    ----------
    merged : MarkerSet
        :func:`merge_fragments`' output: the surface's markers in the first
        ``surface.n_markers`` columns, leftover fragment columns after them;
        positions (T, C, 3) metres, NaN where missing.
    surface : MarkerSurface
        The surface over the first ``surface.n_markers`` columns.
    settings : HiddenSettings
        The thresholds named above (in units of the neighbourhood's median spacing,
        :func:`neighbour_spacing`), each documented there.

    Returns
    -------
    list of list of int
        One list per new marker: columns of ``merged`` (all >= ``surface.n_markers``),
        the seed (longest) first, the others in time order of no consequence.
    """
    n = surface.n_markers
    pos = merged.positions
    if pos.shape[1] < n:
        raise ValidationError(f"merged has {pos.shape[1]} columns but the surface {n} markers")
    left = pos[:, n:]
    present = np.isfinite(left).all(axis=2)  # (T, L)
    frags = _Leftovers(left, present, present.sum(axis=0))
    if not (frags.frames >= settings.min_frames).any() or n < settings.k:
        return []
    est, _ = estimate_missing(pos[:, :n], surface, surface.reference, temporal=True)
    cands = _neighbourhoods(frags, est, neighbour_spacing(surface), settings)
    if cands is None:
        return []
    measured = np.isfinite(pos[:, :n]).all(axis=2)  # (T, N)
    # (T, N, 3) the known markers' measured samples only
    meas_pos = np.where(measured[..., None], pos[:, :n], np.nan)
    ride = _ride_with_skin(frags, est, cands)
    rival = _has_unmeasured_rival(frags, est, meas_pos, measured, cands, settings)
    g, strict, common = _accepted(frags, est, pos[:, :n], measured, cands, ride, rival, settings)
    if g.size == 0:
        return []
    g, at_ref = _clear_in_reference(frags, est, meas_pos, measured, surface, cands, g, settings)
    groups = _group_into_markers(frags, est, cands, g, at_ref, strict, n, settings)
    if settings.grow and groups.members:
        _grow_in_time(
            groups.members,
            groups.track,
            groups.taken,
            est,
            left,
            present,
            cands.cols,
            cands.nb,
            cands.spacing,
            common,
            n,
            settings.grow_gap,
            settings.group_radius,
        )
    return groups.members


def _grow_in_time(
    groups: list[list[int]],
    track: list[np.ndarray],
    taken: list[np.ndarray],
    est: np.ndarray,
    left: np.ndarray,
    present: np.ndarray,
    cand: np.ndarray,
    nb: np.ndarray,
    s: np.ndarray,
    ok: np.ndarray,
    n: int,
    max_gap: int,
    radius: float,
) -> None:
    """Extend the groups (in place) by continuity in time.

    A leftover candidate that passed the clearance and rival tests (whatever its
    spread, chain or grouping verdict) and does not continue a known marker joins
    the one group whose track it continues: within ``max_gap`` frames, carried there by its
    neighbourhood (:func:`_time_link`), within ``radius`` spacings of the group's
    sample; repeated until nothing joins.

    Parameters
    ----------
    groups, track, taken : lists, one item per group
        Member columns (of the merged capture, >= ``n``), (T, 3) metres samples
        so far (NaN elsewhere) and (T,) bool frames taken.
    est : (T, N, 3) float, metres
    left : (T, L, 3) float, metres; present (T, L) bool
        The leftover columns.
    cand, nb, s, ok : (Cc,), (Cc, k), (Cc,), (Cc,)
        Candidate columns of ``left``, their neighbourhoods, spacings (metres) and
        whether they may join.
    """
    used = {c - n for grp in groups for c in grp}
    while True:
        joined = False
        for i in np.flatnonzero(ok).tolist():
            c = int(cand[i])
            if c in used:
                continue
            hits = []
            for q in range(len(groups)):
                if np.any(taken[q] & present[:, c]):
                    continue
                gap, dist = _time_link(est, left[:, c], track[q], nb[i])
                if 0 <= gap <= max_gap and dist <= radius * s[i]:
                    hits.append(q)
            if len(hits) == 1:
                q = hits[0]
                groups[q].append(c + n)
                taken[q] |= present[:, c]
                track[q] = np.where(present[:, c, None], left[:, c], track[q])
                used.add(c)
                joined = True
        if not joined:
            return
