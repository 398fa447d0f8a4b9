"""Length units and up axis of BVH files: the table, and the guesses from a rest pose."""

from __future__ import annotations

import math

import numpy as np

from skincap.io._common import (
    UNIT_TO_METRES,
)

__all__ = ["BVH_UNITS", "guess_bvh_units", "guess_bvh_up"]


#: Length units of BVH files, metres per unit: the general units plus ``"cmu"``,
#: the CMU ASF unit (1/0.45 inch) of the cgspeed CMU conversions.
BVH_UNITS: dict[str, float] = dict(UNIT_TO_METRES)

#: The units :func:`guess_bvh_units` chooses from.
_GUESSABLE = ("m", "dm", "cm", "mm", "in", "cmu")
#: Typical standing height of the humans BVH files hold, metres.
_HUMAN_HEIGHT = 1.7
_PLAUSIBLE_HEIGHT = (1.0, 2.5)


def guess_bvh_units(height: float) -> str:
    """The unit that makes a skeleton ``height`` units tall a plausible human.

    Picks, among ``m``, ``dm``, ``cm``, ``mm``, ``in`` and ``cmu`` (the CMU ASF unit,
    1/0.45 inch), the one whose height in metres is closest to 1.7 m on a log scale
    (so 1.2-2.2 units -> m, 12-22 -> dm, 120-220 -> cm, 1200-2200 -> mm, 45-60 -> in,
    about 24-38 -> cmu).

    Parameters
    ----------
    height : float
        Largest extent of the rest-pose joint positions, in file units. A skeleton of
        zero (or non-finite) height gives ``"m"``.

    Returns
    -------
    str
        A key of :data:`BVH_UNITS`.
    """
    h = float(height)
    if not math.isfinite(h) or h <= 0:
        return "m"
    return min(_GUESSABLE, key=lambda u: abs(math.log(h * BVH_UNITS[u] / _HUMAN_HEIGHT)))


def _rest_extent(parents: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(3,) extent along the file's x, y, z of the rest-pose joint positions, offsets' unit."""
    pos = np.zeros_like(offsets)
    for k in range(parents.size):
        pos[k] = offsets[k] if parents[k] < 0 else pos[parents[k]] + offsets[k]
    return pos.max(axis=0) - pos.min(axis=0) if pos.size else np.zeros(3)


def _skeleton_height(parents: np.ndarray, offsets: np.ndarray) -> float:
    """Largest extent (over x, y, z) of the rest-pose joint positions, offsets' unit."""
    return float(_rest_extent(parents, offsets).max())


def standing_height(extent: np.ndarray, up: str) -> tuple[float, bool]:
    """The size a unit guess reads as a human height, from the rest pose's extent.

    A standing rest pose's height is its extent along the up axis; its arm span in a
    T-pose (fingertip end sites included) may be larger, so the largest extent would
    overstate it. A figure shorter along the up axis than half its largest extent does
    not stand that way (the wrong up axis given, a pair of arms): then the largest
    extent.

    Parameters
    ----------
    extent : (3,) float
        Extent of the rest-pose joints along the file's x, y, z, in file units.
    up : {"y", "z"}
        The file's up axis.

    Returns
    -------
    height : float
        File units.
    standing : bool
        Whether ``height`` is the extent along ``up`` (else the largest extent).
    """
    ext = np.asarray(extent, dtype=np.float64)
    along = float(ext["xyz".index(up)])
    largest = float(ext.max()) if ext.size else 0.0
    if along >= 0.5 * largest:
        return along, True
    return largest, False


def guess_bvh_up(extent: np.ndarray) -> str:
    """ "y" or "z": the up axis of a BVH file from its rest pose's extent (3,) along x, y, z.

    A BVH's rest pose stands (T- or A-pose). Read with the wrong up axis a standing
    body lies down: its extent along the supposed up axis is its depth, a fraction of
    its height. "z" only when the body is clearly standing along z (z extent at least
    twice the y extent and the largest of the two); otherwise "y", the BVH norm.
    """
    y, z = float(extent[1]), float(extent[2])
    return "z" if z > 0 and z >= 2.0 * y else "y"
