"""Automatic landmarks: which template vertex each of a few markers sits on.

Park & Hodgins placed 40 landmarks by hand (elbows, knees, ...). Here they are found
from geometry alone, so any layout works -- skincap's dense and sparse synthetic sets,
named anatomical markers (CMU, Plug-in Gait) and unnamed ones -- and the template may
stand in another pose (an A-pose MakeHuman body against T-pose markers):

1. The five extremities (head top, hands, feet) of the template and of the markers:
   geodesic farthest-point sampling from the point nearest the centroid, on the mesh
   edges for the template and on a k-nearest-neighbour graph for the markers; the
   highest is the head, the two lowest the feet, the others the hands; left is +X
   (skincap: Y up, the body faces +Z).
2. Every vertex and every marker gets a pose-invariant signature: its geodesic
   distances to the five extremities over the body's geodesic height (head to feet),
   plus its depth (Z about the centre, same scale), which tells front from back.
3. A spread subset of the markers (farthest-point sampling in space, ``count`` of
   them, the paper's 40) takes the vertex with the nearest signature.

A marker label that carries a side (``L...``/``R...`` anatomical names) is not used:
the side comes from the geometry, so unnamed dense markers are treated alike.

Limits: the markers' graph must join the body through the markers (a hand closer to
a thigh than to its forearm's markers would short-cut the geodesics), and both the
template and the markers stand upright, facing +Z, arms not above the head.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from skincap.errors import ValidationError

__all__ = ["automatic_landmarks", "body_extremities", "geodesic_signature", "LANDMARK_COUNT"]

#: Landmarks chosen by default (Park & Hodgins placed 40 by hand).
LANDMARK_COUNT = 40

#: Neighbours per marker in the markers' geodesic graph.
MARKER_NEIGHBOURS = 6

#: Longest marker-graph edge, in local spacings (see :func:`_knn_graph`).
EDGE_SPACING_RATIO = 1.6

_EXTREMITY_NAMES = ("head", "left_hand", "right_hand", "left_foot", "right_foot")


def _mesh_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    length = np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)
    length = np.maximum(length, 1e-12)  # a zero-length edge still connects
    n = vertices.shape[0]
    g = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return g.maximum(g.T).tocsr()


def _knn_graph(points: np.ndarray, k: int) -> sp.csr_matrix:
    """Symmetric k-nearest-neighbour graph without short-cuts, joined into one component.

    An edge is kept only when it is no longer than :data:`EDGE_SPACING_RATIO` times the
    local spacing (median neighbour distance) at *both* ends, so two limbs close
    together (the feet, a hand by a thigh) are not joined where sparse markers reach
    far for their k neighbours.
    """
    n = points.shape[0]
    kk = min(k + 1, n)
    dist, idx = cKDTree(points).query(points, k=kk)
    spacing = np.median(dist[:, 1:], axis=1)
    rows = np.repeat(np.arange(n), kk - 1)
    cols = idx[:, 1:].ravel()
    d = dist[:, 1:].ravel()
    keep = d <= EDGE_SPACING_RATIO * np.minimum(spacing[rows], spacing[cols])
    g = sp.coo_matrix((np.maximum(d[keep], 1e-12), (rows[keep], cols[keep])), shape=(n, n)).tocsr()
    g = g.maximum(g.T).tocsr()
    # Join stray components by their closest pair of points, one at a time.
    count, comp = connected_components(g, directed=False)
    while count > 1:
        main = comp == np.bincount(comp).argmax()
        tree = cKDTree(points[main])
        d, j = tree.query(points[~main])
        a = int(np.argmin(d))
        i_out = np.nonzero(~main)[0][a]
        i_in = np.nonzero(main)[0][j[a]]
        g = g.tolil()
        g[i_out, i_in] = g[i_in, i_out] = max(float(d[a]), 1e-12)
        g = g.tocsr()
        count, comp = connected_components(g, directed=False)
    return g


def body_extremities(points: np.ndarray, graph: sp.csr_matrix) -> tuple[np.ndarray, int]:
    """The head top, left hand, right hand, left foot, right foot of a body.

    Upright and facing +Z is assumed (left = +X), so the sides and the head come from
    position and only the tips from geodesics: the head is the highest node; each foot
    is the node of its side geodesically farthest from the head; each hand the node
    farthest from the head among those of its side reaching out at least half as far
    as the side's widest node and above the lower third of the body. A short-cut of
    the graph between the feet (sparse foot markers) or between a hand and a thigh
    then does not turn a knee or a hip into an extremity.

    Parameters
    ----------
    points : (N, 3) float, metres
        Nodes (mesh vertices or markers), Y up, facing +Z, left = +X.
    graph : (N, N) sparse
        Edge lengths between neighbouring nodes (one component).

    Returns
    -------
    nodes : (5,) int64
        Node of each extremity, in the order head, left hand, right hand, left foot,
        right foot.
    centre : int
        Node nearest the centroid (the origin of the depth coordinate).
    """
    centre = int(np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1)))
    head = int(np.argmax(points[:, 1]))
    from_head = dijkstra(graph, indices=head)
    reach = np.where(np.isfinite(from_head), from_head, -1.0)
    lateral = points[:, 0] - points[centre, 0]  # + left, - right
    floor, top = float(points[:, 1].min()), float(points[head, 1])
    above_knees = points[:, 1] > floor + (top - floor) / 3.0
    picked = [head]
    for side in (1.0, -1.0):  # the hands: left, right
        out = side * lateral
        arm = (out > 0.5 * out.max()) & above_knees
        if not arm.any():
            raise ValidationError("landmarks: cannot find the hands of the body")
        picked.append(int(np.argmax(np.where(arm, reach, -np.inf))))
    for side in (1.0, -1.0):  # the feet: left, right
        leg = (side * lateral > 0) & ~above_knees
        if not leg.any():
            raise ValidationError("landmarks: cannot find the feet of the body")
        picked.append(int(np.argmax(np.where(leg, reach, -np.inf))))
    if len(set(picked)) != 5:
        raise ValidationError("landmarks: cannot find the head, hands and feet of the body")
    return np.array(picked, dtype=np.int64), centre


def geodesic_signature(points: np.ndarray, graph: sp.csr_matrix) -> np.ndarray:
    """(N, 6) pose-invariant coordinates of every node: see the module docstring.

    Columns: geodesic distance to the head, left hand, right hand, left foot, right
    foot, over the body's geodesic height; then depth (Z about the centre node) on the
    same scale.
    """
    nodes, centre = body_extremities(points, graph)
    d = dijkstra(graph, indices=nodes).T  # (N, 5)
    height = 0.5 * (d[nodes[3], 0] + d[nodes[4], 0])
    if not np.isfinite(height) or height <= 0:
        raise ValidationError("landmarks: the body's head and feet are not connected")
    depth = (points[:, 2] - points[centre, 2])[:, None]
    sig = np.concatenate([d, depth], axis=1) / height
    return np.where(np.isfinite(sig), sig, 1e3)


def _spread(points: np.ndarray, count: int) -> np.ndarray:
    """``count`` indices of ``points`` by farthest-point sampling (deterministic)."""
    n = points.shape[0]
    count = min(count, n)
    first = int(np.argmax(points[:, 1]))
    chosen = [first]
    nearest = np.linalg.norm(points - points[first], axis=1)
    for _ in range(count - 1):
        k = int(np.argmax(nearest))
        chosen.append(k)
        nearest = np.minimum(nearest, np.linalg.norm(points - points[k], axis=1))
    return np.array(chosen, dtype=np.int64)


def automatic_landmarks(
    vertices: np.ndarray,
    faces: np.ndarray,
    markers: np.ndarray,
    labels: list[str],
    *,
    count: int = LANDMARK_COUNT,
) -> dict[str, int]:
    """Landmarks found from geometry: marker label -> template vertex.

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The template, Y up, facing +Z (left = +X).
    faces : (F, 3) int
    markers : (M, 3) float, metres
        Reference-pose markers in the same convention; NaN rows are skipped.
    labels : list of M str
    count : int, default 40
        How many landmarks (spread over the markers).

    Returns
    -------
    dict of str to int
        ``count`` (or fewer, when fewer markers are seen) landmarks.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    m = np.asarray(markers, dtype=np.float64)
    names = [str(s) for s in labels]
    if f.shape[0] == 0:
        raise ValidationError("faces: the mesh has no faces")
    if m.ndim != 2 or m.shape[1] != 3 or len(names) != m.shape[0]:
        raise ValidationError(
            f"markers, labels: expected (M, 3) and M labels, got {m.shape} and {len(names)}"
        )
    seen = np.nonzero(np.isfinite(m).all(axis=1))[0]
    if seen.size < 6:
        raise ValidationError(
            f"markers: need at least 6 seen markers to find landmarks, got {seen.size}"
        )
    if int(count) < 1:
        raise ValidationError(f"count: expected >= 1, got {count!r}")
    # The template: its largest connected piece (eyes, teeth... are separate pieces).
    graph = _mesh_graph(v, f)
    n_comp, comp = connected_components(graph, directed=False)
    body = (
        np.nonzero(comp == np.bincount(comp).argmax())[0] if n_comp > 1 else np.arange(v.shape[0])
    )
    sub = graph[body][:, body]
    vertex_sig = geodesic_signature(v[body], sub)
    pts = m[seen]
    marker_sig = geodesic_signature(pts, _knn_graph(pts, MARKER_NEIGHBOURS))
    pick = _spread(pts, int(count))
    _, nearest = cKDTree(vertex_sig).query(marker_sig[pick])
    return {names[seen[p]]: int(body[j]) for p, j in zip(pick, nearest, strict=True)}
