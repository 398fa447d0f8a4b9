"""io.read's and io.write's tables: every row names a reader or writer that exists, each
kind of file comes back as its type, a written file reads back, and an unknown extension
or a type the extension cannot hold is refused with nothing written."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import numpy as np
import pytest

from skincap import io
from skincap.errors import FormatError
from skincap.types import MarkerSet, Mesh, Motion, PointCloud

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.mark.parametrize("ext", io.READ_EXTENSIONS)
def test_every_extension_names_a_reader_that_takes_the_path(ext):
    # the table holds module and function names as text: a typo would only show when
    # a user first reads such a file
    kind, module, function = io._READERS[ext]
    reader = getattr(importlib.import_module(module), function)
    assert callable(reader)
    assert next(iter(inspect.signature(reader).parameters)) == "path"
    assert io.kind_of_extension(f"take{ext.upper()}") == kind
    assert function.startswith("read_") and module.startswith("skincap.io.")


@pytest.mark.parametrize(
    ("name", "options", "expected"),
    [
        ("c3dorg_sample01_Eb015pr.c3d", {}, MarkerSet),
        ("pyomeca_vicon_nexus_trajectories.csv", {}, MarkerSet),
        ("cmu_131_01_bvh11.bvh", {"units": "cmu"}, Motion),
        ("makehuman_base.obj", {"units": "dm"}, Mesh),
        ("makehuman_default.mhskel", {}, dict),
    ],
)
def test_read_returns_the_type_of_the_extensions_kind(name, options, expected):
    assert isinstance(io.read(DATA / name, **options), expected)


@pytest.mark.parametrize("name", ["take.xyz", "take"])
def test_an_unknown_extension_is_refused_naming_the_known_ones(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"not read")
    with pytest.raises(FormatError) as caught:
        io.read(path)
    message = str(caught.value)
    assert str(path) in message and ", ".join(io.READ_EXTENSIONS) in message
    assert path.read_bytes() == b"not read"


@pytest.mark.parametrize(("data_type", "ext"), list(io._WRITERS))
def test_every_writer_row_names_a_writer_of_that_type(data_type, ext):
    module, function = io._WRITERS[(data_type, ext)]
    writer = getattr(importlib.import_module(module), function)
    parameters = inspect.signature(writer).parameters
    assert list(parameters)[1] == "path" and "force" in parameters
    assert function.startswith("write_") and ext in io.WRITE_EXTENSIONS


def _markers() -> MarkerSet:
    positions = np.random.default_rng(0).normal(size=(5, 3, 3))
    positions[2, 1] = np.nan
    return MarkerSet(positions=positions, labels=["A", "B", "C"], rate=100.0)


@pytest.mark.parametrize("ext", [".c3d", ".trc", ".csv"])
def test_markers_written_by_extension_read_back(tmp_path, ext):
    markers = _markers()
    path = tmp_path / f"take{ext}"
    io.write(markers, path)
    back = io.read(path)
    assert isinstance(back, MarkerSet) and back.labels == markers.labels
    np.testing.assert_allclose(back.positions, markers.positions, atol=1e-6)


def test_a_point_cloud_goes_to_the_long_points_csv(tmp_path):
    cloud = PointCloud(points=np.eye(3), offsets=np.array([0, 2, 3]), rate=50.0)
    io.write(cloud, tmp_path / "points.csv")
    assert (tmp_path / "points.csv").read_text().splitlines()[2] == "frame,time,x,y,z"


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("take.bvh", "cannot write a MarkerSet as .bvh"),
        (
            "take.glb",
            "cannot write '.glb' files; skincap writes .c3d, .trc, .csv, .bvh, .obj, .ply",
        ),
    ],
)
def test_a_type_the_extension_cannot_hold_is_refused_with_nothing_written(tmp_path, name, message):
    with pytest.raises(FormatError, match=message):
        io.write(_markers(), tmp_path / name)
    assert list(tmp_path.iterdir()) == []
