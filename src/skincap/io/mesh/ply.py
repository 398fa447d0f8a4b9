"""Stanford PLY meshes (ASCII and binary): reader and writer.

No length unit and no up axis in the file: see :mod:`skincap.io.mesh`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError, ValidationError
from skincap.io._common import atomic_output, check_readable, to_y_up
from skincap.io.mesh.common import (
    format_floats,
    polygons_of,
    restore_units,
    scale_and_up,
    triangulate_polygons,
)
from skincap.types import Mesh

__all__ = ["read_ply", "write_ply"]


_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


class _PlyElement:
    def __init__(self, name: str, count: int) -> None:
        self.name = name
        self.count = count
        # (name, dtype) for scalars, (name, count dtype, item dtype) for lists
        self.props: list[tuple[str, str, str | None]] = []


def _ply_header(path: Path, data: bytes) -> tuple[str, list[_PlyElement], int, list[str]]:
    if not data.startswith(b"ply"):
        raise FormatError(path, "not a PLY file (no 'ply' magic)", offset=0)
    end = data.find(b"end_header")
    if end < 0:
        raise FormatError(path, "PLY header has no 'end_header'", offset=0)
    nl = data.find(b"\n", end)
    if nl < 0:
        raise FormatError(path, "PLY header: 'end_header' line is not terminated", offset=end)
    body_start = nl + 1
    try:
        header = data[:end].decode("ascii")
    except UnicodeDecodeError as exc:
        raise FormatError(path, "PLY header is not ASCII", offset=exc.start) from None
    fmt = ""
    elements: list[_PlyElement] = []
    comments: list[str] = []
    for lineno, line in enumerate(header.splitlines(), start=1):
        parts = line.split()
        if not parts or lineno == 1:
            continue
        key = parts[0]
        if key == "format":
            if len(parts) != 3 or parts[1] not in (
                "ascii",
                "binary_little_endian",
                "binary_big_endian",
            ):
                raise FormatError(
                    path, f"PLY header: unknown format line {line.strip()!r}", line=lineno
                )
            fmt = parts[1]
        elif key == "element":
            if len(parts) != 3 or not parts[2].isdigit():
                raise FormatError(
                    path, f"PLY header: bad element line {line.strip()!r}", line=lineno
                )
            elements.append(_PlyElement(parts[1], int(parts[2])))
        elif key == "property":
            if not elements:
                raise FormatError(path, "PLY header: property before any element", line=lineno)
            if len(parts) == 5 and parts[1] == "list":
                if parts[2] not in _PLY_TYPES or parts[3] not in _PLY_TYPES:
                    raise FormatError(
                        path, f"PLY header: unknown list types in {line.strip()!r}", line=lineno
                    )
                if _PLY_TYPES[parts[2]][0] == "f":
                    raise FormatError(
                        path, "PLY header: list count type must be an integer", line=lineno
                    )
                elements[-1].props.append((parts[4], _PLY_TYPES[parts[2]], _PLY_TYPES[parts[3]]))
            elif len(parts) == 3 and parts[1] in _PLY_TYPES:
                elements[-1].props.append((parts[2], _PLY_TYPES[parts[1]], None))
            else:
                raise FormatError(
                    path, f"PLY header: bad property line {line.strip()!r}", line=lineno
                )
        elif key in ("comment", "obj_info"):
            comments.append(line.split(None, 1)[1] if len(parts) > 1 else "")
        else:
            raise FormatError(path, f"PLY header: unknown keyword {key!r}", line=lineno)
    if not fmt:
        raise FormatError(path, "PLY header has no format line", offset=0)
    return fmt, elements, body_start, comments


def _ply_binary(
    path: Path, data: bytes, pos: int, el: _PlyElement, endian: str
) -> tuple[dict[str, Any], int]:
    """Parse one binary element at byte ``pos``; return {prop: array or list} and the end."""
    if el.count == 0:
        return {name: np.zeros(0) for name, _, _ in el.props}, pos
    has_list = any(item is not None for _, _, item in el.props)
    if not has_list:
        dt = np.dtype([(f"p{i}", endian + t) for i, (_, t, _) in enumerate(el.props)])
        need = dt.itemsize * el.count
        if pos + need > len(data):
            raise FormatError(
                path, f"element '{el.name}': truncated, needs {need} bytes", offset=pos
            )
        rec = np.frombuffer(data, dtype=dt, count=el.count, offset=pos)
        return {
            name: rec[f"p{i}"].astype(np.float64) for i, (name, _, _) in enumerate(el.props)
        }, pos + need
    # Lists: fast path when every row has the same list lengths as the first row.
    first_counts: list[int] = []
    q = pos
    fields: list[tuple[str, Any]] = []
    for i, (_name, t, item) in enumerate(el.props):
        if item is None:
            fields.append((f"p{i}", endian + t))
            q += np.dtype(t).itemsize
        else:
            if q + np.dtype(t).itemsize > len(data):
                raise FormatError(path, f"element '{el.name}': truncated list", offset=q)
            n = int(np.frombuffer(data, dtype=endian + t, count=1, offset=q)[0])
            if n < 0:
                raise FormatError(path, f"element '{el.name}': negative list length", offset=q)
            if q + np.dtype(t).itemsize + n * np.dtype(item).itemsize > len(data):
                # before a dtype of n items is built: a lying 4e9 would not fit a C int
                raise FormatError(
                    path, f"element '{el.name}': bad or truncated list of {n}", offset=q
                )
            first_counts.append(n)
            fields.append((f"c{i}", endian + t))
            fields.append((f"p{i}", (endian + item, (n,))))
            q += np.dtype(t).itemsize + n * np.dtype(item).itemsize
    dt = np.dtype(fields)
    need = dt.itemsize * el.count
    if pos + need <= len(data):
        rec = np.frombuffer(data, dtype=dt, count=el.count, offset=pos)
        uniform = all(
            (rec[f"c{i}"] == first_counts[k]).all()
            for k, i in enumerate(i for i, p in enumerate(el.props) if p[2] is not None)
        )
        if uniform:
            out: dict[str, Any] = {}
            for i, (name, _, item) in enumerate(el.props):
                col = rec[f"p{i}"]
                if item is None:
                    out[name] = col.astype(np.float64)
                else:
                    arr = col.reshape(el.count, -1)
                    out[name] = (
                        arr.astype(np.float64) if item[0] == "f" else arr.astype(np.int64),
                        None,
                    )
            return out, pos + need
    # Slow path: rows of different lengths, one row at a time.
    values: dict[str, list[Any]] = {name: [] for name, _, _ in el.props}
    q = pos
    for _ in range(el.count):
        for name, t, item in el.props:
            size = np.dtype(t).itemsize
            if q + size > len(data):
                raise FormatError(path, f"element '{el.name}': truncated", offset=q)
            n = np.frombuffer(data, dtype=endian + t, count=1, offset=q)[0]
            q += size
            if item is None:
                values[name].append(float(n))
                continue
            n = int(n)
            isz = np.dtype(item).itemsize
            if n < 0 or q + n * isz > len(data):
                raise FormatError(
                    path, f"element '{el.name}': bad or truncated list of {n}", offset=q - size
                )
            values[name].append(np.frombuffer(data, dtype=endian + item, count=n, offset=q))
            q += n * isz
    out = {}
    for name, _, item in el.props:
        if item is None:
            out[name] = np.asarray(values[name], dtype=np.float64)
        else:
            lens = np.array([len(a) for a in values[name]], dtype=np.int64)
            flat = np.concatenate(values[name]) if values[name] else np.zeros(0)
            out[name] = (flat.astype(np.float64) if item[0] == "f" else flat.astype(np.int64), lens)
    return out, q


def _ply_ascii(
    path: Path, tokens: list[str], pos: int, el: _PlyElement
) -> tuple[dict[str, Any], int]:
    """Parse one ASCII element starting at token ``pos``."""
    has_list = any(item is not None for _, _, item in el.props)
    n_props = len(el.props)

    def num(tok_slice: list[str], what: str) -> np.ndarray:
        try:
            return np.array(tok_slice, dtype=np.float64)
        except ValueError:
            raise FormatError(path, f"element '{el.name}': non-numeric {what}") from None

    if el.count == 0:
        return {name: np.zeros(0) for name, _, _ in el.props}, pos
    if not has_list:
        need = n_props * el.count
        if pos + need > len(tokens):
            raise FormatError(
                path,
                f"element '{el.name}': truncated, expected {el.count} rows of {n_props} values",
            )
        arr = num(tokens[pos : pos + need], "value").reshape(el.count, n_props)
        return {name: arr[:, i] for i, (name, _, _) in enumerate(el.props)}, pos + need
    # rows with lists: walk row by row over the token list (counts are in the data)
    values: dict[str, list[Any]] = {name: [] for name, _, _ in el.props}
    q = pos
    for _ in range(el.count):
        for name, _, item in el.props:
            if q >= len(tokens):
                raise FormatError(path, f"element '{el.name}': truncated")
            if item is None:
                values[name].append(tokens[q])
                q += 1
                continue
            try:
                n = int(tokens[q])
            except ValueError:
                raise FormatError(
                    path, f"element '{el.name}': list length {tokens[q]!r} is not an integer"
                ) from None
            if n < 0 or q + 1 + n > len(tokens):
                raise FormatError(path, f"element '{el.name}': bad or truncated list of {n}")
            values[name].append(tokens[q + 1 : q + 1 + n])
            q += 1 + n
    out: dict[str, Any] = {}
    for name, _, item in el.props:
        if item is None:
            out[name] = num(values[name], name)
        else:
            lens = np.array([len(a) for a in values[name]], dtype=np.int64)
            flat = num([t for a in values[name] for t in a], name)
            if item[0] != "f":
                if not np.all(flat == np.round(flat)):
                    raise FormatError(path, f"element '{el.name}': non-integer index in '{name}'")
                flat = flat.astype(np.int64)
            out[name] = (flat, lens)
    return out, q


def read_ply(path: str | os.PathLike[str], *, units: str = "m", up: str = "y") -> Mesh:
    """Read a Stanford PLY mesh (ASCII, binary little or big endian).

    Parameters
    ----------
    path : str or PathLike
    units : {"m", "dm", "cm", "mm", "in"}, default "m"
        Length unit of the file (PLY has none); recorded as ``meta["source_units"]``.
    up : {"y", "z"}, default "y"
        The file's up axis; recorded as ``meta["up"]``.

    Returns
    -------
    Mesh
        ``vertices`` (V, 3) float64 metres from the ``vertex`` element's x, y, z;
        the ``face`` element's ``vertex_indices`` (or ``vertex_index``) lists as
        source polygons (CSR) and fan-triangulated ``faces`` (F, 3) int64 with
        ``face_polygon``; ``uv`` (V, 2) from s/t, u/v or texture_u/texture_v when
        present. Other elements and properties are skipped; the header comments are
        ``meta["comments"]``.

    Raises
    ------
    FormatError
        Missing magic or header, unknown types, truncated body, non-numeric values,
        non-finite coordinates, polygons with fewer than 3 corners or indices out of
        range (byte offset for binary bodies where known).
    """
    p_path = check_readable(path)
    scale, up_key = scale_and_up(units, up)
    data = p_path.read_bytes()
    fmt, elements, body_start, comments = _ply_header(p_path, data)
    parsed: dict[str, dict[str, Any]] = {}
    try:
        if fmt == "ascii":
            try:
                tokens = data[body_start:].decode("ascii").split()
            except UnicodeDecodeError as exc:
                raise FormatError(
                    p_path, "PLY ascii body is not ASCII", offset=body_start + exc.start
                ) from None
            pos = 0
            for el in elements:
                parsed[el.name], pos = _ply_ascii(p_path, tokens, pos, el)
        else:
            endian = "<" if fmt == "binary_little_endian" else ">"
            pos = body_start
            for el in elements:
                parsed[el.name], pos = _ply_binary(p_path, data, pos, el, endian)
    except (ValueError, TypeError, OverflowError, MemoryError) as exc:
        raise FormatError(p_path, f"malformed PLY body: {exc}") from None

    vert = parsed.get("vertex")
    if vert is None or not all(k in vert for k in ("x", "y", "z")):
        raise FormatError(p_path, "PLY has no vertex element with x, y, z properties")
    if any(isinstance(vert[k], tuple) for k in ("x", "y", "z")):
        raise FormatError(p_path, "PLY vertex x, y, z must be scalar properties")
    verts = np.stack([vert["x"], vert["y"], vert["z"]], axis=1).astype(np.float64)
    if not np.isfinite(verts).all():
        k = int(np.nonzero(~np.isfinite(verts).all(axis=1))[0][0])
        raise FormatError(p_path, f"vertex {k} has a non-finite coordinate")
    n_v = verts.shape[0]
    uv = None
    for u_name, v_name in (("s", "t"), ("u", "v"), ("texture_u", "texture_v")):
        if u_name in vert and v_name in vert and not isinstance(vert[u_name], tuple):
            uv = np.stack([vert[u_name], vert[v_name]], axis=1)
            if not np.isfinite(uv).all():
                raise FormatError(p_path, "texture coordinates contain non-finite values")
            break

    poly_idx = np.zeros(0, dtype=np.int64)
    poly_off = np.zeros(1, dtype=np.int64)
    face_el = parsed.get("face")
    if face_el is not None:
        key = next((k for k in ("vertex_indices", "vertex_index") if k in face_el), None)
        if key is None or not isinstance(face_el[key], tuple):
            if any(el.name == "face" and el.count for el in elements):
                raise FormatError(p_path, "PLY face element has no vertex_indices list")
        else:
            flat, lens = face_el[key]
            n_f = next(el.count for el in elements if el.name == "face")
            if lens is None:
                lens = np.full(n_f, flat.shape[1] if flat.ndim == 2 else 0, dtype=np.int64)
            flat = np.asarray(flat).reshape(-1)
            if (lens < 3).any():
                k = int(np.nonzero(lens < 3)[0][0])
                raise FormatError(p_path, f"face {k} has {int(lens[k])} corners, at least 3 needed")
            if flat.size and (flat.min() < 0 or flat.max() >= n_v):
                raise FormatError(
                    p_path,
                    f"face vertex index out of range 0..{n_v - 1}: {int(flat.min())}..{int(flat.max())}",
                )
            poly_idx = flat.astype(np.int64)
            poly_off = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    faces, face_polygon = triangulate_polygons(poly_idx, poly_off)
    meta: dict[str, Any] = {
        "source_units": units,
        "up": up_key,
        "source_format": "ply",
        "ply_format": fmt,
    }
    if comments:
        meta["comments"] = comments
    return Mesh(
        vertices=to_y_up(verts * scale, up_key),
        faces=faces,
        polygon_indices=poly_idx if poly_idx.size else None,
        polygon_offsets=poly_off if poly_idx.size else None,
        face_polygon=face_polygon if poly_idx.size else None,
        uv=uv,
        meta=meta,
    )


def write_ply(
    mesh: Mesh,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    binary: bool = True,
    units: str | None = None,
    up: str | None = None,
) -> None:
    """Write a mesh as Stanford PLY.

    Vertices are written as ``double`` x, y, z (plus s, t when ``mesh.uv`` is set),
    faces as ``list uchar int vertex_indices``: the source polygons when present,
    else the triangles.

    Parameters
    ----------
    mesh : Mesh
    path : str or PathLike
        Output file; refused when it exists unless ``force``.
    force : bool
        Replace an existing file.
    binary : bool, default True
        ``binary_little_endian`` when True, else ``ascii``.
    units, up : str, optional
        Unit and up axis of the file; default ``meta["source_units"]`` / ``meta["up"]``.
    """
    verts, units_name, up_key = restore_units(mesh, units, up)
    poly_idx, poly_off = polygons_of(mesh)
    sizes = np.diff(poly_off)
    if sizes.size and sizes.max() > 255:
        raise ValidationError(
            f"mesh: a polygon has {int(sizes.max())} corners, PLY 'uchar' counts allow 255"
        )
    fmt = "binary_little_endian" if binary else "ascii"
    header = [
        "ply",
        f"format {fmt} 1.0",
        "comment written by skincap",
        f"comment units {units_name}",
        f"comment up {up_key}",
        f"element vertex {verts.shape[0]}",
        "property double x",
        "property double y",
        "property double z",
    ]
    cols = [verts]
    if mesh.uv is not None:
        header += ["property double s", "property double t"]
        cols.append(mesh.uv)
    header += [f"element face {sizes.size}", "property list uchar int vertex_indices", "end_header"]
    vdata = np.concatenate(cols, axis=1)
    head = ("\n".join(header) + "\n").encode("ascii")
    with atomic_output(path, force=force) as tmp, open(tmp, "wb") as fh:
        fh.write(head)
        if binary:
            fh.write(vdata.astype("<f8").tobytes())
            if sizes.size and (sizes == sizes[0]).all():
                n = int(sizes[0])
                rec = np.zeros(sizes.size, dtype=np.dtype([("n", "u1"), ("i", "<i4", (n,))]))
                rec["n"] = n
                rec["i"] = poly_idx.reshape(-1, n)
                fh.write(rec.tobytes())
            else:
                # mixed polygon sizes: interleave counts and indices in one byte buffer
                counts = sizes.astype("u1")
                idx_bytes = poly_idx.astype("<i4").tobytes()
                parts = []
                offs = (poly_off * 4).tolist()
                for g in range(sizes.size):
                    parts.append(counts[g : g + 1].tobytes())
                    parts.append(idx_bytes[offs[g] : offs[g + 1]])
                fh.write(b"".join(parts))
        else:
            flat = format_floats(vdata.reshape(-1), True)
            w = vdata.shape[1]
            lines = [" ".join(flat[w * i : w * i + w]) for i in range(vdata.shape[0])]
            idx_txt = poly_idx.astype(str).tolist()
            offs = poly_off.tolist()
            lines += [
                f"{offs[g + 1] - offs[g]} " + " ".join(idx_txt[offs[g] : offs[g + 1]])
                for g in range(sizes.size)
            ]
            fh.write(("\n".join(lines) + "\n").encode("ascii"))
