"""CSV readers and writers: Vicon Nexus, OptiTrack Motive, long-format point clouds."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import FormatError, OutputExistsError, SkincapError, UnitWarning
from skincap.io.c3d import read_c3d
from skincap.io.csv import (
    read_csv,
    read_optitrack_csv,
    read_points_csv,
    read_vicon_csv,
    write_points_csv,
    write_vicon_csv,
)
from skincap.types import MarkerSet, PointCloud

DATA = Path(__file__).resolve().parents[1] / "data"
VICON = DATA / "pyomeca_vicon_nexus_trajectories.csv"
VICON_C3D = DATA / "pyomeca_markers_analogs.c3d"


# --------------------------------------------------------------------------- Vicon
def test_vicon_real_file():
    m = read_vicon_csv(VICON)
    assert m.positions.shape == (580, 51, 3)
    assert m.rate == 100.0
    assert m.labels[0] == "boite:gauche_ext" and m.labels[-1] == "Daphnee:LATH"
    assert m.meta["first_frame"] == 1 and m.meta["up"] == "z" and m.meta["source_units"] == "mm"
    assert m.missing.sum() == 305
    # first row, first marker: 44.1628,-276.862,675.697 mm, Z up -> (x, z, -y) metres
    np.testing.assert_allclose(m.positions[0, 0], [0.0441628, 0.675697, 0.276862])


def test_vicon_csv_agrees_with_the_c3d_of_the_same_session():
    """Same labels, frames and missing samples; positions to the CSV's 6 digits.

    No frame offset: CSV frame 1 is the C3D's first frame (header frame 1); shifting
    either by one frame makes the positions differ by ~19 mm.
    """
    v = read_vicon_csv(VICON)
    c = read_c3d(VICON_C3D)
    assert v.labels == c.labels
    assert v.n_frames == c.n_frames and v.meta["first_frame"] == c.meta["first_frame"]
    np.testing.assert_array_equal(v.missing, c.missing)
    both = ~v.missing
    diff = np.abs(v.positions - c.positions)[both]
    # Nexus prints 6 significant digits: half a unit of the 6th digit is <= 5e-6 relative
    assert diff.max() <= 5.0e-6
    assert (diff <= 5.0e-6 * np.abs(c.positions[both]).max(axis=1, keepdims=True) + 1e-9).all()
    shifted = np.nanmax(np.abs(v.positions[1:] - c.positions[:-1]))
    assert shifted > 1e-3


def test_vicon_round_trip(tmp_path):
    m = read_vicon_csv(VICON)
    f = tmp_path / "out.csv"
    write_vicon_csv(m, f)
    r = read_vicon_csv(f)
    assert r.labels == m.labels and r.rate == m.rate and r.meta["first_frame"] == 1
    np.testing.assert_array_equal(r.missing, m.missing)
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-15, atol=1e-15)
    assert f.read_bytes().startswith(b"Trajectories,")
    with pytest.raises(OutputExistsError):
        write_vicon_csv(m, f)


def test_vicon_reads_only_the_trajectories_section(tmp_path):
    body = VICON.read_text()
    devices = "Devices,,\r\n1000,,\r\n,,Imported AMTI:Force\r\nFrame,Sub Frame,Fx\r\n,,N\r\n1,0,5.0\r\n1,1,5.5\r\n\r\n"
    outputs = "\r\nModel Outputs,,\r\n100,,\r\n,,Daphnee:Angle,,\r\nFrame,Sub Frame,X,Y,Z\r\n,,deg,deg,deg\r\n1,0,1,2,3\r\n"
    f = tmp_path / "sections.csv"
    f.write_text(devices + body.rstrip("\r\n") + outputs, newline="")
    m = read_vicon_csv(f)
    ref = read_vicon_csv(VICON)
    assert m.labels == ref.labels and m.n_frames == 580
    np.testing.assert_array_equal(m.positions, ref.positions)
    # a section title straight after the data (no blank line) also ends it
    f.write_text(body.rstrip("\r\n") + "\r\nModel Outputs,,\r\n100,,\r\n", newline="")
    assert read_vicon_csv(f).n_frames == 580


def _vicon_small(tmp_path, rows: list[str]) -> Path:
    head = [
        "Trajectories",
        "100",
        ",,S:A,,,S:B,,",
        "Frame,Sub Frame,X,Y,Z,X,Y,Z",
        ",,mm,mm,mm,mm,mm,mm",
    ]
    f = tmp_path / "small.csv"
    f.write_text("\n".join(head + rows) + "\n")
    return f


@pytest.mark.parametrize(
    ("rows", "line", "match"),
    [
        (["1,0,1,2,3,4,5,6", "2,0,1,2,3,4,5"], 7, "fields"),
        (["1,0,1,2,3,4,5,6", "2,0,1,x,3,4,5,6"], 7, "not a finite number"),
        (["1,0,1,2,3,4,5,6", "3,0,1,2,3,4,5,6"], 7, "consecutive"),
        (["1,0,1,2,3,4,5,6", "2,1,1,2,3,4,5,6"], 7, "sub-frames"),
        (["1,0,1,2,3,4,5,6,7"], 6, "fields"),
    ],
)
def test_vicon_bad_rows(tmp_path, rows, line, match):
    f = _vicon_small(tmp_path, rows)
    with pytest.raises(FormatError, match=match) as e:
        read_vicon_csv(f)
    assert e.value.line == line and "small.csv" in str(e.value)


def test_vicon_missing_section(tmp_path):
    f = tmp_path / "x.csv"
    f.write_text("Devices\n1000\n")
    with pytest.raises(FormatError, match="Trajectories"):
        read_vicon_csv(f)


# ----------------------------------------------------------------------- OptiTrack
def _motive_text(units: str | None = "Millimeters", timecode: bool = False) -> str:
    """A Motive 1.23 CSV export built by hand from the documented layout.

    Columns: rigid body "Pelvis" (quaternion X,Y,Z,W, position X,Y,Z, mean marker
    error), one of its solved rigid-body markers (X,Y,Z, marker quality), two
    labelled markers and one unlabelled marker; occlusions are empty cells.
    """
    meta = [
        "Format Version", "1.23", "Take Name", "walk_001", "Take Notes", "",
        "Capture Frame Rate", "120.000000", "Export Frame Rate", "120.000000",
        "Capture Start Time", "2021-03-04 10.11.12.123 AM", "Capture Start Frame", "1024",
        "Total Frames in Take", "4", "Total Exported Frames", "4", "Rotation Type", "Quaternion",
    ]  # fmt: skip
    if units is not None:
        meta += ["Length Units", units]
    meta += ["Coordinate Space", "Global"]
    cols = (
        [("Rigid Body", "Pelvis", "1", "Rotation", a) for a in "XYZW"]
        + [("Rigid Body", "Pelvis", "1", "Position", a) for a in "XYZ"]
        + [("Rigid Body", "Pelvis", "1", "Mean Marker Error", "")]
        + [("Rigid Body Marker", "Pelvis:Marker1", "1:1", "Position", a) for a in "XYZ"]
        + [("Rigid Body Marker", "Pelvis:Marker1", "1:1", "Marker Quality", "")]
        + [("Marker", "Subject:LASI", "2:1", "Position", a) for a in "XYZ"]
        + [("Marker", "Subject:RASI", "2:2", "Position", a) for a in "XYZ"]
        + [("Marker", "Unlabeled 1234", "3:1234", "Position", a) for a in "XYZ"]
    )
    lead = ["", ""] + ([""] if timecode else [])
    lines = [",".join(meta), ""]
    lines.append(",".join(lead[:-1] + ["Type"] + [c[0] for c in cols]))
    lines.append(",".join(lead[:-1] + ["Name"] + [c[1] for c in cols]))
    lines.append(",".join(lead[:-1] + ["ID"] + [c[2] for c in cols]))
    lines.append(",".join(lead + [c[3] for c in cols]))
    lines.append(
        ",".join(
            ["Frame", "Time (Seconds)"] + (["TimeCode"] if timecode else []) + [c[4] for c in cols]
        )
    )
    rng = np.random.default_rng(5)
    for f in range(4):
        vals = ["0.0", "0.0", "0.0", "1.0", "100.5", "950.25", "-20.0", "0.0004"]
        vals += ["110.0", "960.0", "-25.0", "1.0"]
        mk = [f"{v:.6f}" for v in rng.uniform(-900, 900, 9)]
        if f == 2:
            mk[3:6] = ["", "", ""]  # RASI occluded
        if f == 3:
            mk[6:9] = ["", "", ""]  # unlabelled marker gone: trailing empty cells
        row = [str(f), f"{f / 120:.6f}"] + ([f"10:11:12:{f:02d}.0"] if timecode else []) + vals + mk
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def test_optitrack_markers_only(tmp_path):
    f = tmp_path / "take.csv"
    f.write_text(_motive_text())
    m = read_optitrack_csv(f)
    assert m.labels == ["Subject:LASI", "Subject:RASI", "*1234"]
    assert m.unlabelled.tolist() == [False, False, True]
    assert m.rate == 120.0 and m.n_frames == 4
    assert m.meta["source_units"] == "mm" and m.meta["up"] == "y" and m.meta["first_frame"] == 0
    assert m.meta["marker_ids"] == ["2:1", "2:2", "3:1234"]
    assert m.missing.tolist() == [
        [False] * 3,
        [False] * 3,
        [False, True, False],
        [False, False, True],
    ]
    rows = f.read_text().splitlines()
    first = rows[7].split(",")
    np.testing.assert_allclose(m.positions[0, 0], np.array(first[14:17], dtype=float) / 1000.0)


def test_optitrack_timecode_column_and_metres(tmp_path):
    f = tmp_path / "tc.csv"
    f.write_text(_motive_text(units="Meters", timecode=True))
    m = read_optitrack_csv(f)
    g = tmp_path / "plain.csv"
    g.write_text(_motive_text(units="Meters"))
    ref = read_optitrack_csv(g)
    assert m.labels == ref.labels
    np.testing.assert_array_equal(m.positions, ref.positions)
    assert np.nanmax(np.abs(m.positions)) > 100  # metres taken as they are


def test_optitrack_without_units_warns(tmp_path):
    f = tmp_path / "old.csv"
    f.write_text(_motive_text(units=None))
    with pytest.warns(UnitWarning, match="old.csv.*Meters"):
        m = read_optitrack_csv(f)
    assert m.meta["source_units"] == "m"


def test_optitrack_bad_rows(tmp_path):
    text = _motive_text().splitlines()
    text[9] = text[9].replace("100.5", "abc")
    f = tmp_path / "bad.csv"
    f.write_text("\n".join(text) + "\n")
    # a bad rigid-body value is not read, so it is harmless ...
    assert read_optitrack_csv(f).n_frames == 4
    text[9] = text[9].replace(text[9].split(",")[-1], "1e999")
    f.write_text("\n".join(text) + "\n")
    with pytest.raises(FormatError, match="finite") as e:
        read_optitrack_csv(f)
    assert e.value.line == 10
    text = _motive_text().splitlines()
    text[8] = text[8].replace("0.008333", "0.5")
    f.write_text("\n".join(text) + "\n")
    with pytest.raises(FormatError, match="disagrees") as e:
        read_optitrack_csv(f)
    assert e.value.line == 9


# -------------------------------------------------------------------- point clouds
def _cloud(seed=0, empty=(2, 5), ids=True) -> PointCloud:
    rng = np.random.default_rng(seed)
    counts = rng.integers(1, 5, 7)
    counts[list(empty)] = 0
    offsets = np.concatenate([[0], np.cumsum(counts)])
    pts = rng.normal(size=(offsets[-1], 3))
    return PointCloud(pts, offsets, 119.88, ids=rng.integers(-1, 20, offsets[-1]) if ids else None)


@pytest.mark.parametrize("ids", [True, False])
def test_points_round_trip_exact(tmp_path, ids):
    c = _cloud(ids=ids)
    f = tmp_path / "p.csv"
    write_points_csv(c, f)
    r = read_points_csv(f)
    np.testing.assert_array_equal(r.points, c.points)
    np.testing.assert_array_equal(r.offsets, c.offsets)
    assert r.rate == c.rate and r.n_frames == 7
    if ids:
        np.testing.assert_array_equal(r.ids, c.ids)
    else:
        assert r.ids is None
    assert f.read_text().startswith("# rate=119.88\n# frames=7\nframe,time,x,y,z")
    assert isinstance(read_csv(f), PointCloud)


def test_points_trailing_empty_frames(tmp_path):
    c = PointCloud(np.ones((2, 3)), [0, 1, 2, 2, 2], 50.0)
    f = tmp_path / "p.csv"
    write_points_csv(c, f)
    r = read_points_csv(f)
    assert r.n_frames == 4 and r.counts.tolist() == [1, 1, 0, 0]


def test_points_rate_inferred(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("frame,time,x,y,z\n0,0.5,1,2,3\n0,0.5,4,5,6\n3,0.53,1,1,1\n")
    r = read_points_csv(f)
    assert r.rate == pytest.approx(100.0)
    assert r.counts.tolist() == [2, 0, 0, 1]
    assert r.meta["start_time"] == pytest.approx(0.5)
    f.write_text("frame,time,x,y,z\n0,0,1,2,3\n1,0.01,1,2,3\n2,0.025,1,2,3\n4,0.04,1,1,1\n")
    with pytest.raises(FormatError, match="disagrees") as e:
        read_points_csv(f)
    assert e.value.line == 4
    f.write_text("frame,time,x,y,z\n0,0,1,2,3\n0,0,1,2,3\n")
    with pytest.raises(FormatError, match="rate="):
        read_points_csv(f)
    f.write_text("# rate=30\nframe,time,x,y,z\n0,0,1,2,3\n")
    assert read_points_csv(f).rate == 30.0


@pytest.mark.parametrize(
    ("body", "line", "match"),
    [
        ("0,0,1,2,3\n1,0.1,1,2\n", 3, "fields"),
        ("0,0,1,2,3\n1,0.1,1,z,3\n", 3, "finite"),
        ("0,0,1,2,3\n1,0.1,1,,3\n", 3, "empty"),
        ("1,0.1,1,2,3\n0,0,1,2,3\n", 3, "non-decreasing"),
        ("0,0,1,2,3\n1.5,0.1,1,2,3\n", 3, "integers"),
        ("0,0,1,2,3\n1,0.1,1,2,nan\n", 3, "non-finite"),
        ("0,0,1,2,3\n99999999999,0.01,1,2,3\n", 3, "at most 10000000 frames"),
        ("0,0,1,2,3\n1e300,0.01,1,2,3\n", 3, "at most 10000000 frames"),
    ],
)
def test_points_bad_rows(tmp_path, body, line, match):
    f = tmp_path / "pts.csv"
    f.write_text("frame,time,x,y,z\n" + body)
    with pytest.raises(FormatError, match=match) as e:
        read_points_csv(f)
    assert e.value.line == line and "pts.csv" in str(e.value)


def test_points_ids_beyond_exact_floats_are_refused_not_wrapped(tmp_path):
    """1e20 became -9223372036854775808 (with a cast warning); 2**53 + 1 read as 2**53."""
    f = tmp_path / "pts.csv"
    for big in ("99999999999999999999", "9007199254740993", "-1e19"):
        f.write_text(f"frame,time,x,y,z,id\n0,0,0,0,0,1\n1,0.01,1,1,1,{big}\n")
        with pytest.raises(
            FormatError, match=r"ids must be integers of magnitude below 2\*\*53"
        ) as e:
            read_points_csv(f)
        assert e.value.line == 3
    f.write_text(f"frame,time,x,y,z,id\n0,0,0,0,0,{2**53 - 1}\n1,0.01,1,1,1,-1\n")
    assert read_points_csv(f).ids.tolist() == [2**53 - 1, -1]


@pytest.mark.parametrize("bad", ["-2", "-5", "-1e15"])
def test_points_negative_ids_other_than_unknown_are_refused(tmp_path, bad):
    """-1 means unknown; -5 was read as an identity of its own."""
    f = tmp_path / "pts.csv"
    f.write_text(f"frame,time,x,y,z,id\n0,0,0,0,0,-1\n1,0.01,1,1,1,{bad}\n")
    with pytest.raises(FormatError, match=r"ids must be >= 0, or -1 for unknown") as e:
        read_points_csv(f)
    assert e.value.line == 3 and "pts.csv" in str(e.value)


def test_points_declared_frame_count_is_bounded(tmp_path):
    # '# frames=' past the bound would size the offsets (T + 1,) from the header alone
    f = tmp_path / "pts.csv"
    f.write_text("# rate=100\n# frames=99999999999\nframe,time,x,y,z\n0,0,1,2,3\n")
    with pytest.raises(FormatError, match=r"pts\.csv.*frames=99999999999.*at most 10000000"):
        read_points_csv(f)
    f.write_text("# rate=100\n# frames=10000000\nframe,time,x,y,z\n0,0,1,2,3\n")
    assert read_points_csv(f).n_frames == 10_000_000


# --------------------------------------------------------------------------- sniff
def test_read_csv_sniffs(tmp_path):
    assert read_csv(VICON).n_markers == 51
    f = tmp_path / "t.csv"
    f.write_text(_motive_text())
    assert read_csv(f).labels[-1] == "*1234"
    g = tmp_path / "what.csv"
    g.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(FormatError, match="what.csv.*unrecognised"):
        read_csv(g)


# ---------------------------------------------------------------------------- fuzz
_FUZZ_SOURCES = {
    "vicon": "\n".join(VICON.read_text().splitlines()[:12]).encode(),
    "motive": _motive_text().encode(),
    "points": b"# rate=10\nframe,time,x,y,z,id\n0,0,1,2,3,4\n0,0,1,2,3,-1\n2,0.2,1.5,2,3,4\n",
}


@settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    kind=st.sampled_from(sorted(_FUZZ_SOURCES)),
    edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=4),
    cut=st.one_of(st.none(), st.integers(0, 10**6)),
    insert=st.one_of(
        st.none(), st.tuples(st.integers(0, 10**6), st.binary(min_size=1, max_size=6))
    ),
    delete=st.one_of(st.none(), st.tuples(st.integers(0, 10**6), st.integers(1, 30))),
)
def test_fuzz_parsed_or_format_error(tmp_path, kind, edits, cut, insert, delete):
    src = _FUZZ_SOURCES[kind]
    data = bytearray(src)
    for k, v in edits:
        data[k % len(data)] = v
    if delete is not None:
        k = delete[0] % len(src)
        del data[k : k + delete[1]]
    if insert is not None:
        k = insert[0] % (len(data) + 1)
        data[k:k] = insert[1]
    if cut is not None:
        data = data[: cut % (len(data) + 1)]
    f = tmp_path / "fuzz.csv"
    f.write_bytes(bytes(data))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnitWarning)
            out = read_csv(f)
    except SkincapError:
        return
    assert isinstance(out, MarkerSet | PointCloud)


def test_vicon_writer_uses_z_up_for_other_sources(tmp_path):
    m = read_vicon_csv(VICON)
    y_src = MarkerSet(m.positions, m.labels, m.rate, meta={"source_format": "trc", "up": "y"})
    f = tmp_path / "z.csv"
    write_vicon_csv(y_src, f)
    r = read_vicon_csv(f)  # "auto" = Z up, as the writer wrote
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-15, atol=1e-15)
    written = np.array(f.read_text().splitlines()[5].split(",")[2:5], dtype=float)
    source = np.array(VICON.read_text().splitlines()[5].split(",")[2:5], dtype=float)
    np.testing.assert_allclose(written, source, rtol=1e-15)  # same axes as Nexus wrote
