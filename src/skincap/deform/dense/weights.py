"""Marker and vertex part weights (Park & Hodgins 2006, §5.2).

Marker weights α (N, P): a marker inside a part weighs 1 for it. A marker on the
boundary between parts (its marker-surface triangles, or its neighbours, belong to
several parts) is compared with the rigid motion of each neighbouring part, defined by
that part's inside markers: its RMS distance ``e_p`` from where the part's rigid motion
carries its reference position. A Gaussian model turns the errors into likelihoods,
``ℓ_p ∝ exp(-e_p² / 2 s_p²)`` with ``s_p`` the RMS error of the part's own inside markers
under its rigid motion (how rigid the part is; floored at ``noise_floor``, since a
perfectly rigid synthetic part would make every assignment hard), normalised over the
candidate parts; a part is kept when its likelihood exceeds 0.2 (the paper's threshold)
and the kept ones are normalised again.

Blend weights (the default of :func:`skincap.deform.dense.rig.build_dense_rig`): where
the skin between two parts moves as a blend of both (a shoulder, a hip), a Gaussian
choice of parts leaves the vertices between them following one part's motion too far.
:func:`marker_blend_weights` instead fits every boundary marker, over the whole
range-of-motion take, as the convex combination of its candidate parts' rigid motions
that reproduces its trajectory best (the least-squares skinning weights James & Twigg
2005 fit per vertex, here per marker): ``min_w Σ_t ||x_i(t) - Σ_p w_p T_p(t) x_i⁰||²``
with ``w ≥ 0, Σ w = 1``; the candidates are the parts of the marker's triangles and of
its surface neighbours' (:func:`spread_candidates`), so a marker one row away from a
seam can still blend. On the synthetic jumprope take (240 frames, ROM of 240 frames,
5000 vertices, automatic parts) the ``quadratic_rbf`` vertex RMS goes from 3.00 mm
(Gaussian, triangle candidates) to 2.65 mm.

Vertex weights β (V, P): each vertex of the detailed mesh takes the weights of the
three markers of the nearest marker-surface triangle, interpolated at the barycentric
coordinates of its projection. That triangle speaks for a point only near it: on a
sparse capture (a few dozen markers, a marker surface over the trunk and legs only) a
point of the forearm, or a held-out wrist marker, lies far from every triangle, and its
nearest one belongs to another part. Beyond the triangle's reach (one local marker
spacing, and no farther than the nearest marker) a point therefore fades, by twice that
distance, to the inverse-distance blend of its nearest markers' weights
(:func:`surface_interpolation`); a point within reach keeps the paper's weights exactly.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from skincap.errors import ValidationError
from skincap.geometry.raycast import closest_points_on_mesh
from skincap.geometry.rigid import fit_rigid
from skincap.geometry.simplex import simplex_least_squares

__all__ = [
    "candidates_from_marker_parts",
    "candidates_from_triangle_parts",
    "marker_blend_weights",
    "marker_part_weights",
    "part_motion_errors",
    "seam_vertex_weights",
    "spread_candidates",
    "surface_interpolation",
    "vertex_part_weights",
]

#: Likelihood above which a boundary marker joins a part (Park & Hodgins: 0.2).
WEIGHT_THRESHOLD = 0.2

#: Markers a point beyond its nearest triangle's reach takes its weights from.
NEAREST_MARKERS = 3


def candidates_from_triangle_parts(
    faces: np.ndarray, triangle_parts: np.ndarray, n_markers: int, n_parts: int | None = None
) -> np.ndarray:
    """Which parts each marker touches: the parts of its marker-surface triangles.

    Parameters
    ----------
    faces : (F, 3) int, marker indices
    triangle_parts : (F,) int, part of every triangle (-1 = none)
    n_markers : int
    n_parts : int, optional (default ``triangle_parts.max() + 1``)

    Returns
    -------
    (N, P) bool
        A marker on no labelled triangle has no candidate (all False).
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    tp = np.asarray(triangle_parts, dtype=np.int64)
    if tp.shape != (f.shape[0],):
        raise ValidationError(f"triangle_parts must have shape ({f.shape[0]},); got {tp.shape}")
    n_p = int(tp.max()) + 1 if n_parts is None else int(n_parts)
    out = np.zeros((int(n_markers), n_p), dtype=bool)
    keep = tp >= 0
    out[f[keep].ravel(), np.repeat(tp[keep], 3)] = True
    return out


def candidates_from_marker_parts(
    marker_parts: np.ndarray, edges: np.ndarray, n_parts: int | None = None
) -> np.ndarray:
    """Which parts each marker touches: its own and those of its surface neighbours.

    Parameters
    ----------
    marker_parts : (N,) int, part of every marker (-1 = none)
    edges : (E, 2) int, marker-surface edges
    n_parts : int, optional

    Returns
    -------
    (N, P) bool
    """
    mp = np.asarray(marker_parts, dtype=np.int64)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    n_p = int(mp.max()) + 1 if n_parts is None else int(n_parts)
    out = np.zeros((mp.size, n_p), dtype=bool)
    own = mp >= 0
    out[np.flatnonzero(own), mp[own]] = True
    for a, b in ((0, 1), (1, 0)):  # both directions of every edge
        src, dst = e[:, a], e[:, b]
        ok = mp[dst] >= 0
        out[src[ok], mp[dst[ok]]] = True
    return out


def spread_candidates(candidates: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Every marker also takes the candidate parts of its marker-surface neighbours.

    Parameters
    ----------
    candidates : (N, P) bool
    faces : (F, 3) int, marker-surface triangles

    Returns
    -------
    (N, P) bool
    """
    cand = np.asarray(candidates, dtype=bool)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    out = cand.copy()
    for a, b in ((0, 1), (1, 2), (2, 0), (1, 0), (2, 1), (0, 2)):  # both ways of each edge
        out[f[:, a]] |= cand[f[:, b]]
    return out


def _fit_part_motions(
    x: np.ndarray, ref: np.ndarray, members: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motion reference -> frame t of every part from its members: (T, P, 3, 3), (T, P, 3)."""
    few = members.sum(axis=0) < 3
    if few.any():
        raise ValidationError(
            f"members: parts {np.flatnonzero(few).tolist()} have fewer than three markers"
        )
    return fit_rigid(ref[None, None], x[:, None], members.T[None])


def marker_blend_weights(
    positions: np.ndarray,
    reference: np.ndarray,
    members: np.ndarray,
    candidates: np.ndarray,
    *,
    max_candidates: int = 5,
    min_weight: float = 0.02,
) -> np.ndarray:
    """Marker weights α as least-squares blends of the candidate parts' rigid motions.

    Every part's rigid motion (reference -> frame t) is fitted to its ``members``; a
    marker with one candidate weighs 1 for it; any other takes the convex weights
    ``w`` over its candidates that minimise ``Σ_t ||x(t) - Σ_p w_p (R_p(t) x⁰ + d_p(t))||²``
    over the frames it is measured in (exactly, :func:`skincap.geometry.simplex.simplex_least_squares`). A
    marker rigidly on one part gets that part alone; one moving halfway between two
    parts gets one half each.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
        The take the weights are learnt from (the range of motion).
    reference : (N, 3) float, metres
    members : (N, P) bool
        Markers the parts' rigid motions are fitted to (a part needs three).
    candidates : (N, P) bool
        Parts a marker may blend; a marker with none is compared with every part.
    max_candidates : int
        A marker keeps at most this many candidates, those whose rigid motion alone
        follows it best (the exact solve tries every subset: 2^k).
    min_weight : float
        Smaller blend weights are dropped and the row renormalised: a marker with any
        weight for a part is one of the part's members, whose RBF must reproduce it
        exactly, so a marker that follows another part must not join for a sliver.

    Returns
    -------
    (N, P) float64
        Rows sum to 1.

    Raises
    ------
    ValidationError
        Shapes, or a part with fewer than three members.
    """
    x = np.asarray(positions, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    mem = np.asarray(members, dtype=bool)
    cand = np.asarray(candidates, dtype=bool)
    if x.ndim != 3 or x.shape[2] != 3 or ref.shape != x.shape[1:]:
        raise ValidationError(
            f"positions (T, N, 3) and reference (N, 3) expected; got {x.shape} and {ref.shape}"
        )
    if mem.shape != cand.shape or cand.ndim != 2 or cand.shape[0] != ref.shape[0]:
        raise ValidationError(
            f"members and candidates must have shape ({ref.shape[0]}, P); "
            f"got {mem.shape} and {cand.shape}"
        )
    n, n_p = cand.shape
    cand = cand | (cand.sum(axis=1) == 0)[:, None]  # no candidate: every part is one
    rot, trans = _fit_part_motions(x, ref, mem)  # (T, P, 3, 3), (T, P, 3)
    k = int(min(max(1, int(max_candidates)), cand.sum(axis=1).max()))
    # each marker's k best candidates by their single-part error, padded
    single = part_motion_errors(x, ref, rot, trans, cand)  # (N, P), inf off-candidate
    order = np.argsort(single, axis=1, kind="stable")[:, :k]  # (N, k)
    usable = np.take_along_axis(cand & np.isfinite(single), order, axis=1)
    usable[:, 0] = True  # the best one (a marker never seen keeps its first candidate)
    pred = np.einsum("tnkab,nb->tnka", rot[:, order], ref) + trans[:, order]  # (T, N, k, 3)
    resid = pred - x[:, :, None, :]
    seen = np.isfinite(resid).all(axis=(-1, -2))  # (T, N)
    resid = np.where(seen[..., None, None], resid, 0.0)
    gram = np.einsum("tnka,tnla->nkl", resid, resid) / np.maximum(seen.sum(0), 1)[:, None, None]
    w = simplex_least_squares(gram, usable)
    alpha = np.zeros((n, n_p))
    np.put_along_axis(alpha, order, np.where(usable, w, 0.0), axis=1)
    alpha = np.where(alpha >= float(min_weight), alpha, 0.0)
    alpha[np.arange(n), order[:, 0]] += (alpha.sum(axis=1) == 0).astype(np.float64)
    return alpha / alpha.sum(axis=1, keepdims=True)


def part_motion_errors(
    positions: np.ndarray,
    reference: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    pairs: np.ndarray,
) -> np.ndarray:
    """Mean squared distance of markers from where parts' rigid motions carry them.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    reference : (N, 3) float, metres
    rotation : (T, P, 3, 3) float, reference -> frame t (NaN where a part is unfitted)
    translation : (T, P, 3) float, metres
    pairs : (N, P) bool
        The (marker, part) pairs to measure.

    Returns
    -------
    (N, P) float64, m²
        Over the frames where both the marker and the part are; inf off ``pairs`` and
        where there is no such frame.
    """
    x, ref, rot, trans, cand = positions, reference, rotation, translation, pairs
    n, n_p = cand.shape
    marker_of, part_of = np.nonzero(cand)
    predicted = np.einsum("tnab,nb->tna", rot[:, part_of], ref[marker_of]) + trans[:, part_of]
    sq = ((predicted - x[:, marker_of]) ** 2).sum(-1)  # (T, pairs)
    seen = np.isfinite(sq)
    count = seen.sum(axis=0)
    err = np.full((n, n_p), np.inf)
    err[marker_of, part_of] = np.where(
        count > 0, np.where(seen, sq, 0.0).sum(axis=0) / np.maximum(count, 1), np.inf
    )
    return err


def marker_part_weights(
    positions: np.ndarray,
    reference: np.ndarray,
    candidates: np.ndarray,
    *,
    threshold: float = WEIGHT_THRESHOLD,
    noise_floor: float = 0.001,
) -> np.ndarray:
    """Marker weights α: 1 inside a part, Gaussian likelihoods on the boundaries.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
        The take the weights are learnt from (the range of motion).
    reference : (N, 3) float, metres
        Reference pose.
    candidates : (N, P) bool
        Parts each marker touches; exactly one = inside that part. A marker with none
        is compared with every part.
    threshold : float
        Likelihood a part must exceed to keep a boundary marker (0.2).
    noise_floor : float, metres
        Smallest Gaussian scale ``s_p``.

    Returns
    -------
    (N, P) float64
        Rows sum to 1.

    Raises
    ------
    ValidationError
        Shapes, or a part with fewer than three markers it could be fitted from.
    """
    x = np.asarray(positions, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    cand = np.asarray(candidates, dtype=bool)
    if x.ndim != 3 or x.shape[2] != 3 or ref.shape != x.shape[1:]:
        raise ValidationError(
            f"positions (T, N, 3) and reference (N, 3) expected; got {x.shape} and {ref.shape}"
        )
    if cand.ndim != 2 or cand.shape[0] != ref.shape[0]:
        raise ValidationError(f"candidates must have shape ({ref.shape[0]}, P); got {cand.shape}")
    n, n_p = cand.shape
    orphan = ~cand.any(axis=1)
    cand = cand | orphan[:, None]
    inside = cand & (cand.sum(axis=1) == 1)[:, None]  # (N, P)
    fit_from = np.where((inside.sum(axis=0) >= 3)[None, :], inside, cand & ~orphan[:, None])
    few = fit_from.sum(axis=0) < 3
    if few.any():
        raise ValidationError(
            f"candidates: parts {np.flatnonzero(few).tolist()} have fewer than three markers"
        )
    # rigid motion of every part from its inside markers: reference -> frame t
    rot, trans = fit_rigid(ref[None, None], x[:, None], fit_from.T[None])  # (T, P, 3, 3), (T, P, 3)
    # only the (marker, part) pairs that matter: candidates and the fitting markers
    err2 = part_motion_errors(x, ref, rot, trans, cand | fit_from)
    own = np.where(fit_from, err2, np.nan)
    with np.errstate(invalid="ignore"):
        scale2 = np.nanmean(np.where(np.isfinite(own), own, np.nan), axis=0)  # (P,)
    scale2 = np.maximum(np.where(np.isfinite(scale2), scale2, 0.0), float(noise_floor) ** 2)
    logit = np.where(cand, -err2 / (2.0 * scale2[None, :]), -np.inf)
    logit = logit - logit.max(axis=1, keepdims=True)
    like = np.exp(logit)
    like /= like.sum(axis=1, keepdims=True)
    like = np.where(like > float(threshold), like, 0.0)
    # the best part always stays (a likelihood spread over > 5 parts may leave none)
    best = np.argmax(np.where(cand, -err2 / scale2[None, :], -np.inf), axis=1)
    like[np.arange(n), best] = np.maximum(like[np.arange(n), best], 1e-12)
    alpha = like / like.sum(axis=1, keepdims=True)
    alpha[inside.any(axis=1)] = inside[inside.any(axis=1)].astype(np.float64)
    return alpha


def surface_interpolation(
    points: np.ndarray,
    surface_vertices: np.ndarray,
    surface_faces: np.ndarray,
    *,
    n_nearest: int = NEAREST_MARKERS,
) -> tuple[np.ndarray, np.ndarray]:
    """How each point interpolates per-marker values: markers and their weights.

    A point near the marker surface takes the barycentric coordinates of its projection
    on the nearest triangle (Park & Hodgins §5.2). That triangle's reach is
    ``r = min(h, d_nn)``: ``h`` the local marker spacing (the mean edge length of that
    triangle) and ``d_nn`` the distance to the nearest marker (a marker on no triangle,
    such as a forearm marker of a sparse set, may be nearer than the surface). A point
    within ``r`` of the triangle keeps its barycentric coordinates exactly; farther, it
    blends towards the inverse-distance weights of its ``n_nearest`` markers, smoothly
    (a smoothstep of ``(d - r) / r``), wholly from ``2 r`` on, so the weights of a mesh
    stay continuous. Without triangles, every point takes its nearest markers.

    Parameters
    ----------
    points : (V, 3) float, metres
    surface_vertices : (N, 3) float, metres
        The markers in the reference pose; NaN rows (missing markers) are not used.
    surface_faces : (F, 3) int
    n_nearest : int
        Markers of the inverse-distance blend.

    Returns
    -------
    markers : (V, 3 + k) int64
        Marker indices: the nearest triangle's three, then the ``k`` nearest markers
        (``k = min(n_nearest, usable markers)``; without triangles only those ``k``).
    weights : (V, 3 + k) float64
        Rows sum to 1; a value per marker ``values (N, ...)`` interpolates as
        ``einsum("vk,vk...->v...", weights, values[markers])``.

    Raises
    ------
    ValidationError
        No usable marker.
    """
    v = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sv = np.asarray(surface_vertices, dtype=np.float64)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    usable = np.isfinite(sv).all(axis=1)
    idx = np.flatnonzero(usable)
    if idx.size == 0:
        raise ValidationError("surface_vertices: no marker is present")
    k = int(min(max(1, int(n_nearest)), idx.size))
    inverse, near, d_nn = _nearest_marker_weights(v, sv[idx], k)
    near = idx[near]  # (V, k)
    f = f[usable[f].all(axis=1)]
    if f.shape[0] == 0:
        return near, inverse
    d_tri, face, bary = closest_points_on_mesh(np.where(usable[:, None], sv, 0.0), f, v)
    corners = f[face]  # (V, 3)
    p = sv[corners]  # (V, 3, 3)
    spacing = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=-1).mean(axis=1)  # h, (V,)
    reach = np.minimum(spacing, d_nn)  # r
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.clip((d_tri - reach) / reach, 0.0, 1.0)
    u = np.where(reach > 0, u, (d_tri > 0).astype(np.float64))  # on a marker off the surface
    far = u * u * (3.0 - 2.0 * u)  # smoothstep: 0 within reach, 1 from twice it
    weights = np.concatenate([bary * (1.0 - far)[:, None], inverse * far[:, None]], axis=1)
    return np.concatenate([corners, near], axis=1), weights


def _nearest_marker_weights(
    points: np.ndarray, markers: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse-distance weights (V, k) over each point's ``k`` nearest markers, their
    indices (V, k) and the nearest distance (V,), metres.

    The weights are ``1/d_i - 1/d_(k+1)`` (``d_(k+1)`` the next marker's distance), not
    ``1/d_i``: a marker leaves a point's k nearest with weight 0, so the weights change
    continuously over space (plain k-nearest inverse distance jumps where the set of
    nearest markers changes, a tear in a mesh's weights).
    """
    n = markers.shape[0]
    q = min(k + 1, n)
    d, nn = cKDTree(markers).query(points, k=q)
    d = d.reshape(points.shape[0], q)
    nn = nn.reshape(points.shape[0], q)
    inverse = 1.0 / np.maximum(d, 1e-9)
    if q > k:
        inverse = inverse[:, :k] - inverse[:, k:]
    tied = inverse.sum(axis=1) <= 0  # the k + 1 nearest all equally far: share equally
    inverse[tied] = 1.0
    return inverse / inverse.sum(axis=1, keepdims=True), nn[:, :k], d[:, 0]


def vertex_part_weights(
    vertices: np.ndarray,
    surface_vertices: np.ndarray,
    surface_faces: np.ndarray,
    marker_weights: np.ndarray,
) -> np.ndarray:
    """Vertex weights β: the marker weights interpolated on the nearest surface triangle.

    A vertex beyond that triangle's reach takes its nearest markers' weights instead
    (:func:`surface_interpolation`).

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The detailed mesh in the reference pose.
    surface_vertices : (N, 3) float, metres
        The markers in the reference pose (the marker surface's vertices).
    surface_faces : (F, 3) int
        Marker-surface triangles. With none, a vertex takes the inverse-distance blend
        of its three nearest markers' weights.
    marker_weights : (N, P) float
        α.

    Returns
    -------
    (V, P) float64
        Rows sum to 1.
    """
    v = np.asarray(vertices, dtype=np.float64)
    sv = np.asarray(surface_vertices, dtype=np.float64)
    alpha = np.asarray(marker_weights, dtype=np.float64)
    if alpha.shape[0] != sv.shape[0]:
        raise ValidationError(
            f"marker_weights has {alpha.shape[0]} rows for {sv.shape[0]} surface vertices"
        )
    markers, w = surface_interpolation(v, sv, surface_faces)
    beta = np.einsum("vk,vkp->vp", w, alpha[markers])
    beta = np.clip(beta, 0.0, None)
    return beta / beta.sum(axis=1, keepdims=True)


def seam_vertex_weights(
    vertices: np.ndarray,
    surface_vertices: np.ndarray,
    surface_faces: np.ndarray,
    members: np.ndarray,
) -> np.ndarray:
    """How much each vertex follows each part's field through its seam centres.

    A part's seam centres (the markers one marker-surface edge beyond its members,
    :func:`skincap.deform.dense.parts.part_frames`) carry its field across its seam,
    but they also pull on it inside the part, where the members alone describe the
    skin exactly. So a marker at a seam of part ``p`` (a seam centre of ``p``, or a
    member of ``p`` with one as a neighbour) weighs 1, any other 0, and every vertex
    takes these values interpolated at the barycentric coordinates of its projection
    on the nearest marker-surface triangle, as β is (:func:`vertex_part_weights`, also
    beyond the triangle's reach): 1 on the triangles of a seam, 0 inside a part,
    continuous across every edge.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    surface_vertices : (N, 3) float, metres, the markers in the reference pose
    surface_faces : (F, 3) int
    members : (N, P) bool
        The members of every part (α > 0).

    Returns
    -------
    (V, P) float64 in [0, 1]
    """
    v = np.asarray(vertices, dtype=np.float64)
    sv = np.asarray(surface_vertices, dtype=np.float64)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    mem = np.asarray(members, dtype=bool)
    if mem.ndim != 2 or mem.shape[0] != sv.shape[0]:
        raise ValidationError(f"members must have shape ({sv.shape[0]}, P); got {mem.shape}")
    usable = np.isfinite(sv).all(axis=1)
    f = f[usable[f].all(axis=1)]
    if f.shape[0] == 0:
        return np.zeros((v.shape[0], mem.shape[1]))
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])  # both ways
    beyond = np.zeros_like(mem)  # seam centres: a neighbour is a member, it is not
    np.logical_or.at(beyond, edges[:, 0], mem[edges[:, 1]])
    beyond &= ~mem
    at_seam = beyond.copy()  # and the members next to one
    np.logical_or.at(at_seam, edges[:, 0], beyond[edges[:, 1]] & mem[edges[:, 0]])
    markers, w = surface_interpolation(v, sv, f)
    weights = np.einsum("vk,vkp->vp", w, at_seam[markers].astype(np.float64))
    return np.clip(weights, 0.0, 1.0)
