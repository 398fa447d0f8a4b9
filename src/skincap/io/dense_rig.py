"""Dense rig files: ``RIG.npz`` (the arrays) + ``RIG.json`` (labels, settings, version).

No pickle anywhere: the NPZ holds plain numeric arrays (read with
``allow_pickle=False``), the labels and settings live in the JSON sidecar beside it.
The arrays are those of :class:`skincap.deform.dense.rig.DenseRig` (this module,
below the algorithms, only knows their names and shapes)::

    vertices (V, 3) float64 m    faces (F, 3) int64         reference (N, 3) float64 m
    surface_faces (S, 3) int64   marker_parts (N,) int64    marker_weights (N, P) float64
    vertex_weights (V, P) float64

Sidecar: ``{"format": "skincap-dense-rig", "version": 1, "labels": [...N],
"n_parts": P, "settings": {...}}``.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError
from skincap.io._common import atomic_output, check_readable
from skincap.io.json_file import read_json

__all__ = ["RIG_FORMAT", "RIG_VERSION", "dense_rig_files", "read_dense_rig", "write_dense_rig"]

RIG_FORMAT = "skincap-dense-rig"
RIG_VERSION = 1
#: name -> (dtype kind, trailing shape: "N", "V", "P" or a number)
_ARRAYS: dict[str, tuple[str, tuple[str | int, ...]]] = {
    "vertices": ("f", ("V", 3)),
    "faces": ("i", ("F", 3)),
    "reference": ("f", ("N", 3)),
    "surface_faces": ("i", ("S", 3)),
    "marker_parts": ("i", ("N",)),
    "marker_weights": ("f", ("N", "P")),
    "vertex_weights": ("f", ("V", "P")),
}


def dense_rig_files(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """The two files of a rig: ``RIG.npz`` and its ``RIG.json`` sidecar."""
    p = Path(path)
    return p, p.with_suffix(".json")


def write_dense_rig(
    path: str | os.PathLike[str],
    arrays: Mapping[str, np.ndarray],
    labels: list[str],
    settings: Mapping[str, Any],
    *,
    force: bool = False,
) -> list[Path]:
    """Write a rig's arrays to ``path`` (``.npz``) and the sidecar beside it, atomically.

    Parameters
    ----------
    path : path-like, ending ``.npz``
    arrays : mapping of the names above to arrays
    labels : list of N str
    settings : JSON-serialisable mapping
    force : bool
        Replace existing files.

    Returns
    -------
    [npz, json] paths

    Raises
    ------
    FormatError
        Not ``.npz``, a missing array, shapes that disagree.
    OutputExistsError
        An output exists and ``force`` is False.
    """
    npz, sidecar = dense_rig_files(path)
    if npz.suffix.lower() != ".npz":
        raise FormatError(npz, f"a rig is saved as .npz, not {npz.suffix or 'no extension'!r}")
    clean = {name: np.ascontiguousarray(arrays[name]) for name in _ARRAYS if name in arrays}
    _check_arrays(npz, clean, len(labels))
    meta = {
        "format": RIG_FORMAT,
        "version": RIG_VERSION,
        "labels": [str(s) for s in labels],
        "n_parts": int(clean["marker_weights"].shape[1]),
        "settings": dict(settings),
    }
    text = json.dumps(meta, indent=1, allow_nan=False)
    with atomic_output(npz, force=force) as tmp_npz, atomic_output(sidecar, force=force) as tmp:
        with open(tmp_npz, "wb") as fh:
            np.savez_compressed(fh, **clean)  # type: ignore[arg-type]
        tmp.write_text(text + "\n", encoding="utf-8")
    return [npz, sidecar]


def read_dense_rig(
    path: str | os.PathLike[str],
) -> tuple[dict[str, np.ndarray], list[str], dict[str, Any]]:
    """Read ``RIG.npz`` and its sidecar.

    Returns
    -------
    arrays : dict of the names above
    labels : list of N str
    settings : dict

    Raises
    ------
    FormatError
        Either file missing or unreadable, another format or version, arrays missing,
        of the wrong kind (an object array is refused: no pickle) or shapes that
        disagree with each other or with the labels.
    """
    npz, sidecar = dense_rig_files(path)
    check_readable(npz)
    if not sidecar.exists():
        raise FormatError(npz, f"the rig's sidecar {sidecar.name} is missing beside it")
    check_readable(sidecar)
    meta = read_json(sidecar, what="rig sidecar JSON")
    if not isinstance(meta, dict) or meta.get("format") != RIG_FORMAT:
        raise FormatError(sidecar, f"not a skincap dense rig sidecar (format {RIG_FORMAT!r})")
    if meta.get("version") != RIG_VERSION:
        raise FormatError(
            sidecar, f"rig format version {meta.get('version')!r}; this skincap reads {RIG_VERSION}"
        )
    labels = meta.get("labels")
    if not isinstance(labels, list) or not all(isinstance(s, str) for s in labels):
        raise FormatError(sidecar, "labels: expected a list of strings")
    settings = meta.get("settings", {})
    if not isinstance(settings, dict):
        raise FormatError(sidecar, "settings: expected an object")
    try:
        _check_npz_sizes(npz)
        with np.load(npz, allow_pickle=False) as data:
            arrays = {name: np.asarray(data[name]) for name in data.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise FormatError(npz, f"not a readable NPZ rig ({exc})") from None
    _check_arrays(npz, arrays, len(labels))
    return arrays, labels, settings


#: Most bytes deflate can expand one byte into (zlib's limit is about 1032).
_DEFLATE_MAX_RATIO = 1100


def _check_npz_sizes(npz: Path) -> None:
    """FormatError when an array's ``.npy`` header declares more bytes than its member
    holds: ``np.load`` allocates the declared shape before it reads (a header claiming
    (2**40, 3) asked for 24 TiB). The members' sizes are bounded by the file's own size."""
    file_size = npz.stat().st_size
    with zipfile.ZipFile(npz) as z:
        for info in z.infolist():
            if not info.filename.endswith(".npy"):
                continue
            most = info.compress_size * (
                1 if info.compress_type == zipfile.ZIP_STORED else _DEFLATE_MAX_RATIO
            )
            if info.compress_size > file_size or info.file_size > most:
                raise FormatError(
                    npz,
                    f"{info.filename}: the archive claims {info.file_size} bytes from "
                    f"{info.compress_size} stored, in a file of {file_size}",
                )
            with z.open(info) as f:
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                else:
                    shape, _, dtype = np.lib.format.read_array_header_2_0(f)
                header = f.tell()
            count = math.prod(shape)
            if count * dtype.itemsize > info.file_size - header:
                name = info.filename.removesuffix(".npy")
                raise FormatError(
                    npz,
                    f"{name}: the header declares shape {shape} ({count * dtype.itemsize} "
                    f"bytes) but the array holds {info.file_size - header}",
                )


def _check_arrays(path: Path, arrays: Mapping[str, np.ndarray], n_labels: int) -> None:
    missing = [name for name in _ARRAYS if name not in arrays]
    if missing:
        raise FormatError(path, f"rig arrays missing: {', '.join(missing)}")
    sizes: dict[str, int] = {"N": n_labels}
    for name, (kind, shape) in _ARRAYS.items():
        arr = arrays[name]
        if arr.dtype.kind not in (kind, "u" if kind == "i" else kind) or arr.ndim != len(shape):
            raise FormatError(
                path, f"{name}: expected a {len(shape)}-d {'float' if kind == 'f' else 'int'} array"
            )
        for axis, want in enumerate(shape):
            got = int(arr.shape[axis])
            if isinstance(want, int):
                ok = got == want
            else:
                ok = sizes.setdefault(want, got) == got
            if not ok:
                raise FormatError(
                    path, f"{name}: shape {arr.shape} disagrees with the rest of the rig"
                )
    if arrays["faces"].shape[0] == 0:
        raise FormatError(path, "faces: the rig's mesh has no triangles")
    if sizes["P"] == 0:
        raise FormatError(path, "marker_weights: the rig has no parts")
    parts = arrays["marker_parts"]
    if parts.size and (parts.min() < -1 or parts.max() >= sizes["P"]):
        raise FormatError(path, f"marker_parts: expected -1 (none) or a part 0..{sizes['P'] - 1}")
