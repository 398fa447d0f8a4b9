"""JSON outputs (reports, evaluations), written atomically like every other output."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from skincap.errors import FormatError
from skincap.io._common import atomic_output

__all__ = ["parse_json", "read_json", "write_json"]


def parse_json(path: str | os.PathLike[str], text: str, *, what: str = "JSON") -> Any:
    """``text``, read from ``path``, parsed as JSON.

    Raises
    ------
    FormatError
        ``invalid <what>: <reason>`` with the line, or nesting too deep to parse.
    """
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(Path(path), f"invalid {what}: {exc.msg}", line=exc.lineno) from None
    except RecursionError:
        raise FormatError(Path(path), f"invalid {what}: nested too deeply") from None


def read_json(path: str | os.PathLike[str], *, what: str = "JSON") -> Any:
    """The JSON document in the file ``path`` (UTF-8).

    Raises
    ------
    FormatError
        The bytes are not UTF-8 (names the byte), not JSON or nested too deeply to
        parse (see :func:`parse_json`).
    """
    p = Path(path)
    raw = p.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(p, f"not UTF-8 text (byte {exc.start})", offset=exc.start) from None
    return parse_json(p, text, what=what)


def write_json(
    path: str | os.PathLike[str],
    data: Any,
    *,
    force: bool = False,
    indent: int = 1,
    allow_nan: bool = True,
) -> None:
    """Write ``data`` as UTF-8 JSON with a final newline, atomically.

    ``allow_nan=False`` refuses NaN and infinities (ValueError) instead of writing
    JavaScript's ``NaN``, which strict JSON readers reject. An existing ``path`` is
    replaced only with ``force``.
    """
    with atomic_output(path, force=force) as tmp:
        text = json.dumps(data, indent=indent, allow_nan=allow_nan)
        tmp.write_text(text + "\n", encoding="utf-8")
