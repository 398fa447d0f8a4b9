"""Filled runs that join their measured ends without a step and move like the take.

A hole filler estimates each missing sample from its neighbourhood; nothing in that
estimate ties one frame to the next, so an unstable neighbourhood can make it jump, or
alternate frame to frame between two solutions (a zig-zag). :func:`condition_fills`
makes every filled run continuous by construction and keeps it only if it moves like
the measured data:

1. a cubic Hermite curve ``h`` through the run's measured ends, with the ends'
   measured velocities (one end only: constant at that end);
2. the filler's estimate ``f``, less its step at each end (its sample next to the
   end less the measured end carried on at its velocity, blended linearly across the
   run), enters as its departure ``d = f - step - h``,
   low-passed with the iterated ``x <- x - λ Δ⁴ x`` update at ``λ = 1/16`` (zero gain
   at the Nyquist frequency: a frame-to-frame alternation is removed whatever its
   size) with ``d`` held at zero on the measured samples around the run, so the run
   joins its ends in value and slope;
3. the result ``h + smooth(d)`` is kept only if the largest second difference of
   every filled sample (``x[t-1] - 2x[t] + x[t+1]``, with the measured ends; a fill at
   the take's first or last frame, which has none, by its neighbour's) is within
   ``limit``; otherwise a stronger low-pass is tried, then, for a short interior run,
   ``h`` alone; a run that still fails keeps only the part its measured ends reach
   before its first excess (less three frames); the rest is left unfilled (NaN)
   and counted. (The iterated Δ⁴ update is a short kernel: it removes jitter and
   zig-zag but cannot turn a filler's jump into a plausible ramp, so such a run is
   cut rather than bent.)
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import as_trajectories, missing_runs
from skincap.cleanup.smooth import smooth_trajectories
from skincap.errors import ValidationError

__all__ = ["condition_fills", "second_difference", "measured_acceleration_limit"]

#: Low-pass strengths tried in turn (iterations of λ = 1/16).
_PASSES = (8, 32, 128)


def second_difference(positions: np.ndarray) -> np.ndarray:
    """``|x[t-1] - 2x[t] + x[t+1]|`` per sample; NaN at the take's ends and where missing.

    Parameters
    ----------
    positions : (T, N, 3) float

    Returns
    -------
    (T, N) float64, the unit of ``positions`` per frame²
    """
    p = np.asarray(positions, dtype=np.float64)
    d2 = np.full(p.shape[:2], np.nan)
    if p.shape[0] >= 3:
        d2[1:-1] = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1)
    return d2


def measured_acceleration_limit(
    positions: np.ndarray, measured: np.ndarray, *, factor: float = 3.0, percentile: float = 99.9
) -> float:
    """``factor`` times the ``percentile`` of the measured samples' second differences.

    Only samples whose two neighbours in time are measured count. ``inf`` when there is
    none (no limit can be learnt from the take).
    """
    d2 = second_difference(positions)
    m = np.asarray(measured, dtype=bool)
    triple = np.zeros_like(m)
    triple[1:-1] = m[:-2] & m[1:-1] & m[2:]
    values = d2[triple & ~np.isnan(d2)]
    if values.size == 0:
        return float("inf")
    return float(factor * np.percentile(values, percentile))


def _run_bounds(fill: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of True per column of (T, N): (column, start, end) with end exclusive."""
    col, start, length = missing_runs(fill)
    return col, start, start + length


def _hermite(p: np.ndarray, fill: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Hermite curve through each fill run's known ends, and the filler's steps there.

    Returns
    -------
    curve : (T, N, 3)
        Cubic Hermite through the run's known ends with their velocities (the known end
        sample minus its known neighbour outside the run; zero when that is unknown). A
        run with one known end is held at it; NaN off the runs and on runs with none.
    offset : (T, N, 3)
        The filler's step at each known end (its sample next to that end less the
        measured end carried one frame on at its measured velocity), blended linearly
        across the run (held over a run with one known end): subtracting it joins the
        fill to its ends. Zero off the runs.
    """
    t, n, _ = p.shape
    out = np.full_like(p, np.nan)
    offset = np.zeros_like(p)
    col, start, end = _run_bounds(fill)
    for c, s, e in zip(col.tolist(), start.tolist(), end.tolist(), strict=True):
        has0 = s > 0 and known[s - 1, c]
        has1 = e < t and known[e, c]
        if not (has0 or has1):
            continue
        if has0 and has1:
            x0, x1 = p[s - 1, c], p[e, c]
            v0 = x0 - p[s - 2, c] if s >= 2 and known[s - 2, c] else np.zeros(3)
            v1 = p[e + 1, c] - x1 if e + 1 < t and known[e + 1, c] else np.zeros(3)
            span = e - s + 1  # frames from one known end to the other
            u = (np.arange(s, e) - (s - 1)) / span
            h00 = 2 * u**3 - 3 * u**2 + 1
            h10 = u**3 - 2 * u**2 + u
            h01 = -2 * u**3 + 3 * u**2
            h11 = u**3 - u**2
            out[s:e, c] = (
                h00[:, None] * x0
                + h10[:, None] * span * v0
                + h01[:, None] * x1
                + h11[:, None] * span * v1
            )
        else:
            out[s:e, c] = p[s - 1, c] if has0 else p[e, c]
        # the filler's step at each known end: its first (last) sample less the measured
        # end carried one frame on at its measured velocity
        step0 = (
            p[s, c] - (2 * p[s - 1, c] - p[s - 2, c])
            if has0 and s >= 2 and known[s - 2, c]
            else (p[s, c] - p[s - 1, c] if has0 else None)
        )
        step1 = (
            p[e - 1, c] - (2 * p[e, c] - p[e + 1, c])
            if has1 and e + 1 < t and known[e + 1, c]
            else (p[e - 1, c] - p[e, c] if has1 else None)
        )
        if step0 is not None and step1 is not None:
            u = (np.arange(s, e) - (s - 1)) / (e - s + 1)
            offset[s:e, c] = (1 - u)[:, None] * step0 + u[:, None] * step1
        else:
            offset[s:e, c] = step0 if step0 is not None else step1
    return out, offset


def _within_from_ends(
    d2: np.ndarray, runs: np.ndarray, known: np.ndarray, limit: float, margin: int = 3
) -> np.ndarray:
    """(T, N) bool: the samples of each run that a measured end reaches before the
    first second difference above ``limit``, less ``margin`` frames."""
    keep = np.zeros(runs.shape, dtype=bool)
    t = runs.shape[0]
    col, start, end = _run_bounds(runs)
    for c, s, e in zip(col.tolist(), start.tolist(), end.tolist(), strict=True):
        bad = np.flatnonzero(~(d2[s:e, c] <= limit))
        if bad.size == 0:
            continue
        if s > 0 and known[s - 1, c]:
            keep[s : s + max(int(bad[0]) - margin, 0), c] = True
        if e < t and known[e, c]:
            keep[s + min(int(bad[-1]) + 1 + margin, e - s) : e, c] = True
    return keep


def _judged_second_difference(positions: np.ndarray) -> np.ndarray:
    """:func:`second_difference` with the take's first and last frames at 0 where present:
    they have no second difference of their own, and a fill there is judged by its
    neighbour's, which includes it (NaN would fail every run touching the take's ends)."""
    d2 = second_difference(positions)
    if d2.shape[0] >= 3:
        for row in (0, -1):
            d2[row] = np.where(np.isnan(positions[row, :, 0]), np.nan, 0.0)
    return d2


def _run_peak(d2: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """(T, N) the largest second difference over each sample's fill run (NaN -> inf)."""
    peak = np.zeros(fill.shape)
    col, start, end = _run_bounds(fill)
    v = np.where(np.isnan(d2), np.inf, d2)
    for c, s, e in zip(col.tolist(), start.tolist(), end.tolist(), strict=True):
        peak[s:e, c] = v[s:e, c].max()
    return peak


def condition_fills(
    positions: np.ndarray,
    fill: np.ndarray,
    *,
    limit: float,
    short_run: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Make every filled run continuous and keep it only if it moves like the take.

    See the module docstring for the construction.

    Parameters
    ----------
    positions : (T, N, 3) float, metres
        The capture after filling: measured samples and the filler's estimates; NaN
        where nothing was filled.
    fill : (T, N) bool
        The filled samples (those that may change); every other present sample is a
        fixed end.
    limit : float, metres per frame²
        The largest second difference a filled sample may have (e.g.
        :func:`measured_acceleration_limit`).
    short_run : int
        Interior runs up to this many frames may fall back to the Hermite curve alone.

    Returns
    -------
    positions : (T, N, 3) float64
        Filled runs replaced by their conditioned version; NaN where a run was dropped.
    dropped : (T, N) bool
        Filled samples removed because no version of their run stayed within ``limit``.
    """
    p = as_trajectories(positions)
    f = np.asarray(fill, dtype=bool) & ~np.isnan(p[..., 0])
    if f.shape != p.shape[:2]:
        raise ValidationError(f"fill: expected shape {p.shape[:2]}, got {f.shape}")
    if not (np.isfinite(limit) or limit == np.inf) or limit <= 0:
        raise ValidationError(f"limit: expected a positive number, got {limit!r}")
    out = p.copy()
    if not f.any():
        return out, np.zeros(f.shape, dtype=bool)
    known = ~np.isnan(p[..., 0]) & ~f
    h, offset = _hermite(p, f, known)
    base = ~np.isnan(h[..., 0]) & f
    # departure from the Hermite curve, the filler's end steps removed, held at zero
    # on the known samples around the run
    d = np.where(known[..., None], np.zeros_like(p), np.nan)
    d[base] = p[base] - offset[base] - h[base]
    pending = base.copy()
    for n_pass in _PASSES:
        if not pending.any():
            break
        cols = np.flatnonzero(pending.any(axis=0))  # only the columns still to do
        sm = np.zeros_like(p)
        sm[:, cols] = smooth_trajectories(
            d[:, cols], lam=1.0 / 16.0, iterations=n_pass, mask=pending[:, cols]
        )
        out[pending] = h[pending] + sm[pending]
        ok = _run_peak(_judged_second_difference(out), pending) <= limit
        pending &= ~ok
    if pending.any():
        col, start, end = _run_bounds(pending)
        t = p.shape[0]
        short = np.zeros_like(pending)
        for c, s, e in zip(col.tolist(), start.tolist(), end.tolist(), strict=True):
            interior = s > 0 and e < t and known[s - 1, c] and known[e, c]
            if interior and e - s <= short_run:
                short[s:e, c] = True
        out[short] = h[short]
        ok = short & (_run_peak(_judged_second_difference(out), short) <= limit)
        pending &= ~ok
    if pending.any():
        # keep what stays within the limit from each measured end (the last pass)
        out[pending] = h[pending] + sm[pending]
        pending &= ~_within_from_ends(_judged_second_difference(out), pending, known, limit)
    dropped = (f & ~base) | pending
    out[dropped] = np.nan
    return out, dropped
