"""Fixtures of the sweep deformer's tests."""

from __future__ import annotations

import pytest

from skincap.io.makehuman import read_makehuman
from skincap.types import Mesh


@pytest.fixture(scope="session")
def body(data_dir) -> Mesh:
    return read_makehuman(data_dir / "makehuman_base.obj")
