"""The up axis of a C3D file that does not say (no ``POINT:Y_SCREEN``), from its markers.

Z up is the C3D norm and Vicon's, but not every writer's: BTS and MotionMonitor files
stand their subject along Y and leave ``Y_SCREEN`` out. Read as Z up, such a subject
lies on its back. :func:`guess_up_from_markers` keeps Z unless the markers clearly
stand along Y: in a typical frame the body spans at least :data:`MIN_BODY_SPAN_M` and
twice as much along Y as along Z, and Y has a floor (its lowest samples near zero,
as the lab's origin lies on the floor), which a subject lying along Y in a Z-up lab
does not (AML's prone start lies along X, its Y values reaching a metre below zero).
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_BODY_SPAN_M", "guess_up_from_markers"]

#: Least span (metres) of a typical frame's markers along the axis taken for up.
MIN_BODY_SPAN_M = 0.5
#: Y is taken only when a typical frame spans at least this multiple along Y as along Z.
SPAN_RATIO = 2.0
#: The floor: the 1st percentile of the up coordinate lies within these bounds (metres).
FLOOR_RANGE_M = (-0.1, 0.3)
#: Fewest markers a frame must see for its span to count.
MIN_MARKERS = 3


def _typical_span(coord: np.ndarray, seen: np.ndarray, judged: np.ndarray) -> float:
    """Median over the judged frames of the markers' extent along one axis (metres)."""
    hi = np.where(seen, coord, -np.inf).max(axis=0)[judged]  # (T',)
    lo = np.where(seen, coord, np.inf).min(axis=0)[judged]
    return float(np.median(hi - lo))


def guess_up_from_markers(xyz: np.ndarray, missing: np.ndarray, scale: float) -> str:
    """ "y" or "z": the up axis the markers of a C3D file stand along.

    Parameters
    ----------
    xyz : (3, N, T) float
        The markers' coordinates along the file's x, y, z, in file units.
    missing : (N, T) bool
        Samples to ignore.
    scale : float
        Metres per file unit.

    Returns
    -------
    str
        ``"y"`` only when a typical frame (median over frames seeing at least three
        markers) spans at least 0.5 m and twice as much along y as along z, and the 1st
        percentile of y lies between -0.1 and 0.3 m (a floor); ``"z"`` otherwise,
        including a take too sparse to judge.
    """
    seen = ~np.asarray(missing, dtype=bool) & np.isfinite(xyz).all(axis=0)  # (N, T)
    judged = seen.sum(axis=0) >= MIN_MARKERS  # (T,)
    if not judged.any():
        return "z"
    y = np.asarray(xyz[1], dtype=np.float64) * scale  # (N, T) metres
    z = np.asarray(xyz[2], dtype=np.float64) * scale
    span_y = _typical_span(y, seen, judged)
    span_z = _typical_span(z, seen, judged)
    if span_y < MIN_BODY_SPAN_M or span_y < SPAN_RATIO * span_z:
        return "z"
    floor = float(np.percentile(y[seen], 1.0))
    return "y" if FLOOR_RANGE_M[0] <= floor <= FLOOR_RANGE_M[1] else "z"
