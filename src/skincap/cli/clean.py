"""``skincap clean``, ``skincap eval fill`` and ``skincap bench clean``: the marker-cleanup verbs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cleanup.methods import FILL_METHODS
from skincap.cli._app import (
    _user_errors,
    app,
    bench_app,
    check_seed,
    err,
    eval_app,
    out,
    print_bench_results,
    stage_progress,
)
from skincap.cli._options import BenchJsonOption, ForceOption, SurfaceOption
from skincap.errors import FormatError
from skincap.workflows.clean_file import clean_summary

# -------------------------------------------------------------------------- clean
#: ``--rigid-blend``, shared by ``clean`` and ``eval fill``.
RigidBlendOption = Annotated[
    float | None,
    typer.Option(
        help="Local methods: weight of the rigid fill in each filled sample, 0-1 "
        "(0: the paper's local PCA alone). Default: chosen per gap."
    ),
]


@app.command()
def clean(
    src: Annotated[Path, typer.Argument(help="Capture (.c3d/.trc/.csv): labels and *N fragments.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Cleaned C3D to write.")],
    method: Annotated[
        str, typer.Option(help=f"Hole filling: {', '.join(FILL_METHODS)}.")
    ] = "local_pca",
    rigid_blend: RigidBlendOption = None,
    reference_frame: Annotated[
        int | None, typer.Option(help="Reference pose frame (default: most markers present).")
    ] = None,
    surface: SurfaceOption = None,
    no_smooth: Annotated[
        bool, typer.Option("--no-smooth", help="Skip the local-frame smoothing.")
    ] = False,
    lam: Annotated[float, typer.Option("--lambda", help="Smoothing damping λ.")] = 0.02,
    iterations: Annotated[int, typer.Option(help="Smoothing iterations, 1-1000.")] = 10,
    report: Annotated[
        Path | None,
        typer.Option(
            help="JSON report: counts per take and per marker (filled, unfilled, outliers, "
            "relabelled, largest move) and invented [start, end) runs."
        ),
    ] = None,
    fragment_truth: Annotated[
        Path | None,
        typer.Option(
            help="Ground truth 'fragment,truth' CSV (skincap synth's truth/fragments.csv): "
            "the report then counts wrong merges."
        ),
    ] = None,
    no_hidden: Annotated[
        bool,
        typer.Option(
            "--no-hidden",
            help="Do not label markers hidden in the reference frame (new U<n> columns); "
            "their fragments stay unlabelled.",
        ),
    ] = False,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the summary as JSON instead of one line.")
    ] = False,
    force: ForceOption = False,
) -> None:
    """Clean a capture: marker surface, merge fragments into labels, fill holes, smooth.

    Measured samples are kept: smoothing moves one by at most 3x its marker's noise
    (estimated from the take) and never over 1.5 mm. Spikes and label swaps are
    repaired and, like every fill, flagged as invented (all camera bits). A fill that
    would not join its measured ends smoothly or would move faster than the take
    does is left unfilled and counted. The summary line gives samples filled, left
    unfilled, outliers replaced, fragments relabelled and the largest move of a kept
    measured sample (--json: the same as JSON). With --report, a JSON file with the
    surface, Table-1 merge counts, per-marker counts and the invented runs.
    Markers hidden in the reference frame, found among the leftover fragments (they
    ride with a skin neighbourhood over their whole span), come after the labelled
    markers as U<n> columns, named after their longest fragment *<n>.

    Example: skincap clean take.c3d -o take_clean.c3d --report take_clean.json
    """
    from skincap.workflows.clean_file import clean_file

    options = clean_workflow_options(
        method, rigid_blend, reference_frame, surface, no_smooth, lam, iterations, no_hidden
    )
    with _user_errors(), stage_progress("cleaning") as progress:
        summary = clean_file(
            src,
            output,
            report=report,
            fragment_truth=fragment_truth,
            force=force,
            progress=progress,
            **options,
        )
    if json_output:
        print(json.dumps(clean_summary(summary), indent=2))
    else:
        out.print(format_clean_summary(summary), markup=False, soft_wrap=True)


def clean_workflow_options(
    method: str,
    rigid_blend: float | None,
    reference_frame: int | None,
    surface: Path | None,
    no_smooth: bool,
    lam: float,
    iterations: int,
    no_hidden: bool,
) -> dict[str, Any]:
    """``clean``'s options (by their parameter names) as :func:`clean_file`'s keywords;
    ``skincap batch clean`` takes the same options through this."""
    return {
        "method": method,
        "rigid_blend": rigid_blend,
        "reference_frame": reference_frame,
        "surface": surface,
        "smooth": not no_smooth,
        "lam": lam,
        "iterations": iterations,
        "recover_hidden": not no_hidden,
    }


def format_clean_summary(report: dict[str, Any]) -> str:
    """``clean``'s one-line summary: filled, unfilled, outliers, relabelled, largest move."""
    s = clean_summary(report)
    merge = report["merge"]
    line = (
        f"{s['input']} -> {s['output']}: {s['trajectories_before']} -> "
        f"{s['trajectories_after']} trajectories, {s['filled_samples']} samples filled, "
        f"{s['unfilled_samples']} left unfilled"
        + (" (warning: many)" if s["unfilled_warning"] else "")
        + f", {s['outliers_replaced']} of {s['outlier_samples']} outliers replaced, "
        f"{s['relabelled_fragments']} fragments relabelled ({s['fragments_merged']} merged, "
        f"{s['label_swaps_repaired']} swaps repaired), largest move of a kept measured "
        f"sample {s['largest_move_mm']:.2f} mm"
        + (
            f", {s['hidden_markers_labelled']} hidden markers labelled"
            if s["hidden_markers_labelled"]
            else ""
        )
    )
    if merge["wrongly_merged"] is not None:
        line += (
            f"; {merge['wrongly_merged']} wrongly merged ({100 * merge['wrong_rate']:.2f} %), "
            f"{merge['left_unmerged']} body fragments left unmerged "
            f"({merge['left_unmerged_frames']} samples)"
        )
    return line


# ---------------------------------------------------------------------- eval fill
def _int_list(text: str, option: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise FormatError(option, f"expected comma-separated whole numbers, got {text!r}") from None
    if not values or min(values) < 1:
        raise FormatError(option, f"expected positive whole numbers, got {text!r}")
    return values


def _fill_method_list(text: str) -> list[str]:
    """``--methods``: comma-separated names, each one of ``FILL_METHODS``."""
    chosen = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in chosen if m not in FILL_METHODS]
    if unknown or not chosen:
        raise FormatError("--methods", f"unknown {unknown}; choose from {', '.join(FILL_METHODS)}")
    return chosen


@eval_app.command("fill")
def eval_fill(
    src: Annotated[Path, typer.Argument(help="Capture with labelled markers (.c3d/.trc/.csv).")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Folder for fill_eval.json and fill_eval.png.")
    ],
    methods: Annotated[
        str | None,
        typer.Option(help=f"Comma-separated methods (default all: {', '.join(FILL_METHODS)})."),
    ] = None,
    gap_lengths: Annotated[
        str, typer.Option(help="Comma-separated gap lengths in frames.")
    ] = "30,60,90,120",
    gaps: Annotated[int, typer.Option(help="Gaps punched per length.")] = 10,
    simultaneous: Annotated[int, typer.Option(help="Markers removed together per gap.")] = 1,
    rigid_blend: RigidBlendOption = None,
    seed: Annotated[
        int, typer.Option(help="Random seed: the same seed punches the same gaps.")
    ] = 0,
    force: ForceOption = False,
) -> None:
    """Punch gaps into visible data, fill them with every method and score the fills.

    Errors (mean, 95th percentile, maximum, RMSE) in mm and normalised by each
    marker's mean neighbour distance (Park & Hodgins Table 2's unit), per gap length;
    neighbourhoods are the motion-consistent neighbours of each marker. Writes
    OUT/fill_eval.json and OUT/fill_eval.png and prints a table.

    Example: skincap eval fill walk.c3d --methods local_pca,rigid,spline --gaps 5 -o fill_eval
    """
    from skincap.io.output_safety import guard_outputs

    json_path, png_path = output / "fill_eval.json", output / "fill_eval.png"
    with _user_errors(), guard_outputs([src], [json_path, png_path], folders=[output], force=force):
        from rich.progress import Progress
        from rich.table import Table

        from skincap import io
        from skincap.evaluate.cleanup import evaluate_fill, format_fill_table, plot_fill_evaluation
        from skincap.io.json_file import write_json
        from skincap.types import MarkerSet

        check_seed(seed)
        chosen = None if methods is None else _fill_method_list(methods)
        lengths = _int_list(gap_lengths, "--gap-lengths")
        if gaps < 1 or simultaneous < 1:
            raise FormatError("--gaps/--simultaneous", "must be at least 1")
        if rigid_blend is not None and not 0.0 <= rigid_blend <= 1.0:
            raise FormatError("--rigid-blend", f"expected a weight in [0, 1], got {rigid_blend}")
        markers = io.read(src)
        if not isinstance(markers, MarkerSet):
            raise FormatError(src, "not a marker capture (labelled trajectories)")
        labelled = ~markers.unlabelled
        if labelled.sum() < 4:
            raise FormatError(src, f"needs at least 4 labelled markers, has {int(labelled.sum())}")
        markers = markers.select(labelled)
        with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task("evaluating", total=1.0)

            def progress(fraction: float, label: str) -> None:
                bar.update(task, completed=fraction, description=label)

            result = evaluate_fill(
                markers,
                methods=chosen,
                gap_lengths=lengths,
                gaps=gaps,
                simultaneous=simultaneous,
                seed=seed,
                rigid_blend=rigid_blend,
                progress=progress,
            )
        result["input"] = str(src)
        output.mkdir(parents=True, exist_ok=True)
        write_json(json_path, result, force=force)
        plot_fill_evaluation(result, png_path, force=force)
    table = Table(title=f"{src}: punched-gap fill errors", title_justify="left")
    for name in (
        "method",
        "gap",
        "mean mm",
        "p95 mm",
        "max mm",
        "rmse mm",
        "mean/d",
        "max/d",
        "unfilled",
    ):
        if name == "method":
            table.add_column(name, no_wrap=True, min_width=18)
        else:
            table.add_column(name, justify="right")
    for row in format_fill_table(result):
        table.add_row(*row)
    out.print(table)
    best = result["comparison"]
    if best:
        ratios = ", ".join(
            f"{k[9:]} x{v:.2f}" for k, v in best.items() if k.startswith("ratio_to_")
        )
        out.print(
            f"best: {best['best']} (RMSE {best['best_rmse_mm']:.2f} mm; vs {ratios})", markup=False
        )


# -------------------------------------------------------------------------- bench
@bench_app.command("clean")
def bench_clean(
    markers: Annotated[int, typer.Option(help="Markers of the synthetic dense take.")] = 350,
    frames: Annotated[
        str, typer.Option(help="Comma-separated take lengths (the last is the headline).")
    ] = "250,500,1000",
    methods: Annotated[str, typer.Option(help="Comma-separated fill methods.")] = "local_pca",
    json_output: BenchJsonOption = False,
) -> None:
    """Time the whole clean (and its fill and smoothing) against the linear fill.

    Example: skincap bench clean --markers 350 --frames 250,1000
    """
    with _user_errors():
        from skincap.evaluate.bench.cleanup import run_clean_benchmark

        chosen = _fill_method_list(methods)
        if markers < 4:
            raise FormatError("--markers", "must be at least 4")
        results = run_clean_benchmark(
            n_markers=markers, frames=_int_list(frames, "--frames"), methods=chosen
        )
    print_bench_results(results, json_output)
