"""``skincap track``, ``skincap eval track`` and ``skincap bench track``: the rope-tracking verbs."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli._app import (
    _user_errors,
    app,
    bench_app,
    check_seed,
    err,
    eval_app,
    frame_bar,
    out,
    print_bench_results,
    print_json,
)
from skincap.cli._options import (
    BenchJsonOption,
    EvalJsonOption,
    ForceOption,
    OutputFolderOption,
    RepeatOption,
    SynthFramesOption,
    SynthVerticesOption,
)
from skincap.errors import ValidationError


# ------------------------------------------------------------------------- track
def _parse_numbers(text: str, option: str, *, count: int | None, kind: type) -> list[Any]:
    try:
        values = [kind(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise ValidationError(f"{option}: expected comma-separated numbers, got {text!r}") from None
    if count is not None and len(values) != count:
        raise ValidationError(f"{option}: expected {count} numbers, got {len(values)}")
    return values


def track_workflow_options(
    rope_box: str | None, rope_markers: str | None, rope: str | None, window: float
) -> dict[str, Any]:
    """``track``'s options, checked, as :func:`track_file`'s keywords (shared with
    ``batch track``).

    Raises
    ------
    ValidationError
        Not exactly one rope selection, a malformed box or index list, a bad window.
    """
    if not (math.isfinite(window) and window > 0):  # before the rope checks: -1, nan, inf
        raise ValidationError(f"--window: expected seconds > 0, got {window:g}")
    given = [rope_box is not None, rope_markers is not None, rope is not None]
    if sum(given) != 1:
        raise ValidationError("give exactly one of --rope-box, --rope-markers or --rope auto")
    if rope is not None and rope != "auto":
        raise ValidationError(f"--rope: the only choice is 'auto', got {rope!r}")
    box = None if rope_box is None else _parse_numbers(rope_box, "--rope-box", count=6, kind=float)
    idx = (
        None
        if rope_markers is None
        else _parse_numbers(rope_markers, "--rope-markers", count=None, kind=int)
    )
    return {"box": box, "markers": idx, "auto": rope is not None, "window_seconds": window}


@app.command()
def track(
    input_file: Annotated[
        Path, typer.Argument(help="Long points CSV, OptiTrack CSV, or C3D of '*N' points.")
    ],
    output: OutputFolderOption,
    rope_box: Annotated[
        str | None,
        typer.Option(help="x0,y0,z0,x1,y1,z1 (metres, Y up): frame-0 points in the box."),
    ] = None,
    rope_markers: Annotated[
        str | None, typer.Option(help="Indices of the rope's points among frame 0's points.")
    ] = None,
    rope: Annotated[
        str | None, typer.Option(help="'auto': find the rope as a still chain of points.")
    ] = None,
    window: Annotated[
        float, typer.Option(help="Seconds at the start where the rope hangs still.")
    ] = 0.5,
    force: ForceOption = False,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the summary as JSON (counts, written files).")
    ] = False,
) -> None:
    """Separate a rope from the body in un-indexed points and track it (Porter 2012).

    Writes DIR/rope.c3d (rope_00… in order, invented samples flagged),
    DIR/body_points.csv (the points the rope did not take), DIR/rope_curve.csv
    (the rope resampled per frame) and DIR/report.json. Select the rope in frame 0
    with exactly one of --rope-box, --rope-markers or --rope auto.

    Example: skincap track capture_points.csv --rope auto -o tracked
    """
    from skincap.workflows.track_file import OUTPUT_NAMES, track_file

    outputs = [output / name for name in OUTPUT_NAMES]
    with _user_errors(), frame_bar("tracking the rope") as advance:
        options = track_workflow_options(rope_box, rope_markers, rope, window)
        report = track_file(input_file, output, force=force, progress=advance, **options)
    if json_output:
        print_json(
            {
                "input": str(input_file),
                "outputs": [str(p) for p in outputs],
                "frames": report["frames"],
                "rope_markers": len(report["rope_markers"]),
                "rope_points": report["rope_points"],
                "invented_samples": report["invented_samples"],
                "lost_traces": len(report["lost_traces"]),
                "lost": report["lost_traces"],
            }
        )
        return
    lost = "; ".join(
        f"{t['marker']} frames " + ", ".join(f"{a}-{b}" for a, b in t["lost_runs"])
        for t in report["lost_traces"]
    )
    out.print(
        f"{input_file} -> {output}: {report['frames']} frames, "
        f"{len(report['rope_markers'])} rope markers, {report['rope_points']} rope points, "
        f"{report['invented_samples']} invented samples, {len(report['lost_traces'])} lost traces"
        + (f" ({lost})" if lost else ""),
        markup=False,
        soft_wrap=True,
    )


# -------------------------------------------------------------------- eval track
_EVAL_OUTPUTS = ("track_eval.json", "track_eval.png")
_DEFAULT_GAPS = "10,20,30,40,50,60,70,80,90,100,110,120"


def _parse_gaps(text: str) -> list[int]:
    try:
        gaps = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise ValidationError(
            f"--gaps: expected frame counts like 10,20,30, got {text!r}"
        ) from None
    if not gaps or min(gaps) < 1:
        raise ValidationError(f"--gaps: expected positive frame counts, got {text!r}")
    return gaps


def _synth_take(rope: str, frames: int, markers: str, vertices: int, seed: int, report: Any) -> Any:
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=vertices, seed=seed)
    motion = build_motion(body, "jumprope", frames=frames, seed=seed)
    return generate_capture(body, motion, markers=markers, rope=rope, seed=seed, progress=report)


def _cm(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.2f}"


def _print_eval_table(result: dict[str, Any]) -> None:
    from rich.table import Table

    rows = result["gap_repair"]
    single = {r["gap"]: r for r in rows.get("single", [])}
    adjacent = {r["gap"]: r for r in rows.get("adjacent", [])}
    table = Table(
        title="gap repair (mean error over the gap, cm; lost/trials)", title_justify="left"
    )
    table.add_column("gap (frames)", justify="right")
    table.add_column("one marker", justify="right")
    table.add_column("lost", justify="right")
    table.add_column("two adjacent", justify="right")
    table.add_column("lost", justify="right")
    for gap in sorted(set(single) | set(adjacent)):
        s, a = single.get(gap), adjacent.get(gap)
        table.add_row(
            str(gap),
            _cm(s["mean_error_m"]) if s else "",
            f"{s['lost']}/{s['trials']}" if s else "",
            _cm(a["mean_error_m"]) if a else "",
            f"{a['lost']}/{a['trials']}" if a else "",
        )
    out.print(table)
    c = result["classification"]
    out.print(
        f"rope/body classification: precision {c['precision']:.4f}, recall {c['recall']:.4f}, "
        f"F1 {c['f1']:.4f} ({c['false_positive']} body points taken, "
        f"{c['false_negative']} rope points missed; {result['followed']} of "
        f"{result['rope_markers']} rope markers tracked)",
        markup=False,
        soft_wrap=True,
    )
    b = result["baseline"]
    out.print(
        f"tracking without hold-back: {100 * b['followed_2cm_fraction']:.1f}% of rope marker "
        f"samples followed within 2 cm; gap trials are drawn where the marker is measured "
        f"(from the take and --seed only, whatever the tracking)",
        markup=False,
        soft_wrap=True,
    )
    for name, t in result["targets"].items():
        mark = {True: "met", False: "NOT met", None: "not evaluated"}[t["met"]]
        value = t["value"]
        shown = "-" if value is None else f"{value:.4g}"
        thesis = f"; thesis {t['thesis']}" if t["thesis"] else ""
        out.print(f"target {name}: {shown} ({t['target']}{thesis}): {mark}", markup=False)


@eval_app.command("track")
def eval_track(
    output: OutputFolderOption,
    input_dir: Annotated[
        Path | None,
        typer.Argument(help="A folder written by 'skincap synth --rope jump|whip'."),
    ] = None,
    synth: Annotated[
        str | None,
        typer.Option("--synth", help="jump or whip: generate a jump-rope take in memory instead."),
    ] = None,
    frames: SynthFramesOption = 600,
    markers: Annotated[
        str, typer.Option(help="Body markers of a --synth take: dense or sparse.")
    ] = "dense",
    vertices: SynthVerticesOption = 6000,
    gaps: Annotated[
        str,
        typer.Option(
            help="Gap sizes in frames, evaluated in order until the tracker loses the marker."
        ),
    ] = _DEFAULT_GAPS,
    starts: Annotated[int, typer.Option(help="Start frames (trials) per gap size and case.")] = 8,
    seed: Annotated[
        int, typer.Option(help="Seed of the start frames (and of a --synth take).")
    ] = 0,
    all_gaps: Annotated[
        bool, typer.Option("--all-gaps", help="Run every gap size, even after the tracker lost it.")
    ] = False,
    json_output: EvalJsonOption = False,
    force: ForceOption = False,
) -> None:
    """Measure rope tracking against ground truth as the thesis does (Fig. 4.4).

    Holds back one rope marker's points, and separately two adjacent markers', for
    gaps of 10, 20, 30, ... frames at seeded start frames until the tracker loses
    them (> 0.5 m off), and measures the repaired positions over the gap; classifies
    every point as rope or body against the truth (precision, recall, F1). Writes
    OUTPUT/track_eval.json and OUTPUT/track_eval.png and prints a table with the
    targets beside the thesis' figures.

    Example: skincap eval track --synth jump --frames 600 --starts 8 -o eval_jump
    """
    from rich.progress import Progress

    from skincap.evaluate.tracking import evaluate_tracking, plot_gap_repair
    from skincap.io.json_file import write_json
    from skincap.io.output_safety import guard_outputs
    from skincap.io.synth_truth import SYNTH_TRACK_INPUTS, read_synth_folder

    paths = [output / name for name in _EVAL_OUTPUTS]
    inputs = [] if input_dir is None else [input_dir / name for name in SYNTH_TRACK_INPUTS]
    with _user_errors(), guard_outputs(inputs, paths, folders=[output], force=force):
        if (input_dir is None) == (synth is None):
            raise ValidationError(
                "give a folder made by skincap synth or --synth jump|whip (one of them)"
            )
        if synth is not None and synth not in ("jump", "whip"):
            raise ValidationError(f"--synth: expected jump or whip, got {synth!r}")
        if markers not in ("dense", "sparse"):
            raise ValidationError(f"--markers: expected dense or sparse, got {markers!r}")
        if frames < 2 or starts < 1:
            raise ValidationError("--frames must be at least 2 and --starts at least 1")
        check_seed(seed)
        gap_sizes = _parse_gaps(gaps)
        with Progress(console=err, transient=True, disable=not err.is_terminal) as progress:
            task = progress.add_task("reading", total=1.0)
            if input_dir is not None:
                cloud, point_truth, truth = read_synth_folder(input_dir)
                source = str(input_dir)
            else:

                def made(fraction: float, label: str) -> None:
                    progress.update(task, completed=0.3 * fraction, description=f"synth: {label}")

                take = _synth_take(synth, frames, markers, vertices, seed, made)
                cloud, point_truth, truth = take.points, take.point_truth, take.truth
                source = f"synth {synth} ({markers} markers, {frames} frames, seed {seed})"
            lo = 0.3 if input_dir is None else 0.05

            def evaluated(fraction: float, label: str) -> None:
                progress.update(task, completed=lo + (1 - lo) * fraction, description=label)

            result = evaluate_tracking(
                cloud,
                point_truth,
                truth,
                gaps=gap_sizes,
                starts=starts,
                seed=seed,
                stop_when_lost=not all_gaps,
                progress=evaluated,
            )
        result = {"source": source, **result}
        output.mkdir(parents=True, exist_ok=True)
        write_json(paths[0], result, force=force, indent=2, allow_nan=False)
        plot_gap_repair(result, paths[1], force=force, title=f"Gap repair: {source}")
    if json_output:
        print_json(result)
        return
    _print_eval_table(result)
    out.print(f"wrote {paths[0]} and {paths[1]}", markup=False, soft_wrap=True)


# ------------------------------------------------------------------- bench track
@bench_app.command("track")
def bench_track(
    frames: Annotated[int, typer.Option(help="Frames of the scene (120 Hz).")] = 1200,
    points: Annotated[int, typer.Option(help="Points per frame (rope and body).")] = 400,
    rope_markers: Annotated[int, typer.Option(help="Tape markers on the rope.")] = 24,
    repeat: RepeatOption = 3,
    json_output: BenchJsonOption = False,
) -> None:
    """track_rope's frames per second against real time and a naive nearest-neighbour tracker.

    Example: skincap bench track --frames 1200 --points 400
    """
    from skincap.evaluate.bench.tracking import run_track_benchmark

    with _user_errors():
        if frames < 2 or rope_markers < 3 or points <= rope_markers or repeat < 1:
            raise ValidationError(
                "bench track: need --frames >= 2, --rope-markers >= 3, --points > --rope-markers, --repeat >= 1"
            )
        results = run_track_benchmark(
            frames=frames, points_per_frame=points, rope_markers=rope_markers, repeat=repeat
        )
    print_bench_results(results, json_output)
