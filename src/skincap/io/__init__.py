"""Readers and writers of every format skincap uses, and a dispatcher by file extension.

=============  =================================  ======================================
extension      read                               write
=============  =================================  ======================================
``.c3d``       :func:`skincap.io.c3d.read_c3d`    :func:`skincap.io.c3d.write_c3d`
``.trc``       :func:`skincap.io.trc.read_trc`    :func:`skincap.io.trc.write_trc`
``.csv``       :func:`skincap.io.csv.read_csv`    Vicon trajectories (markers) or long
               (Vicon, OptiTrack or long points)  point format (point clouds)
``.bvh``       :func:`skincap.io.bvh.read_bvh`    :func:`skincap.io.bvh.write_bvh`
``.obj``       :func:`skincap.io.mesh.read_obj`   :func:`skincap.io.mesh.write_obj`
``.ply``       :func:`skincap.io.mesh.read_ply`   :func:`skincap.io.mesh.write_ply`
``.gltf/.glb`` :func:`skincap.io.gltf.reader.read_gltf`  (export issue)
``.mhskel``    :func:`skincap.io.makehuman.read_mhskel`
``.mhw``       :func:`skincap.io.makehuman.read_mhw`
=============  =================================  ======================================

Files of skincap's own verbs have their own modules, outside the dispatch: the truth
files of a ``skincap synth`` folder (:mod:`skincap.io.synth_truth`), ``track``'s
``rope_curve.csv`` (:mod:`skincap.io.rope_curve`), marker edge lists
(:mod:`skincap.io.edge_csv`) and JSON reports (:mod:`skincap.io.json_file`).

The modules are imported on first use, so importing :mod:`skincap.io` stays cheap.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError, naming_file
from skincap.types import MarkerSet, Mesh, Motion, PointCloud

__all__ = [
    "read",
    "read_mesh",
    "write",
    "READ_EXTENSIONS",
    "WRITE_EXTENSIONS",
    "kind_of_extension",
]

#: extension -> (kind of data, module, reader function); the module is imported on
#: first use. The order is the one error messages list the extensions in.
_READERS: dict[str, tuple[str, str, str]] = {
    ".c3d": ("markers", "skincap.io.c3d", "read_c3d"),
    ".trc": ("markers", "skincap.io.trc", "read_trc"),
    ".csv": ("markers", "skincap.io.csv", "read_csv"),
    ".bvh": ("motion", "skincap.io.bvh", "read_bvh"),
    ".obj": ("mesh", "skincap.io.mesh", "read_obj"),
    ".ply": ("mesh", "skincap.io.mesh", "read_ply"),
    ".gltf": ("mesh", "skincap.io.gltf.reader", "read_gltf"),
    ".glb": ("mesh", "skincap.io.gltf.reader", "read_gltf"),
    ".mhskel": ("rig", "skincap.io.makehuman", "read_mhskel"),
    ".mhw": ("weights", "skincap.io.makehuman", "read_mhw"),
}
READ_EXTENSIONS = tuple(_READERS)

#: (data type, extension) -> (module, writer function), imported on first use.
_WRITERS: dict[tuple[type, str], tuple[str, str]] = {
    (MarkerSet, ".c3d"): ("skincap.io.c3d", "write_c3d"),
    (MarkerSet, ".trc"): ("skincap.io.trc", "write_trc"),
    (MarkerSet, ".csv"): ("skincap.io.csv", "write_vicon_csv"),
    (PointCloud, ".csv"): ("skincap.io.csv", "write_points_csv"),
    (Motion, ".bvh"): ("skincap.io.bvh", "write_bvh"),
    (Mesh, ".obj"): ("skincap.io.mesh", "write_obj"),
    (Mesh, ".ply"): ("skincap.io.mesh", "write_ply"),
}
WRITE_EXTENSIONS = tuple(dict.fromkeys(ext for _, ext in _WRITERS))


def kind_of_extension(path: str | os.PathLike[str]) -> str:
    """The kind of data a file's extension promises (``markers``, ``motion``, ``mesh``…)."""
    ext = Path(path).suffix.lower()
    if ext not in _READERS:
        raise FormatError(
            path,
            f"unknown file type {ext or '(no extension)'!r}; skincap reads {', '.join(READ_EXTENSIONS)}",
        )
    return _READERS[ext][0]


def read(path: str | os.PathLike[str], **options: Any) -> Any:
    """Read any supported file into its skincap type, chosen by the extension.

    Parameters
    ----------
    path : path-like
        The input file. Its content is checked too: a BVH named ``.c3d`` fails with a
        :class:`~skincap.errors.FormatError` naming the file.
    **options
        Passed to the format's reader (``units=``, ``up=``…).

    Returns
    -------
    MarkerSet, PointCloud, Motion, Mesh, or a dict for MakeHuman rig/weight files.
    """
    with naming_file(path):
        return _read_by_extension(path, **options)


def _read_by_extension(path: str | os.PathLike[str], **options: Any) -> Any:
    kind_of_extension(path)  # an unknown extension fails here, naming the known ones
    _, module, function = _READERS[Path(path).suffix.lower()]
    reader = getattr(importlib.import_module(module), function)
    data = reader(path, **options)
    if isinstance(data, (MarkerSet, PointCloud)):
        _check_capture_reach(path, data)
    return data


#: Farthest a marker or point may lie from the origin, metres (as the BVH reader's
#: bound on offsets and channels). A file's float32 or text may hold 1e38 mm: one such
#: sample made 'clean' die in an SVD that did not converge and 'render' draw a floor
#: grid of 6e9 points, where a sample within the bound is an outlier they handle.
MAX_CAPTURE_COORDINATE_M = 1e9


def _check_capture_reach(path: str | os.PathLike[str], data: MarkerSet | PointCloud) -> None:
    """FormatError naming the first sample of ``data`` (markers (T, N, 3) or points
    (M, 3), metres) beyond :data:`MAX_CAPTURE_COORDINATE_M`; NaN (missing) passes."""
    xyz = data.positions if isinstance(data, MarkerSet) else data.points
    far = np.abs(xyz) > MAX_CAPTURE_COORDINATE_M  # NaN compares False
    if not far.any():
        return
    if isinstance(data, MarkerSet):
        t, n, _ = (int(i[0]) for i in np.nonzero(far))
        where, at = f"marker {data.labels[n]!r} in frame {t}", xyz[t, n]
    else:
        k = int(np.nonzero(far)[0][0])
        t = int(np.searchsorted(data.offsets, k, side="right")) - 1
        where, at = f"a point of frame {t}", xyz[k]
    raise FormatError(
        path,
        f"{where} lies at {[float(x) for x in at]} m, beyond the ±{MAX_CAPTURE_COORDINATE_M:g} "
        "m a capture may reach (a corrupt sample or a wrong unit?)",
    )


def read_mesh(path: str | os.PathLike[str], *, units: str | None = None) -> Any:
    """Read a mesh file: a MakeHuman OBJ with its rig beside it, a glTF, or a bare OBJ/PLY.

    An ``.obj`` with a ``.mhskel`` in its folder is read with
    :func:`skincap.io.makehuman.read_makehuman` (skinned; decimetres unless ``units``
    says otherwise) when it has the vertices the rig names
    (:func:`skincap.io.makehuman.is_rigged_base_mesh`; a body-only OBJ skincap wrote
    beside the rig does not); other files by their extension's reader.

    Parameters
    ----------
    path : path-like
    units : str, optional
        Length unit of an OBJ/PLY (glTF is always metres).

    Returns
    -------
    Mesh

    Raises
    ------
    FormatError
        Not a mesh file, or a malformed one.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".obj" and any(p.parent.glob("*.mhskel")):
        from skincap.io.makehuman import is_rigged_base_mesh, read_makehuman

        with naming_file(p):
            if is_rigged_base_mesh(p):
                return read_makehuman(p, units=units or "dm")
    if ext not in (".obj", ".ply", ".gltf", ".glb"):
        raise FormatError(
            p, f"expected a mesh (.obj, .ply, .gltf, .glb), got {ext or 'no extension'!r}"
        )
    options = {"units": units} if units is not None and ext in (".obj", ".ply") else {}
    mesh = read(p, **options)
    if not isinstance(mesh, Mesh):
        raise FormatError(p, "is not a mesh")
    return mesh


def write(obj: Any, path: str | os.PathLike[str], *, force: bool = False, **options: Any) -> None:
    """Write ``obj`` to ``path`` in the format its extension names.

    The file is written to a temporary file beside ``path`` and renamed into place,
    so a failure never leaves a partial output; an existing ``path`` is replaced only
    with ``force=True``.
    """
    with naming_file(path):
        _write_by_extension(obj, path, force=force, **options)


def _write_by_extension(
    obj: Any, path: str | os.PathLike[str], *, force: bool, **options: Any
) -> None:
    ext = Path(path).suffix.lower()
    if ext not in WRITE_EXTENSIONS:
        raise FormatError(
            path,
            f"cannot write {ext or '(no extension)'!r} files; skincap writes {', '.join(WRITE_EXTENSIONS)}",
        )
    for (data_type, suffix), (module, function) in _WRITERS.items():
        if suffix == ext and isinstance(obj, data_type):
            writer = getattr(importlib.import_module(module), function)
            return writer(obj, path, force=force, **options)
    raise FormatError(path, f"cannot write a {type(obj).__name__} as {ext}")
