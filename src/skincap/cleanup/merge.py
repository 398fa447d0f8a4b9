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

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.cleanup.local_frames import estimate_missing, neighbour_table
from skincap.cleanup.surface import MarkerSurface
from skincap.errors import ValidationError
from skincap.geometry.rigid import fit_rigid
from skincap.types import MarkerSet

__all__ = ["MergeReport", "merge_fragments", "neighbour_spacing"]


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
    progress: Progress | None = None,
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
