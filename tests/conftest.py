"""Shared fixtures: the real-data folder and helpers to make bad files."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests explore new random cases on every developer run; CI
# (HYPOTHESIS_PROFILE=ci, set by .ci/run) replays one fixed derandomised set, so a run
# that lands is reproducible. A failure found locally is fixed, not hidden: its example
# is printed with the blob to replay it.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

# backend="auto" compiles numba kernels in the test process (as an explicit
# backend="numba" does) instead of running NumPy while a background process compiles:
# the same backend whatever the cache holds, and no second compile competing for the
# cores. The background policy has its own tests (tests/skinning/test_deformers.py).
os.environ.setdefault("SKINCAP_COMPILE", "inline")

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """tests/data: real captures copied from the shared collection, with licences."""
    return DATA
