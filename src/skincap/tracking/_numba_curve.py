"""The rope's curve, the neighbour velocity and F at the ends, compiled (numba).

One frame at a time, the numba twins of :func:`skincap.tracking.curve.fill_interior_on_curve`
(the Hermite curve through the measured markers in rest arc length),
:func:`skincap.tracking.curve.settle_single_gaps`, and the thesis' ṽ (eq. 3.3) and F
(eq. 3.6) of :mod:`skincap.tracking._steps_numpy`, and the twins of
:func:`skincap.tracking.curve.carry_last_seen`, :func:`skincap.tracking.curve.end_is_free` and
:func:`skincap.tracking.curve.drag_free_ends`.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._numba_search import JIT, norm3

__all__ = [
    "carry_last_seen",
    "curve_at",
    "drag_free_ends",
    "end_is_free",
    "fill_interior",
    "interp_along",
    "known_span",
    "neighbour_velocity",
    "predict_ends",
    "settle",
    "side_neighbours",
]


@numba.njit(**JIT)
def side_neighbours(known):  # pragma: no cover - runs compiled
    """Nearest known index strictly before (-1) and strictly after (M) each marker."""
    m = known.size
    before = np.empty(m, np.int64)
    after = np.empty(m, np.int64)
    last = -1
    for j in range(m):
        before[j] = last
        if known[j]:
            last = j
    nxt = m
    for j in range(m - 1, -1, -1):
        after[j] = nxt
        if known[j]:
            nxt = j
    return before, after


@numba.njit(**JIT)
def interp_along(known, values, s):  # pragma: no cover - runs compiled
    m = known.size
    before, after = side_neighbours(known)
    out = np.zeros((m, 3))
    for j in range(m):
        if known[j]:
            out[j] = values[j]
            continue
        hb, ha = before[j] >= 0, after[j] < m
        if not (hb or ha):
            continue
        if hb and ha:
            w = (s[j] - s[before[j]]) / (s[after[j]] - s[before[j]])
        else:
            w = 0.0 if hb else 1.0
        _blend_sides(values, before, after, j, 1.0 - w, w, out)
    return out


@numba.njit(**JIT)
def _blend_sides(values, before, after, j, w_before, w_after, out):  # pragma: no cover
    """``out[j] = w_before values[before[j]] + w_after values[after[j]]`` (M, 3), a
    missing side's index clipped into the rope (the caller weights it 0)."""
    m = values.shape[0]
    b = min(max(before[j], 0), m - 1)
    a = min(max(after[j], 0), m - 1)
    for c in range(3):
        out[j, c] = w_before * values[b, c] + w_after * values[a, c]


@numba.njit(**JIT)
def _slope(x0, x1, x2, s0, s1, s2):  # pragma: no cover - runs compiled
    """One coordinate's three-point slope dx/ds at s1 (x0, x1, x2 scalars, metres)."""
    h0 = s1 - s0
    h1 = s2 - s1
    d0 = (x1 - x0) / (h0 if h0 > 0 else 1.0)
    d1 = (x2 - x1) / (h1 if h1 > 0 else 1.0)
    if h0 > 0 and h1 > 0:
        return (d0 * h1 + d1 * h0) / (h0 + h1)
    if h0 > 0:
        return d0
    return d1


@numba.njit(**JIT)
def curve_at(x, known, s, j, a, b, before, after, out):  # pragma: no cover - runs compiled
    """Hermite curve between known markers a < j < b at s_j (as fill_interior_on_curve)."""
    m = known.size
    pa = a
    if a > 0:
        pa = before[a] if not known[a - 1] else a - 1
        if pa < 0:
            pa = a
    nb = b
    if b < m - 1:
        nb = after[b] if not known[b + 1] else b + 1
        if nb >= m:
            nb = b
    h = s[b] - s[a]
    u = (s[j] - s[a]) / h
    u2 = u * u
    u3 = u * u * u
    h00 = 2 * u3 - 3 * u2 + 1
    h10 = u3 - 2 * u2 + u
    h01 = -2 * u3 + 3 * u2
    h11 = u3 - u2
    # the tangents at a and b one coordinate at a time: no (3,) temporaries per call
    for c in range(3):
        ta = _slope(x[pa, c], x[a, c], x[b, c], s[pa], s[a], s[b])
        tb = _slope(x[a, c], x[b, c], x[nb, c], s[a], s[b], s[nb])
        out[c] = h00 * x[a, c] + h10 * h * ta + h01 * x[b, c] + h11 * h * tb


@numba.njit(**JIT)
def fill_interior(x, known, s, out):  # pragma: no cover - runs compiled
    """out = x with interior unknown markers on the curve; returns the interior mask."""
    m = known.size
    before, after = side_neighbours(known)
    interior = np.zeros(m, np.bool_)
    out[:] = x
    for j in range(m):
        if known[j] or before[j] < 0 or after[j] >= m:
            continue
        interior[j] = True
        curve_at(x, known, s, j, before[j], after[j], before, after, out[j])
    return interior


@numba.njit(**JIT)
def settle(out, known, spacing, weight):  # pragma: no cover - runs compiled
    """As curve.settle_single_gaps on one frame, in place on ``out`` (M, 3)."""
    m = known.size
    if weight == 0.0:
        return
    for j in range(1, m - 1):
        if known[j] or not (known[j - 1] and known[j + 1]):
            continue
        l1 = spacing[j - 1]
        l2 = spacing[j]
        d = out[j + 1] - out[j - 1]
        c = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if not c > 0:
            continue
        u = d / c
        along = (c * c + l1 * l1 - l2 * l2) / (2.0 * c)
        r2 = l1 * l1 - along * along
        centre = out[j - 1] + along * u
        off = out[j] - centre
        off = off - (off[0] * u[0] + off[1] * u[1] + off[2] * u[2]) * u
        on = np.sqrt(off[0] * off[0] + off[1] * off[1] + off[2] * off[2])
        if not (r2 > 0 and on > 1e-12):
            continue
        scale = ((1.0 - weight) * on + weight * np.sqrt(r2)) / on
        out[j] = centre + scale * off


@numba.njit(**JIT)
def neighbour_velocity(known, velocity, fallback):  # pragma: no cover - runs compiled
    m = known.size
    before, after = side_neighbours(known)
    out = np.empty((m, 3))
    for j in range(m):
        hb, ha = before[j] >= 0, after[j] < m
        if not (hb or ha):
            out[j] = fallback[j]
            continue
        if hb and ha:
            n_b = float(j - before[j])
            n_a = float(after[j] - j)
            beta = n_a / (n_a + n_b)
        else:
            beta = 1.0 if hb else 0.0
        _blend_sides(velocity, before, after, j, beta, 1.0 - beta, out)
    return out


@numba.njit(**JIT)
def _predict_end(cur, prev, v_tilde, temp_count, spacing, j, step):  # pragma: no cover
    m = cur.shape[0]
    j1, j2, j3 = j + step, j + 2 * step, j + 3 * step
    v_pred = prev[j] + v_tilde[j]
    l1 = spacing[min(j, j1)]
    if 0 <= j2 < m:
        far = j3 if 0 <= j3 < m else j2
        d = (cur[j1] - cur[far]) / 2.0
        norm = norm3(d[0], d[1], d[2])
        n_pred = cur[j1] + l1 * d / norm if norm > 0 else v_pred
    else:
        n_pred = v_pred
    alpha = 1.0 / temp_count[j]
    f = alpha * v_pred + (1.0 - alpha) * n_pred
    r = f - cur[j1]
    rn = norm3(r[0], r[1], r[2])
    cur[j] = cur[j1] + l1 * r / rn if rn > 0 else f


@numba.njit(**JIT)
def known_span(known):  # pragma: no cover - runs compiled
    """(first, last) index of a True in ``known`` (m,) bool; (-1, -1) when none is."""
    first = -1
    last = -1
    for j in range(known.size):
        if known[j]:
            if first < 0:
                first = j
            last = j
    return first, last


@numba.njit(**JIT)
def predict_ends(cur, known, prev, v_tilde, temp_count, spacing):  # pragma: no cover
    m = known.size
    first, last = known_span(known)
    for j in range(first - 1, -1, -1):
        # np.int64, not a literal: one compiled signature for both sides
        _predict_end(cur, prev, v_tilde, temp_count, spacing, j, np.int64(1))
    for j in range(last + 1, m):
        _predict_end(cur, prev, v_tilde, temp_count, spacing, j, np.int64(-1))


_CARRY_OFFSETS = np.array([-1, 1, -2, 2, -3, 3, -4, 4], dtype=np.int64)
_CARRY_NEIGHBOURS = 4


@numba.njit(**JIT)
def carry_last_seen(pred, cur, known, rows, then, then_measured, tolerance):  # pragma: no cover
    """Twin of :func:`skincap.tracking.curve.carry_last_seen` (returns a new array)."""
    out = pred.copy()
    m = known.size
    if rows.size == 0 or m < 4:
        return out
    idx = np.empty(_CARRY_NEIGHBOURS, np.int64)
    for u in range(rows.size):
        j = rows[u]
        count = 0
        for o in _CARRY_OFFSETS:
            k = j + o
            if count < _CARRY_NEIGHBOURS and 0 <= k < m and known[k] and then_measured[u, k]:
                idx[count] = k
                count += 1
        if count < 3:
            continue
        pc = np.zeros(3)
        qc = np.zeros(3)
        for i in range(count):
            pc += then[u, idx[i]]
            qc += cur[idx[i]]
        pc /= count
        qc /= count
        h = np.zeros((3, 3))
        for i in range(count):
            a = then[u, idx[i]] - pc
            b = cur[idx[i]] - qc
            for r in range(3):
                for c in range(3):
                    h[r, c] += a[r] * b[c]
        u_svd, _, vt = np.linalg.svd(h)
        det = np.sign(np.linalg.det(u_svd @ vt))
        for c in range(3):
            vt[2, c] *= det
        rot = vt.T @ u_svd.T  # R = V D U^T
        sq = 0.0
        for i in range(count):
            d = rot @ (then[u, idx[i]] - pc) + qc - cur[idx[i]]
            sq += d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        rms = np.sqrt(sq / count)
        last = then[u, j] - pc
        carried = rot @ last + qc
        spread = 0.0
        for i in range(count):
            a = then[u, idx[i]] - pc
            spread += a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
        spread = max(spread / count, 1e-300)
        error = rms * np.sqrt(
            1.0 + (last[0] * last[0] + last[1] * last[1] + last[2] * last[2]) / spread
        )
        w = 1.0 / (1.0 + (error / tolerance) ** 2)
        for c in range(3):
            out[j, c] = w * carried[c] + (1.0 - w) * out[j, c]
    return out


@numba.njit(**JIT)
def end_is_free(end, points, is_rope, reach):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking.curve.end_is_free`."""
    r2 = reach * reach
    for i in range(points.shape[0]):
        if is_rope[i]:
            continue
        d0 = points[i, 0] - end[0]
        d1 = points[i, 1] - end[1]
        d2 = points[i, 2] - end[2]
        if d0 * d0 + d1 * d1 + d2 * d2 <= r2:
            return False
    return True


@numba.njit(**JIT)
def drag_free_ends(pred, known, prev, velocity, spacing, runs):  # pragma: no cover
    """Twin of :func:`skincap.tracking.curve.drag_free_ends` (returns a new array)."""
    out = pred.copy()
    m = known.size
    first, last = known_span(known)
    if first < 0:
        return out
    for side in range(2):
        lo, hi, step = (first - 1, -1, -1) if side == 0 else (last + 1, m, 1)
        for j in range(lo, hi, step):
            if not runs[j] or known[j]:
                continue
            inner = j - step
            d = prev[j] + velocity[j] - out[inner]
            dist = norm3(d[0], d[1], d[2])
            rest = spacing[min(j, inner)]
            scale = rest / dist if dist > rest else 1.0
            for c in range(3):
                out[j, c] = out[inner, c] + scale * d[c]
    return out


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
