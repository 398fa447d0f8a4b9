"""The solved skeleton as a BVH-ready :class:`~skincap.types.Motion`.

Each segment drives one joint (the template's ``joint``); ``via`` and ``fixed_joints``
add rotation-less joints (collars, ``Chest2``, ``Head``) and every leaf segment ends in
an end site, so the built-in templates give the Biovision hierarchy and joint names
(``Hips``, ``Chest``, ``Chest2``, ``Neck``, ``Head``, ``LeftCollar``,
``LeftShoulder``, ``LeftElbow``, ``LeftWrist``, ``LeftHip``, ``LeftKnee``,
``LeftAnkle``...), which skincap's retargeting and Blender read as they are. All
identity rotations give the anatomical frames' T-pose: Y up, facing +Z, the body's
left on +X. Local rotation of a segment joint: ``R_parent^T R_segment``.
"""

from __future__ import annotations

import numpy as np

from skincap.geometry.rotations import matrix_to_quat
from skincap.solve.calibrate import BodyModel
from skincap.types import Motion, Skeleton

__all__ = ["skeleton_of", "motion_of"]


def skeleton_of(model: BodyModel) -> tuple[Skeleton, np.ndarray]:
    """The output skeleton and, per segment, the index of the joint it drives.

    Returns
    -------
    skeleton : Skeleton
        Offsets in metres.
    segment_joint : (S,) int64
    """
    tpl = model.template
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    seg_joint = np.zeros(model.n_segments, dtype=np.int64)
    # per segment: joint name -> (index, position in the segment's frame)
    inside: dict[int, dict[str, tuple[int, np.ndarray]]] = {}

    def add(name: str, parent: int, offset: np.ndarray) -> int:
        names.append(name)
        parents.append(parent)
        offsets.append(np.asarray(offset, dtype=np.float64))
        return len(names) - 1

    children: dict[int, list[int]] = {}
    for s in range(1, model.n_segments):
        children.setdefault(int(model.segment_parents[s]), []).append(s)

    def visit(s: int, parent_joint: int, offset: np.ndarray) -> None:
        spec = tpl.segments[s]
        j = parent_joint
        for v in spec.via:
            j = add(v, j, np.zeros(3))
        j = add(spec.joint, j, offset)
        seg_joint[s] = j
        inside[s] = {spec.joint: (j, np.zeros(3))}
        for fname, pos in model.fixed.get(spec.name, []):
            k = add(fname, j, pos)
            inside[s][fname] = (k, pos)
        kids = children.get(s, [])
        for c in kids:
            cspec = tpl.segments[c]
            anchor = cspec.parent_joint or spec.joint
            k, pos = inside[s].get(anchor, (j, np.zeros(3)))
            visit(c, k, model.joint_offsets[c] - pos)
        if not kids:
            last = max(idx for idx, _ in inside[s].values())
            pos = dict((idx, p) for idx, p in inside[s].values())[last]
            add(f"{names[last]}_end", last, model.ends.get(spec.name, np.zeros(3)) - pos)

    visit(0, -1, np.zeros(3))
    skel = Skeleton(
        names=names, parents=np.array(parents, dtype=np.int64), offsets=np.array(offsets)
    )
    return skel, seg_joint


def motion_of(model: BodyModel, rotations: np.ndarray, root: np.ndarray, rate: float) -> Motion:
    """Motion of the solved skeleton from world segment rotations (T, S, 3, 3) and the root (T, 3) metres."""
    skel, seg_joint = skeleton_of(model)
    t = rotations.shape[0]
    par = model.segment_parents
    local = rotations.copy()
    local[:, 1:] = np.einsum("tsji,tsjk->tsik", rotations[:, par[1:]], rotations[:, 1:])
    quats = np.zeros((t, skel.n_joints, 4))
    quats[..., 3] = 1.0
    q = matrix_to_quat(local)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    quats[:, seg_joint] = q
    trans = np.broadcast_to(skel.offsets, (t, skel.n_joints, 3)).copy()
    trans[:, seg_joint[0]] = root
    leaves = skel.is_leaf
    channels: list[tuple[str, ...]] = [
        ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
        if p < 0
        else (() if leaves[k] else ("Zrotation", "Xrotation", "Yrotation"))
        for k, p in enumerate(skel.parents)
    ]
    return Motion(
        skeleton=skel,
        rotations=quats,
        translations=trans,
        rate=rate,
        channels=channels,
        meta={"source_units": "cm", "up": "y"},
    )
