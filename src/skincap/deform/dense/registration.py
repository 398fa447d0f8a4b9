"""Registration of a body mesh to the reference-pose markers (Park & Hodgins 2006, §5.1).

After Allen, Curless & Popović 2003 ("The space of human body shapes"): every vertex
``i`` of the template gets its own affine transform ``T_i`` (3 x 4), and the deformed
vertex is ``T_i [v_i; 1]``. The transforms minimise

``E = w_d Σ_m |p_m(T) - m|² + w_s Σ_(i,j) |T_i - T_j|²_F + w_l Σ_(k -> i) |T_i [v_i; 1] - m_k|²``

- data (``E_d``): each marker ``m`` to its closest point ``p_m`` on the deformed surface,
  a barycentric point of one triangle, re-found after every solve (closest-point
  iterations, as ICP);
- smoothness (``E_s``): the difference of the transforms of the two ends of every mesh
  edge, so that the template keeps its shape where no marker pulls;
- landmarks (``E_l``): a marker's chosen vertex goes to the marker.
- with the marker surface (``marker_faces``), from
  :attr:`RegistrationSettings.surface_first_stage` on: every vertex to its closest point
  on the Phong-smoothed marker surface (:mod:`skincap.deform.dense.surface_targets`),
  where that surface covers it -- the reverse of ``E_d``, so that the template does not
  bulge or sag between sparse markers.

The schedule is the paper's first phase, then Allen et al.'s annealing: first
smoothness and landmarks only (the model is placed and posed globally: one linear
solve), then all three terms with the smoothness weight falling stage by stage
(:attr:`RegistrationSettings.smoothness_schedule`) and the landmarks fading with it,
each stage a few closest-point iterations.

The unknowns are reduced (as embedded deformation, Sumner et al. 2007): every vertex's
transform is a fixed smooth blend of the transforms of ``n`` deformation nodes
(:attr:`RegistrationSettings.nodes`, 1500: farthest-point samples; each vertex blends
its :data:`NODES_PER_VERTEX` nearest among the nodes of its own and the adjacent
geodesic cells, Sumner's ``(1 - d / d_max)²`` weights), ``X = (B ⊗ I4) Y``; a fixed
number of nodes per vertex keeps the system equally sparse on an uneven mesh. The
first stages run on fewer nodes (:attr:`RegistrationSettings.coarse_nodes` for
:attr:`RegistrationSettings.coarse_stages` stages; coarse to fine: whole limbs
first), each fine node then starting from the coarse transform at its vertex. The smoothness term is still
summed over the template's edges. A 20k-vertex body then solves ``4n x 4n`` normal
equations (one sparse LU per closest-point iteration, SuperLU, COLAMD, shared by the
three coordinates) instead of ``4V x 4V``: ~25 s CPU and ~0.2 GB instead of ~140 s and
~2 GB, and ~3.5 cm between nodes is finer than the ~4.5 cm between dense markers. A
template with at most ``n`` vertices gets one node per vertex (the paper's exact form).

Vertices are expressed about the template's centroid in units of its RMS radius
before solving, so the linear part of ``T`` and its translation are commensurate in the
smoothness term and the result does not depend on where the mesh sits; the returned
transforms act on the template's own coordinates.

Conventions: metres, Y up.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from skincap._arrays import Progress
from skincap.deform.dense.landmarks import automatic_landmarks
from skincap.deform.dense.surface_targets import marker_surface_targets
from skincap.errors import SkincapWarning, ValidationError
from skincap.geometry.normals import area_weighted_vertex_normals
from skincap.geometry.raycast import closest_points_on_mesh

__all__ = [
    "MIN_MARKERS",
    "Registration",
    "RegistrationSettings",
    "automatic_landmarks",
    "check_landmarks",
    "register_mesh",
]

#: Fewest seen markers a registration accepts: below this the surface is not covered.
MIN_MARKERS = 30

#: Deformation nodes blended into each vertex's transform (Sumner et al. use 4).
NODES_PER_VERTEX = 4


@dataclass(frozen=True)
class RegistrationSettings:
    """Weights, schedule and iteration counts of :func:`register_mesh`.

    The smoothness weight falls stage by stage (Allen et al. 2003 anneal it; Amberg et
    al. 2007, "optimal step non-rigid ICP", call it the stiffness): a stiff template is
    first placed and posed as a whole, then bends locally as the weight falls, so the
    closest points it finds are right before it is allowed to follow them closely.
    The landmark weight fades with it: landmarks found across two different bodies
    are approximate, so the data term has the last word.
    """

    #: Weight of the data term (markers to the surface), every stage after the first.
    data_weight: float = 1.0
    #: Smoothness weight of each stage, falling. The first stage (landmarks and
    #: smoothness only: the global placement, the paper's first phase) uses the first.
    smoothness_schedule: tuple[float, ...] = (1.0, 0.3, 0.1, 0.03, 0.01)
    #: Landmark weight of the first stage; stage k uses it times
    #: ``smoothness_schedule[k] / smoothness_schedule[0]``.
    landmark_weight: float = 1.0
    #: Closest-point iterations per stage, at most.
    fit_iterations: int = 4
    #: End a stage when no vertex moved more than this in one iteration, metres.
    tolerance: float = 1e-4
    #: Pull of every transform toward its previous value (damping; keeps an unobserved
    #: part of the mesh, e.g. a separate eyeball, where it was).
    damping: float = 1e-6
    #: Deformation nodes whose transforms every vertex's transform blends (the unknowns:
    #: 4 x 3 per node); a template with fewer vertices gets one node per vertex.
    nodes: int = 1500
    #: Nodes of the coarse stages (0: none): the first ``coarse_stages`` stages of the
    #: schedule move the template through this few nodes (whole limbs and the torso,
    #: stiff), the rest through ``nodes`` (coarse to fine): the stiff stages then size
    #: and place body parts without bending into closest points that are still wrong.
    coarse_nodes: int = 400
    #: Stages of ``smoothness_schedule`` (from the first, the landmark-only placement
    #: included) solved on the ``coarse_nodes`` nodes.
    coarse_stages: int = 3
    #: Radius of the markers, metres: the surface is fitted this far inside each marker
    #: (along the surface normal at its closest point); 0 fits the marker centres.
    marker_radius: float = 0.0
    #: Weight of the reverse data term, every template vertex to the smoothed marker
    #: surface (when ``marker_faces`` are given): summed over the vertices it weighs as
    #: much as the markers' term (each vertex ``surface_weight * M / V``).
    surface_weight: float = 1.0
    #: Vertices farther than this from the marker surface are not pulled to it, metres.
    surface_max_distance: float = 0.03
    #: First stage of ``smoothness_schedule`` (0-based) with the reverse term. A later
    #: start lets the stiff stages place the template before the pull; measured on the
    #: MakeHuman/procedural pairs, pulling from the first stage registers closer.
    surface_first_stage: int = 0
    #: The marker normals that shape the smoothed marker surface: 0 takes Max's, from
    #: the marker triangles alone; > 0 the mean normal of the template (as it stands in
    #: each closest-point iteration) within this many marker spacings of each marker
    #: (:func:`skincap.deform.dense.surface_targets.template_patch_normals`): the
    #: template passes through the markers, and its surface there tilts less than a
    #: normal from a few neighbours 4-7 cm away across a limb, a foot or the head.
    normal_patch_ratio: float = 0.5

    def __post_init__(self) -> None:
        for name in ("data_weight", "landmark_weight", "damping", "surface_weight"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValidationError(f"{name}: expected a finite weight >= 0, got {value!r}")
        schedule = np.asarray(self.smoothness_schedule, dtype=np.float64)
        if schedule.ndim != 1 or schedule.size == 0 or not np.isfinite(schedule).all():
            raise ValidationError(
                f"smoothness_schedule: expected finite weights, got {self.smoothness_schedule!r}"
            )
        if (schedule <= 0).any():
            raise ValidationError(
                "smoothness_schedule: weights must be > 0 (they hold the mesh together)"
            )
        if int(self.nodes) < 1:
            raise ValidationError(f"nodes: expected >= 1, got {self.nodes!r}")
        for name in ("coarse_nodes", "coarse_stages"):
            if int(getattr(self, name)) < 0:
                raise ValidationError(f"{name}: expected >= 0, got {getattr(self, name)!r}")
        if int(self.surface_first_stage) < 0:
            raise ValidationError(
                f"surface_first_stage: expected >= 0, got {self.surface_first_stage!r}"
            )
        if int(self.fit_iterations) < 0:
            raise ValidationError(f"fit_iterations: expected >= 0, got {self.fit_iterations!r}")
        ratio = self.normal_patch_ratio
        if not (np.isfinite(ratio) and ratio >= 0):
            raise ValidationError(
                f"normal_patch_ratio: expected a finite ratio >= 0, got {ratio!r}"
            )
        for name in ("tolerance", "marker_radius", "surface_max_distance"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValidationError(
                    f"{name}: expected a finite length >= 0 in metres, got {value!r}"
                )


@dataclass(frozen=True)
class Registration:
    """A template mesh registered to markers.

    Attributes
    ----------
    vertices : (V, 3) float64, metres
        The registered mesh (the template's faces are unchanged).
    affine : (V, 3, 4) float64
        Per-vertex affine transform: ``vertices[i] = affine[i, :, :3] @ v_i + affine[i, :, 3]``
        with ``v_i`` the template vertex (metres).
    landmarks : dict of str to int
        Marker label -> template vertex index used as a landmark.
    marker_distance : (M,) float64, metres
        Each marker's distance to the registered surface; NaN for an unseen marker.
    iterations : int
        Closest-point iterations run, summed over the stages of the schedule.
    """

    vertices: np.ndarray
    affine: np.ndarray
    landmarks: dict[str, int]
    marker_distance: np.ndarray
    iterations: int = 0


# ----------------------------------------------------------------------- checks
def _mesh(vertices: object, faces: object) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
        raise ValidationError(f"vertices: expected shape (V, 3) with V >= 3, got {v.shape}")
    if not np.isfinite(v).all():
        raise ValidationError("vertices: must be finite")
    f = np.asarray(faces)
    if f.size == 0:
        raise ValidationError("faces: the mesh has no faces (registration needs a surface)")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValidationError(
            f"faces: expected an integer array of shape (F, 3), got {f.shape} {f.dtype}"
        )
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValidationError(f"faces: vertex indices must be in 0..{v.shape[0] - 1}")
    return v, f


def _markers(markers: object, labels: object) -> tuple[np.ndarray, list[str]]:
    m = np.asarray(markers, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValidationError(f"markers: expected shape (M, 3), got {m.shape}")
    names = [str(s) for s in labels]  # type: ignore[attr-defined]
    if len(names) != m.shape[0]:
        raise ValidationError(
            f"labels: expected {m.shape[0]} labels (one per marker), got {len(names)}"
        )
    if len(set(names)) != len(names):
        raise ValidationError("labels: marker labels must be unique")
    seen = np.isfinite(m).all(axis=1)
    if np.isinf(m).any():
        raise ValidationError("markers: infinite coordinates (use NaN rows for unseen markers)")
    if int(seen.sum()) < MIN_MARKERS:
        raise ValidationError(
            f"markers: registration needs at least {MIN_MARKERS} seen markers, got {int(seen.sum())}"
        )
    return m, names


def check_landmarks(landmarks: object, labels: list[str], n_vertices: int) -> dict[str, int]:
    """``landmarks`` as ``{label: vertex}``, or :class:`ValidationError` naming the bad entry.

    Parameters
    ----------
    landmarks : mapping of str to int
        Marker label -> template vertex index.
    labels : list of M str
        The markers' labels; every landmark must name one of them.
    n_vertices : int
        V; every vertex index must be in ``0..V-1``.
    """
    if not hasattr(landmarks, "items"):
        raise ValidationError(
            f"landmarks: expected a mapping label -> vertex index, got {type(landmarks).__name__}"
        )
    known = set(labels)
    out: dict[str, int] = {}
    for label, vertex in landmarks.items():
        if str(label) not in known:
            raise ValidationError(f"landmarks: {label!r} is not a marker label")
        if isinstance(vertex, bool) or not isinstance(vertex, (int, np.integer)):
            raise ValidationError(
                f"landmarks: vertex of {label!r} must be an integer, got {vertex!r}"
            )
        if not 0 <= int(vertex) < n_vertices:
            raise ValidationError(
                f"landmarks: vertex {int(vertex)} of {label!r} is out of range 0..{n_vertices - 1}"
            )
        out[str(label)] = int(vertex)
    return out


def _check_marker_faces(faces: object, markers: np.ndarray) -> _MarkerSurface | None:
    """The marker surface for the reverse term, or None; :class:`ValidationError` if malformed."""
    if faces is None:
        return None
    f = np.asarray(faces)
    if f.size == 0:
        return None
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValidationError(
            f"marker_faces: expected an integer array of shape (G, 3), got {f.shape} {f.dtype}"
        )
    if f.min() < 0 or f.max() >= markers.shape[0]:
        raise ValidationError(f"marker_faces: marker indices must be in 0..{markers.shape[0] - 1}")
    return _MarkerSurface(markers=markers, faces=f.astype(np.int64))


# ---------------------------------------------------------------- linear system
def _edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) unique undirected mesh edges."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


def _point_rows(
    corners: np.ndarray, weights: np.ndarray, homog: np.ndarray, n_vertices: int
) -> sp.csr_matrix:
    """(K, 4V) rows mapping the stacked transforms X (4V, 3) to K surface points.

    A point with barycentric ``weights`` (K, C) over vertices ``corners`` (K, C) is
    ``Σ_c w_c T_c [v_c; 1]``: its row holds ``w_c * [v_c; 1]`` at columns ``4 c .. 4 c + 3``.
    """
    k, c = corners.shape
    rows = np.repeat(np.arange(k), 4 * c)
    cols = (4 * corners[:, :, None] + np.arange(4)).reshape(-1)
    vals = (weights[:, :, None] * homog[corners]).reshape(-1)
    return sp.csr_matrix((vals, (rows, cols)), shape=(k, 4 * n_vertices))


def _solve_normal_equations(normal: sp.spmatrix, rhs: np.ndarray) -> np.ndarray:
    """X (4V, 3) from the SPD normal equations ``N X = R`` by one sparse LU.

    COLAMD ordering: on a body mesh's ``4V x 4V`` system it factors in about a second
    for 13k vertices, where the minimum-degree orderings take a minute; the three
    coordinates share the factors. A direct solve, not PCG: once the smoothness weight
    has fallen, the few hundred marker rows make the system ill-conditioned and PCG
    needs about as many steps as there are rows.
    """
    return spla.splu(sp.csc_matrix(normal), permc_spec="COLAMD").solve(np.asarray(rhs))


# ------------------------------------------------------------------------ steps
def _seen_landmarks(
    landmarks: dict[str, int] | None,
    v: np.ndarray,
    f: np.ndarray,
    m: np.ndarray,
    names: list[str],
) -> tuple[dict[str, int], np.ndarray, np.ndarray]:
    """The landmarks to use (given or automatic) on seen markers: dict, marker and vertex indices."""
    seen = np.isfinite(m).all(axis=1)
    if landmarks is None:
        chosen = automatic_landmarks(v, f, m, names)
    else:
        chosen = check_landmarks(landmarks, names, v.shape[0])
    index = {s: k for k, s in enumerate(names)}
    dropped = [s for s in chosen if not seen[index[s]]]
    if dropped:
        warnings.warn(
            f"landmarks: {len(dropped)} landmark(s) on unseen markers ignored ({', '.join(dropped[:5])})",
            SkincapWarning,
            stacklevel=3,
        )
    chosen = {s: i for s, i in chosen.items() if seen[index[s]]}
    lm_marker = np.array([index[s] for s in chosen], dtype=np.int64)
    lm_vertex = np.array([chosen[s] for s in chosen], dtype=np.int64)
    return chosen, lm_marker, lm_vertex


def _farthest_point_nodes(v: np.ndarray, count: int) -> np.ndarray:
    """``count`` vertex indices spread over ``v`` (V, 3) by farthest-point sampling.

    Deterministic (starts at the highest vertex); one O(V) NumPy pass per node.
    """
    first = int(np.argmax(v[:, 1]))
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = first
    nearest = np.linalg.norm(v - v[first], axis=1)
    for k in range(1, count):
        chosen[k] = int(np.argmax(nearest))
        nearest = np.minimum(nearest, np.linalg.norm(v - v[chosen[k]], axis=1))
    return chosen


def _node_cells(
    v: np.ndarray, f: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """Deformation nodes, each vertex's geodesic cell, and the cells' adjacency.

    The nodes are ``count`` farthest-point samples of the largest connected piece
    (a loose piece -- eye, teeth -- has no edge to the body, so nodes of its own would
    be held by nothing and could fly off); a vertex's cell is the node nearest along
    the mesh (Dijkstra from all nodes at once), or nearest in space for a vertex of
    another piece. Two cells are adjacent when a mesh edge joins them.

    Returns nodes (n,) vertex indices, cell (V,) node index of each vertex, and the
    (n, n) boolean adjacency of the cells, with the diagonal.
    """
    n_v = v.shape[0]
    e = _edges(f)
    length = np.maximum(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1), 1e-12)
    graph = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n_v, n_v)).tocsr()
    _, piece = connected_components(graph, directed=False)
    main = np.nonzero(piece == np.bincount(piece).argmax())[0]
    nodes = main[_farthest_point_nodes(v[main], min(count, main.size))]
    dist, _, source = dijkstra(
        graph, directed=False, indices=nodes, min_only=True, return_predecessors=True
    )
    node_of = np.full(n_v, -1, dtype=np.int64)
    node_of[nodes] = np.arange(nodes.size)
    cell = np.where(np.isfinite(dist), node_of[np.maximum(source, 0)], -1)
    stray = cell < 0
    if stray.any():
        cell[stray] = cKDTree(v[nodes]).query(v[stray])[1]
    a, b = cell[e[:, 0]], cell[e[:, 1]]
    ends = np.concatenate([a, b, np.arange(nodes.size)])
    other = np.concatenate([b, a, np.arange(nodes.size)])
    adjacency = sp.csr_matrix(
        (np.ones(ends.size, dtype=bool), (ends, other)), shape=(nodes.size, nodes.size)
    )
    return nodes, cell, adjacency


def _node_basis(v: np.ndarray, f: np.ndarray, count: int) -> sp.csr_matrix:
    """(V, n) smooth partition of unity over ``count`` nodes (:func:`_nodes_and_basis`)."""
    return _nodes_and_basis(v, f, count)[1]


def _nodes_and_basis(v: np.ndarray, f: np.ndarray, count: int) -> tuple[np.ndarray, sp.csr_matrix]:
    """Node vertex indices (n,) and the (V, n) smooth partition of unity: each vertex's weights over ``n`` deformation nodes.

    Embedded deformation's blend (Sumner, Schmid & Pauly 2007): each vertex takes its
    :data:`NODES_PER_VERTEX` nearest nodes among those of its own geodesic cell and
    the cells next to it (:func:`_node_cells`; so an arm near the torso does not follow
    it), weighted ``(1 - d / d_max)²`` with ``d_max`` the distance of the next nearest
    candidate, then normalised. A fixed number of nodes per vertex keeps the normal
    equations equally sparse on an uneven mesh (MakeHuman's fine hands and face beside
    its coarse limbs), where neighbour averaging over a fixed number of edges spread
    the blend over up to 54 nodes. All vertices, the identity, when ``count >= V``.
    Rows sum to 1.
    """
    n_v = v.shape[0]
    if count >= n_v:
        return np.arange(n_v), sp.identity(n_v, format="csr")
    nodes, cell, adjacency = _node_cells(v, f, int(count))
    # candidates of each vertex: the nodes of its cell's neighbourhood, a padded table
    adjacency = adjacency.tocsr()
    degree = np.diff(adjacency.indptr)
    table = np.full((nodes.size, int(degree.max())), -1, dtype=np.int64)
    slot = np.arange(adjacency.indices.size) - np.repeat(adjacency.indptr[:-1], degree)
    table[np.repeat(np.arange(nodes.size), degree), slot] = adjacency.indices
    candidate = table[cell]  # (V, D)
    d = np.linalg.norm(v[:, None, :] - v[nodes[np.maximum(candidate, 0)]], axis=2)
    d[candidate < 0] = np.inf
    k = min(NODES_PER_VERTEX, candidate.shape[1])
    order = np.argsort(d, axis=1)[:, : k + 1]
    near = np.take_along_axis(d, order, axis=1)
    chosen = np.take_along_axis(candidate, order[:, :k], axis=1)
    # d_max: the next candidate, or (fewer candidates than k + 1) past the farthest one
    d_max = near[:, k] if near.shape[1] > k else np.full(n_v, np.inf)
    farthest = np.where(np.isfinite(near[:, :k]), near[:, :k], 0.0).max(axis=1)
    d_max = np.where(np.isfinite(d_max), d_max, 1.5 * farthest + 1e-12)
    weight = np.clip(1.0 - near[:, :k] / np.maximum(d_max, 1e-12)[:, None], 0.0, None) ** 2
    weight[chosen < 0] = 0.0
    weight[:, 0] = np.where(weight.sum(axis=1) > 0, weight[:, 0], 1.0)  # vertex on a tie
    weight /= weight.sum(axis=1, keepdims=True)
    keep = weight > 0
    rows = np.repeat(np.arange(n_v), keep.sum(axis=1))
    return nodes, sp.csr_matrix((weight[keep], (rows, chosen[keep])), shape=(n_v, nodes.size))


class _AffineSystem:
    """The template in normalised coordinates and the fixed parts of the normal equations.

    Vertices are taken about their centroid in units of their RMS radius, so the
    linear part of a transform and its translation weigh alike in the smoothness term.
    Per-vertex transforms are blends of ``n`` node transforms (:func:`_node_basis`):
    ``X = (B ⊗ I4) Y`` with ``B`` (V, n). The unknown ``Y`` (4n, 3) stacks the node
    transforms transposed, ``Y[4 a : 4 a + 4] = T_aᵀ``, and a deformed vertex is
    ``[v_i; 1]ᵀ X[4 i : 4 i + 4]``. The smoothness term stays the paper's, over the
    template's edges: ``Σ_edges |T_i - T_j|² = trace(Yᵀ ((Bᵀ L B) ⊗ I4) Y)``.
    """

    def __init__(self, v: np.ndarray, f: np.ndarray, nodes: int) -> None:
        n_v = v.shape[0]
        self.n_vertices = n_v
        self.faces = f
        self.centre = v.mean(axis=0)
        self.scale = float(np.sqrt(((v - self.centre) ** 2).sum(axis=1).mean())) or 1.0
        self.homog = np.concatenate([(v - self.centre) / self.scale, np.ones((n_v, 1))], axis=1)
        self.nodes, self.basis = _nodes_and_basis(v, f, int(nodes))
        self.n_nodes = self.basis.shape[1]
        self.expand = sp.kron(self.basis, sp.identity(4), format="csr")  # (4V, 4n)
        edges = _edges(f)
        n_e = len(edges)
        incidence = sp.csr_matrix(
            (
                np.concatenate([np.ones(n_e), -np.ones(n_e)]),
                (np.tile(np.arange(n_e), 2), np.concatenate([edges[:, 0], edges[:, 1]])),
            ),
            shape=(n_e, n_v),
        )
        difference = incidence @ self.basis  # (E, n): T_i - T_j per edge, from the nodes
        self.smoothness = sp.kron(difference.T @ difference, sp.identity(4), format="csr")
        self.identity = sp.identity(4 * self.n_nodes, format="csr")

    def template_transforms(self) -> np.ndarray:
        """Y (4n, 3) of the template itself: ``T_a = [I | 0]`` in the original units."""
        y = np.zeros((4 * self.n_nodes, 3))
        y.reshape(self.n_nodes, 4, 3)[:, :3, :] = np.eye(3) * self.scale
        y.reshape(self.n_nodes, 4, 3)[:, 3, :] = self.centre
        return y

    def from_vertex_transforms(self, x: np.ndarray) -> np.ndarray:
        """Y (4n, 3) taking each node's transform from per-vertex transforms X (4V, 3).

        Carries a coarser system's fit over to this one: a node sits on a vertex.
        """
        return np.asarray(x).reshape(-1, 4, 3)[self.nodes].reshape(-1, 3).copy()

    def vertex_transforms(self, y: np.ndarray) -> np.ndarray:
        """X (4V, 3): every vertex's transform, blended from the nodes' Y (4n, 3)."""
        return np.asarray(self.expand @ y)

    def deformed(self, y: np.ndarray) -> np.ndarray:
        """(V, 3) deformed vertices, metres."""
        x = self.vertex_transforms(y)
        return np.einsum("vk,vkx->vx", self.homog, x.reshape(self.n_vertices, 4, 3))

    def point_rows(self, corners: np.ndarray, weights: np.ndarray) -> sp.csr_matrix:
        """(K, 4n) rows mapping Y to K barycentric surface points (see :func:`_point_rows`)."""
        return (_point_rows(corners, weights, self.homog, self.n_vertices) @ self.expand).tocsr()

    def affine(self, y: np.ndarray) -> np.ndarray:
        """(V, 3, 4) per-vertex affines acting on the template's own coordinates."""
        xs = self.vertex_transforms(y).reshape(self.n_vertices, 4, 3)
        linear = np.swapaxes(xs[:, :3, :], 1, 2) / self.scale
        translation = xs[:, 3, :] - np.einsum("vxk,k->vx", linear, self.centre)
        return np.concatenate([linear, translation[:, :, None]], axis=2)


def _data_targets(
    current: np.ndarray, faces: np.ndarray, markers: np.ndarray, marker_radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest surface points of the markers and where they should go.

    Returns the closest point's face (K,) and barycentric weights (K, 3) on the current
    surface, and its target (K, 3): the marker, or ``marker_radius`` inside it along the
    surface normal there (a marker sits on the skin, its centre one radius above).
    """
    _, face, bary = closest_points_on_mesh(current, faces, markers)
    if marker_radius <= 0:
        return face, bary, markers
    normals = area_weighted_vertex_normals(current, faces)
    n_at = np.einsum("kc,kcx->kx", bary, normals[faces[face]])
    n_at /= np.maximum(np.linalg.norm(n_at, axis=1, keepdims=True), 1e-12)
    return face, bary, markers - marker_radius * n_at


@dataclass(frozen=True)
class _MarkerSurface:
    """The markers' triangles for the reverse data term: all marker rows (M, 3), faces (G, 3)."""

    markers: np.ndarray
    faces: np.ndarray


def _surface_rows(
    system: _AffineSystem,
    current: np.ndarray,
    surface: _MarkerSurface | None,
    n_markers: int,
    settings: RegistrationSettings,
) -> tuple[sp.csr_matrix, np.ndarray]:
    """Weighted rows (K, 4n) and targets (K, 3) pulling vertices to the marker surface.

    The rows carry ``sqrt(surface_weight * M / V)`` so that the term, summed over all V
    vertices, weighs like the M markers' term whatever the template's resolution.
    """
    if surface is None or settings.surface_weight <= 0:
        return sp.csr_matrix((0, 4 * system.n_nodes)), np.zeros((0, 3))
    targets, valid = marker_surface_targets(
        current,
        area_weighted_vertex_normals(current, system.faces),
        surface.markers,
        surface.faces,
        marker_radius=settings.marker_radius,
        max_distance=settings.surface_max_distance,
        patch_ratio=settings.normal_patch_ratio,
    )
    idx = np.nonzero(valid)[0]
    scale = np.sqrt(settings.surface_weight * n_markers / system.n_vertices)
    rows = system.point_rows(idx[:, None], np.full((idx.size, 1), scale))
    return rows, scale * targets[idx]


def _fit_stage(
    system: _AffineSystem,
    x: np.ndarray,
    markers: np.ndarray,
    landmark_rows: sp.csr_matrix,
    landmark_targets: np.ndarray,
    *,
    smoothness: float,
    landmark: float,
    settings: RegistrationSettings,
    surface: _MarkerSurface | None = None,
) -> tuple[np.ndarray, int]:
    """One stage of the schedule: closest-point iterations at fixed weights.

    Each iteration re-finds the markers' closest points on the current surface (and,
    with a marker surface, the vertices' targets on it) and solves the normal
    equations of all the terms (plus damping toward the current transforms). Returns X
    and the iterations run.
    """
    s = settings
    f = system.faces
    damping = max(s.damping, 1e-12)
    base = smoothness * system.smoothness + landmark * (landmark_rows.T @ landmark_rows)
    base_rhs = landmark * (landmark_rows.T @ landmark_targets)
    iterations = 0
    for it in range(int(s.fit_iterations)):
        current = system.deformed(x)
        face, bary, target = _data_targets(current, f, markers, s.marker_radius)
        data_rows = system.point_rows(f[face], bary)
        pull_rows, pull_targets = _surface_rows(system, current, surface, markers.shape[0], s)
        normal = (
            base
            + s.data_weight * (data_rows.T @ data_rows)
            + pull_rows.T @ pull_rows
            + damping * system.identity
        ).tocsr()
        rhs = (
            base_rhs
            + s.data_weight * (data_rows.T @ target)
            + pull_rows.T @ pull_targets
            + damping * x
        )
        x_new = _solve_normal_equations(normal, rhs)
        moved = float(np.abs(system.deformed(x_new) - current).max())
        x = x_new
        iterations = it + 1
        if moved < s.tolerance:
            break
    return x, iterations


# ------------------------------------------------------------------------ main
def register_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    markers: np.ndarray,
    labels: list[str],
    *,
    landmarks: dict[str, int] | None = None,
    marker_faces: np.ndarray | None = None,
    settings: RegistrationSettings = RegistrationSettings(),
    progress: Progress | None = None,
) -> Registration:
    """Fit a template mesh to reference-pose markers, one affine transform per vertex.

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The template (any body mesh: MakeHuman, the procedural body, an OBJ...).
    faces : (F, 3) int
        Its triangles (at least one).
    markers : (M, 3) float, metres
        The markers in the reference pose; NaN rows (unseen markers) are ignored.
        At least :data:`MIN_MARKERS` must be seen.
    labels : list of M str
        Unique marker labels.
    landmarks : dict of str to int, optional
        Marker label -> template vertex that the marker sits on. Default: found by
        :func:`automatic_landmarks`. Landmarks on unseen markers are dropped.
    marker_faces : (G, 3) int, optional
        Triangles over the marker rows (the marker surface,
        :func:`skincap.cleanup.surface.build_marker_surface`). Given, every template
        vertex is also pulled to the smoothed marker surface where it covers the body
        (:mod:`skincap.deform.dense.surface_targets`), so the template does not bulge
        or sag between sparse markers. Triangles using unseen markers are dropped.
    settings : RegistrationSettings
        Weights, smoothness schedule and iterations.
    progress : callable(fraction, message), optional

    Returns
    -------
    Registration
        The registered vertices (V, 3), per-vertex affines (V, 3, 4), the landmarks
        used and each marker's distance to the registered surface (M,), metres.

    Raises
    ------
    ValidationError
        A mesh with no faces, fewer than :data:`MIN_MARKERS` seen markers, a landmark
        naming an unknown label or a vertex out of range, bad settings.
    """
    v, f = _mesh(vertices, faces)
    m, names = _markers(markers, labels)
    if not isinstance(settings, RegistrationSettings):
        raise ValidationError(
            f"settings: expected RegistrationSettings, got {type(settings).__name__}"
        )
    seen = np.isfinite(m).all(axis=1)
    surface = _check_marker_faces(marker_faces, m)

    def report(fraction: float, message: str) -> None:
        if progress is not None:
            progress(float(min(max(fraction, 0.0), 1.0)), message)

    report(0.0, "landmarks")
    chosen, lm_marker, lm_vertex = _seen_landmarks(landmarks, v, f, m, names)
    # coarse to fine only where the coarse system has fewer nodes than the fine one
    coarse = int(settings.coarse_stages) > 0 and 0 < int(settings.coarse_nodes) < min(
        int(settings.nodes), v.shape[0]
    )
    system = _AffineSystem(v, f, settings.coarse_nodes if coarse else settings.nodes)
    lm_rows = system.point_rows(lm_vertex[:, None], np.ones((lm_vertex.size, 1)))
    lm_targets = m[lm_marker]
    x = system.template_transforms()
    schedule = [float(w) for w in settings.smoothness_schedule]

    # First stage: landmarks and smoothness only (global placement and pose).
    report(0.05, "global fit")
    if lm_vertex.size:
        normal = (
            schedule[0] * system.smoothness
            + settings.landmark_weight * (lm_rows.T @ lm_rows)
            + max(settings.damping, 1e-12) * system.identity
        ).tocsr()
        rhs = settings.landmark_weight * (lm_rows.T @ lm_targets) + max(settings.damping, 1e-12) * x
        x = _solve_normal_equations(normal, rhs)

    # Then every stage with the data term, the smoothness and landmarks falling.
    iterations = 0
    for k, smoothness in enumerate(schedule):
        if coarse and k == int(settings.coarse_stages):  # coarse to fine
            fine = _AffineSystem(v, f, settings.nodes)
            x = fine.from_vertex_transforms(system.vertex_transforms(x))
            system = fine
            lm_rows = system.point_rows(lm_vertex[:, None], np.ones((lm_vertex.size, 1)))
        report(0.1 + 0.85 * k / len(schedule), f"fit, stiffness {smoothness:g}")
        x, ran = _fit_stage(
            system, x, m[seen], lm_rows, lm_targets,
            smoothness=smoothness,
            landmark=settings.landmark_weight * smoothness / schedule[0],
            settings=settings, surface=surface if k >= settings.surface_first_stage else None,
        )  # fmt: skip
        iterations += ran

    report(0.97, "distances")
    out = system.deformed(x)
    distance = np.full(m.shape[0], np.nan)
    distance[seen], _, _ = closest_points_on_mesh(out, f, m[seen])
    report(1.0, "registered")
    return Registration(
        vertices=out,
        affine=system.affine(x),
        landmarks={str(k): int(val) for k, val in chosen.items()},
        marker_distance=distance,
        iterations=iterations,
    )
