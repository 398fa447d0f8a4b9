"""Choosing between a numba kernel and its NumPy reference, and when to compile.

The skinning deformers, the dense deformer and the rope tracker each keep a plain NumPy path as the
reference and a numba kernel that must give the same results; both pick one with
:func:`resolve_backend`. numba is a core dependency, so ``backend="auto"`` runs the
compiled kernel -- once it is compiled.

A kernel compiles once per machine (``cache=True``: numba writes it to
``__pycache__`` beside the module, or, where the package folder is read-only, to its
user-wide cache, ``~/.cache/numba``; ``NUMBA_CACHE_DIR`` overrides both) and every
later process loads it in well under a second. The first compile is what a user
must not wait for (about a minute for the tracker): when ``auto`` finds a kernel
neither compiled in this process nor in the cache, it runs the NumPy reference for
this call and starts one detached, low-priority process that compiles the kernel
into the cache (:func:`compile_in_background`), so the next run is compiled. The
environment variable ``SKINCAP_COMPILE=inline`` compiles in the calling process
instead (the behaviour of an explicit ``backend="numba"``).

numba keys a cached kernel on its own file only; the tracker's and the dense deformer's
kernels compile callees from their package's other files into themselves, so their
modules end with :func:`key_caches_on_package`, which keys them on every source file of
the package (an edit anywhere there recompiles them once, never runs stale code).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from skincap.errors import MissingDependencyError, SkincapWarning, ValidationError

__all__ = [
    "numba_available",
    "resolve_backend",
    "KernelWatch",
    "RECHECK_SECONDS",
    "kernel_ready",
    "compile_in_background",
    "start_pending_compiles",
    "BACKENDS",
    "WARM_UPS",
    "key_caches_on_package",
]

#: The values a ``backend=`` argument takes.
BACKENDS = ("auto", "numba", "numpy")

#: Kernels that can be compiled ahead in a background process: name -> the
#: ``module:function`` that compiles it by running it once on a tiny input of the
#: production argument types. Only these run in :func:`compile_in_background`.
WARM_UPS = {
    "skinning.lbs": "skincap.deform.skeletal.deformers:warm_up_lbs",
    "skinning.dqs": "skincap.deform.skeletal.deformers:warm_up_dqs",
    "tracking": "skincap.tracking.tracker:warm_up_kernel",
    "dense": "skincap.deform.dense.deformer:warm_up_kernel",
    "ik": "skincap.solve.ik:warm_up_kernel",
}

#: Where each of those kernels' numba dispatcher comes from (``module:function``).
DISPATCHERS = {
    "skinning.lbs": "skincap.deform.skeletal.deformers:_lbs_dispatcher",
    "skinning.dqs": "skincap.deform.skeletal.deformers:_dqs_dispatcher",
    "tracking": "skincap.tracking.tracker:_track_frames_dispatcher",
    "dense": "skincap.deform.dense._kernel_numba:dense_dispatcher",
    "ik": "skincap.solve._ik_numba:ik_dispatcher",
}

# a background compile older than this is taken as dead (its lock is removed)
_STALE_LOCK_S = 30 * 60.0


@functools.cache
def numba_available() -> bool:
    """True when numba can be imported (a core dependency; False on a broken install)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def _compile_policy() -> str:
    value = os.environ.get("SKINCAP_COMPILE", "background").strip().lower()
    return "inline" if value == "inline" else "background"


#: How often (seconds) an ``auto`` run that started on NumPy asks whether its kernel
#: has landed in the cache (an ask reads numba's cache index: about a millisecond).
RECHECK_SECONDS = 1.0


class KernelWatch:
    """Whether a kernel compiling in the background has landed, asked at most every
    :data:`RECHECK_SECONDS`.

    An ``auto`` run that started on the NumPy reference (the tracker, the skeletal and
    the dense deformers) holds one and asks :meth:`landed` between batches, so a long
    take switches to the kernel mid-run. Once the kernel has landed, or numba cannot
    set it up (``resolve_backend`` warned already), it never asks again.

    Parameters
    ----------
    dispatcher : callable() -> numba dispatcher
        Builds (or returns) the kernel's dispatcher; called only when asking.
    waiting : bool
        False: there is nothing to wait for (:meth:`landed` is always False).
    """

    def __init__(self, dispatcher: Any, waiting: bool) -> None:
        self._dispatcher = dispatcher
        self.waiting = bool(waiting)
        self._next_check = time.monotonic() + RECHECK_SECONDS

    def landed(self) -> bool:
        """True once, when the kernel is first found compiled (or in the cache)."""
        if not self.waiting:
            return False
        now = time.monotonic()
        if now < self._next_check:
            return False
        self._next_check = now + RECHECK_SECONDS
        try:
            ready = kernel_ready(self._dispatcher())
        except RuntimeError:  # numba cannot set the kernel up (resolve_backend warned)
            ready = False
            self.waiting = False
        if ready:
            self.waiting = False
        return bool(ready)


def kernel_ready(dispatcher: Any) -> bool:
    """Whether calling a numba dispatcher now costs no compilation.

    Parameters
    ----------
    dispatcher : numba dispatcher (an ``@njit(cache=True)`` function)

    Returns
    -------
    bool
        True when it has a compiled overload in this process, or an entry in its
        on-disk cache for this machine (CPU), this numba and this source (numba's
        own index key). Also True when the cache cannot be inspected (an unknown
        numba layout): the caller then compiles as numba always does.
    """
    if dispatcher.signatures:
        return True
    try:
        cache = dispatcher._cache
        cache_file = getattr(cache, "_cache_file", None)
        if cache_file is None:  # no on-disk cache for this function
            return False
        index = cache_file._load_index()
        probe = cache._index_key(None, dispatcher.targetctx.codegen())
    except Exception:  # noqa: BLE001 - private numba API: fall back to compiling
        return True
    return any(key[1:] == probe[1:] for key in index)


@functools.cache
def _package_fingerprint(folder: str) -> str:
    """sha256 of the names and bytes of every ``*.py`` file in ``folder`` (hex)."""
    digest = hashlib.sha256()
    for path in sorted(Path(folder).glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def key_caches_on_package(module_name: str) -> int:
    """Make the on-disk numba caches of a module's kernels depend on its whole package.

    numba keys a cached kernel on its own bytecode and its own file's stamp only, yet
    a kernel compiles its callees (and the constants it reads) from other modules into
    itself: edit a callee in another file and the next process silently loads the old
    machine code. Called at the end of a module that defines ``@njit(cache=True)``
    kernels calling across files, this adds a fingerprint of every ``*.py`` file in the
    module's folder to each of those kernels' cache keys, so any source change in the
    package recompiles them (once) instead of running stale code.

    Parameters
    ----------
    module_name : str
        ``__name__`` of the calling module (already in ``sys.modules``).

    Returns
    -------
    int
        How many kernels were keyed (0 where numba's cache layout is unknown: they then
        cache as numba always does).
    """
    module = sys.modules[module_name]
    folder = str(Path(module.__file__ or ".").resolve().parent)
    fingerprint = _package_fingerprint(folder)
    keyed = 0
    for value in list(vars(module).values()):
        py_func = getattr(value, "py_func", None)
        cache: Any = getattr(value, "_cache", None)
        if py_func is None or getattr(py_func, "__module__", None) != module_name:
            continue  # not a kernel of this module (an import)
        index_key = getattr(cache, "_index_key", None)
        if index_key is None or getattr(index_key, "skincap_keyed", False):
            continue  # no on-disk cache, or keyed already

        def keyed_index_key(sig: Any, codegen: Any, _own: Any = index_key) -> tuple[Any, ...]:
            return (*_own(sig, codegen), fingerprint)

        keyed_index_key.skincap_keyed = True  # type: ignore[attr-defined]
        cache._index_key = keyed_index_key
        keyed += 1
    return keyed


def _lock_path(dispatcher: Any, name: str) -> Path | None:
    try:
        folder = Path(dispatcher._cache._cache_path)
    except Exception:  # noqa: BLE001 - private numba API
        return None
    return folder / f"skincap-compiling-{name}.lock"


def compile_in_background(name: str, dispatcher: Any) -> bool:
    """Start compiling kernel ``name`` into numba's cache in a detached process.

    At most one such process per kernel and cache folder runs at a time (a lock file
    beside the cache, removed when it ends, ignored after 30 minutes). The process
    runs at low priority, prints nothing and touches nothing but numba's cache.

    Parameters
    ----------
    name : str
        A key of :data:`WARM_UPS`.
    dispatcher : numba dispatcher
        The kernel (for the location of its cache).

    Returns
    -------
    bool
        True when a process was started, False when one is already running or the
        cache folder cannot be written.
    """
    if name not in WARM_UPS:
        raise ValidationError(f"name: expected one of {sorted(WARM_UPS)}, got {name!r}")
    lock = _lock_path(dispatcher, name)
    if lock is None:
        return False
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        if lock.exists() and time.time() - lock.stat().st_mtime > _STALE_LOCK_S:
            lock.unlink(missing_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except OSError:  # running already, or no writable cache folder
        return False
    # the child imports skincap from wherever this process did
    path = os.pathsep.join(p for p in sys.path if p)
    env = dict(os.environ, SKINCAP_COMPILE="inline", PYTHONPATH=path)
    try:
        child = subprocess.Popen(
            [sys.executable, "-m", "skincap.backends", name, str(lock)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
            start_new_session=True,
            close_fds=True,
        )
    except OSError:
        os.close(fd)
        lock.unlink(missing_ok=True)
        return False
    os.write(fd, str(child.pid).encode())  # whoever measures the compile can find it
    os.close(fd)
    return True


def start_pending_compiles(names: tuple[str, ...] | None = None) -> list[str]:
    """Start the background compile of every kernel not compiled yet, now.

    A long run that will reach several kernels (``skincap demo``) calls this first,
    so the compiles overlap its early steps on the other core instead of starting
    when each kernel is first needed. Does nothing without numba or with
    ``SKINCAP_COMPILE=inline``.

    Parameters
    ----------
    names : tuple of str, optional
        Keys of :data:`WARM_UPS`; default all.

    Returns
    -------
    list of str
        The kernels whose compile was started.
    """
    if not numba_available() or _compile_policy() != "background":
        return []
    started = []
    for name in names if names is not None else tuple(WARM_UPS):
        if name not in DISPATCHERS:
            raise ValidationError(f"names: expected keys of {sorted(DISPATCHERS)}, got {name!r}")
        module, function = DISPATCHERS[name].split(":")
        try:
            dispatcher = getattr(importlib.import_module(module), function)()
        except RuntimeError:  # numba cannot set the kernel up: the run will say so
            continue
        if not kernel_ready(dispatcher) and compile_in_background(name, dispatcher):
            started.append(name)
    return started


def resolve_backend(
    backend: str,
    *,
    numba_installed: bool,
    feature: str,
    kernel: tuple[str, Any] | None = None,
) -> str:
    """The kernel to run: ``"numba"`` or ``"numpy"``.

    Parameters
    ----------
    backend : {"auto", "numba", "numpy"}
        ``"auto"`` takes numba when it is installed and its kernel compiled (see
        ``kernel``), NumPy otherwise.
    numba_installed : bool
        Whether numba can be used (callers pass their module's
        :func:`numba_available`, which tests may replace).
    feature : str
        Named in the error when ``"numba"`` is asked for without numba.
    kernel : (name, callable returning the numba dispatcher), optional
        For ``"auto"``: when the kernel is not compiled yet (:func:`kernel_ready`)
        and ``SKINCAP_COMPILE`` is not ``inline``, start
        :func:`compile_in_background` and return ``"numpy"`` for this call.

    Raises
    ------
    ValidationError
        An unknown ``backend``.
    MissingDependencyError
        ``backend="numba"`` without numba.
    """
    if backend not in BACKENDS:
        raise ValidationError(f"backend: expected 'auto', 'numba' or 'numpy', got {backend!r}")
    if backend == "numpy":
        return "numpy"
    if not numba_installed:
        if backend == "numba":
            raise MissingDependencyError("numba", "fast", feature)
        return "numpy"
    if backend == "auto" and kernel is not None and _compile_policy() == "background":
        name, get_dispatcher = kernel
        try:
            dispatcher = get_dispatcher()
        except RuntimeError as exc:  # e.g. numba finds no writable cache folder
            warnings.warn(
                f"{feature}: the numba kernel cannot be set up ({exc}); using NumPy",
                SkincapWarning,
                stacklevel=3,
            )
            return "numpy"
        if not kernel_ready(dispatcher):
            compile_in_background(name, dispatcher)
            return "numpy"
    return "numba"


def _main(argv: list[str]) -> int:
    """``python -m skincap.backends NAME LOCK``: compile one kernel, then drop LOCK."""
    name, lock = argv[0], Path(argv[1])
    try:
        if hasattr(os, "nice"):
            os.nice(10)
        module, function = WARM_UPS[name].split(":")
        getattr(importlib.import_module(module), function)()
    finally:
        lock.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":  # pragma: no cover - runs in the background process
    raise SystemExit(_main(sys.argv[1:]))
