"""Which frame-0 points move with the body, not the rope (beyond Porter 2012).

Used by the automatic initialisation (:func:`~skincap.tracking.init.init_rope` with
``auto=True``) to drop hand and body markers from the chain it found: frame 0's points
are followed by unambiguous nearest neighbours (:func:`follow_points`) and a chain
point that keeps its distance to body points, or whose links stretch beyond any rope,
is body-like (:func:`body_like`). The rigidity constants here are also the defaults of
the tracker's per-frame rigidity test (:class:`~skincap.tracking.settings.TrackSettings`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from skincap.types import PointCloud

__all__ = ["body_like", "follow_points"]

#: Frames of the take (seconds) over which frame 0's points are followed for rigidity.
_RIGID_SECONDS = 5.0
#: A pair is rigid when its distance varies by less than this many spacings.
_RIGID_RANGE = 0.1
#: Partners searched within this many spacings of a chain point.
_RIGID_RADIUS = 3.0
#: A chain point with at least this many rigid partners off the chain is a body marker.
_RIGID_PARTNERS = 2
#: A link stretched beyond (1 + this) times its rest length is not along a rope.
_STRETCH = 0.25


def follow_points(cloud: PointCloud, n_frames: int, gate: float) -> np.ndarray:
    """Follow every frame-0 point by unambiguous nearest neighbours (no identities).

    Each point predicts its next position at constant velocity and takes the
    nearest point of the next frame when that lies within ``gate``, no other point
    lies within twice that distance of the prediction, and no other followed point
    takes it. The first frame without such a match ends the point's run for good.

    Parameters
    ----------
    cloud : PointCloud
    n_frames : int
        Frames to follow from frame 0 (clipped to the take).
    gate : float, metres

    Returns
    -------
    (F, N0, 3) float64, metres
        Positions of frame 0's ``N0`` points; NaN from the frame a run ends.
    """
    n_frames = int(min(max(1, n_frames), cloud.n_frames))
    p0 = cloud.frame(0)
    n0 = p0.shape[0]
    out = np.full((n_frames, n0, 3), np.nan)
    out[0] = p0
    pos = p0.copy()
    vel = np.zeros_like(p0)
    alive = np.ones(n0, dtype=bool)
    for t in range(1, n_frames):
        frame = cloud.frame(t)
        rows = np.nonzero(alive)[0]
        if rows.size == 0 or frame.shape[0] < 2:
            break
        d, i = cKDTree(frame).query(pos[rows] + vel[rows], k=2)
        ok = (d[:, 0] < gate) & (d[:, 1] > 2.0 * d[:, 0])
        took, count = np.unique(i[ok, 0], return_counts=True)
        ok[ok] &= np.isin(i[ok, 0], took[count == 1])
        alive[rows[~ok]] = False
        got = rows[ok]
        new = frame[i[ok, 0]]
        vel[got] = new - pos[got]
        pos[got] = new
        out[t, got] = new
    return out


def body_like(
    cloud: PointCloud, chain: np.ndarray, spacing: float, *, seconds: float = _RIGID_SECONDS
) -> np.ndarray:
    """Flag chain points that move rigidly with body points (beyond the thesis).

    A hand marker at the end of a held rope, or a body marker the chain took where a
    rope marker is hidden, moves rigidly with its neighbours on the body; a rope
    marker does not (rope markers keep their distance only to their own neighbours
    along the rope, which are in the chain). Frame 0's points are followed
    (:func:`follow_points`, gate a quarter of the spacing) for ``seconds``; a chain
    point is body-like when at least two points off the chain, within three
    spacings of it in frame 0, keep their distance to it within a tenth of the
    spacing over all frames both are followed, and those frames include the chain
    point moving at least half a spacing away from where it started. A point never
    followed that far gives no evidence and stays in the chain.

    A body marker that does not move (a shin beside the rope's middle) is caught by
    the rope's length instead: two rope markers about ``k`` spacings apart in frame
    0 never get farther apart than ``k`` spacings of rope (25 % tolerance). A point
    whose links to both chain neighbours (its one link, at an end) stretch beyond
    that while followed is body-like (an interior point only: one link stretched at
    an end may be the following's mistake where the held end is among hand markers).

    Parameters
    ----------
    cloud : PointCloud
    chain : (C,) int
        Indices of the chain's points among frame 0's points.
    spacing : float, metres
        The chain's median link.
    seconds : float

    Returns
    -------
    (C,) bool
        True for a body-like point.
    """
    chain = np.asarray(chain, dtype=np.int64)
    n_follow = int(round(seconds * cloud.rate))
    traj = follow_points(cloud, n_follow, 0.25 * spacing)  # (F, N0, 3)
    p0 = traj[0]
    off_chain = np.ones(p0.shape[0], dtype=bool)
    off_chain[chain] = False
    out = np.zeros(chain.size, dtype=bool)
    near = cKDTree(p0).query_ball_point(p0[chain], r=_RIGID_RADIUS * spacing)
    for c, (point, partners) in enumerate(zip(chain.tolist(), near, strict=True)):
        q = np.asarray([k for k in partners if off_chain[k]], dtype=np.int64)
        if q.size == 0:
            continue
        both = np.isfinite(traj[:, point, 0])[:, None] & np.isfinite(traj[:, q, 0])  # (F, Q)
        moved = np.linalg.norm(traj[:, point] - p0[point], axis=1)  # (F,) NaN when lost
        far = np.nan_to_num(moved, nan=0.0) >= 0.5 * spacing
        d = np.linalg.norm(traj[:, q] - traj[:, point][:, None], axis=2)  # (F, Q)
        hi = np.where(both, d, -np.inf).max(axis=0)
        lo = np.where(both, d, np.inf).min(axis=0)
        seen_moving = (both & far[:, None]).any(axis=0)
        rigid = seen_moving & (hi - lo < _RIGID_RANGE * spacing)
        out[c] = int(rigid.sum()) >= _RIGID_PARTNERS
    # Links a rope cannot make: the chord between two rope markers never exceeds
    # the rope between them (k spacings for a link of about k spacings in frame 0).
    rest = np.flatnonzero(~out)  # the chain without its rigid (hand) points
    if rest.size >= 3:
        kept = chain[rest]
        a, b = traj[:, kept[:-1]], traj[:, kept[1:]]  # (F, C'-1, 3)
        chord = np.nan_to_num(np.linalg.norm(b - a, axis=2), nan=0.0).max(axis=0)
        k = np.maximum(1.0, np.rint(np.linalg.norm(p0[kept[1:]] - p0[kept[:-1]], axis=1) / spacing))
        stretched = chord > (1.0 + _STRETCH) * k * spacing
        # interior points only: ends answer to the rigidity test (a held end follows a hand)
        out[rest[1:-1]] |= stretched[:-1] & stretched[1:]
    return out
