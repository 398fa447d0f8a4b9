"""A mesh animation as a sequence of Wavefront OBJ files, one per frame.

Every file has the rest mesh's topology as :func:`skincap.io.mesh.write_obj` writes it
(source polygons, so quads stay quads; groups, objects, materials and UVs) and that
frame's vertex positions. The topology text is produced once and reused; only the
``v`` lines change from frame to frame, formatted for all vertices of a frame in one
call. Normals of the rest mesh are not written (they would be wrong once the mesh
deforms; importers compute their own).

Files are named ``<stem>_<frame>.obj`` with the frame number zero-padded to at least
four digits (``frame_0000.obj``, ``frame_0001.obj``...), numbered from 0.
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from skincap.errors import FormatError, OutputExistsError, ValidationError
from skincap.io._common import atomic_output, finite_frame_chunks, from_y_up, unit_scale
from skincap.io.mesh import write_obj
from skincap.io.mesh.obj import rate_comment
from skincap.io.output_safety import is_protected_input
from skincap.types import Mesh, MeshAnimation

__all__ = ["write_obj_sequence", "obj_sequence_paths", "estimate_obj_sequence_bytes"]

_STEM = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


def _topology_text(
    rest: Mesh, units: str, up: str, comments: tuple[str, ...] = ()
) -> tuple[str, str]:
    """(head, tail): the rest mesh's OBJ text before and after its ``v`` lines."""
    meta = {k: v for k, v in rest.meta.items() if k not in ("normal_table", "corner_normal")}
    bare = replace(rest, meta=meta, skin=None)
    with tempfile.TemporaryDirectory(prefix="skincap_obj_") as tmp:
        path = Path(tmp) / "rest.obj"
        write_obj(bare, path, units=units, up=up, comments=comments)
        lines = path.read_text(encoding="utf-8").split("\n")
    first = next(i for i, line in enumerate(lines) if line.startswith("v "))
    n = rest.n_vertices
    head = "\n".join(lines[:first]) + "\n"
    tail = "\n".join(lines[first + n :])
    return head, tail


def _frame_digits(n_frames: int) -> int:
    return max(4, len(str(max(n_frames - 1, 0))))


def _vertex_line(digits: int | None) -> str:
    return "v %r %r %r\n" if digits is None else f"v %.{digits}g %.{digits}g %.{digits}g\n"


def obj_sequence_paths(
    folder: str | os.PathLike[str], n_frames: int, *, stem: str = "frame"
) -> list[Path]:
    """The files :func:`write_obj_sequence` writes for ``n_frames`` frames, in frame order."""
    width = _frame_digits(n_frames)
    return [Path(folder) / f"{stem}_{t:0{width}d}.obj" for t in range(n_frames)]


def estimate_obj_sequence_bytes(
    rest: Mesh,
    n_frames: int,
    *,
    units: str | None = None,
    up: str | None = None,
    digits: int | None = 9,
) -> int:
    """Bytes :func:`write_obj_sequence` will write for ``n_frames`` frames of ``rest``.

    The rest mesh's own file (topology written once per frame, vertices formatted as
    the sequence formats them) times the frame count: exact for the topology. The
    rest coordinates are nudged by a relative 1e-8·√2 first, so they print with every
    significant digit as a moving body's do (a modelled rest pose often has short
    ones, ``0.49627``). So it errs a little high: 4 % for a bending cylinder whose
    base stays still (still vertices keep short numbers), 3 % for a body moving as a
    whole (the MakeHuman body on a BVH: 11.9 MB said, 11.56 MB written).

    Parameters
    ----------
    rest : Mesh
        (V, 3) rest vertices, metres, Y up.
    n_frames : int
    units, up, digits
        As for :func:`write_obj_sequence`.
    """
    units_name = units if units is not None else str(rest.meta.get("source_units", "m"))
    up_key = up if up is not None else str(rest.meta.get("up", "y"))
    # the rate comment at its longest float text (sign, 17 digits, exponent)
    head, tail = _topology_text(
        rest, units_name, up_key, (rate_comment("OBJ sequence", -1.2345678901234567e-100, ""),)
    )
    coords = from_y_up(rest.vertices, up_key) / unit_scale(units_name)
    coords = coords * (1.0 + np.sqrt(2.0) * 1e-8)  # every significant digit shows
    vertices = (_vertex_line(digits) * rest.n_vertices) % tuple(coords.reshape(-1).tolist())
    return int(n_frames) * len((head + vertices + tail).encode("utf-8"))


def write_obj_sequence(
    animation: MeshAnimation,
    folder: str | os.PathLike[str],
    *,
    force: bool = False,
    stem: str = "frame",
    units: str | None = None,
    up: str | None = None,
    digits: int | None = 9,
    chunk: int = 64,
    progress: Callable[[int, int], None] | None = None,
) -> list[Path]:
    """Write one OBJ file per frame of a mesh animation.

    Parameters
    ----------
    animation : MeshAnimation
        ``n_frames`` frames of (V, 3) float64 positions, metres, Y up, streamed from
        ``animation.iter_chunks(chunk)``; topology from ``animation.rest``. NaN or
        infinite positions are refused (OBJ has no missing vertices).
    folder : str or PathLike
        Output folder, created when missing (its parent must exist). An existing
        non-empty folder is refused unless ``force``; with ``force``, files of the
        sequence are replaced and older ``<stem>_<digits>.obj`` files beyond the new
        frame count are removed (nothing else in the folder is touched).
    force : bool
        Write into an existing non-empty folder.
    stem : str, default "frame"
        File name stem: letters, digits, ``.``, ``_``, ``-``.
    units, up : str, optional
        Unit and up axis of the files; default the rest mesh's
        ``meta["source_units"]`` and ``meta["up"]`` (metres and Y when absent), as
        :func:`skincap.io.mesh.write_obj` does.
    digits : int or None, default 9
        Significant digits of the vertex coordinates (9 keeps float32 exactly);
        None writes the shortest text that reads back to the same float64.
    chunk : int, default 64
        Frames pulled from the animation at a time.
    progress : callable, optional
        Called as ``progress(frames_done, n_frames)`` after each chunk.

    Returns
    -------
    list of Path
        The files written, in frame order.

    Raises
    ------
    OutputExistsError
        ``folder`` exists, is not empty and ``force`` is False.
    FormatError
        ``folder`` is a file, or its parent folder does not exist.
    ValidationError
        Bad ``stem``/``units``/``up``/``digits``/``chunk``, non-finite positions, or a
        streamed animation whose frame count differs from ``n_frames``. Each file is
        written atomically; files of earlier frames stay when a later frame fails.
    """
    if not isinstance(animation, MeshAnimation):
        raise ValidationError(
            f"animation: expected a skincap MeshAnimation, got {type(animation).__name__}"
        )
    if not _STEM.match(stem):
        raise ValidationError(
            f"stem: expected letters, digits, '.', '_' or '-' (no path), got {stem!r}"
        )
    if digits is not None and not (isinstance(digits, int) and 1 <= digits <= 17):
        raise ValidationError(f"digits: expected None or an integer in 1..17, got {digits!r}")
    if int(chunk) < 1:
        raise ValidationError(f"chunk: expected a positive number of frames, got {chunk!r}")
    rest = animation.rest
    units_name = units if units is not None else str(rest.meta.get("source_units", "m"))
    up_key = up if up is not None else str(rest.meta.get("up", "y"))
    scale = 1.0 / unit_scale(units_name)
    from_y_up(np.zeros((1, 3)), up_key)  # validates ``up``

    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise FormatError(out, "exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise OutputExistsError(out)
    if not out.parent.is_dir():
        raise FormatError(out, f"cannot create: folder {str(out.parent)!r} does not exist")
    out.mkdir(exist_ok=True)

    n_frames = int(animation.n_frames or 0)
    width = _frame_digits(n_frames)
    # every frame notes the take's rate (an OBJ has none) for view and render
    note = rate_comment("OBJ sequence", animation.rate, "this folder")
    head, tail = _topology_text(rest, units_name, up_key, (note,))
    n = rest.n_vertices
    vertex_format = _vertex_line(digits) * n
    written: list[Path] = []
    for _, block in finite_frame_chunks(animation, chunk):
        coords = from_y_up(block, up_key) * scale  # (t, V, 3) in the file's unit and axes
        for frame in coords:
            target = out / f"{stem}_{len(written):0{width}d}.obj"
            text = head + vertex_format % tuple(frame.reshape(-1).tolist()) + tail
            with atomic_output(target, force=True) as tmp:
                tmp.write_text(text, encoding="utf-8")
            written.append(target)
        if progress is not None:
            progress(len(written), n_frames)
    pattern = re.compile(rf"^{re.escape(stem)}_\d{{4,}}\.obj$")
    keep = {p.name for p in written}
    for old in out.iterdir():
        if (
            old.is_file()
            and pattern.match(old.name)
            and old.name not in keep
            and not is_protected_input(old)  # an input in the folder is never deleted
        ):
            old.unlink()
    return written
