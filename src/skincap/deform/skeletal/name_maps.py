"""Built-in joint-name maps: each known rig convention mapped to canonical body landmarks.

A *landmark* is a joint whose rotation drives one body segment (the segment runs from
that joint to the next landmark down the chain): ``hips`` (pelvis and root motion),
``spine``, ``chest``, ``upper_chest``, ``neck``, ``neck_upper``, ``head``, and per side
(``_l`` / ``_r``) ``clavicle``, ``upperarm``, ``forearm``, ``hand``, ``thigh``,
``shin``, ``foot``, ``toe``. A convention maps a landmark to one joint name, or to a
tuple of sibling joints that move together (MakeHuman's five toes for one BVH toe).
Conventions need not name every landmark (the classic Biovision set has no ``spine``
and no ``toe``); retargeting pairs the landmarks both skeletons have.

Conventions built in, for the skeletons in skincap's test data and their families:

``cmu_bvh11``
    CMU motion capture converted with the old ``amc2bvh`` naming (``LeftHip``,
    ``LeftKnee``, ``lowerback``, ``Chest``, ``Chest2``, ``lowerneck``, ``lhand``,
    ``LeftToe``...), as in ``cmu_131_01_bvh11.bvh``.
``cmu_cgspeed``
    The cgspeed (Bruce Hahne) BVH release of the CMU database (``LeftUpLeg``,
    ``LeftLeg``, ``LeftFoot``, ``LeftToeBase``, ``LowerBack``, ``Spine``, ``Spine1``,
    ``Neck1``, ``LeftArm``, ``LeftForeArm``, ``LeftHand``...).
``mixamo``
    Adobe Mixamo's rig (``Hips``, ``Spine``, ``Spine1``, ``Spine2``, ``Neck``, ``Head``,
    ``LeftShoulder``, ``LeftArm``, ``LeftForeArm``, ``LeftHand``, ``LeftUpLeg``,
    ``LeftLeg``, ``LeftFoot``, ``LeftToeBase``...), usually under a ``mixamorig:``
    namespace, which retargeting looks past.
``biovision``
    The classic Biovision set (``Hips``, ``Chest``, ``Chest2``, ``LeftCollar``,
    ``LeftShoulder``, ``LeftElbow``, ``LeftWrist``, ``LeftHip``, ``LeftKnee``,
    ``LeftAnkle``...), as in ``bvhtoolbox_test_mocapbank.bvh``.
``makehuman``
    The MakeHuman default rig (163 bones: ``root``, ``spine05``..``spine01``,
    ``neck01``..``neck03``, ``clavicle.L``, ``upperarm01.L``, ``lowerarm01.L``,
    ``wrist.L``, ``upperleg01.L``, ``lowerleg01.L``, ``foot.L``, ``toe1-1.L``...).
    MakeHuman splits segments into chains (``upperarm01.L`` + ``upperarm02.L``,
    ``spine05`` + ``spine04``); only the first bone of a chain is a landmark, the rest
    follow it rigidly during retargeting.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "LANDMARKS",
    "CONVENTIONS",
    "bare_names",
    "convention_joints",
    "detect_convention",
]

#: Canonical landmarks, parents before children.
LANDMARKS: tuple[str, ...] = (
    "hips",
    "spine",
    "chest",
    "upper_chest",
    "neck",
    "neck_upper",
    "head",
    "clavicle_l",
    "upperarm_l",
    "forearm_l",
    "hand_l",
    "clavicle_r",
    "upperarm_r",
    "forearm_r",
    "hand_r",
    "thigh_l",
    "shin_l",
    "foot_l",
    "toe_l",
    "thigh_r",
    "shin_r",
    "foot_r",
    "toe_r",
)


def _sided(left: dict[str, str | tuple[str, ...]], mirror: dict[str, str]) -> dict:
    """Left-side entries plus their right-side copies (``mirror`` maps substrings)."""
    out: dict[str, str | tuple[str, ...]] = {}
    for key, value in left.items():
        out[key + "_l"] = value
        names = (value,) if isinstance(value, str) else value
        right = []
        for name in names:
            for a, b in mirror.items():
                name = name.replace(a, b)
            right.append(name)
        out[key + "_r"] = right[0] if isinstance(value, str) else tuple(right)
    return out


#: Landmark -> joint name (or tuple of joint names) per convention.
#: The limbs of the rigs that name them LeftArm / LeftForeArm / LeftUpLeg (CMU's cgspeed
#: conversions and Mixamo, whose spines differ).
_LIMBS_LEFT_ARM_UP_LEG = _sided(
    {
        "clavicle": "LeftShoulder",
        "upperarm": "LeftArm",
        "forearm": "LeftForeArm",
        "hand": "LeftHand",
        "thigh": "LeftUpLeg",
        "shin": "LeftLeg",
        "foot": "LeftFoot",
        "toe": "LeftToeBase",
    },
    {"Left": "Right"},
)

CONVENTIONS: dict[str, dict[str, str | tuple[str, ...]]] = {
    "cmu_bvh11": {
        "hips": "Hips",
        "spine": "lowerback",
        "chest": "Chest",
        "upper_chest": "Chest2",
        "neck": "lowerneck",
        "neck_upper": "Neck",
        "head": "Head",
        **_sided(
            {
                "clavicle": "LeftCollar",
                "upperarm": "LeftShoulder",
                "forearm": "LeftElbow",
                "hand": "lhand",
                "thigh": "LeftHip",
                "shin": "LeftKnee",
                "foot": "LeftAnkle",
                "toe": "LeftToe",
            },
            {"Left": "Right", "lhand": "rhand"},
        ),
    },
    "cmu_cgspeed": {
        "hips": "Hips",
        "spine": "LowerBack",
        "chest": "Spine",
        "upper_chest": "Spine1",
        "neck": "Neck",
        "neck_upper": "Neck1",
        "head": "Head",
        **_LIMBS_LEFT_ARM_UP_LEG,
    },
    "mixamo": {
        "hips": "Hips",
        "spine": "Spine",
        "chest": "Spine1",
        "upper_chest": "Spine2",
        "neck": "Neck",
        "head": "Head",
        **_LIMBS_LEFT_ARM_UP_LEG,
    },
    "biovision": {
        "hips": "Hips",
        "chest": "Chest",
        "upper_chest": "Chest2",
        "neck": "Neck",
        "head": "Head",
        **_sided(
            {
                "clavicle": "LeftCollar",
                "upperarm": "LeftShoulder",
                "forearm": "LeftElbow",
                "hand": "LeftWrist",
                "thigh": "LeftHip",
                "shin": "LeftKnee",
                "foot": "LeftAnkle",
            },
            {"Left": "Right"},
        ),
    },
    "makehuman": {
        "hips": "root",
        "spine": "spine05",
        "chest": "spine03",
        "upper_chest": "spine01",
        "neck": "neck01",
        "neck_upper": "neck03",
        "head": "head",
        **_sided(
            {
                "clavicle": "clavicle.L",
                "upperarm": "upperarm01.L",
                "forearm": "lowerarm01.L",
                "hand": "wrist.L",
                "thigh": "upperleg01.L",
                "shin": "lowerleg01.L",
                "foot": "foot.L",
                "toe": ("toe1-1.L", "toe2-1.L", "toe3-1.L", "toe4-1.L", "toe5-1.L"),
            },
            {".L": ".R"},
        ),
    },
}

#: A convention is recognised when at least this share of its joint names is present.
_MIN_SHARE = 0.8


def convention_joints(convention: str) -> list[str]:
    """All joint names a convention uses (tuples flattened), in landmark order."""
    out: list[str] = []
    for value in CONVENTIONS[convention].values():
        out.extend((value,) if isinstance(value, str) else value)
    return out


def bare_names(names: Sequence[str]) -> dict[str, int]:
    """Joint name without its namespace (the text after the last ``:``, so Mixamo's
    ``mixamorig:Hips`` is ``Hips``) -> index; a bare name two joints share keeps the first."""
    out: dict[str, int] = {}
    for i, name in enumerate(names):
        out.setdefault(name.rsplit(":", 1)[-1], i)
    return out


def detect_convention(names: Sequence[str]) -> str | None:
    """Name of the built-in convention a skeleton's joint names follow, or None.

    A convention qualifies when at least 80 % of its joint names are among ``names``;
    among those, the one with the most names present wins (so a CMU ``bvh11``
    skeleton, which also contains every Biovision name, is recognised as
    ``cmu_bvh11``), ties going to the larger share.

    Parameters
    ----------
    names : sequence of str
        The skeleton's joint names (case-sensitive).

    Returns
    -------
    str or None
        A key of :data:`CONVENTIONS`.
    """
    present = set(names)
    best: tuple[int, float, str] | None = None
    for conv in CONVENTIONS:
        joints = convention_joints(conv)
        hits = sum(1 for j in joints if j in present)
        share = hits / len(joints)
        if share < _MIN_SHARE:
            continue
        key = (hits, share, conv)
        if best is None or key[:2] > best[:2]:
            best = key
    return None if best is None else best[2]
