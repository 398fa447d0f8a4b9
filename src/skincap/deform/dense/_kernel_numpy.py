"""NumPy reference of the dense deformer's per-frame vertex evaluation (eqs. 8-9).

The (vertex, part) pairs come sorted by part and cut into small spatial tiles
(:mod:`skincap.deform.dense._pair_tiles`). For every part, one matrix product moves all
its pairs through every frame's quadratic field at once (the pairs' quadratic basis
``q̂⁰`` is frame-independent and computed once, at binding). The RBF sum of eq. 8 is
taken tile by tile over all the frames at once: the cubic B-spline vanishes beyond σ,
so a tile needs only the centres within σ of its bounding box at some frame (about a
quarter of a body part's centres); for them, a stack of squared-distance matrices from
one augmented product per frame, the B-spline written so that its two cubes share one
buffer, and one product per frame with the members' and the seam field's weights,
blended by each pair's seam share. One sparse product blends the pairs (eq. 9).
:mod:`skincap.deform.dense._kernel_numba` computes the same, compiled.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["SUPPORT_SLACK", "blend_pairs", "move_pairs_numpy"]

#: Tiles (:data:`skincap.deform.dense._pair_tiles.TILE_PAIRS` pairs each) taken together
#: in one NumPy slab: 64 pairs a slab was ~1.3x faster than 32 or 128 on the 50k-vertex
#: benchmark (each NumPy call's few µs of overhead against the extra centres a larger
#: slab reaches).
_TILES_PER_SLAB = 2
#: Slack of the support test on squared scaled distances (the support is s² < 4): a
#: centre left out is at s² >= 4 - 1e-9, where φ < 1e-14 of φ(0).
SUPPORT_SLACK = 1e-9


def _centres_reaching(box_lo: np.ndarray, box_hi: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Centres within the B-spline's support of a box at some frame.

    Parameters
    ----------
    box_lo, box_hi : (T, 3) float64: a tile's deformed positions' bounds, scaled by 2/σ
    centres : (T, K, 3) float64, scaled by 2/σ

    Returns
    -------
    (k,) int64: indices of the centres whose scaled distance to the box is below 2
    (s < 2, φ > 0) at one frame at least.
    """
    gap = np.maximum(box_lo[:, None] - centres, 0.0) + np.maximum(centres - box_hi[:, None], 0.0)
    near = ((gap * gap).sum(-1) < 4.0 + SUPPORT_SLACK).any(axis=0)  # (K,)
    return np.flatnonzero(near)


def _add_rbf_sums(
    world: np.ndarray,
    local: np.ndarray,
    seam: np.ndarray,
    centres: np.ndarray,
    member_weights: np.ndarray,
    seam_weights: np.ndarray,
    rotation: np.ndarray,
) -> None:
    """``world += ((1 - s) Σ_i wm_i φ_i + s Σ_i ws_i φ_i) R`` in place (the sum of eq. 8
    for both fields of a part, blended by each pair's seam share ``s``), every frame of
    one tile at once; ``φ_i = φ(||local - p̃_i|| / σ)``.

    Parameters
    ----------
    world : (n, T, 3) float64, metres
    local : (n, T, 3) float64: the deformed positions ``Ã q̂⁰``, scaled by 2/σ
    seam : (n,) float64 in [0, 1]
    centres : (T, k, 3) float64: ``p̃``, scaled by 2/σ (so ``s = 2 d / σ`` is a distance)
    member_weights, seam_weights : (T, k, 3) float64, metres
    rotation : (T, 3, 3) float64: R̃, taking the sum to the world's axes
    """
    n_t, k = centres.shape[:2]
    # s² = |x|² - 2 x·c + |c|²  as one product per frame: [-2c, 1, |c|²] @ [x; |x|²; 1]
    left = np.empty((n_t, k, 5))
    left[..., :3] = -2.0 * centres
    left[..., 3] = 1.0
    left[..., 4] = (centres * centres).sum(-1)
    right = np.empty((n_t, 5, local.shape[0]))
    right[:, :3] = local.transpose(1, 2, 0)
    right[:, 3] = (right[:, :3] * right[:, :3]).sum(1)
    right[:, 4] = 1.0
    s = left @ right  # (T, k, n): s², up to rounding
    np.clip(s, 0.0, 4.0, out=s)  # beyond s = 2 (d = σ) both cubes are 0
    np.sqrt(s, out=s)
    # 6 φ = (2 - s)³ - 4 max(1 - s, 0)³: the two cubes share one buffer
    cubes = np.empty((2, *s.shape))
    np.subtract(2.0, s, out=cubes[0])
    np.subtract(1.0, s, out=cubes[1])
    np.maximum(cubes[1], 0.0, out=cubes[1])
    square = cubes * cubes
    cubes *= square
    cubes[1] *= 4.0
    np.subtract(cubes[0], cubes[1], out=s)  # 6 φ
    # both fields' sums in one product per frame, with ((w / 6) R)ᵀ taking them to the world
    weights = np.concatenate([member_weights, seam_weights], axis=-1) * (1.0 / 6.0)  # (T, k, 6)
    reduce = np.concatenate(
        [weights[..., :3] @ rotation, weights[..., 3:] @ rotation], axis=-1
    ).swapaxes(-1, -2)  # (T, 6, k)
    sums = (reduce @ s).transpose(2, 0, 1)  # (n, T, 6)
    share = seam[:, None, None]
    world += (1.0 - share) * sums[..., :3] + share * sums[..., 3:]


def move_pairs_numpy(
    pair_basis: np.ndarray,
    pair_seam: np.ndarray,
    part_start: np.ndarray,
    tile_start: np.ndarray,
    quadratic: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    centres: np.ndarray,
    member_weights: np.ndarray,
    seam_weights: np.ndarray,
    rbf_scale: np.ndarray,
    rbf_members: np.ndarray,
) -> np.ndarray:
    """Every pair's position moved by its part (eq. 8), for a block of frames.

    Parameters
    ----------
    pair_basis : (Q, 10) float64
        ``q̂⁰`` of every (vertex, part) pair, pairs sorted by part.
    pair_seam : (Q,) float64 in [0, 1]
        Each pair's share of its part's seam field (the rest follows the members' field).
    part_start : (P + 1,) int
        Pairs of part ``p`` are ``part_start[p]:part_start[p + 1]``.
    tile_start : (n_tiles + 1,) int
        Tiles of pairs (each within one part, ``part_start`` among its boundaries).
    quadratic : (T, P, 3, 10) float64
    rotation : (T, P, 3, 3) float64
    translation : (T, P, 3) float64, metres
    centres, member_weights, seam_weights : (T, P, K, 3) float64, metres
        The RBF centres ``p̃`` and both fields' weights (the members' field: 0 on the
        seam centres).
    rbf_scale : (P,) float64, 1/metres
        ``2 / σ_p``.
    rbf_members : (P,) int
        Centres of part ``p`` in the RBF sums (0: the part has no RBF).

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
    tile_start = np.asarray(tile_start)
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
        if k == 0:
            continue
        scale = float(rbf_scale[p])
        # Ã q̂⁰ of every pair and frame, scaled by 2/σ: (n, T, 3)
        local = (basis @ quadratic[:, p].reshape(3 * n_t, -1).T).reshape(-1, n_t, 3) * scale
        c = centres[:, p, :k] * scale
        # slabs of _TILES_PER_SLAB tiles: fewer NumPy calls for a few more centres a slab
        bounds = tile_start[(tile_start >= start) & (tile_start < stop)][::_TILES_PER_SLAB]
        bounds = np.append(bounds, stop)
        for t0, t1 in zip(bounds[:-1] - start, bounds[1:] - start, strict=True):
            tile = local[t0:t1]
            with np.errstate(invalid="ignore"):  # NaN fields (an unseen part): no centre
                near = _centres_reaching(tile.min(axis=0), tile.max(axis=0), c)
            if near.size:
                _add_rbf_sums(
                    part[t0:t1],
                    tile,
                    pair_seam[start + t0 : start + t1],
                    c[:, near],
                    member_weights[:, p, near],
                    seam_weights[:, p, near],
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
