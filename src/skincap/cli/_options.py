"""Typer options that several verbs share, as ``Annotated`` aliases.

A verb writes ``force: ForceOption = False``; the flag's name and help text live here
once, so the same option reads the same in every verb's ``--help``. The default stays
in the verb's signature (it differs between verbs). Options that only one verb has
stay beside that verb.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = [
    "BenchJsonOption",
    "EvalJsonOption",
    "ForceOption",
    "MeshUnitsOption",
    "OutputFolderOption",
    "PartsOption",
    "RepeatOption",
    "SurfaceOption",
    "SynthFramesOption",
    "SynthVerticesOption",
]

#: ``-o/--output`` of a verb that writes a folder of files.
OutputFolderOption = Annotated[Path, typer.Option("-o", "--output", help="Output folder.")]

#: ``--force``: without it no existing output is replaced.
ForceOption = Annotated[bool, typer.Option("--force", help="Replace existing outputs.")]

#: ``--json`` of a ``bench`` verb.
BenchJsonOption = Annotated[bool, typer.Option("--json", help="Print the measurements as JSON.")]

#: ``--json`` of an ``eval`` verb.
EvalJsonOption = Annotated[bool, typer.Option("--json", help="Print the result as JSON.")]

#: ``--repeat`` of a ``bench`` verb.
RepeatOption = Annotated[int, typer.Option(help="Timing repeats (the best is kept).")]

#: ``--frames`` of an ``eval`` verb that can make its own take (``--synth``).
SynthFramesOption = Annotated[int, typer.Option(help="Frames of a --synth take (120 Hz).")]

#: ``--vertices`` of an ``eval`` verb that can make its own take (``--synth``).
SynthVerticesOption = Annotated[
    int, typer.Option(help="Procedural body vertices of a --synth take.")
]

#: ``--mesh-units`` of a verb that reads a body mesh.
MeshUnitsOption = Annotated[
    str | None, typer.Option(help="Mesh length unit (default m; MakeHuman dm).")
]

#: ``--parts``: the near-rigid parts of the dense deformer.
PartsOption = Annotated[int, typer.Option(help="Near-rigid parts.")]

#: ``--surface``: a user marker surface instead of the automatic one.
SurfaceOption = Annotated[
    Path | None,
    typer.Option(help="User marker surface: PLY/OBJ over the markers or an edge-list CSV."),
]
