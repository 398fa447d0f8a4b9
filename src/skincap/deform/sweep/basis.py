"""A sweep's interpolation written as fixed weights on its key ellipses, for many frames at once.

Binding fixes each vertex's sweep parameter ``t_V``; only the key ellipses move. The
centre curve (an interpolating cubic B-spline, :class:`skincap.geometry.sweep.Sweep`)
is linear in the key centres, so ``C(t_V) = B(t_V) @ centres`` with a basis matrix
``B`` computed once; the orientation is the paper's normalised linear interpolation of
consecutive key quaternions (§3.2), fixed by the segment and the fraction of ``t_V``
in it. Evaluating a moving sweep at fixed parameters is then a few array products
over (frames, points), with no spline built per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from skincap.geometry.sweep import KeyEllipses, Sweep

__all__ = ["SweepBasis", "align_hemispheres", "nlerp"]


def align_hemispheres(q: np.ndarray) -> np.ndarray:
    """Flip key quaternions (..., K, 4) so consecutive keys have a non-negative dot product."""
    dots = np.einsum("...ki,...ki->...k", q[..., 1:, :], q[..., :-1, :])
    flips = np.where(dots < 0, -1.0, 1.0)
    ones = np.ones(q.shape[:-2] + (1,))
    signs = np.cumprod(np.concatenate([ones, flips], axis=-1), axis=-1)
    return q * signs[..., None]


def nlerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``((1 - u) q0 + u q1) / |...|`` for (..., 4) quaternions and (...) fractions."""
    q = (1.0 - u)[..., None] * q0 + u[..., None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@dataclass(frozen=True, eq=False)
class SweepBasis:
    """Fixed interpolation weights of a sweep at parameters ``t`` (n,).

    Attributes
    ----------
    t : (n,) float64
    centre : (n, K) float64
        ``C(t) = centre @ key_centres``.
    tangent : (n, K) float64
        ``C'(t) = tangent @ key_centres`` (metres per unit of t).
    segment : (n,) int64
        Index i of the keys ``(i, i + 1)`` around ``t``.
    frac : (n,) float64
        Fraction of ``t`` between them, in [0, 1].
    radii : (n, 2) float64
        Rest half-axes ``(a(t), b(t))`` (PCHIP of the keys', metres).
    hat : (n, K) float64
        Piecewise-linear hat functions of the keys at ``t`` (rows sum to 1): spreads a
        per-key value (a radius scale) along the sweep.
    """

    t: np.ndarray
    centre: np.ndarray
    tangent: np.ndarray
    segment: np.ndarray
    frac: np.ndarray
    radii: np.ndarray
    hat: np.ndarray

    @classmethod
    def at(cls, sweep: Sweep, t: np.ndarray) -> SweepBasis:
        keys: KeyEllipses = sweep.keys
        p = keys.params
        k = keys.n_keys
        tt = np.clip(np.asarray(t, dtype=np.float64), p[0], p[-1])
        spline = make_interp_spline(p, np.eye(k), k=min(3, k - 1), axis=0)
        seg = np.clip(np.searchsorted(p, tt, side="right") - 1, 0, k - 2)
        frac = np.clip((tt - p[seg]) / (p[seg + 1] - p[seg]), 0.0, 1.0)
        hat = np.zeros((tt.size, k))
        rows = np.arange(tt.size)
        hat[rows, seg] = 1.0 - frac
        hat[rows, seg + 1] += frac
        return cls(
            t=tt,
            centre=np.asarray(spline(tt)),
            tangent=np.asarray(spline.derivative()(tt)),
            segment=seg.astype(np.int64),
            frac=frac,
            radii=sweep.radii(tt),
            hat=hat,
        )

    def centres(self, key_centres: np.ndarray) -> np.ndarray:
        """(..., K, 3) key centres -> (..., n, 3) centres ``C(t)``."""
        return np.einsum("nk,...kc->...nc", self.centre, key_centres)

    def tangents(self, key_centres: np.ndarray) -> np.ndarray:
        """(..., K, 3) key centres -> (..., n, 3) ``C'(t)``."""
        return np.einsum("nk,...kc->...nc", self.tangent, key_centres)

    def quaternions(self, key_quats: np.ndarray) -> np.ndarray:
        """(..., K, 4) hemisphere-aligned key quaternions -> (..., n, 4) unit ``R(t)``."""
        q0 = key_quats[..., self.segment, :]
        q1 = key_quats[..., self.segment + 1, :]
        return nlerp(q0, q1, np.broadcast_to(self.frac, q0.shape[:-1]))
