"""Volume preservation of a moving sweep (Hyun et al. §4.4), for many frames at once.

The swept volume ``I = ∫ π a(t) b(t) <N(t), C'(t)> dt`` (§3.1) is integrated by
Gauss-Legendre quadrature at fixed parameters, so for moving keys it is a sum over
fixed nodes. The half-axes are scaled by ``1 + h(t) · beta``, ``h`` the keys'
piecewise-linear hat functions and ``beta`` (K,) one scale change per key (the paper's
``alpha_i``, ``beta_i``; a and b of a key scale together), and ``beta`` is moved by the
paper's step

    Δbeta = (I0 - I) ∇I / |∇I|²

a few times: first on the interior joints' keys only (the elbow or knee, where a bend
changes the volume most), then on all keys, as the paper describes. ``I`` is quadratic
in ``beta``, so three or four steps bring it to ``I0`` to a small fraction of a
percent; scales are kept at 0.2 or more.
"""

from __future__ import annotations

import numpy as np

from skincap.deform.sweep.basis import SweepBasis, align_hemispheres
from skincap.deform.sweep.fit import LimbSweep
from skincap.geometry.rotations import quat_apply
from skincap.geometry.sweep import Sweep

__all__ = ["LimbVolume"]

#: Smallest radius scale the volume step may set.
MIN_SCALE = 0.2


class LimbVolume:
    """Swept volume of a limb's sweep and the radius scales that keep it at the rest value.

    Parameters
    ----------
    limb : LimbSweep
    intervals : int, default 32
        Quadrature sub-intervals (4 Gauss-Legendre nodes each).
    joint_steps, all_steps : int, default 2, 2
        Steps on the interior joints' keys, then on every key.
    """

    def __init__(
        self, limb: LimbSweep, *, intervals: int = 32, joint_steps: int = 2, all_steps: int = 2
    ) -> None:
        sweep = Sweep(limb.keys, orientation="nlerp")
        lo, hi = sweep.t_range
        edges = np.linspace(lo, hi, int(intervals) + 1)
        x, w = np.polynomial.legendre.leggauss(4)
        half = 0.5 * np.diff(edges)
        t = (0.5 * (edges[:-1] + edges[1:])[:, None] + half[:, None] * x[None]).ravel()
        self.basis = SweepBasis.at(sweep, t)
        self.weights = (half[:, None] * w[None]).ravel()  # (Q,)
        ab = self.basis.radii
        self._area = np.pi * ab[:, 0] * ab[:, 1] * self.weights  # (Q,) π a b dt
        interior = limb.is_joint.copy()
        interior[[0, -1]] = False
        self._masks = [interior] * int(joint_steps if interior.any() else 0) + [
            np.ones_like(interior)
        ] * int(all_steps)
        self.rest = float(self.volume(limb.keys.centres, align_hemispheres(limb.keys.rotations)))

    def _integrand(self, centres: np.ndarray, quats: np.ndarray) -> np.ndarray:
        """(..., Q) ``π a b <N, C'> w`` at the nodes for (..., K, 3) centres, (..., K, 4) quats."""
        n = quat_apply(self.basis.quaternions(quats), np.array([0.0, 0.0, 1.0]))
        g = np.einsum("...qc,...qc->...q", n, self.basis.tangents(centres))
        return self._area * g

    def volume(self, centres: np.ndarray, quats: np.ndarray) -> np.ndarray:
        """(...,) swept volume (m³) of key ellipses at their rest radii."""
        return self._integrand(centres, quats).sum(axis=-1)

    def scales(self, centres: np.ndarray, quats: np.ndarray) -> np.ndarray:
        """Per-key radius scale changes ``beta`` (..., K) that restore the rest volume.

        Parameters
        ----------
        centres : (..., K, 3) float, metres
        quats : (..., K, 4) float
            Posed keys, hemisphere-aligned.

        Returns
        -------
        (..., K) float64
            The radii of key k are scaled by ``1 + beta_k`` (>= :data:`MIN_SCALE`).
        """
        c = self._integrand(centres, quats)  # (..., Q)
        hat = self.basis.hat  # (Q, K)
        beta = np.zeros(c.shape[:-1] + (hat.shape[1],))
        for mask in self._masks:  # a few steps, each over all frames at once
            s = 1.0 + beta @ hat.T  # (..., Q)
            volume = np.sum(c * s * s, axis=-1)
            grad = 2.0 * (c * s) @ hat * mask  # (..., K)
            norm2 = np.sum(grad * grad, axis=-1)
            gap = self.rest - volume
            ok = (norm2 > 0) & (np.abs(gap) > 1e-12 * abs(self.rest))
            step = np.where(ok, gap / np.where(ok, norm2, 1.0), 0.0)
            beta = np.maximum(beta + step[..., None] * grad, MIN_SCALE - 1.0)
        return beta
