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
from typing import Any, NamedTuple

import numpy as np

from skincap._arrays import Progress, missing_runs
from skincap.cleanup.local_frames import estimate_missing, neighbour_table
from skincap.cleanup.settings import MergeSettings
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


class _Runs(NamedTuple):
    """Every contiguous run of a fragment column: one unlabelled trajectory each.

    ``column`` (F,) the column of ``markers`` holding run f, ``start``/``end`` (F,) its
    frames ``[start, end)``, ``present`` (T, F) bool, ``positions`` (T, F, 3) metres
    (NaN outside the run), ``per_column`` (Fc,) runs in each fragment column,
    ``frag_cols`` (Fc,) the fragment columns.
    """

    column: np.ndarray
    start: np.ndarray
    end: np.ndarray
    present: np.ndarray
    positions: np.ndarray
    per_column: np.ndarray
    frag_cols: np.ndarray

    @property
    def length(self) -> np.ndarray:
        return self.end - self.start


def _fragment_runs(pos: np.ndarray, frag_cols: np.ndarray) -> _Runs:
    """Step 1: the runs of the fragment columns (a gappy ``*N`` column holds several)."""
    t_count = pos.shape[0]
    col_present = np.isfinite(pos[:, frag_cols]).all(axis=2)  # (T, Fc)
    # runs of *present* samples, sorted by column then start
    run_col, run_start, run_len = missing_runs(col_present)
    run_end = run_start + run_len
    frags = frag_cols[run_col]  # (F,) column of each run
    frames_idx = np.arange(t_count)[:, None]
    present = (frames_idx >= run_start[None, :]) & (frames_idx < run_end[None, :])  # (T, F)
    positions = np.where(present[..., None], pos[:, frags], np.nan)  # (T, F, 3)
    per_column = np.bincount(run_col, minlength=frag_cols.size)
    return _Runs(frags, run_start, run_end, present, positions, per_column, frag_cols)


class _Candidates(NamedTuple):
    """Fragment-marker pairs of one pass: run ``fi`` (P,), marker ``ci`` (P,), whether
    the pair passes the paper's tests (``ok``), and its mean distance to the marker's
    estimate (``mean_d``, metres, inf when never estimated)."""

    fi: np.ndarray
    ci: np.ndarray
    ok: np.ndarray
    mean_d: np.ndarray


def _candidates(
    runs: _Runs,
    open_f: np.ndarray,
    est: np.ndarray,
    anchor_present: np.ndarray,
    eps1: np.ndarray,
    eps2: np.ndarray,
) -> _Candidates | None:
    """Step 2: pairs of an open fragment and a missing marker near it (eq. 3).

    Loose candidates (within ε² in the fragment's first frame) compete in the ambiguity
    test; strict ones (ε¹ there, ε² in every frame estimated, estimates in at least
    half its frames, no overlap in time with the marker) may win.
    """
    first = runs.start
    f0 = first[open_f]
    p0 = runs.positions[f0, open_f]  # (Fo, 3)
    d0 = np.linalg.norm(est[f0] - p0[:, None, :], axis=2)  # (Fo, N), NaN if no estimate
    cand = (d0 < np.maximum(eps1, eps2)[None, :]) & ~anchor_present[f0]
    cf, ci = np.nonzero(cand)
    fi = open_f[cf]
    if fi.size == 0:
        return None
    strict = d0[cf, ci] < eps1[ci]
    # no temporal overlap with the marker's current trajectory
    free = ~_overlaps(runs.present[:, fi], anchor_present[:, ci])
    fi, ci, strict = fi[free], ci[free], strict[free]
    # ε² in every frame the fragment spans
    dist = np.linalg.norm(est[:, ci] - runs.positions[:, fi], axis=2)  # (T, P)
    checked = np.isfinite(dist)
    within = np.where(checked, dist < eps2[ci][None, :], True).all(axis=0)
    enough = 2 * checked.sum(axis=0) >= runs.length[fi]
    ok = strict & within & enough
    mean_d = np.where(checked, dist, 0.0).sum(axis=0) / np.maximum(checked.sum(axis=0), 1)
    mean_d = np.where(checked.any(axis=0), mean_d, np.inf)
    return _Candidates(fi, ci, ok, mean_d)


def _accept_beyond_paper(
    cands: _Candidates,
    runs: _Runs,
    est: np.ndarray,
    anchor_present: np.ndarray,
    surface: MarkerSurface,
    spacing: np.ndarray,
    rivals: tuple[np.ndarray, np.ndarray],
    settings: MergeSettings,
) -> np.ndarray:
    """Step 3a: ``ok`` narrowed by the neighbour-identity margin and the prediction test
    (``settings.neighbour_check``, ``prediction_factor``); (P,) bool."""
    ok = cands.ok.copy()
    if not (settings.neighbour_check and ok.any()):
        return ok
    fi, ci = cands.fi, cands.ci
    okp = np.flatnonzero(ok)
    e90_all, calibrated = _prediction_error(
        est, anchor_present, surface, calibrate=settings.calibrate
    )
    d_mark, d_other, worse = _neighbour_identity_margin(
        est,
        anchor_present,
        surface,
        runs.positions,
        runs.present,
        fi[okp],
        ci[okp],
        rivals,
        calibrated,
    )
    # short fragments are weak evidence: the margin grows as they shrink
    length = runs.length[fi[okp]]
    short_frames = settings.short_frames
    margin = settings.rival_ratio * np.minimum(1.0, length / max(short_frames, 1))
    by_fit = d_mark < margin * d_other
    by_time = (cands.mean_d[okp] < 0.5 * margin * d_other) & (d_mark < 2.5 * margin * d_other)
    ok[okp] = ~worse & (by_fit | by_time)
    if settings.prediction_factor is not None:
        e90 = e90_all[ci[okp]]
        floor = 0.1 * spacing[ci[okp]]
        scale = np.where(np.isfinite(e90), np.maximum(e90, floor), np.inf)
        ok[okp] &= d_mark <= settings.prediction_factor * scale
        # a short fragment is too little evidence for a marker its
        # neighbours predict poorly (a ghost near the estimate fits as well)
        short = length < short_frames
        ok[okp] &= ~short | (np.nan_to_num(e90, nan=np.inf) <= 0.2 * spacing[ci[okp]])
    return ok


def _clear_winners(
    cands: _Candidates, ok: np.ndarray, ambiguity_ratio: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 3b: per fragment, its best valid match when clearly closer than any other
    marker whose estimate comes near (valid or not). Returns run, marker and mean
    distance (W,) of the winners."""
    order = np.lexsort((cands.mean_d, cands.fi))
    fi, ci, mean_d, ok = cands.fi[order], cands.ci[order], cands.mean_d[order], ok[order]
    head = np.ones(fi.size, dtype=bool)
    head[1:] = fi[1:] != fi[:-1]
    same_next = np.zeros(fi.size, dtype=bool)
    same_next[:-1] = fi[1:] == fi[:-1]
    second = np.full(fi.size, np.inf)
    second[:-1] = np.where(same_next[:-1], mean_d[1:], np.inf)
    clear = head & ok & (mean_d < ambiguity_ratio * second)
    return fi[clear], ci[clear], mean_d[clear]


@dataclass
class _MergeState:
    """What the passes build: the anchors' samples so far ``cur`` (T, N, 3), their
    residuals, invented flags and camera masks (T, N) (None when the input has none),
    and the anchor index each run joined, ``target`` (F,) int, -1 while open."""

    cur: np.ndarray
    res: np.ndarray | None
    inv: np.ndarray | None
    target: np.ndarray
    cam: np.ndarray | None = None


def _join_chains(
    state: _MergeState,
    markers: MarkerSet,
    runs: _Runs,
    winners: tuple[np.ndarray, np.ndarray, np.ndarray],
    anchor_present: np.ndarray,
) -> int:
    """Step 3c: per marker, closest first, join the winners that do not overlap (a
    chain of fragments may join one marker in one pass); in place on ``state``.
    Returns how many joined."""
    fi, ci, mean_d = winners
    order = np.argsort(mean_d, kind="stable")
    taken = anchor_present.copy()
    merged_now = 0
    for f, i in zip(fi[order].tolist(), ci[order].tolist(), strict=True):
        frames = runs.present[:, f]
        if np.any(taken[frames, i]):
            continue
        taken[frames, i] = True
        state.target[f] = i
        state.cur[frames, i] = runs.positions[frames, f]
        col = runs.column[f]
        if state.res is not None and markers.residuals is not None:
            state.res[frames, i] = markers.residuals[frames, col]
        if state.inv is not None and markers.invented is not None:
            state.inv[frames, i] = markers.invented[frames, col]
        if state.cam is not None and markers.camera_masks is not None:
            state.cam[frames, i] = markers.camera_masks[frames, col]
        merged_now += 1
    return merged_now


def _assemble(
    markers: MarkerSet, anchors: np.ndarray, runs: _Runs, state: _MergeState
) -> tuple[MarkerSet, np.ndarray]:
    """Step 4: anchor columns then the leftover columns with their unmerged runs
    (all-NaN columns dropped). Returns the capture and the input columns kept."""
    pos = markers.positions
    t_count, c_count, _ = pos.shape
    gone = runs.present[:, state.target >= 0]  # (T, Fm)
    removed = np.zeros((t_count, c_count), dtype=bool)
    np.logical_or.at(removed.T, runs.column[state.target >= 0], gone.T)
    left = np.unique(runs.column[state.target < 0])
    keep_cols = np.concatenate([anchors, left])
    rest = np.where(removed[:, left, None], np.nan, pos[:, left])
    out_res = (
        None
        if state.res is None or markers.residuals is None
        else np.concatenate(
            [state.res, np.where(removed[:, left], np.nan, markers.residuals[:, left])], 1
        )
    )
    out_inv = (
        None
        if state.inv is None or markers.invented is None
        else np.concatenate([state.inv, markers.invented[:, left] & ~removed[:, left]], axis=1)
    )
    out_cam = (
        None
        if state.cam is None or markers.camera_masks is None
        else np.concatenate(
            [state.cam, np.where(removed[:, left], 0, markers.camera_masks[:, left])], axis=1
        )
    )
    labels = list(markers.labels)
    out = MarkerSet(
        positions=np.concatenate([state.cur, rest], axis=1),
        labels=[labels[c] for c in keep_cols],
        rate=markers.rate,
        meta=dict(markers.meta),
        residuals=out_res,
        invented=out_inv,
        camera_masks=out_cam,
    )
    return out, keep_cols


def _report(
    labels: list[str],
    anchors: np.ndarray,
    runs: _Runs,
    target: np.ndarray,
    kept_columns: int,
    passes: int,
    settings: MergeSettings,
    fragment_truth: dict[str, str] | None,
) -> MergeReport:
    """Step 5: Table 1's counts and the assignments, wrong merges counted with truth."""
    col_of = {int(c): k for k, c in enumerate(runs.frag_cols.tolist())}
    frags = runs.column

    def run_name(f: int) -> str:
        col = int(frags[f])
        if runs.per_column[col_of[col]] == 1:
            return labels[col]
        return f"{labels[col]}[{int(runs.start[f])}:{int(runs.end[f])}]"

    merged_runs = np.flatnonzero(target >= 0).tolist()
    assignments = {run_name(f): labels[anchors[target[f]]] for f in merged_runs}
    left_run = target < 0
    wrong: int | None = None
    left_count = int(left_run.sum())
    left_frames: int | None = None
    if fragment_truth is not None:

        def truth(label: str) -> str:
            return fragment_truth.get(label, label)

        anchor_truth = {truth(labels[a]) for a in anchors.tolist()}
        wrong = sum(
            truth(labels[frags[f]]) != truth(labels[anchors[target[f]]]) for f in merged_runs
        )
        should = np.array(
            [truth(labels[c]) in anchor_truth for c in frags[left_run].tolist()], dtype=bool
        )
        left_count = int(should.sum())
        left_frames = int(runs.length[left_run][should].sum())
    merged_count = len(assignments)
    return MergeReport(
        trajectories_before=len(labels),
        trajectories_after=int(kept_columns),
        fragments_before=int(frags.size),
        fragments_after=int(left_run.sum()),
        merged=merged_count,
        wrongly_merged=wrong,
        wrong_rate=None if wrong is None else (wrong / merged_count if merged_count else 0.0),
        left_unmerged=left_count,
        left_unmerged_frames=left_frames,
        passes=passes,
        alpha1=float(settings.alpha1),
        alpha2=float(settings.alpha2),
        assignments=assignments,
    )


def _check_anchors(markers: MarkerSet, surface: MarkerSurface, anchors: Any) -> np.ndarray:
    """The anchor columns as (N,) int64, checked against the capture and the surface."""
    c_count = markers.positions.shape[1]
    if anchors is None:
        anchors = np.flatnonzero([not str(lab).startswith("*") for lab in markers.labels])
    anchors = np.asarray(anchors, dtype=np.int64)
    n = anchors.size
    if surface.n_markers != n:
        raise ValidationError(
            f"surface has {surface.n_markers} markers but {n} anchor columns were given"
        )
    if n and (anchors.min() < 0 or anchors.max() >= c_count or np.unique(anchors).size != n):
        raise ValidationError(f"anchors must be distinct columns in 0..{c_count - 1}")
    return anchors


def merge_fragments(
    markers: MarkerSet,
    surface: MarkerSurface,
    anchors: np.ndarray | None = None,
    settings: MergeSettings = MergeSettings(),
    *,
    fragment_truth: dict[str, str] | None = None,
    progress: Progress | None = None,
) -> tuple[MarkerSet, MergeReport]:
    """Merge unlabelled fragments into the markers of the marker surface.

    The method is the module docstring's, run as named steps: the fragment columns'
    runs (:func:`_fragment_runs`); then passes of estimate -> candidates
    (:func:`_candidates`, eq. 3) -> accept (:func:`_accept_beyond_paper`,
    :func:`_clear_winners`) -> join (:func:`_join_chains`) until nothing joins or
    ``settings.max_passes``; then assemble the output (:func:`_assemble`) and count
    (:func:`_report`).

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
    settings : MergeSettings
        Tolerances and the tests beyond the paper (each field documented there).
        Fragments shorter than ``settings.min_frames`` stay unmerged: a single-frame
        fragment is the weakest evidence there is (one distance, no motion); left
        alone, its sample is filled by the hole filler instead.
        ``neighbour_check`` refuses a fragment that lies nearly as close to where one
        of the marker's *missing neighbours* should be (its estimate, or where the
        marker's neighbourhood fit puts it when it has none) as to the marker: the
        mean distance to the marker must be below ``rival_ratio`` times the mean
        distance to the nearest missing neighbour (or, where the skin deforms and the
        fit is off, the temporal estimate must explain it with half that ratio and
        the fit with 2.5 times it), and no missing neighbour may be nearer in any
        frame. A neighbour without an estimate never competes in the paper's test,
        yet it is the likeliest owner of a fragment near a crease. The figures that
        chose these margins are in ``docs/results.md``.
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
    anchors = _check_anchors(markers, surface, anchors)
    pos = markers.positions
    n = anchors.size
    is_anchor = np.zeros(pos.shape[1], dtype=bool)
    is_anchor[anchors] = True
    runs = _fragment_runs(pos, np.flatnonzero(~is_anchor))
    state = _MergeState(
        cur=pos[:, anchors].copy(),  # (T, N, 3)
        res=None if markers.residuals is None else markers.residuals[:, anchors].copy(),
        inv=None if markers.invented is None else markers.invented[:, anchors].copy(),
        target=np.full(runs.column.size, -1, dtype=np.int64),
        cam=None if markers.camera_masks is None else markers.camera_masks[:, anchors].copy(),
    )
    spacing = neighbour_spacing(surface, robust=settings.robust_spacing)
    eps1 = settings.alpha1 * spacing  # ε¹, eq. 3 (NaN without neighbours: never matched)
    eps2 = settings.alpha2 * spacing  # ε²
    rivals = _rivals(surface, spacing)
    passes = 0
    for passes in range(1, settings.max_passes + 1):
        open_f = np.flatnonzero((state.target < 0) & (runs.length >= settings.min_frames))
        if open_f.size == 0 or n == 0:
            break
        est, _ = estimate_missing(state.cur, surface, surface.reference, temporal=settings.temporal)
        anchor_present = np.isfinite(state.cur).all(axis=2)  # (T, N)
        cands = _candidates(runs, open_f, est, anchor_present, eps1, eps2)
        if cands is None:
            break
        ok = _accept_beyond_paper(
            cands, runs, est, anchor_present, surface, spacing, rivals, settings
        )
        winners = _clear_winners(cands, ok, settings.ambiguity_ratio)
        merged_now = _join_chains(state, markers, runs, winners, anchor_present)
        if progress is not None:
            progress(passes / settings.max_passes, "merging fragments")
        if merged_now == 0:
            break
    out, keep_cols = _assemble(markers, anchors, runs, state)
    labels = [str(lab) for lab in markers.labels]
    report = _report(
        labels, anchors, runs, state.target, keep_cols.size, passes, settings, fragment_truth
    )
    return out, report
