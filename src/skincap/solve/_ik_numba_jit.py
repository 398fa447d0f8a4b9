"""The numba kernels of :mod:`skincap.solve._ik_numba` (this module imports numba).

Both loop over frames one by one, serially (the NumPy reference is single-threaded
too), and touch only what is non-zero: a marker's rows of the Jacobian reach the root
origin and the segments on its path to the root, so its normal-equation blocks are
closed forms of those few vectors, and the tree-shaped normal matrix is eliminated
from its last parameter back (children before parents) with no fill.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def normal_equations_kernel(
    rot: np.ndarray,
    local: np.ndarray,
    pair_segment: np.ndarray,
    pair_start: np.ndarray,
    weight: np.ndarray,
    resid: np.ndarray,
    normal: np.ndarray,
    h: np.ndarray,
    g: np.ndarray,
) -> None:
    """``h[t] = normal + J^T J`` (its upper triangle) and ``g[t] = J^T r`` of every frame
    (see :func:`skincap.solve._ik_numba.normal_equations` for the shapes)."""
    n_frames, n_markers = weight.shape
    n_par = normal.shape[0]
    v = np.zeros((pair_segment.size, 3))
    for t in range(n_frames):
        ht = h[t]
        gt = g[t]
        for i in range(n_par):
            gt[i] = 0.0
            for j in range(i, n_par):
                ht[i, j] = normal[i, j]
        for m in range(n_markers):
            w = weight[t, m]
            if w == 0.0:
                continue
            # each pair's world vector, weighted: its segment's rotation times its local vector
            for q in range(pair_start[m], pair_start[m + 1]):
                s = pair_segment[q]
                for i in range(3):
                    v[q, i] = w * (
                        rot[t, s, i, 0] * local[q, 0]
                        + rot[t, s, i, 1] * local[q, 1]
                        + rot[t, s, i, 2] * local[q, 2]
                    )
            r0, r1, r2 = resid[t, m, 0], resid[t, m, 1], resid[t, m, 2]
            # the root origin's rows are w I: block w^2 I, gradient w r
            for i in range(3):
                ht[i, i] += w * w
            gt[0] += w * r0
            gt[1] += w * r1
            gt[2] += w * r2
            for qa in range(pair_start[m], pair_start[m + 1]):
                a0, a1, a2 = v[qa, 0], v[qa, 1], v[qa, 2]
                ca = 3 + 3 * pair_segment[qa]
                # a segment's rows are -[a]x: gradient [a]x r = a x r
                gt[ca] += a1 * r2 - a2 * r1
                gt[ca + 1] += a2 * r0 - a0 * r2
                gt[ca + 2] += a0 * r1 - a1 * r0
                # root origin x segment block: w I^T (-[a]x)
                ht[0, ca + 1] += w * a2
                ht[0, ca + 2] -= w * a1
                ht[1, ca] -= w * a2
                ht[1, ca + 2] += w * a0
                ht[2, ca] += w * a1
                ht[2, ca + 1] -= w * a0
                # segment blocks (-[b]x)^T (-[a]x) = (a.b) I - a b^T for the segments b at
                # or above a on the path (pairs run from the marker's segment rootwards and
                # parents come first, so b's rows come first: the upper triangle)
                for qb in range(qa, pair_start[m + 1]):
                    b0, b1, b2 = v[qb, 0], v[qb, 1], v[qb, 2]
                    cb = 3 + 3 * pair_segment[qb]
                    dot = a0 * b0 + a1 * b1 + a2 * b2
                    if cb <= ca:
                        _add_block(ht, cb, ca, dot, a0, a1, a2, b0, b1, b2)
                    else:  # a tree not in parents-first order: the transposed block
                        _add_block(ht, ca, cb, dot, b0, b1, b2, a0, a1, a2)


@njit(cache=True, nogil=True, inline="always")
def _add_block(
    ht: np.ndarray, row: int, col: int, dot: float,
    a0: float, a1: float, a2: float, b0: float, b1: float, b2: float,
) -> None:  # fmt: skip
    """``ht[row:row + 3, col:col + 3] += (a.b) I - a b^T``."""
    ht[row, col] += dot - a0 * b0
    ht[row, col + 1] -= a0 * b1
    ht[row, col + 2] -= a0 * b2
    ht[row + 1, col] -= a1 * b0
    ht[row + 1, col + 1] += dot - a1 * b1
    ht[row + 1, col + 2] -= a1 * b2
    ht[row + 2, col] -= a2 * b0
    ht[row + 2, col + 1] -= a2 * b1
    ht[row + 2, col + 2] += dot - a2 * b2


@njit(cache=True, nogil=True)
def damped_solve_kernel(
    h: np.ndarray, g: np.ndarray, damping: np.ndarray, floor: float, step: np.ndarray
) -> None:
    """``step[t] = -(h[t] + diag(damping[t] * diag(h[t]) + floor))^-1 g[t]``, ``h``
    overwritten: symmetric Gaussian elimination without pivoting (the damped matrix is
    positive definite), from the last parameter back, skipping zero couplings."""
    n_frames, n_par = g.shape
    b = np.zeros(n_par)
    nz = np.zeros(n_par, dtype=np.int64)
    for t in range(n_frames):
        a = h[t]
        for i in range(n_par):
            a[i, i] += damping[t] * a[i, i] + floor
            b[i] = g[t, i]
        # eliminate x_k from the equations j < k; only the upper triangle a[i, j], i <= j
        # is read and written (the reduced matrix stays symmetric)
        for k in range(n_par - 1, 0, -1):
            count = 0
            for j in range(k):
                if a[j, k] != 0.0:
                    nz[count] = j
                    count += 1
            inv = 1.0 / a[k, k]
            for jj in range(count):
                j = nz[jj]
                f = a[j, k] * inv
                b[j] -= f * b[k]
                for ii in range(jj + 1):
                    i = nz[ii]
                    a[i, j] -= f * a[i, k]
        # back-substitute from the first parameter on: equation k holds x_j, j <= k
        for k in range(n_par):
            s = b[k]
            for j in range(k):
                s -= a[j, k] * step[t, j]
            step[t, k] = s / a[k, k]
        for k in range(n_par):
            step[t, k] = -step[t, k]
