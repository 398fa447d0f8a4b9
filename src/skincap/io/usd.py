"""USD export of a mesh animation as time-sampled points (needs usd-core).

The stage has one ``Xform`` ``/Root`` (the default prim) holding one ``Mesh``
``/Root/<name>``: the rest topology (source polygons, so quads stay quads), the rest
positions as the default ``points`` value, and one ``points`` (and ``extent``) time
sample per frame at time codes ``0 .. T-1``. ``timeCodesPerSecond`` and
``framesPerSecond`` are the animation's rate, so time code ``t`` is ``t / rate``
seconds. The stage is Y up and ``metersPerUnit`` 1: skincap's own axes and unit, no
conversion. ``subdivisionScheme`` is ``none`` (USD's default would show the mesh as a
Catmull-Clark surface). UVs, when the rest mesh has them, are a per-vertex ``st``
primvar. Points are stored as float32, as ``UsdGeomMesh`` defines them.

usd-core is an optional extra: ``pip install 'skincap[usd]'``. It is imported on
first use; without it :func:`write_usd` raises
:class:`~skincap.errors.MissingDependencyError`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from skincap.errors import FormatError, MissingDependencyError, ValidationError
from skincap.io._common import atomic_output, finite_frame_chunks
from skincap.io.narrowing import check_float32, frame_vertex_axis
from skincap.types import MeshAnimation

__all__ = ["write_usd", "USD_SUFFIXES"]

#: File suffixes usd-core writes: crate (binary) for ``.usd``/``.usdc``, text for ``.usda``.
USD_SUFFIXES = (".usd", ".usdc", ".usda")


def _pxr() -> dict[str, ModuleType]:
    try:
        from pxr import Sdf, Usd, UsdGeom, Vt
    except ImportError:
        raise MissingDependencyError("usd-core", "usd", "USD export") from None
    return {"Sdf": Sdf, "Usd": Usd, "UsdGeom": UsdGeom, "Vt": Vt}


def _prim_name(name: Any) -> str:
    """A valid USD prim name from ``name`` (letters, digits, underscores)."""
    text = re.sub(r"[^A-Za-z0-9_]", "_", str(name or "mesh"))
    return text if text and not text[0].isdigit() else f"_{text}"


def write_usd(
    animation: MeshAnimation,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    chunk: int = 64,
    progress: Callable[[int, int], None] | None = None,
) -> None:
    """Write a mesh animation as a USD stage with time-sampled mesh points.

    Parameters
    ----------
    animation : MeshAnimation
        ``n_frames`` frames of (V, 3) float64 positions, metres, Y up (streamed from
        ``animation.iter_chunks(chunk)``), topology and UVs from ``animation.rest``.
        NaN or infinite positions are refused.
    path : str or PathLike
        Output file, ``.usd``/``.usdc`` (binary crate) or ``.usda`` (text); refused
        when it exists unless ``force``.
    force : bool
        Replace an existing file.
    chunk : int, default 64
        Frames pulled from the animation at a time.
    progress : callable, optional
        Called as ``progress(frames_done, n_frames)`` after each chunk.

    Raises
    ------
    MissingDependencyError
        usd-core (the ``pxr`` package) is not installed.
    ValidationError
        A suffix usd-core cannot write, bad ``chunk``, non-finite positions, or a
        streamed animation whose frame count differs from ``n_frames``.
    OutputExistsError
        ``path`` exists and ``force`` is False.
    FormatError
        usd-core failed to create or save the file.

    Examples
    --------
    >>> write_usd(animation, "walk.usd")  # doctest: +SKIP
    """
    if not isinstance(animation, MeshAnimation):
        raise ValidationError(
            f"animation: expected a skincap MeshAnimation, got {type(animation).__name__}"
        )
    suffix = Path(path).suffix.lower()
    if suffix not in USD_SUFFIXES:
        raise ValidationError(f"path: expected a {'/'.join(USD_SUFFIXES)} file, got {suffix!r}")
    if int(chunk) < 1:
        raise ValidationError(f"chunk: expected a positive number of frames, got {chunk!r}")
    pxr = _pxr()
    Sdf, Usd, UsdGeom, Vt = pxr["Sdf"], pxr["Usd"], pxr["UsdGeom"], pxr["Vt"]
    rest = animation.rest
    n_frames = int(animation.n_frames or 0)
    if rest.polygon_indices is not None and rest.polygon_offsets is not None:
        counts = np.diff(rest.polygon_offsets)
        indices = rest.polygon_indices
    else:
        counts = np.full(rest.n_faces, 3, dtype=np.int64)
        indices = rest.faces.reshape(-1)

    check_float32(
        rest.vertices, path, lambda idx: f"rest vertex {idx[0]}, {'xyz'[idx[1]]}", unit="m"
    )
    with atomic_output(path, force=force) as tmp:
        # the temporary name keeps the suffix, so usd-core picks the same file format
        layer = Sdf.Layer.CreateNew(str(tmp))
        if layer is None:
            raise FormatError(path, "usd-core could not create the file")
        stage = Usd.Stage.Open(layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(animation.rate)
        stage.SetFramesPerSecond(animation.rate)
        stage.SetStartTimeCode(0.0)
        stage.SetEndTimeCode(float(max(n_frames - 1, 0)))
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        mesh = UsdGeom.Mesh.Define(
            stage, f"/Root/{_prim_name(rest.meta.get('name') or animation.meta.get('name'))}"
        )
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices.astype(np.int32)))
        points = mesh.CreatePointsAttr(
            Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(rest.vertices, dtype=np.float32))
        )
        extent = mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(rest.bounds.astype(np.float32)))
        if rest.uv is not None:
            st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
                "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
            )
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(rest.uv, dtype=np.float32)))
        for done, block in finite_frame_chunks(animation, chunk):
            check_float32(block, path, frame_vertex_axis(done), unit="m")
            f32 = np.ascontiguousarray(block, dtype=np.float32)
            bounds = np.stack([f32.min(axis=1), f32.max(axis=1)], axis=1)  # (t, 2, 3)
            # usd-core takes one time sample per call: the loop only hands over arrays
            for k in range(f32.shape[0]):
                code = Usd.TimeCode(float(done + k))
                points.Set(Vt.Vec3fArray.FromNumpy(f32[k]), code)
                extent.Set(Vt.Vec3fArray.FromNumpy(bounds[k]), code)
            if progress is not None:
                progress(done + block.shape[0], n_frames)
        if not layer.Save():
            raise FormatError(path, "usd-core could not save the file")
        del stage, layer
