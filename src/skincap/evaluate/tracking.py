"""Rope tracking measured against ground truth, as Porter (2012) measures it (§4, Fig. 4.4).

Two measurements on a synthetic take whose every point has a known true label:

* **Classification.** Every point of the cloud is either taken by the rope tracker
  (rope) or left for the body; against the truth (``rope_NN`` labels) this gives
  precision, recall and F1 of the rope class and the confusion counts.
* **Gap repair by hold-back.** Starting from the un-indexed cloud, the points of one
  rope marker (and, as a separate case, of two markers adjacent along the rope) are
  removed for ``n`` frames from a start frame, the tracker runs on what is left, and
  the positions it invents over the gap are compared with the true positions there.
  ``n`` grows 10, 20, 30, … until the tracker loses the marker (it strays more than
  ``lost_distance`` = 0.5 m from the truth), at many seeded start frames. The mean
  error per gap size and case is the thesis' Fig. 4.4; the thesis reports under 0.1 m
  for 10–30-frame gaps.

The tracker is passed in as a function ``cloud -> track`` so the harness can measure
any tracker with the :class:`~skincap.tracking.tracker.RopeTrack` interface
(``positions (T, K, 3)``, ``invented (T, K)``, ``rope_points_mask(cloud)``);
:func:`rope_tracker_from_truth` builds the default one (initialised from the true
rope points of frame 0, like a user's selection). Nothing here reads files: the CLI
(``skincap eval track``) does.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from skincap._arrays import Progress
from skincap.errors import ValidationError
from skincap.types import MarkerSet, PointCloud

__all__ = [
    "THESIS",
    "TARGETS",
    "TrackLike",
    "rope_truth_mask",
    "classification_scores",
    "classify_points",
    "hold_back_points",
    "crop_frames",
    "match_traces_to_truth",
    "gap_errors",
    "evaluate_gap_repair",
    "rope_tracker_from_truth",
    "evaluate_tracking",
    "target_summary",
    "plot_gap_repair",
]

#: The thesis' figures (Porter 2012, §4): gap-repair error under 0.1 m for 10–30 frames.
THESIS: dict[str, Any] = {"gap_error_10_30_m": 0.1}

#: The targets of issue #6.
TARGETS: dict[str, Any] = {
    "f1": 0.99,
    "single_gap_error_10_30_m": 0.02,
    "single_no_loss_up_to_frames": 60,
    "adjacent_gap_error_30_m": 0.05,
}

CASES: dict[str, int] = {"single": 1, "adjacent": 2}


class TrackLike(Protocol):
    """What the harness needs of a tracker's result (a ``RopeTrack``)."""

    positions: np.ndarray  # (T, K, 3) float64 metres, NaN where the trace has no position
    invented: np.ndarray  # (T, K) bool: True where the position was invented

    def rope_points_mask(self, cloud: PointCloud) -> np.ndarray:  # (M,) bool
        ...


TrackFn = Callable[[PointCloud], TrackLike]


# ----------------------------------------------------------------- classification
def rope_truth_mask(point_truth: np.ndarray) -> np.ndarray:
    """(M,) bool: True where a point's true label is a rope marker (``rope_NN``).

    Parameters
    ----------
    point_truth : (M,) str
        True label per point: ``rope_NN``, a body marker label, or ``ghost``.
    """
    truth = np.asarray(point_truth).astype(str)
    if truth.ndim != 1:
        raise ValidationError(f"point_truth: expected (M,), got shape {truth.shape}")
    return np.char.startswith(truth, "rope_")


def classification_scores(predicted: np.ndarray, actual: np.ndarray) -> dict[str, Any]:
    """Precision, recall and F1 of the positive (rope) class, with the confusion counts.

    Parameters
    ----------
    predicted, actual : (M,) bool
        Predicted and true class per point (True = rope).

    Returns
    -------
    dict
        ``precision``, ``recall``, ``f1`` (floats in [0, 1]); ``true_positive``,
        ``false_positive``, ``false_negative``, ``true_negative``, ``points`` (ints).
        With nothing predicted rope precision is 0 (recall 0 likewise with nothing
        truly rope), except that when there is neither a predicted nor a true rope
        point all three scores are 1: there was nothing to find and nothing was
        wrongly found.
    """
    p = np.asarray(predicted)
    a = np.asarray(actual)
    if p.dtype != bool or a.dtype != bool:
        raise ValidationError(f"predicted/actual: expected bool arrays, got {p.dtype}/{a.dtype}")
    if p.ndim != 1 or p.shape != a.shape:
        raise ValidationError(
            f"predicted/actual: expected two (M,) arrays, got {p.shape} and {a.shape}"
        )
    tp = int(np.count_nonzero(p & a))
    fp = int(np.count_nonzero(p & ~a))
    fn = int(np.count_nonzero(~p & a))
    tn = int(np.count_nonzero(~p & ~a))
    if tp + fp + fn == 0:
        precision = recall = f1 = 1.0
    else:
        precision = tp / (tp + fp) if tp + fp else 0.0
        recall = tp / (tp + fn) if tp + fn else 0.0
        f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "precision": float(precision),
        "recall": float(recall),
        "f1": float(f1),
        "true_positive": tp,
        "false_positive": fp,
        "false_negative": fn,
        "true_negative": tn,
        "points": int(p.size),
    }


def classify_points(track: TrackLike, cloud: PointCloud, point_truth: np.ndarray) -> dict[str, Any]:
    """Score the tracker's rope/body split of every point against the truth.

    Parameters
    ----------
    track : RopeTrack-like
        Its ``rope_points_mask(cloud)`` gives the (M,) bool rope class per point.
    cloud : PointCloud
        The cloud the track was made from (M points).
    point_truth : (M,) str
        True label per point; ``rope_NN`` is rope, anything else (body markers,
        ``ghost``) is body.

    Returns
    -------
    dict
        :func:`classification_scores` plus ``ghosts_taken_as_rope`` (ghost points the
        rope took) and ``ghosts`` (ghost points in the cloud).
    """
    truth = np.asarray(point_truth).astype(str)
    if truth.shape != (cloud.points.shape[0],):
        raise ValidationError(
            f"point_truth: expected ({cloud.points.shape[0]},) labels, got shape {truth.shape}"
        )
    predicted = np.asarray(track.rope_points_mask(cloud), dtype=bool)
    scores = classification_scores(predicted, rope_truth_mask(truth))
    ghost = truth == "ghost"
    scores["ghosts"] = int(np.count_nonzero(ghost))
    scores["ghosts_taken_as_rope"] = int(np.count_nonzero(ghost & predicted))
    return scores


# ---------------------------------------------------------------------- hold-back
def hold_back_points(
    cloud: PointCloud,
    point_truth: np.ndarray,
    labels: Sequence[str],
    start: int,
    length: int,
) -> tuple[PointCloud, np.ndarray]:
    """Remove the points of the markers ``labels`` in frames ``start … start+length-1``.

    Parameters
    ----------
    cloud : PointCloud
        (M,) points over T frames; not modified.
    point_truth : (M,) str
        True label per point.
    labels : sequence of str
        The true labels whose points are held back (e.g. ``["rope_07"]``).
    start, length : int
        First held-back frame and the number of frames (the gap); the gap must lie
        within the take.

    Returns
    -------
    cloud : PointCloud
        A new cloud over the same T frames without those points (ids and meta kept).
    keep : (M,) bool
        Which points of the input survive, in order; ``point_truth[keep]`` labels the
        new cloud.
    """
    truth = np.asarray(point_truth).astype(str)
    if truth.shape != (cloud.points.shape[0],):
        raise ValidationError(
            f"point_truth: expected ({cloud.points.shape[0]},) labels, got shape {truth.shape}"
        )
    start, length = int(start), int(length)
    if length < 1 or start < 0 or start + length > cloud.n_frames:
        raise ValidationError(
            f"gap: frames {start}..{start + length - 1} do not lie within 0..{cloud.n_frames - 1}"
        )
    frame = cloud.frame_index
    drop = np.isin(truth, np.asarray(list(labels), dtype=str))
    drop &= (frame >= start) & (frame < start + length)
    keep = ~drop
    return cloud.select(keep), keep


def crop_frames(cloud: PointCloud, stop: int) -> PointCloud:
    """The first ``stop`` frames of ``cloud`` (all of it when ``stop >= T``)."""
    stop = int(min(max(stop, 1), cloud.n_frames))
    if stop == cloud.n_frames:
        return cloud
    keep = np.zeros(cloud.points.shape[0], dtype=bool)
    keep[: cloud.offsets[stop]] = True
    return cloud.select(keep, stop)


# ----------------------------------------------------------------------- matching
def match_traces_to_truth(
    positions: np.ndarray,
    invented: np.ndarray,
    truth: np.ndarray,
    *,
    max_distance: float = 0.06,
) -> tuple[np.ndarray, np.ndarray]:
    """Pair each tracked trace with the true rope marker it follows.

    The cost of trace ``k`` and truth marker ``r`` is their mean distance over the
    frames where the trace holds a real (not invented) finite position; the pairing
    minimises the total cost (``scipy.optimize.linear_sum_assignment``) and pairs
    farther apart than ``max_distance`` on average are dropped. This makes the
    measurement independent of the tracker's own label order.

    Parameters
    ----------
    positions : (T, K, 3) float64, metres
        The traces; NaN where a trace has no position (ignored).
    invented : (T, K) bool
        True where the trace's position was invented (ignored for matching).
    truth : (T, R, 3) float64, metres
        True rope marker positions, NaN-free where the truth exists.
    max_distance : float, metres
        Largest mean distance of an accepted pair (default half the 0.12 m tape spacing).

    Returns
    -------
    truth_of_trace : (K,) int64
        Truth column per trace, -1 where unmatched.
    cost : (K,) float64, metres
        Mean distance of each trace to its matched truth marker; NaN where unmatched.
    """
    from scipy.optimize import linear_sum_assignment

    pos = np.asarray(positions, dtype=np.float64)
    inv = np.asarray(invented, dtype=bool)
    tru = np.asarray(truth, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 3 or inv.shape != pos.shape[:2]:
        raise ValidationError(
            f"positions/invented: expected (T, K, 3) and (T, K), got {pos.shape} and {inv.shape}"
        )
    if tru.ndim != 3 or tru.shape[2] != 3 or tru.shape[0] != pos.shape[0]:
        raise ValidationError(f"truth: expected ({pos.shape[0]}, R, 3), got {tru.shape}")
    k_count, r_count = pos.shape[1], tru.shape[1]
    truth_of_trace = np.full(k_count, -1, dtype=np.int64)
    cost_of_trace = np.full(k_count, np.nan)
    if k_count == 0 or r_count == 0:
        return truth_of_trace, cost_of_trace
    d = np.linalg.norm(pos[:, :, None, :] - tru[:, None, :, :], axis=3)  # (T, K, R)
    usable = (~inv & np.isfinite(pos).all(axis=2))[:, :, None] & np.isfinite(d)  # (T, K, R)
    count = usable.sum(axis=0)  # (K, R)
    total = np.where(usable, d, 0.0).sum(axis=0)  # (K, R)
    big = 1e9
    cost = np.where(count > 0, total / np.maximum(count, 1), big)
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] <= max_distance
    truth_of_trace[rows[ok]] = cols[ok]
    cost_of_trace[rows[ok]] = cost[rows[ok], cols[ok]]
    return truth_of_trace, cost_of_trace


def gap_errors(positions: np.ndarray, truth: np.ndarray, start: int, length: int) -> np.ndarray:
    """Distance of the repaired positions to the truth over the gap frames only.

    Parameters
    ----------
    positions : (T, C, 3) float64, metres
        The traces that follow the held-back markers (C = 1 or 2); NaN where the
        tracker gave no position.
    truth : (T', C, 3) float64, metres
        The held-back markers' true positions (T' >= start + length).
    start, length : int
        The gap: frames ``start … start+length-1``.

    Returns
    -------
    (length, C) float64, metres; NaN where the trace had no position (a frame past
    the end of ``positions`` counts as no position).
    """
    pos = np.asarray(positions, dtype=np.float64)
    tru = np.asarray(truth, dtype=np.float64)
    stop = start + length
    if tru.shape[0] < stop:
        raise ValidationError(f"truth: has {tru.shape[0]} frames, the gap ends at {stop}")
    window = np.full((length, pos.shape[1], 3), np.nan)
    have = max(0, min(pos.shape[0], stop) - start)
    window[:have] = pos[start : start + have]
    return np.linalg.norm(window - tru[start:stop], axis=2)


# ---------------------------------------------------------------- gap-repair loop
def _summary_of_trials(
    errors: list[float], lost: list[bool], extra: dict[str, list[float]]
) -> dict[str, Any]:
    err = np.asarray(errors, dtype=np.float64)
    lost_arr = np.asarray(lost, dtype=bool)
    kept = err[~lost_arr & np.isfinite(err)]
    out: dict[str, Any] = {
        "trials": int(err.size),
        "lost": int(np.count_nonzero(lost_arr)),
        "mean_error_m": float(kept.mean()) if kept.size else None,
        "median_error_m": float(np.median(kept)) if kept.size else None,
        "max_error_m": float(kept.max()) if kept.size else None,
    }
    for key, values in extra.items():
        v = np.asarray(values, dtype=np.float64)
        v = v[~lost_arr & np.isfinite(v)]
        out[key] = float(v.mean()) if v.size else None
    return out


def evaluate_gap_repair(
    cloud: PointCloud,
    point_truth: np.ndarray,
    truth: np.ndarray,
    truth_labels: Sequence[str],
    track: TrackFn,
    *,
    truth_of_trace: np.ndarray,
    baseline: np.ndarray | None = None,
    gaps: Sequence[int] = (10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120),
    starts: int = 8,
    seed: int = 0,
    cases: Sequence[Literal["single", "adjacent"]] = ("single", "adjacent"),
    first_start: int = 0,
    after: int = 10,
    tail: int | None = 30,
    lost_distance: float = 0.5,
    stop_when_lost: bool = True,
    progress: Progress | None = None,
) -> dict[str, list[dict[str, Any]]]:
    """Hold back rope markers for growing gaps and measure the repaired positions.

    For each case (``single``: one marker; ``adjacent``: two markers next to each
    other along the rope) and each gap size ``n`` in increasing order, ``starts``
    trials draw, without repeats, a start frame ``s`` in ``[first_start, T - n - after]``
    and a marker (or adjacent pair) whose data is *known* through the whole window
    ``s … s+n+after-1`` — the thesis creates gaps "in the known data": the marker's
    point is measured (present in the cloud) in every frame of the window. The draw
    depends only on the take and ``(seed, case, n)`` (the generator's seed), never
    on a tracking result, so figures are comparable across tracker versions; a
    marker without a trace (``truth_of_trace`` has none for it) is a lost trial. The markers' points are removed in frames
    ``s … s+n-1`` (:func:`hold_back_points`), the cloud is cut ``tail`` frames after
    ``s+n+after`` (tracking is causal, frames further on cannot change the gap) and
    tracked, and the trace that follows each held-back marker is compared with the
    truth over the gap frames only (:func:`gap_errors`).

    A trial is **lost** when the trace is NaN or farther than ``lost_distance`` from
    the truth anywhere in the gap or in the ``after`` frames that follow it (it did not
    recover the marker). Errors are averaged over the gap frames and the held-back
    markers of a trial; the per-gap summaries average the trials that were not lost.
    With ``stop_when_lost`` a case stops after the first gap size at which at least
    half of the trials were lost ("until the tracker loses it").

    Parameters
    ----------
    cloud : PointCloud
        The un-indexed take, T frames, M points; not modified.
    point_truth : (M,) str
        True label per point.
    truth : (T, R, 3) float64, metres
        True positions of the rope markers, in order along the rope.
    truth_labels : sequence of R str
        Their labels (``rope_00`` …), as in ``point_truth``.
    track : callable(PointCloud) -> RopeTrack-like
        Runs the tracker; its traces keep their column order from run to run.
    truth_of_trace : (K,) int
        The truth column each trace follows, -1 for none
        (:func:`match_traces_to_truth` on a run without hold-back).
    baseline : (T, K, 3) float64, metres, optional
        The traces without hold-back; when given, each gap also reports
        ``baseline_error_m``, the tracker's error over the same frames with nothing
        held back (it does not change which trials are drawn).
    gaps : sequence of int
        Gap sizes in frames, evaluated in increasing order.
    starts : int
        Trials (start frames) per case and gap size.
    seed : int
    cases : sequence of {"single", "adjacent"}
    first_start : int
        Earliest gap start (after the tracker's initialisation window).
    after : int
        Frames after the gap in which the trace must be back within ``lost_distance``.
    tail : int or None
        Extra frames tracked past ``s+n+after``; None tracks the whole take.
    lost_distance : float, metres
    stop_when_lost : bool
    progress : callable(fraction, label), optional

    Returns
    -------
    dict
        ``{case: [{"gap", "candidates", "trials", "lost", "mean_error_m", "median_error_m",
        "max_error_m", "invented_fraction", "baseline_error_m"?}, …]}`` per gap size
        evaluated. ``candidates`` counts the known (start, marker) pairs, ``trials``
        is ``min(starts, candidates)``; errors are None when every trial was lost or
        no trial could be drawn.
        ``invented_fraction`` is the share of gap samples the tracker flagged as
        invented (below 1 means it took some other point in the held-back marker's
        place). ``flagged_lost`` (when the track has ``lost_frames``) counts trials
        in which the tracker itself flagged the trace lost in the gap or after it.
        ``detail`` lists every trial: ``start``, ``markers``, ``mean_error_m`` (over
        the gap), ``max_error_m`` (over the gap and the ``after`` frames), ``lost``.
    """
    truth_arr = np.asarray(truth, dtype=np.float64)
    labels = [str(x) for x in truth_labels]
    n_frames = cloud.n_frames
    if truth_arr.ndim != 3 or truth_arr.shape[0] != n_frames or truth_arr.shape[1] != len(labels):
        raise ValidationError(
            f"truth: expected ({n_frames}, {len(labels)}, 3), got {truth_arr.shape}"
        )
    tot = np.asarray(truth_of_trace, dtype=np.int64)
    trace_of_truth = np.full(len(labels), -1, dtype=np.int64)
    matched = tot >= 0
    trace_of_truth[tot[matched]] = np.flatnonzero(matched)
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise ValidationError(f"cases: expected 'single' and/or 'adjacent', got {unknown}")
    gap_sizes = sorted({int(g) for g in gaps})
    if not gap_sizes or gap_sizes[0] < 1:
        raise ValidationError(f"gaps: expected positive frame counts, got {list(gaps)}")
    if starts < 1:
        raise ValidationError(f"starts: expected at least 1, got {starts}")

    # Where the data is "known": the marker's point is measured in that frame. (T, R) bool.
    truth_text = np.asarray(point_truth).astype(str)
    if truth_text.shape != (cloud.points.shape[0],):
        raise ValidationError(
            f"point_truth: expected ({cloud.points.shape[0]},) labels, got {truth_text.shape}"
        )
    names, which = np.unique(truth_text, return_inverse=True)
    column_of_name = np.array([labels.index(x) if x in labels else -1 for x in names.tolist()])
    column = column_of_name[which].reshape(-1)
    frame_of_point = np.repeat(np.arange(n_frames), cloud.counts)
    known = np.zeros((n_frames, len(labels)), dtype=bool)
    on = column >= 0
    known[frame_of_point[on], column[on]] = True
    if baseline is not None:
        base_arr = np.asarray(baseline, dtype=np.float64)
        if base_arr.ndim != 3 or base_arr.shape[0] != n_frames or base_arr.shape[1] != tot.size:
            raise ValidationError(
                f"baseline: expected ({n_frames}, {tot.size}, 3), got {base_arr.shape}"
            )
    total_runs = len(cases) * len(gap_sizes) * starts
    runs_done = 0
    results: dict[str, list[dict[str, Any]]] = {}
    for case_index, case in enumerate(cases):
        width = CASES[case]
        # (T, R - width + 1): every marker of the group known in that frame.
        group = np.ones((n_frames, max(0, len(labels) - width + 1)), dtype=bool)
        for k in range(width):
            group &= known[:, k : k + group.shape[1]]
        csum = np.concatenate([np.zeros((1, group.shape[1]), np.int64), np.cumsum(group, axis=0)])
        rows: list[dict[str, Any]] = []
        for n in gap_sizes:
            window = n + after
            last_start = n_frames - window
            errors: list[float] = []
            lost: list[bool] = []
            invented_share: list[float] = []
            base_err: list[float] = []
            flagged: list[float] = []
            detail: list[dict[str, Any]] = []
            # (start, first column) pairs whose whole window is known.
            if last_start >= first_start and group.shape[1]:
                s_range = np.arange(first_start, last_start + 1)
                whole = (csum[s_range + window] - csum[s_range]) == window
                pairs = np.argwhere(whole)
                pairs[:, 0] += first_start
            else:
                pairs = np.zeros((0, 2), dtype=np.int64)
            if pairs.shape[0]:
                rng = np.random.default_rng([seed, case_index, n])
                pick = rng.choice(pairs.shape[0], size=min(starts, pairs.shape[0]), replace=False)
                trial_starts, trial_markers = pairs[pick, 0], pairs[pick, 1]
                for s, r0 in zip(trial_starts.tolist(), trial_markers.tolist(), strict=True):
                    columns = np.arange(r0, r0 + width)
                    traces = trace_of_truth[columns]
                    if (traces < 0).any():  # the tracker never had this marker
                        lost.append(True)
                        errors.append(np.nan)
                        detail.append(
                            {
                                "start": int(s),
                                "markers": [labels[c] for c in columns],
                                "mean_error_m": None,
                                "max_error_m": None,
                                "lost": True,
                            }
                        )
                        invented_share.append(np.nan)
                        if baseline is not None:
                            base_err.append(np.nan)
                        runs_done += 1
                        continue
                    held, _ = hold_back_points(
                        cloud, point_truth, [labels[c] for c in columns], s, n
                    )
                    if tail is not None:
                        held = crop_frames(held, s + n + after + tail)
                    result = track(held)
                    pos = np.asarray(result.positions, dtype=np.float64)[:, traces]
                    err = gap_errors(pos, truth_arr[:, columns], s, n + after)
                    gap_part = err[:n]
                    is_lost = bool(~np.isfinite(err).all() or np.nanmax(err) > lost_distance)
                    lost.append(is_lost)
                    errors.append(float(gap_part.mean()) if np.isfinite(gap_part).all() else np.nan)
                    finite = err[np.isfinite(err)]
                    detail.append(
                        {
                            "start": int(s),
                            "markers": [labels[c] for c in columns],
                            "mean_error_m": None if np.isnan(errors[-1]) else errors[-1],
                            "max_error_m": float(finite.max()) if finite.size else None,
                            "lost": is_lost,
                        }
                    )
                    flags = getattr(result, "lost_frames", None)
                    if flags is not None:
                        window = np.asarray(flags, dtype=bool)[s : s + n + after][:, traces]
                        flagged.append(float(window.any()))
                    inv = np.asarray(result.invented, dtype=bool)[s : s + n][:, traces]
                    invented_share.append(float(inv.mean()) if inv.size else np.nan)
                    if baseline is not None:
                        b = gap_errors(
                            np.asarray(baseline, dtype=np.float64)[:, traces],
                            truth_arr[:, columns],
                            s,
                            n,
                        )
                        base_err.append(float(b.mean()) if np.isfinite(b).all() else np.nan)
                    runs_done += 1
                    if progress is not None:
                        progress(runs_done / total_runs, f"{case} gap {n}")
            extra = {"invented_fraction": invented_share}
            if baseline is not None:
                extra["baseline_error_m"] = base_err
            row = {"gap": n, "candidates": int(pairs.shape[0])}
            row.update(_summary_of_trials(errors, lost, extra))
            if flagged:
                row["flagged_lost"] = int(sum(flagged))
            row["detail"] = detail
            rows.append(row)
            if stop_when_lost and (row["trials"] == 0 or 2 * row["lost"] >= row["trials"]):
                break
        results[case] = rows
    if progress is not None:
        progress(1.0, "done")
    return results


# --------------------------------------------------------------------- the whole
def rope_tracker_from_truth(cloud: PointCloud, point_truth: np.ndarray) -> TrackFn:
    """The default tracker: initialised by the true rope points of frame 0.

    This stands for the thesis' user selection (§3.4): the indices, among the first
    frame's points in file order, of the points whose true label is a rope marker are
    passed as ``init_rope(cloud, markers=…)``, then ``track_rope`` runs.

    Parameters
    ----------
    cloud : PointCloud
        The full take (frame 0 must be untouched by any hold-back).
    point_truth : (M,) str

    Returns
    -------
    callable(PointCloud) -> RopeTrack
    """
    from skincap.tracking.init import init_rope
    from skincap.tracking.tracker import track_rope

    first = rope_truth_mask(point_truth)[cloud.offsets[0] : cloud.offsets[1]]
    markers = np.flatnonzero(first)
    if markers.size < 2:
        raise ValidationError(
            f"point_truth: frame 0 shows {markers.size} rope point(s); the tracker needs at least 2"
        )

    def run(held: PointCloud) -> TrackLike:
        return track_rope(held, init_rope(held, markers=markers))

    return run


def target_summary(result: dict[str, Any]) -> dict[str, Any]:
    """Compare an :func:`evaluate_tracking` result with the issue's targets and the thesis.

    ``f1``: the rope class's F1. ``single_gap_error_10_30_m``: the largest per-gap
    mean error of the single-marker case over the 10–30-frame gaps (met only with no
    lost trial there). ``single_no_loss_up_to_60``: lost single-marker trials over
    gaps up to 60 frames (evaluated only when a gap of 60 or more was run).
    ``adjacent_gap_error_30_m``: the two-adjacent case's mean error at exactly 30
    frames (met only with no lost trial).

    Returns
    -------
    dict of target name -> ``{"value", "target", "thesis", "met"}``; ``met`` is None
    when the evaluation did not cover the target (e.g. no 60-frame gap was run).
    """
    out: dict[str, Any] = {}
    cls = result.get("classification")
    f1 = None if cls is None else cls["f1"]
    out["f1"] = {
        "value": f1,
        "target": f">= {TARGETS['f1']}",
        "thesis": None,
        "met": None if f1 is None else bool(f1 >= TARGETS["f1"]),
    }
    rows = result.get("gap_repair", {})
    single = rows.get("single", [])
    short = [r for r in single if 10 <= r["gap"] <= 30]
    errs = [r["mean_error_m"] for r in short]
    worst = None if not short or any(e is None for e in errs) else max(errs)
    any_lost_short = any(r["lost"] for r in short)
    out["single_gap_error_10_30_m"] = {
        "value": worst,
        "target": f"<= {TARGETS['single_gap_error_10_30_m']}",
        "thesis": f"< {THESIS['gap_error_10_30_m']}",
        "met": None
        if not short
        else bool(
            worst is not None
            and not any_lost_short
            and worst <= TARGETS["single_gap_error_10_30_m"]
        ),
    }
    limit = TARGETS["single_no_loss_up_to_frames"]
    upto = [r for r in single if r["gap"] <= limit and r["trials"]]
    covered = any(r["gap"] >= limit and r["trials"] for r in single)
    lost_upto = sum(r["lost"] for r in upto)
    out["single_no_loss_up_to_60"] = {
        "value": lost_upto if upto else None,
        "target": f"0 lost for gaps <= {limit} frames",
        "thesis": None,
        "met": None if not covered else bool(lost_upto == 0),
    }
    adjacent = [r for r in rows.get("adjacent", []) if r["gap"] == 30 and r["trials"]]
    adj = adjacent[0] if adjacent else None
    out["adjacent_gap_error_30_m"] = {
        "value": None if adj is None else adj["mean_error_m"],
        "target": f"<= {TARGETS['adjacent_gap_error_30_m']}",
        "thesis": None,
        "met": None
        if adj is None
        else bool(
            adj["mean_error_m"] is not None
            and adj["lost"] == 0
            and adj["mean_error_m"] <= TARGETS["adjacent_gap_error_30_m"]
        ),
    }
    return out


def evaluate_tracking(
    cloud: PointCloud,
    point_truth: np.ndarray,
    truth: MarkerSet,
    *,
    track: TrackFn | None = None,
    gaps: Sequence[int] = (10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120),
    starts: int = 8,
    seed: int = 0,
    cases: Sequence[Literal["single", "adjacent"]] = ("single", "adjacent"),
    first_start: int | None = None,
    after: int = 10,
    tail: int | None = 30,
    lost_distance: float = 0.5,
    stop_when_lost: bool = True,
    max_match_distance: float = 0.06,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Evaluate rope tracking on a take with ground truth: classification and gap repair.

    1. The tracker runs once on the whole cloud (the baseline). Its traces are paired
       with the true rope markers (:func:`match_traces_to_truth`), its rope/body split
       of every point is scored (:func:`classify_points`), and its error on the
       followed markers is reported.
    2. :func:`evaluate_gap_repair` holds back one marker, then two adjacent markers,
       for growing gaps at ``starts`` seeded start frames.
    3. :func:`target_summary` compares the numbers with the issue's targets and the
       thesis'.

    Parameters
    ----------
    cloud : PointCloud
        The un-indexed take (T frames, M points), e.g. ``SynthCapture.points``.
    point_truth : (M,) str
        True label per point (``rope_NN``, body label or ``ghost``).
    truth : MarkerSet
        Clean labelled positions over the same T frames; its ``rope_NN`` columns are
        the rope truth (metres, no NaN expected; NaN samples are ignored).
    track : callable(PointCloud) -> RopeTrack-like, optional
        Default :func:`rope_tracker_from_truth`.
    gaps, starts, seed, cases, after, tail, lost_distance, stop_when_lost
        See :func:`evaluate_gap_repair` (the baseline run is its ``baseline``).
    first_start : int, optional
        Earliest gap start; default the end of the initialisation window, taken as the
        first frame where any true rope marker has moved 2 cm from frame 0 (at least
        10 frames).
    max_match_distance : float, metres
        See :func:`match_traces_to_truth`.
    progress : callable(fraction, label), optional

    Returns
    -------
    dict (JSON-ready)
        ``frames``, ``rate``, ``points``, ``points_per_frame``, ``rope_markers``,
        ``traces``, ``followed`` (traces paired with a true marker),
        ``classification`` (with ``followed_markers_recall``: recall over the points
        of the rope markers that have a trace), ``baseline`` (``mean_error_real_m``
        and ``mean_error_all_m`` of the followed traces over their real and over all
        samples, ``invented_fraction``, ``followed_2cm_fraction``: the share of all
        frame × true-marker samples a trace follows within 2 cm), ``gap_repair`` (see
        :func:`evaluate_gap_repair`), ``settings``, ``thesis``, ``targets``.
    """
    truth_labels = [lab for lab in truth.labels if lab.startswith("rope_")]
    if not truth_labels:
        raise ValidationError("truth: has no rope_NN markers; evaluate a take made with a rope")
    if truth.n_frames != cloud.n_frames:
        raise ValidationError(f"truth: has {truth.n_frames} frames, the cloud {cloud.n_frames}")
    truth_labels.sort()
    columns = [truth.labels.index(lab) for lab in truth_labels]
    rope_truth = truth.positions[:, columns]  # (T, R, 3)
    truth_text = np.asarray(point_truth).astype(str)
    if truth_text.shape != (cloud.points.shape[0],):
        raise ValidationError(
            f"point_truth: expected ({cloud.points.shape[0]},) labels, got shape {truth_text.shape}"
        )
    if track is None:
        track = rope_tracker_from_truth(cloud, truth_text)
    if first_start is None:
        moved = np.linalg.norm(rope_truth - rope_truth[:1], axis=2)  # (T, R)
        moving = np.flatnonzero(np.nan_to_num(moved, nan=0.0).max(axis=1) > 0.02)
        first_start = max(10, int(moving[0]) if moving.size else 10)

    def sub(lo: float, hi: float) -> Progress | None:
        if progress is None:
            return None
        return lambda f, label: progress(lo + (hi - lo) * f, label)

    if progress is not None:
        progress(0.0, "baseline")
    base = track(cloud)
    positions = np.asarray(base.positions, dtype=np.float64)
    invented = np.asarray(base.invented, dtype=bool)
    truth_of_trace, cost = match_traces_to_truth(
        positions, invented, rope_truth, max_distance=max_match_distance
    )
    classification = classify_points(base, cloud, truth_text)
    followed = truth_of_trace >= 0
    # Recall over the rope markers that have a trace: markers the tracker never had
    # (e.g. unseen in the initialisation window) are what separates it from recall.
    of_followed = np.isin(truth_text, [truth_labels[c] for c in truth_of_trace[followed]])
    taken = np.asarray(base.rope_points_mask(cloud), dtype=bool)
    n_of = int(np.count_nonzero(of_followed))
    classification["followed_markers_recall"] = (
        float(np.count_nonzero(taken & of_followed) / n_of) if n_of else None
    )
    if followed.any():
        d = np.linalg.norm(positions[:, followed] - rope_truth[:, truth_of_trace[followed]], axis=2)
        finite = np.isfinite(d)
        real = finite & ~invented[:, followed]
        base_all = float(d[finite].mean()) if finite.any() else None
        base_real = float(d[real].mean()) if real.any() else None
        inv_frac = float(invented[:, followed].mean())
        # Share of all (frame, true rope marker) samples followed within 2 cm.
        near = np.nan_to_num(d, nan=np.inf) <= 0.02
        known_frac = float(np.count_nonzero(near) / (d.shape[0] * len(truth_labels)))
    else:
        base_all = base_real = inv_frac = None
        known_frac = 0.0
    gap_repair = evaluate_gap_repair(
        cloud,
        truth_text,
        rope_truth,
        truth_labels,
        track,
        truth_of_trace=truth_of_trace,
        baseline=positions,
        gaps=gaps,
        starts=starts,
        seed=seed,
        cases=cases,
        first_start=first_start,
        after=after,
        tail=tail,
        lost_distance=lost_distance,
        stop_when_lost=stop_when_lost,
        progress=sub(0.05, 1.0),
    )
    result: dict[str, Any] = {
        "frames": cloud.n_frames,
        "rate": float(cloud.rate),
        "points": int(cloud.points.shape[0]),
        "points_per_frame": float(cloud.counts.mean()) if cloud.n_frames else 0.0,
        "rope_markers": len(truth_labels),
        "traces": int(positions.shape[1]),
        "followed": int(np.count_nonzero(followed)),
        "trace_truth": [truth_labels[c] if c >= 0 else None for c in truth_of_trace.tolist()],
        "trace_match_error_m": [None if not np.isfinite(c) else float(c) for c in cost],
        "classification": classification,
        "baseline": {
            "mean_error_real_m": base_real,
            "mean_error_all_m": base_all,
            "invented_fraction": inv_frac,
            "followed_2cm_fraction": known_frac,
        },
        "gap_repair": gap_repair,
        "settings": {
            "gaps": sorted({int(g) for g in gaps}),
            "starts": int(starts),
            "seed": int(seed),
            "cases": list(cases),
            "first_start": int(first_start),
            "after": int(after),
            "tail": None if tail is None else int(tail),
            "lost_distance_m": float(lost_distance),
            "trials_drawn_from": "measured data (take and seed only)",
            "stop_when_lost": bool(stop_when_lost),
        },
        "thesis": dict(THESIS),
    }
    result["targets"] = target_summary(result)
    return result


# ------------------------------------------------------------------------- plot
def plot_gap_repair(
    result: dict[str, Any],
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    title: str | None = None,
) -> Path:
    """Plot the mean gap-repair error against the gap size (the thesis' Fig. 4.4) as PNG.

    One line per case (one marker held back, two adjacent markers), the number of
    lost trials written beside each point, and the thesis' 0.1 m level for reference.

    Parameters
    ----------
    result : dict
        From :func:`evaluate_tracking` (uses ``result["gap_repair"]``).
    path : path-like
        The PNG to write (atomically; an existing file only with ``force``).
    title : str, optional

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed (extra ``plot``).
    """
    from skincap.viz.plotting import agg_pyplot

    plt = agg_pyplot("PNG plots")

    from skincap.io._common import atomic_output

    names = {"single": "one marker held back", "adjacent": "two adjacent markers held back"}
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    try:
        top = THESIS["gap_error_10_30_m"]
        for case, rows in result.get("gap_repair", {}).items():
            pts = [(r["gap"], r["mean_error_m"], r["lost"], r["trials"]) for r in rows]
            pts = [p for p in pts if p[1] is not None]
            if not pts:
                continue
            x = [p[0] for p in pts]
            y = [p[1] for p in pts]
            top = max(top, max(y))
            (line,) = ax.plot(x, y, marker="o", label=names.get(case, case))
            for gx, gy, n_lost, n_trials in pts:
                if n_lost:
                    ax.annotate(
                        f"{n_lost}/{n_trials} lost",
                        (gx, gy),
                        textcoords="offset points",
                        xytext=(4, 4),
                        fontsize=7,
                        color=line.get_color(),
                    )
        ax.axhline(
            THESIS["gap_error_10_30_m"],
            color="0.4",
            linestyle="--",
            linewidth=1,
            label="thesis: 0.1 m (10-30 frames)",
        )
        ax.set_ylim(0.0, top * 1.15)
        ax.set_xlabel("gap size (frames)")
        ax.set_ylabel("mean repair error over the gap (m)")
        ax.set_title(title or "Gap repair error as the gap size varies")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        with atomic_output(path, force=force) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return Path(path)
