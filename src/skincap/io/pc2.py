"""PC2 point caches (3ds Max / Blender "Mesh Cache" format): writer and reader.

Layout (little-endian)::

    char[12]  'POINTCACHE2\\0'
    int32     version (1)
    int32     numPoints
    float32   startFrame      first frame number of the cache
    float32   sampleRate      frames between two samples (1.0 = one sample a frame)
    int32     numSamples
    float32   points[numSamples][numPoints][3]

PC2 knows frames, not seconds: the frame rate in Hz is not stored (``sampleRate`` is a
step in frames, as 3ds Max's UI and Blender's own PC2 exporter use it). So
``skin``/``animate`` write it as a comment in the rest OBJ beside the cache
(:func:`pc2_rate_comment`), where the viewer and renderer read it back
(:func:`recorded_pc2_rate`); OBJ readers skip comments.

Coordinates. By default the cache holds skincap's own coordinates: metres, Y up.
That is what Blender needs for an OBJ of the rest mesh imported with Blender's default
OBJ settings (``File > Import > Wavefront (.obj)``, forward -Z, up Y): the importer
keeps the file's coordinates in the mesh data and puts the Y-up -> Z-up turn in the
object's rotation, so a Mesh Cache modifier (format PC2, default axes forward +Y /
up +Z, i.e. no conversion) on that object plays the cache in place. ``up="z"`` writes
Blender-native Z-up coordinates, ``(x, y, z) -> (x, -z, y)``, for a mesh whose data is
already Z up (a mesh modelled in Blender, or imported with the axis conversion baked
into the vertices) -- the same turn Blender's glTF importer applies. Both were checked
in Blender 3.4 (tests/export/test_blender.py). Do not set the modifier's axes to
forward -Z / up +Y for a Y-up cache on a default-imported OBJ: the object's rotation
already turns it, and the mesh ends up turned twice. The vertex order must be the
OBJ's: Blender's OBJ importer (``wm.obj_import``) keeps it; the legacy Python add-on
(``import_scene.obj``, still in 3.4) reorders vertices with its default settings,
which scrambles a point cache.

The Mesh Cache modifier's frame mapping (time mode "Frame", frame start 0, frame scale
1) shows sample ``f`` at scene frame ``f``; set the modifier's frame start to 1 to show
sample 0 at Blender's default first frame.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

from skincap.errors import FormatError, ValidationError
from skincap.io._common import (
    atomic_output,
    check_readable,
    finite_frame_chunks,
    from_y_up,
    to_y_up,
    unit_scale,
)
from skincap.io.narrowing import check_float32, frame_vertex_axis
from skincap.types import MeshAnimation

__all__ = [
    "write_pc2",
    "read_pc2",
    "PC2Cache",
    "PC2_SIGNATURE",
    "pc2_rate_comment",
    "recorded_pc2_rate",
]

PC2_SIGNATURE = b"POINTCACHE2\0"


def pc2_rate_comment(cache: str | os.PathLike[str], rate: float) -> str:
    """The rest OBJ's comment line recording ``cache``'s frame rate ``rate`` (Hz)."""
    from skincap.io.mesh.obj import rate_comment

    return rate_comment("PC2", rate, Path(cache).name)


def recorded_pc2_rate(rest_obj: str | os.PathLike[str]) -> float | None:
    """The frame rate (Hz) :func:`pc2_rate_comment` recorded in ``rest_obj``, or None
    (missing, unreadable or not a positive number: the caller falls back)."""
    from skincap.io.mesh.obj import recorded_rate

    return recorded_rate(rest_obj, "PC2")


_HEADER = struct.Struct("<12siiffi")  # 32 bytes


class PC2Cache(NamedTuple):
    """What :func:`read_pc2` returns; unpacks as ``frames, sample_rate, start_frame``.

    Attributes
    ----------
    frames : (T, V, 3) float64
        Point positions per sample, metres, Y up (after the ``units``/``up`` given
        to :func:`read_pc2`).
    sample_rate : float
        The header's ``sampleRate``: frames between two samples (1.0 = every frame).
        Not a rate in Hz: PC2 does not store one.
    start_frame : float
        The header's ``startFrame``: the frame number of the first sample.
    """

    frames: np.ndarray
    sample_rate: float
    start_frame: float


def _frame_number(animation: MeshAnimation, start_frame: float | None) -> float:
    if start_frame is None:
        start_frame = animation.meta.get("first_frame", animation.rest.meta.get("first_frame", 0))
    try:
        value = float(start_frame)
    except (TypeError, ValueError):
        raise ValidationError(
            f"start_frame: expected a frame number, got {start_frame!r}"
        ) from None
    if not np.isfinite(value):
        raise ValidationError(f"start_frame: expected a finite frame number, got {start_frame!r}")
    return value


def write_pc2(
    animation: MeshAnimation,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    up: str = "y",
    units: str = "m",
    start_frame: float | None = None,
    sample_rate: float = 1.0,
    chunk: int = 64,
) -> None:
    """Write a mesh animation as a PC2 point cache, streaming chunk by chunk.

    Frames are taken from ``animation.iter_chunks(chunk)`` and written as they come,
    so a streamed animation (an iterator of chunks, as the deformers produce) is
    never held in memory as a whole.

    Parameters
    ----------
    animation : MeshAnimation
        ``n_frames`` frames of (V, 3) float64 vertex positions, metres, Y up; in the
        vertex order of ``animation.rest`` (which must match the mesh the cache is
        applied to). NaN or infinite positions are refused.
    path : str or PathLike
        Output ``.pc2``; refused when it exists unless ``force``.
    force : bool
        Replace an existing file.
    up : {"y", "z"}
        Up axis of the written coordinates. ``"y"`` (default): skincap's own, for
        the mesh data of an OBJ imported into Blender with default settings;
        ``"z"``: ``(x, y, z) -> (x, -z, y)``, Blender-native. See the module notes.
    units : str, default "m"
        Length unit of the written coordinates (``"m"``, ``"cm"``, ``"dm"``...); use
        the unit the rest mesh was exported in.
    start_frame : float, optional
        The header's ``startFrame``. Default ``animation.meta["first_frame"]`` (then
        the rest mesh's), else 0.
    sample_rate : float, default 1.0
        The header's ``sampleRate``: frames between samples (positive).
    chunk : int, default 64
        Frames per chunk pulled from the animation.

    Raises
    ------
    ValidationError
        Bad ``up``/``units``/``sample_rate``/``chunk``, non-finite positions, or a
        streamed animation that yields a different number of frames than
        ``n_frames`` (nothing is left behind: the write is atomic).
    FormatError
        A position (in ``units``) beyond float32's range (nothing written).
    OutputExistsError
        ``path`` exists and ``force`` is False.
    """
    if not isinstance(animation, MeshAnimation):
        raise ValidationError(
            f"animation: expected a skincap MeshAnimation, got {type(animation).__name__}"
        )
    from_y_up(np.zeros((1, 3)), up)  # validates ``up``
    scale = 1.0 / unit_scale(units)
    step = float(sample_rate)
    if not np.isfinite(step) or step <= 0:
        raise ValidationError(
            f"sample_rate: expected a positive number of frames between samples, got {sample_rate!r}"
        )
    if int(chunk) < 1:
        raise ValidationError(f"chunk: expected a positive number of frames, got {chunk!r}")
    n_points = animation.rest.n_vertices
    n_samples = int(animation.n_frames or 0)
    start = _frame_number(animation, start_frame)
    check_float32(np.array([start, step]), path, lambda i: ("startFrame", "sampleRate")[i[0]])
    header = _HEADER.pack(PC2_SIGNATURE, 1, n_points, start, step, n_samples)
    with atomic_output(path, force=force) as tmp, open(tmp, "wb") as fh:
        fh.write(header)
        chunks = finite_frame_chunks(
            animation, chunk, missing_note="; PC2 cannot store missing points"
        )
        for first, block in chunks:
            out = from_y_up(block, up) * scale
            check_float32(out, path, frame_vertex_axis(first), unit=units)
            fh.write(np.ascontiguousarray(out, dtype="<f4").tobytes())


def read_pc2(path: str | os.PathLike[str], *, up: str = "y", units: str = "m") -> PC2Cache:
    """Read a PC2 point cache.

    Parameters
    ----------
    path : str or PathLike
    up : {"y", "z"}
        Up axis of the file's coordinates (as given to :func:`write_pc2`);
        converted to Y up.
    units : str, default "m"
        Length unit of the file's coordinates; converted to metres.

    Returns
    -------
    PC2Cache
        ``frames`` (T, V, 3) float64 metres Y up (from float32), ``sample_rate``
        (frames between samples) and ``start_frame`` from the header. Unpacks as
        ``frames, sample_rate, start_frame = read_pc2(path)``. No NaN.

    Raises
    ------
    FormatError
        Not a PC2 file (signature), unknown version, negative counts, a size that
        does not match the header (truncated or trailing bytes), non-finite or
        non-positive header values, or non-finite points (with the byte offset).
    """
    to_y_up(np.zeros((1, 3)), up)
    scale = unit_scale(units)
    p = check_readable(path)
    return _read_pc2(p, up, scale)


def _read_pc2(p: Path, up: str, scale: float) -> PC2Cache:
    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(_HEADER.size)
        if len(head) < _HEADER.size:
            raise FormatError(
                p, f"truncated header: {len(head)} of {_HEADER.size} bytes", offset=len(head)
            )
        sig, version, n_points, start, step, n_samples = _HEADER.unpack(head)
        if sig != PC2_SIGNATURE:
            raise FormatError(p, f"not a PC2 file: signature {sig!r}", offset=0)
        if version != 1:
            raise FormatError(p, f"unsupported PC2 version {version} (expected 1)", offset=12)
        if n_points < 0:
            raise FormatError(p, f"negative point count {n_points}", offset=16)
        if not np.isfinite(start):
            raise FormatError(p, f"startFrame is {start}", offset=20)
        if not (np.isfinite(step) and step > 0):
            raise FormatError(p, f"sampleRate must be a positive frame step, got {step}", offset=24)
        if n_samples < 0:
            raise FormatError(p, f"negative sample count {n_samples}", offset=28)
        expected = _HEADER.size + 12 * n_points * n_samples
        if size != expected:
            what = "truncated" if size < expected else "trailing bytes"
            raise FormatError(
                p,
                f"{what}: the header says {n_samples} samples of {n_points} points "
                f"({expected} bytes), the file has {size} bytes",
                offset=min(size, expected),
            )
        data = np.fromfile(fh, dtype="<f4", count=3 * n_points * n_samples)
    if data.size != 3 * n_points * n_samples:
        raise FormatError(p, "file shrank while reading", offset=_HEADER.size + 4 * data.size)
    finite = np.isfinite(data)
    if not finite.all():
        k = int(np.argmin(finite))
        raise FormatError(
            p,
            f"non-finite point coordinate (sample {k // (3 * max(n_points, 1))}, "
            f"point {(k // 3) % max(n_points, 1)})",
            offset=_HEADER.size + 4 * k,
        )
    frames = to_y_up(data.reshape(n_samples, n_points, 3).astype(np.float64), up) * scale
    return PC2Cache(frames=frames, sample_rate=float(step), start_frame=float(start))
