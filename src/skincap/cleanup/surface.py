"""The marker surface: which markers are neighbours on the skin (Park & Hodgins 2006, §4.1).

The paper built this mesh by hand, once per subject. :func:`build_marker_surface` builds
it from the capture itself:

1. **Reference pose.** A frame where most markers are present (or the one you name).
2. **Candidates.** Each marker's ``k`` nearest markers in that pose (KD-tree), within
   ``max_edge`` when given.
3. **Motion consistency.** A candidate pair is kept when its distance stays nearly
   constant through the take: the coefficient of variation (std / mean) of the pair
   distance over the frames where both are present is below ``max_cv``. Skin
   neighbours stretch a few percent; markers on different limbs swing apart and fail.
   Pairs seen together in fewer than ``min_overlap`` frames cannot be judged and are
   kept (the reference distance alone made them candidates).
4. **Triangulation.** Every triangle whose three edges are kept is a candidate. It is
   accepted when its smallest circumscribed ball (centre in the triangle's plane,
   radius the circumradius) holds no other marker -- the empty-ball test of the
   restricted Delaunay triangulation, and of ball pivoting with a per-triangle radius
   -- when its normal agrees with the local surface normals of its corners (PCA of
   each marker's kept neighbourhood, or the body mesh), and then greedily, smallest
   ball first, when each of its edges has fewer than two accepted triangles and it
   does not fold back over the accepted triangle across a shared edge. The result is
   an edge-manifold triangle mesh whose vertices are the markers.
5. **Neighbourhoods.** A marker's neighbours are its one-ring on that mesh. A marker
   with fewer than ``min_neighbours`` (sparse marker sets, 41-62 markers on bony
   landmarks, where a skin triangulation means little) gets the most
   motion-consistent candidates added -- the rigid-ish cluster it moves with -- until
   it has ``min_neighbours``.

With a body mesh (``body=``, in the reference pose) the markers are projected onto it
for the geometry, its normals replace the PCA normals, and an edge whose midpoint is
farther than ``0.3 ×`` its length from the skin (a bridge through the air between
limbs) is dropped.

A user-made surface enters through :func:`surface_from_faces` or
:func:`surface_from_edges` (reading PLY/OBJ/CSV files is the CLI's job).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from skincap._arrays import as_trajectories
from skincap.errors import ValidationError
from skincap.types import Mesh

__all__ = [
    "MarkerSurface",
    "build_marker_surface",
    "choose_reference_frame",
    "complete_reference_pose",
    "pair_distance_cv",
    "surface_edge_scores",
    "surface_from_edges",
    "surface_from_faces",
]


@dataclass
class MarkerSurface:
    """Neighbourhood structure over the N markers of a capture.

    Attributes
    ----------
    edges : (E, 2) int64
        Unique undirected edges ``i < j`` between marker columns (neighbour relation).
    faces : (F, 3) int64
        Triangles of the marker surface (may be empty for a pure edge neighbourhood).
    offsets : (N + 1,) int64
        CSR offsets: marker ``i``'s neighbours are ``indices[offsets[i]:offsets[i+1]]``.
    indices : (2E,) int64
        CSR neighbour columns, sorted by distance in the reference pose (nearest first).
    mean_neighbour_distance : (N,) float64, metres
        Mean reference-pose distance from each marker to its neighbours (NaN for a
        marker without neighbours). ε¹ and ε² of eq. 3 scale with it, and Table 2's
        errors are normalised by it.
    reference : (N, 3) float64, metres
        Marker positions in the reference pose (NaN where unknown).
    reference_frame : int
        The frame the reference pose came from (-1 when given directly).
    """

    edges: np.ndarray
    faces: np.ndarray
    offsets: np.ndarray
    indices: np.ndarray
    mean_neighbour_distance: np.ndarray
    reference: np.ndarray
    reference_frame: int = -1

    @property
    def n_markers(self) -> int:
        """Number of markers N."""
        return int(self.offsets.shape[0] - 1)

    @property
    def degree(self) -> np.ndarray:
        """(N,) int64: number of neighbours per marker."""
        return np.diff(self.offsets)

    @property
    def neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """The CSR pair ``(offsets, indices)`` (what the fill and smooth steps take)."""
        return self.offsets, self.indices

    def neighbours_of(self, i: int) -> np.ndarray:
        """(d_i,) int64: the neighbours of marker ``i``, nearest first."""
        return self.indices[self.offsets[i] : self.offsets[i + 1]]

    def padded(self) -> tuple[np.ndarray, np.ndarray]:
        """Neighbours as a dense table.

        Returns
        -------
        table : (N, D) int64
            Neighbour columns, ``D`` the largest degree; padding entries are 0.
        valid : (N, D) bool
            False on padding.
        """
        deg = self.degree
        d = int(deg.max()) if deg.size else 0
        col = np.arange(d)
        valid = col[None, :] < deg[:, None]
        table = np.zeros((self.n_markers, d), dtype=np.int64)
        table[valid] = self.indices
        return table, valid


def _unique_edges(edges: np.ndarray) -> np.ndarray:
    e = np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)
    e = e[e[:, 0] != e[:, 1]]
    if e.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.unique(e, axis=0)


def _assemble(
    edges: np.ndarray,
    faces: np.ndarray,
    reference: np.ndarray,
    reference_frame: int,
) -> MarkerSurface:
    """CSR neighbourhoods (nearest first) and mean neighbour distances from edges."""
    n = reference.shape[0]
    e = _unique_edges(edges)
    src = np.concatenate([e[:, 0], e[:, 1]])
    dst = np.concatenate([e[:, 1], e[:, 0]])
    length = np.linalg.norm(reference[src] - reference[dst], axis=1)
    order = np.lexsort((dst, np.where(np.isnan(length), np.inf, length), src))
    src, dst, length = src[order], dst[order], length[order]
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=offsets[1:])
    ok = np.isfinite(length)
    total = np.bincount(src[ok], weights=length[ok], minlength=n)
    count = np.bincount(src[ok], minlength=n)
    mean = np.full(n, np.nan)
    np.divide(total, count, out=mean, where=count > 0)
    return MarkerSurface(
        edges=e,
        faces=np.asarray(faces, dtype=np.int64).reshape(-1, 3),
        offsets=offsets,
        indices=dst.astype(np.int64),
        mean_neighbour_distance=mean,
        reference=reference,
        reference_frame=reference_frame,
    )


def _reference_array(reference: np.ndarray, n: int | None = None) -> np.ndarray:
    ref = np.asarray(reference, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 3 or (n is not None and ref.shape[0] != n):
        want = f"({n}, 3)" if n is not None else "(N, 3)"
        raise ValidationError(f"reference must have shape {want}; got {ref.shape}")
    if np.isinf(ref).any():
        raise ValidationError("reference must not contain inf")
    return ref


def _marker_columns(
    name: str, rows: str, values: np.ndarray, width: int, n_markers: int, *, empty_any_shape: bool
) -> np.ndarray:
    """``values`` as an (``rows``, ``width``) integer array of marker columns ``0..n_markers-1``.

    With ``empty_any_shape`` an empty input of any shape passes (an empty edge list).
    """
    a = np.asarray(values)
    if (a.size or not empty_any_shape) and (a.ndim != 2 or a.shape[1] != width):
        raise ValidationError(f"{name} must have shape ({rows}, {width}); got {a.shape}")
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise ValidationError(f"{name} must be integers; got dtype {a.dtype}")
    if a.size and (a.min() < 0 or a.max() >= n_markers):
        raise ValidationError(
            f"{name} refer to markers outside 0..{n_markers - 1} (min {a.min()}, max {a.max()})"
        )
    return a


def surface_from_edges(
    edges: np.ndarray, reference: np.ndarray, *, reference_frame: int = -1
) -> MarkerSurface:
    """A :class:`MarkerSurface` from a user edge list (no faces).

    Parameters
    ----------
    edges : (E, 2) int
        Marker column pairs, either order, duplicates and self-pairs ignored.
    reference : (N, 3) float, metres
        Reference-pose positions (for neighbour order and distances); NaN allowed.
    reference_frame : int, default -1

    Returns
    -------
    MarkerSurface
    """
    ref = _reference_array(reference)
    e = _marker_columns("edges", "E", edges, 2, ref.shape[0], empty_any_shape=True)
    return _assemble(e.reshape(-1, 2), np.zeros((0, 3), np.int64), ref, reference_frame)


def surface_from_faces(
    faces: np.ndarray, reference: np.ndarray, *, reference_frame: int = -1
) -> MarkerSurface:
    """A :class:`MarkerSurface` from user triangles whose vertices are marker columns.

    Parameters
    ----------
    faces : (F, 3) int
        Triangles over marker columns ``0..N-1``.
    reference : (N, 3) float, metres
        Reference-pose positions; NaN allowed.
    reference_frame : int, default -1

    Returns
    -------
    MarkerSurface
        Edges are the triangles' edges.
    """
    ref = _reference_array(reference)
    f = _marker_columns("faces", "F", faces, 3, ref.shape[0], empty_any_shape=False)
    f = f.astype(np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return _assemble(e, f, ref, reference_frame)


def _trajectories_with_frames(positions: np.ndarray) -> np.ndarray:
    """``positions`` as (T, N, 3) float64 with T > 0, or :class:`ValidationError`."""
    pos = as_trajectories(positions)
    if pos.shape[0] == 0:
        raise ValidationError("positions: expected at least one frame, got 0")
    return pos


def choose_reference_frame(positions: np.ndarray) -> int:
    """The first frame in which the most markers are present.

    Parameters
    ----------
    positions : (T, N, 3) float, NaN where missing

    Returns
    -------
    int
    """
    pos = _trajectories_with_frames(positions)
    present = np.isfinite(pos).all(axis=2).sum(axis=1)
    return int(np.argmax(present))


def complete_reference_pose(
    positions: np.ndarray, reference_frame: int, *, k: int = 6
) -> np.ndarray:
    """The reference pose with the markers hidden in it placed by their neighbours.

    The paper assumed no marker is missing in the reference pose. For each marker
    missing there: the frame nearest in time where it is present, its ``k`` nearest
    markers in that frame that are present in both frames, and the rigid transform
    (Kabsch) carrying them from that frame to the reference frame, applied to the
    marker.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    reference_frame : int
    k : int, default 6
        Neighbours carrying each hidden marker (at least 3 must be available).

    Returns
    -------
    (N, 3) float64, metres
        The reference frame's positions, hidden markers filled in; NaN for markers
        never present or without 3 usable neighbours.
    """
    from skincap.geometry.rigid import apply_rigid, fit_rigid

    pos = np.asarray(positions, dtype=np.float64)
    t_count, n, _ = pos.shape
    if not 0 <= reference_frame < t_count:
        raise ValidationError(f"reference_frame {reference_frame} is outside 0..{t_count - 1}")
    ref = pos[reference_frame].copy()
    present = np.isfinite(pos).all(axis=2)  # (T, N)
    hidden = np.flatnonzero(~present[reference_frame] & present.any(axis=0))
    if hidden.size == 0 or n < 4:
        return ref
    # the present frame nearest in time to the reference frame, per hidden marker
    gap = np.abs(np.arange(t_count)[:, None] - reference_frame)
    src_frame = np.argmin(np.where(present[:, hidden], gap, t_count + 1), axis=0)  # (H,)
    both = present[src_frame] & present[reference_frame][None, :]  # (H, N)
    here = pos[src_frame]  # (H, N, 3)
    dist = np.linalg.norm(here - pos[src_frame, hidden][:, None, :], axis=2)
    dist = np.where(both, dist, np.inf)
    kk = min(k, n - 1)
    nb = np.argsort(dist, axis=1, kind="stable")[:, :kk]  # (H, k)
    use = np.isfinite(np.take_along_axis(dist, nb, axis=1))
    rot, tr = fit_rigid(here[np.arange(hidden.size)[:, None], nb], ref[nb], mask=use)
    moved = apply_rigid(rot, tr, pos[src_frame, hidden][:, None, :])[:, 0]
    ref[hidden] = moved  # NaN where fewer than 3 neighbours
    return ref


def pair_distance_cv(positions: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How constant each pair's distance stays through the take.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    pairs : (P, 2) int

    Returns
    -------
    cv : (P,) float64
        Standard deviation over mean of the pair distance over frames where both are
        present; NaN when they are never present together.
    overlap : (P,) int64
        Number of frames where both are present.
    """
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    dist = np.linalg.norm(positions[:, p[:, 0]] - positions[:, p[:, 1]], axis=-1)  # (T, P)
    ok = np.isfinite(dist)
    n = ok.sum(axis=0)
    dz = np.where(ok, dist, 0.0)
    safe = np.maximum(n, 1)
    mean = dz.sum(axis=0) / safe
    var = np.where(ok, (dz - mean) ** 2, 0.0).sum(axis=0) / safe
    cv = np.full(p.shape[0], np.nan)
    np.divide(np.sqrt(var), mean, out=cv, where=(n > 0) & (mean > 0))
    return cv, n.astype(np.int64)


def _pca_normals(ref: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(N, 3) unit normals: least-variance direction of each marker's kept neighbourhood."""
    n = ref.shape[0]
    known = np.isfinite(ref).all(axis=1)
    ref = np.where(known[:, None], ref, 0.0)
    src = np.concatenate([edges[:, 0], edges[:, 1], np.arange(n)])
    dst = np.concatenate([edges[:, 1], edges[:, 0], np.arange(n)])
    cnt = np.bincount(src, minlength=n).astype(float)
    centroid = np.zeros((n, 3))
    np.add.at(centroid, src, ref[dst])
    centroid /= cnt[:, None]
    d = ref[dst] - centroid[src]
    cov = np.zeros((n, 3, 3))
    np.add.at(cov, src, d[:, :, None] * d[:, None, :])
    _, vec = np.linalg.eigh(cov)
    normal = vec[:, :, 0]
    normal[(cnt < 3) | ~known] = np.nan  # too few points to define a plane
    return normal


def _candidate_triangles(edges: np.ndarray, n: int) -> np.ndarray:
    """(F, 3) all triangles ``a < b < c`` whose three edges are in ``edges``."""
    if edges.shape[0] == 0:
        return np.zeros((0, 3), np.int64)
    adj = sparse.coo_matrix(
        (np.ones(edges.shape[0], dtype=np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n)
    ).tocsr()
    adj = ((adj + adj.T) > 0).tocsr()
    indptr, ind = adj.indptr, adj.indices
    a, b = edges[:, 0], edges[:, 1]
    deg = np.diff(indptr)[a]
    rep = np.repeat(np.arange(a.shape[0]), deg)
    # positions inside the CSR rows of a: indptr[a] + 0..deg-1
    within = np.arange(rep.shape[0]) - np.repeat(np.cumsum(deg) - deg, deg)
    c = ind[indptr[a][rep] + within]
    aa, bb = a[rep], b[rep]
    keep = c > bb
    aa, bb, c = aa[keep], bb[keep], c[keep]
    if c.size == 0:  # no wedge at all (e.g. two markers): scipy's empty fancy index is sparse
        return np.zeros((0, 3), np.int64)
    closed = np.asarray(adj[bb, c]).ravel() > 0
    return np.stack([aa[closed], bb[closed], c[closed]], axis=1).astype(np.int64)


def _circumballs(pts: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Circumcentres (F, 3), circumradii (F,) and unit normals (F, 3) of triangles."""
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    ab, ac = b - a, c - a
    nrm = np.cross(ab, ac)
    n2 = np.einsum("ij,ij->i", nrm, nrm)
    good = n2 > 1e-24
    safe = np.where(good, n2, 1.0)[:, None]
    centre = a + (
        np.cross(nrm, ab) * np.einsum("ij,ij->i", ac, ac)[:, None]
        + np.cross(ac, nrm) * np.einsum("ij,ij->i", ab, ab)[:, None]
    ) / (2.0 * safe)
    radius = np.where(good, np.linalg.norm(centre - a, axis=1), np.inf)
    unit = nrm / np.sqrt(safe)
    return centre, radius, unit


def _greedy_manifold(pts: np.ndarray, tri: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Accept triangles in ``order`` while every edge has < 2 and nothing folds.

    A sequential greedy pass like ball pivoting: each decision depends on the ones
    before it. The loop runs over candidate triangles (a few per marker) and does only
    set bookkeeping and a 3-vector test per shared edge.
    """
    accepted: list[int] = []
    on_edge: dict[tuple[int, int], list[int]] = {}
    for f in order.tolist():
        a, b, c = (int(v) for v in tri[f])
        tri_edges = ((a, b, c), (b, c, a), (a, c, b))  # (edge ends, opposite vertex)
        ok = True
        for p, q, opp in tri_edges:
            key = (min(p, q), max(p, q))
            others = on_edge.get(key, ())
            if len(others) >= 2:
                ok = False
                break
            for g in others:
                other_opp = int(next(v for v in tri[g] if v != p and v != q))
                axis = pts[q] - pts[p]
                axis = axis / np.linalg.norm(axis)
                u = pts[opp] - pts[p]
                v = pts[other_opp] - pts[p]
                u = u - axis * (u @ axis)
                v = v - axis * (v @ axis)
                # both triangles on the same side of the shared edge: a fold
                if u @ v > 0.0:
                    ok = False
                    break
            if not ok:
                break
        if not ok:
            continue
        accepted.append(f)
        for p, q, _ in tri_edges:
            on_edge.setdefault((min(p, q), max(p, q)), []).append(f)
    return np.asarray(accepted, dtype=np.int64)


def _on_body(ref: np.ndarray, present: np.ndarray, body: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """The present markers (``present`` (P,) rows of ``ref`` (N, 3) metres) snapped to
    their closest points on the body mesh, and the mesh's unit normals there (N, 3),
    NaN for absent markers."""
    from skincap.geometry.raycast import closest_points_on_mesh

    geom = ref.copy()
    _, face, bary = closest_points_on_mesh(body.vertices, body.faces, ref[present])
    corners = body.vertices[body.faces[face]]  # (P, 3, 3)
    geom[present] = np.einsum("pk,pki->pi", bary, corners)
    fn = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.full((ref.shape[0], 3), np.nan)
    normals[present] = fn / np.linalg.norm(fn, axis=1, keepdims=True)
    return geom, normals


def _triangulate(
    geom: np.ndarray,
    tree: cKDTree,
    kept: np.ndarray,
    normals: np.ndarray | None,
    max_normal_angle: float,
    ball_slack: float,
) -> np.ndarray:
    """Faces (F, 3) over the kept edges (E, 2): candidate triangles whose shrunk
    circumball holds no marker and whose normal agrees with its corners' surface
    normals (the mesh's, else PCA normals over ``kept``), smallest ball first, kept
    while the surface stays manifold. ``geom`` (N, 3) metres; ``tree`` over its
    present rows."""
    tri = _candidate_triangles(kept, geom.shape[0])
    if not tri.shape[0]:
        return np.zeros((0, 3), np.int64)
    centre, radius, unit = _circumballs(geom, tri)
    # empty ball: nothing strictly inside (the three corners lie on the sphere)
    inside = tree.query_ball_point(
        centre, np.maximum(radius * (1.0 - ball_slack), 0.0), return_length=True
    )
    good = (inside == 0) & np.isfinite(radius)
    if normals is None:
        normals = _pca_normals(geom, kept)
    cos_tri = np.abs(np.einsum("fi,fki->fk", unit, normals[tri]))  # (F, 3), NaN if unknown
    cos_min = np.cos(np.radians(max_normal_angle))
    good &= np.all(np.where(np.isnan(cos_tri), 1.0, cos_tri) >= cos_min, axis=1)
    tri, radius = tri[good], radius[good]
    order = np.argsort(radius, kind="stable")
    return tri[_greedy_manifold(geom, tri, order)]


def build_marker_surface(
    positions: np.ndarray,
    *,
    reference_frame: int | None = None,
    k: int = 10,
    max_edge: float | None = None,
    max_cv: float = 0.2,
    min_overlap: int = 10,
    min_neighbours: int = 3,
    max_normal_angle: float = 60.0,
    ball_slack: float = 0.05,
    body: Mesh | None = None,
) -> MarkerSurface:
    """Build the marker surface automatically from a capture.

    Parameters
    ----------
    positions : (T, N, 3) float, metres
        Marker trajectories (NaN where missing). The surface's vertices are the N
        columns; columns absent from the reference frame get no neighbours.
    reference_frame : int, optional
        The reference pose; default :func:`choose_reference_frame`.
    k : int, default 10
        Candidate neighbours per marker (nearest in the reference pose).
    max_edge : float, optional, metres
        Longest candidate edge.
    max_cv : float, default 0.2
        Largest coefficient of variation of a kept pair's distance.
    min_overlap : int, default 10
        Frames two markers must share before their CV can reject them.
    min_neighbours : int, default 3
        Markers with fewer surface neighbours get their most motion-consistent
        candidates added until they have this many (when available).
    max_normal_angle : float, default 60, degrees
        Largest angle between a triangle's normal and its corners' surface normals.
    ball_slack : float, default 0.05
        The empty-ball test shrinks each ball by this fraction of its radius, so
        near-cocircular quads (noise, curvature) keep both diagonals as candidates;
        the greedy manifold pass then keeps one of them.
    body : Mesh, optional
        Body surface in the reference pose (metres, same axes) guiding the geometry.

    Returns
    -------
    MarkerSurface
        ``reference`` is the reference frame's positions (NaN for absent markers).

    Raises
    ------
    ValidationError
        Bad shapes, a reference frame out of range, or non-finite ``k``/thresholds.
    """
    pos = _trajectories_with_frames(positions)
    if np.isinf(pos).any():
        raise ValidationError("positions must not contain inf (use NaN for missing)")
    if k < 1 or min_neighbours < 0 or not (max_cv > 0) or min_overlap < 2:
        raise ValidationError(
            f"need k >= 1, min_neighbours >= 0, max_cv > 0, min_overlap >= 2; got "
            f"k={k}, min_neighbours={min_neighbours}, max_cv={max_cv}, min_overlap={min_overlap}"
        )
    t_count, n, _ = pos.shape
    if reference_frame is None:
        reference_frame = choose_reference_frame(pos)
    if not 0 <= reference_frame < t_count:
        raise ValidationError(f"reference_frame {reference_frame} is outside 0..{t_count - 1}")
    ref = pos[reference_frame].copy()
    present = np.flatnonzero(np.isfinite(ref).all(axis=1))
    if present.size < 2:
        return _assemble(np.zeros((0, 2), np.int64), np.zeros((0, 3)), ref, reference_frame)

    geom, mesh_normals = (ref.copy(), None) if body is None else _on_body(ref, present, body)

    # 2. candidates: k nearest in the reference pose
    tree = cKDTree(geom[present])
    kk = min(k + 1, present.size)
    dist, nn = tree.query(geom[present], kk)
    dist, nn = dist[:, 1:], nn[:, 1:]
    rows = np.repeat(present, kk - 1)
    cols = present[nn.ravel()]
    okc = np.isfinite(dist.ravel())
    if max_edge is not None:
        okc &= dist.ravel() <= max_edge
    cand = _unique_edges(np.stack([rows[okc], cols[okc]], axis=1))

    # 3. motion consistency
    cv, overlap = pair_distance_cv(pos, cand)
    judged = overlap >= min_overlap
    kept = cand[~judged | (cv <= max_cv)]
    if body is not None:
        from skincap.geometry.raycast import closest_points_on_mesh

        mid = 0.5 * (geom[kept[:, 0]] + geom[kept[:, 1]])
        gap, _, _ = closest_points_on_mesh(body.vertices, body.faces, mid)
        length = np.linalg.norm(geom[kept[:, 0]] - geom[kept[:, 1]], axis=1)
        kept = kept[gap <= 0.3 * length]

    # 4. triangulation over kept edges
    faces = _triangulate(geom, tree, kept, mesh_normals, max_normal_angle, ball_slack)

    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [0, 2]]])
    edges = _unique_edges(edges)

    # 5. sparse fallback: top up with the most motion-consistent kept candidates
    if min_neighbours > 0:
        deg = np.bincount(edges.ravel(), minlength=n)
        fresh = ~_edge_in(cand, edges) & (~judged | (cv <= max_cv))
        extra = _top_up(cand[fresh], cv[fresh], overlap[fresh], min_overlap, deg, min_neighbours)
        edges = _unique_edges(np.concatenate([edges, extra]))
    return _assemble(edges, faces, ref, reference_frame)


def _top_up(
    cand: np.ndarray,
    cv: np.ndarray,
    overlap: np.ndarray,
    min_overlap: int,
    deg: np.ndarray,
    min_neighbours: int,
) -> np.ndarray:
    """Edges from the most motion-consistent candidates of under-connected markers."""
    score = np.where(overlap >= min_overlap, cv, np.inf)  # unjudged pairs last
    src = np.concatenate([cand[:, 0], cand[:, 1]])
    dst = np.concatenate([cand[:, 1], cand[:, 0]])
    sc = np.concatenate([score, score])
    need = np.maximum(min_neighbours - deg, 0)[src]
    order = np.lexsort((dst, sc, src))
    src, dst, sc, need = src[order], dst[order], sc[order], need[order]
    first = np.searchsorted(src, src)  # start of each marker's block
    rank = np.arange(src.shape[0]) - first
    pick = rank < need
    return np.stack([src[pick], dst[pick]], axis=1)


def _edge_in(edges: np.ndarray, among: np.ndarray) -> np.ndarray:
    """(E,) bool: whether each sorted edge of ``edges`` is in the sorted edge set ``among``."""
    if edges.size == 0 or among.size == 0:
        return np.zeros(edges.shape[0], dtype=bool)
    big = int(max(edges.max(), among.max())) + 1
    return np.isin(edges[:, 0] * big + edges[:, 1], among[:, 0] * big + among[:, 1])


def surface_edge_scores(found: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Edge precision and recall of a surface against a ground-truth edge set.

    Parameters
    ----------
    found, truth : (E, 2) int
        Undirected edges over the same vertex numbering.

    Returns
    -------
    precision, recall : float
        NaN when the respective denominator is empty.
    """
    f = _unique_edges(found)
    t = _unique_edges(truth)
    if f.size == 0 or t.size == 0:
        return (float("nan") if f.size == 0 else 0.0, float("nan") if t.size == 0 else 0.0)
    hit = int(_edge_in(f, t).sum())
    return hit / f.shape[0], hit / t.shape[0]
