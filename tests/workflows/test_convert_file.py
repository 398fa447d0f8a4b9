"""convert_file called from Python (a notebook, a batch runner): str paths, counts, refusals."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skincap import io
from skincap.errors import FormatError, OutputExistsError, SkincapWarning
from skincap.workflows.convert_file import convert_file


def test_convert_c3d_to_trc_from_str_paths(tmp_path, data_dir):
    src = data_dir / "c3dorg_sample01_Eb015pr.c3d"
    dst = tmp_path / "sample.trc"
    with pytest.warns(SkincapWarning, match="16 analog channels"):  # TRC holds markers only
        counts = convert_file(str(src), str(dst))
    before, after = io.read(src), io.read(dst)
    assert counts == {"frames": before.n_frames}
    assert after.labels == before.labels
    np.testing.assert_allclose(after.positions, before.positions, atol=1e-5, equal_nan=True)
    with pytest.raises(OutputExistsError):
        convert_file(str(src), str(dst))


def test_convert_bvh_counts_joints_and_refuses_other_outputs(tmp_path, data_dir):
    src = data_dir / "bvhtoolbox_test_mocapbank.bvh"
    motion = io.read(src, units="cm")
    counts = convert_file(src, tmp_path / "copy.bvh", units="cm")
    assert counts == {"frames": motion.n_frames, "joints": motion.skeleton.n_joints}
    with pytest.raises(FormatError, match="a BVH converts to .bvh or .csv"):
        convert_file(src, tmp_path / "copy.trc", units="cm")
    with pytest.raises(FormatError, match="cannot write '.xyz'"):
        convert_file(src, tmp_path / "copy.xyz", units="cm")
    assert not (tmp_path / "copy.trc").exists() and not (tmp_path / "copy.xyz").exists()


def _trc(path, n_frames_header: int, labels: list[str], rows: int):
    """A minimal TRC: ``rows`` data rows of zeros for ``labels``, NumFrames as given."""
    names = "".join(f"\t{name}\t\t" for name in labels)
    axes = "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, len(labels) + 1))
    data = "".join(f"{f + 1}\t{f / 100}" + "\t0" * (3 * len(labels)) + "\n" for f in range(rows))
    path.write_text(
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}\n"
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
        f"100.0\t100.0\t{n_frames_header}\t{len(labels)}\tmm\t100.0\t1\t{n_frames_header}\n"
        f"Frame#\tTime{names}\n\t\t{axes}\n\n{data}"
    )
    return path


def _c3d_without_markers(path):
    """A 5-frame C3D with no POINTs, written by ezc3d (skincap's writer refuses one)."""
    import ezc3d

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["data"]["points"] = np.zeros((4, 0, 5))
    c3d.write(str(path))
    return path


@pytest.mark.parametrize(
    "make, fragment",
    [
        (lambda d: _trc(d / "no_frames.trc", 0, ["a", "b"], 0), "at least one frame, got 0"),
        (lambda d: _trc(d / "no_markers.trc", 3, [], 3), "at least one marker or analog"),
        (lambda d: _c3d_without_markers(d / "no_markers.c3d"), "at least one marker or analog"),
    ],
)
def test_empty_capture_to_c3d_names_the_input(tmp_path, make, fragment):
    src = make(tmp_path)
    before = src.read_bytes()
    dst = tmp_path / "out" / "x.c3d"
    dst.parent.mkdir()
    with pytest.raises(FormatError, match=fragment) as info:
        convert_file(src, dst)
    assert info.value.path is not None and str(info.value.path) == str(src)
    assert not dst.exists() and list(dst.parent.iterdir()) == []
    assert src.read_bytes() == before


def _analog_only(src, path):
    """``src`` with its POINT block emptied by ezc3d: the same analogs, no markers."""
    import ezc3d

    c3d = ezc3d.c3d(str(src))
    t = c3d["data"]["points"].shape[2]
    c3d["data"]["points"] = np.zeros((4, 0, t))
    c3d["data"]["meta_points"]["residuals"] = np.zeros((1, 0, t))
    c3d["data"]["meta_points"]["camera_masks"] = np.zeros((7, 0, t), dtype=bool)
    for name in ("LABELS", "DESCRIPTIONS"):
        c3d["parameters"]["POINT"][name]["value"] = []
    c3d["parameters"]["POINT"]["UNITS"]["value"] = [""]  # no points, no length unit
    c3d.write(str(path))
    return path


def test_analog_only_c3d_round_trips(tmp_path, data_dir):
    # an EMG or force-plate-only take was refused ("at least one marker") by convert
    import ezc3d

    src = _analog_only(data_dir / "pyomeca_markers_analogs.c3d", tmp_path / "emg.c3d")
    before = src.read_bytes()
    a = ezc3d.c3d(str(src))
    assert a["header"]["points"]["size"] == 0 and a["data"]["analogs"].shape[1] > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no POINT: no unit to guess, nothing to warn about
        counts = convert_file(src, tmp_path / "copy.c3d")
    b = ezc3d.c3d(str(tmp_path / "copy.c3d"))
    assert counts == {"frames": a["header"]["points"]["last_frame"] + 1}
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    for key in ("first_frame", "last_frame", "frame_rate"):
        assert b["header"]["points"][key] == a["header"]["points"][key]
        assert b["header"]["analogs"][key] == a["header"]["analogs"][key]
    for name in ("LABELS", "RATE", "SCALE", "OFFSET", "UNITS"):
        va, vb = a["parameters"]["ANALOG"][name]["value"], b["parameters"]["ANALOG"][name]["value"]
        assert list(np.ravel(vb)) == list(np.ravel(va)), name
    assert src.read_bytes() == before


def _camera_bits(path):
    from skincap.io.c3d import read_c3d

    return int(np.count_nonzero(read_c3d(path).camera_masks))


@pytest.mark.parametrize(
    "out, points, fmt",
    [
        ("x.trc", False, "a TRC"),
        ("x.csv", False, "a Vicon trajectories CSV"),
        ("x.csv", True, "a point CSV"),
    ],
)
def test_marker_outputs_say_they_drop_camera_masks_once(tmp_path, data_dir, out, points, fmt):
    # TRC and CSV have no column for which cameras saw a sample: they were dropped silently
    from typer.testing import CliRunner

    from skincap.cli import app

    src = data_dir / "external" / "c3dorg_sample02_pc_int.c3d"
    seen = _camera_bits(src)
    assert seen > 0
    args = ["convert", str(src), str(tmp_path / out)] + (["--points"] if points else [])
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    lines = [ln for ln in result.stderr.splitlines() if "camera masks" in ln]
    assert len(lines) == 1, result.stderr
    assert f"{fmt} holds marker trajectories only" in lines[0]
    assert f"camera masks of {seen:,} samples; residuals; 16 analog channels" in lines[0]
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def test_marker_outputs_of_a_trc_warn_nothing(tmp_path, data_dir):
    src = data_dir / "external" / "btk_motionanalysis_gait.trc"
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        convert_file(src, tmp_path / "x.trc")
        convert_file(src, tmp_path / "x.csv")
