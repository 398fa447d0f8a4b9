"""The compiled dense kernel and its steps (eqs. 8-9), numba.

Imported only by :func:`skincap.deform.dense._kernel_numba.dense_dispatcher`, so numba
is imported on the kernel's first use, not with the deformer. The steps are inlined
into the kernel by numba (``inline="always"``): the kernel compiles to the code of one
function, and it alone is cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.deform.dense._kernel_numpy import (
    F32_ERROR_PER_WEIGHT,
    SUPPORT_SLACK,
)
from skincap.deform.dense._pair_tiles import MEMBER_LANES

__all__ = ["dense_kernel", "dense_kernel_no_rbf"]

_FASTMATH = {"contract", "reassoc"}
#: Runs of tiles per frame in the parallel loop: enough to balance the threads, few
#: enough that each run's scratch table costs nothing.
_TILE_CHUNKS = 64
#: Runs of vertices in the fused (no-RBF) path's parallel loop: the same balance.
_VERTEX_CHUNKS = 64
#: float32 lanes of an AVX2 vector: the float32 RBF loop runs a tile's pairs padded to
#: whole steps of it (the padding lanes are scratch), so it has no scalar remainder.
_F32_LANES = 8


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _quadratic_field(quadratic, t, p, x, y, z):  # pragma: no cover - runs compiled
    """Ã q(p̂⁰) of part ``p`` in frame ``t``: the local position (x, y, z), metres, moved by
    the part's quadratic field; quadratic (T, P, 3, 10). Returns (lx, ly, lz), metres."""
    xx = x * x
    yy = y * y
    zz = z * z
    xy = x * y
    yz = y * z
    zx = z * x
    # Ã q(p̂⁰), q = [x, y, z, x², y², z², xy, yz, zx, 1]
    lx = (
        quadratic[t, p, 0, 0] * x + quadratic[t, p, 0, 1] * y
        + quadratic[t, p, 0, 2] * z + quadratic[t, p, 0, 3] * xx
        + quadratic[t, p, 0, 4] * yy + quadratic[t, p, 0, 5] * zz
        + quadratic[t, p, 0, 6] * xy + quadratic[t, p, 0, 7] * yz
        + quadratic[t, p, 0, 8] * zx + quadratic[t, p, 0, 9]
    )  # fmt: skip
    ly = (
        quadratic[t, p, 1, 0] * x + quadratic[t, p, 1, 1] * y
        + quadratic[t, p, 1, 2] * z + quadratic[t, p, 1, 3] * xx
        + quadratic[t, p, 1, 4] * yy + quadratic[t, p, 1, 5] * zz
        + quadratic[t, p, 1, 6] * xy + quadratic[t, p, 1, 7] * yz
        + quadratic[t, p, 1, 8] * zx + quadratic[t, p, 1, 9]
    )  # fmt: skip
    lz = (
        quadratic[t, p, 2, 0] * x + quadratic[t, p, 2, 1] * y
        + quadratic[t, p, 2, 2] * z + quadratic[t, p, 2, 3] * xx
        + quadratic[t, p, 2, 4] * yy + quadratic[t, p, 2, 5] * zz
        + quadratic[t, p, 2, 6] * xy + quadratic[t, p, 2, 7] * yz
        + quadratic[t, p, 2, 8] * zx + quadratic[t, p, 2, 9]
    )  # fmt: skip
    return lx, ly, lz


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _rbf_sums(near, n_k, gx, gy, gz):  # pragma: no cover - runs compiled
    """Both RBF sums (eq. 8) at the position (gx, gy, gz) scaled by 2/σ (unitless) over
    the first ``n_k`` columns of ``near`` (9, K): rows x, y, z of the centres scaled by
    2/σ, then the members' field's weights w / 6, then the seam field's.
    Returns (mx, my, mz, sx, sy, sz), metres."""
    mx = 0.0
    my = 0.0
    mz = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    # branch-free over the centres (a support test would mispredict): s = 2 d / σ
    # clipped to 2, where both cubes of φ vanish. LLVM runs this loop 8 centres a step
    # plus a scalar remainder, which the caller's padding to whole steps (zero weights)
    # skips: MEMBER_LANES
    for i in range(n_k):
        dx = gx - near[0, i]
        dy = gy - near[1, i]
        dz = gz - near[2, i]
        s = np.sqrt(min(dx * dx + dy * dy + dz * dz, 4.0))
        u = 2.0 - s
        b = max(1.0 - s, 0.0)
        phi = u * u * u - 4.0 * (b * b * b)  # 6 φ
        mx += phi * near[3, i]
        my += phi * near[4, i]
        mz += phi * near[5, i]
        sx += phi * near[6, i]
        sy += phi * near[7, i]
        sz += phi * near[8, i]
    return mx, my, mz, sx, sy, sz


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _tile_rbf_sums_f32(near32, n_near, pos32, n_lanes, acc):  # pragma: no cover - runs compiled
    """Both RBF sums (eq. 8) of a tile's pairs in float32, the pairs along the vector
    lanes: ``near32`` (9, K) float32, the first ``n_near`` centres (rows x, y, z scaled
    by 2/σ and relative to the tile's origin, then the members' and the seam field's
    weights w / 6); ``pos32`` (3, n) the pairs' positions the same way; ``acc`` (6, n)
    float32 receives the sums (members' x, y, z, then the seam field's), metres, for the
    first ``n_lanes`` pairs (a whole number of vector steps; lanes past the tile's pairs
    are scratch). No horizontal reduction, no padding of the centres."""
    zero = np.float32(0.0)
    one = np.float32(1.0)
    two = np.float32(2.0)
    four = np.float32(4.0)
    for r in range(6):
        for q in range(n_lanes):
            acc[r, q] = zero
    for i in range(n_near):
        cx = near32[0, i]
        cy = near32[1, i]
        cz = near32[2, i]
        w0 = near32[3, i]
        w1 = near32[4, i]
        w2 = near32[5, i]
        w3 = near32[6, i]
        w4 = near32[7, i]
        w5 = near32[8, i]
        for q in range(n_lanes):
            dx = pos32[0, q] - cx
            dy = pos32[1, q] - cy
            dz = pos32[2, q] - cz
            s = np.sqrt(min(dx * dx + dy * dy + dz * dz, four))
            u = two - s
            b = max(one - s, zero)
            phi = u * u * u - four * (b * b * b)  # 6 φ
            acc[0, q] += phi * w0
            acc[1, q] += phi * w1
            acc[2, q] += phi * w2
            acc[3, q] += phi * w3
            acc[4, q] += phi * w4
            acc[5, q] += phi * w5


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _gather_near(
    rbf_table, t, p, n_k, lo_x, lo_y, lo_z, hi_x, hi_y, hi_z, near
):  # pragma: no cover - runs compiled
    """Copy into ``near`` (9, K) the columns of ``rbf_table[t, p]`` (the first ``n_k``)
    whose centre is within scaled distance 2 (the B-spline's support) of the box
    ``lo``-``hi``, zero the rest up to a whole :data:`MEMBER_LANES` step; returns the
    columns to sum (a multiple of the step)."""
    m = 0
    for i in range(n_k):
        cx = rbf_table[t, p, 0, i]
        cy = rbf_table[t, p, 1, i]
        cz = rbf_table[t, p, 2, i]
        dx = max(lo_x - cx, 0.0) + max(cx - hi_x, 0.0)
        dy = max(lo_y - cy, 0.0) + max(cy - hi_y, 0.0)
        dz = max(lo_z - cz, 0.0) + max(cz - hi_z, 0.0)
        if dx * dx + dy * dy + dz * dz < 4.0 + SUPPORT_SLACK:
            for r in range(9):
                near[r, m] = rbf_table[t, p, r, i]
            m += 1
    n_sum = -(-m // MEMBER_LANES) * MEMBER_LANES
    for i in range(m, n_sum):
        for r in range(9):
            near[r, i] = 0.0
    return m


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _local_to_world(rotation, translation, t, p, lx, ly, lz):  # pragma: no cover - runs compiled
    """(local - d̃) R̃ of part ``p`` in frame ``t``: the local position (lx, ly, lz),
    metres, back to the world; rotation (T, P, 3, 3), translation (T, P, 3), metres.
    Returns (wx, wy, wz), metres."""
    ux = lx - translation[t, p, 0]
    uy = ly - translation[t, p, 1]
    uz = lz - translation[t, p, 2]
    wx = ux * rotation[t, p, 0, 0] + uy * rotation[t, p, 1, 0] + uz * rotation[t, p, 2, 0]
    wy = ux * rotation[t, p, 0, 1] + uy * rotation[t, p, 1, 1] + uz * rotation[t, p, 2, 1]
    wz = ux * rotation[t, p, 0, 2] + uy * rotation[t, p, 1, 2] + uz * rotation[t, p, 2, 2]
    return wx, wy, wz


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _field_coefficients(quadratic, t, p):  # pragma: no cover - runs compiled
    """Ã of part ``p`` in frame ``t`` as 30 scalars, row-major (quadratic (T, P, 3, 10)):
    a tile's loops over its pairs then read them from registers, where loads from the
    array would be repeated for every pair (the loops store to other arrays, which the
    compiler cannot prove apart from it)."""
    a = quadratic[t, p]
    return (
        a[0, 0], a[0, 1], a[0, 2], a[0, 3], a[0, 4], a[0, 5], a[0, 6], a[0, 7], a[0, 8], a[0, 9],
        a[1, 0], a[1, 1], a[1, 2], a[1, 3], a[1, 4], a[1, 5], a[1, 6], a[1, 7], a[1, 8], a[1, 9],
        a[2, 0], a[2, 1], a[2, 2], a[2, 3], a[2, 4], a[2, 5], a[2, 6], a[2, 7], a[2, 8], a[2, 9],
    )  # fmt: skip


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _apply_field(c, x, y, z):  # pragma: no cover - runs compiled
    """:func:`_quadratic_field` with Ã given by :func:`_field_coefficients` (the same
    operations in the same order)."""
    xx = x * x
    yy = y * y
    zz = z * z
    xy = x * y
    yz = y * z
    zx = z * x
    lx = (
        c[0] * x + c[1] * y + c[2] * z + c[3] * xx + c[4] * yy + c[5] * zz
        + c[6] * xy + c[7] * yz + c[8] * zx + c[9]
    )  # fmt: skip
    ly = (
        c[10] * x + c[11] * y + c[12] * z + c[13] * xx + c[14] * yy + c[15] * zz
        + c[16] * xy + c[17] * yz + c[18] * zx + c[19]
    )  # fmt: skip
    lz = (
        c[20] * x + c[21] * y + c[22] * z + c[23] * xx + c[24] * yy + c[25] * zz
        + c[26] * xy + c[27] * yz + c[28] * zx + c[29]
    )  # fmt: skip
    return lx, ly, lz


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _pose_coefficients(rotation, translation, t, p):  # pragma: no cover - runs compiled
    """R̃ (row-major) and d̃ of part ``p`` in frame ``t`` as 12 scalars, for the same
    reason as :func:`_field_coefficients`."""
    r = rotation[t, p]
    d = translation[t, p]
    return (
        r[0, 0], r[0, 1], r[0, 2], r[1, 0], r[1, 1], r[1, 2], r[2, 0], r[2, 1], r[2, 2],
        d[0], d[1], d[2],
    )  # fmt: skip


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _to_world(c, lx, ly, lz):  # pragma: no cover - runs compiled
    """:func:`_local_to_world` with the pose given by :func:`_pose_coefficients`."""
    ux = lx - c[9]
    uy = ly - c[10]
    uz = lz - c[11]
    wx = ux * c[0] + uy * c[3] + uz * c[6]
    wy = ux * c[1] + uy * c[4] + uz * c[7]
    wz = ux * c[2] + uy * c[5] + uz * c[8]
    return wx, wy, wz


@numba.njit(inline="always", nogil=True, fastmath=_FASTMATH)
def _store_blend(out, t, v, sx, sy, sz, den):  # pragma: no cover - runs compiled
    """Eq. 9's β-weighted mean into ``out[t, v]``; NaN when no pair was finite (den 0)."""
    if den > 0.0:
        out[t, v, 0] = sx / den
        out[t, v, 1] = sy / den
        out[t, v, 2] = sz / den
    else:
        out[t, v, 0] = np.nan
        out[t, v, 1] = np.nan
        out[t, v, 2] = np.nan


@numba.njit(parallel=True, cache=True, nogil=True, fastmath=_FASTMATH)
def dense_kernel_no_rbf(
    vertex_local, vertex_part, vertex_weight, vertex_start, quadratic, rotation, translation, out
):  # pragma: no cover - runs compiled
    """Eqs. 8-9 without an RBF field (``rigid``, ``quadratic``), one fused pass: each
    vertex's pairs moved by their part's quadratic field, back to the world and
    β-blended at once (no (T, Q, 3) buffer of moved pairs, which costs more than the
    arithmetic when there is no RBF sum to amortise it).

    vertex_local (Q, 3) p̂⁰ and vertex_part (Q,) of the pairs sorted by vertex,
    vertex_weight (Q,) their β, vertex_start (V + 1,) CSR rows; quadratic, rotation,
    translation and out as :func:`dense_kernel`'s. A kernel of its own, not a branch of
    :func:`dense_kernel`: the default ``quadratic_rbf`` never compiles it.
    """
    n_v = vertex_start.shape[0] - 1
    n_t = quadratic.shape[0]
    # contiguous runs of vertices, every frame of a run in turn: a run's pairs stay in
    # cache across the frames and its rows of ``out`` are written in whole lines
    n_runs = min(n_v, _VERTEX_CHUNKS)
    for run in numba.prange(n_runs):
        v0 = run * n_v // n_runs
        v1 = (run + 1) * n_v // n_runs
        for t in range(n_t):
            for v in range(v0, v1):
                sx = 0.0
                sy = 0.0
                sz = 0.0
                den = 0.0
                for i in range(vertex_start[v], vertex_start[v + 1]):
                    p = vertex_part[i]
                    lx, ly, lz = _quadratic_field(
                        quadratic, t, p, vertex_local[i, 0], vertex_local[i, 1], vertex_local[i, 2]
                    )
                    wx, wy, wz = _local_to_world(rotation, translation, t, p, lx, ly, lz)
                    if np.isfinite(wx) and np.isfinite(wy) and np.isfinite(wz):
                        beta = vertex_weight[i]
                        sx += beta * wx
                        sy += beta * wy
                        sz += beta * wz
                        den += beta
                _store_blend(out, t, v, sx, sy, sz, den)


@numba.njit(nogil=True, fastmath=_FASTMATH)
def _move_tile(
    tile,
    pair_local,
    pair_seam,
    tile_start,
    tile_part,
    quadratic,
    rotation,
    translation,
    rbf_table,
    rbf_scale,
    rbf_members,
    f32_tolerance,
    near,
    near32,
    pos32,
    acc,
    loc,
    w_sum,
    pair_vertex,
    pair_slot,
    moved,
    out,
):  # pragma: no cover - runs compiled
    """Eq. 8 for one tile's pairs at every frame into ``moved`` (a pair of a vertex of
    several pairs) or straight into ``out`` (a vertex's only pair, eq. 9 being that
    pair): arguments as :func:`dense_kernel`'s, ``near`` to ``w_sum`` the calling run's scratch. A function
    of its own, not inlined into the kernel's parallel loop: numba's parallel passes
    then see a loop body of one call (a large inlined body made the kernel's compile
    take most of its time)."""
    n_t = quadratic.shape[0]
    lanes = _F32_LANES
    p = tile_part[tile]
    q0 = tile_start[tile]
    n = tile_start[tile + 1] - q0
    n_lanes = -(-n // lanes) * lanes
    n_k = rbf_members[p]
    g = rbf_scale[p]
    for t in range(n_t):  # a tile's rows of ``moved`` stay in cache over its frames
        field = _field_coefficients(quadratic, t, p)
        pose = _pose_coefficients(rotation, translation, t, p)
        for j in range(n):  # along the lanes: the pairs' local positions are SoA
            lx, ly, lz = _apply_field(
                field, pair_local[0, q0 + j], pair_local[1, q0 + j], pair_local[2, q0 + j]
            )
            loc[0, j] = lx
            loc[1, j] = ly
            loc[2, j] = lz
        lo_x = lo_y = lo_z = np.inf
        hi_x = hi_y = hi_z = -np.inf
        for j in range(n):
            lo_x = min(lo_x, loc[0, j])
            lo_y = min(lo_y, loc[1, j])
            lo_z = min(lo_z, loc[2, j])
            hi_x = max(hi_x, loc[0, j])
            hi_y = max(hi_y, loc[1, j])
            hi_z = max(hi_z, loc[2, j])
        lo_x *= g
        lo_y *= g
        lo_z *= g
        hi_x *= g
        hi_y *= g
        hi_z *= g
        n_near = 0
        if n_k > 0:
            n_near = _gather_near(rbf_table, t, p, n_k, lo_x, lo_y, lo_z, hi_x, hi_y, hi_z, near)
        ox = 0.5 * (lo_x + hi_x)
        oy = 0.5 * (lo_y + hi_y)
        oz = 0.5 * (lo_z + hi_z)
        use32 = False
        if n_near > 0:
            # float32 where its modelled rounding error stays within the
            # tolerance (_kernel_numpy.f32_error_bound), per tile and frame
            reach = max(hi_x - ox, hi_y - oy, hi_z - oz)
            w_sum[:] = 0.0
            for i in range(n_near):
                reach = max(reach, abs(near[0, i] - ox), abs(near[1, i] - oy))
                reach = max(reach, abs(near[2, i] - oz))
                for r in range(6):
                    w_sum[r] += abs(near[3 + r, i])
            bound = w_sum.max() * F32_ERROR_PER_WEIGHT * (reach + n_near)
            use32 = bound <= f32_tolerance
        if use32:
            for i in range(n_near):
                near32[0, i] = np.float32(near[0, i] - ox)
                near32[1, i] = np.float32(near[1, i] - oy)
                near32[2, i] = np.float32(near[2, i] - oz)
                for r in range(3, 9):
                    near32[r, i] = np.float32(near[r, i])
            for j in range(n):
                pos32[0, j] = np.float32(loc[0, j] * g - ox)
                pos32[1, j] = np.float32(loc[1, j] * g - oy)
                pos32[2, j] = np.float32(loc[2, j] * g - oz)
            _tile_rbf_sums_f32(near32, n_near, pos32, n_lanes, acc)
            for j in range(n):
                s = pair_seam[q0 + j]
                loc[0, j] += (1.0 - s) * acc[0, j] + s * acc[3, j]
                loc[1, j] += (1.0 - s) * acc[1, j] + s * acc[4, j]
                loc[2, j] += (1.0 - s) * acc[2, j] + s * acc[5, j]
        elif n_near > 0:
            n_sum = -(-n_near // MEMBER_LANES) * MEMBER_LANES
            for j in range(n):
                mx, my, mz, sx, sy, sz = _rbf_sums(
                    near, n_sum, loc[0, j] * g, loc[1, j] * g, loc[2, j] * g
                )
                s = pair_seam[q0 + j]
                loc[0, j] += (1.0 - s) * mx + s * sx
                loc[1, j] += (1.0 - s) * my + s * sy
                loc[2, j] += (1.0 - s) * mz + s * sz
        for j in range(n):
            wx, wy, wz = _to_world(pose, loc[0, j], loc[1, j], loc[2, j])
            slot = pair_slot[q0 + j]
            if slot >= 0:  # a vertex of several pairs: blended after all the tiles
                moved[slot, t, 0] = wx
                moved[slot, t, 1] = wy
                moved[slot, t, 2] = wz
            elif np.isfinite(wx) and np.isfinite(wy) and np.isfinite(wz):  # eq. 9, one pair
                out[t, pair_vertex[q0 + j], 0] = wx
                out[t, pair_vertex[q0 + j], 1] = wy
                out[t, pair_vertex[q0 + j], 2] = wz
            else:
                out[t, pair_vertex[q0 + j], 0] = np.nan
                out[t, pair_vertex[q0 + j], 1] = np.nan
                out[t, pair_vertex[q0 + j], 2] = np.nan


@numba.njit(parallel=True, cache=True, nogil=True, fastmath=_FASTMATH)
def dense_kernel(
    pair_local,
    pair_seam,
    tile_start,
    tile_part,
    pair_vertex,
    pair_slot,
    shared_vertex,
    shared_start,
    shared_weight,
    quadratic,
    rotation,
    translation,
    rbf_table,
    rbf_scale,
    rbf_members,
    f32_tolerance,
    moved,
    out,
):  # pragma: no cover - runs compiled
    """Deformed vertices of every frame into ``out`` (eqs. 8-9) with an RBF field
    (a part with ``rbf_members`` 0 has none; without any, :func:`dense_kernel_no_rbf`).

    pair_local (3, Q) p̂⁰ and pair_seam (Q,) s of the pairs sorted by part, in tiles tile_start (n + 1,) of
    one part each, tile_part (n,); pair_vertex (Q,) each pair's vertex, pair_slot (Q,)
    its row of ``moved`` (-1: its vertex's only pair, written to ``out`` directly);
    shared_vertex (S,) the vertices of several pairs (or none), shared_start (S + 1,)
    CSR rows of ``moved`` (their pairs' slots, in order), shared_weight (M,) the slots' β;
    quadratic (T, P, 3, 10) Ã, rotation (T, P, 3, 3) R̃, translation (T, P, 3) d̃;
    rbf_table (T, P, 9, K): rows x, y, z of the centres p̃ scaled by 2/σ, then the
    members' field's weights w / 6, then the seam field's (centres along the last axis);
    rbf_scale (P,) 2/σ; rbf_members (P,) centres summed (0: no RBF); f32_tolerance the
    largest modelled error (metres) of a tile's float32 RBF sums (negative: float64
    throughout); moved (M, T, 3) scratch (slot-major: a vertex's rows are contiguous
    over its frames); out (T, V, 3), metres (NaN for a vertex none of whose pairs is finite).
    """
    n_tiles = tile_part.shape[0]
    width = rbf_table.shape[3]
    # the tiles in _TILE_CHUNKS contiguous runs, one scratch table a run (not a tile)
    n_runs = min(n_tiles, _TILE_CHUNKS)
    n_t = quadratic.shape[0]
    # each tile at each frame: its pairs moved by the quadratic field, the centres
    # reaching its box, the RBF sums over them alone, back to the world. Two parallel
    # loops a block (not two a frame): each barrier costs the waiting thread's spin.
    # The RBF sums run in float32 with the pairs along the vector lanes where the
    # error model allows (twice the lanes of float64, no horizontal reduction per
    # pair), else in float64 with the centres along the lanes
    lanes = _F32_LANES
    tile_max = 0
    for tile in range(n_tiles):
        tile_max = max(tile_max, tile_start[tile + 1] - tile_start[tile])
    tile_max = -(-tile_max // lanes) * lanes
    for run in numba.prange(n_runs):
        near = np.empty((9, width))
        near32 = np.empty((9, width), dtype=np.float32)
        pos32 = np.zeros((3, tile_max), dtype=np.float32)
        acc = np.zeros((6, tile_max), dtype=np.float32)
        loc = np.zeros((3, tile_max))  # the tile's Ã q(p̂⁰), then its world positions
        w_sum = np.empty(6)
        for tile in range(run * n_tiles // n_runs, (run + 1) * n_tiles // n_runs):
            _move_tile(
                tile,
                pair_local,
                pair_seam,
                tile_start,
                tile_part,
                quadratic,
                rotation,
                translation,
                rbf_table,
                rbf_scale,
                rbf_members,
                f32_tolerance,
                near,
                near32,
                pos32,
                acc,
                loc,
                w_sum,
                pair_vertex,
                pair_slot,
                moved,
                out,
            )
    # eq. 9 for the vertices of several pairs (or none): their finite pairs, β-weighted
    for i in numba.prange(shared_vertex.shape[0]):
        v = shared_vertex[i]
        for t in range(n_t):
            sx = 0.0
            sy = 0.0
            sz = 0.0
            den = 0.0
            for m in range(shared_start[i], shared_start[i + 1]):
                wx = moved[m, t, 0]
                wy = moved[m, t, 1]
                wz = moved[m, t, 2]
                if np.isfinite(wx) and np.isfinite(wy) and np.isfinite(wz):
                    beta = shared_weight[m]
                    sx += beta * wx
                    sy += beta * wy
                    sz += beta * wz
                    den += beta
            _store_blend(out, t, v, sx, sy, sz, den)


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
