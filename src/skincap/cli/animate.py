"""``skincap animate``: dense markers drive a body mesh (:mod:`skincap.workflows.animate_file`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from skincap.cli._app import _user_errors, app, out, print_json, stage_progress


@app.command()
def animate(
    mesh_path: Annotated[
        Path | None,
        typer.Argument(
            metavar="MESH",
            help="Body mesh (.obj/.ply/.gltf/.glb) in the markers' reference pose, or "
            "any pose with --register. Leave out with --rig.",
            show_default=False,
        ),
    ],
    output: Annotated[
        Path,
        typer.Option(
            "-o",
            "--output",
            help="OUT.pc2 (+ OUT.obj), OUT.usd/.usda/.usdc, or a folder for an OBJ sequence.",
        ),
    ],
    markers_path: Annotated[
        Path | None,
        typer.Argument(
            metavar="MARKERS",
            help="A cleaned, labelled dense take (.c3d/.trc/.csv).",
            show_default=False,
        ),
    ] = None,
    rom: Annotated[
        Path | None,
        typer.Option(help="Range-of-motion take the parts are learnt from (default: the take)."),
    ] = None,
    method: Annotated[
        str,
        typer.Option(help="quadratic_rbf (the paper's), quadratic, rigid_rbf or rigid."),
    ] = "quadratic_rbf",
    parts: Annotated[int, typer.Option(help="Near-rigid parts to segment.")] = 17,
    surface: Annotated[
        Path | None,
        typer.Option(help="Marker surface: PLY/OBJ over the markers or an edge CSV."),
    ] = None,
    landmarks: Annotated[
        Path | None,
        typer.Option(help="JSON {marker label: vertex index} guiding --register."),
    ] = None,
    reference_frame: Annotated[
        int | None,
        typer.Option(help="Frame whose pose the mesh matches (default: most markers)."),
    ] = None,
    register: Annotated[
        bool,
        typer.Option("--register", help="Fit the mesh to the reference-pose markers first."),
    ] = False,
    save_rig: Annotated[
        Path | None,
        typer.Option(help="Save the subject rig built here as R.npz + R.json."),
    ] = None,
    rig: Annotated[
        Path | None,
        typer.Option(help="Use a saved subject rig (R.npz) instead of MESH."),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(help="JSON report: parts, registration, per-frame timing."),
    ] = None,
    mesh_units: Annotated[
        str | None, typer.Option(help="Mesh length unit (default m; MakeHuman dm).")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace existing outputs.")] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")] = False,
) -> None:
    """Animate a body mesh with a dense marker take (Park & Hodgins 2006, §5).

    Builds the subject rig (marker surface, near-rigid parts, weights) on --rom or the
    take itself, then moves every vertex by its parts' rigid + quadratic + RBF fields.
    A take with gaps is filled by clean's default filler first, with a warning.

    Example: skincap animate body.obj take.c3d --reference-frame 0 --save-rig subj.npz -o take.pc2

    Example: skincap animate --rig subj.npz take2.c3d -o take2.usd
    """
    from skincap.workflows.animate_file import animate_file

    if rig is not None and markers_path is None:
        mesh_path, markers_path = None, mesh_path  # animate --rig R.npz MARKERS
    with _user_errors():
        if markers_path is None:
            from skincap.errors import FormatError

            raise_path = mesh_path if mesh_path is not None else Path("MARKERS")
            raise FormatError(raise_path, "give MESH and MARKERS (or --rig R.npz and MARKERS)")
        with stage_progress("animating") as progress:
            summary = animate_file(
                mesh_path,
                markers_path,
                output,
                rom=rom,
                method=method,
                n_parts=parts,
                surface=surface,
                landmarks=landmarks,
                reference_frame=reference_frame,
                register=register,
                save_rig=save_rig,
                rig=rig,
                report=report,
                mesh_units=mesh_units,
                force=force,
                progress=progress,
            )
    if json_output:
        print_json(summary)
        return
    ms = summary["deformation_ms_per_frame"]["mean"]
    out.print(
        f"{markers_path.name} -> {', '.join(summary['outputs'])}: {summary['frames']} frames, "
        f"{summary['vertices']} vertices, {summary['markers']} markers, "
        f"{summary['parts']['count']} parts, {summary['method']}"
        + (f", {ms:.3g} ms/frame" if ms is not None else ""),
        markup=False,
        soft_wrap=True,
    )
