"""Small convex quadratic programs on the probability simplex, many at once, exactly.

Blend weights are convex: non-negative and summing to one. Both the dense deformer's
marker weights (a blend of parts' rigid motions) and the fitted skin weights (a blend of
joints' transforms) minimise a quadratic over that simplex for every marker, each over a
handful of candidates. With ``k`` candidates the exact minimum is found by trying every
support ``S`` (2^k - 1 batched solves): on ``S`` the equality-constrained optimum of
``wᵀ G w - 2 hᵀ w`` is ``w = G_S⁻¹ (h_S + ν 1)`` with ``ν`` making it sum to one, and the
best non-negative one is the convex problem's KKT point.
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["simplex_least_squares"]


def simplex_least_squares(
    gram: np.ndarray, usable: np.ndarray, rhs: np.ndarray | None = None
) -> np.ndarray:
    """``argmin wᵀ G w - 2 hᵀ w`` over ``w ≥ 0``, ``Σ w = 1`` on each row's usable entries.

    Parameters
    ----------
    gram : (N, K, K) float
        Symmetric positive semi-definite. A tiny ridge (1e-9 of its mean diagonal)
        breaks ties of a singular ``G``; a support whose system stays singular is
        skipped.
    usable : (N, K) bool
        The entries a row may use; at least one True per row.
    rhs : (N, K) float, optional
        ``h``; zero when omitted (``argmin wᵀ G w``).

    Returns
    -------
    (N, K) float64
        Rows on the simplex, 0 where not usable.
    """
    n, k = usable.shape
    h = np.zeros((n, k)) if rhs is None else np.asarray(rhs, dtype=np.float64)
    scale = np.einsum("nkk->n", gram) / k
    g_all = gram + 1e-9 * np.maximum(scale, 1e-300)[:, None, None] * np.eye(k)
    best = np.full(n, np.inf)
    weights = np.zeros((n, k))
    for size in range(1, k + 1):
        for subset in itertools.combinations(range(k), size):
            s = list(subset)
            rows = np.flatnonzero(usable[:, s].all(axis=1))  # only rows whose entries exist
            if rows.size == 0:
                continue
            g = g_all[rows][:, s][:, :, s]
            h_s = h[rows][:, s]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                # a singular G_S gives inf/NaN here; such a row fails isfinite below
                both = np.linalg.solve(g, np.stack([h_s, np.ones((rows.size, size))], -1))
                gh, g1 = both[..., 0], both[..., 1]  # G_S⁻¹ h_S, G_S⁻¹ 1
                total = g1.sum(axis=1)
                nu = (1.0 - gh.sum(axis=1)) / np.where(np.abs(total) > 0, total, 1.0)
                w = gh + nu[:, None] * g1
                value = np.einsum("nk,nkl,nl->n", w, g, w) - 2.0 * np.einsum("nk,nk->n", w, h_s)
            better = (w >= -1e-12).all(axis=1) & np.isfinite(value) & (value < best[rows])
            take = rows[better]
            best[take] = value[better]
            weights[take] = 0.0
            weights[np.ix_(take, s)] = w[better]
    weights = np.maximum(weights, 0.0)
    return weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
