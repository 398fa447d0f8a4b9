"""``skincap animate`` as a workflow: a body mesh and a dense marker take in, moving skin out.

The dense chain of Park & Hodgins (2006), §5:

1. **Markers.** The take's labelled columns (``*N`` fragments are dropped); a take
   with gaps is filled by ``clean``'s default filler (local PCA) first, with a
   :class:`~skincap.errors.SkincapWarning`.
2. **Rig** (once per subject, :mod:`skincap.deform.dense.rig`): the marker surface
   (``--surface`` or built from the take), the mesh registered to the reference pose
   (``register=True``; otherwise the mesh must already be in that pose), the
   near-rigid parts segmented on the range-of-motion take (``--rom``, default the take
   itself), marker and vertex weights. Or ``--rig`` loads a saved one.
3. **Deformation** (eqs. 6-9), streamed in frame chunks into the writer:

``OUT.pc2`` (+ ``OUT.obj``)
    A point cache and the rest mesh it plays on (Blender's Mesh Cache modifier).
``OUT.usd`` / ``.usda`` / ``.usdc``
    Time-sampled points.
a folder
    One OBJ per frame.

Bad input (a mesh with no triangles, fewer than :data:`MIN_MARKERS` labelled markers,
a rig or a ROM take of another marker set, a range of motion of one frame, an
unregistered mesh farther than :data:`MESH_REFUSE_DISTANCE_M` from the markers,
``--landmarks`` without ``--register``) raises a :class:`FormatError` naming the
file before anything is written; every output goes through a temporary file.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from skincap._arrays import Progress, track_largest_step
from skincap.errors import FormatError, OutputExistsError, SkincapWarning, ValidationError
from skincap.io.mesh_animation_files import animation_output_files, write_mesh_animation

if TYPE_CHECKING:
    from skincap.deform.dense.deformer import Method
    from skincap.deform.dense.rig import DenseRig
    from skincap.types import MarkerSet, Mesh

__all__ = [
    "ANIMATE_OUTPUTS",
    "MESH_REFUSE_DISTANCE_M",
    "MESH_WARN_DISTANCE_M",
    "MIN_MARKERS",
    "MIN_ROM_FRAMES",
    "animate_file",
    "animate_markers",
    "check_animate_options",
    "check_parts",
    "labelled_markers",
    "read_landmarks",
]

#: Output extensions of :func:`animate_file` (an output without one is a folder).
ANIMATE_OUTPUTS = (".pc2", ".usd", ".usda", ".usdc")
#: Fewest labelled markers a dense take needs (17 parts of three markers is 51; below
#: ~30 there is not one well-spread part per limb segment).
MIN_MARKERS = 30
#: Fewest frames of the range of motion the parts are segmented on (one frame shows no
#: motion: every grouping of the markers is as rigid as any other).
MIN_ROM_FRAMES = 2
#: Mean marker-to-mesh distance (m) in the reference frame above which an unregistered
#: mesh is warned about ...
MESH_WARN_DISTANCE_M = 0.05
#: ... and above which it is refused: farther than a limb's girth, no marker can be on
#: the mesh's skin, and the fields extrapolated out there explode.
MESH_REFUSE_DISTANCE_M = 0.15
#: Fastest vertex over fastest marker above which the output is warned about (the
#: markers' speed counted as at least :data:`SPEED_FLOOR_M_S`).
SPEED_WARN_RATIO = 4.0
#: Slowest marker speed (m/s) the vertices are compared with (a walking pace), so a
#: still take's noise is no reason to warn.
SPEED_FLOOR_M_S = 1.0
#: Frames per streamed deformation chunk.
CHUNK_FRAMES = 32
#: The method beyond the paper: a solved skeleton's DQS plus the markers' residuals.
SKELETON_METHOD = "skeleton_rbf"


def labelled_markers(markers: MarkerSet, path: Path) -> MarkerSet:
    """The labelled columns (labels not starting with ``*``) of a take, checked.

    Raises
    ------
    FormatError
        Fewer than :data:`MIN_MARKERS` labelled markers, or none ever seen.
    """
    from skincap.types import MarkerSet

    if not isinstance(markers, MarkerSet):
        raise FormatError(path, "is not a labelled marker capture")
    keep = [i for i, lab in enumerate(markers.labels) if not str(lab).startswith("*")]
    seen = [i for i in keep if np.isfinite(markers.positions[:, i]).any()]
    if len(seen) < MIN_MARKERS:
        raise FormatError(
            path,
            f"{len(seen)} labelled markers; the dense chain needs at least {MIN_MARKERS} "
            "(clean or label the capture first)",
        )
    return markers.select(seen)


def _filled(markers: MarkerSet, path: Path) -> tuple[np.ndarray, int]:
    """Positions with the gaps filled by clean's default filler and kept only where
    clean's continuity guard keeps them; the count filled.

    Unguarded, local PCA filled aml_PronetoRun01's trailing gaps at 30-71 m/s (its
    measured markers never pass 19 m/s), and the body leapt with them; a fill the guard
    cannot make move like the take stays missing, and its part is held.
    """
    from skincap.cleanup.continuity import condition_fills, measured_acceleration_limit
    from skincap.cleanup.fill import fill_gaps
    from skincap.cleanup.guarded import ACCELERATION_FACTOR

    pos = markers.positions
    if not np.isnan(pos).any():
        return pos, 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)  # one warning below says it all
        filled, invented = fill_gaps(markers)
    measured = ~np.isnan(pos[..., 0])
    # at least 1 um/frame^2, as clean: a take that never moves still lets a fill hold still
    limit = max(measured_acceleration_limit(filled, measured, factor=ACCELERATION_FACTOR), 1e-6)
    filled, dropped = condition_fills(filled, invented, limit=limit)
    invented = invented & ~dropped
    left = int(np.isnan(filled[..., 0]).sum())
    warnings.warn(
        f"{path}: the take has gaps; {int(invented.sum())} samples filled by local PCA "
        f"(clean's default) before animating"
        + (f", {left} left missing (their parts are held)" if left else ""),
        SkincapWarning,
        stacklevel=3,
    )
    return filled, int(invented.sum())


def read_landmarks(path: Path, labels: list[str], n_vertices: int) -> dict[str, int]:
    """``--landmarks FILE.json`` (:func:`skincap.io.landmarks_json.read_landmarks`),
    checked against the take's labels and the mesh's vertices."""
    from skincap.io.landmarks_json import read_landmarks as read_landmark_file

    marks = read_landmark_file(path)
    known = set(labels)
    for lab, idx in marks.items():
        if lab not in known:
            raise FormatError(path, f"landmark {lab!r} is not a marker of the take")
        if not 0 <= idx < n_vertices:
            raise FormatError(path, f"landmark {lab!r}: vertex {idx} is not in 0..{n_vertices - 1}")
    return marks


def _output_files(output: Path) -> list[Path]:
    return animation_output_files(output)


def animate_file(
    mesh_path: str | os.PathLike[str] | None,
    markers_path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    rom: str | os.PathLike[str] | None = None,
    method: str = "quadratic_rbf",
    n_parts: int = 17,
    surface: str | os.PathLike[str] | None = None,
    landmarks: str | os.PathLike[str] | None = None,
    reference_frame: int | None = None,
    register: bool = False,
    marker_radius_mm: float = 0.0,
    save_rig: str | os.PathLike[str] | None = None,
    rig: str | os.PathLike[str] | None = None,
    report: str | os.PathLike[str] | None = None,
    mesh_units: str | None = None,
    skeleton_template: str = "auto",
    force: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Build or load the subject rig, deform the mesh by the take, write it; return the summary.

    Parameters
    ----------
    mesh_path : path-like or None
        OBJ/PLY/glTF body (:func:`skincap.io.read_mesh`); ignored (may be None) with ``rig``.
    markers_path : path-like
        A cleaned, labelled take (C3D, TRC, CSV), metres inside.
    output : path-like
        ``.pc2`` (+ ``.obj`` beside it), ``.usd``/``.usda``/``.usdc`` or a folder.
    rom : path-like, optional
        Range-of-motion take the parts are learnt from (default the take itself); it
        must carry every marker of the take.
    method : {"quadratic_rbf", "quadratic", "rigid_rbf", "rigid", "skeleton_rbf"}
        ``skeleton_rbf`` (beyond the paper): a skeleton solved from the markers
        (calibrated on ``rom``), skinned to the mesh with automatic weights, plus one
        interpolation of the markers' residuals (:mod:`skincap.deform.dense.skeleton_rbf`);
        it has no part rig, so ``rig``/``save_rig`` are refused.
    n_parts : int
        Near-rigid parts (the paper's 17).
    surface : path-like, optional
        Marker surface (PLY/OBJ over the markers or an edge CSV); default built from the take.
    landmarks : path-like, optional
        JSON ``{marker label: vertex index}`` for the registration (only with
        ``register``; refused without it rather than ignored).
    reference_frame : int, optional
        The take's frame the mesh matches (default the frame with the most markers).
    register : bool
        Fit the mesh to the reference-pose markers first (§5.1). Without it the mesh
        must already be in the markers' reference pose: a warning above
        :data:`MESH_WARN_DISTANCE_M` mean marker-to-mesh distance, refused above
        :data:`MESH_REFUSE_DISTANCE_M`.
    marker_radius_mm : float
        With ``register``: how far outside the skin the marker centres sit (ball
        radius plus base), millimetres; the surface is fitted that far inside them.
    save_rig, rig : path-like, optional
        Save the rig built here (``.npz`` + ``.json``) / use a saved one instead.
    report : path-like, optional
        JSON report: parts, registration distances, per-frame timing, method.
    mesh_units : str, optional
        Length unit of an OBJ/PLY mesh.
    skeleton_template : str
        With ``skeleton_rbf``: the solve template (``"auto"``, a built-in name or JSON).
    force : bool
        Replace existing outputs.
    progress : callable(fraction, stage), optional

    Returns
    -------
    dict
        The report (also written to ``report``).
    """
    from skincap.io.dense_rig import dense_rig_files
    from skincap.io.output_safety import guard_outputs
    from skincap.workflows.skin_file import mesh_input_files

    check_animate_options(method, n_parts, marker_radius_mm)
    if method == SKELETON_METHOD and (rig is not None or save_rig is not None):
        raise ValidationError(
            "--method skeleton_rbf: --rig/--save-rig hold a part rig; skeleton_rbf solves "
            "its skeleton from each take and keeps no rig (leave them out)"
        )
    markers_path, output = Path(markers_path), Path(output)
    given = {"mesh": mesh_path, "rom": rom, "surface": surface, "landmarks": landmarks,
             "rig": rig, "save_rig": save_rig, "report": report}  # fmt: skip
    paths = {name: None if value is None else Path(value) for name, value in given.items()}
    if rig is not None and save_rig is not None:
        raise FormatError(Path(rig), "give --rig or --save-rig, not both")
    if landmarks is not None and not register:
        # only the registration reads them: without it they would be ignored unchecked
        raise FormatError(
            Path(landmarks), "--landmarks guide --register; add --register or leave them out"
        )
    if rig is None and paths["mesh"] is None:
        raise FormatError(markers_path, "a MESH is needed unless --rig gives the subject's rig")
    ext = output.suffix.lower()
    if ext and ext not in ANIMATE_OUTPUTS:
        raise FormatError(
            output,
            f"cannot write {ext!r}; animate writes {', '.join(ANIMATE_OUTPUTS)} or a folder (OBJ sequence)",
        )
    if not ext and output.is_dir() and any(output.iterdir()) and not force:
        raise OutputExistsError(output)
    outputs = _output_files(output)
    if paths["save_rig"] is not None:
        outputs += list(dense_rig_files(paths["save_rig"]))
    if paths["report"] is not None:
        outputs.append(paths["report"])
    inputs: list[Path | None] = [markers_path, paths["rom"], paths["surface"], paths["landmarks"]]
    if paths["rig"] is not None:
        inputs += list(dense_rig_files(paths["rig"]))
    if paths["mesh"] is not None:
        inputs += mesh_input_files(paths["mesh"])
    with guard_outputs(inputs, outputs, folders=[] if ext else [output], force=force):
        return _animate(
            paths, markers_path, output,
            method=method, n_parts=n_parts, reference_frame=reference_frame,
            register=register, marker_radius_mm=marker_radius_mm, mesh_units=mesh_units,
            skeleton_template=skeleton_template, force=force, progress=progress,
        )  # fmt: skip


def check_animate_options(method: str, n_parts: int, marker_radius_mm: float) -> None:
    """Refuse a bad option before any file is touched, naming the option (not the output)."""
    from skincap.deform.dense.deformer import METHODS

    if method not in (*METHODS, SKELETON_METHOD):
        raise ValidationError(
            f"--method: expected one of {', '.join((*METHODS, SKELETON_METHOD))}, got {method!r}"
        )
    if not 0.0 <= marker_radius_mm <= 50.0:  # NaN fails too
        raise ValidationError(f"--marker-radius: expected 0-50 mm, got {marker_radius_mm}")
    check_parts(n_parts)


def check_parts(n_parts: int) -> None:
    """``--parts`` of ``animate`` and ``eval animate``: 1..200, or a ValidationError."""
    if isinstance(n_parts, bool) or not 1 <= n_parts <= 200:
        raise ValidationError(f"--parts: expected 1..200, got {n_parts}")


def _animate(
    paths: dict[str, Path | None],
    markers_path: Path,
    output: Path,
    *,
    method: str,
    n_parts: int,
    reference_frame: int | None,
    register: bool,
    marker_radius_mm: float,
    mesh_units: str | None,
    skeleton_template: str,
    force: bool,
    progress: Progress | None,
) -> dict[str, Any]:
    from skincap import io
    from skincap.deform.dense.rig import DenseRig

    take = labelled_markers(io.read(markers_path), markers_path)
    positions, filled = _filled(take, markers_path)
    labels = [str(s) for s in take.labels]
    if method == SKELETON_METHOD:
        return _animate_skeleton_rbf(
            paths, markers_path, output, take, positions, filled,
            reference_frame=reference_frame, register=register,
            marker_radius_mm=marker_radius_mm, mesh_units=mesh_units,
            skeleton_template=skeleton_template, force=force, progress=progress,
        )  # fmt: skip
    if paths["rig"] is not None:
        from skincap.io.dense_rig import read_dense_rig

        arrays, rig_labels, settings = read_dense_rig(paths["rig"])
        try:
            subject = DenseRig.from_arrays(arrays, rig_labels, settings)
            deformer = subject.deformer()  # its checks: a bad weight is the rig's fault
            columns = _rig_columns(subject, labels)
        except ValidationError as exc:
            raise FormatError(paths["rig"], str(exc)) from None
        _check_rig_parts_seen(subject, columns, deformer.parts, markers_path)
        rest = _rest_mesh(subject, None)
        build: dict[str, Any] = {"rig": str(paths["rig"])}
    else:
        assert paths["mesh"] is not None  # animate_file checked it
        mesh = io.read_mesh(paths["mesh"], units=mesh_units)
        if mesh.n_faces == 0:
            raise FormatError(paths["mesh"], "the mesh has no faces (triangles are needed)")
        subject, build = _build_rig(
            mesh, take, positions, markers_path, paths, n_parts=n_parts, reference_frame=reference_frame,
            register=register, marker_radius_mm=marker_radius_mm, progress=progress,
        )  # fmt: skip
        columns = np.arange(len(labels))
        rest = _rest_mesh(subject, mesh)
    timing: list[tuple[float, int]] = []
    fastest: list[tuple[float, int]] = []
    frames = _timed_frames(subject, _in_rig_order(positions, columns), method, timing, progress)
    frames = track_largest_step(frames, fastest)
    written = _write_animation(rest, frames, take.n_frames, take.rate, output, force=force)
    if paths["save_rig"] is not None:
        # after the animation, the long and interruptible part: a run stopped there
        # (Ctrl-C, a failed write) left R.npz + R.json and no animation
        from skincap.io.dense_rig import write_dense_rig

        write_dense_rig(
            paths["save_rig"], subject.to_arrays(), list(subject.labels),
            subject.settings, force=force,
        )  # fmt: skip
    return _summary(
        markers_path, paths, written, take, timing, force=force, method=method,
        vertices=int(subject.vertices.shape[0]), markers=subject.n_markers,
        filled_samples=filled, parts=_parts_report(subject), rig=build,
        speed=_speed_check(fastest, take.positions, take.rate, output),
    )  # fmt: skip


def _rig_columns(subject: DenseRig, labels: list[str]) -> np.ndarray:
    """Column of each of the rig's markers in the take (N,) int64, -1 where the take
    lacks it (never labelled, or never seen: :func:`labelled_markers` dropped it).

    A marker lost for a whole take (fallen off) is missing data the deformer already
    handles frame by frame: that rig's other takes were refused as "another marker
    set". A take lacking most of the rig's markers still is (ValidationError).
    """
    where = {lab: i for i, lab in enumerate(labels)}
    columns = np.array([where.get(str(lab), -1) for lab in subject.labels], dtype=np.int64)
    if 2 * int((columns < 0).sum()) > columns.size:
        subject.columns_of(labels)  # raises, naming the markers
    return columns


def _check_rig_parts_seen(
    subject: DenseRig, columns: np.ndarray, parts: Any, markers_path: Path
) -> None:
    """Refuse a take lacking so many of a part's markers that the part cannot be fitted
    in any frame (its vertices would be NaN); warn about the markers it lacks."""
    from skincap.deform.dense.deformer import MIN_PART_MARKERS

    absent = [str(lab) for lab, c in zip(subject.labels, columns, strict=True) if c < 0]
    if not absent:
        return
    shown = ", ".join(absent[:5]) + (" …" if len(absent) > 5 else "")
    # (P, K) members the take has, padding and seam centres out
    have = (columns[parts.members] >= 0) & parts.fitted
    short = np.flatnonzero(have.sum(axis=1) < MIN_PART_MARKERS)
    if short.size:
        raise FormatError(
            markers_path,
            f"lacks {len(absent)} of the rig's {subject.n_markers} markers ({shown}); "
            f"{short.size} of its parts keep fewer than {MIN_PART_MARKERS} of theirs "
            "and could not move",
        )
    warnings.warn(
        f"{markers_path}: lacks {len(absent)} of the rig's {subject.n_markers} markers "
        f"({shown}); their parts move by the others",
        SkincapWarning,
        stacklevel=4,  # at animate_file's caller
    )


def _in_rig_order(positions: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(T, N, 3) the take's positions in the rig's marker order, NaN where ``columns``
    is -1 (a rig marker the take lacks)."""
    out = np.full((positions.shape[0], columns.size, 3), np.nan)
    has = columns >= 0
    out[:, has] = positions[:, columns[has]]
    return out


def _summary(
    markers_path: str | os.PathLike[str],
    paths: dict[str, Path | None],
    written: list[Path],
    take: MarkerSet,
    timing: list[tuple[float, int]],
    *,
    force: bool,
    **rows: Any,
) -> dict[str, Any]:
    """The run's summary (``rows`` in the middle), written to ``--report`` when given."""
    per_frame = (
        np.repeat([t / n for t, n in timing], [n for _, n in timing]) if timing else np.zeros(0)
    )
    summary: dict[str, Any] = {
        "markers_file": str(markers_path),
        "mesh": None if paths["mesh"] is None else str(paths["mesh"]),
        "outputs": [str(p) for p in written],
        "method": rows.pop("method"),
        "frames": int(take.n_frames),
        "rate": float(take.rate),
        **rows,
        "deformation_ms_per_frame": {
            "mean": float(per_frame.mean() * 1e3) if per_frame.size else None,
            "frames": [round(float(x) * 1e3, 4) for x in per_frame],
        },
    }
    if paths["report"] is not None:
        from skincap.io.json_file import write_json

        write_json(paths["report"], summary, force=force, allow_nan=False)
    return summary


def _parts_report(subject: DenseRig) -> dict[str, Any]:
    alpha = subject.marker_weights
    boundary = (alpha > 0).sum(axis=1) > 1
    return {
        "count": subject.n_parts,
        "markers_per_part": [int(c) for c in (alpha > 0).sum(axis=0)],
        "boundary_markers": int(boundary.sum()),
        "settings": subject.settings,
    }


def _rest_mesh(subject: DenseRig, source: Mesh | None) -> Mesh:
    """The mesh the output plays on: the source's polygons and UVs, the rig's vertices."""
    from skincap.types import Mesh

    if source is not None and source.n_vertices == subject.vertices.shape[0]:
        return dataclasses.replace(source, vertices=subject.vertices, skin=None)
    return Mesh(vertices=subject.vertices, faces=subject.faces)


def _stage(progress: Progress | None, label: str) -> Callable[..., None] | None:
    if progress is None:
        return None

    def report(fraction: float, *_: Any) -> None:
        progress(float(fraction), label)

    return report


def _build_rig(
    mesh: Mesh,
    take: MarkerSet,
    positions: np.ndarray,
    markers_path: Path,
    paths: dict[str, Path | None],
    *,
    n_parts: int,
    reference_frame: int | None,
    register: bool,
    marker_radius_mm: float,
    progress: Progress | None,
) -> tuple[DenseRig, dict[str, Any]]:
    from skincap.cleanup.surface import build_marker_surface
    from skincap.deform.dense.rig import build_dense_rig
    from skincap.workflows.clean_file import read_marker_surface

    labels = [str(s) for s in take.labels]
    frame = _reference_frame(positions, reference_frame, markers_path)
    reference = positions[frame]
    # the range of motion is checked first: a take that cannot be segmented is refused
    # before the registration's seconds (and before the mesh is blamed for its pose)
    rom_positions = positions
    if paths["rom"] is not None:
        rom_positions = _read_rom(paths["rom"], labels).positions
    if rom_positions.shape[0] < MIN_ROM_FRAMES:
        n_rom = rom_positions.shape[0]
        raise FormatError(
            paths["rom"] or markers_path,
            f"{n_rom} frame{'' if n_rom == 1 else 's'}; the near-rigid parts are learnt from "
            f"how the markers move, which needs a range of motion of at least {MIN_ROM_FRAMES} "
            "frames (give a longer --rom, or a saved --rig)",
        )
    filled_take = dataclasses.replace(take, positions=positions)
    if paths["surface"] is not None:
        surf = read_marker_surface(paths["surface"], filled_take, frame)
    else:
        surf = build_marker_surface(positions, reference_frame=frame)
    build: dict[str, Any] = {
        "reference_frame": int(frame),
        "surface_triangles": int(surf.faces.shape[0]),
    }
    if surf.faces.shape[0] == 0:
        raise FormatError(paths["surface"] or markers_path, "the marker surface has no triangles")
    vertices = mesh.vertices
    if register:
        vertices, build["registration"] = _register(
            mesh, reference, labels, paths, marker_radius_mm, progress, surf.faces
        )
    build["marker_to_mesh_m"] = _marker_to_mesh(vertices, mesh.faces, reference)
    if not register:
        _check_mesh_in_pose(build["marker_to_mesh_m"]["mean"], paths["mesh"], frame)
    if paths["rom"] is not None:
        build["rom"] = str(paths["rom"])
    subject = build_dense_rig(
        vertices, mesh.faces, labels, reference, surf.faces, rom_positions,
        n_parts=n_parts, settings=dict(build), progress=_stage(progress, "segmentation"),
    )  # fmt: skip
    return subject, build


def _check_mesh_in_pose(mean_m: float, mesh_path: Path | None, frame: int) -> None:
    """Warn when the unregistered mesh lies off the reference-pose markers; refuse when
    it lies so far off that the markers cannot be on its skin.

    Every vertex is carried by the fields of the markers near it in the reference
    pose; a mesh standing elsewhere (a T-pose body under a take that starts crouched or
    lying, a mesh in other units) puts its vertices tens of centimetres outside every
    part, where the quadratic and RBF fields extrapolate: the output explodes (a body
    3-5 m tall moving at hundreds of m/s on real captures) rather than fail.
    """
    if mean_m > MESH_REFUSE_DISTANCE_M:
        raise FormatError(
            mesh_path or Path("MESH"),
            f"the markers are {mean_m * 100:.1f} cm from the mesh on average in reference "
            f"frame {frame} (more than {MESH_REFUSE_DISTANCE_M * 100:.0f} cm: the mesh is not "
            "in the markers' reference pose); add --register to fit it, or choose the "
            "--reference-frame where the subject stands as the mesh does",
        )
    if mean_m > MESH_WARN_DISTANCE_M:
        warnings.warn(
            f"{mesh_path}: the markers are {mean_m * 100:.1f} cm from the mesh on average in "
            f"reference frame {frame}; is the mesh in the markers' reference pose? "
            "(--register fits it)",
            SkincapWarning,
            stacklevel=5,
        )


def _read_rom(path: Path, labels: list[str]) -> MarkerSet:
    """The range-of-motion take in the take's marker order, gaps filled (``labels``: the
    take's; a ROM lacking one is refused, naming the file)."""
    from skincap import io

    rom_take = labelled_markers(io.read(path), path)
    where = {str(lab): i for i, lab in enumerate(rom_take.labels)}
    missing = [lab for lab in labels if lab not in where]
    if missing:
        raise FormatError(
            path,
            f"the range-of-motion take lacks {len(missing)} of the take's {len(labels)} "
            f"markers ({', '.join(missing[:5])}{' …' if len(missing) > 5 else ''})",
        )
    rom_take = rom_take.select([where[lab] for lab in labels])
    filled, _ = _filled(rom_take, path)
    return dataclasses.replace(rom_take, positions=filled)


def _reference_frame(positions: np.ndarray, reference_frame: int | None, path: Path) -> int:
    """The frame the mesh matches (default the one with the most markers), checked."""
    from skincap.cleanup.surface import choose_reference_frame

    frame = choose_reference_frame(positions) if reference_frame is None else reference_frame
    if not 0 <= frame < positions.shape[0]:
        raise FormatError(path, f"--reference-frame {frame} is outside 0..{positions.shape[0] - 1}")
    if not np.isfinite(positions[frame]).all():
        raise FormatError(
            path,
            f"{int((~np.isfinite(positions[frame]).all(1)).sum())} markers are missing in reference "
            f"frame {frame} even after filling; choose another --reference-frame",
        )
    return int(frame)


def _animate_skeleton_rbf(
    paths: dict[str, Path | None],
    markers_path: Path,
    output: Path,
    take: MarkerSet,
    positions: np.ndarray,
    filled: int,
    *,
    reference_frame: int | None,
    register: bool,
    marker_radius_mm: float,
    mesh_units: str | None,
    skeleton_template: str,
    force: bool,
    progress: Progress | None,
) -> dict[str, Any]:
    """``--method skeleton_rbf``: solve the take's skeleton (calibrated on ``--rom``), bind
    the mesh to it in the reference frame, deform by DQS + the markers' residuals."""
    from skincap import io
    from skincap.cleanup.surface import build_marker_surface
    from skincap.deform.dense.skeleton_rbf import build_skeleton_rbf
    from skincap.solve.with_rom import solve_with_range_of_motion

    assert paths["mesh"] is not None  # animate_file checked it
    mesh = io.read_mesh(paths["mesh"], units=mesh_units)
    if mesh.n_faces == 0:
        raise FormatError(paths["mesh"], "the mesh has no faces (triangles are needed)")
    labels = [str(s) for s in take.labels]
    frame = _reference_frame(positions, reference_frame, markers_path)
    reference = positions[frame]
    build: dict[str, Any] = {"reference_frame": frame, "skeleton_template": skeleton_template}
    vertices = mesh.vertices
    if register:
        surf = build_marker_surface(positions, reference_frame=frame)
        vertices, build["registration"] = _register(
            mesh, reference, labels, paths, marker_radius_mm, progress, surf.faces
        )
    build["marker_to_mesh_m"] = _marker_to_mesh(vertices, mesh.faces, reference)
    if not register:
        _check_mesh_in_pose(build["marker_to_mesh_m"]["mean"], paths["mesh"], frame)
    filled_take = dataclasses.replace(take, positions=positions)
    rom = None
    if paths["rom"] is not None:
        rom = _read_rom(paths["rom"], labels)
        build["rom"] = str(paths["rom"])
    try:
        solved = solve_with_range_of_motion(
            filled_take, rom, template=skeleton_template, progress=_stage(progress, "skeleton")
        )
        # skin weights: bone heat corrected by the take's own marker motion
        deformer = build_skeleton_rbf(
            vertices, mesh.faces, reference, solved.motion, frame, positions=positions
        )
    except ValidationError as exc:
        raise FormatError(paths["rom"] or markers_path, str(exc)) from None
    build["skeleton"] = {
        "joints": int(solved.motion.skeleton.n_joints),
        "markers_used": len(solved.model.marker_labels),
        "residual_rms_m": float(np.sqrt(np.nanmean(solved.residuals**2))),
    }
    timing: list[tuple[float, int]] = []
    blocks = deformer.deform(positions, solved.motion, progress=_stage(progress, "deformation"))
    fastest: list[tuple[float, int]] = []
    frames = track_largest_step(_timed(blocks, timing), fastest)
    rest = dataclasses.replace(mesh, vertices=vertices, skin=None)
    written = _write_animation(rest, frames, take.n_frames, take.rate, output, force=force)
    return _summary(
        markers_path, paths, written, take, timing, force=force, method=SKELETON_METHOD,
        vertices=int(vertices.shape[0]), markers=len(labels), filled_samples=filled,
        parts=None, rig=build, speed=_speed_check(fastest, take.positions, take.rate, output, 5),
    )  # fmt: skip


def _timed(blocks: Iterator[np.ndarray], timing: list[tuple[float, int]]) -> Iterator[np.ndarray]:
    """The blocks, each one's wall time and frame count appended to ``timing``."""
    while True:
        start = time.perf_counter()
        try:
            block = next(blocks)
        except StopIteration:
            return
        timing.append((time.perf_counter() - start, int(block.shape[0])))
        yield block


def _speed_check(
    fastest: list[tuple[float, int]],
    positions: np.ndarray,
    rate: float,
    output: Path,
    stacklevel: int = 4,
) -> dict[str, Any]:
    """The fastest vertex and measured marker (m/s; ``positions`` (T, N, 3) metres, the
    take before gap filling, NaN where missing) and a warning when the mesh outruns its
    markers.

    Skin between markers moves with them; a vertex far faster than every marker is one
    a part's fields carry far outside its markers (a mesh not fitted to the reference
    pose, a registration folded onto a lying subject): aml_PronetoRun01 registered on
    its prone first frame moved vertices at 105-316 m/s under markers of 18.6 m/s, while
    takes with a standing reference stay within 1.1-1.7x of their markers.
    """
    marker_step = np.linalg.norm(np.diff(positions, axis=0), axis=-1)  # (T-1, N), NaN gaps
    finite = np.isfinite(marker_step)
    marker_speed = float(marker_step[finite].max()) * rate if finite.any() else None
    if not fastest:
        return {"max_vertex_speed_m_s": None, "max_marker_speed_m_s": marker_speed}
    step, frame = fastest[0]
    vertex_speed = step * rate
    figures = {
        "max_vertex_speed_m_s": vertex_speed,
        "max_vertex_speed_frame": frame,
        "max_marker_speed_m_s": marker_speed,
    }
    # a still take's markers barely move: compare against at least a walking pace
    floor = max(marker_speed or 0.0, SPEED_FLOOR_M_S)
    if vertex_speed > SPEED_WARN_RATIO * floor:
        warnings.warn(
            f"{output}: the mesh moves up to {vertex_speed:.3g} m/s (frame {frame}), "
            f"{vertex_speed / floor:.0f} times the fastest marker ({marker_speed or 0.0:.3g} "
            "m/s): parts of it lie far from the markers that drive them; check the mesh's "
            "fit in the reference frame (the report's marker_to_mesh_m, or a "
            "--reference-frame where the subject stands as the mesh does)",
            SkincapWarning,
            stacklevel=stacklevel,  # at animate_file's caller
        )
    return figures


def _marker_to_mesh(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> dict[str, float]:
    """Distance from every marker to the mesh surface: mean, p95, max (metres)."""
    from skincap.geometry.raycast import closest_points_on_mesh

    d, _, _ = closest_points_on_mesh(vertices, faces, points)
    return {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max())}


def _register(
    mesh: Mesh,
    reference: np.ndarray,
    labels: list[str],
    paths: dict[str, Path | None],
    marker_radius_mm: float,
    progress: Progress | None,
    marker_faces: np.ndarray,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Fit the mesh to the reference pose (§5.1) and the marker surface ``marker_faces``
    (G, 3): registered vertices and the figures."""
    from skincap.deform.dense.registration import RegistrationSettings, register_mesh

    marks = None
    if paths["landmarks"] is not None:
        marks = read_landmarks(paths["landmarks"], labels, mesh.n_vertices)
    try:
        result = register_mesh(
            mesh.vertices, mesh.faces, reference, labels, landmarks=marks,
            marker_faces=marker_faces,
            settings=RegistrationSettings(marker_radius=marker_radius_mm / 1000.0),
            progress=_stage(progress, "registration"),
        )  # fmt: skip
    except ValidationError as exc:
        raise FormatError(paths["landmarks"] or paths["mesh"] or Path("MESH"), str(exc)) from None
    d = np.asarray(result.marker_distance, dtype=np.float64)
    figures = {
        "landmarks": len(result.landmarks),
        "iterations": int(result.iterations),
        "marker_distance_mean_m": float(np.nanmean(d)),
        "marker_distance_p95_m": float(np.nanpercentile(d, 95)),
        "marker_distance_max_m": float(np.nanmax(d)),
    }
    return np.asarray(result.vertices, dtype=np.float64), figures


def _timed_frames(
    subject: DenseRig,
    positions: np.ndarray,
    method: str,
    timing: list[tuple[float, int]],
    progress: Progress | None,
) -> Iterator[np.ndarray]:
    """The deformer's chunks, each one's wall time and frame count appended to ``timing``."""
    blocks = subject.deformer().deform(
        positions,
        cast("Method", method),  # checked against METHODS by check_animate_options
        chunk=CHUNK_FRAMES,
        progress=_stage(progress, "deformation"),
    )
    return _timed(blocks, timing)


def _write_animation(
    rest: Mesh,
    frames: Iterator[np.ndarray],
    n_frames: int,
    rate: float,
    output: Path,
    *,
    force: bool,
) -> list[Path]:
    from skincap.types import MeshAnimation

    animation = MeshAnimation(rest=rest, frames=frames, rate=rate, n_frames=n_frames)
    return write_mesh_animation(animation, output, force=force)


def animate_markers(
    subject: DenseRig,
    positions: np.ndarray,
    method: str = "quadratic_rbf",
    *,
    chunk: int = CHUNK_FRAMES,
) -> np.ndarray:
    """All deformed frames of a (short) take in memory: the API's one-call form.

    Parameters
    ----------
    subject : DenseRig
    positions : (T, N, 3) float, metres, in the rig's marker order, NaN where missing
    method : str

    Returns
    -------
    (T, V, 3) float64, metres
    """
    blocks = list(subject.deformer().deform(positions, cast("Method", method), chunk=chunk))
    return np.concatenate(blocks) if blocks else np.zeros((0, subject.vertices.shape[0], 3))
