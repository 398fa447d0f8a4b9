"""A hidden held end carried by the hand that holds it, in NumPy (the reference).

Beyond Porter (2012). A held end of the rope moves rigidly with the hand (or foot)
that holds it; the thesis' F (eq. 3.6) points the end straight out from its last
measured links instead, which a rope bent at the hand misses by 15-30 cm. When an
end first goes missing, the points beside it in its last measured frame that the rope
did not take (within :data:`~skincap.tracking.curve.HELD_END_REACH`, the reach that
makes an end *held*) become its hand anchors (:func:`seat_hand`; a frame where every
end is measured does no hand work); while it is hidden they are followed frame by
frame, unambiguously, at constant velocity (:func:`follow_hand`), and the end is
placed where the rigid motion of the anchors since its last measured frame takes it
(:func:`carry_with_hand`), and searched for there (in the frame it goes missing, also
at the free point nearest there: :func:`search_with_hand`). While it is hidden, its anchors
are body points, which a trace back from a gap does not take.

The anchors live in :class:`~skincap.tracking.state.TrackState` (``hand_index``,
``hand_then``, ``hand_vel``; row 0 for trace 0, row 1 for trace M - 1). Each function
has a numba twin of the same name and signature in :mod:`skincap.tracking._hand_numba`.
"""

from __future__ import annotations

import numpy as np

from skincap.tracking._refusals_numpy import link_limit, rigid_with_body
from skincap.tracking.curve import HELD_END_REACH
from skincap.tracking.state import StepParams, TrackState

__all__ = [
    "carry_with_hand",
    "follow_hand",
    "place_with_hand",
    "release_hand",
    "search_with_hand",
    "seat_hand",
    "zip_with_hand",
]


def _ends(m: int) -> tuple[tuple[int, int], tuple[int, int]]:
    """(row of the anchors, trace) for both ends of a rope of ``m`` markers."""
    return (0, 0), (1, m - 1)


def seat_hand(state: TrackState, t: int, p: StepParams) -> None:
    """While frame t is matched: each end not measured in frame t (so far) that was
    measured in frame t - 1 and has no anchors yet takes as anchors the points of
    frame t - 1 the rope did not take there (``point_index``) within
    ``HELD_END_REACH`` of it, nearest first (at most ``hand_index.shape[1]``), moving
    as the end moved (metres per frame), and follows them into frame t
    (:func:`follow_hand`'s rule). An end with none there (a free end) has no anchors.

    Seated only when an end first goes missing, so a frame where every end is
    measured costs nothing here; calling it again in the same frame changes nothing.
    Call before ``temp_count`` counts frame t.
    """
    if t < 1:
        return
    f = t - 1
    a, b = int(state.offsets[f]), int(state.offsets[f + 1])
    k_max = state.hand_index.shape[1]
    for row, e in _ends(state.known.size):
        if state.known[e] or state.temp_count[e] > 0 or np.any(state.hand_index[row] >= 0):
            continue
        if b == a:
            continue
        d2 = np.sum((state.points[a:b] - state.positions[f, e]) ** 2, axis=1)
        taken = state.point_index[f]
        taken = taken[(taken >= a) & (taken < b)]
        d2[taken - a] = np.inf
        order = np.argsort(d2, kind="mergesort")[:k_max]
        order = order[d2[order] <= HELD_END_REACH * HELD_END_REACH]
        n = order.size
        state.hand_index[row, :n] = order + a
        state.hand_then[row, :n] = state.points[order + a]
        state.hand_vel[row, :n] = state.velocity[e]
        _follow_row(state, t, row, p)


def release_hand(state: TrackState, t: int, p: StepParams) -> None:
    """After frame t is committed: each end measured in frame t drops its anchors (it
    takes new ones from its last measured frame when it next goes missing)."""
    for row, e in _ends(state.known.size):
        if state.known[e]:
            state.hand_index[row] = -1


def follow_hand(state: TrackState, t: int, p: StepParams) -> None:
    """Before frame t is matched: move the anchors of each end hidden in frame t - 1
    into frame t (:func:`_follow_row`). They are body points of frame t
    (``state.body``, ``body_vel``): a trace coming back from a gap does not take them
    (the hidden end's F, or its carried position, lies among its hand's markers), and
    the body chains continue from them, so hand markers that dropped out before are
    body again."""
    for row in range(2):
        if np.any(state.hand_index[row] >= 0):
            _follow_row(state, t, row, p)


def _carries(state: TrackState) -> bool:
    """An end hidden so far this frame has anchors: :func:`carry_with_hand` moves it
    (most frames none has, and the hand steps have nothing to do)."""
    return any(
        not state.known[e] and np.any(state.hand_index[row] >= 0)
        for row, e in _ends(state.known.size)
    )


def _follow_row(state: TrackState, t: int, row: int, p: StepParams) -> None:
    """Move every anchor of ``row`` to frame t's point nearest its constant-velocity
    prediction, when that lies within γ, the second nearest lies more than twice as
    far and no earlier anchor of the same end took it; otherwise the anchor is dropped
    (no evidence beats a wrong hand). An end hidden in frame t - 1 makes them body."""
    a, b = int(state.offsets[t]), int(state.offsets[t + 1])
    frame = state.points[a:b]
    end = 0 if row == 0 else state.known.size - 1
    for k in range(state.hand_index.shape[1]):
        q = int(state.hand_index[row, k])
        if q < 0:
            continue
        state.hand_index[row, k] = -1
        if b - a < 1:
            continue
        d2 = np.sum((frame - (state.points[q] + state.hand_vel[row, k])) ** 2, axis=1)
        order = np.argsort(d2, kind="mergesort")[:2]
        d1 = d2[order[0]]
        if d1 > p.gamma * p.gamma:
            continue
        if order.size > 1 and d2[order[1]] <= 4.0 * d1:
            continue
        new = int(order[0]) + a
        if np.any(state.hand_index[row, :k] == new):
            continue
        state.hand_index[row, k] = new
        state.hand_vel[row, k] = state.points[new] - state.points[q]
        if state.temp_count[end] > 0:  # a hidden end's hand is body
            state.body[new] = True
            state.body_vel[new] = state.hand_vel[row, k]


def carry_with_hand(state: TrackState, t: int, cur: np.ndarray, p: StepParams) -> None:
    """Place each hidden end of frame t that has anchors in ``cur`` (M, 3), in place.

    The end moves from its last measured position by the rigid motion (Kabsch) of its
    anchors from that frame to frame t, when three or more are left and they moved
    rigidly (rms residual within ``rigid_range`` median spacings); otherwise by their
    mean displacement. The carry must keep the rope's length to the marker of frame t
    measured nearest the end (:func:`_carry_keeps_rope`); a hand that would stretch
    the rope there (anchors on a wrist turning under the handle, or slid onto other
    markers) does not carry it, and ``cur[e]`` is left as it was (F). Call before
    ``temp_count`` counts frame t.
    """
    for row, e in _ends(state.known.size):
        if state.known[e]:
            continue
        last = t - 1 - int(state.temp_count[e])
        valid = state.hand_index[row] >= 0
        if last < 0 or state.invented[last, e] or not valid.any():
            continue
        now = state.points[state.hand_index[row, valid]]  # (K', 3)
        then = state.hand_then[row, valid]
        x = state.positions[last, e]
        c_then, c_now = then.mean(axis=0), now.mean(axis=0)
        moved = x + (c_now - c_then)
        if now.shape[0] >= 3:
            h = (then - c_then).T @ (now - c_now)  # (3, 3)
            u, _, vt = np.linalg.svd(h)
            d = np.eye(3)
            d[2, 2] = np.sign(np.linalg.det(vt.T @ u.T))
            rot = vt.T @ d @ u.T  # now ≈ rot (then - c_then) + c_now
            res = now - ((then - c_then) @ rot.T + c_now)
            rms = np.sqrt(np.mean(np.sum(res * res, axis=1)))
            if rms <= p.rigid_range * p.median_spacing:
                moved = rot @ (x - c_then) + c_now
        if _carry_keeps_rope(state, last, t, e, moved, p):
            cur[e] = moved


def _carry_keeps_rope(
    state: TrackState, last: int, t: int, e: int, moved: np.ndarray, p: StepParams
) -> bool:
    """Whether end ``e`` at ``moved`` (3,) lies within the reach the rope allows of the
    marker measured nearest it in frame t (``state.known``, ``state.cur``): the bound
    :func:`~skincap.tracking._refusals_numpy.reject_overstretched` puts on two measured
    markers (rest spacing plus ``adjacent_stretch`` γ for neighbours, ``stretch`` times
    the rest arc length plus γ farther apart). True when nothing is measured, or when
    that marker was not measured in every frame from ``last`` (the end's last measured
    frame) to t - 1: a marker back from a gap since may sit on a wrong point, and is no
    evidence against the hand."""
    idx = np.flatnonzero(state.known)
    if idx.size == 0:
        return True
    j = int(idx[0]) if e == 0 else int(idx[-1])
    if state.invented[last:t, j].any():
        return True
    lim = link_limit(state.arclength, state.link_rest, min(e, j), max(e, j), p)
    d = moved - state.cur[j]
    return bool(np.dot(d, d) <= lim * lim)


def search_with_hand(state: TrackState, t: int, pred: np.ndarray, p: StepParams) -> None:
    """Where the search looks for each hidden end with anchors, ``pred`` (M, 3), in place:
    its carried position (:func:`carry_with_hand`) when a point of frame t that is not
    taken and not a body point lies within γ / 2 of it; else, for an end measured in
    frame t - 1, that nearest free point itself when :func:`_may_take` allows it; else
    ``pred`` as it was (F).

    A hand carries the end's own marker there; a looser gate lets an end whose anchors
    were seated beside a wrong point pull the rope's markers along. The rigid carry
    misses an end that swings about its grip (a foot stamping) by more than the γ a
    lonely end may move from its prediction, and its own velocity misses the new
    direction too; the free point nearest the carry, when the end's own motion and the
    rope both reach it, is that end."""
    if not _carries(state):
        return
    carried = pred.copy()
    carry_with_hand(state, t, carried, p)
    a, b = int(state.offsets[t]), int(state.offsets[t + 1])
    if b == a:
        return
    free = ~state.body[a:b]
    taken = state.taken[state.known]
    free[taken - a] = False
    near = (0.5 * p.gamma) ** 2
    idx = np.flatnonzero(free)
    for e in (0, state.known.size - 1):
        if state.known[e] or idx.size == 0:
            continue
        d2 = np.sum((state.points[a:b][idx] - carried[e]) ** 2, axis=1)
        n = int(np.argmin(d2))
        if d2[n] <= near:
            pred[e] = carried[e]
        elif _may_take(state, t, e, a + int(idx[n]), float(d2[n]), p):
            pred[e] = state.points[a + int(idx[n])]


def _may_take(state: TrackState, t: int, e: int, q: int, d2: float, p: StepParams) -> bool:
    """Whether hidden held end ``e`` may be searched for at point ``q`` of frame t (an
    index into ``state.points``), ``d2`` (m²) from its carried position.

    Only an end whose point went missing this frame: measured in frame t - 1, with
    ``q`` within ``wide_gate`` γ of both its carry and its own velocity's prediction
    (V): the end swung off both by less than the wide gate. An end hidden for longer
    has no velocity of its own to confirm a point, and the hand's markers coming back
    from their dropouts lie beside its carry. Further, ``q`` lies within the reach the
    rope allows of the marker measured nearest the end (:func:`_carry_keeps_rope`), no
    point of frame t - 1 the rope did not take lies nearer to it than the end's last
    position (else it continues that point: a marker on the hand) and it does not move
    rigidly with body points
    (:func:`~skincap.tracking._refusals_numpy.rigid_with_body`)."""
    reach = (p.wide_gate * p.gamma) ** 2
    last = t - 1
    if d2 > reach or state.temp_count[e] != 0 or state.invented[last, e]:
        return False
    v = state.positions[last, e] + state.velocity[e]
    if np.sum((state.points[q] - v) ** 2) > reach:
        return False
    if not _carry_keeps_rope(state, last, t, e, state.points[q], p):
        return False
    a0, a1 = int(state.offsets[last]), int(state.offsets[t])
    untaken = np.ones(a1 - a0, dtype=bool)
    mine = state.point_index[last]
    untaken[mine[(mine >= a0) & (mine < a1)] - a0] = False
    own = np.sum((state.points[q] - state.positions[last, e]) ** 2)
    other = np.sum((state.points[a0:a1][untaken] - state.points[q]) ** 2, axis=1)
    if np.any(other <= own):  # it continues a point the rope did not take: not the end
        return False
    return not rigid_with_body(state, t, -1, q, p)


def place_with_hand(state: TrackState, t: int, p: StepParams) -> None:
    """The temporary markers of frame t's hidden held ends, in ``state.cur``, carried
    by their hands (:func:`carry_with_hand`)."""
    if _carries(state):
        carry_with_hand(state, t, state.cur, p)


def zip_with_hand(
    state: TrackState, t: int, rows: np.ndarray, pred: np.ndarray, p: StepParams
) -> np.ndarray:
    """Where the zipper looks for a hidden held end: its hand carry, within γ.

    ``rows`` (R,) int and ``pred`` (M, 3) metres are the zipper's
    (:func:`~skincap.tracking._steps_numpy.zipper_predictions`): each end among
    ``rows`` that its hand carries (:func:`carry_with_hand`: anchors left and a carry
    that keeps the rope) and that was hidden in frame t - 1 too is predicted at the
    carry instead, in place. Returns ``tight`` (M,) bool, True for those ends: they
    are searched within γ of the carry, in the same one-to-one assignment as the other
    traces of the zipper. Call before ``temp_count`` counts frame t.

    The zipper continues the rope's last measured links straight on; a rope bent at
    the hand leaves the end several centimetres off that line, where a leg marker
    beside the hand can lie within the wide gate while the carry, moving with the
    hand, stays within a centimetre of the end. An end that goes missing this frame
    keeps the zipper: its anchors were seated this frame and followed no further, and
    :func:`search_with_hand` already looked for it at its carry and its own velocity
    (the synthetic whip, ``eval track --all-gaps``: carried from the first hidden
    frame on, its 60- and 120-frame single-marker gaps grew by 0.3 and 1.0 cm).
    """
    m = state.known.size
    tight = np.zeros(m, dtype=bool)
    if rows.size == 0 or not _carries(state):
        return tight
    carried = np.full((m, 3), np.nan)
    carry_with_hand(state, t, carried, p)
    for e in (0, m - 1):
        if state.temp_count[e] > 0 and np.any(rows == e) and np.isfinite(carried[e, 0]):
            pred[e] = carried[e]
            tight[e] = True
    return tight
