"""Compiled normal equations and damped solve of the IK's Levenberg-Marquardt step, numba.

The NumPy reference in :func:`skincap.solve.ik._solve_chunk` scatters every frame's
Jacobian into a dense ``(3 M, P)`` matrix (mostly zeros), multiplies it out in single
precision and hands the ``(T, P, P)`` stack to ``np.linalg.solve`` (an LU of a
dense 63 x 63 matrix per frame); together that is 60 % of the IK's time. Here

* :func:`normal_equations` builds ``h = normal + J^T J`` (its upper triangle) and
  ``g = J^T r`` (float64) per frame from the closed-form blocks of each marker:
  ``w^2 I`` for the root origin, ``-w [a]x`` between the root origin and a segment,
  ``(a . b) I - a b^T`` between two segments on its path, with ``a``, ``b`` the
  weighted world vectors those segments carry (``-[a]x`` is a segment's block of the
  marker's Jacobian rows), computed there from the rotations;
* :func:`damped_solve` adds the Levenberg-Marquardt damping and solves by block
  elimination, children first: every coupling is between a parameter block and one
  of its ancestors' (markers, link springs, joint limits), and a segment comes after
  its parent, so eliminating from the last block back updates only pairs of
  ancestors, which are coupled already -- no fill, and a fixed list of 3 x 3 block
  updates per block (:func:`ancestor_blocks`) instead of a dense LU;
* :func:`lm_steps` does both per frame with the normal matrix in one buffer that
  stays in cache, which :func:`skincap.solve.ik.solve_poses` runs.

Both agree with the NumPy reference to rounding (``tests/solve/test_ik_numba.py``).
The kernels compile once per machine into numba's on-disk cache (``cache=True``);
:func:`skincap.solve.ik.solve_poses` picks them with ``backend=``
(:func:`skincap.backends.resolve_backend`).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = [
    "ik_dispatcher",
    "normal_equations",
    "damped_solve",
    "lm_steps",
    "ancestor_blocks",
    "rotated",
]


@functools.cache
def ik_dispatcher() -> Any:
    """The numba dispatcher of the solve kernel (for :func:`skincap.backends.kernel_ready`).

    The kernels live in :mod:`skincap.solve._ik_numba_jit`, which imports numba:
    importing it here keeps numba out of ``skincap.solve``'s import.

    Raises
    ------
    ImportError
        numba is not installed (callers check :func:`skincap.backends.numba_available`).
    """
    from skincap.solve._ik_numba_jit import lm_step_kernel

    return lm_step_kernel


def normal_equations(
    rot: np.ndarray,
    local: np.ndarray,
    pair_segment: np.ndarray,
    pair_start: np.ndarray,
    weight: np.ndarray,
    resid: np.ndarray,
    normal: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame Gauss-Newton normal equations of the marker residuals.

    Parameters
    ----------
    rot : (T, S, 3, 3) float64
        World rotations of the segments.
    local : (Q, 3) float64, metres
        Per (marker, segment-on-its-path) pair, ordered by marker and within a marker
        from its segment rootwards: the vector the segment carries towards the marker
        in its own frame (its child's joint offset, or the marker's offset).
    pair_segment : (Q,) int64
        Each pair's segment.
    pair_start : (M + 1,) int64
        Marker ``m``'s pairs are ``pair_start[m]:pair_start[m + 1]``.
    weight : (T, M) float64
        Each marker's row weight (0: missing in that frame).
    resid : (T, M, 3) float64, metres
        Weighted residuals, model minus measured.
    normal : (P, P) float64, ``P = 3 + 3 S``
        Added to every frame's matrix (the link springs' constant ``J^T J``).

    Returns
    -------
    h : (T, P, P) float64
        ``normal + J^T J`` in the upper triangle (row <= column, what
        :func:`damped_solve` reads); below it, ``normal`` or partial sums.
    g : (T, P) float64
        ``J^T r``.
    """
    from skincap.solve._ik_numba_jit import normal_equations_kernel

    t, p = weight.shape[0], normal.shape[0]
    h = np.zeros((t, p, p))
    g = np.zeros((t, p))
    normal_equations_kernel(
        np.require(rot, np.float64, "C"), np.require(local, np.float64, "C"),
        np.require(pair_segment, np.int64, "C"), np.require(pair_start, np.int64, "C"),
        np.require(weight, np.float64, "C"), np.require(resid, np.float64, "C"),
        np.require(normal, np.float64, "C"), h, g,
    )  # fmt: skip
    return h, g


def ancestor_blocks(parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each parameter block's ancestor blocks, for :func:`damped_solve` and :func:`lm_steps`.

    Block 0 is the root origin, block ``s + 1`` segment ``s``'s rotation increment.

    Parameters
    ----------
    parents : (S,) int, -1 for the root, parents first (``parents[s] < s``)

    Returns
    -------
    start : (S + 2,) int64
        Block ``k``'s ancestors are ``block[start[k]:start[k + 1]]``.
    block : int64
        The root origin and the blocks of the segments above (block 0: none).
    """
    lists: list[list[int]] = [[]]
    for s, p in enumerate(np.asarray(parents, dtype=np.int64)):
        if p >= s:
            raise ValidationError(f"parents: expected parents first, segment {s} has parent {p}")
        lists.append([0] if p < 0 else [p + 1, *lists[p + 1]])
    start = np.concatenate([[0], np.cumsum([len(a) for a in lists])]).astype(np.int64)
    return start, np.array([b for a in lists for b in a], dtype=np.int64)


def damped_solve(
    h: np.ndarray, g: np.ndarray, damping: np.ndarray, floor: float, parents: np.ndarray
) -> np.ndarray:
    """Levenberg-Marquardt steps ``-(h + diag(damping * diag(h) + floor))^-1 g``.

    Parameters
    ----------
    h : (T, P, P) float64, ``P = 3 + 3 S``
        Symmetric positive semi-definite normal matrices coupling a parameter block
        only with its ancestors' (see :func:`ancestor_blocks`), read from the upper
        triangle (row <= column) and the diagonal 3 x 3 blocks; overwritten.
    g : (T, P) float64
        Gradients ``J^T r``.
    damping : (T,) float64
        Each frame's Levenberg-Marquardt factor.
    floor : float
        Added to every diagonal entry (> 0 keeps the matrix positive definite).
    parents : (S,) int, parents first

    Returns
    -------
    (T, P) float64
    """
    from skincap.solve._ik_numba_jit import damped_solve_kernel

    step = np.zeros(g.shape)
    anc_start, anc_block = ancestor_blocks(parents)
    damped_solve_kernel(
        h if h.flags.c_contiguous and h.dtype == np.float64 else np.ascontiguousarray(h, float),
        np.require(g, np.float64, "C"), np.require(damping, np.float64, "C"), float(floor),
        anc_start, anc_block, step,
    )  # fmt: skip
    return step


def lm_steps(
    rot: np.ndarray,
    local: np.ndarray,
    pair_segment: np.ndarray,
    pair_start: np.ndarray,
    weight: np.ndarray,
    resid: np.ndarray,
    normal: np.ndarray,
    gradient: np.ndarray,
    limit_segment: np.ndarray,
    limit_parent: np.ndarray,
    limit_axis: np.ndarray,
    damping: np.ndarray,
    floor: float,
    ancestors: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """:func:`normal_equations` and :func:`damped_solve` of every frame in one pass.

    Parameters
    ----------
    rot, local, pair_segment, pair_start, weight, resid, normal
        As in :func:`normal_equations`.
    gradient : (T, P) float64
        Added to ``J^T r``: the springs' and the joint limits' part of the gradient.
    limit_segment, limit_parent : (K,) int64
        The segment and the parent of each joint limit.
    limit_axis : (T, K, 3) float64
        Each limit's Jacobian row ``u`` (its segment's block; ``-u`` its parent's), zero
        where the limit holds: ``u u^T`` goes into the normal matrix.
    damping, floor
        As in :func:`damped_solve`.
    ancestors : (start, block) from :func:`ancestor_blocks`

    Returns
    -------
    (T, P) float64
        The Levenberg-Marquardt steps.
    """
    from skincap.solve._ik_numba_jit import lm_step_kernel

    step = np.zeros(gradient.shape)
    lm_step_kernel(
        np.require(rot, np.float64, "C"), np.require(local, np.float64, "C"),
        np.require(pair_segment, np.int64, "C"), np.require(pair_start, np.int64, "C"),
        np.require(weight, np.float64, "C"), np.require(resid, np.float64, "C"),
        np.require(normal, np.float64, "C"), np.require(gradient, np.float64, "C"),
        np.require(limit_segment, np.int64, "C"), np.require(limit_parent, np.int64, "C"),
        np.require(limit_axis, np.float64, "C"), np.require(damping, np.float64, "C"),
        float(floor), ancestors[0], ancestors[1], step,
    )  # fmt: skip
    return step


def rotated(step: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``exp(step) rot``: rotations ``rot (T, S, 3, 3)`` turned by the rotation vectors
    ``step (T, S, 3)`` (radians, world axes), as ``_exp(step) @ rot`` in
    :mod:`skincap.solve.ik` (to rounding); ``(T, S, 3, 3)`` float64."""
    from skincap.solve._ik_numba_jit import rotated_kernel

    out = np.zeros(rot.shape)
    rotated_kernel(np.require(step, np.float64, "C"), np.require(rot, np.float64, "C"), out)
    return out
