"""Samples that leap off the body: a corrupt value, a ghost across the room.

A sample kilometres from the performer is not a spike the local-frame detector
(:func:`~skincap.cleanup.outliers.find_spikes`) should meet: before it runs, the one
sample has already emptied its marker's surface edges (a pair distance's spread over
the take is dominated by it) and so left the marker without neighbours to fill from.
:func:`off_body_leaps` finds such samples first, so ``clean`` can take them out before
the surface is built and fill them like any other hole.

A marker may legitimately roam off the body (a prop set down across the room), but it
travels there: only a run of off-body samples (:func:`skincap.geometry.off_body.off_body_samples`)
both entered and left by a leap longer than the reach (from the marker's previous seen
sample, to its next; a track's own start or end counts as one) is taken.
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import as_trajectories
from skincap.geometry.off_body import OFF_BODY_REACH_M, off_body_samples

__all__ = ["off_body_leaps"]


def _neighbour_seen(seen: np.ndarray, backwards: bool) -> np.ndarray:
    """(T, N) int: the frame of each marker's previous (or next) seen sample, -1 if none."""
    t = seen.shape[0]
    frames = np.arange(t)[:, None]
    if not backwards:
        last = np.maximum.accumulate(np.where(seen, frames, -1), axis=0)  # last seen <= t
        return np.vstack([np.full((1, seen.shape[1]), -1), last[:-1]])
    nxt = np.minimum.accumulate(np.where(seen, frames, t)[::-1], axis=0)[::-1]  # next >= t
    out = np.vstack([nxt[1:], np.full((1, seen.shape[1]), t)])
    return np.where(out >= t, -1, out)


def off_body_leaps(positions: np.ndarray, *, reach_m: float = OFF_BODY_REACH_M) -> np.ndarray:
    """(T, N) bool: off-body samples reached or left by a leap beyond ``reach_m``.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    reach_m : float
        Metres beyond a marker's usual distance from the body's centre
        (:func:`~skincap.geometry.off_body.off_body_samples`), and the least step
        between consecutive seen samples that counts as a leap.

    Returns
    -------
    (T, N) bool
        Every sample of each run of consecutive (in seen order) off-body samples, split
        where the marker moves over ``reach_m`` between two of them, that is both
        entered and left by such a leap (or begins or ends the marker's track); False
        wherever the marker is missing.
    """
    p = as_trajectories(positions)
    t, n, _ = p.shape
    off = off_body_samples(p, reach_m=reach_m)  # (T, N)
    if not off.any():
        return off
    seen = np.isfinite(p).all(axis=2)
    cols = np.arange(n)[None, :]
    frames = np.arange(t)[:, None]

    def leap(other: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether the step to ``other`` exceeds the reach, and whether ``other`` is off."""
        has = other >= 0
        idx = np.where(has, other, 0)
        step = np.linalg.norm(p - p[idx, cols], axis=2)  # (T, N), NaN where unseen
        with np.errstate(invalid="ignore"):
            far = has & seen & (step > reach_m)
        return far, has & off[idx, cols]

    prev, nxt = _neighbour_seen(seen, False), _neighbour_seen(seen, True)
    far_in, prev_off = leap(prev)
    far_out, next_off = leap(nxt)
    # runs of off samples, split where the marker leaps between two of them
    start = off & (~prev_off | far_in)
    end = off & (~next_off | far_out)
    entered = far_in | (prev < 0)  # a run at the track's start has nothing to leap from
    left = far_out | (nxt < 0)
    # each off sample's run: its latest start at or before it, its earliest end at or after
    run_start = np.maximum.accumulate(np.where(start, frames, -1), axis=0)
    run_end = np.minimum.accumulate(np.where(end, frames, t)[::-1], axis=0)[::-1]
    by_leap_in = entered[np.clip(run_start, 0, t - 1), cols] & (run_start >= 0)
    by_leap_out = left[np.clip(run_end, 0, t - 1), cols] & (run_end < t)
    return off & by_leap_in & by_leap_out
