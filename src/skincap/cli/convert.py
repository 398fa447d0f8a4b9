"""``skincap convert``: one file to another format (:mod:`skincap.workflows.convert_file`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli._app import _user_errors, app, out, print_json
from skincap.cli._options import ForceOption


@app.command()
def convert(
    src: Annotated[Path, typer.Argument(help="Input file.")],
    dst: Annotated[Path, typer.Argument(help="Output file; its extension picks the format.")],
    force: ForceOption = False,
    units: Annotated[
        str | None, typer.Option(help="Length unit of a BVH/OBJ input (m, cm, mm, in).")
    ] = None,
    points: Annotated[
        bool, typer.Option("--points", help="Markers to the long point CSV (frame,time,x,y,z,id).")
    ] = False,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the summary as JSON (input, output, counts).")
    ] = False,
) -> None:
    """Convert between formats: C3D <-> TRC <-> CSV, BVH -> BVH, BVH -> CSV joint positions, OBJ <-> PLY.

    Example: skincap convert walk.c3d walk.trc
    """
    from skincap.workflows.convert_file import convert_file

    with _user_errors():
        counts = convert_file(src, dst, force=force, **convert_workflow_options(units, points))
    if json_output:
        print_json({"input": str(src), "output": str(dst), **counts})
        return
    what = ", ".join(f"{n} {name}" for name, n in counts.items())
    out.print(f"{src} -> {dst}: {what}", markup=False)


def convert_workflow_options(units: str | None, points: bool) -> dict[str, Any]:
    """``convert``'s options as :func:`convert_file`'s keywords (shared with ``batch convert``)."""
    return {"units": units, "points": points}
