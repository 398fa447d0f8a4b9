"""Automatic skin weights by bone heat (Baran & Popovic 2007, "Automatic rigging and
animation of 3D characters", section 4) and influence limiting.

Bone heat treats the surface as a heat-conducting body: bone ``i`` heats the vertices
it is the nearest visible bone of, and the equilibrium temperature is the weight of
bone ``i``. For every bone the weights ``w_i`` (V,) solve

    (-Delta + H) w_i = H p_i                                  (Baran & Popovic, eq. 2)

with ``Delta = M^-1 L`` the discrete Laplace-Beltrami operator (cotangent Laplacian
``L``, mixed Voronoi mass matrix ``M``), ``H`` diagonal with ``H_jj = c / d(j)^2``
where ``d(j)`` is the distance from vertex ``j`` to its nearest visible bone (0 when
no bone is visible), and ``p_i[j] = 1`` when bone ``i`` is that bone. A bone is
*visible* from a vertex when the straight segment from the vertex to the closest
point of the bone does not cross the surface. ``c = 1``, as in the paper and in
Pinocchio and Blender (``heat_constant``). Bones at the same distance (within a
relative 1e-4, Blender's tolerance) share the vertex: ``p = 1/k`` each and
``H = k c / d^2``. The system is multiplied by ``M`` to be symmetric,
``(-L + M H) w = M H p``; it is factorised once and solved for all joints together.
Because the ``p`` rows sum to one, the weights are a partition of unity before they
are limited to the largest ``max_influences`` per vertex, clamped at zero and
renormalised.

Bones and joints. A bone is a segment from a joint (its *head*) to a child joint. The
weight of a bone is given to its head joint: a vertex of the upper arm is bound to the
shoulder joint (the joint whose rotation moves the upper arm), which is what
:class:`~skincap.types.Skin` and the deformers expect. A joint with several children
(pelvis, chest) owns several segments. Leaf joints (BVH end sites) own no segment and
get no weight, unless ``leaf_tails`` gives them one -- their rotation moves nothing in
a BVH. Give explicit segments with ``bones=`` for rigs whose bones are not
joint-to-child (MakeHuman's head-to-tail bones).

Components. A mesh in several pieces is solved as one block-diagonal system; a piece
from which no bone is visible falls back to its nearest bones without the visibility
test (otherwise its system would be singular), and so does a vertex in no triangle.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from skincap.errors import ValidationError
from skincap.geometry.laplacian import connected_components, cotangent_laplacian, vertex_areas
from skincap.geometry.raycast import TriangleGrid as _TriangleGrid
from skincap.geometry.raycast import (  # shared argument checks
    _mesh_arrays,
    _parents,
    _points,
    segments_cross_surface,
)
from skincap.types import Mesh

__all__ = [
    "bone_segments",
    "point_segment_distances",
    "segments_cross_surface",
    "bone_heat_weight_matrix",
    "bone_heat_weights",
    "limit_influences",
    "check_max_influences",
]

#: Relative distance tolerance under which two bones are equally near (Blender's).
TIE_TOLERANCE = 1e-4
#: Entries (vertices x joints, or bone segments) of the dense (V, J) tables bone heat
#: builds (distances, segment parameters, the weights): 2**25 float64 are 256 MB each.
#: A MakeHuman body is 13,380 x 163 = 2.2e6; a 600-vertex mesh with the 200,000 joints
#: of a hostile 8 MB BVH asked for 2.7 GB at once.
MAX_DENSE_ENTRIES = 2**25


# -------------------------------------------------------------------------- bones
def bone_segments(
    joint_positions: np.ndarray,
    parents: np.ndarray,
    *,
    leaf_tails: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bone segments of a skeleton and the joint each one belongs to.

    Parameters
    ----------
    joint_positions : (J, 3) float, metres
        World positions of the joints in the pose the mesh is in.
    parents : (J,) int
        Parent of each joint, -1 for a root, ``parents[j] < j``.
    leaf_tails : (J, 3) float, metres, optional
        Tail position of a bone for joints without children; rows of joints that
        have children are ignored, and NaN rows mean "no bone". Without it, leaf
        joints own no segment.

    Returns
    -------
    heads : (B, 3) float64, metres
        Start of each segment: the position of its joint.
    tails : (B, 3) float64, metres
        End of each segment: a child joint (or the leaf tail).
    joints : (B,) int64
        The joint each segment belongs to (its head): one segment per child, so a
        joint with several children owns several segments. Sorted by joint.
    """
    pos = _points("joint_positions", joint_positions)
    if not np.isfinite(pos).all():
        raise ValidationError("joint_positions: must be finite")
    par = _parents(parents, pos.shape[0])
    child = np.nonzero(par >= 0)[0]
    owner = par[child]
    heads = [pos[owner]]
    tails = [pos[child]]
    joints = [owner]
    if leaf_tails is not None:
        lt = _points("leaf_tails", leaf_tails, pos.shape[0])
        has_child = np.zeros(pos.shape[0], dtype=bool)
        has_child[owner] = True
        leaf = np.nonzero(~has_child & np.isfinite(lt).all(axis=1))[0]
        heads.append(pos[leaf])
        tails.append(lt[leaf])
        joints.append(leaf)
    h = np.concatenate(heads)
    t = np.concatenate(tails)
    j = np.concatenate(joints).astype(np.int64)
    order = np.argsort(j, kind="stable")
    return h[order], t[order], j[order]


def point_segment_distances(
    points: np.ndarray, heads: np.ndarray, tails: np.ndarray, *, chunk: int = 4096
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from every point to every segment, and the parameter of the closest point.

    Parameters
    ----------
    points : (N, 3) float
    heads, tails : (B, 3) float
        Segment end points (a zero-length segment is a point).
    chunk : int, default 4096
        Points per block (memory is ``chunk * B * 3`` floats).

    Returns
    -------
    dist : (N, B) float64
        Euclidean distances, unit of the inputs.
    param : (N, B) float64
        ``s`` in [0, 1]: the closest point is ``heads + s * (tails - heads)``.
    """
    p = _points("points", points)
    a = _points("heads", heads)
    b = _points("tails", tails, a.shape[0])
    ab = b - a  # (B, 3)
    len2 = np.einsum("bx,bx->b", ab, ab)
    safe = np.where(len2 > 0, len2, 1.0)
    dist = np.zeros((p.shape[0], a.shape[0]))
    param = np.zeros((p.shape[0], a.shape[0]))
    # points per block: at most `chunk`, and fewer for many segments so that a block's
    # (n, B, 3) temporaries stay near 2**22 entries (32 MB) each
    step = max(1, min(int(chunk), (1 << 22) // max(a.shape[0], 1)))
    for s in range(0, p.shape[0], step):
        ap = p[s : s + step, None, :] - a[None]  # (n, B, 3)
        u = np.clip(np.einsum("nbx,bx->nb", ap, ab) / safe, 0.0, 1.0)
        u[:, len2 == 0] = 0.0
        diff = ap - u[..., None] * ab[None]
        dist[s : s + step] = np.sqrt(np.einsum("nbx,nbx->nb", diff, diff))
        param[s : s + step] = u
    return dist, param


# ----------------------------------------------------------------------- weights
def _nearest_visible(
    v: np.ndarray,
    f: np.ndarray,
    heads: np.ndarray,
    tails: np.ndarray,
    *,
    visibility: bool,
    candidates: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per vertex: the candidate bones (V, C), their distances, and which share the heat.

    Returns ``cand`` (V, C) bone indices sorted by distance, ``dist`` (V, C),
    ``share`` (V, C) bool (the nearest visible bone and those tied with it) and
    ``nearest_any`` (V,) the nearest bone regardless of visibility.
    """
    n_v = v.shape[0]
    n_b = heads.shape[0]
    c = min(candidates, n_b)
    all_d, all_s = point_segment_distances(v, heads, tails)
    if c < n_b:
        cand = np.argpartition(all_d, c - 1, axis=1)[:, :c]
    else:
        cand = np.tile(np.arange(n_b), (n_v, 1))
    dist = np.take_along_axis(all_d, cand, axis=1)
    order = np.argsort(dist, axis=1, kind="stable")
    cand = np.take_along_axis(cand, order, axis=1)
    dist = np.take_along_axis(dist, order, axis=1)
    param = np.take_along_axis(all_s, cand, axis=1)
    if not visibility:
        # the nearest bone and those tied with it
        return cand, dist, dist <= dist[:, :1] * (1.0 + TIE_TOLERANCE), cand[:, 0].copy()

    grid = _TriangleGrid(v, f, None)
    visible = np.zeros((n_v, c), dtype=bool)
    best = np.full(n_v, np.inf)  # distance of the nearest visible bone so far
    for col in range(c):
        need = np.isinf(best) | (dist[:, col] <= best * (1.0 + TIE_TOLERANCE))
        rows = np.nonzero(need)[0]
        if rows.size == 0:
            break
        b = cand[rows, col]
        target = heads[b] + param[rows, col, None] * (tails[b] - heads[b])
        blocked = grid.crossed(v[rows], target, rows, 1_000_000)
        vis_rows = rows[~blocked]
        visible[vis_rows, col] = True
        best[vis_rows] = np.minimum(best[vis_rows], dist[vis_rows, col])
    share = visible & (dist <= best[:, None] * (1.0 + TIE_TOLERANCE))
    return cand, dist, share, cand[:, 0].copy()


def bone_heat_weight_matrix(
    mesh: Mesh | tuple[np.ndarray, np.ndarray],
    joint_positions: np.ndarray,
    parents: np.ndarray,
    *,
    bones: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    leaf_tails: np.ndarray | None = None,
    heat_constant: float = 1.0,
    visibility: bool = True,
    visibility_candidates: int = 4,
) -> np.ndarray:
    """Bone-heat weights of every joint at every vertex, before influence limiting.

    Parameters are those of :func:`bone_heat_weights` (without ``max_influences``).

    Returns
    -------
    (V, J) float64
        Weight of joint ``j`` at vertex ``v``; the rows sum to 1 (up to the solver's
        round-off); entries can be slightly negative or above 1 where the mesh has
        obtuse triangles (negative cotangents). Joints that own no bone have a zero
        column. No NaN.
    """
    v, f = _mesh_arrays(mesh)
    pos = _points("joint_positions", joint_positions)
    if not np.isfinite(pos).all():
        raise ValidationError("joint_positions: must be finite")
    n_j = pos.shape[0]
    par = _parents(parents, n_j)
    if bones is None:
        heads, tails, owner = bone_segments(pos, par, leaf_tails=leaf_tails)
    else:
        try:
            heads, tails, owner = bones
        except (TypeError, ValueError):
            raise ValidationError(
                "bones: expected a (heads (B, 3), tails (B, 3), joints (B,)) tuple"
            ) from None
        heads = _points("bones heads", heads)
        tails = _points("bones tails", tails, heads.shape[0])
        owner = np.asarray(owner)
        if owner.shape != (heads.shape[0],) or (
            owner.size and not np.issubdtype(owner.dtype, np.integer)
        ):
            raise ValidationError(
                f"bones joints: expected ({heads.shape[0]},) integers, got {owner.shape} {owner.dtype}"
            )
        owner = owner.astype(np.int64)
        if owner.size and (owner.min() < 0 or owner.max() >= n_j):
            raise ValidationError(f"bones joints: must index the {n_j} joints")
        if not (np.isfinite(heads).all() and np.isfinite(tails).all()):
            raise ValidationError("bones: segment ends must be finite")
    if heads.shape[0] == 0:
        raise ValidationError(
            "bones: the skeleton has no bone segment (a single joint, or only leaves without leaf_tails)"
        )
    c = float(heat_constant)
    if not (c > 0 and np.isfinite(c)):
        raise ValidationError(f"heat_constant: expected a positive number, got {heat_constant!r}")
    if int(visibility_candidates) < 1:
        raise ValidationError(
            f"visibility_candidates: expected a positive integer, got {visibility_candidates!r}"
        )
    n_v = v.shape[0]
    if n_v == 0:
        return np.zeros((0, n_j))
    width = max(n_j, heads.shape[0])
    if n_v * width > MAX_DENSE_ENTRIES:
        raise ValidationError(
            f"bone heat: {n_v} vertices x {width} joints is {n_v * width} weights in dense "
            f"(V, J) tables, more than the {MAX_DENSE_ENTRIES} it holds; give weights "
            "from a file or a skeleton with fewer joints"
        )

    cand, dist, share, nearest = _nearest_visible(
        v, f, heads, tails, visibility=bool(visibility), candidates=int(visibility_candidates)
    )
    n_comp, label = connected_components(f, n_v)
    in_face = np.zeros(n_v, dtype=bool)
    in_face[f.ravel()] = True
    # a piece that sees no bone at all, or a vertex in no face: nearest bones, no visibility
    comp_heated = np.zeros(n_comp, dtype=bool)
    comp_heated[label[share.any(axis=1)]] = True
    fallback = ~comp_heated[label] | ~in_face
    if fallback.any():
        rows = np.nonzero(fallback)[0]
        share[rows] = dist[rows] <= dist[rows, :1] * (1.0 + TIE_TOLERANCE)

    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    d_floor = 1e-4 * (diag if diag > 0 else 1.0)
    k = share.sum(axis=1)  # bones sharing each vertex
    d_near = np.where(share, dist, np.inf).min(axis=1)
    d_near = np.where(k > 0, np.maximum(d_near, d_floor), 1.0)
    heat = np.where(k > 0, c * k / d_near**2, 0.0)  # H_jj, 1 / m^2
    # p: each sharing bone's joint gets 1/k (joints owning several tied bones add up)
    rows, cols = np.nonzero(share)
    p = sp.coo_matrix((1.0 / k[rows], (rows, owner[cand[rows, cols]])), shape=(n_v, n_j)).tocsc()

    lap = cotangent_laplacian(v, f)
    area = vertex_areas(v, f)
    mh = area * heat  # (M H)_jj, dimensionless
    # A vertex in no face has no Laplacian row, and a piece whose heated vertices all
    # have zero area has no anchor: their equations become w = p ("pinned").
    comp_mass = np.zeros(n_comp)
    np.add.at(comp_mass, label, mh)
    pinned = ~in_face | (comp_mass[label] <= 0)
    free = (~pinned).astype(np.float64)
    a = (sp.diags(free) @ -lap + sp.diags(np.where(pinned, 1.0, mh))).tocsc()
    rhs_scale = np.where(pinned, 1.0, mh)
    used = np.unique(owner)
    rhs = p[:, used].multiply(rhs_scale[:, None]).toarray()  # (V, J_used)
    try:
        solver = spla.splu(
            a,
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    except RuntimeError as exc:  # singular factor: cannot happen after pinning
        raise ValidationError(f"mesh: the bone-heat system is singular ({exc})") from None
    out = np.zeros((n_v, n_j))
    out[:, used] = solver.solve(rhs)
    return out


def check_max_influences(max_influences: int) -> int:
    """``max_influences`` (joints per vertex) as an int >= 1, or a ValidationError."""
    m = int(max_influences)
    if m < 1:
        raise ValidationError(
            f"max_influences: expected a positive integer, got {max_influences!r}"
        )
    return m


def limit_influences(
    indices: np.ndarray, weights: np.ndarray, max_influences: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Keep the largest ``max_influences`` weights per vertex, clamp negatives, renormalise.

    Parameters
    ----------
    indices : (V, K) int
        Joint of each influence. Repeated joints in a row are merged (summed) first.
    weights : (V, K) float
        Weights; negative ones are set to 0. Must be finite.
    max_influences : int, default 4

    Returns
    -------
    indices : (V, K') int64, ``K' = min(K, max_influences)``
        Sorted by decreasing weight; unused slots hold joint 0 with weight 0.
    weights : (V, K') float64
        Non-negative, each row sums to 1. A row whose weights are all zero (or
        negative) keeps its first joint with weight 1.
    """
    idx = np.asarray(indices)
    w = np.asarray(weights, dtype=np.float64)
    if idx.ndim != 2 or w.shape != idx.shape:
        raise ValidationError(
            f"indices, weights: expected two (V, K) arrays of the same shape, got {idx.shape} and {w.shape}"
        )
    if idx.size and not np.issubdtype(idx.dtype, np.integer):
        raise ValidationError(f"indices: expected integers, got dtype {idx.dtype}")
    if not np.isfinite(w).all():
        raise ValidationError("weights: must be finite")
    m = check_max_influences(max_influences)
    idx = idx.astype(np.int64)
    n_v, k = w.shape
    k_out = min(k, m)
    if n_v == 0 or k == 0:
        return np.zeros((n_v, k_out), dtype=np.int64), np.zeros((n_v, k_out))
    w = np.maximum(w, 0.0)
    # merge repeated joints within a row: sort by joint, add runs into their first slot
    order = np.argsort(idx, axis=1, kind="stable")
    idx = np.take_along_axis(idx, order, axis=1)
    w = np.take_along_axis(w, order, axis=1)
    if k > 1:
        run_start = np.ones((n_v, k), dtype=bool)
        run_start[:, 1:] = idx[:, 1:] != idx[:, :-1]
        run_id = np.cumsum(run_start, axis=1) - 1
        merged = np.zeros((n_v, k))
        np.add.at(merged, (np.repeat(np.arange(n_v), k), run_id.ravel()), w.ravel())
        merged_idx = np.zeros((n_v, k), dtype=np.int64)
        merged_idx[np.repeat(np.arange(n_v), k), run_id.ravel()] = idx.ravel()
        idx, w = merged_idx, merged
    top = np.argsort(-w, axis=1, kind="stable")[:, :k_out]
    idx = np.take_along_axis(idx, top, axis=1)
    w = np.take_along_axis(w, top, axis=1)
    sums = w.sum(axis=1)
    empty = sums <= 0
    if empty.any():
        w[empty] = 0.0
        w[empty, 0] = 1.0
        idx[empty, 0] = np.asarray(indices)[empty, 0]
        sums[empty] = 1.0
    w = w / sums[:, None]
    idx = np.where(w > 0, idx, 0)
    return idx, w


def bone_heat_weights(
    mesh: Mesh | tuple[np.ndarray, np.ndarray],
    joint_positions: np.ndarray,
    parents: np.ndarray,
    *,
    max_influences: int = 4,
    bones: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    leaf_tails: np.ndarray | None = None,
    heat_constant: float = 1.0,
    visibility: bool = True,
    visibility_candidates: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Automatic skin weights by bone heat (Baran & Popovic 2007).

    Parameters
    ----------
    mesh : Mesh or (vertices (V, 3), faces (F, 3))
        Triangle mesh in metres, in the pose of ``joint_positions`` (bind pose).
        Ideally closed (the visibility test looks for the surface between a vertex
        and a bone); several pieces are fine.
    joint_positions : (J, 3) float, metres
        World positions of the joints in that pose. Must be finite.
    parents : (J,) int
        Parent of each joint, -1 for a root, ``parents[j] < j``.
    max_influences : int, default 4
        Joints kept per vertex (the largest weights, renormalised).
    bones : (heads (B, 3), tails (B, 3), joints (B,)), optional
        Explicit bone segments (metres) and the joint each belongs to; default
        :func:`bone_segments` (joint to each child; the weight goes to the bone's
        head joint, e.g. the upper arm to the shoulder joint).
    leaf_tails : (J, 3) float, metres, optional
        Give leaf joints a bone from the joint to this point (see
        :func:`bone_segments`). Ignored when ``bones`` is given.
    heat_constant : float, default 1.0
        ``c`` in ``H_jj = c / d(j)^2``. Larger values keep weights closer to the
        nearest bone; smaller values smooth them further.
    visibility : bool, default True
        Only bones visible from a vertex heat it. False: the nearest bone always.
    visibility_candidates : int, default 4
        Nearest bones tested for visibility per vertex, in order of distance; a
        vertex that sees none of them gets no heat and takes its weights from the
        surface around it.

    Returns
    -------
    indices : (V, K) int64, ``K = min(max_influences, J)``
        Joints influencing each vertex, by decreasing weight; unused slots hold
        joint 0 with weight 0.
    weights : (V, K) float64
        Non-negative, each row sums to 1. No NaN.

    Raises
    ------
    ValidationError
        Shapes or values are wrong, or the skeleton has no bone segment.

    Examples
    --------
    >>> import trimesh
    >>> tube = trimesh.creation.cylinder(radius=0.05, height=1.0, sections=24)
    >>> joints = np.array([[0.0, 0.0, -0.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.5]])
    >>> idx, w = bone_heat_weights((tube.vertices, tube.faces), joints, [-1, 0, 1], max_influences=2)
    >>> bool(np.allclose(w.sum(axis=1), 1.0))
    True
    """
    m = check_max_influences(max_influences)
    dense = bone_heat_weight_matrix(
        mesh,
        joint_positions,
        parents,
        bones=bones,
        leaf_tails=leaf_tails,
        heat_constant=heat_constant,
        visibility=visibility,
        visibility_candidates=visibility_candidates,
    )
    n_v, n_j = dense.shape
    k = min(m, n_j)
    if n_v == 0:
        return np.zeros((0, k), dtype=np.int64), np.zeros((0, k))
    dense = np.maximum(dense, 0.0)
    if k < n_j:
        top = np.argpartition(-dense, k - 1, axis=1)[:, :k]
    else:
        top = np.tile(np.arange(n_j), (n_v, 1))
    w = np.take_along_axis(dense, top, axis=1)
    empty = w.sum(axis=1) <= 0
    if empty.any():
        # cannot happen for a partition of unity; guard against round-off anyway
        best = np.argmax(dense[empty], axis=1)
        top[empty, 0] = best
        w[empty] = 0.0
        w[empty, 0] = 1.0
    return limit_influences(top, w, k)
