"""Compiled per-frame vertex evaluation of the dense deformer (eqs. 8-9), numba.

One parallel loop over the tiles of (vertex, part) pairs, every frame of a tile in turn
(:mod:`skincap.deform.dense._pair_tiles`): each tile moves its pairs' local reference
positions by their part's quadratic field, gathers the part's RBF centres within the
B-spline's support of the tile's bounding box (about a quarter of a body part's: the
others' terms of eq. 8 are exactly 0), sums both RBF fields over them (the members'
and the seam field, blended by each pair's seam share) and takes the result back to
the world. A vertex with one pair (inside a part) is that pair (eq. 9 with β = 1), which
the tile pass writes straight to the output; the pairs of the vertices with several
(at a seam) go to a buffer, and one parallel loop over those vertices blends them by β.
Nothing of size (vertices, centres) is ever stored. Without an RBF field (``rigid``,
``quadratic``) there is no centre search to share across a tile, so a second kernel
takes one fused parallel loop over the vertices instead: each vertex's pairs moved by
their part's field and blended by β at once, with no buffer of moved pairs. (Two
kernels, not two branches of one: a parallel kernel's compile time grows with every
loop it holds, and the default ``quadratic_rbf`` needs only the first.)

The RBF sums of a tile at a frame run in float32, the tile's pairs along the vector
lanes, where the error model of :func:`skincap.deform.dense._kernel_numpy.f32_error_bound`
stays within 1e-6 m (``precision="mixed"``, the default), else in float64.
:mod:`skincap.deform.dense._kernel_numpy` is the reference this kernel must agree with
(to rounding in float64, to 1e-6 m mixed);
:class:`skincap.deform.dense.deformer.DenseDeformer` picks between them (``backend=``,
:func:`skincap.backends.resolve_backend`). Each kernel compiles on its first use, once
per machine, into numba's on-disk cache (``cache=True``).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from skincap.deform.dense._kernel_numpy import F32_TOLERANCE, Precision
from skincap.deform.dense._pair_tiles import MEMBER_LANES, PairTiles

__all__ = [
    "MEMBER_LANES",
    "deform_vertices_numba",
    "dense_dispatcher",
    "dense_no_rbf_dispatcher",
]


@functools.cache
def dense_dispatcher() -> Any:
    """The numba dispatcher of the kernel (compiles, or loads from the cache, on first call).

    The kernel and its steps live in :mod:`skincap.deform.dense._kernel_numba_jit`, which
    imports numba: importing it here keeps numba out of the deformer's import.

    Raises
    ------
    ImportError
        numba is not installed (callers check :func:`skincap.backends.numba_available`).
    """
    from skincap.deform.dense._kernel_numba_jit import dense_kernel

    return dense_kernel


@functools.cache
def dense_no_rbf_dispatcher() -> Any:
    """The numba dispatcher of the kernel without an RBF field (``rigid``,
    ``quadratic``): a kernel of its own, compiled on its first use, so that the
    default ``quadratic_rbf`` compiles only :func:`dense_dispatcher`'s."""
    from skincap.deform.dense._kernel_numba_jit import dense_kernel_no_rbf

    return dense_kernel_no_rbf


def deform_vertices_numba(
    tiles: PairTiles,
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
) -> np.ndarray:
    """Deformed vertices of a block of frames with the compiled kernel (eqs. 8-9).

    Parameters
    ----------
    tiles : PairTiles
        The (vertex, part) pairs, tiled (:func:`skincap.deform.dense._pair_tiles.pair_tiles`).
    quadratic : (T, P, 3, 10) float64
    rotation : (T, P, 3, 3) float64
    translation : (T, P, 3) float64, metres
    centres, member_weights, seam_weights : (T, P, K, 3) float64, metres
        The RBF centres ``p̃`` and both fields' weights (the members' field: 0 on the
        seam centres).
    rbf_scale : (P,) float64, 1/metres
        ``2 / σ_p``.
    rbf_members : (P,) int64
        Centres of part ``p`` in the RBF sums (0: the part has no RBF).
    precision : {"mixed", "float64"}
        "mixed": a tile's RBF sums at a frame in float32 where
        :func:`~skincap.deform.dense._kernel_numpy.f32_error_bound` stays within
        :data:`~skincap.deform.dense._kernel_numpy.F32_TOLERANCE`; "float64": never.

    Returns
    -------
    (T, V, 3) float64, metres
        NaN for a vertex none of whose pairs is finite.
    """
    n_t, n_v = quadratic.shape[0], tiles.vertex_start.shape[0] - 1
    out = np.zeros((n_t, n_v, 3))
    if n_t and n_v:
        scale = np.asarray(rbf_scale, dtype=np.float64)
        # one argument signature a kernel (C-contiguous, writeable): a second would
        # compile again
        if not np.any(rbf_members):  # fused, no buffer: the pairs in by-vertex order
            dense_no_rbf_dispatcher()(
                np.require(tiles.local[tiles.by_vertex], np.float64, ("C", "W")),
                np.require(tiles.part[tiles.by_vertex], np.int64, ("C", "W")),
                np.require(tiles.weight_by_vertex, np.float64, ("C", "W")),
                np.require(tiles.vertex_start, np.int64, ("C", "W")),
                *(np.require(a, np.float64, ("C", "W")) for a in (
                    quadratic, rotation, translation)),
                out,
            )  # fmt: skip
            return out
        table = _rbf_table(centres, member_weights, seam_weights, scale)
        pair_slot, shared_vertex, shared_start, shared_weight = _shared_vertices(tiles)
        # the pairs of vertices with several, between the two passes
        moved = np.zeros((shared_weight.shape[0], n_t, 3))
        dense_dispatcher()(
            # p̂⁰ structure-of-arrays (3, Q): the tiled path runs a tile's pairs along
            # the vector lanes
            *(np.require(a, np.float64, ("C", "W")) for a in (tiles.local.T, tiles.seam)),
            *(np.require(a, np.int64, ("C", "W")) for a in (
                tiles.tile_start, tiles.tile_part, tiles.vertex, pair_slot, shared_vertex,
                shared_start)),
            *(np.require(a, np.float64, ("C", "W")) for a in (
                shared_weight, quadratic, rotation, translation, table, scale)),
            np.require(rbf_members, np.int64, ("C", "W")),
            F32_TOLERANCE if precision == "mixed" else -1.0,
            moved,
            out,
        )  # fmt: skip
    return out


def _shared_vertices(tiles: PairTiles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where the kernel puts each pair: a vertex's only pair is eq. 9's result itself
    (β renormalised to 1), written to the output by the tile pass; the pairs of the
    vertices with several (a seam's) get rows ("slots") of the buffer the blend pass
    reads, in the vertices' order.

    Returns
    -------
    pair_slot : (Q,) int64
        Each pair's slot, -1 for a vertex's only pair.
    shared_vertex : (S,) int64
        The vertices with several pairs, or none (their blend writes NaN).
    shared_start : (S + 1,) int64
        Slots of ``shared_vertex[i]`` are ``shared_start[i]:shared_start[i + 1]``, in the
        order of ``tiles.by_vertex`` (the sums run in the NumPy reference's order).
    shared_weight : (M,) float64
        β of each slot's pair.
    """
    counts = np.diff(tiles.vertex_start)
    shared = counts != 1
    in_shared = np.repeat(shared, counts)  # (Q,), by-vertex order
    shared_pairs = tiles.by_vertex[in_shared]
    pair_slot = np.full(tiles.vertex.shape[0], -1, dtype=np.int64)
    pair_slot[shared_pairs] = np.arange(shared_pairs.size)
    shared_start = np.concatenate([[0], np.cumsum(counts[shared])]).astype(np.int64)
    return (
        pair_slot,
        np.flatnonzero(shared).astype(np.int64),
        shared_start,
        tiles.weight_by_vertex[in_shared],
    )


def _rbf_table(
    centres: np.ndarray, member_weights: np.ndarray, seam_weights: np.ndarray, scale: np.ndarray
) -> np.ndarray:
    """The kernel's (T, P, 9, K') centre table.

    The table holds the centres scaled by 2/σ, then the members' field's weights
    w / 6, then the seam field's, centres along the last axis. K' is K rounded up to a
    multiple of :data:`MEMBER_LANES`, so that the kernel's per-tile copy of the centres
    it needs always has room to pad them to whole vector steps with zero weights (no
    scalar remainder loop: ~20 % less CPU for the RBF variants).

    Returns
    -------
    (T, P, 9, K') float64, C-contiguous
    """
    n_t, n_p, k = centres.shape[:3]
    width = max(MEMBER_LANES, -(-k // MEMBER_LANES) * MEMBER_LANES)
    table = np.zeros((n_t, n_p, 9, width))
    table[..., :3, :k] = np.swapaxes(centres * scale[None, :, None, None], -1, -2)
    table[..., 3:6, :k] = np.swapaxes(member_weights * (1.0 / 6.0), -1, -2)
    table[..., 6:, :k] = np.swapaxes(seam_weights * (1.0 / 6.0), -1, -2)
    return table
