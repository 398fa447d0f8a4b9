"""A simulated rope wrapped with reflective tape (Porter 2012, §3.2).

The rope is a chain of particles solved with extended position-based dynamics (XPBD;
Müller et al. 2007, Macklin et al. 2016) in small substeps: gravity and velocity damping
predict, then bending springs between next-but-one particles, capsule/sphere colliders and
the floor, and the stretch constraints between neighbours are projected. The stretch
constraints of a chain couple only neighbours, so their linearised system
``J W Jᵀ Δλ = -C - α̃λ`` is tridiagonal and is solved exactly (a direct, O(P) LAPACK
``gtsv`` solve per iteration, the "fast projection" of Goldenthal et al. 2007): the rope
keeps its length to well under a per cent even when it is whipped. The soft bending
springs are projected once per substep, all at once (Jacobi, with a denominator that
cannot overshoot).

Held ends are pinned to the hand positions, interpolated linearly between frames within
the substeps. Before frame 0 the rope is settled at the first frame's hand positions so
that the take opens with a rope hanging still — Porter's initialisation window, in which
the rope markers are picked out by hand.

Conventions: metres, seconds, Y up, right-handed; the body faces +Z, its left is +X.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.linalg.lapack import dgtsv

from skincap.errors import SkincapError, SkincapWarning, ValidationError
from skincap.types import MarkerSet

__all__ = [
    "RopeResult",
    "simulate_rope",
    "jump_rope_hands",
    "whip_hand",
    "rope_occluders",
]

_UP = np.array([0.0, 1.0, 0.0])


@dataclass(eq=False)
class RopeResult:
    """The simulated rope and its tape markers.

    Attributes
    ----------
    particles : (T, P, 3) float64, metres
        Particle positions of the chain, first particle = first end (the first hand).
        Never NaN.
    markers : (T, M, 3) float64, metres
        Tape marker centres on the rope axis, interpolated along the chain at the arc
        lengths ``marker_param``. Never NaN.
    labels : list of M str
        ``rope_00``, ``rope_01``… ordered along the rope from the first end.
    marker_param : (M,) float64, metres
        Rest arc length of each marker measured from the first end; evenly spaced by
        ``marker_spacing`` and centred on the rope.
    rate : float, Hz
        Frame rate of ``particles`` and ``markers``.
    meta : dict
        ``mode``, ``length``, ``n_particles``, ``segment_length``, ``substeps``,
        ``iterations``, ``hang_frames``, ``rope_radius``, ``marker_spacing``, ``seed``,
        ``max_length_error`` (largest relative deviation of the chain length from the
        rest length over all frames), ``max_hang_speed`` (largest particle speed in the
        hanging window, m/s).
    """

    particles: np.ndarray
    markers: np.ndarray
    labels: list[str]
    marker_param: np.ndarray
    rate: float
    meta: dict[str, Any] = field(default_factory=dict)

    def chain_length(self) -> np.ndarray:
        """Sum of segment lengths per frame, (T,) float64, metres."""
        return np.linalg.norm(np.diff(self.particles, axis=1), axis=2).sum(axis=1)

    def marker_set(self) -> MarkerSet:
        """The clean labelled rope markers as a :class:`~skincap.types.MarkerSet`."""
        meta = {"source": "skincap.synth.rope", "mode": self.meta.get("mode")}
        return MarkerSet(self.markers.copy(), list(self.labels), self.rate, meta=meta)


# ----------------------------------------------------------------------------- hands
def jump_rope_hands(
    n_frames: int,
    rate: float,
    *,
    height: float = 1.75,
    shoulder_width: float = 0.40,
    frequency: float = 1.8,
    hang_seconds: float = 0.5,
    seed: int = 0,
) -> np.ndarray:
    """Hand paths of a person turning a jump rope (forward, over the head).

    The hands rest by the hips for ``hang_seconds`` (the rope hangs still, lying behind
    the heels), then wind the rope up with a slow, wide arm circle (0.45 m radius, 0.65
    turns per second, the hands lifting to chest height first) that brings it
    over the head; within 2.5 s the circles shrink to the
    0.15 m wrist circles of steady skipping at ``frequency`` turns per second. The hands
    bob with the hops, once per turn. Circles lie in the body's sagittal (YZ) plane and
    turn forward (over the head from back to front, i.e. positively about +X).

    Parameters
    ----------
    n_frames : int
        Number of frames T (>= 1).
    rate : float
        Frame rate, Hz.
    height : float
        Body height, metres; the hands turn at 0.53 × height (hip level).
    shoulder_width : float
        Biacromial width, metres; the hands are 1.7 × that apart (a hand span
        from the hips).
    frequency : float
        Turns per second in steady skipping.
    hang_seconds : float
        Leading window in which the hands are exactly still, seconds.
    seed : int
        Seeds the slight irregularity of a real person (turn rate, circle size, bob).

    Returns
    -------
    (T, 2, 3) float64, metres
        Left hand (+X) then right hand (-X), per frame.
    """
    n_frames = _check_count("n_frames", n_frames, minimum=1)
    rate = _check_positive("rate", rate)
    height = _check_positive("height", height)
    shoulder_width = _check_positive("shoulder_width", shoulder_width)
    frequency = _check_positive("frequency", frequency)
    hang_seconds = _check_nonnegative("hang_seconds", hang_seconds)
    rng = np.random.default_rng(seed)

    t = np.arange(n_frames, dtype=np.float64) / rate
    tau = np.clip(t - hang_seconds, 0.0, None)  # time since the hands started moving
    # Wind-up: one slow, wide arm circle (0.65 turns/s, 0.45 m) brings the rope from
    # behind the heels over the head; within 2.5 s the circles shrink to 0.15 m wrist
    # circles at the skipping rate. Small fast circles alone cannot start a resting
    # rope turning (they drive it far above its pendulum frequency).
    wind = 2.5
    ease = _smoothstep(tau / 0.4)  # the circles grow from nothing: no jerk at the start
    decay = _smoothstep(tau / wind)
    # Slowly varying irregularity: a few random harmonics.
    wobble_f = rng.uniform(0.15, 0.45, size=3)
    wobble_p = rng.uniform(0.0, 2.0 * np.pi, size=3)
    wobble = np.sin(2.0 * np.pi * wobble_f[None] * tau[:, None] + wobble_p[None])  # (T, 3)

    f0 = min(0.65, frequency)
    freq = (f0 + (frequency - f0) * decay) * (1.0 + 0.03 * wobble[:, 0] * decay)
    # Phase: the integral of the turn rate, held at zero in the hanging window.
    phase = np.concatenate([[0.0], np.cumsum(0.5 * (freq[1:] + freq[:-1]) / rate)])
    phase = 2.0 * np.pi * np.where(tau > 0.0, phase - phase[np.argmax(tau > 0.0) - 1], 0.0)
    radius = (0.45 + (0.15 - 0.45) * decay) * ease * (1.0 + 0.08 * wobble[:, 1] * decay)
    # The circle's centre sits up and forward of the resting hand (along 45°) by the
    # radius and the hand enters it up and back (angle -45°): the first move lifts the
    # hands straight up to chest height, pulling the rope up from behind the heels.
    rest_angle = np.deg2rad(225.0)
    angle = np.deg2rad(-45.0) + phase
    # Hops: the body (and the hands with it) is highest as the rope passes under the
    # feet, which happens when the hands are at about 240° (they lead the rope by ~50°
    # in steady skipping with these circles).
    bob = 0.03 * decay * np.cos(angle - np.deg2rad(240.0)) * (1.0 + 0.1 * wobble[:, 2])
    out = np.empty((n_frames, 2, 3))
    half = 0.85 * shoulder_width
    for side, x in enumerate((half, -half)):
        out[:, side, 0] = x
        out[:, side, 1] = 0.53 * height + bob + radius * (np.cos(angle) - np.cos(rest_angle))
        out[:, side, 2] = 0.12 + radius * (np.sin(angle) - np.sin(rest_angle))
    return out


def whip_hand(
    n_frames: int,
    rate: float,
    *,
    height: float = 1.75,
    frequency: float = 1.0,
    hang_seconds: float = 0.5,
    seed: int = 0,
) -> np.ndarray:
    """Path of one hand cracking a whip: overhead figure-of-eight swings in front.

    Parameters
    ----------
    n_frames : int
        Number of frames T (>= 1).
    rate : float
        Frame rate, Hz.
    height : float
        Body height, metres; the hand swings around shoulder height (0.82 × height).
    frequency : float
        Swings per second.
    hang_seconds : float
        Leading window in which the hand is exactly still, seconds.
    seed : int
        Seeds the irregularity of the swings.

    Returns
    -------
    (T, 3) float64, metres
        The right hand's position per frame.
    """
    n_frames = _check_count("n_frames", n_frames, minimum=1)
    rate = _check_positive("rate", rate)
    height = _check_positive("height", height)
    frequency = _check_positive("frequency", frequency)
    hang_seconds = _check_nonnegative("hang_seconds", hang_seconds)
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames, dtype=np.float64) / rate
    tau = np.clip(t - hang_seconds, 0.0, None)
    ease = _smoothstep(tau / 0.4)
    f = frequency * (1.0 + 0.05 * np.sin(2.0 * np.pi * rng.uniform(0.1, 0.3) * tau))
    phase = 2.0 * np.pi * np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) / rate)])
    amp = 0.6 * ease
    out = np.empty((n_frames, 3))
    out[:, 0] = -0.25 + amp * 0.6 * np.sin(phase)
    out[:, 1] = 0.82 * height + amp * 0.5 * (1.0 - np.cos(phase)) * 0.8
    out[:, 2] = 0.25 + amp * 0.5 * np.sin(2.0 * phase)
    return out


# -------------------------------------------------------------------------- occluders
def rope_occluders(
    particles: np.ndarray, radius: float = 0.01
) -> tuple[np.ndarray, np.ndarray, float]:
    """The rope as capsules for a camera model's occlusion test.

    Parameters
    ----------
    particles : (T, P, 3) float, metres
        Rope particle positions (``RopeResult.particles``). NaN is passed through.
    radius : float
        Capsule radius, metres (the rope's visual thickness).

    Returns
    -------
    a, b : (T, P-1, 3) float64, metres
        Segment end points, one capsule per chain segment.
    radius : float
        The capsule radius, metres.
    """
    p = np.asarray(particles, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[1] < 2:
        raise ValidationError(f"particles: expected shape (T, P>=2, 3), got {p.shape}")
    radius = _check_positive("radius", radius)
    return p[:, :-1].copy(), p[:, 1:].copy(), radius


# ------------------------------------------------------------------------- simulation
def simulate_rope(
    hands: np.ndarray,
    rate: float,
    *,
    mode: Literal["jump", "whip"] = "jump",
    length: float = 2.8,
    n_particles: int | None = None,
    marker_spacing: float = 0.12,
    hang_seconds: float = 0.5,
    stretch_stiffness: float = 1.0e6,
    bend_stiffness: float = 40.0,
    damping: float = 0.3,
    gravity: float = 9.81,
    substeps: int = 8,
    iterations: int = 2,
    linear_density: float = 0.06,
    rope_radius: float = 0.004,
    floor: float | None = 0.0,
    floor_friction: float = 0.6,
    colliders: Sequence[tuple[Any, ...]] | None = None,
    settle_seconds: float = 3.0,
    lay_direction: Sequence[float] | np.ndarray | None = None,
    seed: int = 0,
    progress: Callable[[float], object] | None = None,
) -> RopeResult:
    """Simulate a rope held in the hands and place tape markers along it.

    Parameters
    ----------
    hands : (T, 2, 3) or (T, 3) float, metres
        Hand positions per frame; finite. ``mode="jump"`` needs both hands (the rope's
        first end in ``hands[:, 0]``, its last in ``hands[:, 1]``) and their distance
        must stay below ``length``. ``mode="whip"`` holds the first end in the first hand
        (``hands[:, 0]`` or the (T, 3) array); the other end is free.
    rate : float
        Frame rate, Hz (120 for the capture rigs of the papers).
    mode : {"jump", "whip"}
        Both ends held (a skipping rope turned around the body) or one end held.
    length : float
        Rest length of the rope, metres (2.5–3 for a skipping rope).
    n_particles : int, optional
        Chain particles P (>= 3); default one per ~4.5 cm (64 for 2.8 m).
    marker_spacing : float
        Arc length between tape markers, metres (0.10–0.15 in practice). The
        ``floor(length / marker_spacing)`` markers are centred on the rope.
    hang_seconds : float
        Length of the hanging window at the start, seconds. The caller keeps the hands
        still there; a :class:`~skincap.errors.SkincapWarning` is issued if they move more
        than 5 mm. ``meta["max_hang_speed"]`` reports the largest particle speed in it.
    stretch_stiffness : float
        Spring constant of each chain segment, N/m (XPBD compliance = 1 / stiffness;
        ``inf`` makes the rope inextensible).
    bend_stiffness : float
        Spring constant between next-but-one particles, N/m (resistance to bending;
        0 gives a limp chain).
    damping : float
        Velocity damping rate, 1/s (air drag; velocities decay as ``exp(-damping t)``).
    gravity : float
        Gravitational acceleration along -Y, m/s².
    substeps : int
        Solver substeps per frame.
    iterations : int
        Constraint iterations per substep.
    linear_density : float
        Rope mass per metre, kg/m (sets the particle masses the springs act on).
    rope_radius : float
        Rope radius for contacts, metres: particles stay this far from the floor and the
        colliders.
    floor : float or None
        Floor height (y), metres; None for no floor.
    floor_friction : float
        Coulomb friction coefficient of the floor (>= 0).
    colliders : sequence of tuples, optional
        Bodies the rope is pushed out of: capsules ``(a, b, radius)`` and spheres
        ``(centre, radius)``, with ``a``, ``b``, ``centre`` of shape (T, 3) or (3,)
        (metres) and ``radius`` in metres; e.g. the torso and legs. Interpolated
        between frames like the hands.
    settle_seconds : float
        Simulated time before frame 0, with the hands at their first positions and
        strong damping, so the take starts with the rope at rest.
    lay_direction : (3,) float, optional
        Horizontal direction in which the rope's slack initially lies on the floor
        before settling; default -Z (behind the body) for "jump", +Z for "whip".
    seed : int
        Seeds a millimetre-scale perturbation of the initial shape.
    progress : callable, optional
        Called with the fraction of frames done (0..1).

    Returns
    -------
    RopeResult
        ``particles`` (T, P, 3), ``markers`` (T, M, 3), ``labels``, ``marker_param``
        (M,), ``rate`` and ``meta``; all finite.

    Raises
    ------
    ValidationError
        On a bad argument: wrong shape, NaN/inf hands, hands further apart than the
        rope is long, non-positive sizes, an unknown mode.

    Notes
    -----
    The ends are pinned in position only (no handle torque), so what turns the rope is
    the hands' own circling. A resting rope needs a wind-up — one slow, wide arm circle
    (about 0.45 m radius at 0.65 turns/s) — and steady skipping needs hand circles of
    about 0.12–0.15 m radius at 1.5–2.2 turns/s with the hands ~0.6–0.7 m apart;
    smaller circles let a turning rope die out within a few turns. :func:`jump_rope_hands`
    makes such paths. The rope is a chain, so it does not collide with itself.

    Examples
    --------
    >>> hands = jump_rope_hands(600, 120.0)
    >>> rope = simulate_rope(hands, 120.0, mode="jump")
    >>> rope.markers.shape
    (600, 23, 3)
    """
    rate = _check_positive("rate", rate)
    if mode not in ("jump", "whip"):
        raise ValidationError(f"mode: expected 'jump' or 'whip', got {mode!r}")
    length = _check_positive("length", length)
    marker_spacing = _check_positive("marker_spacing", marker_spacing)
    if marker_spacing > length:
        raise ValidationError(
            f"marker_spacing: must not exceed the rope length {length} m, got {marker_spacing}"
        )
    hang_seconds = _check_nonnegative("hang_seconds", hang_seconds)
    stretch_stiffness = _check_positive("stretch_stiffness", stretch_stiffness, allow_inf=True)
    bend_stiffness = _check_nonnegative("bend_stiffness", bend_stiffness, allow_inf=True)
    damping = _check_nonnegative("damping", damping)
    gravity = _check_finite("gravity", gravity)
    substeps = _check_count("substeps", substeps, minimum=1)
    iterations = _check_count("iterations", iterations, minimum=1)
    linear_density = _check_positive("linear_density", linear_density)
    rope_radius = _check_nonnegative("rope_radius", rope_radius)
    if floor is not None:
        floor = _check_finite("floor", floor)
    floor_friction = _check_nonnegative("floor_friction", floor_friction)
    settle_seconds = _check_nonnegative("settle_seconds", settle_seconds)
    if progress is not None and not callable(progress):
        raise ValidationError("progress: expected a callable taking a fraction, or None")
    if n_particles is None:
        n_particles = max(3, int(math.ceil(length / 0.045)) + 1)
    n_particles = _check_count("n_particles", n_particles, minimum=3)

    held = _check_hands(hands, mode, length)  # (T, H, 3), H = 2 or 1
    n_frames = held.shape[0]
    hang_frames = min(n_frames, int(round(hang_seconds * rate)))
    if hang_frames > 1:
        drift = np.linalg.norm(held[:hang_frames] - held[:1], axis=2).max()
        if drift > 0.005:
            warnings.warn(
                f"hands move {drift * 1000:.1f} mm in the {hang_seconds} s hanging window; "
                "the rope will not hang still there",
                SkincapWarning,
                stacklevel=2,
            )
    capsules = _check_colliders(colliders, n_frames)  # (T, K, 3), (T, K, 3), (K,)

    if lay_direction is None:
        lay = np.array([0.0, 0.0, -1.0 if mode == "jump" else 1.0])
    else:
        lay = np.asarray(lay_direction, dtype=np.float64)
        if lay.shape != (3,) or not np.isfinite(lay).all():
            raise ValidationError(f"lay_direction: expected 3 finite numbers, got {lay!r}")
        lay = lay - lay[1] * _UP
        if np.linalg.norm(lay) < 1e-9:
            raise ValidationError("lay_direction: must have a horizontal component")
    lay = lay / np.linalg.norm(lay)

    seg = length / (n_particles - 1)
    solver = _ChainSolver(
        n_particles=n_particles,
        segment=seg,
        pinned=(0, n_particles - 1) if mode == "jump" else (0,),
        mass=linear_density * seg,
        stretch_stiffness=stretch_stiffness,
        bend_stiffness=bend_stiffness,
        gravity=gravity,
        rope_radius=rope_radius,
        floor=floor,
        floor_friction=floor_friction,
        iterations=iterations,
    )

    rng = np.random.default_rng(seed)
    x = _initial_shape(held[0], length, n_particles, lay, floor, rope_radius)
    x[solver.free] += rng.normal(scale=0.001, size=(int(solver.free.sum()), 3))
    if floor is not None:
        x[:, 1] = np.maximum(x[:, 1], floor + rope_radius)
    v = np.zeros_like(x)

    # Settle before frame 0: still hands, strong damping, then a calm tail at the
    # working damping; velocities are zeroed at the end (the rope is at rest).
    h = 1.0 / (rate * substeps)
    n_settle = int(math.ceil(settle_seconds * rate * substeps))
    cap0 = (capsules[0][0], capsules[1][0], capsules[2]) if capsules is not None else None
    for k in range(n_settle):
        settle_damping = 12.0 if k < 0.8 * n_settle else max(damping, 2.0)
        x, v = solver.step(x, v, h, settle_damping, held[0], cap0)
    v[:] = 0.0

    particles = np.empty((n_frames, n_particles, 3))
    particles[0] = x
    max_speed_hang = 0.0
    report_every = max(1, n_frames // 100)
    for f in range(1, n_frames):
        h0, h1 = held[f - 1], held[f]
        for s in range(substeps):
            a = (s + 1) / substeps
            target = h0 + (h1 - h0) * a
            cap = None
            if capsules is not None:
                ca, cb, cr = capsules
                cap = (
                    ca[f - 1] + (ca[f] - ca[f - 1]) * a,
                    cb[f - 1] + (cb[f] - cb[f - 1]) * a,
                    cr,
                )
            x, v = solver.step(x, v, h, damping, target, cap)
        particles[f] = x
        if f < hang_frames:
            max_speed_hang = max(max_speed_hang, float(np.sqrt((v * v).sum(axis=1).max())))
        if progress is not None and (f % report_every == 0 or f == n_frames - 1):
            progress(f / max(1, n_frames - 1))
    if progress is not None and n_frames == 1:
        progress(1.0)

    if not np.isfinite(particles).all():  # pragma: no cover - a solver failure, not input
        raise SkincapError("rope simulation diverged (non-finite positions); try more substeps")

    n_markers = max(1, int(math.floor(length / marker_spacing + 1e-9)))
    offset = 0.5 * (length - (n_markers - 1) * marker_spacing)
    marker_param = offset + marker_spacing * np.arange(n_markers, dtype=np.float64)
    markers = _points_on_chain(particles, marker_param / seg)
    width = max(2, len(str(n_markers - 1)))
    labels = [f"rope_{i:0{width}d}" for i in range(n_markers)]

    chain = np.linalg.norm(np.diff(particles, axis=1), axis=2).sum(axis=1)
    meta = {
        "mode": mode,
        "length": length,
        "n_particles": n_particles,
        "segment_length": seg,
        "substeps": substeps,
        "iterations": iterations,
        "hang_frames": hang_frames,
        "rope_radius": rope_radius,
        "marker_spacing": marker_spacing,
        "seed": seed,
        "max_length_error": float(np.abs(chain / length - 1.0).max()),
        "max_hang_speed": max_speed_hang,
    }
    return RopeResult(particles, markers, labels, marker_param, rate, meta)


# ----------------------------------------------------------------------- the solver
class _ChainSolver:
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
            (dist > 1e-12)[..., None], diff / np.maximum(dist, 1e-12)[..., None], _UP
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


# ----------------------------------------------------------------------- helpers
def _initial_shape(
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
            pts = [a, 0.5 * (a + b) - sag * _UP, b]
    else:
        drop = a[1] - ground
        if drop >= length:
            pts = [a, a - length * _UP]
        else:
            fa = a.copy()
            fa[1] = ground
            pts = [a, fa, fa + (length - drop) * lay]
    poly = np.array(pts, dtype=np.float64)
    seglen = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seglen)])
    s = np.linspace(0.0, arc[-1], n)
    return np.stack([np.interp(s, arc, poly[:, k]) for k in range(3)], axis=1)


def _points_on_chain(particles: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Linear interpolation along the chain at fractional particle indices u (M,)."""
    p = particles.shape[1]
    i = np.clip(np.floor(u).astype(np.int64), 0, p - 2)
    frac = (u - i)[None, :, None]
    return particles[:, i] * (1.0 - frac) + particles[:, i + 1] * frac


def _check_hands(hands: Any, mode: str, length: float) -> np.ndarray:
    try:
        arr = np.asarray(hands, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"hands: expected a float array: {exc}") from None
    if mode == "jump":
        if arr.ndim != 3 or arr.shape[1:] != (2, 3) or arr.shape[0] < 1:
            raise ValidationError(
                f"hands: mode 'jump' needs shape (T, 2, 3) with T >= 1, got {arr.shape}"
            )
    else:
        if arr.ndim == 2 and arr.shape[1] == 3 and arr.shape[0] >= 1:
            arr = arr[:, None, :]
        elif arr.ndim == 3 and arr.shape[1] in (1, 2) and arr.shape[2] == 3 and arr.shape[0] >= 1:
            arr = arr[:, :1, :]
        else:
            raise ValidationError(
                f"hands: mode 'whip' needs shape (T, 3) or (T, 2, 3) with T >= 1, got {arr.shape}"
            )
    if not np.isfinite(arr).all():
        bad = int(np.flatnonzero(~np.isfinite(arr).reshape(arr.shape[0], -1).all(axis=1))[0])
        raise ValidationError(f"hands: must be finite, frame {bad} has NaN or inf")
    if mode == "jump":
        span = np.linalg.norm(arr[:, 1] - arr[:, 0], axis=1)
        if span.max() >= length:
            bad = int(np.argmax(span))
            raise ValidationError(
                f"hands: {span[bad]:.3f} m apart at frame {bad}, not less than the rope "
                f"length {length} m"
            )
    return np.ascontiguousarray(arr)


def _check_colliders(
    colliders: Sequence[tuple[Any, ...]] | None, n_frames: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    if colliders is None or len(colliders) == 0:
        return None
    a_list, b_list, r_list = [], [], []
    for k, col in enumerate(colliders):
        if not isinstance(col, (tuple, list)) or len(col) not in (2, 3):
            raise ValidationError(
                f"colliders[{k}]: expected (a, b, radius) or (centre, radius), got {type(col)}"
            )
        ends = [_collider_track(f"colliders[{k}]", c, n_frames) for c in col[:-1]]
        radius = _check_positive(f"colliders[{k}] radius", col[-1])
        a_list.append(ends[0])
        b_list.append(ends[-1])
        r_list.append(radius)
    return (
        np.stack(a_list, axis=1),
        np.stack(b_list, axis=1),
        np.asarray(r_list, dtype=np.float64),
    )


def _collider_track(name: str, value: Any, n_frames: int) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: expected a float array: {exc}") from None
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (n_frames, 3))
    elif arr.shape != (n_frames, 3):
        raise ValidationError(f"{name}: expected shape (3,) or ({n_frames}, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValidationError(f"{name}: must be finite")
    return arr


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _check_positive(name: str, value: Any, *, allow_inf: bool = False) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a positive number, got {value!r}") from None
    if math.isnan(val) or val <= 0.0 or (math.isinf(val) and not allow_inf):
        raise ValidationError(f"{name}: expected a positive finite number, got {value!r}")
    return val


def _check_nonnegative(name: str, value: Any, *, allow_inf: bool = False) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a number >= 0, got {value!r}") from None
    if math.isnan(val) or val < 0.0 or (math.isinf(val) and not allow_inf):
        raise ValidationError(f"{name}: expected a finite number >= 0, got {value!r}")
    return val


def _check_finite(name: str, value: Any) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a finite number, got {value!r}") from None
    if not math.isfinite(val):
        raise ValidationError(f"{name}: expected a finite number, got {value!r}")
    return val


def _check_count(name: str, value: Any, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValidationError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValidationError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)
