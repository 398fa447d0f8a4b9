"""From a mesh and a motion to a skinned mesh and a motion on its rig.

This is what ``skincap skin`` runs between reading and exporting:

* a **rigged** mesh (MakeHuman, a skinned glTF) keeps its rig; its weights come from
  the file or are recomputed by bone heat; the motion is retargeted onto the rig;
* a **bare** mesh is bound to the motion's own skeleton: the skeleton's rest pose is
  scaled and moved onto the mesh (the mesh must stand in that pose, Y up), bone-heat
  weights are computed, and the motion is scaled and moved the same way.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from skincap.deform.skeletal.bind import bind_mesh, fit_skeleton_to_mesh, transform_skeleton
from skincap.deform.skeletal.rest_pose import warn_if_rest_pose_differs
from skincap.deform.skeletal.retarget import retarget
from skincap.errors import ValidationError
from skincap.types import Mesh, Motion

__all__ = ["SkinningSetup", "prepare_skinning", "fit_motion"]


@dataclass
class SkinningSetup:
    """A skinned mesh and a motion on its skeleton, ready for a deformer or export.

    Attributes
    ----------
    mesh : Mesh
        With a :class:`~skincap.types.Skin`.
    motion : Motion
        On ``mesh.skin.skeleton`` (same joint names, same order).
    report : dict
        How they were made: ``rig`` (``"mesh"`` or ``"motion"``), ``weights``
        (``"file"`` or ``"auto"``), ``max_influences``, and the retargeting or
        fitting details.
    """

    mesh: Mesh
    motion: Motion
    report: dict[str, Any] = field(default_factory=dict)


def fit_motion(motion: Motion, scale: float, translation: np.ndarray) -> Motion:
    """``motion`` with every length scaled and its roots moved: ``p -> scale * p + translation``.

    Rotations are unchanged; local translations (T, J, 3) are scaled; roots also
    get ``translation`` (metres) added, so world joint positions map the same way.
    """
    skeleton = transform_skeleton(motion.skeleton, scale, translation)
    translations = motion.translations * float(scale)
    roots = motion.skeleton.parents < 0
    translations[:, roots] += np.asarray(translation, dtype=np.float64)
    return Motion(
        skeleton=skeleton,
        rotations=motion.rotations,
        translations=translations,
        rate=motion.rate,
        channels=motion.channels,
        meta={
            **motion.meta,
            "fit": {"scale": float(scale), "translation": np.asarray(translation).tolist()},
        },
    )


def prepare_skinning(
    mesh: Mesh,
    motion: Motion,
    *,
    weights: Literal["auto", "file"] | None = None,
    name_map: dict[str, Any] | str | os.PathLike[str] | None = None,
    max_influences: int = 4,
) -> SkinningSetup:
    """Bind ``mesh`` and put ``motion`` on its rig.

    Parameters
    ----------
    mesh : Mesh
        Metres, Y up. With a skin (rigged) or without (bare).
    motion : Motion
        Any skeleton, metres, Y up; its zero pose is its rest pose.
    weights : {"auto", "file"}, optional
        ``"file"`` uses the mesh's own weights (it must have a skin); ``"auto"``
        computes bone-heat weights. Default: ``"file"`` for a rigged mesh,
        ``"auto"`` for a bare one.
    name_map : dict or JSON path, optional
        Source-to-target joint names for retargeting onto a rigged mesh; overrides
        the built-in maps.
    max_influences : int
        Joints per vertex, the largest weights renormalised.

    Returns
    -------
    SkinningSetup
    """
    if weights is None:
        weights = "file" if mesh.skin is not None else "auto"
    if weights not in ("auto", "file"):
        raise ValidationError(f"weights: expected 'auto' or 'file', got {weights!r}")
    if weights == "file" and mesh.skin is None:
        raise ValidationError(
            "weights: the mesh has no skin weights in its file; use weights='auto'"
        )
    report: dict[str, Any] = {"weights": weights, "max_influences": int(max_influences)}

    if mesh.skin is not None:
        skin = mesh.skin
        bound = bind_mesh(
            mesh,
            skin.skeleton,
            rest_world=skin.bind_matrices,
            weights=weights,
            max_influences=max_influences,
        )
        on_rig = retarget(motion, bound, name_map=name_map)
        report.update(rig="mesh", retarget=on_rig.meta.get("retarget", {}))
        return SkinningSetup(bound, on_rig, report)

    if name_map is not None:
        raise ValidationError(
            "name_map: a bare mesh is bound to the motion's own skeleton; there is nothing to map"
        )
    scale, translation = fit_skeleton_to_mesh(motion.skeleton, mesh)
    fitted = fit_motion(motion, scale, translation)
    # a mesh not in the skeleton's rest pose binds skin to the wrong bones: say how far off
    misfit = warn_if_rest_pose_differs(mesh, fitted.skeleton, stacklevel=2)
    bound = bind_mesh(mesh, fitted.skeleton, weights="auto", max_influences=max_influences)
    report.update(
        rig="motion", fit_scale=scale, fit_translation=translation.tolist(), rest_pose=misfit
    )
    return SkinningSetup(bound, fitted, report)
