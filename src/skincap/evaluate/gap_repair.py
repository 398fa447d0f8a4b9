"""Gap repair by hold-back, as Porter (2012) measures it (§4, Fig. 4.4).

Starting from the un-indexed cloud, the points of one rope marker (and, as a separate
case, of two markers adjacent along the rope) are removed for ``n`` frames from a start
frame, the tracker runs on what is left, and the positions it invents over the gap are
compared with the true positions there. ``n`` grows 10, 20, 30, … until the tracker
loses the marker (it strays more than ``lost_distance`` = 0.5 m from the truth), at many
seeded start frames. The mean error per gap size and case is the thesis' Fig. 4.4; the
thesis reports under 0.1 m for 10–30-frame gaps.

The tracker is passed in as a function ``cloud -> track`` (:data:`TrackFn`), so any
tracker with the :class:`~skincap.tracking.tracker.RopeTrack` interface can be measured.
:mod:`skincap.evaluate.tracking` runs this after the classification measurement.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from skincap._arrays import Progress
from skincap.errors import ValidationError
from skincap.types import PointCloud

__all__ = [
    "CASES",
    "TrackLike",
    "TrackFn",
    "hold_back_points",
    "crop_frames",
    "gap_errors",
    "evaluate_gap_repair",
]

#: Held-back markers per case: one marker, or two adjacent along the rope.
CASES: dict[str, int] = {"single": 1, "adjacent": 2}


class TrackLike(Protocol):
    """What the harness needs of a tracker's result (a ``RopeTrack``)."""

    positions: np.ndarray  # (T, K, 3) float64 metres, NaN where the trace has no position
    invented: np.ndarray  # (T, K) bool: True where the position was invented

    def rope_points_mask(self, cloud: PointCloud) -> np.ndarray:  # (M,) bool
        ...


TrackFn = Callable[[PointCloud], TrackLike]


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
    depends only on the take and ``(seed, case, n)``, never on a tracking result, so
    figures are comparable across tracker versions; a marker without a trace
    (``truth_of_trace`` has none for it) is a lost trial. The markers' points are
    removed in frames ``s … s+n-1`` (:func:`hold_back_points`), the cloud is cut
    ``tail`` frames after ``s+n+after`` (tracking is causal) and tracked, and the
    trace that follows each held-back marker is compared with the truth over the gap
    frames only (:func:`gap_errors`).

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
    truth_arr, labels, trace_of_truth, gap_sizes = _checked_gap_inputs(
        cloud, truth, truth_labels, truth_of_trace, cases, gaps, starts, baseline
    )
    run = _HoldBackRun(cloud, point_truth, truth_arr, labels, track, trace_of_truth, baseline,
                       after, tail, lost_distance)  # fmt: skip
    known = _known_samples(cloud, point_truth, labels)
    total_trials, trials_done = len(cases) * len(gap_sizes) * starts, 0
    results: dict[str, list[dict[str, Any]]] = {}
    for case_index, case in enumerate(cases):
        width, rows = CASES[case], []
        known_before = _group_known_cumsum(known, width)
        for n in gap_sizes:
            pairs = _known_windows(known_before, n + after, first_start, cloud.n_frames)
            trials: list[dict[str, Any]] = []
            for s, r0 in _draw(pairs, starts, key=(seed, case_index, n)):
                trials.append(_gap_trial(run, np.arange(r0, r0 + width), s, n))
                trials_done += 1
                if progress is not None and trials[-1]["tracked"]:
                    progress(trials_done / total_trials, f"{case} gap {n}")
            rows.append(_gap_row(n, pairs.shape[0], trials, with_baseline=baseline is not None))
            if stop_when_lost and _mostly_lost(rows[-1]):
                break
        results[case] = rows
    if progress is not None:
        progress(1.0, "done")
    return results


def _mostly_lost(row: dict[str, Any]) -> bool:
    """Whether a gap size lost at least half of its trials (or drew none): the tracker
    "loses it" there, and longer gaps of the case are not run."""
    return bool(row["trials"] == 0 or 2 * row["lost"] >= row["trials"])


@dataclass(frozen=True)
class _HoldBackRun:
    """What every trial of one :func:`evaluate_gap_repair` call shares."""

    cloud: PointCloud  # the whole take, T frames, M points
    point_truth: np.ndarray  # (M,) str true labels
    truth: np.ndarray  # (T, R, 3) float64 metres, the rope markers in order
    labels: list[str]  # R truth labels
    track: TrackFn
    trace_of_truth: np.ndarray  # (R,) int64, the trace following each column, -1 none
    baseline: np.ndarray | None  # (T, K, 3) float64 metres, the untouched run
    after: int  # frames after the gap in which the trace must be back
    tail: int | None  # frames tracked past the window; None: the whole take
    lost_distance: float  # metres


def _draw(pairs: np.ndarray, starts: int, *, key: tuple[int, int, int]) -> list[tuple[int, int]]:
    """Up to ``starts`` of the (start, first column) ``pairs``, drawn without repeats by a
    generator seeded with ``key`` (seed, case index, gap size) alone."""
    if not pairs.shape[0]:
        return []
    rng = np.random.default_rng(list(key))
    pick = rng.choice(pairs.shape[0], size=min(starts, pairs.shape[0]), replace=False)
    return list(zip(pairs[pick, 0].tolist(), pairs[pick, 1].tolist(), strict=True))


def _checked_gap_inputs(
    cloud: PointCloud,
    truth: np.ndarray,
    truth_labels: Sequence[str],
    truth_of_trace: np.ndarray,
    cases: Sequence[str],
    gaps: Sequence[int],
    starts: int,
    baseline: np.ndarray | None,
) -> tuple[np.ndarray, list[str], np.ndarray, list[int]]:
    """Validate :func:`evaluate_gap_repair`'s arguments.

    Returns the truth as (T, R, 3) float64, its R labels, the trace following each
    truth column ((R,) int64, -1 for none) and the sorted distinct gap sizes.
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
    if baseline is not None:
        base_arr = np.asarray(baseline, dtype=np.float64)
        if base_arr.ndim != 3 or base_arr.shape[0] != n_frames or base_arr.shape[1] != tot.size:
            raise ValidationError(
                f"baseline: expected ({n_frames}, {tot.size}, 3), got {base_arr.shape}"
            )
    return truth_arr, labels, trace_of_truth, gap_sizes


def _known_samples(cloud: PointCloud, point_truth: np.ndarray, labels: list[str]) -> np.ndarray:
    """(T, R) bool: where the data is "known", the marker's point measured in that frame."""
    truth_text = np.asarray(point_truth).astype(str)
    if truth_text.shape != (cloud.points.shape[0],):
        raise ValidationError(
            f"point_truth: expected ({cloud.points.shape[0]},) labels, got {truth_text.shape}"
        )
    names, which = np.unique(truth_text, return_inverse=True)
    column_of_name = np.array([labels.index(x) if x in labels else -1 for x in names.tolist()])
    column = column_of_name[which].reshape(-1)
    frame_of_point = np.repeat(np.arange(cloud.n_frames), cloud.counts)
    known = np.zeros((cloud.n_frames, len(labels)), dtype=bool)
    on = column >= 0
    known[frame_of_point[on], column[on]] = True
    return known


def _group_known_cumsum(known: np.ndarray, width: int) -> np.ndarray:
    """(T + 1, R - width + 1) int64: frames before t in which all ``width`` markers from
    column r on are known (a running count, so any window's count is one difference)."""
    n_frames = known.shape[0]
    group = np.ones((n_frames, max(0, known.shape[1] - width + 1)), dtype=bool)
    for k in range(width):
        group &= known[:, k : k + group.shape[1]]
    return np.concatenate([np.zeros((1, group.shape[1]), np.int64), np.cumsum(group, axis=0)])


def _known_windows(
    known_before: np.ndarray, window: int, first_start: int, n_frames: int
) -> np.ndarray:
    """(P, 2) int: the (start frame, first column) pairs whose whole ``window`` is known."""
    last_start = n_frames - window
    if last_start < first_start or not known_before.shape[1]:
        return np.zeros((0, 2), dtype=np.int64)
    s_range = np.arange(first_start, last_start + 1)
    whole = (known_before[s_range + window] - known_before[s_range]) == window
    pairs = np.argwhere(whole)
    pairs[:, 0] += first_start
    return pairs


def _gap_trial(run: _HoldBackRun, columns: np.ndarray, start: int, n: int) -> dict[str, Any]:
    """Hold back the markers ``columns`` for frames ``start … start+n-1``, track, score.

    Returns ``tracked`` (False when a marker has no trace: a lost trial, nothing run),
    ``error`` (mean over the gap, NaN unless finite throughout), ``lost``,
    ``invented`` (share of gap samples flagged invented), ``baseline`` (the untouched
    run's error over the gap, None without ``baseline``), ``flagged`` (1.0 when the
    tracker flagged the trace lost in the gap or after it, None when it flags nothing)
    and the ``detail`` record of the trial.
    """
    after, baseline, traces = run.after, run.baseline, run.trace_of_truth[columns]
    names = [run.labels[c] for c in columns]
    no_baseline = np.nan if baseline is not None else None
    if (traces < 0).any():  # the tracker never had this marker
        detail = {
            "start": int(start),
            "markers": names,
            "mean_error_m": None,
            "max_error_m": None,
            "lost": True,
        }
        return {
            "tracked": False,
            "error": np.nan,
            "lost": True,
            "invented": np.nan,
            "baseline": no_baseline,
            "flagged": None,
            "detail": detail,
        }
    held, _ = hold_back_points(run.cloud, run.point_truth, names, start, n)
    if run.tail is not None:
        held = crop_frames(held, start + n + after + run.tail)
    result = run.track(held)
    pos = np.asarray(result.positions, dtype=np.float64)[:, traces]
    err = gap_errors(pos, run.truth[:, columns], start, n + after)
    gap_part = err[:n]
    is_lost = bool(~np.isfinite(err).all() or np.nanmax(err) > run.lost_distance)
    error = float(gap_part.mean()) if np.isfinite(gap_part).all() else np.nan
    finite = err[np.isfinite(err)]
    detail = {
        "start": int(start),
        "markers": names,
        "mean_error_m": None if np.isnan(error) else error,
        "max_error_m": float(finite.max()) if finite.size else None,
        "lost": is_lost,
    }
    flags = getattr(result, "lost_frames", None)
    flagged = None
    if flags is not None:
        flagged = float(np.asarray(flags, dtype=bool)[start : start + n + after][:, traces].any())
    inv = np.asarray(result.invented, dtype=bool)[start : start + n][:, traces]
    base_error = no_baseline
    if baseline is not None:
        b = gap_errors(
            np.asarray(baseline, dtype=np.float64)[:, traces], run.truth[:, columns], start, n
        )
        base_error = float(b.mean()) if np.isfinite(b).all() else np.nan
    return {
        "tracked": True,
        "error": error,
        "lost": is_lost,
        "invented": float(inv.mean()) if inv.size else np.nan,
        "baseline": base_error,
        "flagged": flagged,
        "detail": detail,
    }


def _gap_row(
    n: int, candidates: int, trials: list[dict[str, Any]], *, with_baseline: bool
) -> dict[str, Any]:
    """The per-gap summary of :func:`evaluate_gap_repair` from its trials' records."""
    extra = {"invented_fraction": [t["invented"] for t in trials]}
    if with_baseline:
        extra["baseline_error_m"] = [t["baseline"] for t in trials]
    row: dict[str, Any] = {"gap": n, "candidates": int(candidates)}
    row.update(_summary_of_trials([t["error"] for t in trials], [t["lost"] for t in trials], extra))
    flagged = [t["flagged"] for t in trials if t["flagged"] is not None]
    if flagged:
        row["flagged_lost"] = int(sum(flagged))
    row["detail"] = [t["detail"] for t in trials]
    return row
