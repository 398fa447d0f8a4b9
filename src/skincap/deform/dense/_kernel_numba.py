"""Compiled per-frame vertex evaluation of the dense deformer (eqs. 8-9), numba.

One parallel loop over the vertices of every frame: each vertex walks its (vertex,
part) pairs, moves its local reference position by the part's quadratic field, adds
the part's RBF sum (eq. 8) over the members whose kernel reaches it, takes the result
back to the world and blends the pairs by β (eq. 9). Nothing of size (vertices,
members) is ever stored.

The cubic B-spline kernel has compact support: a member farther than σ from the
deformed position contributes exactly 0, so the sum tests the squared distance
first and evaluates the spline only inside the support (about a third of the
members of a part on a body).

:mod:`skincap.deform.dense._kernel_numpy` is the reference this kernel must agree with
(to rounding); :class:`skincap.deform.dense.deformer.DenseDeformer` picks between
them (``backend=``, :func:`skincap.backends.resolve_backend`). The kernel compiles
once per machine into numba's on-disk cache (``cache=True``).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

__all__ = ["dense_dispatcher", "deform_vertices_numba"]


@functools.cache
def dense_dispatcher() -> Any:
    """The numba dispatcher of the kernel (compiles, or loads from the cache, on first call).

    Raises
    ------
    ImportError
        numba is not installed (callers check :func:`skincap.backends.numba_available`).
    """
    import numba

    @numba.njit(parallel=True, cache=True, nogil=True, fastmath={"contract", "reassoc"})
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
        # pair_local (Q, 3) p̂⁰ sorted by vertex, pair_part (Q,), pair_weight (Q,) β,
        # vertex_start (V + 1,) CSR rows; quadratic (T, P, 3, 10) Ã, rotation (T, P, 3, 3)
        # R̃, translation (T, P, 3) d̃; rbf_table (T, P, 6, K): rows x, y, z of the centres
        # p̃ scaled by 2/σ, then the weights w / 6 (members along the last axis, so the
        # member loop runs over contiguous rows); rbf_scale (P,) 2/σ; rbf_members (P,)
        # members summed (0: no RBF); out (T, V, 3)
        n_v = vertex_start.shape[0] - 1
        for t in range(quadratic.shape[0]):
            for v in numba.prange(n_v):
                sx = 0.0
                sy = 0.0
                sz = 0.0
                den = 0.0
                for q in range(vertex_start[v], vertex_start[v + 1]):
                    p = pair_part[q]
                    x = pair_local[q, 0]
                    y = pair_local[q, 1]
                    z = pair_local[q, 2]
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
                    n_k = rbf_members[p]
                    if n_k > 0:
                        g = rbf_scale[p]
                        gx = lx * g
                        gy = ly * g
                        gz = lz * g
                        rx = 0.0
                        ry = 0.0
                        rz = 0.0
                        # branch-free over the members (the support test would mispredict):
                        # s = 2 d / σ clipped to 2, where both cubes of φ vanish
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
                        lx += rx
                        ly += ry
                        lz += rz
                    # back to the world: (local - d̃) R̃
                    ux = lx - translation[t, p, 0]
                    uy = ly - translation[t, p, 1]
                    uz = lz - translation[t, p, 2]
                    wx = (
                        ux * rotation[t, p, 0, 0]
                        + uy * rotation[t, p, 1, 0]
                        + uz * rotation[t, p, 2, 0]
                    )
                    wy = (
                        ux * rotation[t, p, 0, 1]
                        + uy * rotation[t, p, 1, 1]
                        + uz * rotation[t, p, 2, 1]
                    )
                    wz = (
                        ux * rotation[t, p, 0, 2]
                        + uy * rotation[t, p, 1, 2]
                        + uz * rotation[t, p, 2, 2]
                    )
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

    return dense_kernel


def deform_vertices_numba(
    pair_local: np.ndarray,
    pair_part: np.ndarray,
    pair_weight: np.ndarray,
    vertex_start: np.ndarray,
    quadratic: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    centres: np.ndarray,
    rbf_weights: np.ndarray,
    rbf_scale: np.ndarray,
    rbf_members: np.ndarray,
) -> np.ndarray:
    """Deformed vertices of a block of frames with the compiled kernel (eqs. 8-9).

    Parameters
    ----------
    pair_local : (Q, 3) float64, metres
        ``p̂⁰`` of every (vertex, part) pair, sorted by vertex.
    pair_part : (Q,) int64
    pair_weight : (Q,) float64
        β of each pair.
    vertex_start : (V + 1,) int64
        Pairs of vertex ``v`` are ``vertex_start[v]:vertex_start[v + 1]``.
    quadratic : (T, P, 3, 10) float64
    rotation : (T, P, 3, 3) float64
    translation : (T, P, 3) float64, metres
    centres, rbf_weights : (T, P, K, 3) float64, metres
    rbf_scale : (P,) float64, 1/metres
        ``2 / σ_p``.
    rbf_members : (P,) int64
        Members of part ``p`` in the RBF sum (0: the part has no RBF).

    Returns
    -------
    (T, V, 3) float64, metres
        NaN for a vertex none of whose pairs is finite.
    """
    n_t, n_v = quadratic.shape[0], vertex_start.shape[0] - 1
    out = np.zeros((n_t, n_v, 3))
    if n_t and n_v:
        scale = np.asarray(rbf_scale, dtype=np.float64)
        table = np.concatenate(
            [centres * scale[None, :, None, None], rbf_weights * (1.0 / 6.0)], axis=-1
        )  # (T, P, K, 6)
        # one argument signature only (C-contiguous, writeable): a second would compile again
        dense_dispatcher()(
            pair_local, pair_part, pair_weight, vertex_start,
            *(np.require(a, np.float64, ("C", "W")) for a in (
                quadratic, rotation, translation, np.swapaxes(table, -1, -2), scale)),
            np.require(rbf_members, np.int64, ("C", "W")), out,
        )  # fmt: skip
    return out
