"""Choosing between a numba kernel and its NumPy reference (the optional ``fast`` extra).

The skinning deformers and the rope tracker each keep a plain NumPy path as the
reference and a numba kernel that must give the same results; both pick one with
:func:`resolve_backend`.
"""

from __future__ import annotations

import functools

from skincap.errors import MissingDependencyError, ValidationError

__all__ = ["numba_available", "resolve_backend", "BACKENDS"]

#: The values a ``backend=`` argument takes.
BACKENDS = ("auto", "numba", "numpy")


@functools.cache
def numba_available() -> bool:
    """True when numba can be imported (the optional ``fast`` extra)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def resolve_backend(backend: str, *, numba_installed: bool, feature: str) -> str:
    """The kernel to run: ``"numba"`` or ``"numpy"``.

    Parameters
    ----------
    backend : {"auto", "numba", "numpy"}
        ``"auto"`` takes numba when it is installed, NumPy otherwise.
    numba_installed : bool
        Whether numba can be used (callers pass their module's
        :func:`numba_available`, which tests may replace).
    feature : str
        Named in the error when ``"numba"`` is asked for without numba.

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
    if numba_installed:
        return "numba"
    if backend == "numba":
        raise MissingDependencyError("numba", "fast", feature)
    return "numpy"
