"""``skincap solve``, ``skincap eval solve`` and ``skincap bench solve``.

Registered on :data:`skincap.cli._app.app` / ``eval_app`` / ``bench_app`` when
:mod:`skincap.cli` is imported. Heavy imports stay inside the commands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli._app import (
    _user_errors,
    app,
    bench_app,
    check_seed,
    eval_app,
    out,
    print_bench_results,
    print_json,
    stage_progress,
)
from skincap.cli._options import (
    BenchJsonOption,
    EvalJsonOption,
    ForceOption,
    OutputFolderOption,
    SynthFramesOption,
    SynthVerticesOption,
)
from skincap.errors import FormatError, ValidationError


@app.command()
def solve(
    input_file: Annotated[Path, typer.Argument(help="Labelled markers: .c3d, .trc or .csv.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="The solved motion, .bvh.")],
    template: Annotated[
        str,
        typer.Option(
            help="Marker set: pig, cmu41, synth-sparse, synth-dense, aml62, auto (found "
            "from the markers' motion) or a template JSON file."
        ),
    ] = "cmu41",
    units: Annotated[str, typer.Option(help="Length unit of the BVH (m, cm, mm, in).")] = "cm",
    markers_out: Annotated[
        Path | None,
        typer.Option("--markers-out", help="Write the model's markers per frame (.c3d/.trc/.csv)."),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(
            help="Write a JSON report: per-marker and per-frame RMS residuals, the "
            "joint-centre method per joint, bone lengths."
        ),
    ] = None,
    smooth_hz: Annotated[
        float | None,
        typer.Option(
            "--smooth-hz",
            help="Low-pass the solved poses at this cut-off (Hz, zero-phase Butterworth); "
            "default: none.",
        ),
    ] = None,
    loss: Annotated[
        str,
        typer.Option(
            help="IK loss of each marker's residual: squared, huber or cauchy (robust: a "
            "marker that slides or is mislabelled in some frames pulls its segment less; "
            "its own residual then grows)."
        ),
    ] = "squared",
    loss_scale_cm: Annotated[
        float,
        typer.Option("--loss-scale-cm", help="Scale of the robust loss, cm."),
    ] = 2.0,
    refine_offsets: Annotated[
        int,
        typer.Option(
            "--refine-offsets",
            help="Rounds of re-fitting the markers' offsets to the solved poses, each "
            "followed by another IK (0: keep the calibration's; at most 20).",
        ),
    ] = 1,
    joint_limits: Annotated[
        bool,
        typer.Option(
            "--joint-limits",
            help="Hold the joints within the template's limits (the built-in templates: "
            "knee and elbow flexion).",
        ),
    ] = False,
    keep_jumps: Annotated[
        bool,
        typer.Option(
            "--keep-jumps",
            help="Fit every sample, even a piece of a track that jumps off its segment "
            "and back (a swapped label); by default such samples are left out and listed "
            "in the report.",
        ),
    ] = False,
    force: ForceOption = False,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the summary as JSON (counts, residuals, files).")
    ] = False,
) -> None:
    """Solve a skeleton from labelled markers: joint centres, inverse kinematics, BVH.

    Calibrates on the take itself (SCoRE/SARA functional joint centres where the
    joints move enough, the template's regression otherwise, with a warning), then
    fits every frame by least squares over the markers it sees. The BVH has the
    Biovision hierarchy and names, Y up, so `skincap skin MESH OUT.bvh` plays it.

    Example: skincap solve walk.c3d -o walk.bvh --template cmu41 --report walk.json
    """
    from skincap.io.output_safety import guard_outputs
    from skincap.workflows.solve import solve_file

    outputs = [p for p in (output, markers_out, report) if p is not None]
    with _user_errors():
        options = solve_workflow_options(
            template,
            units,
            smooth_hz,
            loss,
            loss_scale_cm,
            refine_offsets,
            joint_limits,
            keep_jumps,
        )
    with _user_errors(), guard_outputs([input_file], outputs, force=force):
        with stage_progress("calibration") as advance:
            summary = solve_file(
                input_file,
                output,
                markers_out=markers_out,
                report=report,
                force=force,
                progress=advance,
                **options,
            )
    if json_output:
        print_json(summary)
        return
    _print_solve_summary(input_file, output, summary)


def solve_workflow_options(
    template: str,
    units: str,
    smooth_hz: float | None,
    loss: str,
    loss_scale_cm: float,
    refine_offsets: int,
    joint_limits: bool,
    keep_jumps: bool,
) -> dict[str, Any]:
    """``solve``'s options as :func:`solve_file`'s keywords (shared with ``batch solve``).

    Raises
    ------
    FormatError
        An unknown ``--units`` (checked before the solve: the BVH writer's own error
        would name the output).
    """
    from skincap.io.bvh.units import BVH_UNITS

    if units not in BVH_UNITS:
        raise FormatError(
            "--units", f"unknown BVH length unit {units!r}, expected one of {sorted(BVH_UNITS)}"
        )
    return {
        "template": template,
        "units": units,
        "smooth_hz": smooth_hz,
        "loss": loss,
        "loss_scale_m": loss_scale_cm / 100.0,
        "refine_offsets": refine_offsets,
        "joint_limits": joint_limits,
        "reject_jumps": not keep_jumps,
    }


def _print_solve_summary(input_file: Path, output: Path, summary: dict[str, Any]) -> None:
    """One line for ``skincap solve``: frames, joints, markers, residuals, left-out samples."""
    out.print(
        f"{input_file} -> {output}: {summary['frames']} frames, {summary['joints']} joints, "
        f"{summary['markers']} markers ({summary['template']}), RMS residual "
        f"{summary['rms_m'] * 100:.2f} cm, max {summary['max_m'] * 100:.2f} cm"
        + (f", {summary['rejected']} jumped samples left out" if summary["rejected"] else "")
        + (f", {summary['off_body']} off-body samples left out" if summary["off_body"] else ""),
        markup=False,
        soft_wrap=True,
    )


@eval_app.command("solve")
def eval_solve(
    input_dir: Annotated[
        Path | None,
        typer.Argument(
            help="A folder written by 'skincap synth --markers sparse' or '--markers dense' "
            "(solved with synth-sparse or synth-dense, whichever its labels match)."
        ),
    ] = None,
    output: OutputFolderOption = Path("eval_solve"),
    synth: Annotated[
        str | None,
        typer.Option(
            "--synth", help="A clip (flex, squat, punch...) or .bvh: make a sparse take in memory."
        ),
    ] = None,
    real: Annotated[
        list[Path] | None, typer.Option("--real", help="A real labelled capture (repeatable).")
    ] = None,
    template: Annotated[str, typer.Option(help="Template of the --real captures.")] = "cmu41",
    frames: SynthFramesOption = 600,
    vertices: SynthVerticesOption = 8000,
    seed: Annotated[int, typer.Option(help="Seed of a --synth take.")] = 0,
    force: ForceOption = False,
    json_output: EvalJsonOption = False,
) -> None:
    """Measure the solver against issue #17's targets and print the table.

    On a synthetic sparse or dense take (perfectly labelled, with the capture's occlusion,
    noise and soft tissue): joint-position error per joint against truth/motion.bvh,
    knee/elbow flexion-angle error, marker residual, --template auto. On real captures:
    the marker residual and its distribution per marker. Writes DIR/solve_eval.json.

    Example: skincap eval solve take1 --real walk.c3d -o eval_solve
    """
    from skincap.io.output_safety import guard_outputs
    from skincap.workflows.solve import evaluate_solve

    inputs = [input_dir, *(real or [])]
    with (
        _user_errors(),
        guard_outputs(inputs, [output / "solve_eval.json"], folders=[output], force=force),
    ):
        if input_dir is not None and synth is not None:
            raise ValidationError("give a synth folder or --synth, not both")
        check_seed(seed)
        with stage_progress("eval solve") as advance:
            result = evaluate_solve(
                output, synth_dir=input_dir, synth_motion=synth, real=list(real or []),
                real_template=template, frames=frames, vertices=vertices, seed=seed,
                force=force, progress=advance,
            )  # fmt: skip
    if json_output:
        print_json(result)
        return
    from rich.table import Table

    table = Table(title="skeleton solving against issue #17's targets", title_justify="left")
    for col in ("measure", "measured", "target", "met"):
        table.add_column(col)
    for row in result["table"]:
        table.add_row(row["measure"], row["measured"], row["target"], row["met"])
    out.print(table)
    syn = result.get("synthetic")
    if syn:
        per = ", ".join(f"{k} {v['mean_m'] * 1000:.0f}" for k, v in syn["joint_errors"].items())
        out.print(f"joint error per joint (mm, mean): {per}", markup=False, soft_wrap=True)
    out.print(f"wrote {result['outputs'][0]}", markup=False, soft_wrap=True)


@bench_app.command("solve")
def bench_solve(
    input_file: Annotated[
        Path | None,
        typer.Argument(help="A labelled capture (default: a synthetic 41-marker take)."),
    ] = None,
    template: Annotated[str, typer.Option(help="Template of INPUT.")] = "cmu41",
    frames: Annotated[int, typer.Option(help="Frames of the synthetic take (120 Hz).")] = 600,
    json_output: BenchJsonOption = False,
) -> None:
    """IK frames per second (and against SciPy frame by frame), and a one-minute C3D -> BVH solve.

    Example: skincap bench solve walk.c3d --template cmu41
    """
    from skincap.evaluate.bench.solve import run_solve_benchmark
    from skincap.workflows.solve import read_labelled_markers, synth_take_in_memory

    with _user_errors():
        if input_file is None:
            markers, _ = synth_take_in_memory("punch", frames=frames, vertices=8000, seed=0)
            template = "synth-sparse"
        else:
            markers = read_labelled_markers(input_file)
        results = run_solve_benchmark(markers, template=template)
    print_bench_results(results, json_output)
