"""Forward kinematics: local joint rotations and translations to world transforms.

A joint's local transform is ``L_j = [R_j | t_j]`` (rotate, then translate: BVH's
``T(position) @ R(euler)``), relative to its parent; the world transform is
``W_j = W_parent(j) @ L_j`` and ``W_root = L_root``. The loop runs over joints (in
topological order, ``parents[j] < j``) and every step is vectorised over frames: frames
are never looped over.

Units are whatever the translations are in (metres for a :class:`~skincap.types.Motion`).
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import broadcast_leading
from skincap.errors import ValidationError
from skincap.geometry.rotations import quat_to_matrix
from skincap.types import Motion, Skeleton

__all__ = [
    "forward_kinematics",
    "joint_positions",
    "forward_kinematics_arrays",
    "joint_positions_arrays",
    "rest_positions",
]


def _parents(skeleton: Skeleton | np.ndarray) -> np.ndarray:
    if isinstance(skeleton, Skeleton):
        return skeleton.parents
    p = np.asarray(skeleton)
    if p.ndim != 1 or not (np.issubdtype(p.dtype, np.integer) or p.size == 0):
        raise ValidationError(
            f"parents: expected a (J,) integer array or a Skeleton, got shape {p.shape} dtype {p.dtype}"
        )
    p = p.astype(np.int64)
    bad = np.nonzero((p >= np.arange(p.size)) | (p < -1))[0]
    if bad.size:
        raise ValidationError(
            f"parents: each joint's parent must come before it (-1 for a root); joint {int(bad[0])} has parent {int(p[bad[0]])}"
        )
    return p


def _prepare(
    skeleton: Skeleton | np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, ...]]:
    parents = _parents(skeleton)
    j = parents.size
    q = np.asarray(rotations, dtype=np.float64)
    t = np.asarray(translations, dtype=np.float64)
    if q.ndim < 2 or q.shape[-2:] != (j, 4):
        raise ValidationError(
            f"rotations: expected shape (..., {j}, 4) for {j} joints, got {q.shape}"
        )
    if t.ndim < 2 or t.shape[-2:] != (j, 3):
        raise ValidationError(
            f"translations: expected shape (..., {j}, 3) for {j} joints, got {t.shape}"
        )
    lead = broadcast_leading(
        q.shape[:-2],
        t.shape[:-2],
        error=f"rotations {q.shape} and translations {t.shape}: leading (frame) axes do not broadcast",
    )
    q = np.broadcast_to(q, lead + (j, 4)).reshape(-1, j, 4)
    t = np.broadcast_to(t, lead + (j, 3)).reshape(-1, j, 3)
    return parents, q, t, lead


def _world(parents: np.ndarray, q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (J, N, 3, 3) and positions (J, N, 3) from (N, J, ...) locals."""
    n, j = q.shape[:2]
    # joint-major layout: every per-joint slice below is contiguous
    local_r = quat_to_matrix(np.ascontiguousarray(q.transpose(1, 0, 2)))  # (J, N, 3, 3)
    local_t = np.ascontiguousarray(t.transpose(1, 0, 2))  # (J, N, 3)
    world_r = np.zeros((j, n, 3, 3))
    world_p = np.zeros((j, n, 3))
    for k in range(j):
        p = parents[k]
        if p < 0:
            world_r[k] = local_r[k]
            world_p[k] = local_t[k]
        else:
            np.matmul(world_r[p], local_r[k], out=world_r[k])  # (N, 3, 3)
            # world_p[k] = world_p[p] + world_r[p] @ t_k  (N, 3), no temporaries
            np.einsum("nij,nj->ni", world_r[p], local_t[k], out=world_p[k])
            world_p[k] += world_p[p]
    return world_r, world_p


def forward_kinematics_arrays(
    skeleton: Skeleton | np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> np.ndarray:
    """World transforms of every joint from local rotations and translations.

    Parameters
    ----------
    skeleton : Skeleton or (J,) int array
        The hierarchy (or just its ``parents``, -1 for roots, ``parents[j] < j``).
    rotations : (..., J, 4) float
        Local rotations relative to the parent, quaternions ``(x, y, z, w)``
        (normalised on the fly).
    translations : (..., J, 3) float, any length unit
        Local translations relative to the parent (world position for roots). The
        leading axes broadcast against those of ``rotations``: pass
        ``skeleton.offsets`` (J, 3) for a skeleton without position channels.

    Returns
    -------
    (..., J, 4, 4) float64
        ``W[..., j]`` maps joint ``j``'s local coordinates to world coordinates (same
        length unit as ``translations``). NaN in a joint's input spreads to that joint
        and all its descendants, nowhere else, without warnings.

    Examples
    --------
    >>> parents = np.array([-1, 0])
    >>> q = np.array([[0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], [0.0, 0.0, 0.0, 1.0]])
    >>> t = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    >>> np.round(forward_kinematics_arrays(parents, q, t)[1, :3, 3], 12)  # child swung to +y
    array([0., 1., 0.])
    """
    parents, q, t, lead = _prepare(skeleton, rotations, translations)
    j = parents.size
    with np.errstate(invalid="ignore"):
        world_r, world_p = _world(parents, q, t)
    out = np.zeros((q.shape[0], j, 4, 4))
    out[:, :, :3, :3] = world_r.transpose(1, 0, 2, 3)
    out[:, :, :3, 3] = world_p.transpose(1, 0, 2)
    out[:, :, 3, 3] = 1.0
    return out.reshape(lead + (j, 4, 4))


def joint_positions_arrays(
    skeleton: Skeleton | np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> np.ndarray:
    """World positions of every joint (the translation part of :func:`forward_kinematics_arrays`).

    Parameters
    ----------
    skeleton : Skeleton or (J,) int array
    rotations : (..., J, 4) float, quaternions ``(x, y, z, w)``
    translations : (..., J, 3) float, any length unit; broadcast against ``rotations``

    Returns
    -------
    (..., J, 3) float64
        World positions, unit of ``translations``. NaN spreads to descendants only.
    """
    parents, q, t, lead = _prepare(skeleton, rotations, translations)
    with np.errstate(invalid="ignore"):
        _, world_p = _world(parents, q, t)
    return np.ascontiguousarray(world_p.transpose(1, 0, 2)).reshape(lead + (parents.size, 3))


def forward_kinematics(motion: Motion) -> np.ndarray:
    """World transforms of every joint in every frame of ``motion``.

    Parameters
    ----------
    motion : Motion
        Local rotations ``(T, J, 4)`` and translations ``(T, J, 3)`` in metres (always
        finite: :class:`~skincap.types.Motion` refuses NaN).

    Returns
    -------
    (T, J, 4, 4) float64
        Homogeneous world transforms, translation part in metres.
    """
    return forward_kinematics_arrays(motion.skeleton, motion.rotations, motion.translations)


def joint_positions(motion: Motion) -> np.ndarray:
    """World positions of every joint in every frame of ``motion``.

    Parameters
    ----------
    motion : Motion

    Returns
    -------
    (T, J, 3) float64, metres
    """
    return joint_positions_arrays(motion.skeleton, motion.rotations, motion.translations)


def rest_positions(skeleton: Skeleton) -> np.ndarray:
    """World positions of the joints in the rest pose (all rotations identity).

    Parameters
    ----------
    skeleton : Skeleton

    Returns
    -------
    (J, 3) float64
        Sums of offsets along each joint's chain, in the unit of ``skeleton.offsets``
        (metres for a skincap skeleton).
    """
    parents = _parents(skeleton)
    offsets = np.asarray(skeleton.offsets, dtype=np.float64)
    out = np.zeros_like(offsets)
    for k in range(parents.size):
        out[k] = offsets[k] if parents[k] < 0 else out[parents[k]] + offsets[k]
    return out
