"""A C3D parameter section rewritten record by record, for files ezc3d would misread.

Two writers' habits break ezc3d's strictly chained, signed reading of the records while
each record's own pointer to the next still says where it ends:

* OptiTrack (BTKData ``others/mocap36.c3d``) leaves out the description-length byte
  of ``POINT:LABELS``: the values run to the pointer;
* BKIN Technologies' Dexterit-E (c3d.org sample22) writes descriptions of 128-255
  bytes, whose length byte ezc3d reads as a negative number (and then asks for 4 GiB);
* Motion Analysis (c3d.org sample06) writes no ``ANALOG:OFFSET`` and c3d.org sample13
  stores it as FLOAT, where ezc3d needs one INT per channel (:func:`_analog_offsets`);
  sample13 also declares one ``POINT:FRAMES`` more than the file holds
  (:func:`_point_frames`);
* PhaseSpace (c3d.org sample20) writes no parameter at all, only the header
  (:func:`_point_group_from_header`).

:func:`repaired_parameter_section` walks the records by their pointers, as the C3D
format defines them, and writes each back canonically (an empty description where the
byte is missing, a description cut to the 127 bytes a signed length holds), in the
space the file gives the section before its data. The header and the data section are
kept byte for byte. Whatever cannot be walked so is left to the strict checks, which
then refuse the file as before.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["intel_copy_of_mips", "repaired_parameter_section"]

_SIZES = {-1: 1, 1: 1, 2: 2, 4: 4}


def _s8(byte: int) -> int:
    return byte - 256 if byte > 127 else byte


def repaired_parameter_section(data: bytes) -> tuple[bytes, list[str]] | None:
    """The file with its parameter records rewritten canonically, and what was changed.

    Parameters
    ----------
    data : bytes
        A whole Intel or DEC C3D file (MIPS files are left alone).

    Returns
    -------
    (bytes, list of str) or None
        The repaired file (same length, header and data section unchanged) and one
        phrase per change; None when nothing needs changing or the records cannot be
        walked by their pointers inside the space before the data section.
    """
    if len(data) < 512 or data[1] != 0x50 or data[0] < 2:
        return None
    start = (data[0] - 1) * 512
    if start + 4 > len(data) or data[start + 3] not in (84, 85):
        return None
    data_start = (int.from_bytes(data[16:18], "little") - 1) * 512
    limit = data_start if start < data_start <= len(data) else len(data)
    out = bytearray()
    changes: list[str] = []
    records: list[_Record] = []
    pos = start + 4
    while True:
        if pos + 2 > limit:
            return None
        nchars, gid = _s8(data[pos]), _s8(data[pos + 1])
        if nchars == 0:
            break
        name_end = pos + 2 + abs(nchars)
        if gid == 0 or name_end + 2 > limit:
            return None
        name = bytes(data[pos + 2 : name_end])
        nxt = int.from_bytes(data[name_end : name_end + 2], "little")
        body = name_end + 2
        rec_end: int | None = limit if nxt == 0 else name_end + nxt
        if rec_end is not None and rec_end > limit:
            # a pointer out of the section (SGI's c3d.org sample02 ends on one): the
            # record ends where its own lengths say, and is the last
            rec_end, nxt = _content_end(data, body, gid, limit), 0
            changes.append(f"{name.decode('latin-1')}: pointer out of the section, the last record")
        if rec_end is None or rec_end < body:
            return None
        label = name.decode("latin-1")
        if gid < 0:
            fixed = _description(data, body, rec_end, label, changes)
            if fixed is None:
                return None
            new_body = fixed
        else:
            if body + 2 > rec_end:
                return None
            kind, ndims = _s8(data[body]), data[body + 1]
            if kind not in _SIZES or ndims > 7:
                return None
            vstart = body + 2 + ndims
            dims = list(data[body + 2 : vstart])
            vend = vstart + (math.prod(dims) if ndims else 1) * _SIZES[kind]
            if vend > rec_end:
                return None
            fixed = _description(data, vend, rec_end, label, changes)
            if fixed is None:
                return None
            new_body = bytes(data[body:vend]) + fixed
        records.append((bytes(data[pos:name_end]), label.upper(), gid, new_body))
        if nxt == 0:
            break
        pos = rec_end
    if not records:
        records = _point_group_from_header(data, data_start, changes)
    records = _analog_offsets(records, changes)
    records = _point_frames(records, data, data_start, changes)
    if not changes:
        return None
    for head, _, _, new_body in records:
        out += head + (len(new_body) + 2).to_bytes(2, "little") + new_body
    out += b"\x00\x00"
    nblocks = -(-(len(out) + 4) // 512)
    room = limit - start
    if nblocks * 512 > room or nblocks > 255:
        return None
    section = bytes([data[start], data[start + 1], nblocks, data[start + 3]]) + bytes(out)
    section += bytes(room - len(section))
    return bytes(data[:start]) + section + bytes(data[limit:]), changes


#: One walked record: its bytes up to the pointer (name length, group id, name), the
#: upper-case name, the group id and its canonical body (everything after the pointer).
_Record = tuple[bytes, str, int, bytes]


def _analog_offsets(records: list[_Record], changes: list[str]) -> list[_Record]:
    """``ANALOG:OFFSET`` as ezc3d reads it: INT, one value per channel.

    Motion Analysis (c3d.org sample06, ``MACsample.c3d``) writes no OFFSET at all: a
    zero offset for each of ``ANALOG:USED`` channels is added (the format's meaning of
    an absent offset). c3d.org sample13 (``Dance.c3d``, ``golfswing.c3d``) stores it
    as FLOAT: whole numbers within int16 are written back as INT. Other values are
    left alone (the checks then refuse the file as before). Notes each change.
    """
    analog = [-gid for _, name, gid, _ in records if gid < 0 and name == "ANALOG"]
    if not analog:
        return records
    gid = analog[0]
    own = {name: i for i, (_, name, g, _) in enumerate(records) if g == gid}
    out = list(records)
    if "OFFSET" in own:
        i = own["OFFSET"]
        head, name, g, body = records[i]
        kind, ndims = _s8(body[0]), body[1]
        if kind == 4:
            dims = list(body[2 : 2 + ndims])
            n = math.prod(dims) if ndims else 1
            vstart = 2 + ndims
            values = np.frombuffer(body[vstart : vstart + 4 * n], dtype="<f4").astype(np.float64)
            if np.all(np.isfinite(values)) and np.all(values == np.round(values)):
                if np.all(np.abs(values) <= 32767):
                    ints = values.astype("<i2").tobytes()
                    desc = body[vstart + 4 * n :]
                    out[i] = (head, name, g, bytes([2, ndims]) + body[2:vstart] + ints + desc)
                    changes.append("ANALOG:OFFSET: whole FLOAT values read as INT")
        return out
    if "USED" not in own:
        return records
    _, _, _, used_body = records[own["USED"]]
    kind, ndims = _s8(used_body[0]), used_body[1]
    if kind not in (1, 2) or ndims > 1 or (ndims and used_body[2] < 1):
        return records
    vstart = 2 + ndims
    used = int.from_bytes(used_body[vstart : vstart + _SIZES[kind]], "little", signed=True)
    if not 0 < used <= 255:
        return records
    head = bytes([len(b"OFFSET"), gid]) + b"OFFSET"
    body = bytes([2, 1, used]) + bytes(2 * used) + b"\x00"
    out.insert(own["USED"] + 1, (head, "OFFSET", gid, body))
    changes.append(f"ANALOG:OFFSET missing: 0 for each of {used} channels")
    return out


def _point_group_from_header(data: bytes, data_start: int, changes: list[str]) -> list[_Record]:
    """A POINT group built from the header, for a file with no parameter record at all.

    PhaseSpace (c3d.org sample20) writes an empty parameter section (0 blocks, no
    record) and puts everything in the header: points per frame, scale, rate, first
    and last frame, data block. ``POINT:USED``, ``SCALE``, ``RATE``, ``DATA_START``
    and ``FRAMES`` are written from it (labels and units absent: the reader names the
    columns by number and guesses the unit, with a warning). Only files without
    analog samples; anything else is left to the checks.
    """
    words = np.frombuffer(data[:20], dtype="<u2").astype(np.int64)
    n3d, n_meas, first, last, block = (int(w) for w in (*words[1:5], words[8]))
    scale, rate = (float(x) for x in np.frombuffer(data[12:16] + data[20:24], dtype="<f4"))
    frames = last - first + 1
    ok = 0 < n3d <= 32767 and n_meas == 0 and 1 <= first <= last and frames <= 32767
    if not ok or not (np.isfinite(scale) and scale != 0 and np.isfinite(rate) and rate > 0):
        return []
    if (block - 1) * 512 != data_start:
        return []

    def record(name: bytes, body: bytes) -> _Record:
        return (bytes([len(name), 1]) + name, name.decode(), 1, body + b"\x00")

    def integer(v: int) -> bytes:
        return bytes([2, 0]) + int(v).to_bytes(2, "little", signed=True)

    def real(v: float) -> bytes:
        return bytes([4, 0]) + np.float32(v).astype("<f4").tobytes()

    changes.append(
        f"no parameters: POINT from the header ({n3d} points, {rate:g} Hz, frames {first}-{last})"
    )
    return [
        (bytes([5, 0xFF]) + b"POINT", "POINT", -1, b"\x00"),
        record(b"USED", integer(n3d)),
        record(b"SCALE", real(scale)),
        record(b"RATE", real(rate)),
        record(b"DATA_START", integer(block)),
        record(b"FRAMES", integer(frames)),
    ]


def _point_frames(
    records: list[_Record], data: bytes, data_start: int, changes: list[str]
) -> list[_Record]:
    """``POINT:FRAMES`` held to the frames the file holds when it claims more.

    ezc3d reads ``POINT:FRAMES`` frames when it differs from the header's count; c3d.org
    sample13 (``Dance.c3d``, ``golfswing.c3d``) declares one frame more than its header
    and its data section hold. When the header's count fits the file and the
    parameter's does not, the parameter takes the header's count (an INT scalar only;
    anything else is left to the checks).
    """
    words = np.frombuffer(data[:20], dtype="<u2").astype(np.int64)
    n3d, n_meas, first, last = (int(w) for w in words[1:5])
    scale = float(np.frombuffer(data[12:16], dtype="<f4")[0])
    frame_bytes = (4 * n3d + n_meas) * (4 if scale < 0 else 2)
    header_frames = last - first + 1 if first else last
    if frame_bytes <= 0 or header_frames < 1 or data_start < 512:
        return records
    held = (len(data) - data_start) // frame_bytes
    point = [-gid for _, name, gid, _ in records if gid < 0 and name == "POINT"]
    if not point or header_frames > held:
        return records
    for i, (head, name, gid, body) in enumerate(records):
        if gid != point[0] or name != "FRAMES" or _s8(body[0]) != 2 or body[1] != 0:
            continue
        declared = int.from_bytes(body[2:4], "little", signed=True)
        if declared > held and header_frames <= 32767:
            out = list(records)
            out[i] = (head, name, gid, body[:2] + header_frames.to_bytes(2, "little") + body[4:])
            changes.append(
                f"POINT:FRAMES {declared} beyond the {held} frames the file holds: "
                f"{header_frames}, the header's"
            )
            return out
    return records


def _content_end(data: bytes, body: int, gid: int, limit: int) -> int | None:
    """Where a record whose body starts at ``body`` ends by its own lengths (its
    description included), or None past ``limit``."""
    at = body
    if gid > 0:
        if body + 2 > limit or _s8(data[body]) not in _SIZES:
            return None
        kind, ndims = _s8(data[body]), data[body + 1]
        dims = list(data[body + 2 : body + 2 + ndims])
        at = body + 2 + ndims + (math.prod(dims) if ndims else 1) * _SIZES[kind]
    if at + 1 > limit or at + 1 + data[at] > limit:
        return None
    return at + 1 + data[at]


def _description(
    data: bytes, at: int, rec_end: int, label: str, changes: list[str]
) -> bytes | None:
    """The canonical description bytes (length byte first) of the record content from
    ``at`` to ``rec_end``; notes in ``changes`` what differs from the file."""
    if at == rec_end:
        changes.append(f"{label}: no description length byte")
        return b"\x00"
    dlen = data[at]
    if at + 1 + dlen > rec_end:
        return None
    text = bytes(data[at + 1 : at + 1 + dlen])
    if dlen > 127:
        # only text: a long "description" of binary bytes is a corrupted record
        if not all(32 <= c < 127 or c >= 160 or c in (9, 10, 13) for c in text.rstrip(b"\0 ")):
            return None
        changes.append(f"{label}: description of {dlen} bytes cut to 127")
        text = text[:127]
    return bytes([len(text)]) + text


def _swap(buf: bytearray, start: int, stop: int, size: int) -> None:
    """Reverse the bytes of every ``size``-byte word of ``buf[start:stop]`` in place."""
    stop = start + (stop - start) // size * size
    if stop > start:
        words = np.frombuffer(bytes(buf[start:stop]), dtype=np.uint8).reshape(-1, size)
        buf[start:stop] = words[:, ::-1].tobytes()


def intel_copy_of_mips(data: bytes) -> bytes | None:
    """A MIPS (big-endian, processor 86) C3D rewritten little-endian (processor 84).

    ezc3d reads Intel and DEC files only. The header's words and floats, every
    parameter record's pointer and INT or FLOAT values, and every word of the data
    section (from the data start to the end of the file: points and analogs are all
    float32 or all int16 there, by the sign of the scale) are byte-swapped; text,
    BYTE values and the header's event flags and labels are kept.

    Returns None when the file is not MIPS or its records cannot be walked inside the
    file (the checks then refuse it as before).
    """
    if len(data) < 512 or data[1] != 0x50 or data[0] < 2:
        return None
    start = (data[0] - 1) * 512
    if start + 4 > len(data) or data[start + 3] != 86:
        return None
    data_block = int.from_bytes(data[16:18], "big")
    section_end = (data_block - 1) * 512 if data_block > data[0] else len(data)
    out = bytearray(data)
    for a, b, size in ((2, 12, 2), (12, 16, 4), (16, 20, 2), (20, 24, 4), (24, 304, 2)):
        _swap(out, a, b, size)
    _swap(out, 304, 376, 4)  # event times
    _swap(out, 394, 396, 2)
    pos = start + 4
    while True:
        if pos + 2 > len(data):
            return None
        nchars, gid = _s8(data[pos]), _s8(data[pos + 1])
        if nchars == 0:
            break
        name_end = pos + 2 + abs(nchars)
        if gid == 0 or name_end + 2 > len(data):
            return None
        nxt = int.from_bytes(data[name_end : name_end + 2], "big")
        _swap(out, name_end, name_end + 2, 2)
        body = name_end + 2
        if gid > 0:
            if body + 2 > len(data):
                return None
            kind, ndims = _s8(data[body]), data[body + 1]
            if kind not in _SIZES:
                return None
            vstart = body + 2 + ndims
            dims = list(data[body + 2 : vstart])
            vend = vstart + (math.prod(dims) if ndims else 1) * _SIZES[kind]
            if vend > len(data):
                return None
            if kind in (2, 4):
                _swap(out, vstart, vend, kind)
        if nxt == 0 or name_end + nxt >= section_end:
            break  # the last record (SGI's c3d.org sample02 ends on a pointer into the data)
        pos = name_end + nxt
    out[start + 3] = 84
    scale = np.frombuffer(bytes(out[12:16]), dtype="<f4")[0]
    data_start = (int.from_bytes(bytes(out[16:18]), "little") - 1) * 512
    if not start < data_start <= len(data):
        return None
    _swap(out, data_start, len(out), 4 if scale < 0 else 2)
    return bytes(out)
