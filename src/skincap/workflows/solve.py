"""``skincap solve``'s file-in/file-out glue: a labelled capture to a solved BVH.

Reads the capture (C3D, TRC or CSV), solves it with :func:`skincap.solve.solve_markers`
(or the model found by :func:`skincap.solve.auto.calibrate_auto` for ``"auto"``), and
writes the BVH, optionally the model's markers (``--markers-out``) and the residual
report (``--report``). Everything is computed before the first file is written, and
each file is written to a temporary name and renamed, so a failure leaves no output.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.errors import FormatError, ValidationError, naming_file
from skincap.io import read, write
from skincap.io._common import atomic_output
from skincap.types import MarkerSet

#: Extensions ``--markers-out`` writes.
MARKER_OUTPUTS = (".c3d", ".trc", ".csv")
#: Most rounds of --refine-offsets taken (each one a full IK over the take).
MAX_REFINE_ROUNDS = 20

__all__ = [
    "check_solve_options",
    "solve_file",
    "read_labelled_markers",
    "read_synth_take",
    "check_synth_dense_body",
    "synth_take_in_memory",
    "evaluate_solve",
]


#: Farthest a marker of a capture may lie from the origin, metres: a sample beyond it is
#: a corrupt value (or a wrong unit), and the rigid fits of the calibration lose every
#: other marker's digits against it (3e35 m gave a null rotation and a traceback).
MAX_CAPTURE_COORDINATE_M = 1e4


def read_labelled_markers(path: str | os.PathLike[str]) -> MarkerSet:
    """The labelled markers of a capture file (``*N`` fragment columns dropped).

    Raises
    ------
    FormatError
        The file holds no markers, or no labelled ones, or a sample farther than
        :data:`MAX_CAPTURE_COORDINATE_M` from the origin.
    """
    data = read(path)
    if not isinstance(data, MarkerSet):
        raise FormatError(path, "solve reads labelled markers (C3D, TRC or trajectories CSV)")
    keep = [k for k, label in enumerate(data.labels) if not label.startswith("*")]
    if not keep:
        raise FormatError(path, "has no labelled markers (only '*N' fragments): label it first")
    data = data if len(keep) == data.n_markers else data.select(keep)
    far = np.abs(data.positions) > MAX_CAPTURE_COORDINATE_M  # NaN (missing) compares False
    if far.any():
        t, n, _ = (int(i[0]) for i in np.nonzero(far))
        raise FormatError(
            path,
            f"marker {data.labels[n]!r} in frame {t} lies at "
            f"{[float(x) for x in data.positions[t, n]]} m, beyond the "
            f"±{MAX_CAPTURE_COORDINATE_M:g} m a capture may reach (a corrupt sample or a wrong unit?)",
        )
    return data


def check_solve_options(
    output_path: str | os.PathLike[str],
    markers_out: str | os.PathLike[str] | None,
    loss: str,
    loss_scale_m: float,
    refine_offsets: int,
) -> None:
    """Refuse :func:`solve_file`'s options that need no input read: the output
    extensions, the IK loss, its scale ``loss_scale_m`` (metres, reported in cm as the
    CLI's ``--loss-scale-cm``) and the count of offset-refining rounds.

    Raises
    ------
    ValidationError
        The first bad option, in that order.
    """
    if Path(output_path).suffix.lower() != ".bvh":
        raise ValidationError(
            f"-o: the solved motion is written as .bvh, got {Path(output_path).name!r}"
        )
    if markers_out is not None and Path(markers_out).suffix.lower() not in MARKER_OUTPUTS:
        raise ValidationError(
            f"--markers-out: expected {', '.join(MARKER_OUTPUTS)}, got {Path(markers_out).name!r}"
        )
    from skincap.solve.ik import LOSSES

    if loss not in LOSSES:
        raise ValidationError(f"--loss: expected one of {', '.join(LOSSES)}, got {loss!r}")
    if not (math.isfinite(loss_scale_m) and loss_scale_m > 0):
        raise ValidationError(
            f"--loss-scale-cm: expected a positive length, got {loss_scale_m * 100:g}"
        )
    if not 0 <= refine_offsets <= MAX_REFINE_ROUNDS:
        # each round is another full IK: a billion of them never ends
        raise ValidationError(
            f"--refine-offsets: expected a count 0..{MAX_REFINE_ROUNDS}, got {refine_offsets}"
        )


def _check_smooth_hz(smooth_hz: float | None, rate: float) -> None:
    """Refuse a low-pass cut-off ``smooth_hz`` (Hz) outside (0, Nyquist) of the
    capture's frame ``rate`` (Hz); ``None`` (no smoothing) passes.

    Raises
    ------
    ValidationError
        ``smooth_hz`` is not between 0 and half of ``rate``.
    """
    if smooth_hz is not None and not 0.0 < smooth_hz < 0.5 * rate:
        raise ValidationError(
            f"--smooth-hz: expected between 0 and {0.5 * rate:g} Hz (half the "
            f"{rate:g} Hz frame rate), got {smooth_hz:g}"
        )


def _resolve_template(template: str, input_path: str | os.PathLike[str], markers: MarkerSet) -> Any:
    """The template :func:`~skincap.solve.solve_markers` takes for ``template``: the
    name or JSON path as given, or for ``"auto"`` the body model found and calibrated
    on ``markers`` (:func:`~skincap.solve.auto.calibrate_auto`). ``"synth-dense"`` first checks that
    ``input_path`` is a dense synthetic take (:func:`check_synth_dense_body`).
    """
    if template == "synth-dense":
        check_synth_dense_body(input_path)
    if template == "auto":
        from skincap.solve.auto import calibrate_auto
        from skincap.solve.outliers import off_body_samples

        # the search must not see what solve_markers leaves out (and warns about) later
        off = off_body_samples(markers.positions)
        if off.any():
            markers = replace(
                markers, positions=np.where(off[..., None], np.nan, markers.positions)
            )
        tpl: Any = calibrate_auto(markers)
    else:
        tpl = template
    return tpl


def _write_solve_outputs(
    result: Any,
    rep: dict[str, Any],
    output_path: str | os.PathLike[str],
    markers_out: str | os.PathLike[str] | None,
    report: str | os.PathLike[str] | None,
    *,
    force: bool,
    units: str,
) -> list[str]:
    """Write the solve's BVH (lengths in ``units``), the fitted markers and the JSON
    report ``rep``, the last two when asked; all or nothing: a failed write removes
    what this call wrote before it, and re-raises.

    Returns
    -------
    list of str
        The paths written, in that order.
    """
    outputs: list[str] = []
    try:  # all or nothing: a failed write removes what this call wrote before it
        write(result.motion, output_path, force=force, units=units)
        outputs.append(os.fspath(output_path))
        if markers_out is not None:
            write(result.fitted, markers_out, force=force)
            outputs.append(os.fspath(markers_out))
        if report is not None:
            with atomic_output(report, force=force) as tmp:
                tmp.write_text(json.dumps(rep, indent=1) + "\n", encoding="utf-8")
            outputs.append(os.fspath(report))
    except BaseException:
        for done in outputs:
            Path(done).unlink(missing_ok=True)
        raise
    return outputs


def solve_file(
    input_path: str | os.PathLike[str],
    output_path: str | os.PathLike[str],
    *,
    template: str = "cmu41",
    units: str = "cm",
    markers_out: str | os.PathLike[str] | None = None,
    report: str | os.PathLike[str] | None = None,
    force: bool = False,
    smooth_hz: float | None = None,
    loss: str = "squared",
    loss_scale_m: float = 0.02,
    refine_offsets: int = 1,
    joint_limits: bool = False,
    reject_jumps: bool = True,
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
    smooth_hz : float, optional
        Low-pass cut-off (Hz) of the solved poses; default none.
    loss, loss_scale_m, refine_offsets, joint_limits
        The IK's loss, its scale (metres), the rounds of marker-offset re-fitting and
        whether the template's joint limits hold, whether samples that jump off their
        segment are left out (:func:`skincap.solve.solve_markers`).
    progress : callable(fraction, label), optional

    Returns
    -------
    dict
        ``frames``, ``joints``, ``markers``, ``rms_m``, ``max_m``, ``template``,
        ``rejected`` (samples left out as jumps), ``off_body`` (samples left out as too far
        from the body), ``outputs`` (the files written).
    """
    check_solve_options(output_path, markers_out, loss, loss_scale_m, refine_offsets)
    markers = read_labelled_markers(input_path)
    _check_smooth_hz(smooth_hz, markers.rate)
    from skincap.solve import solve_markers

    tpl = _resolve_template(template, input_path, markers)
    result = solve_markers(
        markers,
        tpl,
        smooth_hz=smooth_hz,
        loss=loss,
        loss_scale=loss_scale_m,
        refine_offsets=refine_offsets,
        joint_limits=joint_limits,
        reject_jumps=reject_jumps,
        progress=progress,
    )
    rep = result.report()
    rep["input"] = os.fspath(input_path)
    outputs = _write_solve_outputs(
        result, rep, output_path, markers_out, report, force=force, units=units
    )
    return {
        "input": os.fspath(input_path),
        "template": rep["template"],
        "frames": rep["frames"],
        "joints": rep["joints"],
        "markers": rep["markers_used"],
        "rms_m": rep["overall"]["rms_m"],
        "max_m": rep["overall"]["max_m"],
        "rejected": rep["rejected_samples"]["count"],
        "off_body": rep["off_body_samples"]["count"],
        "outputs": outputs,
    }


def read_synth_take(folder: str | os.PathLike[str]) -> tuple[MarkerSet, Any]:
    """The labelled take and the true motion of a ``skincap synth --markers sparse`` folder.

    Returns
    -------
    markers : MarkerSet
        ``capture.c3d`` with each fragment moved to its true marker (``truth/fragments.csv``).
    truth : Motion
        ``truth/motion.bvh`` (metres).
    """
    import csv

    from skincap.evaluate.solve import labelled_from_fragments
    from skincap.io.bvh import read_bvh

    root = Path(folder)
    if not root.is_dir():
        raise FormatError(root, "not a folder (expected one written by skincap synth)")
    for name in ("capture.c3d", "truth/fragments.csv", "truth/motion.bvh"):
        if not (root / name).is_file():
            raise FormatError(root / name, "missing: the folder was not written by skincap synth")
    capture = read(root / "capture.c3d")
    with open(root / "truth" / "fragments.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or set(rows[0]) != {"fragment", "truth"}:
        raise FormatError(root / "truth" / "fragments.csv", "expected the columns fragment,truth")
    mapping = {r["fragment"]: r["truth"] for r in rows}
    truth = read_bvh(root / "truth" / "motion.bvh", units="m")
    return labelled_from_fragments(capture, mapping), truth


def check_synth_dense_body(capture: str | os.PathLike[str]) -> None:
    """Refuse the synth-dense template for a take made on another synthetic body.

    synth-dense's labels ``D000``... name skin points of the body of ``skincap synth
    --markers dense --vertices 20000 --seed 0``; on any other body they sit elsewhere.
    A take in a ``skincap synth`` folder (``capture`` is ``DIR/capture.c3d`` or
    ``DIR/truth/markers.c3d``, or ``DIR`` itself) is checked against that folder's
    ``truth/marker_parts.csv``; for any other capture nothing tells the body, and a
    :class:`~skincap.errors.SkincapWarning` says so.

    Raises
    ------
    FormatError
        Fewer than :data:`~skincap.evaluate.solve.SYNTH_DENSE_MIN_AGREEMENT` of the
        template's markers ride their segment on the folder's body.
    """
    import csv
    import warnings

    from skincap.errors import SkincapWarning
    from skincap.evaluate.solve import SYNTH_DENSE_MIN_AGREEMENT, synth_dense_body_check

    path = Path(capture)
    folders = [path] if path.is_dir() else [path.parent, path.parent.parent]
    parts_file = next(
        (
            f / "truth" / "marker_parts.csv"
            for f in folders
            if (f / "truth" / "marker_parts.csv").is_file()
        ),
        None,
    )
    if parts_file is None:
        warnings.warn(
            "template synth-dense: its labels name skin points of the default synthetic body "
            "(skincap synth --markers dense --vertices 20000 --seed 0); this capture is not in "
            "a skincap synth folder, so which body it comes from cannot be checked",
            SkincapWarning,
            stacklevel=2,
        )
        return
    with open(parts_file, newline="", encoding="utf-8") as fh:
        parts = {row.get("marker", ""): row.get("part", "") for row in csv.DictReader(fh)}
    agree, total = synth_dense_body_check(parts)
    if agree < SYNTH_DENSE_MIN_AGREEMENT * total:
        raise FormatError(
            parts_file,
            f"template synth-dense fits only the body of 'skincap synth --markers dense "
            f"--vertices 20000 --seed 0': on this take's body {agree} of its {total} markers "
            "ride their segment; make the take with those options",
        )


def synth_take_in_memory(
    motion: str, *, frames: int, vertices: int, seed: int, progress: Progress | None = None
) -> tuple[MarkerSet, Any]:
    """A sparse-marker synthetic take made in memory: (labelled markers, true motion)."""
    from skincap.evaluate.solve import labelled_from_fragments
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=vertices, seed=seed)
    clip = build_motion(
        body, motion, frames=frames, seed=seed, units="cmu" if motion.endswith(".bvh") else None
    )
    take = generate_capture(body, clip, markers="sparse", seed=seed, progress=progress)
    return labelled_from_fragments(take.capture, take.fragment_truth), take.motion


def evaluate_solve(
    output_dir: str | os.PathLike[str],
    *,
    synth_dir: str | os.PathLike[str] | None = None,
    synth_motion: str | None = None,
    real: list[str | os.PathLike[str]] = (),  # type: ignore[assignment]
    real_template: str = "cmu41",
    frames: int = 600,
    vertices: int = 8000,
    seed: int = 0,
    auto: bool = True,
    force: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """``skincap eval solve``: measure the solver and write ``DIR/solve_eval.json``.

    Returns the result with ``table`` (the issue's targets, one row each).
    """
    from skincap.evaluate.solve import (
        evaluate_auto,
        evaluate_real,
        evaluate_synthetic,
        targets_table,
    )

    out = Path(output_dir)
    report_path = out / "solve_eval.json"
    synthetic = auto_result = None
    source = None
    if synth_dir is not None or synth_motion is not None:
        if synth_dir is not None:
            markers, truth = read_synth_take(synth_dir)
            source = os.fspath(synth_dir)
            from skincap.solve.templates import detect_template

            if detect_template(markers.labels, candidates=("synth-sparse", "synth-dense")) == (
                "synth-dense"
            ):
                check_synth_dense_body(synth_dir)
        else:

            def sub(f: float, label: str) -> None:
                if progress is not None:
                    progress(0.5 * f, f"synth: {label}")

            markers, truth = synth_take_in_memory(
                str(synth_motion), frames=frames, vertices=vertices, seed=seed, progress=sub
            )
            source = f"synth {synth_motion} (sparse, {frames} frames, seed {seed})"
        if progress is not None:
            progress(0.5, "solving the synthetic take")
        synthetic = evaluate_synthetic(markers, truth)
        if auto:
            if progress is not None:
                progress(0.7, "--template auto")
            auto_result = evaluate_auto(markers, truth)
    reals: dict[str, Any] = {}
    for path in real:
        if progress is not None:
            progress(0.85, f"solving {Path(path).name}")
        with naming_file(path):  # "the take has 1 frames" says which --real take
            reals[Path(path).name] = evaluate_real(read_labelled_markers(path), real_template)
    if synthetic is None and not reals:
        raise ValidationError("give a synth folder, --synth MOTION or --real FILE (at least one)")
    result: dict[str, Any] = {
        "synthetic_source": source,
        "synthetic": synthetic,
        "auto": auto_result,
        "real": reals,
        "table": targets_table(synthetic, reals, auto_result),
    }
    out.mkdir(parents=True, exist_ok=True)
    with atomic_output(report_path, force=force) as tmp:
        tmp.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    result["outputs"] = [os.fspath(report_path)]
    return result
