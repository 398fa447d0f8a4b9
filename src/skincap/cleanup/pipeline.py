"""The whole cleanup (Park & Hodgins 2006, §4): surface -> merge -> fill -> smooth.

:func:`clean_markers` runs the four steps on a capture of labelled markers and
unlabelled fragments and returns the cleaned :class:`~skincap.types.MarkerSet` (filled
samples flagged in ``invented``) and a typed
:class:`~skincap.cleanup.report.CleanReport`. Between merging and filling,
label swaps are swapped back and spikes removed; smoothing keeps measured samples
within their noise and fills are kept only where continuous
(:mod:`skincap.cleanup.guarded`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from skincap._arrays import Progress, missing_runs
from skincap.cleanup.guarded import MAX_MOVE, MAX_MOVE_NOISE, GuardedFill, guarded_fill_smooth
from skincap.cleanup.hidden import find_hidden_markers
from skincap.cleanup.merge import MergeReport, merge_fragments
from skincap.cleanup.off_body import off_body_leaps
from skincap.cleanup.report import (
    CleanReport,
    FillSummary,
    HiddenReport,
    SmoothSummary,
    SurfaceSummary,
)
from skincap.cleanup.settings import CleanSettings
from skincap.cleanup.surface import (
    MarkerSurface,
    build_marker_surface,
    choose_reference_frame,
    complete_reference_pose,
    pair_distance_cv,
)
from skincap.errors import ValidationError
from skincap.types import MarkerSet

__all__ = ["clean_markers", "invented_runs"]


def invented_runs(invented: np.ndarray, labels: list[str]) -> dict[str, list[list[int]]]:
    """Runs of invented samples per marker.

    Parameters
    ----------
    invented : (T, N) bool
    labels : N str

    Returns
    -------
    dict of str to list of [start, end)
        Only markers with at least one invented sample; frames numbered from 0.
    """
    marker, start, length = missing_runs(invented)  # runs of True, by marker then frame
    out: dict[str, list[list[int]]] = {}
    for m, s, e in zip(marker.tolist(), start.tolist(), (start + length).tolist(), strict=True):
        out.setdefault(str(labels[m]), []).append([s, e])
    return out


def _surface(positions: np.ndarray, reference_frame: int) -> MarkerSurface:
    """The automatic surface, with markers hidden in the reference frame placed there
    by their neighbours (:func:`complete_reference_pose`) so they get neighbours too."""
    pos = positions.copy()
    pos[reference_frame] = complete_reference_pose(positions, reference_frame)
    return build_marker_surface(pos, reference_frame=reference_frame)


def _automatic_surface(
    markers: MarkerSet, settings: CleanSettings, progress: Progress | None
) -> tuple[MarkerSurface, np.ndarray, int]:
    """The marker surface over the labelled columns (and, with promotion, the fragments
    seen in the reference frame that move with at least three skin neighbours).

    Returns the surface, its columns of ``markers`` (N,) and the reference frame.
    """
    pos = markers.positions
    labels = [str(lab) for lab in markers.labels]
    labelled = np.flatnonzero([not lab.startswith("*") for lab in labels])
    promote = settings.promote_fragments
    if promote is None:
        promote = labelled.size == 0
    reference_frame = settings.reference_frame
    if reference_frame is None:
        reference_frame = choose_reference_frame(pos[:, labelled] if labelled.size else pos)
    t_count = pos.shape[0]
    if not 0 <= reference_frame < t_count:
        raise ValidationError(f"reference_frame {reference_frame} is outside 0..{t_count - 1}")
    seen = np.isfinite(pos[reference_frame]).all(axis=1)
    fragment = np.array([lab.startswith("*") for lab in labels], dtype=bool)
    promoted = np.flatnonzero(fragment & seen) if promote else np.zeros(0, int)
    anchors = np.concatenate([labelled, promoted])
    if progress is not None:
        progress(0.0, "building the marker surface")
    surface = _surface(pos[:, anchors], reference_frame)
    if promoted.size:
        # a promoted fragment stays only when it moves with >= 3 skin neighbours
        # (rope markers and ghosts seen in the reference frame do not)
        cv, overlap = pair_distance_cv(pos[:, anchors], surface.edges)
        firm = surface.edges[(overlap >= 10) & (cv <= 0.2)]
        firm_deg = np.bincount(firm.ravel(), minlength=anchors.size)
        keep = np.ones(anchors.size, dtype=bool)
        keep[labelled.size :] = firm_deg[labelled.size :] >= 3
        if not keep.all():
            anchors = anchors[keep]
            surface = _surface(pos[:, anchors], reference_frame)
    return surface, anchors, reference_frame


def _hidden_columns(
    markers: MarkerSet, merged: MarkerSet, groups: list[list[int]]
) -> tuple[MarkerSet, dict[str, list[str]]]:
    """The capture with one new marker column per group of leftover fragments.

    ``groups`` index columns of ``merged`` (a first merge's output); each group's
    samples move out of their fragment columns into a new column ``U<n>`` named after
    the group's first (longest) fragment ``*<n>``, appended after the capture's
    columns. Returns the new capture and new label -> its fragments' labels.
    """
    labels = [str(lab) for lab in markers.labels]
    column_of = {lab: c for c, lab in enumerate(labels)}
    pos = markers.positions.copy()
    res = None if markers.residuals is None else markers.residuals.copy()
    inv = None if markers.invented is None else markers.invented.copy()
    cam = None if markers.camera_masks is None else markers.camera_masks.copy()
    t_count = pos.shape[0]
    new_pos = np.full((t_count, len(groups), 3), np.nan)
    new_res = None if res is None else np.full((t_count, len(groups)), np.nan)
    new_inv = None if inv is None else np.zeros((t_count, len(groups)), dtype=bool)
    new_cam = None if cam is None else np.zeros((t_count, len(groups)), dtype=np.uint8)
    new_markers: dict[str, list[str]] = {}
    taken = set(labels)
    for g, members in enumerate(groups):
        names = [str(merged.labels[m]) for m in members]
        base = "U" + names[0].lstrip("*")
        name, k = base, 1
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name)
        new_markers[name] = names
        for m, lab in zip(members, names, strict=True):
            col = column_of[lab]
            rows = np.isfinite(merged.positions[:, m]).all(axis=1)
            new_pos[rows, g] = pos[rows, col]
            pos[rows, col] = np.nan
            if res is not None and new_res is not None:
                new_res[rows, g] = res[rows, col]
                res[rows, col] = np.nan
            if inv is not None and new_inv is not None:
                new_inv[rows, g] = inv[rows, col]
                inv[rows, col] = False
            if cam is not None and new_cam is not None:
                new_cam[rows, g] = cam[rows, col]
                cam[rows, col] = 0
    out = MarkerSet(
        positions=np.concatenate([pos, new_pos], axis=1),
        labels=labels + list(new_markers),
        rate=markers.rate,
        meta=dict(markers.meta),
        residuals=None if res is None else np.concatenate([res, new_res], axis=1),
        invented=None if inv is None else np.concatenate([inv, new_inv], axis=1),
        camera_masks=None if cam is None else np.concatenate([cam, new_cam], axis=1),
    )
    return out, new_markers


def _score_hidden(
    new_markers: dict[str, list[str]],
    known_labels: list[str],
    fragment_truth: dict[str, str],
) -> tuple[dict[str, str], HiddenReport]:
    """The truth extended with each new label (its seed fragment's truth), and the
    hidden-marker report with the truth counts. ``known_labels``: the surface's
    markers before the hidden ones were added."""
    fragment_truth = dict(fragment_truth)
    known = {fragment_truth.get(lab, lab) for lab in known_labels}
    seen: set[str] = set()
    wrong_markers = wrong_fragments = 0
    for name, names in new_markers.items():
        truth = fragment_truth.get(names[0], names[0])
        fragment_truth[name] = truth
        wrong_fragments += sum(fragment_truth.get(f, f) != truth for f in names[1:])
        is_marker = truth in markers_in_truth(fragment_truth) and truth not in known
        if not is_marker or truth in seen:
            wrong_markers += 1
        seen.add(truth)
    report = HiddenReport(
        enabled=True,
        new_markers=len(new_markers),
        markers=new_markers,
        recovered=len(new_markers) - wrong_markers,
        wrong_markers=wrong_markers,
        wrong_fragments=wrong_fragments,
    )
    return fragment_truth, report


def _add_hidden_markers(
    markers: MarkerSet,
    anchors: np.ndarray,
    merged: MarkerSet,
    groups: list[list[int]],
    fragment_truth: dict[str, str] | None,
) -> tuple[MarkerSet, np.ndarray, dict[str, str] | None, HiddenReport]:
    """The capture with the hidden markers' columns (:func:`_hidden_columns`) appended
    after its columns and to ``anchors``, the truth extended with their labels and the
    hidden-marker report."""
    if not groups:
        scored = fragment_truth is not None
        zero = 0 if scored else None
        return markers, anchors, fragment_truth, HiddenReport(True, 0, {}, zero, zero, zero)
    out, new_markers = _hidden_columns(markers, merged, groups)
    known_labels = [str(markers.labels[a]) for a in anchors.tolist()]
    c_count = markers.n_markers
    anchors = np.concatenate([anchors, np.arange(c_count, c_count + len(groups))])
    if fragment_truth is None:
        return out, anchors, None, HiddenReport(True, len(groups), new_markers)
    fragment_truth, report = _score_hidden(new_markers, known_labels, fragment_truth)
    return out, anchors, fragment_truth, report


def _without_off_body_leaps(
    markers: MarkerSet, labelled: np.ndarray
) -> tuple[MarkerSet, np.ndarray]:
    """The capture with its labelled markers' off-body leaps
    (:func:`~skincap.cleanup.off_body.off_body_leaps`) made missing, and those samples
    (T, C) bool. Fragments are left as they are: the merge judges them."""
    leaps = np.zeros(markers.positions.shape[:2], dtype=bool)
    if labelled.size:
        leaps[:, labelled] = off_body_leaps(markers.positions[:, labelled])
    if not leaps.any():
        return markers, leaps
    pos = markers.positions.copy()
    pos[leaps] = np.nan
    res = None if markers.residuals is None else np.where(leaps, np.nan, markers.residuals)
    inv = None if markers.invented is None else markers.invented & ~leaps
    return replace(markers, positions=pos, residuals=res, invented=inv), leaps


def markers_in_truth(fragment_truth: dict[str, str]) -> set[str]:
    """True marker labels named by a fragment truth: everything but ``ghost`` and ``rope_*``."""
    return {v for v in fragment_truth.values() if v != "ghost" and not v.startswith("rope_")}


def _cleaned_capture(
    markers: MarkerSet, merged: MarkerSet, n: int, guarded: GuardedFill, keep_fragments: bool
) -> MarkerSet:
    """The marker columns as filled and smoothed, then (``keep_fragments``) the leftover
    fragments as the merge left them; residuals NaN and camera masks 0 on invented and
    unfilled samples."""
    filled, invented = guarded.positions, guarded.invented
    out_pos = filled
    out_labels = list(merged.labels[:n])
    out_inv = invented
    out_res = (
        None
        if guarded.residuals is None
        else np.where(invented | guarded.unfilled, np.nan, guarded.residuals)
    )
    # the cameras that saw a measured sample; an invented one has none
    out_cam = (
        None
        if guarded.camera_masks is None
        else np.where(invented | guarded.unfilled, 0, guarded.camera_masks)
    )
    if keep_fragments and merged.n_markers > n:
        rest = merged.select(np.arange(n, merged.n_markers))
        out_pos = np.concatenate([filled, rest.positions], axis=1)
        out_labels += list(rest.labels)
        rest_inv = (
            rest.invented
            if rest.invented is not None
            else np.zeros(rest.positions.shape[:2], dtype=bool)
        )
        out_inv = np.concatenate([invented, rest_inv], axis=1)
        if out_res is not None and rest.residuals is not None:
            out_res = np.concatenate([out_res, rest.residuals], axis=1)
        else:
            out_res = None
        if out_cam is not None and rest.camera_masks is not None:
            out_cam = np.concatenate([out_cam, rest.camera_masks], axis=1)
        else:
            out_cam = None
    return MarkerSet(
        positions=out_pos,
        labels=out_labels,
        rate=markers.rate,
        meta=dict(markers.meta),
        residuals=out_res,
        invented=out_inv,
        camera_masks=out_cam,
    )


def _clean_report(
    markers: MarkerSet,
    surface: MarkerSurface,
    hidden: HiddenReport,
    merge: MergeReport,
    guarded: GuardedFill,
    settings: CleanSettings,
) -> CleanReport:
    """The report of one run; ``markers`` is the input capture."""
    n = surface.n_markers
    mnd = surface.mean_neighbour_distance
    fill, smooth = settings.fill, settings.smooth
    counts = guarded.counts
    return CleanReport(
        frames=int(markers.n_frames),
        rate=float(markers.rate),
        surface=SurfaceSummary(
            markers=int(n),
            edges=int(surface.edges.shape[0]),
            faces=int(surface.faces.shape[0]),
            reference_frame=int(surface.reference_frame),
            mean_neighbour_distance_m=(
                float(np.nanmedian(mnd)) if np.isfinite(mnd).any() else None
            ),
            markers_without_neighbours=int((surface.degree == 0).sum()),
        ),
        hidden=hidden,
        # counted on the input: the hidden markers' columns are made of its fragments
        merge=replace(merge, trajectories_before=int(markers.n_markers)),
        fill=FillSummary(
            method=fill.method,
            rigid_blend="per gap" if fill.rigid_blend is None else float(fill.rigid_blend),
            holes_before=guarded.holes,
            invented_samples=int(guarded.invented.sum()),
            filled_samples=counts["filled"],
            unfilled_samples=counts["unfilled"],
            unfilled_fraction=counts["unfilled_fraction"],
            unstable_fills_dropped=counts["dropped"],
            acceleration_limit_mm_per_frame2=guarded.limit_mm,
        ),
        guard=guarded.summary(merge.merged),
        markers=guarded.per_marker(),
        smooth=SmoothSummary(
            enabled=bool(smooth.enabled),
            lam=float(smooth.lam),
            iterations=int(smooth.iterations),
            max_move_noise_multiple=MAX_MOVE_NOISE,
            max_move_mm=1000 * MAX_MOVE,
        ),
        invented=invented_runs(guarded.invented, guarded.labels),
    )


def clean_markers(
    markers: MarkerSet,
    settings: CleanSettings = CleanSettings(),
    *,
    surface: MarkerSurface | None = None,
    fragment_truth: dict[str, str] | None = None,
    progress: Progress | None = None,
) -> tuple[MarkerSet, CleanReport]:
    """Clean a capture: marker surface, merge fragments, fill holes, smooth.

    The steps: the marker surface (:func:`_automatic_surface`, unless one is given);
    with ``settings.recover_hidden``, a first merge and the markers hidden in the
    reference frame (:func:`~skincap.cleanup.hidden.find_hidden_markers`,
    :func:`_add_hidden_markers`); the merge
    (:func:`~skincap.cleanup.merge.merge_fragments`); swap and spike repair, filling,
    smoothing and continuity (:func:`~skincap.cleanup.guarded.guarded_fill_smooth`);
    then the output (:func:`_cleaned_capture`) and the report (:func:`_clean_report`).

    Parameters
    ----------
    markers : MarkerSet
        Positions (T, C, 3) metres, NaN where missing; labelled columns plus ``*N``
        unlabelled fragments.
    settings : CleanSettings
        Every option, by stage (see :mod:`skincap.cleanup.settings`). The reference
        pose defaults to the first frame with the most labelled markers; labelled
        markers missing there are placed by their neighbours from the nearest frame
        where they are seen
        (:func:`~skincap.cleanup.surface.complete_reference_pose`). Fragments are
        promoted to markers by default only when the capture has no labelled column;
        beware: the tape markers of a rope keep their mutual distances too, so they
        pass the promotion test. Beyond the paper (which assumed a complete reference
        frame), ``recover_hidden`` gives the markers hidden in the reference frame a
        label: a first merge runs; the leftover fragments that ride with a skin
        neighbourhood over their whole span and never come near a known marker
        become new marker columns labelled ``U<n>`` after their longest fragment
        ``*<n>``; then the surface is rebuilt and the merge runs again from the
        start, so fragments that had gone to a neighbour of the hidden marker now go
        to it.
    surface : MarkerSurface, optional
        A ready surface over the labelled columns (in column order), e.g. a user
        surface; then no fragment is promoted, no hidden marker recovered and
        ``settings.reference_frame`` is not used.
    fragment_truth : dict of str to str, optional
        Ground truth for the merge report's wrong-merge count.
    progress : callable(fraction, label), optional

    Returns
    -------
    cleaned : MarkerSet
        Marker columns (merged, filled, smoothed) then, with ``keep_fragments``, the
        leftover fragments. ``invented`` (T, C') is True on filled samples (and on
        samples the input already flagged). NaN where nothing could be filled.
    report : CleanReport
        Surface, hidden markers, merge (Table 1), fill, guard (take-wide counts),
        per-marker counts, smoothing and the invented runs; ``report.as_dict()`` is
        the JSON of ``skincap clean --report``.

    Warns
    -----
    SkincapWarning
        When more than 1 % of the markers' samples are left unfilled.
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    if markers.n_frames == 0:
        raise ValidationError("markers has no frames")
    if markers.n_markers == 0:
        raise ValidationError("markers has no marker columns to clean")
    labelled = np.flatnonzero([not str(lab).startswith("*") for lab in markers.labels])

    def step(base: float, span: float) -> Progress | None:
        if progress is None:
            return None
        return lambda f, label: progress(base + span * f, label)

    source = markers
    # samples leaping kilometres off the body go before anything averages over them
    # (the surface's pair-distance spread, the merge); they are filled as outliers
    markers, leaps = _without_off_body_leaps(markers, labelled)
    hidden = HiddenReport(enabled=False, new_markers=0, markers={})
    if surface is not None:
        if surface.n_markers != labelled.size:
            raise ValidationError(
                f"surface has {surface.n_markers} vertices but the capture has "
                f"{labelled.size} labelled markers"
            )
        anchors = labelled
    else:
        surface, anchors, reference_frame = _automatic_surface(markers, settings, progress)
        if settings.recover_hidden and labelled.size:
            first, _ = merge_fragments(markers, surface, anchors, settings.merge)
            groups = find_hidden_markers(first, surface, settings.hidden)
            markers, anchors, fragment_truth, hidden = _add_hidden_markers(
                markers, anchors, first, groups, fragment_truth
            )
            if groups:
                surface = _surface(markers.positions[:, anchors], reference_frame)
    merged, merge_report = merge_fragments(
        markers,
        surface,
        anchors,
        settings.merge,
        fragment_truth=fragment_truth,
        progress=step(0.05, 0.25),
    )
    n = anchors.size
    if progress is not None:
        progress(0.3, "filling holes")
    # the hidden markers' columns (appended after the input's) had no leap taken out
    leaps = np.pad(leaps, ((0, 0), (0, markers.n_markers - leaps.shape[1])))
    guarded = guarded_fill_smooth(
        merged.select(np.arange(n)),
        surface.neighbours,
        settings,
        removed=leaps[:, anchors],
        progress=step(0.3, 0.5),
    )
    cleaned = _cleaned_capture(source, merged, n, guarded, settings.keep_fragments)
    if progress is not None:
        progress(1.0, "done")
    return cleaned, _clean_report(source, surface, hidden, merge_report, guarded, settings)
