"""Edge-list CSV: pairs of marker labels, one ``label_a,label_b`` per line.

``skincap clean --surface edges.csv`` reads a user's marker surface from it (an
optional header line is skipped).
"""

from __future__ import annotations

import os

import numpy as np

from skincap.errors import FormatError
from skincap.io._common import check_readable, read_utf8_text

__all__ = ["read_edge_csv"]


def read_edge_csv(path: str | os.PathLike[str], labels: list[str]) -> np.ndarray:
    """Read an edge list of marker labels as index pairs into ``labels``.

    Parameters
    ----------
    path : path-like
        UTF-8 text, one ``label_a,label_b`` pair per line; blank lines are skipped, and
        a first line whose labels are not markers is taken as a header.
    labels : list of str
        The marker labels the pairs name; an edge ``(i, j)`` joins ``labels[i]`` and
        ``labels[j]``.

    Returns
    -------
    (E, 2) int64
        One row per edge, in file order.

    Raises
    ------
    FormatError
        Not UTF-8 (with the byte offset), a line without exactly two cells or with an
        unknown label (with the line), or no edge at all.
    """
    p = check_readable(path)
    text = read_utf8_text(p)
    index = {lab: i for i, lab in enumerate(labels)}
    pairs: list[tuple[int, int]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        cells = [c.strip() for c in line.split(",")]
        if not line.strip():
            continue
        if len(cells) != 2:
            raise FormatError(p, f"expected two labels per line, got {len(cells)}", line=number)
        if cells[0] not in index or cells[1] not in index:
            if number == 1 and not pairs:
                continue  # a header line
            unknown = cells[0] if cells[0] not in index else cells[1]
            raise FormatError(p, f"unknown marker label {unknown!r}", line=number)
        pairs.append((index[cells[0]], index[cells[1]]))
    if not pairs:
        raise FormatError(p, "no edges")
    return np.asarray(pairs, dtype=np.int64)
