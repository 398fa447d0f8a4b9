"""The checks run before ezc3d opens a C3D: every rule on a hand-built file, real files pass.

These tests call :func:`check_before_ezc3d` directly, so a rule that stops working makes
a test fail, never crashes the test run (the CLI reproducers run in a child process:
``tests/fuzz/test_reproducers.py``).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from skincap.errors import FormatError
from skincap.io.c3d import read_c3d
from skincap.io.c3d.checks import MAX_SAMPLES_PER_FRAME, check_before_ezc3d

DATA = Path(__file__).parents[1] / "data"
CHAR, BYTE, INT, FLOAT = -1, 1, 2, 4


def _param(kind: int, dims: list[int], values: list) -> tuple[int, list[int], bytes]:
    if kind == CHAR:
        raw = "".join(str(v).ljust(dims[0]) for v in values).encode("latin-1") if dims else b""
    else:
        raw = struct.pack("<" + {BYTE: "b", INT: "h", FLOAT: "f"}[kind] * len(values), *values)
    return kind, dims, raw


def _base(n_points: int = 2, frames: int = 3) -> dict[str, dict[str, tuple]]:
    return {
        "POINT": {
            "USED": _param(INT, [], [n_points]),
            "SCALE": _param(FLOAT, [], [-1.0]),
            "RATE": _param(FLOAT, [], [100.0]),
            "FRAMES": _param(INT, [], [frames]),
            "LABELS": _param(CHAR, [4, n_points], [f"M{i}" for i in range(n_points)]),
            "UNITS": _param(CHAR, [2], ["mm"]),
        },
        "ANALOG": {
            "USED": _param(INT, [], [0]),
            "RATE": _param(FLOAT, [], [0.0]),
            "GEN_SCALE": _param(FLOAT, [], [1.0]),
            "SCALE": _param(FLOAT, [0], []),
            "OFFSET": _param(INT, [0], []),
        },
    }


def _c3d(
    groups: dict[str, dict[str, tuple]],
    *,
    n_points: int = 2,
    frames: int = 3,
    first: int = 1,
    last: int | None = None,
    analog_words: int = 0,
    byframe: int = 0,
    processor: int = 84,
    data: bytes | None = None,
    pointer_slack: int = 0,
) -> bytes:
    """A C3D from scratch: 512-byte header, parameter records, float point data.

    ``pointer_slack`` adds bytes to the first record's pointer (a chaining fault).
    """
    records = []
    for gid, (gname, params) in enumerate(groups.items(), start=1):
        name = gname.encode()
        records.append(bytes([len(name), (-gid) & 0xFF]) + name + struct.pack("<H", 3) + b"\0")
        for pname, (kind, dims, raw) in params.items():
            body = bytes([kind & 0xFF, len(dims) & 0xFF, *dims]) + raw + b"\0"
            n = pname.encode()
            records.append(bytes([len(n), gid]) + n + struct.pack("<H", 2 + len(body)) + body)
    if pointer_slack:
        r = bytearray(records[0])
        at = 2 + r[0]
        struct.pack_into("<H", r, at, struct.unpack_from("<H", r, at)[0] + pointer_slack)
        records[0] = bytes(r)
    last_rec = bytearray(records[-1])
    struct.pack_into("<H", last_rec, 2 + last_rec[0], 0)  # a zero pointer ends the section
    records[-1] = bytes(last_rec)
    section = b"".join(records)
    nblocks = (4 + len(section)) // 512 + 1
    section = bytes([1, 0x50, nblocks, processor]) + section
    section += b"\0" * (nblocks * 512 - len(section))
    data_block = 2 + nblocks
    header = bytearray(512)
    header[0], header[1] = 2, 0x50
    last = frames if last is None else last
    struct.pack_into("<5H", header, 2, n_points, analog_words, first, last, 0)
    struct.pack_into("<f", header, 12, -1.0)
    struct.pack_into("<2H", header, 16, data_block, byframe)
    struct.pack_into("<f", header, 20, 100.0)
    if data is None:
        xyz = np.arange(1, 1 + frames * n_points * 3, dtype="<f4").reshape(frames, n_points, 3)
        data = np.concatenate([xyz, np.zeros((frames, n_points, 1), "<f4")], axis=2).tobytes()
    return bytes(header) + section + data


def _refused(tmp_path: Path, data: bytes, match: str) -> None:
    p = tmp_path / "t.c3d"
    p.write_bytes(data)
    with pytest.raises(FormatError, match=match):
        check_before_ezc3d(p, data)


def test_hand_built_file_reads_back_exactly(tmp_path):
    p = tmp_path / "ok.c3d"
    data = _c3d(_base())
    p.write_bytes(data)
    check_before_ezc3d(p, data)
    m = read_c3d(p, up="z")
    assert m.labels == ["M0", "M1"] and m.n_frames == 3
    # (x, y, z) mm, Z up -> (x, z, -y) m, Y up
    xyz = np.arange(1, 19, dtype=float).reshape(3, 2, 3) / 1000.0
    np.testing.assert_allclose(m.positions, xyz[..., [0, 2, 1]] * [1, 1, -1], rtol=1e-7)


@pytest.mark.parametrize("path", sorted(DATA.glob("*.c3d")), ids=lambda p: p.name)
def test_every_real_file_passes(path):
    check_before_ezc3d(path, path.read_bytes())


@pytest.mark.parametrize(
    "group, name, param, match",
    [
        ("POINT", "RATE", _param(INT, [], [100]), "POINT:RATE is INT, expected FLOAT"),
        ("POINT", "RATE", _param(CHAR, [1], ["x"]), "POINT:RATE is CHAR, expected FLOAT"),
        ("POINT", "USED", _param(INT, [0], []), r"POINT:USED has no value \(dimensions \[0\]\)"),
        ("POINT", "USED", _param(INT, [0, 0], []), "POINT:USED has no value"),
        ("POINT", "USED", _param(INT, [], [-1]), "POINT:USED is negative"),
        (
            "POINT",
            "FRAMES",
            _param(FLOAT, [], [3.0]),
            "POINT:FRAMES is FLOAT, expected BYTE or INT",
        ),
        ("POINT", "FRAMES", _param(INT, [0], []), "POINT:FRAMES has no value"),
        ("POINT", "SCALE", _param(FLOAT, [0], []), "POINT:SCALE has no value for 2 points"),
        ("POINT", "RATE", _param(FLOAT, [], [float("nan")]), "POINT:RATE is nan, not a rate"),
        ("POINT", "RATE", _param(FLOAT, [], [-100.0]), "POINT:RATE is -100, not a rate"),
        ("POINT", "RATE", _param(FLOAT, [], [1e30]), "POINT:RATE is 1e[+]30, not a rate"),
        ("ANALOG", "USED", _param(INT, [0, 0], []), "ANALOG:USED has no value"),
        ("POINT", "SCALE", _param(CHAR, [1], ["x"]), "POINT:SCALE is CHAR, expected FLOAT"),
        ("ANALOG", "OFFSET", _param(FLOAT, [1], [0.0]), "ANALOG:OFFSET is FLOAT, expected BYTE"),
        ("ANALOG", "GEN_SCALE", _param(FLOAT, [0], []), "ANALOG:GEN_SCALE has no value"),
        ("ANALOG", "RATE", _param(FLOAT, [], [float("inf")]), "ANALOG:RATE is inf"),
    ],
)
def test_parameters_ezc3d_dereferences(tmp_path, group, name, param, match):
    groups = _base()
    groups[group][name] = param
    _refused(tmp_path, _c3d(groups), match)


def test_a_parameter_ezc3d_reads_may_be_absent(tmp_path):
    """ezc3d supplies defaults for missing mandatory parameters: that is no fault."""
    groups = _base()
    del groups["POINT"]["FRAMES"], groups["ANALOG"]["GEN_SCALE"], groups["ANALOG"]["RATE"]
    del groups["POINT"]["SCALE"]  # ezc3d's default -1.0: float data, 16 bytes a point
    p = tmp_path / "defaults.c3d"
    p.write_bytes(_c3d(groups))
    check_before_ezc3d(p, p.read_bytes())
    assert read_c3d(p).n_frames == 3


def test_analog_channels_need_a_scale_and_offset_each(tmp_path):
    groups = _base()
    groups["ANALOG"] |= {
        "USED": _param(INT, [], [2]),
        "RATE": _param(FLOAT, [], [200.0]),
        "SCALE": _param(FLOAT, [2], [1.0, 1.0]),
        "OFFSET": _param(INT, [1], [0]),
    }
    frame = 2 * 16 + 2 * 2 * 4  # 2 points, 2 subframes of 2 float channels
    data = _c3d(groups, analog_words=4, byframe=2, data=b"\0" * (3 * frame))
    _refused(tmp_path, data, "ANALOG:OFFSET has 1 values, 2 analog channels need one each")
    groups["ANALOG"]["OFFSET"] = _param(INT, [2], [0, 0])
    check_before_ezc3d("t.c3d", _c3d(groups, analog_words=4, byframe=2, data=b"\0" * (3 * frame)))


@pytest.mark.parametrize(
    "analog_rate, match",
    [
        (100.0 * (MAX_SAMPLES_PER_FRAME + 1), "analog samples per frame; a C3D holds at most"),
        # in range, but 1000 subframes of 3 channels a frame: 36 kB the file does not have
        (
            100.0 * 1000,
            r"3 frames of 12032 bytes from byte 1024 need 37120 bytes, the file has 1120",
        ),
    ],
)
def test_analog_subframes_are_bounded_by_the_file(tmp_path, analog_rate, match):
    """#13: ANALOG:RATE = 1e9 made ezc3d build 8 million subframes a frame (6.8 GB)."""
    groups = _base()
    groups["ANALOG"] |= {
        "USED": _param(INT, [], [3]),
        "RATE": _param(FLOAT, [], [analog_rate]),
        "SCALE": _param(FLOAT, [3], [1.0] * 3),
        "OFFSET": _param(INT, [3], [0] * 3),
    }
    _refused(tmp_path, _c3d(groups, analog_words=3, byframe=1), match)


def test_declared_frames_must_be_in_the_file(tmp_path):
    groups = _base(frames=1000)
    _refused(tmp_path, _c3d(groups, frames=3, last=1000), "1000 frames of 32 bytes")
    groups = _base(frames=0)
    _refused(
        tmp_path,
        _c3d(groups, first=5, last=2),
        r"the last frame \(2\) comes before the first \(5\)",
    )


def test_rotation_group_is_checked(tmp_path):
    groups = _base()
    groups["ROTATION"] = {"USED": _param(INT, [], [1]), "RATIO": _param(INT, [], [1])}
    _refused(tmp_path, _c3d(groups), "ROTATION:DATA_START is missing")
    groups["ROTATION"]["DATA_START"] = _param(INT, [], [4])
    groups["ROTATION"]["RATIO"] = _param(INT, [], [5000])
    _refused(tmp_path, _c3d(groups, data=b"\0" * (3 * 32 + 512)), "rotation data of 3 frames")
    groups["ROTATION"]["RATIO"] = _param(INT, [], [1])
    groups["ROTATION"]["DATA_START"] = _param(INT, [], [-3])
    _refused(tmp_path, _c3d(groups), "ROTATION:DATA_START is negative")


def _edit_record(data: bytes, name: bytes, offset_in_body: int, value: int) -> bytes:
    """Set one byte of the body (after the pointer) of the first record called ``name``."""
    body = data.index(name) + len(name) + 2
    b = bytearray(data)
    b[body + offset_in_body] = value & 0xFF
    return bytes(b)


def test_record_layout_faults(tmp_path):
    base = _c3d(_base())
    # UNITS: type CHAR, 1 dimension of 2: body = [0xFF, 1, 2, 'm', 'm', 0]
    _refused(tmp_path, _edit_record(base, b"UNITS", 1, -1), "negative dimension count -1")
    _refused(tmp_path, _edit_record(base, b"UNITS", 1, 0), "CHAR with no dimensions")
    _refused(tmp_path, _edit_record(base, b"UNITS", 5, -2), "negative description length -2")
    _refused(tmp_path, _edit_record(base, b"UNITS", 0, 3), "unknown data type 3")
    _refused(tmp_path, _edit_record(base, b"OFFSET", 2, 250), "overrun the parameter section")
    _refused(tmp_path, _edit_record(base, b"UNITS", 2, 250), "overruns the next record")
    _refused(tmp_path, _c3d(_base(), pointer_slack=1), "ends before the next record")
    _refused(tmp_path, _c3d(_base(), processor=86), "MIPS")
    _refused(tmp_path, _c3d(_base(), processor=0), "unknown processor type 0")
    b = bytearray(base)
    b[512 + 4 + 1] = 0  # the first record's group id
    _refused(tmp_path, bytes(b), "group id 0")
