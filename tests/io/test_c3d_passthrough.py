"""C3D pass-through: analogs, force plates, events and every parameter go out as they came in.

Checked with ezc3d (an independent reader), values and not only counts, on the files
in tests/data that carry analog channels.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.errors import FormatError, SkincapWarning, UnitWarning
from skincap.io.c3d import read_c3d, write_c3d
from skincap.io.c3d.content import C3dContent
from skincap.io.csv import write_vicon_csv
from skincap.io.trc import write_trc
from skincap.types import MarkerSet

DATA = Path(__file__).resolve().parents[1] / "data"
ANALOG_FILES = [
    DATA / "pyomeca_markers_analogs.c3d",  # 38 channels at 20 samples a frame, EVENT groups
    DATA / "btk_pig_calibration_hole_unlabeled_fragments.c3d",  # 38 channels, 2 plates
    DATA / "c3dorg_sample01_Eb015pr.c3d",  # integer file, OFFSET 2048, GEN_SCALE 0.5, header events
]
#: POINT parameters the writer rewrites from the MarkerSet
REWRITTEN_POINT = {"USED", "FRAMES", "DATA_START", "SCALE", "LABELS", "DESCRIPTIONS"}


def _read(path: Path) -> MarkerSet:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        return read_c3d(path)


def _params(c) -> dict[tuple[str, str], dict]:
    out = {}
    for g, params in c["parameters"].items():
        for name, p in params.items():
            if name != "__METADATA__":
                out[(g, name)] = p
    return out


def _same_value(a, b) -> bool:
    if isinstance(a, list) or isinstance(b, list):
        return [str(s).strip() for s in a] == [str(s).strip() for s in b]
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def assert_carried(src: Path, out: Path, *, points_changed: bool = False) -> None:
    """Everything of ``src`` but the point data is in ``out``, per ezc3d."""
    a, b = (
        ezc3d.c3d(str(src), extract_forceplat_data=True),
        ezc3d.c3d(str(out), extract_forceplat_data=True),
    )
    # analog samples, scaled by each file's own SCALE/OFFSET/GEN_SCALE: bit for bit
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    assert b["header"]["analogs"] == a["header"]["analogs"]  # rate, first/last sample
    assert b["header"]["points"]["first_frame"] == a["header"]["points"]["first_frame"]
    assert b["header"]["points"]["last_frame"] == a["header"]["points"]["last_frame"]
    # header events
    assert b["header"]["events"] == a["header"]["events"]
    # every parameter, its type and value (POINT's own point description aside)
    pa, pb = _params(a), _params(b)
    for key, p in pa.items():
        g, name = key
        if g == "POINT" and (name.rstrip("0123456789") in REWRITTEN_POINT or points_changed):
            continue
        assert key in pb, f"{g}:{name} lost"
        assert pb[key]["type"] == p["type"], f"{g}:{name} type {p['type']} -> {pb[key]['type']}"
        assert _same_value(pb[key]["value"], p["value"]), f"{g}:{name} changed"
        assert pb[key]["description"] == p["description"], f"{g}:{name} description"
    # force plates as ezc3d computes them from the analogs and FORCE_PLATFORM
    plates_a, plates_b = a["data"].get("platform", []), b["data"].get("platform", [])
    assert len(plates_b) == len(plates_a)
    for fa, fb in zip(plates_a, plates_b, strict=True):
        for k in ("force", "moment", "center_of_pressure", "corners", "origin", "cal_matrix"):
            np.testing.assert_array_equal(fb[k], fa[k])


@pytest.mark.parametrize("src", ANALOG_FILES, ids=lambda p: p.stem)
def test_write_keeps_everything_the_points_do_not_change(src, tmp_path):
    m = _read(src)
    content = m.meta["c3d"]
    assert isinstance(content, C3dContent) and content.n_analog_channels > 0
    out = tmp_path / "out.c3d"
    write_c3d(m, out)
    assert_carried(src, out)
    again = _read(out)
    np.testing.assert_array_equal(again.meta["c3d"].analogs, content.analogs)
    # and the points themselves come back (float32 storage)
    np.testing.assert_array_equal(again.missing, m.missing)
    np.testing.assert_allclose(again.positions, m.positions, rtol=1e-6, atol=1e-9)


def test_counts_of_what_the_files_carry():
    """Ground truth for the three files, read with ezc3d in an independent session."""
    pig = _read(ANALOG_FILES[1]).meta["c3d"]
    assert (pig.n_analog_channels, pig.analog_ratio, pig.n_force_plates()) == (38, 10, 2)
    old = _read(ANALOG_FILES[2]).meta["c3d"]
    assert (old.n_analog_channels, old.analog_ratio, old.n_force_plates()) == (16, 4, 2)
    assert old.events is not None and old.events.label_list() == ["RIC", "RHS", "RTO"]
    np.testing.assert_allclose(old.events.times[:3], [2.72, 5.40, 7.32], atol=1e-6)


@pytest.mark.parametrize("src", ANALOG_FILES[1:], ids=lambda p: p.stem)
def test_added_columns_keep_analogs_aligned(src, tmp_path):
    """Cleanup adds columns (U1…) on the same frames: POINT is rewritten, the rest carried."""
    m = _read(src)
    extra = np.full((m.n_frames, 1, 3), np.nan)
    extra[::2, 0] = m.positions[::2, 0] + 0.01
    grown = MarkerSet(
        positions=np.concatenate([m.positions, extra], axis=1),
        labels=[*m.labels, "U1"],
        rate=m.rate,
        meta=dict(m.meta),
    )
    out = tmp_path / "grown.c3d"
    write_c3d(grown, out)
    assert_carried(src, out, points_changed=True)
    back = _read(out)
    assert back.labels == grown.labels
    # the source's descriptions follow their labels
    assert back.meta["descriptions"] == [*m.meta["descriptions"], ""]
    np.testing.assert_allclose(back.positions, grown.positions, rtol=1e-6, atol=1e-9)


def test_changed_frame_count_drops_analogs_with_a_warning(tmp_path):
    m = _read(ANALOG_FILES[1])
    outputs = {
        g: {k: v[:100] for k, v in series.items()} for g, series in m.meta["model_outputs"].items()
    }
    meta = {**m.meta, "model_outputs": outputs}
    cut = MarkerSet(positions=m.positions[:100], labels=m.labels, rate=m.rate, meta=meta)
    out = tmp_path / "cut.c3d"
    with pytest.warns(SkincapWarning, match=r"38 analog channels.*300.*2 force plates"):
        write_c3d(cut, out)
    c = ezc3d.c3d(str(out))
    assert c["data"]["analogs"].shape[1] == 0
    assert int(c["parameters"]["FORCE_PLATFORM"]["USED"]["value"][0]) == 0
    # everything that does not depend on the sample count is still there
    assert (
        c["parameters"]["SUBJECTS"]["NAMES"]["value"]
        == ezc3d.c3d(str(ANALOG_FILES[1]))["parameters"]["SUBJECTS"]["NAMES"]["value"]
    )
    assert _read(out).n_frames == 100


@pytest.mark.parametrize("writer", [write_trc, write_vicon_csv], ids=["trc", "csv"])
def test_text_formats_warn_about_what_they_cannot_hold(writer, tmp_path):
    m = _read(ANALOG_FILES[2])
    with pytest.warns(SkincapWarning, match=r"16 analog channels; 2 force plates; 3 events"):
        writer(m, tmp_path / "out.txt")


def test_unicode_labels_round_trip(tmp_path):
    pos = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3) + 1.0
    labels = ["Δelta", "Ωmega_é", "plain"]
    m = MarkerSet(positions=pos, labels=labels, rate=100.0, meta={"descriptions": ["ü", "", "ß"]})
    out = tmp_path / "u.c3d"
    write_c3d(m, out)
    back = read_c3d(out)
    assert back.labels == labels
    assert back.meta["descriptions"] == ["ü", "", "ß"]
    raw = ezc3d.c3d(str(out))["parameters"]["POINT"]["LABELS"]["value"]
    assert [s.strip() for s in raw] == labels  # ezc3d reads UTF-8 too


def test_latin1_labels_of_old_files_still_read(tmp_path):
    """A Latin-1 byte that is not valid UTF-8 is read as Latin-1 (old files)."""
    pos = np.ones((2, 1, 3))
    out = tmp_path / "l.c3d"
    write_c3d(MarkerSet(positions=pos, labels=["Xe9X"], rate=100.0), out)
    data = bytearray(out.read_bytes())
    at = data.index(b"Xe9X")
    data[at : at + 4] = b"X\xe9X "
    out.write_bytes(bytes(data))
    assert read_c3d(out).labels == ["XéX"]


@pytest.mark.parametrize("value", [1e39, -3.5e38])
def test_values_beyond_float32_are_refused(value, tmp_path):
    pos = np.ones((3, 2, 3))
    pos[2, 1, 0] = value
    out = tmp_path / "big.c3d"
    with pytest.raises(FormatError, match=r"point 'b', frame 2, x: .*e\+3[89].*float32"):
        write_c3d(MarkerSet(positions=pos, labels=["a", "b"], rate=100.0), out, units="m")
    assert not out.exists()


@pytest.mark.slow
def test_cli_convert_and_clean_keep_analogs(tmp_path):
    src = ANALOG_FILES[0]
    runner = CliRunner()
    conv = tmp_path / "conv.c3d"
    r = runner.invoke(app, ["convert", str(src), str(conv)])
    assert r.exit_code == 0, r.output
    assert_carried(src, conv)
    cleaned = tmp_path / "clean.c3d"
    r = runner.invoke(app, ["clean", str(src), "-o", str(cleaned)])
    assert r.exit_code == 0, r.output
    assert_carried(src, cleaned, points_changed=True)


def test_cli_refuses_a_trc_value_a_c3d_cannot_hold(tmp_path):
    """Issue #13 item 6: 1e39 in a TRC used to become a C3D that skincap could not read.

    The reader now refuses it first (a coordinate beyond 1e9 m is a corrupt sample);
    the C3D writer's own float32 check is held by test_values_beyond_float32_are_refused."""
    pos = np.ones((3, 2, 3))
    pos[1, 0, 2] = 1e36  # metres: the TRC (mm) holds 1e39
    trc = tmp_path / "big.trc"
    write_trc(MarkerSet(positions=pos, labels=["a", "b"], rate=100.0), trc, units="mm")
    out = tmp_path / "big.c3d"
    r = CliRunner().invoke(app, ["convert", str(trc), str(out)])
    assert r.exit_code == 2, r.output
    lines = [s for s in r.output.splitlines() if s.strip()]
    assert len(lines) == 1 and "big.trc" in lines[0], r.output
    assert "marker 'a' in frame 1" in lines[0] and "1e+36" in lines[0], r.output
    assert not out.exists()


@pytest.mark.parametrize("n_frames", [40_000, 70_000])
def test_long_takes_keep_every_frame(n_frames, tmp_path):
    """Past 32767 frames POINT:FRAMES is read unsigned; past 65535 the header and data decide."""
    pos = np.random.default_rng(0).normal(size=(n_frames, 1, 3))
    out = tmp_path / "long.c3d"
    write_c3d(MarkerSet(positions=pos, labels=["a"], rate=1000.0), out, units="m")
    assert ezc3d.c3d(str(out))["data"]["points"].shape == (4, 1, n_frames)
    back = read_c3d(out)
    assert back.n_frames == n_frames
    np.testing.assert_allclose(back.positions, pos, atol=1e-6)


def test_carried_parameters_keep_type_shape_case_lock_and_bytes(tmp_path):
    """A vendor group with every parameter type goes out record for record."""
    from skincap.io.c3d.content import C3dGroup, C3dParameter

    floats = np.arange(24, dtype=np.float64).reshape(2, 3, 4) / 8.0
    vendor = C3dGroup(
        "Vendor_x",
        description="ünïcode group".encode(),
        locked=True,
        parameters=(
            C3dParameter("Flags", 1, (5,), bytes([0, 1, 2, 127, 255]), b"bytes", True),
            C3dParameter("COUNTS", 2, (2, 2), np.array([1, -2, 300, 32767], "<i2").tobytes()),
            C3dParameter("GRID", 4, (2, 3, 4), floats.astype("<f4").ravel(order="F").tobytes()),
            C3dParameter("NAMES", -1, (6, 2), "Δx    ".encode()[:6].ljust(6) + b"plain "),
            C3dParameter("ONE", 4, (), np.array([2.5], "<f4").tobytes()),
        ),
    )
    src = _read(ANALOG_FILES[0])
    content = src.meta["c3d"]
    meta = {**src.meta, "c3d": type(content)(
        groups=(*content.groups, vendor),
        analogs=content.analogs,
        analog_ratio=content.analog_ratio,
        n_frames=content.n_frames,
        first_frame=content.first_frame,
        events=content.events,
    )}  # fmt: skip
    out = tmp_path / "vendor.c3d"
    write_c3d(MarkerSet(src.positions, src.labels, src.rate, meta=meta), out)
    back = _read(out).meta["c3d"].group("VENDOR_X")
    assert back == vendor  # names as written, types, dims, bytes, descriptions, locks
    ez = ezc3d.c3d(str(out))["parameters"]["Vendor_x"]
    assert ez["Flags"]["type"] == 1 and ez["Flags"]["value"].tolist() == [0, 1, 2, 127, -1]
    assert ez["COUNTS"]["value"].tolist() == [[1, 300], [-2, 32767]]
    np.testing.assert_array_equal(ez["GRID"]["value"], floats)
    assert [s.strip() for s in ez["NAMES"]["value"]] == ["Δx", "plain"]


def test_a_file_skincap_wrote_through_ezc3d_loses_only_its_rotation_pointer(tmp_path):
    """Files ezc3d wrote carry ROTATION:DATA_START, a block of theirs: not carried."""
    src = DATA / "aml_PronetoRun01_labeled.c3d"
    c = ezc3d.c3d(str(src))
    c.add_parameter("ROTATION", "USED", 0)
    c.add_parameter("ROTATION", "DATA_START", 12)
    old = tmp_path / "old.c3d"
    c.write(str(old))
    out = tmp_path / "new.c3d"
    write_c3d(_read(old), out)
    params = ezc3d.c3d(str(out))["parameters"]
    assert "ROTATION" not in params
    written_by = ezc3d.c3d(str(old))["parameters"]["EZC3D"]["VERSION"]["value"]
    assert params["EZC3D"]["VERSION"]["value"] == written_by  # other groups carried
