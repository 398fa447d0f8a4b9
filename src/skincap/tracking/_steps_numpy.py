"""The rope tracker's per-frame steps in NumPy: the reference.

Every public function here has a twin of the same name and signature in
:mod:`skincap.tracking._steps_numba`; both read and write a
:class:`~skincap.tracking.state.TrackState` in place and take the run's
:class:`~skincap.tracking.state.StepParams` ``p``. What each step is for, and which
parts go beyond Porter (2012), is told in :mod:`skincap.tracking.tracker`.

A frame (:func:`track_frame`) runs::

    V = begin_frame                       prediction by the trace's own velocity (eqs. 3.1-3.2)
    continue_body_chains                  body points of this frame
    follow_hand                           a hidden held end's hand anchors into this frame
    match_measured_best                   steady traces at V or at V + acceleration
        accelerated_prediction            V plus the trace's last change of velocity
        match_measured                    steady traces at V, then at V + residuals
            match_traces / reject_overstretched / reject_odd_motion / residual_predictions
    pred = gap_predictions                the curve inside the rope, F at its ends
    match_missing                         the rest at pred, then the zipper
        match_traces / reject_* / zipper_predictions
    reacquire_on_shell                    the rest followed out along the rope
    bridge_hidden_runs                    short hidden runs on the chain that fits between their ends
    unshift_chain                         a chain matched one marker along moves back
    swap_onto_curve                       a trace off the curve moves onto it
    place_invented                        temporary markers where nothing was found
    seat_hand                             an end gone missing: its hand from frame t - 1
    place_with_hand                       a hidden held end moved with its hand
    commit_frame                          row t of the results, velocity, counts
    release_hand                          a measured end drops its hand

Candidate points come from a KD-tree over the frame's points, built when the frame
is first searched (the numba twin buckets it along one axis instead). The refusals
(:func:`rigid_with_body`, ``reject_*``) live in :mod:`skincap.tracking._refusals_numpy`
and the re-acquisition in :mod:`skincap.tracking._reacquire_numpy`; both are
re-exported here, so this module names every step.
"""

from __future__ import annotations

import threading
import weakref

import numpy as np
from scipy.spatial import cKDTree

from skincap.tracking._bridge_numpy import bridge_hidden_runs
from skincap.tracking._hand_numpy import (
    follow_hand,
    place_with_hand,
    release_hand,
    search_with_hand,
    seat_hand,
    zip_with_hand,
)
from skincap.tracking._reacquire_numpy import reacquire_on_shell
from skincap.tracking._refusals_numpy import (
    _squared_distances,
    reject_odd_motion,
    reject_overstretched,
    rigid_with_body,
)
from skincap.tracking.curve import (
    carry_last_seen,
    drag_free_ends,
    end_is_free,
    fill_interior_on_curve,
    settle_single_gaps,
)
from skincap.tracking.init import gated_assignment
from skincap.tracking.state import StepParams, TrackState

__all__ = [
    "accelerated_prediction",
    "begin_frame",
    "bridge_hidden_runs",
    "commit_frame",
    "continue_body_chains",
    "gap_predictions",
    "learn_link_rest",
    "match_measured",
    "match_measured_best",
    "match_missing",
    "match_traces",
    "place_invented",
    "reacquire_on_shell",
    "reject_odd_motion",
    "reject_overstretched",
    "residual_predictions",
    "rigid_with_body",
    "swap_onto_curve",
    "track_frame",
    "track_frames",
    "unshift_chain",
    "zipper_predictions",
]


# ------------------------------------------------------------------ search helpers
class _FrameTrees(threading.local):
    """The KD-tree of the frame last searched (one frame is searched several times).

    One per thread (takes tracked in parallel threads each keep their own), keyed on
    the points array itself and the frame's bounds.
    """

    def __init__(self) -> None:
        self.key: tuple[int, int] = (-1, -1)
        self.owner: weakref.ref[np.ndarray] | None = None
        self.tree: cKDTree | None = None

    def nearest(
        self, points: np.ndarray, a: int, b: int, q: np.ndarray, k: int, gate: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(R, k) distances (inf for none) and global indices of points[a:b] near ``q``.

        ``b - a >= k >= 1``. Where the distance is inf the index is meaningless.
        """
        owner = self.owner() if self.owner is not None else None
        if self.tree is None or owner is not points or self.key != (a, b):
            self.tree = cKDTree(points[a:b])
            self.owner, self.key = weakref.ref(points), (a, b)
        d, i = self.tree.query(q, k=k, distance_upper_bound=gate)
        return d.reshape(q.shape[0], k), i.reshape(q.shape[0], k) + a


_TREES = _FrameTrees()


def _side_neighbours(known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M,) nearest known index before (-1 if none) and after (M if none) each marker."""
    m = known.size
    ar = np.arange(m)
    before = np.maximum.accumulate(np.where(known, ar, -1))
    before = np.concatenate([[-1], before[:-1]])
    after = np.minimum.accumulate(np.where(known, ar, m)[::-1])[::-1]
    after = np.concatenate([after[1:], [m]])
    return before, after


def _frame_bounds(state: TrackState, t: int) -> tuple[int, int]:
    return int(state.offsets[t]), int(state.offsets[t + 1])


# ------------------------------------------------------------------ frame start and end
def begin_frame(state: TrackState, t: int, p: StepParams) -> np.ndarray:
    """Clear the frame's ``cur``/``known``/``taken``; return V (M, 3), metres.

    V is each trace's own prediction, ``m^{t-1} + v^{t-1} Δt`` (eqs. 3.1-3.2).
    """
    state.cur[:] = 0.0
    state.known[:] = False
    state.taken[:] = -1
    return state.positions[t - 1] + state.velocity


def commit_frame(state: TrackState, t: int, p: StepParams) -> None:
    """Write row t of the results from ``cur``/``known``/``taken`` and advance the
    carried state: temporary-marker counts, losses, velocities (metres per frame).

    A trace is lost after more than ``max_temp_markers`` temporary markers unless a
    marker measured this frame within :data:`PINNING_REACH` markers along the rope
    pins it (its curve, carry and the rope's length hold it within a few spacings).

    A trace measured again after temporary markers takes the velocity ṽ of its
    neighbours measured in both frames (eq. 3.3; beyond the thesis) when the point
    is confirmed as its marker (:func:`_confirmed_returns`): its own displacement is
    then the error of its invented position (a slack end lying still beside the
    hand, invented at the rest spacing 5-9 cm away, would be predicted that far on
    and missed every other frame). An unconfirmed return keeps its own displacement
    (eq. 3.2): if the point is not its marker, the next frame's prediction leaves it."""
    known = state.known
    back = known & state.invented[t - 1]  # measured again after temporary markers
    moving = known & ~back  # measured in both frames: a displacement of the rope
    confirmed = np.zeros_like(back)
    if back.any() and moving.any():
        jump = state.cur - state.positions[t - 1]
        v_tilde = _neighbour_velocity(moving, jump, jump)
        confirmed = _confirmed_returns(state, t, back, v_tilde, p)
    state.temp_count[:] = np.where(known, 0, state.temp_count + 1)
    state.invented[t] = ~known
    state.lost_frames[t] = (state.temp_count > p.max_temp_markers) & ~_pinned(known)
    state.point_index[t] = state.taken
    state.positions[t] = state.cur
    state.velocity[:] = state.cur - state.positions[t - 1]
    if confirmed.any():
        state.velocity[confirmed] = v_tilde[confirmed]
    learn_link_rest(state, t, p)


def _confirmed_returns(
    state: TrackState, t: int, back: np.ndarray, v_tilde: np.ndarray, p: StepParams
) -> np.ndarray:
    """(M,) bool: the traces in ``back`` whose point of frame t is confirmed as their marker.

    Confirmed: within γ of the temporary marker moved by ṽ (``v_tilde`` (M, 3), metres
    per frame; the thesis' Ṽ, eq. 3.1 with 3.3), or repeating within γ its link to a
    neighbour measured in frame t as that link was when both were last measured (the
    frame before its temporary markers; a slack end folded beside the hand). A point
    taken on weaker evidence (the shell of a neighbour, the wide gate) is not: given
    ṽ, a wrong point that moves slower than the rope by less than γ (a body marker
    beside a slow rope) lies within γ of every next prediction and is kept; given
    its own jump, the next prediction leaves it (synthetic jump frames 81-90).
    Call before ``temp_count`` counts frame t.
    """
    m = back.size
    e = state.cur - (state.positions[t - 1] + v_tilde)
    confirmed = back & (np.einsum("ij,ij->i", e, e) <= p.gamma * p.gamma)
    last = t - 1 - state.temp_count  # (M,) the frame each trace was last measured in
    for j in np.flatnonzero(back & ~confirmed & (last >= 0)):
        f = int(last[j])
        if state.invented[f, j]:
            continue
        for k in (j - 1, j + 1):
            if 0 <= k < m and state.known[k] and not state.invented[f, k]:
                d = (state.cur[j] - state.cur[k]) - (state.positions[f, j] - state.positions[f, k])
                if d @ d <= p.gamma * p.gamma:
                    confirmed[j] = True
    return confirmed


#: A hidden marker with a measured marker at most this many markers away along the
#: rope is pinned by it: never reported lost, however long its gap.
PINNING_REACH = 2


def _pinned(known: np.ndarray) -> np.ndarray:
    """(M,) bool: a marker measured within :data:`PINNING_REACH` markers of each."""
    m = known.size
    pad = np.concatenate([np.zeros(PINNING_REACH, bool), known, np.zeros(PINNING_REACH, bool)])
    window = np.stack([pad[k : k + m] for k in range(2 * PINNING_REACH + 1)])  # (5, M)
    return np.asarray(window.any(axis=0), dtype=bool)


def learn_link_rest(state: TrackState, t: int, p: StepParams) -> None:
    """Raise ``link_rest`` to the chords of links measured at both ends in frame t
    (beyond the thesis), capped at ``stretch`` times the rest spacing, or times the
    larger of it and the median spacing for a link measured at both ends in frame
    t - 1 too (a start made on a slack frame is short of the taut rope's), in place.

    The still window's chord is a slack rope's: shorter than the rope between the two
    markers (8.2 cm for 9.2 cm of rope on a 1.1 m whip), so a taut link would be
    refused as over-stretched. Every chord accepted is at most ``link_rest`` plus
    ``adjacent_stretch γ``, so the rest length grows only by what the rope showed.
    """
    both = state.known[:-1] & state.known[1:]
    e = state.cur[1:] - state.cur[:-1]
    chord = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    # a link's start may be a slack frame's chord, short of the tape spacing the rope
    # shows taut: measured at both ends in frame t - 1 too, it may learn up to stretch
    # times the larger of the two
    then = state.invented[t - 1]
    steady = ~(then[:-1] | then[1:])
    cap = p.stretch * np.where(steady, np.maximum(state.spacing, p.median_spacing), state.spacing)
    state.link_rest[:] = np.where(
        both, np.maximum(state.link_rest, np.minimum(chord, cap)), state.link_rest
    )


# ------------------------------------------------------------------ body points
def continue_body_chains(state: TrackState, t: int, v_pred: np.ndarray, p: StepParams) -> None:
    """Flag frame t's points that continue a body point of frame t - 1 (beyond the thesis).

    A point is a body point when it is the only point within ``ε = body_chain_gate γ``
    of where a previous body point's velocity takes it, that prediction is the only
    one (body, or ``v_pred`` (M, 3) of any trace) within ε of it. A hidden trace's
    prediction counts too: a body marker that drops out beside a rope marker hidden at
    the same time would otherwise hand its chain to that marker's point when it comes
    back, which the trace, back from its gap, then refuses as a body point. Writes
    ``state.body`` and ``state.body_vel`` (its displacement, metres per frame; zero
    elsewhere) for frame t's points.
    """
    a0, a1 = _frame_bounds(state, t - 1)
    a2 = int(state.offsets[t + 1])
    eps = p.body_chain_gate * p.gamma
    points = state.points[a1:a2]
    n = points.shape[0]
    body = np.zeros(n, dtype=bool)
    vel = np.zeros((n, 3))
    qi = np.nonzero(state.body[a0:a1])[0]
    if qi.size and n:
        prev_points = state.points[a0:a1]
        pred = prev_points[qi] + state.body_vel[a0:a1][qi]
        near = _squared_distances(points, pred) < eps * eps  # (N, Q)
        single = near.sum(axis=1) == 1
        rope_pred = v_pred[np.isfinite(v_pred).all(axis=1)]
        if rope_pred.shape[0]:
            single &= ~(_squared_distances(points, rope_pred) < eps * eps).any(axis=1)
        ok = near & single[:, None] & (near.sum(axis=0) == 1)[None, :]
        p_idx, q_col = np.nonzero(ok)
        body[p_idx] = True
        vel[p_idx] = points[p_idx] - prev_points[qi[q_col]]
    state.body[a1:a2] = body
    state.body_vel[a1:a2] = vel


# ------------------------------------------------------------------ matching
def match_traces(
    state: TrackState,
    t: int,
    rows: np.ndarray,
    pred: np.ndarray,
    wide: bool,
    tight: np.ndarray,
    p: StepParams,
) -> bool:
    """Match traces ``rows`` (R,) int to free points of frame t near ``pred`` (M, 3), in place.

    The gate is γ, or ``wide_gate γ`` with ``wide``, except for the traces marked in
    ``tight`` (M,) bool, always searched within γ (a hidden held end at its hand carry,
    :func:`~skincap.tracking._hand_numpy.zip_with_hand`). Refused: points taken this frame;
    body points, for traces that are not steady (``temp_count > 0``); points that
    continue something slower than the rope (:func:`_follows_other`). With ``wide``
    also: for a steady trace predicted to move at most γ, points beyond γ; for a
    trace that is not steady, points moving rigidly with body points
    (:func:`rigid_with_body`); points beyond γ of the prediction unless at their rest
    spacing (± γ) from a measured neighbour, and any point more than γ beyond that
    spacing from a measured neighbour (a bent rope's chord is shorter, never longer); for
    a trace that is not steady, points nearer V of a trace measured in frame t - 1 and not
    found yet than its own prediction (:func:`_continues_missed`). Conflicts are resolved one-to-one, minimising the summed
    distance (:func:`~skincap.tracking.init.gated_assignment`). Writes ``cur``,
    ``known``, ``taken``; True if any trace matched.
    """
    a, b = _frame_bounds(state, t)
    if rows.size == 0 or b == a:
        return False
    gamma = p.gamma
    gate = p.wide_gate * gamma if wide else gamma
    known, taken = state.known, state.taken
    steady = state.temp_count == 0
    n_taken = int(known.sum())
    kk = min(min(p.candidates, b - a) + n_taken, b - a)
    d, i = _TREES.nearest(state.points, a, b, pred[rows], kk, gate)
    if n_taken:
        d = np.where(np.isin(i, taken[known]), np.inf, d)
    last = state.points.shape[0] - 1
    d = np.where(state.body[np.minimum(i, last)] & ~steady[rows][:, None], np.inf, d)
    if wide and gate > gamma:
        e = pred[rows] - state.positions[t - 1][rows]
        slow = steady[rows] & (np.einsum("ij,ij->i", e, e) <= gamma * gamma)
        d = np.where(slow[:, None] & (d >= gamma), np.inf, d)
    d = np.where(tight[rows][:, None] & (d >= gamma), np.inf, d)
    d = np.where(_follows_other(state, t, rows, pred, i, d, gamma), np.inf, d)
    if wide:
        d = np.where(_continues_missed(state, t, rows, i, d, p), np.inf, d)
        for r in np.nonzero(~steady[rows])[0]:
            for c in range(d.shape[1]):
                if np.isfinite(d[r, c]) and d[r, c] < gate:
                    if rigid_with_body(state, t, -1, int(i[r, c]), p):
                        d[r, c] = np.inf
        d = _refuse_off_spacing(state, rows, i, d, gamma)
    hit_rows, pts = gated_assignment(d, i, gate)
    if hit_rows.size == 0:
        return False
    hit = rows[hit_rows]
    known[hit] = True
    taken[hit] = pts
    state.cur[hit] = state.points[pts]
    return True


def _loose(state: TrackState) -> np.ndarray:
    """(M,) bool, all False: no trace held to γ in a wide search."""
    return np.zeros(state.known.size, dtype=bool)


def _refuse_off_spacing(
    state: TrackState, rows: np.ndarray, i: np.ndarray, d: np.ndarray, gamma: float
) -> np.ndarray:
    """``d`` (R, K) with inf where the candidate lies more than γ beyond its rest
    spacing from a measured neighbour, or beyond γ of its prediction and more than γ
    short of that spacing, or beyond γ with no measured neighbour.

    A rope bends: a link's chord may be shorter than its rest spacing (a slack rope
    lying folded on the floor: 8.4 cm chords for 12.1 cm), never longer; a short
    chord refuses only the candidates the wide gate reaches beyond γ.
    """
    known, spacing = state.known, state.spacing
    m = known.size
    q = state.points[np.minimum(i, state.points.shape[0] - 1)]  # (R, K, 3)
    lonely = ~(known[np.maximum(rows - 1, 0)] & (rows > 0))
    lonely &= ~(known[np.minimum(rows + 1, m - 1)] & (rows < m - 1))
    d = np.where(lonely[:, None] & (d >= gamma), np.inf, d)
    for step in (-1, 1):
        nb = rows + step
        nbc = np.clip(nb, 0, m - 1)
        has = (nb >= 0) & (nb < m) & known[nbc]
        if not has.any():
            continue
        rest = spacing[np.minimum(np.minimum(rows, nbc), m - 2)]
        chord = np.linalg.norm(q - state.cur[nbc][:, None, :], axis=2)
        off = (chord - rest[:, None] > gamma) | ((rest[:, None] - chord > gamma) & (d >= gamma))
        d = np.where(has[:, None] & off, np.inf, d)
    return d


def _follows_other(
    state: TrackState,
    t: int,
    rows: np.ndarray,
    pred: np.ndarray,
    cand: np.ndarray,
    dist: np.ndarray,
    gamma: float,
) -> np.ndarray:
    """(R, K) bool: the candidate continues something else than the rope (beyond the thesis).

    A body marker beside a fast rope moves far less than the rope. A trace that is
    not steady, or any inner trace, refuses a candidate within ``min(γ, D - γ)`` of a
    point of frame t - 1 the rope did not take, ``D`` being how far the trace is
    predicted to move from its frame t - 1 position: that point moved slower than the
    rope by more than γ. Off where the rope is slow (``D <= γ``); the ends of a
    steady rope are exempt (held in the hands, among hand markers).
    """
    a0, a1 = _frame_bounds(state, t - 1)
    mine = state.point_index[t - 1]
    untaken = np.ones(a1 - a0, dtype=bool)
    untaken[mine[(mine >= a0) & (mine < a1)] - a0] = False
    out = np.zeros(dist.shape, dtype=bool)
    q = state.points[a0:a1][untaken]
    if q.shape[0] == 0:
        return out
    m = mine.size
    e = pred[rows] - state.positions[t - 1][rows]
    speed = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    lim = np.minimum(gamma, speed - gamma)
    steady = state.temp_count[rows] == 0
    judged = (~steady | ((rows > 0) & (rows < m - 1))) & (lim > 0.0)
    r_idx, c_idx = np.nonzero(judged[:, None] & np.isfinite(dist))
    if r_idx.size == 0:
        return out
    near = (
        _squared_distances(state.points[cand[r_idx, c_idx]], q) < (lim[r_idx] * lim[r_idx])[:, None]
    )
    out[r_idx, c_idx] = near.any(axis=1)
    return out


def _continues_missed(
    state: TrackState, t: int, rows: np.ndarray, cand: np.ndarray, dist: np.ndarray, p: StepParams
) -> np.ndarray:
    """(R, K) bool: the candidate of a trace coming back from a gap (``temp_count > 0``)
    lies nearer V of a trace measured in frame t - 1 and not found yet this frame than
    ``dist`` (its distance to the returning trace's prediction, metres), and within
    ``wide_gate`` γ of that V (beyond the thesis).

    A marker that moves a little more than γ in a frame is missed at V, and then looked
    for at the curve through the measured markers, as is its hidden neighbour: the
    neighbour, a spacing along the rope, can lie nearer its point by millimetres
    (c3d.org jump, a foot stamping beside a held-back marker) and the two traces swap
    for the rest of the gap. The point continues the missed trace's own.
    """
    out = np.zeros(dist.shape, dtype=bool)
    missed = (state.temp_count == 0) & ~state.known
    returning = state.temp_count[rows] > 0
    if not missed.any() or not returning.any():
        return out
    v = state.positions[t - 1][missed] + state.velocity[missed]  # (Q, 3)
    r_idx, c_idx = np.nonzero(returning[:, None] & np.isfinite(dist))
    if r_idx.size == 0:
        return out
    gate2 = (p.wide_gate * p.gamma) ** 2
    dv2 = _squared_distances(state.points[cand[r_idx, c_idx]], v)  # (N, Q)
    own2 = dist[r_idx, c_idx] ** 2
    out[r_idx, c_idx] = ((dv2 <= gate2) & (dv2 < own2[:, None])).any(axis=1)
    return out


# ------------------------------------------------------------------ predictions
def residual_predictions(
    state: TrackState, t: int, v_pred: np.ndarray, p: StepParams
) -> np.ndarray:
    """(M, 3) V (``v_pred``) corrected by the prediction errors of the steady traces
    found so far, interpolated linearly in rest arc length (nearest at the ends)."""
    found = state.known & (state.temp_count == 0)
    if not found.any():
        return v_pred.copy()
    values = np.where(found[:, None], state.cur - v_pred, 0.0)
    m = found.size
    before, after = _side_neighbours(found)
    has_b, has_a = before >= 0, after < m
    b = np.clip(before, 0, m - 1)
    a = np.clip(after, 0, m - 1)
    both = has_b & has_a
    s = state.arclength
    span = np.where(both, s[a] - s[b], 1.0)
    w = np.where(both, (s - s[b]) / span, np.where(has_b, 0.0, 1.0))
    out = (1.0 - w)[:, None] * values[b] + w[:, None] * values[a]
    return v_pred + np.where(found[:, None], values, out)


def accelerated_prediction(
    state: TrackState, t: int, v_pred: np.ndarray, p: StepParams
) -> np.ndarray:
    """(M, 3) V (``v_pred``) plus each trace's last change of velocity, metres
    (beyond the thesis).

    ``V + (m^{t-1} - 2 m^{t-2} + m^{t-3})``: a second-order prediction, for traces
    measured in frames t - 1, t - 2 and t - 3 (V elsewhere, and before frame 3). A
    swinging rope's markers move on curves: its bottom turning at 20-45 cm a frame is
    missed by V by 5-13 cm (2-4 γ), and by this by 1-5 cm.
    """
    if t < 3:
        return v_pred.copy()
    x, invented = state.positions, state.invented
    seen = ~(invented[t - 1] | invented[t - 2] | invented[t - 3])
    acc = x[t - 1] - 2.0 * x[t - 2] + x[t - 3]
    return v_pred + np.where(seen[:, None], acc, 0.0)


def gap_predictions(state: TrackState, t: int, p: StepParams) -> np.ndarray:
    """(M, 3) where the markers not found yet are predicted, metres.

    With nothing measured: V. Inside the measured part: the curve through the
    measured markers at the rest arc length, a lone marker settled toward its rest
    spacings. Beyond it: F (eq. 3.6) outward from the measured part, each at its rest
    spacing from its inner neighbour (:func:`_predict_ends`); a hidden held end where
    its hand carries it when a free point lies there
    (:func:`~skincap.tracking._hand_numpy.search_with_hand`).
    """
    known = state.known
    prev = state.positions[t - 1]
    pred = prev + state.velocity
    if not known.any():
        return pred
    meas_vel = np.where(known[:, None], state.cur - prev, 0.0)
    v_tilde = _neighbour_velocity(known, meas_vel, state.velocity)
    pred, _ = fill_interior_on_curve(
        np.where(known[:, None], state.cur, 0.0), known, state.arclength
    )
    pred = settle_single_gaps(pred, known, state.spacing, p.settle)
    count = np.where(known, 0, state.temp_count + 1)
    pred = _predict_ends(pred, known, prev, v_tilde, count, state.spacing)
    seat_hand(state, t, p)  # an end gone missing takes its hand
    search_with_hand(state, t, pred, p)  # a held end where its hand carries it
    return pred


def _carry_hidden(
    state: TrackState, t: int, pred: np.ndarray, rows_mask: np.ndarray, p: StepParams
) -> np.ndarray:
    """``pred`` (M, 3) with the hidden markers of ``rows_mask`` (M,) bool that lie
    between measured markers carried from where they were last seen
    (:func:`~skincap.tracking.curve.carry_last_seen`), and those in the run at a free
    end of the rope (:func:`_free_end_runs`) dragged by the rope
    (:func:`~skincap.tracking.curve.drag_free_ends`, from the end's own velocity:
    :func:`_end_velocity`).

    The runs at a held end keep F here (the end itself is then carried by its hand,
    :func:`~skincap.tracking._hand_numpy.carry_with_hand`): carried beyond its rope
    neighbours, an end turning with the hand strays (the synthetic jump rope's handle
    end: 4 -> 10 cm). A free end is not carried either: a tip lying on the floor while
    the rope beside it turns is carried away with the turn (pyomeca whip, rope_11
    hidden 30 frames from 210: 11.5 cm; dragged 1.4 cm), and F, pointing the rope
    straight out from its last measured links, misses a swinging tip by 15-25 cm."""
    free_runs = _free_end_runs(state, t) & rows_mask
    if free_runs.any():
        velocity = _end_velocity(state, t, free_runs)
        pred = drag_free_ends(
            pred, state.known, state.positions[t - 1], velocity, state.spacing, free_runs
        )
    if p.carry_tolerance <= 0.0:
        return pred
    last = t - 1 - state.temp_count  # (M,) the frame each trace was last measured
    before, after = _side_neighbours(state.known)
    inside = (before >= 0) & (after < state.known.size)
    rows = np.nonzero(rows_mask & inside & ~state.known & (last >= 0))[0]
    if rows.size == 0:
        return pred
    tolerance = p.carry_tolerance * p.median_spacing
    then = state.positions[last[rows]]
    then_measured = ~state.invented[last[rows]]
    return carry_last_seen(pred, state.cur, state.known, rows, then, then_measured, tolerance)


#: Frames over which a hidden end's last measured velocity is averaged (:func:`_end_velocity`).
END_VELOCITY_FRAMES = 3


def _end_velocity(state: TrackState, t: int, rows_mask: np.ndarray) -> np.ndarray:
    """(M, 3) metres per frame: ``state.velocity``, except for the markers of
    ``rows_mask`` (M,) bool measured in frame t - 1, which move as they moved on
    average since the earliest measured frame f of the :data:`END_VELOCITY_FRAMES`
    before: ``(x^{t-1} - x^f) / (t - 1 - f)``; zero without one.

    A one-frame difference carries the markers' noise on as a drift (pyomeca whip,
    rope_11 lying still from frame 210: 1.8 mm per frame, 3.1 cm mean error over 30
    frames; over three frames 1.5 cm), and a trace measured again after a dropout
    carries its neighbours' velocity (eq. 3.3, :func:`commit_frame`), which is right
    for finding it in the next frame but not for a loose end; three frames still follow
    a whip's tip as it speeds up (CMU whip from frame 724, 3-6 cm per frame: 2.4 cm,
    five frames 3.0)."""
    out = state.velocity.copy()
    for j in np.nonzero(rows_mask & (state.temp_count == 0))[0]:
        out[j] = 0.0
        for f in range(max(t - 1 - END_VELOCITY_FRAMES, 0), t - 1):
            if not state.invented[f, j]:
                out[j] = (state.positions[t - 1, j] - state.positions[f, j]) / (t - 1 - f)
                break
    return out


def _free_end_runs(state: TrackState, t: int) -> np.ndarray:
    """(M,) bool: the hidden markers at an end of the rope, up to its first measured
    marker, where that end marker was free (:func:`~skincap.tracking.curve.end_is_free`)
    in the frame it was last measured, among the points the rope did not take there."""
    known = state.known
    m = known.size
    runs = np.zeros(m, dtype=bool)
    measured = np.nonzero(known)[0]
    if measured.size == 0:
        return runs
    for e, run in ((0, slice(0, measured[0])), (m - 1, slice(measured[-1] + 1, m))):
        seen = t - 1 - int(state.temp_count[e])
        if known[e] or seen < 0:
            continue
        a, b = state.offsets[seen], state.offsets[seen + 1]
        taken = state.point_index[seen]
        is_rope = np.zeros(b - a, dtype=bool)
        is_rope[taken[taken >= 0] - a] = True
        if end_is_free(state.positions[seen, e], state.points[a:b], is_rope):
            runs[run] = True
    return runs


def _neighbour_velocity(
    known: np.ndarray, velocity: np.ndarray, fallback: np.ndarray
) -> np.ndarray:
    """ṽ (eq. 3.3): β-weighted velocity of the nearest measured neighbour on each side.

    With neighbours ``n`` and ``m`` markers away, ``ṽ = m/(n+m) v_{j-n} + n/(n+m)
    v_{j+m}``; one side only gives that side's velocity; none gives ``fallback``.
    """
    m = known.size
    before, after = _side_neighbours(known)
    ar = np.arange(m)
    has_b, has_a = before >= 0, after < m
    n_b = np.where(has_b, ar - before, 0).astype(np.float64)
    n_a = np.where(has_a, after - ar, 0).astype(np.float64)
    vb = velocity[np.clip(before, 0, m - 1)]
    va = velocity[np.clip(after, 0, m - 1)]
    both = has_b & has_a
    beta = np.where(both, n_a / np.where(both, n_a + n_b, 1.0), has_b.astype(np.float64))
    out = beta[:, None] * vb + (1.0 - beta)[:, None] * va
    none = ~(has_b | has_a)
    out[none] = fallback[none]
    return out


def _predict_ends(
    cur: np.ndarray,
    known: np.ndarray,
    prev: np.ndarray,
    v_tilde: np.ndarray,
    temp_count: np.ndarray,
    spacing: np.ndarray,
) -> np.ndarray:
    """F (eq. 3.6) for the runs of unknown markers at the rope's ends, outward from
    the measured part, each projected to its rest spacing from its inner neighbour.

    ``cur`` (M, 3) holds the measured markers; the end markers are written in place.
    ``F = α Ṽ + (1 - α) N``, ``α = 1 / temp_count``, Ṽ = prev + ṽ, N by midpoint
    displacement from the next two or three markers inward (eqs. 3.4-3.5).
    """
    m = known.size
    idx = np.nonzero(known)[0]
    first, last = int(idx[0]), int(idx[-1])
    outward = [(j, +1) for j in range(first - 1, -1, -1)] + [(j, -1) for j in range(last + 1, m)]
    for j, step in outward:
        j1, j2, j3 = j + step, j + 2 * step, j + 3 * step
        v_pred = prev[j] + v_tilde[j]  # Ṽ, eq. 3.1 with ṽ
        l1 = spacing[min(j, j1)]
        if 0 <= j2 < m:
            far = j3 if 0 <= j3 < m else j2
            d = (cur[j1] - cur[far]) / 2.0  # eq. 3.4: ((m1 - m2) + (m2 - m3)) / 2
            norm = float(np.linalg.norm(d))
            n_pred = cur[j1] + l1 * d / norm if norm > 0 else v_pred  # eq. 3.5
        else:
            n_pred = v_pred
        alpha = 1.0 / temp_count[j]
        f = alpha * v_pred + (1.0 - alpha) * n_pred  # eq. 3.6
        r = f - cur[j1]
        rn = float(np.linalg.norm(r))
        cur[j] = cur[j1] + l1 * r / rn if rn > 0 else f
    return cur


def zipper_predictions(state: TrackState, p: StepParams) -> tuple[np.ndarray, np.ndarray]:
    """Where the ends of runs of unknown markers continue the rope (beyond the thesis).

    An unknown marker ``j`` inside the measured part of the rope, or an unknown end of
    the rope, with two measured markers on one side and an unknown neighbour on the
    other, is predicted by continuing the measured side at the rest spacing from its
    neighbour, bending as it bends when a third measured marker follows::

        e = 3 m_{j-1} - 3 m_{j-2} + m_{j-3}   (or 2 m_{j-1} - m_{j-2})
        x_j = m_{j-1} + l * (e - m_{j-1}) / |e - m_{j-1}|

    Returns ``rows`` (R,) int64, the markers predicted, and ``pred`` (M, 3) metres,
    their predictions (zero elsewhere).
    """
    cur, known, spacing = state.cur, state.known, state.spacing
    m = known.size
    pred = np.zeros((m, 3))
    if m < 4:
        return np.zeros(0, dtype=np.int64), pred
    ar = np.arange(m)
    pad = np.concatenate([[False] * 3, known, [False] * 3])
    k_m3, k_m2, k_m1 = pad[ar], pad[ar + 1], pad[ar + 2]
    k_p1, k_p2, k_p3 = pad[ar + 4], pad[ar + 5], pad[ar + 6]
    before, after = _side_neighbours(known)
    inner = ~known & (ar > 0) & (ar < m - 1) & (before >= 0) & (after < m)
    target = inner | (~known & ((ar == 0) | (ar == m - 1)))
    lo = target & k_m1 & k_m2 & ~k_p1
    hi = target & k_p1 & k_p2 & ~k_m1
    for side, step, third in ((lo, -1, k_m3), (hi, 1, k_p3)):
        j = np.nonzero(side)[0]
        if j.size == 0:
            continue
        a, b = cur[j + step], cur[j + 2 * step]
        c = cur[np.clip(j + 3 * step, 0, m - 1)]
        e = np.where(third[j][:, None], 3.0 * a - 3.0 * b + c, 2.0 * a - b)
        d = e - a
        norm = np.linalg.norm(d, axis=1)
        rest = spacing[np.minimum(j, j + step)]
        ok = norm > 0
        pred[j[ok]] = a[ok] + (rest[ok] / norm[ok])[:, None] * d[ok]
        side[j[~ok]] = False
    return np.nonzero(lo | hi)[0], pred


# ------------------------------------------------------------------ after matching
def swap_onto_curve(state: TrackState, t: int, p: StepParams) -> bool:
    """Move a trace off a body point onto the rope marker it lost (beyond the thesis).

    For every measured marker with measured markers on both sides, the curve through
    the *other* measured markers gives ``C_j``; a marker farther than ``2 γ`` from
    ``C_j`` takes a free point at least γ nearer to ``C_j`` and within γ of it,
    conflicts resolved one-to-one. In place (``cur``, ``taken``); True if any moved.
    """
    a, b = _frame_bounds(state, t)
    known, cur, s = state.known, state.cur, state.arclength
    m = known.size
    if b == a or known.sum() < 3:
        return False
    before, after = _side_neighbours(known)
    rows = np.nonzero(known & (before >= 0) & (after < m))[0]
    if rows.size == 0:
        return False
    x = np.where(known[:, None], cur, 0.0)
    # markers j-2 … j+2 all measured (or beyond an end): the precomputed weights
    pad = np.concatenate([[True, True], known, [True, True]])
    full = pad[rows] & pad[rows + 1] & pad[rows + 3] & pad[rows + 4]
    c = state.leave_one_out[rows] @ x
    slow = np.nonzero(~full)[0]
    if slow.size:
        loo = np.broadcast_to(known, (slow.size, m)).copy()
        loo[np.arange(slow.size), rows[slow]] = False
        curve, _ = fill_interior_on_curve(np.broadcast_to(x, (slow.size, m, 3)), loo, s)
        c[slow] = curve[np.arange(slow.size), rows[slow]]
    dev = np.linalg.norm(cur[rows] - c, axis=1)
    odd = dev > 2.0 * p.gamma
    if not odd.any():
        return False
    rows, c, dev = rows[odd], c[odd], dev[odd]
    n_taken = int(known.sum())
    kk = min(min(p.candidates, b - a) + n_taken, b - a)
    d, i = _TREES.nearest(state.points, a, b, c, kk, p.gamma)
    taken = state.taken
    d = np.where(np.isin(i, taken[known]) | (d > (dev - p.gamma)[:, None]), np.inf, d)
    hit_rows, pts = gated_assignment(d, i, p.gamma)
    if hit_rows.size:
        hit = rows[hit_rows]
        taken[hit] = pts
        cur[hit] = state.points[pts]
    return bool(hit_rows.size)


def unshift_chain(state: TrackState, t: int, p: StepParams) -> bool:
    """Undo a run of traces matched one marker along the rope (beyond the thesis), in place.

    A rope sliding along itself by about a spacing in one frame (a whip jerked
    lengthwise, a jump rope's arm pulled through the hand's turn) can be matched with
    every trace of a run on its neighbour's marker: the chain's shape holds, the
    trace past the run finds nothing and the marker at the rope's end is left free.
    For an end trace ``e`` (steady) measured with its neighbour, the run is ``e`` up to
    the first trace not found, ``u``. When ``e`` lies more than ``2 γ`` from its own
    prediction V_e and the free point nearest V_e (not taken, not a body point) lies
    within γ of V_e and at ``e``'s link rest length (± γ) from ``e``'s point, the run
    moves one marker towards ``u`` (which takes the point of its neighbour) and ``e``
    takes that point. Tries end 0 first; at most one run moves. True if one moved.
    """
    a, b = _frame_bounds(state, t)
    known, taken, cur = state.known, state.taken, state.cur
    m = known.size
    if b == a or m < 3 or known.all():
        return False
    pts = state.points[a:b]
    free = ~state.body[a:b]
    free[taken[known] - a] = False
    gamma = p.gamma
    for e in (0, m - 1):
        step = 1 if e == 0 else -1
        if not (known[e] and known[e + step]) or state.temp_count[e] != 0:
            continue
        v = state.positions[t - 1, e] + state.velocity[e]
        if np.sum((cur[e] - v) ** 2) <= (2.0 * gamma) ** 2:
            continue
        d2 = np.where(free, np.sum((pts - v) ** 2, axis=1), np.inf)
        q = int(np.argmin(d2))
        if not d2[q] < gamma * gamma:
            continue
        link = state.link_rest[0 if e == 0 else m - 2]
        if abs(float(np.linalg.norm(pts[q] - cur[e])) - link) > gamma:
            continue
        order = np.arange(m) if e == 0 else np.arange(m - 1, -1, -1)
        u = int(order[np.argmin(known[order])])  # the first trace not found from e
        run = order[: abs(u - e) + 1]  # e … u
        taken[run[1:]], cur[run[1:]] = taken[run[:-1]].copy(), cur[run[:-1]].copy()
        known[u], taken[e], cur[e] = True, a + q, pts[q]
        return True
    return False


def place_invented(state: TrackState, t: int, pred: np.ndarray, refit: bool, p: StepParams) -> None:
    """Temporary markers for the traces not found, in ``cur``.

    With ``refit`` (more was measured after ``pred`` (M, 3) was made) the unknown
    interior markers go on the curve through every marker measured now (a lone one
    settled); otherwise, and at the ends, they take ``pred``. Those between measured
    markers are then carried from where they were last seen, and those at a free end
    dragged as a loose end (:func:`_carry_hidden`;
    only the placement: the searches keep the curve, as the synthetic whip's F1 did
    not: 0.9926 -> 0.9913 with the carried prediction searched).
    """
    known, cur = state.known, state.cur
    still = ~known
    if not still.any():
        return
    if known.any() and refit:
        x = np.where(known[:, None], cur, 0.0)
        curve, interior = fill_interior_on_curve(x, known, state.arclength)
        curve = settle_single_gaps(curve, known, state.spacing, p.settle)
        cur[still] = np.where(interior[still, None], curve[still], pred[still])
    else:
        cur[still] = pred[still]
    cur[still] = _carry_hidden(state, t, cur, still, p)[still]


# ------------------------------------------------------------------ a frame
def match_measured(state: TrackState, t: int, v_pred: np.ndarray, p: StepParams) -> None:
    """Pass 1: the steady traces at V (``v_pred`` (M, 3)) within γ, then up to
    ``retry_rounds`` times at V corrected by the residuals of those found, in the
    wide gate; each match followed by the two refusals."""
    steady = state.temp_count == 0
    match_traces(state, t, np.nonzero(steady)[0], v_pred, False, _loose(state), p)
    reject_overstretched(state, t, p)
    reject_odd_motion(state, t, p)
    tried = v_pred
    for _ in range(p.retry_rounds):
        found = state.known & steady
        want = steady & ~state.known
        if not (found.any() and want.any()):
            break
        pred = residual_predictions(state, t, v_pred, p)
        want &= np.einsum("ij,ij->i", pred - tried, pred - tried) > (0.5 * p.gamma) ** 2
        if not want.any():
            break
        if not match_traces(state, t, np.nonzero(want)[0], pred, True, _loose(state), p):
            break
        reject_overstretched(state, t, p)
        reject_odd_motion(state, t, p)
        tried = np.where(want[:, None], pred, tried)


def _match_score(state: TrackState, pred: np.ndarray) -> tuple[int, float]:
    """Traces found this frame and their summed distance (metres) to ``pred`` (M, 3)."""
    known = state.known
    e = state.cur - pred
    dist = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    return int(known.sum()), float(np.sum(dist[known]))


def match_measured_best(state: TrackState, t: int, v_pred: np.ndarray, p: StepParams) -> None:
    """Pass 1 at V (``v_pred`` (M, 3)) or at the accelerated prediction, whichever
    explains the frame better (beyond the thesis).

    :func:`match_measured` runs at V; when that leaves a steady trace unfound or
    farther than ``swing_gate γ`` from V, and some trace's
    :func:`accelerated_prediction` lies more than ``swing_gate γ`` from V, it runs
    again at the accelerated prediction and the one that finds more traces is kept
    (on a tie the one nearer its predictions, V on an exact tie): a swinging rope is
    followed by its acceleration, a jerking hand (a foot stamping at 50 Hz, whose last
    change of velocity is not the next) by its velocity. When the two give a trace
    different points, the one whose disputed traces lie nearer their predictions (summed
    distance) is kept, however many traces each found: the one-to-one assignment finds
    as many traces as it can, so where two arms of a rope lie side by side (a doubled
    U on the floor, 1.8 cm apart) the wrong prediction finds more by handing a trace its
    neighbour-arm's point (c3d.org jump frame 406: 20 traces, two on the wrong arm 2.6
    cm from V, against 14 all right within 0.4 cm of the accelerated prediction).
    """
    known, taken, cur = state.known, state.taken, state.cur
    start = (known.copy(), taken.copy(), cur.copy())
    match_measured(state, t, v_pred, p)
    gate = p.swing_gate * p.gamma
    steady = state.temp_count == 0
    miss = cur - v_pred
    far = np.einsum("ij,ij->i", miss, miss) > gate * gate
    if not (steady & (~known | far)).any():  # V found every steady trace near it
        return
    v_acc = accelerated_prediction(state, t, v_pred, p)
    e = v_acc - v_pred
    if not (np.einsum("ij,ij->i", e, e) > gate * gate).any():
        return
    at_v = (known.copy(), taken.copy(), cur.copy())
    n_v, d_v = _match_score(state, v_pred)
    known[:], taken[:], cur[:] = start
    match_measured(state, t, v_acc, p)
    n_a, d_a = _match_score(state, v_acc)
    # traces both matchings found, on different points: one of the two is wrong there
    disputed = known & at_v[0] & (taken != at_v[1])
    if disputed.any():
        e_v = at_v[2][disputed] - v_pred[disputed]
        e_a = cur[disputed] - v_acc[disputed]
        n_v, d_v = 0, float(np.sum(np.sqrt(np.einsum("ij,ij->i", e_v, e_v))))
        n_a, d_a = 0, float(np.sum(np.sqrt(np.einsum("ij,ij->i", e_a, e_a))))
    if n_v > n_a or (n_v == n_a and d_v <= d_a):
        known[:], taken[:], cur[:] = at_v


def match_missing(state: TrackState, t: int, pred: np.ndarray, p: StepParams) -> bool:
    """Pass 2: the traces still unknown at ``pred`` (M, 3) in the wide gate, then the
    zipper (up to ``zipper_rounds``); each match followed by the two refusals.
    True if any trace matched."""
    found_more = match_traces(state, t, np.nonzero(~state.known)[0], pred, True, _loose(state), p)
    reject_overstretched(state, t, p)
    reject_odd_motion(state, t, p)
    for _ in range(p.zipper_rounds):
        rows, zpred = zipper_predictions(state, p)
        # a hidden held end continues its hand, not the rope's last links
        tight = zip_with_hand(state, t, rows, zpred, p)
        if rows.size == 0 or not match_traces(state, t, rows, zpred, True, tight, p):
            break
        found_more = True
        reject_overstretched(state, t, p)
        reject_odd_motion(state, t, p)
    return found_more


def track_frame(state: TrackState, t: int, p: StepParams) -> None:
    """Track frame t (>= 1) from frame t - 1: every step above, in order."""
    has_points = state.offsets[t + 1] > state.offsets[t]
    v_pred = begin_frame(state, t, p)
    continue_body_chains(state, t, v_pred, p)
    follow_hand(state, t, p)
    if has_points:
        match_measured_best(state, t, v_pred, p)
    pred = state.positions[t - 1] + state.velocity
    found_more = False
    if not state.known.all():
        pred = gap_predictions(state, t, p)
        if has_points:
            found_more = match_missing(state, t, pred, p)
            if not state.known.all():
                found_more |= reacquire_on_shell(state, t, p)
            if not state.known.all():
                found_more |= bridge_hidden_runs(state, t, pred, p)
    swapped = unshift_chain(state, t, p)
    swapped |= swap_onto_curve(state, t, p)
    place_invented(state, t, pred, found_more or swapped, p)
    seat_hand(state, t, p)
    place_with_hand(state, t, p)
    commit_frame(state, t, p)
    release_hand(state, t, p)


def track_frames(state: TrackState, t0: int, t1: int, p: StepParams) -> None:
    """Track frames ``t0 … t1 - 1`` (``t0 >= 1``) in place."""
    for t in range(t0, t1):
        track_frame(state, t, p)
