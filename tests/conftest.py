"""Shared fixtures: the real-data folder and helpers to make bad files."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """tests/data: real captures copied from the shared collection, with licences."""
    return DATA
