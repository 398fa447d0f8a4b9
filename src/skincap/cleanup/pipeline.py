"""The whole cleanup (Park & Hodgins 2006, §4): surface -> merge -> fill -> smooth.

:func:`clean_markers` runs the four steps on a capture of labelled markers and
unlabelled fragments and returns the cleaned :class:`~skincap.types.MarkerSet` (filled
samples flagged in ``invented``) and a JSON-ready report.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

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
    fragment_truth: dict[str, str] | None = None,
    progress: Callable[[float, str], None] | None = None,
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
        ``merge`` (:class:`~skincap.cleanup.merge.MergeReport` fields), ``fill``
        (method, holes before, invented and unfilled samples), ``smooth`` (λ,
        iterations) and ``invented`` (label -> [start, end) runs).
    """
    from skincap.cleanup.fill import fill_gaps
    from skincap.cleanup.smooth import smooth_local

    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    pos = markers.positions
    t_count, c_count, _ = pos.shape
    if t_count == 0:
        raise ValidationError("markers has no frames")
    labels = [str(lab) for lab in markers.labels]
    labelled = np.flatnonzero([not lab.startswith("*") for lab in labels])

    def step(base: float, span: float) -> Callable[[float, str], None] | None:
        if progress is None:
            return None
        return lambda f, label: progress(base + span * f, label)

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
    holes = int(np.isnan(body.positions[..., 0]).sum())
    if progress is not None:
        progress(0.3, "filling holes")
    filled, invented = fill_gaps(
        body,
        method=method,
        neighbours=surface.neighbours,
        rigid_blend=rigid_blend,
        progress=step(0.3, 0.5),
    )
    if smooth:
        if progress is not None:
            progress(0.8, "smoothing")
        filled = smooth_local(filled, surface.neighbours, lam=lam, iterations=iterations)
    if body.invented is not None:
        invented = invented | body.invented
    out_pos = filled
    out_labels = list(body.labels)
    out_inv = invented
    out_res = None if body.residuals is None else np.where(invented, np.nan, body.residuals)
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
        "merge": merge_report.as_dict(),
        "fill": {
            "method": method,
            "rigid_blend": "per gap" if rigid_blend is None else float(rigid_blend),
            "holes_before": holes,
            "invented_samples": int(invented.sum()),
            "unfilled_samples": int(np.isnan(filled[..., 0]).sum()),
        },
        "smooth": {"enabled": bool(smooth), "lambda": float(lam), "iterations": int(iterations)},
        "invented": invented_runs(invented, list(body.labels)),
    }
    return cleaned, report
