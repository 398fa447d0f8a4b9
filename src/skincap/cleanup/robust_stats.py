"""NaN-aware robust statistics along time: medians that ignore missing samples.

The cleanup stages compare each sample with a robust summary of its neighbours in time
or space; these helpers compute those summaries without NumPy's all-NaN warnings.
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import as_trajectories
from skincap.errors import ValidationError

__all__ = ["nan_median", "nan_median_last", "running_median"]

#: Elements per chunk of the running median's window stack (bounds its memory).
_CHUNK_ELEMENTS = 1 << 22


def nan_median_last(values: np.ndarray, *, min_count: int = 1) -> np.ndarray:
    """Median over the last axis ignoring NaN; NaN where fewer than ``min_count`` values.

    No RuntimeWarning for all-NaN slices (unlike ``np.nanmedian``).
    """
    s = np.sort(values, axis=-1)  # NaN sort last
    count = (~np.isnan(values)).sum(axis=-1)
    lo = np.clip((count - 1) // 2, 0, None)
    hi = np.clip(count // 2, 0, values.shape[-1] - 1)
    a = np.take_along_axis(s, lo[..., None], axis=-1)[..., 0]
    b = np.take_along_axis(s, hi[..., None], axis=-1)[..., 0]
    return np.where(count >= max(min_count, 1), 0.5 * (a + b), np.nan)


def _run_ends(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, N) first and last frame of the run of present samples each sample is in."""
    t, n = valid.shape
    frame = np.arange(t)[:, None].repeat(n, 1)
    first = valid & ~np.vstack([np.zeros((1, n), bool), valid[:-1]])
    last = valid & ~np.vstack([valid[1:], np.zeros((1, n), bool)])
    start = np.maximum.accumulate(np.where(first, frame, -1), axis=0)
    end = np.minimum.accumulate(np.where(last, frame, t)[::-1], axis=0)[::-1]
    return start, end


def nan_median(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """Median along ``axis`` ignoring NaN, NaN where all are NaN (without NumPy's warning)."""
    return nan_median_last(np.moveaxis(np.asarray(values, dtype=np.float64), axis, -1))


def running_median(positions: np.ndarray, window: int = 9) -> np.ndarray:
    """Per-coordinate running median along time, within each run of present samples.

    Past either end of a run the window sees the run's odd reflection ``2 x[end] -
    x[2 end - t]``, so a marker moving steadily up to a gap or the take's end has no
    bias there.

    Parameters
    ----------
    positions : (T, N, 3) float; NaN where missing
    window : odd int >= 3
        Frames in the window, centred. A run of up to ``window // 2`` outlying frames
        inside a run does not move the median.

    Returns
    -------
    (T, N, 3) float64; NaN where missing
    """
    p = as_trajectories(positions)
    if window < 3 or window % 2 == 0:
        raise ValidationError(f"window: expected an odd number >= 3, got {window!r}")
    t, n, _ = p.shape
    valid = ~np.isnan(p[..., 0])
    live = valid.any(axis=0)
    if not live.all():  # columns never present (padded neighbour slots) stay NaN, unworked
        out = np.full_like(p, np.nan)
        if live.any():
            out[:, live] = running_median(p[:, live], window)
        return out
    start, end = _run_ends(valid)
    frame = np.arange(t)[:, None]
    # frames of the run before and after each present sample (a window reaching further
    # takes the reflection); a missing sample never reflects
    room_before = np.where(valid, frame - start, window)
    room_after = np.where(valid, end - frame, window)
    half = window // 2
    out = np.full_like(p, np.nan)
    step = max(1, _CHUNK_ELEMENTS // max(1, n * 3 * window))
    padded = np.concatenate([np.zeros((half, n, 3)), np.nan_to_num(p), np.zeros((half, n, 3))])
    # NaN (a missing y or z beside a present x) or inf in a window: take the partition
    finite = bool(np.isfinite(p[valid]).all())
    p_flat, start_flat, end_flat = p.reshape(-1, 3), start.reshape(-1), end.reshape(-1)
    for a in range(0, t, step):
        b = min(t, a + step)
        slots = []
        for k in range(-half, half + 1):
            v = padded[a + half + k : b + half + k].copy()  # x[t + k] inside the run
            if k:
                room = room_before[a:b] if k < 0 else room_after[a:b]
                tt, cc = np.nonzero(room < abs(k))
            if k and tt.size:  # past a run end: its odd reflection 2 x[end] - x[2 end - t - k]
                at = (tt + a) * n + cc  # flat (frame, marker) indices: 1-D gathers
                s0, e0 = start_flat[at], end_flat[at]
                anchor = s0 if k < 0 else e0
                idx = np.clip(2 * anchor - (tt + a + k), s0, e0)
                v.reshape(-1, 3)[tt * n + cc] = 2 * p_flat[anchor * n + cc] - p_flat[idx * n + cc]
            slots.append(v)
        out[a:b] = np.where(valid[a:b, :, None], _median_of(slots, finite=finite), np.nan)
    return out


# Devillard's median-of-9 exchange network (19 compare-exchanges, after Paeth): picks the
# same element a sort would, with elementwise minimum/maximum instead of a partition
# along a short last axis (several times faster in NumPy).
_MEDIAN9 = (
    (1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3),
    (5, 8), (4, 7), (3, 6), (1, 4), (2, 5), (4, 7), (4, 2), (6, 4), (4, 2),
)  # fmt: skip


def _median_of(slots: list[np.ndarray], *, finite: bool) -> np.ndarray:
    """Elementwise median of an odd number of equally shaped float arrays.

    ``finite``: every value is finite, so the window of 9 can take the exchange network
    (it overwrites ``slots``); otherwise a partition, which sorts NaN last.
    """
    half = len(slots) // 2
    if len(slots) != 9 or not finite:
        return np.partition(np.stack(slots, axis=-1), half, axis=-1)[..., half]
    v = list(slots)
    spare = np.empty_like(v[0])
    for i, j in _MEDIAN9:
        np.minimum(v[i], v[j], out=spare)
        np.maximum(v[i], v[j], out=v[j])
        v[i], spare = spare, v[i]
    return v[4]
