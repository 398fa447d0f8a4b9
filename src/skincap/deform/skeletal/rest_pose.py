"""Does a bare mesh stand in the skeleton's rest pose? How far off is it?

A bare mesh is bound to the motion's own skeleton, scaled onto the mesh; that is right
only when the mesh stands in the skeleton's rest pose. When it does not (an A-pose body
on a T-pose skeleton, legs apart on legs together), bones lie outside the body and the
bone-heat weights tie skin to the wrong bones (legs fused, arms torn). The measure here
is how far the skeleton's inner joints (end sites excluded: they sit on the surface by
construction of the fit) stand outside the mesh: a joint is inside when the mesh's
generalised winding number at it is over one half (Jacobson et al. 2013, which also
copes with small holes), and an outside joint is as far off as the nearest surface.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from skincap.errors import SkincapWarning, ValidationError
from skincap.geometry.raycast import (
    MAX_COORDINATE,
    check_vertex_coordinates,
    closest_points_on_mesh,
)
from skincap.types import Mesh, Skeleton

__all__ = ["winding_numbers", "rest_pose_misfit", "warn_if_rest_pose_differs", "RestPoseWarning"]

#: An inner joint further outside the mesh than this fraction of its height is a misfit
#: (6.8 cm on a 1.7 m body). A body in its skeleton's own pose stays under it: the
#: procedural body on its T-pose skeleton, after the bounding-box fit, has its worst
#: joint (a finger) 4.9 cm = 2.9 % outside; the MakeHuman body (arms down) on the
#: bvhtoolbox and CMU T-poses has ankles and toes 9.8 cm = 5.9 % and 16.5 cm = 9.9 % out.
MISFIT_FRACTION = 0.04


class RestPoseWarning(SkincapWarning):
    """A bare mesh does not stand in the rest pose of the skeleton it is bound to."""


def winding_numbers(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, *, block: int = 100_000
) -> np.ndarray:
    """Generalised winding number of a triangle surface at each point.

    Sum over the triangles of their signed solid angle seen from the point, over 4π
    (Van Oosterom & Strackee's formula): 1 inside a closed, outward-facing surface, 0
    outside, in between near holes.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    points : (P, 3) float, metres
    block : int
        Point-triangle pairs per vectorised block (bounds memory).

    Returns
    -------
    (P,) float64
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = np.asarray(points, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValidationError(f"vertices, faces: expected (V, 3), (F, 3); got {v.shape}, {f.shape}")
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValidationError(f"points: expected shape (P, 3), got {p.shape}")
    tri = v[f]  # (F, 3, 3)
    out = np.zeros(p.shape[0])
    step = max(1, int(block) // max(f.shape[0], 1))
    for lo in range(0, p.shape[0], step):
        rel = tri[None] - p[lo : lo + step, None, None, :]  # (b, F, 3 corners, 3)
        a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("...i,...i->...", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("...i,...i->...", a, b) * lc
            + np.einsum("...i,...i->...", b, c) * la
            + np.einsum("...i,...i->...", c, a) * lb
        )
        out[lo : lo + step] = 2.0 * np.arctan2(det, den).sum(axis=1)
    return out / (4.0 * np.pi)


def rest_pose_misfit(mesh: Mesh, skeleton: Skeleton) -> dict[str, Any]:
    """How far a skeleton's rest pose, already fitted onto ``mesh``, stands outside it.

    Parameters
    ----------
    mesh : Mesh
        (V, 3) vertices, metres, Y up; at least one face.
    skeleton : Skeleton
        In the mesh's frame (``fit_skeleton_to_mesh`` applied), metres.

    Returns
    -------
    dict
        ``joints_outside`` (names of inner joints outside the mesh, furthest first),
        ``worst_joint`` (or None), ``worst_distance_m`` (0.0 when all are inside),
        ``height_m`` (the mesh's Y extent) and ``misfit`` (True when the worst
        distance exceeds :data:`MISFIT_FRACTION` of the height).
    """
    from skincap.geometry.kinematics import rest_positions

    parents = np.asarray(skeleton.parents)
    inner = np.isin(np.arange(skeleton.n_joints), parents[parents >= 0])  # not end sites
    joints = rest_positions(skeleton)[inner]
    names = [n for n, keep in zip(skeleton.names, inner, strict=True) if keep]
    height = float(np.ptp(mesh.vertices[:, 1])) if mesh.n_vertices else 0.0
    result: dict[str, Any] = {
        "joints_outside": [],
        "worst_joint": None,
        "worst_distance_m": 0.0,
        "height_m": height,
        "misfit": False,
    }
    if joints.shape[0] == 0 or mesh.n_faces == 0:
        return result
    check_vertex_coordinates(mesh.vertices)  # a stray vertex is named before the joints
    far = ~(np.abs(joints) <= MAX_COORDINATE).all(axis=1)
    if far.any():
        k = int(np.argmax(far))
        raise ValidationError(
            f"skeleton: joint {names[k]!r} lies at {[float(x) for x in joints[k]]} m in the rest "
            "pose fitted onto the mesh (a stray OFFSET in the motion?)"
        )
    outside = winding_numbers(mesh.vertices, mesh.faces, joints) < 0.5
    if not outside.any():
        return result
    distance, _, _ = closest_points_on_mesh(mesh.vertices, mesh.faces, joints[outside])
    order = np.argsort(-distance)
    out_names = [n for n, o in zip(names, outside, strict=True) if o]
    result.update(
        joints_outside=[out_names[i] for i in order],
        worst_joint=out_names[order[0]],
        worst_distance_m=float(distance[order[0]]),
        misfit=bool(distance[order[0]] > MISFIT_FRACTION * height),
    )
    return result


def warn_if_rest_pose_differs(mesh: Mesh, skeleton: Skeleton, *, stacklevel: int = 2) -> dict:
    """:func:`rest_pose_misfit`, with a :class:`RestPoseWarning` when it is a misfit."""
    misfit = rest_pose_misfit(mesh, skeleton)
    if misfit["misfit"]:
        others = len(misfit["joints_outside"]) - 1
        warnings.warn(
            f"the mesh does not stand in the BVH's rest pose: joint {misfit['worst_joint']!r} "
            f"is {100 * misfit['worst_distance_m']:.1f} cm outside the body "
            f"({100 * misfit['worst_distance_m'] / misfit['height_m']:.0f} % of its "
            f"{misfit['height_m']:.2f} m height)"
            + (f" and {others} more joints are outside" if others > 0 else "")
            + "; the automatic weights will tie skin to the wrong bones "
            "(pose the mesh like the BVH's zero pose, or give a rigged mesh)",
            RestPoseWarning,
            stacklevel=stacklevel + 1,
        )
    return misfit
