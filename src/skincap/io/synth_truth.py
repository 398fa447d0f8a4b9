"""The ground-truth files of a ``skincap synth`` folder, read back for evaluation.

``truth/fragments.csv``
    ``fragment,truth``: the true label (or ``ghost``) of every ``*N`` fragment of
    ``capture.c3d`` (:func:`read_fragment_truth`; ``skincap clean --fragment-truth``).
``truth/points.csv``
    ``row,frame,truth``: the true marker of every row of ``capture_points.csv``
    (:func:`read_point_truth`).
``truth/marker_parts.csv``
    ``marker,part``: the true near-rigid part (``pelvis``, ``thigh_l``, …; the 17 of
    :data:`skincap.synth.marker_parts.PART_NAMES`) of every body marker, the dominant
    bone group of its skin weights (:func:`write_marker_parts`,
    :func:`read_marker_parts`; scores ``skincap.deform.dense`` segmentation).
The folder as a whole (:func:`read_synth_folder`; ``skincap eval track``): the
un-indexed capture, its per-point truth and the clean markers ``truth/markers.c3d``,
checked against each other. The writer is :mod:`skincap.workflows.synth_folder`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from skincap.errors import FormatError
from skincap.io._common import atomic_output, check_readable, read_utf8_text
from skincap.types import MarkerSet, PointCloud

__all__ = [
    "read_fragment_truth",
    "read_marker_parts",
    "read_point_truth",
    "read_synth_folder",
    "write_marker_parts",
    "SYNTH_TRACK_INPUTS",
]

#: The files :func:`read_synth_folder` reads, relative to the folder.
SYNTH_TRACK_INPUTS = ("capture_points.csv", "truth/markers.c3d", "truth/points.csv")


def read_fragment_truth(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a ``fragment,truth`` CSV: fragment label -> true label.

    Blank lines and a ``fragment,truth`` header line are skipped.

    Raises
    ------
    FormatError
        Not UTF-8 (with the byte offset), a line that is not two non-empty cells (with
        the line), or no row at all.
    """
    p = check_readable(path)
    text = read_utf8_text(p)
    truth: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != 2 or not cells[0] or not cells[1]:
            raise FormatError(p, "expected 'fragment,truth' on every line", line=number)
        if number == 1 and cells == ["fragment", "truth"]:
            continue
        truth[cells[0]] = cells[1]
    if not truth:
        raise FormatError(p, "no fragment rows")
    return truth


def write_marker_parts(
    path: str | os.PathLike[str],
    labels: list[str],
    parts: list[str],
    *,
    force: bool = False,
) -> None:
    """Write ``truth/marker_parts.csv``: a ``marker,part`` header, one row per marker.

    Parameters
    ----------
    path : path-like
    labels : list of N str
        Marker labels, in the capture's column order (unique, no comma or newline).
    parts : list of N str
        The true part of each marker (no comma or newline).
    force : bool
        Replace an existing file.

    Raises
    ------
    ValidationError
        Lengths differ, a duplicate label, or a cell that would break the CSV.
    OutputExistsError
        ``path`` exists and not ``force``.
    """
    from skincap.errors import ValidationError

    if len(labels) != len(parts):
        raise ValidationError(f"labels ({len(labels)}) and parts ({len(parts)}) differ in length")
    if len(set(labels)) != len(labels):
        raise ValidationError("labels: must be unique")
    cells = [str(c) for c in (*labels, *parts)]
    if any(not c or "," in c or "\n" in c or "\r" in c for c in cells):
        raise ValidationError("labels and parts must be non-empty and hold no comma or newline")
    text = "marker,part\n" + "".join(f"{m},{p}\n" for m, p in zip(labels, parts, strict=True))
    with atomic_output(Path(path), force=force) as tmp:
        tmp.write_text(text, encoding="utf-8")


def read_marker_parts(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read ``truth/marker_parts.csv``: marker label -> true part name, in file order.

    Raises
    ------
    FormatError
        Not UTF-8, a header other than ``marker,part``, a row that is not two
        non-empty cells, a marker listed twice (with the line), or no row.
    """
    p = check_readable(path)
    text = read_utf8_text(p)
    lines = text.splitlines()
    if not lines or lines[0].strip() != "marker,part":
        raise FormatError(p, "expected the header 'marker,part'", line=1)
    parts: dict[str, str] = {}
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != 2 or not cells[0] or not cells[1]:
            raise FormatError(p, "expected 'marker,part' on every line", line=number)
        if cells[0] in parts:
            raise FormatError(p, f"marker {cells[0]!r} is listed twice", line=number)
        parts[cells[0]] = cells[1]
    if not parts:
        raise FormatError(p, "no marker rows")
    return parts


def read_point_truth(path: str | os.PathLike[str], cloud: PointCloud) -> np.ndarray:
    """Read ``truth/points.csv`` (``row,frame,truth``) and check it against ``cloud``.

    Parameters
    ----------
    path : path-like
    cloud : PointCloud
        The capture the file describes: one row per point, rows numbered 0, 1, …
        and each on its point's frame.

    Returns
    -------
    (M,) str
        The true label of every point of ``cloud`` (a marker label or ``ghost``).

    Raises
    ------
    FormatError
        Not UTF-8, a wrong header, a row count other than the cloud's points, a row
        without 3 fields or with non-integer row/frame, or a row whose number or
        frame differs from the cloud's (with the line).
    """
    p = check_readable(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(p, f"not UTF-8 text (byte {exc.start})") from None
    lines = text.splitlines()
    if not lines or lines[0].strip() != "row,frame,truth":
        raise FormatError(p, "expected the header 'row,frame,truth'", line=1)
    body = lines[1:]
    if len(body) != cloud.points.shape[0]:
        raise FormatError(
            p,
            f"has {len(body)} rows, capture_points.csv has {cloud.points.shape[0]} points",
        )
    fields = [line.split(",") for line in body]
    bad = next((i for i, f in enumerate(fields) if len(f) != 3), None)
    if bad is not None:
        raise FormatError(p, "expected 3 fields: row,frame,truth", line=bad + 2)
    cols = np.array(fields, dtype=str).reshape(-1, 3)
    try:
        rows = cols[:, 0].astype(np.int64)
        frames = cols[:, 1].astype(np.int64)
    except (ValueError, OverflowError):
        num = np.char.isdigit(cols[:, 0]) & np.char.isdigit(cols[:, 1])
        num &= (np.char.str_len(cols[:, 0]) < 19) & (np.char.str_len(cols[:, 1]) < 19)
        first = int(np.flatnonzero(~num)[0]) if (~num).any() else 0
        raise FormatError(p, "row and frame must be integers", line=first + 2) from None
    wrong = (rows != np.arange(rows.size)) | (frames != cloud.frame_index)
    if wrong.any():
        i = int(np.flatnonzero(wrong)[0])
        raise FormatError(
            p, f"row {i} does not match capture_points.csv (row or frame differs)", line=i + 2
        )
    return cols[:, 2]


def read_synth_folder(folder: str | os.PathLike[str]) -> tuple[PointCloud, np.ndarray, MarkerSet]:
    """The un-indexed capture, per-point truth and clean markers of a ``skincap synth`` folder.

    The folder must hold a rope (``--rope jump|whip``): rope points must lie on their
    true markers (median distance 1 cm at most), which ties the three files together.

    Returns
    -------
    cloud : PointCloud
        ``capture_points.csv``.
    point_truth : (M,) str
        ``truth/points.csv``, one label per point of ``cloud``.
    truth : MarkerSet
        ``truth/markers.c3d``, the clean markers (``rope_00``… along the rope).

    Raises
    ------
    FormatError
        Not a folder, a file missing or malformed, frame counts that differ, no rope
        points, or truth that does not describe the capture.
    """
    from skincap.io.c3d import read_c3d
    from skincap.io.csv import read_points_csv

    root = Path(folder)
    if not root.is_dir():
        raise FormatError(root, "not a folder (expected one written by skincap synth)")
    cloud = read_points_csv(root / "capture_points.csv")
    truth_path = root / "truth" / "markers.c3d"
    truth = read_c3d(truth_path)
    point_truth = read_point_truth(root / "truth" / "points.csv", cloud)
    if truth.n_frames != cloud.n_frames:
        raise FormatError(
            truth_path, f"has {truth.n_frames} frames, capture_points.csv {cloud.n_frames}"
        )
    # The truth must describe these points: rope points lie on their true markers.
    rope = np.char.startswith(point_truth, "rope_")
    if not rope.any():
        raise FormatError(
            root / "truth" / "points.csv",
            "no rope_NN points: make the take with --rope jump|whip",
        )
    index = {label: i for i, label in enumerate(truth.labels)}
    labels = point_truth[rope]
    unknown = sorted(set(labels.tolist()) - set(index))
    if unknown:
        raise FormatError(truth_path, f"has no marker {unknown[0]!r} named in truth/points.csv")
    names, which = np.unique(labels, return_inverse=True)
    col = np.array([index[name] for name in names.tolist()], dtype=np.int64)[which]
    dist = np.linalg.norm(
        cloud.points[rope] - truth.positions[cloud.frame_index[rope], col], axis=1
    )
    median = float(np.nanmedian(dist)) if np.isfinite(dist).any() else float("inf")
    if median > 0.01:
        raise FormatError(
            truth_path,
            f"rope points lie {median * 1000:.0f} mm (median) from their true markers: "
            "not the truth of capture_points.csv",
        )
    return cloud, point_truth, truth
