"""``rope_curve.csv``: a tracked rope resampled per frame, ``frame,s,x,y,z``.

One row per sample: the frame (from 0), ``s`` the arc length in metres from the
rope's first marker, and the position in metres, Y up. Every frame has the same
number of samples. ``skincap track`` writes it (:mod:`skincap.workflows.track_file`)
and ``skincap view`` draws it. The file has no rate: the reader takes it from the
``report.json`` beside it (``track``'s report), else :data:`DEFAULT_CURVE_RATE`.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np

from skincap.errors import FormatError, ValidationError
from skincap.io._common import atomic_output

__all__ = [
    "ROPE_CURVE_HEADER",
    "DEFAULT_CURVE_RATE",
    "write_rope_curve",
    "read_rope_curve",
    "is_rope_curve_csv",
]

#: First line of ``rope_curve.csv``.
ROPE_CURVE_HEADER = "frame,s,x,y,z"
#: Rate of a ``rope_curve.csv`` without a ``report.json`` beside it, Hz.
DEFAULT_CURVE_RATE = 120.0


def write_rope_curve(
    path: str | os.PathLike[str], s: np.ndarray, points: np.ndarray, *, force: bool = False
) -> None:
    """Write a resampled rope as ``rope_curve.csv`` (atomically; ``force`` replaces).

    Parameters
    ----------
    path : path-like
    s : (T, K) float
        Arc length of each sample from the first marker, metres.
    points : (T, K, 3) float
        The samples, metres, Y up. Written with 9 significant digits (``%.9g``); NaN
        as ``nan``.
    """
    s = np.asarray(s, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    if s.ndim != 2 or points.shape != (*s.shape, 3):
        raise ValidationError(
            f"rope curve: s must be (T, K) and points (T, K, 3), got {s.shape} and {points.shape}"
        )
    t_frames, n = s.shape
    table = np.column_stack([np.repeat(np.arange(t_frames), n), s.ravel(), points.reshape(-1, 3)])
    lines = [ROPE_CURVE_HEADER]
    if table.size:
        cols = [np.char.mod("%d", table[:, 0].astype(np.int64))]
        cols += [np.char.mod("%.9g", table[:, c]) for c in range(1, 5)]
        lines.extend(",".join(r) for r in np.stack(cols, axis=1).tolist())
    with atomic_output(path, force=force) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="\n")


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
    """Read a ``rope_curve.csv`` written by :func:`write_rope_curve`.

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
        with warnings.catch_warnings():  # an empty table is reported below, as a FormatError
            warnings.simplefilter("ignore", UserWarning)
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
