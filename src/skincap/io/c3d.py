"""C3D marker files: read through ezc3d, written by skincap (:mod:`skincap.io.c3d_encode`).

skincap validates the whole C3D structure in Python before ezc3d sees a file
(header, every parameter record, the size of the data section): ezc3d can crash the
interpreter or loop forever on a corrupted parameter section, so only files whose
structure is consistent reach it, and every problem is a :class:`FormatError` with the
byte offset at fault.

What the reader keeps
---------------------
* Marker columns: every POINT that is not a model output; labels from ``POINT:LABELS``,
  ``LABELS2``, ``LABELS3``… (the first ``POINT:USED`` of them, old files list more).
  Empty labels become ``point_<column>`` and duplicates ``name_2``, ``name_3``… in
  column order; ``meta["renamed_labels"]`` maps each new label to the file's label.
* Missing samples: residual < 0 (the C3D rule) and samples exactly at (0, 0, 0), which
  many exporters write for a missing marker (a real marker exactly on the lab origin to
  float precision does not happen); both are NaN. ``meta["zeros_as_missing"]`` counts
  the (0, 0, 0) samples.
* Model outputs stored as POINTs (labels listed in ``POINT:ANGLES``, ``FORCES``,
  ``MOMENTS``, ``POWERS``, ``SCALARS``, ``REACTIONS`` or in a parameter named by
  ``POINT:TYPE_GROUPS``, plus Plug-in Gait segment axes: four labels ``XO XA XL XP``
  sharing a prefix, group ``"bones"``) go to ``meta["model_outputs"]`` in their own
  units, neither scaled nor rotated.
* Invented samples: files written by skincap mark them with camera mask 0b1111111
  and declare it in ``SKINCAP:INVENTED_CAMERA_MASK``; without that parameter
  ``invented`` is None.
* Everything else, for the writer (``meta["c3d"]``, a
  :class:`~skincap.io.c3d_content.C3dContent`): every parameter group and parameter
  (type, dimensions, values, description, name as written), the analog samples as
  stored and the header's events. Text is UTF-8, or Latin-1 where it is not valid
  UTF-8.

What the writer writes
----------------------
The points from the MarkerSet (POINT's labels, descriptions, units, scale, rate and
frame count rewritten from it, its other parameters kept), and ``meta["c3d"]`` as it
came: analog samples with ``ANALOG`` unchanged (so ``SCALE``, ``OFFSET`` and
``GEN_SCALE`` give the same values), ``FORCE_PLATFORM``, ``EVENT``,
``EVENT_CONTEXT``, header events, vendor groups. Columns added on the same frames
(cleanup's ``U1``…) keep the analogs aligned. When the frame count differs from the
source's, the analog samples cannot be realigned (which frames went is unknown): they
and the force plates are left out with a :class:`SkincapWarning`, never written
misaligned; events (in seconds) and the other groups stay. Refusing would block the
markers, the product asked for, with no way around; the warning names what is lost.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from skincap.errors import (
    FormatError,
    MissingDependencyError,
    SkincapWarning,
    UnitWarning,
    ValidationError,
)
from skincap.io._common import (
    UNIT_TO_METRES,
    atomic_output,
    check_readable,
    from_y_up,
    unit_scale,
    up_rotation,
)
from skincap.io.c3d_checks import check_before_ezc3d
from skincap.io.c3d_content import (
    C3dContent,
    C3dGroup,
    C3dParameter,
    HeaderEvents,
    decode_text,
)
from skincap.io.c3d_encode import C3dFrames, char_parameter, encode_c3d, number_parameter
from skincap.io.narrowing import FLOAT32_MAX, check_float32
from skincap.types import MarkerSet

__all__ = ["read_c3d", "write_c3d", "MODEL_OUTPUT_GROUPS"]

#: POINT parameters that list labels of model outputs, and their units parameter.
MODEL_OUTPUT_GROUPS: dict[str, str] = {
    "ANGLES": "ANGLE_UNITS",
    "FORCES": "FORCE_UNITS",
    "MOMENTS": "MOMENT_UNITS",
    "POWERS": "POWER_UNITS",
    "SCALARS": "SCALAR_UNITS",
    "REACTIONS": "REACTION_UNITS",
}
_BONE_SUFFIXES = ("O", "A", "L", "P")
#: Camera mask (all seven camera bits) marking invented samples in files skincap writes.
_INVENTED_MASK = 0b1111111
_PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_TYPE_SIZES = {-1: 1, 1: 1, 2: 2, 4: 4}


# ------------------------------------------------------------------ structure scan
@dataclass
class _C3dLayout:
    """What the Python scan of a C3D learnt: header words and decoded parameters."""

    processor: str
    n_points: int
    n_analog_per_frame: int
    first_frame: int
    last_frame: int
    scale: float
    data_offset: int
    header_rate: float
    params: dict[tuple[str, str], Any]
    #: every group in file order: NAME -> (name as written, description, locked,
    #: {PARAMETER NAME: record})
    records: dict[str, tuple[str, bytes, bool, dict[str, C3dParameter]]] = field(
        default_factory=dict
    )


def _decode_floats(raw: bytes, processor: str) -> np.ndarray:
    """float32 values stored by ``processor`` -> float64 array."""
    b = np.frombuffer(raw, dtype=np.uint8)
    if processor == "intel":
        return b.view("<f4").astype(np.float64)
    if processor == "mips":
        return b.view(">f4").astype(np.float64)
    # DEC F-float: 16-bit words swapped relative to IEEE, exponent bias 128 vs 127.
    sw = b.reshape(-1, 4)[:, [2, 3, 0, 1]].copy().reshape(-1).view("<f4")
    return sw.astype(np.float64) / 4.0


def _decode_ints(raw: bytes, processor: str, size: int) -> np.ndarray:
    if size == 1:
        return np.frombuffer(raw, dtype=np.int8).astype(np.int64)
    return np.frombuffer(raw, dtype=">i2" if processor == "mips" else "<i2").astype(np.int64)


def _decode_strings(raw: bytes, dims: list[int]) -> list[str]:
    """A CHAR parameter -> list of strings (UTF-8, else Latin-1; trailing blanks and NULs removed)."""
    if not dims:
        return [decode_text(raw)]
    width = dims[0]
    count = math.prod(dims[1:])
    return [decode_text(raw[i * width : (i + 1) * width]) for i in range(count)]


def _intel_bytes(value: Any, ptype: int, raw: bytes) -> bytes:
    """A decoded parameter value back to little-endian bytes (CHAR and BYTE unchanged)."""
    if ptype in (-1, 1):
        return raw
    return np.asarray(value).astype("<f4" if ptype == 4 else "<i2").tobytes()


def _s8(byte: int) -> int:
    """An unsigned byte value read as a signed int8."""
    return byte - 256 if byte > 127 else byte


def _scan_c3d(path: Path, data: bytes) -> _C3dLayout:
    """Validate a C3D's header and parameter section in Python; FormatError on any fault."""
    size = len(data)
    if size < 512:
        raise FormatError(
            path, f"file is {size} bytes, shorter than the 512-byte C3D header", offset=size
        )
    if data[1] != 0x50:
        raise FormatError(
            path, f"not a C3D file: byte 1 is 0x{data[1]:02x}, expected 0x50", offset=1
        )
    pblock = data[0]
    if pblock < 2:
        raise FormatError(path, f"parameter block pointer {pblock} must be >= 2", offset=0)
    start = (pblock - 1) * 512
    if start + 4 > size:
        raise FormatError(
            path,
            f"parameter section at byte {start} lies past the end of the file ({size} bytes)",
            offset=0,
        )
    nblocks = data[start + 2]
    proc_code = data[start + 3]
    if proc_code not in _PROCESSORS:
        raise FormatError(
            path, f"unknown processor type {proc_code} (expected 84, 85 or 86)", offset=start + 3
        )
    processor = _PROCESSORS[proc_code]
    end = start + nblocks * 512
    if nblocks == 0 or end > size:
        raise FormatError(
            path,
            f"parameter section of {nblocks} blocks from byte {start} does not fit in the file ({size} bytes)",
            offset=start + 2,
        )

    ie = ">" if processor == "mips" else "<"
    words = np.frombuffer(data[:24], dtype=f"{ie}u2").astype(np.int64)
    n_points, n_analog = int(words[1]), int(words[2])
    first, last = int(words[3]), int(words[4])
    scale = float(_decode_floats(data[12:16], processor)[0])
    data_block = int(words[8])
    rate = float(_decode_floats(data[20:24], processor)[0])

    groups: dict[int, str] = {}
    group_meta: dict[int, tuple[str, bytes, bool]] = {}
    raw_params: list[tuple[int, str, Any, int, C3dParameter]] = []
    pos = start + 4
    while True:
        if pos + 2 > end:
            raise FormatError(path, "parameter section ends inside a record header", offset=pos)
        nchars = _s8(data[pos])
        gid = _s8(data[pos + 1])
        if nchars == 0:
            break
        nlen = abs(nchars)
        if gid == 0:
            raise FormatError(path, "parameter record with group id 0", offset=pos + 1)
        name_end = pos + 2 + nlen
        if name_end + 2 > end:
            raise FormatError(path, "parameter record runs past the parameter section", offset=pos)
        name_raw = data[pos + 2 : name_end]
        if not all(32 < c < 127 for c in name_raw):
            raise FormatError(
                path, f"parameter name {name_raw!r} is not printable ASCII", offset=pos + 2
            )
        name_as_written = name_raw.decode("ascii")  # kept for writing back (Vicon: "Bodymass")
        name = name_as_written.upper()
        offset_field = name_end
        nxt = int(np.frombuffer(data[offset_field : offset_field + 2], dtype=f"{ie}i2")[0])
        last_record = nxt == 0
        rec_end = end if last_record else offset_field + nxt
        if not last_record and (nxt < 2 or rec_end > end):
            raise FormatError(
                path,
                f"record {name!r}: pointer to the next record ({nxt}) leaves the parameter section",
                offset=offset_field,
            )
        body = offset_field + 2
        if gid < 0:
            if body + 1 > rec_end:
                raise FormatError(path, f"group {name!r}: record too short", offset=body)
            dlen = data[body]
            if body + 1 + dlen > rec_end:
                raise FormatError(
                    path,
                    f"group {name!r}: description of {dlen} bytes overruns its record",
                    offset=body,
                )
            if -gid in groups and groups[-gid] != name:
                raise FormatError(
                    path, f"group id {-gid} defined twice ({groups[-gid]!r}, {name!r})", offset=pos
                )
            groups[-gid] = name
            group_meta[-gid] = (name_as_written, data[body + 1 : body + 1 + dlen], nchars < 0)
        else:
            if body + 2 > rec_end:
                raise FormatError(path, f"parameter {name!r}: record too short", offset=body)
            ptype = _s8(data[body])
            if ptype not in _TYPE_SIZES:
                raise FormatError(
                    path, f"parameter {name!r}: unknown data type {ptype}", offset=body
                )
            ndims = data[body + 1]
            if ndims > 7:
                raise FormatError(
                    path, f"parameter {name!r}: {ndims} dimensions (at most 7)", offset=body + 1
                )
            dims = list(data[body + 2 : body + 2 + ndims])
            vstart = body + 2 + ndims
            nbytes = math.prod(dims) * _TYPE_SIZES[ptype] if ndims else _TYPE_SIZES[ptype]
            if vstart + nbytes + 1 > rec_end:
                raise FormatError(
                    path,
                    f"parameter {name!r}: {nbytes} bytes of values overrun its record",
                    offset=vstart,
                )
            dlen = data[vstart + nbytes]
            if vstart + nbytes + 1 + dlen > rec_end:
                raise FormatError(
                    path,
                    f"parameter {name!r}: description of {dlen} bytes overruns its record",
                    offset=vstart + nbytes,
                )
            raw = data[vstart : vstart + nbytes]
            if ptype == -1:
                value: Any = _decode_strings(raw, dims)
            elif ptype == 4:
                value = _decode_floats(raw, processor)
            else:
                value = _decode_ints(raw, processor, _TYPE_SIZES[ptype])
            record = C3dParameter(
                name=name_as_written,
                type=ptype,
                dims=tuple(int(d) for d in dims),
                raw=_intel_bytes(value, ptype, raw),
                description=data[vstart + nbytes + 1 : vstart + nbytes + 1 + dlen],
                locked=nchars < 0,
            )
            raw_params.append((gid, name, value, pos, record))
        if last_record:
            break
        pos = rec_end

    params: dict[tuple[str, str], Any] = {}
    records: dict[str, tuple[str, bytes, bool, dict[str, C3dParameter]]] = {}
    for gid, gname in groups.items():  # file order; a name defined twice is one group
        records.setdefault(gname, (*group_meta[gid], {}))
    for gid, name, value, where, record in raw_params:
        if gid not in groups:
            raise FormatError(
                path,
                f"parameter {name!r} belongs to group id {gid}, which is not defined",
                offset=where,
            )
        key = (groups[gid], name)
        # a group may appear twice under two ids (Vicon writes PROCESSING so): the
        # later definition of a parameter wins, as in ezc3d
        params[key] = value
        records[groups[gid]][3][name] = record

    used = params.get(("POINT", "USED"))
    if used is not None and (len(used) < 1 or int(used[0]) & 0xFFFF != n_points):
        raise FormatError(
            path,
            f"POINT:USED ({list(used)[:1]}) disagrees with the header's {n_points} points",
            offset=2,
        )
    if data_block < 1:
        raise FormatError(path, f"data start block {data_block} must be >= 1", offset=16)
    data_offset = (data_block - 1) * 512
    if data_offset < start + 4:
        raise FormatError(
            path,
            f"data section (block {data_block}) starts before the parameter section",
            offset=16,
        )
    if data_offset > size:
        raise FormatError(
            path, f"data section (block {data_block}) starts past the end of the file", offset=16
        )
    if n_analog:
        a_used = params.get(("ANALOG", "USED"))
        if a_used is None or len(a_used) < 1 or int(a_used[0]) <= 0 or n_analog % int(a_used[0]):
            raise FormatError(
                path,
                f"header says {n_analog} analog samples per frame but ANALOG:USED is {a_used if a_used is None else list(a_used)}",
                offset=4,
            )
    for key, value in params.items():
        if (
            key[0] in ("POINT", "ANALOG")
            and key[1] in ("RATE", "SCALE")
            and isinstance(value, np.ndarray)
        ):
            if value.size and not np.isfinite(value).all():
                raise FormatError(path, f"{key[0]}:{key[1]} is not finite ({value.tolist()[:3]})")
    if not np.isfinite(scale) or scale == 0:
        scale_p = params.get(("POINT", "SCALE"))
        if scale_p is None or not len(scale_p) or scale_p[0] == 0:
            raise FormatError(path, f"point scale factor {scale} is zero or not finite", offset=12)
        scale = float(scale_p[0])
    return _C3dLayout(
        processor, n_points, n_analog, first, last, scale, data_offset, rate, params, records
    )


# ---------------------------------------------------------------------------- read
def _import_ezc3d() -> Any:
    try:
        import ezc3d  # noqa: F401
        from ezc3d import ezc3d as swig
    except ImportError:  # pragma: no cover - ezc3d is a core dependency
        raise MissingDependencyError("ezc3d", "c3d", "reading and writing C3D files") from None
    return swig


def _labels(layout: _C3dLayout, key: str) -> list[str]:
    """POINT:<key>, <key>2, <key>3… concatenated."""
    out: list[str] = []
    first = layout.params.get(("POINT", key))
    if not isinstance(first, list):
        return out
    out.extend(first)
    k = 2
    while isinstance(layout.params.get(("POINT", f"{key}{k}")), list):
        out.extend(layout.params[("POINT", f"{key}{k}")])
        k += 1
    return out


def _unique_labels(raw: list[str]) -> tuple[list[str], dict[str, str]]:
    """Deterministic unique labels: empty -> point_<i>, repeats -> name_2, name_3…"""
    out: list[str] = []
    renamed: dict[str, str] = {}
    real = set(raw)
    taken: set[str] = set()
    for i, lab in enumerate(raw):
        base = lab if lab else f"point_{i + 1}"
        new = base
        k = 2
        # never take a label already used, nor one a later column really has
        while new in taken or (new != lab and new in real):
            new = f"{base}_{k}"
            k += 1
        if new != lab:
            renamed[new] = lab
        taken.add(new)
        out.append(new)
    return out, renamed


def _up_from_screen(layout: _C3dLayout, path: Path) -> tuple[str, bool]:
    """Source up axis from POINT:Y_SCREEN; (axis, guessed)."""
    ys = layout.params.get(("POINT", "Y_SCREEN"))
    if not isinstance(ys, list) or not ys or not ys[0].strip():
        return "z", True
    val = ys[0].strip().upper().lstrip("+")
    if val in ("Z", "Y"):
        return val.lower(), False
    warnings.warn(
        f"{path}: POINT:Y_SCREEN is {ys[0]!r}; skincap handles Y or Z up only, assuming Z up",
        UnitWarning,
        stacklevel=3,
    )
    return "z", True


def _analog_samples(layout: _C3dLayout, data: bytes, n_frames: int) -> tuple[np.ndarray, int]:
    """Analog samples as stored, (C, n_frames * ratio) float64, and the ratio."""
    n_analog = layout.n_analog_per_frame
    if not n_analog:
        return np.zeros((0, 0)), 0
    used = layout.params.get(("ANALOG", "USED"))
    channels = int(used[0])  # the scan checked it divides n_analog
    ratio = n_analog // channels
    words = 4 * layout.n_points + n_analog
    is_float = layout.scale < 0
    size = 4 if is_float else 2
    block = data[layout.data_offset : layout.data_offset + n_frames * words * size]
    if is_float:
        with np.errstate(invalid="ignore"):  # NaN samples are carried as they are
            flat = _decode_floats(block, layout.processor)
    else:
        fmt = layout.params.get(("ANALOG", "FORMAT"))
        unsigned = isinstance(fmt, list) and bool(fmt) and fmt[0].strip().upper() == "UNSIGNED"
        ie = ">" if layout.processor == "mips" else "<"
        flat = np.frombuffer(block, dtype=f"{ie}{'u2' if unsigned else 'i2'}").astype(np.float64)
    frames = flat.reshape(n_frames, words)[:, 4 * layout.n_points :]  # (T, ratio * C)
    # each frame holds `ratio` sub-frames of every channel: -> (C, T * ratio)
    samples = frames.reshape(n_frames, ratio, channels).transpose(2, 0, 1)
    return samples.reshape(channels, n_frames * ratio), ratio


def _header_events(layout: _C3dLayout, data: bytes) -> HeaderEvents | None:
    """The header's event block (bytes 294-467), or None when it holds no event."""
    ie = ">" if layout.processor == "mips" else "<"
    w = np.frombuffer(data[294:302], dtype=f"{ie}u2").astype(np.int64)
    count = int(w[3])
    if not 0 < count <= 18:
        return None
    return HeaderEvents(
        count=count,
        times=_decode_floats(data[304:376], layout.processor),
        display=bytes(data[376:394]),
        labels=bytes(data[396:468]),
        label_range_present=int(w[0]),
        label_range_block=int(w[1]),
    )


def _content(layout: _C3dLayout, data: bytes, n_frames: int) -> C3dContent:
    """meta["c3d"]: the file's parameters, analog samples and header events."""
    analogs, ratio = _analog_samples(layout, data, n_frames)
    groups = tuple(
        C3dGroup(name=name, description=desc, locked=locked, parameters=tuple(params.values()))
        for name, desc, locked, params in layout.records.values()
    )
    return C3dContent(
        groups=groups,
        analogs=analogs,
        analog_ratio=ratio,
        n_frames=n_frames,
        first_frame=layout.first_frame,
        events=_header_events(layout, data),
        processor=layout.processor,
    )


def _guess_units(xyz: np.ndarray) -> str:
    """'m' when every coordinate (NaN ignored) is within 20 units of the origin, else 'mm'."""
    if xyz.size == 0:
        return "mm"
    biggest = float(np.fmax.reduce(np.abs(xyz).ravel()))  # NaN only when all are NaN
    return "m" if biggest < 20.0 else "mm"


def read_c3d(path: str | os.PathLike[str], *, up: Literal["auto", "y", "z"] = "auto") -> MarkerSet:
    """Read the labelled marker trajectories of a C3D file.

    Parameters
    ----------
    path : str or PathLike
        The ``.c3d`` file (Intel, DEC or MIPS; integer or float data).
    up : {"auto", "y", "z"}
        The file's up axis. ``"auto"`` reads ``POINT:Y_SCREEN`` (``"+Z"`` means Z up,
        ``"+Y"`` Y up) and assumes Z up when it is absent (``meta["up_guessed"]``).

    Returns
    -------
    MarkerSet
        ``positions`` (T, N, 3) float64 metres, Y up, NaN where missing (residual < 0
        or exactly (0, 0, 0)); ``residuals`` (T, N) float64 metres, NaN where missing;
        ``invented`` (T, N) bool for files written by skincap with invented samples,
        else None; ``rate`` the exact POINT:RATE (the float32 in the file printed at
        its shortest round-trip precision, so 59.94 stays 59.94). ``meta`` holds
        ``source_units``, ``up``, ``first_frame`` (the header's own frame number),
        ``model_outputs`` ({group: {label: (T, 3) float64}} in the file's units,
        NaN where missing), ``model_output_units``, ``descriptions``,
        ``renamed_labels``, ``zeros_as_missing``, ``point_scale``, ``screen_axes``.

    Raises
    ------
    FormatError
        Missing, truncated, corrupted or inconsistent file (with the byte offset).

    Warns
    -----
    UnitWarning
        ``POINT:UNITS`` empty or unknown: the unit is guessed (mm unless every
        coordinate is within 20 units of the origin, then m).
    """
    p = check_readable(path)
    if up not in ("auto", "y", "z"):
        raise ValidationError(f"up: expected 'auto', 'y' or 'z', got {up!r}")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise FormatError(p, f"cannot read: {exc.strerror}") from None
    check_before_ezc3d(p, data)
    layout = _scan_c3d(p, data)
    swig = _import_ezc3d()
    try:
        c3d = swig.c3d(str(p), swig.Options(False, False))
        points = c3d.get_points()
        residuals = c3d.get_point_residuals()
        n_frames = int(c3d.header().nbFrames())
        rate_ez = float(c3d.header().frameRate())
    except (RuntimeError, OSError, ValueError, IndexError, MemoryError, TypeError) as exc:
        raise FormatError(p, f"ezc3d could not read the file: {exc}") from None
    word = 4 if layout.scale < 0 else 2
    frame_bytes = (4 * layout.n_points + layout.n_analog_per_frame) * word
    # ezc3d stops quietly at the end of a truncated file: hold it to the header's count
    declared = max(n_frames, layout.last_frame - layout.first_frame + 1)
    need = layout.data_offset + declared * frame_bytes
    if need > len(data):
        raise FormatError(
            p,
            f"truncated: {declared} frames of {frame_bytes} bytes from byte {layout.data_offset} need {need} bytes, the file has {len(data)}",
            offset=len(data),
        )
    n = layout.n_points
    if points.shape != (4, n, n_frames) or residuals.shape != (1, n, n_frames):
        raise FormatError(
            p, f"ezc3d returned points of shape {points.shape}, expected (4, {n}, {n_frames})"
        )

    raw_labels = _labels(layout, "LABELS")
    if len(raw_labels) < n:
        raw_labels = raw_labels + [""] * (n - len(raw_labels))
    raw_labels = [s.strip() for s in raw_labels[:n]]
    descriptions = _labels(layout, "DESCRIPTIONS")
    descriptions = (descriptions + [""] * n)[:n]

    # work on ezc3d's (component, N, T) planes; one transposed copy at the end
    xyz = points[:3]  # (3, N, T) file units, view
    res_nt = residuals[0]  # (N, T)
    if np.isinf(xyz).any():
        raise FormatError(p, "point data contains infinite coordinates")
    nan_nt = np.isnan(xyz[0]) | np.isnan(xyz[1]) | np.isnan(xyz[2])
    neg_nt = res_nt < 0
    zero_nt = (xyz[0] == 0.0) & (xyz[1] == 0.0) & (xyz[2] == 0.0)
    invalid_nt = nan_nt | neg_nt  # the C3D rule
    missing_nt = invalid_nt | zero_nt  # plus exporters' (0, 0, 0)
    n_zero = int((zero_nt & ~invalid_nt).sum())

    # model outputs -------------------------------------------------------------
    label_index = {lab: i for i, lab in enumerate(raw_labels) if lab}
    group_names = list(MODEL_OUTPUT_GROUPS)
    tg = layout.params.get(("POINT", "TYPE_GROUPS"))
    if isinstance(tg, list):
        for g in tg:
            g = g.strip().upper()
            if g and g not in group_names and isinstance(layout.params.get(("POINT", g)), list):
                group_names.append(g)
    output_cols: dict[str, list[int]] = {}
    taken: set[int] = set()
    for g in group_names:
        listed = _labels(layout, g)
        if not listed:
            continue
        cols = [
            label_index[s.strip()]
            for s in listed
            if s.strip() in label_index and label_index[s.strip()] not in taken
        ]
        if cols:
            output_cols[g.lower()] = cols
            taken.update(cols)
    bone_cols = []
    for i, lab in enumerate(raw_labels):
        if i in taken or len(lab) < 2 or lab.startswith("*") or lab[-1] != "O":
            continue
        quad = [label_index.get(lab[:-1] + s) for s in _BONE_SUFFIXES]
        if all(q is not None and q not in taken for q in quad):
            bone_cols.extend(quad)  # type: ignore[arg-type]
    if bone_cols:
        output_cols["bones"] = bone_cols
        taken.update(bone_cols)

    units_raw = layout.params.get(("POINT", "UNITS"))
    units_str = units_raw[0].strip().lower() if isinstance(units_raw, list) and units_raw else ""
    marker_cols = np.array([i for i in range(n) if i not in taken], dtype=np.int64)
    all_markers = marker_cols.size == n
    m_xyz = xyz if all_markers else xyz[:, marker_cols]  # (3, N', T)
    m_miss = missing_nt if all_markers else missing_nt[marker_cols]  # (N', T)
    units_guessed = units_str not in UNIT_TO_METRES
    if units_guessed:
        guess = _guess_units(m_xyz)
        what = "empty" if not units_str else f"{units_str!r}, not a known length unit"
        warnings.warn(f"{p}: POINT:UNITS is {what}; guessing {guess!r}", UnitWarning, stacklevel=2)
        units_str = guess
    scale = unit_scale(units_str)

    up_src, up_guessed = _up_from_screen(layout, p) if up == "auto" else (up, False)

    model_outputs: dict[str, dict[str, np.ndarray]] = {}
    model_units: dict[str, str] = {}
    for g, cols in output_cols.items():
        arr = np.ascontiguousarray(xyz[:, cols].transpose(2, 1, 0))  # (T, k, 3)
        arr[invalid_nt[cols].T] = np.nan
        model_outputs[g] = {raw_labels[c]: arr[:, k] for k, c in enumerate(cols)}
        unit_param = MODEL_OUTPUT_GROUPS.get(g.upper(), g.upper().rstrip("S") + "_UNITS")
        u = layout.params.get(("POINT", unit_param))
        if g == "bones":
            model_units[g] = units_str
        elif isinstance(u, list) and u and u[0].strip():
            model_units[g] = u[0].strip()

    t_n, n_m = n_frames, int(marker_cols.size)
    rot = up_rotation(up_src)  # each row picks one source axis, with a sign
    mpos = np.zeros((t_n, n_m, 3))  # (T, N', 3) metres, Y up
    for k in range(3):  # three coordinates, not a loop over data
        axis = int(np.argmax(np.abs(rot[k])))
        np.multiply(m_xyz[axis].T, rot[k, axis] * scale, out=mpos[..., k])
    mmiss = m_miss.T  # (T, N')
    mpos[mmiss] = np.nan
    mres = np.zeros((t_n, n_m))
    np.multiply((res_nt if all_markers else res_nt[marker_cols]).T, scale, out=mres)
    mres[mmiss] = np.nan
    labels, renamed = _unique_labels([raw_labels[i] for i in marker_cols])

    invented = None
    sk = layout.params.get(("SKINCAP", "INVENTED_CAMERA_MASK"))
    if sk is not None and len(sk) >= 1:
        try:
            masks = c3d.get_point_camera_masks()  # (7, N, T) bool
        except (RuntimeError, ValueError) as exc:
            raise FormatError(p, f"ezc3d could not read the camera masks: {exc}") from None
        bits = (masks.astype(np.int64) << np.arange(7)[:, None, None]).sum(axis=0).T  # (T, N)
        invented = (bits[:, marker_cols] == int(round(float(sk[0])))) & ~mmiss

    rate_p = layout.params.get(("POINT", "RATE"))
    rate32 = (
        float(rate_p[0])
        if isinstance(rate_p, np.ndarray) and rate_p.size and rate_p[0] > 0
        else rate_ez
    )
    if not (np.isfinite(rate32) and rate32 > 0):
        raise FormatError(p, f"frame rate {rate32} is not a positive number", offset=20)
    rate = float(str(np.float32(rate32)))

    xs = layout.params.get(("POINT", "X_SCREEN"))
    ys = layout.params.get(("POINT", "Y_SCREEN"))
    meta: dict[str, Any] = {
        "source_format": "c3d",
        "source_path": str(p),
        "source_units": units_str,
        "units_guessed": units_guessed,
        "up": up_src,
        "up_guessed": up_guessed,
        "first_frame": int(layout.first_frame),
        "point_scale": abs(float(layout.scale)),
        "model_outputs": model_outputs,
        "model_output_units": model_units,
        "descriptions": [descriptions[i] for i in marker_cols],
        "renamed_labels": renamed,
        "zeros_as_missing": n_zero,
        "c3d": _content(layout, data, n_frames),
    }
    if isinstance(xs, list) and xs and isinstance(ys, list) and ys:
        meta["screen_axes"] = (xs[0].strip(), ys[0].strip())
    return MarkerSet(
        positions=mpos,
        labels=labels,
        rate=rate,
        residuals=mres,
        invented=invented,
        meta=meta,
    )


# --------------------------------------------------------------------------- write
def write_c3d(
    markers: MarkerSet,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    units: str | None = None,
    up: Literal["y", "z"] | None = None,
) -> None:
    """Write a MarkerSet (its model outputs and ``meta["c3d"]``) as a float C3D.

    Parameters
    ----------
    markers : MarkerSet
        ``positions`` (T, N, 3) metres Y up; NaN samples are written as (0, 0, 0)
        with residual -1 (the C3D "invalid" mark; ezc3d and other readers return
        them as missing). ``residuals`` (T, N) metres are written back (0 where
        None); they are stored as a byte times ``POINT:SCALE`` so they are quantised
        to ``meta["point_scale"]`` (the source file's, when the residuals fit in its
        255 steps) or else to the smallest power of ten (file units) whose 255 steps
        hold the largest residual.
        ``invented`` samples get camera mask 0b1111111, declared in
        ``SKINCAP:INVENTED_CAMERA_MASK``. ``meta["model_outputs"]`` groups are
        written as extra POINTs listed in ``POINT:<GROUP>`` and ``POINT:TYPE_GROUPS``.
        Labels beyond 255 go to ``POINT:LABELS2``, ``LABELS3``…, and
        ``meta["descriptions"]`` to ``DESCRIPTIONS``, ``DESCRIPTIONS2``…; text is
        UTF-8. ``meta["c3d"]`` (from :func:`read_c3d`) is written back as the
        module docstring says: analogs kept when the frame count is the source's,
        else left out with a SkincapWarning.
    path : str or PathLike
        Output file; refused if it exists unless ``force``.
    units : str, optional
        Length unit of the file; default ``meta["source_units"]`` or ``"mm"``.
    up : {"y", "z"}, optional
        Up axis of the file; default ``meta["up"]`` or ``"z"``.

    Raises
    ------
    OutputExistsError, ValidationError
    FormatError
        A value the file cannot hold (a coordinate beyond float32, a label over 255
        bytes), naming the value and where it is; nothing is written.

    Warns
    -----
    SkincapWarning
        The source's analog channels (and force plates) are left out because the
        frame count changed.
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    meta = markers.meta
    units = str(units if units is not None else meta.get("source_units", "mm"))
    scale = unit_scale(units)
    up = str(up if up is not None else meta.get("up", "z")).lower()
    if up not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up!r}")
    t, n = markers.n_frames, markers.n_markers
    if t == 0:
        raise ValidationError("markers: a C3D needs at least one frame")

    pos = from_y_up(markers.positions, up) / scale  # (T, N, 3) file units
    miss = markers.missing
    res = np.zeros((t, n)) if markers.residuals is None else markers.residuals / scale
    res = np.where(np.isnan(res), 0.0, res)
    if (res < 0).any():
        raise ValidationError("markers.residuals: must be >= 0 (NaN allowed) where present")

    labels = list(markers.labels)
    out_pos = [pos]
    out_miss = [miss]
    out_res = [res]
    groups: dict[str, list[str]] = {}
    model_outputs = meta.get("model_outputs") or {}
    model_units = dict(meta.get("model_output_units") or {})
    for g, series in model_outputs.items():
        if not series:
            continue
        gname = str(g).upper()
        names = [str(k) for k in series]
        arr = np.stack([np.asarray(v, dtype=np.float64) for v in series.values()], axis=1)
        if arr.shape != (t, len(names), 3):
            raise ValidationError(
                f"meta['model_outputs'][{g!r}]: expected arrays of shape ({t}, 3), got {arr.shape[::2]}"
            )
        gu = model_units.get(g)
        if gu in UNIT_TO_METRES and gu != units:
            arr = arr * (UNIT_TO_METRES[gu] / scale)
            model_units[g] = units
        clash = set(names) & set(labels)
        if clash:
            raise ValidationError(
                f"meta['model_outputs'][{g!r}]: labels {sorted(clash)[:5]} are also marker labels"
            )
        labels.extend(names)
        m = np.isnan(arr).any(axis=2)
        out_pos.append(arr)
        out_miss.append(m)
        out_res.append(np.zeros((t, len(names))))
        groups[gname] = names
    all_pos = np.concatenate(out_pos, axis=1)
    all_miss = np.concatenate(out_miss, axis=1)
    all_res = np.concatenate(out_res, axis=1)
    all_pos[all_miss] = 0.0
    finite_res = all_res[~all_miss]
    rmax = float(finite_res.max()) if finite_res.size else 0.0
    pscale = float(meta.get("point_scale", 0.0) or 0.0)
    if not (np.isfinite(pscale) and pscale > 0 and rmax <= 255 * pscale * (1 + 1e-6)):
        # the smallest power of ten whose 255 steps hold the largest residual
        pscale = 10.0 ** np.ceil(np.log10(rmax / 255.0)) if rmax > 0 else 1.0
    # stored as a byte k with residual = k * |SCALE|
    steps = np.clip(np.round(all_res / pscale), 0, 255).astype(np.int64)
    total = len(labels)
    target = Path(path)
    where_names = labels

    def where(idx: tuple[int, ...]) -> str:
        return f"point {where_names[idx[1]]!r}, frame {idx[0]}, {'xyz'[idx[2]]}"

    check_float32(np.where(all_miss[..., None], 0.0, all_pos), target, where, unit=units)
    if not (np.isfinite(markers.rate) and 0 < markers.rate <= FLOAT32_MAX):
        raise FormatError(target, f"frame rate {markers.rate} cannot be stored as a float32")
    first = int(meta.get("first_frame", 1))
    if first < 0 or first > 65535:
        raise ValidationError(f"meta['first_frame']: must be in 0..65535, got {first}")

    content = meta.get("c3d")
    if not isinstance(content, C3dContent):
        content = None
    keep_analogs = content is not None and content.n_frames == t
    if content is not None and not keep_analogs and content.n_analog_channels:
        fp = content.n_force_plates()
        warnings.warn(
            f"{target}: the markers have {t} frames, the source's {content.n_analog_channels} "
            f"analog channels were aligned with {content.n_frames}: analog data"
            f"{f' and {fp} force plates' if fp else ''} not written (they cannot be "
            "realigned with frames that changed)",
            SkincapWarning,
            stacklevel=2,
        )
    if keep_analogs and content is not None:
        analogs, ratio = content.analogs, content.analog_ratio
    else:
        analogs, ratio = np.zeros((0, 0)), 0

    def num(name: str, values: Any, kind: str, scalar: bool | None = None) -> C3dParameter:
        return number_parameter(name, values, kind, target=target, scalar=scalar)

    def text(name: str, values: str | list[str]) -> C3dParameter:
        return char_parameter(name, values, target=target)

    def chunked(name: str, values: list[str]) -> list[C3dParameter]:
        """LABELS, LABELS2, LABELS3… of at most 255 strings each."""
        out = [text(name, values[:255])]
        for k in range(255, len(values), 255):
            out.append(text(f"{name}{k // 255 + 1}", values[k : k + 255]))
        return out

    # --- POINT: what describes the points is written from the MarkerSet
    point: list[C3dParameter] = [
        num("USED", total, "int"),
        # int16 read as unsigned by ezc3d up to 65535; beyond, -1 and the header decide
        num("FRAMES", t if t <= 65535 else -1, "int"),
        num("DATA_START", 0, "int"),
        num("SCALE", -pscale, "float"),
        num("RATE", float(markers.rate), "float"),
        text("UNITS", units),
    ]
    point += chunked("LABELS", labels)
    descriptions = meta.get("descriptions")
    if not (isinstance(descriptions, list) and len(descriptions) == n):
        # columns added, removed or reordered: the source's descriptions by label
        by_label = _source_descriptions(content) if content is not None else {}
        descriptions = [by_label.get(lab, "") for lab in markers.labels]
    point += chunked("DESCRIPTIONS", [str(d) for d in descriptions] + [""] * (total - n))
    screen = meta.get("screen_axes")
    if not (
        isinstance(screen, tuple | list)
        and len(screen) == 2
        and str(screen[1]).upper().lstrip("+") == up.upper()
    ):
        screen = ("+X", "+Z" if up == "z" else "+Y")
    point += [text("X_SCREEN", str(screen[0])), text("Y_SCREEN", str(screen[1]))]
    source_groups = list(content.groups) if content is not None else []
    source_point = next((g for g in source_groups if g.name.upper() == "POINT"), None)
    if source_point is not None and source_point.get("BONES") is None:
        # segment axes the reader recognised by their labels: the source did not list
        # them, and the reader recognises them again without the list
        groups.pop("BONES", None)
    type_groups: list[str] = []
    for gname, names in groups.items():
        point += chunked(gname, names)  # ANGLES, ANGLES2… like LABELS
        type_groups.extend([gname, gname[:-1] if gname.endswith("S") else gname])
        unit_param = MODEL_OUTPUT_GROUPS.get(gname, gname.rstrip("S") + "_UNITS")
        gu = model_units.get(gname.lower())
        if gu and gname != "BONES":
            point.append(text(unit_param, str(gu)))
    if type_groups:
        point.append(text("TYPE_GROUPS", type_groups))
    if source_point is not None:
        point = [_like_source(p, source_point.get(p.name)) for p in point]
        tg = source_point.get("TYPE_GROUPS")
        if tg is not None and tg.type == -1:
            listed = {str(v).strip().upper() for v in tg.value}
            if set(type_groups) <= listed:  # the source's list still holds: keep it as it is
                point = [p for p in point if p.name != "TYPE_GROUPS"] + [tg]
    written = {p.name for p in point}

    def rewritten(name: str) -> bool:
        """A POINT parameter of the source that the MarkerSet's points replace."""
        name = name.upper()
        if name in written or name in ("LONG_FRAMES", "TYPE_GROUPS"):
            return True
        listing = {"LABELS", "DESCRIPTIONS", *MODEL_OUTPUT_GROUPS, *groups}
        listing |= {g.rstrip("S") + "_UNITS" for g in groups} | set(MODEL_OUTPUT_GROUPS.values())
        return name.rstrip("0123456789") in listing

    out_groups: list[C3dGroup] = []
    seen: set[str] = set()
    for g in source_groups:
        key = g.name.upper()
        seen.add(key)
        if key == "POINT":
            kept = tuple(p for p in g.parameters if not rewritten(p.name))
            out_groups.append(replace(g, parameters=tuple(point) + kept))
        elif key == "ANALOG" and not keep_analogs:
            out_groups.append(replace(g, parameters=_no_analogs(num, text)))
        elif key == "FORCE_PLATFORM" and not keep_analogs:
            out_groups.append(replace(g, parameters=(num("USED", 0, "int"),)))
        elif key == "TRIAL" and not keep_analogs:
            # frame numbers of another frame count
            kept = tuple(p for p in g.parameters if not p.name.upper().startswith("ACTUAL_"))
            out_groups.append(replace(g, parameters=kept))
        elif key == "ROTATION":
            # rotation samples are not read: their group (and its DATA_START, a block
            # of the source) would point at nothing in this file
            used = g.get("USED")
            if used is not None and used.type in (1, 2) and np.any(np.asarray(used.value) > 0):
                warnings.warn(
                    f"{target}: the source's ROTATION data (segment rotations) is not written",
                    SkincapWarning,
                    stacklevel=2,
                )
        elif key == "SKINCAP":
            kept = tuple(p for p in g.parameters if p.name.upper() != "INVENTED_CAMERA_MASK")
            if kept:
                out_groups.append(replace(g, parameters=kept))
        else:
            out_groups.append(g)
    if "POINT" not in seen:
        out_groups.insert(0, C3dGroup("POINT", parameters=tuple(point)))
    if "ANALOG" not in seen:
        out_groups.append(C3dGroup("ANALOG", parameters=_no_analogs(num, text)))
    if "FORCE_PLATFORM" not in seen:
        out_groups.append(C3dGroup("FORCE_PLATFORM", parameters=(num("USED", 0, "int"),)))
    masks = np.zeros((t, total), dtype=np.int64)
    if markers.invented is not None:
        masks[:, :n] = np.where(markers.invented & ~miss, _INVENTED_MASK, 0)
        mask_param = num("INVENTED_CAMERA_MASK", _INVENTED_MASK, "int")
        for k, g in enumerate(out_groups):
            if g.name.upper() == "SKINCAP":
                out_groups[k] = replace(g, parameters=g.parameters + (mask_param,))
                break
        else:
            out_groups.append(C3dGroup("SKINCAP", parameters=(mask_param,)))

    frames = C3dFrames(
        xyz=all_pos,
        invalid=all_miss,
        residual_steps=steps,
        camera_masks=masks,
        analogs=analogs,
        ratio=ratio,
    )
    payload = encode_c3d(
        out_groups,
        frames,
        first_frame=first,
        rate=float(markers.rate),
        point_scale=pscale,
        events=content.events if content is not None else None,
        target=target,
    )
    with atomic_output(target, force=force) as tmp:
        tmp.write_bytes(payload)


def _source_descriptions(content: C3dContent) -> dict[str, str]:
    """The source file's POINT descriptions by label."""

    def listed(name: str) -> list[str]:
        out: list[str] = []
        k = 1
        while (p := content.parameter("POINT", name + (str(k) if k > 1 else ""))) is not None:
            if p.type != -1:
                break
            out.extend(p.value)  # type: ignore[arg-type]
            k += 1
        return out

    return {lab: d for lab, d in zip(listed("LABELS"), listed("DESCRIPTIONS"), strict=False) if lab}


def _like_source(new: C3dParameter, old: C3dParameter | None) -> C3dParameter:
    """The source's record when it holds the same values; else ``new`` with its description."""
    if old is None or old.name.upper() == "DATA_START":
        return new
    if old.type == new.type and old.value_equals(new):
        return old
    return replace(new, description=old.description, locked=old.locked)


def _no_analogs(num: Any, text: Any) -> tuple[C3dParameter, ...]:
    """An ANALOG group with no channel."""
    return (
        num("USED", 0, "int"),
        num("RATE", 0.0, "float"),
        num("GEN_SCALE", 1.0, "float"),
        num("SCALE", np.zeros(0), "float", False),
        num("OFFSET", np.zeros(0, dtype=np.int64), "int", False),
        text("LABELS", []),
        text("DESCRIPTIONS", []),
        text("UNITS", []),
    )
