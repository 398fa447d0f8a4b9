"""Marker neighbourhoods as CSR ``(offsets, indices)``: checking one, finding one from
the motion, and each marker's mean distance to its neighbours.

Every local method of the cleanup (fill, smoothing, spike and swap detection) takes a
neighbourhood in this form, or a :class:`~skincap.cleanup.surface.MarkerSurface`
holding one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = ["CSR", "as_csr", "motion_neighbours", "mean_neighbour_distance"]

#: A neighbourhood: ``offsets`` (N + 1,) int64 and ``indices`` (E,) int64; marker ``i``'s
#: neighbours are ``indices[offsets[i]:offsets[i + 1]]``.
CSR = tuple[np.ndarray, np.ndarray]


def as_csr(neighbours: Any, n_markers: int) -> CSR:
    """Normalise a neighbour structure to CSR ``(offsets, indices)``.

    Parameters
    ----------
    neighbours : (offsets, indices) or an object with a ``neighbours`` attribute holding
        one (such as :class:`skincap.cleanup.surface.MarkerSurface`)
        ``offsets`` (N + 1,) int, non-decreasing from 0; marker ``i``'s neighbours are
        ``indices[offsets[i]:offsets[i + 1]]``, each in ``[0, N)`` and not ``i``.
    n_markers : int
        N.

    Returns
    -------
    offsets : (N + 1,) int64
    indices : (E,) int64
    """
    if hasattr(neighbours, "neighbours"):
        neighbours = neighbours.neighbours
    try:
        offsets, indices = neighbours
    except (TypeError, ValueError):
        raise ValidationError(
            "neighbours: expected a CSR pair (offsets, indices) or a MarkerSurface"
        ) from None
    offsets = np.asarray(offsets)
    indices = np.asarray(indices)
    if offsets.ndim != 1 or offsets.shape[0] != n_markers + 1:
        raise ValidationError(
            f"neighbours: offsets must have shape ({n_markers + 1},), got {offsets.shape}"
        )
    if not (np.issubdtype(offsets.dtype, np.integer) or offsets.size == 0):
        raise ValidationError(f"neighbours: offsets must be integers, got {offsets.dtype}")
    if indices.size and not np.issubdtype(indices.dtype, np.integer):
        raise ValidationError(f"neighbours: indices must be integers, got {indices.dtype}")
    offsets = offsets.astype(np.int64)
    indices = indices.astype(np.int64).reshape(-1)
    if offsets[0] != 0 or np.any(np.diff(offsets) < 0) or offsets[-1] != indices.size:
        raise ValidationError(
            "neighbours: offsets must start at 0, not decrease and end at len(indices)"
        )
    if indices.size and (indices.min() < 0 or indices.max() >= n_markers):
        raise ValidationError(f"neighbours: indices must lie in [0, {n_markers})")
    owner = np.repeat(np.arange(n_markers), np.diff(offsets))
    if np.any(owner == indices):
        raise ValidationError("neighbours: a marker cannot be its own neighbour")
    return offsets, indices


def motion_neighbours(positions: np.ndarray, k: int = 6, *, max_frames: int = 100) -> CSR:
    """Motion-consistent neighbours: for each marker the ``k`` markers whose distance
    to it stays most nearly constant through the take (skin and segment neighbours
    keep it; markers on other limbs do not), ties broken by closeness.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    k : int
        Neighbours per marker (capped at N - 1).
    max_frames : int
        Frames sampled evenly to measure the distances (bounds memory and time).

    Returns
    -------
    offsets : (N + 1,) int64
    indices : (N * k,) int64
        Each marker's neighbours, most consistent first. Pairs never seen together
        are never neighbours unless nothing else is left.
    """
    p = np.asarray(positions, dtype=np.float64)
    t, n, _ = p.shape
    k = int(min(k, n - 1))
    if k < 1:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    frames = np.unique(np.linspace(0, t - 1, min(t, max_frames)).round().astype(np.int64))
    q = p[frames]  # (F, N, 3)
    ok = ~np.isnan(q[..., 0])  # (F, N)
    qz = np.where(ok[..., None], q, 0.0)
    sq = (qz**2).sum(axis=-1)  # (F, N)
    # |a - b|² = |a|² + |b|² - 2 a·b, one matrix product per frame
    d2 = sq[:, :, None] + sq[:, None, :] - 2.0 * np.einsum("fnc,fmc->fnm", qz, qz)
    seen = ok[:, :, None] & ok[:, None, :]
    d = np.where(seen, np.sqrt(np.maximum(d2, 0.0)), np.nan)  # (F, N, N)
    count = seen.sum(axis=0)  # (N, N)
    dz = np.where(seen, d, 0.0)
    safe = np.maximum(count, 1)
    mean = dz.sum(axis=0) / safe
    var = np.maximum((dz**2).sum(axis=0) / safe - mean**2, 0.0)
    # score: distance variation plus a little of the distance itself (nearer preferred)
    score = np.sqrt(var) + 0.1 * mean
    score = np.where(count >= max(3, len(frames) // 10), score, np.inf)
    np.fill_diagonal(score, np.inf)
    order = np.argsort(score, axis=1, kind="stable")[:, :k]  # (N, k)
    offsets = np.arange(n + 1, dtype=np.int64) * k
    return offsets, order.reshape(-1).astype(np.int64)


def mean_neighbour_distance(positions: np.ndarray, neighbours: CSR) -> np.ndarray:
    """Each marker's mean distance to its neighbours, averaged over the take.

    Table 2's unit of Park & Hodgins (their "average distance to the neighbors").

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    neighbours : CSR (offsets (N + 1,), indices (E,))

    Returns
    -------
    (N,) float64, metres
        NaN for a marker without neighbours or never seen with one.
    """
    p = np.asarray(positions, dtype=np.float64)
    offsets, indices = neighbours
    n = p.shape[1]
    owner = np.repeat(np.arange(n), np.diff(offsets))
    d = np.linalg.norm(p[:, owner] - p[:, indices], axis=-1)  # (T, E)
    ok = np.isfinite(d)
    cnt = ok.sum(axis=0)
    edge = np.where(cnt > 0, np.where(ok, d, 0.0).sum(axis=0) / np.maximum(cnt, 1), np.nan)
    good = np.isfinite(edge)
    total = np.bincount(owner[good], weights=edge[good], minlength=n)
    num = np.bincount(owner[good], minlength=n)
    return np.where(num > 0, total / np.maximum(num, 1), np.nan)
