"""TRC marker files (OpenSim / Motion Analysis "PathFileType 4").

The writer follows OpenSim's own ``TRCFileAdapter`` byte for byte in layout, which is
what its strict reader accepts::

    PathFileType<TAB>4<TAB>(X/Y/Z)<TAB><file name>
    DataRate<TAB>CameraRate<TAB>NumFrames<TAB>NumMarkers<TAB>Units<TAB>OrigDataRate<TAB>OrigDataStartFrame<TAB>OrigNumFrames
    <values of the line above>
    Frame#<TAB>Time<TAB>M1<TAB><TAB><TAB>M2<TAB><TAB><TAB>...
    <TAB><TAB>X1<TAB>Y1<TAB>Z1<TAB>X2<TAB>...
    <empty line>
    1<TAB>0<TAB>x<TAB>y<TAB>z<TAB>...

Every field is followed by a tab (OpenSim counts one token per tab, so this keeps a
row whose last marker is missing at the right length); a missing sample is three
empty fields, which OpenSim reads as NaN.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

import numpy as np

from skincap.errors import FormatError, ValidationError
from skincap.io._common import (
    UNIT_TO_METRES,
    atomic_output,
    check_readable,
    from_y_up,
    read_file_bytes,
    to_y_up,
    unit_scale,
)
from skincap.io.c3d.content import warn_dropped_c3d_content
from skincap.types import MarkerSet

__all__ = ["read_trc", "write_trc"]

_KEYS = [
    "DataRate",
    "CameraRate",
    "NumFrames",
    "NumMarkers",
    "Units",
    "OrigDataRate",
    "OrigDataStartFrame",
    "OrigNumFrames",
]
_MISSING_TOKENS = ("", "nan", "NaN", "NAN", "-nan", "-NaN", "nan(ind)", "-nan(ind)")


def read_text_lines(path: Path) -> list[str]:
    """The lines of a text file without line endings; FormatError if not text."""
    raw = read_file_bytes(path)
    if b"\x00" in raw:
        raise FormatError(path, "binary data (NUL byte) in a text file", offset=raw.index(b"\x00"))
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise FormatError(path, f"not UTF-8 text (byte {exc.start})", line=line) from None
    return text.splitlines()


def fields_of_width(p: Path, fields: list[str], width: int, *, line: int) -> list[str]:
    """A row's text ``fields`` cut to ``width`` (only empty trailing ones may go).

    Raises
    ------
    FormatError
        More non-empty fields than ``width``, or fewer fields (naming ``line``, 1-based).
    """
    if len(fields) > width and not any(fields[width:]):
        return fields[:width]
    if len(fields) != width:
        raise FormatError(p, f"row has {len(fields)} fields, expected {width}", line=line)
    return fields


def parse_float_rows(
    path: Path, rows: list[list[str]], line_numbers: list[int], what: str = "value"
) -> np.ndarray:
    """(R, C) float64 from equal-length rows of strings; empty or NaN fields -> NaN.

    Raises FormatError naming the line and column of the first non-numeric field, or of
    an infinite value.
    """
    if not rows:
        return np.zeros((0, 0))
    arr = np.array(rows, dtype=str)
    blank = np.isin(arr, _MISSING_TOKENS)
    arr = np.where(blank, "nan", arr)
    try:
        out = arr.astype(np.float64)
    except ValueError:
        out = None
    if out is None or not np.isfinite(out[~blank]).all():
        for r, row in enumerate(rows):
            for c, field in enumerate(row):
                if field in _MISSING_TOKENS:
                    continue
                try:
                    v = float(field)
                except ValueError:
                    v = None
                if v is None or not np.isfinite(v):
                    raise FormatError(
                        path,
                        f"field {c + 1}: {what} {field[:40]!r} is not a finite number",
                        line=line_numbers[r],
                    )
        raise FormatError(path, "unparsable numbers", line=line_numbers[0])  # pragma: no cover
    return out


def format_float_fields(values: np.ndarray, fmt: str = "%.17g") -> np.ndarray:
    """(..., ) float -> same-shape str array, NaN -> empty string."""
    strs = np.char.mod(fmt, values)
    return np.where(np.isnan(values), "", strs)


def read_trc(path: str | os.PathLike[str], *, up: Literal["y", "z"] = "y") -> MarkerSet:
    """Read a TRC marker file.

    Parameters
    ----------
    path : str or PathLike
    up : {"y", "z"}
        The file's up axis; OpenSim TRC files are Y up (the default).

    Returns
    -------
    MarkerSet
        ``positions`` (T, N, 3) float64 metres, Y up, NaN where a sample is missing
        (empty fields or ``NaN``; one missing coordinate makes the sample missing);
        ``rate`` is DataRate. ``meta``: ``source_units``, ``up``, ``first_frame``
        (the first ``Frame#``), ``start_time`` (first Time, s), ``camera_rate``,
        ``orig_data_rate``, ``orig_data_start_frame``, ``orig_num_frames``.

    Raises
    ------
    FormatError
        Missing header lines, wrong keys, counts that disagree with the data, ragged
        or non-numeric rows (with the line number), a Time column that disagrees
        with DataRate by half a frame or more.

    Notes
    -----
    Tolerant of trailing tabs, CRLF line ends, blank lines between header and data
    and at the end, and of NaN written as an empty field or as ``NaN``.
    """
    p = check_readable(path)
    if up not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up!r}")
    lines = read_text_lines(p)
    head, rate, n_frames, n_markers = _trc_header(p, lines)
    units = head["Units"].strip()
    if units.lower() not in UNIT_TO_METRES:
        raise FormatError(
            p, f"Units {units!r} is not a known length unit ({', '.join(UNIT_TO_METRES)})", line=3
        )
    scale = UNIT_TO_METRES[units.lower()]
    labels = _trc_labels(p, lines, n_markers)
    rows, numbers = _trc_data_rows(p, lines, 2 + 3 * len(labels), n_frames)
    # Motion Analysis (Cortex, EVaRT) appends unnamed markers to a row after the named
    # ones, as many as that frame saw: columns ``*k`` (k its number in the row, as X<k>)
    width = max([2 + 3 * len(labels)] + [len(r) for r in rows])
    width = 2 + 3 * -(-(width - 2) // 3)
    labels = labels + [f"*{k}" for k in range(len(labels) + 1, (width - 2) // 3 + 1)]
    n_markers = len(labels)
    if len(rows) * width > 8 * sum(len(line) for line in lines) + 1_000_000:
        raise FormatError(p, f"rows of up to {width} fields would need too many cells", line=5)
    rows = [r + [""] * (width - len(r)) for r in rows]
    table = parse_float_rows(p, rows, numbers) if rows else np.zeros((0, width))
    if table.size and (np.isnan(table[:, :2]).any()):
        bad = int(np.nonzero(np.isnan(table[:, :2]).any(axis=1))[0][0])
        raise FormatError(p, "Frame# and Time must not be empty", line=numbers[bad])
    frames = table[:, 0]
    times = table[:, 1]
    _check_trc_clock(p, frames, times, rate, numbers)
    pos = table[:, 2:].reshape(len(rows), n_markers, 3) * scale
    try:
        first_frame = int(frames[0]) if frames.size else int(float(head["OrigDataStartFrame"]))
    except ValueError:
        first_frame = 1
    meta: dict[str, Any] = {
        "source_format": "trc",
        "source_path": str(p),
        "source_units": units,
        "up": up,
        "first_frame": first_frame,
        "start_time": float(times[0]) if times.size else 0.0,
        "camera_rate": head["CameraRate"],
        "orig_data_rate": head["OrigDataRate"],
        "orig_data_start_frame": head["OrigDataStartFrame"],
        "orig_num_frames": head["OrigNumFrames"],
    }
    if len(set(labels)) != len(labels):
        dup = sorted({s for s in labels if labels.count(s) > 1})
        raise FormatError(p, f"duplicate marker names {dup[:5]}", line=4)
    return MarkerSet(positions=to_y_up(pos, up), labels=labels, rate=rate, meta=meta)


def _trc_header(p: Path, lines: list[str]) -> tuple[dict[str, str], float, int, int]:
    """Lines 1-3: the header values by key, DataRate (Hz), NumFrames and NumMarkers."""
    if len(lines) < 5:
        raise FormatError(
            p, f"a TRC file needs 5 header lines, found {len(lines)}", line=len(lines) or 1
        )
    first = lines[0].split("\t")
    if not first or first[0].strip() != "PathFileType":
        raise FormatError(p, "not a TRC file: line 1 must start with 'PathFileType'", line=1)
    keys = [k.strip() for k in lines[1].split("\t") if k.strip()]
    if keys != _KEYS:
        raise FormatError(
            p, f"expected the keys {' '.join(_KEYS)}, got {' '.join(keys)[:120]!r}", line=2
        )
    values = [v.strip() for v in lines[2].split("\t") if v.strip()]
    if len(values) != len(_KEYS):
        raise FormatError(p, f"expected {len(_KEYS)} header values, got {len(values)}", line=3)
    head = dict(zip(_KEYS, values, strict=True))
    try:
        rate = float(head["DataRate"])
        n_frames = int(head["NumFrames"])
        n_markers = int(head["NumMarkers"])
    except ValueError:
        raise FormatError(p, "DataRate, NumFrames and NumMarkers must be numbers", line=3) from None
    if not (np.isfinite(rate) and rate > 0) or n_frames < 0 or n_markers < 0:
        raise FormatError(
            p,
            f"DataRate {head['DataRate']}, NumFrames {n_frames}, NumMarkers {n_markers} are not valid",
            line=3,
        )
    return head, rate, n_frames, n_markers


def _trc_labels(p: Path, lines: list[str], n_markers: int) -> list[str]:
    """The marker labels of line 4, checked against NumMarkers and line 5's X1 Y1 Z1…"""
    names = [s.strip() for s in lines[3].split("\t") if s.strip()]
    if len(names) < 2 or names[0] != "Frame#" or names[1] != "Time":
        raise FormatError(p, "line 4 must start with 'Frame#' and 'Time'", line=4)
    labels = names[2:]
    xyz = [s.strip() for s in lines[4].split("\t") if s.strip()]

    def listed(n: int) -> bool:
        return xyz == [f"{a}{i}" for i in range(1, n + 1) for a in "XYZ"]

    # Motion Analysis counts its unnamed markers in NumMarkers and names and lists
    # only the named ones
    if len(labels) != n_markers and not (len(labels) < n_markers and listed(len(labels))):
        raise FormatError(
            p, f"NumMarkers is {n_markers} but line 4 names {len(labels)} markers", line=4
        )
    if not listed(len(labels)):
        raise FormatError(p, f"line 5 must list X1 Y1 Z1 ... Z{len(labels)}", line=5)
    return labels


def _trc_data_rows(
    p: Path, lines: list[str], width: int, n_frames: int
) -> tuple[list[list[str]], list[int]]:
    """The data rows (at least ``width`` text fields each: more where unnamed markers
    follow, empty trailing fields cut) and their 1-based line numbers; FormatError when
    a row is shorter or their count is not NumFrames."""
    rows: list[list[str]] = []
    numbers: list[int] = []
    for k in range(5, len(lines)):
        line = lines[k]
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split("\t")]
        while len(fields) > width and not fields[-1]:
            fields.pop()
        rows.append(
            fields if len(fields) > width else fields_of_width(p, fields, width, line=k + 1)
        )
        numbers.append(k + 1)
    if len(rows) != n_frames:
        where = numbers[-1] if numbers else len(lines)
        raise FormatError(
            p, f"NumFrames is {n_frames} but the file has {len(rows)} data rows", line=where
        )
    return rows, numbers


def _check_trc_clock(
    p: Path, frames: np.ndarray, times: np.ndarray, rate: float, numbers: list[int]
) -> None:
    """FormatError unless Frame# (T,) are consecutive integers and Time (T,) seconds
    follows DataRate (Hz) within half a frame."""
    if frames.size and (np.any(frames != np.round(frames)) or np.any(np.diff(frames) != 1)):
        bad = int(
            np.argmax(np.concatenate([[frames[0] != np.round(frames[0])], np.diff(frames) != 1]))
        )
        raise FormatError(p, "Frame# must be consecutive integers", line=numbers[bad])
    if times.size:
        dev = np.abs(times - (times[0] + np.arange(times.size) / rate))
        if dev.max() >= 0.5 / rate:
            bad = int(np.argmax(dev))
            raise FormatError(
                p, f"Time {times[bad]!r} disagrees with DataRate {rate!r}", line=numbers[bad]
            )


def write_trc(
    markers: MarkerSet,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    units: str = "mm",
    up: Literal["y", "z"] | None = None,
) -> None:
    """Write a MarkerSet as an OpenSim-readable TRC file.

    Parameters
    ----------
    markers : MarkerSet
        ``positions`` (T, N, 3) metres, Y up; NaN samples become empty fields.
    path : str or PathLike
        Output; refused if it exists unless ``force``.
    units : str
        Length unit written (default ``"mm"``, OpenSim's usual).
    up : {"y", "z"}, optional
        Up axis of the file; default Y (OpenSim's), or ``meta["up"]`` when the
        markers came from a TRC.

    Notes
    -----
    Coordinates are printed with ``%.17g`` (every float64 digit), Time as
    ``start_time + i / rate`` with ``%.17g``; Frame# counts from
    ``meta["first_frame"]`` (1 by default).
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    scale = unit_scale(units)
    if up is None:
        up = markers.meta.get("up", "y") if markers.meta.get("source_format") == "trc" else "y"
    if up not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up!r}")
    bad = [
        s for s in markers.labels if not s or any(c in s for c in "\t\r\n\x00") or s != s.strip()
    ]
    if bad:
        raise ValidationError(
            f"markers.labels: TRC names cannot be empty or hold tabs, line breaks, NULs or edge blanks: {bad[:5]}"
        )
    t, n = markers.n_frames, markers.n_markers
    first_frame = int(markers.meta.get("first_frame", 1))
    start_time = float(markers.meta.get("start_time", 0.0))
    pos = from_y_up(markers.positions, up) / scale  # (T, N, 3) file units
    rate_s = repr(float(markers.rate))
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{Path(path).name}",
        "\t".join(_KEYS),
        "\t".join([rate_s, rate_s, str(t), str(n), units, rate_s, str(first_frame), str(t)]),
        "Frame#\tTime\t" + "".join(f"{s}\t\t\t" for s in markers.labels),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, n + 1)),
        "",
    ]
    frames = np.char.mod("%d", np.arange(first_frame, first_frame + t))
    times = np.char.mod("%.17g", start_time + np.arange(t) / markers.rate)
    coords = format_float_fields(pos.reshape(t, 3 * n))
    table = (
        np.concatenate([frames[:, None], times[:, None], coords], axis=1)
        if t
        else np.zeros((0, 2 + 3 * n), dtype=str)
    )
    body = "\n".join("\t".join(row) + "\t" for row in table.tolist())
    text = "\n".join(header) + "\n" + body + ("\n" if t else "")
    warn_dropped_c3d_content(
        markers.meta,
        "a TRC",
        path,
        stacklevel=2,
        camera_masks=markers.camera_masks,
        residuals=markers.residuals,
    )
    with atomic_output(path, force=force) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
