"""The order of a rope's markers along the rope, from their positions alone.

Porter (2012, §3.4) orders the initial traces by height, which holds for a rope that
hangs from one end. A rope held at both ends sags into a U whose bottom may lie folded
on the floor; its arms then pass closer to each other than the tape spacing, and a
spanning tree (or any nearest-neighbour walk) jumps from arm to arm. Here the order is
the **shortest open path through all the points** (a shortest Hamiltonian path): a
rope visits its markers one after the other with links of about the tape spacing, so
the true order is the shortest way through them; jumping across to the other arm
saves a link but must pay a long one to come back. With a spacing prior a link shorter
than the tape spacing costs one spacing (a step across the arms or over a fold earns
nothing), and among paths as short the one that turns least wins. The path is found by
local search (2-opt and segment moves, Or-opt) from nearest-neighbour walks, plain and
keeping their heading; for the tens of markers of a rope this takes milliseconds.
Known limit: a rope lying flat with its arms closer together than the spread of its
own links (a ladder) has zigzag orders as short as the true one.

:func:`off_chain_points` then names the points that do not belong on the rope's chain
(a ghost or a duplicate beside a marker): both of their links are much shorter than the
spacing while their two neighbours are at about the spacing from each other.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError

__all__ = ["chain_length", "off_chain_points", "shortest_open_path", "typical_spacing"]

#: Nearest-neighbour walks started (from the points farthest from the centroid first).
_WALKS = 4
#: Paths within this many metres of the shortest are as short (the turning decides).
_TIE = 1e-6
#: Longest segment moved by Or-opt, points.
_SEGMENT = 3
#: A move must shorten the path by more than this (metres) to count: no cycling on ties.
_EPS = 1e-12


def chain_length(points: np.ndarray, order: np.ndarray) -> float:
    """Length (metres) of the open path visiting ``points`` (N, 3) in ``order`` (N,)."""
    p = np.asarray(points, dtype=np.float64)[np.asarray(order)]
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def shortest_open_path(points: np.ndarray, spacing: float | None = None) -> np.ndarray:
    """Order points along the shortest open path through all of them.

    Parameters
    ----------
    points : (N, 3) float, metres
        Finite positions (e.g. the rope traces' mean positions), N >= 1.
    spacing : float, metres, optional
        The spacing prior: a link shorter than this costs as much as this (a rope's
        links are about one tape spacing long; a shorter one, across the arms of a U
        or a fold, earns nothing). None: plain Euclidean length.

    Returns
    -------
    (N,) int64
        A permutation of ``range(N)``: the order of the points along the path. Which
        end comes first is not specified (the caller orients the chain).

    Notes
    -----
    The open path is a closed tour through the points and one dummy point at zero
    cost from all of them; each start (nearest-neighbour walks from the points
    farthest from the centroid) is improved by 2-opt (reverse a stretch) and Or-opt
    (move a stretch of up to three points elsewhere, either way round) until neither
    shortens it; of the paths as short, the one that turns least is kept. Every move's
    gain is computed for all positions at once.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise ValidationError(f"points: expected (N, 3) finite positions, got shape {p.shape}")
    n = p.shape[0]
    if n <= 2:
        return np.arange(n, dtype=np.int64)
    d = np.zeros((n + 1, n + 1))  # node n is the dummy: the path's two ends meet there
    d[:n, :n] = np.linalg.norm(p[:, None] - p[None, :], axis=2)
    if spacing is not None:
        d[:n, :n] = np.maximum(d[:n, :n], float(spacing))
    far_first = np.argsort(-np.linalg.norm(p - p.mean(axis=0), axis=1), kind="stable")
    best_tour, best_len = np.arange(n + 1), np.inf
    walks = [(int(a), w) for a in far_first[: min(_WALKS, n)] for w in (None, p)]
    best_turning = np.inf
    for start, heading in walks:
        tour = _improve(_nearest_neighbour_walk(d, start, heading), d)
        length = _tour_length(tour, d)
        # of paths as short (a ladder of rungs shorter than the prior: zigzag or along
        # the arms), the one that turns least
        turning = _turning(p, tour)
        if length < best_len - _TIE or (length <= best_len + _TIE and turning < best_turning):
            best_tour, best_len, best_turning = tour, min(length, best_len), turning
    # the tour through the dummy, cut open there
    k = int(np.flatnonzero(best_tour == n)[0])
    return np.concatenate([best_tour[k + 1 :], best_tour[:k]]).astype(np.int64)


def _turning(points: np.ndarray, tour: np.ndarray) -> float:
    """Sum of ``1 - cos θ`` over the turns of the open path in ``tour`` (dummy dropped)."""
    n = points.shape[0]
    k = int(np.flatnonzero(tour == n)[0])
    step = np.diff(points[np.concatenate([tour[k + 1 :], tour[:k]])], axis=0)
    step /= np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-12)
    return float((1.0 - np.einsum("ij,ij->i", step[1:], step[:-1])).sum())


def _tour_length(tour: np.ndarray, d: np.ndarray) -> float:
    return float(d[tour, np.roll(tour, -1)].sum())


def _nearest_neighbour_walk(
    d: np.ndarray, start: int, points: np.ndarray | None = None
) -> np.ndarray:
    """(N + 1,) tour: from ``start`` always to the cheapest unvisited point, the dummy
    (last index of ``d``) last.

    With ``points`` (N, 3) the walk keeps its direction: the next point minimises
    ``d / d_min + (1 - cos θ) / 2`` (``d_min`` the cheapest step, θ the turn from the
    last step), so along the arms of a U it follows its own arm rather than stepping
    across to the other one.
    """
    n = d.shape[0] - 1
    free = np.ones(n, dtype=bool)
    tour = [start]
    free[start] = False
    heading = np.zeros(3)
    for _ in range(n - 1):
        row = np.where(free, d[tour[-1], :n], np.inf)
        if points is not None and heading.any():
            step = points - points[tour[-1]]
            norm = np.maximum(np.linalg.norm(step, axis=1), 1e-12)
            turn = 0.5 * (1.0 - step @ heading / norm)
            row = row / max(float(row.min()), 1e-12) + turn
        nxt = int(np.argmin(row))
        if points is not None:
            step = points[nxt] - points[tour[-1]]
            heading = step / max(float(np.linalg.norm(step)), 1e-12)
        tour.append(nxt)
        free[nxt] = False
    tour.append(n)
    return np.asarray(tour, dtype=np.int64)


def _improve(tour: np.ndarray, d: np.ndarray) -> np.ndarray:
    """2-opt and Or-opt on the closed ``tour`` over distance matrix ``d`` until neither
    finds a shorter tour; returns the improved tour."""
    for _ in range(50 * tour.size):  # each pass shortens the tour; bounded for safety
        better = _two_opt_move(tour, d)
        if better is None:
            better = _or_opt_move(tour, d)
        if better is None:
            return tour
        tour = better
    return tour


def _two_opt_move(tour: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """The best 2-opt move (reverse ``tour[i+1 .. j]``), or None when none shortens it."""
    m = tour.size
    nxt = np.roll(tour, -1)
    # edges (a_i, b_i) = (tour[i], tour[i+1]); replacing edges i and j by
    # (a_i, a_j) and (b_i, b_j) reverses the stretch between them
    gain = (
        d[tour, nxt][:, None]
        + d[tour, nxt][None, :]
        - d[tour[:, None], tour[None, :]]
        - d[nxt[:, None], nxt[None, :]]
    )
    i_idx, j_idx = np.triu_indices(m, k=2)
    g = gain[i_idx, j_idx]
    valid = ~((i_idx == 0) & (j_idx == m - 1))  # the same two edges, adjacent round the tour
    g = np.where(valid, g, -np.inf)
    best = int(np.argmax(g))
    if not g[best] > _EPS:
        return None
    i, j = int(i_idx[best]), int(j_idx[best])
    out = tour.copy()
    out[i + 1 : j + 1] = tour[i + 1 : j + 1][::-1]
    return out


def _or_opt_move(tour: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """The best Or-opt move (a stretch of 1 to ``_SEGMENT`` points moved between two
    other neighbours, either way round), or None when none shortens the tour."""
    m = tour.size
    best_gain, best_tour = _EPS, None
    for length in range(1, min(_SEGMENT, m - 3) + 1):
        starts = np.arange(m)
        seg = (starts[:, None] + np.arange(length)[None, :]) % m  # (m, L) positions
        first, last = tour[seg[:, 0]], tour[seg[:, -1]]
        before, after = tour[(starts - 1) % m], tour[(starts + length) % m]
        removed = d[before, first] + d[last, after] - d[before, after]  # (m,)
        # insert between tour[k] and tour[k + 1], for every edge k outside the stretch
        a, b = tour, np.roll(tour, -1)  # (m,) edge k = (a_k, b_k)
        ins_fwd = d[a[None, :], first[:, None]] + d[last[:, None], b[None, :]] - d[a, b][None, :]
        ins_rev = d[a[None, :], last[:, None]] + d[first[:, None], b[None, :]] - d[a, b][None, :]
        # edge k must not touch the stretch: k in [start + L, start - 2] round the tour
        offset = (np.arange(m)[None, :] - starts[:, None]) % m  # edge k's start from seg start
        allowed = (offset >= length) & (offset <= m - 2)
        for ins, flip in ((ins_fwd, False), (ins_rev, True)):
            gain = np.where(allowed, removed[:, None] - ins, -np.inf)
            s, k = np.unravel_index(int(np.argmax(gain)), gain.shape)
            if gain[s, k] > best_gain:
                best_gain = float(gain[s, k])
                best_tour = _moved(tour, int(s), length, int(k), flip)
    return best_tour


def _moved(tour: np.ndarray, start: int, length: int, edge: int, flip: bool) -> np.ndarray:
    """``tour`` with its stretch ``start .. start+length-1`` (round the tour) moved
    between ``tour[edge]`` and ``tour[edge + 1]``, reversed when ``flip``."""
    m = tour.size
    rolled = np.roll(tour, -start)  # the stretch first
    seg, rest = rolled[:length], rolled[length:]
    at = (edge - start) % m - length  # edge's first point within ``rest``
    piece = seg[::-1] if flip else seg
    return np.concatenate([rest[: at + 1], piece, rest[at + 1 :]])


def typical_spacing(points: np.ndarray) -> float:
    """The tape spacing of a rope from its marker positions (N, 3) metres, in any order.

    The median distance to each point's *second* nearest neighbour: along a chain
    the two nearest are the chain neighbours; where two arms of a U lie closer than the
    spacing the nearest is across and the second is still along. (The first nearest
    alone would give the gap between the arms.) Metres; 0 for fewer than 3 points.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.shape[0] < 3:
        return 0.0
    d = np.linalg.norm(p[:, None] - p[None, :], axis=2)
    return float(np.median(np.sort(d, axis=1)[:, 2]))


def off_chain_points(points: np.ndarray, spacing: float, *, short: float = 0.6) -> np.ndarray:
    """Points of an ordered chain that are not on it: a ghost or duplicate beside a marker.

    An inner point ``j`` is off the chain when both its links are shorter than
    ``short`` times the local spacing while its neighbours ``j - 1`` and ``j + 1`` lie
    within ``(1 ± (1 - short))`` local spacings of each other: the chain is whole without
    it. The local spacing is the shortest of ``spacing`` and the links just outside,
    ``j - 2 → j - 1`` and ``j + 1 → j + 2``: a rope bunched where it bends has short
    chords between real markers, but so have the links beside them, so skipping a marker
    there would leave one long link among short ones. (A rope folded back on itself has
    one short link between two markers, never two.)

    Parameters
    ----------
    points : (N, 3) float, metres
        The chain's points in order.
    spacing : float, metres
        The rope's typical spacing between neighbouring markers.
    short : float
        A link shorter than this many spacings is not a spacing.

    Returns
    -------
    (N,) bool
        True for the points off the chain (never two neighbours).
    """
    p = np.asarray(points, dtype=np.float64)
    out = np.zeros(p.shape[0], dtype=bool)
    if p.shape[0] < 3:
        return out
    link = np.linalg.norm(np.diff(p, axis=0), axis=1)  # (N - 1,)
    skip = np.linalg.norm(p[2:] - p[:-2], axis=1)  # (N - 2,) j - 1 to j + 1
    # the links just outside inner point j (= 1 .. N - 2): j - 2 -> j - 1 and j + 1 -> j + 2
    before = np.concatenate([[np.nan], link[:-2]])  # (N - 2,)
    after = np.concatenate([link[2:], [np.nan]])
    # the shortest of them and the typical spacing: a link across a hidden marker is
    # twice the spacing and must not make its neighbours look short
    local = np.fmin(np.fmin(before, after), spacing)
    inner = (
        (link[:-1] < short * local)
        & (link[1:] < short * local)
        & (np.abs(skip - local) <= (1.0 - short) * local)
    )
    # of two neighbouring candidates, keep the one whose removal leaves the better link
    cand = np.flatnonzero(inner) + 1
    taken = np.zeros(p.shape[0], dtype=bool)
    for j in cand[np.argsort(np.abs(skip[cand - 1] - spacing), kind="stable")]:
        if not (taken[j - 1] or taken[j + 1]):
            taken[j] = True
    out[taken] = True
    return out
