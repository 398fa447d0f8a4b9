"""The ``skincap`` command line: ``info``, ``convert``, ``demo`` and ``bench``.

Errors the user can fix (bad input, an existing output) print one line,
``skincap: error: <file>: <what is wrong>``, and exit with status 2. Warnings
(a guessed unit) print ``skincap: warning: …`` and the command goes on.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from skincap.errors import (
    FormatError,
    MissingDependencyError,
    OutputExistsError,
    SkincapError,
    SkincapWarning,
    ValidationError,
    one_line,
)

app = typer.Typer(
    name="skincap",
    help="Optical motion capture to moving human skin. Run 'skincap demo' to see it work.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
bench_app = typer.Typer(
    help="Benchmarks that print speed ratios against a peer measured in the same run.",
    no_args_is_help=True,
)
app.add_typer(bench_app, name="bench")
eval_app = typer.Typer(
    help="Evaluations against ground truth, as JSON and PNG plots.", no_args_is_help=True
)
app.add_typer(eval_app, name="eval")

out = Console(highlight=False)
err = Console(stderr=True, highlight=False)


def skincap_version() -> str:
    """The installed distribution's version (``skincap.__version__`` when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("skincap")
    except PackageNotFoundError:
        from skincap import __version__

        return __version__


def _print_version(value: bool) -> None:
    if value:
        print(f"skincap {skincap_version()}")
        raise typer.Exit()


@app.callback()
def _global_options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Optical motion capture to moving human skin. Run 'skincap demo' to see it work."""


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn skincap errors into one line and status 2; show each warning once, one line each.

    Warnings are collected while the verb runs and printed when it ends (before the
    error line, if any), each distinct message once.
    """
    error_line = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SkincapWarning)
        try:
            yield
        except SkincapError as exc:
            error_line = _skincap_error_line(exc)
        except OSError as exc:
            error_line = _os_error_line(exc)
        finally:
            _flush_warnings(caught)
    if error_line is not None:
        _print_line(f"skincap: error: {error_line}")
        raise typer.Exit(2)


def _print_line(text: str) -> None:
    """One line on stderr, exactly as given: no markup, emoji codes or highlighting."""
    err.print(text, markup=False, emoji=False, highlight=False, soft_wrap=True)


def _flush_warnings(caught: list[warnings.WarningMessage]) -> None:
    """Print the recorded warnings, each distinct one once, and forget them.

    Warnings from NumPy, SciPy or Python itself are printed here too, with their
    category, rather than handed back to ``warnings.showwarning``: inside
    ``catch_warnings(record=True)`` that appends to the very list being printed.
    """
    shown: set[str] = set()
    for w in caught:
        if issubclass(w.category, SkincapWarning):
            text = one_line(str(w.message))
        else:
            text = one_line(f"{w.category.__name__}: {w.message}")
        if text not in shown:
            shown.add(text)
            _print_line(f"skincap: warning: {text}")
    caught.clear()


def _skincap_error_line(exc: SkincapError) -> str:
    """``<file>: <what is wrong>`` for a skincap error, on one line.

    An error that names no file (an argument check deep in an algorithm) is prefixed
    with the input files the verb was given.
    """
    text = str(exc)
    if getattr(exc, "path", None) is None and not isinstance(exc, MissingDependencyError):
        inputs = _verb_input_files()
        if inputs and not any(text.startswith(f"{p}:") for p in inputs):
            text = f"{', '.join(inputs)}: {text}"
    return one_line(text)


def _os_error_line(exc: OSError) -> str:
    """``<file>: <system message>`` for an OSError, naming the path the user gave."""
    name = exc.filename if exc.filename is not None else exc.filename2
    what = exc.strerror or str(exc)
    if name is None:
        inputs = _verb_input_files()
        return one_line(f"{', '.join(inputs)}: {what}" if inputs else what)
    return one_line(f"{_path_given(os.fsdecode(name))}: {what.lower()}")


# atomic_output (skincap.io._common) writes ``<folder>/.<name>.<8 random>.part<suffix>``
# and renames it onto ``<folder>/<name>``; an error on that file is about ``<name>``.
_TEMP_OUTPUT = re.compile(r"^\.(?P<name>.+)\.[A-Za-z0-9_]{8}\.part(?P<suffix>\.[^./]*)?$")


def _path_given(filename: str) -> str:
    """The output path the user gave, when ``filename`` is atomic_output's temporary file."""
    folder, base = os.path.split(filename)
    match = _TEMP_OUTPUT.match(base)
    if match is None or not match["name"].endswith(match["suffix"] or ""):
        return filename
    return match["name"] if folder in ("", ".") else os.path.join(folder, match["name"])


def _verb_input_files() -> list[str]:
    """The existing files among the running verb's positional arguments, as given."""
    try:
        from typer._click.globals import get_current_context  # a typer that vendors click
    except ImportError:  # pragma: no cover - a typer built on click
        from click import get_current_context

    ctx = get_current_context(silent=True)
    if ctx is None:
        return []
    found: list[str] = []
    for param in ctx.command.params:
        if param.param_type_name != "argument":
            continue
        value = ctx.params.get(param.name or "")
        for item in value if isinstance(value, list | tuple) else [value]:
            if isinstance(item, Path) and item.is_file():
                found.append(str(item))
    return found


def frame_progress() -> Any:
    """A transient rich progress bar on stderr counting frames (hidden off a terminal)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} frames"),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    )


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
        typer.Argument(help="C3D, TRC, CSV, BVH, OBJ, PLY, glTF/GLB or MakeHuman rig files."),
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
    interior gaps and the longest. BVH: joints, frames, rate, units, channel orders.
    Mesh: vertices, faces, bounds, skin joints.

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


# ------------------------------------------------------------------------ convert
_MARKER_OUT = (".c3d", ".trc", ".csv")
_MESH_OUT = (".obj", ".ply")


def convert_file(
    src: Path,
    dst: Path,
    *,
    force: bool = False,
    units: str | None = None,
    points: bool = False,
) -> dict[str, int]:
    """Convert ``src`` to ``dst`` by their extensions; return the counts written.

    Markers go C3D <-> TRC <-> CSV (Vicon trajectories CSV; the long point format
    with ``points=True``), BVH -> BVH (``units`` rescales the written file), BVH ->
    CSV of joint world positions, and meshes between OBJ and PLY (glTF read).
    ``dst`` is checked against ``src`` (links included) before anything is read.
    """
    from skincap.io.output_safety import guard_outputs

    with guard_outputs([src], [dst], force=force):
        return _convert_checked(src, dst, force=force, units=units, points=points)


def _convert_checked(
    src: Path, dst: Path, *, force: bool, units: str | None, points: bool
) -> dict[str, int]:
    """Read ``src``, write ``dst``; return what was written: frames, joints, vertices, triangles."""
    from skincap import io
    from skincap.types import MarkerSet, Mesh, Motion, PointCloud

    in_kind = io.kind_of_extension(src)
    out_ext = dst.suffix.lower()
    read_options: dict[str, Any] = {}
    if (
        units is not None
        and in_kind in ("motion", "mesh")
        and src.suffix.lower() in (".bvh", ".obj")
    ):
        read_options["units"] = units
    if in_kind in ("markers", "motion", "mesh") and out_ext not in _MARKER_OUT + _MESH_OUT + (
        ".bvh",
    ):
        raise FormatError(
            dst,
            f"cannot write {out_ext or '(no extension)'!r}; convert writes {', '.join(_MARKER_OUT + ('.bvh',) + _MESH_OUT)}",
        )
    obj = io.read(src, **read_options)

    if isinstance(obj, MarkerSet | PointCloud):
        if out_ext not in _MARKER_OUT:
            raise FormatError(dst, f"markers convert to {', '.join(_MARKER_OUT)}, not {out_ext}")
        if isinstance(obj, MarkerSet) and points:
            if out_ext != ".csv":
                raise FormatError(
                    dst, "--points writes the long point CSV format: give a .csv output"
                )
            obj = PointCloud.from_markerset(obj)
        elif isinstance(obj, PointCloud) and out_ext != ".csv":
            obj = obj.to_markerset()
        io.write(obj, dst, force=force)
        return {"frames": obj.n_frames}
    if isinstance(obj, Motion):
        if out_ext == ".bvh":
            io.write(obj, dst, force=force)
        elif out_ext == ".csv":
            from skincap.io.joints_csv import write_joint_positions_csv

            write_joint_positions_csv(obj, dst, force=force)
        else:
            raise FormatError(
                dst, f"a BVH converts to .bvh or .csv (joint positions), not {out_ext}"
            )
        return {"frames": obj.n_frames, "joints": obj.skeleton.n_joints}
    if isinstance(obj, Mesh):
        if out_ext not in _MESH_OUT:
            raise FormatError(dst, f"a mesh converts to {', '.join(_MESH_OUT)}, not {out_ext}")
        io.write(obj, dst, force=force)
        return {"vertices": obj.n_vertices, "triangles": obj.n_faces}
    raise FormatError(src, "this file type cannot be converted")


@app.command()
def convert(
    src: Annotated[Path, typer.Argument(help="Input file.")],
    dst: Annotated[Path, typer.Argument(help="Output file; its extension picks the format.")],
    force: Annotated[bool, typer.Option("--force", help="Replace an existing output.")] = False,
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
    with _user_errors():
        counts = convert_file(src, dst, force=force, units=units, points=points)
    if json_output:
        print_json({"input": str(src), "output": str(dst), **counts})
        return
    what = ", ".join(f"{n} {name}" for name, n in counts.items())
    out.print(f"{src} -> {dst}: {what}", markup=False)


def print_json(data: Any) -> None:
    """Print ``data`` as JSON on stdout: the machine-readable form of a verb's summary line."""
    print(json.dumps(data, indent=2, allow_nan=False, default=str))


# --------------------------------------------------------------------------- skin
def load_skinnable_mesh(path: Path, *, units: str | None = None) -> Any:
    """Read a mesh for skinning (see :func:`skincap.io.read_mesh`)."""
    from skincap import io

    return io.read_mesh(path, units=units)


_SKIN_OUTPUTS = (".glb", ".pc2", ".usd", ".usda", ".usdc")


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
            help="Deformer for baked outputs: lbs or dqs (glTF skinning is always linear)."
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
    mesh_units: Annotated[
        str | None, typer.Option(help="Mesh length unit (default m; MakeHuman dm).")
    ] = None,
    max_influences: Annotated[int, typer.Option(help="Joints per vertex.")] = 4,
    force: Annotated[bool, typer.Option("--force", help="Replace existing outputs.")] = False,
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
    from skincap.io.output_safety import guard_outputs

    with (
        _user_errors(),
        guard_outputs(
            [*mesh_input_files(mesh_path), motion_path, name_map],
            skin_output_files(output),
            folders=[] if output.suffix else [output],
            force=force,
        ),
    ):
        summary = _skin(
            mesh_path,
            motion_path,
            output,
            method=method,
            weights=weights,
            name_map=name_map,
            units=units,
            mesh_units=mesh_units,
            max_influences=max_influences,
            force=force,
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


def mesh_input_files(mesh_path: Path) -> list[Path]:
    """Every file reading ``mesh_path`` may open: the mesh, a MakeHuman rig beside an
    ``.obj`` (``.mhskel``/``.mhw``), the ``.bin`` buffers beside a ``.gltf``."""
    files = [mesh_path]
    ext = mesh_path.suffix.lower()
    folder = mesh_path.parent
    if ext == ".obj" and folder.is_dir():
        files += sorted(folder.glob("*.mhskel")) + sorted(folder.glob("*.mhw"))
    elif ext == ".gltf" and folder.is_dir():
        files += sorted(folder.glob("*.bin"))
    return files


def skin_output_files(output: Path) -> list[Path]:
    """The files ``skin -o output`` writes, known before skinning (a folder's frames are
    checked once the frame count is known)."""
    if output.suffix.lower() == ".pc2":
        return [output, output.with_suffix(".obj")]  # the cache and the mesh it plays on
    return [output] if output.suffix else []


def _skin(
    mesh_path: Path,
    motion_path: Path,
    output: Path,
    *,
    method: str,
    weights: str | None,
    name_map: Path | None,
    units: str | None,
    mesh_units: str | None,
    max_influences: int,
    force: bool,
) -> dict[str, Any]:
    """Bind, retarget, deform and export; return the summary (``skin --json``)."""
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.io.bvh import read_bvh

    ext = output.suffix.lower()
    if method not in ("lbs", "dqs"):
        raise FormatError(output, f"--method must be lbs or dqs, got {method!r}")
    if ext and ext not in _SKIN_OUTPUTS:
        raise FormatError(
            output,
            f"cannot write {ext!r}; skin writes {', '.join(_SKIN_OUTPUTS)} or a folder (OBJ sequence)",
        )
    if ext == ".glb" and method != "lbs":
        raise FormatError(
            output,
            "glTF skinning is linear blend skinning; write .pc2, .usd or a folder to bake DQS",
        )
    if weights not in (None, "auto", "file"):
        raise FormatError(output, f"--weights must be auto or file, got {weights!r}")
    if not ext and output.is_dir() and any(output.iterdir()) and not force:
        raise OutputExistsError(output)
    mesh = load_skinnable_mesh(mesh_path, units=mesh_units)
    motion = read_bvh(motion_path, units=units)
    if not ext:  # before binding, which can take minutes for a bare mesh
        _check_obj_sequence(mesh, motion.n_frames, output)
    setup = prepare_skinning(
        mesh,
        motion,
        weights=weights,
        name_map=name_map,
        max_influences=max_influences,  # type: ignore[arg-type]
    )
    frames = setup.motion.n_frames
    with frame_progress() as progress:
        task = progress.add_task(f"skinning ({method})", total=frames)

        def advance(fraction: float) -> None:
            progress.update(task, completed=fraction * frames)

        written = _write_skinned(setup, output, method=method, force=force, progress=advance)
    from skincap.evaluate.summary import mesh_height

    return {
        "mesh": str(mesh_path),
        "motion": str(motion_path),
        "outputs": [str(p) for p in (written if output.suffix else [output])],
        "files": len(written),
        "vertices": setup.mesh.n_vertices,
        "height_m": mesh_height(setup.mesh),
        "joints": setup.mesh.skin.skeleton.n_joints,
        "frames": frames,
        "rate": setup.motion.rate,
        "method": method,
        "weights": setup.report["weights"],
    }


def _check_obj_sequence(mesh: Any, frames: int, folder: Path) -> None:
    """Check an OBJ-sequence folder's frame files against the inputs; say the size first.

    ``mesh`` is the rest mesh as read (binding keeps its vertices and topology) and
    ``frames`` the motion's frame count (retargeting keeps it)."""
    from skincap.io.obj_sequence import estimate_obj_sequence_bytes, obj_sequence_paths
    from skincap.io.output_safety import check_outputs

    check_outputs(obj_sequence_paths(folder, frames), force=True)
    size = estimate_obj_sequence_bytes(mesh, frames, units="m", up="y")
    err.print(
        f"skin: writing {frames} OBJ files to {folder}, about {_bytes_text(size)}",
        markup=False,
        soft_wrap=True,
    )


def _bytes_text(size: float) -> str:
    """``4.0 GB``, ``512 MB``…: decimal units, as file managers and ``df -H`` show them."""
    if size < 1000:
        return f"{size:.0f} B"
    for unit in ("kB", "MB", "GB"):
        size /= 1000
        if size < 1000 or unit == "GB":
            break
    return f"{size:.1f} {unit}"


def _write_skinned(
    setup: Any, output: Path, *, method: str, force: bool, progress: Any
) -> list[Path]:
    """Export a :class:`SkinningSetup` by ``output``'s extension; return the written paths."""
    from skincap.deform.skeletal.deformers import skin_motion

    ext = output.suffix.lower()
    if ext == ".glb":
        from skincap.io.gltf.writer import write_glb

        write_glb(setup.mesh, setup.motion, output, force=force)
        progress(1.0)
        return [output]
    animation = skin_motion(setup.mesh, setup.motion, method=method, progress=progress)
    if ext == ".pc2":
        from skincap.io.mesh import write_obj
        from skincap.io.pc2 import write_pc2

        rest_obj = output.with_suffix(".obj")
        # The mesh Blender's Mesh Cache modifier plays the PC2 on: same metres, Y up.
        write_obj(setup.mesh, rest_obj, force=force, units="m", up="y")
        write_pc2(animation, output, force=force)
        return [output, rest_obj]
    if ext in (".usd", ".usda", ".usdc"):
        from skincap.io.usd import write_usd

        write_usd(animation, output, force=force)
        return [output]
    from skincap.io.obj_sequence import write_obj_sequence

    write_obj_sequence(animation, output, force=force, units="m", up="y")
    return [output]


# -------------------------------------------------------------------------- synth
@app.command()
def synth(
    output: Annotated[Path, typer.Option("-o", "--output", help="Output folder.")],
    body: Annotated[
        str,
        typer.Option(help="procedural (swept elliptic sections) or makehuman (shipped CC0 rig)."),
    ] = "procedural",
    motion: Annotated[
        str,
        typer.Option(
            help="A clip (tpose, flex, twist, squat, punch, jumprope, breathe) or a .bvh file."
        ),
    ] = "jumprope",
    markers: Annotated[
        str, typer.Option(help="dense (~350, Park & Hodgins) or sparse (~41 landmarks).")
    ] = "dense",
    rope: Annotated[
        str, typer.Option(help="none, jump (both ends in the hands) or whip (one end held).")
    ] = "none",
    frames: Annotated[
        int | None,
        typer.Option(help="Length in frames (default: the clip's 4 s, or the whole BVH)."),
    ] = None,
    seconds: Annotated[
        float | None, typer.Option(help="Length in seconds (instead of --frames).")
    ] = None,
    rate: Annotated[float, typer.Option(help="Capture rate of built-in clips, Hz.")] = 120.0,
    vertices: Annotated[
        int, typer.Option(help="Procedural body resolution (about 5k to 80k vertices).")
    ] = 20_000,
    noise_mm: Annotated[
        float, typer.Option(help="Gaussian noise of reconstructed markers, mm.")
    ] = 0.5,
    soft_tissue: Annotated[
        float, typer.Option(help="Scale of bulge, jiggle and breathing (0 switches them off).")
    ] = 1.0,
    units: Annotated[
        str | None, typer.Option(help="Length unit of a BVH motion (guessed when omitted).")
    ] = None,
    spikes: Annotated[
        int,
        typer.Option(help="Spikes put into capture.c3d: a marker jumps 4-6 cm for 1-3 frames."),
    ] = 0,
    swaps: Annotated[
        int,
        typer.Option(
            help="Label swaps put into capture.c3d: two labelled markers within 12 cm "
            "exchange labels for 5-40 frames."
        ),
    ] = 0,
    prop: Annotated[
        bool,
        typer.Option("--prop", help="Add a 4-marker rigid prop moving on its own beside the body."),
    ] = False,
    seed: Annotated[int, typer.Option(help="Random seed: the same seed gives the same bytes.")] = 0,
    real_markers: Annotated[
        Path | None,
        typer.Option(
            help="A labelled capture (C3D, TRC, CSV) to use as the body instead of a "
            "synthetic one: its real markers, with a PBD-simulated rope (--rope whip|jump) "
            "in the performer's hands."
        ),
    ] = None,
    hands: Annotated[
        str | None,
        typer.Option(
            help="With --real-markers: marker names of the left[:right] hand, e.g. "
            "LWRA,LWRB:RWRA,RWRB (found by name when omitted); a whip is held in the last."
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace outputs of an earlier run.")
    ] = False,
) -> None:
    """Generate a synthetic optical capture with exact ground truth.

    Writes capture.c3d (first-frame labels plus *N fragments), capture_points.csv
    (un-indexed), summary.json and truth/ (clean markers, fragment and point truth,
    marker surface, motion, animated skin, the rigged body, and corruption.json: where
    --spikes, --swaps and --prop put real-world corruption into capture.c3d; the
    un-indexed capture_points.csv is left as the cameras saw it).

    With --real-markers the body is a real labelled capture (its markers un-indexed in
    capture_points.csv, with the take's own gaps) and the rope, held by the hand
    markers, is simulated by position-based dynamics; there is no skin or motion truth.

    Example: skincap synth --motion jumprope --rope jump --frames 1000 -o take1

    Example: skincap synth --real-markers walk.c3d --rope whip --seconds 4 -o real_whip
    """
    from skincap.workflows.synth_folder import OUTPUT_FILES

    if real_markers is not None:
        _synth_on_real_markers(
            real_markers, output, rope, hands, frames, seconds, noise_mm, seed, force
        )
        return
    from rich.progress import Progress

    from skincap.io.output_safety import guard_outputs
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion
    from skincap.workflows.synth_folder import write_synth_outputs

    motion_file = Path(motion) if motion.lower().endswith(".bvh") else None
    with (
        _user_errors(),
        guard_outputs(
            [motion_file], [output / name for name in OUTPUT_FILES], folders=[output], force=force
        ),
    ):
        if frames is not None and seconds is not None:
            raise FormatError(output, "give --frames or --seconds, not both")
        if frames is not None and frames < 1 or seconds is not None and seconds <= 0:
            raise FormatError(output, "--frames/--seconds must be positive")
        if markers not in ("dense", "sparse") or rope not in ("none", "jump", "whip"):
            raise FormatError(
                output, "--markers must be dense or sparse; --rope none, jump or whip"
            )
        if soft_tissue < 0 or noise_mm < 0:
            raise FormatError(output, "--soft-tissue and --noise-mm must not be negative")
        if spikes < 0 or swaps < 0:
            raise FormatError(output, "--spikes and --swaps must not be negative")
        with Progress(console=err, transient=True, disable=not err.is_terminal) as progress:
            task = progress.add_task("body", total=1.0)

            def report(fraction: float, label: str) -> None:
                progress.update(task, completed=0.1 + 0.8 * fraction, description=label)

            progress.update(task, description=f"{body} body")
            mesh = build_body(body, n_vertices=vertices, seed=seed)
            progress.update(task, completed=0.05, description="motion")
            take = build_motion(
                mesh, motion, frames=frames, seconds=seconds, rate=rate, units=units, seed=seed
            )
            result = generate_capture(
                mesh,
                take,
                markers=markers,  # type: ignore[arg-type]
                rope=rope,  # type: ignore[arg-type]
                bulge=soft_tissue,
                jiggle=soft_tissue,
                breathing=soft_tissue,
                noise_mm=noise_mm,
                seed=seed,
                progress=report,
            )
            corruption = None
            if spikes or swaps or prop:
                from skincap.synth.corrupt import corrupt_capture

                try:
                    result.capture, corruption = corrupt_capture(
                        result.capture, spikes=spikes, swaps=swaps, prop=prop, seed=seed + 1
                    )
                except ValidationError as exc:
                    raise FormatError(output, str(exc)) from None
            progress.update(task, completed=0.9, description="writing")
            output.mkdir(parents=True, exist_ok=True)
            write_synth_outputs(result, output, force=force, corruption=corruption)
    s = result.summary
    out.print(
        f"synth: {s['frames']} frames, {s['markers']} markers + {s['rope_markers']} rope markers -> "
        f"{s['fragments']} fragments, {100 * s['missing_fraction']:.1f}% missing, {s['ghosts']} ghosts; wrote {output}",
        markup=False,
        soft_wrap=True,
    )


def _synth_on_real_markers(
    source: Path,
    output: Path,
    rope: str,
    hands: str | None,
    frames: int | None,
    seconds: float | None,
    noise_mm: float,
    seed: int,
    force: bool,
) -> None:
    """``skincap synth --real-markers``: a PBD rope in a real capture's hands."""
    from skincap.io.output_safety import guard_outputs
    from skincap.synth.real_capture import real_capture_with_rope
    from skincap.types import MarkerSet
    from skincap.workflows.synth_folder import OUTPUT_FILES, write_synth_outputs

    with (
        _user_errors(),
        guard_outputs(
            [source], [output / name for name in OUTPUT_FILES], folders=[output], force=force
        ),
    ):
        if rope not in ("whip", "jump"):
            raise FormatError(output, "--real-markers needs --rope whip or --rope jump")
        if frames is not None and seconds is not None:
            raise FormatError(output, "give --frames or --seconds, not both")
        if frames is not None and frames < 2 or seconds is not None and seconds <= 0:
            raise FormatError(output, "--frames must be at least 2 and --seconds positive")
        if noise_mm < 0:
            raise FormatError(output, "--noise-mm must not be negative")
        markers = _read(source)
        if not isinstance(markers, MarkerSet) or all(
            label.startswith("*") for label in markers.labels
        ):
            raise FormatError(source, "--real-markers needs a capture of labelled markers")
        n = markers.n_frames
        if frames is not None:
            n = min(n, frames)
        elif seconds is not None:
            n = min(n, max(2, int(round(seconds * markers.rate))))
        markers = MarkerSet(
            markers.positions[:n], markers.labels, markers.rate, meta=dict(markers.meta)
        )
        groups = None
        if hands is not None:
            groups = [[n for n in part.split(",") if n.strip()] for part in hands.split(":")]
            if not 1 <= len(groups) <= 2 or not all(groups):
                raise FormatError(output, f"--hands: expected L1,L2[:R1,R2], got {hands!r}")
        try:
            result = real_capture_with_rope(
                markers,
                rope=rope,  # type: ignore[arg-type]
                hands=groups,
                noise_mm=noise_mm,
                seed=seed,
            )
        except ValidationError as exc:
            raise FormatError(source, str(exc)) from None
        result.summary["source"] = source.name
        output.mkdir(parents=True, exist_ok=True)
        write_synth_outputs(result, output, force=force)
    s = result.summary
    out.print(
        f"synth: {s['frames']} frames of {source}, {s['markers']} real markers + "
        f"{s['rope_markers']} rope markers ({s['rope']}, held by "
        f"{' and '.join('+'.join(h) for h in s['hands'])}) -> {s['fragments']} fragments, "
        f"{s['ghosts']} ghosts; wrote {output}",
        markup=False,
        soft_wrap=True,
    )


# --------------------------------------------------------------------------- demo
@app.command()
def demo(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Folder for the demo's outputs.")
    ] = Path("skincap-demo"),
    frames: Annotated[
        int, typer.Option(help="Frames of the synthetic take at 120 Hz (>= 240).")
    ] = 480,
    force: Annotated[
        bool, typer.Option("--force", help="Replace outputs from an earlier run.")
    ] = False,
) -> None:
    """Run the whole chain on data skincap makes and ships, and write report.html.

    Generates a synthetic jump-rope capture with exact truth, cleans it, finds and
    tracks the rope, skins the shipped MakeHuman body with a real CMU walk (DQS),
    converts the shipped real captures, and writes every output plus an HTML report
    (missing-data maps, fill and rope gap-repair errors, artefact table, timings,
    rendered frames). Prints the `skincap view` command that shows the result.

    Example: skincap demo -o demo-out
    """
    from skincap.workflows.demo import run_demo

    with _user_errors():
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        columns = (TextColumn("{task.description:<28}"), BarColumn(), TimeElapsedColumn())
        with Progress(
            *columns, console=err, transient=True, disable=not err.is_terminal
        ) as progress:
            task = progress.add_task("demo", total=1.0)

            def report(fraction: float, label: str) -> None:
                progress.update(task, completed=fraction, description=label)

            result = run_demo(output, force=force, frames=frames, progress=report)
    figures = result["figures"]
    cl, tr = figures["cleanup"], figures["tracking"]
    verdict = figures["fill_verdict"]
    if verdict is None:
        fill_line = "  gap fill: no method filled the punched gaps"
    else:
        # the same targets, and so the same verdict, as the report's red and green marks
        from skincap.workflows.demo_report import FILL_TARGET_MAX, FILL_TARGET_MEAN

        fill_line = (
            f"  gap fill, lowest error: {verdict['method']}, mean {verdict['mean_normalised']:.4f} "
            f"x mean neighbour distance ({verdict['mean_mm']:.2f} mm), max "
            f"{verdict['max_normalised']:.3f}: "
            + ("meets" if verdict["meets_targets"] else "misses")
            + f" the targets (mean <= {FILL_TARGET_MEAN}, max <= {FILL_TARGET_MAX})"
        )
    lines = [
        f"demo: {len(result['outputs'])} files in {output} ({figures['total_seconds']:.0f} s)",
        f"  cleanup: {cl['merged']} fragments merged, {cl['wrongly_merged']} wrongly "
        f"({cl['wrong_rate'] * 100:.2f} %); {cl['invented_samples']} samples filled; "
        f"labelled trajectories {cl['labelled_missing_before'] * 100:.1f} % -> "
        f"{cl['labelled_missing_after'] * 100:.1f} % missing",
        fill_line,
        f"  rope: {tr['rope_markers_found']} markers tracked, rope/body F1 {tr['f1']:.3f}",
        f"  report: {result['report']}",
        "Look at it in the browser (raw against cleaned capture with the rope; the walk):",
        *(f"  {command}" for command in result["view"]),
    ]
    for line in lines:
        out.print(line, markup=False, soft_wrap=True)


# -------------------------------------------------------------------------- bench
def print_bench_results(results: dict[str, Any], json_output: bool) -> None:
    """Print a benchmark's ``lines``, or its measurements as JSON (without the lines)."""
    if json_output:
        print(json.dumps({k: v for k, v in results.items() if k != "lines"}, indent=2, default=str))
        return
    for line in results["lines"]:
        out.print(line, markup=False, soft_wrap=True)


@bench_app.command("io")
def bench_io(
    repeat: Annotated[int, typer.Option(help="Timing repeats (the best is kept).")] = 5,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the measurements as JSON.")
    ] = False,
) -> None:
    """BVH read and FK against bvhio, our C3D read against raw ezc3d, as ratios.

    Example: skincap bench io --repeat 3
    """
    from skincap.evaluate.bench.common import run_io_benchmarks

    with _user_errors():
        results = run_io_benchmarks(repeat=repeat)
    print_bench_results(results, json_output)


@bench_app.command("skin")
def bench_skin(
    vertices: Annotated[int, typer.Option(help="Mesh vertices.")] = 50_000,
    influences: Annotated[int, typer.Option(help="Joints per vertex.")] = 4,
    frames: Annotated[int, typer.Option(help="Frames per timed batch.")] = 64,
    repeat: Annotated[int, typer.Option(help="Timing repeats (the best is kept).")] = 5,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the measurements as JSON.")
    ] = False,
) -> None:
    """LBS and DQS milliseconds per frame (numba and NumPy) against libigl and UsdSkel, as ratios.

    Example: skincap bench skin --vertices 50000 --influences 4
    """
    from skincap.evaluate.bench.skinning import run_skinning_benchmark

    with _user_errors():
        results = run_skinning_benchmark(
            n_vertices=vertices, n_influences=influences, n_frames=frames, repeat=repeat
        )
    print_bench_results(results, json_output)


@bench_app.command("synth")
def bench_synth(
    frames: Annotated[int, typer.Option(help="Frames of the take (120 Hz).")] = 1000,
    vertices: Annotated[int, typer.Option(help="Procedural body vertices.")] = 20_000,
) -> None:
    """Time a dense jump-rope synthetic take stage by stage, against the take's duration.

    Example: skincap bench synth --frames 1000
    """
    from skincap.evaluate.bench.synth import run_synth_benchmark

    with _user_errors():
        results = run_synth_benchmark(frames=frames, vertices=vertices)
    print_bench_results(results, json_output=False)


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds like Ctrl-C so every ``.part`` file is removed."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated(signum)


def install_termination_handlers() -> None:
    """Make SIGTERM and SIGHUP raise :class:`Terminated` (a BaseException).

    Without this Python dies on them at once and a write in progress leaves its
    temporary ``.part`` file; raised as an exception, the signal unwinds through
    :func:`skincap.io._common.atomic_output`, which removes it, as SIGINT does.
    """
    import signal

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), _raise_terminated)


def main() -> None:
    """Console-script entry point."""
    install_termination_handlers()
    try:
        app()
    except KeyboardInterrupt:
        err.print("skincap: interrupted")
        sys.exit(130)
    except Terminated as exc:
        import signal

        err.print(f"skincap: terminated by {signal.Signals(exc.signum).name}")
        sys.exit(128 + exc.signum)
