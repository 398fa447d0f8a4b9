"""Where the marker surface says each template vertex should be (registration's second data term).

Allen et al.'s data term pulls each *marker* to the template surface. Where markers
are sparse (about 5 cm apart on the limbs and the head of the dense layout) the
template is free between them, and a template fatter than the subject bulges out
between the markers it was pulled onto. This module gives the reverse term its
targets: each template vertex's closest point on the marker surface (the triangles
over the markers, :mod:`skincap.cleanup.surface` builds them), made smooth and moved
one marker radius inward.

The marker surface's flat triangles cut under a curved body by the sagitta (about 8 mm
across a 5 cm chord on a 4 cm forearm), so the target is the point of Phong
tessellation (Boubekeur & Alexa 2008) over the flat closest point: each corner's
tangent-plane projection, blended by the barycentric weights, then blended with the
flat point by the shape factor α. A fixed α = 1/2 lands on a circle through the
corners only to second order in the chord's angle (a flat chord misses it by
``r θ² / 2``); markers 4-6 cm apart on a limb or the head span angles where that
leaves the target millimetres under the skin, so each point takes the α that puts
it on the sphere (or cylinder) its corners' normals imply (:func:`phong_shape`). The
marker normals are Max's (1999) weighted averages, exact where a marker and its
neighbours lie on a sphere; given ``patch_ratio`` they are instead the mean outward
normal of the template's vertices within a patch around each marker
(:func:`template_patch_normals`): the lift is only as good as the corner normals, and a
marker's few neighbours on the marker surface (4-7 cm away, across a curved limb or a
foot) tilt Max's normal where the registered template, which passes through the
marker, has the body's own surface there.

Triangles with an edge over :data:`LONG_EDGE_RATIO` times the median edge bridge a gap
(arm to torso, leg to leg) and are dropped. A vertex gets no target (weight 0) where
the marker surface does not speak for it: its
closest point lies on the surface's border (hands, feet and the top of the head
beyond the last markers), it is farther than ``max_distance`` from it, or its normal
disagrees with the marker surface's there (the inside of an arm facing the torso).

Conventions: metres; ``marker_faces`` index the marker rows; NaN markers drop the
triangles that use them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

# the exact, vectorised point-triangle closest point (Ericson 5.1.5)
from skincap.geometry.raycast import _closest_on_triangles

__all__ = [
    "PHONG_SHAPE",
    "lift_normals",
    "marker_surface_normals",
    "marker_surface_targets",
    "phong_shape",
    "template_patch_normals",
]

#: Phong tessellation shape factor α: None (default) takes each point's α from its
#: corners' normals so that it lands on the sphere they imply (:func:`phong_shape`);
#: a number fixes it (1/2 is exact on a circle only in the limit of small angles
#: between the corner normals; 0 is the flat triangle).
PHONG_SHAPE: float | None = None

#: Least cosine between a vertex normal and the marker surface's normal at its target.
MIN_NORMAL_COSINE = 0.5

#: Template vertices nearest a marker triangle whose normals vote on its orientation.
ORIENTATION_VOTES = 8

#: Least cosine between two corner normals of the marker triangle under a vertex
#: (-1: no triangle dropped for its curvature; 0.5 costs the measured body pairs).
MIN_CORNER_COSINE = -1.0

#: Marker triangles with an edge longer than this many times the median edge are
#: dropped (gap-bridging triangles; inf: none dropped, as measured best on body pairs).
LONG_EDGE_RATIO = float("inf")

#: Nearest markers whose triangles are a point's candidates for its closest point.
CANDIDATE_MARKERS = 4

#: Markers whose distances set a marker's spacing for :func:`template_patch_normals`.
PATCH_SPACING_NEIGHBOURS = 4

#: Query points per block (bounds the candidate pairs' memory: ~25 per point).
_QUERY_BLOCK = 20000


def _face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) area-weighted (unnormalised) triangle normals."""
    p = points[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def phong_shape(bary: np.ndarray, corner_normals: np.ndarray) -> np.ndarray:
    """(K,) Phong shape factor that puts each point on the sphere its corners' normals imply.

    Phong tessellation with a fixed α is exact on a circle only as the angle between the
    corner normals goes to zero (α -> 1/2). Markers a few centimetres apart on a limb or
    a head span a large angle, where a flat-limit α leaves the point under the skin.
    For corners ``p_c = o + r n_c`` on a sphere (or a cylinder's cross-section) and a
    point with barycentric weights ``b``, the Phong point is ``o + r (N + α u)`` with
    ``N = Σ b_c n_c`` and ``u = Σ b_c (1 - N·n_c) n_c``, so ``|N + α u| = 1`` gives α
    from the normals alone, whatever ``r``. Clipped to [1/2, 1]; 1/2 where the normals
    agree (a flat patch: α does not matter there).

    Parameters
    ----------
    bary : (K, 3) float, barycentric weights
    corner_normals : (K, 3, 3) float, unit normals at each point's three corners
    """
    big_n = np.einsum("kc,kcx->kx", bary, corner_normals)  # (K, 3)
    gap = 1.0 - np.einsum("kx,kcx->kc", big_n, corner_normals)  # (K, 3)
    u = np.einsum("kc,kcx->kx", bary * gap, corner_normals)
    uu = np.einsum("kx,kx->k", u, u)
    nu = np.einsum("kx,kx->k", big_n, u)
    nn = np.einsum("kx,kx->k", big_n, big_n)
    disc = np.maximum(nu**2 - uu * (nn - 1.0), 0.0)
    ok = uu > 1e-12
    alpha = np.full(bary.shape[0], 0.5)
    alpha[ok] = (np.sqrt(disc[ok]) - nu[ok]) / uu[ok]
    return np.clip(alpha, 0.5, 1.0)


def marker_surface_normals(
    markers: np.ndarray,
    faces: np.ndarray,
    reference_points: np.ndarray,
    reference_normals: np.ndarray,
) -> np.ndarray:
    """(M, 3) unit outward normals at the markers, from a possibly unoriented triangulation.

    A marker surface built from a cloud need not be consistently oriented, so each
    triangle is turned to agree with the summed outward normals of the
    :data:`ORIENTATION_VOTES` nearest of ``reference_points`` (the template placed over
    the markers; a vote, so a stray normal does not turn it) before Max's (1999)
    weighted average at each marker (each triangle's corner cross product over the
    squared lengths of its two edges: exact for a marker whose neighbours lie on a
    sphere, however unevenly).

    Parameters
    ----------
    markers : (M, 3) float, metres (rows unused by ``faces`` may be NaN)
    faces : (F, 3) int, triangles over the marker rows, all finite
    reference_points : (V, 3) float, metres; reference_normals : (V, 3) unit outward normals

    Returns
    -------
    (M, 3) float64; zero for a marker in no triangle.
    """
    fn = _face_normals(markers, faces)
    centre = markers[faces].mean(axis=1)
    k = min(ORIENTATION_VOTES, reference_points.shape[0])
    _, nearest = cKDTree(reference_points).query(centre, k=k)
    vote = reference_normals[np.asarray(nearest).reshape(centre.shape[0], k)].sum(axis=1)
    flip = np.einsum("fx,fx->f", fn, vote) < 0
    fn[flip] *= -1.0
    # Max (1999): each corner's edge cross product over |e1|² |e2|², exact at a vertex
    # whose neighbours lie on a sphere, however unevenly; area weights tilt a marker's
    # normal toward its biggest triangles, and the Phong lift is only as good as these
    sign = np.where(flip, -1.0, 1.0)[:, None]
    normals = np.zeros_like(markers)
    for corner in range(3):
        p0 = markers[faces[:, corner]]
        e1 = markers[faces[:, (corner + 1) % 3]] - p0
        e2 = markers[faces[:, (corner + 2) % 3]] - p0
        w = np.einsum("fx,fx->f", e1, e1) * np.einsum("fx,fx->f", e2, e2)
        n_corner = sign * np.cross(e1, e2) / np.maximum(w, 1e-30)[:, None]
        np.add.at(normals, faces[:, corner], n_corner)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def template_patch_normals(
    markers: np.ndarray,
    used: np.ndarray,
    fallback: np.ndarray,
    reference_points: np.ndarray,
    reference_normals: np.ndarray,
    patch_ratio: float,
) -> np.ndarray:
    """(M, 3) unit normals at the markers: the mean normal of the template around each.

    Each used marker takes the normalised sum of the unit normals of the reference
    points (the template's vertices, placed over the markers) within a ball of radius
    ``patch_ratio`` times the marker's spacing (the median distance to its
    :data:`PATCH_SPACING_NEIGHBOURS` nearest used markers), so the patch scales with the
    layout's density; a marker with no reference point in its ball, or whose patch
    normals cancel, keeps its ``fallback`` normal.

    Parameters
    ----------
    markers : (M, 3) float, metres (rows not in ``used`` may be NaN)
    used : (U,) int, the marker rows in the triangulation
    fallback : (M, 3) float, unit normals (Max's, :func:`marker_surface_normals`)
    reference_points : (V, 3) float, metres; reference_normals : (V, 3) unit outward normals
    patch_ratio : float > 0, the patch radius in marker spacings

    Returns
    -------
    (M, 3) float64; ``fallback`` at the rows not in ``used``.
    """
    out = np.array(fallback, dtype=np.float64, copy=True)
    if used.size < 2 or reference_points.shape[0] == 0:
        return out
    centres = markers[used]
    k = min(PATCH_SPACING_NEIGHBOURS + 1, used.size)
    near = np.asarray(cKDTree(centres).query(centres, k=k)[0]).reshape(used.size, k)
    radius = patch_ratio * np.median(near[:, 1:], axis=1)  # (U,)
    pairs = cKDTree(centres).sparse_distance_matrix(
        cKDTree(reference_points), float(radius.max()), output_type="coo_matrix"
    )
    inside = pairs.data <= radius[pairs.row]
    total = np.zeros((used.size, 3))
    np.add.at(total, pairs.row[inside], reference_normals[pairs.col[inside]])
    length = np.linalg.norm(total, axis=1)
    ok = length > 1e-9 * np.maximum(np.bincount(pairs.row[inside], minlength=used.size), 1)
    out[used[ok]] = total[ok] / length[ok, None]
    return out


def _on_border(faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(K,) bool: the closest point lies on a border edge or border corner of the surface."""
    e = np.sort(np.concatenate([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]]), axis=1)
    key = e[:, 0] * (faces.max() + 1) + e[:, 1]
    uniq, count = np.unique(key, return_counts=True)
    border_edge = (
        (count == 1)[np.searchsorted(uniq, key)].reshape(3, -1).T
    )  # (F, 3) opposite corner c
    border_vertex = np.zeros(int(faces.max()) + 1, dtype=bool)
    border_vertex[e[(count == 1)[np.searchsorted(uniq, key)]].ravel()] = True
    zero = bary <= 1e-9  # (K, 3): on the edge opposite each zero corner
    on_edge = (zero & border_edge[face]).any(axis=1)
    at_corner = (zero.sum(axis=1) == 2) & border_vertex[faces[face, np.argmax(bary, axis=1)]]
    return on_edge | at_corner


def _closest_on_surface_near(
    markers: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point of each point among the triangles of its nearest markers.

    Not :func:`skincap.geometry.raycast.closest_points_on_mesh`: its exact candidate
    radius (nearest vertex + longest edge) holds hundreds of the marker surface's
    long triangles per point (4 CPU s per call on a 20k-vertex template, every
    iteration). The point nearest a surface lies, but for a surface folded back on
    itself, on a triangle of one of its few nearest vertices.

    Returns distance (K,), face (K,), barycentric weights (K, 3).
    """
    used = np.unique(faces)
    k = min(CANDIDATE_MARKERS, used.size)
    # marker -> incident faces as a padded table (pad: -1)
    order = np.argsort(faces.ravel(), kind="stable")
    owner = faces.ravel()[order]
    start = np.searchsorted(owner, np.arange(markers.shape[0]))
    count = np.bincount(owner, minlength=markers.shape[0])
    slot = np.arange(order.size) - start[owner]
    table = np.full((markers.shape[0], int(count.max())), -1, dtype=np.int64)
    table[owner, slot] = order // 3
    dist = np.empty(points.shape[0])
    face = np.empty(points.shape[0], dtype=np.int64)
    bary = np.empty((points.shape[0], 3))
    tree = cKDTree(markers[used])
    for s0 in range(0, points.shape[0], _QUERY_BLOCK):
        q = points[s0 : s0 + _QUERY_BLOCK]
        _, near = tree.query(q, k=k)
        cand = table[used[np.asarray(near).reshape(q.shape[0], k)]].reshape(q.shape[0], -1)
        row, col = np.nonzero(cand >= 0)
        fi = cand[row, col]
        corners = markers[faces[fi]]  # (P, 3, 3)
        bc = _closest_on_triangles(q[row], corners[:, 0], corners[:, 1], corners[:, 2])
        d = np.linalg.norm(np.einsum("pc,pcx->px", bc, corners) - q[row], axis=1)
        o = np.lexsort((d, row))  # best candidate of each point first
        first = o[np.r_[True, row[o][1:] != row[o][:-1]]]
        dist[s0 + row[first]] = d[first]
        face[s0 + row[first]] = fi[first]
        bary[s0 + row[first]] = bc[first]
    return dist, face, bary


def _usable_faces(markers: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(G', 3) the marker triangles the lift uses: all corners seen, no gap-bridging edge."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    f = f[np.isfinite(markers[f]).all(axis=(1, 2))]
    if f.shape[0] == 0:
        return f
    # a triangle much longer than its neighbours bridges a gap (arm to torso, leg to
    # leg) rather than covering skin: it is dropped, leaving a hole (a border)
    edge = np.linalg.norm(markers[f] - markers[np.roll(f, 1, axis=1)], axis=2)  # (G, 3)
    return f[edge.max(axis=1) <= LONG_EDGE_RATIO * np.median(edge)]


def _lift_normals(
    points: np.ndarray,
    point_normals: np.ndarray,
    markers: np.ndarray,
    faces: np.ndarray,
    patch_ratio: float,
) -> np.ndarray:
    """(M, 3) corner normals over usable ``faces``: Max's, or the template's patch mean."""
    normals = marker_surface_normals(markers, faces, points, point_normals)
    if patch_ratio > 0:
        used = np.unique(faces)
        normals = template_patch_normals(markers, used, normals, points, point_normals, patch_ratio)
    return normals


def lift_normals(
    points: np.ndarray,
    point_normals: np.ndarray,
    markers: np.ndarray,
    faces: np.ndarray,
    *,
    patch_ratio: float = 0.0,
) -> np.ndarray:
    """(M, 3) the normals at the markers that :func:`marker_surface_targets` lifts with.

    The same triangles (seen corners, no gap-bridging edge) and the same rule (Max's
    normals, or with ``patch_ratio`` > 0 the template's mean normal around each marker),
    so a measurement of these is a measurement of the registration's own.

    Parameters
    ----------
    points : (V, 3) float, metres; point_normals : (V, 3) unit outward normals
        The template where it is now (the registered mesh, after the registration).
    markers : (M, 3) float, metres (NaN rows: unseen)
    faces : (F, 3) int, marker-surface triangles over the marker rows
    patch_ratio : float, as :func:`marker_surface_targets`

    Returns
    -------
    (M, 3) float64 unit normals; zero for a marker in no usable triangle.
    """
    m = np.asarray(markers, dtype=np.float64)
    f = _usable_faces(m, faces)
    if f.shape[0] == 0:
        return np.zeros_like(m)
    p = np.asarray(points, dtype=np.float64)
    out = _lift_normals(p, np.asarray(point_normals, dtype=np.float64), m, f, patch_ratio)
    out[np.setdiff1d(np.arange(m.shape[0]), np.unique(f))] = 0.0
    return out


def marker_surface_targets(
    points: np.ndarray,
    point_normals: np.ndarray,
    markers: np.ndarray,
    faces: np.ndarray,
    *,
    marker_radius: float,
    max_distance: float,
    patch_ratio: float = 0.0,
    marker_normals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's target on the smoothed marker surface, and whether it has one.

    Parameters
    ----------
    points : (V, 3) float, metres
        The template's vertices where they are now.
    point_normals : (V, 3) float
        Their unit outward normals.
    markers : (M, 3) float, metres
        Marker centres; NaN rows drop every triangle using them.
    faces : (F, 3) int
        Marker-surface triangles over the marker rows.
    marker_radius : float, metres
        The skin lies this far inside the marker centres (along the surface normal).
    max_distance : float, metres
        Points farther than this from the marker surface get no target.
    patch_ratio : float, default 0
        0: the corner normals of the Phong lift are Max's, from the marker surface
        alone. > 0: they are the mean normals of ``points`` (the template placed over
        the markers) within this many marker spacings of each marker
        (:func:`template_patch_normals`).
    marker_normals : (M, 3) float, optional
        Unit outward normals at the markers that replace those above as the corner
        normals (a zero row keeps its marker's); for measuring what the normals cost
        (:func:`skincap.evaluate.registration.marker_surface_bound`).

    Returns
    -------
    targets : (V, 3) float64, metres
        The Phong-smoothed closest point less ``marker_radius`` along the normal there
        (the point itself where it has no target).
    valid : (V,) bool
        False where the marker surface does not speak for the point (see module doc).
    """
    p = np.asarray(points, dtype=np.float64)
    targets = p.copy()
    valid = np.zeros(p.shape[0], dtype=bool)
    m = np.asarray(markers, dtype=np.float64)
    f = _usable_faces(m, faces)
    if f.shape[0] == 0 or p.shape[0] == 0:
        return targets, valid
    normals = _lift_normals(p, point_normals, m, f, patch_ratio)
    if marker_normals is not None:
        given = np.asarray(marker_normals, dtype=np.float64)
        keep = np.linalg.norm(given, axis=1) > 0.5  # a zero row keeps the normal above
        normals[keep] = given[keep]
    dist, face, bary = _closest_on_surface_near(np.where(np.isfinite(m), m, 0.0), f, p)
    corners, corner_normals = m[f[face]], normals[f[face]]  # (V, 3, 3)
    flat = np.einsum("vc,vcx->vx", bary, corners)
    # Phong tessellation: the flat point projected on each corner's tangent plane, blended
    height = np.einsum("vcx,vcx->vc", flat[:, None, :] - corners, corner_normals)  # (V, 3)
    projected = flat[:, None, :] - height[:, :, None] * corner_normals
    alpha = phong_shape(bary, corner_normals) if PHONG_SHAPE is None else PHONG_SHAPE
    alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (p.shape[0],))[:, None]
    smooth = (1.0 - alpha) * flat + alpha * np.einsum("vc,vcx->vx", bary, projected)
    normal = np.einsum("vc,vcx->vx", bary, corner_normals)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    agree = np.einsum("vx,vx->v", normal, point_normals) >= MIN_NORMAL_COSINE
    # corners whose normals differ much: markers too sparse for the curvature, where
    # even the smoothed triangle passes under the skin (a thin limb's few markers)
    spread = np.einsum("vcx,vcx->vc", corner_normals, np.roll(corner_normals, 1, axis=1))
    gentle = spread.min(axis=1) >= MIN_CORNER_COSINE
    valid = (dist <= max_distance) & agree & gentle & ~_on_border(f, face, bary)
    targets[valid] = (smooth - marker_radius * normal)[valid]
    return targets, valid
