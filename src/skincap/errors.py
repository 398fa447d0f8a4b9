"""The skincap exception and warning hierarchy.

Every error skincap raises on purpose derives from :class:`SkincapError`; the CLI turns
one into ``skincap: error: <file>: <what is wrong>`` and exit status 2. Recoverable
oddities (a guessed unit, a gap left unfilled) are :class:`SkincapWarning`.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator

__all__ = [
    "SkincapError",
    "FormatError",
    "ValidationError",
    "OutputExistsError",
    "MissingDependencyError",
    "SkincapWarning",
    "UnitWarning",
    "naming_file",
    "quote_excerpt",
    "one_line",
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


@contextlib.contextmanager
def naming_file(path: str | os.PathLike[str]) -> Iterator[None]:
    """Prefix ``path`` to a skincap error raised inside that names no file.

    An argument check deep in a reader or writer (``ids: id 12 appears 2 times``)
    does not know the file; the public read or write call around it does. The error
    keeps its type and gains a ``path`` attribute and the ``<path>: `` prefix.
    """
    try:
        yield
    except SkincapError as exc:
        if getattr(exc, "path", None) is None and not isinstance(exc, MissingDependencyError):
            name = os.fspath(path)
            exc.path = name  # type: ignore[attr-defined]
            exc.args = (f"{name}: {exc}",)
        raise


# ----------------------------------------------------------------- message text
#: Longest excerpt of a file's content quoted in a message, in characters.
EXCERPT_LIMIT = 40

_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")
# a NumPy scalar's repr, np.int64(12) or np.float64(733.0), as NumPy 2 prints it
_NUMPY_REPR = re.compile(
    r"\bnp\.(?:u?int\d*|float\d*|longdouble|bool_?|str_|bytes_|complex\d*)\(([^()]*)\)"
)
_TERMINAL_UNSAFE = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def quote_excerpt(text: str | bytes, *, limit: int = EXCERPT_LIMIT) -> str:
    """Quote a piece of a file for an error message: short, printable, or named as binary.

    Text with control characters other than tab (bytes that are not text: a C3D read
    as a BVH) is described rather than shown, ``binary data (N bytes)``; long text is
    cut to ``limit`` characters with an ellipsis. The result is the repr of the kept text.
    """
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    if _CONTROL.search(text) or "\ufffd" in text:
        return "binary data"
    if len(text) > limit:
        return repr(text[:limit]) + "..."
    return repr(text)


def one_line(message: str) -> str:
    """An error or warning message as one terminal-safe line.

    Line breaks and runs of spaces become one space (a NumPy array printed over several
    lines), NumPy scalar reprs lose their wrapper (``np.int64(12)`` -> ``12``), and
    other control characters are shown escaped so a file name or a quoted piece of a
    file cannot move the cursor or recolour the terminal.
    """
    text = " ".join(message.split())
    text = _NUMPY_REPR.sub(r"\1", text)
    return _TERMINAL_UNSAFE.sub(lambda m: repr(m.group())[1:-1], text)
