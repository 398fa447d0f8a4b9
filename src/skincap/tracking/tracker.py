"""Rope marker tracking through an un-indexed point cloud (Porter 2012, §3.5).

Every frame, each rope trace looks for the point nearest its predicted position
within γ. The prediction is the marker's own velocity (eqs. 3.1-3.2,
``V = m^{i-1} + v^{i-1} Δt``) while the trace is measured; when that finds nothing,
or while the trace is in a gap, it is ``F = α Ṽ + (1 - α) N`` (eq. 3.6) with ``Ṽ``
from the velocities of the nearest measured neighbours on each side (eq. 3.3, ``β``
weighting the nearer neighbour more), ``N`` by midpoint displacement from the three
nearest traces on the measured side (eqs. 3.4-3.5) and ``α = 1 /`` the number of
consecutive temporary markers. Found nothing, the trace gets a temporary (invented)
marker at its prediction.

Beyond the thesis:

* Conflicts are resolved per frame globally: the traces and the points within γ of
  their predictions are matched one-to-one minimising the summed distance
  (:func:`~skincap.tracking.init.gated_assignment`), so two traces never take one
  point.
* A missing marker with measured markers on both sides is predicted (and, if still
  unseen, invented) on the smooth curve through the measured markers at its rest
  arc length (:mod:`skincap.tracking.curve`); the thesis' ``F`` is kept for runs of
  missing markers at the ends of the rope, and it is projected to the rest spacing
  ``l_j`` from its measured side, so invented markers keep the rope's length.
* After more than ``maxTempMarkers`` consecutive temporary markers a trace is *lost*:
  it goes on being invented the same way (so positions are never NaN) and flagged in
  :attr:`RopeTrack.lost_frames`, and it keeps looking for a point within γ of that
  invented position; taking one ends the loss.

* A measured trace not found within γ of V gets a second chance in the same frame:
  V corrected by the prediction errors of the traces found (interpolated along the
  rope), searched within ``2 γ`` but only at its rest spacing ``l_j`` (± γ) from a
  measured neighbour — the fast middle of a turning rope accelerates far beyond γ
  per frame, and the errors of neighbouring markers are alike. The same wider,
  length-constrained gate is used for the curve/F searches.
* A point that continues a point of the previous frame that the rope did not take,
  moving slower than the rope by more than γ, is a body marker beside a fast rope:
  traces coming back from a gap, and inner traces, do not take it.
* Body chains: every point of frame 0 the rope does not take is a body point (the user
  selected the rope there); a point that continues a body point of the previous frame
  (the only point within ``γ / 3`` of where that point's velocity takes it, and that
  point the only one near it, and no trace measured there predicted near it) is a
  body point too. A trace coming back from a gap (or never seen) does not take a
  body point. This keeps the traces of markers hidden in the initialisation window,
  invented on the curve beside the legs, off the leg markers while the rope hangs
  still and no motion test can tell the two apart.
* The zipper: a run of two or more invented markers inside the rope (a whip's wave,
  a rope lifting off the floor) is badly bridged by the curve, so the markers at the
  run's ends are also searched where the measured side continues: bent as it bends
  (quadratic extrapolation through three measured markers, else straight on as N),
  at the rest spacing, inward one marker per side and round
  (:func:`_zipper_predictions`).
* Traces that break the rope's length (two measured markers farther apart than the
  rope between them, neighbours more than 0.4 γ beyond their rest spacing) are
  resolved by keeping the largest consistent chain (a trace that slipped onto its
  neighbour's marker is dropped), markers on points that move rigidly with body
  points counting against a chain (a body marker keeps its distance to two or more
  points the rope does not take over the last quarter second; a rope marker does
  not): the body-like side of a stretched link goes. A trace coming back from a gap
  does not take such a point either. A trace that sits more than ``2 γ`` off the
  curve through the other measured markers moves to a free point on that curve (it
  had taken a body point while its marker was hidden).

Candidate points come from a KD-tree over each frame's points, built when the frame
is first searched.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from skincap.backends import numba_available, resolve_backend
from skincap.errors import SkincapWarning, ValidationError
from skincap.tracking.curve import fill_interior_on_curve, rest_arclength, settle_single_gaps
from skincap.tracking.init import (
    _RIGID_PARTNERS,
    _RIGID_RADIUS,
    _RIGID_RANGE,
    RopeInit,
    gated_assignment,
)
from skincap.tracking.physical import bound_invented
from skincap.types import MarkerSet, PointCloud

__all__ = ["RopeTrack", "track_rope"]

#: Largest chord between neighbouring markers, in rest spacings (plus γ).
_STRETCH = 1.1
#: Candidates per trace considered by the assignment.
_CANDIDATES = 3
#: Rounds of residual-corrected prediction for traces not found at V.
_ROUNDS = 3
#: Gate of the second-chance searches (residual-corrected V, curve/F), in γ; a point
#: beyond γ is taken there only at its rest spacing (± γ) from a measured neighbour.
_WIDE_GATE = 2.0
#: Refuse candidates that continue a point the rope did not take (:func:`_follows_other`).
_FOLLOW = True
#: Gate of the body chains (:func:`_body_chains`), in γ: a point continues a body point
#: of the previous frame when it lies this close to where that point's velocity takes it.
_CHAIN = 1.0 / 3.0
#: A steady trace predicted to move at most γ takes no point beyond γ in the wider
#: second-chance gates (a slow rope does not jump; a body point beside it would).
_SLOW = True
#: Largest chord between two neighbouring measured markers: their rest spacing plus
#: this many γ (a rope does not stretch; a body point beside the rope sits farther).
_ADJ = 0.4
#: Window of the rigidity test (:func:`_rigid_with_body`), in seconds.
_RIGID_WINDOW = 0.25
#: The rigidity test needs the point to move this many rest spacings in its window.
_RIGID_MOVE = 0.3
#: Rounds of the zipper (:func:`_zipper_predictions`): a run of invented inner markers
#: is searched from its measured ends inward, one marker per side and round.
_ZIP = 3
#: The zipper only inside the rope (a run at an end of the rope is left to F: with the
#: end marker hidden among hand markers, continuing the run outward takes them).
_ZIP_INNER = True
#: The zipper bends with the measured side (quadratic), not straight on (linear).
_ZIP_QUAD = True
#: The zipper also predicts a rope end next to two measured markers (a curled free
#: end is missed by the thesis' straight N; rigid body points beside it are refused).
_ZIP_ENDS = True
#: A lone invented inner marker moves this share of the way from the curve to its rest
#: spacings from both neighbours (:func:`~skincap.tracking.curve.settle_single_gaps`):
#: the curve cuts a whip's sharp bend.
_SETTLE = 0.5


@dataclass(eq=False)
class RopeTrack:
    """The tracked rope.

    Attributes
    ----------
    positions : (T, M, 3) float64, metres
        Rope markers in order along the rope; invented where unseen, within the
        distance the rope's length allows from the measured markers (10 % stretch,
        :mod:`skincap.tracking.physical`); NaN where the trace is lost.
    invented : (T, M) bool
        True where the sample is a temporary marker rather than a measured point.
    point_index : (T, M) int64
        Index into ``cloud.points`` of the point each trace took; -1 where invented.
        No point appears twice.
    lost_frames : (T, M) bool
        True where the trace had more than ``max_temp_markers`` consecutive
        temporary markers, or no place the rope's length allows: ``positions`` is NaN
        there (the tracker goes on predicting it internally, so it can be found again).
    labels : list of M str
        ``rope_00``, ``rope_01``….
    rate : float, Hz
    init : RopeInit
    meta : dict
        The cloud's meta (units, up axis, first frame) for writers.
    """

    positions: np.ndarray
    invented: np.ndarray
    point_index: np.ndarray
    lost_frames: np.ndarray
    labels: list[str]
    rate: float
    init: RopeInit
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[1])

    @property
    def lost(self) -> np.ndarray:
        """(M,) bool: True for traces lost at some frame."""
        return self.lost_frames.any(axis=0)

    def rope_points_mask(self, cloud: PointCloud) -> np.ndarray:
        """(cloud.points.shape[0],) bool: True for the points the rope took."""
        mask = np.zeros(cloud.points.shape[0], dtype=bool)
        taken = self.point_index[self.point_index >= 0]
        if taken.size and taken.max() >= mask.size:
            raise ValidationError("cloud: not the point cloud this rope was tracked in")
        mask[taken] = True
        return mask

    def to_markerset(self) -> MarkerSet:
        """The rope as labelled markers, invented samples flagged, lost samples NaN."""
        return MarkerSet(
            positions=self.positions.copy(),
            labels=list(self.labels),
            rate=self.rate,
            invented=self.invented & np.isfinite(self.positions).all(axis=2),
            meta=dict(self.meta),
        )


class _FrameTree:
    """Nearest points of one frame: a KD-tree over that frame's points, built on demand."""

    def __init__(self, cloud: PointCloud) -> None:
        self.cloud = cloud
        self.t = -1
        self.tree: cKDTree | None = None
        self.base = 0

    def count(self, t: int) -> int:
        """Points in frame t."""
        return int(self.cloud.offsets[t + 1] - self.cloud.offsets[t])

    def query(self, t: int, q: np.ndarray, k: int, gate: float) -> tuple[np.ndarray, np.ndarray]:
        """(R, k) distances (inf for none) and global point indices near ``q`` in frame t.

        Frame t must hold at least ``k >= 1`` points. Where the distance is inf the
        index is meaningless.
        """
        if t != self.t:
            a, b = int(self.cloud.offsets[t]), int(self.cloud.offsets[t + 1])
            self.tree = cKDTree(self.cloud.points[a:b])
            self.base, self.t = a, t
        assert self.tree is not None
        d, i = self.tree.query(q, k=k, distance_upper_bound=gate)
        return d.reshape(q.shape[0], k), i.reshape(q.shape[0], k) + self.base


def _side_neighbours(known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M,) nearest known index before (-1 if none) and after (M if none) each marker."""
    m = known.size
    ar = np.arange(m)
    before = np.maximum.accumulate(np.where(known, ar, -1))
    before = np.concatenate([[-1], before[:-1]])
    after = np.minimum.accumulate(np.where(known, ar, m)[::-1])[::-1]
    after = np.concatenate([after[1:], [m]])
    return before, after


def _reject_overstretched(
    cur: np.ndarray,
    known: np.ndarray,
    taken: np.ndarray,
    s: np.ndarray,
    gamma: float,
    rigid: Callable[[int, int], bool] | None = None,
) -> None:
    """Refuse taken points that would stretch the rope (beyond the thesis), in place.

    A rope does not stretch: two measured markers ``a < b`` lie at most
    ``1.1 (s_b - s_a) + γ`` apart, neighbours ``b = a + 1`` at most their rest spacing
    plus ``_ADJ γ`` (a body point beside the rope sits farther). When consecutive
    measured markers break that, the measured markers kept are the best subset in
    which every consecutive pair obeys it (dynamic programming over the chain): each
    marker kept counts +1, or -1 where ``rigid(j, point)`` says its point moves
    rigidly with body points (:func:`_rigid_with_body`: the body-like side of a
    stretched link goes, never the rope-like side), each link less half its
    deformation (chord below or beyond the rest arc length, relative: a trace that
    slipped onto its neighbour's marker, or onto a point beside the rope). The others
    are un-taken. ``rigid`` is only asked when a link breaks the limits.
    """
    idx = np.nonzero(known)[0]
    if idx.size < 2:
        return
    xs = cur[idx]
    chord = np.linalg.norm(xs[1:] - xs[:-1], axis=1)
    ds1 = s[idx[1:]] - s[idx[:-1]]
    lim1 = np.where(idx[1:] - idx[:-1] == 1, ds1 + _ADJ * gamma, _STRETCH * ds1 + gamma)
    if np.all(chord <= lim1):
        return
    n = idx.size
    si = s[idx]
    dist = np.linalg.norm(xs[:, None] - xs[None, :], axis=2)  # (n, n)
    ds = si[None, :] - si[:, None]  # s_b - s_a
    adjacent = idx[None, :] - idx[:, None] == 1
    limit = np.where(adjacent, ds + _ADJ * gamma, _STRETCH * ds + gamma)
    feasible = np.triu(dist <= limit, k=1)
    dev = (ds - dist) / np.where(ds > 0, ds, 1.0)
    squeeze = np.clip(dev, 0.0, 1.0) + np.clip(-dev, 0.0, 1.0)  # compressed or stretched
    # a marker counts +1, one on a point moving rigidly with body points -1
    w = np.ones(n)
    if rigid is not None:
        w = np.array([-1.0 if rigid(int(j), int(taken[j])) else 1.0 for j in idx])
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
    rows = idx[~keep]
    known[rows] = False
    taken[rows] = -1


def _rigid_with_body(
    points: np.ndarray,
    offsets: np.ndarray,
    point_index: np.ndarray,
    t: int,
    j: int,
    p: int,
    taken: np.ndarray,
    spacing: float,
    window: int,
) -> bool:
    """True when the point ``p`` of frame t moves rigidly with body points (beyond the thesis).

    ``p``'s path over the last ``window`` frames is trace ``j``'s points where the
    trace was measured in all of them; otherwise (or ``j < 0``) ``p`` is followed
    backward itself at constant velocity, to the nearest point when that lies within
    ``2 _RIGID_RANGE`` spacings and the second nearest twice as far; a frame without
    such a point means no evidence (False), as does a path moving less than
    ``_RIGID_MOVE`` spacings (a still point moves "rigidly" with everything still). Every point of frame t within
    ``_RIGID_RADIUS`` spacings of ``p`` that the rope does not take (``taken``) is
    followed backward frame by frame, moving as ``p``'s trace moved, to the nearest
    point within ``_RIGID_RANGE`` spacings of that prediction that the rope did not
    take; ``p`` is body-like when at least two of them keep their distance to it
    within ``_RIGID_RANGE`` spacings over the whole window (a body marker moves with
    its segment's markers; a rope marker does not; the rope's own points are taken).

    Parameters
    ----------
    points : (N, 3) float64, metres
        The cloud's points; ``offsets`` (T + 1,) int its frames.
    point_index : (T, M) int64
        The points the traces took in frames before t (-1 where invented).
    t, j, p : int
        The frame, the trace (-1: none), the point (global index in frame t).
    taken : (M,) int64
        The points the traces take in frame t so far (-1 for none).
    spacing : float, metres
        The rope's median rest spacing.
    window : int
        Frames looked back (none before frame ``window``: False).
    """
    if t < window:
        return False
    tol = _RIGID_RANGE * spacing
    hist = point_index[t - window : t, j] if j >= 0 else np.full(window, -1)
    if np.any(hist < 0):
        # follow p itself backward at constant velocity, unambiguous nearest points
        traj = np.empty((window + 1, 3))
        traj[-1] = points[p]
        v = np.zeros(3)
        for f in range(t - 1, t - window - 1, -1):
            fa, fb = int(offsets[f]), int(offsets[f + 1])
            if fb - fa < 2:
                return False
            x = traj[f - t + window + 1]
            dd = np.linalg.norm(points[fa:fb] - (x - v), axis=1)
            o = np.argsort(dd)[:2]
            if not (dd[o[0]] < 2.0 * tol and dd[o[1]] > 2.0 * dd[o[0]]):
                return False
            traj[f - t + window] = points[fa + o[0]]
            v = x - traj[f - t + window]
    else:
        traj = np.concatenate([points[hist], points[p][None]])  # (W + 1, 3)
    if np.max(np.linalg.norm(traj - traj[-1], axis=1)) < _RIGID_MOVE * spacing:
        return False
    a, b = int(offsets[t]), int(offsets[t + 1])
    frame = points[a:b]
    d0 = np.linalg.norm(frame - traj[-1], axis=1)
    cand = (d0 < _RIGID_RADIUS * spacing) & (np.arange(a, b) != p)
    cand[taken[(taken >= a) & (taken < b)] - a] = False
    found = 0
    for c in np.nonzero(cand)[0]:
        q = frame[c]
        dq = d0[c]
        ok = True
        for f in range(t - 1, t - window - 1, -1):
            fa, fb = int(offsets[f]), int(offsets[f + 1])
            if fb == fa:
                ok = False
                break
            pred = q + (traj[f - t + window] - traj[f - t + window + 1])
            dd = np.linalg.norm(points[fa:fb] - pred, axis=1)
            dd[point_index[f][(point_index[f] >= fa) & (point_index[f] < fb)] - fa] = np.inf
            n = int(np.argmin(dd))
            q = points[fa + n]
            if not (dd[n] < tol and abs(np.linalg.norm(q - traj[f - t + window]) - dq) < tol):
                ok = False
                break
        if ok:
            found += 1
            if found >= _RIGID_PARTNERS:
                return True
    return False


def _reject_odd_motion(
    cur: np.ndarray,
    prev: np.ndarray,
    known: np.ndarray,
    taken: np.ndarray,
    limit: float,
    steady: np.ndarray,
) -> None:
    """Refuse taken points that do not move with the rope (beyond the thesis), in place.

    A marker whose two neighbours are measured moves, frame to frame, within
    ``limit`` of the mean of their moves (the rope is smooth); a point that does not
    belongs to something else (a body marker sitting on the rope's path). Only
    ``steady`` markers (measured in the previous frame) are judged: one coming back
    from a gap "moves" by the error of its invented position, which says nothing
    about the point (those are judged by :func:`_follows_other`).
    """
    inner = known[1:-1] & known[:-2] & known[2:] & steady[1:-1]
    if not inner.any():
        return
    move = cur - prev
    expected = 0.5 * (move[:-2] + move[2:])
    odd = inner & (np.linalg.norm(move[1:-1] - expected, axis=1) > limit)
    if odd.any():
        idx = np.nonzero(odd)[0] + 1
        known[idx] = False
        taken[idx] = -1


@dataclass
class _Previous:
    """The previous frame, for :func:`_follows_other`."""

    points: np.ndarray  # (n, 3) that frame's points, metres
    untaken: np.ndarray  # (n,) bool: not taken by the rope there
    positions: np.ndarray  # (M, 3) the rope there
    steady: np.ndarray  # (M,) bool: measured there


def _follows_other(
    prev: _Previous,
    rows: np.ndarray,
    pred: np.ndarray,
    cand: np.ndarray,
    dist: np.ndarray,
    points: np.ndarray,
    gamma: float,
) -> np.ndarray:
    """(R, K) bool: the candidate continues something else than the rope (beyond the thesis).

    A body marker beside a fast rope moves far less than the rope. The trace of a
    marker coming back from a gap, or any inner trace, refuses a candidate that lies
    within ``min(γ, D - γ)`` of a point of the previous frame that the rope did not
    take, ``D`` being how far the trace is predicted to move: that point has moved
    slower than the rope by more than γ, so it is not the rope. Off where the rope
    is slow (``D <= γ``); the ends of a steady rope are exempt (they are held in
    the hands, among hand markers that move with them).
    """
    m = prev.steady.size
    out = np.zeros(dist.shape, dtype=bool)
    q = prev.points[prev.untaken]
    if q.shape[0] == 0:
        return out
    e = pred[rows] - prev.positions[rows]
    speed = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    lim = np.minimum(gamma, speed - gamma)
    judged = (~prev.steady[rows] | ((rows > 0) & (rows < m - 1))) & (lim > 0.0)
    r_idx, c_idx = np.nonzero(judged[:, None] & np.isfinite(dist))
    if r_idx.size == 0:
        return out
    p = points[cand[r_idx, c_idx]]  # (P, 3)
    dx = p[:, None, 0] - q[None, :, 0]
    dy = p[:, None, 1] - q[None, :, 1]
    dz = p[:, None, 2] - q[None, :, 2]
    near = (dx * dx + dy * dy + dz * dz) < (lim[r_idx] * lim[r_idx])[:, None]
    out[r_idx, c_idx] = near.any(axis=1)
    return out


def _body_chains(
    prev_points: np.ndarray,
    prev_body: np.ndarray,
    prev_vel: np.ndarray,
    points: np.ndarray,
    rope_pred: np.ndarray,
    eps: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Body points of a frame, by continuity with the previous frame's (beyond the thesis).

    Parameters
    ----------
    prev_points : (P, 3) float64, metres
        The previous frame's points.
    prev_body : (P,) bool
        Which of them are body points.
    prev_vel : (P, 3) float64, metres per frame
        Their last displacement (zero where a chain starts).
    points : (N, 3) float64, metres
        This frame's points.
    rope_pred : (R, 3) float64, metres
        Where the traces measured in the previous frame are predicted now (V): a point
        near one of them is ambiguous and not a body point (a hand marker hidden
        beside the rope's end does not pass its chain to the rope).
    eps : float, metres
        Gate around the predicted position ``q + v`` of each previous body point.

    Returns
    -------
    body : (N,) bool
        The points that are the only one within ``eps`` of a previous body point's
        prediction which itself is the only prediction (body or rope) within ``eps``
        of them.
    vel : (N, 3) float64, metres per frame
        Their displacement from that point (zero elsewhere).
    """
    n = points.shape[0]
    body = np.zeros(n, dtype=bool)
    vel = np.zeros((n, 3))
    qi = np.nonzero(prev_body)[0]
    if qi.size == 0 or n == 0:
        return body, vel
    pred = prev_points[qi] + prev_vel[qi]
    dx = points[:, None, 0] - pred[None, :, 0]
    dy = points[:, None, 1] - pred[None, :, 1]
    dz = points[:, None, 2] - pred[None, :, 2]
    near = (dx * dx + dy * dy + dz * dz) < eps * eps  # (N, Q)
    single = near.sum(axis=1) == 1
    if rope_pred.shape[0]:
        ex = points[:, None, 0] - rope_pred[None, :, 0]
        ey = points[:, None, 1] - rope_pred[None, :, 1]
        ez = points[:, None, 2] - rope_pred[None, :, 2]
        single &= ~((ex * ex + ey * ey + ez * ez) < eps * eps).any(axis=1)
    ok = near & single[:, None] & (near.sum(axis=0) == 1)[None, :]
    p_idx, q_col = np.nonzero(ok)
    body[p_idx] = True
    vel[p_idx] = points[p_idx] - prev_points[qi[q_col]]
    return body, vel


def _match(
    tree: _FrameTree,
    t: int,
    rows: np.ndarray,
    pred: np.ndarray,
    k: int,
    gamma: float,
    cur: np.ndarray,
    known: np.ndarray,
    taken: np.ndarray,
    points: np.ndarray,
    gate: float | None = None,
    spacing: np.ndarray | None = None,
    follow: _Previous | None = None,
    body: np.ndarray | None = None,
    body_steady: np.ndarray | None = None,
    prev: np.ndarray | None = None,
    rigid: Callable[[int, int], bool] | None = None,
) -> bool:
    """Match the traces ``rows`` to free points of frame t within γ of ``pred``, in place.

    Points already taken this frame are skipped; conflicts are resolved one-to-one
    (:func:`~skincap.tracking.init.gated_assignment`). With ``follow``, points that
    continue another object (:func:`_follows_other`) are skipped too; with ``body``
    ((cloud points,) bool) and ``body_steady`` ((M,) bool: traces measured in the
    previous frame), the body points (:func:`_body_chains`) are skipped by the traces
    that are not steady. With ``prev`` ((M, 3) the rope in the previous frame) and a
    wider ``gate``, a steady trace predicted to move no more than γ does not take a
    point beyond γ (:data:`_SLOW`). With ``rigid`` (``(trace, point) -> bool``, see
    :func:`_rigid_with_body`) and ``body_steady``, the traces that are not steady
    (coming back from a gap) do not take a point moving rigidly with body points.
    Returns True if any matched.
    """
    if rows.size == 0:
        return False
    gate = gamma if gate is None else gate
    n_taken = int(known.sum())
    kk = min(k + n_taken, tree.count(t))
    d, i = tree.query(t, pred[rows], kk, gate)
    if n_taken:
        d = np.where(np.isin(i, taken[known]), np.inf, d)
    if body is not None and body_steady is not None:
        off = body[np.minimum(i, points.shape[0] - 1)] & ~body_steady[rows][:, None]
        d = np.where(off, np.inf, d)
    if _SLOW and prev is not None and body_steady is not None and gate > gamma:
        e = pred[rows] - prev[rows]
        slow = body_steady[rows] & (np.einsum("ij,ij->i", e, e) <= gamma * gamma)
        d = np.where(slow[:, None] & (d >= gamma), np.inf, d)
    if follow is not None:
        d = np.where(_follows_other(follow, rows, pred, i, d, points, gamma), np.inf, d)
    if rigid is not None and body_steady is not None:
        for r in np.nonzero(~body_steady[rows])[0]:
            for c in range(d.shape[1]):
                if np.isfinite(d[r, c]) and d[r, c] < gate and rigid(-1, int(i[r, c])):
                    d[r, c] = np.inf
    if spacing is not None:
        # the chord to each measured neighbour within γ of its rest spacing
        m = known.size
        q = points[np.minimum(i, points.shape[0] - 1)]  # (R, kk, 3)
        lonely = ~(known[np.maximum(rows - 1, 0)] & (rows > 0))
        lonely &= ~(known[np.minimum(rows + 1, m - 1)] & (rows < m - 1))
        d = np.where(lonely[:, None] & (d >= gamma), np.inf, d)
        for step in (-1, 1):
            nb = rows + step
            okn = (nb >= 0) & (nb < m)
            nbc = np.clip(nb, 0, m - 1)
            has = okn & known[nbc]
            if not has.any():
                continue
            rest = spacing[np.minimum(np.minimum(rows, nbc), m - 2)]
            chord = np.linalg.norm(q - cur[nbc][:, None, :], axis=2)
            bad = has[:, None] & (np.abs(chord - rest[:, None]) > gamma)
            d = np.where(bad, np.inf, d)
    hit_rows, pts = gated_assignment(d, i, gate)
    if hit_rows.size == 0:
        return False
    hit = rows[hit_rows]
    known[hit] = True
    taken[hit] = pts
    cur[hit] = points[pts]
    return True


def _zipper_predictions(
    cur: np.ndarray, known: np.ndarray, spacing: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where the ends of runs of unknown markers continue the rope (beyond the thesis).

    The curve through the measured markers bridges a long run of unknown markers
    badly (a whip's wave, a rope lifting off the floor): the prediction falls far
    from markers that are in plain view. An unknown marker ``j`` (an end of the rope
    only with ``_ZIP_ENDS``; an inner one with ``_ZIP_INNER`` only inside the
    measured part) with two measured
    markers on one side (``j - 1`` and ``j - 2``, or ``j + 1`` and ``j + 2``) and an
    unknown neighbour on the other is predicted by continuing the measured side, bending as it bends
    when a third measured marker follows (quadratic extrapolation with ``_ZIP_QUAD``,
    else straight on as the thesis' N, eq. 3.5), at the rest spacing from its neighbour::

        e = 3 m_{j-1} - 3 m_{j-2} + m_{j-3}   (or 2 m_{j-1} - m_{j-2})
        x_j = m_{j-1} + l * (e - m_{j-1}) / |e - m_{j-1}|

    Parameters
    ----------
    cur : (M, 3) float64, metres
        The markers; only the measured ones are read.
    known : (M,) bool
        Measured this frame.
    spacing : (M - 1,) float64, metres
        Rest spacings ``l_j``.

    Returns
    -------
    rows : (R,) int64
        The markers predicted.
    pred : (M, 3) float64, metres
        Their predictions (zero elsewhere).
    """
    m = known.size
    pred = np.zeros((m, 3))
    if m < 4:
        return np.zeros(0, dtype=np.int64), pred
    ar = np.arange(m)
    pad = np.concatenate([[False] * 3, known, [False] * 3])
    k_m3, k_m2, k_m1 = pad[ar], pad[ar + 1], pad[ar + 2]
    k_p1, k_p2, k_p3 = pad[ar + 4], pad[ar + 5], pad[ar + 6]
    body = ~known & (ar > 0) & (ar < m - 1)
    if _ZIP_INNER:
        before, after = _side_neighbours(known)
        body &= (before >= 0) & (after < m)
    if _ZIP_ENDS:
        body |= ~known & ((ar == 0) | (ar == m - 1))
    lo = body & k_m1 & k_m2 & ~k_p1
    hi = body & k_p1 & k_p2 & ~k_m1
    for side, step, third in ((lo, -1, k_m3), (hi, 1, k_p3)):
        j = np.nonzero(side)[0]
        if j.size == 0:
            continue
        a, b = cur[j + step], cur[j + 2 * step]
        c = cur[np.clip(j + 3 * step, 0, m - 1)]
        e = np.where((third[j] & _ZIP_QUAD)[:, None], 3.0 * a - 3.0 * b + c, 2.0 * a - b)
        d = e - a
        norm = np.linalg.norm(d, axis=1)
        rest = spacing[np.minimum(j, j + step)]
        ok = norm > 0
        pred[j[ok]] = a[ok] + (rest[ok] / norm[ok])[:, None] * d[ok]
        side[j[~ok]] = False
    return np.nonzero(lo | hi)[0], pred


def _interp_along(known: np.ndarray, values: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(M, 3) ``values`` of the known markers, interpolated linearly in rest arc length.

    Unknown markers between two known ones get the linear interpolation at their
    ``s``; unknown markers at an end the value of the nearest known one; known markers
    keep theirs. With nothing known the result is zero.
    """
    m = known.size
    before, after = _side_neighbours(known)
    has_b, has_a = before >= 0, after < m
    b = np.clip(before, 0, m - 1)
    a = np.clip(after, 0, m - 1)
    both = has_b & has_a
    span = np.where(both, s[a] - s[b], 1.0)
    w = np.where(both, (s - s[b]) / span, np.where(has_b, 0.0, 1.0))
    out = (1.0 - w)[:, None] * values[b] + w[:, None] * values[a]
    out[~(has_b | has_a)] = 0.0
    return np.where(known[:, None], values, out)


def _leave_one_out_weights(s: np.ndarray) -> np.ndarray:
    """(M, M) W: ``W[j] @ x`` is the curve through every marker but ``j``, at ``s_j``.

    :func:`~skincap.tracking.curve.fill_interior_on_curve` is linear in the
    positions, so it is evaluated once on unit positions. Row ``j`` is valid when
    markers ``j - 2 … j + 2`` (those that exist) are all measured; rows 0 and M - 1
    are zero (an end has no curve on both sides).
    """
    m = s.size
    basis = np.zeros((m, m, m, 3))
    basis[:, np.arange(m), np.arange(m), 0] = 1.0  # [j, k]: marker k at unit x
    known = np.ones((m, m, m), dtype=bool)
    known[np.arange(m), :, np.arange(m)] = False
    filled, _ = fill_interior_on_curve(basis, known, s)
    w = filled[np.arange(m), :, np.arange(m), 0]  # (j, k)
    w[[0, m - 1]] = 0.0
    return w


def _check_on_curve(
    tree: _FrameTree,
    t: int,
    k: int,
    gamma: float,
    s: np.ndarray,
    cur: np.ndarray,
    known: np.ndarray,
    taken: np.ndarray,
    points: np.ndarray,
    loo_weights: np.ndarray,
) -> bool:
    """Move a trace off a body point onto the rope marker it lost (beyond the thesis).

    A trace that took a body point while its rope marker was hidden keeps following
    that point by its own velocity after the marker reappears. For every measured
    marker with measured markers on both sides, the curve through the *other*
    measured markers gives where it should be (``C_j``); a marker farther than
    ``2 γ`` from ``C_j`` swaps to a free point that is at least γ nearer to ``C_j``
    (and within γ of it), conflicts resolved one-to-one. In place; True if any moved.
    """
    m = known.size
    before, after = _side_neighbours(known)
    rows = np.nonzero(known & (before >= 0) & (after < m))[0]
    if rows.size == 0:
        return False
    x = np.where(known[:, None], cur, 0.0)
    # markers j-2 … j+2 all measured (or beyond an end): the precomputed weights
    pad = np.concatenate([[True, True], known, [True, True]])
    full = pad[rows] & pad[rows + 1] & pad[rows + 3] & pad[rows + 4]
    c = loo_weights[rows] @ x
    slow = np.nonzero(~full)[0]
    if slow.size:
        loo = np.broadcast_to(known, (slow.size, m)).copy()
        loo[np.arange(slow.size), rows[slow]] = False
        batch = np.broadcast_to(x, (slow.size, m, 3))
        curve, _ = fill_interior_on_curve(batch, loo, s)
        c[slow] = curve[np.arange(slow.size), rows[slow]]
    dev = np.linalg.norm(cur[rows] - c, axis=1)
    odd = dev > 2.0 * gamma
    if not odd.any():
        return False
    rows, c, dev = rows[odd], c[odd], dev[odd]
    n_taken = int(known.sum())
    kk = min(k + n_taken, tree.count(t))
    d, i = tree.query(t, c, kk, gamma)
    d = np.where(np.isin(i, taken[known]) | (d > (dev - gamma)[:, None]), np.inf, d)
    hit_rows, pts = gated_assignment(d, i, gamma)
    if hit_rows.size:
        hit = rows[hit_rows]
        taken[hit] = pts
        cur[hit] = points[pts]
    return bool(hit_rows.size)


def _neighbour_velocity(
    known: np.ndarray, velocity: np.ndarray, fallback: np.ndarray
) -> np.ndarray:
    """ṽ (eq. 3.3): β-weighted velocity of the nearest measured neighbour on each side.

    β favours the nearer neighbour: with neighbours ``n`` and ``m`` markers away,
    ``ṽ = m/(n+m) v_{j-n} + n/(n+m) v_{j+m}``; one side only gives that side's
    velocity; none gives ``fallback``.
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
    the measured part; each projected to its rest spacing from its inner neighbour.

    ``cur`` (M, 3) holds the measured markers; the unknown end markers are written
    in place and returned.
    """
    m = known.size
    idx = np.nonzero(known)[0]
    first, last = int(idx[0]), int(idx[-1])
    # outward order: head run from first-1 down to 0, tail run from last+1 up to m-1
    for j, step in [(j, +1) for j in range(first - 1, -1, -1)] + [
        (j, -1) for j in range(last + 1, m)
    ]:
        j1, j2, j3 = j + step, j + 2 * step, j + 3 * step
        v_pred = prev[j] + v_tilde[j]  # Ṽ, eq. 3.1 with ṽ
        if 0 <= j2 < m:
            far = j3 if 0 <= j3 < m else j2
            d = (cur[j1] - cur[far]) / 2.0  # eq. 3.4: ((m1 - m2) + (m2 - m3)) / 2
            norm = float(np.linalg.norm(d))
            l1 = spacing[min(j, j1)]
            n_pred = cur[j1] + l1 * d / norm if norm > 0 else v_pred  # eq. 3.5
        else:
            l1 = spacing[min(j, j1)]
            n_pred = v_pred
        alpha = 1.0 / temp_count[j]
        f = alpha * v_pred + (1.0 - alpha) * n_pred  # eq. 3.6
        r = f - cur[j1]
        rn = float(np.linalg.norm(r))
        cur[j] = cur[j1] + l1 * r / rn if rn > 0 else f
    return cur


def _track_frames_dispatcher() -> Any:
    from skincap.tracking._kernel import track_frames

    return track_frames


def _resolve_backend(backend: str) -> str:
    # "auto" runs NumPy while the kernel is not compiled yet and compiles it in the
    # background (skincap.backends): a first run never waits for the compiler
    return resolve_backend(
        backend,
        numba_installed=numba_available(),
        feature="the compiled rope tracker",
        kernel=("tracking", _track_frames_dispatcher),
    )


def _track_numpy(
    cloud: PointCloud,
    init: RopeInit,
    s: np.ndarray,
    positions: np.ndarray,
    invented: np.ndarray,
    point_index: np.ndarray,
    lost_frames: np.ndarray,
    velocity: np.ndarray,
    temp_count: np.ndarray,
    body: np.ndarray,
    body_vel: np.ndarray,
    progress: Callable[[float], object] | None,
    every: int,
) -> None:
    """The per-frame loop of :func:`track_rope` in NumPy (the reference), in place.

    Frame 0 of the output arrays is filled; ``velocity`` (M, 3) and ``temp_count``
    (M,) are the state after frame 0; ``body`` (cloud points,) bool and ``body_vel``
    (cloud points, 3) hold frame 0's body points (:func:`_body_chains`) and are
    filled frame by frame.
    """
    t_frames, m = cloud.n_frames, init.n_markers
    gamma = init.gamma
    spacing = init.spacing
    points = cloud.points
    tree = _FrameTree(cloud)
    loo_weights = _leave_one_out_weights(s)
    k_cand = _CANDIDATES
    offsets = cloud.offsets
    window = int(round(_RIGID_WINDOW * cloud.rate))
    l_med = float(np.median(spacing))

    for t in range(1, t_frames):
        prev = positions[t - 1]
        cur = np.zeros((m, 3))
        known = np.zeros(m, dtype=bool)
        taken = np.full(m, -1, dtype=np.int64)
        n_t = int(cloud.offsets[t + 1] - cloud.offsets[t])
        k = min(k_cand, n_t)
        a0, a1, a2 = int(cloud.offsets[t - 1]), int(cloud.offsets[t]), int(cloud.offsets[t + 1])
        v_pred = prev + velocity  # V (eqs. 3.1-3.2)
        body[a1:a2], body_vel[a1:a2] = _body_chains(
            points[a0:a1],
            body[a0:a1],
            body_vel[a0:a1],
            points[a1:a2],
            v_pred[point_index[t - 1] >= 0],
            _CHAIN * gamma,
        )
        active = temp_count == 0

        def rigid(j: int, p: int, t: int = t, taken: np.ndarray = taken) -> bool:
            return _rigid_with_body(points, offsets, point_index, t, j, p, taken, l_med, window)

        if k > 0:
            # ---- pass 1: measured traces at V, then at V corrected by the
            # residuals of the traces found (beyond the thesis)
            untaken = np.ones(a1 - a0, dtype=bool)
            mine = point_index[t - 1]
            untaken[mine[(mine >= a0) & (mine < a1)] - a0] = False
            follow = _Previous(points[a0:a1], untaken, prev, active) if _FOLLOW else None
            _match(
                tree,
                t,
                np.nonzero(active)[0],
                v_pred,
                k,
                gamma,
                cur,
                known,
                taken,
                points,
                follow=follow,
                body=body,
                body_steady=active,
            )
            _reject_overstretched(cur, known, taken, s, gamma, rigid)
            _reject_odd_motion(cur, prev, known, taken, gamma, active)
            tried = v_pred
            for _ in range(_ROUNDS):
                found = known & active
                want = active & ~known
                if not (found.any() and want.any()):
                    break
                pred = v_pred + _interp_along(found, np.where(found[:, None], cur - v_pred, 0.0), s)
                want &= np.einsum("ij,ij->i", pred - tried, pred - tried) > (0.5 * gamma) ** 2
                if not want.any():
                    break
                rows = np.nonzero(want)[0]
                if not _match(
                    tree,
                    t,
                    rows,
                    pred,
                    k,
                    gamma,
                    cur,
                    known,
                    taken,
                    points,
                    gate=_WIDE_GATE * gamma,
                    spacing=spacing,
                    follow=follow,
                    body=body,
                    body_steady=active,
                    prev=prev,
                    rigid=rigid,
                ):
                    break
                _reject_overstretched(cur, known, taken, s, gamma, rigid)
                _reject_odd_motion(cur, prev, known, taken, gamma, active)
                tried = np.where(want[:, None], pred, tried)
        new_count = np.where(known, 0, temp_count + 1)
        pred = prev + velocity
        if not known.all():
            # ---- pass 2: the rest at the curve (interior) or F (ends)
            meas_vel = np.where(known[:, None], cur - prev, 0.0)
            v_tilde = _neighbour_velocity(known, meas_vel, velocity)
            if known.any():
                pred, _ = fill_interior_on_curve(np.where(known[:, None], cur, 0.0), known, s)
                pred = settle_single_gaps(pred, known, spacing, _SETTLE)
                pred = _predict_ends(pred, known, prev, v_tilde, new_count, spacing)
            found_more = False
            if k > 0:
                want = np.nonzero(~known)[0]
                found_more = _match(
                    tree,
                    t,
                    want,
                    pred,
                    k,
                    gamma,
                    cur,
                    known,
                    taken,
                    points,
                    gate=_WIDE_GATE * gamma,
                    spacing=spacing,
                    follow=follow,
                    body=body,
                    body_steady=active,
                    prev=prev,
                    rigid=rigid,
                )
                _reject_overstretched(cur, known, taken, s, gamma, rigid)
                _reject_odd_motion(cur, prev, known, taken, gamma, active)
                # ---- the zipper: runs of inner markers from their measured ends
                for _ in range(_ZIP):
                    rows, zpred = _zipper_predictions(cur, known, spacing)
                    if rows.size == 0 or not _match(
                        tree,
                        t,
                        rows,
                        zpred,
                        k,
                        gamma,
                        cur,
                        known,
                        taken,
                        points,
                        gate=_WIDE_GATE * gamma,
                        spacing=spacing,
                        follow=follow,
                        body=body,
                        body_steady=active,
                        prev=prev,
                        rigid=rigid,
                    ):
                        break
                    found_more = True
                    _reject_overstretched(cur, known, taken, s, gamma, rigid)
                    _reject_odd_motion(cur, prev, known, taken, gamma, active)
        swapped = False
        if k > 0 and known.sum() >= 3:
            swapped = _check_on_curve(tree, t, k, gamma, s, cur, known, taken, points, loo_weights)
        still = ~known
        if still.any():
            if known.any() and (found_more or swapped):
                # re-place the interior invented markers on the curve through every
                # marker measured this frame
                refit, interior = fill_interior_on_curve(
                    np.where(known[:, None], cur, 0.0), known, s
                )
                refit = settle_single_gaps(refit, known, spacing, _SETTLE)
                cur[still] = np.where(interior[still, None], refit[still], pred[still])
            else:
                cur[still] = pred[still]  # nothing new measured: the curve/F prediction
        temp_count = np.where(known, 0, temp_count + 1)
        invented[t] = still
        lost_frames[t] = temp_count > init.max_temp_markers
        point_index[t] = taken
        positions[t] = cur
        velocity = cur - prev
        if progress is not None and t % every == 0:
            progress(t / t_frames)


def track_rope(
    cloud: PointCloud,
    init: RopeInit,
    *,
    progress: Callable[[float], object] | None = None,
    backend: str = "auto",
) -> RopeTrack:
    """Track the rope markers through the whole take.

    Parameters
    ----------
    cloud : PointCloud
        The take (the one ``init`` was made from), metres, Y up.
    init : RopeInit
        From :func:`~skincap.tracking.init.init_rope`: frame-0 indices, spacings
        ``l_j``, γ, maxTempMarkers.
    progress : callable, optional
        Called with the fraction of frames done (0..1), about a hundred times.
    backend : {"auto", "numba", "numpy"}
        ``numba`` runs the per-frame loop compiled (:mod:`skincap.tracking._kernel`;
        tens of times faster; compiled on first use if needed), ``numpy`` the NumPy
        reference; ``auto`` picks numba once its kernel is compiled, and until then
        NumPy while the kernel compiles in the background
        (:func:`skincap.backends.resolve_backend`). Both take the same points and
        invent the same markers; invented positions agree to rounding.

    Returns
    -------
    RopeTrack
        Positions NaN only where a trace is lost (a SkincapWarning counts them),
        invented samples bounded by the rope's length; ``invented`` where a temporary
        marker was used;
        ``point_index`` the taken points (each at most once); ``lost_frames``.

    Raises
    ------
    ValidationError
        ``init`` does not fit ``cloud`` (an index beyond frame 0's points), or an
        unknown ``backend``.
    MissingDependencyError
        ``backend="numba"`` without numba installed.
    """
    if not isinstance(cloud, PointCloud):
        raise ValidationError(f"cloud: expected a PointCloud, got {type(cloud).__name__}")
    if not isinstance(init, RopeInit):
        raise ValidationError(f"init: expected a RopeInit, got {type(init).__name__}")
    n0 = int(cloud.counts[0]) if cloud.n_frames else 0
    if cloud.n_frames < 1 or init.indices.max() >= n0 or init.n_markers < 3:
        raise ValidationError(
            f"init: rope index {int(init.indices.max())} is beyond frame 0's {n0} points"
        )
    t_frames, m = cloud.n_frames, init.n_markers
    gamma = init.gamma
    spacing = init.spacing
    s = rest_arclength(spacing)
    points = cloud.points

    positions = np.empty((t_frames, m, 3))
    invented = np.zeros((t_frames, m), dtype=bool)
    point_index = np.full((t_frames, m), -1, dtype=np.int64)
    lost_frames = np.zeros((t_frames, m), dtype=bool)
    seen0 = init.indices >= 0
    positions[0] = init.positions
    positions[0, seen0] = points[cloud.offsets[0] + init.indices[seen0]]
    point_index[0, seen0] = init.indices[seen0]
    invented[0] = ~seen0
    velocity = np.zeros((m, 3))  # v^{i-1} Δt: last per-frame displacement (eq. 3.2)
    temp_count = (~seen0).astype(np.int64)  # consecutive temporary markers
    # frame 0's points the rope does not take are body points (the user's selection)
    body = np.zeros(points.shape[0], dtype=bool)
    body_vel = np.zeros((points.shape[0], 3))
    body[cloud.offsets[0] : cloud.offsets[1]] = True
    body[cloud.offsets[0] + init.indices[seen0]] = False
    every = max(1, t_frames // 100)
    if _resolve_backend(backend) == "numba":
        from skincap.tracking._kernel import track_frames

        offsets = np.ascontiguousarray(cloud.offsets, dtype=np.int64)
        pts = np.ascontiguousarray(points, dtype=np.float64)
        rig = np.array(
            [
                float(np.median(spacing)),
                float(round(_RIGID_WINDOW * cloud.rate)),
                _RIGID_RADIUS,
                _RIGID_RANGE,
                float(_RIGID_PARTNERS),
                _ADJ,
                _RIGID_MOVE,
            ]
        )
        t0 = 1
        while t0 < t_frames:
            t1 = min(t_frames, (t0 - 1) // every * every + every + 1)
            track_frames(
                t0, t1, pts, offsets, float(gamma), np.asarray(spacing, dtype=np.float64), s,
                int(init.max_temp_markers), _STRETCH, _CANDIDATES, _ROUNDS, _WIDE_GATE, _FOLLOW,
                positions, invented, point_index, lost_frames, velocity, temp_count,
                _CHAIN, body, body_vel, _ZIP, _ZIP_INNER, _ZIP_QUAD, _SLOW, rig, _ZIP_ENDS, _SETTLE,
            )  # fmt: skip
            if progress is not None and (t1 - 1) % every == 0:
                progress((t1 - 1) / t_frames)
            t0 = t1
    else:
        _track_numpy(
            cloud, init, s, positions, invented, point_index, lost_frames, velocity, temp_count,
            body, body_vel, progress, every,
        )  # fmt: skip
    if progress is not None:
        progress(1.0)
    positions, moved = _physical_output(positions, invented, lost_frames, spacing, init.labels)
    return RopeTrack(
        positions=positions,
        invented=invented,
        point_index=point_index,
        lost_frames=lost_frames,
        labels=init.labels,
        rate=cloud.rate,
        init=init,
        meta={
            **{k: v for k, v in cloud.meta.items() if k != "id_labels"},
            "invented_bounded": int(moved.sum()),
        },
    )


def _physical_output(
    positions: np.ndarray,
    invented: np.ndarray,
    lost_frames: np.ndarray,
    spacing: np.ndarray,
    labels: list[str],
) -> tuple[np.ndarray, np.ndarray]:
    """The tracked positions as reported: invented samples bounded, lost samples NaN.

    Both backends track with their own (unbounded) predictions; what leaves the
    tracker is physical (:func:`skincap.tracking.physical.bound_invented`), and a lost
    trace is NaN with a :class:`~skincap.errors.SkincapWarning` that counts them.
    """
    bounded, moved = bound_invented(positions, invented, spacing)
    unplaced = ~np.isfinite(bounded).all(axis=2)  # (T, M) no position the rope allows
    lost_frames |= unplaced
    bounded[lost_frames] = np.nan
    if lost_frames.any():
        lost = np.flatnonzero(lost_frames.any(axis=0))
        first = [int(np.argmax(lost_frames[:, j])) for j in lost]
        where = ", ".join(f"{labels[j]} from frame {f}" for j, f in zip(lost, first, strict=True))
        warnings.warn(
            f"rope: {lost.size} of {len(labels)} traces lost ({where}); "
            f"{int(lost_frames.sum())} samples are NaN",
            SkincapWarning,
            stacklevel=3,
        )
    return bounded, moved


def warm_up_kernel() -> None:
    """Compile :func:`track_frames` into numba's cache by tracking a tiny analytic take.

    Goes through :func:`~skincap.tracking.tracker.track_rope` so the argument types
    are exactly those of a real call (run by the background compile). The take: a rope
    of 8 markers sweeping an arc beside 40 still body points, 60 frames at 120 Hz.
    """
    import numpy as np

    from skincap.tracking.init import init_rope
    from skincap.types import PointCloud

    frames, rope_markers, body_markers = 60, 8, 40
    t = np.arange(frames)[:, None] / 120.0
    s = np.linspace(0.0, 1.0, rope_markers)[None, :]
    angle = np.pi + 0.5 * np.sin(2 * np.pi * t)  # (T, 1): the arc swings about x
    rope = np.stack(
        [
            -0.45 + 0.9 * s + 0 * t,
            1.0 + np.sin(np.pi * s) * np.cos(angle),
            np.sin(np.pi * s) * np.sin(angle),
        ],
        axis=-1,
    )
    grid = np.linspace(-0.3, 0.3, body_markers)
    body = np.stack(
        [0.2 * np.cos(7 * grid), 1.0 + 2.0 * grid, 0.5 + 0.1 * np.sin(5 * grid)], axis=-1
    )
    frames_points = np.concatenate([rope, np.broadcast_to(body, (frames, body_markers, 3))], axis=1)
    count = rope_markers + body_markers
    cloud = PointCloud(
        points=frames_points.reshape(-1, 3),
        offsets=np.arange(frames + 1, dtype=np.int64) * count,
        rate=120.0,
    )
    track_rope(cloud, init_rope(cloud, markers=np.arange(rope_markers)), backend="numba")
