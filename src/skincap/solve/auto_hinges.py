"""Where along its axis ``--template auto`` puts a hinge: between its neighbours' joints.

Motion fixes a hinge's axis but not the point of it that is the joint (every point of
the axis stays fixed in both segments). A named template places it by a regression
from anatomical landmarks; an unknown marker set has none. What the skeleton itself
offers: a bone runs square to the hinge it ends at -- a thigh from the hip, a shank
to the ankle -- so the joint is the foot of the perpendicular from the parent's own
joint, and equally from the child's distal joint. Either alone carries the error of
the axis's direction times the bone's length (4 degrees on a 0.42 m thigh: 30 mm);
the two lie on opposite sides of the hinge, so their mean cancels most of it. This
module moves each calibrated hinge to that mean, once the whole tree is calibrated
(the distal joint is only known then), and keeps every marker, end site and child
joint where it was in the world.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.solve.calibrate import BodyModel

__all__ = ["HINGE_METHODS", "MIN_BONE_ANGLE_DEG", "centre_hinges_between_neighbours", "hinge_axis"]

#: The calibration methods (:attr:`BodyModel.methods`) that found a hinge's axis.
HINGE_METHODS = ("SARA", "sphere-fit axis")


def hinge_axis(r_parent: np.ndarray, r_child: np.ndarray) -> np.ndarray | None:
    """(3,) unit axis, in the parent's frame, about which the child turns most.

    The principal direction of the rotation vectors of ``R_c R_mean^T`` expressed in
    the parent (``R_p^T R_c = exp(w) R_mean``); None with fewer than 3 frames where
    both rotations ``(T, 3, 3)`` are known.
    """
    ok = np.isfinite(r_parent).all(axis=(1, 2)) & np.isfinite(r_child).all(axis=(1, 2))
    if ok.sum() < 3:
        return None
    rel = Rotation.from_matrix(np.einsum("tji,tjk->tik", r_parent[ok], r_child[ok]))
    w = (rel * rel.mean().inv()).as_rotvec()  # (T', 3) in the parent's frame
    _, _, vt = np.linalg.svd(w - w.mean(axis=0), full_matrices=False)
    return vt[0]


#: A neighbour's joint counts only when its bone (hinge -> that joint) makes at least
#: this angle with the hinge's axis (degrees): a pelvis hung from one hip does not run
#: square to that hip's axis towards the other hip.
MIN_BONE_ANGLE_DEG = 60.0


def _square_to(bone: np.ndarray, axis: np.ndarray) -> bool:
    """Whether bone vectors ``(T, 3)`` make, in the median, at least
    :data:`MIN_BONE_ANGLE_DEG` with the unit ``axis``."""
    length = np.linalg.norm(bone, axis=1)
    ok = length > 1e-9
    if not ok.any():
        return False
    cos = float(np.median(np.abs(bone[ok] @ axis) / length[ok]))
    return cos <= np.cos(np.radians(MIN_BONE_ANGLE_DEG))


def centre_hinges_between_neighbours(model: BodyModel) -> BodyModel:
    """Slide each hinge along its axis to the mean of its neighbours' perpendicular feet.

    A segment whose joint was found as a hinge (:data:`HINGE_METHODS`), whose parent is
    not the root (the root's origin is no joint) and that has children: its joint
    ``k`` moves along the axis ``a`` (:func:`hinge_axis` on the calibrated frames) by
    the mean of ``(J - k) . a`` (the median over the take) over its neighbours'
    joints ``J`` -- the parent's own joint and the children's -- whose bone ``J - k``
    runs square enough to the axis (:data:`MIN_BONE_ANGLE_DEG`), all in the parent's
    anatomical frame; with no such neighbour it stays. The child's markers, end site,
    fixed joints and children's joints are re-expressed so they do not move in the
    world; ``methods`` notes the change.

    Parameters
    ----------
    model : BodyModel
        Calibrated (:func:`~skincap.solve.calibrate.calibrate`), metres.

    Returns
    -------
    BodyModel
        A new model; ``model`` is not changed.
    """
    parents = model.segment_parents
    offsets = model.joint_offsets.copy()
    marker_offsets = model.marker_offsets.copy()
    ends = {k: v.copy() for k, v in model.ends.items()}
    fixed = {k: [(n, p.copy()) for n, p in v] for k, v in model.fixed.items()}
    methods = dict(model.methods)
    rot = model.init_rotations  # (T, S, 3, 3) anatomical frames measured on the take
    for c in range(1, model.n_segments):
        name = model.segment_names[c]
        p = int(parents[c])
        kids = np.flatnonzero(parents == c)
        if model.methods.get(name) not in HINGE_METHODS or parents[p] < 0 or kids.size == 0:
            continue
        axis = hinge_axis(rot[:, p], rot[:, c])
        if axis is None:
            continue
        rel = np.einsum("tji,tjk->tik", rot[:, p], rot[:, c])  # (T, 3, 3) child in parent
        ok = np.isfinite(rel).all(axis=(1, 2))
        k = offsets[c]
        # each neighbour's joint relative to the hinge, in the parent's frame: the
        # parent's own (its origin) and, over the take, the children's
        bones = [-k[None]] + [
            np.einsum("tij,j->ti", rel[ok], offsets[kid]) for kid in kids
        ]  # each (T', 3)
        feet = [float(np.median(b @ axis)) for b in bones if _square_to(b, axis)]
        if not feet:
            continue
        shift_p = axis * float(np.mean(feet))  # in the parent's frame
        shift_c = np.median(np.einsum("tji,j->ti", rel[ok], shift_p), axis=0)  # in the child's
        offsets[c] = k + shift_p
        offsets[kids] -= shift_c
        marker_offsets[model.marker_segments == c] -= shift_c
        if name in ends:
            ends[name] = ends[name] - shift_c
        if name in fixed:
            fixed[name] = [(n, pos - shift_c) for n, pos in fixed[name]]
        methods[name] = f"{methods[name]}, centred between its neighbours' joints"
    return replace(
        model,
        joint_offsets=offsets,
        marker_offsets=marker_offsets,
        ends=ends,
        fixed=fixed,
        methods=methods,
    )
