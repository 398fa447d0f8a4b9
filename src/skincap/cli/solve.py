"""``skincap solve``, ``skincap eval solve`` and ``skincap bench solve``.

Registered on :data:`skincap.cli._app.app` / ``eval_app`` / ``bench_app`` when
:mod:`skincap.cli` is imported. Heavy imports stay inside the commands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli._app import _user_errors, app, err, out, print_json


def _percent_progress() -> Any:
    """A transient progress bar on stderr in percent (hidden off a terminal)."""
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    )


@app.command()
def solve(
    input_file: Annotated[Path, typer.Argument(help="Labelled markers: .c3d, .trc or .csv.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="The solved motion, .bvh.")],
    template: Annotated[
        str,
        typer.Option(
            help="Marker set: pig, cmu41, synth-sparse, aml62, auto (found from the "
            "markers' motion) or a template JSON file."
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
    force: Annotated[bool, typer.Option("--force", help="Replace existing outputs.")] = False,
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
    with _user_errors(), guard_outputs([input_file], outputs, force=force):
        with _percent_progress() as progress:
            task = progress.add_task("calibration", total=100.0)

            def advance(fraction: float, label: str) -> None:
                progress.update(task, completed=100.0 * fraction, description=label)

            summary = solve_file(
                input_file,
                output,
                template=template,
                units=units,
                markers_out=markers_out,
                report=report,
                force=force,
                progress=advance,
            )
    if json_output:
        print_json(summary)
        return
    out.print(
        f"{input_file} -> {output}: {summary['frames']} frames, {summary['joints']} joints, "
        f"{summary['markers']} markers ({summary['template']}), RMS residual "
        f"{summary['rms_m'] * 100:.2f} cm, max {summary['max_m'] * 100:.2f} cm",
        markup=False,
        soft_wrap=True,
    )
