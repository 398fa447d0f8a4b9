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

from skincap._arrays import check_count, check_nonnegative, check_positive
from skincap.errors import SkincapError, SkincapWarning, ValidationError
from skincap.synth._settings import settings_with
from skincap.synth.rope_settings import RopeSettings
from skincap.synth.rope_solver import UP, ChainSolver, initial_shape, points_on_chain
from skincap.types import MarkerSet

__all__ = [
    "RopeResult",
    "RopeSettings",
    "simulate_rope",
    "jump_rope_hands",
    "whip_hand",
    "rope_occluders",
]


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
def _hand_clock(n_frames: int, rate: float, hang_seconds: float) -> tuple[int, float, np.ndarray]:
    """Checked frame count and rate, and (T,) seconds since the hands started moving
    (0 through the ``hang_seconds`` window in which they are exactly still)."""
    n_frames = check_count("n_frames", n_frames, minimum=1)
    rate = check_positive("rate", rate)
    hang_seconds = check_nonnegative("hang_seconds", hang_seconds)
    t = np.arange(n_frames, dtype=np.float64) / rate
    return n_frames, rate, np.clip(t - hang_seconds, 0.0, None)


def _turns_elapsed(frequency: np.ndarray, rate: float) -> np.ndarray:
    """(T,) turns made since frame 0 at the per-frame turn rate ``frequency`` (T,) Hz:
    its integral over time by the trapezoid rule, frames ``1 / rate`` seconds apart."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (frequency[1:] + frequency[:-1]) / rate)])


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
    n_frames, rate, tau = _hand_clock(n_frames, rate, hang_seconds)
    height = check_positive("height", height)
    shoulder_width = check_positive("shoulder_width", shoulder_width)
    frequency = check_positive("frequency", frequency)
    rng = np.random.default_rng(seed)
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
    # Phase: the turns so far, held at zero in the hanging window.
    turns = _turns_elapsed(freq, rate)
    phase = 2.0 * np.pi * np.where(tau > 0.0, turns - turns[np.argmax(tau > 0.0) - 1], 0.0)
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
    n_frames, rate, tau = _hand_clock(n_frames, rate, hang_seconds)
    height = check_positive("height", height)
    frequency = check_positive("frequency", frequency)
    rng = np.random.default_rng(seed)
    ease = _smoothstep(tau / 0.4)
    f = frequency * (1.0 + 0.05 * np.sin(2.0 * np.pi * rng.uniform(0.1, 0.3) * tau))
    phase = 2.0 * np.pi * _turns_elapsed(f, rate)
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
    radius = check_positive("radius", radius)
    return p[:, :-1].copy(), p[:, 1:].copy(), radius


# ------------------------------------------------------------------------- simulation
def simulate_rope(
    hands: np.ndarray,
    rate: float,
    settings: RopeSettings | None = None,
    *,
    mode: Literal["jump", "whip"] = "jump",
    colliders: Sequence[tuple[Any, ...]] | None = None,
    seed: int = 0,
    progress: Callable[[float], object] | None = None,
    **options: Any,
) -> RopeResult:
    """Simulate a rope held in the hands and place tape markers along it.

    Parameters
    ----------
    hands : (T, 2, 3) or (T, 3) float, metres
        Hand positions per frame; finite. ``mode="jump"`` needs both hands (the rope's
        first end in ``hands[:, 0]``, its last in ``hands[:, 1]``) and their distance
        must stay below the rope's length. ``mode="whip"`` holds the first end in the
        first hand (``hands[:, 0]`` or the (T, 3) array); the other end is free.
    rate : float
        Frame rate, Hz (120 for the capture rigs of the papers).
    settings : RopeSettings, optional
        Length, particles, marker spacing, stiffness, damping, substeps, floor, …
        (:class:`~skincap.synth.rope_settings.RopeSettings`; its defaults when omitted).
    mode : {"jump", "whip"}
        Both ends held (a skipping rope turned around the body) or one end held.
    colliders : sequence of tuples, optional
        Bodies the rope is pushed out of: capsules ``(a, b, radius)`` and spheres
        ``(centre, radius)``, with ``a``, ``b``, ``centre`` of shape (T, 3) or (3,)
        (metres) and ``radius`` in metres; e.g. the torso and legs. Interpolated
        between frames like the hands.
    seed : int
        Seeds a millimetre-scale perturbation of the initial shape.
    progress : callable, optional
        Called with the fraction of frames done (0..1).
    **options
        Any :class:`RopeSettings` field by name (``length=2.5``), replacing the one
        in ``settings``.

    Returns
    -------
    RopeResult
        ``particles`` (T, P, 3), ``markers`` (T, M, 3), ``labels``, ``marker_param``
        (M,), ``rate`` and ``meta``; all finite. ``meta["max_hang_speed"]`` is the
        largest particle speed in the hanging window.

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
    cfg = settings_with(RopeSettings, settings, options, caller="simulate_rope")
    rate = check_positive("rate", rate)
    if mode not in ("jump", "whip"):
        raise ValidationError(f"mode: expected 'jump' or 'whip', got {mode!r}")
    if progress is not None and not callable(progress):
        raise ValidationError("progress: expected a callable taking a fraction, or None")
    held = _check_hands(hands, mode, cfg.length)  # (T, H, 3), H = 2 or 1
    n_frames = held.shape[0]
    hang_frames = min(n_frames, int(round(cfg.hang_seconds * rate)))
    _warn_if_hands_move(held[:hang_frames], cfg.hang_seconds)
    capsules = _check_colliders(colliders, n_frames)  # (T, K, 3), (T, K, 3), (K,)
    n_particles = cfg.particles()
    seg = cfg.length / (n_particles - 1)
    solver = ChainSolver(
        n_particles=n_particles,
        segment=seg,
        pinned=(0, n_particles - 1) if mode == "jump" else (0,),
        mass=cfg.linear_density * seg,
        stretch_stiffness=cfg.stretch_stiffness,
        bend_stiffness=cfg.bend_stiffness,
        gravity=cfg.gravity,
        rope_radius=cfg.rope_radius,
        floor=cfg.floor,
        floor_friction=cfg.floor_friction,
        iterations=cfg.iterations,
    )
    h = 1.0 / (rate * cfg.substeps)
    lay = _lay_direction(cfg.lay_direction, mode)
    x = _settled_rope(solver, held[0], capsules, cfg, lay, rate, np.random.default_rng(seed))
    particles, max_speed_hang = _run_frames(
        solver, x, held, capsules, cfg, h, hang_frames, progress
    )
    if not np.isfinite(particles).all():  # pragma: no cover - a solver failure, not input
        raise SkincapError("rope simulation diverged (non-finite positions); try more substeps")
    markers, labels, marker_param = _tape_markers(particles, cfg.length, cfg.marker_spacing, seg)
    chain = np.linalg.norm(np.diff(particles, axis=1), axis=2).sum(axis=1)
    meta = {
        "mode": mode,
        "length": cfg.length,
        "n_particles": n_particles,
        "segment_length": seg,
        "substeps": cfg.substeps,
        "iterations": cfg.iterations,
        "hang_frames": hang_frames,
        "rope_radius": cfg.rope_radius,
        "marker_spacing": cfg.marker_spacing,
        "seed": seed,
        "max_length_error": float(np.abs(chain / cfg.length - 1.0).max()),
        "max_hang_speed": max_speed_hang,
    }
    return RopeResult(particles, markers, labels, marker_param, rate, meta)


def _warn_if_hands_move(hang: np.ndarray, hang_seconds: float) -> None:
    """A SkincapWarning (at simulate_rope's caller) if the hands drift > 5 mm in ``hang``."""
    if hang.shape[0] > 1:
        drift = np.linalg.norm(hang - hang[:1], axis=2).max()
        if drift > 0.005:
            warnings.warn(
                f"hands move {drift * 1000:.1f} mm in the {hang_seconds} s hanging window; "
                "the rope will not hang still there",
                SkincapWarning,
                stacklevel=3,
            )


def _lay_direction(lay_direction: Sequence[float] | None, mode: str) -> np.ndarray:
    """(3,) unit horizontal direction the slack first lies in."""
    if lay_direction is None:
        lay = np.array([0.0, 0.0, -1.0 if mode == "jump" else 1.0])
    else:
        lay = np.asarray(lay_direction, dtype=np.float64)
        lay = lay - lay[1] * UP
    return lay / np.linalg.norm(lay)


Capsules = tuple[np.ndarray, np.ndarray, np.ndarray]


def _settled_rope(
    solver: ChainSolver,
    held0: np.ndarray,
    capsules: Capsules | None,
    cfg: RopeSettings,
    lay: np.ndarray,
    rate: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """(P, 3) the rope at rest at the first frame's hands, before frame 0.

    Laid out on the floor, perturbed by a millimetre, then settled with still hands and
    strong damping, and a calm tail at the working damping.
    """
    x = initial_shape(held0, cfg.length, solver.w.size, lay, cfg.floor, cfg.rope_radius)
    x[solver.free] += rng.normal(scale=0.001, size=(int(solver.free.sum()), 3))
    if cfg.floor is not None:
        x[:, 1] = np.maximum(x[:, 1], cfg.floor + cfg.rope_radius)
    v = np.zeros_like(x)
    h = 1.0 / (rate * cfg.substeps)
    n_settle = int(math.ceil(cfg.settle_seconds * rate * cfg.substeps))
    cap0 = (capsules[0][0], capsules[1][0], capsules[2]) if capsules is not None else None
    for k in range(n_settle):
        settle_damping = 12.0 if k < 0.8 * n_settle else max(cfg.damping, 2.0)
        x, v = solver.step(x, v, h, settle_damping, held0, cap0)
    return x


def _run_frames(
    solver: ChainSolver,
    x: np.ndarray,
    held: np.ndarray,
    capsules: Capsules | None,
    cfg: RopeSettings,
    h: float,
    hang_frames: int,
    progress: Callable[[float], object] | None,
) -> tuple[np.ndarray, float]:
    """(T, P, 3) particles frame by frame from the settled ``x`` (at rest), and the
    largest particle speed in the hanging window, m/s.

    Hands and colliders are interpolated linearly within each frame's substeps.
    """
    n_frames = held.shape[0]
    substeps = cfg.substeps
    v = np.zeros_like(x)
    particles = np.empty((n_frames, x.shape[0], 3))
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
            x, v = solver.step(x, v, h, cfg.damping, target, cap)
        particles[f] = x
        if f < hang_frames:
            max_speed_hang = max(max_speed_hang, float(np.sqrt((v * v).sum(axis=1).max())))
        if progress is not None and (f % report_every == 0 or f == n_frames - 1):
            progress(f / max(1, n_frames - 1))
    if progress is not None and n_frames == 1:
        progress(1.0)
    return particles, max_speed_hang


def _tape_markers(
    particles: np.ndarray, length: float, spacing: float, segment: float
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Markers (T, M, 3) every ``spacing`` metres centred on the rope, labels, arc params (M,)."""
    n_markers = max(1, int(math.floor(length / spacing + 1e-9)))
    offset = 0.5 * (length - (n_markers - 1) * spacing)
    marker_param = offset + spacing * np.arange(n_markers, dtype=np.float64)
    markers = points_on_chain(particles, marker_param / segment)
    width = max(2, len(str(n_markers - 1)))
    labels = [f"rope_{i:0{width}d}" for i in range(n_markers)]
    return markers, labels, marker_param


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
        radius = check_positive(f"colliders[{k}] radius", col[-1])
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
