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

__all__ = ["MEMBER_LANES", "dense_dispatcher", "deform_vertices_numba"]

#: Members the kernel's RBF loop sums per vectorised step (LLVM's two AVX2 vectors of
#: 4). The member table is padded to a multiple of it with zero weights and the counts
#: rounded up, so the loop runs whole steps with no scalar remainder.
MEMBER_LANES = 8


@functools.cache
def dense_dispatcher() -> Any:
    """The numba dispatcher of the kernel (compiles, or loads from the cache, on first call).

    The kernel and its steps live in :mod:`skincap.deform.dense._kernel_numba_jit`, which
    imports numba: importing it here keeps numba out of the deformer's import.

    Raises
    ------
    ImportError
        numba is not installed (callers check :func:`skincap.backends.numba_available`).
    """
    from skincap.deform.dense._kernel_numba_jit import dense_kernel

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
        table, members = _rbf_table(centres, rbf_weights, scale, np.asarray(rbf_members))
        # one argument signature only (C-contiguous, writeable): a second would compile again
        dense_dispatcher()(
            pair_local, pair_part, pair_weight, vertex_start,
            *(np.require(a, np.float64, ("C", "W")) for a in (
                quadratic, rotation, translation, table, scale)),
            members, out,
        )  # fmt: skip
    return out


def _rbf_table(
    centres: np.ndarray, rbf_weights: np.ndarray, scale: np.ndarray, members: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's (T, P, 6, K') member table and the members it sums per part.

    The table holds the centres scaled by 2/σ, then w / 6, members along the last axis.
    K' is K rounded up to a multiple of :data:`MEMBER_LANES`, every slot past a part's
    ``members`` weighs exactly 0, and each part's count is rounded up the same way
    (0 stays 0: no RBF): the kernel then sums whole vector steps of members, with no
    scalar remainder loop, and the extra slots add nothing (30 members a part: ~20 %
    less CPU for the RBF variants).

    Returns
    -------
    table : (T, P, 6, K') float64, C-contiguous
    summed : (P,) int64
    """
    n_t, n_p, k = centres.shape[:3]
    width = -(-k // MEMBER_LANES) * MEMBER_LANES
    table = np.zeros((n_t, n_p, 6, width))
    table[..., :3, :k] = np.swapaxes(centres * scale[None, :, None, None], -1, -2)
    own = (np.arange(k)[None, :] < members[:, None])[None, :, :, None]  # (1, P, K, 1)
    table[..., 3:, :k] = np.swapaxes(np.where(own, rbf_weights, 0.0) * (1.0 / 6.0), -1, -2)
    summed = np.minimum(-(-members.astype(np.int64) // MEMBER_LANES) * MEMBER_LANES, width)
    return table, np.ascontiguousarray(summed, dtype=np.int64)
