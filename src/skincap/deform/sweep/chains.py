"""Limb chains of a skeleton: the joints a sweep runs through (Hyun et al. §3.2).

A chain is three joints down one limb -- shoulder, elbow, wrist or hip, knee, ankle --
found by the built-in joint-name conventions (:mod:`skincap.deform.skeletal.name_maps`),
or given by name. Its *bones* are the joints whose skin weights bind a vertex to the
sweep: the first joint and everything below it, except the last joint's subtree (the
hand or the foot, which keep skeletal skinning).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from skincap.deform.skeletal.name_maps import CONVENTIONS, bare_names, detect_convention
from skincap.errors import ValidationError
from skincap.types import Skeleton

__all__ = ["LIMB_LANDMARKS", "LimbChain", "limb_chains", "subtree"]

#: Chains swept by default: canonical landmarks (name_maps) from the limb's root to its end.
LIMB_LANDMARKS: dict[str, tuple[str, str, str]] = {
    "arm_l": ("upperarm_l", "forearm_l", "hand_l"),
    "arm_r": ("upperarm_r", "forearm_r", "hand_r"),
    "leg_l": ("thigh_l", "shin_l", "foot_l"),
    "leg_r": ("thigh_r", "shin_r", "foot_r"),
}


def subtree(parents: np.ndarray, joint: int) -> np.ndarray:
    """(J,) bool: ``joint`` and every joint below it (``parents[k] < k``)."""
    inside = np.zeros(parents.size, dtype=bool)
    inside[joint] = True
    for k in range(joint + 1, parents.size):  # joints are topologically ordered
        if parents[k] >= 0 and inside[parents[k]]:
            inside[k] = True
    return inside


@dataclass(frozen=True, eq=False)
class LimbChain:
    """One swept limb.

    Attributes
    ----------
    name : str
        ``"arm_l"``, ``"leg_r"``, or the caller's name.
    joints : (3,) int64
        Skeleton indices of the key joints, root first (e.g. shoulder, elbow, wrist).
    parent : int
        The first joint's parent (-1 for a root): the segment the sweep starts from.
    bones : (J,) bool
        Joints whose skin weights count as this sweep's.
    """

    name: str
    joints: np.ndarray
    parent: int
    bones: np.ndarray


def _chain(skeleton: Skeleton, name: str, names: Sequence[str]) -> LimbChain:
    if len(names) < 3:
        raise ValidationError(f"chain {name!r}: needs at least 3 joints, got {len(names)}")
    where = {n: k for k, n in enumerate(skeleton.names)}
    missing = [n for n in names if n not in where]
    if missing:
        raise ValidationError(f"chain {name!r}: joint {missing[0]!r} is not in the skeleton")
    idx = np.array([where[n] for n in names], dtype=np.int64)
    parents = skeleton.parents
    for a, b in zip(idx[:-1], idx[1:], strict=True):
        if not subtree(parents, int(a))[b] or a == b:
            raise ValidationError(
                f"chain {name!r}: joint {skeleton.names[b]!r} is not below {skeleton.names[a]!r}"
            )
    bones = subtree(parents, int(idx[0])) & ~subtree(parents, int(idx[-1]))
    return LimbChain(name=name, joints=idx, parent=int(parents[idx[0]]), bones=bones)


def limb_chains(
    skeleton: Skeleton, chains: Mapping[str, Sequence[str]] | None = None
) -> list[LimbChain]:
    """The chains to sweep on ``skeleton``.

    Parameters
    ----------
    skeleton : Skeleton
    chains : mapping of name -> joint names, optional
        Explicit chains (each at least 3 joints, each below the previous one).
        Default: both arms and both legs, by the joint-name convention the skeleton
        follows (CMU, Biovision, MakeHuman, Mixamo; :func:`detect_convention`, names
        matched past a namespace such as ``mixamorig:``).

    Returns
    -------
    list of LimbChain
        At least one.

    Raises
    ------
    ValidationError
        No chain given and no known convention (or none of its limbs present), or a
        named joint missing or out of order.
    """
    if chains is not None:
        out = [_chain(skeleton, name, list(names)) for name, names in chains.items()]
        if not out:
            raise ValidationError("chains: expected at least one chain")
        return out
    bare = bare_names(skeleton.names)
    conv = detect_convention(list(bare))
    if conv is None:
        raise ValidationError(
            "skeleton: its joint names follow no known convention (CMU, Biovision, MakeHuman, "
            "Mixamo), "
            "so no arm or leg chain to sweep was found (the Python API takes chains=)"
        )
    table = CONVENTIONS[conv]
    out = []
    for name, marks in LIMB_LANDMARKS.items():
        joints = [table.get(m) for m in marks]
        if all(isinstance(j, str) and j in bare for j in joints):
            full = [skeleton.names[bare[j]] for j in joints]  # type: ignore[index]
            out.append(_chain(skeleton, name, full))
    if not out:
        raise ValidationError(f"skeleton: no arm or leg of the {conv} convention is present")
    return out
