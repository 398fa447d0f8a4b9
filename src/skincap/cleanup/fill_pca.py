"""Whole-body PCA gap filling (the ``pca`` method, Gløersen & Federolf 2016).

The take is one (T, 3N) matrix; missing entries are reconstructed iteratively from the
principal components of all markers' normalised coordinates, after the body's travel
is taken out. A baseline for the local methods of :mod:`skincap.cleanup.fill_local`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from skincap.cleanup.fill_temporal import fill_linear, previous_next_present

__all__ = ["fill_pca"]


def fill_pca(
    positions: np.ndarray,
    target: np.ndarray,
    *,
    variance: float = 0.99,
    max_iterations: int = 40,
    tol: float = 1e-4,
) -> np.ndarray:
    """Whole-body PCA fill (Gløersen & Federolf 2016).

    The body's travel is taken out first: each frame is shifted by the mean
    displacement of its present markers from their own temporal means (a centroid
    that does not jump when a marker drops out), and put back at the end. Without
    this, a walk's or a run's translation takes most of the variance and the kept
    components miss the limbs (the punched-gap errors with and without are in
    ``docs/results.md``).

    The take is then a (T, 3N) matrix; columns are centred and scaled to unit variance
    over their present samples, missing entries are initialised by linear
    interpolation in time (nearest present sample at the ends), then repeatedly
    replaced by their reconstruction from the principal components that keep
    ``variance`` of the variance, until they move less than ``tol`` (in normalised
    units) or ``max_iterations`` is reached.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Samples to fill. Markers never present stay NaN.
    variance : float in (0, 1]
    max_iterations : int
    tol : float

    Returns
    -------
    (T, N, 3) float64 : a filled copy.
    """
    p = np.array(positions, dtype=np.float64)
    t, n, _ = p.shape
    present = ~np.isnan(p[..., 0])
    usable = present.sum(axis=0) >= 2
    if t < 3 or usable.sum() < 2:
        return p
    travel = _body_travel(p, present, usable)  # (T, 1, 3)
    p -= travel
    cols = np.nonzero(usable)[0]
    x = p[:, cols].reshape(t, -1)  # (T, 3M)
    obs = np.repeat(present[:, cols], 3, axis=1)
    mean = np.nanmean(np.where(obs, x, np.nan), axis=0)
    std = np.sqrt(np.nanmean(np.where(obs, (x - mean) ** 2, np.nan), axis=0))
    std = np.where(std > 1e-9, std, 1.0)
    z = (x - mean) / std
    # initialise: linear in time, then nearest sample at the ends
    zi = fill_linear(z.reshape(t, -1, 3), ~present[:, cols]).reshape(t, -1)
    prev, nxt = previous_next_present(np.repeat(present[:, cols], 3, axis=1))
    col = np.arange(zi.shape[1])[None, :].repeat(t, 0)
    still = np.isnan(zi)
    src = np.where(prev >= 0, prev, nxt)
    zi[still] = z[src[still], col[still]]
    miss = ~obs
    q = 0
    for _ in range(max_iterations):
        mu = zi.mean(axis=0)
        c = zi - mu
        v = _leading_axes(c, variance, q)  # (3M, q)
        q = v.shape[1]
        recon = mu + (c @ v) @ v.T
        change = np.abs(recon[miss] - zi[miss]).max() if miss.any() else 0.0
        zi[miss] = recon[miss]
        if change < tol:
            break
    filled = (zi * std + mean).reshape(t, -1, 3)
    sub = target[:, cols]
    block = p[:, cols]
    block[sub] = filled[sub]
    p[:, cols] = block
    return p + travel


def _leading_axes(c: np.ndarray, variance: float, hint: int = 0) -> np.ndarray:
    """(D, q) the principal axes of the centred rows ``c`` (F, D) that keep ``variance``.

    The eigenproblem of the smaller of the (D, D) covariance and the (F, F) Gram
    matrix (axes ``c^T u / |c^T u|``), solved only for the leading ``k`` eigenpairs
    (LAPACK ``syevr``; ``k`` a few more than ``hint``, the previous iteration's ``q``,
    doubled until they hold ``variance`` of the trace): cheaper than the whole
    decomposition when ``q`` is a few dozen of hundreds. Same axes as
    :func:`_leading_axes_full`, the reference, up to sign and rounding.
    """
    gram_rows = c.shape[1] > c.shape[0]
    a = c @ c.T if gram_rows else c.T @ c
    n = a.shape[0]
    total = max(float(np.trace(a)), 1e-300)
    k = min(n, max(hint + 8, 16))
    while True:
        ev, vec = scipy.linalg.eigh(a, subset_by_index=[n - k, n - 1], driver="evr")
        ev, vec = np.maximum(ev[::-1], 0.0), vec[:, ::-1]
        # all of them: the reference's sum (the trace differs in the last bits)
        frac = np.cumsum(ev) / (max(float(ev.sum()), 1e-300) if k == n else total)
        if frac[-1] >= variance or k == n:
            break
        k = min(n, 2 * k)
    q = int(min(np.searchsorted(frac, variance) + 1, k))
    vec = vec[:, :q]
    if gram_rows:
        vec = c.T @ vec
        vec /= np.maximum(np.linalg.norm(vec, axis=0), 1e-300)
    return vec


def _leading_axes_full(c: np.ndarray, variance: float) -> np.ndarray:
    """The reference of :func:`_leading_axes`: the whole eigendecomposition."""
    if c.shape[1] <= c.shape[0]:  # principal axes from the (D, D) covariance
        ev, vec = np.linalg.eigh(c.T @ c)
    else:  # or from the (F, F) Gram matrix: axes c^T u / |c^T u|
        ev, u = np.linalg.eigh(c @ c.T)
        vec = c.T @ u
        vec /= np.maximum(np.linalg.norm(vec, axis=0), 1e-300)
    ev, vec = np.maximum(ev[::-1], 0.0), vec[:, ::-1]
    frac = np.cumsum(ev) / max(float(ev.sum()), 1e-300)
    q = int(min(np.searchsorted(frac, variance) + 1, len(ev)))
    return vec[:, :q]


def _body_travel(p: np.ndarray, present: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(T, 1, 3) per-frame mean displacement of the present markers from their means.

    Frames where no usable marker is present take the nearest frames' value (linear).
    """
    sub = p[:, usable]
    ok = present[:, usable]
    mean = np.nanmean(np.where(ok[..., None], sub, np.nan), axis=0)  # (M, 3)
    disp = np.where(ok[..., None], sub - mean, 0.0)
    count = ok.sum(axis=1)
    travel = disp.sum(axis=1) / np.maximum(count, 1)[:, None]  # (T, 3)
    seen = count > 0
    if not seen.all():
        frames = np.arange(p.shape[0])
        for a in range(3):  # three coordinates, each interpolated over all frames at once
            travel[~seen, a] = np.interp(frames[~seen], frames[seen], travel[seen, a])
    return travel[:, None, :]
