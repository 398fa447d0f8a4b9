"""Files of ``skincap track``: the rope, the body points, the rope curve, a report.

This is the composition layer between the tracker and :mod:`skincap.io` (the CLI
calls it); the tracking algorithms themselves never import io.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError, ValidationError
from skincap.io._common import atomic_output
from skincap.tracking.curve import resample_by_arclength
from skincap.tracking.tracker import RopeTrack
from skincap.types import PointCloud

__all__ = [
    "OUTPUT_NAMES",
    "ROPE_CURVE_HEADER",
    "track_report",
    "write_track_outputs",
    "read_rope_curve",
    "is_rope_curve_csv",
]

#: The files written into the output folder.
OUTPUT_NAMES = ("rope.c3d", "body_points.csv", "rope_curve.csv", "report.json")
#: First line of ``rope_curve.csv``.
ROPE_CURVE_HEADER = "frame,s,x,y,z"
#: Rate of a ``rope_curve.csv`` without a ``report.json`` beside it, Hz.
DEFAULT_CURVE_RATE = 120.0


def _body_cloud(cloud: PointCloud, track: RopeTrack) -> PointCloud:
    """Every point the rope did not take, frames kept (ids kept when present)."""
    keep = ~track.rope_points_mask(cloud)
    frame = cloud.frame_index[keep]
    offsets = np.concatenate([[0], np.cumsum(np.bincount(frame, minlength=cloud.n_frames))])
    return PointCloud(
        points=cloud.points[keep],
        offsets=offsets,
        rate=cloud.rate,
        ids=None if cloud.ids is None else cloud.ids[keep],
        meta=dict(cloud.meta),
    )


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
        arc length per frame (``s`` metres from the first marker), Y up, metres;
        through the markers that are not lost (NaN rows where fewer than two are left).
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
    from skincap.errors import OutputExistsError
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
    write_points_csv(_body_cloud(cloud, track), out / "body_points.csv", force=force)
    s, pts = _resample_finite(track.positions, curve_samples)
    t_frames, n = s.shape
    table = np.column_stack([np.repeat(np.arange(t_frames), n), s.ravel(), pts.reshape(-1, 3)])
    lines = [ROPE_CURVE_HEADER]
    if table.size:
        cols = [np.char.mod("%d", table[:, 0].astype(np.int64))]
        cols += [np.char.mod("%.9g", table[:, c]) for c in range(1, 5)]
        lines.extend(",".join(r) for r in np.stack(cols, axis=1).tolist())
    with atomic_output(out / "rope_curve.csv", force=force) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="\n")
    report = track_report(cloud, track)
    with atomic_output(out / "report.json", force=force) as tmp:
        tmp.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return report


def is_rope_curve_csv(path: str | os.PathLike[str]) -> bool:
    """True when the file's first line is the ``rope_curve.csv`` header."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            first = fh.readline(256).decode("utf-8", errors="replace").strip().lower()
    except OSError as exc:
        raise FormatError(p, f"cannot read: {exc.strerror}") from None
    return first.replace(" ", "") == ROPE_CURVE_HEADER


def read_rope_curve(path: str | os.PathLike[str]) -> tuple[np.ndarray, float]:
    """Read a ``rope_curve.csv`` written by :func:`write_track_outputs`.

    Returns
    -------
    curves : (T, K, 3) float64, metres
        The resampled rope per frame (NaN for frames the file lacks).
    rate : float, Hz
        From the ``report.json`` beside it, else :data:`DEFAULT_CURVE_RATE`.

    Raises
    ------
    FormatError
        No rows, rows without 5 columns, decreasing frames, or frames with different
        sample counts.
    """
    p = Path(path)
    try:
        table = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise FormatError(p, f"rope curve table: {exc}") from None
    if table.size == 0:
        raise FormatError(p, "rope curve has no rows")
    if table.shape[1] != 5:
        raise FormatError(
            p, f"rope curve rows need 5 columns (frame,s,x,y,z), got {table.shape[1]}"
        )
    frames = table[:, 0].astype(np.int64)
    if (np.diff(frames) < 0).any() or frames[0] < 0:
        raise FormatError(p, "rope curve frames must start at >= 0 and not decrease")
    counts = np.bincount(frames)
    k = int(counts.max())
    if (counts[counts > 0] != k).any():
        raise FormatError(p, "rope curve: every frame needs the same number of samples")
    curves = np.full((counts.size, k, 3), np.nan)
    slot = np.arange(frames.size) - np.repeat(np.cumsum(counts) - counts, counts)
    curves[frames, slot] = table[:, 2:5]
    rate = DEFAULT_CURVE_RATE
    report = p.with_name("report.json")
    if report.is_file():
        try:
            value = json.loads(report.read_text(encoding="utf-8")).get("rate")
            if isinstance(value, (int, float)) and value > 0:
                rate = float(value)
        except (OSError, ValueError, AttributeError):
            pass
    return curves, rate
