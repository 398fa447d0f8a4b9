"""What the cleaner must not trust in measured data: the take's noise, spikes, label swaps.

Real captures are not Gaussian: a marker jumps a few centimetres for a frame or three
(a reflection, a merged blob), two neighbouring markers exchange labels for a while.
The cleanup must neither smooth such samples into their neighbours nor keep them as
measured. This module finds them; :mod:`skincap.cleanup.pipeline` removes them (the
hole filler then replaces them) and flags every sample it changed as invented.

* :func:`measurement_noise` -- each marker's measurement noise σ, from the data alone:
  a robust MAD of the high-pass residual ``x[t] - (-x[t-2] + 4x[t-1] + 4x[t+1] -
  x[t+2]) / 6`` (the cubic through the four neighbours in time, exact on any cubic
  motion), whose variance is ``(1 + 34/36) σ²`` for white noise.
* :func:`find_spikes` -- samples far from the running median (window 9: a bump of up
  to 4 frames cannot move it) of their trajectory *in the local frame of their skin
  neighbours* (fitted robustly: one bad neighbour is dropped for that frame). Real
  motion, however fast, moves the neighbourhood with the marker and leaves the local
  trajectory smooth; a spike does not.
* :func:`find_label_swaps` -- two neighbouring markers that each jump onto where the
  other was heading, in the same frame, and later back.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap._arrays import as_trajectories
from skincap.cleanup.local_frames import neighbour_table
from skincap.cleanup.robust_stats import nan_median_last, running_median
from skincap.errors import ValidationError

__all__ = ["find_label_swaps", "find_spikes", "measurement_noise"]

#: Variance of the cubic-prediction residual over the variance of white noise.
_RESIDUAL_GAIN = 1.0 + 34.0 / 36.0
#: Elements per chunk of the (frames, markers, window) temporaries.
_CHUNK_ELEMENTS = 1 << 22


def measurement_noise(positions: np.ndarray) -> np.ndarray:
    """Each marker's measurement noise σ (metres), estimated from the take.

    The residual of each sample against the cubic through its four neighbours in time,
    ``e = x[t] - (-x[t-2] + 4x[t-1] + 4x[t+1] - x[t+2]) / 6``, is zero for any cubic
    motion and has variance ``(1 + 34/36) σ²`` for white noise of deviation σ. σ is
    the robust deviation ``1.4826 MAD`` of ``e`` over all three coordinates and every
    frame where the five samples are present, divided by ``sqrt(1 + 34/36)``; the MAD
    ignores the few spikes and fast accelerations.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing

    Returns
    -------
    (N,) float64, metres
        NaN for a marker with fewer than 10 usable residuals.
    """
    p = as_trajectories(positions)
    t, n, _ = p.shape
    if t < 5:
        return np.full(n, np.nan)
    e = p[2:-2] - (-p[:-4] + 4 * p[1:-3] + 4 * p[3:-1] - p[4:]) / 6.0  # (T-4, N, 3)
    e = np.moveaxis(e, 1, 0).reshape(n, -1)  # (N, 3 (T-4))
    med = nan_median_last(e)
    mad = nan_median_last(np.abs(e - med[:, None]))
    usable = (~np.isnan(e)).sum(axis=1) >= 30
    return np.where(usable, 1.4826 * mad / np.sqrt(_RESIDUAL_GAIN), np.nan)


def find_spikes(
    positions: np.ndarray,
    neighbours: Any,
    *,
    candidates: np.ndarray | None = None,
    window: int = 9,
    threshold: float = 10.0,
    floor: float = 0.01,
) -> np.ndarray:
    """Measured samples that jump away from their trajectory, alone among their neighbours.

    Two residuals against a running median over ``window`` frames
    (:func:`running_median`): the global one less the median of the neighbours' in the
    same frame (``e_g = r - median_k r_k``, one bad neighbour is outvoted), and the
    one of the marker's trajectory in its neighbours' local frame
    (:func:`~skincap.cleanup.smooth.local_trajectories`, fitted robustly). A sample is
    a spike when both exceed ``max(threshold * median_t |e|, floor)`` (the median over
    the marker's take): real fast motion is shared by the neighbourhood and leaves at
    least one of them small. A sample without a local frame (fewer than three
    neighbours present) is judged on ``e_g`` alone against twice the floor.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    neighbours : MarkerSurface or CSR (offsets (N+1,), indices)
    candidates : (T, N) bool, optional
        Samples that may be called spikes (default: every present sample).
    window : odd int
        Running-median window in frames; spikes up to ``window // 2`` frames long.
    threshold : float
        Multiple of the marker's typical ``|e|``.
    floor : float, metres
        Never a spike below this distance (default 1 cm).

    Returns
    -------
    (T, N) bool
    """
    p = as_trajectories(positions)
    t, n, _ = p.shape
    present = ~np.isnan(p[..., 0])
    if t < window:
        return np.zeros((t, n), dtype=bool)
    from skincap.cleanup.smooth import local_trajectories

    # own trajectory, less what the neighbours did (a median: one bad neighbour is outvoted)
    r = p - running_median(p, window)
    table, valid = neighbour_table(neighbours, n)
    e_global = r.copy()
    k = table.shape[1]
    if k:
        step = max(1, _CHUNK_ELEMENTS // max(1, n * 3 * k))
        for a in range(0, t, step):
            nb = np.where(valid[None, :, :, None], r[a : a + step][:, table], np.nan)
            ok = (~np.isnan(nb[..., 0])).sum(axis=2) >= 2  # (B, N)
            consensus = nan_median_last(np.moveaxis(nb, 2, 3))  # (B, N, 3)
            e_global[a : a + step] = np.where(
                ok[..., None], r[a : a + step] - consensus, r[a : a + step]
            )
    # the trajectory in the neighbours' (robust) local frame
    local, _, _ = local_trajectories(p, neighbours)
    e_local = local - running_median(local, window)
    spike = _beyond(e_global, threshold, floor) & _beyond(e_local, threshold, floor)
    # without a local frame (fewer than three neighbours present): the global test alone,
    # against twice the floor
    bare = np.isnan(local[..., 0]) & present
    spike |= bare & _beyond(e_global, threshold, 2 * floor)
    spike &= present
    if candidates is not None:
        c = np.asarray(candidates, dtype=bool)
        if c.shape != (t, n):
            raise ValidationError(f"candidates: expected shape ({t}, {n}), got {c.shape}")
        spike &= c
    return spike


def _beyond(e: np.ndarray, threshold: float, floor: float) -> np.ndarray:
    """(T, N) bool: ``|e| > max(threshold * median_t |e|, floor)`` per marker."""
    size = np.linalg.norm(e, axis=-1)
    typical = nan_median_last(size.T)  # (N,)
    limit = np.maximum(threshold * np.nan_to_num(typical, nan=np.inf), floor)
    return np.nan_to_num(size, nan=0.0) > limit[None, :]


def _edge_pairs(neighbours: Any, n: int) -> np.ndarray:
    table, valid = neighbour_table(neighbours, n)
    i = np.repeat(np.arange(n), valid.sum(axis=1))
    j = table[valid]
    pairs = np.unique(np.sort(np.stack([i, j], axis=1), axis=1), axis=0)
    return pairs[pairs[:, 0] != pairs[:, 1]]


def _close_pairs(p: np.ndarray, reach: float = 0.1, every: int = 3) -> np.ndarray:
    """(P, 2) pairs ``i < j`` where ``j`` is ``i``'s nearest marker in some frame (every
    ``every``-th frame: two markers close enough to swap stay close for a few frames),
    within ``reach`` metres (the markers a swap can happen between)."""
    p = p[::every]
    t, n, _ = p.shape
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    found = []
    step = max(1, _CHUNK_ELEMENTS // max(1, n * n))
    for a in range(0, t, step):
        q = p[a : a + step]
        ok = ~np.isnan(q[..., 0])
        qz = np.where(ok[..., None], q, 0.0)
        sq = (qz**2).sum(axis=-1)
        d2 = sq[:, :, None] + sq[:, None, :] - 2.0 * np.einsum("fnc,fmc->fnm", qz, qz)
        d2 = np.where(ok[:, :, None] & ok[:, None, :], d2, np.inf)
        d2[:, np.arange(n), np.arange(n)] = np.inf
        near = np.argmin(d2, axis=2)  # (B, N)
        close = np.take_along_axis(d2, near[..., None], axis=2)[..., 0] < reach**2
        i = np.broadcast_to(np.arange(n), near.shape)[close]
        found.append(np.sort(np.stack([i, near[close]], axis=1), axis=1))
    pairs = np.concatenate(found, axis=0) if found else np.zeros((0, 2), dtype=np.int64)
    return np.unique(pairs, axis=0) if pairs.size else np.zeros((0, 2), dtype=np.int64)


def find_label_swaps(
    positions: np.ndarray,
    neighbours: Any,
    *,
    candidates: np.ndarray | None = None,
    ratio: float = 0.2,
    floor: float = 0.01,
) -> list[tuple[int, int, np.ndarray]]:
    """Pairs of neighbouring markers whose labels were exchanged for some frames.

    At a swap both markers jump in the same frame, each onto where the other was
    heading: with the constant-velocity predictions ``p = 2x[t-1] - x[t-2]`` (or
    ``x[t-1]``), the crossed error ``|x_i - p_j| + |x_j - p_i|`` is below ``ratio``
    times the straight one ``|x_i - p_i| + |x_j - p_j|``, and the straight one is
    above ``floor``. The frames from a pair's swap event to the next (or to the first
    frame either marker is missing: a swap back inside a gap cannot be seen) are
    swapped. A marker repaired in two pairs at the same frame is ambiguous: neither
    pair is repaired.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    neighbours : MarkerSurface or CSR
        Swaps are looked for between neighbours and between each marker and the
        marker nearest to it in some frame (every third frame, within 10 cm) only.
    candidates : (T, N) bool, optional
        Samples that may take part (default all present).
    ratio, floor : float
        See above; ``floor`` in metres.

    Returns
    -------
    list of (i, j, frames)
        Marker columns ``i < j`` and the (F,) frames whose samples should be exchanged.
    """
    p = as_trajectories(positions)
    t, n, _ = p.shape
    if t < 3 or n < 2:
        return []
    # surface neighbours and, as a swap needs two markers close together, the nearest ones
    pairs = np.concatenate([_edge_pairs(neighbours, n), _close_pairs(p)], axis=0)
    if pairs.size == 0:
        return []
    pairs = np.unique(pairs, axis=0)
    ok = ~np.isnan(p[..., 0])
    if candidates is not None:
        ok &= np.asarray(candidates, dtype=bool)
    pred = _predict(p, ok)
    xi, xj = p[2:, pairs[:, 0]], p[2:, pairs[:, 1]]  # (T-2, E, 3)
    pi, pj = pred[:, pairs[:, 0]], pred[:, pairs[:, 1]]
    event = _swap_events(xi, xj, pi, pj, ratio, floor)
    out: list[tuple[int, int, np.ndarray]] = []
    for e in np.flatnonzero(event.any(axis=0)):
        i, j = int(pairs[e, 0]), int(pairs[e, 1])
        frames = _pair_swap_frames(p[:, [i, j]], ok[:, [i, j]], ratio, floor)
        if frames.size:
            out.append((i, j, frames))
    # a marker in two repaired pairs at the same frame is ambiguous: keep neither
    owner: dict[tuple[int, int], int] = {}
    clash: set[int] = set()
    for k, (i, j, frames) in enumerate(out):
        for f in frames.tolist():
            for c in (i, j):
                if (f, c) in owner and owner[(f, c)] != k:
                    clash.update({k, owner[(f, c)]})
                owner[(f, c)] = k
    return [item for k, item in enumerate(out) if k not in clash]


def _predict(p: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Constant-velocity prediction of frames 2..T-1 from the two frames before
    (``x[t-1]`` when ``x[t-2]`` is missing); (T-2, ..., 3)."""
    both = (ok[1:-1] & ok[:-2])[..., None]
    one = ok[1:-1][..., None]
    return np.where(both, 2 * p[1:-1] - p[:-2], np.where(one, p[1:-1], np.nan))


def _swap_events(
    xi: np.ndarray, xj: np.ndarray, pi: np.ndarray, pj: np.ndarray, ratio: float, floor: float
) -> np.ndarray:
    """(F, ...) bool: the crossed assignment explains the frame far better."""
    straight = np.linalg.norm(xi - pi, axis=-1) + np.linalg.norm(xj - pj, axis=-1)
    crossed = np.linalg.norm(xi - pj, axis=-1) + np.linalg.norm(xj - pi, axis=-1)
    event = np.zeros(straight.shape, dtype=bool)
    known = ~np.isnan(straight) & ~np.isnan(crossed)
    event[known] = (straight[known] > floor) & (crossed[known] < ratio * straight[known])
    return event


def _pair_swap_frames(pair: np.ndarray, ok: np.ndarray, ratio: float, floor: float) -> np.ndarray:
    """Frames where one pair's two columns are swapped, (F,) int.

    Events are found one after the other: after a swap the columns are exchanged from
    that frame on, so the next prediction (and so the swap back) uses the right
    samples.
    """
    t = pair.shape[0]
    x = pair.copy()
    k = ok.copy()
    toggles = np.zeros(t + 1, dtype=np.int64)
    start = 2
    for _ in range(10_000):
        if start >= t:
            break
        pred = _predict(x[start - 2 :], k[start - 2 :])
        ev = _swap_events(x[start:, 0], x[start:, 1], pred[:, 0], pred[:, 1], ratio, floor)
        hit = np.flatnonzero(ev)
        if hit.size == 0:
            break
        f = start + int(hit[0])
        toggles[f] += 1
        x[f:] = x[f:, ::-1]
        k[f:] = k[f:, ::-1]
        start = f + 1
    # the state toggles at each swap; a frame where either marker is missing ends it
    # (a swap back hidden in the gap cannot be seen, so nothing after it is assumed)
    both = ok.all(axis=1)
    swapped = np.zeros(t, dtype=bool)
    state = False
    for f in range(t):
        if toggles[f]:
            state = not state if toggles[f] % 2 else state
        if not both[f]:
            state = False
        swapped[f] = state
    seen = ok.any(axis=1)
    return np.flatnonzero(swapped & seen)
