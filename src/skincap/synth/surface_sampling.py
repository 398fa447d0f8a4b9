"""Points spread evenly over a triangle mesh, and the regions they own.

Area-weighted vertex normals (:func:`vertex_normals`), uniform surface samples
(:func:`sample_surface`), a greedy Poisson-disk subset of them computed in parallel
rounds (:func:`greedy_blue_noise`) and the geodesic Voronoi partition of a mesh by seed
vertices with its dual triangulation (:func:`voronoi_dual`). The dense marker layout and
the camera model's occlusion proxy are both built from these.

Conventions: metres; faces counter-clockwise seen from outside.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from skincap.errors import ValidationError

__all__ = ["vertex_normals", "sample_surface", "greedy_blue_noise", "voronoi_dual"]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, for one or many frames.

    Parameters
    ----------
    vertices : (V, 3) or (T, V, 3) float, metres
    faces : (F, 3) int, counter-clockwise seen from outside

    Returns
    -------
    (V, 3) or (T, V, 3) float64
        Unit normals; a vertex in no (non-degenerate) face gets (0, 0, 0).
    """
    v = np.asarray(vertices, dtype=np.float64)
    single = v.ndim == 2
    vt = v[None] if single else v
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(vt[:, f[:, 1]] - vt[:, f[:, 0]], vt[:, f[:, 2]] - vt[:, f[:, 0]])  # (T, F, 3)
    n_v = vt.shape[1]
    inc = sp.csr_matrix(
        (np.ones(f.size), (f.ravel(), np.repeat(np.arange(f.shape[0]), 3))),
        shape=(n_v, f.shape[0]),
    )
    acc = (inc @ fn.transpose(1, 0, 2).reshape(f.shape[0], -1)).reshape(n_v, vt.shape[0], 3)
    acc = acc.transpose(1, 0, 2)
    norm = np.linalg.norm(acc, axis=2, keepdims=True)
    out = np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)
    return out[0] if single else out


def sample_surface(
    v: np.ndarray, f: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-weighted uniform surface samples: faces (n,), bary (n, 3), points (n, 3)."""
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    cdf = np.cumsum(area)
    face = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), f.shape[0] - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)
    pts = np.einsum("nk,nkx->nx", bary, v[f[face]])
    return face, bary, pts


def greedy_blue_noise(
    pts: np.ndarray,
    normals: np.ndarray,
    radius: np.ndarray,
    priority: np.ndarray,
    forced: np.ndarray,
) -> np.ndarray:
    """Maximal Poisson-disk subset, greedy in ``priority`` order, vectorised.

    Two candidates conflict when closer than the mean of their radii and their
    normals are less than ~107 degrees apart (facing skin folds do not conflict).
    Iterated local minima (Luby): every round accepts the candidates whose priority
    is the lowest among their live neighbours, which gives exactly the sequential
    greedy result. ``forced`` candidates (bool) never conflict with each other and
    have the lowest priorities.
    """
    tree = cKDTree(pts)
    pairs = tree.query_pairs(float(radius.max()), output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    d = np.linalg.norm(pts[i] - pts[j], axis=1)
    conflict = (d < 0.5 * (radius[i] + radius[j])) & (
        np.einsum("kx,kx->k", normals[i], normals[j]) > -0.3
    )
    conflict &= ~(forced[i] & forced[j])
    i, j = i[conflict], j[conflict]
    a = np.concatenate([i, j])
    b = np.concatenate([j, i])
    prio = np.where(forced, -1.0, priority)
    alive = np.ones(pts.shape[0], dtype=bool)
    chosen = np.zeros(pts.shape[0], dtype=bool)
    while alive.any():
        live = alive[a] & alive[b]
        best_nb = np.full(pts.shape[0], np.inf)
        np.minimum.at(best_nb, a[live], prio[b[live]])
        win = alive & ((prio < best_nb) | forced)
        chosen |= win
        alive &= ~win
        killed = b[win[a]]
        alive[killed] = False
    return np.nonzero(chosen)[0]


def voronoi_dual(
    vertices: np.ndarray, faces: np.ndarray, seeds: np.ndarray
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Geodesic Voronoi partition of a mesh by seed vertices, and its dual triangulation.

    Multi-source Dijkstra on the edge graph (edge lengths in metres) gives each vertex
    its nearest seed; every mesh triangle whose three vertices belong to three
    different seeds yields a dual triangle over those seeds, with the mesh triangle's
    winding (so it faces outwards like the mesh). Duplicates are merged; triangles on
    an edge used more than twice are dropped, least supported first, until every edge
    has at most two triangles.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    seeds : (S,) int
        Distinct vertex indices.

    Returns
    -------
    owner : (V,) int64
        Index into ``seeds`` of each vertex's region; -1 for vertices no seed reaches.
    triangles : (P, 3) int64
        Dual triangles over seed indices, counter-clockwise seen from outside.
    stats : dict
        ``n_nonmanifold_dropped``, ``n_boundary_edges`` (edges of one triangle: holes),
        ``n_nonmanifold_edges`` (after cleaning, 0), ``n_isolated`` (seeds in no
        triangle), ``euler`` (V - E + F of the dual).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    seeds = np.asarray(seeds, dtype=np.int64)
    if np.unique(seeds).size != seeds.size:
        raise ValidationError("seeds: must be distinct vertices")
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    w = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    w = np.maximum(w, 1e-12)  # csgraph treats explicit zeros as missing edges
    n_v = v.shape[0]
    graph = sp.coo_matrix((w, (e[:, 0], e[:, 1])), shape=(n_v, n_v)).tocsr()
    graph = graph.maximum(graph.T)
    _, _, source = dijkstra(
        graph, directed=False, indices=seeds, min_only=True, return_predecessors=True
    )
    seed_index = np.full(n_v, -1, dtype=np.int64)
    seed_index[seeds] = np.arange(seeds.size)
    owner = np.where(source >= 0, seed_index[np.maximum(source, 0)], -1)
    o = owner[f]  # (F, 3)
    tri_mask = (
        (o >= 0).all(axis=1) & (o[:, 0] != o[:, 1]) & (o[:, 1] != o[:, 2]) & (o[:, 0] != o[:, 2])
    )
    tri = o[tri_mask]
    key = np.sort(tri, axis=1)
    uniq, first, support = np.unique(key, axis=0, return_index=True, return_counts=True)
    tri = tri[first]
    dropped = 0
    while True:
        ed = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        ekey = ed[:, 0] * seeds.size + ed[:, 1]
        _, inv, cnt = np.unique(ekey, return_inverse=True, return_counts=True)
        bad_edge = cnt[inv] > 2  # (3P,)
        bad_tri = bad_edge.reshape(3, -1).any(axis=0)
        if not bad_tri.any():
            break
        # drop, on each over-used edge, its least supported triangle (ties: the last)
        cand = np.nonzero(bad_tri)[0]
        worst = cand[np.lexsort((-cand, support[cand]))[0]]
        keep = np.ones(tri.shape[0], dtype=bool)
        keep[worst] = False
        tri, support = tri[keep], support[keep]
        dropped += 1
    ed = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    ekey = ed[:, 0] * seeds.size + ed[:, 1]
    _, cnt = np.unique(ekey, return_counts=True)
    used = np.zeros(seeds.size, dtype=bool)
    used[tri.ravel()] = True
    stats = {
        "n_nonmanifold_dropped": int(dropped),
        "n_boundary_edges": int((cnt == 1).sum()),
        "n_nonmanifold_edges": int((cnt > 2).sum()),
        "n_isolated": int((~used).sum()),
        "euler": int(seeds.size - cnt.size + tri.shape[0]),
    }
    del uniq
    return owner, tri.astype(np.int64), stats
