"""Checks that a C3D file is safe to hand to ezc3d, done in Python before ezc3d opens it.

ezc3d (1.5-1.7) trusts the file: a parameter with no value is read at index 0 (a
NULL dereference: segfault), a CHAR parameter with no dimensions or a parameter with a
negative dimension count crashes its parameter reader, a negative description length
asks for 4 GiB, and the data reader allocates one object per declared sample before it
notices the end of the file (``ANALOG:RATE = 1e9`` meant 8 million analog subframes
per frame: 35 s and 6.8 GB before anything was refused).

Why checks here and not a subprocess
------------------------------------
The alternative, parsing in a child process that may crash, was rejected:

* a crash is not the only failure: ezc3d also allocates without bound or loops, so a
  child would still need memory and time limits, and would burn them (seconds and
  gigabytes) before being killed; the checks refuse the same files in microseconds;
* :func:`skincap.io.read_c3d` is library API, used from notebooks, the viewer and Dask
  workers, not only from the CLI: a process per read costs the import of NumPy and
  ezc3d (~0.5 s) plus a copy of every array through a pipe, and ``fork`` is unsafe in
  threaded workers;
* a refusal here names the parameter and the byte at fault; a dead child can only say
  that the parser crashed.

The price is that this module must follow ezc3d's parser. It mirrors ezc3d 1.7.2
(``Header::read``, ``Parameters::Parameters``, ``Group::read``, ``Parameter::read``,
``setMandatoryParameters``, ``c3d::updateHeader``, ``Data::Data`` and the
Points/Analogs/Rotations ``Info`` classes): it walks the parameter records exactly as
ezc3d does (strictly chained, as with ``Options(ignoreBadFormatting=False)``), resolves
groups and parameters by ezc3d's exact-name rules, recomputes the sizes ezc3d will
derive (points and analog channels per frame, analog subframes, frame count, rotation
blocks), and refuses the file unless

* every record lies inside the parameter section and ends where the next begins;
* every parameter ezc3d dereferences (``POINT:USED, RATE, FRAMES, SCALE…``,
  ``ANALOG:USED, RATE, GEN_SCALE, SCALE…, OFFSET…``, ``ROTATION:DATA_START, USED,
  RATIO/RATE``) has the type ezc3d reads it as and enough values;
* every count is non-negative and every rate finite, with at most
  :data:`MAX_SAMPLES_PER_FRAME` analog or rotation subframes per frame (what a
  16-bit header word holds);
* every data block ezc3d will read (points and analogs, then rotations) lies inside
  the file, so nothing it allocates can outgrow the file.

The CLI fuzz test (``tests/fuzz``) runs mutated C3Ds through the real CLI in a
child process with memory and time limits: it is the net that catches a future ezc3d
that reads something this module does not know about.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from skincap.errors import FormatError

__all__ = ["check_before_ezc3d", "MAX_SAMPLES_PER_FRAME", "MAX_RATE_HZ"]

#: Most analog (or rotation) subframes per point frame: the header stores the analog
#: count in a 16-bit word, so a C3D cannot describe more.
MAX_SAMPLES_PER_FRAME = 65535
#: Highest frame or analog rate accepted (Hz); beyond it ezc3d's integer casts of the
#: rates are undefined, and no capture system samples that fast.
MAX_RATE_HZ = 1e7
_TYPE_NAMES = {-1: "CHAR", 1: "BYTE", 2: "INT", 4: "FLOAT"}
_INT_TYPES = (1, 2)
#: Bytes of one rotation: a 4x4 float matrix and a float reliability.
_ROTATION_BYTES = 17 * 4


@dataclass
class _Param:
    """One parameter as ezc3d stores it."""

    kind: int  # -1 CHAR, 1 BYTE, 2 INT, 4 FLOAT
    dims: list[int]  # ezc3d's dimensions ([1] for a numeric scalar)
    values: np.ndarray  # (count,) float64 for BYTE/INT/FLOAT, empty for CHAR
    offset: int  # byte of the record, for messages


@dataclass
class _Group:
    name: str = ""
    params: dict[str, _Param] = field(default_factory=dict)


def _s8(byte: int) -> int:
    return byte - 256 if byte > 127 else byte


def _floats(raw: bytes, processor: int) -> np.ndarray:
    """float32 values as ezc3d's ``readFloat`` decodes them -> (n,) float64."""
    b = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 4)
    if processor == 85:  # DEC: words swapped, high byte decremented (exponent - 2)
        b = b[:, [2, 3, 0, 1]].copy()
        b[:, 3] = np.where(b[:, 3] != 0, b[:, 3] - 1, 0)
    return b.reshape(-1).view("<f4").astype(np.float64)


def _ints(raw: bytes, size: int) -> np.ndarray:
    """Signed BYTE (int8) or INT (int16) values as ezc3d's ``readInt`` -> (n,) float64."""
    return np.frombuffer(raw, dtype=np.int8 if size == 1 else "<i2").astype(np.float64)


def _trunc_int(x: float) -> int:
    """C's ``static_cast<int>`` of a double on x86-64 (out of range -> INT_MIN)."""
    if not math.isfinite(x) or not (-(2.0**31) < x < 2.0**31):
        return -(2**31)
    return int(x)


class _Checker:
    def __init__(self, path: os.PathLike[str] | str, data: bytes) -> None:
        self.path = path
        self.data = data
        self.groups: list[_Group] = []

    def fail(self, what: str, offset: int | None = None) -> FormatError:
        return FormatError(self.path, what, offset=offset)

    # ----------------------------------------------------------------- header
    def header(self) -> tuple[int, int]:
        """(start of the parameter section, end of its declared blocks)."""
        data, size = self.data, len(self.data)
        if size < 512:
            raise self.fail(f"file is {size} bytes, shorter than the 512-byte C3D header", size)
        if data[1] != 0x50:
            raise self.fail(f"not a C3D file: byte 1 is 0x{data[1]:02x}, expected 0x50", 1)
        if data[0] < 2:
            raise self.fail(f"parameter block pointer {data[0]} must be >= 2", 0)
        start = (data[0] - 1) * 512
        if start + 4 > size:
            raise self.fail(
                f"parameter section at byte {start} lies past the end of the file ({size} bytes)",
                0,
            )
        self.processor = data[start + 3]
        if self.processor == 86:
            raise self.fail("MIPS (big-endian) C3D files are not supported by ezc3d", start + 3)
        if self.processor not in (84, 85):
            raise self.fail(
                f"unknown processor type {self.processor} (expected 84 or 85)", start + 3
            )
        end = start + data[start + 2] * 512
        if data[start + 2] == 0 or end > size:
            raise self.fail(
                f"parameter section of {data[start + 2]} blocks from byte {start} does not fit in the file ({size} bytes)",
                start + 2,
            )
        return start, _section_end(data, start, end)

    # ------------------------------------------------------------- parameters
    def records(self, start: int, end: int) -> None:
        """Walk the records as ezc3d does, refusing what would crash or mislead it."""
        data = self.data
        pos = start + 4
        while True:
            if pos + 2 > end:
                raise self.fail("parameter section ends inside a record header", pos)
            nchars = _s8(data[pos])
            if nchars == 0:
                return
            gid = _s8(data[pos + 1])
            if gid == 0:
                raise self.fail("parameter record with group id 0", pos + 1)
            name_end = pos + 2 + abs(nchars)
            if name_end + 2 > end:
                raise self.fail("parameter record runs past the parameter section", pos)
            # ezc3d keeps a name up to its first NUL
            name = data[pos + 2 : name_end].split(b"\0", 1)[0].decode("latin-1")
            nxt = int.from_bytes(data[name_end : name_end + 2], "little")
            body = name_end + 2
            if gid < 0:
                rec_end = self.description(body, end, f"group {name!r}")
                while len(self.groups) < -gid:
                    self.groups.append(_Group())
                self.groups[-gid - 1].name = name
            else:
                param, rec_end = self.parameter(body, end, name, pos)
                while len(self.groups) < gid:
                    self.groups.append(_Group())
                self.groups[gid - 1].params[name] = param
            if nxt == 0:
                return
            if name_end + nxt != rec_end:
                # ezc3d reads records back to back and refuses any gap or overlap
                how = (
                    "overruns the next record"
                    if rec_end > name_end + nxt
                    else "ends before the next record"
                )
                raise self.fail(
                    f"record {name!r} {how}: its content ends at byte {rec_end}, its pointer leads to byte {name_end + nxt}",
                    name_end,
                )
            pos = rec_end

    def description(self, at: int, end: int, what: str) -> int:
        """Check a description length byte at ``at``; the byte after the description."""
        if at + 1 > end:
            raise self.fail(f"{what}: record runs past the parameter section", at)
        dlen = _s8(self.data[at])
        if dlen < 0:  # ezc3d reads it signed and asks for ~4 GiB
            raise self.fail(f"{what}: negative description length {dlen}", at)
        if at + 1 + dlen > end:
            raise self.fail(f"{what}: description of {dlen} bytes overruns the section", at)
        return at + 1 + dlen

    def parameter(self, body: int, end: int, name: str, pos: int) -> tuple[_Param, int]:
        data = self.data
        if body + 2 > end:
            raise self.fail(f"parameter {name!r}: record runs past the parameter section", body)
        kind = _s8(data[body])
        if kind not in _TYPE_NAMES:
            raise self.fail(f"parameter {name!r}: unknown data type {kind}", body)
        ndims = _s8(data[body + 1])
        if ndims < 0:  # ezc3d reads values along a missing dimension: segfault
            raise self.fail(f"parameter {name!r}: negative dimension count {ndims}", body + 1)
        if ndims == 0 and kind == -1:  # ezc3d's CHAR reader needs a dimension: segfault
            raise self.fail(f"parameter {name!r}: CHAR with no dimensions", body + 1)
        vstart = body + 2 + ndims
        if vstart > end:
            raise self.fail(f"parameter {name!r}: dimensions overrun the section", body + 1)
        dims = list(data[body + 2 : vstart]) if ndims else [1]
        count = math.prod(dims)
        size = abs(kind)
        if vstart + count * size > end:
            raise self.fail(
                f"parameter {name!r}: {count} values of {size} bytes overrun the parameter section",
                vstart,
            )
        raw = data[vstart : vstart + count * size]
        if kind == 4:
            values = _floats(raw, self.processor)
        elif kind in _INT_TYPES:
            values = _ints(raw, size)
        else:
            values = np.zeros(0)
        rec_end = self.description(vstart + count * size, end, f"parameter {name!r}")
        return _Param(kind, dims, values, pos), rec_end

    # ----------------------------------------------------------- lookups
    def group(self, name: str) -> _Group | None:
        """ezc3d's ``group(name)``: the first group of that exact name."""
        return next((g for g in self.groups if g.name == name), None)

    def param(self, gname: str, pname: str, kinds: tuple[int, ...]) -> _Param | None:
        """A parameter ezc3d reads at index 0: right type and at least one value."""
        g = self.group(gname)
        p = None if g is None else g.params.get(pname)
        if p is None:
            return None
        where = f"{gname}:{pname}"
        if p.kind not in kinds:
            want = " or ".join(_TYPE_NAMES[k] for k in kinds)
            raise self.fail(f"{where} is {_TYPE_NAMES[p.kind]}, expected {want}", p.offset)
        if p.values.size == 0:
            raise self.fail(f"{where} has no value (dimensions {p.dims})", p.offset)
        return p

    def first(self, gname: str, pname: str, kinds: tuple[int, ...], default: float) -> float:
        p = self.param(gname, pname, kinds)
        return default if p is None else float(p.values[0])

    def chain(
        self, gname: str, pname: str, kinds: tuple[int, ...], default: list[float]
    ) -> np.ndarray:
        """``NAME`` (ezc3d's default when absent), ``NAME2``, ``NAME3``… concatenated, as
        ezc3d's Points and Analogs Info classes build their per-column factors."""
        g = self.group(gname)
        params = {} if g is None else g.params
        parts = [] if pname in params else [np.asarray(default, dtype=np.float64)]
        k = 1
        while k == 1 or (key := f"{pname}{k}") in params:
            key = pname if k == 1 else f"{pname}{k}"
            k += 1
            if key not in params:
                continue
            p = params[key]
            if p.kind not in kinds:
                want = " or ".join(_TYPE_NAMES[t] for t in kinds)
                raise self.fail(
                    f"{gname}:{key} is {_TYPE_NAMES[p.kind]}, expected {want}", p.offset
                )
            parts.append(p.values)
        return np.concatenate(parts)

    def count(self, gname: str, pname: str) -> int:
        v = self.first(gname, pname, _INT_TYPES, 0.0)
        if v < 0:
            raise self.fail(f"{gname}:{pname} is negative ({int(v)})")
        return int(v)

    def rate(self, gname: str, pname: str) -> float:
        return self.check_rate(f"{gname}:{pname}", self.first(gname, pname, (4,), 0.0))

    def check_rate(self, what: str, v: float) -> float:
        if not (math.isfinite(v) and 0 <= v <= MAX_RATE_HZ):
            raise self.fail(f"{what} is {v:g}, not a rate in 0..{MAX_RATE_HZ:g} Hz")
        return v

    # ------------------------------------------------------------- sizes
    def sizes(self, start: int) -> None:
        """Recompute what ezc3d derives from header and parameters; check it fits."""
        data, size = self.data, len(self.data)
        words = np.frombuffer(data[:20], dtype="<u2").astype(np.int64)
        scale_hdr, rate_hdr = (float(x) for x in _floats(data[12:16] + data[20:24], self.processor))
        n3d_hdr, n_meas, first_raw, last_raw = (int(w) for w in words[1:5])
        data_block, byframe_hdr = int(words[8]), int(words[9])
        # Header::read: frame numbers are 1-based unless the first is 0
        first = first_raw - 1 if first_raw else 0
        last = last_raw - 1 if (last_raw and first_raw) else last_raw

        # setMandatoryParameters, then updateHeader
        frames_p = self.param("POINT", "FRAMES", _INT_TYPES)
        n_frames_param = 0
        if frames_p is not None:
            n_frames_param = int(frames_p.values[0])
            if frames_p.values.size > 1 or n_frames_param < 0:
                n_frames_param &= 0xFFFF  # ezc3d casts to uint16
        analogs_hdr = n_meas // byframe_hdr if byframe_hdr else 0
        frames_hdr = 0 if n3d_hdr == 0 and analogs_hdr == 0 else last - first + 1
        if n_frames_param != 0 and n_frames_param != frames_hdr:
            last = n_frames_param + first - 1
        point_rate = self.rate("POINT", "RATE")
        n_points = self.count("POINT", "USED")
        if _trunc_int(point_rate * 1e4) != _trunc_int(
            float(np.float32(rate_hdr) * np.float32(1e4))
        ):
            if point_rate == 0.0 and n_points != 0:
                # ezc3d copies the header's rate into POINT:RATE, and its nested
                # updateHeader derives the analog subframes from that rate
                point_rate = self.check_rate("the header's frame rate", rate_hdr)
            else:
                rate_hdr = float(np.float32(point_rate))
        analog_rate = self.rate("ANALOG", "RATE")
        byframe = byframe_hdr
        if int(point_rate) != 0:
            ratio = analog_rate / point_rate
            if ratio > MAX_SAMPLES_PER_FRAME:
                raise self.fail(
                    f"ANALOG:RATE {analog_rate:g} / POINT:RATE {point_rate:g} = {ratio:g} analog samples per frame; a C3D holds at most {MAX_SAMPLES_PER_FRAME}"
                )
            shadow = self.group("SHADOW") is not None
            if int(ratio) != byframe_hdr and not (byframe_hdr == 1 and shadow):
                byframe = int(ratio)
        n_channels = self.count("ANALOG", "USED")  # read even when it is not used
        if not byframe:
            n_channels = 0
        rotations = self.group("ROTATION") is not None
        if n_points == 0 and n_channels == 0 and not rotations:
            n_frames = 0
        else:
            n_frames = last - first + 1
            if n_frames < 0:
                raise self.fail(
                    f"the last frame ({last_raw}) comes before the first ({first_raw})", 6
                )

        # Data::Data: every value the Info classes index must exist
        self.first("ANALOG", "GEN_SCALE", (4,), 1.0)
        # the factor chains are type-checked even where ezc3d would not read them
        scales = self.chain("POINT", "SCALE", (4,), [-1.0])
        analog_factors = {
            "SCALE": self.chain("ANALOG", "SCALE", (4,), []).size,
            "OFFSET": self.chain("ANALOG", "OFFSET", _INT_TYPES, []).size,
        }
        point_bytes = 0
        if n_points:
            if scales.size == 0:
                raise self.fail(f"POINT:SCALE has no value for {n_points} points")
            per_point = np.full(n_points, scales[0])
            k = min(n_points, scales.size)
            per_point[:k] = scales[:k]
            point_bytes = int(8 * n_points + 8 * np.count_nonzero(per_point < 0))
        analog_bytes = byframe * n_channels * (4 if scale_hdr < 0 else 2)
        if n_channels and n_frames:
            shadow = self.group("SHADOW") is not None
            for pname, have in analog_factors.items():
                if have < n_channels and not (shadow and have == 0):
                    raise self.fail(
                        f"ANALOG:{pname} has {have} values, {n_channels} analog channels need one each"
                    )
        frame_bytes = point_bytes + analog_bytes

        if n_frames:
            if data_block < 1:
                raise self.fail(f"data start block {data_block} must be >= 1", 16)
            data_start = (data_block - 1) * 512
            if data_start < start + 4:
                raise self.fail(
                    f"data section (block {data_block}) starts before the parameter section", 16
                )
            if n_frames == 0xFFFF and not rotations:
                n_frames = 1  # ezc3d reads to the end of the file: at least one frame
            need = data_start + n_frames * frame_bytes
            if need > size:
                raise self.fail(
                    f"{n_frames} frames of {frame_bytes} bytes from byte {data_start} need {need} bytes, the file has {size}",
                    size,
                )
        rotation = self.group("ROTATION")
        if rotation is not None:
            self.rotation_block(rotation, n_frames, rate_hdr)

    def rotation_block(self, g: _Group, n_frames: int, rate_hdr: float) -> None:
        """ROTATION group (RotationsInfo and Data::Data): parameters and block size."""
        for pname in ("DATA_START", "USED"):
            if pname not in g.params:
                raise self.fail(f"ROTATION:{pname} is missing")
        block = self.count("ROTATION", "DATA_START")
        used = self.count("ROTATION", "USED")
        if "RATIO" in g.params:
            ratio = float(self.count("ROTATION", "RATIO"))
        elif "RATE" in g.params:
            rate = self.rate("ROTATION", "RATE")
            if not (math.isfinite(rate_hdr) and rate_hdr > 0):
                raise self.fail(f"ROTATION:RATE needs a positive frame rate, not {rate_hdr:g}")
            ratio = rate / rate_hdr
        else:
            raise self.fail("ROTATION has neither RATIO nor RATE")
        if ratio > MAX_SAMPLES_PER_FRAME:
            raise self.fail(
                f"{ratio:g} rotation samples per frame; at most {MAX_SAMPLES_PER_FRAME}"
            )
        if block < 1:
            raise self.fail(f"ROTATION:DATA_START {block} must be >= 1")
        start, size = (block - 1) * 512, len(self.data)
        need = start + n_frames * int(ratio) * used * _ROTATION_BYTES
        if start <= size and need > size:  # ezc3d skips a block that starts past the end
            raise self.fail(
                f"rotation data of {n_frames} frames from byte {start} need {need} bytes, the file has {size}",
                size,
            )


def _section_end(data: bytes, start: int, declared_end: int) -> int:
    """Where the parameter records may run to: the declared blocks' end, or the data
    section's start when the header puts that later (within the file).

    ezc3d walks the records by their pointers whatever the block count says, and some
    writers (Peak Performance, c3d.org sample15) declare fewer blocks than their
    parameters fill; the data section's start still bounds them.
    """
    data_start = (int.from_bytes(data[16:18], "little") - 1) * 512
    if declared_end < data_start <= len(data):
        return data_start
    return declared_end


def check_before_ezc3d(path: os.PathLike[str] | str, data: bytes) -> None:
    """Refuse a C3D that would crash ezc3d or make it allocate beyond the file's size.

    Parameters
    ----------
    path : str or PathLike
        The file, for messages.
    data : bytes
        Its whole content.

    Raises
    ------
    FormatError
        Naming the header word, record or parameter at fault (with its byte offset
        where there is one). Files that pass may still be refused later by the reader
        for reasons that do not endanger ezc3d.
    """
    checker = _Checker(path, data)
    start, end = checker.header()
    checker.records(start, end)
    checker.sizes(start)
