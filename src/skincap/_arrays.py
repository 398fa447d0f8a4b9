"""Small helpers every layer shares: runs of missing samples, shape and scalar checks, progress.

Kept at the ground floor (it imports only :mod:`skincap.errors`) so that io, the
algorithms and the workflows find a run of gaps, check a ``(T, N, 3)`` array and report
progress the same way, with the house error messages.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = [
    "Progress",
    "missing_runs",
    "interior_runs",
    "as_points",
    "as_trajectories",
    "as_finite_array",
    "broadcast_leading",
    "check_positive",
    "check_nonnegative",
    "check_finite",
    "check_count",
    "track_largest_step",
]

#: A progress callback: ``progress(fraction in [0, 1], message)``. ``None`` where taken
#: means no reporting. The CLI turns it into a progress bar; library code only calls it.
Progress = Callable[[float, str], None]


def missing_runs(missing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every maximal run of missing samples, per column, the take's ends included.

    Parameters
    ----------
    missing : (T, N) bool
        True where column n is missing in frame t.

    Returns
    -------
    column : (R,) int64
    start : (R,) int64
        First missing frame of each run.
    length : (R,) int64
        Number of missing frames. Sorted by column, then start.
    """
    missing = np.asarray(missing, dtype=bool)
    if missing.ndim != 2:
        raise ValidationError(f"missing: expected shape (T, N), got {missing.shape}")
    t, n = missing.shape
    if t == 0 or n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty.copy(), empty.copy()
    # Pad with "present" so every run has a start and an end edge.
    padded = np.zeros((t + 2, n), dtype=np.int8)
    padded[1:-1] = missing
    edges = np.diff(padded, axis=0)  # (T + 1, N): +1 at a run start, -1 one past its end
    # nonzero on the transpose lists (column, frame) sorted by column then frame, so the
    # k-th start and the k-th end belong to one run.
    column, starts = np.nonzero(edges.T == 1)
    _, ends = np.nonzero(edges.T == -1)
    return column.astype(np.int64), starts.astype(np.int64), (ends - starts).astype(np.int64)


def interior_runs(missing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The runs of :func:`missing_runs` with a present sample on both sides (the gaps).

    A run at the start or the end of the take has nothing to fill between, so it is not
    a gap. Same shapes as :func:`missing_runs`.
    """
    column, start, length = missing_runs(missing)
    t = np.asarray(missing).shape[0]
    inside = (start > 0) & (start + length < t)
    return column[inside], start[inside], length[inside]


def as_points(values: object, name: str = "points") -> np.ndarray:
    """``values`` as a float64 ``(..., 3)`` array, or :class:`ValidationError` naming ``name``."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim < 1 or array.shape[-1] != 3:
        raise ValidationError(f"{name}: expected shape (..., 3), got {array.shape}")
    return array


def as_trajectories(values: object, name: str = "positions") -> np.ndarray:
    """``values`` as a float64 ``(T, N, 3)`` array (NaN where missing), or :class:`ValidationError`."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValidationError(f"{name}: expected shape (T, N, 3), got {array.shape}")
    return array


def as_finite_array(
    values: object, name: str, shape: tuple[int | None, ...], *, copy: bool = False
) -> np.ndarray:
    """``values`` as a finite float64 array of ``shape`` (None: any size on that axis).

    A copy when ``copy``. Raises :class:`ValidationError` naming ``name`` with the
    expected shape (``*`` for any size) and the actual one, or saying it must be finite.
    """
    want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
    try:
        arr = np.array(values, dtype=np.float64, copy=True if copy else None)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: expected a float array of shape {want}: {exc}") from None
    if arr.ndim != len(shape) or any(
        s is not None and s != n for s, n in zip(shape, arr.shape, strict=False)
    ):
        raise ValidationError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValidationError(f"{name}: must be finite")
    return arr


def broadcast_leading(*shapes: tuple[int, ...], error: str) -> tuple[int, ...]:
    """The shape the leading (batch) axes ``shapes`` broadcast to, or a ValidationError.

    ``np.broadcast_shapes(*shapes)``; when they do not broadcast, a
    :class:`ValidationError` whose message is ``error`` (name the arguments and give
    their shapes).
    """
    try:
        return np.broadcast_shapes(*shapes)
    except ValueError:
        raise ValidationError(error) from None


# ------------------------------------------------------------------ scalar arguments
def check_positive(
    name: str,
    value: Any,
    *,
    allow_inf: bool = False,
    expected: str = "a positive number",
    expected_finite: str = "a positive finite number",
) -> float:
    """``value`` as a float > 0 (finite unless ``allow_inf``), or a ValidationError.

    The message is ``name: expected <expected>, got <value>`` when ``value`` is not a
    number and ``name: expected <expected_finite>, got <value>`` when it is NaN, not
    positive, or infinite; the phrases let a caller say what the number is (``"a
    positive finite frame rate in Hz"``).
    """
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected {expected}, got {value!r}") from None
    if math.isnan(val) or val <= 0.0 or (math.isinf(val) and not allow_inf):
        raise ValidationError(f"{name}: expected {expected_finite}, got {value!r}")
    return val


def check_nonnegative(name: str, value: Any, *, allow_inf: bool = False) -> float:
    """``value`` as a float >= 0 (finite unless ``allow_inf``), or a ValidationError."""
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a number >= 0, got {value!r}") from None
    if math.isnan(val) or val < 0.0 or (math.isinf(val) and not allow_inf):
        raise ValidationError(f"{name}: expected a finite number >= 0, got {value!r}")
    return val


def check_finite(name: str, value: Any) -> float:
    """``value`` as a finite float, or a ValidationError."""
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a finite number, got {value!r}") from None
    if not math.isfinite(val):
        raise ValidationError(f"{name}: expected a finite number, got {value!r}")
    return val


def check_count(name: str, value: Any, *, minimum: int) -> int:
    """``value`` as an int >= ``minimum`` (a bool is not a count), or a ValidationError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValidationError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValidationError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def track_largest_step(
    blocks: Iterable[np.ndarray], fastest: list[tuple[float, int]]
) -> Iterator[np.ndarray]:
    """Yield the frame blocks ``(t, V, 3)`` unchanged while finding the largest step.

    ``fastest`` ends as ``[(step, frame)]``: the largest distance a point moves between
    two consecutive frames (the blocks' unit) and the later frame's number, steps across
    block boundaries included; ``[]`` for fewer than two frames. NaN (an unseen point)
    never counts. Memory: one block and one frame, so a long take can stream through.
    """
    last: np.ndarray | None = None
    offset = 0  # frame number of the block's first frame
    best = (-1.0, -1)  # a still mesh's 0.0 counts
    for block in blocks:
        # the previous block's last frame in front, so the step across the boundary counts
        joined = block if last is None else np.concatenate([last[None], block])
        first = offset if last is None else offset - 1  # frame number of joined[0]
        if joined.shape[0] > 1:
            d = np.linalg.norm(np.diff(joined, axis=0), axis=-1)  # (t, V)
            step = np.where(np.isfinite(d), d, -np.inf).max(axis=1)  # (t,)
            k = int(np.argmax(step))
            if step[k] > best[0]:
                best = (float(step[k]), first + k + 1)
        offset += block.shape[0]
        if block.shape[0]:
            last = block[-1]
        yield block
    if best[1] >= 0:
        fastest.append(best)
