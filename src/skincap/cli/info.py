"""``skincap info``: summarise capture, motion, mesh and rig files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from skincap.cli._app import _user_errors, app, out


def _read(path: Path, **options: Any) -> Any:
    from skincap import io

    return io.read(path, **options)


def _print_summary(path: Path, summary: dict[str, Any]) -> None:
    table = Table(
        title=str(path), title_justify="left", show_header=False, box=None, pad_edge=False
    )
    table.add_column(style="bold")
    table.add_column()
    for key, value in summary.items():
        if isinstance(value, float):
            text = f"{value:.6g}"
        elif isinstance(value, list) and value and isinstance(value[0], float):
            text = "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
        else:
            text = str(value)
        table.add_row(key, text)
    out.print(table)


def _read_for_info(path: Path, units: str | None) -> Any:
    """Read ``path`` as the other verbs would: a mesh as ``skin`` reads it (a MakeHuman
    ``.obj`` with its rig beside it, in metres), anything else by its extension."""
    from skincap import io

    ext = path.suffix.lower()
    if ext in (".obj", ".ply", ".gltf", ".glb"):
        return io.read_mesh(path, units=units)
    if ext == ".pc2":  # skin's and animate's output; the OBJ beside it notes its rate
        from skincap.evaluate.summary import summarize_point_cache
        from skincap.io.pc2 import read_pc2, recorded_pc2_rate

        cache = read_pc2(path, units=units or "m")
        return summarize_point_cache(
            cache.frames,
            start_frame=cache.start_frame,
            frame_step=cache.sample_rate,
            rate=recorded_pc2_rate(path.with_suffix(".obj")),
        )
    return _read(path, **({"units": units} if units is not None and ext == ".bvh" else {}))


def _summary_of(obj: Any) -> dict[str, Any]:
    from skincap.evaluate.summary import summarize

    if isinstance(obj, dict):  # MakeHuman rig and weight files read as summaries
        return obj
    return summarize(obj)


# --------------------------------------------------------------------------- info
@app.command()
def info(
    files: Annotated[
        list[Path],
        typer.Argument(help="C3D, TRC, CSV, BVH, OBJ, PLY, glTF/GLB, PC2 or MakeHuman rig files."),
    ],
    json_output: Annotated[
        bool, typer.Option("--json", help="Print JSON (one object, or a list for several files).")
    ] = False,
    units: Annotated[
        str | None,
        typer.Option(help="BVH/OBJ length unit (m, cm, mm, in); guessed for BVH when omitted."),
    ] = None,
) -> None:
    """Summarise capture, motion and mesh files.

    Markers: frames, rate, duration, labelled/unlabelled counts, missing fraction,
    interior gaps and the longest; a C3D's analog channels, force plates and events. BVH: joints, frames, rate, units, channel orders.
    Mesh: vertices, faces, bounds, skin joints. PC2 point cache (skin's and animate's
    output): frames, points, rate (noted in the OBJ beside it), bounds, fastest point.

    Example: skincap info walk.c3d run.bvh --json
    """
    summaries = []
    with _user_errors():
        for path in files:
            summary = {"file": str(path), **_summary_of(_read_for_info(path, units))}
            summaries.append(summary)
            if not json_output:
                _print_summary(path, summary)
    if json_output:
        print(json.dumps(summaries[0] if len(summaries) == 1 else summaries, indent=2))
