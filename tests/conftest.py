"""Shared fixtures: the real-data folder and helpers to make bad files."""

from __future__ import annotations

import hashlib
import importlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

from skincap import backends
from skincap.backends import WARM_UPS, kernel_ready

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

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


_COMPILED: set[str] = set()


def _compile_once(name: str, get_dispatcher: Callable[[], Any]) -> None:
    """Make sure numba kernel ``name`` is compiled (in this process or numba's cache),
    compiling it in one process at a time.

    Under pytest-xdist two workers reaching an uncompiled kernel would both compile it
    (the tracker: ~2 min of CPU each, ~120 s of the suite's wall time). Here the first
    worker takes a file lock and runs the kernel's warm-up (``backends.WARM_UPS``: a
    tiny run with the production argument types, compiled into numba's cache); a
    worker that arrives meanwhile waits on the lock, then only loads the cache.
    """
    if name in _COMPILED or fcntl is None or name not in WARM_UPS:
        return
    _COMPILED.add(name)  # first: the warm-up below resolves its backend too
    try:
        ready = kernel_ready(get_dispatcher())
    except Exception:  # noqa: BLE001 - numba cannot set it up: the test itself says so
        return
    if ready:
        return
    _compile_locked(name, _lock_path(name))


def _lock_path(name: str) -> Path:
    """The file lock of kernel ``name``'s compile in this checkout and numba cache."""
    key = f"{name}|{Path(__file__).resolve()}|{os.environ.get('NUMBA_CACHE_DIR', '')}"
    digest = hashlib.sha1(key.encode()).hexdigest()[:12]
    return Path(tempfile.gettempdir()) / f"skincap-tests-compile-{digest}.lock"


def _compile_locked(name: str, lock: Path) -> None:
    """Run kernel ``name``'s warm-up holding ``lock`` (waiting for whoever holds it)."""
    with lock.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # released when the file closes
        module, function = WARM_UPS[name].split(":")
        getattr(importlib.import_module(module), function)()


def _resolving_once(resolve: Callable[..., str]) -> Callable[..., str]:
    """``resolve_backend`` that compiles the chosen numba kernel once per run first."""

    def resolve_backend(backend: str, **options: Any) -> str:
        used = resolve(backend, **options)
        kernel = options.get("kernel")
        if used == "numba" and kernel is not None:
            _compile_once(*kernel)
        return used

    return resolve_backend


#: Kernels whose compile the xdist controller starts before the workers run tests (the
#: tracker's takes ~2 min of CPU; the others a few seconds, compiled where needed).
_COMPILE_AHEAD = ("tracking",)
_ahead: list[subprocess.Popen[bytes]] = []


def _start_compiles_ahead(config: pytest.Config) -> None:
    """In the controller of a ``-n 2`` run: compile the slow kernels in a process of
    their own, holding their locks, beside the two workers from the first second
    (instead of inside whichever worker first needs them, while the other idles)."""
    if (
        fcntl is None
        or hasattr(config, "workerinput")
        or not getattr(config.option, "numprocesses", None)
    ):
        return
    for name in _COMPILE_AHEAD:
        module, function = backends.DISPATCHERS[name].split(":")
        try:
            if kernel_ready(getattr(importlib.import_module(module), function)()):
                continue
        except Exception:  # noqa: BLE001 - numba cannot set it up: the tests say so
            continue
        code = (
            "import sys; sys.path[:0] = sys.argv[3:]; import conftest; "
            "conftest._compile_locked(sys.argv[1], conftest.Path(sys.argv[2]))"
        )
        _ahead.append(
            subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    code,
                    name,
                    str(_lock_path(name)),
                    str(Path(__file__).parent),
                ],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
    if _ahead:  # give the compiles their locks before a worker asks
        time.sleep(2.0)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """A compile started ahead and still running (a short run) is stopped."""
    for child in _ahead:
        if child.poll() is None:
            child.terminate()
            child.wait(timeout=30)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Every numba kernel compiles once per run, not once per xdist worker: the modules
    with a kernel (those of ``backends.WARM_UPS``) resolve their backend through
    :func:`_resolving_once`; under xdist the tracker's compile starts at once."""
    _start_compiles_ahead(session.config)
    for where in WARM_UPS.values():
        module = importlib.import_module(where.split(":")[0])
        module.resolve_backend = _resolving_once(module.resolve_backend)  # type: ignore[attr-defined]


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
