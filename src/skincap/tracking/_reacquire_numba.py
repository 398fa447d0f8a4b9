"""The rope tracker's re-acquisition step compiled with numba: the twin of
:mod:`skincap.tracking._reacquire_numpy` (the reference), re-exported by
:mod:`skincap.tracking._steps_numba`.
"""

from __future__ import annotations

import numba
import numpy as np

from skincap.backends import key_caches_on_package
from skincap.tracking._numba_search import JIT, norm3
from skincap.tracking._refusals_numba import (
    _PAD,
    grid_run_of,
    path_back_to_trace,
    reject_overstretched,
    rigid_with_body,
)

__all__ = ["reacquire_on_shell"]

_INF = np.inf
# NumPy bools, not literals: _seat_nearest compiles once, not twice
_SHELL = np.bool_(True)
_NO_SHELL = np.bool_(False)


@numba.njit(**JIT)
def reacquire_on_shell(state, t, p):  # pragma: no cover - runs compiled
    """Twin of :func:`skincap.tracking._reacquire_numpy.reacquire_on_shell`."""
    a, b = state.offsets[t], state.offsets[t + 1]
    known, link_rest = state.known, state.link_rest
    m = known.size
    if b == a:
        return False
    prev = state.positions[t - 1]
    free = ~state.body[a:b]
    for j in range(m):
        if known[j]:
            free[state.taken[j] - a] = False
    if not free.any():  # nothing left to take: the passes below would find nothing
        return False
    found = False
    if not known.any():
        for j in (0, m - 1):
            rest = link_rest[min(j, m - 2)]
            want = prev[j] + state.velocity[j]
            if _seat_nearest(state, t, j, want, rest, _NO_SHELL, 0.0, 0.0, want, free, p):
                found = True
    for _ in range(m):
        if not _seat_pass(state, t, free, p):
            break
        found = True
    if found:
        reject_overstretched(state, t, p)
    return found


@numba.njit(**JIT)
def _seat_pass(state, t, free, p):  # pragma: no cover - runs compiled
    """Twin of the reference's ``_seat_pass``: proposals seated nearest-first (ties in
    the order proposed)."""
    a = state.offsets[t]
    known, cur, link_rest = state.known, state.cur, state.link_rest
    m = known.size
    prev = state.positions[t - 1]
    who = np.empty(2 * m, dtype=np.int64)
    what = np.empty(2 * m, dtype=np.int64)
    cost = np.empty(2 * m)
    n = 0
    for j in range(m):
        for k in (j - 1, j + 1):
            if known[j] or not (0 <= k < m and known[k]):
                continue
            rest = link_rest[min(j, k)]
            want = cur[k] + (prev[j] - prev[k])
            inner = rest - p.gamma
            outer = rest + p.adjacent_stretch * p.gamma
            c, d = _nearest_free(state, t, j, want, rest, _SHELL, inner, outer, cur[k], free, p)
            if c < 0:
                c, d = _as_last_seen(state, t, j, k, rest, free, p)
            if c < 0 and 0 < j < m - 1 and state.temp_count[j] >= p.lone_after:
                c = _lone(state, t, j, inner, outer, cur[k], free, p)
                d = _INF
            if c >= 0:
                who[n], what[n], cost[n] = j, c, d
                n += 1
    seated = False
    used = np.zeros(n, dtype=np.bool_)
    for _ in range(n):
        best = -1
        for q in range(n):  # the nearest left, the first proposed on a tie (stable)
            if not used[q] and (best < 0 or cost[q] < cost[best]):
                best = q
        used[best] = True
        j, c = who[best], what[best]
        if known[j] or not free[c]:
            continue
        _seat(state, j, a, c, free)
        seated = True
    return seated


@numba.njit(**JIT)
def _seat_nearest(
    state, t, j, want, gate, use_shell, inner, outer, centre, free, p
):  # pragma: no cover
    """Twin of the reference's ``_seat_nearest``."""
    c, _ = _nearest_free(state, t, j, want, gate, use_shell, inner, outer, centre, free, p)
    if c < 0:
        return False
    _seat(state, j, state.offsets[t], c, free)
    return True


@numba.njit(**JIT)
def _nearest_free(
    state, t, j, want, gate, use_shell, inner, outer, centre, free, p
):  # pragma: no cover
    """Twin of the reference's ``_nearest_free``: the shell is (``inner``, ``outer``,
    ``centre``) when ``use_shell``; (index in the frame or -1, distance).

    Scans only frame t's grid rows within ``gate`` of ``want`` (the tracker's frame
    grid, :func:`~skincap.tracking._refusals_numba.frame_grid`), and takes the
    candidates in ascending (distance, row) order, as the reference's stable sort
    does, by rescanning that run for the next one after each refusal: refusals are
    rare, and a rescan of a few rows costs less than a buffer per call."""
    a = state.offsets[t]
    points, order = state.points, state.grid_order
    k0, k1 = grid_run_of(state, t, p.gamma, want[0], want[1], want[2], gate * _PAD)
    last_d = -1.0  # the last candidate refused, in (distance, row) order
    last_q = -1
    while True:
        best_q = -1
        best_d = _INF
        for k in range(k0, k1):
            q = order[k]
            if not free[q - a]:
                continue
            dc = norm3(points[q, 0] - want[0], points[q, 1] - want[1], points[q, 2] - want[2])
            if not (dc <= gate and dc < _INF):
                continue
            if dc < last_d or (dc == last_d and q <= last_q):  # refused already
                continue
            if best_q >= 0 and (dc > best_d or (dc == best_d and q > best_q)):
                continue
            if use_shell:
                r = norm3(
                    points[q, 0] - centre[0], points[q, 1] - centre[1], points[q, 2] - centre[2]
                )
                if not (r >= inner and r <= outer):
                    continue
            best_q = q
            best_d = dc
        if best_q < 0:  # the usual case for a trace still hidden
            return np.int64(-1), _INF
        if _beside_trace(state, t, j, best_q, p) or rigid_with_body(
            state, t, np.int64(-1), best_q, p
        ):
            last_d = best_d
            last_q = best_q
            continue
        return np.int64(best_q - a), best_d


@numba.njit(**JIT)
def _as_last_seen(state, t, j, k, rest, free, p):  # pragma: no cover - runs compiled
    """Twin of the reference's ``_as_last_seen``."""
    last = t - 1 - state.temp_count[j]
    if state.temp_count[j] == 0 or last < 0 or state.invented[last, j] or state.invented[last, k]:
        return np.int64(-1), _INF
    want = np.empty(3)
    for c in range(3):
        want[c] = state.cur[k, c] + (state.positions[last, j, c] - state.positions[last, k, c])
    outer = rest + p.adjacent_stretch * p.gamma
    return _nearest_free(state, t, j, want, p.gamma, _SHELL, 0.0, outer, state.cur[k], free, p)


@numba.njit(**JIT)
def _lone(state, t, j, inner, outer, centre, free, p):  # pragma: no cover
    """Twin of the reference's ``_lone``: the shell is (``inner``, ``outer``,
    ``centre``)."""
    a = state.offsets[t]
    points, order = state.points, state.grid_order
    # frame t's grid rows within the shell's outer radius; the answer does not depend
    # on the order the candidates are met in (one survivor or none)
    k0, k1 = grid_run_of(state, t, p.gamma, centre[0], centre[1], centre[2], outer * _PAD)
    only = -1
    for k in range(k0, k1):
        q = order[k]
        c = q - a
        if not free[c]:
            continue
        r = norm3(points[q, 0] - centre[0], points[q, 1] - centre[1], points[q, 2] - centre[2])
        if not (r >= inner and r <= outer):
            continue
        if _beside_trace(state, t, j, q, p) or rigid_with_body(state, t, np.int64(-1), q, p):
            continue
        if only >= 0:  # two candidates: nothing says which is the rope
            return np.int64(-1)
        only = c
    return np.int64(only)


@numba.njit(**JIT)
def _seat(state, j, a, c, free):  # pragma: no cover - runs compiled
    """Twin of the reference's ``_seat``."""
    state.known[j] = True
    state.taken[j] = a + c
    for k in range(3):
        state.cur[j, k] = state.points[a + c, k]
    free[c] = False


@numba.njit(**JIT)
def _beside_trace(state, t, j, point, p):  # pragma: no cover - runs compiled
    """Twin of the reference's ``_beside_trace``."""
    reached, f, apart = path_back_to_trace(state, t, j, point, p)
    return reached >= 0 and reached != state.point_index[f, j] and apart > p.gamma


# numba keys each cache on its own file only; these kernels compile callees and constants
# from the rest of the package into themselves (skincap.backends.key_caches_on_package)
key_caches_on_package(__name__)
