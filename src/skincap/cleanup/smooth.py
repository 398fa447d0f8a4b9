"""Smoothing in local frames after Park & Hodgins (2006) §4.4.

Filtering global trajectories would smear the large rigid motions of the body; instead
each marker is expressed in the local frame of its neighbourhood (the rigid transform,
eq. 2, that carries the neighbours' reference shape onto their current positions), the
local trajectory is smoothed with the update ``x <- x - λ Δ⁴ x`` applied ``n`` times,
and the result is transformed back to the global frame.

Frequency response
------------------
``Δ⁴`` is the fourth central difference ``x[t-2] - 4x[t-1] + 6x[t] - 4x[t+1] + x[t+2]``,
whose response to ``e^{iωt}`` (ω in radians per sample) is ``(2 - 2 cos ω)²``. One update
multiplies that frequency by ``1 - λ(2 - 2cos ω)²``; ``n`` updates by

    H(ω) = (1 - λ (2 - 2 cos ω)²)^n ,

real and symmetric, so the filter is zero-phase (like a forward-backward ``filtfilt``).
Stability (``|H| <= 1`` at every frequency) needs ``0 < λ <= 1/8`` (the factor is
``1 - 16λ`` at Nyquist); ``λ = 1/16`` removes Nyquist exactly. The -3 dB frequency,
where ``H = 1/√2``, is

    f_c = rate / (2π) · arccos(1 - s/2),   s = sqrt((1 - 2^(-1/(2n))) / λ),

(:func:`cutoff_frequency`) and, inverted, ``λ = (1 - 2^(-1/(2n))) / (2 - 2cos(2π f_c /
rate))²`` (:func:`lambda_for_cutoff`). Near zero frequency ``H ≈ 1 - nλω⁴``: the same
``ω⁴`` roll-in as a second-order Butterworth low-pass ``|H_B| = (1 + (ω/ω_B)⁴)^(-1/2)
≈ 1 - ½(ω/ω_B)⁴``, so the pass band matches a 2nd-order Butterworth with
``ω_B = (2nλ)^(-1/4)`` (rad/sample); the stop band falls faster with more iterations
(``n`` large approaches a Gaussian in ``ω²``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap._arrays import as_trajectories
from skincap.errors import ValidationError
from skincap.geometry.rigid import apply_rigid, fit_rigid

__all__ = [
    "smooth_local",
    "local_trajectories",
    "smooth_trajectories",
    "frequency_response",
    "cutoff_frequency",
    "lambda_for_cutoff",
    "butterworth_equivalent_cutoff",
]


def _within_mask(change: np.ndarray, mask: Any) -> np.ndarray:
    """``change`` (T, N) bool restricted to the caller's ``mask`` (T, N) bool, if any."""
    if mask is None:
        return change
    m = np.asarray(mask, dtype=bool)
    if m.shape != change.shape:
        t, n = change.shape
        raise ValidationError(f"mask: expected shape ({t}, {n}), got {m.shape}")
    return change & m


def _check_lam_n(lam: float, iterations: int) -> None:
    if not (np.isfinite(lam) and 0 < lam <= 0.125):
        raise ValidationError(f"lam: expected 0 < lam <= 1/8 (stability), got {lam!r}")
    if not isinstance(iterations, int | np.integer) or iterations < 1:
        raise ValidationError(f"iterations: expected a positive integer, got {iterations!r}")


def frequency_response(
    frequency_hz: np.ndarray | float, rate: float, *, lam: float, iterations: int
) -> np.ndarray:
    """Gain ``H = (1 - λ(2 - 2cos ω)²)^n`` of the iterated Δ⁴ update, ``ω = 2π f / rate``.

    Parameters
    ----------
    frequency_hz : (...) float, Hz
    rate : float, Hz (frame rate)
    lam : float in (0, 1/8]
    iterations : int >= 1

    Returns
    -------
    (...) float64 : real gain (zero phase).
    """
    _check_lam_n(lam, iterations)
    w = 2 * np.pi * np.asarray(frequency_hz, dtype=np.float64) / rate
    return (1.0 - lam * (2.0 - 2.0 * np.cos(w)) ** 2) ** iterations


def cutoff_frequency(lam: float, rate: float, iterations: int) -> float:
    """-3 dB frequency (Hz) of the iterated Δ⁴ update; ``rate / 2`` when the gain never
    falls that low below Nyquist."""
    _check_lam_n(lam, iterations)
    s = np.sqrt((1.0 - 2.0 ** (-1.0 / (2 * iterations))) / lam)
    if s >= 4.0:
        return rate / 2.0
    return float(rate / (2 * np.pi) * np.arccos(1.0 - s / 2.0))


def lambda_for_cutoff(cutoff_hz: float, rate: float, iterations: int) -> float:
    """λ giving a -3 dB frequency of ``cutoff_hz`` with ``iterations`` updates.

    Raises
    ------
    ValidationError
        If the cut-off is not in (0, rate/2), or needs λ > 1/8 (unstable): a lower
        cut-off needs more iterations (the message says how many).
    """
    if not (np.isfinite(rate) and rate > 0):
        raise ValidationError(f"rate: expected a positive frame rate, got {rate!r}")
    if not (np.isfinite(cutoff_hz) and 0 < cutoff_hz < rate / 2):
        raise ValidationError(
            f"cutoff_hz: expected 0 < cutoff < rate/2 = {rate / 2}, got {cutoff_hz!r}"
        )
    if not isinstance(iterations, int | np.integer) or iterations < 1:
        raise ValidationError(f"iterations: expected a positive integer, got {iterations!r}")
    w = 2 * np.pi * cutoff_hz / rate
    lam = (1.0 - 2.0 ** (-1.0 / (2 * iterations))) / (2.0 - 2.0 * np.cos(w)) ** 2
    if lam > 0.125:
        # with λ = 1/8: (1 - g/8)^n = 1/√2  ->  n = ln 2 / (-2 ln(1 - g/8))
        g = (2.0 - 2.0 * np.cos(w)) ** 2
        need = int(np.ceil(np.log(2.0) / (-2.0 * np.log1p(-g / 8.0))))
        raise ValidationError(
            f"a {cutoff_hz} Hz cut-off at {rate} Hz with {iterations} iterations needs "
            f"lam = {lam:.4g} > 1/8 (unstable); use at least {need} iterations"
        )
    return float(lam)


def butterworth_equivalent_cutoff(lam: float, rate: float, iterations: int) -> float:
    """Cut-off (Hz) of the 2nd-order Butterworth low-pass with the same pass-band
    roll-in ``1 - nλω⁴``: ``ω_B = (2nλ)^(-1/4)`` rad/sample."""
    _check_lam_n(lam, iterations)
    wb = (2.0 * iterations * lam) ** -0.25
    return float(min(wb, np.pi) * rate / (2 * np.pi))


def _reflect_plan(valid: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """For offsets -2, -1, +1, +2: (index, anchor, reflected) arrays (T, N).

    Inside a run of valid samples the neighbour is ``x[t+k]``; past the run end ``e``
    it is the odd reflection ``2 x[e] - x[2e - (t+k)]`` (keeps the end point and linear
    trends). ``anchor`` is the run end used (or t), ``reflected`` a bool.
    """
    t, n = valid.shape
    frame = np.arange(t)[:, None].repeat(n, 1)
    # run bounds per valid sample
    start = np.maximum.accumulate(
        np.where(valid & ~np.vstack([np.zeros((1, n), bool), valid[:-1]]), frame, -1), axis=0
    )
    last = np.where(valid & ~np.vstack([valid[1:], np.zeros((1, n), bool)]), frame, t)
    end = np.minimum.accumulate(last[::-1], axis=0)[::-1]
    plan = []
    for k in (-2, -1, 1, 2):
        j = frame + k
        lo_out = j < start
        hi_out = j > end
        anchor = np.where(lo_out, start, np.where(hi_out, end, frame))
        idx = np.where(lo_out | hi_out, 2 * anchor - j, j)
        idx = np.clip(idx, 0, t - 1)
        plan.append((idx, np.clip(anchor, 0, t - 1), lo_out | hi_out))
    return plan


def smooth_trajectories(
    x: np.ndarray, *, lam: float, iterations: int, mask: np.ndarray | None = None
) -> np.ndarray:
    """Iterate ``x <- x - λ Δ⁴ x`` along axis 0 of trajectories with gaps.

    Parameters
    ----------
    x : (T, N, 3) float; NaN where missing
    lam : float in (0, 1/8]
    iterations : int >= 1
    mask : (T, N) bool, optional
        True where a sample may change (default: every present sample). Samples outside
        the mask keep their value but still act as neighbours.

    Returns
    -------
    (T, N, 3) float64
        Each run of present samples is filtered on its own (odd reflection at its
        ends, so the end samples stay put); runs shorter than 5 samples and NaN samples
        are unchanged.
    """
    _check_lam_n(lam, iterations)
    y = np.array(x, dtype=np.float64)
    t, n, _ = y.shape
    valid = ~np.isnan(y[..., 0])
    # run lengths: only runs of >= 5 samples are filtered
    plan = _reflect_plan(valid)
    frame = np.arange(t)[:, None].repeat(n, 1)
    run_start = np.maximum.accumulate(
        np.where(valid & ~np.vstack([np.zeros((1, n), bool), valid[:-1]]), frame, -1), axis=0
    )
    run_end = np.minimum.accumulate(
        np.where(valid & ~np.vstack([valid[1:], np.zeros((1, n), bool)]), frame, t)[::-1], axis=0
    )[::-1]
    change = _within_mask(valid & (run_end - run_start + 1 >= 5), mask)
    coeff = {-2: 1.0, -1: -4.0, 1: -4.0, 2: 1.0}
    # Inside a run the neighbour at offset k is z shifted by k frames; only the samples
    # whose neighbour lies past their run end take the odd reflection, so gather those
    # few (flat indices into (T N, 3)) instead of indexing all T N samples each pass.
    shifts = []
    for k, (idx, anchor, refl) in zip((-2, -1, 1, 2), plan, strict=True):
        rows = np.flatnonzero((refl & valid).reshape(-1))
        cols = rows % n if n else rows
        shifts.append(
            (k, rows, anchor.reshape(-1)[rows] * n + cols, idx.reshape(-1)[rows] * n + cols)
        )
    # C order: the flat (T N, 3) views below must share memory with z and nb
    z = np.ascontiguousarray(np.where(valid[..., None], y, 0.0))
    change3 = np.broadcast_to(change[..., None], z.shape)
    nb = np.empty(z.shape)
    for _ in range(iterations):
        flat = z.reshape(-1, 3)
        d4 = 6.0 * z
        for k, rows, anchor_flat, idx_flat in shifts:
            _shifted(z, k, out=nb)
            nb.reshape(-1, 3)[rows] = 2.0 * flat[anchor_flat] - flat[idx_flat]
            nb *= coeff[k]
            d4 += nb
        d4 *= lam  # z - λ Δ⁴z where the sample may change (in place: same values)
        np.subtract(z, d4, out=d4)
        np.copyto(z, d4, where=change3)
    return np.where(valid[..., None], z, np.nan)


def _shifted(z: np.ndarray, k: int, *, out: np.ndarray) -> np.ndarray:
    """``out[t] = z[t + k]`` along axis 0, zero where ``t + k`` falls outside the take."""
    t = z.shape[0]
    out[...] = 0.0
    if k >= 0:
        out[: max(t - k, 0)] = z[k:]
    elif -k < t:
        out[-k:] = z[: t + k]
    return out


def smooth_local(
    positions: np.ndarray,
    neighbours: Any,
    *,
    lam: float = 0.02,
    iterations: int = 10,
    mask: np.ndarray | None = None,
    max_move: np.ndarray | float | None = None,
) -> np.ndarray:
    """Smooth marker trajectories in their local frames (Park & Hodgins §4.4).

    For every marker ``i`` and frame: the rigid transform (Kabsch, eq. 2) carrying its
    neighbours' reference shape (their mean shape over the take, Procrustes-aligned)
    onto their present positions; the marker's local trajectory ``x̂_i = R^T (x_i - t)``
    is filtered by ``iterations`` updates ``x̂ <- x̂ - λ Δ⁴ x̂`` and mapped back.
    See the module docstring for the frequency response and :func:`lambda_for_cutoff`
    for choosing λ from a Butterworth-like cut-off (defaults: λ = 0.02, 10 iterations,
    a -3 dB point at ≈ 0.19 × rate, 23 Hz at 120 Hz: it removes jitter, not motion).

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    neighbours : CSR (offsets (N + 1,), indices (E,)) or a MarkerSurface
    lam : float in (0, 1/8]
    iterations : int >= 1
    mask : (T, N) bool, optional
        True where a sample may change (default: all present samples).
    max_move : float, (N,) or (T, N) float, metres, optional
        The farthest a sample may move: a longer smoothing step is shortened to this
        length (e.g. a small multiple of each marker's measurement noise, so measured
        data stay measured). Default: no bound.

    Returns
    -------
    (T, N, 3) float64, metres
        NaN stays NaN; a frame where a marker has fewer than 3 present neighbours
        splits its local trajectory (the sample is left as it was).

    Notes
    -----
    The local frames are robust to one bad neighbour: after a first fit, the neighbour
    whose residual changed most suddenly, when that is over 2.5 times the other
    neighbours' (and over 1 cm), is put back where its steady residual says for that
    frame and the frame refitted
    (:func:`skincap.cleanup.local_frames.fit_frames_robust`), so a spike on a
    neighbour does not shake the marker's local trajectory.
    """
    _check_lam_n(lam, iterations)
    p = as_trajectories(positions)
    t, n, _ = p.shape
    present = ~np.isnan(p[..., 0])
    if t < 5:
        return p.copy()
    local, rot, tr = local_trajectories(p, neighbours)
    if rot is None:
        return p.copy()
    has_frame = ~np.isnan(tr[..., 0])
    change = _within_mask(present & has_frame, mask)
    sm = smooth_trajectories(local, lam=lam, iterations=iterations, mask=change)
    back = apply_rigid(rot, tr, sm[:, :, None, :])[:, :, 0]
    if max_move is not None:
        bound = (
            np.broadcast_to(np.asarray(max_move, dtype=np.float64), (t, n))
            if np.ndim(max_move) != 1
            else np.broadcast_to(np.asarray(max_move, dtype=np.float64)[None, :], (t, n))
        )
        step = back - p
        length = np.linalg.norm(step, axis=-1)
        scale = np.where(length > bound, bound / np.where(length > 0, length, 1.0), 1.0)
        back = p + step * np.nan_to_num(scale, nan=0.0)[..., None]
    out = p.copy()
    out[change] = back[change]
    return out


def local_trajectories(
    positions: np.ndarray, neighbours: Any
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Each marker's trajectory in the local frame of its neighbours.

    The frame carries the neighbours' reference shape (their Procrustes mean over the
    take) onto their present positions (eq. 2), fitted robustly
    (:func:`skincap.cleanup.local_frames.fit_frames_robust`: an outlying neighbour is
    dropped for that frame). ``x̂ = R^T (x - t)``.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    neighbours : CSR (offsets, indices) or a MarkerSurface

    Returns
    -------
    local : (T, N, 3) float64, metres
        NaN where the marker is missing or has fewer than 3 present neighbours.
    rot : (T, N, 3, 3) or None, tr : (T, N, 3) or None
        The frames (NaN where undetermined); None when no marker has 3 neighbours.
    """
    from skincap.cleanup.local_frames import fit_frames_robust
    from skincap.cleanup.neighbours import as_csr

    p = np.asarray(positions, dtype=np.float64)
    t, n, _ = p.shape
    offsets, indices = as_csr(neighbours, n)
    present = ~np.isnan(p[..., 0])
    deg = np.diff(offsets)
    kmax = int(deg.max()) if n and deg.size else 0
    if kmax < 3 or t == 0:
        return np.full_like(p, np.nan), None, None
    slot = np.arange(kmax)
    nb_ok = slot[None, :] < deg[:, None]  # (N, K)
    nb = np.where(
        nb_ok, indices[np.minimum(offsets[:-1, None] + slot, max(len(indices) - 1, 0))], 0
    )
    cur = p[:, nb]  # (T, N, K, 3)
    cur_ok = present[:, nb] & nb_ok[None]
    # reference shape of each neighbourhood: mean over frames after a Procrustes pass
    ref = _neighbourhood_reference(cur, cur_ok, deg)  # (N, K, 3)
    # fitted per neighbourhood size: no work on the padded slots of the small ones (the
    # frames agree with one padded fit to rounding, ~1e-12 m); fewer than 3: no frame
    rot = np.full((t, n, 3, 3), np.nan)
    tr = np.full((t, n, 3), np.nan)
    for size in np.unique(deg[deg >= 3]).tolist():
        cols = np.flatnonzero(deg == size)
        rot[:, cols], tr[:, cols] = fit_frames_robust(
            ref[None, cols, :size], cur[:, cols, :size], cur_ok[:, cols, :size]
        )  # (T, n_size, 3, 3), (T, n_size, 3)
    has_frame = ~np.isnan(tr[..., 0])
    local = np.einsum("tnji,tnj->tni", rot, p - tr)  # R^T (x - t)
    local = np.where((present & has_frame)[..., None], local, np.nan)
    return local, rot, tr


def _neighbourhood_reference(cur: np.ndarray, ok: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(N, K, 3) neighbourhood shapes from (T, N, K, 3) with presence (T, N, K): the
    per-coordinate median of the aligned frames (a spike in a few frames cannot
    bend it), after a first alignment on the mean. ``sizes`` (N,) int: members of each
    neighbourhood (its first slots; the rest are padding, NaN in the result, as is
    every neighbourhood of fewer than 3)."""
    from skincap.cleanup.robust_stats import nan_median

    if cur.shape[0] > 120:  # a spread of frames is enough for the mean shape
        pick = np.linspace(0, cur.shape[0] - 1, 120).round().astype(np.int64)
        cur, ok = cur[pick], ok[pick]
    t = cur.shape[0]
    count = ok.sum(axis=2)  # (T, N)
    # start from each neighbourhood's best-covered frame (all K slots filled counts only
    # for the largest neighbourhoods)
    best_all = np.argmax(count + ok.all(axis=2) * t, axis=0)  # (N,)
    out = np.full(cur.shape[1:], np.nan)
    # one pass per neighbourhood size: no fits over padded slots
    for size in np.unique(sizes[sizes >= 3]).tolist():
        cols = np.flatnonzero(sizes == size)
        c_cur, c_ok, best = cur[:, cols, :size], ok[:, cols, :size], best_all[cols]
        n = cols.size
        ref = c_cur[best, np.arange(n)]  # (n, size, 3)
        ref_ok = c_ok[best, np.arange(n)]
        ref = np.where(ref_ok[..., None], ref, 0.0)
        for last in (False, True):
            # current -> reference
            rot, tr = fit_rigid(c_cur, ref[None], mask=c_ok & ref_ok[None])
            aligned = apply_rigid(rot, tr, c_cur)  # (T, n, size, 3)
            good = c_ok & ~np.isnan(tr[..., 0])[..., None]
            cnt = good.sum(axis=0)  # (n, size)
            if last:
                new = nan_median(np.where(good[..., None], aligned, np.nan), axis=0)
            else:
                total = np.where(good[..., None], aligned, 0.0).sum(axis=0)
                new = total / np.maximum(cnt, 1)[..., None]
            ref_ok = cnt > 0
            ref = np.where(ref_ok[..., None], new, 0.0)
        out[cols, :size] = np.where(ref_ok[..., None], ref, np.nan)
    return out
