"""``skincap skin``: skin a mesh with a BVH motion (:mod:`skincap.workflows.skin_file`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from skincap.cli._app import _user_errors, app, err, frame_bar, out, print_json
from skincap.cli._options import ForceOption, MeshUnitsOption
from skincap.errors import FormatError

#: The most joints per vertex --max-influences allows: skinning formats carry 4 or 8, and
#: past a few dozen the weights are noise (1e9 was accepted and meant "all of them").
MAX_INFLUENCES = 64


@app.command()
def skin(
    mesh_path: Annotated[
        Path,
        typer.Argument(
            metavar="MESH",
            help="MakeHuman .obj (rig beside it), skinned .glb/.gltf, or bare .obj/.ply.",
        ),
    ],
    motion_path: Annotated[Path, typer.Argument(metavar="MOTION", help="A BVH motion.")],
    output: Annotated[
        Path,
        typer.Option(
            "-o",
            "--output",
            help="OUT.glb (skin + joint animation), OUT.pc2 (+ OUT.obj), OUT.usd, or a folder for an OBJ sequence.",
        ),
    ],
    method: Annotated[
        str,
        typer.Option(
            help="Deformer for baked outputs: lbs, dqs, or sweep (arms and legs on sweeps of "
            "ellipses fitted to the mesh, volume kept; Hyun et al. 2005). glTF skinning is always linear."
        ),
    ] = "lbs",
    weights: Annotated[
        str | None,
        typer.Option(
            help="auto (bone heat) or file; default: file for a rigged mesh, auto for a bare one."
        ),
    ] = None,
    name_map: Annotated[
        Path | None,
        typer.Option(
            "--map", help="JSON {bvh_joint: mesh_joint} overriding the built-in name maps."
        ),
    ] = None,
    units: Annotated[
        str | None,
        typer.Option(
            help="BVH length unit (m, dm, cm, mm, in, cmu); guessed from the skeleton when omitted."
        ),
    ] = None,
    mesh_units: MeshUnitsOption = None,
    max_influences: Annotated[
        int, typer.Option(help=f"Joints per vertex, 1..{MAX_INFLUENCES}.")
    ] = 4,
    force: ForceOption = False,
    json_output: Annotated[
        bool,
        typer.Option(
            "--json", help="Print the summary as JSON (outputs, vertices, height, joints)."
        ),
    ] = False,
) -> None:
    """Skin a mesh with a BVH motion: bind, retarget, deform, export.

    A folder output (one OBJ per frame) says the size it will write before it starts.

    Example: skincap skin makehuman_base.obj walk.bvh --units cmu --method dqs -o walk.pc2
    """
    from skincap.workflows.skin_file import skin_file

    def announce(line: str) -> None:
        err.print(f"skin: {line}", markup=False, soft_wrap=True)

    with _user_errors():
        options = skin_workflow_options(
            method, weights, name_map, units, mesh_units, max_influences
        )
    with _user_errors(), frame_bar(f"skinning ({method})") as advance:
        summary = skin_file(
            mesh_path,
            motion_path,
            output,
            force=force,
            progress=advance,
            notify=announce,
            **options,
        )
    if json_output:
        print_json(summary)
        return
    out.print(
        f"{mesh_path.name} + {motion_path.name} -> {', '.join(summary['outputs'])}: "
        f"{summary['vertices']} vertices, {summary['height_m']:.3g} m tall, "
        f"{summary['joints']}-joint rig, {summary['frames']} frames at {summary['rate']:.6g} Hz, "
        f"{method}, {summary['weights']} weights",
        markup=False,
        soft_wrap=True,
    )


def skin_workflow_options(
    method: str,
    weights: str | None,
    name_map: Path | None,
    units: str | None,
    mesh_units: str | None,
    max_influences: int,
) -> dict[str, Any]:
    """``skin``'s options, checked, as :func:`skin_file`'s keywords (shared with ``batch skin``).

    Raises
    ------
    FormatError
        ``--max-influences`` outside 1..:data:`MAX_INFLUENCES`.
    """
    if not 1 <= max_influences <= MAX_INFLUENCES:
        raise FormatError(
            "--max-influences",
            f"expected 1..{MAX_INFLUENCES} joints per vertex, got {max_influences}",
        )
    return {
        "method": method,
        "weights": weights,
        "name_map": name_map,
        "units": units,
        "mesh_units": mesh_units,
        "max_influences": max_influences,
    }
