"""NumPy reference of the dense deformer's per-frame vertex evaluation (eqs. 8-9).

The (vertex, part) pairs are sorted by part. For every part, one matrix product moves
all its pairs through every frame's quadratic field at once (the pairs' quadratic
basis ``q̂⁰`` is frame-independent and computed once, at binding); the RBF sum of
eq. 8 at the deformed positions is, for slabs of pairs over all the frames at once,
a stack of squared-distance matrices from one augmented product per frame, the cubic
B-spline written so that its two cubes share one buffer, and one product per frame
with the weights (one NumPy call covers every frame: per frame and slab, the calls'
own overhead was a third of the time); one sparse product blends the pairs (eq. 9). :mod:`skincap.deform.dense._kernel_numba` computes the same, compiled.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["blend_pairs", "move_pairs_numpy"]

#: Kernel values per RBF slab (frames x members x pairs): the (2, T, K, pairs) cube
#: buffers stay ~1 MB, near the cache, while each NumPy call still covers enough
#: values that the calls' own overhead (a few µs each) stays small.
_RBF_SLAB_VALUES = 1 << 16


def _add_rbf_sums(
    world: np.ndarray,
    local: np.ndarray,
    centres: np.ndarray,
    weights: np.ndarray,
    scale: float,
    rotation: np.ndarray,
) -> None:
    """``world += (Σ_i w_i φ(||local - p̃_i|| / σ)) R`` in place (the sum of eq. 8), every
    frame of one part at once.

    Parameters
    ----------
    world : (n, T, 3) float64, metres
    local : (n, T, 3) float64, metres: the deformed positions ``Ã q̂⁰``
    centres, weights : (T, K, 3) float64, metres
    scale : float, 2/σ (1/metres)
    rotation : (T, 3, 3) float64: R̃, taking the sum to the world's axes
    """
    n_t, k = centres.shape[:2]
    c = centres * scale  # scaled so that s = 2 d / σ is a plain distance
    # s² = |x|² - 2 x·c + |c|²  as one product per frame: [-2c, 1, |c|²] @ [x; |x|²; 1]
    left = np.empty((n_t, k, 5))
    left[..., :3] = -2.0 * c
    left[..., 3] = 1.0
    left[..., 4] = (c * c).sum(-1)
    # 6 φ = (2 - s)³ - 4 max(1 - s, 0)³: the two cubes share one buffer, are combined,
    # and one product per frame with ((w / 6) R)ᵀ takes the sum to the world.
    # Frames lead, members run down the rows and points along them.
    reduce = np.swapaxes((weights * (1.0 / 6.0)) @ rotation, -1, -2)  # (T, 3, K)
    n = local.shape[0]
    cols = max(1, min(n, _RBF_SLAB_VALUES // (n_t * k)))
    right = np.empty((n_t, 5, cols))
    s = np.empty((n_t, k, cols))
    cubes = np.empty((2, n_t, k, cols))
    square = np.empty((2, n_t, k, cols))
    for c0 in range(0, n, cols):
        c1 = min(n, c0 + cols)
        m = c1 - c0
        rg, sm, cb, sq = right[..., :m], s[..., :m], cubes[..., :m], square[..., :m]
        np.multiply(local[c0:c1].transpose(1, 2, 0), scale, out=rg[:, :3])
        np.einsum("txn,txn->tn", rg[:, :3], rg[:, :3], out=rg[:, 3])
        rg[:, 4] = 1.0
        np.matmul(left, rg, out=sm)  # s², up to rounding
        np.clip(sm, 0.0, 4.0, out=sm)  # beyond s = 2 (d = σ) both cubes are 0
        np.sqrt(sm, out=sm)
        np.subtract(2.0, sm, out=cb[0])
        np.subtract(1.0, sm, out=cb[1])
        np.maximum(cb[1], 0.0, out=cb[1])
        np.multiply(cb, cb, out=sq)
        cb *= sq
        cb[1] *= 4.0
        np.subtract(cb[0], cb[1], out=sm)  # 6 φ
        world[c0:c1] += (reduce @ sm).transpose(2, 0, 1)


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
            _add_rbf_sums(
                part,
                local,
                centres[:, p, :k],
                rbf_weights[:, p, :k],
                float(rbf_scale[p]),
                rotation[:, p],
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
