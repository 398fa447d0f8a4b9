"""The whole cleanup (Park & Hodgins 2006, §4): surface -> merge -> fill -> smooth.

:func:`clean_markers` runs the four steps on a capture of labelled markers and
unlabelled fragments and returns the cleaned :class:`~skincap.types.MarkerSet` (filled
samples flagged in ``invented``) and a JSON-ready report. Between merging and filling,
label swaps are swapped back and spikes removed; smoothing keeps measured samples
within their noise and fills are kept only where continuous
(:mod:`skincap.cleanup.guarded`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.cleanup.guarded import MAX_MOVE, MAX_MOVE_NOISE, guarded_fill_smooth
from skincap.cleanup.hidden import find_hidden_markers
from skincap.cleanup.merge import merge_fragments
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
    inv = np.asarray(invented, dtype=bool)
    n = inv.shape[1]
    pad = np.zeros((n, 1), dtype=np.int8)
    step = np.diff(np.concatenate([pad, inv.T.astype(np.int8), pad], axis=1), axis=1)  # (N, T+1)
    marker, start = np.nonzero(step == 1)  # sorted by marker, then frame
    _, end = np.nonzero(step == -1)
    out: dict[str, list[list[int]]] = {}
    for m, s, e in zip(marker.tolist(), start.tolist(), end.tolist(), strict=True):
        out.setdefault(str(labels[m]), []).append([s, e])
    return out


def _surface(positions: np.ndarray, reference_frame: int) -> MarkerSurface:
    """The automatic surface, with markers hidden in the reference frame placed there
    by their neighbours (:func:`complete_reference_pose`) so they get neighbours too."""
    pos = positions.copy()
    pos[reference_frame] = complete_reference_pose(positions, reference_frame)
    return build_marker_surface(pos, reference_frame=reference_frame)


def _add_hidden_markers(
    markers: MarkerSet,
    anchors: np.ndarray,
    merged: MarkerSet,
    groups: list[list[int]],
    fragment_truth: dict[str, str] | None,
) -> tuple[MarkerSet, np.ndarray, dict[str, str] | None, dict[str, Any]]:
    """The capture with one new marker column per group of leftover fragments.

    ``groups`` index columns of ``merged`` (a first merge's output); each group's
    samples move out of their fragment columns into a new column ``U<n>`` named after
    the group's first (longest) fragment ``*<n>``, appended after the capture's
    columns and to ``anchors``. Returns the new capture, anchors, the truth extended
    with each new label (its first fragment's truth) and the ``hidden`` report.
    """
    labels = [str(lab) for lab in markers.labels]
    hidden: dict[str, Any] = {"enabled": True, "new_markers": len(groups), "markers": {}}
    if not groups:
        if fragment_truth is not None:
            hidden.update(recovered=0, wrong_markers=0, wrong_fragments=0)
        return markers, anchors, fragment_truth, hidden
    column_of = {lab: c for c, lab in enumerate(labels)}
    pos = markers.positions.copy()
    res = None if markers.residuals is None else markers.residuals.copy()
    inv = None if markers.invented is None else markers.invented.copy()
    t_count = pos.shape[0]
    new_pos = np.full((t_count, len(groups), 3), np.nan)
    new_res = None if res is None else np.full((t_count, len(groups)), np.nan)
    new_inv = None if inv is None else np.zeros((t_count, len(groups)), dtype=bool)
    new_labels: list[str] = []
    taken = set(labels)
    for g, members in enumerate(groups):
        names = [str(merged.labels[m]) for m in members]
        base = "U" + names[0].lstrip("*")
        name, k = base, 1
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name)
        new_labels.append(name)
        hidden["markers"][name] = names
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
    out = MarkerSet(
        positions=np.concatenate([pos, new_pos], axis=1),
        labels=labels + new_labels,
        rate=markers.rate,
        meta=dict(markers.meta),
        residuals=None if res is None else np.concatenate([res, new_res], axis=1),
        invented=None if inv is None else np.concatenate([inv, new_inv], axis=1),
    )
    c_count = len(labels)
    anchors = np.concatenate([anchors, np.arange(c_count, c_count + len(groups))])
    if fragment_truth is not None:
        fragment_truth = dict(fragment_truth)
        known = {fragment_truth.get(labels[a], labels[a]) for a in anchors[: -len(groups)]}
        seen: set[str] = set()
        wrong_markers = wrong_fragments = 0
        for name, names in hidden["markers"].items():
            truth = fragment_truth.get(names[0], names[0])
            fragment_truth[name] = truth
            wrong_fragments += sum(fragment_truth.get(f, f) != truth for f in names[1:])
            is_marker = truth in markers_in_truth(fragment_truth) and truth not in known
            if not is_marker or truth in seen:
                wrong_markers += 1
            seen.add(truth)
        hidden.update(
            recovered=len(groups) - wrong_markers,
            wrong_markers=wrong_markers,
            wrong_fragments=wrong_fragments,
        )
    return out, anchors, fragment_truth, hidden


def markers_in_truth(fragment_truth: dict[str, str]) -> set[str]:
    """True marker labels named by a fragment truth: everything but ``ghost`` and ``rope_*``."""
    return {v for v in fragment_truth.values() if v != "ghost" and not v.startswith("rope_")}


def clean_markers(
    markers: MarkerSet,
    *,
    method: str = "local_pca",
    rigid_blend: float | None = None,
    reference_frame: int | None = None,
    surface: MarkerSurface | None = None,
    smooth: bool = True,
    lam: float = 0.02,
    iterations: int = 10,
    alpha1: float = 0.5,
    alpha2: float = 0.6,
    keep_fragments: bool = True,
    promote_fragments: bool | None = None,
    recover_hidden: bool = True,
    fragment_truth: dict[str, str] | None = None,
    progress: Progress | None = None,
) -> tuple[MarkerSet, dict[str, Any]]:
    """Clean a capture: marker surface, merge fragments, fill holes, smooth.

    Parameters
    ----------
    markers : MarkerSet
        Positions (T, C, 3) metres, NaN where missing; labelled columns plus ``*N``
        unlabelled fragments.
    method : str, default "local_pca"
        Hole-filling method of :func:`skincap.cleanup.fill.fill_gaps`.
    rigid_blend : float in [0, 1], optional
        Local methods: the rigid fill's weight in the filled samples
        (:func:`~skincap.cleanup.fill.fill_gaps`); None (default) per gap, 0 the
        paper's local PCA alone.
    reference_frame : int, optional
        Reference pose; default the first frame with the most labelled markers.
        Labelled markers missing there are placed by their neighbours from the
        nearest frame where they are seen (see
        :func:`~skincap.cleanup.surface.complete_reference_pose`).
    surface : MarkerSurface, optional
        A ready surface over the labelled columns (in column order), e.g. a user
        surface; then no fragment is promoted.
    smooth : bool, default True
        Run :func:`skincap.cleanup.smooth.smooth_local` after filling.
    lam, iterations : float, int
        Smoothing damping λ and number of Δ⁴ updates.
    alpha1, alpha2 : float
        Merge tolerances of eq. 3.
    keep_fragments : bool, default True
        Keep the fragments left unmerged (unfilled, after the markers) in the output.
    promote_fragments : bool, optional
        Default: only when the capture has no labelled column (an unlabelled file).
        Let fragments present in the reference frame that move with at least three
        skin neighbours (distance CV <= 0.2 over >= 10 shared frames) become marker
        columns. Off: only the labelled columns are markers. Beware: the tape markers
        of a rope keep their mutual distances too, so they pass this test.
    recover_hidden : bool, default True
        Beyond the paper (which assumed a complete reference frame): with an
        automatic surface over labelled columns, give the markers hidden in the
        reference frame a label. A first merge runs; the leftover fragments that ride
        with a skin neighbourhood over their whole span and never come near a known
        marker (:func:`~skincap.cleanup.hidden.find_hidden_markers`) become new marker
        columns labelled ``U<n>`` after their longest fragment ``*<n>``; then the
        surface is rebuilt and the merge runs again from the start, so fragments
        that had gone to a neighbour of the hidden marker now go to it.
    fragment_truth : dict of str to str, optional
        Ground truth for the merge report's wrong-merge count.
    progress : callable(fraction, label), optional

    Returns
    -------
    cleaned : MarkerSet
        Marker columns (merged, filled, smoothed) then, with ``keep_fragments``, the
        leftover fragments. ``invented`` (T, C') is True on filled samples (and on
        samples the input already flagged). NaN where nothing could be filled.
    report : dict
        ``surface`` (markers, edges, faces, reference_frame, mean neighbour distance),
        ``hidden`` (new markers -> their fragments; with truth, how many hidden
        markers were recovered and how many fragments or markers were wrong),
        ``merge`` (:class:`~skincap.cleanup.merge.MergeReport` fields), ``fill``
        (method, holes before, invented, filled and unfilled samples, fills dropped
        as unstable, the second-difference limit), ``guard`` (take-wide: filled,
        unfilled (and whether above the warning threshold), outliers found and
        replaced, relabelled fragments (merged + 2 per repaired swap), largest move of
        a kept measured sample in mm, median noise), ``markers`` (the same per marker
        column, :meth:`~skincap.cleanup.guarded.GuardedFill.per_marker`), ``smooth``
        (λ, iterations, the noise bound) and ``invented`` (label -> [start, end)
        runs).

    Warns
    -----
    SkincapWarning
        When more than 1 % of the markers' samples are left unfilled.
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    pos = markers.positions
    t_count, c_count, _ = pos.shape
    if t_count == 0:
        raise ValidationError("markers has no frames")
    labels = [str(lab) for lab in markers.labels]
    labelled = np.flatnonzero([not lab.startswith("*") for lab in labels])

    def step(base: float, span: float) -> Progress | None:
        if progress is None:
            return None
        return lambda f, label: progress(base + span * f, label)

    auto_surface = surface is None
    if surface is not None:
        if surface.n_markers != labelled.size:
            raise ValidationError(
                f"surface has {surface.n_markers} vertices but the capture has "
                f"{labelled.size} labelled markers"
            )
        anchors = labelled
    else:
        if promote_fragments is None:
            promote_fragments = labelled.size == 0
        if reference_frame is None:
            reference_frame = choose_reference_frame(pos[:, labelled] if labelled.size else pos)
        if not 0 <= reference_frame < t_count:
            raise ValidationError(f"reference_frame {reference_frame} is outside 0..{t_count - 1}")
        seen = np.isfinite(pos[reference_frame]).all(axis=1)
        fragment = np.array([lab.startswith("*") for lab in labels], dtype=bool)
        promoted = np.flatnonzero(fragment & seen) if promote_fragments else np.zeros(0, int)
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

    hidden: dict[str, Any] = {"enabled": False, "new_markers": 0, "markers": {}}
    if recover_hidden and auto_surface and labelled.size and reference_frame is not None:
        first, _ = merge_fragments(markers, surface, anchors, alpha1=alpha1, alpha2=alpha2)
        groups = find_hidden_markers(first, surface)
        markers, anchors, fragment_truth, hidden = _add_hidden_markers(
            markers, anchors, first, groups, fragment_truth
        )
        if groups:
            surface = _surface(markers.positions[:, anchors], reference_frame)

    merged, merge_report = merge_fragments(
        markers,
        surface,
        anchors,
        alpha1=alpha1,
        alpha2=alpha2,
        fragment_truth=fragment_truth,
        progress=step(0.05, 0.25),
    )
    n = anchors.size
    body = merged.select(np.arange(n))
    if progress is not None:
        progress(0.3, "filling holes")
    guarded = guarded_fill_smooth(
        body,
        surface.neighbours,
        method=method,
        rigid_blend=rigid_blend,
        smooth=smooth,
        lam=lam,
        iterations=iterations,
        progress=step(0.3, 0.5),
    )
    filled, invented, holes = guarded.positions, guarded.invented, guarded.holes
    out_pos = filled
    out_labels = list(body.labels)
    out_inv = invented
    out_res = (
        None
        if guarded.residuals is None
        else np.where(invented | guarded.unfilled, np.nan, guarded.residuals)
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
    cleaned = MarkerSet(
        positions=out_pos,
        labels=out_labels,
        rate=markers.rate,
        meta=dict(markers.meta),
        residuals=out_res,
        invented=out_inv,
    )
    if progress is not None:
        progress(1.0, "done")
    mnd = surface.mean_neighbour_distance
    report: dict[str, Any] = {
        "frames": int(t_count),
        "rate": float(markers.rate),
        "surface": {
            "markers": int(n),
            "edges": int(surface.edges.shape[0]),
            "faces": int(surface.faces.shape[0]),
            "reference_frame": int(surface.reference_frame),
            "mean_neighbour_distance_m": (
                float(np.nanmedian(mnd)) if np.isfinite(mnd).any() else None
            ),
            "markers_without_neighbours": int((surface.degree == 0).sum()),
        },
        "hidden": hidden,
        # counted on the input: the hidden markers' columns are made of its fragments
        "merge": {**merge_report.as_dict(), "trajectories_before": int(c_count)},
        "fill": {
            "method": method,
            "rigid_blend": "per gap" if rigid_blend is None else float(rigid_blend),
            "holes_before": holes,
            "invented_samples": int(invented.sum()),
            "filled_samples": guarded.counts["filled"],
            "unfilled_samples": guarded.counts["unfilled"],
            "unfilled_fraction": guarded.counts["unfilled_fraction"],
            "unstable_fills_dropped": guarded.counts["dropped"],
            "acceleration_limit_mm_per_frame2": guarded.limit_mm,
        },
        "guard": guarded.summary(merge_report.merged),
        "markers": guarded.per_marker(),
        "smooth": {
            "enabled": bool(smooth),
            "lambda": float(lam),
            "iterations": int(iterations),
            "max_move_noise_multiple": MAX_MOVE_NOISE,
            "max_move_mm": 1000 * MAX_MOVE,
        },
        "invented": invented_runs(invented, list(body.labels)),
    }
    return cleaned, report
