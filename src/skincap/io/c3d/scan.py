"""The Python scan of a C3D file's structure (header, parameter records), before ezc3d.

Also the conventions the reader and the writer share: model-output groups and the
camera mask of invented samples.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import (
    FormatError,
    SkincapWarning,
)
from skincap.io.c3d.content import (
    C3dParameter,
    decode_text,
)

#: POINT parameters that list labels of model outputs, and their units parameter.
MODEL_OUTPUT_GROUPS: dict[str, str] = {
    "ANGLES": "ANGLE_UNITS",
    "FORCES": "FORCE_UNITS",
    "MOMENTS": "MOMENT_UNITS",
    "POWERS": "POWER_UNITS",
    "SCALARS": "SCALAR_UNITS",
    "REACTIONS": "REACTION_UNITS",
}
BONE_SUFFIXES = ("O", "A", "L", "P")
#: Camera mask (all seven camera bits) marking invented samples in files skincap writes.
INVENTED_MASK = 0b1111111
_PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_TYPE_SIZES = {-1: 1, 1: 1, 2: 2, 4: 4}


# ------------------------------------------------------------------ structure scan
@dataclass
class C3dLayout:
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


def decode_floats(raw: bytes, processor: str) -> np.ndarray:
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


def scan_c3d(path: Path, data: bytes) -> C3dLayout:
    """Validate a C3D's header and parameter section in Python; FormatError on any fault."""
    start, end, processor = _parameter_section(path, data)
    ie = ">" if processor == "mips" else "<"
    words = np.frombuffer(data[:24], dtype=f"{ie}u2").astype(np.int64)
    n_points, n_analog = int(words[1]), int(words[2])
    first, last = int(words[3]), int(words[4])
    scale = float(decode_floats(data[12:16], processor)[0])
    data_block = int(words[8])
    rate = float(decode_floats(data[20:24], processor)[0])

    groups, group_meta, raw_params = _read_records(path, data, start, end, processor)
    params, records = _index_parameters(path, groups, group_meta, raw_params)
    data_offset = _check_parameters(path, data, params, n_points, n_analog, data_block, start)
    if not np.isfinite(scale) or scale == 0:
        scale_p = params.get(("POINT", "SCALE"))
        if scale_p is None or not len(scale_p) or scale_p[0] == 0:
            raise FormatError(path, f"point scale factor {scale} is zero or not finite", offset=12)
        scale = float(scale_p[0])
    n_analog = _analog_words_per_frame(
        params, len(data) - data_offset, n_points, n_analog, last - first + 1, scale, rate
    )
    return C3dLayout(
        processor, n_points, n_analog, first, last, scale, data_offset, rate, params, records
    )


def _analog_words_per_frame(
    params: dict[tuple[str, str], Any],
    data_bytes: int,
    n_points: int,
    n_analog_header: int,
    n_frames: int,
    scale: float,
    header_rate: float,
) -> int:
    """Analog samples stored per frame: the header's word, unless ANALOG:USED x the
    subframes ANALOG:RATE / POINT:RATE give another count and only that one fills the
    ``data_bytes`` after the data start with ``n_frames`` frames (to the last block).

    The MotionMonitor's header says 16 where its 16 channels at 980 Hz against 140 Hz
    store 112 (c3d.org sample24); BTS writes the header's count and no ANALOG:RATE.
    """

    def first(key: tuple[str, str]) -> float:
        v = params.get(key)
        return float(v[0]) if isinstance(v, np.ndarray) and v.size else 0.0

    used, analog_rate = first(("ANALOG", "USED")), first(("ANALOG", "RATE"))
    point_rate = first(("POINT", "RATE")) or header_rate
    if not (used > 0 and analog_rate > 0 and point_rate > 0 and n_frames > 0):
        return n_analog_header
    from_rates = int(used) * int(round(analog_rate / point_rate))
    word = 4 if scale < 0 else 2

    def fills(per_frame: int) -> bool:
        need = n_frames * (4 * n_points + per_frame) * word
        return need <= data_bytes < need + 512

    if from_rates != n_analog_header and fills(from_rates) and not fills(n_analog_header):
        return from_rates
    return n_analog_header


def _parameter_section(path: Path, data: bytes) -> tuple[int, int, str]:
    """(first byte, end byte, processor) of the parameter section the header points at."""
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
    # some writers declare fewer blocks than their records fill (Peak Performance);
    # the records may run on to where the header says the data starts, as ezc3d reads
    data_block = int.from_bytes(data[16:18], "big" if processor == "mips" else "little")
    data_start = (data_block - 1) * 512
    if end < data_start <= size:
        end = data_start
    return start, end, processor


_RawParameter = tuple[int, str, Any, int, C3dParameter]  # (group id, NAME, value, byte, record)


def _read_records(
    path: Path, data: bytes, start: int, end: int, processor: str
) -> tuple[dict[int, str], dict[int, tuple[str, bytes, bool]], list[_RawParameter]]:
    """Walk the records of bytes ``start``..``end``: group names and (name as written,
    description, locked) by group id, and the parameters in file order."""
    ie = ">" if processor == "mips" else "<"
    groups: dict[int, str] = {}
    group_meta: dict[int, tuple[str, bytes, bool]] = {}
    raw_params: list[_RawParameter] = []
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
        # printable ASCII; Vicon's PROCESSING group names hold spaces ("Pelvis Width")
        if not all(32 <= c < 127 for c in name_raw):
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
            description = _group_description(path, data, name, body, rec_end)
            if -gid in groups and groups[-gid] != name:
                raise FormatError(
                    path, f"group id {-gid} defined twice ({groups[-gid]!r}, {name!r})", offset=pos
                )
            groups[-gid] = name
            group_meta[-gid] = (name_as_written, description, nchars < 0)
        else:
            value, record = _parameter_record(
                path, data, name_as_written, nchars < 0, body, rec_end, processor
            )
            raw_params.append((gid, name, value, pos, record))
        if last_record:
            break
        pos = rec_end
    return groups, group_meta, raw_params


def _group_description(path: Path, data: bytes, name: str, body: int, rec_end: int) -> bytes:
    """The description bytes of the group record whose body spans ``body``..``rec_end``."""
    if body + 1 > rec_end:
        raise FormatError(path, f"group {name!r}: record too short", offset=body)
    dlen = data[body]
    if body + 1 + dlen > rec_end:
        raise FormatError(
            path,
            f"group {name!r}: description of {dlen} bytes overruns its record",
            offset=body,
        )
    return data[body + 1 : body + 1 + dlen]


def _parameter_record(
    path: Path,
    data: bytes,
    name_as_written: str,
    locked: bool,
    body: int,
    rec_end: int,
    processor: str,
) -> tuple[Any, C3dParameter]:
    """The decoded value (list of str, or int64/float64 array) and the record of the
    parameter whose body spans ``body``..``rec_end``."""
    name = name_as_written.upper()
    if body + 2 > rec_end:
        raise FormatError(path, f"parameter {name!r}: record too short", offset=body)
    ptype = _s8(data[body])
    if ptype not in _TYPE_SIZES:
        raise FormatError(path, f"parameter {name!r}: unknown data type {ptype}", offset=body)
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
        value = decode_floats(raw, processor)
    else:
        value = _decode_ints(raw, processor, _TYPE_SIZES[ptype])
    record = C3dParameter(
        name=name_as_written,
        type=ptype,
        dims=tuple(int(d) for d in dims),
        raw=_intel_bytes(value, ptype, raw),
        description=data[vstart + nbytes + 1 : vstart + nbytes + 1 + dlen],
        locked=locked,
    )
    return value, record


def _index_parameters(
    path: Path,
    groups: dict[int, str],
    group_meta: dict[int, tuple[str, bytes, bool]],
    raw_params: list[_RawParameter],
) -> tuple[dict[tuple[str, str], Any], dict[str, tuple[str, bytes, bool, dict[str, C3dParameter]]]]:
    """Values by (GROUP, NAME) and the records by group (C3dLayout.records), in file order.

    A parameter of an undefined group (Vicon's c3d.org sample10 has ``IS_STATIC`` in
    group 7 and no group 7) has no group to be found or written in: it is left out with
    a SkincapWarning naming it, as ezc3d leaves it in a nameless group.
    """
    params: dict[tuple[str, str], Any] = {}
    records: dict[str, tuple[str, bytes, bool, dict[str, C3dParameter]]] = {}
    for gid, gname in groups.items():  # file order; a name defined twice is one group
        records.setdefault(gname, (*group_meta[gid], {}))
    orphans = [(gid, name, where) for gid, name, _, where, _ in raw_params if gid not in groups]
    if orphans:
        names = ", ".join(name for _, name, _ in orphans[:5]) + (
            ", ..." if len(orphans) > 5 else ""
        )
        ids = sorted({gid for gid, _, _ in orphans})
        warnings.warn(
            f"{path}: byte {orphans[0][2]}: {len(orphans)} parameters of group id "
            f"{', '.join(map(str, ids))}, which the file does not define, left out ({names})",
            SkincapWarning,
            stacklevel=4,
        )
    for gid, name, value, _where, record in raw_params:
        if gid not in groups:
            continue
        key = (groups[gid], name)
        # a group may appear twice under two ids (Vicon writes PROCESSING so): the
        # later definition of a parameter wins, as in ezc3d
        params[key] = value
        records[groups[gid]][3][name] = record
    return params, records


def _check_parameters(
    path: Path,
    data: bytes,
    params: dict[tuple[str, str], Any],
    n_points: int,
    n_analog: int,
    data_block: int,
    start: int,
) -> int:
    """The data section's byte offset, once the parameters agree with the header words
    (point and analog counts, data start block) and the rates and scales are finite."""
    size = len(data)
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
    return data_offset
