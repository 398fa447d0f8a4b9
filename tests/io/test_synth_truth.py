"""The ground-truth files of a ``skincap synth`` folder: point truth, fragment truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import FormatError, SkincapError
from skincap.io.synth_truth import read_fragment_truth, read_marker_parts, read_point_truth
from skincap.types import PointCloud


def _tiny_truth(tmp_path):
    cloud = PointCloud(points=np.zeros((5, 3)), offsets=np.array([0, 2, 2, 5]), rate=120.0)
    text = "row,frame,truth\n0,0,rope_00\n1,0,LASI\n2,2,ghost\n3,2,rope_01\n4,2,RASI\n"
    path = tmp_path / "points.csv"
    path.write_bytes(text.encode())
    return cloud, path, text.encode()


def test_point_truth_reader_reads_and_checks(tmp_path):
    cloud, path, _ = _tiny_truth(tmp_path)
    assert read_point_truth(path, cloud).tolist() == [
        "rope_00",
        "LASI",
        "ghost",
        "rope_01",
        "RASI",
    ]
    path.write_text("row,frame,truth\n0,0,a\n1,1,b\n2,2,c\n3,2,d\n4,2,e\n")
    with pytest.raises(FormatError, match="line 3"):  # row 1 is in frame 0
        read_point_truth(path, cloud)
    path.write_text("row,frame,truth\n0,0,a\n1,0,b\n2,2,c\n3,99999999999999999999999,d\n4,2,e\n")
    with pytest.raises(FormatError, match="line 5"):
        read_point_truth(path, cloud)


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.data())
def test_point_truth_reader_fuzz(tmp_path, data):
    """Mutated bytes give a label array or a SkincapError, nothing else."""
    cloud, path, good = _tiny_truth(tmp_path)
    raw = bytearray(good)
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["flip", "insert", "delete", "truncate"]))
        pos = data.draw(st.integers(0, max(0, len(raw) - 1)))
        if op == "flip" and raw:
            raw[pos] = data.draw(st.integers(0, 255))
        elif op == "insert":
            raw.insert(pos, data.draw(st.integers(0, 255)))
        elif op == "delete" and raw:
            del raw[pos]
        else:
            del raw[pos:]
    path.write_bytes(bytes(raw))
    try:
        got = read_point_truth(path, cloud)
    except SkincapError:
        return
    assert got.shape == (5,)


def test_fragment_truth_reader(tmp_path):
    path = tmp_path / "fragments.csv"
    path.write_text("fragment,truth\n*1,LASI\n\n*2 , ghost\n")
    assert read_fragment_truth(path) == {"*1": "LASI", "*2": "ghost"}
    path.write_text("fragment,truth\n*1,LASI,extra\n")
    with pytest.raises(FormatError, match="line 2"):
        read_fragment_truth(path)
    path.write_text("fragment,truth\n")
    with pytest.raises(FormatError, match="no fragment rows"):
        read_fragment_truth(path)
    path.write_bytes(b"fragment,truth\n*1,L\xffASI\n")
    with pytest.raises(FormatError, match="not UTF-8"):
        read_fragment_truth(path)


def test_truth_readers_name_the_first_byte_that_is_not_utf8(tmp_path):
    # byte 19 (18) is the 0xff: the fragment and marker-part readers report its offset
    path = tmp_path / "truth.csv"
    path.write_bytes(b"fragment,truth\n*1,L\xffASI\n")
    want = f"{path}: byte 19: not UTF-8 text (byte 19)"
    with pytest.raises(FormatError) as err:
        read_fragment_truth(path)
    assert str(err.value) == want
    path.write_bytes(b"marker,part\nLASI,p\xffelvis\n")
    with pytest.raises(FormatError) as err:
        read_marker_parts(path)
    # built afresh: replacing "19" in ``want`` also rewrote a tmp path such as pytest-19
    assert str(err.value) == f"{path}: byte 18: not UTF-8 text (byte 18)"


def test_marker_parts_round_trip_and_bad_files(tmp_path):
    from skincap.errors import OutputExistsError, ValidationError
    from skincap.io.synth_truth import read_marker_parts, write_marker_parts

    path = tmp_path / "marker_parts.csv"
    write_marker_parts(path, ["D000", "D001", "LKNE"], ["thigh_l", "shin_l", "shin_l"])
    assert path.read_text() == "marker,part\nD000,thigh_l\nD001,shin_l\nLKNE,shin_l\n"
    assert read_marker_parts(path) == {"D000": "thigh_l", "D001": "shin_l", "LKNE": "shin_l"}
    with pytest.raises(OutputExistsError):
        write_marker_parts(path, ["A"], ["pelvis"])
    with pytest.raises(ValidationError):
        write_marker_parts(tmp_path / "x.csv", ["A", "B"], ["pelvis"])
    with pytest.raises(ValidationError):
        write_marker_parts(tmp_path / "x.csv", ["A,B"], ["pelvis"])
    assert not (tmp_path / "x.csv").exists()
    for text, line in (
        ("marker,truth\nA,pelvis\n", 1),
        ("marker,part\nA,pelvis\nB\n", 3),
        ("marker,part\nA,pelvis\nA,chest\n", 3),
    ):
        path.write_text(text)
        with pytest.raises(FormatError) as info:
            read_marker_parts(path)
        assert f"line {line}" in str(info.value)
    path.write_text("marker,part\n")
    with pytest.raises(FormatError, match="no marker rows"):
        read_marker_parts(path)
