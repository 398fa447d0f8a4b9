"""A clean synthetic skeleton in a T-pose with the CMU ``bvh11`` joint names.

The hierarchy is exactly that of the CMU database converted with the old ``amc2bvh``
naming (``tests/data/cmu_131_01_bvh11.bvh``): the same 38 joints in the same
depth-first order, including the zero-length helper joints (``LHipJoint``,
``lowerback``, ``lowerneck``, ``LeftCollar``, ``lhand``) and the end sites, named
``<parent>_end`` like :func:`skincap.io.bvh.read_bvh` names them. So
:mod:`skincap.deform.skeletal.retarget`'s built-in ``cmu_bvh11`` map recognises it and any
CMU ``bvh11`` motion plays on it joint for joint.

The proportions are not the capture's but a symmetric adult's, from the classic
segment-length fractions of stature (Drillis & Contini 1966, as tabulated by Winter,
*Biomechanics and Motor Control of Human Movement*): hip joint at 0.525 H, knee at
0.285 H, ankle at 0.045 H, shoulder joint at 0.80 H, upper arm 0.186 H, forearm
0.146 H, hand 0.108 H, foot 0.152 H. Identity local rotations give the T-pose:
facing +Z, Y up, the body's left on +X, arms straight out along +-X with the palms
down, legs straight down and the soles on ``y = 0``.
"""

from __future__ import annotations

import math

import numpy as np

from skincap.errors import ValidationError
from skincap.types import Skeleton

__all__ = ["synth_skeleton", "SYNTH_JOINTS"]

# (name, parent name, offset from the parent as fractions of the height H) for the
# left side and the spine; the right side mirrors the left (x -> -x). Order is the
# file's depth-first order.
_LEFT_LEG = (
    ("LHipJoint", "Hips", (0.0, 0.0, 0.0)),
    ("LeftHip", "LHipJoint", (0.055, -0.030, 0.0)),  # hip joint centre at 0.525 H
    ("LeftKnee", "LeftHip", (0.0, -0.240, 0.0)),  # knee at 0.285 H
    ("LeftAnkle", "LeftKnee", (0.0, -0.240, 0.0)),  # ankle at 0.045 H
    ("LeftToe", "LeftAnkle", (0.0, -0.033, 0.070)),  # ball of the foot, 0.012 H high
    ("LeftToe_end", "LeftToe", (0.0, 0.0, 0.038)),  # tip of the big toe (foot 0.152 H)
)
_SPINE = (
    ("lowerback", "Hips", (0.0, 0.0, 0.0)),
    ("Chest", "lowerback", (0.0, 0.075, 0.0)),  # 0.630 H
    ("Chest2", "Chest", (0.0, 0.085, 0.0)),  # 0.715 H
    ("lowerneck", "Chest2", (0.0, 0.0, 0.0)),
    ("Neck", "lowerneck", (0.0, 0.110, 0.0)),  # base of the neck (C7), 0.825 H
    ("Head", "Neck", (0.0, 0.065, 0.0)),  # skull base, 0.890 H
    ("Head_end", "Head", (0.0, 0.075, 0.0)),  # crown, inside the head, 0.965 H
)
_LEFT_ARM = (
    ("LeftCollar", "Chest2", (0.0, 0.0, 0.0)),
    ("LeftShoulder", "LeftCollar", (0.100, 0.085, 0.0)),  # glenohumeral joint, 0.80 H
    ("LeftElbow", "LeftShoulder", (0.186, 0.0, 0.0)),
    ("LeftWrist", "LeftElbow", (0.146, 0.0, 0.0)),
    ("lhand", "LeftWrist", (0.0, 0.0, 0.0)),
    ("LFingers", "lhand", (0.048, 0.0, 0.0)),  # knuckles
    ("LFingers_end", "LFingers", (0.055, 0.0, 0.0)),  # finger tips, 0.103 H from the wrist
    ("LThumb", "LeftWrist", (0.010, -0.004, 0.012)),
    ("LThumb_end", "LThumb", (0.025, 0.0, 0.010)),
)

_RIGHT_NAMES = {
    "LHipJoint": "RHipJoint",
    "LeftCollar": "RightCollar",
    "lhand": "rhand",
    "LFingers": "RFingers",
    "LThumb": "RThumb",
}


def _mirror_name(name: str) -> str:
    """Right-side name of a left-side joint (``LeftHip`` -> ``RightHip``)."""
    base, end = (name[:-4], "_end") if name.endswith("_end") else (name, "")
    if base in _RIGHT_NAMES:
        return _RIGHT_NAMES[base] + end
    if base.startswith("Left"):
        return "Right" + base[4:] + end
    raise ValueError(f"no mirror rule for joint {name!r}")  # pragma: no cover - static table


def _mirror(rows: tuple[tuple[str, str, tuple[float, float, float]], ...]) -> tuple:
    out = []
    for name, parent, (x, y, z) in rows:
        p = parent if parent in ("Hips", "Chest2") else _mirror_name(parent)
        out.append((_mirror_name(name), p, (-x, y, z)))
    return tuple(out)


#: The synthetic skeleton's rows ``(name, parent, offset / height)`` in file order.
SYNTH_JOINTS: tuple[tuple[str, str | None, tuple[float, float, float]], ...] = (
    (("Hips", None, (0.0, 0.555, 0.0)),)
    + _LEFT_LEG
    + _mirror(_LEFT_LEG)
    + _SPINE[:4]
    + _SPINE[4:]
    + _LEFT_ARM
    + _mirror(_LEFT_ARM)
)


def synth_skeleton(height: float = 1.75) -> Skeleton:
    """A symmetric adult skeleton in a T-pose with the CMU ``bvh11`` hierarchy.

    Parameters
    ----------
    height : float, default 1.75
        Stature in metres (floor to the top of the head of a body built on it, e.g.
        :func:`skincap.synth.body.procedural_body`). Every offset scales with it.

    Returns
    -------
    Skeleton
        38 joints with the names, parents and order of ``cmu_131_01_bvh11.bvh``
        (end sites ``Head_end``, ``LeftToe_end``, ``LFingers_end``, ``LThumb_end``...
        included). ``offsets`` (38, 3) float64 in metres, Y up, facing +Z, the left
        side on +X; the root ``Hips`` is placed at ``(0, 0.555 * height, 0)`` so that
        with identity local rotations the ankles are at ``0.045 * height`` and the
        balls of the feet at ``0.012 * height`` above the floor ``y = 0``, arms along
        +-X at shoulder height ``0.80 * height``. Exactly mirror-symmetric in x.

    Raises
    ------
    ValidationError
        ``height`` is not a finite number in (0.3, 3.0] metres.

    Examples
    --------
    >>> sk = synth_skeleton(1.80)
    >>> sk.names[:3]
    ['Hips', 'LHipJoint', 'LeftHip']
    """
    try:
        h = float(height)
    except (TypeError, ValueError):
        raise ValidationError(f"height: expected a number of metres, got {height!r}") from None
    if not math.isfinite(h) or not 0.3 < h <= 3.0:
        raise ValidationError(f"height: expected metres in (0.3, 3.0], got {height!r}")
    names = [row[0] for row in SYNTH_JOINTS]
    index = {n: k for k, n in enumerate(names)}
    parents = np.array(
        [-1 if row[1] is None else index[row[1]] for row in SYNTH_JOINTS], dtype=np.int64
    )
    offsets = np.array([row[2] for row in SYNTH_JOINTS], dtype=np.float64) * h
    return Skeleton(names=names, parents=parents, offsets=offsets)
