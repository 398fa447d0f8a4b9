"""Marker and vertex part weights (Park & Hodgins 2006, §5.2).

Marker weights α (N, P): a marker inside a part weighs 1 for it. A marker on the
boundary between parts (its marker-surface triangles, or its neighbours, belong to
several parts) is compared with the rigid motion of each neighbouring part, defined by
that part's inside markers: its RMS distance ``e_p`` from where the part's rigid motion
carries its reference position. A Gaussian model turns the errors into likelihoods,
``ℓ_p ∝ exp(-e_p² / 2 s_p²)`` with ``s_p`` the RMS error of the part's own inside markers
under its rigid motion (how rigid the part is; floored at ``noise_floor``, since a
perfectly rigid synthetic part would make every assignment hard), normalised over the
candidate parts; a part is kept when its likelihood exceeds 0.2 (the paper's threshold)
and the kept ones are normalised again.

Vertex weights β (V, P): each vertex of the detailed mesh takes the weights of the
three markers of the nearest marker-surface triangle, interpolated at the barycentric
coordinates of its projection.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from skincap.errors import ValidationError
from skincap.geometry.raycast import closest_points_on_mesh
from skincap.geometry.rigid import fit_rigid

__all__ = [
    "candidates_from_marker_parts",
    "candidates_from_triangle_parts",
    "marker_part_weights",
    "vertex_part_weights",
]

#: Likelihood above which a boundary marker joins a part (Park & Hodgins: 0.2).
WEIGHT_THRESHOLD = 0.2


def candidates_from_triangle_parts(
    faces: np.ndarray, triangle_parts: np.ndarray, n_markers: int, n_parts: int | None = None
) -> np.ndarray:
    """Which parts each marker touches: the parts of its marker-surface triangles.

    Parameters
    ----------
    faces : (F, 3) int, marker indices
    triangle_parts : (F,) int, part of every triangle (-1 = none)
    n_markers : int
    n_parts : int, optional (default ``triangle_parts.max() + 1``)

    Returns
    -------
    (N, P) bool
        A marker on no labelled triangle has no candidate (all False).
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    tp = np.asarray(triangle_parts, dtype=np.int64)
    if tp.shape != (f.shape[0],):
        raise ValidationError(f"triangle_parts must have shape ({f.shape[0]},); got {tp.shape}")
    n_p = int(tp.max()) + 1 if n_parts is None else int(n_parts)
    out = np.zeros((int(n_markers), n_p), dtype=bool)
    keep = tp >= 0
    out[f[keep].ravel(), np.repeat(tp[keep], 3)] = True
    return out


def candidates_from_marker_parts(
    marker_parts: np.ndarray, edges: np.ndarray, n_parts: int | None = None
) -> np.ndarray:
    """Which parts each marker touches: its own and those of its surface neighbours.

    Parameters
    ----------
    marker_parts : (N,) int, part of every marker (-1 = none)
    edges : (E, 2) int, marker-surface edges
    n_parts : int, optional

    Returns
    -------
    (N, P) bool
    """
    mp = np.asarray(marker_parts, dtype=np.int64)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    n_p = int(mp.max()) + 1 if n_parts is None else int(n_parts)
    out = np.zeros((mp.size, n_p), dtype=bool)
    own = mp >= 0
    out[np.flatnonzero(own), mp[own]] = True
    for a, b in ((0, 1), (1, 0)):  # both directions of every edge
        src, dst = e[:, a], e[:, b]
        ok = mp[dst] >= 0
        out[src[ok], mp[dst[ok]]] = True
    return out


def marker_part_weights(
    positions: np.ndarray,
    reference: np.ndarray,
    candidates: np.ndarray,
    *,
    threshold: float = WEIGHT_THRESHOLD,
    noise_floor: float = 0.001,
) -> np.ndarray:
    """Marker weights α: 1 inside a part, Gaussian likelihoods on the boundaries.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
        The take the weights are learnt from (the range of motion).
    reference : (N, 3) float, metres
        Reference pose.
    candidates : (N, P) bool
        Parts each marker touches; exactly one = inside that part. A marker with none
        is compared with every part.
    threshold : float
        Likelihood a part must exceed to keep a boundary marker (0.2).
    noise_floor : float, metres
        Smallest Gaussian scale ``s_p``.

    Returns
    -------
    (N, P) float64
        Rows sum to 1.

    Raises
    ------
    ValidationError
        Shapes, or a part with fewer than three markers it could be fitted from.
    """
    x = np.asarray(positions, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    cand = np.asarray(candidates, dtype=bool)
    if x.ndim != 3 or x.shape[2] != 3 or ref.shape != x.shape[1:]:
        raise ValidationError(
            f"positions (T, N, 3) and reference (N, 3) expected; got {x.shape} and {ref.shape}"
        )
    if cand.ndim != 2 or cand.shape[0] != ref.shape[0]:
        raise ValidationError(f"candidates must have shape ({ref.shape[0]}, P); got {cand.shape}")
    n, n_p = cand.shape
    orphan = ~cand.any(axis=1)
    cand = cand | orphan[:, None]
    inside = cand & (cand.sum(axis=1) == 1)[:, None]  # (N, P)
    fit_from = np.where((inside.sum(axis=0) >= 3)[None, :], inside, cand & ~orphan[:, None])
    few = fit_from.sum(axis=0) < 3
    if few.any():
        raise ValidationError(
            f"candidates: parts {np.flatnonzero(few).tolist()} have fewer than three markers"
        )
    # rigid motion of every part from its inside markers: reference -> frame t
    rot, trans = fit_rigid(ref[None, None], x[:, None], fit_from.T[None])  # (T, P, 3, 3), (T, P, 3)
    # only the (marker, part) pairs that matter: candidates and the fitting markers
    marker_of, part_of = np.nonzero(cand | fit_from)
    predicted = np.einsum("tnab,nb->tna", rot[:, part_of], ref[marker_of]) + trans[:, part_of]
    sq = ((predicted - x[:, marker_of]) ** 2).sum(-1)  # (T, pairs), NaN where unseen
    seen = np.isfinite(sq)
    count = seen.sum(axis=0)
    err2 = np.full((n, n_p), np.inf)
    err2[marker_of, part_of] = np.where(
        count > 0, np.where(seen, sq, 0.0).sum(axis=0) / np.maximum(count, 1), np.inf
    )
    own = np.where(fit_from, err2, np.nan)
    with np.errstate(invalid="ignore"):
        scale2 = np.nanmean(np.where(np.isfinite(own), own, np.nan), axis=0)  # (P,)
    scale2 = np.maximum(np.where(np.isfinite(scale2), scale2, 0.0), float(noise_floor) ** 2)
    logit = np.where(cand, -err2 / (2.0 * scale2[None, :]), -np.inf)
    logit = logit - logit.max(axis=1, keepdims=True)
    like = np.exp(logit)
    like /= like.sum(axis=1, keepdims=True)
    like = np.where(like > float(threshold), like, 0.0)
    # the best part always stays (a likelihood spread over > 5 parts may leave none)
    best = np.argmax(np.where(cand, -err2 / scale2[None, :], -np.inf), axis=1)
    like[np.arange(n), best] = np.maximum(like[np.arange(n), best], 1e-12)
    alpha = like / like.sum(axis=1, keepdims=True)
    alpha[inside.any(axis=1)] = inside[inside.any(axis=1)].astype(np.float64)
    return alpha


def vertex_part_weights(
    vertices: np.ndarray,
    surface_vertices: np.ndarray,
    surface_faces: np.ndarray,
    marker_weights: np.ndarray,
) -> np.ndarray:
    """Vertex weights β: the marker weights interpolated on the nearest surface triangle.

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The detailed mesh in the reference pose.
    surface_vertices : (N, 3) float, metres
        The markers in the reference pose (the marker surface's vertices).
    surface_faces : (F, 3) int
        Marker-surface triangles. With none, a vertex takes the inverse-distance blend
        of its three nearest markers' weights.
    marker_weights : (N, P) float
        α.

    Returns
    -------
    (V, P) float64
        Rows sum to 1.
    """
    v = np.asarray(vertices, dtype=np.float64)
    sv = np.asarray(surface_vertices, dtype=np.float64)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    alpha = np.asarray(marker_weights, dtype=np.float64)
    if alpha.shape[0] != sv.shape[0]:
        raise ValidationError(
            f"marker_weights has {alpha.shape[0]} rows for {sv.shape[0]} surface vertices"
        )
    usable = np.isfinite(sv).all(axis=1)
    f = f[usable[f].all(axis=1)]
    if f.shape[0]:
        _, face, bary = closest_points_on_mesh(np.where(usable[:, None], sv, 0.0), f, v)
        beta = np.einsum("vk,vkp->vp", bary, alpha[f[face]])
    else:
        idx = np.flatnonzero(usable)
        d, nn = cKDTree(sv[idx]).query(v, k=min(3, idx.size))
        d = d.reshape(v.shape[0], -1)
        nn = nn.reshape(v.shape[0], -1)
        w = 1.0 / np.maximum(d, 1e-9)
        beta = np.einsum("vk,vkp->vp", w, alpha[idx[nn]])
    beta = np.clip(beta, 0.0, None)
    return beta / beta.sum(axis=1, keepdims=True)
