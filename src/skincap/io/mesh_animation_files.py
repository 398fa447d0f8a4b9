"""A :class:`~skincap.types.MeshAnimation` to the file (or folder) its path names.

``.pc2`` writes the point cache and, beside it, the rest mesh as an OBJ of the same
name (metres, Y up: the mesh Blender's Mesh Cache modifier plays the cache on; a
comment in it records the frame rate PC2 cannot hold);
``.usd``/``.usda``/``.usdc`` a USD stage with time-sampled points; any other path a
folder of OBJ frames. Shared by ``skin`` and ``animate``.
"""

from __future__ import annotations

from pathlib import Path

from skincap.types import MeshAnimation

_USD = (".usd", ".usda", ".usdc")


def animation_output_files(output: Path) -> list[Path]:
    """The files :func:`write_mesh_animation` writes to ``output``, known before any
    frame is computed (a folder's frames are known only once the frame count is)."""
    if output.suffix.lower() == ".pc2":
        return [output, output.with_suffix(".obj")]  # the cache and the mesh it plays on
    return [output] if output.suffix else []


def write_mesh_animation(animation: MeshAnimation, output: Path, *, force: bool) -> list[Path]:
    """Write ``animation`` (its frames streamed once) by ``output``'s extension; return
    the written paths."""
    ext = output.suffix.lower()
    if ext == ".pc2":
        from skincap.io.mesh import write_obj
        from skincap.io.pc2 import pc2_rate_comment, write_pc2

        rest_obj = output.with_suffix(".obj")
        # The cache first: its frames are computed while it streams, so it is the write
        # that can fail midway; the rest mesh is cheap. A failed OBJ takes the new cache
        # with it, so a failure never leaves one file of the pair.
        write_pc2(animation, output, force=force)
        try:
            write_obj(
                animation.rest,
                rest_obj,
                force=force,
                units="m",
                up="y",
                comments=(pc2_rate_comment(output, animation.rate),),
            )
        except BaseException:
            output.unlink(missing_ok=True)
            raise
        return [output, rest_obj]
    if ext in _USD:
        from skincap.io.usd import write_usd

        write_usd(animation, output, force=force)
        return [output]
    from skincap.io.obj_sequence import write_obj_sequence

    write_obj_sequence(animation, output, force=force, units="m", up="y")
    return [output]
