"""Skin weights fitted to the motion of points on the body (markers), and carried to a mesh.

Automatic weights (bone heat) know only where the bones are; a marker's trajectory says
how the skin under it actually follows them. Under linear blend skinning a point's
position is linear in its weights,

    x(t) = sum_j w_j M_j(t) p,        M_j(t) = world_j(t) bind_j^-1,

so each marker's weights are one small least-squares problem over the take's frames,
with ``w >= 0`` and ``sum w = 1`` (the constraints of a skin), and a pull toward the
prior weights (bone heat) that decides what the motion cannot: a marker whose candidate
joints hardly move against each other keeps its prior. :func:`fit_point_skin_weights`
solves all markers together (each small constrained system exactly, by trying every
support). :func:`carry_weight_corrections` brings the fitted weights to every vertex as
a *correction* of the vertex's own prior weights, interpolated from the markers near it
over the reference-pose surface, so that away from markers the prior stays.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from skincap.errors import ValidationError
from skincap.geometry.simplex import simplex_least_squares

__all__ = [
    "candidate_joints",
    "carry_weight_corrections",
    "dense_weights",
    "fit_point_skin_weights",
    "lbs_points",
]


def dense_weights(indices: np.ndarray, weights: np.ndarray, n_joints: int) -> np.ndarray:
    """(P, J) float64 weight matrix from sparse ``indices``/``weights`` (P, K)."""
    idx = np.asarray(indices, dtype=np.int64)
    w = np.asarray(weights, dtype=np.float64)
    out = np.zeros((idx.shape[0], int(n_joints)))
    np.add.at(out, (np.repeat(np.arange(idx.shape[0]), idx.shape[1]), idx.ravel()), w.ravel())
    return out


def candidate_joints(
    prior: np.ndarray, parents: np.ndarray, max_candidates: int = 6, *, threshold: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """The joints each point's weights may use: its prior support and their neighbours.

    Parameters
    ----------
    prior : (P, J) float, prior weights (rows sum to 1)
    parents : (J,) int, -1 for a root
    max_candidates : int
        At most this many per point: the support by decreasing prior weight first, then
        the support's parents and children (in joint order).
    threshold : float
        A prior weight above this puts a joint in the support.

    Returns
    -------
    indices : (P, k) int64, ``k = min(max_candidates, J)``; valid : (P, k) bool
        (False in the padding slots, which hold joint 0).
    """
    w = np.asarray(prior, dtype=np.float64)
    par = np.asarray(parents, dtype=np.int64)
    n_p, n_j = w.shape
    if par.shape != (n_j,):
        raise ValidationError(f"parents: expected ({n_j},), got {par.shape}")
    adjacency = np.zeros((n_j, n_j), dtype=bool)
    child = np.flatnonzero(par >= 0)
    adjacency[child, par[child]] = adjacency[par[child], child] = True
    support = w > threshold
    ring = (support.astype(np.int64) @ adjacency.astype(np.int64) > 0) & ~support
    # support ranked by weight (scores in (1, 2]), then the ring (scores in (0, 1))
    score = np.where(support, 1.0 + w, 0.0) + np.where(ring, 1.0 - np.arange(n_j) / (2 * n_j), 0)
    k = min(int(max_candidates), n_j)
    order = np.argsort(-score, axis=1, kind="stable")[:, :k]
    valid = np.take_along_axis(score, order, axis=1) > 0
    return np.where(valid, order, 0).astype(np.int64), valid


def lbs_points(reference: np.ndarray, skinning: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(T, P, 3) linear-blend-skinned points: ``sum_j w_pj M_j(t) p``.

    ``reference`` (P, 3) metres, ``skinning`` (T, J, 4, 4), ``weights`` (P, J) dense.
    """
    moved = np.einsum("tjab,pb->tpja", skinning[:, :, :3, :3], reference)
    moved += skinning[:, None, :, :3, 3]
    return np.einsum("tpja,pj->tpa", moved, weights)


def fit_point_skin_weights(
    reference: np.ndarray,
    positions: np.ndarray,
    skinning: np.ndarray,
    prior: np.ndarray,
    parents: np.ndarray,
    *,
    max_candidates: int = 6,
    prior_scale: float = 0.003,
    chunk: int = 64,
) -> np.ndarray:
    """Each point's skin weights that best explain its trajectory under linear blend skinning.

    Parameters
    ----------
    reference : (P, 3) float, metres, the points in the bind pose
    positions : (T, P, 3) float, metres, their measured trajectories; NaN where missing
    skinning : (T, J, 4, 4) float, the joints' skinning transforms ``world @ bind^-1``
    prior : (P, J) float, prior weights (bone heat at the point), rows summing to 1
    parents : (J,) int
    max_candidates : int
        Joints each point may use (:func:`candidate_joints`).
    prior_scale : float, metres
        The pull toward the prior: moving one unit of weight away from it costs as much
        as a residual of this size in every measured frame
        (``lambda = n_frames * prior_scale**2``).
    chunk : int
        Frames per block of the normal equations (memory: chunk x P x k x 12 floats).

    Returns
    -------
    (P, J) float64
        Non-negative, rows summing to 1, zero outside each point's candidates. A point
        never measured keeps its prior.
    """
    p = np.asarray(reference, dtype=np.float64)
    x = np.asarray(positions, dtype=np.float64)
    m = np.asarray(skinning, dtype=np.float64)
    w0 = np.asarray(prior, dtype=np.float64)
    n_t, n_p = x.shape[:2]
    if p.shape != (n_p, 3) or x.shape != (n_t, n_p, 3):
        raise ValidationError(
            f"reference (P, 3) and positions (T, P, 3) expected; got {p.shape}, {x.shape}"
        )
    if m.shape[0] != n_t or m.shape[2:] != (4, 4):
        raise ValidationError(f"skinning: expected ({n_t}, J, 4, 4), got {m.shape}")
    if w0.shape != (n_p, m.shape[1]):
        raise ValidationError(f"prior: expected ({n_p}, {m.shape[1]}), got {w0.shape}")
    if not (np.isfinite(p).all() and np.isfinite(m).all() and np.isfinite(w0).all()):
        raise ValidationError("reference, skinning and prior must be finite")
    if prior_scale <= 0:
        raise ValidationError(f"prior_scale must be > 0, got {prior_scale}")
    cand, valid = candidate_joints(w0, parents, max_candidates)
    seen = np.asarray(np.isfinite(x).all(axis=-1))  # (T, P)
    k = cand.shape[1]
    gram, rhs = np.zeros((n_p, k, k)), np.zeros((n_p, k))
    for t0 in range(0, n_t, int(chunk)):  # normal equations summed over frame blocks
        sl = slice(t0, t0 + int(chunk))
        xs = np.where(seen[sl, :, None], x[sl], 0.0)
        # a[t, p, c] = M_{cand[p, c]}(t) p: the point moved rigidly by each candidate
        a = np.einsum("tpcab,pb->tpca", m[sl, :, :3, :3][:, cand], p)
        a += m[sl, :, :3, 3][:, cand]
        a *= seen[sl, :, None, None]
        gram += np.einsum("tpca,tpda->pcd", a, a)
        rhs += np.einsum("tpca,tpa->pc", a, xs)
    lam = seen.sum(axis=0) * prior_scale**2  # (P,)
    w0c = np.take_along_axis(w0, cand, axis=1) * valid
    # a point never seen has lam = 0: give it a unit pull so its system stays regular
    lam = np.where(lam > 0, lam, 1.0)
    gram = gram + lam[:, None, None] * np.eye(k)
    rhs = rhs + lam[:, None] * w0c
    wc = simplex_least_squares(gram, valid, rhs)
    out = np.zeros_like(w0)
    np.add.at(out, (np.repeat(np.arange(n_p), cand.shape[1]), cand.ravel()), (wc * valid).ravel())
    never = ~seen.any(axis=0)
    out[never] = w0[never]
    return out


def carry_weight_corrections(
    vertices: np.ndarray,
    vertex_prior: np.ndarray,
    points: np.ndarray,
    point_prior: np.ndarray,
    point_fitted: np.ndarray,
    *,
    width: float | None = None,
    prior_width: float = 0.5,
    max_influences: int = 4,
    chunk: int = 2048,
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex weights = prior + the points' weight corrections, averaged near each vertex.

    Each vertex takes a kernel-weighted mean of the points' corrections (fitted minus
    prior). The kernel is a Gaussian of the reference-pose distance times a Gaussian of
    the L1 difference of the two prior weight rows, so a point on the forearm does not
    correct the hip beside it (bone heat already tells them apart). The mean fades to no
    correction away from the points: "no correction" enters it with the kernel's value
    at three widths. Then negatives are clipped, ``max_influences`` kept, rows
    renormalised. A smooth average, not an interpolation: an exact interpolant
    (thin-plate) of the corrections overshoots between points of different bones.

    Parameters
    ----------
    vertices : (V, 3) float, metres, the mesh in the bind pose
    vertex_prior : (V, J) float, the vertices' prior weights
    points : (P, 3) float, metres, the points in the bind pose (P >= 2)
    point_prior, point_fitted : (P, J) float
    width : float, metres, optional
        The distance Gaussian's standard deviation; default 0.75 x the points' median
        nearest-neighbour distance.
    prior_width : float
        The prior-difference Gaussian's standard deviation (L1 weight units, 0..2).
    max_influences : int
    chunk : int
        Vertices per block (memory: chunk x P).

    Returns
    -------
    indices : (V, K) int64; weights : (V, K) float64, rows summing to 1, by decreasing
        weight (as :func:`~skincap.deform.skeletal.weights.limit_influences`).
    """
    from scipy.spatial.distance import cdist

    from skincap.deform.skeletal.weights import limit_influences

    v = np.asarray(vertices, dtype=np.float64)
    c = np.asarray(points, dtype=np.float64)
    wv0 = np.asarray(vertex_prior, dtype=np.float64)
    wc0 = np.asarray(point_prior, dtype=np.float64)
    delta = np.asarray(point_fitted, dtype=np.float64) - wc0
    if c.ndim != 2 or c.shape[0] < 2 or c.shape[1] != 3 or v.ndim != 2 or v.shape[1] != 3:
        raise ValidationError(
            f"vertices (V, 3) and points (P >= 2, 3) expected; got {v.shape}, {c.shape}"
        )
    if (
        wv0.shape != (v.shape[0], wc0.shape[1])
        or delta.shape != wc0.shape
        or wc0.shape[0] != c.shape[0]
    ):
        raise ValidationError(
            f"vertex_prior (V, J), point_prior and point_fitted (P, J) expected; got "
            f"{wv0.shape}, {wc0.shape}, {delta.shape}"
        )
    if width is None:
        d, _ = cKDTree(c).query(c, k=2)
        width = 0.75 * float(np.median(d[:, 1]))
    if not (width > 0 and prior_width > 0):
        raise ValidationError(f"width and prior_width must be > 0, got {width}, {prior_width}")
    far = np.exp(-4.5)  # the distance kernel at three widths
    out = np.empty_like(wv0)
    for s in range(0, v.shape[0], int(chunk)):
        sl = slice(s, s + int(chunk))
        k = np.exp(-0.5 * cdist(v[sl], c, "sqeuclidean") / width**2)  # (v, P)
        k *= np.exp(-0.5 * (cdist(wv0[sl], wc0, "cityblock") / prior_width) ** 2)
        out[sl] = wv0[sl] + (k @ delta) / (k.sum(axis=1, keepdims=True) + far)
    idx = np.broadcast_to(np.arange(out.shape[1]), out.shape)
    return limit_influences(idx, np.maximum(out, 0.0), max_influences)
