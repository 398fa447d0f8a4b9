"""Merging broken trajectories into labelled markers (Park & Hodgins 2006, §4.2).

Labelled columns (the markers of the marker surface) carry the capture's first-frame
labels; the other trajectories are unlabelled fragments (``*N`` columns). In every frame
where a labelled marker is missing, its position is estimated from its neighbours
(eq. 2, :func:`~skincap.cleanup.local_frames.estimate_missing`). A fragment becomes
part of marker ``i`` when

* it does not overlap in time with what marker ``i`` already has,
* in its first frame it lies within ``ε¹_i = α¹ · d̄_i`` of the estimate (eq. 3, ``d̄_i``
  the mean reference-pose distance from ``i`` to its neighbours), and
* in **every** frame it spans where an estimate exists, it lies within ``ε²_i = α² · d̄_i``
  (this rejects markers of another body part passing close by), with estimates in at
  least half of its frames.

A fragment with two such markers is merged into the closer only when it is clearly
closer (mean distance below ``ambiguity_ratio`` times the other's); otherwise it waits.
Several fragments may join one marker in the same pass (a chain) when they do not
overlap each other. After each pass the estimates are recomputed with the merged data,
and passes repeat until nothing changes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from skincap.cleanup.local_frames import estimate_missing, neighbour_table
from skincap.cleanup.surface import MarkerSurface
from skincap.errors import ValidationError
from skincap.geometry.rigid import fit_rigid
from skincap.types import MarkerSet

__all__ = ["MergeReport", "find_hidden_markers", "merge_fragments", "neighbour_spacing"]


@dataclass
class MergeReport:
    """Table 1's columns for one merge, plus what was merged where.

    Attributes
    ----------
    trajectories_before, trajectories_after : int
        Columns before and after merging (Table 1, "# of trajectories").
    fragments_before, fragments_after : int
        Unlabelled trajectories before and after: contiguous runs of the non-anchor
        columns (a gappy ``*N`` column counts once per run).
    merged : int
        Fragments merged into a marker.
    wrongly_merged : int or None
        Merged fragments whose true label differs from the marker's (needs truth).
    wrong_rate : float or None
        ``wrongly_merged / merged`` (Table 1's "error rate"; 0 when nothing merged).
    left_unmerged : int
        Fragments left over. With truth: only those whose true label is one of the
        markers (they should have been merged); ghosts and other objects do not count.
    left_unmerged_frames : int or None
        Samples in those fragments (with truth).
    passes : int
        Estimate-and-merge passes run.
    alpha1, alpha2 : float
        Tolerances of eq. 3.
    assignments : dict of str to str
        Fragment label (``*N[start:end]`` for one run of a gappy column) -> marker
        label it joined.
    """

    trajectories_before: int
    trajectories_after: int
    fragments_before: int
    fragments_after: int
    merged: int
    wrongly_merged: int | None
    wrong_rate: float | None
    left_unmerged: int
    left_unmerged_frames: int | None
    passes: int
    alpha1: float
    alpha2: float
    assignments: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return asdict(self)


def _overlaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) bool: whether presence columns ``a[:, p]`` and ``b[:, p]`` share a frame."""
    return np.any(a & b, axis=0)


def neighbour_spacing(surface: MarkerSurface, *, robust: bool = True) -> np.ndarray:
    """Each marker's typical distance to its neighbours in the reference pose (eq. 3's d̄).

    Parameters
    ----------
    surface : MarkerSurface
    robust : bool, default True
        The median of the marker's neighbour distances instead of the paper's mean. An
        automatic surface has a few long edges (a bridge across a crease or to a
        marker with few neighbours) that inflate the mean, and with it ε¹ and ε²,
        until a neighbouring marker's fragment fits inside them.

    Returns
    -------
    (N,) float64, metres
        NaN for a marker without neighbours (it is never matched).
    """
    if not robust:
        return np.asarray(surface.mean_neighbour_distance, dtype=np.float64)
    table, valid = neighbour_table(surface, surface.n_markers)
    ref = surface.reference
    length = np.where(valid, np.linalg.norm(ref[table] - ref[:, None, :], axis=2), np.inf)
    length = np.where(np.isfinite(length), length, np.inf)
    length.sort(axis=1)
    count = np.isfinite(length).sum(axis=1)
    lo = np.clip((count - 1) // 2, 0, max(length.shape[1] - 1, 0))
    hi = np.clip(count // 2, 0, max(length.shape[1] - 1, 0))
    rows = np.arange(surface.n_markers)
    if length.shape[1] == 0:
        return np.full(surface.n_markers, np.nan)
    med = 0.5 * (length[rows, lo] + length[rows, hi])
    return np.where(count > 0, med, np.nan)


def _neighbour_identity_margin(
    est: np.ndarray,
    present: np.ndarray,
    surface: MarkerSurface,
    frag_pos: np.ndarray,
    frag_present: np.ndarray,
    fi: np.ndarray,
    ci: np.ndarray,
    rivals: tuple[np.ndarray, np.ndarray],
    calibrated: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How much closer each candidate fragment is to its marker than to the marker's
    missing neighbours.

    For every candidate pair (fragment ``fi[p]``, marker ``ci[p]``) and every frame the
    fragment spans, the marker's neighbourhood is fitted rigidly (eq. 2) to the
    available neighbours (measured ones weigh 20 times the estimated ones); the fit
    predicts where the marker and each of its neighbours should be, and where each
    of its *rivals* should be: the markers near it in the reference pose
    (``rivals``: (N, M) columns and validity, its surface neighbours and the nearest
    other markers, since an automatic surface misses some true neighbours). A rival
    that is missing in that frame could be the fragment too: its position is its own
    estimate when it has one, else the prediction. ``calibrated`` (N, 3) metres:
    where the marker and its rivals sit in the reference pose (see
    :func:`_prediction_error`); default the reference pose itself.

    Returns
    -------
    d_marker : (P,) float64
        Mean distance from the fragment to the marker's predicted position.
    d_other : (P,) float64
        Mean over frames of the distance to the nearest missing neighbour (inf when
        no neighbour is ever missing).
    worse : (P,) bool
        Whether in some frame a missing neighbour is nearer than the marker.
    """
    table, valid = neighbour_table(surface, surface.n_markers)
    ref = surface.reference
    cal = ref if calibrated is None else calibrated  # the marker's and rivals' places
    rel = np.where(valid[..., None], ref[table] - cal[:, None, :], np.nan)  # (N, D, 3)
    comp, comp_ok = rivals  # (N, M): markers near each marker in the reference pose
    rel_c = np.where(comp_ok[..., None], cal[comp] - cal[:, None, :], 0.0)  # (N, M, 3)
    rp, rt = np.nonzero(frag_present[:, fi].T)  # rows: (pair, frame)
    p_count = fi.size
    if rp.size == 0 or table.shape[1] == 0:
        return np.full(p_count, np.inf), np.full(p_count, np.inf), np.zeros(p_count, bool)
    i = ci[rp]
    nb = table[i]  # (R, D)
    nb_ok = valid[i] & np.isfinite(rel[i]).all(axis=2)
    dst = est[rt[:, None], nb]  # (R, D, 3), NaN where unavailable
    # measured neighbours lead the fit; estimated ones (a guess of a guess) barely count
    w = np.where(present[rt[:, None], nb], 1.0, 0.05)
    rot, tr = fit_rigid(np.where(nb_ok[..., None], rel[i], 0.0), dst, weights=w, mask=nb_ok)
    cj = comp[i]  # (R, M)
    pred = np.einsum("rij,rmj->rmi", rot, rel_c[i]) + tr[:, None]
    own = est[rt[:, None], cj]
    other = np.where(np.isfinite(own), own, pred)  # (R, M, 3)
    frag = frag_pos[rt, fi[rp]]  # (R, 3)
    d_i = np.linalg.norm(frag - tr, axis=1)  # (R,)
    missing = comp_ok[i] & ~present[rt[:, None], cj]
    d_j = np.where(missing, np.linalg.norm(other - frag[:, None], axis=2), np.inf)
    d_j = np.where(np.isfinite(d_j), d_j, np.inf)
    near_j = d_j.min(axis=1)  # (R,)
    fitted = np.isfinite(d_i)
    cnt = np.bincount(rp[fitted], minlength=p_count)
    d_marker = np.bincount(rp[fitted], weights=d_i[fitted], minlength=p_count)
    d_marker = np.where(cnt > 0, d_marker / np.maximum(cnt, 1), np.inf)
    finite_j = fitted & np.isfinite(near_j)
    cnt_j = np.bincount(rp[finite_j], minlength=p_count)
    d_other = np.bincount(rp[finite_j], weights=near_j[finite_j], minlength=p_count)
    d_other = np.where(cnt_j > 0, d_other / np.maximum(cnt_j, 1), np.inf)
    worse = np.bincount(rp[fitted & (near_j <= d_i)], minlength=p_count) > 0
    return d_marker, d_other, worse


def _prediction_error(
    est: np.ndarray,
    present: np.ndarray,
    surface: MarkerSurface,
    *,
    max_frames: int = 40,
    calibrate: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each marker's neighbourhood puts it, learnt from the frames it was measured
    in, and how well.

    Over up to ``max_frames`` of each marker's measured frames, its neighbours'
    reference positions are fitted rigidly to where they are (eq. 2) and the
    marker's measured position is carried back into the reference pose by the
    inverse fit; the mean is the marker's *calibrated* reference position (its
    reference-pose place as its neighbourhood sees it across the take, which matters
    for a marker placed in the reference frame by its neighbours from another frame,
    :func:`~skincap.cleanup.surface.complete_reference_pose`).

    ``calibrate=False``: the reference pose's positions are used as they are.

    Returns
    -------
    error : (N,) float, metres
        90th percentile over those frames of the distance between the fit's
        prediction from the calibrated position and the measured one; NaN when
        never predicted.
    calibrated : (N, 3) float, metres
        The calibrated reference positions; the reference pose's where never
        predicted.
    """
    n = surface.n_markers
    table, valid = neighbour_table(surface, n)
    out = np.full(n, np.nan)
    ref = surface.reference
    cal = np.array(ref, dtype=np.float64, copy=True)
    if table.shape[1] == 0:
        return out, cal
    seen = present.T  # (N, T)
    order = np.cumsum(seen, axis=1)
    step = np.maximum(order[:, -1] / max_frames, 1.0)[:, None]
    pick = seen & (np.floor((order - 1) / step) != np.floor((order - 2) / step))
    mi, ti = np.nonzero(pick)
    ok = valid[mi] & np.isfinite(ref[table[mi]]).all(axis=2)
    rot, tr = fit_rigid(
        np.where(ok[..., None], ref[table[mi]], 0.0), est[ti[:, None], table[mi]], mask=ok
    )
    back = np.einsum("rji,rj->ri", rot, est[ti, mi] - tr)  # R^T (x - t), reference pose
    good = np.isfinite(back).all(axis=1)
    mi, ti, rot, tr, back = mi[good], ti[good], rot[good], tr[good], back[good]
    if mi.size == 0:
        return out, cal
    cnt = np.bincount(mi, minlength=n)
    has = cnt > 0
    mean = np.stack([np.bincount(mi, weights=back[:, a], minlength=n) for a in range(3)], axis=1)
    if calibrate:
        cal[has] = mean[has] / cnt[has, None]
    pred = np.einsum("rij,rj->ri", rot, cal[mi]) + tr
    err = np.linalg.norm(pred - est[ti, mi], axis=1)
    # per-marker 90th percentile: sort by (marker, error) and index into each block
    order2 = np.lexsort((err, mi))
    mi, err = mi[order2], err[order2]
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    idx = first + np.floor(0.9 * (cnt - 1)).astype(np.int64)
    out[has] = err[idx[has]]
    return out, cal


def _rivals(
    surface: MarkerSurface, spacing: np.ndarray, k: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """(N, M) int and bool: each marker's surface neighbours plus the markers within
    twice its spacing in the reference pose (at most ``k`` nearest), itself excluded."""
    from scipy.spatial import cKDTree

    n = surface.n_markers
    ref = surface.reference
    known = np.flatnonzero(np.isfinite(ref).all(axis=1))
    table, valid = neighbour_table(surface, n)
    near = np.zeros((n, 0), dtype=np.int64)
    near_ok = np.zeros((n, 0), dtype=bool)
    if known.size > 1:
        kk = min(k + 1, known.size)
        dist, idx = cKDTree(ref[known]).query(np.where(np.isfinite(ref), ref, 0.0), k=kk)
        dist = dist.reshape(n, kk)
        idx = known[idx.reshape(n, kk)]
        reach = 2.0 * np.where(np.isfinite(spacing), spacing, 0.0)
        near_ok = (dist <= reach[:, None]) & (idx != np.arange(n)[:, None])
        near_ok &= np.isfinite(ref).all(axis=1)[:, None]
        near = np.where(near_ok, idx, 0)
    return np.concatenate([table, near], axis=1), np.concatenate([valid, near_ok], axis=1)


def merge_fragments(
    markers: MarkerSet,
    surface: MarkerSurface,
    anchors: np.ndarray | None = None,
    *,
    alpha1: float = 0.5,
    alpha2: float = 0.6,
    ambiguity_ratio: float = 0.7,
    rival_ratio: float = 0.2,
    calibrate: bool = True,
    short_frames: int = 4,
    max_passes: int = 10,
    temporal: bool = True,
    robust_spacing: bool = True,
    neighbour_check: bool = True,
    prediction_factor: float | None = 2.0,
    min_frames: int = 2,
    fragment_truth: dict[str, str] | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> tuple[MarkerSet, MergeReport]:
    """Merge unlabelled fragments into the markers of the marker surface.

    Parameters
    ----------
    markers : MarkerSet
        Capture with labelled columns and fragment columns, positions (T, C, 3) metres,
        NaN where missing.
    surface : MarkerSurface
        Neighbourhoods over the anchor columns, in ``anchors`` order, with its
        ``reference`` pose and ``mean_neighbour_distance``.
    anchors : (N,) int, optional
        Columns of ``markers`` that are the surface's vertices. Default: every column
        whose label does not start with ``*``.
    alpha1, alpha2 : float, default 0.5, 0.6
        Tolerances α¹ (first frame) and α² (every frame) of eq. 3.
    ambiguity_ratio : float, default 0.7
        A fragment matching two markers joins the closer only when its mean distance
        is below this fraction of the other's.
    max_passes : int, default 10
    min_frames : int, default 2
        Fragments shorter than this are left unmerged. A single-frame fragment is
        the weakest evidence there is (one distance, no motion) and on the synthetic
        jump-rope take one in seven of them went to the wrong marker; left alone, its
        sample is filled by the hole filler instead.
    robust_spacing : bool, default True
        Scale ε¹ and ε² by the median neighbour distance instead of the mean (see
        :func:`neighbour_spacing`).
    neighbour_check : bool, default True
        Beyond the paper: refuse a fragment that lies nearly as close to where one
        of the marker's *missing neighbours* should be (its estimate, or where the
        marker's neighbourhood fit puts it when it has none) as to the marker: the
        mean distance to the marker must be below ``rival_ratio`` times the mean
        distance to the nearest missing neighbour, and no missing neighbour may be
        nearer in any frame. A neighbour without an estimate never competes in the
        paper's test, yet it is the likeliest owner of a fragment near a crease.
        Left unmerged, the samples are filled by the hole filler instead.
    rival_ratio : float, default 0.2
        The margin of ``neighbour_check``: a fragment joins its marker only when the
        marker's neighbourhood fit explains it five times better than any missing
        rival does -- or, where the skin deforms and that fit is off, when the
        marker's temporal estimate (the shape of the frames bracketing the gap)
        explains it ten times better (half the ratio) and the fit still twice as
        well (2.5 times the ratio). The fit's error is a fair share of the spacing
        where the skin deforms, so a fragment of an adjacent marker missing at the
        same time (or of one hidden in the reference frame, beside such a rival)
        passes a margin of 0.7 (the paper's kind of ambiguity test) yet not these.
        Measured on five synthetic jump-rope takes (300 frames seeds 0-3, 600
        frames seed 4; ground truth, ``clean_markers``' final merge): a margin of
        0.7 merged 291/345/341/422/515 fragments of which 0/8/4/2/11 wrongly;
        these margins with ``calibrate`` and ``short_frames`` 302/342/311/395/515,
        none wrongly; on two takes not used to choose them (300 frames, seeds 5
        and 6) 1 of 269 wrongly (a neighbour's fragment at the take's last frames,
        the marker fitted from only three measured neighbours) and none of 319.
    calibrate : bool, default True
        With ``neighbour_check``: the neighbourhood fit predicts the marker (and its
        rivals) from where its neighbourhood puts it across the frames it was
        measured in, not from its reference-pose position alone (see
        :func:`_prediction_error`). A marker hidden in the reference frame and
        placed there by its neighbours from another frame can sit half a spacing
        off; its fragments then failed the margin.
    short_frames : int, default 4
        A fragment shorter than this is weaker evidence: its margin shrinks in
        proportion (a two-frame fragment needs twice the margin) and, with
        ``prediction_factor``, its marker must be predicted by its neighbours
        within a fifth of its spacing (90th percentile). Ghosts are mostly one to
        three frames long and, riding a nearby marker, can sit near a missing
        marker's estimate for a frame or two.
    prediction_factor : float or None, default 2.0
        Beyond the paper, with ``neighbour_check``: a fragment's mean distance to
        where the marker's neighbourhood fit puts it must stay within this many times
        the fit's usual error *for this marker* -- the 90th percentile of that
        distance over the frames where the marker was measured, at least a tenth of
        its spacing. Where the skin barely deforms the fit is tight and a nearby
        marker's fragment (one hidden in the reference frame, or a neighbour missing
        at the same time) no longer fits inside the fixed ε². None: off.
    temporal : bool, default True
        Estimate from the neighbourhood shape in the frames bracketing each gap
        (see :func:`~skincap.cleanup.local_frames.estimate_missing`) instead of the
        reference pose alone; fewer wrong merges around creases (elbow, armpit).
    fragment_truth : dict of str to str, optional
        True label per fragment (and anchor) label, e.g. ``take.fragment_truth``;
        used only to count wrong merges in the report.
    progress : callable(fraction, label), optional

    Returns
    -------
    merged : MarkerSet
        Anchor columns (with the fragments merged in) followed by the fragments left
        over, same frames and rate; residuals and invented flags follow their samples.
    report : MergeReport
    """
    pos = markers.positions
    t_count, c_count, _ = pos.shape
    labels = list(markers.labels)
    if anchors is None:
        anchors = np.flatnonzero([not str(lab).startswith("*") for lab in labels])
    anchors = np.asarray(anchors, dtype=np.int64)
    n = anchors.size
    if surface.n_markers != n:
        raise ValidationError(
            f"surface has {surface.n_markers} markers but {n} anchor columns were given"
        )
    if n and (anchors.min() < 0 or anchors.max() >= c_count or np.unique(anchors).size != n):
        raise ValidationError(f"anchors must be distinct columns in 0..{c_count - 1}")
    if not (
        0 < alpha1
        and 0 < alpha2
        and 0 < ambiguity_ratio <= 1
        and 0 < rival_ratio <= 1
        and short_frames >= 1
        and max_passes >= 1
        and min_frames >= 1
    ):
        raise ValidationError(
            "need alpha1 > 0, alpha2 > 0, 0 < ambiguity_ratio <= 1, 0 < rival_ratio <= 1, "
            "short_frames >= 1, max_passes >= 1, "
            "min_frames >= 1"
        )
    is_anchor = np.zeros(c_count, dtype=bool)
    is_anchor[anchors] = True
    frag_cols = np.flatnonzero(~is_anchor)
    # every contiguous run of a fragment column is one trajectory (a gappy *N column
    # holds several)
    col_present = np.isfinite(pos[:, frag_cols]).all(axis=2)  # (T, Fc)
    pad = np.zeros((frag_cols.size, 1), dtype=np.int8)
    step = np.diff(np.concatenate([pad, col_present.T.astype(np.int8), pad], axis=1), axis=1)
    run_col, run_start = np.nonzero(step == 1)  # sorted by column, then frame
    _, run_end = np.nonzero(step == -1)
    frags = frag_cols[run_col]  # (F,) column of each run
    frames_idx = np.arange(t_count)[:, None]
    frag_present = (frames_idx >= run_start[None, :]) & (frames_idx < run_end[None, :])  # (T, F)
    frag_pos = np.where(frag_present[..., None], pos[:, frags], np.nan)  # (T, F, 3)
    runs_per_col = np.bincount(run_col, minlength=frag_cols.size)

    cur = pos[:, anchors].copy()  # (T, N, 3)
    res = None if markers.residuals is None else markers.residuals[:, anchors].copy()
    inv = None if markers.invented is None else markers.invented[:, anchors].copy()
    has_data = np.ones(frags.size, dtype=bool)
    first = run_start  # (F,)
    length = run_end - run_start
    target = np.full(frags.size, -1, dtype=np.int64)  # anchor index each run joined

    mnd = neighbour_spacing(surface, robust=robust_spacing)
    eps1 = alpha1 * mnd  # ε¹, eq. 3 (NaN for markers without neighbours: never matched)
    eps2 = alpha2 * mnd  # ε²
    rivals = _rivals(surface, mnd)
    passes = 0
    for passes in range(1, max_passes + 1):
        open_f = np.flatnonzero((target < 0) & has_data & (length >= min_frames))
        if open_f.size == 0 or n == 0:
            break
        est, _ = estimate_missing(cur, surface, surface.reference, temporal=temporal)
        anchor_present = np.isfinite(cur).all(axis=2)  # (T, N)
        # ε¹ at each open fragment's first frame, against every missing marker
        f0 = first[open_f]
        p0 = frag_pos[f0, open_f]  # (Fo, 3)
        d0 = np.linalg.norm(est[f0] - p0[:, None, :], axis=2)  # (Fo, N), NaN if no estimate
        # loose candidates (within ε²) compete; strict ones (ε¹, then ε² everywhere) win
        cand = (d0 < np.maximum(eps1, eps2)[None, :]) & ~anchor_present[f0]
        cf, ci = np.nonzero(cand)
        fi = open_f[cf]
        if fi.size == 0:
            break
        strict = d0[cf, ci] < eps1[ci]
        # no temporal overlap with the marker's current trajectory
        free = ~_overlaps(frag_present[:, fi], anchor_present[:, ci])
        fi, ci, strict = fi[free], ci[free], strict[free]
        # ε² in every frame the fragment spans
        dist = np.linalg.norm(est[:, ci] - frag_pos[:, fi], axis=2)  # (T, P)
        checked = np.isfinite(dist)
        within = np.where(checked, dist < eps2[ci][None, :], True).all(axis=0)
        enough = 2 * checked.sum(axis=0) >= length[fi]
        ok = strict & within & enough
        mean_d = np.where(checked, dist, 0.0).sum(axis=0) / np.maximum(checked.sum(axis=0), 1)
        mean_d = np.where(checked.any(axis=0), mean_d, np.inf)
        if neighbour_check and ok.any():
            okp = np.flatnonzero(ok)
            e90_all, calibrated = _prediction_error(
                est, anchor_present, surface, calibrate=calibrate
            )
            d_mark, d_other, worse = _neighbour_identity_margin(
                est,
                anchor_present,
                surface,
                frag_pos,
                frag_present,
                fi[okp],
                ci[okp],
                rivals,
                calibrated,
            )
            # short fragments are weak evidence: the margin grows as they shrink
            margin = rival_ratio * np.minimum(1.0, length[fi[okp]] / max(short_frames, 1))
            by_fit = d_mark < margin * d_other
            by_time = (mean_d[okp] < 0.5 * margin * d_other) & (d_mark < 2.5 * margin * d_other)
            ok[okp] = ~worse & (by_fit | by_time)
            if prediction_factor is not None:
                e90 = e90_all[ci[okp]]
                floor = 0.1 * mnd[ci[okp]]
                scale = np.where(np.isfinite(e90), np.maximum(e90, floor), np.inf)
                ok[okp] &= d_mark <= prediction_factor * scale
                # a short fragment is too little evidence for a marker its
                # neighbours predict poorly (a ghost near the estimate fits as well)
                short = length[fi[okp]] < short_frames
                ok[okp] &= ~short | (np.nan_to_num(e90, nan=np.inf) <= 0.2 * mnd[ci[okp]])
        # per fragment: the best valid match must be clearly closer than any other
        # marker whose estimate comes near (valid or not)
        order = np.lexsort((mean_d, fi))
        fi, ci, mean_d, ok = fi[order], ci[order], mean_d[order], ok[order]
        head = np.ones(fi.size, dtype=bool)
        head[1:] = fi[1:] != fi[:-1]
        same_next = np.zeros(fi.size, dtype=bool)
        same_next[:-1] = fi[1:] == fi[:-1]
        second = np.full(fi.size, np.inf)
        second[:-1] = np.where(same_next[:-1], mean_d[1:], np.inf)
        clear = head & ok & (mean_d < ambiguity_ratio * second)
        fi, ci, mean_d = fi[clear], ci[clear], mean_d[clear]
        # chains: per marker, closest first, keep fragments that do not overlap
        order = np.argsort(mean_d, kind="stable")
        taken = anchor_present.copy()
        merged_now = 0
        for f, i in zip(fi[order].tolist(), ci[order].tolist(), strict=True):
            frames = frag_present[:, f]
            if np.any(taken[frames, i]):
                continue
            taken[frames, i] = True
            target[f] = i
            cur[frames, i] = frag_pos[frames, f]
            col = frags[f]
            if res is not None:
                res[frames, i] = markers.residuals[frames, col]
            if inv is not None:
                inv[frames, i] = markers.invented[frames, col]
            merged_now += 1
        if progress is not None:
            progress(passes / max_passes, "merging fragments")
        if merged_now == 0:
            break

    # leftover columns keep their unmerged runs; all-NaN columns are dropped
    gone = frag_present[:, target >= 0]  # (T, Fm)
    removed = np.zeros((t_count, c_count), dtype=bool)
    np.logical_or.at(removed.T, frags[target >= 0], gone.T)
    left_run = target < 0
    left = np.unique(frags[left_run])
    keep_cols = np.concatenate([anchors, left])
    rest = np.where(removed[:, left, None], np.nan, pos[:, left])
    out_pos = np.concatenate([cur, rest], axis=1)
    out_res = (
        None
        if res is None
        else np.concatenate(
            [res, np.where(removed[:, left], np.nan, markers.residuals[:, left])], 1
        )
    )
    out_inv = (
        None
        if inv is None
        else np.concatenate([inv, markers.invented[:, left] & ~removed[:, left]], axis=1)
    )
    out = MarkerSet(
        positions=out_pos,
        labels=[labels[c] for c in keep_cols],
        rate=markers.rate,
        meta=dict(markers.meta),
        residuals=out_res,
        invented=out_inv,
    )

    col_of = {int(c): k for k, c in enumerate(frag_cols.tolist())}

    def run_name(f: int) -> str:
        col = int(frags[f])
        if runs_per_col[col_of[col]] == 1:
            return labels[col]
        return f"{labels[col]}[{int(run_start[f])}:{int(run_end[f])}]"

    merged_runs = np.flatnonzero(target >= 0).tolist()
    assignments = {run_name(f): labels[anchors[target[f]]] for f in merged_runs}
    wrong: int | None = None
    left_count = int(left_run.sum())
    left_frames: int | None = None
    if fragment_truth is not None:
        anchor_truth = {fragment_truth.get(labels[a], labels[a]) for a in anchors.tolist()}
        wrong = sum(
            fragment_truth.get(labels[frags[f]], labels[frags[f]])
            != fragment_truth.get(labels[anchors[target[f]]], labels[anchors[target[f]]])
            for f in merged_runs
        )
        should = np.array(
            [
                fragment_truth.get(labels[c], labels[c]) in anchor_truth
                for c in frags[left_run].tolist()
            ],
            dtype=bool,
        )
        left_count = int(should.sum())
        left_frames = int(length[left_run][should].sum())
    merged_count = len(assignments)
    report = MergeReport(
        trajectories_before=int(c_count),
        trajectories_after=int(keep_cols.size),
        fragments_before=int(frags.size),
        fragments_after=int(left_run.sum()),
        merged=merged_count,
        wrongly_merged=wrong,
        wrong_rate=None if wrong is None else (wrong / merged_count if merged_count else 0.0),
        left_unmerged=left_count,
        left_unmerged_frames=left_frames,
        passes=passes,
        alpha1=float(alpha1),
        alpha2=float(alpha2),
        assignments=assignments,
    )
    return out, report


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


def find_hidden_markers(
    merged: MarkerSet,
    surface: MarkerSurface,
    *,
    k: int = 8,
    min_frames: int = 10,
    max_spread: float = 0.1,
    max_fit: float = 0.1,
    min_clearance: float = 0.45,
    group_radius: float = 0.5,
    rival_radius: float = 1.5,
    loose_spread: float = 0.5,
    spread_ratio: float = 2.0,
    loose_min_frames: int = 20,
    rule_out_gap: int = 5,
    rule_out_radius: float = 0.7,
    min_seed_frames: int = 15,
    grow: bool = True,
    grow_gap: int = 5,
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
    k : int, default 8
        Markers in a fragment's neighbourhood (at least 3).
    min_frames : int, default 10
        Shorter leftover columns are not considered.
    max_spread, max_fit, min_clearance, group_radius, rival_radius : float
        Thresholds in units of the neighbourhood's median spacing
        (:func:`neighbour_spacing`).
    loose_spread, rule_out_radius : float, defaults 0.5 and 0.7
        Likewise, in spacings.
    spread_ratio : float, default 2.0
        Largest spread over fit residual for the long fragments above.
    loose_min_frames : int, default 20
        Shortest fragment taken by the looser spread test (a ghost lasts about
        three frames).
    rule_out_gap : int, default 5
        Frames within which continuity in time is trusted (0: not used).
    min_seed_frames : int, default 15
        Shortest fragment that starts a new marker; shorter ones (at least
        ``min_frames``) can only join one.
    grow : bool, default True
    grow_gap : int, default 5
        Frames within which continuity in time extends a group. At 5 on the
        synthetic takes (seeds 0-4) 518 more leftover samples went to their
        hidden marker, none wrong; at 15 one 14-sample fragment went wrong.

    Returns
    -------
    list of list of int
        One list per new marker: columns of ``merged`` (all >= ``surface.n_markers``),
        the seed (longest) first, the others in time order of no consequence.
    """
    n = surface.n_markers
    pos = merged.positions
    t_count, c_count, _ = pos.shape
    if k < 3 or min_frames < 1:
        raise ValidationError(
            f"need k >= 3 and min_frames >= 1; got k={k}, min_frames={min_frames}"
        )
    if c_count < n:
        raise ValidationError(f"merged has {c_count} columns but the surface {n} markers")
    left = pos[:, n:]
    present = np.isfinite(left).all(axis=2)  # (T, L)
    count = present.sum(axis=0)
    cand = np.flatnonzero(count >= min_frames)
    if cand.size == 0 or n < k:
        return []
    est, _ = estimate_missing(pos[:, :n], surface, surface.reference, temporal=True)
    spacing = neighbour_spacing(surface)
    # middle present frame of each candidate
    order = np.cumsum(present[:, cand], axis=0)  # (T, Cc)
    mid = np.argmax(order >= ((count[cand] + 1) // 2)[None, :], axis=0)  # (Cc,)
    here = left[mid, cand]  # (Cc, 3)
    d_mid = np.linalg.norm(est[mid] - here[:, None, :], axis=2)  # (Cc, N)
    d_mid = np.where(np.isfinite(d_mid), d_mid, np.inf)
    nb = np.argsort(d_mid, axis=1, kind="stable")[:, :k]  # (Cc, k)
    has_k = np.isfinite(np.take_along_axis(d_mid, nb, axis=1)).all(axis=1)
    s = np.nanmedian(np.where(np.isfinite(spacing[nb]), spacing[nb], np.nan), axis=1)
    has_k &= np.isfinite(s) & (s > 0)
    cand, mid, here, nb, s = cand[has_k], mid[has_k], here[has_k], nb[has_k], s[has_k]
    if cand.size == 0:
        return []
    rc, rt = np.nonzero(present[:, cand].T)  # rows (candidate, frame)
    src = est[rt[:, None], nb[rc]]  # (R, k, 3), NaN where the neighbour is unknown
    dst = est[mid[rc][:, None], nb[rc]]  # (R, k, 3)
    rot, tr = fit_rigid(src, dst)
    moved = np.einsum("rij,rkj->rki", rot, src) + tr[:, None]
    resid = np.nanmean(np.linalg.norm(moved - dst, axis=2), axis=1) if src.size else np.zeros(0)
    frag = left[rt, cand[rc]]  # (R, 3)
    carried = np.einsum("rij,rj->ri", rot, frag) + tr
    dev = np.linalg.norm(carried - here[rc], axis=1)
    near = np.linalg.norm(src - frag[:, None], axis=2)
    near = np.min(np.where(np.isfinite(near), near, np.inf), axis=1)
    bad = ~np.isfinite(dev) | ~np.isfinite(resid)
    worst = np.zeros((3, cand.size))
    np.maximum.at(worst[0], rc, np.where(bad, np.inf, dev))
    np.maximum.at(worst[1], rc, np.where(bad, np.inf, resid))
    clearance = np.full(cand.size, np.inf)
    np.minimum.at(clearance, rc, near)
    fitted = np.bincount(rc[~bad], minlength=cand.size)
    # a known marker near it that is never measured while it is could own it
    measured = np.isfinite(pos[:, :n]).all(axis=2)  # (T, N)
    seen_with = np.zeros((cand.size, k), dtype=bool)
    np.logical_or.at(seen_with, rc, measured[rt[:, None], nb[rc]])
    d_nb = np.take_along_axis(d_mid[has_k], nb, axis=1)  # (Cc, k)
    riv_c, riv_j = np.nonzero(~seen_with & (d_nb <= rival_radius * s[:, None]))
    # (T, N, 3) the known markers' measured samples only
    meas_pos = np.where(measured[..., None], pos[:, :n], np.nan)
    if rule_out_gap > 0 and riv_c.size:
        # a rival measured next to the fragment in time and elsewhere is not its owner
        out = np.array(
            [
                _ruled_out(
                    est,
                    meas_pos[:, nb[c, j]],
                    left[:, cand[c]],
                    nb[c],
                    rule_out_gap,
                    rule_out_radius * s[c],
                )
                for c, j in zip(riv_c.tolist(), riv_j.tolist(), strict=True)
            ],
            dtype=bool,
        )
        riv_c = riv_c[~out]
    rival = np.zeros(cand.size, dtype=bool)
    rival[riv_c] = True
    strict = (worst[0] <= max_spread * s) & (worst[1] <= max_fit * s)
    loose = (
        ~strict
        & (worst[0] <= loose_spread * s)
        & (worst[1] <= loose_spread * s)
        & (worst[0] <= spread_ratio * worst[1])
        & (count[cand] >= loose_min_frames)
    )
    common = (clearance >= min_clearance * s) & (2 * fitted >= count[cand]) & ~rival
    good = (strict | loose) & common
    if not good.any():
        return []
    g = np.flatnonzero(strict & common)
    g = g[~_in_chain(left, present, cand[g], mid[g], s[g], min_frames)]
    g = np.sort(np.concatenate([g, np.flatnonzero(loose & common)]))
    if rule_out_gap > 0 and g.size:
        cont = np.array(
            [
                _continues_known(
                    est,
                    pos[:, :n],
                    measured,
                    left[:, cand[i]],
                    nb[i],
                    rule_out_gap,
                    rule_out_radius * s[i],
                )
                for i in g.tolist()
            ],
            dtype=bool,
        )
        common[g[cont]] = False  # never grown into a group either
        g = g[~cont]
    if g.size == 0:
        return []
    # each accepted fragment carried into the reference pose by its neighbourhood
    ref = surface.reference
    r_rot, r_tr = fit_rigid(est[mid[g][:, None], nb[g]], ref[nb[g]])
    at_ref = np.einsum("gij,gj->gi", r_rot, here[g]) + r_tr
    keep = np.isfinite(at_ref).all(axis=1)
    g, at_ref = g[keep], at_ref[keep]
    # the same rival test in the reference pose, against every known marker there
    with_g = present[:, cand[g]].T.astype(np.float64) @ measured.astype(np.float64)  # (G, N)
    d_ref = np.linalg.norm(ref[None, :, :] - at_ref[:, None, :], axis=2)  # (G, N), NaN unknown
    near_ref = np.where(np.isfinite(d_ref), d_ref, np.inf) <= rival_radius * s[g][:, None]
    rg, rn = np.nonzero(near_ref & (with_g == 0))
    if rule_out_gap > 0 and rg.size:
        out = np.array(
            [
                _ruled_out(
                    est,
                    meas_pos[:, b],
                    left[:, cand[g[a]]],
                    nb[g[a]],
                    rule_out_gap,
                    rule_out_radius * s[g[a]],
                )
                for a, b in zip(rg.tolist(), rn.tolist(), strict=True)
            ],
            dtype=bool,
        )
        rg = rg[~out]
    keep = np.ones(g.size, dtype=bool)
    keep[rg] = False
    g, at_ref = g[keep], at_ref[keep]
    cols = cand[g]
    seeds: list[int] = []
    groups: list[list[int]] = []
    taken: list[np.ndarray] = []
    track: list[np.ndarray] = []  # (T, 3) each group's samples so far
    # seeds: fragments that passed the strict test first (their carry into the
    # reference pose is the surer), each kind longest first
    order = np.lexsort((-count[cols], ~strict[g]))
    for j in order.tolist():
        dist = [float(np.linalg.norm(at_ref[j] - at_ref[sd])) / s[g[sd]] for sd in seeds]
        apart = [not np.any(taken[q] & present[:, cols[j]]) for q in range(len(seeds))]
        near_seed = [q for q, d in enumerate(dist) if d <= group_radius]
        if (
            len(near_seed) == 1
            and apart[near_seed[0]]
            and _joins_in_time(
                est,
                left[:, cols[j]],
                track[near_seed[0]],
                nb[g[j]],
                group_radius * s[g[j]],
            )
        ):
            q = near_seed[0]
            groups[q].append(int(cols[j]) + n)
            taken[q] |= present[:, cols[j]]
            track[q] = np.where(present[:, cols[j], None], left[:, cols[j]], track[q])
        elif (
            count[cols[j]] >= min_seed_frames
            and not near_seed
            and not any(
                d <= rival_radius
                and a
                and not _ruled_out(
                    est,
                    track[q],
                    left[:, cols[j]],
                    nb[g[j]],
                    rule_out_gap,
                    rule_out_radius * s[g[j]],
                )
                for q, (d, a) in enumerate(zip(dist, apart, strict=True))
            )
        ):
            seeds.append(j)
            groups.append([int(cols[j]) + n])
            taken.append(present[:, cols[j]].copy())
            track.append(left[:, cols[j]].copy())
        # else ambiguous: it could be a seed's marker or a new one; left over
    if grow and groups:
        _grow_in_time(
            groups,
            track,
            taken,
            est,
            left,
            present,
            cand,
            nb,
            s,
            common,
            n,
            grow_gap,
            group_radius,
        )
    return groups


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
