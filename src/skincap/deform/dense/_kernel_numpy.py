"""NumPy reference of the dense deformer's per-frame vertex evaluation (eqs. 8-9).

The (vertex, part) pairs are sorted by part. For every part, one matrix product moves
all its pairs through every frame's quadratic field at once (the pairs' quadratic
basis ``q̂⁰`` is frame-independent and computed once, at binding); the RBF sum of
eq. 8 at the deformed positions is, per frame, a squared-distance matrix from one
augmented product, the cubic B-spline written so that its two cubes share one
buffer, and one product with the weights; one sparse product blends the pairs
(eq. 9). :mod:`skincap.deform.dense._kernel_numba` computes the same, compiled.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["blend_pairs", "move_pairs_numpy"]

#: Pairs per RBF slab: the (2K, pairs) kernel buffers of a 30-member part stay
#: ~0.5 MB, in cache, instead of streaming a whole part's matrix through memory.
_RBF_COLUMNS = 512


def _add_rbf_sum(
    world: np.ndarray,
    local: np.ndarray,
    centres: np.ndarray,
    weights: np.ndarray,
    scale: float,
    rotation: np.ndarray,
) -> None:
    """``world += (Σ_i w_i φ(||local - p̃_i|| / σ)) R`` in place (the sum of eq. 8).

    Parameters
    ----------
    world : (n, 3) float64, metres (a view; may be strided)
    local : (n, 3) float64, metres: the deformed positions ``Ã q̂⁰``
    centres, weights : (K, 3) float64, metres
    scale : float, 2/σ (1/metres)
    rotation : (3, 3) float64: R̃, taking the sum to the world's axes
    """
    k = centres.shape[0]
    c = centres * scale  # scaled so that s = 2 d / σ is a plain distance
    # s² = |x|² - 2 x·c + |c|²  as one product: [-2c, 1, |c|²] @ [x; |x|²; 1]
    left = np.empty((k, 5))
    left[:, :3] = -2.0 * c
    left[:, 3] = 1.0
    left[:, 4] = (c * c).sum(1)
    # the two cubes of φ = ((2 - s)³ - 4 max(1 - s, 0)³) / 6 share one (2K, n) buffer,
    # reduced (and turned to the world) by one product with ([w/6; -2w/3] R)ᵀ.
    # Members run down the rows and points along them: every pass is over long rows.
    reduce = (np.concatenate([weights * (1.0 / 6.0), weights * (-4.0 / 6.0)]) @ rotation).T
    n = local.shape[0]
    cols = min(n, _RBF_COLUMNS)
    right = np.empty((5, cols))
    s = np.empty((k, cols))
    cubes = np.empty((2 * k, cols))
    square = np.empty((2 * k, cols))
    for c0 in range(0, n, cols):
        c1 = min(n, c0 + cols)
        m = c1 - c0
        rg, sm, cb, sq = right[:, :m], s[:, :m], cubes[:, :m], square[:, :m]
        np.multiply(local[c0:c1].T, scale, out=rg[:3])
        np.einsum("xn,xn->n", rg[:3], rg[:3], out=rg[3])
        rg[4] = 1.0
        np.matmul(left, rg, out=sm)  # s², up to rounding
        np.clip(sm, 0.0, 4.0, out=sm)  # beyond s = 2 (d = σ) both cubes are 0
        np.sqrt(sm, out=sm)
        np.subtract(2.0, sm, out=cb[:k])
        np.subtract(1.0, sm, out=cb[k:])
        np.maximum(cb[k:], 0.0, out=cb[k:])
        np.multiply(cb, cb, out=sq)
        cb *= sq
        world[c0:c1] += (reduce @ cb).T


def move_pairs_numpy(
    pair_basis: np.ndarray,
    part_start: np.ndarray,
    quadratic: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    centres: np.ndarray,
    rbf_weights: np.ndarray,
    rbf_scale: np.ndarray,
    rbf_members: np.ndarray,
) -> np.ndarray:
    """Every pair's position moved by its part (eq. 8), for a block of frames.

    Parameters
    ----------
    pair_basis : (Q, 10) float64
        ``q̂⁰`` of every (vertex, part) pair, pairs sorted by part.
    part_start : (P + 1,) int
        Pairs of part ``p`` are ``part_start[p]:part_start[p + 1]``.
    quadratic : (T, P, 3, 10) float64
    rotation : (T, P, 3, 3) float64
    translation : (T, P, 3) float64, metres
    centres, rbf_weights : (T, P, K, 3) float64, metres
    rbf_scale : (P,) float64, 1/metres
        ``2 / σ_p``.
    rbf_members : (P,) int
        Members of part ``p`` in the RBF sum (0: the part has no RBF).

    Returns
    -------
    (Q, T, 3) float64, metres
        NaN for the pairs of a part whose fields are NaN at a frame.
    """
    n_t, n_p = quadratic.shape[:2]
    # eq. 8 without the RBF sum, straight to the world: (Ã q̂⁰ - d̃) R̃ = q̂⁰ (Ãᵀ R̃) with
    # -d̃ R̃ added to the constant row, (T, P, 10, 3)
    world_field = np.swapaxes(quadratic, -1, -2) @ rotation
    world_field[..., 9, :] -= np.einsum("tpx,tpxy->tpy", translation, rotation)
    moved = np.empty((pair_basis.shape[0], n_t, 3))
    for p in range(n_p):  # P (~17) batched steps
        start, stop = int(part_start[p]), int(part_start[p + 1])
        if start == stop:
            continue
        basis = pair_basis[start:stop]  # q̂⁰, (n, 10)
        part = moved[start:stop]  # (n, T, 3)
        # every frame in one product: (n, 10) @ (10, T 3)
        fields = np.ascontiguousarray(world_field[:, p].transpose(1, 0, 2)).reshape(-1, 3 * n_t)
        np.matmul(basis, fields, out=part.reshape(-1, 3 * n_t))
        k = int(rbf_members[p])
        if k > 0:
            local = (basis @ quadratic[:, p].reshape(3 * n_t, -1).T).reshape(-1, n_t, 3)
            for t in range(n_t):
                _add_rbf_sum(
                    part[:, t],
                    local[:, t],
                    centres[t, p, :k],
                    rbf_weights[t, p, :k],
                    float(rbf_scale[p]),
                    rotation[t, p],
                )
    return moved


def blend_pairs(moved: np.ndarray, blend: sparse.csr_matrix) -> np.ndarray:
    """β-weighted mean of each vertex's finite pair positions (eq. 9).

    Parameters
    ----------
    moved : (Q, T, 3) float64, metres
        From :func:`move_pairs_numpy`.
    blend : (V, Q) sparse float64
        β of every pair in its vertex's row.

    Returns
    -------
    (T, V, 3) float64, metres (a transposed view)
        NaN for a vertex none of whose pairs is finite.
    """
    n_q, n_t, _ = moved.shape
    n_v = blend.shape[0]
    flat = moved.reshape(n_q, 3 * n_t)
    if np.isfinite(flat.sum()):  # the common case, one pass: every pair finite
        weight = np.asarray(blend.sum(axis=1))  # (V, 1)
        num = blend @ flat  # (V, 3 T)
        num /= weight
        return num.reshape(n_v, n_t, 3).transpose(1, 0, 2)
    finite = np.isfinite(moved).all(-1)  # (Q, T)
    num = (blend @ np.where(np.repeat(finite, 3, axis=1), flat, 0.0)).reshape(n_v, n_t, 3)
    den = blend @ finite.astype(np.float64)  # (V, T)
    safe = np.where(den > 0, den, 1.0)[..., None]
    out = np.where(den[..., None] > 0, num / safe, np.nan)
    return out.transpose(1, 0, 2)
