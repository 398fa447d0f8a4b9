"""``skincap skin`` as a workflow: a mesh and a BVH motion in, a skinned animation out.

Bind the mesh to a skeleton (the file's weights or bone heat), retarget the motion
onto it, deform (LBS or DQS) and export by the output's extension:

``OUT.glb``
    The skinned mesh with the joint animation (glTF skinning is linear).
``OUT.pc2`` (+ ``OUT.obj``)
    A point cache of the baked frames and the rest mesh it plays on.
``OUT.usd`` / ``.usda`` / ``.usdc``
    Time-sampled points.
a folder
    One OBJ per frame; its size is announced before it is written.

This module composes :mod:`skincap.deform.skeletal` with :mod:`skincap.io`.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from skincap.errors import FormatError, OutputExistsError, UnitWarning, ValidationError
from skincap.io.mesh_animation_files import animation_output_files, write_mesh_animation
from skincap.workflows.progress import FrameProgress, frame_fractions

__all__ = [
    "SKIN_METHODS",
    "SKIN_OUTPUTS",
    "check_skin_request",
    "skin_file",
    "mesh_input_files",
    "skin_output_files",
    "write_skinned",
]

#: Deformers of :func:`skin_file`: skeletal LBS and DQS, and the sweep-based deformer.
SKIN_METHODS = ("lbs", "dqs", "sweep")

#: Output extensions of :func:`skin_file` (an output without one is a folder).
SKIN_OUTPUTS = (".glb", ".pc2", ".usd", ".usda", ".usdc")


def mesh_input_files(mesh_path: Path) -> list[Path]:
    """Every file reading ``mesh_path`` may open: the mesh, a MakeHuman rig beside an
    ``.obj`` (``.mhskel``/``.mhw``), the ``.bin`` buffers beside a ``.gltf``."""
    files = [mesh_path]
    ext = mesh_path.suffix.lower()
    folder = mesh_path.parent
    if ext == ".obj" and folder.is_dir():
        files += sorted(folder.glob("*.mhskel")) + sorted(folder.glob("*.mhw"))
    elif ext == ".gltf" and folder.is_dir():
        files += sorted(folder.glob("*.bin"))
    return files


def skin_output_files(output: Path) -> list[Path]:
    """The files ``skin -o output`` writes, known before skinning (a folder's frames are
    checked once the frame count is known)."""
    return animation_output_files(output)


#: Heights (metres) of a human body a bare OBJ/PLY read in metres may have unwarned.
_PLAUSIBLE_BODY_M = (0.5, 2.5)


def _warn_implausible_height(mesh_path: Path, height_m: float) -> None:
    """Warn when a mesh read as metres (no ``--mesh-units``) is no human height, naming
    the unit that would make it one (an OBJ in decimetres, MakeHuman's unit, is 17 m)."""
    from skincap.io.bvh.units import BVH_UNITS, guess_bvh_units

    if not height_m > 0 or _PLAUSIBLE_BODY_M[0] <= height_m <= _PLAUSIBLE_BODY_M[1]:
        return
    unit = guess_bvh_units(height_m)
    hint = (
        f"; with --mesh-units {unit} it would be {height_m * BVH_UNITS[unit]:.2f} m"
        if unit not in ("m", "cmu")
        else ""
    )
    warnings.warn(
        f"{mesh_path}: the mesh is {height_m:.3g} m tall read as metres, no human height{hint}",
        UnitWarning,
        stacklevel=3,
    )


def skin_file(
    mesh_path: str | os.PathLike[str],
    motion_path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    method: str = "lbs",
    weights: str | None = None,
    name_map: str | os.PathLike[str] | None = None,
    units: str | None = None,
    mesh_units: str | None = None,
    max_influences: int = 4,
    force: bool = False,
    progress: FrameProgress | None = None,
    notify: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Bind, retarget, deform and export; return the summary (``skin --json``).

    Parameters
    ----------
    mesh_path : path-like
        MakeHuman ``.obj`` (rig beside it), skinned ``.glb``/``.gltf``, or a bare
        ``.obj``/``.ply`` (:func:`skincap.io.read_mesh`).
    motion_path : path-like
        A BVH motion.
    output : path-like
        By extension (:data:`SKIN_OUTPUTS`), or a folder for an OBJ sequence.
    method : {"lbs", "dqs", "sweep"}
        Deformer of baked outputs (``.glb`` is always LBS). ``"sweep"``: the arms
        and legs follow sweeps of ellipses fitted to the mesh (Hyun et al. 2005,
        :mod:`skincap.deform.sweep`, volume kept), the rest DQS; a mesh whose limbs
        the sweeps cannot be fitted to raises :class:`FormatError` naming it (a rig
        whose joint names give no limb: the file the rig came from).
    weights : {"auto", "file"}, optional
        Bone heat or the file's weights; default: the file's for a rigged mesh.
    name_map : path-like, optional
        JSON ``{bvh_joint: mesh_joint}`` overriding the built-in name maps.
    units, mesh_units : str, optional
        Length units of the BVH (guessed when omitted) and of the mesh.
    max_influences : int
        Joints per vertex.
    force : bool
        Replace existing outputs (checked, with the inputs, before anything is read).
    progress : FrameProgress, optional
        Frames skinned so far.
    notify : callable, optional
        Receives one line before a folder output is written: how many OBJ files and
        about how many bytes.

    Returns
    -------
    dict
        ``mesh``, ``motion``, ``outputs``, ``files``, ``vertices``, ``height_m``,
        ``joints``, ``frames``, ``rate`` (Hz), ``method``, ``weights``.
    """
    from skincap import io
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.evaluate.summary import mesh_height
    from skincap.io.bvh import read_bvh
    from skincap.io.output_safety import guard_outputs

    mesh_path, motion_path, output = Path(mesh_path), Path(motion_path), Path(output)
    map_path = None if name_map is None else Path(name_map)
    with guard_outputs(
        [*mesh_input_files(mesh_path), motion_path, map_path],
        skin_output_files(output),
        folders=[] if output.suffix else [output],
        force=force,
    ):
        check_skin_request(output, method=method, weights=weights, force=force)
        mesh = io.read_mesh(mesh_path, units=mesh_units)
        if mesh_units is None and mesh_path.suffix.lower() in (".obj", ".ply"):
            _warn_implausible_height(mesh_path, mesh_height(mesh))
        if mesh.n_faces == 0 and (weights == "auto" or mesh.skin is None):
            # bone heat diffuses over the surface: without one every vertex would just
            # follow its nearest bone, a point cloud posing as a skin
            raise FormatError(
                mesh_path,
                "the mesh has no faces; automatic (bone-heat) weights need a triangle surface",
            )
        motion = read_bvh(motion_path, units=units)
        if motion.n_frames == 0:  # every output is an animation; none of them can be empty
            raise FormatError(motion_path, "no motion frames ('Frames: 0'); nothing to skin")
        if not output.suffix:  # before binding, which can take minutes for a bare mesh
            _check_obj_sequence(mesh, motion.n_frames, output, notify)
        try:
            setup = prepare_skinning(
                mesh,
                motion,
                weights=weights,
                name_map=map_path,
                max_influences=max_influences,  # type: ignore[arg-type]
            )
        except ValidationError as exc:
            # a joint the map names that neither skeleton has, or a pairing that breaks
            # the hierarchy: the --map file is at fault, not the mesh or the motion
            text = str(exc)
            if map_path is None or not text.startswith("name_map: "):
                raise
            raise FormatError(map_path, text.removeprefix("name_map: ")) from None
        frames = setup.motion.n_frames
        fractions = frame_fractions(progress, frames)
        animation = None
        if method == "sweep":  # fitted before anything is written: a misfit names the mesh
            from skincap.deform.sweep import sweep_motion

            try:
                animation = sweep_motion(setup.mesh, setup.motion, progress=fractions)
            except ValidationError as exc:
                text = str(exc)
                # limb names come from the rig: the BVH's when a bare mesh took its skeleton
                rig_file = motion_path if setup.report.get("rig") == "motion" else mesh_path
                at_fault = rig_file if text.startswith("skeleton: ") else mesh_path
                raise FormatError(at_fault, text.removeprefix("mesh: ")) from None
        written = write_skinned(
            setup, output, method=method, force=force, progress=fractions, animation=animation
        )
        return {
            "mesh": str(mesh_path),
            "motion": str(motion_path),
            "outputs": [str(p) for p in (written if output.suffix else [output])],
            "files": len(written),
            "vertices": setup.mesh.n_vertices,
            "height_m": mesh_height(setup.mesh),
            "joints": setup.mesh.skin.skeleton.n_joints,
            "frames": frames,
            "rate": setup.motion.rate,
            "method": method,
            "weights": setup.report["weights"],
        }


def check_skin_request(output: Path, *, method: str, weights: str | None, force: bool) -> None:
    """Refuse an unknown method, weights or output extension, DQS into ``.glb``, and a
    non-empty output folder without ``force``, before any input is read."""
    ext = output.suffix.lower()
    if method not in SKIN_METHODS:
        raise FormatError(output, f"--method must be lbs, dqs or sweep, got {method!r}")
    if ext and ext not in SKIN_OUTPUTS:
        raise FormatError(
            output,
            f"cannot write {ext!r}; skin writes {', '.join(SKIN_OUTPUTS)} or a folder (OBJ sequence)",
        )
    if ext == ".glb" and method != "lbs":
        raise FormatError(
            output,
            f"glTF skinning is linear blend skinning; write .pc2, .usd or a folder to bake {method}",
        )
    if weights not in (None, "auto", "file"):
        raise FormatError(output, f"--weights must be auto or file, got {weights!r}")
    if not ext and output.is_dir() and any(output.iterdir()) and not force:
        raise OutputExistsError(output)


def _check_obj_sequence(
    mesh: Any, frames: int, folder: Path, notify: Callable[[str], None] | None
) -> None:
    """Check an OBJ-sequence folder's frame files against the inputs; say the size first.

    ``mesh`` is the rest mesh as read (binding keeps its vertices and topology) and
    ``frames`` the motion's frame count (retargeting keeps it)."""
    from skincap.io.obj_sequence import estimate_obj_sequence_bytes, obj_sequence_paths
    from skincap.io.output_safety import check_outputs

    check_outputs(obj_sequence_paths(folder, frames), force=True)
    size = estimate_obj_sequence_bytes(mesh, frames, units="m", up="y")
    if notify is not None:
        notify(f"writing {frames} OBJ files to {folder}, about {bytes_text(size)}")


def bytes_text(size: float) -> str:
    """``4.0 GB``, ``512 MB``…: decimal units, as file managers and ``df -H`` show them."""
    if size < 1000:
        return f"{size:.0f} B"
    for unit in ("kB", "MB", "GB"):
        size /= 1000
        if size < 1000 or unit == "GB":
            break
    return f"{size:.1f} {unit}"


def write_skinned(
    setup: Any,
    output: Path,
    *,
    method: str,
    force: bool,
    progress: Callable[[float], None],
    animation: Any = None,
) -> list[Path]:
    """Export a :class:`SkinningSetup` by ``output``'s extension; return the written paths.

    ``progress`` receives the fraction of frames deformed (1.0 at once for ``.glb``,
    which stores the joint animation, not baked frames). ``animation``: an already
    built :class:`~skincap.types.MeshAnimation` of ``setup`` to write instead of
    skinning it with ``method`` (how ``skin_file`` passes the sweep deformer's).
    """
    from skincap.deform.skeletal.deformers import skin_motion

    ext = output.suffix.lower()
    if ext == ".glb":
        from skincap.io.gltf.writer import write_glb

        write_glb(setup.mesh, setup.motion, output, force=force)
        progress(1.0)
        return [output]
    if animation is None:
        animation = skin_motion(setup.mesh, setup.motion, method=method, progress=progress)
    return write_mesh_animation(animation, output, force=force)
