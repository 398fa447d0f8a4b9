"""``skincap clean`` and ``skincap eval fill``: the marker-cleanup verbs.

Registered on :data:`skincap.cli.app` / :data:`skincap.cli.eval_app` when
:mod:`skincap.cli` is imported. Heavy imports stay inside the commands.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli import _user_errors, err, eval_app, out
from skincap.errors import FormatError

_CLEAN_METHODS = (
    "local_pca",
    "local_pca_weighted",
    "local_pca_missing",
    "linear",
    "pchip",
    "spline",
    "rigid",
    "pca",
)


def _write_json(path: Path, data: dict[str, Any], *, force: bool) -> None:
    from skincap.io._common import atomic_output

    with atomic_output(path, force=force) as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------- eval fill
def _int_list(text: str, option: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise FormatError(option, f"expected comma-separated whole numbers, got {text!r}") from None
    if not values or min(values) < 1:
        raise FormatError(option, f"expected positive whole numbers, got {text!r}")
    return values


@eval_app.command("fill")
def eval_fill(
    src: Annotated[Path, typer.Argument(help="Capture with labelled markers (.c3d/.trc/.csv).")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Folder for fill_eval.json and fill_eval.png.")
    ],
    methods: Annotated[
        str | None,
        typer.Option(help=f"Comma-separated methods (default all: {', '.join(_CLEAN_METHODS)})."),
    ] = None,
    gap_lengths: Annotated[
        str, typer.Option(help="Comma-separated gap lengths in frames.")
    ] = "30,60,90,120",
    gaps: Annotated[int, typer.Option(help="Gaps punched per length.")] = 10,
    simultaneous: Annotated[int, typer.Option(help="Markers removed together per gap.")] = 1,
    seed: Annotated[
        int, typer.Option(help="Random seed: the same seed punches the same gaps.")
    ] = 0,
    force: Annotated[bool, typer.Option("--force", help="Replace existing outputs.")] = False,
) -> None:
    """Punch gaps into visible data, fill them with every method and score the fills.

    Errors (mean, 95th percentile, maximum, RMSE) in mm and normalised by each
    marker's mean neighbour distance (Park & Hodgins Table 2's unit), per gap length;
    neighbourhoods are the motion-consistent neighbours of each marker. Writes
    OUT/fill_eval.json and OUT/fill_eval.png and prints a table.

    Example: skincap eval fill walk.c3d --methods local_pca,rigid,spline --gaps 5 -o fill_eval
    """
    with _user_errors():
        from rich.progress import Progress
        from rich.table import Table

        from skincap import io
        from skincap.cleanup.evaluate import evaluate_fill, format_fill_table, plot_fill_evaluation
        from skincap.errors import OutputExistsError
        from skincap.types import MarkerSet

        chosen = None if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
        if chosen is not None:
            unknown = [m for m in chosen if m not in _CLEAN_METHODS]
            if unknown or not chosen:
                raise FormatError(
                    "--methods", f"unknown {unknown}; choose from {', '.join(_CLEAN_METHODS)}"
                )
        lengths = _int_list(gap_lengths, "--gap-lengths")
        if gaps < 1 or simultaneous < 1:
            raise FormatError("--gaps/--simultaneous", "must be at least 1")
        if output.exists() and not output.is_dir():
            raise FormatError(output, "exists and is not a folder")
        json_path, png_path = output / "fill_eval.json", output / "fill_eval.png"
        for target in (json_path, png_path):
            if target.exists() and not force:
                raise OutputExistsError(target)
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
                progress=progress,
            )
        result["input"] = str(src)
        output.mkdir(parents=True, exist_ok=True)
        _write_json(json_path, result, force=force)
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
