"""``skincap animate``: dense markers drive a body mesh (:mod:`skincap.workflows.animate_file`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli._app import (
    _user_errors,
    app,
    check_seed,
    eval_app,
    out,
    print_json,
    stage_progress,
)
from skincap.cli._options import (
    EvalJsonOption,
    ForceOption,
    MeshUnitsOption,
    OutputFolderOption,
    SynthFramesOption,
    SynthVerticesOption,
)

# one alias per option, so each verb's signature reads as a list; the options other
# verbs share (same flag, same help) come from cli/_options.py
_MeshArg = Annotated[
    Path | None,
    typer.Argument(
        metavar="MESH",
        help="Body mesh (.obj/.ply/.gltf/.glb) in the markers' reference pose, or "
        "any pose with --register. Leave out with --rig.",
        show_default=False,
    ),
]
_AnimOutput = Annotated[
    Path,
    typer.Option(
        "-o",
        "--output",
        help="OUT.pc2 (+ OUT.obj), OUT.usd/.usda/.usdc, or a folder for an OBJ sequence.",
    ),
]
_MarkersArg = Annotated[
    Path | None,
    typer.Argument(
        metavar="MARKERS",
        help="A cleaned, labelled dense take (.c3d/.trc/.csv).",
        show_default=False,
    ),
]
_Rom = Annotated[
    Path | None,
    typer.Option(help="Range-of-motion take the parts are learnt from (default: the take)."),
]
_Method = Annotated[
    str,
    typer.Option(
        help="quadratic_rbf (the paper's), quadratic, rigid_rbf or rigid; or skeleton_rbf: "
        "a skeleton solved from the markers (calibrated on --rom), skinned, plus the "
        "markers' residuals (no --rig/--save-rig)."
    ),
]
_SkeletonTemplate = Annotated[
    str,
    typer.Option(help="With --method skeleton_rbf: solve template (auto, a built-in or JSON)."),
]
_Parts = Annotated[int, typer.Option(help="Near-rigid parts to segment.")]
_Surface = Annotated[
    Path | None, typer.Option(help="Marker surface: PLY/OBJ over the markers or an edge CSV.")
]
_Landmarks = Annotated[
    Path | None, typer.Option(help="JSON {marker label: vertex index} guiding --register.")
]
_ReferenceFrame = Annotated[
    int | None, typer.Option(help="Frame whose pose the mesh matches (default: most markers).")
]
_Register = Annotated[
    bool, typer.Option("--register", help="Fit the mesh to the reference-pose markers first.")
]
_MarkerRadius = Annotated[
    float, typer.Option(help="With --register: marker centres' height above the skin, mm.")
]
_SaveRig = Annotated[
    Path | None, typer.Option(help="Save the subject rig built here as R.npz + R.json.")
]
_Rig = Annotated[Path | None, typer.Option(help="Use a saved subject rig (R.npz) instead of MESH.")]
_Report = Annotated[
    Path | None, typer.Option(help="JSON report: parts, registration, per-frame timing.")
]
_Json = Annotated[bool, typer.Option("--json", help="Print the report as JSON.")]


@app.command()
def animate(
    output: _AnimOutput,
    mesh_path: _MeshArg = None,
    markers_path: _MarkersArg = None,
    rom: _Rom = None,
    method: _Method = "quadratic_rbf",
    parts: _Parts = 17,
    surface: _Surface = None,
    landmarks: _Landmarks = None,
    reference_frame: _ReferenceFrame = None,
    register: _Register = False,
    marker_radius: _MarkerRadius = 0.0,
    save_rig: _SaveRig = None,
    rig: _Rig = None,
    report: _Report = None,
    mesh_units: MeshUnitsOption = None,
    skeleton_template: _SkeletonTemplate = "auto",
    force: ForceOption = False,
    json_output: _Json = False,
) -> None:
    """Animate a body mesh with a dense marker take (Park & Hodgins 2006, §5).

    Builds the subject rig (marker surface, near-rigid parts, weights) on --rom or the
    take itself, then moves every vertex by its parts' rigid + quadratic + RBF fields.
    A take with gaps is filled by clean's default filler first, with a warning.

    Example: skincap animate body.obj take.c3d --reference-frame 0 --save-rig subj.npz -o take.pc2

    Example: skincap animate --rig subj.npz take2.c3d -o take2.usd

    Example: skincap animate body.obj take.c3d --rom rom.c3d --method skeleton_rbf -o take.pc2
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
                save_rig=save_rig,
                report=report,
                force=force,
                progress=progress,
                **animate_workflow_options(
                    rom,
                    method,
                    parts,
                    surface,
                    landmarks,
                    reference_frame,
                    register,
                    marker_radius,
                    rig,
                    mesh_units,
                    skeleton_template,
                ),  # fmt: skip
            )
    if json_output:
        print_json(summary)
        return
    ms = summary["deformation_ms_per_frame"]["mean"]
    out.print(
        f"{markers_path.name} -> {', '.join(summary['outputs'])}: {summary['frames']} frames, "
        f"{summary['vertices']} vertices, {summary['markers']} markers, "
        + (
            f"{summary['parts']['count']} parts, "
            if summary["parts"] is not None
            else f"{summary['rig']['skeleton']['joints']} joints, "
        )
        + f"{summary['method']}"
        + (f", {ms:.3g} ms/frame" if ms is not None else ""),
        markup=False,
        soft_wrap=True,
    )


def animate_workflow_options(
    rom: Path | None,
    method: str,
    parts: int,
    surface: Path | None,
    landmarks: Path | None,
    reference_frame: int | None,
    register: bool,
    marker_radius: float,
    rig: Path | None,
    mesh_units: str | None,
    skeleton_template: str = "auto",
) -> dict[str, Any]:
    """``animate``'s options as :func:`animate_file`'s keywords (shared with ``batch animate``)."""
    return {
        "rom": rom,
        "method": method,
        "n_parts": parts,
        "surface": surface,
        "landmarks": landmarks,
        "reference_frame": reference_frame,
        "register": register,
        "marker_radius_mm": marker_radius,
        "rig": rig,
        "mesh_units": mesh_units,
        "skeleton_template": skeleton_template,
    }


# ------------------------------------------------------------------ eval animate
_EVAL_OUTPUTS = ("animate_eval.json", "animate_errors.png")


_SynthDir = Annotated[
    Path | None,
    typer.Argument(
        metavar="SYNTH_DIR",
        help="A folder written by 'skincap synth' (dense markers), or a labelled "
        "capture (.c3d/.trc/.csv): the held-out test only.",
    ),
]
_SynthClip = Annotated[
    str | None,
    typer.Option(
        "--synth", help="A clip (flex, jumprope, breathe, rom…) to generate into OUTPUT/take."
    ),
]
_RomFolder = Annotated[
    Path | None,
    typer.Option(
        help="A 'skincap synth --motion rom' folder of the same body and markers to learn the parts on."
    ),
]
_Template = Annotated[
    str | None,
    typer.Option(
        help="Another body (mesh file, or 'makehuman') registered to the markers: the registered-template row."
    ),
]
_TemplateRadius = Annotated[
    float,
    typer.Option(
        help="Marker centres' height above the skin for --template's registration, mm "
        "(synth puts them 1.5 mm out)."
    ),
]
_EvalSeed = Annotated[
    int, typer.Option(help="Seed of the held-out markers (and of a --synth take).")
]
_EvalForce = Annotated[bool, typer.Option("--force", help="Replace outputs of an earlier run.")]
_EvalSkeleton = Annotated[
    str,
    typer.Option(
        help="Solve template of the skeleton_rbf rows (auto, a built-in or JSON; "
        "'none' leaves them out). Calibrated on the take itself."
    ),
]


@eval_app.command("animate")
def eval_animate(
    output: OutputFolderOption,
    input_dir: _SynthDir = None,
    synth: _SynthClip = None,
    rom: _RomFolder = None,
    template: _Template = None,
    marker_radius: _TemplateRadius = 1.5,
    frames: SynthFramesOption = 240,
    vertices: SynthVerticesOption = 5000,
    parts: _Parts = 17,
    seed: _EvalSeed = 0,
    json_output: EvalJsonOption = False,
    force: _EvalForce = False,
    skeleton_template: _EvalSkeleton = "auto",
) -> None:
    """Measure the dense chain against the true skin (Park & Hodgins Fig. 7 and 8 as numbers).

    Rows: the four dense variants on the capture's own body, LBS and DQS driven by the
    true skeleton, one global RBF interpolation of the marker displacements,
    skeleton_rbf (a skeleton solved from the markers, skinned, plus the markers'
    residuals), and 10 % of the markers held out. Writes OUTPUT/animate_eval.json and the per-vertex error
    colour maps OUTPUT/animate_errors.png; prints the table and the issue's targets.

    With --template, another body is registered to the take's reference pose and
    deformed too; that row is the distance to the true skin surface.

    Example: skincap eval animate take_jumprope --rom take_rom --template makehuman -o eval_dense
    """

    from skincap.errors import ValidationError
    from skincap.evaluate.animate import plot_vertex_errors
    from skincap.io.json_file import write_json
    from skincap.io.output_safety import guard_outputs
    from skincap.workflows.animate_file import check_parts

    paths = [output / name for name in _EVAL_OUTPUTS]
    with _user_errors(), guard_outputs([input_dir], paths, folders=[output], force=force):
        if (input_dir is None) == (synth is None):
            raise ValidationError(
                "give a folder made by skincap synth or --synth CLIP (one of them)"
            )
        check_seed(seed)
        check_parts(parts)  # the same range as animate's (0 ran and reported 3 parts)
        with stage_progress("evaluating") as progress:
            if synth is not None:
                input_dir = _synth_take(output, synth, frames, vertices, seed, force, progress)
            assert input_dir is not None  # one of the two was checked above
            if input_dir.is_file():
                _eval_capture(
                    input_dir, paths[0], parts, seed, force, json_output, skeleton_template
                )
                return
            result = _evaluate_folder(
                input_dir, rom, template, marker_radius, parts, seed, progress,
                None if skeleton_template == "none" else skeleton_template,
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
        print_json(result)
        return
    _print_eval_table(result)
    out.print(f"wrote {paths[0]} and {paths[1]}", markup=False, soft_wrap=True)


def _synth_take(
    output: Path, clip: str, frames: int, vertices: int, seed: int, force: bool, progress: Any
) -> Path:
    """``--synth CLIP``: generate the take into OUTPUT/take."""
    from skincap.workflows.synth_folder import synth_folder

    folder = output / "take"
    synth_folder(
        folder, motion=clip, frames=frames, vertices=vertices, seed=seed,
        force=force, progress=progress,
    )  # fmt: skip
    return folder


def _evaluate_folder(
    folder: Path,
    rom: Path | None,
    template: str | None,
    marker_radius_mm: float,
    parts: int,
    seed: int,
    progress: Any,
    skeleton_template: str | None = "auto",
) -> dict[str, Any]:
    """:func:`skincap.evaluate.animate.evaluate_animate` with ``--template`` read."""
    from skincap.evaluate.animate import evaluate_animate

    body = None
    if template is not None:
        from skincap import io
        from skincap.data import path as shipped_file

        body = io.read_mesh(
            shipped_file("makehuman_base.obj") if template == "makehuman" else Path(template)
        )
    return evaluate_animate(
        folder, rom=rom, template=body, marker_radius=marker_radius_mm / 1000.0,
        n_parts=parts, seed=seed, progress=progress, skeleton_template=skeleton_template,
    )  # fmt: skip


def _tail_side(row: dict[str, Any]) -> str:
    """How much of a region's share of the registration's worst 5 % lies under the true skin."""
    inside = row.get("tail_inside_fraction")
    return "" if inside is None else f", {inside * 100:.0f} % of its worst under the skin"


def _print_eval_table(result: dict[str, Any]) -> None:
    """The rows, the registration, the held-out markers and the targets, one line each."""
    from skincap.evaluate.animate import STRETCH_THRESHOLD

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
    for group in result.get("seams") or []:
        if group["region"] != "all":
            shown = ", ".join(f"{m} {v * 1e3:.2f}" for m, v in group["rms_m"].items())
            out.print(
                f"vertices at a seam between parts ({group['vertices']})" if group["region"] == "seam"
                else f"vertices inside one part ({group['vertices']})",
                f"RMS mm: {shown}", markup=False, soft_wrap=True,
            )  # fmt: skip
    for group in result.get("stretch") or []:
        if group["region"] != "all":
            shown = ", ".join(f"{m} {v * 1e3:.2f}" for m, v in group["rms_m"].items())
            out.print(
                f"vertices where the take {'stretches' if group['region'] == 'stretched' else 'never stretches'} "
                f"the marker surface by more than {STRETCH_THRESHOLD:.0%} ({group['vertices']})",
                f"RMS mm: {shown}", markup=False, soft_wrap=True,
            )  # fmt: skip

    reg = result.get("registration")
    if reg:
        out.print(
            f"registration ({reg['template_vertices']} vertices, {reg['seconds']:.1f} s): markers to "
            f"surface {reg['markers_to_surface_mean_m'] * 1e3:.2f} mm mean, surface to true skin "
            f"{reg['surface_to_true_skin_mean_m'] * 1e3:.2f} mm mean, "
            f"{reg['surface_to_true_skin_p95_m'] * 1e3:.2f} mm p95",
            markup=False,
        )
        worst = (reg.get("regions") or [])[:3]
        if worst:
            out.print(
                "registration's worst 5 % by region: " + ", ".join(
                    f"{r['region']} {r['tail_share'] * 100:.0f} % (mean {r['mean_m'] * 1e3:.1f} mm"
                    + _tail_side(r) + ")"
                    for r in worst
                ),
                markup=False, soft_wrap=True,
            )  # fmt: skip
        bound = reg.get("marker_surface_bound") or {}
        if bound.get("target_mean_m") is not None:
            out.print(
                f"marker surface at the true skin: covers {bound['covered_area_fraction'] * 100:.0f} % "
                f"of its area, {bound['target_mean_m'] * 1e3:.2f} mm mean, "
                f"{bound['target_p95_m'] * 1e3:.2f} mm p95 from it there",
                markup=False, soft_wrap=True,
            )  # fmt: skip
        exact = bound.get("exact_normals") or {}
        normals = reg.get("marker_normals") or {}
        if normals.get("error_mean_deg") is not None and exact.get("target_mean_m") is not None:
            out.print(
                f"registration's normals at the markers: {normals['error_mean_deg']:.1f} deg mean, "
                f"{normals['error_p95_deg']:.1f} deg p95 off the true skin's; with the true ones "
                f"the marker surface is {exact['target_mean_m'] * 1e3:.2f} mm mean, "
                f"{exact['target_p95_m'] * 1e3:.2f} mm p95 from it",
                markup=False, soft_wrap=True,
            )  # fmt: skip
    held = result["held_out"]
    if held["mean_m"] is not None:
        out.print(
            f"held out {held['held_out']} of {held['markers']} markers: mean {held['mean_m'] * 1e3:.3f} mm, "
            f"p95 {held['p95_m'] * 1e3:.3f} mm" + _worst_held_out_text(held),
            markup=False, soft_wrap=True,
        )  # fmt: skip
    _print_skeleton_held_out(result.get("held_out_skeleton_rbf"))
    seg = result.get("segmentation") or {}
    if seg.get("ari") is not None:
        out.print(
            f"segmentation: {seg['n_parts']} parts, adjusted Rand index {seg['ari']:.3f} "
            "against truth/marker_parts.csv",
            markup=False,
        )
    for name, t in result["targets"].items():
        mark = {True: "met", False: "NOT met", None: "not evaluated"}[t["met"]]
        shown = "-" if t["value"] is None else f"{t['value']:.4g}"
        out.print(f"target {name}: {shown} (target {t['target']}): {mark}", markup=False)


def _print_skeleton_held_out(held: dict[str, Any] | None) -> None:
    """The skeleton_rbf held-out line (None: not run)."""
    if held is None:
        return
    if held.get("mean_m") is None:
        out.print(
            f"skeleton_rbf held-out markers: {held.get('note', 'not measured')}",
            markup=False,
            soft_wrap=True,
        )
        return
    sk = held["skeleton"]
    out.print(
        f"skeleton_rbf: held out {held['held_out']} of {held['markers']} markers: mean "
        f"{held['mean_m'] * 1e3:.3f} mm, p95 {held['p95_m'] * 1e3:.3f} mm (skeleton solved from "
        f"the kept markers: {sk['joints']} joints, residual {sk['residual_rms_m'] * 1e3:.1f} mm RMS)",
        markup=False, soft_wrap=True,
    )  # fmt: skip


def _worst_held_out_text(held: dict[str, Any]) -> str:
    """``, max … (marker …, … mm from the nearest kept marker)`` of a held-out result."""
    worst = held.get("worst")
    if not worst:
        return ""
    return (
        f", max {worst['max_m'] * 1e3:.2f} mm ({worst['marker']} at frame {worst['frame']}, "
        f"{worst['nearest_kept_m'] * 1e3:.0f} mm from the nearest kept marker)"
    )


def _eval_capture(
    capture: Path,
    json_path: Path,
    parts: int,
    seed: int,
    force: bool,
    json_output: bool,
    skeleton_template: str = "auto",
) -> None:
    """``eval animate CAPTURE``: the held-out test on a real (or any labelled) capture."""

    from skincap import io
    from skincap.evaluate.animate import held_out_on_capture
    from skincap.io.json_file import write_json

    markers = io.read(capture)
    held = held_out_on_capture(markers, n_parts=parts, seed=seed)
    result: dict[str, Any] = {"capture": str(capture), "held_out": held}
    if skeleton_template != "none":
        from skincap.evaluate.skeleton_rbf import held_out_skeleton_rbf_on_capture

        result["held_out_skeleton_rbf"] = held_out_skeleton_rbf_on_capture(
            markers, seed=seed, template=skeleton_template
        )
    json_path.parent.mkdir(parents=True, exist_ok=True)
    write_json(json_path, result, force=force, indent=2, allow_nan=False)
    if json_output:
        print_json(result)
        return
    out.print(
        f"{capture.name}: held out {held['held_out']} of {held['markers']} markers "
        f"({held['n_parts']} parts): mean {held['mean_m'] * 1e3:.2f} mm, p95 "
        f"{held['p95_m'] * 1e3:.2f} mm{_worst_held_out_text(held)}; wrote {json_path}",
        markup=False,
        soft_wrap=True,
    )
    _print_skeleton_held_out(result.get("held_out_skeleton_rbf"))
