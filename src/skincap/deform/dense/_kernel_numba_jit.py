"""The compiled dense kernel and its steps (eqs. 8-9), numba.

Imported only by :func:`skincap.deform.dense._kernel_numba.dense_dispatcher`, so numba
is imported on the kernel's first use, not with the deformer. The steps are inlined
into the kernel by numba (``inline="always"``): the kernel compiles to the code of one
function, and it alone is cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["dense_kernel"]

_FASTMATH = {"contract", "reassoc"}


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
def _rbf_sum(rbf_table, t, p, n_k, gx, gy, gz):  # pragma: no cover - runs compiled
    """The RBF sum (eq. 8) of part ``p`` in frame ``t`` at the position (gx, gy, gz)
    scaled by 2/σ (unitless); rbf_table (T, P, 6, K), its first ``n_k`` members summed.
    Returns (rx, ry, rz), metres."""
    rx = 0.0
    ry = 0.0
    rz = 0.0
    # branch-free over the members (the support test would mispredict):
    # s = 2 d / σ clipped to 2, where both cubes of φ vanish. LLVM runs this loop 8
    # members a step plus a scalar remainder, which the caller's padding of the table
    # to whole steps (zero weights) skips: _kernel_numba.MEMBER_LANES
    for i in range(n_k):
        dx = gx - rbf_table[t, p, 0, i]
        dy = gy - rbf_table[t, p, 1, i]
        dz = gz - rbf_table[t, p, 2, i]
        s = np.sqrt(min(dx * dx + dy * dy + dz * dz, 4.0))
        u = 2.0 - s
        b = max(1.0 - s, 0.0)
        phi = u * u * u - 4.0 * (b * b * b)  # 6 φ
        rx += phi * rbf_table[t, p, 3, i]
        ry += phi * rbf_table[t, p, 4, i]
        rz += phi * rbf_table[t, p, 5, i]
    return rx, ry, rz


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


@numba.njit(parallel=True, cache=True, nogil=True, fastmath=_FASTMATH)
def dense_kernel(
    pair_local,
    pair_part,
    pair_weight,
    vertex_start,
    quadratic,
    rotation,
    translation,
    rbf_table,
    rbf_scale,
    rbf_members,
    out,
):  # pragma: no cover - runs compiled
    """Deformed vertices of every frame into ``out`` (eqs. 8-9).

    pair_local (Q, 3) p̂⁰ sorted by vertex, pair_part (Q,), pair_weight (Q,) β,
    vertex_start (V + 1,) CSR rows; quadratic (T, P, 3, 10) Ã, rotation (T, P, 3, 3)
    R̃, translation (T, P, 3) d̃; rbf_table (T, P, 6, K): rows x, y, z of the centres
    p̃ scaled by 2/σ, then the weights w / 6 (members along the last axis, so the
    member loop runs over contiguous rows); rbf_scale (P,) 2/σ; rbf_members (P,)
    members summed (0: no RBF); out (T, V, 3), metres (NaN for a vertex none of whose
    pairs is finite).
    """
    n_v = vertex_start.shape[0] - 1
    for t in range(quadratic.shape[0]):
        for v in numba.prange(n_v):
            sx = 0.0
            sy = 0.0
            sz = 0.0
            den = 0.0
            for q in range(vertex_start[v], vertex_start[v + 1]):
                p = pair_part[q]
                lx, ly, lz = _quadratic_field(
                    quadratic, t, p, pair_local[q, 0], pair_local[q, 1], pair_local[q, 2]
                )
                n_k = rbf_members[p]
                if n_k > 0:
                    g = rbf_scale[p]
                    rx, ry, rz = _rbf_sum(rbf_table, t, p, n_k, lx * g, ly * g, lz * g)
                    lx += rx
                    ly += ry
                    lz += rz
                wx, wy, wz = _local_to_world(rotation, translation, t, p, lx, ly, lz)
                if np.isfinite(wx) and np.isfinite(wy) and np.isfinite(wz):
                    beta = pair_weight[q]
                    sx += beta * wx
                    sy += beta * wy
                    sz += beta * wz
                    den += beta
            if den > 0.0:
                out[t, v, 0] = sx / den
                out[t, v, 1] = sy / den
                out[t, v, 2] = sz / den
            else:
                out[t, v, 0] = np.nan
                out[t, v, 1] = np.nan
                out[t, v, 2] = np.nan
