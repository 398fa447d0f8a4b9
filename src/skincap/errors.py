"""The skincap exception and warning hierarchy.

Every error skincap raises on purpose derives from :class:`SkincapError`; the CLI turns
one into ``skincap: error: <file>: <what is wrong>`` and exit status 2. Recoverable
oddities (a guessed unit, a gap left unfilled) are :class:`SkincapWarning`.
"""

from __future__ import annotations

import os

__all__ = [
    "SkincapError",
    "FormatError",
    "ValidationError",
    "OutputExistsError",
    "MissingDependencyError",
    "SkincapWarning",
    "UnitWarning",
]


class SkincapError(Exception):
    """Root of every error skincap raises deliberately."""


class FormatError(SkincapError):
    """A file could not be read or written: it is truncated, malformed or inconsistent.

    Parameters
    ----------
    path : str or os.PathLike
        The file at fault.
    what : str
        One line saying what is wrong.
    line : int, optional
        1-based line number for text formats.
    offset : int, optional
        Byte offset for binary formats.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        what: str,
        *,
        line: int | None = None,
        offset: int | None = None,
    ) -> None:
        self.path = os.fspath(path)
        self.what = what
        self.line = line
        self.offset = offset
        where = ""
        if line is not None:
            where = f"line {line}: "
        elif offset is not None:
            where = f"byte {offset}: "
        super().__init__(f"{self.path}: {where}{what}")


class ValidationError(SkincapError, ValueError):
    """An argument has the wrong shape, dtype or value.

    The message names the argument and gives the expected and the actual value.
    """


class OutputExistsError(SkincapError):
    """The output file exists and overwriting was not asked for (``--force``)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        super().__init__(f"{self.path}: output exists; pass --force to replace it")


class MissingDependencyError(SkincapError, ImportError):
    """An optional dependency is needed for this feature and is not installed."""

    def __init__(self, package: str, extra: str, feature: str) -> None:
        super().__init__(f"{feature} needs the '{package}' package: pip install 'skincap[{extra}]'")


class SkincapWarning(UserWarning):
    """Something recoverable happened that the caller should know about."""


class UnitWarning(SkincapWarning):
    """A unit or axis convention was guessed rather than read from the file."""
