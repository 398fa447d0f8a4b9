"""Encoding a C3D file (Intel, float data) from parameter groups and sample arrays.

skincap writes C3D itself rather than through ezc3d: ezc3d's writer resets
``ANALOG:OFFSET`` to 0 and ``GEN_SCALE`` to 1, turns BYTE parameters into INT and
cannot write the header's events, so a file could not go out as it came in. ezc3d
stays the second reader the tests check every written file with.

Layout written (C3D specification, c3d.org): a 512-byte header; the parameter
section from block 2 (groups and parameters in the given order, each group before
its parameters); the data section from the next block: per frame, every point as
four float32 words (x, y, z, then the float of ``residual_steps * 256 + camera_mask``,
or -1 for an invalid sample: the layout ezc3d 1.7 writes and reads), followed by ``ratio`` sub-frames of every analog channel as float32.
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass

import numpy as np

from skincap.errors import FormatError
from skincap.io.c3d.content import TYPE_SIZES, C3dGroup, C3dParameter, HeaderEvents
from skincap.io.narrowing import check_float32

__all__ = ["C3dFrames", "encode_c3d", "char_parameter", "number_parameter"]

_BLOCK = 512
#: int16 next-record offsets count from the offset field; a record's body is at most this.
_MAX_RECORD = 32767 - 2
#: The float32 bit pattern -1.0 that marks an invalid point sample (Vicon, Qualisys, ezc3d).
_INVALID_WORD = 0xBF800000


def char_parameter(
    name: str, values: str | list[str], description: str = "", *, target: str | os.PathLike[str]
) -> C3dParameter:
    """A CHAR parameter: one string (dims ``(width,)``) or a list (dims ``(width, n)``), UTF-8.

    Raises FormatError when a string is longer than 255 bytes or a list longer than
    255 entries (a C3D dimension is one byte).
    """
    single = isinstance(values, str)
    items = [values] if single else list(values)
    encoded = [str(v).encode("utf-8") for v in items]
    width = max((len(e) for e in encoded), default=0)
    if width > 255:
        long = next(str(v) for v, e in zip(items, encoded, strict=True) if len(e) == width)
        raise FormatError(
            target,
            f"parameter {name}: {long[:40]!r}... is {width} bytes in UTF-8; a C3D string holds 255",
        )
    if len(items) > 255:
        raise FormatError(target, f"parameter {name}: {len(items)} strings; a C3D list holds 255")
    raw = b"".join(e.ljust(width, b" ") for e in encoded)
    dims = (width,) if single else (width, len(items))
    return C3dParameter(name, -1, dims, raw, description.encode("utf-8")[:127])


def number_parameter(
    name: str,
    values: float | int | list | np.ndarray,
    kind: str,
    *,
    target: str | os.PathLike[str],
    scalar: bool | None = None,
) -> C3dParameter:
    """An INT (int16) or FLOAT (float32) parameter; dims from the array (F order), () for a scalar.

    Raises FormatError when a value does not fit the type.
    """
    a = np.asarray(values)
    if scalar is None:
        scalar = a.ndim == 0
    if any(d > 255 for d in a.shape) or a.ndim > 7:
        raise FormatError(target, f"parameter {name}: shape {a.shape} exceeds C3D's 7 x 255")
    if kind == "int":
        ai = np.asarray(np.rint(a.astype(np.float64)), dtype=np.int64)
        if ai.size and (ai.min() < -32768 or ai.max() > 65535):
            bad = int(ai.ravel()[np.argmax((ai.ravel() < -32768) | (ai.ravel() > 65535))])
            raise FormatError(
                target,
                f"parameter {name}: {bad} does not fit a C3D 16-bit integer; nothing written",
            )
        # 32768..65535 are stored as their unsigned 16 bits (counts, frame numbers)
        raw = (ai.ravel(order="F") & 0xFFFF).astype("<u2").tobytes()
        ptype = 2
    else:
        check_float32(a, target, lambda idx: f"parameter {name}[{idx}]")
        raw = a.astype("<f4").ravel(order="F").tobytes()
        ptype = 4
    dims = () if scalar else tuple(int(d) for d in a.shape)
    return C3dParameter(name, ptype, dims, raw)


def _record(
    name: str, gid: int, locked: bool, body: bytes, target: str | os.PathLike[str]
) -> bytes:
    nb = name.encode("ascii")
    if not 0 < len(nb) <= 127:
        raise FormatError(target, f"parameter or group name {name!r}: 1..127 characters")
    if len(body) > _MAX_RECORD:
        raise FormatError(
            target,
            f"{name}: {len(body)} bytes; a C3D parameter record holds at most {_MAX_RECORD}",
        )
    return (
        struct.pack("<bb", -len(nb) if locked else len(nb), gid)
        + nb
        + struct.pack("<h", len(body) + 2)
        + body
    )


def _parameter_body(p: C3dParameter, target: str | os.PathLike[str]) -> bytes:
    if len(p.dims) > 7 or any(not 0 <= d <= 255 for d in p.dims):
        raise FormatError(target, f"parameter {p.name}: dimensions {p.dims} exceed C3D's 7 x 255")
    n = math.prod(p.dims) * TYPE_SIZES[p.type] if p.dims else TYPE_SIZES[p.type]
    if len(p.raw) != n:
        raise FormatError(
            target,
            f"parameter {p.name}: {len(p.raw)} bytes of values, dimensions {p.dims} need {n}",
        )
    desc = p.description[:127]
    return (
        struct.pack("<bB", p.type, len(p.dims)) + bytes(p.dims) + p.raw + bytes([len(desc)]) + desc
    )


def _parameter_section(
    groups: list[C3dGroup], target: str | os.PathLike[str]
) -> tuple[bytes, int | None]:
    """The parameter section (whole blocks) and the byte offset of POINT:DATA_START's value."""
    if len(groups) > 127:
        raise FormatError(target, f"{len(groups)} parameter groups; a C3D holds 127")
    out = bytearray(b"\x01\x50\x00\x54")  # first parameter block, key, blocks (later), Intel
    data_start_at = None
    for gid, g in enumerate(groups, start=1):
        desc = g.description[:127]
        out += _record(g.name, -gid, g.locked, bytes([len(desc)]) + desc, target)
        for p in g.parameters:
            rec = _record(p.name, gid, p.locked, _parameter_body(p, target), target)
            if g.name == "POINT" and p.name == "DATA_START" and p.type == 2 and not p.dims:
                # name, offset field, type, ndims: the value follows
                data_start_at = len(out) + 2 + len(p.name) + 2 + 2
            out += rec
    out += b"\x00\x00"  # a zero name length ends the section for every reader
    n_blocks = -(-len(out) // _BLOCK)
    if n_blocks > 255:
        raise FormatError(target, f"parameter section of {n_blocks} blocks; a C3D holds 255")
    out[2] = n_blocks
    out += bytes(n_blocks * _BLOCK - len(out))
    return bytes(out), data_start_at


@dataclass(frozen=True)
class C3dFrames:
    """The data section's content.

    Attributes
    ----------
    xyz : (T, N, 3) float64
        File units; ignored where ``invalid``.
    invalid : (T, N) bool
    residual_steps : (T, N) int
        Residuals in steps of ``|POINT:SCALE|``, 0..255.
    camera_masks : (T, N) int
        Seven camera bits.
    analogs : (C, T * ratio) float64
        As stored (before SCALE/OFFSET/GEN_SCALE).
    ratio : int
        Analog samples per frame (0 without analogs).
    """

    xyz: np.ndarray
    invalid: np.ndarray
    residual_steps: np.ndarray
    camera_masks: np.ndarray
    analogs: np.ndarray
    ratio: int


def encode_c3d(
    groups: list[C3dGroup],
    frames: C3dFrames,
    *,
    first_frame: int,
    rate: float,
    point_scale: float,
    events: HeaderEvents | None,
    target: str | os.PathLike[str],
) -> bytes:
    """The bytes of a float C3D.

    ``groups`` must contain POINT with a scalar INT ``DATA_START`` (filled here) and
    the POINT/ANALOG parameters agreeing with ``frames``; this function does not
    invent parameters. ``point_scale`` (> 0) is written negated (float data).
    """
    t, n = frames.invalid.shape
    channels = frames.analogs.shape[0]
    section, data_start_at = _parameter_section(groups, target)
    data_block = 2 + len(section) // _BLOCK  # header is block 1, parameters from block 2
    if data_start_at is None:
        raise FormatError(target, "internal: POINT:DATA_START missing")
    params = bytearray(section)
    struct.pack_into("<H", params, data_start_at, data_block)

    header = bytearray(_BLOCK)
    header[0], header[1] = 2, 0x50
    last = min(first_frame + t - 1, 0xFFFF)  # longer takes: POINT:FRAMES holds the count
    struct.pack_into("<HHHHH", header, 2, n, channels * frames.ratio, first_frame, max(last, 0), 10)
    struct.pack_into("<f", header, 12, -abs(point_scale))
    struct.pack_into("<HH", header, 16, data_block, frames.ratio if channels else 0)
    struct.pack_into("<f", header, 20, rate)
    if events is not None and events.count:
        struct.pack_into(
            "<HHHH",
            header,
            294,
            events.label_range_present,
            events.label_range_block,
            0x3039,
            events.count,
        )
        struct.pack_into("<18f", header, 304, *events.times.astype(np.float32))
        header[376:394] = events.display[:18].ljust(18, b"\x00")
        header[396:468] = events.labels[:72].ljust(72, b" ")
    else:
        struct.pack_into("<H", header, 298, 0x3039)

    words = 4 * n + channels * frames.ratio
    data = np.zeros((t, words), dtype="<u4")
    pts = data[:, : 4 * n].reshape(t, n, 4)
    pts[..., :3] = frames.xyz.astype("<f4").view("<u4")
    steps = np.clip(frames.residual_steps, 0, 255).astype(np.int64)
    packed = steps * 256 + (frames.camera_masks.astype(np.int64) & 0x7F)  # exact in float32
    pts[..., 3] = packed.astype("<f4").view("<u4")
    pts[frames.invalid] = (0, 0, 0, _INVALID_WORD)
    if channels:
        # (C, T * ratio) -> per frame: ratio sub-frames of every channel
        a = frames.analogs.reshape(channels, t, frames.ratio).transpose(1, 2, 0)
        data[:, 4 * n :] = a.reshape(t, channels * frames.ratio).astype("<f4").view("<u4")
    return bytes(header) + bytes(params) + data.tobytes()
