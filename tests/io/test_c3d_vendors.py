"""C3D files of other vendors' writers (c3d.org samples from BTKData, BSD-3), read as
ezc3d reads them and written back with what they carry."""

from __future__ import annotations

import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from skincap.errors import SkincapWarning
from skincap.io._common import to_y_up
from skincap.io.c3d import read_c3d, write_c3d

EXTERNAL = Path(__file__).resolve().parents[1] / "data" / "external"
PEAK = EXTERNAL / "c3dorg_sample15_peak_FP1.c3d"


def _read(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)  # guessed units, left-out parameters
        return read_c3d(path)


def _same_as_ezc3d(path: Path, units_scale: float) -> None:
    m = _read(path)
    c = ezc3d.c3d(str(path))
    raw = c["data"]["points"][:3].transpose(2, 1, 0)  # (T, N, 3) file units
    assert m.positions.shape == raw.shape
    assert m.rate == pytest.approx(float(c["header"]["points"]["frame_rate"]))
    missing = np.isnan(raw).any(axis=2) | (raw == 0).all(axis=2)
    np.testing.assert_array_equal(m.missing, missing)
    expect = to_y_up(raw * units_scale, m.meta["up"])
    np.testing.assert_allclose(m.positions[~missing], expect[~missing], rtol=0, atol=1e-9)


def test_parameters_past_the_declared_blocks_are_read():
    """Peak Performance declares 3 parameter blocks but fills 5 (the data starts at
    block 7): ezc3d reads the records by their pointers, and so do we."""
    data = PEAK.read_bytes()
    assert data[512 + 2] == 3 and int.from_bytes(data[16:18], "little") == 7
    m = _read(PEAK)
    assert (m.n_frames, len(m.labels), m.rate) == (480, 8, 60.0)
    assert m.labels == [f"PT{i:02d}" for i in range(8)]
    _same_as_ezc3d(PEAK, 1.0)  # POINT:UNITS 'mete', read as metres


def test_peak_file_round_trips_with_its_analog_channels(tmp_path):
    m = _read(PEAK)
    out = tmp_path / "fp1.c3d"
    write_c3d(m, out)
    a, b = ezc3d.c3d(str(PEAK)), ezc3d.c3d(str(out))
    assert b["data"]["analogs"].shape == a["data"]["analogs"].shape == (1, 12, 4800)
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    assert b["parameters"]["ANALOG"]["RATE"]["value"][0] == 600.0
    back = _read(out)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6, equal_nan=True)


BTS = EXTERNAL / "c3dorg_sample28_bts_dynamic.c3d"


def test_parameter_names_with_spaces_are_read_and_kept():
    """Vicon and BTS write subject measurements as ``Pelvis Width`` (a space in the
    name, printable ASCII): the scan keeps them, as written, for the writer."""
    from skincap.io.c3d.scan import scan_c3d

    layout = scan_c3d(BTS, BTS.read_bytes())
    spaced = sorted(name for group, name in layout.params if group == "SUBJECT" and " " in name)
    assert spaced == [
        "LEFT ANKLE",
        "LEFT KNEE",
        "LEFT LEG",
        "LEFT PELVIS DEPTH",
        "PELVIS WIDTH",
        "RIGHT ANKLE",
        "RIGHT KNEE",
        "RIGHT LEG",
        "RIGHT PELVIS DEPTH",
    ]
    records = layout.records["SUBJECT"][3]
    assert records["PELVIS WIDTH"].name == "Pelvis Width"


@pytest.mark.parametrize("path", sorted(EXTERNAL.parent.glob("*.c3d")), ids=lambda p: p.stem)
def test_points_by_header_decodes_as_ezc3d(path):
    """The fallback decoder gives ezc3d's points and residuals where both read a file
    at the same layout (Intel and DEC, float and integer)."""
    from skincap.io.c3d.reader import _points_by_header
    from skincap.io.c3d.scan import scan_c3d

    data = path.read_bytes()
    layout = scan_c3d(path, data)
    c = ezc3d.c3d(str(path))
    expect = c["data"]["points"]
    points, residuals = _points_by_header(layout, data, expect.shape[2])
    np.testing.assert_array_equal(np.isnan(points), np.isnan(expect))
    np.testing.assert_allclose(points, expect, rtol=1e-6, atol=1e-6, equal_nan=True)
    np.testing.assert_allclose(residuals[0], c["data"]["meta_points"]["residuals"][0], atol=1e-6)


def _bts_raw_frames() -> np.ndarray:
    """The BTS file's frames decoded by hand at the header's stride: (296, 142) float32
    (34 points x 4 words, then 6 analog samples)."""
    data = BTS.read_bytes()
    words = np.frombuffer(data[:20], dtype="<u2")
    assert (words[1], words[2], words[9]) == (34, 6, 1)  # points, analog samples/frame
    start = (int(words[8]) - 1) * 512
    return np.frombuffer(data[start:], dtype="<f4").reshape(296, 34 * 4 + 6)


def test_frames_without_analog_rate_are_read_at_the_headers_stride():
    """BTS wrote 6 analog samples into every frame but no ANALOG:RATE: ezc3d then reads
    no analogs and the points at a 544-byte stride instead of 568 (metres of jumps);
    the header's layout decides."""
    m = _read(BTS)
    assert (m.n_frames, m.n_markers, m.rate) == (296, 34, 100.0)
    raw = _bts_raw_frames()[:, : 34 * 4].reshape(296, 34, 4)
    seen = raw[..., 3] >= 0
    expect = to_y_up(raw[..., :3].astype(np.float64) * 0.001, m.meta["up"])
    measured = seen & ~(raw[..., :3] == 0).all(axis=2)
    np.testing.assert_array_equal(~m.missing, measured)
    np.testing.assert_allclose(m.positions[measured], expect[measured], atol=1e-9)
    # a walk at 100 Hz: smooth trajectories, markers at their heights (file Y up)
    walk = _read_y_up(BTS)
    acc = np.linalg.norm(np.diff(walk.positions, 2, axis=0), axis=2)
    assert np.nanpercentile(acc, 99) < 0.03
    y = walk.positions[..., 1]
    height = {
        lab: np.median(y[~walk.missing[:, i], i])
        for i, lab in enumerate(walk.labels)
        if lab in ("r asis", "r knee 1", "r mall", "r met")
    }
    assert height["r asis"] > height["r knee 1"] > height["r mall"] > height["r met"] > 0


@pytest.mark.parametrize(
    ("path", "feet"),
    [
        (BTS, ("r asis", "r knee 1", "r mall", "r met")),
        (EXTERNAL / "c3dorg_sample24_motionmonitor.c3d", None),
    ],
)
def test_files_without_y_screen_standing_along_y_read_y_up(path, feet):
    """BTS and MotionMonitor stand the subject along the file's y and write no
    POINT:Y_SCREEN: read Y up (guessed, with a warning), not lying on its back."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        with pytest.warns(SkincapWarning, match=rf"{path.name}: POINT:Y_SCREEN not given.*Y up"):
            m = read_c3d(path)
    assert m.meta["up"] == "y" and m.meta["up_guessed"]
    y = m.positions[..., 1]
    assert -0.1 < np.nanpercentile(y, 1) < 0.3  # on the floor
    spans = np.nanmedian(np.nanmax(m.positions, axis=1) - np.nanmin(m.positions, axis=1), axis=0)
    assert spans[1] > 2 * spans[2]  # standing, not lying along the depth
    if feet is not None:  # a walk: hips above knees above ankles above toes
        h = [np.nanmedian(y[:, m.labels.index(lab)]) for lab in feet]
        assert h[0] > h[1] > h[2] > h[3] > 0


@pytest.mark.parametrize(
    "name",
    [
        "external/btk_optitrack_mocap36.c3d",
        "external/c3dorg_sample15_peak_FP1.c3d",
        "external/c3dorg_sample22_bkin.c3d",
        "cmu_85_02.c3d",
        "aml_PronetoRun01_labeled.c3d",
        "aml_S09_KneeltoRun02_unlabeled.c3d",
    ],
)
def test_files_without_y_screen_keep_z_up_unless_they_stand_along_y(name):
    # Z-up takes without POINT:Y_SCREEN (a prone start lying along x, a planar robot
    # with z = 0) stay Z up
    m = _read(EXTERNAL.parent / name)
    assert m.meta["up"] == "z" and m.meta["up_guessed"]


def _read_y_up(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        return read_c3d(path, up="y")


def test_frames_without_analog_rate_write_a_file_ezc3d_reads(tmp_path):
    m = _read(BTS)
    out = tmp_path / "bts.c3d"
    write_c3d(m, out)
    c = ezc3d.c3d(str(out))
    assert c["parameters"]["ANALOG"]["RATE"]["value"][0] == 100.0
    analogs = _bts_raw_frames()[:, 34 * 4 :].T  # (6, 296) as stored
    assert c["data"]["analogs"].shape == (1, 6, 296)
    gen = c["parameters"]["ANALOG"]["GEN_SCALE"]["value"][0]
    scale = np.asarray(c["parameters"]["ANALOG"]["SCALE"]["value"])[:, None]
    offset = np.asarray(c["parameters"]["ANALOG"]["OFFSET"]["value"])[:, None]
    np.testing.assert_allclose(c["data"]["analogs"][0], (analogs - offset) * scale * gen, rtol=1e-6)
    back = _read(out)
    np.testing.assert_array_equal(back.missing, m.missing)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6, equal_nan=True)


MOTION_MONITOR = EXTERNAL / "c3dorg_sample24_motionmonitor.c3d"


def test_analog_count_from_the_rates_when_the_header_word_cannot_fill_the_file(tmp_path):
    """The MotionMonitor's header says 16 analog samples a frame; its 16 channels at
    980 Hz against 140 Hz store 112, which is what fills the file: its 840 frames and
    5880 analog samples go out whole (the header's count lost two thirds of the frames)."""
    data = MOTION_MONITOR.read_bytes()
    assert int.from_bytes(data[4:6], "little") == 16
    m = _read(MOTION_MONITOR)
    assert (m.n_frames, m.n_markers, m.rate) == (840, 8, 140.0)
    _same_as_ezc3d(MOTION_MONITOR, 1.0)
    out = tmp_path / "mm.c3d"
    write_c3d(m, out)
    a, b = ezc3d.c3d(str(MOTION_MONITOR)), ezc3d.c3d(str(out))
    assert b["data"]["points"].shape[2] == 840
    assert b["data"]["analogs"].shape == a["data"]["analogs"].shape == (1, 16, 5880)
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    np.testing.assert_allclose(_read(out).positions, m.positions, atol=1e-6, equal_nan=True)


VICON_TYPE2 = EXTERNAL / "c3dorg_sample10_vicon_type2.c3d"


def test_parameters_of_an_undefined_group_are_left_out_with_a_warning(tmp_path):
    """Vicon's c3d.org sample10 holds its SUBJECTS parameters (IS_STATIC...) in group 7
    but defines no group 7: read with a warning naming them, the rest kept."""
    with pytest.warns(SkincapWarning, match=r"byte 709: 9 parameters of group id 7.*IS_STATIC"):
        m = read_c3d(VICON_TYPE2)
    assert (m.n_frames, m.n_markers, m.rate) == (199, 13, 60.0)
    _same_as_ezc3d(VICON_TYPE2, 0.001)
    out = tmp_path / "type2.c3d"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        write_c3d(m, out)
    a, b = ezc3d.c3d(str(VICON_TYPE2)), ezc3d.c3d(str(out))
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    fp = ("TYPE", "CORNERS", "ORIGIN", "CHANNEL", "CAL_MATRIX")
    for name in fp:
        if name in a["parameters"]["FORCE_PLATFORM"]:
            np.testing.assert_array_equal(
                b["parameters"]["FORCE_PLATFORM"][name]["value"],
                a["parameters"]["FORCE_PLATFORM"][name]["value"],
            )


OPTITRACK = EXTERNAL / "btk_optitrack_mocap36.c3d"
BKIN = EXTERNAL / "c3dorg_sample22_bkin.c3d"


def _raw_float_frames(path: Path, n_frames: int, words: int) -> np.ndarray:
    """(n_frames, words) float32 of an Intel float C3D's data section, by hand."""
    data = path.read_bytes()
    start = (int.from_bytes(data[16:18], "little") - 1) * 512
    return np.frombuffer(data[start : start + n_frames * words * 4], dtype="<f4").reshape(
        n_frames, words
    )


def test_record_without_its_description_byte_is_read_by_its_pointer():
    """OptiTrack left out POINT:LABELS' description-length byte (its values run to the
    record's pointer), which ezc3d refuses: the records are read by their pointers."""
    from skincap.io.c3d import checks

    with pytest.raises(Exception, match="LABELS"):
        checks.check_before_ezc3d(OPTITRACK, OPTITRACK.read_bytes())
    with pytest.warns(SkincapWarning, match="LABELS: no description length byte"):
        m = read_c3d(OPTITRACK)
    assert (m.n_frames, m.n_markers, m.rate) == (1380, 36, 100.0)
    assert m.labels[:2] == ["Skeleton_Hip2", "Skeleton_Hip1"]
    assert all(lab.startswith("Skeleton_") for lab in m.labels)
    raw = _raw_float_frames(OPTITRACK, 1380, 36 * 4).reshape(1380, 36, 4)
    measured = (raw[..., 3] >= 0) & ~(raw[..., :3] == 0).all(axis=2)
    np.testing.assert_array_equal(~m.missing, measured)
    expect = to_y_up(raw[..., :3].astype(np.float64) * 0.001, m.meta["up"])
    np.testing.assert_allclose(m.positions[measured], expect[measured], atol=1e-9)


def test_long_descriptions_are_cut_to_what_a_signed_length_holds(tmp_path):
    """BKIN's Dexterit-E writes descriptions of up to 255 bytes; ezc3d reads the length
    signed and would ask for 4 GiB. Cut to 127, the file reads and converts whole."""
    with pytest.warns(SkincapWarning, match="SESSION: description of 163 bytes cut to 127"):
        m = read_c3d(BKIN)
    assert (m.n_frames, m.n_markers, m.rate) == (5065, 2, 1000.0)
    assert m.labels == ["Right_Hand", "Left_Hand"]
    raw = _raw_float_frames(BKIN, 5065, 2 * 4 + 20)
    np.testing.assert_allclose(
        m.positions[:, 0], to_y_up(raw[:, :3].astype(np.float64), m.meta["up"]), atol=1e-9
    )
    out = tmp_path / "bkin.c3d"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        write_c3d(m, out)
    c = ezc3d.c3d(str(out))
    assert c["data"]["analogs"].shape == (1, 20, 5065)
    analog = c["parameters"]["ANALOG"]
    scale = np.asarray(analog["SCALE"]["value"])[:, None] * analog["GEN_SCALE"]["value"][0]
    offset = np.asarray(analog["OFFSET"]["value"])[:, None]
    np.testing.assert_allclose(c["data"]["analogs"][0], (raw[:, 8:].T - offset) * scale, rtol=1e-6)
    assert "EVENT_DEFINITIONS" in c["parameters"] and "RIGHT_KINARM" in c["parameters"]


@pytest.mark.parametrize("path", sorted(EXTERNAL.parent.glob("*.c3d")), ids=lambda p: p.stem)
def test_well_formed_files_need_no_repair(path):
    from skincap.io.c3d.repair import repaired_parameter_section

    assert repaired_parameter_section(path.read_bytes()) is None


@pytest.mark.parametrize("kind", ["int", "real"])
def test_mips_big_endian_files_read_as_their_intel_twins(tmp_path, kind):
    """c3d.org sample02 holds one capture written by an SGI (MIPS, big-endian) and by a
    PC: ezc3d reads only the PC's; the SGI file, byte-swapped to Intel (its last
    parameter record's pointer runs into the data and is taken as the last), gives the
    same markers, rate, labels and analog samples."""
    sgi = _read(EXTERNAL / f"c3dorg_sample02_sgi_{kind}.c3d")
    pc = _read(EXTERNAL / f"c3dorg_sample02_pc_{kind}.c3d")
    assert (sgi.n_frames, sgi.n_markers, sgi.rate) == (89, 36, 50.0)
    assert sgi.labels == pc.labels
    np.testing.assert_array_equal(sgi.missing, pc.missing)
    np.testing.assert_array_equal(sgi.positions, pc.positions)
    a, b = sgi.meta["c3d"], pc.meta["c3d"]
    assert a.analogs.shape == b.analogs.shape == (16, 356)
    np.testing.assert_array_equal(a.analogs, b.analogs)
    out = tmp_path / "sgi.c3d"
    write_c3d(sgi, out)
    c = ezc3d.c3d(str(out))
    assert c["data"]["analogs"].shape == (1, 16, 356)
    np.testing.assert_allclose(_read(out).positions, sgi.positions, atol=1e-6, equal_nan=True)


MAC = EXTERNAL / "c3dorg_sample06_motionanalysis_mips.c3d"
GOLF = EXTERNAL / "c3dorg_sample13_golfswing.c3d"


def test_motion_analysis_file_without_analog_offsets_is_read():
    """Motion Analysis on an SGI (c3d.org sample06) writes no ANALOG:OFFSET, which
    ezc3d needs one per channel (refused before): 0 per channel, the format's meaning.
    Its POINT:SCALE is not its header's: the coordinates follow the parameter, and a
    warning says by how much the header's would change them."""
    with pytest.warns(SkincapWarning) as record:
        m = read_c3d(MAC)
    said = " ".join(str(w.message) for w in record)
    assert "ANALOG:OFFSET missing: 0 for each of 16 channels" in said
    assert "POINT:SCALE 0.0215412 and the header's point scale 0.0551136 disagree" in said
    assert (m.n_frames, m.n_markers, m.rate) == (180, 33, 60.0)
    assert m.meta["c3d"].analogs.shape == (16, 180 * 17)
    # the data section by hand: big-endian int16, 33 points of 4 words then 272 analog words
    data = MAC.read_bytes()
    start = (int.from_bytes(data[16:18], "big") - 1) * 512
    words = np.frombuffer(data[start : start + 180 * 404 * 2], dtype=">i2").reshape(180, 404)
    pts = words[:, :132].reshape(180, 33, 4).astype(np.float64)
    measured = (pts[..., 3] >= 0) & ~(pts[..., :3] == 0).all(axis=2)
    np.testing.assert_array_equal(~m.missing, measured)
    expect = to_y_up(pts[..., :3] * np.float32(0.021541154) / 1000.0, m.meta["up"])
    np.testing.assert_allclose(m.positions[measured], expect[measured], atol=1e-9)
    np.testing.assert_array_equal(
        m.meta["c3d"].analogs,
        words[:, 132:].reshape(180, 17, 16).transpose(2, 0, 1).reshape(16, -1),
    )


def test_float_analog_offsets_and_an_extra_declared_frame_are_read(tmp_path):
    """c3d.org sample13 stores ANALOG:OFFSET as FLOAT and POINT:FRAMES one more than its
    header and data hold (ezc3d: 'OFFSET parameter is not an INT'; refused before):
    the whole-number offsets are read as INT and the frames are the header's."""
    with pytest.warns(SkincapWarning) as record:
        m = read_c3d(GOLF)
    said = " ".join(str(w.message) for w in record)
    assert "ANALOG:OFFSET: whole FLOAT values read as INT" in said
    assert "POINT:FRAMES 515 beyond the 514 frames the file holds: 514" in said
    assert (m.n_frames, m.n_markers) == (514, 29)
    raw = _raw_float_frames(GOLF, 514, 29 * 4 + 8)
    pts = raw[:, : 29 * 4].reshape(514, 29, 4).astype(np.float64)
    measured = (pts[..., 3] >= 0) & ~(pts[..., :3] == 0).all(axis=2)
    np.testing.assert_array_equal(~m.missing, measured)
    expect = to_y_up(pts[..., :3] * 0.001, m.meta["up"])
    np.testing.assert_allclose(m.positions[measured], expect[measured], atol=1e-9)
    np.testing.assert_array_equal(m.meta["c3d"].analogs, raw[:, 29 * 4 :].T)
    out = tmp_path / "golf.c3d"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        write_c3d(m, out)
    back = _read(out)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(back.meta["c3d"].analogs, m.meta["c3d"].analogs)
    assert ezc3d.c3d(str(out))["data"]["analogs"].shape == (1, 8, 514)


PHASESPACE = EXTERNAL / "c3dorg_sample20_phasespace.c3d"


def test_header_only_file_reads_its_points_from_the_header(tmp_path):
    """PhaseSpace (c3d.org sample20) writes an empty parameter section: 0 blocks, no
    record (refused before: 'parameter section of 0 blocks'). The points per frame,
    scale, rate and frames are the header's; the columns are named by number."""
    with pytest.warns(SkincapWarning) as record:
        m = read_c3d(PHASESPACE)
    said = " ".join(str(w.message) for w in record)
    assert "no parameters: POINT from the header (40 points, 30 Hz, frames 1-701)" in said
    assert (m.n_frames, m.n_markers, m.rate) == (701, 40, 30.0)
    assert m.labels[:2] == ["point_1", "point_2"]
    raw = _raw_float_frames(PHASESPACE, 701, 40 * 4).reshape(701, 40, 4).astype(np.float64)
    measured = (raw[..., 3] >= 0) & ~(raw[..., :3] == 0).all(axis=2)
    assert 0.9 < measured.mean() < 1.0
    np.testing.assert_array_equal(~m.missing, measured)
    expect = to_y_up(raw[..., :3] * 0.001, m.meta["up"])
    np.testing.assert_allclose(m.positions[measured], expect[measured], atol=1e-9)
    standing = m.positions[..., 1]  # the subject stands on the floor along the file's Z
    assert -0.05 < np.nanmin(standing) and 1.5 < np.nanmax(standing) < 2.0
    out = tmp_path / "ps.c3d"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        write_c3d(m, out)
    back = _read(out)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6, equal_nan=True)
    assert back.labels == m.labels and back.rate == m.rate
