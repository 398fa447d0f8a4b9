"""The XPBD chain solver of the simulated rope, and the rope's first shape.

See :mod:`skincap.synth.rope` for the method; this module holds one substep
(:class:`ChainSolver`), the polyline the rope starts from (:func:`initial_shape`) and
the interpolation of points along the chain (:func:`points_on_chain`).
Conventions: metres, seconds, Y up.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dgtsv

__all__ = ["ChainSolver", "initial_shape", "points_on_chain", "UP"]

UP = np.array([0.0, 1.0, 0.0])


class ChainSolver:
    """XPBD substep for a particle chain; the state is (x, v), both (P, 3)."""

    def __init__(
        self,
        *,
        n_particles: int,
        segment: float,
        pinned: tuple[int, ...],
        mass: float,
        stretch_stiffness: float,
        bend_stiffness: float,
        gravity: float,
        rope_radius: float,
        floor: float | None,
        floor_friction: float,
        iterations: int,
    ) -> None:
        p = n_particles
        # Lumped masses: half a segment at each end.
        m = np.full(p, mass)
        m[0] = m[-1] = 0.5 * mass
        w = 1.0 / m
        self.pinned = np.array(pinned, dtype=np.int64)
        w[self.pinned] = 0.0
        self.w = w
        self.free = w > 0.0
        self.segment = segment
        self.k_stretch = stretch_stiffness
        self.k_bend = bend_stiffness
        self.gravity = gravity
        self.rope_radius = rope_radius
        self.floor = floor
        self.mu = floor_friction
        self.iterations = iterations
        # Bending springs (k, k+2) are projected together (Jacobi). Each particle feeds
        # at most two of them, so the denominator 2 (w_k + w_k+2) + α̃ can never
        # overshoot, even for an infinitely stiff spring; for the soft springs of a rope
        # α̃ dominates and the step equals the Gauss-Seidel one.
        self.w_b0 = w[:-2, None]
        self.w_b2 = w[2:, None]
        self.w_bsum2 = 2.0 * (w[:-2] + w[2:])
        # Stretch system pieces that do not change.
        self.w_lo = w[:-1]
        self.w_hi = w[1:]
        self.w_mid = w[1:-1]

    def step(
        self,
        x: np.ndarray,
        v: np.ndarray,
        h: float,
        damping: float,
        target: np.ndarray,
        capsules: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    ) -> tuple[np.ndarray, np.ndarray]:
        w = self.w
        v = v * math.exp(-damping * h)
        v[:, 1] -= self.gravity * h  # the pinned particles are overwritten below
        p = x + h * v
        p[self.pinned] = target[: len(self.pinned)]
        predicted_y = p[:, 1].copy()
        alpha_s = 0.0 if math.isinf(self.k_stretch) else 1.0 / (self.k_stretch * h * h)
        bend = self.k_bend > 0.0
        alpha_b = 0.0 if (not bend or math.isinf(self.k_bend)) else 1.0 / (self.k_bend * h * h)
        lam_s = np.zeros(len(w) - 1)
        if bend:  # soft: once per substep
            self._project_bend(p, alpha_b)
        for _ in range(self.iterations):
            if capsules is not None:
                self._push_out(p, capsules)
            if self.floor is not None:
                self._floor(p)
            self._project_stretch(p, lam_s, alpha_s)
        if self.floor is not None:
            self._floor_friction(p, x, predicted_y)
        v = (p - x) / h
        return p, v

    def _project_bend(self, p: np.ndarray, alpha: float) -> None:
        # XPBD springs |x_k+2 - x_k| = 2 l (rest: straight), all at once.
        d = p[2:] - p[:-2]  # (P-2, 3)
        dist = np.sqrt((d * d).sum(axis=1, keepdims=True))
        n = d / np.maximum(dist, 1e-12)
        c = dist[:, 0] - 2.0 * self.segment
        dl = (-c / (self.w_bsum2 + alpha + 1e-300))[:, None] * n
        p[:-2] -= self.w_b0 * dl
        p[2:] += self.w_b2 * dl

    def _project_stretch(self, p: np.ndarray, lam: np.ndarray, alpha: float) -> None:
        # One Newton step of the tridiagonal system (J W Jᵀ + α̃ I) Δλ = -C - α̃ λ.
        d = p[1:] - p[:-1]  # (S, 3)
        dist = np.sqrt((d * d).sum(axis=1))
        n = d / np.maximum(dist, 1e-12)[:, None]
        c = dist - self.segment
        diag = self.w_lo + self.w_hi + alpha
        off = -self.w_mid * (n[:-1] * n[1:]).sum(axis=1)
        rhs = -c - alpha * lam
        _, _, _, dl, info = dgtsv(off, diag, off, rhs)
        if info != 0:  # singular: fall back to a Jacobi step
            dl = rhs / diag
        lam += dl
        corr = dl[:, None] * n
        p[:-1] -= self.w_lo[:, None] * corr
        p[1:] += self.w_hi[:, None] * corr

    def _push_out(self, p: np.ndarray, capsules: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        a, b, r = capsules  # (K, 3), (K, 3), (K,)
        ab = b - a
        ab2 = np.maximum((ab * ab).sum(axis=1), 1e-18)
        ap = p[:, None, :] - a[None]  # (P, K, 3)
        t = np.clip((ap * ab[None]).sum(axis=2) / ab2[None], 0.0, 1.0)
        diff = ap - t[..., None] * ab[None]
        dist = np.sqrt((diff * diff).sum(axis=2))
        depth = r[None] + self.rope_radius - dist  # (P, K)
        hit = (depth > 0.0) & self.free[:, None]
        if not hit.any():
            return
        direction = np.where(
            (dist > 1e-12)[..., None], diff / np.maximum(dist, 1e-12)[..., None], UP
        )
        p += (np.where(hit, depth, 0.0)[..., None] * direction).sum(axis=1)

    def _floor(self, p: np.ndarray) -> None:
        """Lift particles that went below the floor (inside the constraint loop)."""
        level = self.floor + self.rope_radius
        low = (p[:, 1] < level) & self.free
        if low.any():
            p[low, 1] = level

    def _floor_friction(self, p: np.ndarray, x_old: np.ndarray, predicted_y: np.ndarray) -> None:
        """Final floor pass: lift, then Coulomb friction on this substep's sliding.

        The normal displacement is how far the prediction went below the floor; the
        tangential displacement over the substep is cut by ``mu`` times that (static
        friction when it is larger than the slide).
        """
        level = self.floor + self.rope_radius
        hit = np.flatnonzero((np.minimum(p[:, 1], predicted_y) < level + 1e-9) & self.free)
        if hit.size == 0:
            return
        depth = np.maximum(level - predicted_y[hit], 0.0)
        new = p[hit]
        new[:, 1] = np.maximum(new[:, 1], level)
        old = x_old[hit]
        tang = new - old
        tang[:, 1] = 0.0
        slide = np.sqrt((tang * tang).sum(axis=1))
        limit = self.mu * depth
        keep = np.where(slide > limit, 1.0 - limit / np.maximum(slide, 1e-18), 0.0)
        new[:, 0] = old[:, 0] + tang[:, 0] * keep
        new[:, 2] = old[:, 2] + tang[:, 2] * keep
        p[hit] = new


def initial_shape(
    held0: np.ndarray,
    length: float,
    n: int,
    lay: np.ndarray,
    floor: float | None,
    radius: float,
) -> np.ndarray:
    """A polyline of the right length from the hands down to the floor and along it."""
    ground = (floor + radius) if floor is not None else -np.inf
    a = held0[0]
    if held0.shape[0] == 2:
        b = held0[1]
        span = np.linalg.norm(b - a)
        drop_a = a[1] - ground
        drop_b = b[1] - ground
        lie = 0.5 * (length - drop_a - drop_b - span)
        if lie > 0.0:
            fa = a.copy()
            fa[1] = ground
            fb = b.copy()
            fb[1] = ground
            pts = [a, fa, fa + lie * lay, fb + lie * lay, fb, b]
        else:
            # A V hanging straight down (it does not reach the floor).
            half = 0.5 * length
            sag = math.sqrt(max(half * half - 0.25 * span * span, 0.0))
            pts = [a, 0.5 * (a + b) - sag * UP, b]
    else:
        drop = a[1] - ground
        if drop >= length:
            pts = [a, a - length * UP]
        else:
            fa = a.copy()
            fa[1] = ground
            pts = [a, fa, fa + (length - drop) * lay]
    poly = np.array(pts, dtype=np.float64)
    seglen = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seglen)])
    s = np.linspace(0.0, arc[-1], n)
    return np.stack([np.interp(s, arc, poly[:, k]) for k in range(3)], axis=1)


def points_on_chain(particles: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Linear interpolation along the chain at fractional particle indices u (M,)."""
    p = particles.shape[1]
    i = np.clip(np.floor(u).astype(np.int64), 0, p - 2)
    frac = (u - i)[None, :, None]
    return particles[:, i] * (1.0 - frac) + particles[:, i + 1] * frac
