"""Invented rope samples that the rope could have been at (issue #15, item 3).

A rope does not stretch: the straight distance between two of its markers is at most
the rest arc length between them. The tracker invents the markers it cannot see by
extrapolation (velocities, neighbours, the curve), and extrapolation is unbounded; a
hard-accelerating real hand sends it metres away. This module puts every invented
sample back inside the region the measured markers of its frame allow, and reports
the samples of lost traces as NaN rather than as an extrapolation.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError

__all__ = ["STRETCH_ALLOWANCE", "bound_invented", "physics_excess"]

#: Relative stretch tolerated between two markers (a real rope, tape and noise).
STRETCH_ALLOWANCE = 0.1


def _arclength(spacing: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(spacing)])


def physics_excess(
    positions: np.ndarray, invented: np.ndarray, spacing: np.ndarray, *, stretch: float = 0.0
) -> np.ndarray:
    """(T, M) metres by which each invented sample breaks the rope's length; 0 elsewhere.

    For an invented marker j, the largest ``|x_j - x_k| - (1 + stretch) |s_j - s_k|`` over the
    markers k of its frame that are measured (``s`` the rest arc length) and over its
    direct neighbours whatever they are; 0 where nothing constrains it, NaN where the
    sample is NaN.
    """
    pos = np.asarray(positions, dtype=np.float64)
    inv = np.asarray(invented, dtype=bool)
    s = _arclength(np.asarray(spacing, dtype=np.float64))
    t_n, m, _ = pos.shape
    excess = np.zeros((t_n, m))
    index = np.arange(m)
    apart = np.abs(index[:, None] - index[None, :])  # (M, M) index distance
    measured = ~inv  # (T, M) measured markers constrain
    for j in range(m):
        reach = (1.0 + stretch) * np.abs(s[j] - s)[None, :]
        gap = np.linalg.norm(pos[:, j : j + 1] - pos, axis=2) - reach
        counts = (measured | (apart[j] == 1)) & (apart[j] > 0)  # and so do the neighbours
        worst = np.where(counts, np.nan_to_num(gap, nan=-np.inf), -np.inf).max(axis=1)
        excess[:, j] = np.where(inv[:, j], np.maximum(worst, 0.0), 0.0)
    return np.where(np.isfinite(pos).all(axis=2), excess, np.nan)


def _out_of_reach(
    pos: np.ndarray,
    inv: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    s: np.ndarray,
    stretch: float,
) -> np.ndarray:
    """(T, M) bool: invented samples beyond reach of their nearest measured markers or
    of an invented neighbour (``left``/``right``: -1 / M where there is none)."""
    t_n, m, _ = pos.shape
    frames = np.arange(t_n)[:, None]
    out = np.zeros(inv.shape, dtype=bool)
    for anchor, exists in ((left, left >= 0), (right, right < m)):
        a = np.clip(anchor, 0, m - 1)  # (T, M)
        dist = np.linalg.norm(pos - pos[frames, a], axis=2)
        reach = (1.0 + stretch) * np.abs(s[None, :] - s[a])
        out |= inv & exists & (dist > reach)
    link = np.linalg.norm(np.diff(pos, axis=1), axis=2)  # (T, M - 1)
    far = inv[:, :-1] & inv[:, 1:] & (link > (1.0 + stretch) * np.diff(s)[None, :])
    out[:, :-1] |= far
    out[:, 1:] |= far
    return out


def _pull(
    x: np.ndarray,
    j: int,
    anchor: np.ndarray,
    active: np.ndarray,
    share: float,
    s: np.ndarray,
    stretch: float,
    changed: np.ndarray,
) -> None:
    """Move marker j of each active frame of ``x`` (W, M, 3), in place, within reach of
    its ``anchor`` (W,) marker, the anchor taking ``1 - share`` of the move; the frames
    moved are set in ``changed`` (W,) bool. Only the active frames are computed (a
    marker is invented in few of them)."""
    rows = np.flatnonzero(active)
    if not rows.size:
        return
    a = np.clip(anchor[rows], 0, x.shape[1] - 1)
    reach = (1.0 + stretch) * np.abs(s[j] - s[a])  # (R,)
    d = x[rows, j] - x[rows, a]  # (R, 3)
    dist = np.linalg.norm(d, axis=1)
    over = (dist > reach) & np.isfinite(dist)
    if over.any():
        fix = d[over] * ((dist[over] - reach[over]) / dist[over])[:, None]
        moved = rows[over]
        x[moved, j] -= share * fix
        x[moved, a[over]] += (1.0 - share) * fix
        changed[moved] = True


def bound_invented(
    positions: np.ndarray,
    invented: np.ndarray,
    spacing: np.ndarray,
    *,
    stretch: float = STRETCH_ALLOWANCE,
    sweeps: int = 20,
) -> tuple[np.ndarray, np.ndarray]:
    """Move invented samples into the ball the rope's length allows around each marker.

    Each invented marker j is projected, in turn, onto the balls
    ``|x_j - x_k| <= (1 + stretch) |s_j - s_k|`` around the nearest measured marker k
    on each side in its frame, then two invented neighbours onto each other's ball
    (sharing the move) — cyclic projections onto convex sets, ``sweeps`` times,
    vectorised over frames. By the triangle inequality this bounds it against every
    measured marker as long as the measured ones keep the rope's length (where they
    themselves break it, the sample is left where the projections put it, as near
    to every ball as they get). Every sample of a frame in which no marker is
    measured is NaN (nothing says where the rope is: an extrapolation of the whole
    rope is unbounded).

    Parameters
    ----------
    positions : (T, M, 3) float, metres
        Rope markers in order along the rope.
    invented : (T, M) bool
        The samples that were invented; measured samples never move.
    spacing : (M - 1,) float, metres
        Rest distance between consecutive markers.
    stretch : float
        Relative stretch tolerated (>= 0).
    sweeps : int
        Rounds of projections (>= 1).

    Returns
    -------
    positions : (T, M, 3) float64
        A copy with the invented samples bounded.
    moved : (T, M) bool
        The invented samples that were outside and were moved (or made NaN).
    """
    pos = np.array(positions, dtype=np.float64)
    inv = np.asarray(invented, dtype=bool)
    spacing = np.asarray(spacing, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 3 or inv.shape != pos.shape[:2]:
        raise ValidationError(
            f"positions (T, M, 3) and invented (T, M): got {pos.shape} and {inv.shape}"
        )
    if spacing.shape != (pos.shape[1] - 1,) or not (spacing > 0).all():
        raise ValidationError(f"spacing: expected ({pos.shape[1] - 1},) positive, got {spacing}")
    if not stretch >= 0 or sweeps < 1:
        raise ValidationError("stretch must be >= 0 and sweeps >= 1")
    s = _arclength(spacing)
    before = pos.copy()
    m = pos.shape[1]
    # the nearest measured marker on each side of every sample (-1 / m: none)
    idx = np.broadcast_to(np.arange(m), inv.shape)
    left = np.maximum.accumulate(np.where(~inv, idx, -1), axis=1)
    right = np.minimum.accumulate(np.where(~inv, idx, m)[:, ::-1], axis=1)[:, ::-1]
    # only frames with an invented sample out of reach are worked on (most have none)
    work = np.flatnonzero(_out_of_reach(pos, inv, left, right, s, stretch).any(axis=1))
    if work.size:
        sub = pos[work]
        # each frame is projected on its own: a frame whose sweep moved nothing is at its
        # fixed point and leaves the work (the next sweeps would repeat it exactly)
        rows = np.arange(work.size)
        for _ in range(sweeps):
            x, x_inv = sub[rows], inv[work[rows]]
            x_l, x_r = left[work[rows]], right[work[rows]]
            changed = np.zeros(rows.size, dtype=bool)
            for j in range(m):
                for anchor, exists in ((x_l[:, j], x_l[:, j] >= 0), (x_r[:, j], x_r[:, j] < m)):
                    _pull(x, j, anchor, x_inv[:, j] & exists, 1.0, s, stretch, changed)
            for j in range(m - 1):
                both = x_inv[:, j] & x_inv[:, j + 1]
                _pull(x, j, np.full(rows.size, j + 1), both, 0.5, s, stretch, changed)
            sub[rows] = x
            rows = rows[changed]
            if not rows.size:
                break
        pos[work] = sub
    # a frame with no measured marker holds no evidence of where the rope is
    broken = np.broadcast_to(inv.all(axis=1, keepdims=True), inv.shape)
    pos[broken] = np.nan
    moved = inv & (np.nan_to_num(np.abs(pos - before).max(axis=2), nan=1.0) > 0)
    return pos, moved
