"""Binding a mesh to a skeleton: skin weights (from the file or automatic) and bind matrices.

The bind pose is the pose the mesh is modelled in. ``rest_world`` (J, 4, 4) holds the
world transform of every joint in that pose; the skin stores its inverse, so that the
skinning matrices ``W @ skin.inverse_bind`` are the identity when the skeleton is in
the bind pose (see :mod:`skincap.deform.skeletal`).

With ``weights="auto"`` the weights come from bone heat
(:func:`skincap.deform.skeletal.weights.bone_heat_weights`) on the joint positions of the
bind pose; with ``weights="file"`` the mesh's own skin (glTF, MakeHuman) is kept,
mapped onto the given skeleton by joint name, limited to ``max_influences`` and
renormalised.

A bare mesh and a BVH skeleton usually differ in size and place:
:func:`fit_skeleton_to_mesh` gives the scale and translation that put the skeleton's
rest pose on the mesh and :func:`transform_skeleton` applies them.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from skincap._arrays import as_finite_array
from skincap.deform.skeletal.weights import (
    bone_heat_weights,
    check_max_influences,
    limit_influences,
)
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics, rest_positions
from skincap.types import Mesh, Motion, Skeleton, Skin

__all__ = ["bind_mesh", "fit_skeleton_to_mesh", "transform_skeleton", "rest_transforms"]


def rest_transforms(skeleton: Skeleton | Motion) -> np.ndarray:
    """Default bind transforms of a skeleton, or of the first frame of a motion.

    Parameters
    ----------
    skeleton : Skeleton or Motion
        A skeleton: its rest pose (all rotations identity), so each joint's bind
        transform is a pure translation to its rest position. A motion: the world
        transforms of its frame 0 (rotations included) -- pass a one-frame motion
        of the pose the mesh is in.

    Returns
    -------
    (J, 4, 4) float64
        World transforms, translation in metres.
    """
    if isinstance(skeleton, Motion):
        if skeleton.n_frames == 0:
            raise ValidationError("skeleton: the motion has no frame to take the bind pose from")
        return forward_kinematics(skeleton)[0]
    if not isinstance(skeleton, Skeleton):
        raise ValidationError(
            f"skeleton: expected a Skeleton or a Motion, got {type(skeleton).__name__}"
        )
    out = np.tile(np.eye(4), (skeleton.n_joints, 1, 1))
    out[:, :3, 3] = rest_positions(skeleton)
    return out


def _check_rest_world(rest_world: object, n_joints: int) -> np.ndarray:
    rw = as_finite_array(rest_world, "rest_world", (n_joints, 4, 4))  # one per joint
    if np.abs(rw[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise ValidationError("rest_world: the last row of each transform must be (0, 0, 0, 1)")
    det = np.linalg.det(rw[:, :3, :3])
    if np.abs(det).min() < 1e-12:
        k = int(np.argmin(np.abs(det)))
        raise ValidationError(f"rest_world: transform of joint {k} is singular")
    return rw


def _inverse(rw: np.ndarray) -> np.ndarray:
    """Inverse of affine transforms (J, 4, 4)."""
    out = np.zeros_like(rw)
    inv3 = np.linalg.inv(rw[:, :3, :3])
    out[:, :3, :3] = inv3
    out[:, :3, 3] = -np.einsum("jab,jb->ja", inv3, rw[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def _target_skeleton(
    file_skin: Skin | None, skeleton: Skeleton | Motion | None, weights: str
) -> tuple[Skeleton, np.ndarray]:
    """The skeleton to bind to and its default bind-pose world transforms (J, 4, 4)."""
    if weights == "file" and file_skin is None:
        raise ValidationError(
            "mesh: has no skin to take weights from (weights='file'); use weights='auto'"
        )
    if skeleton is None:
        if file_skin is None:
            raise ValidationError("skeleton: required for a mesh without a skin")
        target = file_skin.skeleton
        default_rest = file_skin.bind_matrices
    elif isinstance(skeleton, (Skeleton, Motion)):
        target = skeleton.skeleton if isinstance(skeleton, Motion) else skeleton
        default_rest = rest_transforms(skeleton)
    else:
        raise ValidationError(
            f"skeleton: expected a Skeleton, a Motion or None, got {type(skeleton).__name__}"
        )
    return target, default_rest


def _bind_matrices(
    file_skin: Skin | None,
    file_to_target: np.ndarray | None,
    default_rest: np.ndarray,
    rest_world: np.ndarray | None,
    n_j: int,
    *,
    keep_file_binds: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse-bind (J, 4, 4) and bind-pose world transforms (J, 4, 4) of the target.

    Without ``rest_world``, the file's bind matrices are kept, by joint name, when
    ``keep_file_binds`` (the file knows where the mesh was bound), and its
    inverse-bind matrices are copied exactly (no round trip through ``inv(inv())``).
    """
    if rest_world is not None:
        rw = _check_rest_world(rest_world, n_j)
        return _inverse(rw), rw
    rw = np.array(default_rest, dtype=np.float64)
    if not keep_file_binds or file_skin is None or file_to_target is None:
        return _inverse(rw), rw
    present = file_to_target >= 0
    rw[file_to_target[present]] = file_skin.bind_matrices[present]
    inverse_bind = _inverse(rw)
    inverse_bind[file_to_target[present]] = file_skin.inverse_bind[present]
    return inverse_bind, rw


def _file_weights(
    file_skin: Skin, file_to_target: np.ndarray, max_influences: int
) -> tuple[np.ndarray, np.ndarray]:
    """The file's weights on the target's joints, (V, K) indices and weights."""
    idx = file_skin.joint_indices
    w = file_skin.joint_weights
    mapped = file_to_target[idx]
    missing = (mapped < 0) & (w > 0)
    if missing.any():
        j = int(idx[missing][0])
        raise ValidationError(
            f"skeleton: joint '{file_skin.skeleton.names[j]}' of the mesh's skin weights "
            f"{int(missing.any(axis=1).sum())} vertices but is not in the skeleton"
        )
    return limit_influences(np.maximum(mapped, 0), w, max_influences)


def _check_skeleton_on_mesh(mesh: Mesh, joint_positions: np.ndarray, n_j: int) -> None:
    """At least half the joints (J, 3) inside the mesh's bounds grown by 10 %."""
    bounds = mesh.bounds
    pad = 0.1 * (bounds[1] - bounds[0])
    inside = ((joint_positions >= bounds[0] - pad) & (joint_positions <= bounds[1] + pad)).all(
        axis=1
    )
    if inside.sum() * 2 < n_j:
        raise ValidationError(
            f"skeleton: only {int(inside.sum())} of {n_j} joints lie within the mesh's bounds "
            f"{np.round(bounds, 3).tolist()} m; scale and place it first (fit_skeleton_to_mesh)"
        )


def bind_mesh(
    mesh: Mesh,
    skeleton: Skeleton | Motion | None = None,
    *,
    rest_world: np.ndarray | None = None,
    weights: Literal["auto", "file"] = "auto",
    max_influences: int = 4,
    bones: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    leaf_tails: np.ndarray | None = None,
    heat_constant: float = 1.0,
) -> Mesh:
    """Bind ``mesh`` to ``skeleton`` in the pose the mesh is in.

    Parameters
    ----------
    mesh : Mesh
        Vertices in metres, Y up, in the bind pose. For ``weights="file"`` it must
        carry a :class:`~skincap.types.Skin`.
    skeleton : Skeleton or Motion, optional
        The skeleton to bind to. A Motion gives the skeleton and, by default, the
        bind pose (its frame 0). Default: the skeleton of ``mesh.skin``.
    rest_world : (J, 4, 4) float, optional
        World transform of each joint in the bind pose (translation in metres).
        Default: the file's bind matrices for joints the mesh's skin has (when
        ``weights="file"`` or ``skeleton`` is omitted), otherwise
        :func:`rest_transforms` (identity rotations at the rest positions for a
        Skeleton, frame 0 for a Motion).
    weights : {"auto", "file"}, default "auto"
        ``"auto"``: bone-heat weights (Baran & Popovic 2007) computed on the joint
        positions of ``rest_world``; a vertex near a bone is bound to the bone's
        head joint. ``"file"``: the weights of ``mesh.skin``, mapped to
        ``skeleton`` by joint name.
    max_influences : int, default 4
        Joints kept per vertex: the largest weights, renormalised to sum to 1.
    bones, leaf_tails, heat_constant
        Passed to :func:`~skincap.deform.skeletal.weights.bone_heat_weights` for
        ``weights="auto"``.

    Returns
    -------
    Mesh
        The same geometry (arrays shared, meta copied) with a new skin:
        ``joint_indices`` / ``joint_weights`` (V, K) with ``K <= max_influences``,
        rows summing to 1, and ``inverse_bind = inv(rest_world)``. ``meta`` gains
        ``"skin_weights"`` (``"auto"`` or ``"file"``).

    Raises
    ------
    ValidationError
        No skeleton is given and the mesh has no skin; ``weights="file"`` on a mesh
        without a skin, or a weighted joint of the file missing from ``skeleton``;
        for ``"auto"``, a skeleton that is clearly not on the mesh (fewer than half
        of its joints inside the mesh's bounding box grown by 10 %: use
        :func:`fit_skeleton_to_mesh` first); bad shapes or values.
    """
    if not isinstance(mesh, Mesh):
        raise ValidationError(f"mesh: expected a Mesh, got {type(mesh).__name__}")
    if weights not in ("auto", "file"):
        raise ValidationError(f"weights: expected 'auto' or 'file', got {weights!r}")
    m = check_max_influences(max_influences)
    file_skin = mesh.skin
    target, default_rest = _target_skeleton(file_skin, skeleton, weights)
    n_j = target.n_joints
    # joints of the file's skin, by name, in the target skeleton (-1: absent)
    file_to_target = None
    if file_skin is not None:
        where = {name: k for k, name in enumerate(target.names)}
        file_to_target = np.array(
            [where.get(name, -1) for name in file_skin.skeleton.names], dtype=np.int64
        )
    inverse_bind, rw = _bind_matrices(
        file_skin, file_to_target, default_rest, rest_world, n_j,
        keep_file_binds=file_skin is not None and (skeleton is None or weights == "file"),
    )  # fmt: skip
    if weights == "file":
        if file_skin is None or file_to_target is None:  # pragma: no cover - checked above
            raise ValidationError("mesh: has no skin to take weights from (weights='file')")
        indices, joint_weights = _file_weights(file_skin, file_to_target, m)
    else:
        _check_skeleton_on_mesh(mesh, rw[:, :3, 3], n_j)
        indices, joint_weights = bone_heat_weights(
            mesh,
            rw[:, :3, 3],
            target.parents,
            max_influences=m,
            bones=bones,
            leaf_tails=leaf_tails,
            heat_constant=heat_constant,
        )
    skin = Skin(
        skeleton=target,
        joint_indices=indices,
        joint_weights=joint_weights,
        inverse_bind=inverse_bind,
    )
    meta = dict(mesh.meta)
    meta["skin_weights"] = weights
    return dataclasses.replace(mesh, skin=skin, meta=meta)


def fit_skeleton_to_mesh(
    skeleton: Skeleton | Motion,
    mesh: Mesh,
    *,
    joint_span_ratio: float = 1.0,
) -> tuple[float, np.ndarray]:
    """Scale and translation that put a skeleton's rest pose onto a mesh.

    Assumptions: the mesh stands upright (Y up) in the skeleton's rest pose (a
    BVH's zero pose for a Skeleton, frame 0 for a Motion), and the joints span
    ``joint_span_ratio`` of the body's height (1.0: end sites from the sole to the
    crown, the convention skincap's BVH reader uses to guess units). The scale
    matches the heights (Y extents); the translation then puts the centre of the
    scaled joints' bounding box on the centre of the mesh's bounding box (in Y the
    joints' span is centred in the mesh's height).

    Parameters
    ----------
    skeleton : Skeleton or Motion
    mesh : Mesh
        Vertices in metres, Y up. Must have some height.
    joint_span_ratio : float, default 1.0
        Fraction of the mesh's height that the joints span.

    Returns
    -------
    scale : float
        Dimensionless, positive.
    translation : (3,) float64, metres
        ``p_on_mesh = scale * p_skeleton + translation``.
    """
    if not isinstance(mesh, Mesh) or mesh.n_vertices == 0:
        raise ValidationError("mesh: expected a Mesh with vertices")
    ratio = float(joint_span_ratio)
    if not (0.0 < ratio <= 2.0):
        raise ValidationError(
            f"joint_span_ratio: expected a fraction of the height in (0, 2], got {joint_span_ratio!r}"
        )
    pos = rest_transforms(skeleton)[:, :3, 3]
    lo_s, hi_s = pos.min(axis=0), pos.max(axis=0)
    lo_m, hi_m = mesh.bounds
    height_s = hi_s[1] - lo_s[1]
    height_m = hi_m[1] - lo_m[1]
    if not height_m > 0:
        raise ValidationError("mesh: has no height along Y (is it Y up?)")
    if not height_s > 0:
        raise ValidationError("skeleton: its rest pose has no height along Y (is it Y up?)")
    scale = float(ratio * height_m / height_s)
    translation = 0.5 * (lo_m + hi_m) - scale * 0.5 * (lo_s + hi_s)
    return scale, translation


def transform_skeleton(skeleton: Skeleton, scale: float, translation: np.ndarray) -> Skeleton:
    """A skeleton scaled about the origin and moved: ``p -> scale * p + translation``.

    Parameters
    ----------
    skeleton : Skeleton
    scale : float
        Positive factor applied to every offset.
    translation : (3,) float, metres
        Added to the offsets of the roots.

    Returns
    -------
    Skeleton
        Same names and parents; offsets (J, 3) in metres. Its rest positions are
        ``scale * rest_positions(skeleton) + translation``.
    """
    s = float(scale)
    if not (s > 0 and np.isfinite(s)):
        raise ValidationError(f"scale: expected a positive number, got {scale!r}")
    t = np.asarray(translation, dtype=np.float64)
    if t.shape != (3,) or not np.isfinite(t).all():
        raise ValidationError(f"translation: expected a finite (3,) vector, got shape {t.shape}")
    offsets = skeleton.offsets * s
    offsets[skeleton.parents < 0] += t
    return Skeleton(names=list(skeleton.names), parents=skeleton.parents.copy(), offsets=offsets)
