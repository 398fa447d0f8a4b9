"""Batched weighted absolute orientation (Kabsch / Horn) over leading axes.

The rigid fit is the workhorse of the marker cleanup (Park & Hodgins 2006, eqs. 2 and
5): for every frame and every marker, the rotation and translation that carry a set of
neighbour positions onto their reference positions. All functions batch over any number
of leading axes, so one call solves all frames and all markers at once.

Method (Kabsch 1976, the SVD form of Horn 1987): with weights ``w_k``, centroids
``c_s = Σ w_k s_k / Σ w_k`` and ``c_d`` alike, the cross-covariance
``H = Σ w_k (s_k - c_s)(d_k - c_d)^T = U S V^T`` gives ``R = V diag(1, 1, δ) U^T`` with
``δ = sign det(V U^T)`` (the reflection fix: the best *proper* rotation) and
``t = c_d - R c_s``. This minimises ``Σ w_k ||R s_k + t - d_k||²`` over proper rotations.

Degenerate configurations (all points on a line, or coincident) have a family of
minimisers; the function still returns one of them, a proper rotation whose residual is
minimal. Fewer than three valid points give NaN.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError

__all__ = ["apply_rigid", "fit_rigid", "invert_rigid"]


def _points(name: str, value: np.ndarray) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-1] != 3:
        raise ValidationError(f"{name} must have shape (..., K, 3); got {arr.shape}")
    return arr


def fit_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    *,
    min_points: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Best proper rigid transform with ``dst ≈ R @ src + t``, batched.

    Parameters
    ----------
    src, dst : (..., K, 3) float, any length unit (the same for both)
        Corresponding points. Leading axes broadcast against each other. A point with a
        NaN/inf coordinate in either array is ignored.
    weights : (..., K) float, optional
        Non-negative weight per correspondence (default 1). Non-finite or zero weights
        exclude the point. Negative weights raise :class:`ValidationError`.
    mask : (..., K) bool, optional
        ``False`` excludes a point (default: all included).
    min_points : int, default 3
        Batches with fewer valid points than this get NaN in ``R`` and ``t``.

    Returns
    -------
    R : (..., 3, 3) float64
        Proper rotations (``det R = +1``); NaN where the batch has too few points.
    t : (..., 3) float64, the unit of the inputs
        Translations; NaN where the batch has too few points.

    Notes
    -----
    Collinear or coincident valid points leave the rotation about the line (or all
    rotations) undetermined; a minimiser is still returned, so ``R @ src + t``
    reproduces ``dst`` as well as any rigid transform can.

    Examples
    --------
    >>> src = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> R, t = fit_rigid(src, src + [0.1, 0.2, 0.3])
    >>> np.allclose(R, np.eye(3)), np.allclose(t, [0.1, 0.2, 0.3])
    (True, True)
    """
    s = _points("src", src)
    d = _points("dst", dst)
    if s.shape[-2] != d.shape[-2]:
        raise ValidationError(
            f"src and dst must have the same number of points K; got {s.shape} and {d.shape}"
        )
    try:
        lead = np.broadcast_shapes(s.shape[:-2], d.shape[:-2])
    except ValueError as exc:
        raise ValidationError(
            f"src {s.shape} and dst {d.shape} leading axes do not broadcast"
        ) from exc
    k = s.shape[-2]
    valid = np.isfinite(s).all(axis=-1) & np.isfinite(d).all(axis=-1)
    valid = np.broadcast_to(valid, (*lead, k))
    if weights is None:
        w = np.ones((*lead, k))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[-1:] != (k,):
            raise ValidationError(f"weights must have shape (..., {k}); got {w.shape}")
        if np.any(w < 0):
            raise ValidationError("weights must be non-negative")
        valid = valid & np.isfinite(w) & (w > 0)
    if mask is not None:
        m = np.asarray(mask)
        if m.dtype != bool:
            raise ValidationError(f"mask must be boolean; got dtype {m.dtype}")
        if m.shape[-1:] != (k,):
            raise ValidationError(f"mask must have shape (..., {k}); got {m.shape}")
        valid = valid & m
    try:
        lead = np.broadcast_shapes(lead, valid.shape[:-1], w.shape[:-1])
    except ValueError as exc:
        raise ValidationError("weights/mask leading axes do not broadcast with the points") from exc
    valid = np.broadcast_to(valid, (*lead, k))
    w = np.where(valid, np.broadcast_to(w, (*lead, k)), 0.0)  # (..., K)
    s = np.where(valid[..., None], s, 0.0)  # (..., K, 3), NaN cleared
    d = np.where(valid[..., None], d, 0.0)
    wsum = w.sum(axis=-1)  # (...)
    ok = (valid.sum(axis=-1) >= min_points) & (wsum > 0)
    safe = np.where(ok, wsum, 1.0)[..., None]  # (..., 1)
    cs = np.einsum("...k,...ki->...i", w, s) / safe  # (..., 3)
    cd = np.einsum("...k,...ki->...i", w, d) / safe
    s0 = s - cs[..., None, :]
    d0 = d - cd[..., None, :]
    h = np.einsum("...k,...ki,...kj->...ij", w, s0, d0)  # (..., 3, 3) cross-covariance
    h = np.where(ok[..., None, None], h, np.eye(3))
    u, _, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, -1, -2)
    ut = np.swapaxes(u, -1, -2)
    det = np.linalg.det(v @ ut)  # (...)
    # reflection fix: flip the axis of the smallest singular value when det < 0
    v = v.copy()
    v[..., :, 2] *= np.where(det < 0, -1.0, 1.0)[..., None]
    rot = v @ ut
    trans = cd - np.einsum("...ij,...j->...i", rot, cs)
    rot = np.where(ok[..., None, None], rot, np.nan)
    trans = np.where(ok[..., None], trans, np.nan)
    return rot, trans


def apply_rigid(rotation: np.ndarray, translation: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``R @ p + t`` to points, batched.

    Parameters
    ----------
    rotation : (..., 3, 3) float
    translation : (..., 3) float
    points : (..., M, 3) float
        Leading axes broadcast against those of ``rotation`` / ``translation``.

    Returns
    -------
    (..., M, 3) float64
        Transformed points; NaN propagates (a NaN transform or point gives NaN).
    """
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    p = _points("points", points)
    if r.shape[-2:] != (3, 3):
        raise ValidationError(f"rotation must have shape (..., 3, 3); got {r.shape}")
    if t.shape[-1:] != (3,):
        raise ValidationError(f"translation must have shape (..., 3); got {t.shape}")
    return np.einsum("...ij,...mj->...mi", r, p) + t[..., None, :]


def invert_rigid(rotation: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``p -> R p + t``: ``(R^T, -R^T t)``, batched; NaN propagates.

    Parameters
    ----------
    rotation : (..., 3, 3) float
    translation : (..., 3) float

    Returns
    -------
    R_inv : (..., 3, 3) float64
    t_inv : (..., 3) float64
    """
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    if r.shape[-2:] != (3, 3):
        raise ValidationError(f"rotation must have shape (..., 3, 3); got {r.shape}")
    if t.shape[-1:] != (3,):
        raise ValidationError(f"translation must have shape (..., 3); got {t.shape}")
    rt = np.swapaxes(r, -1, -2)
    return rt, -np.einsum("...ij,...j->...i", rt, t)
