"""``skincap demo``: the whole chain on data skincap makes and ships, and report.html."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from skincap.cli._app import _user_errors, app, err, out
from skincap.cli._options import ForceOption


@app.command()
def demo(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Folder for the demo's outputs.")
    ] = Path("skincap-demo"),
    frames: Annotated[
        int, typer.Option(help="Frames of the synthetic take at 120 Hz (>= 240).")
    ] = 480,
    force: ForceOption = False,
) -> None:
    """Run the whole chain on data skincap makes and ships, and write report.html.

    Generates a synthetic jump-rope capture with exact truth, cleans it, finds and
    tracks the rope, skins the shipped MakeHuman body with a real CMU walk (DQS),
    converts the shipped real captures, and writes every output plus an HTML report
    (missing-data maps, fill and rope gap-repair errors, artefact table, timings,
    rendered frames). Prints the `skincap view` command that shows the result.

    Example: skincap demo -o demo-out
    """
    from skincap.workflows.demo import run_demo

    with _user_errors():
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        columns = (TextColumn("{task.description:<28}"), BarColumn(), TimeElapsedColumn())
        with Progress(
            *columns, console=err, transient=True, disable=not err.is_terminal
        ) as progress:
            task = progress.add_task("demo", total=1.0)

            def report(fraction: float, label: str) -> None:
                progress.update(task, completed=fraction, description=label)

            result = run_demo(output, force=force, frames=frames, progress=report)
    figures = result["figures"]
    cl, tr = figures["cleanup"], figures["tracking"]
    verdict = figures["fill_verdict"]
    if verdict is None:
        fill_line = "  gap fill: no method filled the punched gaps"
    else:
        # the same targets, and so the same verdict, as the report's red and green marks
        from skincap.workflows.demo_report import FILL_TARGET_MAX, FILL_TARGET_MEAN

        fill_line = (
            f"  gap fill{' against the truth' if 'fill_verdict_measured' in figures else ''}, "
            f"lowest error: {verdict['method']}, mean {verdict['mean_normalised']:.4f} "
            f"x mean neighbour distance ({verdict['mean_mm']:.2f} mm), max "
            f"{verdict['max_normalised']:.3f}: "
            + ("meets" if verdict["meets_targets"] else "misses")
            + f" the targets (mean <= {FILL_TARGET_MEAN}, max <= {FILL_TARGET_MAX})"
        )
        measured = figures.get("fill_verdict_measured")
        if measured is not None:
            fill_line += (
                f"; against the noisy measured samples: {measured['method']}, "
                f"mean {measured['mean_normalised']:.4f}, max {measured['max_normalised']:.3f}"
            )
    sv = figures["solve"]
    lines = [
        f"demo: {len(result['outputs'])} files in {output} ({figures['total_seconds']:.0f} s, "
        f"{figures['total_cpu_seconds']:.0f} s of CPU)",
        f"  cleanup: {cl['merged']} fragments merged, {cl['wrongly_merged']} wrongly "
        f"({cl['wrong_rate'] * 100:.2f} %); {cl['invented_samples']} samples filled; "
        f"labelled trajectories {cl['labelled_missing_before'] * 100:.1f} % -> "
        f"{cl['labelled_missing_after'] * 100:.1f} % missing",
        fill_line,
        f"  rope: {tr['rope_markers_found']} markers tracked, rope/body F1 {tr['f1']:.3f}",
        f"  real capture {sv['capture']}: {sv['joints']}-joint skeleton solved, marker residual "
        f"RMS {sv['rms_cm']:.2f} cm, max {sv['max_cm']:.2f} cm; body skinned in {sv['glb']}",
        f"  report: {result['report']}",
        "Look at it in the browser (raw against cleaned capture with the rope; the walk; the solved body):",
        *(f"  {command}" for command in result["view"]),
    ]
    for line in lines:
        out.print(line, markup=False, soft_wrap=True)
