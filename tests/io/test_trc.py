"""TRC reader and writer: OpenSim's layout, round trips, real data via C3D, bad input."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import FormatError, OutputExistsError, SkincapError, UnitWarning
from skincap.io.c3d import read_c3d
from skincap.io.trc import read_trc, write_trc
from skincap.types import MarkerSet

DATA = Path(__file__).resolve().parents[1] / "data"
C3D_FILES = sorted(DATA.glob("*.c3d"))


def _opensim_tokens(line: str) -> list[str]:
    """OpenSim FileAdapter::tokenize: one token per delimiter, a last one if not empty."""
    tokens = line.split("\t")
    if tokens and tokens[-1] == "":
        tokens.pop()
    return tokens


def _markers(t=6, n=3, seed=0) -> MarkerSet:
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1.0, 2.0, (t, n, 3))
    pos[1, 0] = np.nan
    pos[2, n - 1] = np.nan  # the last marker missing: the row's last fields are empty
    return MarkerSet(pos, [f"M{i}" for i in range(n)], 120.0)


def test_layout_is_what_opensim_parses(tmp_path):
    m = _markers()
    f = tmp_path / "walk.trc"
    write_trc(m, f)
    lines = f.read_text().split("\n")
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\twalk.trc"
    assert (
        lines[1]
        == "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames"
    )
    assert lines[2] == "120.0\t120.0\t6\t3\tmm\t120.0\t1\t6"
    assert lines[3] == "Frame#\tTime\tM0\t\t\tM1\t\t\tM2\t\t\t"
    assert lines[4] == "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3\t"
    assert lines[5] == ""  # OpenSim's own writer puts an empty line before the data
    rows = [ln for ln in lines[6:] if ln]
    assert len(rows) == 6
    for row in rows:  # OpenSim's RowLengthMismatch check
        assert len(_opensim_tokens(row)) == 2 + 3 * 3
    assert _opensim_tokens(rows[2])[-3:] == ["", "", ""]
    assert rows[0].split("\t")[:2] == ["1", "0"]


def test_round_trip_exact(tmp_path):
    m = _markers(t=20, n=5, seed=1)
    f = tmp_path / "a.trc"
    write_trc(m, f)
    r = read_trc(f)
    assert r.labels == m.labels and r.rate == m.rate
    np.testing.assert_array_equal(r.missing, m.missing)
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-15, atol=1e-15)
    assert r.meta["source_units"] == "mm" and r.meta["up"] == "y" and r.meta["first_frame"] == 1
    with pytest.raises(OutputExistsError):
        write_trc(m, f)


def test_round_trip_metres_z_up(tmp_path):
    m = _markers(seed=2)
    f = tmp_path / "z.trc"
    write_trc(m, f, units="m", up="z")
    r = read_trc(f, up="z")
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-15, atol=1e-15)
    plain = read_trc(f)  # read as Y up: the file's axes as they are
    np.testing.assert_allclose(plain.positions[..., 2], m.positions[..., 1])


@pytest.mark.parametrize("path", C3D_FILES, ids=lambda p: p.stem)
def test_real_c3d_through_trc(path, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        m = read_c3d(path)
    f = tmp_path / "x.trc"
    write_trc(m, f)
    r = read_trc(f)
    assert r.labels == m.labels and r.rate == m.rate and r.n_frames == m.n_frames
    np.testing.assert_array_equal(r.missing, m.missing)
    np.testing.assert_allclose(r.positions, m.positions, rtol=0, atol=1e-9)
    assert r.meta["first_frame"] == m.meta["first_frame"]


HAND = (
    "PathFileType\t4\t(X/Y/Z)\thand.trc\r\n"
    "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\t\r\n"
    "60.00\t60.00\t3\t2\tmm\t60.00\t1\t3\r\n"
    "Frame#\tTime\tR.ASIS\t\t\tL.ASIS\r\n"
    "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\r\n"
    "\r\n"
    "\r\n"
    "1\t0.000\t1000\t900\t10\t1100\t905\t-5\r\n"
    "2\t0.017\tNaN\tNaN\tNaN\t1101\t906\t-6\t\t\r\n"
    "3\t0.033\t1002\t902\t12\t\t\t\r\n"
    "\r\n"
)


def test_tolerant_reader(tmp_path):
    f = tmp_path / "hand.trc"
    f.write_bytes(HAND.encode())
    m = read_trc(f)
    assert m.labels == ["R.ASIS", "L.ASIS"] and m.rate == 60.0
    assert m.missing.tolist() == [[False, False], [True, False], [False, True]]
    np.testing.assert_allclose(m.positions[0, 0], [1.0, 0.9, 0.01])
    assert m.meta["start_time"] == 0.0


@pytest.mark.parametrize(
    ("old", "new", "line", "match"),
    [
        ("DataRate\tCameraRate", "Rate\tCameraRate", 2, "keys"),
        ("60.00\t60.00\t3", "60.00\t60.00\t4", 10, "NumFrames"),
        ("1101\t906\t-6", "1101\tabc\t-6", 9, "not a finite number"),
        ("1101\t906\t-6", "1101\tinf\t-6", 9, "not a finite number"),
        ("1\t0.000\t1000\t900\t10\t1100\t905\t-5", "1\t0.000\t1000\t900\t10\t1100", 8, "fields"),
        ("3\t0.033", "4\t0.033", 10, "consecutive"),
        ("3\t0.033", "3\t0.5", 10, "DataRate"),
        ("\tmm\t", "\tfurlong\t", 3, "Units"),
        ("X2\tY2\tZ2", "X2\tY2\tW2", 5, "line 5"),
        ("L.ASIS\r", "\r", 4, "NumMarkers"),
        ("PathFileType", "Path", 1, "PathFileType"),
    ],
)
def test_bad_files_name_the_line(tmp_path, old, new, line, match):
    f = tmp_path / "bad.trc"
    f.write_bytes(HAND.replace(old, new, 1).encode())
    with pytest.raises(FormatError, match=match) as e:
        read_trc(f)
    assert e.value.line == line
    assert "bad.trc" in str(e.value)


def test_not_text(tmp_path):
    f = tmp_path / "bin.trc"
    f.write_bytes(b"PathFileType\t4\n\xff\xfe\x00garbage")
    with pytest.raises(FormatError):
        read_trc(f)
    f.write_bytes(b"")
    with pytest.raises(FormatError, match="empty"):
        read_trc(f)


_VALID = HAND.encode()


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    edits=st.lists(st.tuples(st.integers(0, len(_VALID) - 1), st.integers(0, 255)), max_size=4),
    cut=st.one_of(st.none(), st.integers(0, len(_VALID))),
    insert=st.one_of(
        st.none(), st.tuples(st.integers(0, len(_VALID)), st.binary(min_size=1, max_size=6))
    ),
    delete=st.one_of(st.none(), st.tuples(st.integers(0, len(_VALID)), st.integers(1, 20))),
)
def test_fuzz_parsed_or_format_error(tmp_path, edits, cut, insert, delete):
    data = bytearray(_VALID)
    for k, v in edits:
        data[k] = v
    if delete is not None:
        del data[delete[0] : delete[0] + delete[1]]
    if insert is not None:
        data[insert[0] : insert[0]] = insert[1]
    if cut is not None:
        data = data[:cut]
    f = tmp_path / "fuzz.trc"
    f.write_bytes(bytes(data))
    try:
        m = read_trc(f)
    except SkincapError:
        return
    assert isinstance(m, MarkerSet) and m.positions.shape[2] == 3
