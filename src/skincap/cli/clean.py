"""``skincap clean`` and ``skincap eval fill``: the marker-cleanup verbs.

Registered on :data:`skincap.cli._app.app` / :data:`skincap.cli._app.eval_app` when
:mod:`skincap.cli` is imported. Heavy imports stay inside the commands.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from skincap.cleanup.methods import FILL_METHODS
from skincap.cli._app import _user_errors, app, bench_app, err, eval_app, out, print_bench_results
from skincap.errors import FormatError

if TYPE_CHECKING:
    import numpy as np

    from skincap.cleanup.surface import MarkerSurface
    from skincap.types import MarkerSet


# -------------------------------------------------------------------------- clean
def _read_edge_csv(path: Path, labels: list[str]) -> np.ndarray:
    """Edge list CSV: one ``label_a,label_b`` pair per line (an optional header line)."""
    import numpy as np

    from skincap.io._common import check_readable

    check_readable(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not UTF-8 text (byte {exc.start})", offset=exc.start) from None
    index = {lab: i for i, lab in enumerate(labels)}
    pairs: list[tuple[int, int]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        cells = [c.strip() for c in line.split(",")]
        if not line.strip():
            continue
        if len(cells) != 2:
            raise FormatError(path, f"expected two labels per line, got {len(cells)}", line=number)
        if cells[0] not in index or cells[1] not in index:
            if number == 1 and not pairs:
                continue  # a header line
            unknown = cells[0] if cells[0] not in index else cells[1]
            raise FormatError(path, f"unknown marker label {unknown!r}", line=number)
        pairs.append((index[cells[0]], index[cells[1]]))
    if not pairs:
        raise FormatError(path, "no edges")
    return np.asarray(pairs, dtype=np.int64)


def _read_surface(path: Path, markers: MarkerSet, reference_frame: int | None) -> MarkerSurface:
    """A user marker surface over the labelled columns: PLY/OBJ triangles or an edge CSV.

    Mesh vertices are matched to the labelled markers by order when the counts agree,
    else each vertex to the nearest labelled marker in the reference frame (each
    marker at most once, within 5 cm).
    """
    import numpy as np
    from scipy.spatial import cKDTree

    from skincap import io
    from skincap.cleanup.surface import (
        choose_reference_frame,
        surface_from_edges,
        surface_from_faces,
    )

    labelled = [i for i, lab in enumerate(markers.labels) if not str(lab).startswith("*")]
    if not labelled:
        raise FormatError(path, "the capture has no labelled markers to put a surface on")
    pos = markers.positions[:, labelled]
    frame = choose_reference_frame(pos) if reference_frame is None else reference_frame
    if not 0 <= frame < markers.n_frames:
        raise FormatError(path, f"--reference-frame {frame} is outside 0..{markers.n_frames - 1}")
    ref = pos[frame]
    ext = path.suffix.lower()
    if ext == ".csv":
        labels = [str(markers.labels[i]) for i in labelled]
        return surface_from_edges(_read_edge_csv(path, labels), ref, reference_frame=frame)
    if ext not in (".ply", ".obj"):
        raise FormatError(path, f"a surface is a .ply, .obj or edge-list .csv, not {ext!r}")
    mesh = io.read(path)
    if not hasattr(mesh, "faces"):
        raise FormatError(path, "not a mesh")
    if mesh.n_vertices == len(labelled):
        vertex_to_marker = np.arange(mesh.n_vertices)
    else:
        ok = np.isfinite(ref).all(axis=1)
        if ok.sum() < mesh.n_vertices:
            raise FormatError(
                path,
                f"{mesh.n_vertices} vertices but only {int(ok.sum())} labelled markers "
                f"in reference frame {frame}",
            )
        rows = np.flatnonzero(ok)
        dist, near = cKDTree(ref[rows]).query(mesh.vertices)
        vertex_to_marker = rows[near]
        if np.unique(vertex_to_marker).size != vertex_to_marker.size or np.any(dist > 0.05):
            raise FormatError(
                path,
                "surface vertices do not match the markers one to one (by order or within "
                f"5 cm in reference frame {frame})",
            )
    faces = vertex_to_marker[mesh.faces]
    return surface_from_faces(faces, ref, reference_frame=frame)


def _read_fragment_truth(path: Path) -> dict[str, str]:
    """``fragment,truth`` CSV (``skincap synth``'s truth/fragments.csv): label -> true label."""
    from skincap.io._common import check_readable

    check_readable(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not UTF-8 text (byte {exc.start})", offset=exc.start) from None
    truth: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != 2 or not cells[0] or not cells[1]:
            raise FormatError(path, "expected 'fragment,truth' on every line", line=number)
        if number == 1 and cells == ["fragment", "truth"]:
            continue
        truth[cells[0]] = cells[1]
    if not truth:
        raise FormatError(path, "no fragment rows")
    return truth


def _write_json(path: Path, data: dict[str, Any], *, force: bool) -> None:
    from skincap.io._common import atomic_output

    with atomic_output(path, force=force) as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")


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
    surface: Annotated[
        Path | None,
        typer.Option(help="User marker surface: PLY/OBJ over the markers or an edge-list CSV."),
    ] = None,
    no_smooth: Annotated[
        bool, typer.Option("--no-smooth", help="Skip the local-frame smoothing.")
    ] = False,
    lam: Annotated[float, typer.Option("--lambda", help="Smoothing damping λ.")] = 0.02,
    iterations: Annotated[int, typer.Option(help="Smoothing iterations.")] = 10,
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
    force: Annotated[bool, typer.Option("--force", help="Replace existing outputs.")] = False,
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
    from skincap.io.output_safety import guard_outputs

    inputs = [src, surface, fragment_truth]
    outputs = [output] if report is None else [output, report]
    with _user_errors(), guard_outputs(inputs, outputs, force=force):
        from rich.progress import Progress

        from skincap import io
        from skincap.cleanup.pipeline import clean_markers
        from skincap.types import MarkerSet

        if method not in FILL_METHODS:
            raise FormatError(output, f"--method must be one of {', '.join(FILL_METHODS)}")
        if rigid_blend is not None and not 0.0 <= rigid_blend <= 1.0:
            raise FormatError("--rigid-blend", f"expected a weight in [0, 1], got {rigid_blend}")
        if output.suffix.lower() != ".c3d":
            raise FormatError(output, "the cleaned capture is written as .c3d")
        markers = io.read(src)
        if not isinstance(markers, MarkerSet):
            raise FormatError(src, "not a marker capture (labelled trajectories)")
        if markers.n_frames == 0:
            raise FormatError(src, "no frames")
        if reference_frame is not None and not 0 <= reference_frame < markers.n_frames:
            raise FormatError(
                src, f"--reference-frame {reference_frame} is outside 0..{markers.n_frames - 1}"
            )
        user_surface = None if surface is None else _read_surface(surface, markers, reference_frame)
        truth = None if fragment_truth is None else _read_fragment_truth(fragment_truth)
        with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task("cleaning", total=1.0)

            def progress(fraction: float, label: str) -> None:
                bar.update(task, completed=fraction, description=label)

            cleaned, summary = clean_markers(
                markers,
                method=method,
                rigid_blend=rigid_blend,
                reference_frame=reference_frame,
                surface=user_surface,
                smooth=not no_smooth,
                lam=lam,
                iterations=iterations,
                fragment_truth=truth,
                recover_hidden=not no_hidden,
                progress=progress,
            )
        summary["input"] = str(src)
        summary["output"] = str(output)
        io.write(cleaned, output, force=force)
        if report is not None:
            _write_json(report, summary, force=force)
    if json_output:
        print(json.dumps(clean_summary(summary), indent=2))
    else:
        out.print(format_clean_summary(summary), markup=False, soft_wrap=True)


def clean_summary(report: dict[str, Any]) -> dict[str, Any]:
    """The figures of ``clean``'s summary line, as a dict (what ``--json`` prints)."""
    merge, guard = report["merge"], report["guard"]
    return {
        "input": report["input"],
        "output": report["output"],
        "frames": report["frames"],
        "trajectories_before": merge["trajectories_before"],
        "trajectories_after": merge["trajectories_after"],
        "fragments_merged": merge["merged"],
        "filled_samples": guard["filled_samples"],
        "unfilled_samples": guard["unfilled_samples"],
        "unfilled_warning": guard["unfilled_warning"],
        "outlier_samples": guard["outlier_samples"],
        "outliers_replaced": guard["outliers_replaced"],
        "relabelled_fragments": guard["relabelled_fragments"],
        "label_swaps_repaired": guard["label_swaps_repaired"],
        "largest_move_mm": guard["largest_move_mm"],
        "hidden_markers_labelled": report["hidden"]["new_markers"],
        "wrongly_merged": merge["wrongly_merged"],
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
    force: Annotated[bool, typer.Option("--force", help="Replace existing outputs.")] = False,
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
        from skincap.types import MarkerSet

        chosen = None if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
        if chosen is not None:
            unknown = [m for m in chosen if m not in FILL_METHODS]
            if unknown or not chosen:
                raise FormatError(
                    "--methods", f"unknown {unknown}; choose from {', '.join(FILL_METHODS)}"
                )
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


# -------------------------------------------------------------------------- bench
@bench_app.command("clean")
def bench_clean(
    markers: Annotated[int, typer.Option(help="Markers of the synthetic dense take.")] = 350,
    frames: Annotated[
        str, typer.Option(help="Comma-separated take lengths (the last is the headline).")
    ] = "250,500,1000",
    methods: Annotated[str, typer.Option(help="Comma-separated fill methods.")] = "local_pca",
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the measurements as JSON.")
    ] = False,
) -> None:
    """Time the whole clean (and its fill and smoothing) against the linear fill.

    Example: skincap bench clean --markers 350 --frames 250,1000
    """
    with _user_errors():
        from skincap.evaluate.bench.cleanup import run_clean_benchmark

        chosen = [m.strip() for m in methods.split(",") if m.strip()]
        unknown = [m for m in chosen if m not in FILL_METHODS]
        if unknown or not chosen:
            raise FormatError(
                "--methods", f"unknown {unknown}; choose from {', '.join(FILL_METHODS)}"
            )
        if markers < 4:
            raise FormatError("--markers", "must be at least 4")
        results = run_clean_benchmark(
            n_markers=markers, frames=_int_list(frames, "--frames"), methods=chosen
        )
    print_bench_results(results, json_output)
