"""``skincap convert`` as a workflow: one file in another format, by the extensions.

Markers go C3D <-> TRC <-> CSV (Vicon trajectories CSV; the long point format with
``points=True``), BVH -> BVH (``units`` rescales the written file), BVH -> CSV of
joint world positions, and meshes between OBJ and PLY (glTF read).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from skincap.errors import FormatError

__all__ = ["convert_file", "MARKER_OUTPUTS", "MESH_OUTPUTS"]

#: Extensions markers (and point clouds) convert to.
MARKER_OUTPUTS = (".c3d", ".trc", ".csv")
#: Extensions meshes convert to.
MESH_OUTPUTS = (".obj", ".ply")


def convert_file(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    force: bool = False,
    units: str | None = None,
    points: bool = False,
) -> dict[str, int]:
    """Convert ``src`` to ``dst`` by their extensions; return the counts written.

    ``dst`` is checked against ``src`` (links included) before anything is read; an
    existing ``dst`` is replaced only with ``force``. ``units`` is the length unit of
    a BVH or OBJ input; ``points`` writes markers as the long point CSV.

    Returns
    -------
    dict
        What was written: ``frames`` (and ``joints``) for captures and motions,
        ``vertices`` and ``triangles`` for meshes.

    Raises
    ------
    FormatError
        An unreadable input, or an output extension its data cannot be written as.
    """
    from skincap.io.output_safety import guard_outputs

    src, dst = Path(src), Path(dst)
    with guard_outputs([src], [dst], force=force):
        return _convert_checked(src, dst, force=force, units=units, points=points)


def _convert_checked(
    src: Path, dst: Path, *, force: bool, units: str | None, points: bool
) -> dict[str, int]:
    """Read ``src``, write ``dst``; return what was written: frames, joints, vertices, triangles."""
    from skincap import io
    from skincap.types import MarkerSet, Mesh, Motion, PointCloud

    in_kind = io.kind_of_extension(src)
    out_ext = dst.suffix.lower()
    read_options: dict[str, Any] = {}
    if (
        units is not None
        and in_kind in ("motion", "mesh")
        and src.suffix.lower() in (".bvh", ".obj")
    ):
        read_options["units"] = units
    if in_kind in ("markers", "motion", "mesh") and out_ext not in MARKER_OUTPUTS + MESH_OUTPUTS + (
        ".bvh",
    ):
        raise FormatError(
            dst,
            f"cannot write {out_ext or '(no extension)'!r}; convert writes {', '.join(MARKER_OUTPUTS + ('.bvh',) + MESH_OUTPUTS)}",
        )
    obj = io.read(src, **read_options)

    if isinstance(obj, MarkerSet | PointCloud):
        if out_ext not in MARKER_OUTPUTS:
            raise FormatError(dst, f"markers convert to {', '.join(MARKER_OUTPUTS)}, not {out_ext}")
        if isinstance(obj, MarkerSet) and points:
            if out_ext != ".csv":
                raise FormatError(
                    dst, "--points writes the long point CSV format: give a .csv output"
                )
            from skincap.io.c3d.content import warn_dropped_c3d_content

            # said here, where the MarkerSet still has them; the cloud then carries no
            # C3D content, so the writer does not say it again
            warn_dropped_c3d_content(
                obj.meta,
                "a point CSV",
                dst,
                stacklevel=1,
                camera_masks=obj.camera_masks,
                residuals=obj.residuals,
            )
            obj = PointCloud.from_markerset(obj)
            obj.meta.pop("c3d", None)
        elif isinstance(obj, PointCloud) and out_ext != ".csv":
            obj = obj.to_markerset()
        if out_ext == ".c3d" and isinstance(obj, MarkerSet):
            from skincap.io.c3d import c3d_emptiness

            empty = c3d_emptiness(obj)
            if empty is not None:  # the input is at fault, not the output path
                raise FormatError(src, f"cannot convert to {dst.name}: {empty}")
        io.write(obj, dst, force=force)
        return {"frames": obj.n_frames}
    if isinstance(obj, Motion):
        if out_ext == ".bvh":
            io.write(obj, dst, force=force)
        elif out_ext == ".csv":
            from skincap.io.joints_csv import write_joint_positions_csv

            write_joint_positions_csv(obj, dst, force=force)
        else:
            raise FormatError(
                dst, f"a BVH converts to .bvh or .csv (joint positions), not {out_ext}"
            )
        return {"frames": obj.n_frames, "joints": obj.skeleton.n_joints}
    if isinstance(obj, Mesh):
        if out_ext not in MESH_OUTPUTS:
            raise FormatError(dst, f"a mesh converts to {', '.join(MESH_OUTPUTS)}, not {out_ext}")
        io.write(obj, dst, force=force)
        return {"vertices": obj.n_vertices, "triangles": obj.n_faces}
    raise FormatError(src, "this file type cannot be converted")
