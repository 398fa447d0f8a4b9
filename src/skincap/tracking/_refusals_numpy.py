"""The rope tracker's refusals in NumPy (the reference): which taken points are not the rope.

Part of the per-frame steps of :mod:`skincap.tracking._steps_numpy` (which re-exports
the public ones), kept in their own module because both the matching steps there and
the re-acquisition in :mod:`skincap.tracking._reacquire_numpy` use them:
:func:`rigid_with_body` (does a point move rigidly with body points?),
:func:`reject_overstretched` and :func:`reject_odd_motion`. Each has a numba twin of
the same name and signature in :mod:`skincap.tracking._refusals_numba`.
"""

from __future__ import annotations

import numpy as np

from skincap.tracking.state import StepParams, TrackState

__all__ = ["path_back_to_trace", "reject_odd_motion", "reject_overstretched", "rigid_with_body"]


def _squared_distances(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(len(x), len(y)) squared distances, per axis (as the numba twin adds them)."""
    dx = x[:, None, 0] - y[None, :, 0]
    dy = x[:, None, 1] - y[None, :, 1]
    dz = x[:, None, 2] - y[None, :, 2]
    return dx * dx + dy * dy + dz * dz


def path_back_to_trace(
    state: TrackState, t: int, j: int, point: int, p: StepParams
) -> tuple[int, int, float]:
    """Follow ``point`` of frame t back to the last frame trace ``j`` was measured in.

    Each step back takes the nearest point within γ of where the path's last move
    takes it (constant velocity), through up to ``rigid_window`` frames. Returns
    ``(point reached, its frame, its distance to j's own point there, m)`` at the
    first frame ``j`` was measured, or ``(-1, -1, inf)`` when the path breaks (an empty frame, or a move beyond γ: no
    evidence) or ``j`` was not measured in the window.
    """
    points, offsets, point_index = state.points, state.offsets, state.point_index
    x = points[point]
    v = np.zeros(3)
    for f in range(t - 1, max(t - 1 - p.rigid_window, -1), -1):
        fa, fb = int(offsets[f]), int(offsets[f + 1])
        if fb == fa:
            return -1, -1, np.inf
        d = np.sqrt(_squared_distances(points[fa:fb], (x - v)[None])[:, 0])
        n = int(np.argmin(d))
        if not d[n] <= p.gamma:
            return -1, -1, np.inf
        mine = int(point_index[f, j])
        if mine >= 0:
            e = points[fa + n] - points[mine]
            return fa + n, f, float(np.sqrt(e @ e))
        v = x - points[fa + n]
        x = points[fa + n]
    return -1, -1, np.inf


def rigid_with_body(state: TrackState, t: int, j: int, point: int, p: StepParams) -> bool:
    """True when ``point`` of frame t moves rigidly with body points (beyond the thesis).

    The point's path over the last ``p.rigid_window`` frames is trace ``j``'s points
    where the trace was measured in all of them; otherwise (or ``j < 0``) the point is
    followed backward itself at constant velocity, to the nearest point when that
    lies within ``2 rigid_range`` spacings and the second nearest twice as far; a
    frame without such a point means no evidence (False), as does a path moving less
    than ``rigid_move`` spacings. Every point of frame t within ``rigid_radius``
    spacings that the rope does not take (``state.taken``) is followed backward,
    moving as the path moved, to the nearest point within ``rigid_range`` spacings of
    that prediction the rope did not take; points within γ of the prediction V of a
    trace hidden in frame t - 1 and not found yet are not partners (that trace's
    marker). The point is body-like when at least
    ``rigid_partners`` of them keep their distance to it within ``rigid_range``
    spacings over the whole window. Spacings are the median rest spacing. Frames
    before ``rigid_window``: False.
    """
    window = p.rigid_window
    if t < window:
        return False
    points, offsets, point_index = state.points, state.offsets, state.point_index
    spacing = p.median_spacing
    tol = p.rigid_range * spacing
    hist = point_index[t - window : t, j] if j >= 0 else np.full(window, -1)
    if np.any(hist < 0):
        traj = _follow_back(points, offsets, t, window, point, tol)
        if traj is None:
            return False
    else:
        traj = np.concatenate([points[hist], points[point][None]])  # (W + 1, 3)
    if np.max(np.linalg.norm(traj - traj[-1], axis=1)) < p.rigid_move * spacing:
        return False
    a, b = int(offsets[t]), int(offsets[t + 1])
    frame = points[a:b]
    d0 = np.linalg.norm(frame - traj[-1], axis=1)
    cand = (d0 < p.rigid_radius * spacing) & (np.arange(a, b) != point)
    taken = state.taken
    cand[taken[(taken >= a) & (taken < b)] - a] = False
    hidden = _hidden_predictions(state, t)
    if cand.any() and hidden.shape[0]:
        # a point a hidden trace may yet take is rope, not a body partner: hidden rope
        # neighbours moving together would otherwise confirm each other as body
        cand &= ~(_squared_distances(frame, hidden) < p.gamma * p.gamma).any(axis=1)
    found = 0
    for c in np.nonzero(cand)[0]:
        if _keeps_distance(points, offsets, point_index, t, window, traj, frame[c], d0[c], tol):
            found += 1
            if found >= p.rigid_partners:
                return True
    return False


def _hidden_predictions(state: TrackState, t: int) -> np.ndarray:
    """(H, 3) metres: the predictions V (position in frame t - 1 plus velocity) of the
    traces hidden in frame t - 1 and not found yet in frame t, finite ones only."""
    hidden = (state.point_index[t - 1] < 0) & ~state.known
    pred = state.positions[t - 1][hidden] + state.velocity[hidden]
    return pred[np.isfinite(pred).all(axis=1)]


def _follow_back(
    points: np.ndarray, offsets: np.ndarray, t: int, window: int, point: int, tol: float
) -> np.ndarray | None:
    """(W + 1, 3) the point's path back through the window by unambiguous nearest
    points at constant velocity, last row the point; None where it is ambiguous."""
    traj = np.empty((window + 1, 3))
    traj[-1] = points[point]
    v = np.zeros(3)
    for f in range(t - 1, t - window - 1, -1):
        fa, fb = int(offsets[f]), int(offsets[f + 1])
        if fb - fa < 2:
            return None
        x = traj[f - t + window + 1]
        dd = np.linalg.norm(points[fa:fb] - (x - v), axis=1)
        o = np.argsort(dd)[:2]
        if not (dd[o[0]] < 2.0 * tol and dd[o[1]] > 2.0 * dd[o[0]]):
            return None
        traj[f - t + window] = points[fa + o[0]]
        v = x - traj[f - t + window]
    return traj


def _keeps_distance(
    points: np.ndarray,
    offsets: np.ndarray,
    point_index: np.ndarray,
    t: int,
    window: int,
    traj: np.ndarray,
    q: np.ndarray,
    dq: float,
    tol: float,
) -> bool:
    """True when the partner at ``q`` (distance ``dq`` from the path's end) follows the
    path ``traj`` (W + 1, 3) back through the window at a constant distance."""
    for f in range(t - 1, t - window - 1, -1):
        fa, fb = int(offsets[f]), int(offsets[f + 1])
        if fb == fa:
            return False
        pred = q + (traj[f - t + window] - traj[f - t + window + 1])
        dd = np.linalg.norm(points[fa:fb] - pred, axis=1)
        dd[point_index[f][(point_index[f] >= fa) & (point_index[f] < fb)] - fa] = np.inf
        n = int(np.argmin(dd))
        q = points[fa + n]
        if not (dd[n] < tol and abs(np.linalg.norm(q - traj[f - t + window]) - dq) < tol):
            return False
    return True


# ------------------------------------------------------------------ refusals
def link_limit(s: np.ndarray, link_rest: np.ndarray, ja: int, jb: int, p: StepParams) -> float:
    """Largest chord between measured markers ``ja < jb`` that :func:`reject_overstretched`
    allows, metres: neighbours their rest spacing (the larger of the rest arc length and
    the learnt ``link_rest``) plus ``adjacent_stretch`` γ, others ``stretch`` times the
    rest arc length plus γ (the twin of ``_refusals_numba._link_limit``)."""
    ds = float(s[jb] - s[ja])
    if jb - ja == 1:
        return max(ds, float(link_rest[ja])) + p.adjacent_stretch * p.gamma
    return p.stretch * ds + p.gamma


def reject_overstretched(state: TrackState, t: int, p: StepParams) -> None:
    """Refuse taken points that would stretch the rope (beyond the thesis), in place.

    Two measured markers ``a < b`` lie at most ``stretch (s_b - s_a) + γ`` apart,
    neighbours at most their rest spacing plus ``adjacent_stretch γ``. When
    consecutive measured markers break that, the measured markers kept are the best
    chain in which every consecutive pair obeys it (:func:`_keep_best_chain`), a
    marker on a point moving rigidly with body points (:func:`rigid_with_body`)
    counting against it. The others are un-taken (``known``, ``taken``).
    """
    known = state.known
    idx = np.nonzero(known)[0]
    if idx.size < 2:
        return
    cur, s = state.cur, state.arclength
    xs = cur[idx]
    chord = np.linalg.norm(xs[1:] - xs[:-1], axis=1)
    ds1 = s[idx[1:]] - s[idx[:-1]]
    adjacent = idx[1:] - idx[:-1] == 1
    link = state.link_rest[np.minimum(idx[:-1], state.link_rest.size - 1)]
    lim1 = np.where(
        adjacent, np.maximum(ds1, link) + p.adjacent_stretch * p.gamma, p.stretch * ds1 + p.gamma
    )
    if np.all(chord <= lim1):
        return
    rigid = np.array([rigid_with_body(state, t, int(j), int(state.taken[j]), p) for j in idx])
    keep = _keep_best_chain(
        cur[idx], s[idx], idx, rigid, p.gamma, p.stretch, p.adjacent_stretch, state.link_rest
    )
    rows = idx[~keep]
    known[rows] = False
    state.taken[rows] = -1


def _keep_best_chain(
    xs: np.ndarray,
    si: np.ndarray,
    idx: np.ndarray,
    rigid: np.ndarray,
    gamma: float,
    stretch: float,
    adjacent_stretch: float,
    link_rest: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) bool: the measured markers kept, by dynamic programming over the chain.

    ``xs`` (n, 3) their positions, ``si`` (n,) rest arc lengths, ``idx`` (n,) marker
    numbers, ``rigid`` (n,) bool body-like; ``link_rest`` (M - 1,) metres, each link's
    learnt rest length (``TrackState.link_rest``), raises a neighbouring pair's limit
    above its rest arc length (default: the arc length only). Each marker kept counts +1 (-1 where
    body-like: the body-like side of a stretched link goes, never the rope-like
    side), each link less half its deformation (chord below or beyond the rest arc
    length, relative: a trace that slipped onto its neighbour's marker, or onto a
    point beside the rope).
    """
    n = idx.size
    dist = np.linalg.norm(xs[:, None] - xs[None, :], axis=2)  # (n, n)
    ds = si[None, :] - si[:, None]  # s_b - s_a
    adjacent = idx[None, :] - idx[:, None] == 1
    rest = ds
    if link_rest is not None:
        link = link_rest[np.minimum(idx, link_rest.size - 1)]  # the link after each marker
        rest = np.maximum(ds, link[:, None])
    limit = np.where(adjacent, rest + adjacent_stretch * gamma, stretch * ds + gamma)
    feasible = np.triu(dist <= limit, k=1)
    dev = (ds - dist) / np.where(ds > 0, ds, 1.0)
    squeeze = np.clip(dev, 0.0, 1.0) + np.clip(-dev, 0.0, 1.0)  # compressed or stretched
    w = np.where(rigid, -1.0, 1.0)
    gain = np.where(feasible, w[None, :] - 0.5 * squeeze, -np.inf)  # a link: marker − deformation
    score = w.copy()
    back = np.full(n, -1, dtype=np.int64)
    for b in range(1, n):
        cand = score[:b] + gain[:b, b]
        a = int(np.argmax(cand))
        if cand[a] > score[b]:
            score[b] = cand[a]
            back[b] = a
    keep = np.zeros(n, dtype=bool)
    b = int(np.argmax(score))
    while b >= 0:
        keep[b] = True
        b = int(back[b])
    return keep


def reject_odd_motion(state: TrackState, t: int, p: StepParams) -> None:
    """Refuse taken points that do not move with the rope (beyond the thesis), in place.

    A steady inner marker whose two neighbours are measured moves, from frame t - 1,
    within γ of the mean of their moves (the rope is smooth); a point that does not
    belongs to something else. Markers that are not steady are not judged here: one
    coming back from a gap "moves" by the error of its invented position.
    """
    known = state.known
    steady = state.temp_count == 0
    inner = known[1:-1] & known[:-2] & known[2:] & steady[1:-1]
    if not inner.any():
        return
    move = state.cur - state.positions[t - 1]
    expected = 0.5 * (move[:-2] + move[2:])
    odd = inner & (np.linalg.norm(move[1:-1] - expected, axis=1) > p.gamma)
    if odd.any():
        idx = np.nonzero(odd)[0] + 1
        known[idx] = False
        state.taken[idx] = -1
