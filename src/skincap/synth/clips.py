"""Built-in motion clips that stress skin-capture algorithms.

Every clip is a :class:`~skincap.types.Motion` on a given skeleton whose zero pose
(all local rotations identity) is a T-pose: arms along ``+-X`` (the left arm along
``+X``), facing ``+Z``, ``Y`` up, feet on the floor -- the skeleton of
:func:`skincap.synth.skeleton.synth_skeleton`. Joints are found by name through the
built-in naming conventions of :mod:`skincap.deform.skeletal.name_maps` (CMU ``bvh11``,
CMU cgspeed, Biovision, MakeHuman); joints a skeleton lacks are left out of the
motion (a skeleton without arms gets no arm motion).

Every clip starts in the T-pose (Mazrimas et al., appendix A: takes start in the
reference pose): the first :data:`HOLD_SECONDS` hold it exactly (identity local
rotations, root at its rest position), then the action blends in with a minimum-jerk
(quintic smoothstep) envelope over :data:`BLEND_SECONDS`.

The clips
---------
``tpose``
    The T-pose, still (a reference take).
``flex``
    Arms lowered beside the body, then both elbows flex to 150 degrees (the angle
    between the upper-arm and forearm directions) and back, every 1.5 s: a biceps
    curl with the forearm in front of the body.
``twist``
    Arms held out to the sides; both forearms pronate and supinate about their own
    long axis from -90 to +90 degrees (180 degrees of range), 0.5 Hz.
``squat``
    Knees flex to 105 degrees and back every 1.75 s; the pelvis drops and moves back,
    the torso leans forward, the arms reach forward. The legs are solved by two-bone
    inverse kinematics so the ankles stay exactly at their rest positions and the
    feet flat: the feet are planted.
``punch``
    A guard with fists at the chin, then alternating straight punches (shoulder
    flexion with elbow extension) with the torso rotating into each punch.
``jumprope``
    Skipping a real (simulated) rope: the arms come down from the T-pose to the hips
    (hands ~0.68 m apart), then the wrists wind the rope up with a fast lift into a
    wide, slow circle (0.45 m, 0.65 turns/s) that shrinks within 2.5 s into 0.15 m
    circles at 1.8 turns/s by the hips -- the hand paths of
    :func:`skincap.synth.rope.jump_rope_hands`, made reachable and solved by two-bone
    arm IK with the elbows by the sides. The body hops once per turn, timed so the
    feet are ~7 cm up when the rope passes under them; knees bend on landing.
    :func:`skincap.synth.rope.simulate_rope` held in these hands turns ~11 times
    in 1000 frames.
``breathe``
    Relaxed standing with the arms lowered; chest and shoulders rise and fall at
    0.25 Hz (the breathing deformation itself is soft tissue).
``rom``
    A range-of-motion take for near-rigid segmentation (Park & Hodgins §5.2): after
    the hold, each major joint in turn (neck, lower back and chest, shoulders, elbows,
    wrists, hips, knees, ankles; both sides together) swings through its range and
    back, so every one of the 17 true parts of ``truth/marker_parts.csv`` moves
    against its neighbours at some time.

``seed`` adds a subtle natural sway of the trunk (random low frequencies and
phases, below one degree); the prescribed targets (elbow angle, twist range, knee
angle, planted feet) are not randomised. The same arguments give the same bytes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from skincap._arrays import check_positive
from skincap.errors import ValidationError
from skincap.geometry.rotations import (
    quat_apply,
)
from skincap.synth.clip_pose import (
    X_AXIS,
    Y_AXIS,
    Z_AXIS,
    ClipPose,
    axis_angle,
    nlerp,
    quintic,
    unit,
)
from skincap.types import Motion, Skeleton

__all__ = [
    "CLIPS",
    "DEFAULT_SECONDS",
    "HOLD_SECONDS",
    "BLEND_SECONDS",
    "CLIP_RATE_RANGE",
    "MAX_CLIP_FRAMES",
    "clip_frame_count",
    "make_clip",
]

#: Names of the built-in clips.
CLIPS: tuple[str, ...] = (
    "tpose", "flex", "twist", "squat", "punch", "jumprope", "breathe", "rom"
)  # fmt: skip
#: Default clip length, seconds.
DEFAULT_SECONDS = 4.0
#: Most frames of a synthetic take (2.3 hours at 120 Hz): every stage keeps (T, ...)
#: arrays, and 1e14 frames asked NumPy for 728 TiB.
MAX_CLIP_FRAMES = 1_000_000
#: Frame rates a clip may be made at, Hz (1e-300 Hz sized a 4e300-frame time axis).
CLIP_RATE_RANGE = (1.0, 100_000.0)
#: The T-pose is held exactly for this long at the start of every clip, seconds.
HOLD_SECONDS = 0.5
#: Duration of the blend from the T-pose into the action, seconds.
BLEND_SECONDS = 0.6


# ------------------------------------------------------------------ clip parts
def _sway(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    """Subtle trunk sway (below one degree) from random low frequencies and phases."""
    freq = rng.uniform(0.12, 0.45, size=(2, 2))  # Hz, (axis, component)
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(2, 2))
    amp = np.radians(rng.uniform(0.25, 0.45, size=(2, 2)))
    waves = (amp[..., None] * np.sin(2 * np.pi * freq[..., None] * t + phase[..., None])).sum(
        axis=1
    )  # (2, T)
    for axis, wave in zip((X_AXIS, Z_AXIS), waves, strict=True):
        pose.turn("spine", axis_angle(axis, env * wave))


def _sided_dir(v: tuple[float, float, float], side: str) -> np.ndarray:
    """A left-side direction (3,), mirrored in X for the right side."""
    d = np.array(v, dtype=np.float64)
    if side == "r":
        d[0] = -d[0]
    return unit(d)


def _clip_tpose(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    """Nothing moves."""


def _clip_flex(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    _sway(pose, t, env, rng)
    start = HOLD_SECONDS + BLEND_SECONDS
    period = 1.5  # s per curl
    angle = np.where(
        t >= start, np.radians(75.0) * (1.0 - np.cos(2 * np.pi * (t - start) / period)), 0.0
    )
    for s in ("l", "r"):
        if not pose.has(f"upperarm_{s}"):
            continue
        pose.aim(f"upperarm_{s}", _sided_dir((0.35, -0.93, 0.2), s), env)
        if not pose.has(f"forearm_{s}"):
            continue
        upper = unit(
            quat_apply(pose.world(pose.lm[f"upperarm_{s}"]), pose.segment(f"upperarm_{s}"))
        )
        forward = unit(Z_AXIS - np.sum(upper * Z_AXIS, axis=-1, keepdims=True) * upper)
        target = np.cos(angle)[:, None] * upper + np.sin(angle)[:, None] * forward
        pose.aim(f"forearm_{s}", target)


def _clip_twist(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    _sway(pose, t, env, rng)
    start = HOLD_SECONDS + BLEND_SECONDS
    ramp = quintic((t - start) / 0.5)
    angle = np.radians(90.0) * ramp * np.sin(2 * np.pi * 0.5 * (t - start))
    for s in ("l", "r"):
        if not pose.has(f"upperarm_{s}"):
            continue
        pose.aim(f"upperarm_{s}", _sided_dir((1.0, -0.15, 0.25), s), env)
        if pose.has(f"forearm_{s}"):
            axis = unit(pose.segment(f"forearm_{s}"))
            # pronation turns the left palm (down in the T-pose) backwards: about +axis
            pose.turn(f"forearm_{s}", axis_angle(axis, angle if s == "l" else -angle))


def _legs_planted(
    pose: ClipPose, foot_lift: np.ndarray | None = None, toe_down: np.ndarray | None = None
) -> None:
    """Solve both legs so the ankles sit at rest (+ ``foot_lift`` (T,) metres up)."""
    for s in ("l", "r"):
        if not pose.has(f"thigh_{s}", f"shin_{s}", f"foot_{s}"):
            continue
        ankle = np.broadcast_to(pose.rest[pose.lm[f"foot_{s}"]], (pose.n, 3)).copy()
        if foot_lift is not None:
            ankle[:, 1] += foot_lift
        foot = None if toe_down is None else axis_angle(X_AXIS, toe_down)
        pose.leg_ik(s, ankle, foot)


def _legs(pose: ClipPose) -> list[tuple[float, float, np.ndarray]]:
    """Thigh and shin lengths and the rest hip-minus-ankle vector (3,) of each leg."""
    legs = []
    for s in ("l", "r"):
        if pose.has(f"thigh_{s}", f"shin_{s}", f"foot_{s}"):
            h, k, a = (pose.rest[pose.lm[f"{n}_{s}"]] for n in ("thigh", "shin", "foot"))
            legs.append((float(np.linalg.norm(k - h)), float(np.linalg.norm(a - k)), h - a))
    return legs


def _pelvis_for_knee(pose: ClipPose, knee: np.ndarray, back: float) -> np.ndarray:
    """(T, 3) pelvis displacement giving knee flexion ``knee`` (T,) radians with feet at rest.

    The hip moves back by ``back`` times the shortening of the leg, and down so that
    the hip-to-ankle distance matches the bent leg; with legs of different shapes the
    lower of their pelvis heights is taken, so both ankles stay reachable.
    """
    out = np.zeros((pose.n, 3))
    legs = _legs(pose)
    if not legs:
        return out
    l1 = np.mean([g[0] for g in legs])
    l2 = np.mean([g[1] for g in legs])
    shortening = l1 + l2 - np.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * np.cos(knee))  # (T,)
    dz = -back * shortening
    drops = []
    for g1, g2, v0 in legs:
        dist = np.sqrt(g1 * g1 + g2 * g2 + 2 * g1 * g2 * np.cos(knee))  # (T,)
        horizontal2 = v0[0] ** 2 + (v0[2] + dz) ** 2
        drops.append(np.sqrt(np.maximum(dist * dist - horizontal2, 0.0)) - v0[1])
    out[:, 1] = np.minimum.reduce(drops)
    out[:, 2] = dz
    return out


def _clip_squat(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    period = 1.75
    depth = env * 0.5 * (1.0 - np.cos(2 * np.pi * (t - HOLD_SECONDS) / period))
    depth = np.where(t >= HOLD_SECONDS, depth, 0.0)
    pose.root_offset = _pelvis_for_knee(pose, np.radians(105.0) * depth, back=0.55)
    _sway(pose, t, env, rng)
    pose.turn("spine", axis_angle(X_AXIS, np.radians(20.0) * depth))
    pose.turn("chest", axis_angle(X_AXIS, np.radians(12.0) * depth))
    for s in ("l", "r"):
        pose.aim(f"upperarm_{s}", _sided_dir((0.2, -0.25, 1.0), s), env)
    _legs_planted(pose)


def _pulse(t: np.ndarray, start: float, period: float, width: float) -> np.ndarray:
    """sin^2 pulses of ``width`` seconds every ``period`` seconds from ``start``, (T,)."""
    u = np.mod(t - start, period) / width
    return np.where((t >= start) & (u < 1.0), np.sin(np.pi * np.minimum(u, 1.0)) ** 2, 0.0)


def _clip_punch(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    _sway(pose, t, env, rng)
    start = HOLD_SECONDS + BLEND_SECONDS + 0.15
    period, width = 1.2, 0.45
    hit = {"l": _pulse(t, start, period, width), "r": _pulse(t, start + period / 2, period, width)}
    # torso turns into the punch: a right punch turns the chest to the left (+Y)
    turn = np.radians(22.0) * (hit["r"] - hit["l"])
    pose.turn("spine", axis_angle(Y_AXIS, 0.6 * turn))
    pose.turn("chest", axis_angle(Y_AXIS, 0.4 * turn))
    trunk = pose.world(pose.lm["upper_chest"]) if pose.has("upper_chest") else pose.world(pose.root)
    for s in ("l", "r"):
        upper = nlerp(_sided_dir((0.3, -0.65, 0.55), s), _sided_dir((0.05, 0.05, 1.0), s), hit[s])
        fore = nlerp(_sided_dir((-0.3, 0.75, 0.55), s), _sided_dir((-0.05, 0.05, 1.0), s), hit[s])
        pose.aim(f"upperarm_{s}", quat_apply(trunk, upper), env)
        pose.aim(f"forearm_{s}", quat_apply(trunk, fore), env)


#: Steady rope-turn (and hop) frequency of ``jumprope``, Hz.
JUMP_HZ = 1.8
#: Turn rate of the wind-up circle that starts the rope, Hz.
WIND_HZ = 0.65
#: The arms come down from the T-pose to the hips in this long, seconds.
_LOWER_SECONDS = 0.6
#: The wind-up circles shrink to the skipping circles (and speed up) in this long, s.
_WIND_SECONDS = 2.5
#: The wind-up radius grows from nothing in this long (no jerk at the start), s.
_GROW_SECONDS = 0.4
#: Wrist-circle radii, fractions of the arm length (shoulder to wrist): the wide
#: wind-up circle (0.45 m at 1.75 m) and the skipping circles (0.15 m).
_WIND_RADIUS, _SKIP_RADIUS = 0.77, 0.26
#: Hand positions relative to the shoulder joint, fractions of the arm length:
#: out to the side (hands ~0.68 m apart at 1.75 m, 1.7 x the shoulder width) and,
#: in the sagittal plane (up, forward), the bottom of the wind-up and skipping circles.
_HAND_OUT = 0.28
_WIND_BOTTOM = (-0.77, 0.15)
_SKIP_BOTTOM = (-0.80, 0.22)
#: How far the rope lags the hands: it passes under the feet when the hands are this
#: far past the bottom of their circle, radians (measured with skincap.synth.rope).
_ROPE_LAG = np.radians(50.0)
#: Time in the air per hop, s, and hop height, metres.
_FLIGHT, _HOP = 0.22, 0.07
#: The wrist keeps at least this share of the arm length from the shoulder.
_ARM_FLOOR = 0.5


def _smooth3(s: np.ndarray) -> np.ndarray:
    """Cubic smoothstep ``3 s^2 - 2 s^3`` on ``s`` clipped to 0..1."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _ramp_integral(tau: np.ndarray, width: float) -> np.ndarray:
    """Integral from 0 to ``tau`` (T,) of the cubic smoothstep ``S(s / width)``, seconds."""
    u = np.clip(tau / width, 0.0, 1.0)
    return width * (u**3 - 0.5 * u**4) + np.maximum(tau - width, 0.0)


def _rope_turns(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn rate (Hz) and turns done by the hands ``tau`` (T,) seconds into the wind-up.

    The rate rises from :data:`WIND_HZ` to :data:`JUMP_HZ` along a cubic smoothstep
    over :data:`_WIND_SECONDS`; the turns are its closed-form integral (so every frame
    rate samples the same curve). Both are 0 for ``tau <= 0``.
    """
    tau = np.maximum(tau, 0.0)
    rate = np.where(tau > 0, WIND_HZ + (JUMP_HZ - WIND_HZ) * _smooth3(tau / _WIND_SECONDS), 0.0)
    turns = WIND_HZ * tau + (JUMP_HZ - WIND_HZ) * _ramp_integral(tau, _WIND_SECONDS)
    return rate, turns


def _hop_profile(t: np.ndarray, passes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Foot lift (0..1) and knee squash (0..1) around rope passes at ``passes`` (K,) s.

    Each hop is a ``sin^2`` flight of :data:`_FLIGHT` seconds centred on a pass; between
    landing and the next take-off the knees bend and straighten (``sin^2``), and
    before the first take-off there is one such dip of 0.35 s.
    """
    lift = np.zeros_like(t)
    squash = np.zeros_like(t)
    if passes.size == 0:
        return lift, squash
    take_off = passes - 0.5 * _FLIGHT
    landing = passes + 0.5 * _FLIGHT
    k = np.searchsorted(passes, t)  # passes[k-1] < t <= passes[k]
    near = np.clip(np.stack([k - 1, k]), 0, passes.size - 1)  # (2, T)
    off = np.min(np.abs(t[None] - passes[near]), axis=0)
    air = off < 0.5 * _FLIGHT
    lift = np.where(air, np.cos(np.pi * off / _FLIGHT) ** 2, 0.0)
    # contact intervals: from the previous landing (or 0.35 s before the first
    # take-off) to the next take-off
    nxt = np.searchsorted(take_off, t)  # take_off[nxt-1] < t <= take_off[nxt]
    has_next = nxt < passes.size
    nxt_c = np.minimum(nxt, passes.size - 1)
    begin = np.where(nxt_c > 0, landing[np.maximum(nxt_c - 1, 0)], take_off[0] - 0.35)
    stop = take_off[nxt_c]
    s = (t - begin) / np.maximum(stop - begin, 1e-9)
    squash = np.where(has_next & ~air & (s >= 0.0) & (s <= 1.0), np.sin(np.pi * s) ** 2, 0.0)
    return lift, squash


def _clip_jumprope(
    pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator
) -> None:
    """Skipping a rope: arms down from the T-pose, a wind-up circle, then hops.

    The wrists follow prescribed circles in the sagittal plane (two-bone arm IK,
    elbows by the sides): first a wide slow wind-up circle that brings a resting rope
    over the head, shrinking within :data:`_WIND_SECONDS` into skipping circles at
    :data:`JUMP_HZ` (see :func:`skincap.synth.rope.jump_rope_hands`, which these
    follow). The feet leave the floor when the rope passes under them.
    """
    _sway(pose, t, env, rng)
    start = HOLD_SECONDS + _LOWER_SECONDS  # the wind-up begins
    tau = t - start
    _, turns = _rope_turns(tau)
    decay = _smooth3(tau / _WIND_SECONDS)  # 0 -> 1: wind-up -> skipping
    grow = quintic(tau / _GROW_SECONDS)
    # angles in the sagittal plane: 0 = up, 90 deg = forward. The circle passes
    # through the hands' start (its bottom) and grows from nothing while the hands
    # start at 270 deg and turn forward: they first rise (lifting the rope from
    # behind the heels), then go over the top, down the front and back under.
    angle = 1.5 * np.pi + 2.0 * np.pi * turns  # (T,) radians
    # hops: the rope passes under the feet _ROPE_LAG after the hands pass the bottom
    # of their circle, first after three quarters of a turn (from 270 deg)
    n_pass = int(np.floor(turns[-1] + 2.0)) if t.size else 0
    pass_turns = 0.75 + _ROPE_LAG / (2.0 * np.pi) + np.arange(n_pass)
    # invert the monotonic turns(tau) on a 1 ms grid of tau (the same grid points
    # whatever the clip's length and frame rate)
    tau_grid = np.arange(0.0, max(float(tau[-1]), 0.0) + 2.0, 1e-3)
    _, turns_grid = _rope_turns(tau_grid)
    passes = start + np.interp(pass_turns, turns_grid, tau_grid, right=np.inf)
    passes = passes[np.isfinite(passes)]
    lift, squash = _hop_profile(t, passes)
    ramp = quintic((t - start) / 1.0)
    foot_lift = _HOP * lift  # metres
    knee = np.radians(8.0) * env + np.radians(30.0) * ramp * squash
    pose.root_offset = _pelvis_for_knee(pose, knee, back=0.3)
    pose.root_offset[:, 1] += foot_lift
    pose.turn("spine", axis_angle(X_AXIS, np.radians(4.0) * env))

    hold = t < HOLD_SECONDS
    lower = quintic((t - HOLD_SECONDS) / _LOWER_SECONDS)  # (T,) 0 -> 1
    for side in ("l", "r"):
        up, fore, hand = f"upperarm_{side}", f"forearm_{side}", f"hand_{side}"
        if not pose.has(up, fore, hand):
            continue
        sx = 1.0 if side == "l" else -1.0
        sh_rest = pose.rest[pose.lm[up]]
        arm = pose.rest[pose.lm[hand]] - sh_rest  # (3,) T-pose shoulder -> wrist
        length = float(np.linalg.norm(arm))
        # the circles in the sagittal plane, riding with the body (half the hop)
        bottom = (1.0 - decay)[:, None] * np.array(_WIND_BOTTOM) + decay[:, None] * np.array(
            _SKIP_BOTTOM
        )  # (T, 2) (up, forward) / arm length
        radius = (_WIND_RADIUS + (_SKIP_RADIUS - _WIND_RADIUS) * decay) * grow  # (T,)
        centre = bottom + radius[:, None] * np.array([1.0, 0.0])
        up_fwd = centre + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
        # before the wind-up the hands wait at its start point (the bottom)
        target = np.empty((t.size, 3))
        target[:, 0] = sh_rest[0] + sx * _HAND_OUT * length
        target[:, 1] = sh_rest[1] + length * up_fwd[:, 0] + pose.root_offset[:, 1] * 0.5
        target[:, 2] = sh_rest[2] + length * up_fwd[:, 1]
        # lowering from the T-pose: the shoulder-to-wrist direction turns and the
        # reach shortens smoothly from the T-pose's to the stance's
        shoulder = pose.position(pose.lm[up])
        stance = target - shoulder
        # the wrist never comes nearer the shoulder than _ARM_FLOOR of the arm (a soft
        # floor on the distance): the arm swings past the shoulder, it does not fold
        dist = np.linalg.norm(stance, axis=-1)
        floor = _ARM_FLOOR * length
        stance *= ((1.0 + (floor / np.maximum(dist, 1e-9)) ** 8) ** 0.125)[:, None]
        d0 = unit(arm)
        d1 = unit(stance)
        direction = unit((1.0 - lower)[:, None] * d0 + lower[:, None] * d1)
        reach = (1.0 - lower) * length + lower * np.linalg.norm(stance, axis=-1)
        wrist = shoulder + direction * reach[:, None]
        # pole (where the elbow points): straight back as the arm leaves the T-pose
        # (so the T-pose solves the IK there), then down and back, elbows by the
        # sides; it keeps well away from the shoulder-to-wrist line all along the
        # wind-up and skipping circles
        back = np.array([0.3 * sx, 0.0, -1.0])
        down_back = unit(np.array([0.0, -1.5, -1.0]))
        pole = nlerp(back, down_back, quintic(2.0 * lower))
        before = pose.local.copy()
        pose.arm_ik(side, wrist, pole)
        pose.local[hold] = before[hold]  # the T-pose is held exactly
    _legs_planted(pose, foot_lift, np.radians(8.0) * lift)


def _clip_breathe(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    _sway(pose, t, env, rng)
    breath = np.where(
        t >= HOLD_SECONDS, 0.5 * (1.0 - np.cos(2 * np.pi * 0.25 * (t - HOLD_SECONDS))), 0.0
    )
    pose.turn("chest", axis_angle(X_AXIS, -np.radians(1.5) * breath))
    pose.turn("upper_chest", axis_angle(X_AXIS, -np.radians(1.0) * breath))
    pose.turn("neck", axis_angle(X_AXIS, np.radians(2.5) * breath))
    pose.turn("clavicle_l", axis_angle(Z_AXIS, np.radians(2.0) * breath))
    pose.turn("clavicle_r", axis_angle(Z_AXIS, -np.radians(2.0) * breath))
    for s in ("l", "r"):
        pose.aim(f"upperarm_{s}", _sided_dir((0.45, -0.9, 0.05), s), env)


#: The range-of-motion clip: (slot, landmark, local axis, angle in degrees) per
#: movement, left side given (the right mirrors it: Y and Z angles change sign); the
#: slots follow one another, both sides move at once, and joints sharing a slot turn
#: by different angles, so every segment's rotation sequence is its own. Nine slots
#: keep a 4 s clip within the smoothness of the other clips. Local axes are world
#: axes in the T-pose.
_ROM_MOVES: tuple[tuple[int, str, np.ndarray, float], ...] = (
    (0, "neck", X_AXIS, 30.0),  # nod ...
    (0, "chest", X_AXIS, 20.0),  # ... and bend forward ...
    (0, "spine", X_AXIS, 25.0),  # ... from the lower back too (else abdomen = pelvis)
    (1, "neck_upper", Y_AXIS, 45.0),  # look aside ...
    (1, "upper_chest", Y_AXIS, 25.0),  # ... and twist
    (2, "chest", Z_AXIS, 20.0),  # bend sideways ...
    (2, "clavicle_l", Z_AXIS, 15.0),  # ... and shrug
    (3, "upperarm_l", Z_AXIS, -70.0),  # arms down
    (4, "upperarm_l", Y_AXIS, -60.0),  # arms forward
    (5, "forearm_l", Y_AXIS, -80.0),  # elbows bend ...
    (5, "hand_l", Z_AXIS, 50.0),  # ... and wrists
    (6, "forearm_l", X_AXIS, 70.0),  # forearm twist
    (7, "thigh_l", X_AXIS, -70.0),  # march: thighs forward ...
    (7, "shin_l", X_AXIS, 80.0),  # ... knees bent ...
    (7, "foot_l", X_AXIS, -20.0),  # ... toes clear of the floor
    (8, "thigh_l", Z_AXIS, 30.0),  # legs out ...
    (8, "foot_l", X_AXIS, -45.0),  # ... toes up
)


def _clip_rom(pose: ClipPose, t: np.ndarray, env: np.ndarray, rng: np.random.Generator) -> None:
    """Every major joint through its range, one slot after another (for segmentation)."""
    n_slots = max(m[0] for m in _ROM_MOVES) + 1
    span = max(float(t[-1]) - HOLD_SECONDS, 1e-9) if t.size else 1.0
    slot = span / n_slots
    for k, landmark, axis, degrees in _ROM_MOVES:
        s = (t - HOLD_SECONDS - k * slot) / slot
        bump = np.where((s > 0) & (s < 1), np.sin(np.pi * np.clip(s, 0, 1)) ** 2, 0.0)
        sides = [("", 1.0)] if not landmark.endswith("_l") else [("l", 1.0), ("r", -1.0)]
        for side, sign in sides:
            name = landmark if not side else f"{landmark[:-2]}_{side}"
            signed = degrees if axis is X_AXIS else sign * degrees
            pose.turn(name, axis_angle(axis, np.radians(signed) * bump))


_CLIP_FUNCS: dict[str, Callable[[ClipPose, np.ndarray, np.ndarray, np.random.Generator], None]] = {
    "tpose": _clip_tpose,
    "flex": _clip_flex,
    "twist": _clip_twist,
    "squat": _clip_squat,
    "punch": _clip_punch,
    "jumprope": _clip_jumprope,
    "breathe": _clip_breathe,
    "rom": _clip_rom,
}


# ------------------------------------------------------------------ public
def clip_frame_count(frames: Any, seconds: Any, rate: float) -> int:
    """Frames of a clip from ``frames`` (a positive integer) or ``seconds`` (positive,
    finite) at ``rate`` Hz; neither: :data:`DEFAULT_SECONDS`. ValidationError for both,
    for a bad value, or for more than :data:`MAX_CLIP_FRAMES` frames."""
    if frames is not None and seconds is not None:
        raise ValidationError("frames and seconds: give one or neither, not both")
    if frames is not None:
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
            raise ValidationError(f"frames: expected a positive integer, got {frames!r}")
        if frames > MAX_CLIP_FRAMES:
            raise ValidationError(
                f"frames: expected at most {MAX_CLIP_FRAMES} for a synthetic take, got {frames}"
            )
        return int(frames)
    if seconds is None:
        seconds = DEFAULT_SECONDS
    sec = check_positive("seconds", seconds, expected_finite="a positive finite duration")
    n = sec * rate
    if not n <= MAX_CLIP_FRAMES:  # sized before int(): 4 s at 1e300 Hz would not fit
        raise ValidationError(
            f"seconds: {sec:g} s at {rate:g} Hz is {n:.3g} frames, more than the "
            f"{MAX_CLIP_FRAMES} a synthetic take may have"
        )
    return max(1, int(round(n)))


def make_clip(
    name: str,
    skeleton: Skeleton,
    *,
    frames: int | None = None,
    seconds: float | None = None,
    rate: float = 120.0,
    seed: int = 0,
) -> Motion:
    """A built-in motion clip on ``skeleton``, starting in its T-pose.

    Parameters
    ----------
    name : str
        One of :data:`CLIPS` (see the module docstring for what each does).
    skeleton : Skeleton
        Its zero pose must be a T-pose (arms along ``+-X``, left on ``+X``, facing
        ``+Z``, ``Y`` up, offsets in metres), as :func:`skincap.synth.skeleton.synth_skeleton`
        builds. Joints are found by name (:func:`find_landmarks`); missing limbs stay
        in their rest pose.
    frames : int, optional
        Number of frames. Give ``frames`` or ``seconds`` (or neither: 4 s).
    seconds : float, optional
        Duration; ``round(seconds * rate)`` frames (at least one).
    rate : float, default 120.0
        Frame rate, Hz.
    seed : int, default 0
        Seeds the subtle trunk sway. Same arguments, same bytes.

    Returns
    -------
    Motion
        ``rotations`` (T, J, 4) float64 local unit quaternions ``(x, y, z, w)``
        (identity for the first ``HOLD_SECONDS``); ``translations`` (T, J, 3) float64
        metres: the skeleton offsets, except the root's, which is its world position
        (the rest offset plus the clip's pelvis motion); ``rate`` as given; channels:
        six for the root, three rotations for the other joints, none for end sites
        (childless joints). ``meta``: ``clip``, ``seed``, ``source_units`` ``"m"``,
        ``up`` ``"y"``, ``hold_seconds``. Never NaN.

    Raises
    ------
    ValidationError
        Unknown clip name, bad ``frames``/``seconds``/``rate``/``seed``, or not a
        Skeleton.

    Examples
    --------
    >>> from skincap.synth.skeleton import synth_skeleton
    >>> motion = make_clip("flex", synth_skeleton(), seconds=2.0)
    >>> motion.rotations.shape[0]
    240
    """
    if not isinstance(name, str) or name not in _CLIP_FUNCS:
        raise ValidationError(f"name: expected one of {', '.join(CLIPS)}, got {name!r}")
    if not isinstance(skeleton, Skeleton):
        raise ValidationError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    r = check_positive(
        "rate",
        rate,
        expected="a positive number in Hz",
        expected_finite="a positive finite frame rate in Hz",
    )
    if not CLIP_RATE_RANGE[0] <= r <= CLIP_RATE_RANGE[1]:
        raise ValidationError(
            f"rate: expected {CLIP_RATE_RANGE[0]:g}..{CLIP_RATE_RANGE[1]:g} Hz, got {r:g}"
        )
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValidationError(f"seed: expected a non-negative integer, got {seed!r}")
    n = clip_frame_count(frames, seconds, r)
    t = np.arange(n) / r  # (T,) seconds
    env = quintic((t - HOLD_SECONDS) / BLEND_SECONDS)  # (T,) 0 during the hold
    pose = ClipPose(skeleton, n)
    rng = np.random.default_rng(int(seed))
    _CLIP_FUNCS[name](pose, t, env, rng)
    return pose.motion(
        r,
        {
            "clip": name,
            "seed": int(seed),
            "source_units": "m",
            "up": "y",
            "hold_seconds": HOLD_SECONDS,
        },
    )
