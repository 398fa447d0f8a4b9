"""``skincap track`` as a file-in, folder-out workflow: read points, track the rope, write.

The output folder holds (:data:`OUTPUT_NAMES`):

``rope.c3d``
    The rope markers ``rope_00…`` in order along the rope, invented samples flagged
    (C3D camera mask, read back as ``MarkerSet.invented``).
``body_points.csv``
    Every point the rope did not take, in skincap's long point format (with the
    input's ids when it had them), ready for body labelling.
``rope_curve.csv``
    The rope resampled at equal arc length per frame (:mod:`skincap.io.rope_curve`).
``report.json``
    :func:`track_report`.

This module composes :mod:`skincap.tracking` with :mod:`skincap.io`; the tracking
algorithms themselves never touch files.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError, OutputExistsError, ValidationError
from skincap.io.json_file import write_json
from skincap.io.rope_curve import write_rope_curve
from skincap.tracking.curve import resample_by_arclength
from skincap.tracking.tracker import RopeTrack
from skincap.types import MarkerSet, PointCloud
from skincap.workflows.progress import FrameProgress, frame_fractions

__all__ = [
    "OUTPUT_NAMES",
    "read_track_points",
    "track_file",
    "track_report",
    "write_track_outputs",
]

#: The files written into the output folder.
OUTPUT_NAMES = ("rope.c3d", "body_points.csv", "rope_curve.csv", "report.json")


def read_track_points(path: str | os.PathLike[str]) -> PointCloud:
    """The input of ``track`` as an un-indexed PointCloud: long point CSV, OptiTrack CSV or C3D.

    A MarkerSet (OptiTrack CSV, C3D) must hold only unlabelled ``*N`` points; its
    labels are dropped (the tracker sees points, not trajectories).

    Raises
    ------
    FormatError
        The file cannot be read, holds labelled markers, or is not a capture.
    """
    from skincap import io

    obj = io.read(path)
    if isinstance(obj, PointCloud):
        return obj
    if isinstance(obj, MarkerSet):
        labelled = [label for label in obj.labels if not label.startswith("*")]
        if labelled:
            raise FormatError(
                path,
                f"track reads un-indexed points, but {len(labelled)} markers are labelled "
                f"(e.g. {labelled[0]!r}); give a points CSV or a file of '*N' points",
            )
        return PointCloud.from_markerset(obj, keep_ids=False)
    raise FormatError(path, "track reads a points CSV, an OptiTrack CSV or a C3D of '*N' points")


def track_file(
    input_file: str | os.PathLike[str],
    folder: str | os.PathLike[str],
    *,
    box: Sequence[float] | None = None,
    markers: Sequence[int] | None = None,
    auto: bool = False,
    window_seconds: float = 0.5,
    force: bool = False,
    progress: FrameProgress | None = None,
) -> dict[str, Any]:
    """Track the rope in ``input_file`` and write :data:`OUTPUT_NAMES` into ``folder``.

    Parameters
    ----------
    input_file : path-like
        Long points CSV, OptiTrack CSV or C3D of ``*N`` points (:func:`read_track_points`).
    folder : path-like
        Created if missing.
    box, markers, auto
        Exactly one selects the rope in frame 0: a box ``x0,y0,z0,x1,y1,z1`` (metres,
        Y up), indices among frame 0's points, or ``auto=True``
        (:func:`skincap.tracking.init.init_rope`).
    window_seconds : float
        Seconds at the start where the rope hangs still.
    force : bool
        Replace existing outputs; otherwise an existing one is refused before
        anything is read.
    progress : FrameProgress, optional
        Called with the frames tracked so far.

    Returns
    -------
    dict
        The report (:func:`track_report`).
    """
    from skincap.io.output_safety import guard_outputs
    from skincap.tracking.init import init_rope
    from skincap.tracking.tracker import track_rope

    out = Path(folder)
    outputs = [out / name for name in OUTPUT_NAMES]
    with guard_outputs([input_file], outputs, folders=[out], force=force):
        if sum([box is not None, markers is not None, auto]) != 1:
            raise ValidationError("track_file: give exactly one of box, markers or auto=True")
        cloud = read_track_points(input_file)
        if box is not None:
            init = init_rope(cloud, box=box, window_seconds=window_seconds)
        elif markers is not None:
            init = init_rope(cloud, markers=markers, window_seconds=window_seconds)
        else:
            init = init_rope(cloud, auto=True, window_seconds=window_seconds)
        result = track_rope(cloud, init, progress=frame_fractions(progress, cloud.n_frames))
        return write_track_outputs(cloud, result, out, force=force)


def track_report(cloud: PointCloud, track: RopeTrack) -> dict[str, Any]:
    """Summary of a tracking run as JSON-ready values.

    Points per frame (min, mean, max), rope markers and their spacings, invented
    samples (total, per marker, fraction, how many were moved back within the rope's
    length), lost traces with their lost frame counts and ``[first, last]`` frame runs,
    points taken by the rope and left to the body, γ, maxTempMarkers, how the rope
    was selected.
    """
    counts = cloud.counts
    taken = int((track.point_index >= 0).sum())
    lost_counts = track.lost_frames.sum(axis=0)
    return {
        "frames": int(cloud.n_frames),
        "rate": float(cloud.rate),
        "points": int(cloud.points.shape[0]),
        "points_per_frame": {
            "min": int(counts.min()) if counts.size else 0,
            "mean": float(counts.mean()) if counts.size else 0.0,
            "max": int(counts.max()) if counts.size else 0,
        },
        "rope_markers": list(track.labels),
        "rope_selection": str(track.init.meta.get("method", "")),
        "rope_first_frame_indices": [int(i) for i in track.init.indices],
        "spacing_m": [float(v) for v in track.init.spacing],
        "gamma_m": float(track.init.gamma),
        "max_temp_markers": int(track.init.max_temp_markers),
        "rope_points": taken,
        "body_points": int(cloud.points.shape[0]) - taken,
        "invented_samples": int(track.invented.sum()),
        "invented_fraction": float(track.invented.mean()) if track.invented.size else 0.0,
        "invented_per_marker": {
            label: int(n) for label, n in zip(track.labels, track.invented.sum(axis=0), strict=True)
        },
        "lost_traces": [
            {"marker": label, "lost_frames": int(n), "lost_runs": _runs(track.lost_frames[:, j])}
            for j, (label, n) in enumerate(zip(track.labels, lost_counts, strict=True))
            if n > 0
        ],
        "invented_bounded": int(track.meta.get("invented_bounded", 0)),
    }


def _runs(mask: np.ndarray) -> list[list[int]]:
    """``[first, last]`` frame of each run of True in a (T,) mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return [
        [int(a), int(b) - 1]
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True)
    ]


def _resample_finite(positions: np.ndarray, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`resample_by_arclength` per frame through the markers that are not NaN.

    Frames sharing a pattern of lost markers are resampled together; a frame with
    fewer than two markers left gives NaN.
    """
    finite = np.isfinite(positions).all(axis=2)  # (T, M)
    s = np.full(positions.shape[:1] + (n_samples,), np.nan)
    pts = np.full(positions.shape[:1] + (n_samples, 3), np.nan)
    patterns, which = np.unique(finite, axis=0, return_inverse=True)
    for p, keep in enumerate(patterns):
        frames = np.flatnonzero(which.ravel() == p)
        if keep.sum() >= 2:
            s[frames], pts[frames] = resample_by_arclength(positions[frames][:, keep], n_samples)
    return s, pts


def write_track_outputs(
    cloud: PointCloud,
    track: RopeTrack,
    folder: str | os.PathLike[str],
    *,
    force: bool = False,
    curve_samples: int = 50,
) -> dict[str, Any]:
    """Write the results of :func:`~skincap.tracking.tracker.track_rope` into ``folder``.

    ``rope.c3d``
        The rope markers ``rope_00…`` in order along the rope, invented samples
        flagged (C3D camera mask, read back as ``MarkerSet.invented``).
    ``body_points.csv``
        Every point the rope did not take, in skincap's long point format (with the
        input's ids when it had them), ready for body labelling.
    ``rope_curve.csv``
        ``frame,s,x,y,z``: the rope resampled at ``curve_samples`` points of equal
        arc length per frame (``s`` metres from the first marker), Y up, metres
        (:func:`skincap.io.rope_curve.write_rope_curve`); through the markers that are
        not lost (NaN rows where fewer than two are left).
    ``report.json``
        :func:`track_report`.

    Parameters
    ----------
    cloud : PointCloud
        The tracked take.
    track : RopeTrack
    folder : path-like
        Created if missing.
    force : bool
        Replace existing outputs; otherwise an existing one raises
        :class:`~skincap.errors.OutputExistsError` before anything is written.
    curve_samples : int
        Samples per frame of the resampled curve, >= 2.

    Returns
    -------
    dict
        The report.
    """
    from skincap.io.c3d import write_c3d
    from skincap.io.csv import write_points_csv

    if track.n_frames != cloud.n_frames:
        raise ValidationError(f"track: {track.n_frames} frames but the cloud has {cloud.n_frames}")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    if not force:
        for name in OUTPUT_NAMES:
            if (out / name).exists():
                raise OutputExistsError(out / name)
    write_c3d(track.to_markerset(), out / "rope.c3d", force=force)
    write_points_csv(
        cloud.select(~track.rope_points_mask(cloud)), out / "body_points.csv", force=force
    )
    s, pts = _resample_finite(track.positions, curve_samples)
    write_rope_curve(out / "rope_curve.csv", s, pts, force=force)
    report = track_report(cloud, track)
    write_json(out / "report.json", report, force=force, indent=2)
    return report
