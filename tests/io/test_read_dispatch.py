"""io.read's table of readers: every row names a reader that exists, each kind of file
comes back as its type, and an unknown extension is refused naming the known ones."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import pytest

from skincap import io
from skincap.errors import FormatError
from skincap.types import MarkerSet, Mesh, Motion

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
