"""Landmark files for registration: a JSON object ``{"marker label": vertex index, ...}``.

Used by ``--landmarks FILE.json`` (dense registration, :mod:`skincap.deform.dense.registration`):
each named marker sits on the given vertex of the template mesh. Whether the labels and
indices fit a given capture and mesh is checked by the registration itself; this reader
checks the file: valid UTF-8 JSON, one object, string keys, non-negative integer values.

Example::

    {"LKNE": 10452, "RKNE": 3711, "C7": 8120}
"""

from __future__ import annotations

import json
import os

from skincap.errors import FormatError
from skincap.io._common import atomic_output, check_readable

__all__ = ["read_landmarks", "write_landmarks"]

#: Largest landmark file read, bytes (a hand-made file holds tens of entries).
MAX_BYTES = 10_000_000


def read_landmarks(path: str | os.PathLike[str]) -> dict[str, int]:
    """Read a landmark file.

    Parameters
    ----------
    path : str or PathLike
        A JSON object mapping marker labels to template vertex indices.

    Returns
    -------
    dict of str to int
        Label -> vertex index (>= 0), in file order.

    Raises
    ------
    FormatError
        Missing, empty, too large or not UTF-8 JSON; not an object; a duplicate label;
        a value that is not a non-negative integer (``true``, ``1.5``, ``"7"`` are refused).
    """
    p = check_readable(path)
    if p.stat().st_size > MAX_BYTES:
        raise FormatError(p, f"landmark file larger than {MAX_BYTES} bytes")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(p, f"not UTF-8 text (byte {exc.start})", offset=exc.start) from None

    def no_duplicates(pairs: list[tuple[str, object]]) -> dict[str, object]:
        out: dict[str, object] = {}
        for key, value in pairs:
            if key in out:
                raise FormatError(p, f"label {key!r} appears twice")
            out[key] = value
        return out

    try:
        data = json.loads(text, object_pairs_hook=no_duplicates)
    except json.JSONDecodeError as exc:
        raise FormatError(p, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    except RecursionError:
        raise FormatError(p, "JSON nested too deeply") from None
    if not isinstance(data, dict):
        raise FormatError(
            p, f"expected a JSON object {{label: vertex index}}, got {type(data).__name__}"
        )
    out: dict[str, int] = {}
    for label, vertex in data.items():
        if not label:
            raise FormatError(p, "empty marker label")
        if isinstance(vertex, bool) or not isinstance(vertex, int) or vertex < 0:
            raise FormatError(
                p, f"landmark {label!r}: expected a vertex index >= 0, got {vertex!r}"
            )
        out[label] = vertex
    return out


def write_landmarks(
    landmarks: dict[str, int], path: str | os.PathLike[str], *, force: bool = False
) -> None:
    """Write ``{label: vertex}`` as a landmark file (atomically; replaces only with ``force``)."""
    data = {str(k): int(v) for k, v in landmarks.items()}
    with atomic_output(path, force=force) as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
