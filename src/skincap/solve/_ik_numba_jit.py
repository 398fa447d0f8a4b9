"""The numba kernels of :mod:`skincap.solve._ik_numba` (this module imports numba).

They loop over frames one by one, serially (the NumPy reference is single-threaded
too), and touch only what is non-zero. The parameters come in blocks of three: block 0
the root origin, block ``s + 1`` segment ``s``'s rotation increment. A marker's
Jacobian rows reach the root origin and the segments on its path to the root, so its
normal-equation blocks are closed forms of the few vectors those segments carry; and
every coupling of the normal matrix (markers, link springs, joint limits) is between a
block and one of its ancestors. Eliminating the blocks children first (parents come
first, so from the last block back) then updates only pairs of ancestors, which are
coupled already: no fill, and a fixed list of 3 x 3 block updates per block.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
def _frame_normal_equations(
    rot: np.ndarray,
    local: np.ndarray,
    pair_segment: np.ndarray,
    pair_start: np.ndarray,
    weight: np.ndarray,
    resid: np.ndarray,
    normal: np.ndarray,
    v: np.ndarray,
    ht: np.ndarray,
    gt: np.ndarray,
) -> None:
    """One frame: ``ht = normal + J^T J`` in the upper triangle (row <= column; the
    diagonal blocks whole), ``gt += J^T r``. ``rot (S, 3, 3)``, ``weight (M,)``,
    ``resid (M, 3)``; ``v (Q, 3)`` scratch."""
    n_par = normal.shape[0]
    for i in range(n_par):
        for j in range(i, n_par):
            ht[i, j] = normal[i, j]
        for j in range(3 * (i // 3), i):  # a diagonal block's lower part
            ht[i, j] = normal[i, j]
    for m in range(weight.size):
        w = weight[m]
        if w == 0.0:
            continue
        # each pair's world vector, weighted: its segment's rotation times its local vector
        for q in range(pair_start[m], pair_start[m + 1]):
            s = pair_segment[q]
            for i in range(3):
                v[q, i] = w * (
                    rot[s, i, 0] * local[q, 0]
                    + rot[s, i, 1] * local[q, 1]
                    + rot[s, i, 2] * local[q, 2]
                )
        r0, r1, r2 = resid[m, 0], resid[m, 1], resid[m, 2]
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
                _add_block(ht, cb, ca, a0 * b0 + a1 * b1 + a2 * b2, a0, a1, a2, b0, b1, b2)


@njit(cache=True, nogil=True)
def _frame_damped_solve(
    a: np.ndarray,
    b: np.ndarray,
    damping: float,
    floor: float,
    anc_start: np.ndarray,
    anc_block: np.ndarray,
    dinv: np.ndarray,
    f: np.ndarray,
    x: np.ndarray,
) -> None:
    """One frame: ``x = (a + diag(damping * diag(a) + floor))^-1 b`` by block elimination,
    children first. ``a (P, P)`` is read in its upper triangle and diagonal blocks and
    overwritten, ``b (P,)`` overwritten; block ``k``'s ancestors are
    ``anc_block[anc_start[k]:anc_start[k + 1]]``; ``dinv (P / 3, 3, 3)`` and
    ``f (depth, 3, 3)`` scratch."""
    n_par = b.size
    for i in range(n_par):
        a[i, i] += damping * a[i, i] + floor
    for k in range(n_par // 3 - 1, -1, -1):
        c = 3 * k
        # the pivot block's inverse, through its Cholesky factor (it is positive definite)
        l00 = np.sqrt(a[c, c])
        l10 = a[c, c + 1] / l00
        l20 = a[c, c + 2] / l00
        l11 = np.sqrt(a[c + 1, c + 1] - l10 * l10)
        l21 = (a[c + 1, c + 2] - l20 * l10) / l11
        l22 = np.sqrt(a[c + 2, c + 2] - l20 * l20 - l21 * l21)
        # inverse of the factor, m = L^-1 (lower), then dinv = m^T m
        m00 = 1.0 / l00
        m11 = 1.0 / l11
        m22 = 1.0 / l22
        m10 = -l10 * m00 * m11
        m21 = -l21 * m11 * m22
        m20 = -(l20 * m00 + l21 * m10) * m22
        d = dinv[k]
        d[0, 0] = m00 * m00 + m10 * m10 + m20 * m20
        d[0, 1] = m10 * m11 + m20 * m21
        d[0, 2] = m20 * m22
        d[1, 1] = m11 * m11 + m21 * m21
        d[1, 2] = m21 * m22
        d[2, 2] = m22 * m22
        d[1, 0], d[2, 0], d[2, 1] = d[0, 1], d[0, 2], d[1, 2]
        lo, hi = anc_start[k], anc_start[k + 1]
        # f_i = C_i D^-1 for each ancestor block i (C_i = a[i-block, k-block]); b_i -= f_i b_k
        for n in range(lo, hi):
            r = 3 * anc_block[n]
            fn = f[n - lo]
            for i in range(3):
                for j in range(3):
                    fn[i, j] = (
                        a[r + i, c] * d[0, j]
                        + a[r + i, c + 1] * d[1, j]
                        + a[r + i, c + 2] * d[2, j]
                    )
                b[r + i] -= fn[i, 0] * b[c] + fn[i, 1] * b[c + 1] + fn[i, 2] * b[c + 2]
        # the ancestors' blocks lose f_i C_j^T (the upper triangle; diagonal blocks whole)
        for n in range(lo, hi):
            ri = 3 * anc_block[n]
            fn = f[n - lo]
            for n2 in range(lo, hi):
                rj = 3 * anc_block[n2]
                if rj < ri:
                    continue
                for i in range(3):
                    for j in range(3):
                        a[ri + i, rj + j] -= (
                            fn[i, 0] * a[rj + j, c]
                            + fn[i, 1] * a[rj + j, c + 1]
                            + fn[i, 2] * a[rj + j, c + 2]
                        )
    # back-substitute parents first: x_k = D_k^-1 (b_k - sum_i C_i^T x_i)
    for k in range(n_par // 3):
        c = 3 * k
        s0, s1, s2 = b[c], b[c + 1], b[c + 2]
        for n in range(anc_start[k], anc_start[k + 1]):
            r = 3 * anc_block[n]
            for i in range(3):
                s0 -= a[r + i, c] * x[r + i]
                s1 -= a[r + i, c + 1] * x[r + i]
                s2 -= a[r + i, c + 2] * x[r + i]
        d = dinv[k]
        for i in range(3):
            x[c + i] = d[i, 0] * s0 + d[i, 1] * s1 + d[i, 2] * s2


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
    """:func:`_frame_normal_equations` of every frame into ``h (T, P, P)``, ``g (T, P)`` (zeros)."""
    v = np.zeros((pair_segment.size, 3))
    for t in range(weight.shape[0]):
        _frame_normal_equations(
            rot[t], local, pair_segment, pair_start, weight[t], resid[t], normal, v, h[t], g[t]
        )


@njit(cache=True, nogil=True)
def damped_solve_kernel(
    h: np.ndarray,
    g: np.ndarray,
    damping: np.ndarray,
    floor: float,
    anc_start: np.ndarray,
    anc_block: np.ndarray,
    step: np.ndarray,
) -> None:
    """``step[t] = -`` :func:`_frame_damped_solve` of every frame (``h`` overwritten)."""
    n_frames, n_par = g.shape
    dinv = np.zeros((n_par // 3, 3, 3))
    f = np.zeros((n_par // 3, 3, 3))
    b = np.zeros(n_par)
    x = np.zeros(n_par)
    for t in range(n_frames):
        b[:] = g[t]
        _frame_damped_solve(h[t], b, damping[t], floor, anc_start, anc_block, dinv, f, x)
        step[t] = -x


@njit(cache=True, nogil=True)
def lm_step_kernel(
    rot: np.ndarray,
    local: np.ndarray,
    pair_segment: np.ndarray,
    pair_start: np.ndarray,
    weight: np.ndarray,
    resid: np.ndarray,
    normal: np.ndarray,
    g0: np.ndarray,
    limit_segment: np.ndarray,
    limit_parent: np.ndarray,
    limit_axis: np.ndarray,
    damping: np.ndarray,
    floor: float,
    anc_start: np.ndarray,
    anc_block: np.ndarray,
    step: np.ndarray,
) -> None:
    """Both of the above per frame, the normal matrix in one buffer that stays in cache;
    each joint limit ``k`` adds ``u u^T`` (``u = limit_axis[t, k]``) to its segment's and
    its parent's diagonal blocks and ``-u u^T`` between them; ``g0 (T, P)`` is the rest
    of the gradient (springs, limits)."""
    n_frames, n_par = g0.shape
    ht = np.zeros((n_par, n_par))
    gt = np.zeros(n_par)
    x = np.zeros(n_par)
    v = np.zeros((pair_segment.size, 3))
    dinv = np.zeros((n_par // 3, 3, 3))
    f = np.zeros((n_par // 3, 3, 3))
    for t in range(n_frames):
        gt[:] = g0[t]
        _frame_normal_equations(
            rot[t], local, pair_segment, pair_start, weight[t], resid[t], normal, v, ht, gt
        )
        for k in range(limit_segment.size):
            cs, cp = 3 + 3 * limit_segment[k], 3 + 3 * limit_parent[k]
            u = limit_axis[t, k]
            for i in range(3):
                for j in range(3):
                    uu = u[i] * u[j]
                    ht[cs + i, cs + j] += uu
                    ht[cp + i, cp + j] += uu
                    ht[cp + i, cs + j] -= uu
        _frame_damped_solve(ht, gt, damping[t], floor, anc_start, anc_block, dinv, f, x)
        step[t] = -x


@njit(cache=True, nogil=True)
def rotated_kernel(step: np.ndarray, rot: np.ndarray, out: np.ndarray) -> None:
    """``out[t, s] = exp(step[t, s]) rot[t, s]`` (Rodrigues, as ``skincap.solve.ik._exp``)."""
    n_frames, n_seg = step.shape[0], step.shape[1]
    for t in range(n_frames):
        for s in range(n_seg):
            w0, w1, w2 = step[t, s, 0], step[t, s, 1], step[t, s, 2]
            theta2 = w0 * w0 + w1 * w1 + w2 * w2
            theta = np.sqrt(theta2)
            if theta < 1e-8:
                a = 1.0 - theta2 / 6.0
                b = 0.5 - theta2 / 24.0
            else:
                a = np.sin(theta) / theta
                b = (1.0 - np.cos(theta)) / theta2
            # exp = I + a K + b K^2, K = [w]x, K^2 = w w^T - theta^2 I
            e00 = 1.0 + b * (w0 * w0 - theta2)
            e11 = 1.0 + b * (w1 * w1 - theta2)
            e22 = 1.0 + b * (w2 * w2 - theta2)
            e01 = -a * w2 + b * w0 * w1
            e10 = a * w2 + b * w0 * w1
            e02 = a * w1 + b * w0 * w2
            e20 = -a * w1 + b * w0 * w2
            e12 = -a * w0 + b * w1 * w2
            e21 = a * w0 + b * w1 * w2
            r = rot[t, s]
            o = out[t, s]
            for j in range(3):
                o[0, j] = e00 * r[0, j] + e01 * r[1, j] + e02 * r[2, j]
                o[1, j] = e10 * r[0, j] + e11 * r[1, j] + e12 * r[2, j]
                o[2, j] = e20 * r[0, j] + e21 * r[1, j] + e22 * r[2, j]
