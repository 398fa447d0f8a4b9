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

The schedule is the paper's: first smoothness and landmarks only (the model is placed
and posed globally: one linear solve), then all three terms with equal weights until the
closest points stop moving. Each solve is one sparse linear least-squares problem: its
normal equations ``N X = R`` (``N`` is ``4V x 4V``, shared by the three coordinates) are
factored once per iteration (SuperLU) and solved for the three columns of ``X``.

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

from skincap._arrays import Progress
from skincap.deform.dense.landmarks import automatic_landmarks
from skincap.errors import SkincapWarning, ValidationError
from skincap.geometry.raycast import closest_points_on_mesh

__all__ = [
    "MIN_MARKERS",
    "Registration",
    "RegistrationSettings",
    "automatic_landmarks",
    "check_landmarks",
    "register_mesh",
]

#: Closest-point iterations that share one preconditioner factorisation.
_REFACTOR_EVERY = 5

#: Fewest seen markers a registration accepts: below this the surface is not covered.
MIN_MARKERS = 30


@dataclass(frozen=True)
class RegistrationSettings:
    """Weights and iteration counts of :func:`register_mesh` (defaults: the paper's schedule)."""

    #: Weight of the data term in the second phase (the paper: equal to the others).
    data_weight: float = 1.0
    #: Weight of the smoothness term (both phases).
    smoothness_weight: float = 1.0
    #: Weight of the landmark term (both phases).
    landmark_weight: float = 1.0
    #: Closest-point iterations of the second phase (all terms), at most.
    fit_iterations: int = 20
    #: Stop the second phase when no vertex moved more than this in one iteration, metres.
    tolerance: float = 1e-4
    #: Pull of every transform toward its previous value (damping; keeps an unobserved
    #: part of the mesh, e.g. a separate eyeball, where it was).
    damping: float = 1e-6
    #: Radius of the markers, metres: the surface is fitted this far inside each marker
    #: (along the surface normal at its closest point); 0 fits the marker centres.
    marker_radius: float = 0.0

    def __post_init__(self) -> None:
        for name in ("data_weight", "smoothness_weight", "landmark_weight", "damping"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValidationError(f"{name}: expected a finite weight >= 0, got {value!r}")
        if self.smoothness_weight <= 0:
            raise ValidationError("smoothness_weight: must be > 0 (it holds the mesh together)")
        if int(self.fit_iterations) < 0:
            raise ValidationError(f"fit_iterations: expected >= 0, got {self.fit_iterations!r}")
        for name in ("tolerance", "marker_radius"):
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
        Closest-point iterations the second phase ran.
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
    for label, vertex in landmarks.items():  # type: ignore[attr-defined]
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


class _ComponentPreconditioner:
    """``M⁻¹`` for PCG: the system without its coupling between the 4 components.

    ``N`` is ``w_s (L ⊗ I4) + damping I + (data and landmark rows)``; dropping the rows'
    coupling between the components of one vertex (and between vertices) and averaging
    their diagonal over the components leaves ``I4 ⊗ (w_s L + diag(d) + damping I)``:
    one V x V sparse LU, solved for all 4 x 3 columns at once and reused for several
    closest-point iterations.
    """

    def __init__(self, laplacian: sp.csr_matrix, normal: sp.csr_matrix, n_vertices: int) -> None:
        diagonal = normal.diagonal().reshape(n_vertices, 4).mean(axis=1)
        extra = diagonal - laplacian.diagonal()
        self._factor = spla.splu((laplacian + sp.diags(extra)).tocsc(), permc_spec="MMD_AT_PLUS_A")
        self._n = n_vertices

    def __call__(self, r: np.ndarray) -> np.ndarray:
        cols = r.shape[1]
        r4 = r.reshape(self._n, 4 * cols)  # (V, 4 components x 3 coordinates)
        return self._factor.solve(np.ascontiguousarray(r4)).reshape(r.shape)


def _solve_pcg(
    normal: sp.csr_matrix,
    rhs: np.ndarray,
    start: np.ndarray,
    precondition: _ComponentPreconditioner,
    *,
    rtol: float = 1e-7,
    max_iterations: int = 2000,
) -> np.ndarray:
    """X (4V, 3) from the SPD normal equations by preconditioned conjugate gradients.

    The three right-hand sides (x, y, z) run together, each with its own step
    lengths; warm-started from ``start`` (the previous iterate), so a closest-point
    iteration that changes little costs few steps.
    """
    x = start.copy()
    r = rhs - normal @ x
    norm_b = np.maximum(np.linalg.norm(rhs, axis=0), 1e-300)
    z = precondition(r)
    p = z.copy()
    rz = np.einsum("ij,ij->j", r, z)
    for _ in range(max_iterations):
        if (np.linalg.norm(r, axis=0) <= rtol * norm_b).all():
            break
        q = normal @ p
        pq = np.einsum("ij,ij->j", p, q)
        alpha = np.divide(rz, pq, out=np.zeros_like(rz), where=pq > 0)
        x += alpha * p
        r -= alpha * q
        z = precondition(r)
        rz_new = np.einsum("ij,ij->j", r, z)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)
        p = z + beta * p
        rz = rz_new
    return x


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals (zero for an isolated vertex)."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


# ------------------------------------------------------------------------ steps
def _reporter(progress: Progress | None) -> Progress:
    """``progress`` with the fraction clamped to [0, 1]; a no-op when ``progress`` is None."""

    def report(fraction: float, message: str) -> None:
        if progress is not None:
            progress(float(min(max(fraction, 0.0), 1.0)), message)

    return report


def _seen_landmarks(
    v: np.ndarray,
    f: np.ndarray,
    m: np.ndarray,
    names: list[str],
    seen: np.ndarray,
    landmarks: object,
) -> tuple[dict[str, int], np.ndarray, np.ndarray]:
    """The landmarks to fit: given (checked) or automatic, those on unseen markers dropped.

    ``v`` (V, 3) and ``m`` (M, 3) in metres, ``f`` (F, 3), ``seen`` (M,) bool. Warns
    (:class:`SkincapWarning`, at :func:`register_mesh`'s caller) when landmarks are dropped.
    Returns ``{label: vertex}`` kept, and the landmarks' marker indices (L,) and template
    vertex indices (L,), int64, in the same order.
    """
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
            stacklevel=3,  # register_mesh's caller
        )
    chosen = {s: i for s, i in chosen.items() if seen[index[s]]}
    lm_marker = np.array([index[s] for s in chosen], dtype=np.int64)
    lm_vertex = np.array([chosen[s] for s in chosen], dtype=np.int64)
    return chosen, lm_marker, lm_vertex


def _normalised_homogeneous(v: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """The template about its centroid in units of its RMS radius, homogeneous.

    ``v`` (V, 3) metres -> centre (3,) metres, scale (metres, 1.0 for a degenerate mesh)
    and ``[(v - centre) / scale, 1]`` (V, 4), dimensionless.
    """
    n_v = v.shape[0]
    centre = v.mean(axis=0)
    scale = float(np.sqrt(((v - centre) ** 2).sum(axis=1).mean())) or 1.0
    homog = np.concatenate([(v - centre) / scale, np.ones((n_v, 1))], axis=1)  # (V, 4)
    return centre, scale, homog


def _edge_incidence(f: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(E, V) signed incidence of the unique mesh edges: +1 at the first end, -1 at the second.

    ``incidenceᵀ incidence`` is the (V, V) graph Laplacian of the mesh.
    """
    edges = _edges(f)
    return sp.csr_matrix(
        (
            np.concatenate([np.ones(len(edges)), -np.ones(len(edges))]),
            (np.tile(np.arange(len(edges)), 2), np.concatenate([edges[:, 0], edges[:, 1]])),
        ),
        shape=(len(edges), n_vertices),
    )


def _template_transforms(n_vertices: int, centre: np.ndarray, scale: float) -> np.ndarray:
    """X (4V, 3) that leaves every vertex at its template position.

    Acting on the normalised homogeneous vertices, ``T_i = [I | 0]`` in original units:
    the linear part is ``scale * I`` and the translation ``centre`` (metres).
    """
    x = np.zeros((4 * n_vertices, 3))
    x.reshape(n_vertices, 4, 3)[:, :3, :] = np.eye(3) * scale
    x.reshape(n_vertices, 4, 3)[:, 3, :] = centre
    return x


def _deformed(homog: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(V, 3) deformed vertices, metres, from ``homog`` (V, 4) and the transforms X (4V, 3)."""
    return np.einsum("vk,vkx->vx", homog, x.reshape(homog.shape[0], 4, 3))


def _data_targets(
    current: np.ndarray,
    f: np.ndarray,
    face: np.ndarray,
    bary: np.ndarray,
    marker_pts: np.ndarray,
    marker_radius: float,
) -> np.ndarray:
    """(K, 3) points, metres, the closest surface points are pulled to.

    The markers ``marker_pts`` (K, 3) themselves, or, with ``marker_radius`` > 0 (metres),
    each moved that far inward along the normal of ``current`` (V, 3) interpolated at its
    closest point (triangle ``face`` (K,), barycentric ``bary`` (K, 3)).
    """
    target = marker_pts
    if marker_radius > 0:
        normals = _vertex_normals(current, f)
        n_at = np.einsum("kc,kcx->kx", bary, normals[f[face]])
        n_at /= np.maximum(np.linalg.norm(n_at, axis=1, keepdims=True), 1e-12)
        target = marker_pts - marker_radius * n_at
    return target


def _closest_point_iterations(
    x: np.ndarray,
    f: np.ndarray,
    homog: np.ndarray,
    marker_pts: np.ndarray,
    base: sp.csr_matrix,
    base_rhs: np.ndarray,
    laplacian: sp.csr_matrix,
    identity: sp.csr_matrix,
    damping: float,
    s: RegistrationSettings,
    report: Progress,
) -> tuple[np.ndarray, int]:
    """Phase 2: all terms, closest points re-found every iteration.

    From the transforms ``x`` (4V, 3); ``marker_pts`` (K, 3) the seen markers, metres;
    ``base`` (4V, 4V) and ``base_rhs`` (4V, 3) the smoothness and landmark part of the
    normal equations, ``laplacian`` (V, V) the weighted graph Laplacian for the
    preconditioner. Returns the final X (4V, 3) and the iterations run (stops when no
    vertex moved more than ``s.tolerance`` metres).
    """
    n_v = homog.shape[0]
    iterations = 0
    n_iter = int(s.fit_iterations)
    precondition: _ComponentPreconditioner | None = None
    for it in range(n_iter):
        report(0.1 + 0.85 * it / max(n_iter, 1), f"closest-point iteration {it + 1}")
        current = _deformed(homog, x)
        _, face, bary = closest_points_on_mesh(current, f, marker_pts)
        target = _data_targets(current, f, face, bary, marker_pts, s.marker_radius)
        data_rows = _point_rows(f[face], bary, homog, n_v)
        normal = (base + s.data_weight * (data_rows.T @ data_rows) + damping * identity).tocsr()
        rhs = base_rhs + s.data_weight * (data_rows.T @ target) + damping * x
        if precondition is None or it % _REFACTOR_EVERY == 0:
            # the closest points drift slowly: the factors serve several iterations
            precondition = _ComponentPreconditioner(laplacian, normal, n_v)
        x_new = _solve_pcg(normal, rhs, x, precondition)
        moved = float(np.abs(_deformed(homog, x_new) - current).max())
        x = x_new
        iterations = it + 1
        if moved < s.tolerance:
            break
    return x, iterations


def _original_affines(x: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    """(V, 3, 4) per-vertex affines on the template's own coordinates (metres).

    ``x`` (4V, 3) acts on the normalised vertices ``(v - centre) / scale``; undoing the
    normalisation divides the linear part by ``scale`` and moves ``centre`` into the
    translation.
    """
    xs = x.reshape(-1, 4, 3)
    linear = np.swapaxes(xs[:, :3, :], 1, 2) / scale  # (V, 3, 3) acting on original coords
    translation = xs[:, 3, :] - np.einsum("vxk,k->vx", linear, centre)
    return np.concatenate([linear, translation[:, :, None]], axis=2)


# ------------------------------------------------------------------------ main
def register_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    markers: np.ndarray,
    labels: list[str],
    *,
    landmarks: dict[str, int] | None = None,
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
    settings : RegistrationSettings
        Weights and iterations.
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
    n_v = v.shape[0]
    seen = np.isfinite(m).all(axis=1)
    report = _reporter(progress)

    report(0.0, "landmarks")
    chosen, lm_marker, lm_vertex = _seen_landmarks(v, f, m, names, seen, landmarks)

    centre, scale, homog = _normalised_homogeneous(v)
    incidence = _edge_incidence(f, n_v)
    # Σ_edges |T_i - T_j|² = trace(Xᵀ (L ⊗ I4) X) with L the graph Laplacian.
    smooth = sp.kron(incidence.T @ incidence, sp.identity(4), format="csr")
    identity = sp.identity(4 * n_v, format="csr")

    lm_rows = _point_rows(lm_vertex[:, None], np.ones((lm_vertex.size, 1)), homog, n_v)
    lm_target = m[lm_marker]

    x = _template_transforms(n_v, centre, scale)

    s = settings
    laplacian = s.smoothness_weight * (incidence.T @ incidence).tocsr()
    base = s.smoothness_weight * smooth + s.landmark_weight * (lm_rows.T @ lm_rows)
    base_rhs = s.landmark_weight * (lm_rows.T @ lm_target)
    damping = max(s.damping, 1e-12)

    # Phase 1: landmarks and smoothness only (global placement and pose).
    report(0.05, "global fit")
    if lm_vertex.size:
        normal = (base + damping * identity).tocsr()
        x = _solve_pcg(
            normal, base_rhs + damping * x, x, _ComponentPreconditioner(laplacian, normal, n_v)
        )

    # Phase 2: all terms, equal weights, closest points re-found each iteration.
    marker_pts = m[seen]
    x, iterations = _closest_point_iterations(
        x, f, homog, marker_pts, base, base_rhs, laplacian, identity, damping, s, report
    )

    report(0.97, "distances")
    out = _deformed(homog, x)
    distance = np.full(m.shape[0], np.nan)
    distance[seen], _, _ = closest_points_on_mesh(out, f, marker_pts)
    affine = _original_affines(x, centre, scale)
    report(1.0, "registered")
    return Registration(
        vertices=out,
        affine=affine,
        landmarks={str(k): int(val) for k, val in chosen.items()},
        marker_distance=distance,
        iterations=iterations,
    )
