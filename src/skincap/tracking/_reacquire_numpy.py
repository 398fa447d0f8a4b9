"""The rope tracker's re-acquisition step in NumPy (the reference).

Part of the per-frame steps of :mod:`skincap.tracking._steps_numpy` (which re-exports
:func:`reacquire_on_shell`); its numba twin, of the same name and signature, is in
:mod:`skincap.tracking._reacquire_numba`.
"""

from __future__ import annotations

import numpy as np

from skincap.tracking._refusals_numpy import (
    _squared_distances,
    path_back_to_trace,
    reject_overstretched,
    rigid_with_body,
)
from skincap.tracking.state import StepParams, TrackState

__all__ = ["reacquire_on_shell"]


def _frame_bounds(state: TrackState, t: int) -> tuple[int, int]:
    return int(state.offsets[t]), int(state.offsets[t + 1])


def reacquire_on_shell(state: TrackState, t: int, p: StepParams) -> bool:
    """Find the rope again by following it out from what is measured (beyond the thesis).

    Porter's initialisation follows the rope from marker to marker at the rope's
    spacing; this does the same inside a frame for the traces still unknown after
    every prediction missed (a hand reversing at 10 cm per frame, a hanging end that
    swung while it was hidden). An unknown marker ``j`` beside a measured marker ``k``
    takes the free point of frame t on the shell around ``k`` at its learnt rest
    length (``link_rest``, from ``-γ`` to ``+adjacent_stretch γ``) nearest to where the
    previous frame's link puts it, ``m_k + (x_j^{t-1} - x_k^{t-1})``, within one rest
    length of that (the link turned by at most 60° in a frame); an inner trace missing
    for ``lone_after`` frames or more, whose previous link says little, takes the only
    free point on that shell whatever its direction (:func:`_lone`). A trace
    found on neither takes the free point within γ of where its link was when both
    were last measured, however short its chord (:func:`_as_last_seen`: a slack
    end folded beside the hand). With nothing measured, the two end traces are seeded
    first: the free point nearest to ``V`` within one rest length. Free points are
    those the rope did not take, not body points and not moving rigidly with body
    points (:func:`rigid_with_body`). Each pass (:func:`_seat_pass`) lets every
    unknown trace beside a measured one propose its point and seats the proposals
    nearest-first, so a point two traces reach goes to the one whose link puts it
    nearer (a folded rope: a measured marker's held-back neighbour reaches, within
    one rest length, the point of a marker back from a gap beside it); passes repeat,
    each growing the chain for the next, until one seats nothing; then
    :func:`reject_overstretched`. In place; True if any trace matched.
    """
    a, b = _frame_bounds(state, t)
    known, link_rest = state.known, state.link_rest
    m = known.size
    if b == a:
        return False
    prev = state.positions[t - 1]
    free = ~state.body[a:b]
    free[state.taken[known] - a] = False
    if not free.any():  # nothing left to take: the passes below would find nothing
        return False
    found = False
    if not known.any():
        for j in (0, m - 1):
            rest = link_rest[min(j, m - 2)]
            found |= _seat_nearest(state, t, j, prev[j] + state.velocity[j], rest, None, free, p)
    for _ in range(m):
        if not _seat_pass(state, t, free, p):
            break
        found = True
    if found:
        reject_overstretched(state, t, p)
    return found


def _seat_pass(state: TrackState, t: int, free: np.ndarray, p: StepParams) -> bool:
    """One pass of :func:`reacquire_on_shell`: every unknown trace ``j`` beside a
    measured ``k`` proposes a point of frame t by the first rule that finds one (the
    shell nearest to the previous link, the link as last seen, the only point on the
    shell), with its distance to where that rule put it (metres; the lone rule's
    proposals last); the proposals are then seated nearest-first, a trace or a point
    at most once, ``free`` updated. A trace whose point went to a nearer proposal
    proposes again in the next pass. True if any trace was seated."""
    a = int(state.offsets[t])
    known, cur, link_rest = state.known, state.cur, state.link_rest
    m = known.size
    prev = state.positions[t - 1]
    who, what, cost = [], [], []
    for j in range(m):
        for k in (j - 1, j + 1):
            if known[j] or not (0 <= k < m and known[k]):
                continue
            rest = link_rest[min(j, k)]
            want = cur[k] + (prev[j] - prev[k])
            shell = (rest - p.gamma, rest + p.adjacent_stretch * p.gamma, cur[k])
            c, d = _nearest_free(state, t, j, want, rest, shell, free, p)
            if c < 0:
                c, d = _as_last_seen(state, t, j, k, rest, free, p)
            if c < 0 and 0 < j < m - 1 and state.temp_count[j] >= p.lone_after:
                c, d = _lone(state, t, j, shell, free, p), np.inf
            if c >= 0:
                who.append(j)
                what.append(c)
                cost.append(d)
    seated = False
    for n in np.argsort(np.asarray(cost, dtype=np.float64), kind="stable"):
        j, c = who[n], what[n]
        if known[j] or not free[c]:
            continue
        _seat(state, j, a, c, free)
        seated = True
    return seated


def _seat_nearest(
    state: TrackState,
    t: int,
    j: int,
    want: np.ndarray,
    gate: float,
    shell: tuple[float, float, np.ndarray] | None,
    free: np.ndarray,
    p: StepParams,
) -> bool:
    """Trace ``j`` takes the point :func:`_nearest_free` finds; ``free`` is updated.
    True if it took one."""
    c, _ = _nearest_free(state, t, j, want, gate, shell, free, p)
    if c < 0:
        return False
    _seat(state, j, int(state.offsets[t]), c, free)
    return True


def _nearest_free(
    state: TrackState,
    t: int,
    j: int,
    want: np.ndarray,
    gate: float,
    shell: tuple[float, float, np.ndarray] | None,
    free: np.ndarray,
    p: StepParams,
) -> tuple[int, float]:
    """The free point of frame t nearest to ``want`` (3,) within ``gate`` metres (and
    within ``shell`` = (inner, outer radius, centre) if given) that is not refused for
    trace ``j`` (seen beside its marker, moving rigidly with body points): its index
    in the frame (-1 if none) and its distance to ``want`` (metres)."""
    a, b = _frame_bounds(state, t)
    frame = state.points[a:b]
    d = np.sqrt(_squared_distances(frame, want[None])[:, 0])
    ok = free & (d <= gate)
    if shell is not None and ok.any():
        r = np.sqrt(_squared_distances(frame, shell[2][None])[:, 0])
        ok &= (r >= shell[0]) & (r <= shell[1])
    n_ok = int(ok.sum())
    if n_ok == 0:  # the usual case for a trace still hidden: skip the sort
        return -1, np.inf
    for c in np.argsort(np.where(ok, d, np.inf), kind="stable")[:n_ok]:
        if _beside_trace(state, t, j, a + int(c), p) or rigid_with_body(
            state, t, -1, a + int(c), p
        ):
            continue
        return int(c), float(d[c])
    return -1, np.inf


def _as_last_seen(
    state: TrackState, t: int, j: int, k: int, rest: float, free: np.ndarray, p: StepParams
) -> tuple[int, float]:
    """For trace ``j``, back from a gap, the free point of frame t nearest to where
    its link to the measured neighbour ``k`` was when both were last measured
    (``m_k + (x_j^f - x_k^f)``, f the frame ``j`` was last measured), within γ, at
    most ``rest`` plus ``adjacent_stretch γ`` from ``m_k`` however short the chord.

    A rope lying slack beside the hand folds its end link (a 3.7 cm chord for 9.2 cm of
    rope): F and the shell put the end at the rest spacing, 5-9 cm from where it lies,
    and while the rope lies still nothing brings it back (AML whip: 188-246 frames). The
    link as last seen keeps the fold. Not for a trace measured in frame t - 1 (the
    shell's previous link is that link already). Its index in the frame (-1 if none) and
    its distance to where the link puts it (metres).
    """
    last = t - 1 - int(state.temp_count[j])  # the frame j was last measured in
    if state.temp_count[j] == 0 or last < 0 or state.invented[last, j] or state.invented[last, k]:
        return -1, np.inf
    x = state.positions[last]
    want = state.cur[k] + (x[j] - x[k])
    shell = (0.0, rest + p.adjacent_stretch * p.gamma, state.cur[k])
    return _nearest_free(state, t, j, want, p.gamma, shell, free, p)


def _lone(
    state: TrackState,
    t: int,
    j: int,
    shell: tuple[float, float, np.ndarray],
    free: np.ndarray,
    p: StepParams,
) -> int:
    """For trace ``j``, the free point of frame t on ``shell`` = (inner, outer radius,
    centre) when it is the only one there not refused (seen beside the trace's own
    marker, moving rigidly with body points): its index in the frame, -1 if none."""
    a, b = _frame_bounds(state, t)
    frame = state.points[a:b]
    r = np.sqrt(_squared_distances(frame, shell[2][None])[:, 0])
    only = -1
    for c in np.nonzero(free & (r >= shell[0]) & (r <= shell[1]))[0]:
        if _beside_trace(state, t, j, a + int(c), p) or rigid_with_body(
            state, t, -1, a + int(c), p
        ):
            continue
        if only >= 0:  # two candidates: nothing says which is the rope
            return -1
        only = int(c)
    return only


def _seat(state: TrackState, j: int, a: int, c: int, free: np.ndarray) -> None:
    """Trace ``j`` takes point ``c`` of the frame starting at point ``a``; ``c`` is no
    longer free."""
    state.known[j] = True
    state.taken[j] = a + c
    state.cur[j] = state.points[a + c]
    free[c] = False


def _beside_trace(state: TrackState, t: int, j: int, point: int, p: StepParams) -> bool:
    """True when ``point`` of frame t was seen beside trace ``j``'s own marker.

    The point is followed back (nearest point within γ of where its last move takes
    it) through the frames trace ``j`` was not measured in, up to ``rigid_window``
    frames; at the first frame it was measured, a path that reaches another point
    more than γ away means the two existed side by side: a hand marker beside the
    held end, not the end coming back from a dropout. A path that breaks (moved
    farther than γ from its prediction: the rope moving fast) is no evidence.
    """
    reached, f, apart = path_back_to_trace(state, t, j, point, p)
    return reached >= 0 and reached != int(state.point_index[f, j]) and apart > p.gamma
