"""The numba kernels' on-disk caches follow edits to the other modules of their package.

numba keys a cached kernel on its own bytecode and file only; a callee in another file
is compiled into the caller, so without :func:`skincap.backends.key_caches_on_package`
an edited callee keeps running as it was when the caller was cached.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("numba")

_CALLER = """
import numba

from skincap.backends import key_caches_on_package
from kernels_pkg.callee import value


@numba.njit(cache=True)
def kernel():
    return value() + 0.5


KEYED = key_caches_on_package(__name__)
"""

_CALLEE = """
import numba


@numba.njit(cache=True)
def value():
    return {value}
"""


def _run(root: Path) -> str:
    env = dict(os.environ)
    env["NUMBA_CACHE_DIR"] = str(root / "numba-cache")
    env["PYTHONPATH"] = os.pathsep.join([str(root), *sys.path])
    code = "from kernels_pkg.caller import KEYED, kernel; print(KEYED, kernel())"
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_an_edited_callee_in_another_file_recompiles_the_cached_caller(tmp_path: Path) -> None:
    package = tmp_path / "kernels_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "caller.py").write_text(textwrap.dedent(_CALLER))
    (package / "callee.py").write_text(textwrap.dedent(_CALLEE).format(value="1.0"))
    assert _run(tmp_path) == "1 1.5"  # compiled and cached
    assert _run(tmp_path) == "1 1.5"  # from the cache
    (package / "callee.py").write_text(textwrap.dedent(_CALLEE).format(value="2.0"))
    assert _run(tmp_path) == "1 2.5"  # the caller's cache no longer matches


def test_the_compiled_skincap_kernels_are_keyed_on_their_package() -> None:
    from skincap.deform.dense import _kernel_numba_jit
    from skincap.tracking import _steps_numba

    for module in (_steps_numba, _kernel_numba_jit):
        kernels = [
            v
            for v in vars(module).values()
            if getattr(getattr(v, "py_func", None), "__module__", None) == module.__name__
            and hasattr(getattr(v, "_cache", None), "_cache_file")
        ]
        assert kernels, module.__name__
        assert all(getattr(k._cache._index_key, "skincap_keyed", False) for k in kernels)
