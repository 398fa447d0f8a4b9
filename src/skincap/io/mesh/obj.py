"""Wavefront OBJ meshes: reader and writer.

No length unit and no up axis in the file: see :mod:`skincap.io.mesh`.

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
from skincap.io.mesh.common import (
    format_floats,
    polygons_of,
    restore_units,
    scale_and_up,
    triangulate_polygons,
)
from skincap.types import Mesh

__all__ = ["read_obj", "write_obj", "rate_comment", "recorded_rate"]


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
                    value = int(t)
                except ValueError:
                    raise FormatError(
                        path,
                        f"face: bad {name} index in corner {p.corners[k]!r}",
                        line=int(f_lines[k]),
                    ) from None
                if not -(2**63) <= value < 2**63:  # a whole number past int64 (1e23)
                    raise FormatError(
                        path,
                        f"face: {name} index {t[:40]} out of range in corner {p.corners[k][:80]!r}",
                        line=int(f_lines[k]),
                    ) from None
            raise FormatError(path, f"face: bad {name} index") from None
        out.append(arr)
    return out[0], out[1], out[2]


#: Plurals of the OBJ element names used in messages ("vertexs" read as a typo).
_PLURAL = {"vertex": "vertices"}


def _count_of(n: int, noun: str) -> str:
    """``n`` and ``noun`` agreeing: "1 vertex", "3 vertices", "0 normals"."""
    return f"{n} {noun if n == 1 else _PLURAL.get(noun, noun + 's')}"


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
            f"face: {what} index {val} out of range (file has {_count_of(total, what)})",
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
    scale, up_key = scale_and_up(units, up)
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

    def corners(
        raw: np.ndarray, defined: list[int], total: int, what: str, optional: bool
    ) -> np.ndarray:
        # ``defined``: per face, how many entries of that kind came before it (for
        # negative, relative indices); repeated to the face's corners
        per_corner = np.repeat(np.asarray(defined, dtype=np.int64), sizes)
        return _resolve(p_path, raw, per_corner, f_lines, total, what, optional)

    corner_idx = corners(raw_v, p.f_nv, len(p.v_lines), "vertex", False)
    corner_uv = corners(raw_t, p.f_nvt, len(p.vt_lines), "texture coordinate", True)
    corner_nrm = corners(raw_n, p.f_nvn, len(p.vn_lines), "normal", True)
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
    comments: tuple[str, ...] = (),
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
    comments : tuple of str
        Lines written as ``# <line>`` after the header comment (OBJ readers skip
        them; :func:`skincap.io.pc2.recorded_pc2_rate` reads one).
    """
    if any("\n" in c or "\r" in c for c in comments):
        raise ValidationError("comments: one line each, without line breaks")
    verts, units_name, up_key = restore_units(mesh, units, up)
    poly_idx, poly_off = polygons_of(mesh)
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
    out += [f"# {c}" for c in comments]
    out += ["mtllib " + " ".join(str(m) for m in meta["mtllib"])] if meta.get("mtllib") else []
    flat = format_floats(verts.reshape(-1), exact)
    out += ["v " + " ".join(flat[3 * i : 3 * i + 3]) for i in range(verts.shape[0])]
    if uv_table is not None:
        flat = format_floats(uv_table.reshape(-1), True)
        out += ["vt " + " ".join(flat[2 * i : 2 * i + 2]) for i in range(uv_table.shape[0])]
    if nrm_table is not None:
        flat = format_floats(nrm_table.reshape(-1), True)
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


#: Lines at the top of an OBJ searched for a rate comment (it follows the header line).
_RATE_NOTE_LINES = 4


def rate_comment(what: str, rate: float, plays: str) -> str:
    """A comment line recording the frame rate (Hz) of ``what`` (``"PC2"``,
    ``"OBJ sequence"``): ``skincap <what> rate <Hz> Hz: <plays> plays at this rate``.
    Pass it to :func:`write_obj` ``comments``; :func:`recorded_rate` reads it back."""
    return f"skincap {what} rate {float(rate)!r} Hz: {plays} plays at this rate"


def recorded_rate(path: str | os.PathLike[str], what: str) -> float | None:
    """The frame rate :func:`rate_comment` recorded for ``what`` in the OBJ ``path``.

    Only the first few lines are read; a missing, unreadable or malformed note (not
    a positive finite number up to 1 MHz) is None, so the caller falls back as for a
    file from another program.
    """
    prefix = f"# skincap {what} rate "
    try:
        with open(path, "rb") as fh:
            head = [fh.readline(256) for _ in range(_RATE_NOTE_LINES)]
    except OSError:
        return None
    for raw in head:
        line = raw.decode("utf-8", "replace").strip()
        if line.startswith(prefix):
            try:
                rate = float(line[len(prefix) :].split(" ", 1)[0])
            except ValueError:
                return None
            return rate if np.isfinite(rate) and 0 < rate <= 1e6 else None
    return None
