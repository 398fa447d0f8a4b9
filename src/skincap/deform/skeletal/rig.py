"""Rig helpers: the bind pose as a Motion, skinning matrices, motions from world rotations.

A skinned rig's joints carry *bind frames* ``B_j`` (``skin.bind_matrices``, (J, 4, 4),
metres): world transforms whose rotation part is generally not the identity (MakeHuman
bones have a roll, glTF joints arbitrary rest rotations). A :class:`~skincap.types.Motion`
on the rig's skeleton must reproduce them by forward kinematics in the bind pose, so its
local transforms are ``L_j = inv(B_parent) @ B_j``:

- local rotation ``R_parent^T R_j`` (identity only when the rig has no rest rotations);
- local translation ``R_parent^T (h_j - h_parent)`` with ``h`` the joint heads. This
  differs from ``skeleton.offsets`` (``h_j - h_parent`` in world axes) whenever the
  parent frame is rotated.

Decision: every Motion built here gives **every joint six channels** (position then
``Zrotation Yrotation Xrotation``) and stores the bind-local translation in
``translations`` for all frames (the root's translation is its world position). Bone
lengths therefore never change, FK in the bind pose equals ``skin.bind_matrices``
exactly, and a BVH or glTF writer can write the translations channel for channel
without consulting ``skeleton.offsets``.

A skeleton without a skin (e.g. a BVH skeleton used as a rig) has the bind frames
``T(rest position)`` with identity rotations (:func:`skeleton_bind_matrices`); for it
the bind-local translation is exactly ``skeleton.offsets``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics, rest_positions
from skincap.geometry.rotations import matrix_to_quat, quat_to_matrix
from skincap.types import POSITION_CHANNELS, Motion, Skeleton, Skin

__all__ = [
    "ALL_CHANNELS",
    "skeleton_bind_matrices",
    "bind_matrices_of",
    "bind_local_transforms",
    "rest_motion",
    "skinning_matrices",
    "motion_from_world",
    "check_same_joints",
]

#: Channel layout every joint gets in motions built by this module.
ALL_CHANNELS: tuple[str, ...] = POSITION_CHANNELS + ("Zrotation", "Yrotation", "Xrotation")


def skeleton_bind_matrices(skeleton: Skeleton) -> np.ndarray:
    """Bind frames of a bare skeleton: identity rotations at the rest positions.

    Parameters
    ----------
    skeleton : Skeleton

    Returns
    -------
    (J, 4, 4) float64
        ``T(rest_positions(skeleton)[j])``, translation in metres.
    """
    pos = rest_positions(skeleton)
    out = np.tile(np.eye(4), (skeleton.n_joints, 1, 1))
    out[:, :3, 3] = pos
    return out


def bind_matrices_of(rig: Skin | Skeleton) -> tuple[Skeleton, np.ndarray]:
    """The skeleton and (J, 4, 4) bind frames of a skin, or of a bare skeleton.

    Parameters
    ----------
    rig : Skin or Skeleton
        A skin gives ``skin.bind_matrices``; a skeleton :func:`skeleton_bind_matrices`.

    Returns
    -------
    skeleton : Skeleton
    bind : (J, 4, 4) float64, metres
    """
    if isinstance(rig, Skin):
        bind = rig.bind_matrices
        if not np.isfinite(bind).all():
            raise ValidationError("skin.inverse_bind: not invertible (non-finite bind matrices)")
        return rig.skeleton, bind
    if isinstance(rig, Skeleton):
        return rig, skeleton_bind_matrices(rig)
    raise ValidationError(f"rig: expected a Skin or a Skeleton, got {type(rig).__name__}")


def _rotation_parts(bind: np.ndarray) -> np.ndarray:
    """Orthonormal rotation parts of bind frames (J, 3, 3) (polar decomposition)."""
    m = bind[:, :3, :3]
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    flip = np.linalg.det(r) < 0
    if flip.any():
        raise ValidationError(
            f"bind matrices: joint {int(np.nonzero(flip)[0][0])} has a reflection, not a rotation"
        )
    return r


def bind_local_transforms(rig: Skin | Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Local rotation and translation of every joint in the bind pose.

    ``L_j = inv(B_parent) @ B_j`` (``B_j`` for a root).

    Parameters
    ----------
    rig : Skin or Skeleton

    Returns
    -------
    rotations : (J, 4) float64
        Unit quaternions ``(x, y, z, w)``, canonical (``w >= 0``).
    translations : (J, 3) float64, metres
        Bind-local translations; world position for roots.
    """
    skeleton, bind = bind_matrices_of(rig)
    rot = _rotation_parts(bind)
    pos = bind[:, :3, 3]
    parents = skeleton.parents
    has = parents >= 0
    local_r = rot.copy()
    local_t = pos.copy()
    pr = rot[parents[has]]
    local_r[has] = np.einsum("jba,jbc->jac", pr, rot[has])
    local_t[has] = np.einsum("jba,jb->ja", pr, pos[has] - pos[parents[has]])
    return matrix_to_quat(local_r), local_t


def rest_motion(skin: Skin | Skeleton, rate: float = 30.0) -> Motion:
    """A one-frame Motion on the rig's skeleton whose FK is the bind pose.

    Parameters
    ----------
    skin : Skin or Skeleton
    rate : float, Hz

    Returns
    -------
    Motion
        ``rotations`` (1, J, 4) and ``translations`` (1, J, 3) metres from
        :func:`bind_local_transforms`; every joint has the six channels
        :data:`ALL_CHANNELS` (see the module docstring). ``forward_kinematics`` of it
        equals ``skin.bind_matrices`` (to rounding), so its skinning matrices are
        the identity.
    """
    skeleton, _ = bind_matrices_of(skin)
    q, t = bind_local_transforms(skin)
    return Motion(
        skeleton=skeleton,
        rotations=q[None],
        translations=t[None],
        rate=rate,
        channels=[ALL_CHANNELS] * skeleton.n_joints,
        meta={"source": "bind pose"},
    )


def check_same_joints(motion: Motion, skeleton: Skeleton, what: str = "motion") -> None:
    """Raise ValidationError unless ``motion`` has ``skeleton``'s joint names in order.

    The message names the first joint that differs.
    """
    got = motion.skeleton.names
    want = skeleton.names
    for k in range(max(len(got), len(want))):
        a = got[k] if k < len(got) else None
        b = want[k] if k < len(want) else None
        if a != b:
            raise ValidationError(
                f"{what}: joint {k} is {a!r} but the skin's skeleton has {b!r} there; "
                f"the motion must be on the skin's skeleton ({len(want)} joints, same names "
                "and order) -- retarget it first (skincap.deform.skeletal.retarget.retarget)"
            )


def skinning_matrices(motion: Motion, skin: Skin) -> np.ndarray:
    """Skinning matrices ``S = W @ inverse_bind`` of every frame.

    Parameters
    ----------
    motion : Motion
        On ``skin.skeleton`` (same joint names in the same order).
    skin : Skin

    Returns
    -------
    (T, J, 4, 4) float64
        ``S[t, j]`` maps a bind-pose point (metres) bound to joint ``j`` to its posed
        position. The identity in the bind pose. Never NaN (Motion is finite).

    Raises
    ------
    ValidationError
        The motion's joint names differ from the skin's (the first mismatch is named).
    """
    if not isinstance(skin, Skin):
        raise ValidationError(f"skin: expected a Skin, got {type(skin).__name__}")
    check_same_joints(motion, skin.skeleton)
    world = forward_kinematics(motion)
    return np.einsum("tjab,jbc->tjac", world, skin.inverse_bind)


def motion_from_world(
    rig: Skin | Skeleton,
    world_rotations: np.ndarray,
    root_translation: np.ndarray,
    *,
    rate: float,
    meta: dict[str, Any] | None = None,
) -> Motion:
    """A Motion on the rig from world rotations of every joint and the root's path.

    Local rotations are ``R_parent^T R_j``; local translations are the bind-local ones
    (:func:`bind_local_transforms`), so bone lengths are those of the bind pose. The
    first joint (index 0, a root) gets ``root_translation`` as its world position;
    other roots, if any, keep their bind position.

    Parameters
    ----------
    rig : Skin or Skeleton
    world_rotations : (T, J, 4) or (T, J, 3, 3) float
        World rotation of each joint's frame: quaternions ``(x, y, z, w)`` (normalised
        here) or rotation matrices. In the bind pose these are the rotation parts of
        the bind matrices (identity for a bare skeleton).
    root_translation : (T, 3) float, metres
        World position of joint 0.
    rate : float, Hz
    meta : dict, optional

    Returns
    -------
    Motion
        On the rig's skeleton, every joint with :data:`ALL_CHANNELS`.

    Raises
    ------
    ValidationError
        Wrong shapes, non-finite values or zero quaternions.
    """
    skeleton, _ = bind_matrices_of(rig)
    j = skeleton.n_joints
    w = np.asarray(world_rotations, dtype=np.float64)
    if w.ndim == 3 and w.shape[1:] == (j, 4):
        norms = np.linalg.norm(w, axis=-1)
        if not np.isfinite(w).all() or (norms == 0).any():
            raise ValidationError("world_rotations: quaternions must be finite and non-zero")
        mats = quat_to_matrix(w)
    elif w.ndim == 4 and w.shape[1:] == (j, 3, 3):
        if not np.isfinite(w).all():
            raise ValidationError("world_rotations: matrices must be finite")
        mats = w
    else:
        raise ValidationError(
            f"world_rotations: expected shape (T, {j}, 4) or (T, {j}, 3, 3), got {w.shape}"
        )
    t = mats.shape[0]
    root = np.asarray(root_translation, dtype=np.float64)
    if root.shape != (t, 3):
        raise ValidationError(f"root_translation: expected shape ({t}, 3), got {root.shape}")
    if not np.isfinite(root).all():
        raise ValidationError("root_translation: must be finite")
    parents = skeleton.parents
    has = parents >= 0
    local = mats.copy()
    # R_local = R_parent^T R_j, all frames and joints at once: (T, J', 3, 3)
    local[:, has] = np.einsum("tjba,tjbc->tjac", mats[:, parents[has]], mats[:, has])
    _, bind_t = bind_local_transforms(rig)
    trans = np.broadcast_to(bind_t, (t, j, 3)).copy()
    trans[:, 0] = root
    return Motion(
        skeleton=skeleton,
        rotations=matrix_to_quat(local),
        translations=trans,
        rate=rate,
        channels=[ALL_CHANNELS] * j,
        meta=dict(meta or {}),
    )
