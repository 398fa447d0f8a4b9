"""The verbs a batch runs: for each, its workflow, the outputs of one take and its figures.

A :class:`BatchVerb` says how one take (one input file) becomes one call of a
:mod:`skincap.workflows` function: which files it writes under the batch's output
folder (named after the input), which keyword arguments carry them, which kernels it
may reach (compiled ahead, :func:`skincap.backends.start_pending_compiles`) and
which figures of the workflow's returned summary go in the batch table. The
workflow checks every option itself, exactly as when its verb runs alone.

Workers look a verb up here by its name, so nothing but names, paths and option
values travel through the scheduler.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skincap.errors import ValidationError

__all__ = ["BATCH_VERBS", "BatchVerb", "TakePlan", "batch_verb"]


@dataclass(frozen=True)
class TakePlan:
    """One take's call of its workflow.

    Attributes
    ----------
    call : callable(options, input) -> (args, kwargs)
        The workflow's positional and keyword arguments for the input file: the
        take's output paths placed, the batch's own options removed.
    outputs : list of Path
        Every file the take writes; the take is done when they all exist.
    """

    call: Callable[[Mapping[str, Any], Path], tuple[tuple[Any, ...], dict[str, Any]]]
    outputs: list[Path]


@dataclass(frozen=True)
class BatchVerb:
    """How ``skincap batch <name>`` runs one take.

    Attributes
    ----------
    name : str
        The verb (``clean``, ``track``, ...).
    workflow : str
        ``module:function`` of the workflow called once per take.
    suffixes : tuple of str
        Input extensions taken from a folder given as input.
    plan : callable(out_dir, name, options) -> TakePlan
        The take's outputs under ``out_dir`` (named ``name``, the input's name) and
        how the workflow is called with them.
    figures : callable(summary) -> dict
        The key figures (scalars) of the workflow's returned summary.
    kernels : tuple of str
        Compiled kernels the verb may reach (keys of :data:`skincap.backends.WARM_UPS`).
    batch_options : tuple of str
        Options the batch adds to the workflow's (consumed by ``plan``, not passed on).
    check : callable(out_dir, options), optional
        The workflow's own check of the options that need no file read, run once
        before any take (a bad option is one error, not one per take).
    """

    name: str
    workflow: str
    suffixes: tuple[str, ...]
    plan: Callable[[Path, str, Mapping[str, Any]], TakePlan]
    figures: Callable[[Mapping[str, Any]], dict[str, Any]]
    kernels: tuple[str, ...] = ()
    batch_options: tuple[str, ...] = field(default=())
    check: Callable[[Path, Mapping[str, Any]], None] | None = None

    def workflow_function(self) -> Callable[..., dict[str, Any]]:
        """The workflow itself (imported on first use, in the worker)."""
        module, function = self.workflow.split(":")
        workflow: Callable[..., dict[str, Any]] = getattr(importlib.import_module(module), function)
        return workflow


def _workflow_options(options: Mapping[str, Any], batch_options: tuple[str, ...]) -> dict[str, Any]:
    return {k: v for k, v in options.items() if k not in batch_options}


# ------------------------------------------------------------------------- clean
def _plan_clean(out_dir: Path, name: str, options: Mapping[str, Any]) -> TakePlan:
    output, report = out_dir / f"{name}.c3d", out_dir / f"{name}.report.json"

    def call(opts: Mapping[str, Any], src: Path) -> tuple[tuple[Any, ...], dict[str, Any]]:
        return (src, output), {**opts, "report": report}

    return TakePlan(call, [output, report])


def _clean_figures(summary: Mapping[str, Any]) -> dict[str, Any]:
    from skincap.workflows.clean_file import clean_summary

    figures = clean_summary(dict(summary))
    return {k: v for k, v in figures.items() if k not in ("input", "output")}


def _check_clean(out_dir: Path, options: Mapping[str, Any]) -> None:
    from skincap.workflows.clean_file import check_clean_options

    check_clean_options(
        options.get("method", "local_pca"),
        options.get("rigid_blend"),
        options.get("smooth", True),
        options.get("iterations", 10),
    )


# ------------------------------------------------------------------------- track
def _plan_track(out_dir: Path, name: str, options: Mapping[str, Any]) -> TakePlan:
    from skincap.workflows.track_file import OUTPUT_NAMES

    folder = out_dir / name

    def call(opts: Mapping[str, Any], src: Path) -> tuple[tuple[Any, ...], dict[str, Any]]:
        return (src, folder), dict(opts)

    return TakePlan(call, [folder / n for n in OUTPUT_NAMES])


def _track_figures(summary: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "frames": summary["frames"],
        "rope_markers": len(summary["rope_markers"]),
        "rope_points": summary["rope_points"],
        "body_points": summary["body_points"],
        "invented_samples": summary["invented_samples"],
        "lost_traces": len(summary["lost_traces"]),
    }


# ------------------------------------------------------------------------- solve
def _plan_solve(out_dir: Path, name: str, options: Mapping[str, Any]) -> TakePlan:
    output, report = out_dir / f"{name}.bvh", out_dir / f"{name}.report.json"

    def call(opts: Mapping[str, Any], src: Path) -> tuple[tuple[Any, ...], dict[str, Any]]:
        return (src, output), {**opts, "report": report}

    return TakePlan(call, [output, report])


def _solve_figures(summary: Mapping[str, Any]) -> dict[str, Any]:
    return {
        k: summary[k]
        for k in ("frames", "joints", "markers", "template", "rms_m", "max_m", "rejected")
    }


def _check_solve(out_dir: Path, options: Mapping[str, Any]) -> None:
    from skincap.workflows.solve import check_solve_options

    check_solve_options(
        out_dir / "take.bvh",
        None,
        options.get("loss", "squared"),
        options.get("loss_scale_m", 0.02),
        options.get("refine_offsets", 1),
    )


# ----------------------------------------------------------------------- convert
def _target_suffix(options: Mapping[str, Any], verb: str) -> str:
    to = options.get("to")
    if not isinstance(to, str) or not to:
        raise ValidationError(f"--to: batch {verb} needs the output extension, e.g. --to .trc")
    return to if to.startswith(".") else f".{to}"


def _plan_convert(out_dir: Path, name: str, options: Mapping[str, Any]) -> TakePlan:
    output = out_dir / f"{name}{_target_suffix(options, 'convert')}"

    def call(opts: Mapping[str, Any], src: Path) -> tuple[tuple[Any, ...], dict[str, Any]]:
        return (src, output), _workflow_options(opts, ("to",))

    return TakePlan(call, [output])


def _counts(summary: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in summary.items() if isinstance(v, int | float | str)}


# -------------------------------------------------------------------------- skin
def _plan_skin(out_dir: Path, name: str, options: Mapping[str, Any]) -> TakePlan:
    from skincap.workflows.skin_file import skin_output_files

    output = out_dir / f"{name}{_target_suffix(options, 'skin')}"
    mesh = options.get("mesh")
    if mesh is None:
        raise ValidationError("--mesh: batch skin needs the body mesh every motion skins")

    def call(opts: Mapping[str, Any], src: Path) -> tuple[tuple[Any, ...], dict[str, Any]]:
        return (mesh, src, output), _workflow_options(opts, ("to", "mesh"))

    return TakePlan(call, skin_output_files(output))


def _check_skin(out_dir: Path, options: Mapping[str, Any]) -> None:
    from skincap.workflows.skin_file import check_skin_request

    output = out_dir / f"take{_target_suffix(options, 'skin')}"
    check_skin_request(
        output, method=options.get("method", "lbs"), weights=options.get("weights"), force=True
    )


def _skin_figures(summary: Mapping[str, Any]) -> dict[str, Any]:
    keys = ("frames", "rate", "vertices", "joints", "height_m", "weights")
    return {k: summary[k] for k in keys if k in summary}


# ----------------------------------------------------------------------- animate
def _plan_animate(out_dir: Path, name: str, options: Mapping[str, Any]) -> TakePlan:
    from skincap.io.mesh_animation_files import animation_output_files

    output = out_dir / f"{name}{_target_suffix(options, 'animate')}"
    report = out_dir / f"{name}.report.json"
    mesh = options.get("mesh")

    def call(opts: Mapping[str, Any], src: Path) -> tuple[tuple[Any, ...], dict[str, Any]]:
        return (mesh, src, output), {**_workflow_options(opts, ("to", "mesh")), "report": report}

    return TakePlan(call, [*animation_output_files(output), report])


def _check_animate(out_dir: Path, options: Mapping[str, Any]) -> None:
    from skincap.errors import FormatError
    from skincap.workflows.animate_file import ANIMATE_OUTPUTS, check_animate_options

    to = _target_suffix(options, "animate")
    if to.lower() not in ANIMATE_OUTPUTS:
        raise FormatError("--to", f"animate writes {', '.join(ANIMATE_OUTPUTS)}, not {to!r}")
    if options.get("mesh") is None and options.get("rig") is None:
        raise ValidationError("--mesh: batch animate needs the body mesh, or a saved --rig")
    check_animate_options(
        options.get("method", "quadratic_rbf"),
        options.get("n_parts", 17),
        options.get("marker_radius_mm", 0.0),
    )


def _animate_figures(summary: Mapping[str, Any]) -> dict[str, Any]:
    keys = ("frames", "vertices", "markers", "method", "parts")
    return {k: summary[k] for k in keys if isinstance(summary.get(k), int | float | str)}


#: Every verb ``skincap batch`` runs, by name.
BATCH_VERBS: dict[str, BatchVerb] = {
    v.name: v
    for v in (
        BatchVerb(
            "clean",
            "skincap.workflows.clean_file:clean_file",
            (".c3d", ".trc", ".csv"),
            _plan_clean,
            _clean_figures,
            check=_check_clean,
        ),
        BatchVerb(
            "track",
            "skincap.workflows.track_file:track_file",
            (".csv", ".c3d"),
            _plan_track,
            _track_figures,
            kernels=("tracking",),
        ),
        BatchVerb(
            "solve",
            "skincap.workflows.solve:solve_file",
            (".c3d", ".trc", ".csv"),
            _plan_solve,
            _solve_figures,
            kernels=("ik",),
            check=_check_solve,
        ),
        BatchVerb(
            "convert",
            "skincap.workflows.convert_file:convert_file",
            (".c3d", ".trc", ".csv", ".bvh", ".obj", ".ply", ".glb", ".gltf"),
            _plan_convert,
            _counts,
            batch_options=("to",),
        ),
        BatchVerb(
            "skin",
            "skincap.workflows.skin_file:skin_file",
            (".bvh",),
            _plan_skin,
            _skin_figures,
            kernels=("skinning.lbs", "skinning.dqs"),
            batch_options=("to", "mesh"),
            check=_check_skin,
        ),
        BatchVerb(
            "animate",
            "skincap.workflows.animate_file:animate_file",
            (".c3d", ".trc", ".csv"),
            _plan_animate,
            _animate_figures,
            kernels=("dense",),
            batch_options=("to", "mesh"),
            check=_check_animate,
        ),
    )
}


def batch_verb(name: str) -> BatchVerb:
    """The :class:`BatchVerb` called ``name`` (ValidationError naming the choices)."""
    try:
        return BATCH_VERBS[name]
    except KeyError:
        raise ValidationError(
            f"verb: expected one of {', '.join(BATCH_VERBS)}, got {name!r}"
        ) from None
