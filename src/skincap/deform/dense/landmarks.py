"""Automatic landmarks: which template vertex each of a few markers sits on.

Park & Hodgins placed 40 landmarks by hand (elbows, knees, ...). Here they are found
from geometry alone, so any layout works -- skincap's dense and sparse synthetic sets,
named anatomical markers (CMU, Plug-in Gait) and unnamed ones -- and the template may
stand in another pose (an A-pose MakeHuman body against T-pose markers) and have other
proportions (longer arms):

1. The five extremities (head top, hands, feet) of the template and of the markers
   (:func:`body_extremities`), on the mesh edges for the template and on a
   k-nearest-neighbour graph for the markers.
2. Along the shortest path from each hand and each foot to the head, the node at each
   of the same fractions of the path's length (:data:`LIMB_FRACTIONS`: the tip, the
   wrist or ankle, the elbow or knee, up to the shoulder or hip): a fraction of a limb
   is the same anatomy on a long and a short body, in a T-pose and an A-pose, and the
   sides match because the extremities do.
3. Each such marker takes the template vertex at the same place on the same path.

A marker label that carries a side (``L...``/``R...`` anatomical names) is not used:
the side comes from the geometry, so unnamed dense markers are treated alike.

Limits: the markers' graph must join the body through the markers (a hand closer to
a thigh than to its forearm's markers would short-cut the geodesics), and both the
template and the markers stand upright, facing +Z, arms not above the head. The
markers' path zig-zags between markers and the outermost hand or foot marker is not
the fingertip or toe, so a landmark is centimetres off (the tests bound it): good for
placing, posing and sizing the template; its final shape is left to the markers'
closest points (:mod:`skincap.deform.dense.registration` fades the landmarks out).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from skincap.errors import ValidationError

__all__ = ["LIMB_FRACTIONS", "automatic_landmarks", "body_extremities", "limb_path_nodes"]

#: Fractions of each hand-to-head and foot-to-head path that get a landmark: the tip,
#: the wrist or ankle, the elbow or knee, up to the shoulder or hip.
LIMB_FRACTIONS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)

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


def limb_path_nodes(
    points: np.ndarray, graph: sp.csr_matrix, fractions: tuple[float, ...] = LIMB_FRACTIONS
) -> np.ndarray:
    """Nodes at fixed fractions of the shortest paths from the hands and feet to the head.

    Parameters
    ----------
    points : (N, 3) float, metres
        Nodes (mesh vertices or markers), Y up, facing +Z, left = +X.
    graph : (N, N) sparse
        Edge lengths between neighbouring nodes (one component).
    fractions : tuple of P float in [0, 1], default :data:`LIMB_FRACTIONS`
        Where along each path, from the hand or foot (0) toward the head (1).

    Returns
    -------
    (1 + 4 P,) int64
        The head, then for the left hand, right hand, left foot and right foot in turn
        the node at each fraction: the node minimising its detour over the shortest
        path plus its miss of the fraction's distance from the extremity (two distance
        fields per path, vectorised; no path is walked).
    """
    fr = np.asarray(fractions, dtype=np.float64)
    nodes, _ = body_extremities(points, graph)
    d = dijkstra(graph, indices=nodes)  # (5, N) from head, hands, feet
    picked = [nodes[:1]]
    for tip in range(1, 5):
        length = d[0, nodes[tip]]
        detour = d[0] + d[tip] - length  # (N,) 0 on a shortest path
        miss = np.abs(d[tip][None, :] - fr[:, None] * length) + detour[None, :]  # (P, N)
        picked.append(np.argmin(np.where(np.isfinite(miss), miss, np.inf), axis=1))
    return np.concatenate(picked).astype(np.int64)


def automatic_landmarks(
    vertices: np.ndarray,
    faces: np.ndarray,
    markers: np.ndarray,
    labels: list[str],
    *,
    fractions: tuple[float, ...] = LIMB_FRACTIONS,
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
    fractions : tuple of float, default :data:`LIMB_FRACTIONS`
        Where along each limb's path a landmark goes (:func:`limb_path_nodes`).

    Returns
    -------
    dict of str to int
        Up to ``1 + 4 len(fractions)`` landmarks (a marker picked twice, on sparse
        markers, keeps its first vertex).
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
    fr = tuple(float(a) for a in fractions)
    if not fr or not all(0.0 <= a <= 1.0 for a in fr):
        raise ValidationError(f"fractions: expected values in [0, 1], got {fractions!r}")
    # The template: its largest connected piece (eyes, teeth... are separate pieces).
    graph = _mesh_graph(v, f)
    n_comp, comp = connected_components(graph, directed=False)
    body = (
        np.nonzero(comp == np.bincount(comp).argmax())[0] if n_comp > 1 else np.arange(v.shape[0])
    )
    vertex_nodes = body[limb_path_nodes(v[body], graph[body][:, body], fr)]
    pts = m[seen]
    marker_nodes = seen[limb_path_nodes(pts, _knn_graph(pts, MARKER_NEIGHBOURS), fr)]
    out: dict[str, int] = {}
    for marker, vertex in zip(marker_nodes.tolist(), vertex_nodes.tolist(), strict=True):
        out.setdefault(names[marker], int(vertex))  # at most 1 + 4 P entries
    return out
