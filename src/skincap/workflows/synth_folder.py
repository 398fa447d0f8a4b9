"""Write a generated capture to a folder (``skincap synth``'s output).

This module composes :mod:`skincap.synth` with :mod:`skincap.io` and
its writers (the algorithms themselves never touch files).

Layout of the output folder::

    capture.c3d             labelled first-frame trajectories plus *N fragments
    capture_points.csv      the same capture un-indexed (frame,time,x,y,z,id)
    summary.json            frames, markers, fragments, missing fraction, ghosts, rope…
    truth/markers.c3d       clean labelled positions (rope markers rope_00… along the rope)
    truth/fragments.csv     fragment,truth (a marker label or ghost)
    truth/points.csv        row,frame,truth for every row of capture_points.csv
    truth/marker_surface.ply   triangulation whose vertices are the markers (frame 0)
    truth/motion.bvh        the motion on the body's skeleton
    truth/mesh.obj + truth/mesh.pc2   the skin at rest and animated (metres, Y up)
    truth/body.glb          the body with its rig and weights, and the motion on it:
                            ``skincap skin truth/body.glb truth/motion.bvh --method dqs``
                            gives truth/mesh.pc2 back (soft tissue 0)
    truth/corruption.json   spikes, label swaps and prop markers put into capture.c3d
                            (``--spikes``, ``--swaps``, ``--prop``; empty lists otherwise)
    truth/marker_parts.csv  marker,part: the true near-rigid part of every body marker
                            (:mod:`skincap.synth.marker_parts`)

A take built on a real capture's markers (``--real-markers``,
:mod:`skincap.synth.real_capture`) has no skin, motion or marker surface: the
marker_surface, motion, mesh, body and marker_parts files are not written.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.errors import OutputExistsError, ValidationError
from skincap.io._common import atomic_output
from skincap.synth.corrupt import CorruptionTruth
from skincap.synth.generate import SynthCapture

__all__ = ["synth_folder", "write_synth_outputs", "OUTPUT_FILES"]

OUTPUT_FILES = (
    "capture.c3d",
    "capture_points.csv",
    "summary.json",
    "truth/markers.c3d",
    "truth/fragments.csv",
    "truth/points.csv",
    "truth/marker_surface.ply",
    "truth/motion.bvh",
    "truth/mesh.obj",
    "truth/mesh.pc2",
    "truth/body.glb",
    "truth/corruption.json",
    "truth/marker_parts.csv",
)


def _write_text(path: Path, text: str, force: bool) -> None:
    with atomic_output(path, force=force) as tmp:
        tmp.write_text(text, encoding="utf-8")


def corruption_record(labels: list[str], corruption: CorruptionTruth | None) -> dict[str, Any]:
    """JSON-ready truth of :func:`~skincap.synth.corrupt.corrupt_capture`.

    ``spikes``: ``[frame, label]`` per displaced sample; ``swaps``: the two labels and
    the frames ``[start, end)`` they were exchanged over; ``prop``: the prop's labels.
    """
    if corruption is None:
        return {"spikes": [], "swaps": [], "prop": []}
    frames, columns = np.nonzero(corruption.spikes)
    return {
        "spikes": [[int(f), labels[c]] for f, c in zip(frames, columns, strict=True)],
        "swaps": [
            {"labels": [labels[i], labels[j]], "start": s, "end": e}
            for i, j, s, e in corruption.swaps
        ],
        "prop": [labels[c] for c in corruption.prop],
    }


def write_synth_outputs(
    result: SynthCapture,
    folder: str | os.PathLike[str],
    *,
    force: bool = False,
    corruption: CorruptionTruth | None = None,
) -> list[Path]:
    """Write every file of a generated capture into ``folder``; return their paths.

    Existing outputs are refused before anything is written unless ``force``.
    ``truth/corruption.json`` lists the spikes, label swaps and prop markers put into
    ``capture.c3d`` (:func:`skincap.synth.corrupt.corrupt_capture`); empty lists when
    ``corruption`` is None.
    """
    from skincap.io.bvh import write_bvh
    from skincap.io.c3d import write_c3d
    from skincap.io.csv import write_points_csv
    from skincap.io.gltf.writer import write_glb
    from skincap.io.mesh import write_obj, write_ply
    from skincap.io.pc2 import write_pc2
    from skincap.io.synth_truth import write_marker_parts

    root = Path(folder)
    paths = [root / name for name in OUTPUT_FILES]
    if not force:
        for p in paths:
            if p.exists():
                raise OutputExistsError(p)
    (root / "truth").mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def done(p: Path) -> None:
        written.append(p)

    write_c3d(result.capture, root / "capture.c3d", force=force, units="mm")
    done(root / "capture.c3d")
    write_points_csv(result.points, root / "capture_points.csv", force=force)
    done(root / "capture_points.csv")
    write_c3d(result.truth, root / "truth" / "markers.c3d", force=force, units="mm")
    done(root / "truth" / "markers.c3d")

    rows = "".join(f"{label},{truth}\n" for label, truth in result.fragment_truth.items())
    _write_text(root / "truth" / "fragments.csv", "fragment,truth\n" + rows, force)
    done(root / "truth" / "fragments.csv")

    frame_of_point = result.points.frame_index
    lines = [
        f"{i},{int(f)},{t}\n"
        for i, (f, t) in enumerate(zip(frame_of_point, result.point_truth, strict=True))
    ]
    _write_text(root / "truth" / "points.csv", "row,frame,truth\n" + "".join(lines), force)
    done(root / "truth" / "points.csv")

    if result.marker_surface is not None:
        write_ply(result.marker_surface, root / "truth" / "marker_surface.ply", force=force)
        done(root / "truth" / "marker_surface.ply")
    if result.motion is not None and result.skin is not None:
        write_bvh(result.motion, root / "truth" / "motion.bvh", force=force, units="m")
        done(root / "truth" / "motion.bvh")
        write_obj(result.skin.rest, root / "truth" / "mesh.obj", force=force, units="m", up="y")
        done(root / "truth" / "mesh.obj")
        write_pc2(result.skin, root / "truth" / "mesh.pc2", force=force)
        done(root / "truth" / "mesh.pc2")
        # the rigged body, so the skin can be made again from motion.bvh (the procedural
        # body has no other file with its weights)
        write_glb(result.skin.rest, result.motion, root / "truth" / "body.glb", force=force)
        done(root / "truth" / "body.glb")
    if result.marker_parts is not None:
        body_labels = result.truth.labels[: len(result.marker_parts)]
        write_marker_parts(
            root / "truth" / "marker_parts.csv", body_labels, result.marker_parts, force=force
        )
        done(root / "truth" / "marker_parts.csv")
    _write_text(
        root / "truth" / "corruption.json",
        json.dumps(corruption_record(result.capture.labels, corruption), indent=1) + "\n",
        force,
    )
    done(root / "truth" / "corruption.json")
    _write_text(
        root / "summary.json", json.dumps(_jsonable(result.summary), indent=2) + "\n", force
    )
    done(root / "summary.json")
    return written


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _check_length(frames: int | None, seconds: float | None, *, min_frames: int) -> None:
    """Refuse --frames and --seconds together, or out of range, naming the option."""
    if frames is not None and seconds is not None:
        raise ValidationError("give --frames or --seconds, not both")
    if frames is not None and frames < min_frames:
        raise ValidationError(f"--frames: expected at least {min_frames}, got {frames}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ValidationError(f"--seconds: expected a positive number, got {seconds:g}")


def _check_not_negative(*options: tuple[str, float]) -> None:
    """Refuse a negative or non-finite value of each ``(option, value)``, naming the option."""
    for option, value in options:
        if not (math.isfinite(value) and value >= 0):
            raise ValidationError(f"{option}: expected a finite number >= 0, got {value:g}")


def synth_folder(
    output: str | os.PathLike[str],
    *,
    body: str = "procedural",
    motion: str = "jumprope",
    markers: str = "dense",
    rope: str = "none",
    frames: int | None = None,
    seconds: float | None = None,
    rate: float = 120.0,
    vertices: int = 20_000,
    noise_mm: float = 0.5,
    soft_tissue: float = 1.0,
    units: str | None = None,
    spikes: int = 0,
    swaps: int = 0,
    prop: bool = False,
    seed: int = 0,
    force: bool = False,
    progress: Progress | None = None,
) -> SynthCapture:
    """Generate a synthetic capture with exact ground truth and write it to ``output``.

    Parameters
    ----------
    output : path-like
        The folder (created); its files are :data:`OUTPUT_FILES`.
    body : {"procedural", "makehuman"}
        Swept elliptic sections of ``vertices`` vertices, or the shipped CC0 rig.
    motion : str
        A built-in clip (:func:`skincap.synth.inputs.build_motion`) or a ``.bvh`` file
        (length unit ``units``, guessed when None).
    markers : {"dense", "sparse"}
        About 350 markers (Park & Hodgins) or about 41 landmarks.
    rope : {"none", "jump", "whip"}
    frames, seconds : optional
        Length (at most one); default the clip's 4 s or the whole BVH. ``rate`` (Hz)
        is the capture rate of built-in clips.
    noise_mm, soft_tissue : float
        Gaussian noise of the reconstructed markers (mm) and the scale of bulge,
        jiggle and breathing (0 switches them off).
    spikes, swaps, prop
        Real-world corruption put into ``capture.c3d`` (and recorded in
        ``truth/corruption.json``).
    seed : int
        The same seed gives the same bytes.
    force : bool
        Replace outputs of an earlier run (checked before anything is generated).
    progress : Progress, optional

    Returns
    -------
    SynthCapture
        What was written; ``summary`` holds the figures of ``summary.json``.

    Raises
    ------
    ValidationError
        An option out of range, named as the CLI option, before anything is read
        or written.
    FormatError
        Corruption the take cannot hold.
    """
    from skincap.errors import FormatError
    from skincap.io.output_safety import guard_outputs
    from skincap.synth.body import VERTEX_COUNT_RANGE
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    _check_length(frames, seconds, min_frames=1)
    if markers not in ("dense", "sparse"):
        raise ValidationError(f"--markers: expected dense or sparse, got {markers!r}")
    if rope not in ("none", "jump", "whip"):
        raise ValidationError(f"--rope: expected none, jump or whip, got {rope!r}")
    if body == "procedural":
        low, high = VERTEX_COUNT_RANGE
        if not low <= vertices <= high:
            raise ValidationError(
                f"--vertices: expected {low}..{high} for the procedural body, got {vertices}"
            )
    _check_not_negative(("--soft-tissue", soft_tissue), ("--noise-mm", noise_mm))
    _check_not_negative(("--spikes", spikes), ("--swaps", swaps))
    root = Path(output)
    motion_file = Path(motion) if motion.lower().endswith(".bvh") else None
    report = progress if progress is not None else (lambda fraction, label: None)
    with guard_outputs(
        [motion_file], [root / name for name in OUTPUT_FILES], folders=[root], force=force
    ):
        report(0.0, f"{body} body")
        mesh = build_body(body, n_vertices=vertices, seed=seed)
        report(0.05, "motion")
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
            progress=lambda fraction, label: report(0.1 + 0.8 * fraction, label),
        )
        corruption = None
        if spikes or swaps or prop:
            from skincap.synth.corrupt import corrupt_capture

            try:
                result.capture, corruption = corrupt_capture(
                    result.capture, spikes=spikes, swaps=swaps, prop=prop, seed=seed + 1
                )
            except ValidationError as exc:
                raise FormatError(root, str(exc)) from None
        report(0.9, "writing")
        root.mkdir(parents=True, exist_ok=True)
        write_synth_outputs(result, root, force=force, corruption=corruption)
    return result


def real_rope_folder(
    output: str | os.PathLike[str],
    source: str | os.PathLike[str],
    *,
    rope: str,
    hands: str | None = None,
    frames: int | None = None,
    seconds: float | None = None,
    noise_mm: float = 0.5,
    seed: int = 0,
    force: bool = False,
    progress: Progress | None = None,
) -> SynthCapture:
    """``skincap synth --real-markers``: a PBD rope in a real capture's hands, written out.

    Reads the labelled capture ``source`` (C3D, TRC, CSV), keeps its first ``frames``
    (or ``seconds``), builds the take with
    :func:`skincap.synth.real_capture.real_capture_with_rope` (``hands`` as the CLI
    gives it: ``L1,L2[:R1,R2]``, found by name when None) and writes it with
    :func:`write_synth_outputs` (no skin, motion or marker surface files).

    Raises
    ------
    ValidationError
        An option out of range, named as the CLI option, before anything is read.
    FormatError
        A capture that is not labelled markers, or hands that cannot be found.
    """
    from skincap import io
    from skincap.errors import FormatError
    from skincap.io.output_safety import guard_outputs
    from skincap.synth.real_capture import real_capture_with_rope
    from skincap.types import MarkerSet

    if rope not in ("whip", "jump"):
        raise ValidationError(f"--rope: --real-markers needs whip or jump, got {rope!r}")
    _check_length(frames, seconds, min_frames=2)
    _check_not_negative(("--noise-mm", noise_mm))
    root = Path(output)
    report = progress if progress is not None else (lambda fraction, label: None)
    with guard_outputs(
        [Path(source)], [root / name for name in OUTPUT_FILES], folders=[root], force=force
    ):
        groups = None
        if hands is not None:
            groups = [[n for n in part.split(",") if n.strip()] for part in hands.split(":")]
            if not 1 <= len(groups) <= 2 or not all(groups):
                raise FormatError(root, f"--hands: expected L1,L2[:R1,R2], got {hands!r}")
        report(0.0, "reading")
        markers = io.read(source)
        if not isinstance(markers, MarkerSet) or all(
            label.startswith("*") for label in markers.labels
        ):
            raise FormatError(source, "--real-markers needs a capture of labelled markers")
        n = markers.n_frames
        if frames is not None:
            n = min(n, frames)
        elif seconds is not None:
            n = min(n, max(2, int(round(seconds * markers.rate))))
        markers = MarkerSet(markers.positions[:n], markers.labels, markers.rate, meta=markers.meta)
        try:
            result = real_capture_with_rope(
                markers,
                rope=rope,  # type: ignore[arg-type]
                hands=groups,
                noise_mm=noise_mm,
                seed=seed,
                progress=lambda fraction, label: report(0.05 + 0.85 * fraction, label),
            )
        except ValidationError as exc:
            raise FormatError(source, str(exc)) from None
        result.summary["source"] = Path(source).name
        report(0.9, "writing")
        root.mkdir(parents=True, exist_ok=True)
        write_synth_outputs(result, root, force=force)
    return result
