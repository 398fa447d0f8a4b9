"""C3D files of other vendors' writers (c3d.org samples from BTKData, BSD-3), read as
ezc3d reads them and written back with what they carry."""

from __future__ import annotations

import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from skincap.errors import UnitWarning
from skincap.io._common import to_y_up
from skincap.io.c3d import read_c3d, write_c3d

EXTERNAL = Path(__file__).resolve().parents[1] / "data" / "external"
PEAK = EXTERNAL / "c3dorg_sample15_peak_FP1.c3d"


def _read(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
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
