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
    v: np.ndarray,
    weight: np.ndarray,
    resid: np.ndarray,
    pair_start: np.ndarray,
    pair_column: np.ndarray,
    normal: np.ndarray,
    h: np.ndarray,
    g: np.ndarray,
) -> None:
    """``h[t] = normal + J^T J`` and ``g[t] = J^T r`` of every frame (see the module
    :mod:`skincap.solve._ik_numba` for the shapes)."""
    n_frames, n_markers = weight.shape
    n_par = normal.shape[0]
    for t in range(n_frames):
        ht = h[t]
        gt = g[t]
        for i in range(n_par):
            gt[i] = 0.0
            for j in range(n_par):
                ht[i, j] = normal[i, j]
        for m in range(n_markers):
            w = weight[t, m]
            if w == 0.0:
                continue
            r0, r1, r2 = resid[t, m, 0], resid[t, m, 1], resid[t, m, 2]
            # the root origin's rows are w I: block w^2 I, gradient w r
            for i in range(3):
                ht[i, i] += w * w
            gt[0] += w * r0
            gt[1] += w * r1
            gt[2] += w * r2
            for qa in range(pair_start[m], pair_start[m + 1]):
                a0, a1, a2 = v[t, qa, 0], v[t, qa, 1], v[t, qa, 2]
                ca = pair_column[qa]
                # a segment's rows are -[a]x: gradient [a]x r = a x r
                gt[ca] += a1 * r2 - a2 * r1
                gt[ca + 1] += a2 * r0 - a0 * r2
                gt[ca + 2] += a0 * r1 - a1 * r0
                # root origin x segment block w I^T (-[a]x), and its transpose
                ht[0, ca + 1] += w * a2
                ht[0, ca + 2] -= w * a1
                ht[1, ca] -= w * a2
                ht[1, ca + 2] += w * a0
                ht[2, ca] += w * a1
                ht[2, ca + 1] -= w * a0
                ht[ca + 1, 0] += w * a2
                ht[ca + 2, 0] -= w * a1
                ht[ca, 1] -= w * a2
                ht[ca + 2, 1] += w * a0
                ht[ca, 2] += w * a1
                ht[ca + 1, 2] -= w * a0
                # segment x segment block (-[a]x)^T (-[b]x) = (a.b) I - b a^T
                for qb in range(pair_start[m], pair_start[m + 1]):
                    b0, b1, b2 = v[t, qb, 0], v[t, qb, 1], v[t, qb, 2]
                    cb = pair_column[qb]
                    dot = a0 * b0 + a1 * b1 + a2 * b2
                    ht[ca, cb] += dot - b0 * a0
                    ht[ca, cb + 1] -= b0 * a1
                    ht[ca, cb + 2] -= b0 * a2
                    ht[ca + 1, cb] -= b1 * a0
                    ht[ca + 1, cb + 1] += dot - b1 * a1
                    ht[ca + 1, cb + 2] -= b1 * a2
                    ht[ca + 2, cb] -= b2 * a0
                    ht[ca + 2, cb + 1] -= b2 * a1
                    ht[ca + 2, cb + 2] += dot - b2 * a2


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
