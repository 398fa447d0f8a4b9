"""Wavefront OBJ and Stanford PLY mesh readers and writers.

Both formats carry no length unit and no up axis, so the readers take them as
arguments (metres and Y up by default), convert to skincap's metres / Y-up and record
the choice in ``meta["source_units"]`` and ``meta["up"]``; the writers restore them.

OBJ
---
The reader is a small bulk parser: one pass over the lines sorts them by keyword,
the numbers are converted in one numpy call per kind. It reads ``v``, ``vt``,
``vn`` and ``f`` (corners ``v``, ``v/vt``, ``v//vn`` and ``v/vt/vn``, negative
indices counted back from the last element read so far, polygons of any size) and
``g``, ``o``, ``usemtl`` and ``mtllib`` statements. Other statements (``s``, ``l``,
``p``, free-form geometry...) are ignored.

Texture coordinates: when every corner of a vertex uses the same UV the mesh gets a
per-vertex ``Mesh.uv``. When a vertex has several UVs (a texture seam, as in the
MakeHuman base mesh) ``Mesh.uv`` is None and the UVs stay per corner: the OBJ's
``vt`` table is ``meta["uv_table"]`` ``(T, 2)`` and ``meta["corner_uv"]`` ``(P,)``
int64 indexes it for each entry of ``Mesh.polygon_indices`` (-1 where a corner has
no UV). Normals are kept the same way (``meta["normal_table"]``, ``meta["corner_normal"]``).
The writer uses the per-corner tables when they match the polygon layout, else the
per-vertex ``Mesh.uv``. Vertices are never split, so vertex indices stay those of
the file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError, ValidationError
from skincap.io._common import atomic_output, check_readable, from_y_up, to_y_up, unit_scale
from skincap.types import Mesh

__all__ = ["read_obj", "write_obj", "read_ply", "write_ply", "triangulate_polygons"]


# ----------------------------------------------------------------------------- shared
def triangulate_polygons(
    polygon_indices: np.ndarray, polygon_offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fan-triangulate polygons given in CSR layout.

    Parameters
    ----------
    polygon_indices : (P,) int64
        Vertex indices of all polygons, one polygon after the other.
    polygon_offsets : (G + 1,) int64
        Polygon ``g`` is ``polygon_indices[polygon_offsets[g]:polygon_offsets[g + 1]]``;
        every polygon has at least 3 corners.

    Returns
    -------
    faces : (F, 3) int64
        Triangles ``(c0, ck, ck+1)`` for ``k = 1 .. n-2`` of each polygon, in order.
    face_polygon : (F,) int64
        Index of the polygon each triangle comes from.
    """
    idx = np.asarray(polygon_indices, dtype=np.int64)
    off = np.asarray(polygon_offsets, dtype=np.int64)
    sizes = np.diff(off)
    n_tri = sizes - 2
    face_polygon = np.repeat(np.arange(sizes.size, dtype=np.int64), n_tri)
    first = np.repeat(off[:-1], n_tri)
    # k runs 1 .. n-2 inside each polygon
    tri_start = np.concatenate([[0], np.cumsum(n_tri)])[:-1]
    k = np.arange(face_polygon.size, dtype=np.int64) - np.repeat(tri_start, n_tri) + 1
    faces = np.stack([idx[first], idx[first + k], idx[first + k + 1]], axis=1)
    return faces.reshape(-1, 3), face_polygon


def _scale_and_up(units: str, up: str) -> tuple[float, str]:
    scale = unit_scale(units)
    up_key = up.strip().lower().lstrip("+")
    if up_key not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up!r}")
    return scale, up_key


def _restore_units(mesh: Mesh, units: str | None, up: str | None) -> tuple[np.ndarray, str, str]:
    """Vertices in the file's unit and axes, with the unit and up names used."""
    units = units if units is not None else str(mesh.meta.get("source_units", "m"))
    up = up if up is not None else str(mesh.meta.get("up", "y"))
    scale, up = _scale_and_up(units, up)
    return from_y_up(mesh.vertices, up) / scale, units, up


def _polygons_of(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    if mesh.polygon_indices is not None and mesh.polygon_offsets is not None:
        return mesh.polygon_indices, mesh.polygon_offsets
    return mesh.faces.reshape(-1), np.arange(0, 3 * mesh.n_faces + 1, 3, dtype=np.int64)


def _format_floats(values: np.ndarray, exact: bool) -> list[str]:
    """Shortest round-trip text of each float (``exact``) or 15 significant digits."""
    if exact:
        return [repr(x) for x in values.tolist()]
    return [f"{x:.15g}" for x in values.tolist()]


# -------------------------------------------------------------------------------- OBJ
_MISSING = -(2**62)  # marks an absent vt / vn field of a face corner


class _ObjParse:
    """Line-sorted content of an OBJ file (private scratch space of :func:`read_obj`)."""

    def __init__(self) -> None:
        self.v: list[str] = []
        self.v_lines: list[int] = []
        self.v_counts: list[int] = []
        self.vt: list[str] = []
        self.vt_lines: list[int] = []
        self.vt_counts: list[int] = []
        self.vn: list[str] = []
        self.vn_lines: list[int] = []
        self.vn_counts: list[int] = []
        self.corners: list[str] = []
        self.f_lines: list[int] = []
        self.f_sizes: list[int] = []
        # element counts defined before each face, for negative indices
        self.f_nv: list[int] = []
        self.f_nvt: list[int] = []
        self.f_nvn: list[int] = []
        self.groups: dict[str, list[int]] = {}
        self.objects: dict[str, list[int]] = {}
        self.materials: dict[str, list[int]] = {}
        self.mtllib: list[str] = []


def _decode_text(path: Path, data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not UTF-8 text ({exc.reason})", offset=exc.start) from None


def _bulk_floats(
    path: Path, tokens: list[str], counts: list[int], lines: list[int], width: int, what: str
) -> np.ndarray:
    """(n, width) float64 from per-line token lists, FormatError with the bad line."""
    n = len(counts)
    if n == 0:
        return np.zeros((0, width))
    cnt = np.asarray(counts)
    if (cnt != width).any():
        k = int(np.nonzero(cnt != width)[0][0])
        raise FormatError(path, f"{what}: expected {width} numbers, got {counts[k]}", line=lines[k])
    try:
        arr = np.array(tokens, dtype=np.float64).reshape(n, width)
    except ValueError:
        for k in range(n):
            for t in tokens[k * width : (k + 1) * width]:
                try:
                    float(t)
                except ValueError:
                    raise FormatError(
                        path, f"{what}: {t!r} is not a number", line=lines[k]
                    ) from None
        raise FormatError(path, f"{what}: malformed numbers") from None
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        k = int(np.nonzero(bad)[0][0])
        raise FormatError(path, f"{what}: non-finite value", line=lines[k])
    return arr


def _parse_obj_lines(path: Path, text: str) -> _ObjParse:
    p = _ObjParse()
    current_groups: list[str] = []
    current_object: str | None = None
    current_material: str | None = None
    n_poly = 0
    for lineno, raw in enumerate(text.splitlines(), start=1):
        parts = raw.split()
        if not parts:
            continue
        key = parts[0]
        if key == "v":
            # x y z [w] or x y z r g b: position is the first three numbers
            if len(parts) not in (4, 5, 7, 8):
                raise FormatError(
                    path,
                    f"vertex: expected 3 coordinates, got {len(parts) - 1} numbers",
                    line=lineno,
                )
            p.v.extend(parts[1:4])
            p.v_counts.append(3)
            p.v_lines.append(lineno)
        elif key == "vt":
            # u [v [w]]
            if len(parts) < 2 or len(parts) > 4:
                raise FormatError(
                    path,
                    f"texture coordinate: expected 1 to 3 numbers, got {len(parts) - 1}",
                    line=lineno,
                )
            uv = parts[1:3] if len(parts) >= 3 else [parts[1], "0"]
            p.vt.extend(uv)
            p.vt_counts.append(2)
            p.vt_lines.append(lineno)
        elif key == "vn":
            p.vn.extend(parts[1:])
            p.vn_counts.append(len(parts) - 1)
            p.vn_lines.append(lineno)
        elif key == "f":
            if len(parts) < 4:
                raise FormatError(
                    path,
                    f"face: a polygon needs at least 3 corners, got {len(parts) - 1}",
                    line=lineno,
                )
            p.corners.extend(parts[1:])
            p.f_sizes.append(len(parts) - 1)
            p.f_lines.append(lineno)
            p.f_nv.append(len(p.v_lines))
            p.f_nvt.append(len(p.vt_lines))
            p.f_nvn.append(len(p.vn_lines))
            for g in current_groups:
                p.groups[g].append(n_poly)
            if current_object is not None:
                p.objects[current_object].append(n_poly)
            if current_material is not None:
                p.materials[current_material].append(n_poly)
            n_poly += 1
        elif key == "g":
            current_groups = parts[1:]
            for g in current_groups:
                p.groups.setdefault(g, [])
        elif key == "o":
            current_object = " ".join(parts[1:]) if len(parts) > 1 else None
            if current_object is not None:
                p.objects.setdefault(current_object, [])
        elif key == "usemtl":
            current_material = " ".join(parts[1:]) if len(parts) > 1 else None
            if current_material is not None:
                p.materials.setdefault(current_material, [])
        elif key == "mtllib":
            p.mtllib.extend(parts[1:])
        # everything else (comments, s, l, p, curves...) is ignored
    return p


def _corner_fields(path: Path, p: _ObjParse) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P,) raw v, vt, vn indices of every corner (``_MISSING`` where absent)."""
    n = len(p.corners)
    f_lines = np.repeat(np.asarray(p.f_lines, dtype=np.int64), p.f_sizes)
    fields: list[list[str]] = [[], [], []]
    missing = str(_MISSING)
    for c in p.corners:
        s = c.split("/")
        if len(s) == 1:
            fields[0].append(s[0])
            fields[1].append(missing)
            fields[2].append(missing)
        elif len(s) == 2:
            fields[0].append(s[0])
            fields[1].append(s[1] or missing)
            fields[2].append(missing)
        elif len(s) == 3:
            fields[0].append(s[0])
            fields[1].append(s[1] or missing)
            fields[2].append(s[2] or missing)
        else:
            fields[0].append("x")
            fields[1].append(missing)
            fields[2].append(missing)
    out = []
    for name, f in zip(("vertex", "texture", "normal"), fields, strict=True):
        try:
            arr = np.array(f, dtype=np.int64) if n else np.zeros(0, dtype=np.int64)
        except (ValueError, OverflowError):
            for k, t in enumerate(f):
                try:
                    int(t)
                except ValueError:
                    raise FormatError(
                        path,
                        f"face: bad {name} index in corner {p.corners[k]!r}",
                        line=int(f_lines[k]),
                    ) from None
            raise FormatError(path, f"face: bad {name} index") from None
        out.append(arr)
    return out[0], out[1], out[2]


def _resolve(
    path: Path,
    raw: np.ndarray,
    defined: np.ndarray,
    lines: np.ndarray,
    total: int,
    what: str,
    allow_missing: bool,
) -> np.ndarray:
    """OBJ 1-based / negative indices -> 0-based (-1 where missing), range-checked."""
    missing = raw == _MISSING
    idx = np.where(raw > 0, raw - 1, defined + raw)
    bad = (raw == 0) | (idx < 0) | (idx >= total)
    if allow_missing:
        bad &= ~missing
    elif missing.any():
        bad |= missing
    if bad.any():
        k = int(np.nonzero(bad)[0][0])
        val = "missing" if missing[k] else str(int(raw[k]))
        raise FormatError(
            path,
            f"face: {what} index {val} out of range (file has {total} {what}s)",
            line=int(lines[k]),
        )
    return np.where(missing, -1, idx).astype(np.int64)


def read_obj(path: str | os.PathLike[str], *, units: str = "m", up: str = "y") -> Mesh:
    """Read a Wavefront OBJ mesh.

    Parameters
    ----------
    path : str or PathLike
        The ``.obj`` file (UTF-8 text).
    units : {"m", "dm", "cm", "mm", "in"}, default "m"
        Length unit of the file's coordinates (OBJ has none); converted to metres
        and recorded as ``meta["source_units"]``.
    up : {"y", "z"}, default "y"
        The file's up axis; converted to Y up and recorded as ``meta["up"]``.

    Returns
    -------
    Mesh
        ``vertices`` (V, 3) float64 metres; ``faces`` (F, 3) int64, the polygons
        fan-triangulated, with ``face_polygon`` (F,) naming the source polygon;
        ``polygon_indices`` / ``polygon_offsets`` the source polygons (CSR);
        ``groups`` maps each ``g`` name to the (k,) int64 indices of its polygons;
        ``uv`` (V, 2) float64 when every vertex has one UV, else None (see the module
        notes for ``meta["uv_table"]`` / ``meta["corner_uv"]``). ``meta`` also holds
        ``objects`` and ``materials`` (name -> polygon indices, from ``o`` and
        ``usemtl``), ``mtllib`` (list of str) and ``normal_table`` (N, 3) /
        ``corner_normal`` (P,) when the file has normals. No NaN: a non-finite
        number is a format error.

    Raises
    ------
    FormatError
        Empty or non-UTF-8 file, non-numeric or non-finite coordinates, a face with
        fewer than three corners or an index to a missing element (with its line).
    """
    p_path = check_readable(path)
    scale, up_key = _scale_and_up(units, up)
    text = _decode_text(p_path, p_path.read_bytes())
    p = _parse_obj_lines(p_path, text)
    if not p.v_lines:
        raise FormatError(
            p_path, "no vertices ('v' lines) in the file", line=max(1, text.count("\n"))
        )
    verts = _bulk_floats(p_path, p.v, p.v_counts, p.v_lines, 3, "vertex")
    uv_table = _bulk_floats(p_path, p.vt, p.vt_counts, p.vt_lines, 2, "texture coordinate")
    normals = _bulk_floats(p_path, p.vn, p.vn_counts, p.vn_lines, 3, "normal")

    f_lines = np.repeat(np.asarray(p.f_lines, dtype=np.int64), p.f_sizes)
    raw_v, raw_t, raw_n = _corner_fields(p_path, p)
    sizes = np.asarray(p.f_sizes, dtype=np.int64)
    corner_idx = _resolve(
        p_path,
        raw_v,
        np.repeat(np.asarray(p.f_nv, dtype=np.int64), sizes),
        f_lines,
        len(p.v_lines),
        "vertex",
        False,
    )
    corner_uv = _resolve(
        p_path,
        raw_t,
        np.repeat(np.asarray(p.f_nvt, dtype=np.int64), sizes),
        f_lines,
        len(p.vt_lines),
        "texture coordinate",
        True,
    )
    corner_nrm = _resolve(
        p_path,
        raw_n,
        np.repeat(np.asarray(p.f_nvn, dtype=np.int64), sizes),
        f_lines,
        len(p.vn_lines),
        "normal",
        True,
    )
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    faces, face_polygon = triangulate_polygons(corner_idx, offsets)

    n_v = verts.shape[0]
    meta: dict[str, Any] = {"source_units": units, "up": up_key, "source_format": "obj"}
    uv = None
    if uv_table.shape[0] and (corner_uv >= 0).any():
        meta["uv_table"] = uv_table
        meta["corner_uv"] = corner_uv
        uv = _per_vertex_uv(corner_idx, corner_uv, uv_table, n_v)
    if normals.shape[0]:
        meta["normal_table"] = to_y_up(normals, up_key)
        meta["corner_normal"] = corner_nrm
    if p.objects:
        meta["objects"] = {k: np.asarray(v, dtype=np.int64) for k, v in p.objects.items()}
    if p.materials:
        meta["materials"] = {k: np.asarray(v, dtype=np.int64) for k, v in p.materials.items()}
    if p.mtllib:
        meta["mtllib"] = list(p.mtllib)
    return Mesh(
        vertices=to_y_up(verts * scale, up_key),
        faces=faces,
        polygon_indices=corner_idx if corner_idx.size else None,
        polygon_offsets=offsets if corner_idx.size else None,
        face_polygon=face_polygon,
        groups={k: np.asarray(v, dtype=np.int64) for k, v in p.groups.items()},
        uv=uv,
        meta=meta,
    )


def _per_vertex_uv(
    corner_idx: np.ndarray, corner_uv: np.ndarray, uv_table: np.ndarray, n_v: int
) -> np.ndarray | None:
    """(V, 2) UV per vertex when every vertex's corners agree, else None."""
    if (corner_uv < 0).any():
        return None
    corner_coords = uv_table[corner_uv]
    uv = np.zeros((n_v, 2))
    seen = np.zeros(n_v, dtype=bool)
    uv[corner_idx] = corner_coords
    seen[corner_idx] = True
    if not np.array_equal(uv[corner_idx], corner_coords) or not seen.all():
        return None
    return uv


def _group_runs(n_poly: int, mesh: Mesh) -> dict[int, list[str]]:
    """OBJ statements (``g``, ``o``, ``usemtl``) to write before polygon k."""

    def membership(sets: dict[str, np.ndarray], kind: str) -> tuple[np.ndarray, list[str]]:
        # (P, n) bool: polygon p belongs to the n-th name
        names = list(sets)
        member = np.zeros((n_poly, len(names)), dtype=bool)
        for j, name in enumerate(names):
            idx = np.asarray(sets[name], dtype=np.int64)
            if idx.size and (idx.min() < 0 or idx.max() >= n_poly):
                raise ValidationError(
                    f"{kind} {name!r}: polygon index out of range 0..{n_poly - 1}"
                )
            member[idx, j] = True
        return member, names

    kinds = [
        membership(dict(mesh.meta.get("objects", {})), "object"),
        membership(mesh.groups, "group"),
        membership(dict(mesh.meta.get("materials", {})), "material"),
    ]
    if n_poly == 0:
        return {}
    change = np.zeros(n_poly, dtype=bool)
    change[0] = True
    for member, _ in kinds:
        if member.shape[1]:
            change[1:] |= (member[1:] != member[:-1]).any(axis=1)
    runs: dict[int, list[str]] = {}
    prev: list[tuple[str, ...]] = [(), (), ()]
    for k in np.nonzero(change)[0].tolist():
        stmts = []
        for i, (member, names) in enumerate(kinds):
            cur = tuple(names[j] for j in np.nonzero(member[k])[0])
            if cur == prev[i]:
                continue
            if i == 0 and cur:
                stmts.append("o " + cur[0])
            elif i == 1:
                stmts.append("g " + " ".join(cur) if cur else "g")
            elif i == 2 and cur:
                stmts.append("usemtl " + cur[0])
            prev[i] = cur
        if stmts:
            runs[k] = stmts
    return runs


def write_obj(
    mesh: Mesh,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    units: str | None = None,
    up: str | None = None,
) -> None:
    """Write a mesh as Wavefront OBJ text.

    The source polygons are written when present (quads stay quads), else the
    triangles; groups (``g``), objects (``o``), materials (``usemtl``, ``mtllib``),
    UVs and normals are written when present (see the module notes on per-corner UVs).

    Parameters
    ----------
    mesh : Mesh
        Vertices (V, 3) float64 metres, Y up.
    path : str or PathLike
        Output file; refused when it exists unless ``force``.
    force : bool
        Replace an existing file.
    units, up : str, optional
        Unit and up axis of the file; default ``meta["source_units"]`` and
        ``meta["up"]`` (metres and Y when absent). Coordinates are written exactly
        (shortest round-trip text) in metres, to 15 significant digits otherwise.
    """
    verts, units_name, up_key = _restore_units(mesh, units, up)
    poly_idx, poly_off = _polygons_of(mesh)
    n_poly = poly_off.size - 1
    n_corner = poly_idx.size
    meta = mesh.meta
    uv_table = corner_uv = nrm_table = corner_nrm = None
    if "uv_table" in meta and "corner_uv" in meta and np.shape(meta["corner_uv"]) == (n_corner,):
        uv_table = np.asarray(meta["uv_table"], dtype=np.float64).reshape(-1, 2)
        corner_uv = np.asarray(meta["corner_uv"], dtype=np.int64)
        if corner_uv.size and corner_uv.max() >= uv_table.shape[0]:
            uv_table = corner_uv = None
    if uv_table is None and mesh.uv is not None:
        uv_table, corner_uv = mesh.uv, poly_idx
    if (
        "normal_table" in meta
        and "corner_normal" in meta
        and np.shape(meta["corner_normal"]) == (n_corner,)
    ):
        nrm_table = from_y_up(
            np.asarray(meta["normal_table"], dtype=np.float64).reshape(-1, 3), up_key
        )
        corner_nrm = np.asarray(meta["corner_normal"], dtype=np.int64)
        if corner_nrm.size and corner_nrm.max() >= nrm_table.shape[0]:
            nrm_table = corner_nrm = None

    exact = unit_scale(units_name) == 1.0
    out: list[str] = [f"# skincap OBJ, units {units_name}, up {up_key}"]
    out += ["mtllib " + " ".join(str(m) for m in meta["mtllib"])] if meta.get("mtllib") else []
    flat = _format_floats(verts.reshape(-1), exact)
    out += ["v " + " ".join(flat[3 * i : 3 * i + 3]) for i in range(verts.shape[0])]
    if uv_table is not None:
        flat = _format_floats(uv_table.reshape(-1), True)
        out += ["vt " + " ".join(flat[2 * i : 2 * i + 2]) for i in range(uv_table.shape[0])]
    if nrm_table is not None:
        flat = _format_floats(nrm_table.reshape(-1), True)
        out += ["vn " + " ".join(flat[3 * i : 3 * i + 3]) for i in range(nrm_table.shape[0])]

    corner_txt = (poly_idx + 1).astype(str)
    has_t = np.zeros(n_corner, dtype=bool) if corner_uv is None else corner_uv >= 0
    has_n = np.zeros(n_corner, dtype=bool) if corner_nrm is None else corner_nrm >= 0
    if has_t.any() or has_n.any():
        # v, v/vt, v//vn or v/vt/vn per corner
        t_txt = np.char.add("/", (corner_uv + 1).astype(str)) if corner_uv is not None else ""
        n_txt = np.char.add("/", (corner_nrm + 1).astype(str)) if corner_nrm is not None else ""
        corner_txt = np.char.add(corner_txt, np.where(has_t, t_txt, np.where(has_n, "/", "")))
        corner_txt = np.char.add(corner_txt, np.where(has_n, n_txt, ""))
    corners = corner_txt.tolist()
    runs = _group_runs(n_poly, mesh)
    offs = poly_off.tolist()
    for g in range(n_poly):
        if g in runs:
            out += runs[g]
        out.append("f " + " ".join(corners[offs[g] : offs[g + 1]]))
    text = "\n".join(out) + "\n"
    with atomic_output(path, force=force) as tmp:
        tmp.write_text(text, encoding="utf-8")


# -------------------------------------------------------------------------------- PLY
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
    fields: list[tuple[str, str]] = []
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
    scale, up_key = _scale_and_up(units, up)
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
    verts, units_name, up_key = _restore_units(mesh, units, up)
    poly_idx, poly_off = _polygons_of(mesh)
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
            flat = _format_floats(vdata.reshape(-1), True)
            w = vdata.shape[1]
            lines = [" ".join(flat[w * i : w * i + w]) for i in range(vdata.shape[0])]
            idx_txt = poly_idx.astype(str).tolist()
            offs = poly_off.tolist()
            lines += [
                f"{offs[g + 1] - offs[g]} " + " ".join(idx_txt[offs[g] : offs[g + 1]])
                for g in range(sizes.size)
            ]
            fh.write(("\n".join(lines) + "\n").encode("ascii"))
