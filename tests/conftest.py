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


# Under pytest-xdist (README's command: ``-n 2 --dist loadfile``) each group of tests runs
# in one worker: a file, so its module fixtures (the fuzz budget, a real take's fill
# scores) are built once, and each folder of ``_ONE_WORKER_FOLDERS`` as a whole, as its
# files share a session-wide synthetic take (cleanup's dense jump-rope take, tracking's
# rope takes; ~15-20 s each to generate), generated once rather than once per worker.
# Groups holding a ``slow`` test are handed out first, so that no long group starts last
# while the other worker idles. (The scheduler is chosen here because xdist's own
# ``xdist_group`` marks no longer reach its scheduler under pytest 9.2: xdist 3.8 renames
# ``item._nodeid``, which pytest 9.2 no longer reads.)
_ONE_WORKER_FOLDERS = ("cleanup", "tracking")


def _worker_group(nodeid: str) -> str:
    """The group of a test: ``tests/<folder>`` or its file (``tests/...py``)."""
    parts = nodeid.split("::", 1)[0].split("/")
    if len(parts) > 2 and parts[1] in _ONE_WORKER_FOLDERS:
        return "/".join(parts[:2])
    return "/".join(parts)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """``--dist loadfile`` with the shared-take folders as one unit, in collection order."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedTakeScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _worker_group(nodeid)

    config.option.loadscopereorder = False  # keep the slow-first order set below
    return SharedTakeScheduling(config, log)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In an xdist worker: the groups with a slow test first (stable within a group)."""
    if not hasattr(config, "workerinput"):  # not an xdist worker: collection order
        return
    slow = {_worker_group(item.nodeid) for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: _worker_group(item.nodeid) not in slow)
