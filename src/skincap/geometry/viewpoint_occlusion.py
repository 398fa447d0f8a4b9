"""Many points seen from a few viewpoints: which point-to-viewpoint segments cross a mesh.

For each viewpoint (a camera) the triangles are centrally projected onto an image
plane and binned in a 2-D grid over the projected points, so a long segment costs the
same as a short one; candidates are tested exactly (Moller-Trumbore), so the result
equals a brute-force test. Points outside a viewpoint's projection cone fall back to
the 3-D grid of :func:`skincap.geometry.raycast.segments_cross_surface`.

Units are those of the inputs (metres in skincap).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.raycast import (
    _grid_pairs,
    _mesh_arrays,
    _moller_trumbore,
    _points,
    segments_cross_surface,
)

__all__ = ["occluded_from_viewpoints"]


def _view_frames(axis: np.ndarray) -> np.ndarray:
    """(C, 3, 3) orthonormal rows (e1, e2, e3) with e3 = ``axis`` (unit, (C, 3))."""
    helper = np.where(
        (np.abs(axis[:, 1]) < 0.9)[:, None], np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    )
    e1 = np.cross(helper, axis)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(axis, e1)
    return np.stack([e1, e2, axis], axis=1)


def occluded_from_viewpoints(
    vertices: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    viewpoints: np.ndarray,
    *,
    pairs: np.ndarray | None = None,
    start_offset: float = 0.0,
    cull_back_faces: bool = False,
    grid: int = 96,
    cone_deg: float = 60.0,
    max_pairs: int = 2_000_000,
) -> np.ndarray:
    """Whether the segment from each point to each viewpoint crosses the mesh.

    For every viewpoint the triangles in front of it are centrally projected onto an
    image plane (perpendicular to the mean direction of its points) and binned in a
    ``grid x grid`` 2-D grid over the projected points; a point's candidates are the
    triangles whose projected bounding box covers its cell and which come nearer to
    the viewpoint than the point. Candidates are tested exactly (Moller-Trumbore), so
    the result equals a brute-force test; only the work is cut. All viewpoints are
    handled together, vectorised; segments whose point lies outside a ``cone_deg``
    cone around the viewpoint's axis, and triangles that reach behind a viewpoint,
    are tested by :func:`segments_cross_surface` / brute force instead.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    points : (N, 3) float, metres
        Segment starts (e.g. markers). Must be finite.
    viewpoints : (C, 3) float, metres
        Segment ends (e.g. camera centres). Must be finite.
    pairs : (N, C) bool, optional
        Only these point-viewpoint pairs are tested (others come out False).
    start_offset : float, default 0
        Metres of each segment next to its point that are ignored (a hit at distance
        ``<= start_offset`` from the point does not count): lets a point lying on, or
        just above, the surface not be hidden by its own triangles.
    cull_back_faces : bool, default False
        Test only triangles whose normal (counter-clockwise winding) faces the
        viewpoint. Exact for a closed, outward-oriented mesh: a segment that crosses
        such a surface always crosses a front-facing triangle. Halves the work.
    grid : int, default 96
        Cells per axis of each viewpoint's 2-D grid.
    cone_deg : float, default 60
        Half-angle of the cone handled by projection.
    max_pairs : int, default 2,000,000
        Candidate pairs tested per block (bounds memory).

    Returns
    -------
    (N, C) bool
        True where the segment meets a triangle at a distance from the point in
        ``(start_offset, |viewpoint - point|]``. No NaN.
    """
    v, f = _mesh_arrays((vertices, faces))
    p, c, req, off, g = _occlusion_inputs(points, viewpoints, pairs, start_offset, grid)
    if not 0.0 < float(cone_deg) < 90.0:
        raise ValidationError(f"cone_deg: expected an angle in (0, 90) degrees, got {cone_deg!r}")
    if int(max_pairs) < 1:
        raise ValidationError(f"max_pairs: expected a positive integer, got {max_pairs!r}")
    n, n_c = p.shape[0], c.shape[0]
    out = np.zeros((n, n_c), dtype=bool)
    if n == 0 or n_c == 0 or f.shape[0] == 0 or not req.any():
        return out

    rel = p[None, :, :] - c[:, None, :]  # (C, N, 3) viewpoint -> point
    dist = np.linalg.norm(rel, axis=2)  # (C, N)
    unit = np.divide(rel, dist[..., None], out=np.zeros_like(rel), where=dist[..., None] > 0)
    axis = np.einsum("cn,cnx->cx", req.T.astype(np.float64), unit)
    norm = np.linalg.norm(axis, axis=1)
    axis = np.where(norm[:, None] > 0, axis / np.where(norm > 0, norm, 1.0)[:, None], [0, 0, 1.0])
    frames = _view_frames(axis)  # (C, 3, 3)
    pc = np.einsum("cax,cnx->cna", frames, rel)  # (C, N, 3) point in view coordinates
    cone = req.T & (pc[..., 2] >= np.cos(np.radians(cone_deg)) * dist) & (dist > off)
    # the rest (outside the cone) through the 3-D grid
    rest = req.T & ~cone & (dist > off)
    if rest.any():
        ci, ni = np.nonzero(rest)
        o = p[ni] + off * (-unit[ci, ni])
        out[ni, ci] = segments_cross_surface(v, f, o, c[ci])
    if not cone.any():
        return out

    ci, ni = np.nonzero(cone)  # (Q,) the cone pairs
    seg_o = p[ni] - off * unit[ci, ni]  # start (point moved towards the viewpoint)
    seg_d = c[ci] - seg_o
    pts = _projected_point_grid(pc[ci, ni], ci, n_c, g)
    tris = _triangles_in_view(v, f, c, frames, pts.active, cull_back_faces)
    if tris.straddle.any():
        hit_q = _straddling_hits(tris, ci, seg_o, seg_d, v, f, n_c, max_pairs)
        out[ni[hit_q], ci[hit_q]] = True
    blocked = _binned_hits(tris, pts, ci.size, seg_o, seg_d, v, f, g, max_pairs)
    out[ni[blocked], ci[blocked]] = True
    return out


def _occlusion_inputs(
    points: np.ndarray,
    viewpoints: np.ndarray,
    pairs: np.ndarray | None,
    start_offset: float,
    grid: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """Checked points (N, 3), viewpoints (C, 3), requested pairs (N, C), offset, grid."""
    p = _points("points", points)
    c = _points("viewpoints", viewpoints)
    if not (np.isfinite(p).all() and np.isfinite(c).all()):
        raise ValidationError("points, viewpoints: must be finite")
    n, n_c = p.shape[0], c.shape[0]
    if pairs is None:
        req = np.ones((n, n_c), dtype=bool)
    else:
        req = np.asarray(pairs)
        if req.shape != (n, n_c) or req.dtype != bool:
            raise ValidationError(
                f"pairs: expected an ({n}, {n_c}) bool array, got {req.shape} {req.dtype}"
            )
    off = float(start_offset)
    if not (off >= 0 and np.isfinite(off)):
        raise ValidationError(f"start_offset: expected a non-negative number, got {start_offset!r}")
    g = int(grid)
    if g < 1:
        raise ValidationError(f"grid: expected a positive integer, got {grid!r}")
    return p, c, req, off, g


class _PointGrid(NamedTuple):
    """The cone points binned per view in a ``g x g`` grid of the image plane.

    ``lo_u``, ``lo_v``, ``cell`` (C,) the grid origin and cell size per view;
    ``active`` (C,) views with points; ``z`` (Q,) each point's depth; ``order`` (Q,)
    the points sorted by cell key ``key_sorted``; ``sat`` (C, g+1, g+1) summed-area
    table of the point counts.
    """

    lo_u: np.ndarray
    lo_v: np.ndarray
    cell: np.ndarray
    active: np.ndarray
    z: np.ndarray
    order: np.ndarray
    key_sorted: np.ndarray
    sat: np.ndarray


def _projected_point_grid(pc: np.ndarray, ci: np.ndarray, n_c: int, g: int) -> _PointGrid:
    """Bin the points ``pc`` (Q, 3) (view coordinates of view ``ci`` (Q,)) per view."""
    u_pt = pc[:, 0] / pc[:, 2]
    v_pt = pc[:, 1] / pc[:, 2]
    big = np.finfo(np.float64).max
    lo_u = np.full(n_c, big)
    hi_u = np.full(n_c, -big)
    lo_v = np.full(n_c, big)
    hi_v = np.full(n_c, -big)
    np.minimum.at(lo_u, ci, u_pt)
    np.maximum.at(hi_u, ci, u_pt)
    np.minimum.at(lo_v, ci, v_pt)
    np.maximum.at(hi_v, ci, v_pt)
    active = lo_u <= hi_u
    ext = np.where(active, np.maximum(hi_u - lo_u, hi_v - lo_v), 1.0)
    cell = np.maximum(ext, 1e-12) * (1.0 + 1e-9) / g  # (C,)
    lo_u = np.where(active, lo_u, 0.0)
    lo_v = np.where(active, lo_v, 0.0)
    pu = np.minimum(((u_pt - lo_u[ci]) / cell[ci]).astype(np.int64), g - 1)
    pv = np.minimum(((v_pt - lo_v[ci]) / cell[ci]).astype(np.int64), g - 1)
    pkey = (ci * g + pu) * g + pv
    porder = np.argsort(pkey, kind="stable")
    occupancy = np.zeros((n_c, g + 1, g + 1), dtype=np.int64)
    np.add.at(occupancy, (ci, pu + 1, pv + 1), 1)
    sat = occupancy.cumsum(axis=1).cumsum(axis=2)
    return _PointGrid(lo_u, lo_v, cell, active, pc[:, 2], porder, pkey[porder], sat)


class _ViewTriangles(NamedTuple):
    """Triangles per active view: ``view``, ``face`` (K,); ``corners`` three (K,)
    indices into the flattened (C, V) tables ``vu``, ``vv`` (projected corners);
    ``zmin`` (K,) nearest corner depth; ``straddle`` (K,) reaching behind the view."""

    view: np.ndarray
    face: np.ndarray
    corners: list[np.ndarray]
    vu: np.ndarray
    vv: np.ndarray
    zmin: np.ndarray
    straddle: np.ndarray
    zeps: float


def _triangles_in_view(
    v: np.ndarray,
    f: np.ndarray,
    c: np.ndarray,
    frames: np.ndarray,
    active: np.ndarray,
    cull_back_faces: bool,
) -> _ViewTriangles:
    """Project every vertex into every view, then gather the triangles' corners."""
    n_c, n_v = c.shape[0], v.shape[0]
    vc = np.einsum("cax,vx->cva", frames, v) - np.einsum("cax,cx->ca", frames, c)[:, None, :]
    vz = vc[..., 2]  # (C, V)
    safe_z = np.where(vz > 0, vz, 1.0)
    vu = (vc[..., 0] / safe_z).ravel()
    vv = (vc[..., 1] / safe_z).ravel()
    vz = vz.ravel()
    tri_ok = np.broadcast_to(active[:, None], (n_c, f.shape[0]))
    if cull_back_faces:
        normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # (F, 3)
        facing = (c @ normal.T) - np.einsum("fx,fx->f", normal, v[f[:, 0]])[None, :]  # (C, F)
        tri_ok = tri_ok & (facing > 0)
    tc, tf = np.nonzero(tri_ok)
    base = tc * n_v
    flat = [base + f[tf, k] for k in range(3)]  # corners' indices into the (C, V) tables
    cz = [vz[fk] for fk in flat]
    zmin = np.minimum(np.minimum(cz[0], cz[1]), cz[2])
    zmax = np.maximum(np.maximum(cz[0], cz[1]), cz[2])
    scale = float(np.abs(v).max() + np.abs(c).max() + 1.0)
    zeps = 1e-9 * scale
    straddle = (zmin <= zeps) & (zmax > 0)
    return _ViewTriangles(tc, tf, flat, vu, vv, zmin, straddle, zeps)


def _straddling_hits(
    tris: _ViewTriangles,
    ci: np.ndarray,
    seg_o: np.ndarray,
    seg_d: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    n_c: int,
    max_pairs: int,
) -> np.ndarray:
    """Cone pairs (indices into ``ci``) blocked by a triangle reaching behind their view:
    brute force against that view's pairs."""
    sc, sf = tris.view[tris.straddle], tris.face[tris.straddle]
    by_view = np.argsort(ci, kind="stable")
    view_start = np.searchsorted(ci[by_view], np.arange(n_c), side="left")
    view_count = np.searchsorted(ci[by_view], np.arange(n_c), side="right") - view_start
    owner, idx = _grid_pairs(view_start[sc], view_count[sc])
    if not owner.size:
        return np.zeros(0, dtype=np.int64)
    qs = by_view[idx]
    hits = _segment_hits(seg_o[qs], seg_d[qs], v, f[sf[owner]], max_pairs)
    return qs[hits]


def _binned_hits(
    tris: _ViewTriangles,
    pts: _PointGrid,
    n_pairs: int,
    seg_o: np.ndarray,
    seg_d: np.ndarray,
    v: np.ndarray,
    f: np.ndarray,
    g: int,
    max_pairs: int,
) -> np.ndarray:
    """(Q,) bool: cone pairs blocked by a triangle in front of their view.

    Each triangle meets only the points in the cells its projected bounding box
    covers and nearer than them; those pairs are tested exactly, in blocks.
    """
    front = tris.zmin > tris.zeps
    tc, tf, zmin = tris.view[front], tris.face[front], tris.zmin[front]
    flat = [fk[front] for fk in tris.corners]
    blocked = np.zeros(n_pairs, dtype=bool)
    if tc.size == 0:
        return blocked
    tu = [tris.vu[fk] for fk in flat]
    tv = [tris.vv[fk] for fk in flat]
    lu, lv, inv_cell = pts.lo_u[tc], pts.lo_v[tc], 1.0 / pts.cell[tc]
    i0 = np.floor((np.minimum(np.minimum(tu[0], tu[1]), tu[2]) - lu) * inv_cell)
    i1 = np.floor((np.maximum(np.maximum(tu[0], tu[1]), tu[2]) - lu) * inv_cell)
    j0 = np.floor((np.minimum(np.minimum(tv[0], tv[1]), tv[2]) - lv) * inv_cell)
    j1 = np.floor((np.maximum(np.maximum(tv[0], tv[1]), tv[2]) - lv) * inv_cell)
    inside = (i1 >= 0) & (i0 <= g - 1) & (j1 >= 0) & (j0 <= g - 1)
    i0 = np.clip(i0, 0, g - 1).astype(np.int64)
    i1 = np.clip(i1, 0, g - 1).astype(np.int64)
    j0 = np.clip(j0, 0, g - 1).astype(np.int64)
    j1 = np.clip(j1, 0, g - 1).astype(np.int64)
    # points inside the triangle's bounding box (summed-area table)
    sat = pts.sat
    n_in = sat[tc, i1 + 1, j1 + 1] - sat[tc, i0, j1 + 1] - sat[tc, i1 + 1, j0] + sat[tc, i0, j0]
    keep = inside & (n_in > 0)
    tc, tf, i0, i1, j0, j1 = tc[keep], tf[keep], i0[keep], i1[keep], j0[keep], j1[keep]
    tzmin = zmin[keep]
    # expand every triangle over its cells
    ni_cells = i1 - i0 + 1
    n_cells = ni_cells * (j1 - j0 + 1)
    owner, k = _grid_pairs(np.zeros(tc.size, dtype=np.int64), n_cells)
    cu = i0[owner] + k % ni_cells[owner]
    cv = j0[owner] + k // ni_cells[owner]
    ekey = (tc[owner] * g + cu) * g + cv
    left = np.searchsorted(pts.key_sorted, ekey, side="left")
    right = np.searchsorted(pts.key_sorted, ekey, side="right")
    has = right > left
    e_tri = owner[has]
    e_start = left[has]
    e_count = right[has] - left[has]
    if e_tri.size == 0:
        return blocked
    csum = np.cumsum(e_count)
    ends = np.searchsorted(csum, np.arange(max_pairs, int(csum[-1]), max_pairs))
    bounds = np.unique(np.concatenate([[0], ends, [e_tri.size]]))
    for b0, b1 in zip(bounds[:-1], bounds[1:], strict=False):
        own, idx = _grid_pairs(e_start[b0:b1], e_count[b0:b1])
        q = pts.order[idx]
        tri_k = e_tri[b0:b1][own]
        near = (tzmin[tri_k] < pts.z[q]) & ~blocked[q]
        q = q[near]
        tri_k = tri_k[near]
        if q.size == 0:
            continue
        ft = f[tf[tri_k]]
        hit, t, _, _ = _moller_trumbore(seg_o[q], seg_d[q], v[ft[:, 0]], v[ft[:, 1]], v[ft[:, 2]])
        hit &= (t > 1e-9) & (t <= 1.0)
        blocked[q[hit]] = True
    return blocked


def _segment_hits(
    o: np.ndarray, d: np.ndarray, v: np.ndarray, tri_faces: np.ndarray, max_pairs: int
) -> np.ndarray:
    """(K,) bool: segment ``o -> o + d`` meets triangle ``tri_faces`` (row-wise pairs)."""
    hits = np.zeros(o.shape[0], dtype=bool)
    for s in range(0, o.shape[0], max_pairs):
        ft = tri_faces[s : s + max_pairs]
        hit, t, _, _ = _moller_trumbore(
            o[s : s + max_pairs], d[s : s + max_pairs], v[ft[:, 0]], v[ft[:, 1]], v[ft[:, 2]]
        )
        hits[s : s + max_pairs] = hit & (t > 1e-9) & (t <= 1.0)
    return hits
