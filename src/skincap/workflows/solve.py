"""``skincap solve``'s file-in/file-out glue: a labelled capture to a solved BVH.

Reads the capture (C3D, TRC or CSV), solves it with :func:`skincap.solve.solve_markers`
(or the template found by :func:`skincap.solve.auto.auto_template` for ``"auto"``), and
writes the BVH, optionally the model's markers (``--markers-out``) and the residual
report (``--report``). Everything is computed before the first file is written, and
each file is written to a temporary name and renamed, so a failure leaves no output.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from skincap._arrays import Progress
from skincap.errors import FormatError, ValidationError
from skincap.io import read, write
from skincap.io._common import atomic_output
from skincap.types import MarkerSet

__all__ = ["solve_file", "read_labelled_markers"]


def read_labelled_markers(path: str | os.PathLike[str]) -> MarkerSet:
    """The labelled markers of a capture file (``*N`` fragment columns dropped).

    Raises
    ------
    FormatError
        The file holds no markers, or no labelled ones.
    """
    data = read(path)
    if not isinstance(data, MarkerSet):
        raise FormatError(path, "solve reads labelled markers (C3D, TRC or trajectories CSV)")
    keep = [k for k, label in enumerate(data.labels) if not label.startswith("*")]
    if not keep:
        raise FormatError(path, "has no labelled markers (only '*N' fragments): label it first")
    return data if len(keep) == data.n_markers else data.select(keep)


def solve_file(
    input_path: str | os.PathLike[str],
    output_path: str | os.PathLike[str],
    *,
    template: str = "cmu41",
    units: str = "cm",
    markers_out: str | os.PathLike[str] | None = None,
    report: str | os.PathLike[str] | None = None,
    force: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Solve ``input_path`` and write the BVH (and the optional outputs).

    Parameters
    ----------
    input_path : path
        Labelled capture (.c3d, .trc, .csv).
    output_path : path
        The BVH to write.
    template : str
        Built-in template name, a JSON file, or ``"auto"``.
    units : str
        Length unit of the BVH (``m``, ``cm``, ``mm``, ``in``...).
    markers_out : path, optional
        Where to write the model's markers per frame (C3D, TRC or CSV by extension).
    report : path, optional
        Where to write the JSON residual report.
    force : bool
        Replace existing outputs.
    progress : callable(fraction, label), optional

    Returns
    -------
    dict
        ``frames``, ``joints``, ``markers``, ``rms_m``, ``max_m``, ``template``,
        ``outputs`` (the files written).
    """
    if Path(output_path).suffix.lower() != ".bvh":
        raise ValidationError(f"-o: the solved motion is written as .bvh, got {Path(output_path).name!r}")
    markers = read_labelled_markers(input_path)
    from skincap.solve import solve_markers

    if template == "auto":
        from skincap.solve.auto import auto_template

        tpl: Any = auto_template(markers).template
    else:
        tpl = template
    result = solve_markers(markers, tpl, progress=progress)
    rep = result.report()
    rep["input"] = os.fspath(input_path)
    outputs = [os.fspath(output_path)]
    write(result.motion, output_path, force=force, units=units)
    if markers_out is not None:
        write(result.fitted, markers_out, force=force)
        outputs.append(os.fspath(markers_out))
    if report is not None:
        with atomic_output(report, force=force) as tmp:
            tmp.write_text(json.dumps(rep, indent=1) + "\n", encoding="utf-8")
        outputs.append(os.fspath(report))
    return {
        "input": os.fspath(input_path),
        "template": rep["template"],
        "frames": rep["frames"],
        "joints": rep["joints"],
        "markers": rep["markers_used"],
        "rms_m": rep["overall"]["rms_m"],
        "max_m": rep["overall"]["max_m"],
        "outputs": outputs,
    }
