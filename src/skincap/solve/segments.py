"""Per-segment technical frames: the rigid motion of a cluster of markers.

A segment's *technical frame* is the pose, per frame, that carries the cluster's
reference shape onto its measured markers (batched Kabsch, :func:`skincap.geometry.rigid.fit_rigid`).
The reference shape is not one frame's (a marker may be hidden there, and one frame's
noise would bias every pose): it starts from the frame where most markers are seen and
is refined as the median of the markers' local coordinates over all fitted frames,
which also places markers hidden in the starting frame.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.rigid import fit_rigid

__all__ = ["cluster_frames", "to_local", "to_world"]


def cluster_frames(
    points: np.ndarray, *, iterations: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Technical frames of a rigid cluster of markers.

    Parameters
    ----------
    points : (T, K, 3) float, metres
        The cluster's markers (K >= 3, real or virtual), NaN where missing.
    iterations : int, default 3
        Rounds of fit-all-frames / re-estimate-the-reference.

    Returns
    -------
    reference : (K, 3) float64, metres
        Each marker in the frame, centred on the reference's centroid; NaN for a
        marker never seen with two others.
    rotations : (T, 3, 3) float64
        World rotation of the frame; NaN where fewer than 3 markers are seen.
    translations : (T, 3) float64, metres
        World origin of the frame; NaN likewise.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[1] < 3:
        raise ValidationError(f"points: expected (T, K >= 3, 3), got {p.shape}")
    counts = np.isfinite(p).all(axis=2).sum(axis=1)  # (T,) markers seen per frame
    start = int(np.argmax(counts))
    if counts[start] < 3:
        raise ValidationError("points: no frame shows three markers of the cluster")
    ref = p[start] - np.nanmean(p[start], axis=0)
    use = np.ones(p.shape[1], dtype=bool)
    for _ in range(max(1, iterations)):
        rot, trans = fit_rigid(ref, p, mask=use)  # (T, 3, 3), (T, 3)
        local = to_local(rot, trans, p)  # (T, K, 3)
        fitted = np.isfinite(local).all(axis=2)
        new = np.full_like(ref, np.nan)
        have = fitted.any(axis=0)
        if have.any():
            new[have] = np.nanmedian(local[:, have], axis=0)
        new -= np.nanmean(new[use], axis=0)
        ref = new
        use = _rigid_members(local, ref)
    rot, trans = fit_rigid(ref, p, mask=use)
    return ref, rot, trans


#: A marker whose RMS distance from its place in the cluster exceeds both this
#: (metres) and RIGID_FACTOR times the cluster's median does not steer the frame.
RIGID_FLOOR_M = 0.003
RIGID_FACTOR = 2.5


def _rigid_members(local: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(K,) bool: markers that move rigidly with the cluster (skin over a joint does not).

    Keeps at least three (the most rigid) so the frame stays defined.
    """
    d2 = np.sum((local - ref) ** 2, axis=2)  # (T, K)
    seen = np.isfinite(d2)
    count = seen.sum(axis=0)
    rms = np.full(ref.shape[0], np.inf)
    ok = count > 0
    rms[ok] = np.sqrt(np.where(seen, d2, 0.0).sum(axis=0)[ok] / count[ok])
    finite = np.isfinite(rms)
    if finite.sum() <= 3:
        return finite if finite.sum() == 3 else np.ones(ref.shape[0], dtype=bool)
    limit = max(RIGID_FLOOR_M, RIGID_FACTOR * float(np.median(rms[finite])))
    use = rms <= limit
    if use.sum() < 3:
        use = np.zeros_like(use)
        use[np.argsort(rms)[:3]] = True
    return use


def to_local(rotations: np.ndarray, translations: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(T, K, 3) points expressed in the frames ``R^T (x - t)``; NaN spreads per frame."""
    return np.einsum("tji,tkj->tki", rotations, points - translations[:, None, :])


def to_world(rotations: np.ndarray, translations: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(T, K, 3) world positions ``R y + t`` of local points ``(K, 3)`` or ``(T, K, 3)``."""
    loc = np.broadcast_to(local, (rotations.shape[0], *np.shape(local)[-2:]))
    return np.einsum("tij,tkj->tki", rotations, loc) + translations[:, None, :]
