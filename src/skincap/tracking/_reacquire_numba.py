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
            c, d = _nearest_free(
                state, t, j, want, rest, _SHELL, inner, outer, cur[k].copy(), free, p
            )
            if c < 0:
                c, d = _as_last_seen(state, t, j, k, rest, free, p)
            if c < 0 and 0 < j < m - 1 and state.temp_count[j] >= p.lone_after:
                c = _lone(state, t, j, inner, outer, cur[k].copy(), free, p)
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
    ``centre``) when ``use_shell``; (index in the frame or -1, distance)."""
    a, b = state.offsets[t], state.offsets[t + 1]
    points = state.points
    n = b - a
    d = np.full(n, _INF)
    n_ok = 0
    for c in range(n):
        if not free[c]:
            continue
        q = a + c
        dc = norm3(points[q, 0] - want[0], points[q, 1] - want[1], points[q, 2] - want[2])
        if not dc <= gate:
            continue
        if use_shell:
            r = norm3(points[q, 0] - centre[0], points[q, 1] - centre[1], points[q, 2] - centre[2])
            if not (r >= inner and r <= outer):
                continue
        d[c] = dc
        n_ok += 1
    if n_ok == 0:  # the usual case for a trace still hidden
        return np.int64(-1), _INF
    while True:
        best = -1
        for c in range(n):
            if d[c] < _INF and (best < 0 or d[c] < d[best]):
                best = c
        if best < 0:
            return np.int64(-1), _INF
        dist = d[best]
        d[best] = _INF
        if _beside_trace(state, t, j, a + best, p) or rigid_with_body(
            state, t, np.int64(-1), a + best, p
        ):
            continue
        return np.int64(best), dist


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
    return _nearest_free(
        state, t, j, want, p.gamma, _SHELL, 0.0, outer, state.cur[k].copy(), free, p
    )


@numba.njit(**JIT)
def _lone(state, t, j, inner, outer, centre, free, p):  # pragma: no cover
    """Twin of the reference's ``_lone``: the shell is (``inner``, ``outer``,
    ``centre``)."""
    a, b = state.offsets[t], state.offsets[t + 1]
    points = state.points
    only = -1
    for c in range(b - a):
        if not free[c]:
            continue
        q = a + c
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
