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

Precision: by default ("mixed") a tile's kernel values and sums run in float32, the
positions taken relative to the tile's centre, where :func:`f32_error_bound` stays
within :data:`F32_TOLERANCE` (1e-6 m), else in float64; ``precision="float64"`` is the
reference. A part whose base field is the identity at every frame of a block (a rigid
base) keeps its pairs and centres at rest, so its kernel values never change: it sums
through a sparse (pairs, centres) matrix made once (``rest_kernels``), in float64.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

__all__ = [
    "F32_ERROR_PER_WEIGHT",
    "F32_TOLERANCE",
    "SUPPORT_SLACK",
    "Precision",
    "blend_pairs",
    "f32_error_bound",
    "move_pairs_numpy",
]

#: The RBF sums' arithmetic: "mixed" (float32 where :func:`f32_error_bound` allows) or
#: "float64" (the reference).
Precision = Literal["mixed", "float64"]

#: Tiles (:data:`skincap.deform.dense._pair_tiles.TILE_PAIRS` pairs each) taken together
#: in one NumPy slab: 64 pairs a slab was ~1.3x faster than 32 or 128 on the 50k-vertex
#: benchmark (each NumPy call's few µs of overhead against the extra centres a larger
#: slab reaches).
_TILES_PER_SLAB = 2
#: Slack of the support test on squared scaled distances (the support is s² < 4): a
#: centre left out is at s² >= 4 - 1e-9, where φ < 1e-14 of φ(0).
SUPPORT_SLACK = 1e-9


#: Largest modelled error (metres) of a tile's RBF sums in float32 (the 1e-6 m the
#: fast paths must agree with the float64 reference to): beyond it a tile is summed in
#: float64.
F32_TOLERANCE = 1e-6
#: Modelled error of one float32 kernel term per metre of weight and unit of scale:
#: four roundings (unit roundoff 2**-24). On the 20k-vertex benchmark scene and a
#: synthetic jump-rope take (910 slabs, rigid_rbf and quadratic_rbf) no slab's measured
#: error exceeded 0.7 of the model.
F32_ERROR_PER_WEIGHT = 4.0 * 2.0**-24


def f32_error_bound(weight_sum: float, scale: float, n_centres: int) -> float:
    """Modelled error (metres) of a tile's RBF sums computed in float32.

    Each of the ``n_centres`` kernel values carries a few roundings at the scale of the
    numbers it is computed from (``scale``: the largest |coordinate| relative to the
    tile's centre in units of σ / 2, or its square for the expanded product form of
    the NumPy kernel) and each product with a weight one more; ``weight_sum`` (metres:
    the largest over the fields, axes and frames of Σ_i |w_i| / 6) carries them to
    metres. An error model, not a worst-case bound (rounding errors mostly cancel):
    :data:`F32_ERROR_PER_WEIGHT` says how it was checked.

    Returns
    -------
    float, metres
    """
    return weight_sum * F32_ERROR_PER_WEIGHT * (scale + n_centres)


def _centres_reaching(box_lo: np.ndarray, box_hi: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Centres within the B-spline's support of each box at some frame.

    Parameters
    ----------
    box_lo, box_hi : (S, T, 3) float64: the bounds of S slabs' deformed positions,
        scaled by 2/σ
    centres : (T, K, 3) float64, scaled by 2/σ

    Returns
    -------
    (S, K) bool: the centres whose scaled distance to the box is below 2 (s < 2,
    φ > 0) at one frame at least.
    """
    # axis by axis, (S, T, K) arrays: no (S, T, K, 3) temporaries and no sum over a
    # length-3 axis. A centre's gap to the box on an axis is max(lo - c, c - hi, 0) (lo
    # <= hi: at most one is positive), summed in the same order as (gap²).sum(-1)
    dist2 = np.zeros(())
    for axis in range(3):
        c = centres[None, :, :, axis]
        gap = np.maximum(box_lo[:, :, None, axis] - c, c - box_hi[:, :, None, axis])
        np.maximum(gap, 0.0, out=gap)
        gap *= gap
        dist2 = gap if axis == 0 else np.add(dist2, gap, out=dist2)
    return (dist2 < 4.0 + SUPPORT_SLACK).any(axis=1)


def _add_rbf_sums(
    world: np.ndarray,
    local: np.ndarray,
    seam: np.ndarray,
    centres: np.ndarray,
    reduce: np.ndarray,
    *,
    precision: Precision = "mixed",
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
    reduce : (T, 6, k) float64, metres
        ``((w / 6) R̃)ᵀ`` of the members' field (rows 0-2) and the seam field (rows
        3-5): the weights taken to the world's axes.
    precision : {"mixed", "float64"}
        "mixed": the kernel values and their sums in float32, the positions taken
        relative to the tile's centre first, where :func:`f32_error_bound` of the
        tile stays within :data:`F32_TOLERANCE` (otherwise float64); "float64": the
        reference.
    """
    n_t, k = centres.shape[:2]
    dtype = np.float64
    if precision == "mixed":
        origin = 0.5 * (local.min(axis=0) + local.max(axis=0))  # (T, 3)
        local = local - origin
        centres = centres - origin[:, None]
        reach = max(float(np.abs(local).max()), float(np.abs(centres).max()))
        weight = float(np.abs(reduce).sum(axis=-1).max())
        # the expanded product below rounds at the scale of the squared coordinates
        if f32_error_bound(weight, reach * reach, k) <= F32_TOLERANCE:
            dtype = np.float32
            local = local.astype(np.float32)
            centres = centres.astype(np.float32)
            reduce = reduce.astype(np.float32)
    # s² = |x|² - 2 x·c + |c|²  as one product per frame: [-2c, 1, |c|²] @ [x; |x|²; 1]
    left = np.empty((n_t, k, 5), dtype=dtype)
    left[..., :3] = -2.0 * centres
    left[..., 3] = 1.0
    left[..., 4] = (centres * centres).sum(-1)
    right = np.empty((n_t, 5, local.shape[0]), dtype=dtype)
    right[:, :3] = local.transpose(1, 2, 0)
    right[:, 3] = (right[:, :3] * right[:, :3]).sum(1)
    right[:, 4] = 1.0
    s = left @ right  # (T, k, n): s², up to rounding
    np.clip(s, 0.0, 4.0, out=s)  # beyond s = 2 (d = σ) both cubes are 0
    np.sqrt(s, out=s)
    # 6 φ = (2 - s)³ - 4 max(1 - s, 0)³: the two cubes share one buffer
    cubes = np.empty((2, *s.shape), dtype=dtype)
    np.subtract(2.0, s, out=cubes[0])
    np.subtract(1.0, s, out=cubes[1])
    np.maximum(cubes[1], 0.0, out=cubes[1])
    square = cubes * cubes
    cubes *= square
    cubes[1] *= 4.0
    np.subtract(cubes[0], cubes[1], out=s)  # 6 φ
    # both fields' sums in one product per frame, already in the world's axes
    sums = (reduce @ s).transpose(2, 0, 1)  # (n, T, 6)
    world += sums[..., :3]
    world += seam[:, None, None] * (sums[..., 3:] - sums[..., :3])


def _has_a_fixed_base(quadratic: np.ndarray, centres: np.ndarray) -> bool:
    """Whether a part's base field is exactly ``[I 0 0 0]`` at every frame, (T, 3, 10),
    and its (T, k, 3) centres the same at every frame."""
    identity = np.zeros((3, quadratic.shape[-1]))
    identity[:, :3] = np.eye(3)
    return bool((quadratic == identity).all() and (centres == centres[:1]).all())


def _rest_kernel(
    cache: dict[int, tuple[np.ndarray, sparse.csr_matrix]],
    part: int,
    points: np.ndarray,
    centres: np.ndarray,
) -> sparse.csr_matrix:
    """The (n, k) sparse matrix of ``6 φ`` between a part's pairs at rest and its
    centres (both (·, 3), scaled by 2/σ), from ``cache`` when made for these centres.

    Only the entries with s < 2 are stored (about a quarter of a body part's centres
    reach a pair): 12 bytes each.
    """
    hit = cache.get(part)
    if hit is not None and np.array_equal(hit[0], centres):
        return hit[1]
    near = cKDTree(points).sparse_distance_matrix(
        cKDTree(centres), 2.0, output_type="ndarray"
    )  # (i, j, s) records, s = 0 included
    s = near["v"]
    values = (2.0 - s) ** 3 - 4.0 * np.maximum(1.0 - s, 0.0) ** 3  # 6 φ
    matrix = sparse.csr_matrix(
        (values, (near["i"], near["j"])), shape=(points.shape[0], centres.shape[0])
    )
    cache[part] = (centres.copy(), matrix)
    return matrix


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
    *,
    precision: Precision = "mixed",
    rest_kernels: dict[int, tuple[np.ndarray, sparse.csr_matrix]] | None = None,
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
    precision : {"mixed", "float64"}
        The RBF sums' arithmetic (:func:`_add_rbf_sums`); "float64" is the reference.
    rest_kernels : dict, optional
        A cache (part -> its rest centres and sparse kernel matrix) kept by the caller
        across blocks: with it, a part whose base field is the identity at every frame
        of the block and whose centres stay at rest sums its RBF through the matrix
        (float64) instead of the tiles. None: always the tiles.

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
        # both fields' weights taken to the world's axes once per part: ((w / 6) R̃)ᵀ
        weights = np.concatenate([member_weights[:, p, :k], seam_weights[:, p, :k]], axis=-1)
        weights *= 1.0 / 6.0  # (T, k, 6)
        reduce = np.concatenate(
            [weights[..., :3] @ rotation[:, p], weights[..., 3:] @ rotation[:, p]], axis=-1
        ).swapaxes(-1, -2)  # (T, 6, k)
        if rest_kernels is not None and _has_a_fixed_base(quadratic[:, p], c):
            # a rigid base (rigid_rbf, or a part quadratic_rbf keeps rigid): the pairs
            # and the centres sit at their rest positions in every frame, so the kernel
            # values are the binding's, a sparse (n, k) matrix made once
            phi = _rest_kernel(rest_kernels, p, basis[:, :3] * scale, c[0])
            sums = (phi @ reduce.transpose(2, 0, 1).reshape(k, 6 * n_t)).reshape(-1, n_t, 6)
            part += sums[..., :3]
            part += pair_seam[start:stop, None, None] * (sums[..., 3:] - sums[..., :3])
            continue
        # slabs of _TILES_PER_SLAB tiles: fewer NumPy calls for a few more centres a slab
        bounds = tile_start[(tile_start >= start) & (tile_start < stop)][::_TILES_PER_SLAB] - start
        with np.errstate(invalid="ignore"):  # NaN fields (an unseen part): no centre
            reaching = _centres_reaching(
                np.minimum.reduceat(local, bounds, axis=0),
                np.maximum.reduceat(local, bounds, axis=0),
                c,
            )  # (slabs, k)
        bounds = np.append(bounds, stop - start)
        for slab, (t0, t1) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            near = np.flatnonzero(reaching[slab])
            if near.size:
                _add_rbf_sums(
                    part[t0:t1],
                    local[t0:t1],
                    pair_seam[start + t0 : start + t1],
                    c[:, near],
                    reduce[:, :, near],
                    precision=precision,
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
