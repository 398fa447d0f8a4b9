"""Refusing values a file format cannot hold, before anything is written.

Formats that store float32 (C3D, PC2, glTF, USD) or int16 (C3D integer parameters)
cannot hold every float64: 1e39 becomes ``inf`` in a float32, and a file that
skincap (or anyone) cannot read back. Writers call these checks on the data they are
about to narrow; the error names the value and where it is.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from skincap.errors import FormatError

__all__ = ["FLOAT32_MAX", "check_float32", "check_int_range", "frame_vertex_axis"]

#: The largest finite float32.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _first(bad: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.unravel_index(int(np.argmax(bad.ravel())), bad.shape))


def frame_vertex_axis(first_frame: int) -> Callable[[tuple[int, ...]], str]:
    """``where`` of :func:`check_float32` for a block of frames (T, V, 3) starting at
    ``first_frame``: ``"frame 12, vertex 3, z"``."""

    def where(idx: tuple[int, ...]) -> str:
        return f"frame {first_frame + idx[0]}, vertex {idx[1]}, {'xyz'[idx[2]]}"

    return where


def check_float32(
    values: np.ndarray,
    target: str | os.PathLike[str],
    where: Callable[[tuple[int, ...]], str],
    *,
    unit: str = "",
) -> None:
    """Raise FormatError when a finite value would overflow float32.

    Parameters
    ----------
    values : array of float
        What is about to be stored as float32, in the file's units. NaN and inf are
        not checked here (writers decide what they mean).
    target : path
        The file being written (named in the message).
    where : callable
        Index tuple of the first offending value -> words saying where it is
        (``"marker 'LASI', frame 12, z"``).
    unit : str
        Unit of ``values`` for the message.

    Raises
    ------
    FormatError
        ``<target>: <where>: 1e+39 mm does not fit the file's float32 (largest 3.4e+38)``.
    """
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = np.isfinite(v) & (np.abs(v) > FLOAT32_MAX)
    if bad.any():
        idx = _first(bad)
        value = float(v[idx])
        raise FormatError(
            target,
            f"{where(idx)}: {value:.6g}{' ' + unit if unit else ''} does not fit the file's "
            f"float32 (largest {FLOAT32_MAX:.3g}); nothing written",
        )


def check_int_range(
    values: np.ndarray,
    target: str | os.PathLike[str],
    what: str,
    *,
    low: int = -32768,
    high: int = 32767,
) -> None:
    """Raise FormatError when an integer to be stored (int16 by default) is out of range."""
    v = np.asarray(values)
    bad = (v < low) | (v > high)
    if bad.any():
        idx = _first(bad)
        raise FormatError(
            target,
            f"{what}: {int(v[idx])} at index {idx if len(idx) > 1 else idx[0]} does not fit "
            f"the file's {low}..{high}; nothing written",
        )
