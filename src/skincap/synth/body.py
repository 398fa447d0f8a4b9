"""A procedural human body: elliptic cross-sections swept along the bones.

The body follows Hyun et al., *Sweep-based human deformation* (§3): every part --
torso, neck, head, and per side the arm (upper arm and forearm), hand, leg (thigh and
shin) and foot -- is a sweep (:class:`skincap.geometry.sweep.Sweep`) of key ellipses
placed along the bones of a T-pose skeleton (:func:`skincap.synth.skeleton.synth_skeleton`),
with half-axes from adult anthropometry (for a 1.75 m body, scaled with the height:
chest 32 x 24 cm, waist 28 x 20 cm, hips 33 x 22 cm, upper arm 9 cm, thigh 16 x 18 cm
at the crotch, head 15 x 20 cm...). The parts are not stitched: each gives an
approximate signed distance (:meth:`Sweep.signed_distance`); their smooth union
(the log-sum-exp of :func:`skincap.geometry.sweep.smooth_union`, blend length 1 cm,
accumulated part by part so each part is evaluated only inside its own box) is one
implicit body whose zero set has fillets at the shoulders, hips and neck. The field is sampled
on a regular grid (each part only inside its own box) and meshed by marching
tetrahedra (:func:`skincap.geometry.isosurface.marching_tetrahedra`), welded into one
closed, oriented, genus-0 surface, then relaxed on the level set to even out the
triangles.

The grid step is chosen from the requested vertex count (marching tetrahedra gives
about 4.5 vertices per ``h²`` of surface): a first pass measures the count and, when
it misses by more than 8 %, a second pass corrects the step. At coarse resolutions
half-axes are raised to at least 0.6 grid steps so thin parts (fingers, wrists) stay
connected: a 5 000-vertex body has thicker hands.

Skin weights come from the sweeps themselves: each vertex belongs to the part whose
surface is nearest (and, softly, to the parts adjacent to it within a few
centimetres, ``exp(-Δd / 1.2 cm)``); within a part, its binding parameter ``t``
(:meth:`Sweep.locate`) places it along the part's bones, and the weight moves from
one bone's head joint to the next with a smooth step a few centimetres wide around
each joint. At most four influences are kept and renormalised. The bind pose is the
skeleton's rest pose (identity rotations at the rest joint positions).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skincap.deform.skeletal.bind import rest_transforms
from skincap.deform.skeletal.weights import limit_influences
from skincap.errors import ValidationError
from skincap.geometry.isosurface import marching_tetrahedra, relax_on_isosurface
from skincap.geometry.kinematics import rest_positions
from skincap.geometry.sweep import KeyEllipses, Sweep, frames_from_axes
from skincap.synth.skeleton import SYNTH_JOINTS
from skincap.types import Mesh, Skeleton, Skin

__all__ = ["procedural_body", "body_parts", "BodyPart", "VERTEX_COUNT_RANGE"]

#: Vertex counts :func:`procedural_body` builds, inclusive.
VERTEX_COUNT_RANGE = (2_000, 200_000)

#: Reference stature of the radii below (metres).
_REF_HEIGHT = 1.75
#: Marching tetrahedra: vertices per (surface area / grid step²), measured.
_VERTS_PER_AREA = 4.46
#: Adult body surface area at the reference height (m²), the first guess.
_REF_AREA = 1.9
#: Blend length of the smooth union and of the weights between parts (m at 1.75 m).
_BLEND = 0.010
_WEIGHT_BLEND = 0.012


@dataclass(eq=False)
class BodyPart:
    """One swept part of the body.

    Attributes
    ----------
    name : str
        ``torso``, ``neck``, ``head``, ``arm_l``, ``hand_l``, ``leg_l``, ``foot_l``...
    sweep : Sweep
    joints : list of str
        Joints whose bones the part follows, in order along the sweep.
    breaks : (len(joints) - 1,) float
        Positions (metres along the part's axis ``N(t_0)``, from its first centre)
        where the weight passes from one joint to the next.
    width : float
        Width (metres) of each weight transition.
    adjacent : list of str
        Parts it blends with.
    """

    name: str
    sweep: Sweep
    joints: list[str]
    breaks: np.ndarray
    width: float
    adjacent: list[str] = field(default_factory=list)


def _height_of(skeleton: Skeleton, pos: np.ndarray) -> float:
    """Stature implied by a synth skeleton: the crown joint sits at a fixed fraction."""
    rows = {name: (parent, off) for name, parent, off in SYNTH_JOINTS}
    frac, name = 0.0, "Head_end"
    while name is not None:
        parent, off = rows[name]
        frac += off[1]
        name = parent
    return float(pos[skeleton.index("Head_end"), 1] / frac)


def _check_skeleton(skeleton: object) -> tuple[Skeleton, dict[str, np.ndarray]]:
    if not isinstance(skeleton, Skeleton):
        raise ValidationError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    missing = [row[0] for row in SYNTH_JOINTS if row[0] not in skeleton.names]
    if missing:
        raise ValidationError(
            f"skeleton: not a synth (CMU bvh11) skeleton, missing joints {missing[:5]}"
        )
    p = rest_positions(skeleton)
    pos = {n: p[k] for k, n in enumerate(skeleton.names)}

    def direction(a: str, b: str) -> np.ndarray:
        d = pos[b] - pos[a]
        n = np.linalg.norm(d)
        if n <= 0:
            raise ValidationError(f"skeleton: joints {a} and {b} coincide")
        return d / n

    checks = [
        ("LeftShoulder", "LeftElbow", (1, 0, 0)),
        ("LeftElbow", "LeftWrist", (1, 0, 0)),
        ("RightShoulder", "RightElbow", (-1, 0, 0)),
        ("RightElbow", "RightWrist", (-1, 0, 0)),
        ("LeftHip", "LeftKnee", (0, -1, 0)),
        ("LeftKnee", "LeftAnkle", (0, -1, 0)),
        ("RightHip", "RightKnee", (0, -1, 0)),
        ("RightKnee", "RightAnkle", (0, -1, 0)),
        ("Chest", "Neck", (0, 1, 0)),
    ]
    for a, b, want in checks:
        if np.dot(direction(a, b), want) < np.cos(np.radians(15)):
            raise ValidationError(
                f"skeleton: not in a T-pose facing +Z with Y up ({a} -> {b} should point along {want})"
            )
    return skeleton, pos


def _rng_factors(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    return np.clip(1.0 + sigma * rng.standard_normal(n), 1.0 - 3 * sigma, 1.0 + 3 * sigma)


def body_parts(skeleton: Skeleton, *, seed: int = 0, min_radius: float = 0.0) -> list[BodyPart]:
    """The swept parts of the procedural body on a T-pose synth skeleton.

    Parameters
    ----------
    skeleton : Skeleton
        From :func:`~skincap.synth.skeleton.synth_skeleton` (CMU ``bvh11`` names,
        T-pose, metres, Y up, facing +Z).
    seed : int, default 0
        Jitters girths: one overall factor (σ = 4 %) and one per key ellipse
        (σ = 2 %, the same on both sides so the body stays symmetric), clipped to
        3 σ. Lengths are the skeleton's and never change.
    min_radius : float, default 0
        Lower bound for every half-axis (metres).

    Returns
    -------
    list of BodyPart
        ``torso, neck, head, arm_l, hand_l, arm_r, hand_r, leg_l, foot_l, leg_r,
        foot_r``; right parts are exact mirror images of the left ones.

    Raises
    ------
    ValidationError
        Not a synth skeleton in a T-pose.
    """
    skeleton, pos = _check_skeleton(skeleton)
    height = _height_of(skeleton, np.stack(list(pos.values())))
    s = height / _REF_HEIGHT
    rng = np.random.default_rng(seed)
    overall = float(_rng_factors(rng, 1, 0.04)[0])

    def radii(ab: list[tuple[float, float]]) -> np.ndarray:
        r = np.array(ab, dtype=np.float64) * s * overall
        r *= _rng_factors(rng, len(ab), 0.02)[:, None]
        return np.maximum(r, min_radius)

    # the order of the parts is the order of the random girth draws in ``radii``
    body = _Stature(pos, height, s, radii)
    parts = [_torso(body), _neck(body), _head(body)]
    limbs = _left_arm_and_hand(body) + _left_leg_and_foot(body)
    for side, mirror in (("l", False), ("r", True)):
        other = "Right" if mirror else "Left"
        small = "r" if mirror else "l"
        big = "R" if mirror else "L"
        joints = {
            "arm": [f"{other}Shoulder", f"{other}Elbow"],
            "hand": [f"{small}hand", f"{big}Fingers"],
            "leg": [f"{other}Hip", f"{other}Knee"],
            "foot": [f"{other}Ankle", f"{other}Toe"],
        }
        for limb in limbs:
            keys = limb.keys.mirrored(0) if mirror else limb.keys
            parts.append(
                BodyPart(
                    f"{limb.name}_{side}",
                    Sweep(keys, caps=limb.caps),
                    joints[limb.name],
                    limb.breaks,
                    limb.width,
                    [n if n == "torso" else f"{n}_{side}" for n in limb.adjacent],
                )
            )
    return parts


@dataclass(frozen=True)
class _Stature:
    """What every part is sized from: rest joint positions (metres), the height, its
    ratio ``s`` to 1.75 m, and the seeded girths ``radii((a, b) list) -> (K, 2)``."""

    pos: dict[str, np.ndarray]
    height: float
    s: float
    radii: Callable[[list[tuple[float, float]]], np.ndarray]


@dataclass(frozen=True)
class _Limb:
    """A left limb part before it is mirrored: key ellipses, caps, weight breaks and
    width, and its neighbours (``torso`` or a limb name of the same side)."""

    name: str
    keys: KeyEllipses
    caps: tuple[float, float]
    breaks: np.ndarray
    width: float
    adjacent: tuple[str, ...]


_EX, _EY, _EZ = np.eye(3)


def _axial_frames(tangent: np.ndarray, normal: np.ndarray, n: int) -> np.ndarray:
    """(n, 3, 3) the same frame for ``n`` key ellipses along one axis."""
    return frames_from_axes(np.tile(tangent, (n, 1)), np.tile(normal, (n, 1)))


def _vertical_keys(b: _Stature, rows: list[tuple[float, float, float, float]]) -> KeyEllipses:
    """Key ellipses stacked up the body's axis from ``(y, a, b, z)`` rows: height y
    (metres), half-width and half-depth a, b and centroid z (metres at 1.75 m)."""
    c = np.array([[0.0, y, z * b.s] for y, _, _, z in rows])
    r = b.radii([(a, bb) for _, a, bb, _ in rows])
    return KeyEllipses.from_frames(c, _axial_frames(_EY, _EX, len(rows)), r)


def _torso(b: _Stature) -> BodyPart:
    """Hips to shoulders, eight key ellipses."""
    pos, height, s = b.pos, b.height, b.s
    y_hip = pos["LeftHip"][1]
    y_hips, y_chest, y_chest2 = pos["Hips"][1], pos["Chest"][1], pos["Chest2"][1]
    y_sh = pos["LeftShoulder"][1]
    torso = [  # (y, a (half-width), b (half-depth), z of the centroid), m at 1.75 m
        (y_hip - 0.045 * height, 0.135, 0.095, -0.005),
        (y_hip, 0.160, 0.110, -0.010),
        (y_hips + 0.02 * height, 0.163, 0.108, -0.010),
        (y_chest - 0.01 * height, 0.138, 0.098, 0.000),
        (y_chest + 0.4 * (y_chest2 - y_chest), 0.148, 0.108, 0.005),
        (y_chest2 + 0.02 * height, 0.158, 0.118, 0.008),
        (y_sh - 0.02 * height, 0.168, 0.110, 0.000),
        (y_sh + 0.015 * height, 0.140, 0.085, -0.010),
    ]
    keys = _vertical_keys(b, torso)
    return BodyPart(
        "torso",
        Sweep(keys, caps=(0.035 * s, 0.045 * s)),
        ["Hips", "lowerback", "Chest", "Chest2"],
        np.array([y_hips, y_chest, y_chest2]) + 0.01 * height - keys.centres[0, 1],
        0.04 * height,
        ["neck", "arm_l", "arm_r", "leg_l", "leg_r"],
    )


def _neck(b: _Stature) -> BodyPart:
    """Neck base to skull, three key ellipses."""
    pos, height, s = b.pos, b.height, b.s
    y_neck, y_head = pos["Neck"][1], pos["Head"][1]
    neck = [
        (y_neck - 0.03 * height, 0.068, 0.070, -0.005),
        (y_neck + 0.02 * height, 0.057, 0.060, 0.000),
        (y_head + 0.005 * height, 0.055, 0.060, 0.005),
    ]
    keys = _vertical_keys(b, neck)
    return BodyPart(
        "neck",
        Sweep(keys, caps=(0.02 * s, 0.02 * s)),
        ["lowerneck", "Neck"],
        np.array([y_neck - keys.centres[0, 1]]),
        0.03 * height,
        ["torso", "head"],
    )


def _head(b: _Stature) -> BodyPart:
    """Jaw to crown, three key ellipses; the top cap reaches the stature."""
    height = b.height
    head = [
        (0.895 * height, 0.060, 0.080, 0.018),
        (0.930 * height, 0.075, 0.098, 0.012),
        (0.955 * height, 0.076, 0.098, 0.008),
    ]
    keys = _vertical_keys(b, head)
    return BodyPart(
        "head",
        Sweep(keys, caps=(0.025 * height, height - keys.centres[-1, 1])),
        ["Head"],
        np.zeros(0),
        0.03 * height,
        ["neck"],
    )


def _left_arm_and_hand(b: _Stature) -> list[_Limb]:
    """Upper arm and forearm along +X from the shoulder, then the hand to the fingertips."""
    pos, height, s = b.pos, b.height, b.s
    sh, el, wr = pos["LeftShoulder"], pos["LeftElbow"], pos["LeftWrist"]
    kn = pos["LFingers"]
    l1, l2 = el[0] - sh[0], wr[0] - el[0]
    arm = [  # (x from the shoulder, a (vertical), b (front-back))
        (0.0, 0.050, 0.056),
        (0.05 * s, 0.050, 0.052),
        (0.16 * s, 0.043, 0.045),
        (l1, 0.037, 0.040),
        (l1 + 0.06 * s, 0.040, 0.043),
        (l1 + l2 - 0.03 * s, 0.025, 0.032),
        (l1 + l2, 0.021, 0.030),
    ]
    c = np.array([[sh[0] + x, sh[1], sh[2]] for x, _, _ in arm])
    fr = _axial_frames(_EX, _EY, len(arm))
    arm_l = KeyEllipses.from_frames(c, fr, b.radii([(a, bb) for _, a, bb in arm]))
    hand = [
        (0.0, 0.021, 0.030),
        (0.03 * s, 0.018, 0.040),
        (kn[0] - wr[0], 0.014, 0.043),
        (0.13 * s, 0.011, 0.038),
        (0.165 * s, 0.009, 0.032),
    ]
    c = np.array([[wr[0] + x, wr[1], wr[2]] for x, _, _ in hand])
    fr = _axial_frames(_EX, _EY, len(hand))
    hand_l = KeyEllipses.from_frames(c, fr, b.radii([(a, bb) for _, a, bb in hand]))
    tip = pos["LFingers_end"][0] + 0.005 * height
    hand_caps = (0.01 * s, max(tip - c[-1, 0], 0.01 * s))
    return [
        _Limb("arm", arm_l, (0.04 * s, 0.01 * s), np.array([l1]), 0.045 * height,
              ("torso", "hand")),
        _Limb("hand", hand_l, hand_caps, np.array([kn[0] - wr[0]]), 0.02 * height, ("arm",)),
    ]  # fmt: skip


def _left_leg_and_foot(b: _Stature) -> list[_Limb]:
    """Thigh and shin down from the hip, then the foot forward to the toe tip."""
    pos, height, s = b.pos, b.height, b.s
    hp, knee, ank, toe = pos["LeftHip"], pos["LeftKnee"], pos["LeftAnkle"], pos["LeftToe"]
    d1, d2 = hp[1] - knee[1], knee[1] - ank[1]
    leg = [  # (depth below the hip joint, a (side), b (front-back), z of the centroid)
        (0.0, 0.080, 0.092, 0.005),
        (0.06 * s, 0.080, 0.090, 0.005),
        (0.13 * s, 0.072, 0.080, 0.000),
        (d1 - 0.06 * s, 0.058, 0.062, 0.000),
        (d1, 0.052, 0.056, 0.000),
        (d1 + 0.12 * s, 0.050, 0.058, -0.012),
        (d1 + d2 - 0.06 * s, 0.033, 0.036, -0.004),
        (d1 + d2, 0.032, 0.034, 0.000),
    ]
    c = np.array([[hp[0], hp[1] - y, hp[2] + z * s] for y, _, _, z in leg])
    fr = _axial_frames(-_EY, _EX, len(leg))
    leg_l = KeyEllipses.from_frames(c, fr, b.radii([(a, bb) for _, a, bb, _ in leg]))
    foot = [  # (z from the ankle, a (half-width), b (half-height; the sole is at y = 0))
        (-0.045 * s, 0.030, 0.035),
        (0.0, 0.034, 0.048),
        (0.055 * s, 0.040, 0.036),
        (toe[2] - ank[2], 0.046, 0.022),
        (0.175 * s, 0.040, 0.016),
    ]
    r = b.radii([(a, bb) for _, a, bb in foot])
    c = np.array([[ank[0], rb, ank[2] + z] for (z, _, _), rb in zip(foot, r[:, 1], strict=True)])
    fr = _axial_frames(_EZ, _EX, len(foot))
    foot_l = KeyEllipses.from_frames(c, fr, r)
    toe_tip = pos["LeftToe_end"][2] + 0.007 * height
    foot_caps = (0.025 * s, max(toe_tip - c[-1, 2], 0.01 * s))
    return [
        _Limb("leg", leg_l, (0.06 * s, 0.03 * s), np.array([d1]), 0.05 * height,
              ("torso", "foot")),
        _Limb("foot", foot_l, foot_caps, np.array([toe[2] - ank[2] + 0.045 * s]),
              0.03 * height, ("leg",)),
    ]  # fmt: skip


def _part_box(part: BodyPart, margin: float) -> np.ndarray:
    v, _ = part.sweep.tube(24, 24, cap_rings=4)
    return np.stack([v.min(axis=0) - margin, v.max(axis=0) + margin])


def _part_distances(
    parts: list[BodyPart], points: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """(n_parts, P) signed distances (+inf outside a part's box) and binding params."""
    n = points.shape[0]
    d = np.full((len(parts), n), np.inf)
    t = np.full((len(parts), n), np.nan)
    for i, part in enumerate(parts):
        box = _part_box(part, margin)
        sel = np.nonzero(((points >= box[0]) & (points <= box[1])).all(axis=1))[0]
        if sel.size:
            d[i, sel] = part.sweep.signed_distance(points[sel])
            t[i, sel] = part.sweep.locate(points[sel])[0]
    return d, t


def _field(
    parts: list[BodyPart], height: float, h: float, blend: float
) -> tuple[np.ndarray, np.ndarray]:
    """The body's implicit field on a grid of step h: values (nx, ny, nz) and origin."""
    margin = 6.0 * blend
    boxes = np.stack([_part_box(p, 2 * h) for p in parts])
    lo, hi = boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)
    # x nodes symmetric about 0 so the left and right halves are sampled alike
    half_x = int(np.ceil(max(-lo[0], hi[0]) / h))
    nx = 2 * half_x + 1
    ny = int(np.ceil((hi[1] - lo[1]) / h)) + 1
    nz = int(np.ceil((hi[2] - lo[2]) / h)) + 1
    origin = np.array([-half_x * h, lo[1], lo[2]])
    acc = np.zeros((nx, ny, nz))
    for part in parts:
        box = _part_box(part, margin)
        i0 = np.clip(np.floor((box[0] - origin) / h).astype(int), 0, None)
        i1 = np.minimum(np.ceil((box[1] - origin) / h).astype(int) + 1, [nx, ny, nz])
        axes = [origin[a] + h * np.arange(i0[a], i1[a]) for a in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        d = part.sweep.signed_distance(grid.reshape(-1, 3)).reshape(grid.shape[:3])
        # Σ exp(-d / k), the smooth union's sum; d >= -height keeps it finite
        acc[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]] += np.exp(
            -np.clip(d, -height, margin) / blend
        )
    tiny = np.exp(-margin / blend)
    values = -blend * np.log(np.maximum(acc, tiny))
    values[values == 0.0] = 1e-12  # no node exactly on the level
    return values, origin


def _weights(
    parts: list[BodyPart], skeleton: Skeleton, vertices: np.ndarray, blend: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skin weights (V, 4) and the dominant part of each vertex."""
    names = [p.name for p in parts]
    d, t = _part_distances(parts, vertices, 8.0 * blend)
    dom = np.argmin(d, axis=0)  # (V,)
    adj = np.eye(len(parts), dtype=bool)
    for i, p in enumerate(parts):
        for other in p.adjacent:
            adj[i, names.index(other)] = True
    allowed = adj[dom].T  # (n_parts, V)
    dmin = d[dom, np.arange(d.shape[1])]
    logits = np.where(allowed & np.isfinite(d), -(d - dmin[None]) / blend, -np.inf)
    pw = np.exp(logits)
    pw /= pw.sum(axis=0, keepdims=True)
    n_v = vertices.shape[0]
    dense = np.zeros((n_v, skeleton.n_joints))
    for i, p in enumerate(parts):
        use = pw[i] > 1e-6
        if not use.any():
            continue
        tt = t[i, use]
        c = p.sweep.centres(tt)
        c0 = p.sweep.keys.centres[0]
        axis = p.sweep.frames(np.array([p.sweep.t_range[0]]))[0, :, 2]
        s = (c - c0) @ axis  # metres along the part
        w = np.ones((tt.size, 1))
        for b in p.breaks:
            x = np.clip((s - b) / p.width + 0.5, 0.0, 1.0)
            step = x * x * (3.0 - 2.0 * x)  # smoothstep
            w = np.concatenate(
                [w[:, :-1], w[:, -1:] * (1.0 - step)[:, None], w[:, -1:] * step[:, None]], axis=1
            )
        joints = [skeleton.index(j) for j in p.joints]
        for k, j in enumerate(joints):
            dense[use, j] += pw[i, use] * w[:, k]
    # collars: the top of the torso towards each shoulder follows the clavicle
    y_c2 = rest_positions(skeleton)[skeleton.index("Chest2"), 1]
    hgt = _height_of(skeleton, rest_positions(skeleton))
    torso_w = dense[:, skeleton.index("Chest2")].copy()
    ax = np.clip((np.abs(vertices[:, 0]) - 0.06 * hgt) / (0.04 * hgt), 0.0, 1.0)
    ay = np.clip((vertices[:, 1] - y_c2) / (0.04 * hgt), 0.0, 1.0)
    share = (ax * ax * (3 - 2 * ax)) * (ay * ay * (3 - 2 * ay)) * torso_w
    dense[:, skeleton.index("Chest2")] -= share
    left = vertices[:, 0] > 0
    dense[left, skeleton.index("LeftCollar")] += share[left]
    dense[~left, skeleton.index("RightCollar")] += share[~left]
    order = np.argsort(-dense, axis=1, kind="stable")[:, :4]
    idx, wts = limit_influences(order, np.take_along_axis(dense, order, axis=1), 4)
    return idx, wts, dom


def procedural_body(
    skeleton: Skeleton,
    *,
    n_vertices: int = 20_000,
    seed: int = 0,
    relax_iterations: int = 6,
) -> Mesh:
    """A closed, manifold, skinned human mesh swept along a T-pose skeleton.

    Parameters
    ----------
    skeleton : Skeleton
        From :func:`~skincap.synth.skeleton.synth_skeleton` (any height): CMU
        ``bvh11`` joint names, T-pose with identity rotations, metres, Y up,
        facing +Z, the left on +X.
    n_vertices : int, default 20000
        Target vertex count, 2 000 .. 200 000; the result is within about 10 %
        (the grid step is corrected once after a first pass).
    seed : int, default 0
        Jitters the girths by a few percent (see :func:`body_parts`); the same seed
        gives the same mesh, bit for bit.
    relax_iterations : int, default 6
        Laplacian-and-project steps evening out the triangles (0: raw marching
        tetrahedra).

    Returns
    -------
    Mesh
        ``vertices`` (V, 3) float64 metres, ``faces`` (F, 3) int64 counter-clockwise
        seen from outside (positive volume); one closed genus-0 surface (Euler
        characteristic 2). ``skin``: (V, 4) joint indices and weights (rows sum to
        1), ``inverse_bind`` the inverse of the rest transforms (identity rotations at
        the rest joint positions). ``meta``: ``"source": "procedural"``,
        ``"height"`` (m), ``"grid_step"`` (m), ``"seed"``, ``"skin_weights":
        "sweep"`` and ``"regions"``: part name -> (k,) int64 indices of the vertices
        that part dominates (``torso``, ``neck``, ``head``, ``arm_l``, ``hand_l``,
        ``leg_l``, ``foot_l``..., and finer ``belly``, ``chest``, ``upper_arm_l``,
        ``forearm_l``, ``thigh_l``, ``shin_l``... with ``_r`` twins). No NaN.

    Raises
    ------
    ValidationError
        Not a synth skeleton in a T-pose, or ``n_vertices`` out of range.
    """
    try:
        target = int(n_vertices)
    except (TypeError, ValueError):
        raise ValidationError(f"n_vertices: expected an integer, got {n_vertices!r}") from None
    low, high = VERTEX_COUNT_RANGE
    if target != n_vertices or not low <= target <= high:
        raise ValidationError(
            f"n_vertices: expected an integer in {low}..{high}, got {n_vertices!r}"
        )
    skeleton, pos = _check_skeleton(skeleton)
    height = _height_of(skeleton, np.stack(list(pos.values())))
    s = height / _REF_HEIGHT
    blend = _BLEND * s
    area = _REF_AREA * s * s
    h = float(np.sqrt(_VERTS_PER_AREA * area / target))
    for _attempt in range(3):
        parts = body_parts(skeleton, seed=seed, min_radius=0.6 * h)
        values, origin = _field(parts, height, h, blend)
        vertices, faces = marching_tetrahedra(values, origin, h)
        ratio = vertices.shape[0] / target
        if abs(ratio - 1.0) <= 0.08:
            break
        h *= float(np.sqrt(ratio))
    if relax_iterations > 0:
        vertices = relax_on_isosurface(
            vertices, faces, values, origin, h, iterations=int(relax_iterations)
        )
    idx, wts, dom = _weights(parts, skeleton, vertices, _WEIGHT_BLEND * s)
    skin = Skin(
        skeleton=skeleton,
        joint_indices=idx,
        joint_weights=wts,
        inverse_bind=np.linalg.inv(rest_transforms(skeleton)),
    )
    regions = _regions(parts, skeleton, vertices, dom, idx, wts, pos, height)
    return Mesh(
        vertices=vertices,
        faces=faces,
        skin=skin,
        meta={
            "source": "procedural",
            "height": height,
            "grid_step": h,
            "seed": int(seed),
            "skin_weights": "sweep",
            "regions": regions,
        },
    )


def _regions(
    parts: list[BodyPart],
    skeleton: Skeleton,
    vertices: np.ndarray,
    dom: np.ndarray,
    idx: np.ndarray,
    wts: np.ndarray,
    pos: dict[str, np.ndarray],
    height: float,
) -> dict[str, np.ndarray]:
    out = {p.name: np.nonzero(dom == i)[0].astype(np.int64) for i, p in enumerate(parts)}
    top = idx[:, 0]  # the joint with the largest weight
    for side, other in (("l", "Left"), ("r", "Right")):
        out[f"upper_arm_{side}"] = np.nonzero(top == skeleton.index(f"{other}Shoulder"))[0]
        out[f"forearm_{side}"] = np.nonzero(top == skeleton.index(f"{other}Elbow"))[0]
        out[f"thigh_{side}"] = np.nonzero(top == skeleton.index(f"{other}Hip"))[0]
        out[f"shin_{side}"] = np.nonzero(top == skeleton.index(f"{other}Knee"))[0]
    torso = out["torso"]
    y, z = vertices[torso, 1], vertices[torso, 2]
    y_hips, y_chest2 = pos["Hips"][1], pos["Chest2"][1]
    out["belly"] = torso[(z > 0) & (y > y_hips) & (y < y_chest2 - 0.02 * height)]
    out["chest"] = torso[(z > 0) & (y >= y_chest2 - 0.02 * height) & (y < pos["LeftShoulder"][1])]
    return {k: np.asarray(v, dtype=np.int64) for k, v in out.items()}
