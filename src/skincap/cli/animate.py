"""``skincap animate``: dense markers drive a body mesh (:mod:`skincap.workflows.animate_file`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from skincap.cli._app import _user_errors, app, eval_app, out, print_json, stage_progress


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
    marker_radius: Annotated[
        float,
        typer.Option(help="With --register: marker centres' height above the skin, mm."),
    ] = 0.0,
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
                marker_radius_mm=marker_radius,
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


# ------------------------------------------------------------------ eval animate
_EVAL_OUTPUTS = ("animate_eval.json", "animate_errors.png")


@eval_app.command("animate")
def eval_animate(
    output: Annotated[Path, typer.Option("-o", "--output", help="Output folder.")],
    input_dir: Annotated[
        Path | None,
        typer.Argument(
            metavar="SYNTH_DIR",
            help="A folder written by 'skincap synth' (dense markers), or a labelled "
            "capture (.c3d/.trc/.csv): the held-out test only.",
        ),
    ] = None,
    synth: Annotated[
        str | None,
        typer.Option(
            "--synth", help="A clip (flex, jumprope, breathe, rom…) to generate into OUTPUT/take."
        ),
    ] = None,
    rom: Annotated[
        Path | None,
        typer.Option(
            help="A 'skincap synth --motion rom' folder of the same body and markers to learn the parts on."
        ),
    ] = None,
    template: Annotated[
        str | None,
        typer.Option(
            help="Another body (mesh file, or 'makehuman') registered to the markers: the registered-template row."
        ),
    ] = None,
    marker_radius: Annotated[
        float,
        typer.Option(
            help="Marker centres' height above the skin for --template's registration, mm."
        ),
    ] = 0.0,
    frames: Annotated[int, typer.Option(help="Frames of a --synth take (120 Hz).")] = 240,
    vertices: Annotated[
        int, typer.Option(help="Procedural body vertices of a --synth take.")
    ] = 5000,
    parts: Annotated[int, typer.Option(help="Near-rigid parts.")] = 17,
    seed: Annotated[
        int, typer.Option(help="Seed of the held-out markers (and of a --synth take).")
    ] = 0,
    json_output: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    force: Annotated[
        bool, typer.Option("--force", help="Replace outputs of an earlier run.")
    ] = False,
) -> None:
    """Measure the dense chain against the true skin (Park & Hodgins Fig. 7 and 8 as numbers).

    Rows: the four dense variants on the capture's own body, LBS and DQS driven by the
    true skeleton, one global RBF interpolation of the marker displacements, and 10 %
    of the markers held out. Writes OUTPUT/animate_eval.json and the per-vertex error
    colour maps OUTPUT/animate_errors.png; prints the table and the issue's targets.

    With --template, another body is registered to the take's reference pose and
    deformed too; that row is the distance to the true skin surface.

    Example: skincap eval animate take_jumprope --rom take_rom --template makehuman -o eval_dense
    """
    import json

    from skincap.errors import ValidationError
    from skincap.evaluate.animate import evaluate_animate, plot_vertex_errors
    from skincap.io.json_file import write_json
    from skincap.io.output_safety import guard_outputs

    paths = [output / name for name in _EVAL_OUTPUTS]
    with _user_errors(), guard_outputs([input_dir], paths, folders=[output], force=force):
        if (input_dir is None) == (synth is None):
            raise ValidationError(
                "give a folder made by skincap synth or --synth CLIP (one of them)"
            )
        with stage_progress("evaluating") as progress:
            if synth is not None:
                from skincap.workflows.synth_folder import synth_folder

                input_dir = output / "take"
                synth_folder(
                    input_dir, motion=synth, frames=frames, vertices=vertices, seed=seed,
                    force=force, progress=progress,
                )  # fmt: skip
            assert input_dir is not None  # one of the two was checked above
            if input_dir.is_file():
                _eval_capture(input_dir, paths[0], parts, seed, force, json_output)
                return
            body = None
            if template is not None:
                from skincap import io
                from skincap.data import path as shipped_file

                body = io.read_mesh(
                    shipped_file("makehuman_base.obj")
                    if template == "makehuman"
                    else Path(template)
                )
            result = evaluate_animate(
                input_dir, rom=rom, template=body, marker_radius=marker_radius / 1000.0,
                n_parts=parts, seed=seed, progress=progress,
            )  # fmt: skip
        per_vertex = result.pop("per_vertex_rms_m")
        reference_body = result.pop("vertices")
        result.pop("faces")
        output.mkdir(parents=True, exist_ok=True)
        write_json(paths[0], result, force=force, indent=2, allow_nan=False)
        plot_vertex_errors(
            reference_body,
            per_vertex,
            paths[1],
            force=force,
            title=f"Vertex RMS error: {input_dir}",
        )
    if json_output:
        print(json.dumps(result, indent=2, allow_nan=False))
        return
    for row in result["rows"]:
        if row.get("measured"):
            out.print(
                f"{row['case']:<20} {row['method']:<14} RMS {row['rms_m'] * 1e3:7.3f} mm  "
                f"mean {row['mean_m'] * 1e3:7.3f}  p95 {row['p95_m'] * 1e3:7.3f}  max {row['max_m'] * 1e3:7.3f}",
                markup=False,
            )
        else:
            out.print(
                f"{row['case']:<20} {row['method']:<14} not measured: {row['note']}", markup=False
            )
    reg = result.get("registration")
    if reg:
        out.print(
            f"registration ({reg['template_vertices']} vertices, {reg['seconds']:.1f} s): markers to "
            f"surface {reg['markers_to_surface_mean_m'] * 1e3:.2f} mm mean, surface to true skin "
            f"{reg['surface_to_true_skin_mean_m'] * 1e3:.2f} mm mean, "
            f"{reg['surface_to_true_skin_p95_m'] * 1e3:.2f} mm p95",
            markup=False,
        )
    held = result["held_out"]
    if held["mean_m"] is not None:
        out.print(
            f"held out {held['held_out']} of {held['markers']} markers: mean {held['mean_m'] * 1e3:.3f} mm, "
            f"p95 {held['p95_m'] * 1e3:.3f} mm",
            markup=False,
        )
    for name, t in result["targets"].items():
        mark = {True: "met", False: "NOT met", None: "not evaluated"}[t["met"]]
        shown = "-" if t["value"] is None else f"{t['value']:.4g}"
        out.print(f"target {name}: {shown} (target {t['target']}): {mark}", markup=False)
    out.print(f"wrote {paths[0]} and {paths[1]}", markup=False, soft_wrap=True)


def _eval_capture(
    capture: Path, json_path: Path, parts: int, seed: int, force: bool, json_output: bool
) -> None:
    """``eval animate CAPTURE``: the held-out test on a real (or any labelled) capture."""
    import json

    from skincap import io
    from skincap.evaluate.animate import held_out_on_capture
    from skincap.io.json_file import write_json

    held = held_out_on_capture(io.read(capture), n_parts=parts, seed=seed)
    result = {"capture": str(capture), "held_out": held}
    json_path.parent.mkdir(parents=True, exist_ok=True)
    write_json(json_path, result, force=force, indent=2, allow_nan=False)
    if json_output:
        print(json.dumps(result, indent=2, allow_nan=False))
        return
    out.print(
        f"{capture.name}: held out {held['held_out']} of {held['markers']} markers "
        f"({held['n_parts']} parts): mean {held['mean_m'] * 1e3:.2f} mm, p95 "
        f"{held['p95_m'] * 1e3:.2f} mm, max {held['max_m'] * 1e3:.1f} mm; wrote {json_path}",
        markup=False,
        soft_wrap=True,
    )
