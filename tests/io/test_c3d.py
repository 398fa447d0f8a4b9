"""C3D reader and writer: real files against raw ezc3d, round trips, malformed input."""

from __future__ import annotations

import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import (
    FormatError,
    OutputExistsError,
    SkincapError,
    SkincapWarning,
    UnitWarning,
    ValidationError,
)
from skincap.io._common import to_y_up
from skincap.io.c3d import read_c3d, write_c3d
from skincap.types import MarkerSet

DATA = Path(__file__).resolve().parents[1] / "data"
C3D_FILES = sorted(DATA.glob("*.c3d"))
PIG = DATA / "btk_pig_calibration_hole_unlabeled_fragments.c3d"
OLD = DATA / "c3dorg_sample01_Eb015pr.c3d"
AML = DATA / "aml_PronetoRun01_labeled.c3d"


def _read(path: Path) -> MarkerSet:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        return read_c3d(path)


def _raw(path: Path):
    c = ezc3d.c3d(str(path))
    labels = list(c["parameters"]["POINT"]["LABELS"]["value"])
    k = 2
    while f"LABELS{k}" in c["parameters"]["POINT"]:
        labels += c["parameters"]["POINT"][f"LABELS{k}"]["value"]
        k += 1
    n = c["data"]["points"].shape[1]
    return c, [s.strip() for s in labels[:n]]


def test_all_seven_files_present():
    assert len(C3D_FILES) == 7


@pytest.mark.parametrize("path", C3D_FILES, ids=lambda p: p.stem)
def test_matches_raw_ezc3d(path):
    m = _read(path)
    c, raw_labels = _raw(path)
    pts = c["data"]["points"]
    n_frames = pts.shape[2]
    assert m.n_frames == n_frames
    assert m.rate == pytest.approx(float(c["header"]["points"]["frame_rate"]), rel=1e-7)
    # markers + model outputs partition the raw labels, in file order
    outputs = [lab for g in m.meta["model_outputs"].values() for lab in g]
    assert sorted(m.labels + outputs) == sorted(raw_labels)
    cols = [raw_labels.index(lab) for lab in m.labels]
    raw = pts[:3, cols, :].transpose(2, 1, 0)  # (T, N, 3) file units
    raw_missing = np.isnan(raw).any(axis=2) | (raw == 0).all(axis=2)
    np.testing.assert_array_equal(m.missing, raw_missing)
    # units in metres, Z-up source rotated to Y up
    assert m.meta["source_units"] == "mm"
    expect = to_y_up(raw * 0.001, m.meta["up"])
    expect[raw_missing] = np.nan
    np.testing.assert_allclose(m.positions, expect, rtol=0, atol=1e-12)
    res = c["data"]["meta_points"]["residuals"][0][cols].T * 0.001
    np.testing.assert_allclose(m.residuals[~m.missing], res[~m.missing], atol=1e-12)
    assert np.isnan(m.residuals[m.missing]).all()
    assert m.meta["first_frame"] == c["header"]["points"]["first_frame"] + (
        1 if path.stem != "kt_optitrack_walking" else 0
    )


def test_known_counts():
    counts = {p.stem: _read(p) for p in C3D_FILES}
    assert counts["kt_optitrack_walking"].positions.shape == (3361, 12, 3)
    assert counts["kt_optitrack_walking"].rate == 160.0
    assert counts["cmu_85_02"].positions.shape == (810, 41, 3)
    assert counts["cmu_85_02"].missing.sum() == 0
    assert counts["aml_S09_KneeltoRun02_unlabeled"].unlabelled.all()
    assert counts["aml_S09_KneeltoRun02_unlabeled"].n_markers == 75
    assert counts["kt_optitrack_walking"].meta["first_frame"] == 0  # its header says 0
    assert counts["cmu_85_02"].meta["first_frame"] == 1


def test_old_file_with_more_labels_than_points():
    m = _read(OLD)
    c, _ = _raw(OLD)
    all_labels = c["parameters"]["POINT"]["LABELS"]["value"]
    assert len(all_labels) == 48 and m.n_markers == 26
    assert m.labels == [s.strip() for s in all_labels[:26]]
    assert m.meta["point_scale"] == pytest.approx(0.0833333, rel=1e-5)
    # residuals are kept, in metres
    assert np.nanmax(m.residuals) == pytest.approx(5.25e-3, rel=1e-6)


def test_pig_model_outputs_are_kept_apart():
    m = _read(PIG)
    assert m.n_markers == 35 + 66
    assert (~m.unlabelled).sum() == 35 and m.unlabelled.sum() == 66
    assert m.labels[:5] == ["LFHD", "RFHD", "LBHD", "RBHD", "C7"]
    outs = m.meta["model_outputs"]
    assert set(outs) == {"angles", "bones"}
    assert len(outs["angles"]) == 26 and len(outs["bones"]) == 76
    assert "LHipAngles" in outs["angles"] and "PELO" in outs["bones"]
    assert m.meta["model_output_units"]["angles"] == "deg"
    c, raw_labels = _raw(PIG)
    k = raw_labels.index("RFootProgressAngles")
    raw = c["data"]["points"][:3, k, :].T
    # not scaled to metres, not rotated
    np.testing.assert_array_equal(outs["angles"]["RFootProgressAngles"], raw)
    assert np.nanmax(np.abs(outs["angles"]["RFootProgressAngles"])) > 45.0
    assert not any(lab in m.labels for lab in outs["angles"])


def test_up_axis_from_screen_and_forced():
    m = _read(PIG)
    assert m.meta["up"] == "z" and not m.meta["up_guessed"]
    assert m.meta["screen_axes"] == ("+X", "+Z")
    forced = read_c3d(PIG, up="y")
    both = ~m.missing
    # Z-up read: skincap y is the file's z; forced Y-up read keeps coordinates
    np.testing.assert_allclose(m.positions[both][:, 1], forced.positions[both][:, 2])
    assert forced.meta["up"] == "y"
    aml = _read(AML)
    assert aml.meta["up"] == "z" and aml.meta["up_guessed"]


def test_empty_units_warns_and_guesses_mm():
    with pytest.warns(UnitWarning, match=r"aml_PronetoRun01_labeled.*guessing 'mm'"):
        m = read_c3d(AML)
    assert m.meta["source_units"] == "mm" and m.meta["units_guessed"]
    assert 0.5 < np.nanmax(np.abs(m.positions)) < 5.0  # a person in metres


def _ezc3d_file(path: Path, labels, pts, units=None, rate=100.0, extra=None):
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(labels)
    if units is not None:
        c.add_parameter("POINT", "UNITS", [units])
    for (g, k), v in (extra or {}).items():
        c.add_parameter(g, k, v)
    full = np.ones((4,) + pts.shape[1:])
    full[:3] = pts
    c["data"]["points"] = full
    c.write(str(path))
    return path


def test_units_in_metres_guessed(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.5, 1.5, (3, 4, 20))
    f = _ezc3d_file(tmp_path / "m.c3d", ["a", "b", "c", "d"], pts)
    with pytest.warns(UnitWarning, match="guessing 'm'"):
        m = read_c3d(f)
    assert m.meta["source_units"] == "m"
    np.testing.assert_allclose(m.positions, to_y_up(pts.transpose(2, 1, 0), "z"), atol=1e-6)


def test_cm_units_converted(tmp_path):
    pts = np.full((3, 1, 5), 100.0)
    f = _ezc3d_file(tmp_path / "cm.c3d", ["a"], pts, units="cm")
    m = read_c3d(f)
    np.testing.assert_allclose(m.positions[0, 0], [1.0, 1.0, -1.0])


def test_empty_and_duplicate_labels_made_unique(tmp_path):
    pts = np.full((3, 4, 3), 500.0)
    f = _ezc3d_file(tmp_path / "dup.c3d", ["A", "A", "", "A_2"], pts, units="mm")
    m = read_c3d(f)
    assert m.labels == ["A", "A_3", "point_3", "A_2"]
    assert m.meta["renamed_labels"] == {"A_3": "A", "point_3": ""}


def test_zero_samples_are_missing(tmp_path):
    pts = np.full((3, 2, 4), 500.0)
    pts[:, 1, 2] = 0.0
    pts[0, 0, 1] = 0.0  # one zero coordinate is a real value
    f = _ezc3d_file(tmp_path / "z.c3d", ["a", "b"], pts, units="mm")
    m = read_c3d(f)
    assert m.missing.sum() == 1 and m.missing[2, 1]
    assert m.meta["zeros_as_missing"] == 1


# ------------------------------------------------------------------------ round trip
def _assert_same(a: MarkerSet, b: MarkerSet, atol: float = 0.0) -> None:
    assert a.labels == b.labels
    assert a.rate == b.rate
    assert a.meta["first_frame"] == b.meta["first_frame"]
    np.testing.assert_array_equal(a.missing, b.missing)
    np.testing.assert_allclose(a.positions, b.positions, rtol=1e-7, atol=atol)  # float32 storage
    np.testing.assert_allclose(a.residuals, b.residuals, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("path", C3D_FILES, ids=lambda p: p.stem)
def test_round_trip_real_files(path, tmp_path):
    m = _read(path)
    out = tmp_path / "out.c3d"
    write_c3d(m, out)
    r = read_c3d(out)
    _assert_same(m, r)
    assert r.meta["source_units"] == m.meta["source_units"] and r.meta["up"] == m.meta["up"]
    assert not r.meta["units_guessed"]
    for g, series in m.meta["model_outputs"].items():
        assert list(r.meta["model_outputs"][g]) == list(series)
        for lab, arr in series.items():
            np.testing.assert_allclose(r.meta["model_outputs"][g][lab], arr, rtol=1e-6)
    # a second trip is exact: the values are float32 already
    out2 = tmp_path / "out2.c3d"
    write_c3d(r, out2)
    r2 = read_c3d(out2)
    np.testing.assert_array_equal(r2.positions, r.positions)
    # raw ezc3d reads what we wrote
    c, raw_labels = _raw(out)
    # the markers' columns, wherever the source's order puts them among model outputs
    cols = [raw_labels.index(lab) for lab in m.labels]
    assert c["parameters"]["POINT"]["UNITS"]["value"] == [m.meta["source_units"]]
    res = c["data"]["meta_points"]["residuals"][0, cols].T
    assert (res[m.missing] == -1).all() and (res[~m.missing] >= 0).all()
    assert np.isnan(c["data"]["points"][0, cols].T[m.missing]).all()


def test_synthetic_300_markers_labels2_invented(tmp_path):
    rng = np.random.default_rng(3)
    t, n = 12, 300
    pos = rng.uniform(-1.0, 2.0, (t, n, 3))
    pos[rng.random((t, n)) < 0.1] = np.nan
    res = np.where(np.isnan(pos[..., 0]), np.nan, rng.integers(0, 200, (t, n)) * 1e-5)
    inv = (rng.random((t, n)) < 0.1) & ~np.isnan(pos[..., 0])
    labels = [f"S:M{i:03d}" for i in range(n - 10)] + [f"*{i}" for i in range(10)]
    m = MarkerSet(pos, labels, 59.94, residuals=res, invented=inv, meta={"first_frame": 10})
    out = tmp_path / "dense.c3d"
    write_c3d(m, out, units="mm", up="z")
    c, raw_labels = _raw(out)
    assert len(c["parameters"]["POINT"]["LABELS"]["value"]) == 255
    assert len(c["parameters"]["POINT"]["LABELS2"]["value"]) == 45
    assert raw_labels == labels
    r = read_c3d(out)
    assert r.rate == 59.94  # the float32 in the file, printed at shortest precision
    assert r.meta["first_frame"] == 10
    assert r.labels == labels and r.unlabelled.sum() == 10
    np.testing.assert_array_equal(r.missing, m.missing)
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(r.residuals, m.residuals, atol=1e-9)
    np.testing.assert_array_equal(r.invented, inv)
    with pytest.raises(OutputExistsError):
        write_c3d(m, out)
    write_c3d(m, out, force=True)


def test_writer_units_and_up_override(tmp_path):
    m = _read(DATA / "cmu_85_02.c3d")
    out = tmp_path / "y_up_m.c3d"
    write_c3d(m, out, units="m", up="y")
    c, _ = _raw(out)
    assert c["parameters"]["POINT"]["UNITS"]["value"] == ["m"]
    assert c["parameters"]["POINT"]["Y_SCREEN"]["value"] == ["+Y"]
    np.testing.assert_allclose(c["data"]["points"][:3].transpose(2, 1, 0), m.positions, rtol=1e-6)
    r = read_c3d(out)
    np.testing.assert_allclose(r.positions, m.positions, rtol=1e-6)


def test_writer_without_c3d_suffix(tmp_path):
    m = _read(OLD)
    out = tmp_path / "capture.bin"
    write_c3d(m, out)
    assert out.exists() and list(tmp_path.iterdir()) == [out]
    assert read_c3d(out).n_markers == 26


@pytest.mark.parametrize("n_frames, n_markers", [(5, 0), (0, 2), (0, 0)])
def test_writer_refuses_a_take_without_frames_or_markers(tmp_path, n_frames, n_markers):
    # a 0-marker take used to be written and read back with 0 frames: its length was lost
    m = MarkerSet(np.zeros((n_frames, n_markers, 3)), [f"m{i}" for i in range(n_markers)], 100.0)
    with pytest.raises(
        ValidationError, match=r"a C3D needs at least one (frame|marker)\b.*, got 0"
    ):
        write_c3d(m, tmp_path / "empty.c3d")
    assert list(tmp_path.iterdir()) == []


def test_writer_keeps_a_take_of_model_outputs_only(tmp_path):
    angles = {"LKneeAngles": np.tile([10.0, 2.0, 3.0], (4, 1))}
    m = MarkerSet(np.zeros((4, 0, 3)), [], 100.0, meta={"model_outputs": {"angles": angles}})
    write_c3d(m, tmp_path / "angles.c3d")
    assert ezc3d.c3d(str(tmp_path / "angles.c3d"))["data"]["points"].shape == (4, 1, 4)


# ------------------------------------------------------------------------- malformed
def test_garbage_and_short_files(tmp_path):
    f = tmp_path / "g.c3d"
    f.write_bytes(b"hello world")
    with pytest.raises(FormatError, match="shorter than the 512-byte"):
        read_c3d(f)
    f.write_bytes(bytes(2048))
    with pytest.raises(FormatError, match="byte 1") as e:
        read_c3d(f)
    assert e.value.offset == 1
    with pytest.raises(FormatError, match="no such file"):
        read_c3d(tmp_path / "none.c3d")


@pytest.mark.parametrize("fraction", [0.05, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99])
def test_truncated_files(tmp_path, fraction):
    data = OLD.read_bytes()
    f = tmp_path / "t.c3d"
    f.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(FormatError) as e:
        read_c3d(f)
    assert e.value.offset is not None


def test_truncated_at_every_block(tmp_path):
    data = (DATA / "cmu_85_02.c3d").read_bytes()
    f = tmp_path / "t.c3d"
    for cut in range(0, len(data), 512 * 37):
        f.write_bytes(data[:cut] or b"\x00")
        with pytest.raises(FormatError):
            read_c3d(f)


def test_known_ezc3d_crashers_are_rejected(tmp_path):
    """Inputs that segfault ezc3d 1.7 are stopped by the Python structure scan."""
    data = bytearray(OLD.read_bytes())
    # POINT:DESCRIPTIONS turned into a group: ezc3d reads its 255-byte description
    # length as signed and crashes
    bad = bytearray(data)
    bad[624] = 250
    f = tmp_path / "a.c3d"
    f.write_bytes(bytes(bad))
    with pytest.raises(FormatError, match="description length"):
        read_c3d(f)
    # ANALOG:OFFSET renamed away: ezc3d dereferences it per channel, so a zero offset
    # per channel is put in (as Motion Analysis files need), with a warning
    bad = bytearray(data)
    bad[2834] = ord("8")
    f.write_bytes(bytes(bad))
    with pytest.warns(SkincapWarning, match="ANALOG:OFFSET missing: 0 for each of"):
        assert read_c3d(f).n_markers > 0
    # a description overrunning its record (ezc3d loops forever on this one)
    bad = bytearray(data)
    bad[3691] = 100
    f.write_bytes(bytes(bad))
    with pytest.raises(FormatError, match="overruns"):
        read_c3d(f)


_SMALL = OLD.read_bytes()
_STRUCT = 512 * 10  # header + parameter section of the c3d.org sample


@settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    edits=st.lists(
        st.tuples(st.integers(0, _STRUCT - 1), st.integers(0, 255)), min_size=1, max_size=4
    ),
    cut=st.one_of(st.none(), st.integers(0, len(_SMALL) - 1)),
    insert=st.one_of(
        st.none(), st.tuples(st.integers(0, _STRUCT), st.binary(min_size=1, max_size=8))
    ),
)
def test_fuzz_mutations_give_markers_or_format_error(tmp_path, edits, cut, insert):
    data = bytearray(_SMALL)
    for k, v in edits:
        data[k] = v
    if insert is not None:
        data[insert[0] : insert[0]] = insert[1]
    if cut is not None:
        data = data[:cut]
    f = tmp_path / "fuzz.c3d"
    f.write_bytes(bytes(data))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnitWarning)
            m = read_c3d(f)
    except SkincapError:
        return
    assert isinstance(m, MarkerSet)
    assert m.positions.shape[2] == 3


def test_descriptions_round_trip_and_many_points(tmp_path):
    m = _read(DATA / "cmu_85_02.c3d")
    assert m.meta["descriptions"][0] == "Left front waist"
    out = tmp_path / "d.c3d"
    write_c3d(m, out)
    assert read_c3d(out).meta["descriptions"] == m.meta["descriptions"]
    n = 300
    big = MarkerSet(
        np.ones((3, n, 3)),
        [f"m{i}" for i in range(n)],
        100.0,
        meta={"descriptions": [f"d{i}" for i in range(n)]},
    )
    out = tmp_path / "big.c3d"
    write_c3d(big, out)
    _, raw_labels = _raw(out)  # ezc3d reads it back
    assert raw_labels == big.labels
    assert read_c3d(out).labels == big.labels
