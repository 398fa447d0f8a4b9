"""Ray casting against triangle meshes: segment crossings, viewpoint occlusion, ray hits.

Three exact, vectorised queries share one idea -- bin the triangles so that each query
only meets the few triangles it can touch, then test those candidates exactly
(plane-side rejection and Moller-Trumbore), in blocks, with no loop over segments or
triangles:

- :func:`segments_cross_surface` -- arbitrary segments against a mesh; the triangles
  are binned in a uniform 3-D grid and each segment is probed at points a quarter cell
  apart (:class:`TriangleGrid`). Cost grows with segment length over cell size, so it
  suits short segments (vertex to bone, as in bone-heat weights).
- :func:`occluded_from_viewpoints` -- many points seen from a few viewpoints (markers
  and cameras): for each viewpoint the triangles are centrally projected onto an
  image plane and binned in a 2-D grid, so a long segment costs the same as a short
  one. Points outside the viewpoint's projection cone fall back to the 3-D grid.
- :func:`first_ray_hits` -- the first triangle each ray meets (landmark placement).

Plus :func:`segments_near_capsules` for thin non-mesh occluders (a rope as capsules)
and :func:`closest_points_on_mesh`.

Units are those of the inputs (metres in skincap).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.errors import ValidationError
from skincap.types import Mesh

__all__ = [
    "PROBES_PER_CELL",
    "TriangleGrid",
    "segments_cross_surface",
    "first_ray_hits",
    "segments_near_capsules",
    "closest_points_on_mesh",
    "check_vertex_coordinates",
    "MAX_COORDINATE",
]

#: Probes per grid cell along a segment in :func:`segments_cross_surface`.
PROBES_PER_CELL = 4

#: Largest coordinate magnitude accepted for mesh vertices: squared lengths and cross
#: products of edges (up to 2e150 long) must stay far below float64's 1.8e308.
MAX_COORDINATE = 1e150

#: Most grid cells along one axis: cell indices and their flattened keys stay far
#: inside int64 whatever the spread of the coordinates.
MAX_CELLS_PER_AXIS = 2**20


# ------------------------------------------------------------------------- checks
def _points(name: str, value: object, n: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: expected a float array of shape (N, 3): {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n):
        want = f"({n}, 3)" if n is not None else "(N, 3)"
        raise ValidationError(f"{name}: expected shape {want}, got {arr.shape}")
    return arr


def _parents(value: object, n: int) -> np.ndarray:
    p = np.asarray(value)
    if p.shape != (n,):
        raise ValidationError(f"parents: expected shape ({n},) (one per joint), got {p.shape}")
    if p.size and not np.issubdtype(p.dtype, np.integer):
        raise ValidationError(f"parents: expected an integer array, got dtype {p.dtype}")
    p = p.astype(np.int64)
    bad = np.nonzero((p >= np.arange(n)) | (p < -1))[0]
    if bad.size:
        k = int(bad[0])
        raise ValidationError(
            f"parents: each joint's parent must come before it (-1 for a root); joint {k} has parent {int(p[k])}"
        )
    return p


def check_vertex_coordinates(
    v: np.ndarray,
    *,
    name: str = "vertices",
    item: str = "vertex",
    hint: str = "a mesh coordinate may reach (a stray vertex or a wrong unit?)",
) -> None:
    """ValidationError naming the first row of ``v`` (N, 3) beyond :data:`MAX_COORDINATE`
    or not finite: squared distances of such points would overflow float64."""
    bad = ~(np.abs(v) <= MAX_COORDINATE).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValidationError(
            f"{name}: {item} {k} lies at {[float(x) for x in v[k]]}, beyond the "
            f"±{MAX_COORDINATE:g} {hint}"
        )


def _mesh_arrays(mesh: Mesh | tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(mesh, Mesh):
        check_vertex_coordinates(mesh.vertices)
        return mesh.vertices, mesh.faces
    try:
        vertices, faces = mesh
    except (TypeError, ValueError):
        raise ValidationError(
            "mesh: expected a Mesh or a (vertices (V, 3), faces (F, 3)) pair"
        ) from None
    v = _points("vertices", vertices)
    check_vertex_coordinates(v)  # finite, and small enough to square
    f = np.asarray(faces)
    if f.size == 0:
        f = f.reshape(0, 3).astype(np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValidationError(f"faces: expected an (F, 3) integer array, got {f.shape} {f.dtype}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
        raise ValidationError(f"faces: vertex indices must be in 0..{v.shape[0] - 1}")
    return v, f


# ------------------------------------------------------------- segment crossings
def _grid_pairs(starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Expand ranges ``[starts[k], starts[k] + counts[k])`` into (owner, index) pairs."""
    total = int(counts.sum())
    owner = np.repeat(np.arange(counts.size), counts)
    first = np.cumsum(counts) - counts
    index = np.arange(total) - np.repeat(first, counts) + np.repeat(starts, counts)
    return owner, index


class TriangleGrid:
    """Triangles binned in a uniform grid, for exact segment-crossing queries.

    Each triangle is listed in every cell that its bounding box, grown by half the
    probe spacing, overlaps. A segment probed at points at most ``spacing`` apart
    then finds every triangle it can touch in the cells of its probes. Cells are
    counted from ``origin`` (the triangles' lowest corner) and there are at most
    :data:`MAX_CELLS_PER_AXIS` along an axis, so far-flung vertices make the cells
    coarser instead of overflowing the integer cell indices. A grid without
    triangles blocks nothing.
    """

    def __init__(self, v: np.ndarray, f: np.ndarray, cell_size: float | None) -> None:
        self.v = v
        self.f = f
        tri = v[f]  # (F, 3, 3)
        self.tri = tri
        self.normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # (F, 3)
        self.plane = np.einsum("fx,fx->f", self.normal, tri[:, 0])
        self.normal_len = np.linalg.norm(self.normal, axis=1)
        if cell_size is None:
            edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)
            h = float(edges.mean()) if edges.size else 1.0
            if not h > 0:
                h = 1.0
        else:
            h = float(cell_size)
            if not (h > 0 and np.isfinite(h)):
                raise ValidationError(f"cell_size: expected a positive number, got {cell_size!r}")
        if f.shape[0] == 0:
            tri = np.zeros((1, 3, 3))  # one empty cell keeps the tables well formed
        tmin = tri.min(axis=1)
        tmax = tri.max(axis=1)
        self.origin = tmin.min(axis=0)  # (3,)
        span = float((tmax.max(axis=0) - self.origin).max())
        h = max(h, span / (MAX_CELLS_PER_AXIS - 2))
        rel_min = tmin - self.origin  # (F, 3), in [0, span]
        rel_max = tmax - self.origin
        budget = 64 * f.shape[0] + 1_000_000  # triangle-cell entries allowed
        while True:
            spacing = h / PROBES_PER_CELL
            grow = 0.5 * spacing  # every point of a probed segment is this close to a probe
            lo = np.floor((rel_min - grow) / h).astype(np.int64)  # (F, 3)
            hi = np.floor((rel_max + grow) / h).astype(np.int64)
            ext = hi - lo + 1
            per_tri = ext.prod(axis=1)
            if per_tri.sum() <= budget:
                break
            h *= 2.0  # a few huge triangles: coarser cells keep the table small
        if f.shape[0] == 0:
            per_tri = np.zeros(0, dtype=np.int64)
        self.h = h
        self.spacing = spacing
        self.gmin = lo.min(axis=0)
        self.dims = hi.max(axis=0) - self.gmin + 1
        # the box the cells cover, grown by a probe spacing against round-off
        self.box_lo = self.origin + self.gmin * h - spacing
        self.box_hi = self.origin + (self.gmin + self.dims) * h + spacing
        tri_id, k = _grid_pairs(np.zeros(f.shape[0], dtype=np.int64), per_tri)
        ex = ext[tri_id]
        cell = (
            lo[tri_id]
            - self.gmin
            + np.stack(
                [k % ex[:, 0], (k // ex[:, 0]) % ex[:, 1], k // (ex[:, 0] * ex[:, 1])], axis=1
            )
        )
        key = self._key(cell)
        order = np.argsort(key, kind="stable")
        self.tri_sorted = tri_id[order]
        self.keys, self.start, self.count = np.unique(
            key[order], return_index=True, return_counts=True
        )

    def _clip_to_box(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Q,) parameters ``t0 <= t1`` in [0, 1] of each segment's part inside the grid's box.

        A segment that misses the box gets ``t0 > t1``. Only that part can meet a
        triangle, so only it is probed: a segment reaching far outside the mesh costs
        no more than one crossing it.
        """
        t0 = np.zeros(o.shape[0])
        t1 = np.ones(o.shape[0])
        for axis in range(3):
            oa, da = o[:, axis], d[:, axis]
            lo, hi = self.box_lo[axis], self.box_hi[axis]
            moving = da != 0
            safe = np.where(moving, da, 1.0)
            ta, tb = (lo - oa) / safe, (hi - oa) / safe
            within = (oa >= lo) & (oa <= hi)
            enter = np.where(moving, np.minimum(ta, tb), np.where(within, -np.inf, np.inf))
            leave = np.where(moving, np.maximum(ta, tb), np.where(within, np.inf, -np.inf))
            t0 = np.maximum(t0, enter)
            t1 = np.minimum(t1, leave)
        return t0, t1

    def _key(self, cell: np.ndarray) -> np.ndarray:
        return cell[:, 0] + self.dims[0] * (cell[:, 1] + self.dims[1] * cell[:, 2])

    def crossed(
        self,
        o: np.ndarray,
        t_end: np.ndarray,
        ov: np.ndarray,
        max_pairs: int,
    ) -> np.ndarray:
        """(Q,) bool: segment ``o -> t_end`` meets a triangle not containing vertex ``ov``."""
        q = o.shape[0]
        blocked = np.zeros(q, dtype=bool)
        d = t_end - o
        if self.f.shape[0] == 0:
            return blocked
        t0, t1 = self._clip_to_box(o, d)
        inside_len = np.linalg.norm(d, axis=1) * np.maximum(t1 - t0, 0.0)
        n_samples = np.where(t1 >= t0, np.ceil(inside_len / self.spacing).astype(np.int64) + 1, 0)
        # blocks of segments with at most max_pairs probes
        ends = np.searchsorted(
            np.cumsum(n_samples), np.arange(max_pairs, int(n_samples.sum()), max_pairs)
        )
        seg_bounds = np.unique(np.concatenate([[0], ends, [q]]))
        for q0, q1 in zip(seg_bounds[:-1], seg_bounds[1:], strict=False):
            seg_id, s_k = _grid_pairs(np.zeros(q1 - q0, dtype=np.int64), n_samples[q0:q1])
            seg_id += q0
            frac = s_k / np.maximum(n_samples[seg_id] - 1, 1)
            t = t0[seg_id] + frac * (t1[seg_id] - t0[seg_id])
            pts = o[seg_id] + t[:, None] * d[seg_id]
            # cell indices from the origin, clipped before the integer cast (probes lie
            # in the box up to round-off)
            cells = np.clip(np.floor((pts - self.origin) / self.h), -1, MAX_CELLS_PER_AXIS + 1)
            sc = cells.astype(np.int64) - self.gmin
            inside = ((sc >= 0) & (sc < self.dims)).all(axis=1)
            skey = self._key(sc)
            pos = np.minimum(np.searchsorted(self.keys, skey), self.keys.size - 1)
            in_table = inside & (self.keys[pos] == skey)
            # consecutive probes of one segment in the same cell: look once
            repeat = np.zeros(seg_id.size, dtype=bool)
            repeat[1:] = (seg_id[1:] == seg_id[:-1]) & (skey[1:] == skey[:-1])
            use = in_table & ~repeat
            self._test(
                seg_id[use],
                self.start[pos[use]],
                self.count[pos[use]],
                o,
                d,
                ov,
                blocked,
                max_pairs,
            )
        return blocked

    def _test(
        self,
        probe_seg: np.ndarray,
        probe_start: np.ndarray,
        probe_count: np.ndarray,
        o: np.ndarray,
        d: np.ndarray,
        ov: np.ndarray,
        blocked: np.ndarray,
        max_pairs: int,
    ) -> None:
        """Exact segment-triangle tests of the probed cells, in blocks; sets ``blocked``."""
        if probe_seg.size == 0:
            return
        csum = np.cumsum(probe_count)
        ends = np.searchsorted(csum, np.arange(max_pairs, int(csum[-1]), max_pairs))
        bounds = np.unique(np.concatenate([[0], ends, [probe_seg.size]]))
        tri, f = self.tri, self.f
        seg_len = np.linalg.norm(d, axis=1)
        for b0, b1 in zip(bounds[:-1], bounds[1:], strict=False):
            owner, idx = _grid_pairs(probe_start[b0:b1], probe_count[b0:b1])
            seg = probe_seg[b0:b1][owner]
            tri_k = self.tri_sorted[idx]
            # cheap rejection: both ends strictly on one side of the triangle's plane
            nk = self.normal[tri_k]
            s0 = np.einsum("nx,nx->n", nk, o[seg]) - self.plane[tri_k]
            s1 = s0 + np.einsum("nx,nx->n", nk, d[seg])
            # (a conservative filter: ends within round-off of the plane go on to the exact test)
            tol = 1e-9 * self.normal_len[tri_k] * (seg_len[seg] + self.h)
            keep = ~(((s0 > tol) & (s1 > tol)) | ((s0 < -tol) & (s1 < -tol)))
            seg = seg[keep]
            tri_k = tri_k[keep]
            keep = ~blocked[seg] & (f[tri_k] != ov[seg][:, None]).all(axis=1)
            seg = seg[keep]
            tri_k = tri_k[keep]
            if seg.size == 0:
                continue
            # Moller-Trumbore
            p0 = tri[tri_k, 0]
            e1 = tri[tri_k, 1] - p0
            e2 = tri[tri_k, 2] - p0
            dd = d[seg]
            pvec = np.cross(dd, e2)
            det = np.einsum("nx,nx->n", e1, pvec)
            ok = np.abs(det) > 0.0
            inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
            tvec = o[seg] - p0
            u = np.einsum("nx,nx->n", tvec, pvec) * inv
            qvec = np.cross(tvec, e1)
            w = np.einsum("nx,nx->n", dd, qvec) * inv
            t = np.einsum("nx,nx->n", e2, qvec) * inv
            hit = ok & (u >= 0.0) & (w >= 0.0) & (u + w <= 1.0) & (t > 1e-6) & (t <= 1.0)
            blocked[seg[hit]] = True


def segments_cross_surface(
    vertices: np.ndarray,
    faces: np.ndarray,
    origins: np.ndarray,
    targets: np.ndarray,
    *,
    origin_vertex: np.ndarray | None = None,
    cell_size: float | None = None,
    max_pairs: int = 1_000_000,
) -> np.ndarray:
    """Whether each segment ``origins[k] -> targets[k]`` crosses a triangle of the mesh.

    The triangles are binned in a uniform grid; each segment is probed at points a
    quarter cell apart, which finds every triangle it can touch, and those candidates
    are tested exactly (plane-side rejection, then Moller-Trumbore), vectorised in
    blocks. No loop over segments or triangles.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    origins, targets : (Q, 3) float, metres
        Segment ends. Must be finite.
    origin_vertex : (Q,) int, optional
        The mesh vertex each segment starts at: triangles that contain it are not
        counted (a segment always touches them at its start). -1: none.
    cell_size : float, optional
        Grid cell edge, metres; default the mean edge length (made coarser when a
        few huge triangles would fill too many cells).
    max_pairs : int, default 1,000,000
        Probes, and segment-triangle candidate pairs, handled per block (bounds
        memory to a few hundred MB).

    Returns
    -------
    (Q,) bool
        True when the segment meets a triangle at a parameter ``t`` in
        ``(1e-6, 1]`` (``t = 0`` at the origin; touching at the very start is
        ignored). A segment lying in a triangle's plane does not count.
    """
    v, f = _mesh_arrays((vertices, faces))
    o = _points("origins", origins)
    t_end = _points("targets", targets, o.shape[0])
    if not (np.isfinite(o).all() and np.isfinite(t_end).all()):
        raise ValidationError("origins, targets: must be finite")
    q = o.shape[0]
    if origin_vertex is not None:
        ov = np.asarray(origin_vertex)
        if ov.shape != (q,) or (q and not np.issubdtype(ov.dtype, np.integer)):
            raise ValidationError(
                f"origin_vertex: expected ({q},) integers, got {ov.shape} {ov.dtype}"
            )
        ov = ov.astype(np.int64)
    else:
        ov = np.full(q, -1, dtype=np.int64)
    if int(max_pairs) < 1:
        raise ValidationError(f"max_pairs: expected a positive integer, got {max_pairs!r}")
    if q == 0 or f.shape[0] == 0:
        return np.zeros(q, dtype=bool)
    return TriangleGrid(v, f, cell_size).crossed(o, t_end, ov, int(max_pairs))


# ----------------------------------------------------------- viewpoint occlusion
def _moller_trumbore(
    o: np.ndarray, d: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ray ``o + t d`` against triangles ``(p0, p1, p2)``, all (K, 3): hit mask, t, u, w.

    ``hit`` is True when the ray's line meets the triangle (u, w >= 0, u + w <= 1); the
    caller restricts ``t``. Rays parallel to a triangle's plane never hit.
    """
    e1 = p1 - p0
    e2 = p2 - p0
    pvec = np.cross(d, e2)
    det = np.einsum("kx,kx->k", e1, pvec)
    ok = np.abs(det) > 0.0
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
    tvec = o - p0
    u = np.einsum("kx,kx->k", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    w = np.einsum("kx,kx->k", d, qvec) * inv
    t = np.einsum("kx,kx->k", e2, qvec) * inv
    hit = ok & (u >= 0.0) & (w >= 0.0) & (u + w <= 1.0)
    return hit, t, u, w


# ----------------------------------------------------------------------- ray hits
def first_ray_hits(
    vertices: np.ndarray,
    faces: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    *,
    max_pairs: int = 2_000_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first triangle each ray ``origins[k] + t directions[k]``, ``t > 0``, meets.

    Brute force over all ray-triangle pairs in blocks: O(R F) work, meant for a few
    hundred rays (landmark placement), not for per-frame use.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    origins : (R, 3) float, metres
    directions : (R, 3) float
        Need not be unit; ``t`` is in units of ``|directions|``. Must be non-zero.
    max_pairs : int, default 2,000,000
        Ray-triangle pairs per block.

    Returns
    -------
    face : (R,) int64
        Index of the first triangle hit, -1 when the ray misses the mesh.
    t : (R,) float64
        Ray parameter of the hit; ``inf`` for a miss.
    bary : (R, 3) float64
        Barycentric coordinates of the hit in its triangle (weights of the face's
        three vertices, summing to 1); NaN for a miss.
    """
    v, f = _mesh_arrays((vertices, faces))
    o = _points("origins", origins)
    d = _points("directions", directions, o.shape[0])
    if not (np.isfinite(o).all() and np.isfinite(d).all()):
        raise ValidationError("origins, directions: must be finite")
    if (np.linalg.norm(d, axis=1) == 0).any():
        raise ValidationError("directions: must be non-zero")
    r, n_f = o.shape[0], f.shape[0]
    best_t = np.full(r, np.inf)
    best_f = np.full(r, -1, dtype=np.int64)
    best_uw = np.zeros((r, 2))
    if r == 0 or n_f == 0:
        return best_f, best_t, np.full((r, 3), np.nan)
    rows = max(1, int(max_pairs) // n_f)
    for s in range(0, r, rows):
        rr = np.arange(s, min(r, s + rows))
        ray = np.repeat(rr, n_f)
        tri = np.tile(np.arange(n_f), rr.size)
        hit, t, u, w = _moller_trumbore(o[ray], d[ray], v[f[tri, 0]], v[f[tri, 1]], v[f[tri, 2]])
        t = np.where(hit & (t > 1e-12), t, np.inf).reshape(rr.size, n_f)
        k = np.argmin(t, axis=1)
        tk = t[np.arange(rr.size), k]
        better = tk < best_t[rr]
        sel = rr[better]
        best_t[sel] = tk[better]
        best_f[sel] = k[better]
        flat = np.arange(rr.size)[better] * n_f + k[better]
        best_uw[sel] = np.stack([u[flat], w[flat]], axis=1)
    bary = np.stack([1.0 - best_uw[:, 0] - best_uw[:, 1], best_uw[:, 0], best_uw[:, 1]], axis=1)
    bary[best_f < 0] = np.nan
    return best_f, best_t, bary


# ----------------------------------------------------------------- closest points
def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 3) barycentric coordinates of the point of triangle (a, b, c) nearest to p.

    Ericson, Real-Time Collision Detection, 5.1.5, vectorised; degenerate triangles
    resolve to a vertex or an edge.
    """
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = np.einsum("kx,kx->k", ab, ap)
    d2 = np.einsum("kx,kx->k", ac, ap)
    bp = p - b
    d3 = np.einsum("kx,kx->k", ab, bp)
    d4 = np.einsum("kx,kx->k", ac, bp)
    cp = p - c
    d5 = np.einsum("kx,kx->k", ab, cp)
    d6 = np.einsum("kx,kx->k", ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4

    def div(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.divide(x, y, out=np.zeros_like(x), where=y != 0)

    k = p.shape[0]
    one = np.ones(k)
    zero = np.zeros(k)
    t_ab = div(d1, d1 - d3)
    t_ac = div(d2, d2 - d6)
    t_bc = div(d4 - d3, (d4 - d3) + (d5 - d6))
    den = va + vb + vc
    v_in = div(vb, den)
    w_in = div(vc, den)
    conds = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),
        (d6 >= 0) & (d5 <= d6),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
    ]
    bv = np.select(conds, [zero, one, t_ab, zero, zero, 1.0 - t_bc], v_in)
    bw = np.select(conds, [zero, zero, zero, one, t_ac, t_bc], w_in)
    return np.stack([1.0 - bv - bw, bv, bw], axis=1)


#: Query points per block of :func:`closest_points_on_mesh` (bounds its candidate lists).
_QUERY_BLOCK = 2048


def _vertex_radius_groups(v: np.ndarray, f: np.ndarray) -> list[tuple[np.ndarray, Any, float]]:
    """The faces' vertices grouped by their longest incident edge ``L_a``, metres.

    Group ``k`` holds the vertices with ``L_a`` in ``(L 2^(k-1), L 2^k]`` (``L`` the
    shortest such edge): its vertex indices, a KD-tree of them and its largest ``L_a``.
    """
    from scipy.spatial import cKDTree

    length = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)  # (F, 3) edge c-1 -> c
    at_corner = np.maximum(length, np.roll(length, -1, axis=1))  # the two edges at corner c
    longest = np.zeros(v.shape[0])
    np.maximum.at(longest, f.ravel(), at_corner.ravel())
    used = np.unique(f)
    reach = longest[used]
    floor = max(float(reach.min()), 1e-12)
    group = np.ceil(np.log2(np.maximum(reach / floor, 1.0))).astype(np.int64)
    out = []
    for k in np.unique(group):
        members = used[group == k]
        out.append((members, cKDTree(v[members]), float(longest[members].max())))
    return out


def closest_points_on_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    *,
    max_pairs: int = 2_000_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The point of the mesh nearest to each query point (exact).

    Candidate triangles come from KD-trees of the vertices. The nearest surface point
    ``p*`` lies within ``d`` of the query (``d`` the distance to the nearest vertex), and
    every corner ``a`` of its triangle within ``|p* - a| <= L_a`` of it (``L_a`` the
    longest edge at ``a``), so only triangles at the vertices within ``d + L_a`` of the
    query are tested (Ericson's closest point on a triangle, vectorised). Vertices are
    grouped by ``L_a`` (powers of two of the shortest), one tree and one radius per
    group: a mesh with a few long edges (MakeHuman's coarse body beside its fine face)
    does not make every query gather the fine region's hundreds of vertices. Queries
    run in blocks of :data:`_QUERY_BLOCK` points, which bounds the memory.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
        At least one face.
    points : (N, 3) float, metres
        Finite, within ±:data:`MAX_COORDINATE` (distances to them must not overflow).
    max_pairs : int, default 2,000,000
        Point-triangle pairs per block.

    Returns
    -------
    distance : (N,) float64, metres
    face : (N,) int64
        The triangle holding the nearest point.
    bary : (N, 3) float64
        Its barycentric coordinates in that triangle.
    """
    from scipy.spatial import cKDTree

    v, f = _mesh_arrays((vertices, faces))
    p = _points("points", points)
    check_vertex_coordinates(p, name="points", item="point", hint="a query may reach")
    if f.shape[0] == 0:
        raise ValidationError("faces: the mesh has no triangle")
    n, n_f = p.shape[0], f.shape[0]
    dist = np.full(n, np.inf)
    face = np.zeros(n, dtype=np.int64)
    bary = np.zeros((n, 3))
    if n == 0:
        return dist, face, bary
    groups = _vertex_radius_groups(v, f)
    # vertex -> incident faces (CSR)
    order = np.argsort(f.ravel(), kind="stable")
    vf_face = order // 3
    vf_start = np.searchsorted(f.ravel()[order], np.arange(v.shape[0]), side="left")
    vf_count = np.bincount(f.ravel(), minlength=v.shape[0])
    nearest_tree = cKDTree(v[np.unique(f)])
    for q0 in range(0, n, _QUERY_BLOCK):
        q = p[q0 : q0 + _QUERY_BLOCK]
        dv, _ = nearest_tree.query(q)
        owners, verts = [], []
        for members, tree, reach in groups:
            near = tree.query_ball_point(q, dv + reach * (1.0 + 1e-9) + 1e-12)
            counts = np.array([len(x) for x in near], dtype=np.int64)
            owners.append(np.repeat(np.arange(q.shape[0]), counts))
            verts.append(members[np.concatenate([np.asarray(x, dtype=np.int64) for x in near])])
        owner, vert = np.concatenate(owners), np.concatenate(verts)
        pt, k = _grid_pairs(vf_start[vert], vf_count[vert])
        pairs = np.unique(owner[pt] * n_f + vf_face[k])  # sorted by point
        for s0 in range(0, pairs.size, int(max_pairs)):
            blk = pairs[s0 : s0 + int(max_pairs)]
            pi, fi = blk // n_f, blk % n_f
            a, b, c = v[f[fi, 0]], v[f[fi, 1]], v[f[fi, 2]]
            bc = _closest_on_triangles(q[pi], a, b, c)
            d = np.linalg.norm(bc[:, :1] * a + bc[:, 1:2] * b + bc[:, 2:] * c - q[pi], axis=1)
            # best per point within the block (pairs are sorted by point)
            o = np.lexsort((d, pi))
            first = np.ones(o.size, dtype=bool)
            first[1:] = pi[o][1:] != pi[o][:-1]
            sel = o[first]
            tgt = q0 + pi[sel]
            better = d[sel] < dist[tgt]
            dist[tgt[better]] = d[sel][better]
            face[tgt[better]] = fi[sel][better]
            bary[tgt[better]] = bc[sel][better]
    return dist, face, bary


# ---------------------------------------------------------------------- capsules
def segments_near_capsules(
    starts: np.ndarray,
    ends: np.ndarray,
    capsule_a: np.ndarray,
    capsule_b: np.ndarray,
    radius: float | np.ndarray,
    *,
    max_pairs: int = 2_000_000,
) -> np.ndarray:
    """Whether each segment passes through any capsule (a thick segment).

    Parameters
    ----------
    starts, ends : (Q, 3) float, metres
        The segments (e.g. marker to camera).
    capsule_a, capsule_b : (K, 3) float, metres
        Capsule axis ends (e.g. consecutive rope particles).
    radius : float or (K,) float, metres
        Capsule radii.
    max_pairs : int, default 2,000,000

    Returns
    -------
    (Q,) bool
        True when the distance between the segment and some capsule axis is below the
        capsule's radius. Closest points by Ericson 5.1.9, vectorised over all pairs.
    """
    s0 = _points("starts", starts)
    s1 = _points("ends", ends, s0.shape[0])
    a = _points("capsule_a", capsule_a)
    b = _points("capsule_b", capsule_b, a.shape[0])
    rad = np.broadcast_to(np.asarray(radius, dtype=np.float64), (a.shape[0],))
    if not (np.isfinite(s0).all() and np.isfinite(s1).all()):
        raise ValidationError("starts, ends: must be finite")
    if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(rad).all()):
        raise ValidationError("capsules: must be finite")
    q, k = s0.shape[0], a.shape[0]
    out = np.zeros(q, dtype=bool)
    if q == 0 or k == 0:
        return out
    rows = max(1, int(max_pairs) // k)
    for s in range(0, q, rows):
        rr = np.arange(s, min(q, s + rows))
        si = np.repeat(rr, k)
        ki = np.tile(np.arange(k), rr.size)
        p1, q1, p2, q2 = s0[si], s1[si], a[ki], b[ki]
        d1 = q1 - p1
        d2 = q2 - p2
        r = p1 - p2
        aa = np.einsum("kx,kx->k", d1, d1)
        ee = np.einsum("kx,kx->k", d2, d2)
        ff = np.einsum("kx,kx->k", d2, r)
        cc = np.einsum("kx,kx->k", d1, r)
        bb = np.einsum("kx,kx->k", d1, d2)
        den = aa * ee - bb * bb
        sv = np.where(
            den > 1e-15 * np.maximum(aa * ee, 1e-300),
            np.clip(
                np.divide(bb * ff - cc * ee, den, out=np.zeros_like(den), where=den != 0), 0, 1
            ),
            0.0,
        )
        sv = np.where(aa > 0, sv, 0.0)
        tv = np.divide(bb * sv + ff, ee, out=np.zeros_like(ee), where=ee > 0)
        t_clip = np.clip(tv, 0.0, 1.0)
        # re-solve s for a clamped t
        sv = np.where(
            (tv != t_clip) & (aa > 0),
            np.clip(np.divide(bb * t_clip - cc, aa, out=np.zeros_like(aa), where=aa > 0), 0, 1),
            sv,
        )
        c1 = p1 + sv[:, None] * d1
        c2 = p2 + t_clip[:, None] * d2
        dist = np.linalg.norm(c1 - c2, axis=1).reshape(rr.size, k)
        out[rr] = (dist < rad[None, :]).any(axis=1)
    return out
