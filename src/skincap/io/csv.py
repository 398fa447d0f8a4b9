"""Marker and point CSV files: Vicon Nexus, OptiTrack Motive, and skincap's long format.

* :func:`read_vicon_csv` / :func:`write_vicon_csv` -- the "Trajectories" section of a
  Vicon Nexus CSV export (Z up, millimetres).
* :func:`read_optitrack_csv` -- an OptiTrack Motive CSV export (format 1.2x, Y up).
* :func:`read_points_csv` / :func:`write_points_csv` -- un-indexed point clouds, one
  point per row (``frame,time,x,y,z[,id]``, metres, Y up).
* :func:`read_csv` -- sniffs which of the three a file is from its first line.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np

from skincap.errors import FormatError, UnitWarning, ValidationError
from skincap.io._common import (
    UNIT_TO_METRES,
    atomic_output,
    check_readable,
    from_y_up,
    to_y_up,
)
from skincap.io.c3d.content import warn_dropped_c3d_content
from skincap.io.trc import (
    fields_of_width,
    format_float_fields,
    parse_float_rows,
    read_text_lines,
)
from skincap.types import MarkerSet, PointCloud

__all__ = [
    "read_csv",
    "read_vicon_csv",
    "write_vicon_csv",
    "read_optitrack_csv",
    "read_points_csv",
    "write_points_csv",
]

#: Section titles of a Vicon Nexus CSV export; a section ends where the next begins.
VICON_SECTIONS = ("Trajectories", "Devices", "Model Outputs", "Joints", "Segments", "Events")
_MOTIVE_UNITS = {"meters": "m", "centimeters": "cm", "millimeters": "mm"}


def _unique(labels: list[str]) -> list[str]:
    """Deterministically unique labels: repeats become name_2, name_3…"""
    taken: set[str] = set()
    real = set(labels)
    out = []
    for lab in labels:
        new, k = lab, 2
        while new in taken or (new != lab and new in real):
            new, k = f"{lab}_{k}", k + 1
        taken.add(new)
        out.append(new)
    return out


def _cells(line: str) -> list[str]:
    return [c.strip().strip('"').strip() for c in line.split(",")]


def _check_times(
    path: Path, times: np.ndarray, frames: np.ndarray, rate: float, lines: list[int]
) -> None:
    """Time column must agree with frame / rate to within half a frame."""
    if times.size == 0:
        return
    expect = times[0] + (frames - frames[0]) / rate
    dev = np.abs(times - expect)
    if dev.max() >= 0.5 / rate:
        bad = int(np.argmax(dev))
        raise FormatError(
            path,
            f"time {times[bad]!r} disagrees with frame {int(frames[bad])} at {rate!r} Hz",
            line=lines[bad],
        )


def _consecutive_frames(
    path: Path, frames: np.ndarray, lines: list[int], what: str = "Frame"
) -> None:
    if frames.size == 0:
        return
    ok_int = frames == np.round(frames)
    steps = np.concatenate([[True], np.diff(frames) == 1])
    bad = ~(ok_int & steps)
    if bad.any():
        k = int(np.argmax(bad))
        raise FormatError(
            path, f"{what} numbers must be consecutive integers, got {frames[k]!r}", line=lines[k]
        )


# --------------------------------------------------------------------------- Vicon
def read_vicon_csv(
    path: str | os.PathLike[str], *, up: Literal["auto", "y", "z"] = "auto"
) -> MarkerSet:
    """Read the "Trajectories" section of a Vicon Nexus CSV export.

    Layout: a line ``Trajectories``, a line with the rate (Hz), a line with
    ``Subject:Marker`` labels every third column from column 3, ``Frame,Sub Frame,X,Y,Z,…``,
    a units line (``mm``…), then one row per frame with empty fields where a marker is
    missing. Reading stops at a blank line or at the next section title
    (``Devices``, ``Model Outputs``, ``Joints``…); sections before ``Trajectories`` are
    skipped.

    Parameters
    ----------
    path : str or PathLike
    up : {"auto", "y", "z"}
        Nexus' world frame is Z up; ``"auto"`` means ``"z"``.

    Returns
    -------
    MarkerSet
        ``positions`` (T, N, 3) float64 metres, Y up, NaN where missing. ``meta``:
        ``source_units``, ``up``, ``first_frame`` (the first Frame number).

    Raises
    ------
    FormatError
        No Trajectories section, ragged rows, non-numeric fields, non-consecutive
        frames, sub-frames other than 0, mixed units (with the line number).
    """
    p = check_readable(path)
    if up not in ("auto", "y", "z"):
        raise ValidationError(f"up: expected 'auto', 'y' or 'z', got {up!r}")
    up_src = "z" if up == "auto" else up
    lines = read_text_lines(p)
    start = next((k for k, ln in enumerate(lines) if _cells(ln)[0] == "Trajectories"), None)
    if start is None:
        raise FormatError(p, "no 'Trajectories' section (is this a Vicon Nexus CSV export?)")
    if start + 5 > len(lines):
        raise FormatError(
            p, "the Trajectories section ends inside its 5-line header", line=len(lines)
        )
    try:
        rate = float(_cells(lines[start + 1])[0])
    except ValueError:
        raise FormatError(
            p, f"expected the frame rate, got {lines[start + 1][:40]!r}", line=start + 2
        ) from None
    if not (np.isfinite(rate) and rate > 0):
        raise FormatError(p, f"frame rate {rate!r} is not positive", line=start + 2)
    head = _cells(lines[start + 3])
    if head[:2] != ["Frame", "Sub Frame"]:
        raise FormatError(p, "expected 'Frame,Sub Frame,X,Y,Z,…'", line=start + 4)
    axes = head[2:]
    while axes and axes[-1] == "":
        axes.pop()
    n = len(axes) // 3
    if len(axes) % 3 or axes != ["X", "Y", "Z"] * n:
        raise FormatError(p, "coordinate columns must be X,Y,Z triples", line=start + 4)
    width = 2 + 3 * n
    names = _cells(lines[start + 2])
    names = names + [""] * max(0, width - len(names))
    if any(names[width:]):
        raise FormatError(p, "labels line has more columns than the X,Y,Z header", line=start + 3)
    labels = [names[2 + 3 * i] for i in range(n)]
    if any(not s for s in labels) or any(names[3 + 3 * i] or names[4 + 3 * i] for i in range(n)):
        raise FormatError(p, "labels must sit every third column, above each X", line=start + 3)
    unit_cells = _cells(lines[start + 4])[2:width]
    units = {u for u in unit_cells if u}
    if len(units) != 1:
        raise FormatError(
            p, f"expected one length unit for all coordinates, got {sorted(units)}", line=start + 5
        )
    unit = units.pop()
    if unit.lower() not in UNIT_TO_METRES:
        raise FormatError(p, f"unknown length unit {unit!r}", line=start + 5)

    rows: list[list[str]] = []
    numbers: list[int] = []
    for k in range(start + 5, len(lines)):
        cells = _cells(lines[k])
        if not any(cells):
            break
        if cells[0] in VICON_SECTIONS:
            break
        rows.append(fields_of_width(p, cells, width, line=k + 1))
        numbers.append(k + 1)
    table = parse_float_rows(p, rows, numbers) if rows else np.zeros((0, width))
    if table.size and np.isnan(table[:, :2]).any():
        bad = int(np.nonzero(np.isnan(table[:, :2]).any(axis=1))[0][0])
        raise FormatError(p, "Frame and Sub Frame must not be empty", line=numbers[bad])
    _consecutive_frames(p, table[:, 0], numbers)
    if table.size and (table[:, 1] != 0).any():
        bad = int(np.argmax(table[:, 1] != 0))
        raise FormatError(p, "sub-frames other than 0 are not supported", line=numbers[bad])
    pos = table[:, 2:].reshape(len(rows), n, 3) * UNIT_TO_METRES[unit.lower()]
    meta: dict[str, Any] = {
        "source_format": "vicon_csv",
        "source_path": str(p),
        "source_units": unit,
        "up": up_src,
        "first_frame": int(table[0, 0]) if len(rows) else 1,
    }
    if len(set(labels)) != n:
        raise FormatError(
            p,
            f"duplicate marker labels {sorted({s for s in labels if labels.count(s) > 1})[:5]}",
            line=start + 3,
        )
    return MarkerSet(positions=to_y_up(pos, up_src), labels=labels, rate=rate, meta=meta)


def write_vicon_csv(
    markers: MarkerSet, path: str | os.PathLike[str], *, force: bool = False
) -> None:
    """Write a MarkerSet as a Vicon Nexus "Trajectories" CSV that :func:`read_vicon_csv` reads.

    Millimetres; Z up (Nexus' own) unless the markers came from a Vicon CSV read with
    another ``up``, which is restored from ``meta["up"]``; CRLF line
    ends as Nexus writes them; coordinates printed with ``%.17g``; missing samples
    are empty fields; Frame counts from ``meta["first_frame"]`` (1 by default).
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    bad = [
        s for s in markers.labels if not s or any(c in s for c in ',"\r\n\x00') or s != s.strip()
    ]
    if bad:
        raise ValidationError(
            f"markers.labels: CSV labels cannot be empty or hold commas, quotes, line breaks or NULs: {bad[:5]}"
        )
    # a Nexus CSV carries no axis information: write Z up (Nexus' world frame) unless
    # the markers were read from a Vicon CSV with another up axis, which is restored
    up = (
        str(markers.meta.get("up", "z"))
        if markers.meta.get("source_format") == "vicon_csv"
        else "z"
    )
    if up not in ("y", "z"):
        up = "z"
    t, n = markers.n_frames, markers.n_markers
    width = 2 + 3 * n
    pad = "," * (width - 1)
    first = int(markers.meta.get("first_frame", 1))
    pos = from_y_up(markers.positions, up) / UNIT_TO_METRES["mm"]
    lines = [
        "Trajectories" + pad,
        repr(float(markers.rate)) + pad,
        ",," + ",".join(f"{s},," for s in markers.labels)[:-2] if n else pad,
        "Frame,Sub Frame" + ",X,Y,Z" * n,
        ",," + ",".join(["mm"] * (3 * n)),
    ]
    frames = np.char.mod("%d", np.arange(first, first + t))
    coords = format_float_fields(pos.reshape(t, 3 * n))
    for f, row in zip(frames.tolist(), coords.tolist(), strict=True):
        lines.append(f + ",0," + ",".join(row) if n else f + ",0")
    warn_dropped_c3d_content(
        markers.meta,
        "a Vicon trajectories CSV",
        path,
        stacklevel=2,
        camera_masks=markers.camera_masks,
        residuals=markers.residuals,
    )
    with atomic_output(path, force=force) as tmp:
        tmp.write_text("\r\n".join(lines) + "\r\n", encoding="utf-8", newline="")


# ----------------------------------------------------------------------- OptiTrack
def read_optitrack_csv(path: str | os.PathLike[str], *, up: Literal["y", "z"] = "y") -> MarkerSet:
    """Read the marker columns of an OptiTrack Motive CSV export (format 1.2x).

    Layout: a metadata line ``Format Version,1.23,Take Name,…,Export Frame Rate,120,
    …,Length Units,Meters,…`` (key, value pairs); header rows labelled in their
    first cells ``Type`` (Marker, Rigid Body, Rigid Body Marker, Bone, Bone Marker),
    ``Name``, ``ID``, optionally ``Parent``, a row of ``Position``/``Rotation``/
    ``Marker Quality``… per column, then ``Frame,Time (Seconds),X,Y,Z,…`` and the
    data, empty where a marker is occluded.

    Only ``Type == "Marker"`` position triples are kept: labelled names as written
    (``Subject:LASI``), ``Unlabeled 1234`` as ``*1234``; rigid bodies, their
    rotations and solved markers are ignored.

    Parameters
    ----------
    path : str or PathLike
    up : {"y", "z"}
        Motive exports Y up (the default) unless its axis convention was changed.

    Returns
    -------
    MarkerSet
        ``positions`` (T, N, 3) float64 metres, Y up, NaN where occluded; ``rate`` is
        "Export Frame Rate" (else "Capture Frame Rate"). ``meta``: ``source_units``,
        ``up``, ``first_frame``, ``marker_ids`` (the ID row), ``motive_header``.

    Warns
    -----
    UnitWarning
        No "Length Units" in the metadata: metres assumed (Motive's default).
    """
    p = check_readable(path)
    if up not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up!r}")
    lines = read_text_lines(p)
    header = _motive_metadata(p, lines)
    axis_at, axis_row, data_col, rows_by_name, component = _motive_header_rows(p, lines)
    width = len(axis_row)
    cols, labels, id_list = _motive_marker_columns(
        p, axis_row, data_col, rows_by_name, component, axis_at
    )
    rate, unit = _motive_rate_and_unit(p, header)
    rows, numbers = _motive_data_rows(p, lines, axis_at, width, data_col, cols)
    n = len(cols)
    table = parse_float_rows(p, rows, numbers) if rows else np.zeros((0, 2 + 3 * n))
    if table.size and np.isnan(table[:, :2]).any():
        bad = int(np.nonzero(np.isnan(table[:, :2]).any(axis=1))[0][0])
        raise FormatError(p, "Frame and Time must not be empty", line=numbers[bad])
    _consecutive_frames(p, table[:, 0], numbers)
    _check_times(p, table[:, 1], table[:, 0], rate, numbers)
    pos = table[:, 2:].reshape(len(rows), n, 3) * UNIT_TO_METRES[unit]
    meta: dict[str, Any] = {
        "source_format": "optitrack_csv",
        "source_path": str(p),
        "source_units": unit,
        "up": up,
        "first_frame": int(table[0, 0]) if len(rows) else 0,
        "start_time": float(table[0, 1]) if len(rows) else 0.0,
        "marker_ids": id_list,
        "motive_header": header,
    }
    return MarkerSet(positions=to_y_up(pos, up), labels=_unique(labels), rate=rate, meta=meta)


def _motive_metadata(p: Path, lines: list[str]) -> dict[str, str]:
    """The key, value pairs of a Motive CSV's first line (``Format Version,1.23,…``)."""
    first = _cells(lines[0]) if lines else [""]
    if first[0] != "Format Version":
        raise FormatError(p, "not a Motive CSV: line 1 must start with 'Format Version'", line=1)
    header: dict[str, str] = {}
    for i in range(0, len(first) - 1, 2):
        if first[i]:
            header[first[i]] = first[i + 1]
    return header


def _motive_header_rows(
    p: Path, lines: list[str]
) -> tuple[int, list[str], int, dict[str, list[str]], list[str]]:
    """The header rows above the data: (line index of ``Frame,Time…``, that row cut to
    its last non-empty cell (width W), first data column, the labelled rows (Type,
    Name, ID…) by label, the Position/Rotation row), each row W cells."""
    axis_at = next(
        (
            k
            for k, ln in enumerate(lines)
            if _cells(ln)[0] == "Frame" and len(_cells(ln)) > 1 and _cells(ln)[1].startswith("Time")
        ),
        None,
    )
    if axis_at is None:
        raise FormatError(p, "no 'Frame,Time (Seconds),…' header row", line=len(lines))
    axis_row = _cells(lines[axis_at])
    width = len(axis_row)
    while width and axis_row[width - 1] == "":
        width -= 1
    data_col = 2
    while data_col < width and axis_row[data_col] not in ("X", "Y", "Z", "W"):
        data_col += 1  # e.g. a TimeCode column
    rows_by_name: dict[str, list[str]] = {}
    component: list[str] | None = None
    for k in range(1, axis_at):
        cells = _cells(lines[k])
        if not any(cells):
            continue
        cells = (cells + [""] * width)[:width]
        label = next((c for c in cells[:data_col] if c), "")
        if label:
            rows_by_name[label] = cells
        else:
            component = cells
    if "Type" not in rows_by_name or "Name" not in rows_by_name or component is None:
        raise FormatError(
            p, "missing the Type, Name or Position/Rotation header row", line=axis_at + 1
        )
    return axis_at, axis_row[:width], data_col, rows_by_name, component


def _motive_marker_columns(
    p: Path,
    axis_row: list[str],
    data_col: int,
    rows_by_name: dict[str, list[str]],
    component: list[str],
    axis_at: int,
) -> tuple[list[int], list[str], list[str]]:
    """The X column of each ``Marker`` position triple, its label (``Unlabeled 12`` ->
    ``*12``) and its ID, in column order."""
    width = len(axis_row)
    types, names, ids = (
        rows_by_name["Type"],
        rows_by_name["Name"],
        rows_by_name.get("ID", [""] * width),
    )
    cols: list[int] = []
    labels: list[str] = []
    id_list: list[str] = []
    c = data_col
    while c < width:
        if types[c] == "Marker" and component[c] == "Position" and axis_row[c] == "X":
            if (
                c + 2 >= width
                or axis_row[c + 1 : c + 3] != ["Y", "Z"]
                or names[c + 1] != names[c]
                or names[c + 2] != names[c]
            ):
                raise FormatError(
                    p,
                    f"marker {names[c]!r}: expected X,Y,Z columns {c + 1}..{c + 3}",
                    line=axis_at + 1,
                )
            name = names[c]
            m = re.fullmatch(r"Unlabeled\s+(\S+)", name)
            labels.append(f"*{m.group(1)}" if m else name)
            id_list.append(ids[c])
            cols.append(c)
            c += 3
        else:
            c += 1
    return cols, labels, id_list


def _motive_rate_and_unit(p: Path, header: dict[str, str]) -> tuple[float, str]:
    """The frame rate (Hz) and length unit the metadata declares; metres (with a
    UnitWarning at the reader's caller) when it declares none."""
    rate_s = header.get("Export Frame Rate") or header.get("Capture Frame Rate")
    try:
        rate = float(rate_s) if rate_s is not None else float("nan")
    except ValueError:
        rate = float("nan")
    if not (np.isfinite(rate) and rate > 0):
        raise FormatError(
            p, f"no valid 'Export Frame Rate' or 'Capture Frame Rate' ({rate_s!r})", line=1
        )
    unit_name = header.get("Length Units")
    if unit_name is None:
        warnings.warn(
            f"{p}: no 'Length Units' in the header; assuming Meters (Motive's default)",
            UnitWarning,
            stacklevel=3,
        )
        unit = "m"
    elif unit_name.lower() in _MOTIVE_UNITS:
        unit = _MOTIVE_UNITS[unit_name.lower()]
    else:
        raise FormatError(p, f"unknown Length Units {unit_name!r}", line=1)
    return rate, unit


def _motive_data_rows(
    p: Path, lines: list[str], axis_at: int, width: int, data_col: int, cols: list[int]
) -> tuple[list[list[str]], list[int]]:
    """The data rows as text cells (Frame, Time, then X, Y, Z of each marker column
    in ``cols``) and their 1-based line numbers; rows short of trailing occluded
    fields are padded."""
    rows: list[list[str]] = []
    numbers: list[int] = []
    for k in range(axis_at + 1, len(lines)):
        cells = _cells(lines[k])
        if not any(cells):
            continue
        if data_col < len(cells) < width:
            # Motive leaves trailing occluded fields out on some rows; never data
            cells = cells + [""] * (width - len(cells))
        cells = fields_of_width(p, cells, width, line=k + 1)
        rows.append([cells[0], cells[1]] + [cells[j] for c0 in cols for j in (c0, c0 + 1, c0 + 2)])
        numbers.append(k + 1)
    return rows, numbers


# -------------------------------------------------------------------- point clouds
MAX_POINT_FRAMES = 10_000_000  # ~28 h at 100 Hz; offsets (T + 1,) int64 = 80 MB
_POINTS_HEADERS = (["frame", "time", "x", "y", "z"], ["frame", "time", "x", "y", "z", "id"])


#: Point ids must stay below this: every integer under it is exact in float64 (53 bits).
_MAX_EXACT_ID = 2.0**53


def read_points_csv(path: str | os.PathLike[str]) -> PointCloud:
    """Read an un-indexed point cloud in skincap's long CSV format.

    Layout::

        # rate=120.0
        # frames=3
        frame,time,x,y,z,id
        0,0,0.1,1.2,0.3,7
        0,0,0.5,1.1,0.2,-1
        2,0.016666666666666666,0.1,1.2,0.3,7

    One point per row, metres, Y up; ``frame`` 0-based and non-decreasing (frame 1
    above is empty); ``id`` optional, an integer >= 0 (-1 = unknown). ``# key=value`` comment lines
    come first: ``rate`` (Hz) is needed when it cannot be inferred from the times
    (fewer than two distinct frames); ``frames`` gives T when the last frames are
    empty. Without ``rate`` it is inferred from the first and last frame's times,
    and every time must then agree with it.

    Returns
    -------
    PointCloud
        ``points`` (M, 3) float64 metres; ``offsets`` (T + 1,) int64; ``ids`` (M,)
        int64 or None; ``meta["start_time"]`` the time of frame 0 (s).

    Raises
    ------
    FormatError
        Unknown header, ragged rows, non-numeric or non-finite fields, decreasing or
        negative frames, times that disagree with the rate (with the line number);
        more than ``max(MAX_POINT_FRAMES, M)`` frames (a frame number or ``# frames=``).
    """
    p = check_readable(path)
    lines = read_text_lines(p)
    comments, k, width = _points_header(p, lines)
    table, numbers = _points_table(p, lines, k, width)
    frames = _point_frames(p, table[:, 0], numbers)
    times = table[:, 1]
    n_frames = _points_frame_count(p, comments, frames, numbers)
    rate, start_time = _points_rate(p, comments, frames, times, numbers, header_line=k + 1)
    offsets = np.searchsorted(frames, np.arange(n_frames + 1), side="left").astype(np.int64)
    ids = None
    if width == 6:
        idf = table[:, 5]
        if (idf != np.round(idf)).any():
            r = int(np.argmax(idf != np.round(idf)))
            raise FormatError(p, f"id {idf[r]!r} is not an integer", line=numbers[r])
        # past 2**53 the parsed float no longer holds the written integer (two ids would
        # merge) and past 2**63 it wraps in int64: refused rather than renumbered
        too_big = np.abs(idf) >= _MAX_EXACT_ID
        if too_big.any():
            r = int(np.argmax(too_big))
            raise FormatError(
                p,
                f"id {idf[r]:.17g}: ids must be integers of magnitude below 2**53",
                line=numbers[r],
            )
        # -1 is the one negative id (unknown); any other would pose as a real identity
        below = idf < -1
        if below.any():
            r = int(np.argmax(below))
            raise FormatError(
                p, f"id {idf[r]:.17g}: ids must be >= 0, or -1 for unknown", line=numbers[r]
            )
        ids = idf.astype(np.int64)
    meta = {
        "source_format": "points_csv",
        "source_path": str(p),
        "source_units": "m",
        "up": "y",
        "start_time": start_time,
    }
    return PointCloud(points=table[:, 2:5].copy(), offsets=offsets, rate=rate, ids=ids, meta=meta)


def _points_header(p: Path, lines: list[str]) -> tuple[dict[str, str], int, int]:
    """The ``# key=value`` comments (lower-case keys), the 0-based index of the
    ``frame,time,x,y,z[,id]`` line and its number of columns (5 or 6)."""
    comments: dict[str, str] = {}
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        for m in re.finditer(r"(\w+)\s*=\s*(\S+)", lines[k][1:]):
            comments[m.group(1).lower()] = m.group(2)
        k += 1
    if k >= len(lines):
        raise FormatError(p, "no 'frame,time,x,y,z' header line", line=len(lines))
    head = [c.strip().lower() for c in lines[k].split(",")]
    if head not in _POINTS_HEADERS:
        raise FormatError(
            p, f"expected the header 'frame,time,x,y,z[,id]', got {lines[k][:60]!r}", line=k + 1
        )
    return comments, k, len(head)


def _points_table(p: Path, lines: list[str], k: int, width: int) -> tuple[np.ndarray, list[int]]:
    """The rows below header line ``k`` as a finite (M, width) float64 table and their
    1-based line numbers; FormatError for a ragged, empty or non-finite field."""
    body = [(i + 1, ln) for i, ln in enumerate(lines[k + 1 :], start=k + 1) if ln.strip()]
    numbers = [i for i, _ in body]
    table = np.zeros((0, width))
    if body:
        try:
            table = np.loadtxt([ln for _, ln in body], delimiter=",", dtype=np.float64, ndmin=2)
            if table.shape[1] != width:
                raise ValueError
        except ValueError:
            rows = []
            for i, ln in body:
                cells = [c.strip() for c in ln.split(",")]
                if len(cells) != width:
                    raise FormatError(
                        p, f"row has {len(cells)} fields, expected {width}", line=i
                    ) from None
                if any(c == "" for c in cells):
                    raise FormatError(
                        p, "empty field (a point cloud has no missing samples)", line=i
                    ) from None
                rows.append(cells)
            table = parse_float_rows(p, rows, numbers)
        finite = np.isfinite(table)
        if not finite.all():
            r = int(np.nonzero(~finite.all(axis=1))[0][0])
            raise FormatError(p, "non-finite value", line=numbers[r])
    return table, numbers


def _point_frames(p: Path, frames_f: np.ndarray, numbers: list[int]) -> np.ndarray:
    """The frame column (M,) as int64, checked integer, >= 0 and non-decreasing."""
    if frames_f.size:
        bad = (frames_f != np.round(frames_f)) | (frames_f < 0)
        bad |= np.concatenate([[False], np.diff(frames_f) < 0])
        if bad.any():
            r = int(np.argmax(bad))
            raise FormatError(
                p,
                f"frame {frames_f[r]!r}: frames must be integers >= 0, non-decreasing",
                line=numbers[r],
            )
        too_far = frames_f >= _point_frame_limit(frames_f.size)
        if too_far.any():
            r = int(np.argmax(too_far))
            raise FormatError(
                p,
                f"frame {frames_f[r]:.12g}: at most {_point_frame_limit(frames_f.size)} frames "
                f"are read from {frames_f.size} points",
                line=numbers[r],
            )
    return frames_f.astype(np.int64)


def _points_frame_count(
    p: Path, comments: dict[str, str], frames: np.ndarray, numbers: list[int]
) -> int:
    """T: ``# frames=`` when given (at least the rows' last frame + 1), else last + 1."""
    n_frames = int(frames[-1]) + 1 if frames.size else 0
    if "frames" in comments:
        try:
            declared = int(comments["frames"])
        except ValueError:
            raise FormatError(
                p, f"'# frames={comments['frames']}' is not an integer", line=1
            ) from None
        if declared < n_frames:
            raise FormatError(
                p,
                f"'# frames={declared}' but the rows reach frame {n_frames - 1}",
                line=numbers[-1],
            )
        n_frames = declared
    limit = _point_frame_limit(frames.size)
    if n_frames > limit:
        raise FormatError(
            p, f"'# frames={n_frames}' for {frames.size} points; at most {limit} are read", line=1
        )
    return n_frames


def _point_frame_limit(n_points: int) -> int:
    """The most frames a file of ``n_points`` rows may claim: empty frames cost no bytes
    in the file but 8 in the offsets, so a far-off frame number or a ``# frames=``
    header must not make the reader allocate without bound."""
    return max(MAX_POINT_FRAMES, n_points)


def _points_rate(
    p: Path,
    comments: dict[str, str],
    frames: np.ndarray,
    times: np.ndarray,
    numbers: list[int],
    header_line: int,
) -> tuple[float, float]:
    """(rate in Hz, time of frame 0 in s): ``# rate=`` or inferred from the first and
    last rows' times (M,); FormatError when a time disagrees with it."""
    if "rate" in comments:
        try:
            rate = float(comments["rate"])
        except ValueError:
            raise FormatError(p, f"'# rate={comments['rate']}' is not a number", line=1) from None
        if not (np.isfinite(rate) and rate > 0):
            raise FormatError(p, f"'# rate={comments['rate']}' must be positive", line=1)
    else:
        if frames.size == 0 or frames[-1] == frames[0]:
            raise FormatError(
                p,
                "cannot infer the frame rate from fewer than two distinct frames; add '# rate=<Hz>'",
                line=header_line,
            )
        dt = times[-1] - times[0]
        if not dt > 0:
            raise FormatError(p, "times do not increase with frames", line=numbers[-1])
        rate = float((frames[-1] - frames[0]) / dt)
    start_time = float(times[0] - frames[0] / rate) if frames.size else 0.0
    if frames.size:
        dev = np.abs(times - (start_time + frames / rate))
        # an inferred rate must explain every time to 1 % of a frame; a declared one
        # is authoritative and times need only land in the right frame
        tol = 0.5 / rate if "rate" in comments else 0.01 / rate
        if dev.max() > tol:
            r = int(np.argmax(dev))
            raise FormatError(
                p,
                f"time {times[r]!r} of frame {frames[r]} disagrees with {rate!r} Hz",
                line=numbers[r],
            )
    return rate, start_time


def write_points_csv(
    cloud: PointCloud, path: str | os.PathLike[str], *, force: bool = False
) -> None:
    """Write a PointCloud in the long format of :func:`read_points_csv`.

    ``# rate=`` and ``# frames=`` lines first (so empty frames survive), then
    ``frame,time,x,y,z[,id]`` with every float printed as ``%.17g`` (all float64
    digits: reading back is exact). Time is ``meta["start_time"] + frame / rate``.
    """
    if not isinstance(cloud, PointCloud):
        raise ValidationError(f"cloud: expected a PointCloud, got {type(cloud).__name__}")
    frames = cloud.frame_index
    start = float(cloud.meta.get("start_time", 0.0))
    # one %-format per row over Python scalars: the same text as np.char.mod per
    # column, a third of its CPU time (166k points: 2.3 -> 0.8 s)
    cols = [frames.tolist(), (start + frames / cloud.rate).tolist()]
    cols += [cloud.points[:, j].tolist() for j in range(3)]
    head, row = "frame,time,x,y,z", "%d,%.17g,%.17g,%.17g,%.17g"
    if cloud.ids is not None:
        cols.append(cloud.ids.tolist())
        head, row = head + ",id", row + ",%d"
    lines = [f"# rate={float(cloud.rate)!r}", f"# frames={cloud.n_frames}", head]
    warn_dropped_c3d_content(cloud.meta, "a point CSV", path, stacklevel=2)
    if frames.size:
        lines.extend(row % r for r in zip(*cols, strict=True))
    with atomic_output(path, force=force) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="\n")


# --------------------------------------------------------------------------- sniff
def read_csv(path: str | os.PathLike[str], **kw: Any) -> MarkerSet | PointCloud:
    """Read a Vicon Nexus, OptiTrack Motive or skincap point CSV, chosen by its first line.

    ``Trajectories`` (or another Nexus section title) -> :func:`read_vicon_csv`;
    ``Format Version,…`` -> :func:`read_optitrack_csv`; ``# …`` or ``frame,time,x,y,z``
    -> :func:`read_points_csv`. ``kw`` is passed on to the chosen reader.

    Raises
    ------
    FormatError
        The first line matches none of the three.
    """
    p = check_readable(path)
    try:
        with p.open("rb") as fh:
            first_raw = fh.readline(4096)
    except OSError as exc:
        raise FormatError(p, f"cannot read: {exc.strerror}") from None
    first = first_raw.decode("utf-8-sig", errors="replace").strip()
    cell = _cells(first)[0] if first else ""
    if cell in VICON_SECTIONS:
        return read_vicon_csv(p, **kw)
    if cell == "Format Version":
        return read_optitrack_csv(p, **kw)
    if first.startswith("#") or first.lower().replace(" ", "").startswith("frame,time,x,y,z"):
        return read_points_csv(p, **kw)
    raise FormatError(
        p,
        f"unrecognised CSV: line 1 {first[:60]!r} is not a Vicon Nexus, OptiTrack Motive or skincap points header",
        line=1,
    )
