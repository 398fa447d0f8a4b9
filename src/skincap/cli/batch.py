"""``skincap batch VERB INPUTS... -o OUT``: many takes through one verb on Dask.

Each ``batch`` sub-command takes its verb's own options: its signature is built from
the verb's (the same flags, help and defaults) and the verb module's
``<verb>_workflow_options`` turns them into the workflow's keywords, as the verb
itself does, so the two cannot drift. The options that name one take's files
(``--report``, ``--markers-out``, ``--save-rig``, ``--fragment-truth``) are not
taken: the batch names every take's outputs after its input.
"""

from __future__ import annotations

import inspect
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli import animate as animate_cli
from skincap.cli import clean as clean_cli
from skincap.cli import convert as convert_cli
from skincap.cli import skin as skin_cli
from skincap.cli import solve as solve_cli
from skincap.cli import track as track_cli
from skincap.cli._app import (
    _print_line,
    _user_errors,
    app,
    bench_app,
    err,
    out,
    print_bench_results,
)
from skincap.cli._options import BenchJsonOption, ForceOption

batch_app = typer.Typer(
    help="Run many takes through one verb on Dask (local processes or a cluster).",
    no_args_is_help=True,
)
app.add_typer(batch_app, name="batch")

_Inputs = Annotated[
    list[Path],
    typer.Argument(
        metavar="INPUTS",
        help="Takes: files, folders (their takes, not recursive) or quoted glob patterns "
        "('caps/**/*.c3d').",
        show_default=False,
    ),
]
_Output = Annotated[
    Path,
    typer.Option(
        "-o",
        "--output",
        help="Output folder: each take's outputs named after its input, batch.json, batch.csv.",
    ),
]
_Workers = Annotated[
    int | None,
    typer.Option(
        help="Worker processes of the local cluster (default: the core count; never more "
        "than the takes to run)."
    ),
]
_Scheduler = Annotated[
    str | None,
    typer.Option(
        help="tcp://host:port of a running Dask scheduler (its workers see the same files), "
        "or 'synchronous': one take after another in this process."
    ),
]
_BatchJson = Annotated[
    bool, typer.Option("--json", help="Print the rows as JSON instead of the table.")
]
_To = Annotated[str, typer.Option("--to", help="Extension of each take's output, e.g. .trc.")]
_MeshOption = Annotated[
    Path | None,
    typer.Option("--mesh", help="The body mesh every take drives (see the verb's MESH)."),
]

_EPILOG = (
    "Exit status: 0 when every take succeeded or was done by an earlier run, 2 when an "
    "input or option was bad (the others still run; each error is one line in the table "
    "and in batch.json), 1 when a take crashed on an unexpected error, 130 on Ctrl-C "
    "(pending takes cancelled, finished ones kept)."
)


def _run(
    verb: str,
    inputs: list[Path],
    output: Path,
    options: dict[str, Any],
    *,
    workers: int | None,
    scheduler: str | None,
    force: bool,
    json_output: bool,
) -> None:
    """Run the batch under a progress bar over takes; print the table; exit with its status."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from skincap.batch import run_batch

    with (
        _user_errors(),
        Progress(
            TextColumn(f"batch {verb}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.description}"),
            console=err,
            transient=True,
            disable=not err.is_terminal,
        ) as bar,
    ):
        task: Any = None

        def progress(done: int, total: int, row: dict[str, Any] | None) -> None:
            nonlocal task
            if task is None:
                task = bar.add_task("", total=total)
            last = "" if row is None else f"{row['name']}: {row['status']}"
            bar.update(task, completed=done, description=last)

        result = run_batch(
            verb,
            inputs,
            output,
            options=options,
            workers=workers,
            scheduler=scheduler,
            force=force,
            progress=progress,
        )
    if json_output:
        import json

        print(json.dumps({"verb": verb, "rows": result.rows}, indent=2, default=str))
    else:
        _print_table(result, output)
    if result.exit_status:
        raise typer.Exit(result.exit_status)


#: Figures per take the console table shows.
_TABLE_FIGURES = 5


def _print_table(result: Any, output: Path) -> None:
    from rich.table import Table

    table = Table(title=f"batch {result.verb}", title_justify="left")
    for name in ("take", "status", "s", "cpu s", "figures / error"):
        table.add_column(name, justify="right" if name in ("s", "cpu s") else "left")
    for row in result.rows:
        # the first figures only: every one is in batch.json and batch.csv
        shown = list(row.get("figures", {}).items())[:_TABLE_FIGURES]
        figures = ", ".join(f"{k} {_short(v)}" for k, v in shown)
        table.add_row(
            row["name"],
            row["status"],
            "" if row.get("seconds") is None else f"{row['seconds']:.1f}",
            "" if row.get("cpu_seconds") is None else f"{row['cpu_seconds']:.1f}",
            row["error"] or figures,
        )
    out.print(table)
    for row in result.rows:  # each take's warnings and error whole, on one line each
        for text in row.get("warnings", []):
            said = text if text.startswith(row["input"]) else f"{row['input']}: {text}"
            _print_line(f"skincap: warning: {said}")
        if row["error"]:
            _print_line(f"skincap: error: {row['error']}")
    counts = {s: result.count(s) for s in ("done", "skipped", "failed", "crashed", "cancelled")}
    said = ", ".join(f"{n} {s}" for s, n in counts.items() if n)
    out.print(
        f"{len(result.rows)} takes: {said}; rows in {output / 'batch.json'} and "
        f"{output / 'batch.csv'}",
        markup=False,
        soft_wrap=True,
    )


def _short(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _batch_command(
    verb: str,
    verb_command: Callable[..., Any],
    to_workflow_options: Callable[..., dict[str, Any]],
    *,
    extra: dict[str, tuple[Any, Any]] | None = None,
    writes: str,
    example: str,
) -> None:
    """Register ``batch <verb>``: the batch options, then the verb's own options.

    ``to_workflow_options`` names (by its parameters) the verb options the batch takes;
    their flags, help and defaults are read from ``verb_command``'s signature.
    ``extra`` adds batch-only options: name -> (annotation, default).
    """
    hints = typing.get_type_hints(verb_command, include_extras=True)
    verb_params = inspect.signature(verb_command).parameters
    shared = list(inspect.signature(to_workflow_options).parameters)
    extra = extra or {}
    kw = inspect.Parameter.KEYWORD_ONLY
    params = [
        inspect.Parameter("inputs", kw, annotation=_Inputs),
        inspect.Parameter("output", kw, annotation=_Output),
        inspect.Parameter("workers", kw, annotation=_Workers, default=None),
        inspect.Parameter("scheduler", kw, annotation=_Scheduler, default=None),
        *(inspect.Parameter(n, kw, annotation=a, default=d) for n, (a, d) in extra.items()),
        *(
            inspect.Parameter(n, kw, annotation=hints[n], default=verb_params[n].default)
            for n in shared
        ),
        inspect.Parameter("force", kw, annotation=ForceOption, default=False),
        inspect.Parameter("json_output", kw, annotation=_BatchJson, default=False),
    ]

    def command(**values: Any) -> None:
        with _user_errors():
            options = to_workflow_options(**{n: values[n] for n in shared})
        options.update({n: values[n] for n in extra})
        _run(
            verb,
            values["inputs"],
            values["output"],
            options,
            workers=values["workers"],
            scheduler=values["scheduler"],
            force=values["force"],
            json_output=values["json_output"],
        )

    summary = (inspect.getdoc(verb_command) or "").splitlines()[0]
    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params}
    command.__doc__ = (
        f"Many takes through '{verb}': {summary[0].lower()}{summary[1:]}\n\n"
        f"Writes, per take (named after its input), {writes}; and DIR/batch.json, "
        f"DIR/batch.csv: a row per take (status, seconds, outputs, the error, key figures). "
        f"Takes run on local worker processes (--workers) or a Dask cluster "
        f"(--scheduler); a take whose outputs exist is skipped (resume) unless --force. "
        f"{_EPILOG}\n\nExample: {example}"
    )
    command.__name__ = f"batch_{verb}"
    batch_app.command(verb)(command)


_batch_command(
    "clean",
    clean_cli.clean,
    clean_cli.clean_workflow_options,
    writes="DIR/<take>.c3d and its report DIR/<take>.report.json",
    example="skincap batch clean captures/ -o cleaned --workers 2 (writes cleaned/<take>.c3d "
    "and cleaned/<take>.report.json)",
)
_batch_command(
    "track",
    track_cli.track,
    track_cli.track_workflow_options,
    writes="the folder DIR/<take>/ (rope.c3d, body_points.csv, rope_curve.csv, report.json)",
    example="skincap batch track 'session/*.csv' --rope auto -o tracked (a folder per take)",
)
_batch_command(
    "solve",
    solve_cli.solve,
    solve_cli.solve_workflow_options,
    writes="DIR/<take>.bvh and its report DIR/<take>.report.json",
    example="skincap batch solve cleaned/ --template cmu41 -o solved (<take>.bvh and "
    "<take>.report.json)",
)
_batch_command(
    "convert",
    convert_cli.convert,
    convert_cli.convert_workflow_options,
    extra={"to": (_To, ...)},
    writes="DIR/<take><--to>",
    example="skincap batch convert captures/ --to .trc -o trc",
)
_batch_command(
    "skin",
    skin_cli.skin,
    skin_cli.skin_workflow_options,
    extra={
        "mesh": (Annotated[Path, typer.Option("--mesh", help="The body mesh (skin's MESH).")], ...),
        "to": (_To, ".pc2"),
    },
    writes="DIR/<take><--to> (a .pc2 with its .obj beside it)",
    example="skincap batch skin motions/ --mesh makehuman_base.obj --units cmu -o skinned",
)
_batch_command(
    "animate",
    animate_cli.animate,
    animate_cli.animate_workflow_options,
    extra={"mesh": (_MeshOption, None), "to": (_To, ".pc2")},
    writes="DIR/<take><--to> (a .pc2 with its .obj beside it) and DIR/<take>.report.json",
    example="skincap batch animate takes/ --rig subject.npz -o animated",
)


# -------------------------------------------------------------------------- bench
@bench_app.command("batch")
def bench_batch(
    takes: Annotated[
        int, typer.Option(help="Takes in the batch (copies of the real captures).")
    ] = 4,
    workers: Annotated[int, typer.Option(help="Worker processes of the local cluster.")] = 2,
    json_output: BenchJsonOption = False,
) -> None:
    """Time N takes of 'clean' on a local cluster against the same N one after another.

    Both runs in this process's period, on the same inputs (the shipped real captures,
    copied); prints the wall-clock ratio (the batch's speed-up) and the CPU seconds.

    Example: skincap bench batch --takes 4 --workers 2
    """
    with _user_errors():
        from skincap.batch.bench import run_batch_benchmark

        results = run_batch_benchmark(n_takes=takes, workers=workers)
    print_bench_results(results, json_output)
