"""Isosurfaces of sampled scalar fields: marching tetrahedra, welding and relaxation.

:func:`marching_tetrahedra` extracts the zero set of a field sampled on a regular
grid. Every grid cube is split into the six tetrahedra of the Kuhn (Freudenthal)
triangulation, which share the cube's main diagonal; the split is the same in every
cube, so neighbouring cubes agree on their shared face diagonals and the tetrahedra
form one simplicial complex. Inside each tetrahedron the field is linear, so its
zero set is one triangle (one corner on the other side) or one quad (two and two).
Each surface vertex lies on a grid edge crossing the level and is keyed by that
edge, so neighbouring cells share it: the result is welded, closed and 2-manifold
wherever the field is negative only away from the grid border (the border is
treated as outside). Triangles are oriented counter-clockwise seen from the
positive side (outward for a field negative inside).

:func:`relax_on_isosurface` then improves the triangles (marching tetrahedra leaves
slivers where the level passes close to grid nodes): uniform Laplacian steps
alternate with a projection back onto the zero set of the trilinearly interpolated
field, so the vertices spread evenly without leaving the surface.
:func:`taubin_smooth` is the classic λ|μ low-pass filter (Taubin 1995).

The grid is in index space scaled by ``spacing`` and shifted by ``origin`` (metres
inside skincap). Fields must be finite.
"""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp
from scipy.ndimage import map_coordinates

from skincap.errors import ValidationError

__all__ = [
    "marching_tetrahedra",
    "relax_on_isosurface",
    "taubin_smooth",
    "uniform_adjacency",
]

# the 6 Kuhn tetrahedra of the unit cube: corner bit i = offset along axis i
_TETS = np.array(
    [[0, 1 << a, (1 << a) | (1 << b), 7] for a, b, _ in itertools.permutations(range(3))],
    dtype=np.int64,
)
_CORNERS = np.array([[(c >> i) & 1 for i in range(3)] for c in range(8)], dtype=np.int64)


def _case_table() -> tuple[np.ndarray, np.ndarray]:
    """Per inside-mask (16 cases): up to 2 triangles as triples of tet edges (a, b)."""
    tris = np.full((16, 2, 3, 2), -1, dtype=np.int64)
    count = np.zeros(16, dtype=np.int64)
    for mask in range(1, 15):
        ins = [i for i in range(4) if mask >> i & 1]
        out = [i for i in range(4) if not mask >> i & 1]
        if len(ins) in (1, 3):
            s, others = (ins[0], out) if len(ins) == 1 else (out[0], ins)
            tris[mask, 0] = [[s, o] for o in others]
            count[mask] = 1
        else:
            i0, i1 = ins
            o0, o1 = out
            quad = [[i0, o0], [i0, o1], [i1, o1], [i1, o0]]  # a cycle around the quad
            tris[mask, 0] = [quad[0], quad[1], quad[2]]
            tris[mask, 1] = [quad[0], quad[2], quad[3]]
            count[mask] = 2
    return tris, count


_TRIS, _TRI_COUNT = _case_table()


def _check_field(values: object) -> np.ndarray:
    try:
        f = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValidationError("values: expected a 3-D float array") from None
    if f.ndim != 3 or min(f.shape) < 2:
        raise ValidationError(f"values: expected shape (nx, ny, nz) with each >= 2, got {f.shape}")
    if not np.isfinite(f).all():
        raise ValidationError("values: must be finite")
    return f


def _check_grid(origin: object, spacing: float) -> tuple[np.ndarray, float]:
    o = np.asarray(origin, dtype=np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise ValidationError(f"origin: expected 3 finite numbers, got shape {o.shape}")
    h = float(spacing)
    if not np.isfinite(h) or h <= 0:
        raise ValidationError(f"spacing: expected a positive grid step, got {spacing!r}")
    return o, h


def marching_tetrahedra(
    values: np.ndarray, origin: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the zero set of a gridded field (marching tetrahedra, welded).

    Parameters
    ----------
    values : (nx, ny, nz) float
        Field at the grid nodes ``origin + spacing * (i, j, k)``; negative inside.
        Nodes exactly at 0 count as outside. The faces of the grid's border are
        treated as outside, so the surface is closed even where the field is
        negative on the border.
    origin : (3,) float
        Position of node (0, 0, 0), metres.
    spacing : float
        Grid step, metres.

    Returns
    -------
    vertices : (V, 3) float64
        One per grid or diagonal edge that the level crosses, linearly interpolated.
    faces : (F, 3) int64
        Counter-clockwise seen from outside (positive side); every edge is shared
        by exactly two faces.

    Raises
    ------
    ValidationError
        Bad shapes, non-finite values, bad grid.
    """
    f = _check_field(values)
    o, h = _check_grid(origin, spacing)
    f = np.pad(f, 1, constant_values=1.0)  # a border of outside nodes closes the surface
    o = o - h
    shape = np.array(f.shape)
    inside = f < 0
    # cubes with both signs among their 8 corners
    any_in = np.zeros(tuple(shape - 1), dtype=bool)
    all_in = np.ones(tuple(shape - 1), dtype=bool)
    for c in _CORNERS:
        sl = inside[
            c[0] : shape[0] - 1 + c[0], c[1] : shape[1] - 1 + c[1], c[2] : shape[2] - 1 + c[2]
        ]
        any_in |= sl
        all_in &= sl
    cubes = np.argwhere(any_in & ~all_in)  # (C, 3) cube origins
    if cubes.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
    flat = f.ravel()
    # tetrahedra corners as grid points: (C, 6, 4, 3)
    pts = cubes[:, None, None, :] + _CORNERS[_TETS][None]
    node = pts @ strides  # (C, 6, 4)
    val = flat[node]
    mask = ((val < 0) * (1 << np.arange(4))).sum(axis=-1)  # (C, 6)
    pts = pts.reshape(-1, 4, 3)
    node = node.reshape(-1, 4)
    mask = mask.ravel()
    keep = (mask > 0) & (mask < 15)
    pts, node, mask = pts[keep], node[keep], mask[keep]
    tri_edges = []
    tri_tet = []
    for slot in range(2):
        has = _TRI_COUNT[mask] > slot
        tri_edges.append(_TRIS[mask[has], slot])  # (n, 3, 2) local corners
        tri_tet.append(np.nonzero(has)[0])
    edges_local = np.concatenate(tri_edges)  # (T, 3, 2)
    tet = np.concatenate(tri_tet)  # (T,)
    ends = np.take_along_axis(node[tet][:, None, :], edges_local.reshape(-1, 1, 6), axis=2)
    ends = ends.reshape(-1, 3, 2)  # global node ids of each triangle corner's edge
    lo = np.minimum(ends[..., 0], ends[..., 1])
    hi = np.maximum(ends[..., 0], ends[..., 1])
    n_nodes = int(flat.size)
    keys = lo * n_nodes + hi
    uniq, inverse = np.unique(keys.ravel(), return_inverse=True)
    faces = inverse.reshape(-1, 3).astype(np.int64)
    a = uniq // n_nodes
    b = uniq % n_nodes
    fa, fb = flat[a], flat[b]
    u = fa / (fa - fb)  # the level's position along the edge a -> b
    ga = np.stack(np.unravel_index(a, f.shape), axis=-1).astype(np.float64)
    gb = np.stack(np.unravel_index(b, f.shape), axis=-1).astype(np.float64)
    vertices = o + h * (ga + u[:, None] * (gb - ga))
    # orientation from the edge midpoints (never degenerate): the normal must point
    # from the tet's inside corners to its outside corners
    corners = pts[tet].astype(np.float64)  # (T, 4, 3)
    mids = 0.5 * (
        np.take_along_axis(corners, edges_local[..., 0:1], axis=1)
        + np.take_along_axis(corners, edges_local[..., 1:2], axis=1)
    )  # (T, 3, 3)
    normal = np.cross(mids[:, 1] - mids[:, 0], mids[:, 2] - mids[:, 0])
    ins = ((mask[tet][:, None] >> np.arange(4)) & 1).astype(np.float64)  # (T, 4)
    c_in = (ins[..., None] * corners).sum(1) / ins.sum(1, keepdims=True)
    c_out = ((1 - ins)[..., None] * corners).sum(1) / (1 - ins).sum(1, keepdims=True)
    flip = np.einsum("ij,ij->i", normal, c_out - c_in) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces


def uniform_adjacency(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(V, V) sparse 0/1 vertex adjacency of a triangle mesh (symmetric, no diagonal)."""
    f = np.asarray(faces, dtype=np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    a = sp.coo_matrix((np.ones(i.size), (i, j)), shape=(n_vertices, n_vertices)).tocsr()
    a = a + a.T
    a.data[:] = 1.0
    return a.tocsr()


def _neighbour_mean(adj: sp.csr_matrix, v: np.ndarray) -> np.ndarray:
    deg = np.asarray(adj.sum(axis=1)).ravel()
    return (adj @ v) / np.maximum(deg, 1.0)[:, None]


def taubin_smooth(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    iterations: int = 5,
    lam: float = 0.5,
    mu: float = -0.53,
) -> np.ndarray:
    """Taubin λ|μ smoothing with uniform weights (no shrinkage to first order).

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    iterations : int, default 5
        Number of λ-then-μ pairs.
    lam, mu : float
        ``0 < lam < -mu``.

    Returns
    -------
    (V, 3) float64
        Smoothed positions (the input is not modified).
    """
    v = np.array(vertices, dtype=np.float64)
    if not 0 < lam < -mu:
        raise ValidationError(f"lam, mu: need 0 < lam < -mu, got {lam}, {mu}")
    adj = uniform_adjacency(faces, v.shape[0])
    for _ in range(int(iterations)):
        v = v + lam * (_neighbour_mean(adj, v) - v)
        v = v + mu * (_neighbour_mean(adj, v) - v)
    return v


def _trilinear(values: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Field and its gradient (per index unit) at fractional grid coordinates (n, 3)."""
    f = map_coordinates(values, g.T, order=1, mode="nearest")
    grad = np.empty_like(g)
    d = 0.25
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = d
        grad[:, axis] = (
            map_coordinates(values, (g + step).T, order=1, mode="nearest")
            - map_coordinates(values, (g - step).T, order=1, mode="nearest")
        ) / (2 * d)
    return f, grad


def relax_on_isosurface(
    vertices: np.ndarray,
    faces: np.ndarray,
    values: np.ndarray,
    origin: np.ndarray,
    spacing: float,
    *,
    iterations: int = 6,
    step: float = 0.5,
) -> np.ndarray:
    """Even out a triangulated isosurface while keeping it on the level set.

    Each iteration moves every vertex ``step`` of the way to the mean of its
    neighbours (uniform Laplacian) and projects it back onto the zero set of the
    trilinearly interpolated field with two Newton steps along the gradient. The
    connectivity is unchanged.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    values, origin, spacing
        The gridded field, as for :func:`marching_tetrahedra`.
    iterations : int, default 6
    step : float, default 0.5
        Laplacian step in (0, 1].

    Returns
    -------
    (V, 3) float64
        New positions (the input is not modified).
    """
    f = _check_field(values)
    o, h = _check_grid(origin, spacing)
    v = np.array(vertices, dtype=np.float64)
    if not 0 < step <= 1:
        raise ValidationError(f"step: expected a value in (0, 1], got {step!r}")
    adj = uniform_adjacency(faces, v.shape[0])
    hi = np.array(f.shape, dtype=np.float64) - 1.0
    for _ in range(int(iterations)):
        v = v + step * (_neighbour_mean(adj, v) - v)
        for _newton in range(2):
            g = np.clip((v - o) / h, 0.0, hi)
            val, grad = _trilinear(f, g)
            n2 = np.einsum("ij,ij->i", grad, grad)
            ok = n2 > 1e-12
            move = np.where(ok, val / np.where(ok, n2, 1.0), 0.0)[:, None] * grad
            # never jump further than one cell
            length = np.linalg.norm(move, axis=1, keepdims=True)
            move = np.where(length > 1.0, move / np.maximum(length, 1e-300), move)
            v = v - h * move
    return v
