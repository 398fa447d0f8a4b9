"""A second rope simulator: plain position-based dynamics (Müller et al. 2007).

:mod:`skincap.synth.rope` solves the rope with XPBD and an exact tridiagonal stretch
solve, bending springs and smooth synthetic hands; the tracker was tuned on it. This
module simulates the rope with a different model so that a test take does not share
the tracker's assumptions: a chain of equal particles, Verlet integration
(``x' = x + (1 - k Δt)(x - x_prev) + g Δt²``), no bending stiffness at all, and the
distance constraints between neighbours projected by a fixed number of
Gauss-Seidel iterations (red-black order, so each half is one vectorised update) —
the rope stretches a little under load as a PBD rope does. The held end(s) follow the
hand(s) exactly (inverse mass 0), the hand positions interpolated linearly across the
substeps of a frame, so a real hand's jerks reach the rope undamped. An optional floor
stops particles (with sticking friction while in contact).

Before frame 0 the rope settles at the first frame's hand positions, so the take
opens with it hanging: the window in which Porter (2012, §3.4) picks the rope markers.

Conventions: metres, seconds, Y up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from skincap.errors import ValidationError
from skincap.synth.rope import RopeResult

__all__ = ["simulate_rope_pbd"]

_GRAVITY = np.array([0.0, -9.81, 0.0])


def simulate_rope_pbd(
    hands: np.ndarray,
    rate: float,
    *,
    mode: Literal["jump", "whip"] = "whip",
    length: float = 1.1,
    n_markers: int = 12,
    particles_per_marker: int = 2,
    substep_seconds: float = 1.0 / 960.0,
    iterations: int = 5,
    damping: float = 0.5,
    floor: float | None = None,
    lay_direction: np.ndarray | None = None,
    arm_gap: float | None = None,
    settle_seconds: float = 1.0,
) -> RopeResult:
    """Simulate a rope held by one hand (whip) or two (jump) with PBD; place its markers.

    Parameters
    ----------
    hands : (T, 3) or (T, 2, 3) float, metres
        The hand positions per frame, finite. ``whip`` holds the rope's first end in
        ``hands[:, 0]`` (or the (T, 3) array); ``jump`` holds its first end in
        ``hands[:, 0]`` and its last in ``hands[:, 1]``.
    rate : float
        Frame rate, Hz.
    mode : {"whip", "jump"}
        One end held and one hanging free, or both ends held.
    length : float
        Rest length of the rope, metres.
    n_markers : int
        Tape markers (>= 3), evenly spaced at ``length / n_markers`` (whip: the last
        one at the free tip, the first one spacing from the hand) or
        ``length / (n_markers + 1)`` (jump: none at the hands).
    particles_per_marker : int
        Chain particles between consecutive markers (>= 1); markers sit on particles.
    substep_seconds : float
        Longest integration step, seconds; each frame is cut into
        ``ceil(1 / (rate * substep_seconds))`` equal substeps.
    iterations : int
        Gauss-Seidel sweeps of the distance constraints per substep.
    damping : float
        Velocity damping rate ``k``, 1/s.
    floor : float or None
        Height of the floor (y), metres; None for none.
    lay_direction : (3,) float, optional
        Horizontal direction in which the part of the starting rope that would reach
        below the floor is laid along it (default +Z).
    arm_gap : float, optional
        ``jump``: the two arms of the part laid on the floor lie at least this far
        apart side by side (metres; default three marker spacings), as a performer
        lays a rope out in an open loop. Hands held apart across ``lay_direction`` by
        that much or more keep their own separation; hands above one another (a rope
        held at a foot and a shin) would otherwise lay both arms along one line, the
        rope doubled on itself with markers millimetres apart.
    settle_seconds : float
        Time the rope hangs at the first frame's hands before frame 0, seconds; it
        hangs on (up to ten times as long) until no particle moves 5 µm in a frame,
        so frame 0 opens with the rope at rest.

    Returns
    -------
    RopeResult
        ``particles`` (T, P, 3), ``markers`` (T, n_markers, 3), labels
        ``rope_00``…, ``marker_param`` (arc length of each marker from the first end,
        metres); ``meta`` has ``simulator`` ("pbd"), ``max_length_error`` (largest
        relative stretch of the chain over the take) and ``max_link_stretch``.
    """
    h = _checked_hands(hands, mode)
    _check_settings(rate, length, substep_seconds, n_markers, particles_per_marker, iterations)
    if damping < 0 or settle_seconds < 0:
        raise ValidationError("damping and settle_seconds must not be negative")
    n_markers, k = int(n_markers), int(particles_per_marker)
    held = h[:, 0] if mode == "whip" else h  # (T, 3) or (T, 2, 3)

    # particles: whip 0 (hand) … k·M (tip); jump 0 (hand) … k·(M+1) (other hand)
    n_links = k * n_markers if mode == "whip" else k * (n_markers + 1)
    rest = length / n_links  # metres between neighbouring particles
    n_particles = n_links + 1
    marker_particle = k * np.arange(1, n_markers + 1)
    inv_mass = np.ones(n_particles)
    inv_mass[0] = 0.0
    if mode == "jump":
        inv_mass[-1] = 0.0
    # long-range attachments: no particle farther from a held end than the rope between
    held_ends = [0] if mode == "whip" else [0, n_particles - 1]
    arc = rest * np.arange(n_particles)
    substeps = max(1, math.ceil(1.0 / (rate * substep_seconds)))
    dt = 1.0 / (rate * substeps)

    x = _hanging_start(held[0], mode, n_particles, rest)
    if floor is not None:
        if arm_gap is None:
            arm_gap = 3.0 * length / (n_markers + 1)
        if not (math.isfinite(arm_gap) and arm_gap >= 0):
            raise ValidationError(f"arm_gap: expected a distance >= 0, got {arm_gap!r}")
        gap = arm_gap if mode == "jump" else 0.0
        if _across(x, lay_direction) < gap:
            # the loop is laid by arc length, so its start must keep the rest spacing
            x = _arms_start(held[0], n_particles, rest)
        x = _laid_on_floor(x, floor, lay_direction, gap)
    chain = _Chain(
        x=x,
        x_prev=x.copy(),
        mode=mode,
        halves=_link_halves(inv_mass),
        rest=rest,
        iterations=int(iterations),
        held_ends=held_ends,
        reach=[arc, arc[::-1]][: len(held_ends)],
        floor=floor,
        dt=dt,
    )
    settle_steps = int(round(settle_seconds * rate * substeps))
    out = _play(chain, held, substeps, settle_steps, keep=1.0 - min(damping * dt, 1.0))

    links = np.linalg.norm(np.diff(out, axis=1), axis=2)  # (T, P - 1)
    meta = {
        "simulator": "pbd",
        "mode": mode,
        "length": float(length),
        "substeps": substeps,
        "iterations": int(iterations),
        "max_length_error": float(abs(links.sum(axis=1) / length - 1.0).max()),
        "max_link_stretch": float(links.max() / rest - 1.0),
    }
    labels = [f"rope_{i:02d}" for i in range(n_markers)]
    return RopeResult(
        out, out[:, marker_particle].copy(), labels, marker_particle * rest, float(rate), meta
    )


def _checked_hands(hands: np.ndarray, mode: str) -> np.ndarray:
    """``hands`` as (T, H, 3) float64 metres, refused unless ``mode`` can hold them."""
    if mode not in ("whip", "jump"):
        raise ValidationError(f"mode: expected 'whip' or 'jump', got {mode!r}")
    h = np.asarray(hands, dtype=np.float64)
    if h.ndim == 2:
        h = h[:, None, :]
    if h.ndim != 3 or h.shape[-1] != 3 or h.shape[0] < 1:
        raise ValidationError(f"hands: expected (T, 3) or (T, 2, 3), got shape {np.shape(hands)}")
    if mode == "jump" and h.shape[1] != 2:
        raise ValidationError(f"hands: jump needs both hands (T, 2, 3), got {h.shape}")
    if not np.isfinite(h).all():
        raise ValidationError("hands: must be finite (fill the hands' gaps first)")
    return h


def _check_settings(
    rate: float,
    length: float,
    substep_seconds: float,
    n_markers: int,
    particles_per_marker: int,
    iterations: int,
) -> None:
    """Refuse a non-positive rate, length or substep and too few markers or sweeps."""
    for name, value in (("rate", rate), ("length", length), ("substep_seconds", substep_seconds)):
        if not (math.isfinite(value) and value > 0):
            raise ValidationError(f"{name}: expected a positive number, got {value!r}")
    if int(n_markers) < 3 or int(particles_per_marker) < 1 or int(iterations) < 1:
        raise ValidationError("n_markers >= 3, particles_per_marker >= 1 and iterations >= 1")


@dataclass
class _Chain:
    """The PBD particle chain: its state, advanced in place by :meth:`substep`."""

    x: np.ndarray  # (P, 3) metres, the particles now
    x_prev: np.ndarray  # (P, 3) metres, one substep ago
    mode: str  # "whip": particle 0 held; "jump": particles 0 and P - 1 held
    halves: list[tuple[slice, slice, np.ndarray, np.ndarray]]  # from _link_halves
    rest: float  # metres between neighbouring particles
    iterations: int  # Gauss-Seidel sweeps per substep
    held_ends: list[int]  # the held particles
    reach: list[np.ndarray]  # (P,) metres of rope from each held end
    floor: float | None  # floor height (y), metres
    dt: float  # substep, seconds

    def substep(self, target: np.ndarray, keep: float) -> None:
        """Verlet step with velocity factor ``keep``, the held ends at ``target``, then
        the distance, long-range and floor constraints."""
        velocity = (self.x - self.x_prev) * keep
        self.x_prev = self.x
        x = self.x = self.x + velocity + _GRAVITY * self.dt * self.dt
        if self.mode == "whip":
            x[0] = target
        else:
            x[0], x[-1] = target[0], target[1]
        _project_distances(x, self.halves, self.rest, self.iterations)
        _attach_long_range(x, self.held_ends, self.reach)
        if self.floor is not None:
            below = x[:, 1] < self.floor
            if below.any():
                # sticking friction: a particle on the floor keeps its old x, z
                x[below, 1] = self.floor
                x[below, 0] = self.x_prev[below, 0]
                x[below, 2] = self.x_prev[below, 2]


#: Damping rate (1/s) while the rope settles before frame 0: about critical for a
#: rope pendulum of a metre or two (2 sqrt(g / L) = 4-6 /s). A heavier one (20 /s)
#: caps the fall at g / k = 0.5 m/s and leaves a rope laid out far from its rest
#: shape still falling through the still window.
_SETTLE_DAMPING = 6.0
#: The rope is settled when no particle moves more than this in a frame (metres) ...
_SETTLED_MOVE = 5e-6
#: ... or after this many times ``settle_seconds`` (a rope that never comes to rest).
_SETTLE_LIMIT = 10


def _settle(chain: _Chain, hands: np.ndarray, substeps: int, settle_steps: int) -> None:
    """Let the chain come to rest at the hands ``hands`` (3,) or (2, 3), in place.

    At least ``settle_steps`` substeps, then frame by frame until the largest move
    of a particle over a frame is below ``_SETTLED_MOVE`` (at most ``_SETTLE_LIMIT``
    times as long): the take's still window must show the rope still, whatever shape
    it was laid out in. The velocity is zeroed at the end.
    """
    keep = 1.0 - min(_SETTLE_DAMPING * chain.dt, 1.0)
    for _ in range(settle_steps):
        chain.substep(hands, keep)
    for _ in range(_SETTLE_LIMIT * max(settle_steps, substeps) // substeps):
        before = chain.x.copy()
        for _ in range(substeps):
            chain.substep(hands, keep)
        if np.abs(chain.x - before).max() < _SETTLED_MOVE:
            break
    chain.x_prev = chain.x.copy()


def _play(
    chain: _Chain, held: np.ndarray, substeps: int, settle_steps: int, *, keep: float
) -> np.ndarray:
    """(T, P, 3) metres: the chain settled at the first frame's hands
    (:func:`_settle`), then driven through the take, the hands ``held`` (T, 3) or
    (T, 2, 3) interpolated linearly within each frame's ``substeps``."""
    _settle(chain, held[0], substeps, settle_steps)
    out = np.zeros((held.shape[0], *chain.x.shape))
    out[0] = chain.x
    for t in range(1, held.shape[0]):
        for s in range(1, substeps + 1):
            w = s / substeps
            chain.substep((1.0 - w) * held[t - 1] + w * held[t], keep)
        out[t] = chain.x
    return out


def _hanging_start(held: np.ndarray, mode: str, n: int, rest: float) -> np.ndarray:
    """(P, 3) initial chain: straight down from the hand (whip), a V between the hands (jump)."""
    if mode == "whip":
        return held[None, :] + np.outer(np.arange(n) * rest, [0.0, -1.0, 0.0])
    a, b = held[0], held[1]
    half = (n - 1) * rest / 2.0
    span = np.linalg.norm(b - a)
    depth = math.sqrt(max(half * half - span * span / 4.0, 0.0))
    u = np.linspace(0.0, 1.0, n)[:, None]
    sag = depth * (1.0 - np.abs(2.0 * u - 1.0))
    return a + u * (b - a) - sag * np.array([0.0, 1.0, 0.0])


def _arms_start(held: np.ndarray, n: int, rest: float) -> np.ndarray:
    """(P, 3) a chain held at ``held`` (2, 3) metres hanging in two straight arms to a
    low point below the hands' midpoint, ``rest`` metres between neighbours along it.

    Unlike the V of :func:`_hanging_start` (whose arms share the particles equally, so
    their links stretch or shrink by the hands' height difference over P - 1), the
    hand held higher gets the longer arm; the chain lies straight between the hands if
    it is too short to sag below the lower one.
    """
    a, b = held[0], held[1]
    total = (n - 1) * rest
    low = 0.5 * (a + b)
    half_across = 0.5 * math.hypot(b[0] - a[0], b[2] - a[2])

    def arms(y: float) -> float:  # length of the two arms to a low point at height y
        return math.hypot(half_across, a[1] - y) + math.hypot(half_across, b[1] - y)

    top = min(a[1], b[1])
    if arms(top) >= total:
        return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    bottom = top - total
    for _ in range(100):  # bisection: the arms lengthen as the low point drops
        mid = 0.5 * (top + bottom)
        top, bottom = (mid, bottom) if arms(mid) < total else (top, mid)
    low[1] = 0.5 * (top + bottom)
    arm_a = float(np.linalg.norm(low - a))
    arc = rest * np.arange(n)[:, None]  # (P, 1) metres from hand a
    on_a = a + (low - a) * (arc / max(arm_a, 1e-12))
    on_b = low + (b - low) * ((arc - arm_a) / max(total - arm_a, 1e-12))
    return np.where(arc <= arm_a, on_a, on_b)


def _link_halves(inv_mass: np.ndarray) -> list[tuple[slice, slice, np.ndarray, np.ndarray]]:
    """The even and the odd links as strided views, with each end's share of a correction."""
    n = inv_mass.shape[0]
    halves = []
    for first in (0, 1):
        a, b = slice(first, n - 1, 2), slice(first + 1, n, 2)
        wa, wb = inv_mass[a], inv_mass[b]
        w = wa + wb
        # share of the correction each end takes (0 for a pinned end, 0/0 -> 0)
        share_a = np.divide(wa, w, out=np.zeros_like(w), where=w > 0)[:, None]
        share_b = np.divide(wb, w, out=np.zeros_like(w), where=w > 0)[:, None]
        halves.append((a, b, share_a, share_b))
    return halves


def _lay_and_side(direction: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal unit lay direction (default +Z) and the horizontal unit across it."""
    lay = np.array([0.0, 0.0, 1.0]) if direction is None else np.asarray(direction, float)
    lay = lay * np.array([1.0, 0.0, 1.0])
    norm = np.linalg.norm(lay)
    lay = np.array([0.0, 0.0, 1.0]) if norm < 1e-9 else lay / norm
    return lay, np.array([lay[2], 0.0, -lay[0]])


def _across(x: np.ndarray, direction: np.ndarray | None) -> float:
    """Metres between the chain's ends ``x[0]`` and ``x[-1]`` across the lay direction."""
    return abs(float((x[0] - x[-1]) @ _lay_and_side(direction)[1]))


def _laid_on_floor(
    x: np.ndarray, floor: float, direction: np.ndarray | None, arm_gap: float = 0.0
) -> np.ndarray:
    """(P, 3) the chain with what reaches below ``floor`` laid along it, arc length kept.

    ``x`` (P, 3) metres is the hanging start; a particle ``d`` metres below the floor
    is laid ``d`` along a path on the floor. With ``arm_gap`` (metres, for a chain
    held at both ends, its start :func:`_arms_start`) the two arms' paths are spread
    sideways until they lie ``arm_gap`` apart: each turns out on a quarter circle,
    runs along the lay direction and turns back in on a quarter circle to meet the
    other at the deepest particle (an open loop with round ends).
    """
    lay, side = _lay_and_side(direction)
    depth = np.maximum(floor - x[:, 1], 0.0)  # (P,) metres below the floor
    across = float((x[0] - x[-1]) @ side)  # the ends' own separation across the lay
    if across < 0:
        side, across = -side, -across
    deepest = float(depth.max())
    radius = min(0.5 * max(arm_gap - across, 0.0), deepest / math.pi)
    if radius <= 0:
        laid = x + depth[:, None] * lay
    else:
        # arc-length parametrised: quarter circle out, straight, quarter circle in
        turn = 0.5 * math.pi * radius
        out = np.minimum(depth, turn) / radius  # angle turned out, rad
        back = np.maximum(depth - (deepest - turn), 0.0) / radius  # angle turned in
        straight = np.clip(depth - turn, 0.0, deepest - 2.0 * turn)
        lateral = radius * (1.0 - np.cos(out)) - radius * (1.0 - np.cos(back))
        forward = radius * np.sin(out) + straight + radius * np.sin(back)
        arm = np.where(np.arange(x.shape[0]) < int(np.argmax(depth)), 1.0, -1.0)
        laid = x + forward[:, None] * lay + (arm * lateral)[:, None] * side
    laid[:, 1] = np.maximum(x[:, 1], floor)
    return laid


def _attach_long_range(x: np.ndarray, ends: list[int], reach: list[np.ndarray]) -> None:
    """Long-range attachments (Kim, Chentanez & Müller 2012), in place.

    A particle farther from a held end than the rest arc length between them is moved
    straight back onto that sphere: one unilateral constraint per particle and held
    end, which keeps a PBD chain from stretching under a hard-accelerating hand
    without more iterations.
    """
    for end, limit in zip(ends, reach, strict=True):
        d = x - x[end]  # (P, 3)
        dist = np.sqrt(np.einsum("ij,ij->i", d, d))
        over = dist > limit
        if over.any():
            x[over] = x[end] + d[over] * (limit[over] / dist[over])[:, None]


def _project_distances(
    x: np.ndarray,
    halves: list[tuple[slice, slice, np.ndarray, np.ndarray]],
    rest: float,
    sweeps: int,
) -> None:
    """Gauss-Seidel on ``|x[i+1] - x[i]| = rest``, even links then odd links, in place.

    Each half touches every particle at most once, so it is one vectorised update on
    strided views (:func:`_link_halves`).
    """
    for _ in range(sweeps):
        for a, b, share_a, share_b in halves:
            d = x[b] - x[a]  # (L, 3)
            dist = np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
            corr = d * ((dist - rest) / np.maximum(dist, 1e-12))
            x[a] += share_a * corr
            x[b] -= share_b * corr
