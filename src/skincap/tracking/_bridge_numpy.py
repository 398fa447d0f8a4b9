"""The rope tracker's bridging of short hidden runs in NumPy (the reference).

Part of the per-frame steps of :mod:`skincap.tracking._steps_numpy` (which re-exports
:func:`bridge_hidden_runs`); its numba twin, of the same name and signature, is in
:mod:`skincap.tracking._bridge_numba`.
"""

from __future__ import annotations

import numpy as np

from skincap.tracking._refusals_numpy import path_back_to_trace, rigid_with_body
from skincap.tracking.state import StepParams, TrackState

__all__ = ["BRIDGE_RUN", "bridge_hidden_runs"]

#: The longest run of hidden inner traces bridged (every chain of that many free
#: points between the two measured ends is scored).
BRIDGE_RUN = 2


def bridge_hidden_runs(state: TrackState, t: int, pred: np.ndarray, p: StepParams) -> bool:
    """Seat short runs of hidden inner traces on the chain of free points that fits
    the rope between their measured ends (beyond the thesis), in place.

    A rope falling onto the floor stops dead and folds: its links' chords shrink
    below the rest spacing by more than γ (8.8 cm for 12.6 cm of rope) and the
    prediction of a marker hidden as it landed stays a few centimetres off the
    marker lying still (c3d.org jump frames 420-441: 3.7 and 14 cm): every other
    search refuses a point beyond γ of its prediction at a short chord, so nothing
    brings the traces back while the rope lies still. Here a run of at most
    :data:`BRIDGE_RUN` hidden traces ``j0 … j1``, each missing since an earlier frame
    (``temp_count >= 1``), between measured markers ``j0 - 1`` and ``j1 + 1`` neither of
    which is an end of the rope (a held end lies among hand markers), is seated on the
    chain of free points (not taken, not body points, not seen beside the trace's
    own marker as a point the rope did not take: :func:`_seen_beside_as_other`) whose
    every link ``k → k + 1`` is at most ``link_rest_k + adjacent_stretch γ`` long (a
    rope's chord may be short, never long) minimising

        Σ_j |x_j - pred_j|  +  Σ_links max(0, link_rest_k - chord_k)

    (``pred`` (M, 3) metres, the gap predictions: the nearer the prediction and the
    nearer the rest spacing, the likelier; a swapped fold's chords are far short).
    Taken only when the next chain costs at least γ more and no point of the chain
    moves rigidly with body points: two readings of a crumpled rope, nothing says
    which. True if any run was seated.
    """
    a, b = int(state.offsets[t]), int(state.offsets[t + 1])
    known, cur, link_rest = state.known, state.cur, state.link_rest
    m = known.size
    if b == a or known.sum() < 2:
        return False
    frame = state.points[a:b]
    free = ~state.body[a:b]
    free[state.taken[known] - a] = False
    reach = p.adjacent_stretch * p.gamma
    found = False
    j0 = 1
    while j0 < m - 1:
        if known[j0] or not known[j0 - 1]:
            j0 += 1
            continue
        j1 = j0
        while j1 < m - 1 and not known[j1 + 1]:
            j1 += 1
        run = np.arange(j0, j1 + 1)
        if (
            2 <= j0
            and j1 <= m - 3
            and run.size <= BRIDGE_RUN
            and (state.temp_count[run] >= 1).all()
            and free.any()
        ):
            seat = _best_chain(
                frame,
                _allowed(state, t, run, free, reach, p),
                cur[j0 - 1],
                cur[j1 + 1],
                link_rest[j0 - 1 : j1 + 1],
                pred[run],
                reach,
                p.gamma,
            )
            if seat is not None and not any(
                rigid_with_body(state, t, -1, a + int(c), p) for c in seat
            ):
                known[run] = True
                state.taken[run] = a + seat
                cur[run] = frame[seat]
                free[seat] = False
                found = True
        j0 = j1 + 1
    return found


def _allowed(
    state: TrackState, t: int, run: np.ndarray, free: np.ndarray, reach: float, p: StepParams
) -> np.ndarray:
    """(R, frame's points) bool: the points of ``free`` each trace of ``run`` (R,) could
    be on: within the rope's length between them (plus ``reach`` metres) of both
    measured ends of the run, and not seen beside the trace's own marker
    (:func:`_seen_beside_as_other`)."""
    a, b = int(state.offsets[t]), int(state.offsets[t + 1])
    frame = state.points[a:b]
    lo, hi = int(run[0]) - 1, int(run[-1]) + 1
    rest = state.link_rest
    d_lo = np.linalg.norm(frame - state.cur[lo], axis=1)
    d_hi = np.linalg.norm(frame - state.cur[hi], axis=1)
    to_lo = np.array([rest[lo:j].sum() for j in run]) + reach  # (R,) metres
    to_hi = np.array([rest[j:hi].sum() for j in run]) + reach
    out = free[None] & (d_lo[None] <= to_lo[:, None]) & (d_hi[None] <= to_hi[:, None])
    for r, c in zip(*np.nonzero(out), strict=True):
        out[r, c] = not _seen_beside_as_other(state, t, int(run[r]), a + int(c), p)
    return out


def _seen_beside_as_other(state: TrackState, t: int, j: int, point: int, p: StepParams) -> bool:
    """True when ``point`` of frame t was, in the frame trace ``j`` was last measured, a
    point the rope did not take more than γ from ``j``'s own: a foot or hand marker
    beside the rope's marker.

    The point is followed back as :func:`~skincap.tracking._reacquire_numpy._beside_trace`
    follows it (nearest point within γ of where its last move takes it, up to
    ``rigid_window`` frames; a broken path is no evidence), but a path reaching another
    of the rope's points is no evidence either: a rope crumpling as it lands moves a
    marker a few centimetres in a frame, and the path steps onto its neighbour.
    """
    reached, f, apart = path_back_to_trace(state, t, j, point, p)
    return reached >= 0 and apart > p.gamma and reached not in state.point_index[f]


def _best_chain(
    frame: np.ndarray,
    allowed: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    rest: np.ndarray,
    pred: np.ndarray,
    reach: float,
    gamma: float,
) -> np.ndarray | None:
    """(R,) indices into ``frame`` (N, 3) of the cheapest chain of R = ``len(rest) - 1``
    (1 or 2) points, trace r's among ``allowed[r]`` (R, N) bool, from ``start`` to
    ``end`` (3,) metres with links ``rest`` (R + 1,) metres each at most ``reach``
    longer; None when there is none or the next costs less than ``gamma`` more.
    Cost: Σ |x_r - pred_r| + Σ max(0, rest - chord), ``pred`` (R, 3) metres."""
    idx = np.nonzero(allowed.any(axis=0))[0]
    if idx.size == 0:
        return None
    x = frame[idx]  # (C, 3)
    ok = allowed[:, idx]  # (R, C)
    d_start = np.linalg.norm(x - start, axis=1)
    d_end = np.linalg.norm(x - end, axis=1)
    limit = rest + reach
    ok[0] &= d_start <= limit[0]
    ok[-1] &= d_end <= limit[-1]
    # each trace's cost: distance to its prediction and its outer link's shortness
    cost_u = np.linalg.norm(x - pred[0], axis=1) + np.maximum(rest[0] - d_start, 0.0)
    if rest.size == 2:
        cost = np.where(ok[0], cost_u + np.maximum(rest[1] - d_end, 0.0), np.inf)  # (C,)
    else:
        cost_v = np.linalg.norm(x - pred[1], axis=1) + np.maximum(rest[2] - d_end, 0.0)
        d_uv = np.linalg.norm(x[:, None] - x[None], axis=2)  # (C, C) the middle link
        pair = ok[0][:, None] & ok[1][None, :] & (d_uv <= limit[1])
        np.fill_diagonal(pair, False)
        cost = cost_u[:, None] + cost_v[None, :] + np.maximum(rest[1] - d_uv, 0.0)
        cost = np.where(pair, cost, np.inf).ravel()  # (C * C,) row u, column v
    order = np.argsort(cost, kind="stable")[:2]
    best = cost[order[0]]
    if not np.isfinite(best) or (order.size > 1 and cost[order[1]] < best + gamma):
        return None
    if rest.size == 2:
        return idx[order[:1]]
    return idx[[order[0] // idx.size, order[0] % idx.size]]
