"""The (vertex, part) pairs of the dense deformer's vertex pass (eqs. 8-9), in spatial tiles.

Eq. 9 blends, for every vertex, its position moved by each part it belongs to (β > 0).
Both kernels work on these pairs: sorted by part and, inside a part, into tiles of at
most :data:`TILE_PAIRS` pairs that lie close together (the leaves of a k-d tree of their
local reference positions). The pairs of a tile lie close
together, so the cubic B-spline of eq. 8 (zero beyond σ) reaches them from only a few
of the part's RBF centres: each kernel finds those per tile and frame, from the tile's
bounding box at that frame, and sums only them (the others' terms are exactly 0).

With seam centres a part has two RBF fields (its members' and its seam field,
:mod:`skincap.deform.dense.parts`) with the same rigid and quadratic fields and the same
centres; a pair carries its seam share ``s`` and its RBF residual is
``(1 - s) r_members + s r_seam``: one quadratic evaluation and one kernel value per
centre for both fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skincap.deform.dense.parts import PartFrames
from skincap.geometry.quadratic import quadratic_basis

__all__ = ["MEMBER_LANES", "TILE_PAIRS", "PairTiles", "pair_tiles"]

#: Centres the numba kernel's RBF loop sums per vectorised step (LLVM's two AVX2
#: vectors of 4). Each tile's centres are padded to a multiple of it with zero weights,
#: so the loop runs whole steps with no scalar remainder.
MEMBER_LANES = 8
#: Pairs per tile. Smaller tiles find fewer centres per pair but pay the per-tile search
#: (one bounding-box test per centre) more often; on the 50k-vertex benchmark (17 parts,
#: 50 centres, σ 7.4 cm) 32-pair tiles keep ~1/4 of the centres.
TILE_PAIRS = 32


@dataclass(eq=False)
class PairTiles:
    """The (vertex, part) pairs with β > 0, sorted by part and tiled.

    Attributes
    ----------
    vertex, part : (Q,) int64
        The pair's vertex and part.
    weight : (Q,) float64
        β of the pair (rows of β renormalised to 1).
    seam : (Q,) float64 in [0, 1]
        Share of the pair that follows its part's seam field (0 without seam centres).
    local : (Q, 3) float64, metres
        ``p̂⁰``: the vertex's rest position in the part's local frame.
    basis : (Q, 10) float64
        ``q̂⁰``, the quadratic vector of ``local``.
    part_start : (P + 1,) int64
        Pairs of part ``p`` are ``part_start[p]:part_start[p + 1]``.
    tile_start : (n_tiles + 1,) int64
        Tile ``i`` is pairs ``tile_start[i]:tile_start[i + 1]``, all of one part.
    tile_part : (n_tiles,) int64
    by_vertex : (Q,) int64
        Pair indices sorted by vertex (then part).
    weight_by_vertex : (Q,) float64
        ``weight[by_vertex]``.
    vertex_start : (V + 1,) int64
        Pairs of vertex ``v`` are ``by_vertex[vertex_start[v]:vertex_start[v + 1]]``.
    rest_kernels : dict
        The NumPy kernel's cache of the sparse rest kernel matrices of parts with a
        rigid base (:func:`skincap.deform.dense._kernel_numpy.move_pairs_numpy`),
        filled on first use.
    """

    vertex: np.ndarray
    part: np.ndarray
    weight: np.ndarray
    seam: np.ndarray
    local: np.ndarray
    basis: np.ndarray
    part_start: np.ndarray
    tile_start: np.ndarray
    tile_part: np.ndarray
    by_vertex: np.ndarray
    weight_by_vertex: np.ndarray
    vertex_start: np.ndarray
    rest_kernels: dict = field(default_factory=dict)


def _kd_tiles(points: np.ndarray, tile_pairs: int) -> tuple[np.ndarray, np.ndarray]:
    """Order points into compact tiles: split at the median of the longest side until
    a piece holds at most ``tile_pairs`` (the leaves of a k-d tree).

    Parameters
    ----------
    points : (M, 3) float64
    tile_pairs : int

    Returns
    -------
    order : (M,) int64, the points tile by tile
    starts : (n,) int64, where each tile starts in ``order``
    """
    order = np.arange(points.shape[0])
    pieces, leaves = [(0, points.shape[0])], []
    while pieces:  # one split a step: ~2 M / tile_pairs steps
        start, stop = pieces.pop()
        if stop - start <= tile_pairs:
            leaves.append(start)
            continue
        idx = order[start:stop]
        axis = int(np.argmax(np.ptp(points[idx], axis=0)))
        # whole tiles on the left, so that every tile but the last of a part is full
        half = -(-(stop - start) // (2 * tile_pairs)) * tile_pairs
        order[start:stop] = idx[np.argsort(points[idx, axis], kind="stable")]
        pieces += [(start + half, stop), (start, start + half)]
    return order, np.sort(np.array(leaves, dtype=np.int64))


def pair_tiles(
    parts: PartFrames,
    rest_vertices: np.ndarray,
    vertex_weights: np.ndarray,
    seam_weights: np.ndarray,
    *,
    tile_pairs: int = TILE_PAIRS,
) -> PairTiles:
    """Bind the vertices to their parts: the pairs of eq. 9, tiled.

    Parameters
    ----------
    parts : PartFrames
    rest_vertices : (V, 3) float64, metres
    vertex_weights : (V, P) float64
        β, rows summing to 1 (pairs with β <= 1e-6 are left out).
    seam_weights : (V, P) float64 in [0, 1]
        Seam share of every (vertex, part).
    tile_pairs : int
        Most pairs a tile holds.

    Returns
    -------
    PairTiles
    """
    n_v, n_p = vertex_weights.shape
    part_of, vertex_of = np.nonzero(vertex_weights.T > 1e-6)  # by part, then vertex
    local = parts.to_local(rest_vertices[vertex_of], part_of)  # p̂⁰ of each pair
    part_start = np.searchsorted(part_of, np.arange(n_p + 1)).astype(np.int64)
    order, starts = [], []
    for p in range(n_p):  # P (~17) steps: each part's pairs in compact tiles
        start, stop = int(part_start[p]), int(part_start[p + 1])
        if stop > start:
            tile_order, tile_starts = _kd_tiles(local[start:stop], int(tile_pairs))
            order.append(start + tile_order)
            starts.append(start + tile_starts)
    order_all = np.concatenate(order) if order else np.zeros(0, dtype=np.int64)
    part_of, vertex_of, local = part_of[order_all], vertex_of[order_all], local[order_all]
    tile_start = np.append(
        np.concatenate(starts) if starts else np.zeros(0, np.int64), part_of.size
    ).astype(np.int64)
    by_vertex = np.lexsort((part_of, vertex_of)).astype(np.int64)
    weight = np.ascontiguousarray(vertex_weights[vertex_of, part_of], dtype=np.float64)
    return PairTiles(
        vertex=vertex_of.astype(np.int64),
        part=part_of.astype(np.int64),
        weight=weight,
        seam=np.ascontiguousarray(seam_weights[vertex_of, part_of], dtype=np.float64),
        local=np.ascontiguousarray(local),
        basis=quadratic_basis(local),
        part_start=part_start,
        tile_start=tile_start,
        tile_part=part_of[tile_start[:-1]].astype(np.int64),
        by_vertex=by_vertex,
        weight_by_vertex=weight[by_vertex],
        vertex_start=np.searchsorted(vertex_of[by_vertex], np.arange(n_v + 1)).astype(np.int64),
    )
