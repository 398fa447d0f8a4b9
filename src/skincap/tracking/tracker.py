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

Candidate points come from a KD-tree over (x, y, z, frame × 1 km) built once per
chunk of frames, so a query only ever returns points of the frame asked for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from skincap.errors import ValidationError
from skincap.tracking.curve import fill_interior_on_curve, rest_arclength
from skincap.tracking.init import RopeInit, gated_assignment
from skincap.types import MarkerSet, PointCloud

__all__ = ["RopeTrack", "track_rope"]

#: Separation of frames along the tree's fourth axis, metres (far beyond any γ).
_FRAME_SEPARATION = 1000.0
#: Frames per KD-tree chunk.
_CHUNK_FRAMES = 4096
#: Largest chord between neighbouring markers, in rest spacings (plus γ).
_STRETCH = 1.1
#: Candidates per trace considered by the assignment.
_CANDIDATES = 3


@dataclass(eq=False)
class RopeTrack:
    """The tracked rope.

    Attributes
    ----------
    positions : (T, M, 3) float64, metres
        Rope markers in order along the rope; never NaN (invented where unseen).
    invented : (T, M) bool
        True where the sample is a temporary marker rather than a measured point.
    point_index : (T, M) int64
        Index into ``cloud.points`` of the point each trace took; -1 where invented.
        No point appears twice.
    lost_frames : (T, M) bool
        True where the trace had more than ``max_temp_markers`` consecutive
        temporary markers (it is still invented along the rope there).
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
        """The rope as labelled markers, invented samples flagged (no NaN)."""
        return MarkerSet(
            positions=self.positions.copy(),
            labels=list(self.labels),
            rate=self.rate,
            invented=self.invented.copy(),
            meta=dict(self.meta),
        )


class _FrameTree:
    """Nearest points of one frame, from KD-trees over (x, y, z, frame) chunks."""

    def __init__(self, cloud: PointCloud) -> None:
        self.cloud = cloud
        self.chunk = -1
        self.tree: cKDTree | None = None
        self.base = 0

    def query(self, t: int, q: np.ndarray, k: int, gate: float) -> tuple[np.ndarray, np.ndarray]:
        """(R, k) distances (inf for none) and global point indices near ``q`` in frame t."""
        c = t // _CHUNK_FRAMES
        if c != self.chunk:
            f0 = c * _CHUNK_FRAMES
            f1 = min(self.cloud.n_frames, f0 + _CHUNK_FRAMES)
            a, b = int(self.cloud.offsets[f0]), int(self.cloud.offsets[f1])
            frames = np.repeat(np.arange(f1 - f0), np.diff(self.cloud.offsets[f0 : f1 + 1]))
            data = np.column_stack([self.cloud.points[a:b], frames * _FRAME_SEPARATION])
            self.tree = cKDTree(data if data.shape[0] else np.zeros((1, 4)) - 1e9)
            self.base, self.chunk, self.f0 = a, c, f0
        assert self.tree is not None
        q4 = np.empty((q.shape[0], 4))
        q4[:, :3] = q
        q4[:, 3] = (t - self.f0) * _FRAME_SEPARATION
        d, i = self.tree.query(q4, k=k, distance_upper_bound=gate)
        d = d.reshape(q.shape[0], k)
        i = i.reshape(q.shape[0], k) + self.base
        return d, i


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
    cur: np.ndarray, known: np.ndarray, taken: np.ndarray, spacing: np.ndarray, gamma: float
) -> None:
    """Refuse taken points that would stretch the rope (beyond the thesis), in place.

    A rope does not stretch: the chord between neighbouring markers is at most
    their rest spacing. A link longer than ``1.1 l_j + γ`` is broken; a marker all of
    whose measured links are broken (at least one) is un-taken — it follows
    something else, typically a body marker it was confused with.
    """
    link_ok = np.ones(known.size + 1, dtype=bool)  # link j joins j-1 and j; ends open
    both = known[:-1] & known[1:]
    chord = np.linalg.norm(cur[1:] - cur[:-1], axis=1)
    link_ok[1:-1] = ~both | (chord <= _STRETCH * spacing + gamma)
    has_left = np.concatenate([[False], both])
    has_right = np.concatenate([both, [False]])
    bad_left = has_left & ~link_ok[:-1]
    bad_right = has_right & ~link_ok[1:]
    bad = known & (bad_left | bad_right) & (bad_left | ~has_left) & (bad_right | ~has_right)
    if bad.any():
        known[bad] = False
        taken[bad] = -1


def _reject_odd_motion(
    cur: np.ndarray, prev: np.ndarray, known: np.ndarray, taken: np.ndarray, limit: float
) -> None:
    """Refuse taken points that do not move with the rope (beyond the thesis), in place.

    A marker whose two neighbours are measured moves, frame to frame, within
    ``limit`` of the mean of their moves (the rope is smooth); a point that does not
    belongs to something else (a body marker sitting on the rope's path).
    """
    inner = known[1:-1] & known[:-2] & known[2:]
    if not inner.any():
        return
    move = cur - prev
    expected = 0.5 * (move[:-2] + move[2:])
    odd = inner & (np.linalg.norm(move[1:-1] - expected, axis=1) > limit)
    if odd.any():
        idx = np.nonzero(odd)[0] + 1
        known[idx] = False
        taken[idx] = -1


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


def track_rope(
    cloud: PointCloud,
    init: RopeInit,
    *,
    progress: Callable[[float], object] | None = None,
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

    Returns
    -------
    RopeTrack
        Positions never NaN; ``invented`` where a temporary marker was used;
        ``point_index`` the taken points (each at most once); ``lost_frames``.

    Raises
    ------
    ValidationError
        ``init`` does not fit ``cloud`` (an index beyond frame 0's points).
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
    tree = _FrameTree(cloud)
    every = max(1, t_frames // 100)
    k_cand = _CANDIDATES

    for t in range(1, t_frames):
        prev = positions[t - 1]
        cur = np.empty((m, 3))
        known = np.zeros(m, dtype=bool)
        taken = np.full(m, -1, dtype=np.int64)
        n_t = int(cloud.offsets[t + 1] - cloud.offsets[t])
        k = min(k_cand, n_t)
        # ---- pass 1: measured traces at V (eqs. 3.1-3.2)
        active = np.nonzero(temp_count == 0)[0]
        if k > 0 and active.size:
            v_pred = prev[active] + velocity[active]
            d, i = tree.query(t, v_pred, k, gamma)
            rows, pts = gated_assignment(d, i, gamma)
            hit = active[rows]
            known[hit] = True
            taken[hit] = pts
            cur[hit] = points[pts]
        _reject_overstretched(cur, known, taken, spacing, gamma)
        _reject_odd_motion(cur, prev, known, taken, gamma)
        if not known.all():
            # ---- pass 2: the rest at the curve (interior) or F (ends)
            missing = ~known
            new_count = np.where(missing, temp_count + 1, 0)
            meas_vel = np.where(known[:, None], cur - prev, 0.0)
            v_tilde = _neighbour_velocity(known, meas_vel, velocity)
            if known.any():
                pred, _ = fill_interior_on_curve(np.where(known[:, None], cur, 0.0), known, s)
                pred = _predict_ends(pred, known, prev, v_tilde, new_count, spacing)
            else:
                pred = prev + velocity
            want = np.nonzero(missing)[0]
            if k > 0:
                kk = min(n_t, k + int(known.sum()))  # room for points pass 1 took
                d, i = tree.query(t, pred[want], kk, gamma)
                used = np.isin(i, taken[known])
                d = np.where(used, np.inf, d)
                rows, pts = gated_assignment(d, i, gamma)
                hit = want[rows]
                known[hit] = True
                taken[hit] = pts
                cur[hit] = points[pts]
                _reject_overstretched(cur, known, taken, spacing, gamma)
                _reject_odd_motion(cur, prev, known, taken, gamma)
            still = ~known
            if still.any() and known.any():
                # re-place the interior invented markers on the curve through every
                # marker measured this frame (pass 2 may have found more)
                refit, interior = fill_interior_on_curve(
                    np.where(known[:, None], cur, 0.0), known, s
                )
                cur[still] = np.where(interior[still, None], refit[still], pred[still])
            elif still.any():
                cur[still] = pred[still]
            temp_count = np.where(known, 0, temp_count + 1)
            invented[t] = ~known
            lost_frames[t] = temp_count > init.max_temp_markers
        else:
            temp_count[:] = 0
        point_index[t] = taken
        positions[t] = cur
        velocity = cur - prev
        if progress is not None and t % every == 0:
            progress(t / t_frames)
    if progress is not None:
        progress(1.0)
    return RopeTrack(
        positions=positions,
        invented=invented,
        point_index=point_index,
        lost_frames=lost_frames,
        labels=init.labels,
        rate=cloud.rate,
        init=init,
        meta={k: v for k, v in cloud.meta.items() if k != "id_labels"},
    )
