"""Quadratic deformation fields (Müller et al. 2005; Park & Hodgins 2006, eq. 6), batched.

A quadratic field maps a point ``p = (x, y, z)`` to ``A q(p)`` where
``q(p) = [x, y, z, x², y², z², xy, yz, zx, 1]`` and ``A = [A1 A2 A3 a0]`` is 3x10:
``A1`` the linear part, ``A2`` the pure and ``A3`` the mixed quadratic part (the
paper's 3x9 modes), and ``a0`` a constant. Park & Hodgins fit ``A`` by least squares
from a part's member markers in their rigidly aligned local frame (eq. 6, the
pseudo-inverse) with the nine terms only. The tenth, constant term is needed for
exactness: the rigid fit matches the *centroids* of the markers, and the quadratic
terms of a field move the centroid (``x²`` has a positive mean), so without it a pure
quadratic field is not reproduced.

A part with fewer than nine well-spread markers leaves ``A`` under-determined, and the
plain pseudo-inverse then invents large quadratic terms. :func:`fit_quadratic` adds a
Tikhonov term that pulls ``A`` toward the identity ``[I 0 0]`` (what the rigid fit
already explains): weak on the linear columns and stronger on the quadratic ones, both
scaled by the part's size, so a well-spread part is barely biased and a degenerate one
falls back to its linear (then rigid) part.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError

__all__ = ["QUADRATIC_TERMS", "apply_quadratic", "fit_quadratic", "quadratic_basis"]

#: Number of terms of the quadratic vector ``q``: the paper's 9 of eq. 6 and a constant.
QUADRATIC_TERMS = 10


def _points(name: str, value: object) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != 3:
        raise ValidationError(f"{name} must have shape (..., 3); got {arr.shape}")
    return arr


def quadratic_basis(points: np.ndarray) -> np.ndarray:
    """The quadratic vector ``q = [x, y, z, x², y², z², xy, yz, zx, 1]`` of each point.

    Parameters
    ----------
    points : (..., 3) float
        Positions in a part's local frame (metres). NaN propagates.

    Returns
    -------
    (..., 10) float64
    """
    p = _points("points", points)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    one = np.ones_like(x)
    return np.stack([x, y, z, x * x, y * y, z * z, x * y, y * z, z * x, one], axis=-1)


def fit_quadratic(
    reference: np.ndarray,
    current: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    linear_regularisation: float = 1e-9,
    quadratic_regularisation: float = 1e-4,
) -> np.ndarray:
    """Least-squares quadratic field with ``current ≈ A q(reference)``, batched (eq. 6).

    Minimises ``Σ_i w_i ||A q_i - c_i||² + Y ||(A - [I 0 0 0]) Γ||²`` where
    ``Y = Σ w_i``, ``Γ² = diag(λ_lin s², ×3, λ_quad s⁴, ×6, λ_lin)`` and ``s²`` is the
    weighted mean squared distance of the reference points from the origin (so the
    penalty has the units of the data term and does not depend on the part's size).
    With both λ zero this is the pseudo-inverse of eq. 6 (with the constant term).
    Ten or more well-spread points determine ``A``; with fewer the penalty pulls the
    quadratic terms to zero first, then the linear part to the identity.

    Parameters
    ----------
    reference : (..., K, 3) float, metres
        Reference (local part reference) positions; NaN rows are ignored.
    current : (..., K, 3) float, metres
        Positions to reach (the rigidly aligned positions at a frame); NaN rows ignored.
        Leading axes broadcast against ``reference``'s.
    weights : (..., K) float, optional
        Non-negative weight per point (default 1); 0 excludes a point.
    linear_regularisation, quadratic_regularisation : float
        λ_lin and λ_quad above (dimensionless, non-negative).

    Returns
    -------
    A : (..., 3, 10) float64
        The quadratic transformation. A batch with no valid point (or zero total
        weight) gets NaN.
    """
    ref = _points("reference", reference)
    cur = _points("current", current)
    if ref.ndim < 2 or cur.ndim < 2 or ref.shape[-2] != cur.shape[-2]:
        raise ValidationError(
            f"reference and current must be (..., K, 3) with the same K; got {ref.shape} and {cur.shape}"
        )
    lam_lin = float(linear_regularisation)
    lam_quad = float(quadratic_regularisation)
    if not (lam_lin >= 0 and lam_quad >= 0 and np.isfinite(lam_lin + lam_quad)):
        raise ValidationError("regularisation weights must be finite and non-negative")
    k = ref.shape[-2]
    lead = np.broadcast_shapes(ref.shape[:-2], cur.shape[:-2])
    if weights is None:
        w = np.ones((*lead, k))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[-1:] != (k,) or np.any(~(w >= 0)):
            raise ValidationError(
                f"weights must be non-negative with shape (..., {k}); got {w.shape}"
            )
        lead = np.broadcast_shapes(lead, w.shape[:-1])
    valid = np.isfinite(ref).all(-1) & np.isfinite(cur).all(-1)
    w = np.where(valid, w, 0.0)
    w = np.broadcast_to(w, (*lead, k))
    q = np.where(valid[..., None], quadratic_basis(np.where(np.isfinite(ref), ref, 0.0)), 0.0)
    c = np.where(valid[..., None], np.where(np.isfinite(cur), cur, 0.0), 0.0)
    q = np.broadcast_to(q, (*lead, k, QUADRATIC_TERMS))
    c = np.broadcast_to(c, (*lead, k, 3))
    total = w.sum(-1)  # (...)
    safe_total = np.where(total > 0, total, 1.0)
    s2 = np.einsum("...k,...k->...", w, (q[..., :3] ** 2).sum(-1)) / safe_total  # (...) m²
    s2 = np.where(s2 > 0, s2, 1.0)
    gamma2 = (
        np.concatenate(
            [
                np.broadcast_to((lam_lin * s2)[..., None], (*lead, 3)),
                np.broadcast_to((lam_quad * s2 * s2)[..., None], (*lead, 6)),
                np.full((*lead, 1), lam_lin),
            ],
            axis=-1,
        )
        * total[..., None]
    )  # (..., 10)
    n_terms = QUADRATIC_TERMS
    wq_t = np.swapaxes(w[..., None] * q, -1, -2)  # (..., 10, K)
    qqt = wq_t @ q  # (..., 10, 10)
    pqt = np.swapaxes(wq_t @ c, -1, -2)  # (..., 3, 10)
    identity = np.zeros((3, n_terms))
    identity[:, :3] = np.eye(3)
    lhs = qqt + gamma2[..., None, :] * np.eye(n_terms)
    rhs = pqt + identity * gamma2[..., None, :]
    ok = total > 0
    # A lhs = rhs (lhs symmetric)  <=>  lhs A^T = rhs^T
    lhs = np.where(ok[..., None, None], lhs, np.eye(n_terms))
    try:
        a_t = np.linalg.solve(lhs, np.swapaxes(rhs, -1, -2))
    except np.linalg.LinAlgError:
        a_t = np.linalg.pinv(lhs) @ np.swapaxes(rhs, -1, -2)
    a = np.swapaxes(a_t, -1, -2)
    return np.where(ok[..., None, None], a, np.nan)


def apply_quadratic(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``A q(p)`` for every point, batched.

    Parameters
    ----------
    matrix : (..., 3, 10) float
    points : (..., K, 3) float, metres (leading axes broadcast with ``matrix``'s)

    Returns
    -------
    (..., K, 3) float64
    """
    a = np.asarray(matrix, dtype=np.float64)
    if a.shape[-2:] != (3, QUADRATIC_TERMS):
        raise ValidationError(f"matrix must have shape (..., 3, {QUADRATIC_TERMS}); got {a.shape}")
    return np.einsum("...xa,...ka->...kx", a, quadratic_basis(points))
