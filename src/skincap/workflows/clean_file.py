"""``skincap clean`` as a workflow: a capture in, a cleaned C3D (and a JSON report) out.

Also the reader of a user's marker surface (``--surface``): a PLY/OBJ whose vertices
are the labelled markers, or an edge-list CSV of label pairs. This module composes
:mod:`skincap.cleanup` with :mod:`skincap.io`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skincap._arrays import Progress
from skincap.errors import FormatError, ValidationError

if TYPE_CHECKING:
    from skincap.cleanup.surface import MarkerSurface
    from skincap.types import MarkerSet

__all__ = ["check_clean_options", "clean_file", "clean_summary", "read_marker_surface"]

#: Most smoothing iterations ``clean --iterations`` takes.
MAX_SMOOTH_ITERATIONS = 1000


def read_marker_surface(
    path: str | os.PathLike[str], markers: MarkerSet, reference_frame: int | None
) -> MarkerSurface:
    """A user marker surface over the labelled columns: PLY/OBJ triangles or an edge CSV.

    Mesh vertices are matched to the labelled markers by order when the counts agree,
    else each vertex to the nearest labelled marker in the reference frame (each
    marker at most once, within 5 cm). An edge CSV names the markers by label
    (:func:`skincap.io.edge_csv.read_edge_csv`).

    Parameters
    ----------
    path : path-like
        ``.ply``, ``.obj`` or ``.csv``.
    markers : MarkerSet
        The capture; its labelled columns (labels not starting with ``*``) in column
        order are the surface's markers.
    reference_frame : int, optional
        The frame whose positions match the vertices; default the frame with the most
        labelled markers (:func:`skincap.cleanup.surface.choose_reference_frame`).

    Raises
    ------
    FormatError
        No labelled markers, a reference frame out of range, another extension, not a
        mesh, or vertices that match no marker one to one.
    """
    from scipy.spatial import cKDTree

    from skincap import io
    from skincap.cleanup.surface import (
        choose_reference_frame,
        surface_from_edges,
        surface_from_faces,
    )
    from skincap.io.edge_csv import read_edge_csv

    path = Path(path)
    labelled = [i for i, lab in enumerate(markers.labels) if not str(lab).startswith("*")]
    if not labelled:
        raise FormatError(path, "the capture has no labelled markers to put a surface on")
    pos = markers.positions[:, labelled]
    frame = choose_reference_frame(pos) if reference_frame is None else reference_frame
    if not 0 <= frame < markers.n_frames:
        raise FormatError(path, f"--reference-frame {frame} is outside 0..{markers.n_frames - 1}")
    ref = pos[frame]
    ext = path.suffix.lower()
    if ext == ".csv":
        labels = [str(markers.labels[i]) for i in labelled]
        return surface_from_edges(read_edge_csv(path, labels), ref, reference_frame=frame)
    if ext not in (".ply", ".obj"):
        raise FormatError(path, f"a surface is a .ply, .obj or edge-list .csv, not {ext!r}")
    mesh = io.read(path)
    if not hasattr(mesh, "faces"):
        raise FormatError(path, "not a mesh")
    if mesh.n_vertices == len(labelled):
        vertex_to_marker = np.arange(mesh.n_vertices)
    else:
        ok = np.isfinite(ref).all(axis=1)
        if ok.sum() < mesh.n_vertices:
            raise FormatError(
                path,
                f"{mesh.n_vertices} vertices but only {int(ok.sum())} labelled markers "
                f"in reference frame {frame}",
            )
        rows = np.flatnonzero(ok)
        dist, near = cKDTree(ref[rows]).query(mesh.vertices)
        vertex_to_marker = rows[near]
        if np.unique(vertex_to_marker).size != vertex_to_marker.size or np.any(dist > 0.05):
            raise FormatError(
                path,
                "surface vertices do not match the markers one to one (by order or within "
                f"5 cm in reference frame {frame})",
            )
    faces = vertex_to_marker[mesh.faces]
    return surface_from_faces(faces, ref, reference_frame=frame)


def check_clean_options(
    method: str, rigid_blend: float | None, smooth: bool, iterations: int
) -> None:
    """Refuse :func:`clean_file`'s options that need no file read, naming the option.

    Raises
    ------
    ValidationError, FormatError
        An unknown fill method, a rigid blend outside [0, 1], smoothing iterations
        outside 1..:data:`MAX_SMOOTH_ITERATIONS`.
    """
    from skincap.cleanup.methods import FILL_METHODS

    if method not in FILL_METHODS:
        raise ValidationError(
            f"--method: expected one of {', '.join(FILL_METHODS)}, got {method!r}"
        )
    if rigid_blend is not None and not 0.0 <= rigid_blend <= 1.0:
        raise FormatError("--rigid-blend", f"expected a weight in [0, 1], got {rigid_blend}")
    if smooth and not 1 <= iterations <= MAX_SMOOTH_ITERATIONS:
        # 1000 cost 0.7 s more than 10 on a 240-frame, 41-marker take; a billion never end
        raise ValidationError(
            f"--iterations: expected 1..{MAX_SMOOTH_ITERATIONS}, got {iterations}"
        )


def _no_markers_reason(markers: MarkerSet) -> str:
    """Why a capture with no marker columns cannot be cleaned, naming what it holds."""
    groups = markers.meta.get("model_outputs") or {}  # {group: {label: (T, 3)}}
    held = ", ".join(f"{len(series)} {group}" for group, series in dict(groups).items() if series)
    return "holds no marker trajectories to clean" + (
        f" (only model outputs: {held})" if held else ""
    )


def clean_file(
    src: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    method: str = "local_pca",
    rigid_blend: float | None = None,
    reference_frame: int | None = None,
    surface: str | os.PathLike[str] | None = None,
    smooth: bool = True,
    lam: float = 0.02,
    iterations: int = 10,
    report: str | os.PathLike[str] | None = None,
    fragment_truth: str | os.PathLike[str] | None = None,
    recover_hidden: bool = True,
    force: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Clean the capture ``src`` into the C3D ``output``; return the clean report.

    Parameters
    ----------
    src : path-like
        Capture (``.c3d``/``.trc``/``.csv``): labelled markers and ``*N`` fragments.
    output : path-like
        The cleaned ``.c3d``.
    method, rigid_blend, reference_frame, smooth, lam, iterations, recover_hidden
        The CLI's options, checked here with its error lines, then passed on as a
        :class:`~skincap.cleanup.settings.CleanSettings`.
    surface : path-like, optional
        A user marker surface (:func:`read_marker_surface`).
    report : path-like, optional
        Also write the returned report there as JSON.
    fragment_truth : path-like, optional
        ``fragment,truth`` CSV (:func:`skincap.io.synth_truth.read_fragment_truth`):
        the report then counts wrong merges.
    force : bool
        Replace existing outputs (checked, with the inputs, before anything is read).
    progress : Progress, optional

    Returns
    -------
    dict
        :func:`~skincap.cleanup.pipeline.clean_markers`' report as a dict
        (:meth:`~skincap.cleanup.report.CleanReport.as_dict`) with ``input`` and ``output`` added.
    """
    from skincap import io
    from skincap.cleanup.pipeline import clean_markers
    from skincap.cleanup.settings import CleanSettings, FillSettings, SmoothSettings
    from skincap.io.json_file import write_json
    from skincap.io.output_safety import guard_outputs
    from skincap.io.synth_truth import read_fragment_truth
    from skincap.types import MarkerSet

    src, output = Path(src), Path(output)
    inputs = [src, surface, fragment_truth]
    outputs = [output] if report is None else [output, report]
    # options first, before any file is touched, named as the option (not the output)
    check_clean_options(method, rigid_blend, smooth, iterations)
    with guard_outputs(inputs, outputs, force=force):
        if output.suffix.lower() != ".c3d":
            raise FormatError(output, "the cleaned capture is written as .c3d")
        markers = io.read(src)
        if not isinstance(markers, MarkerSet):
            raise FormatError(src, "not a marker capture (labelled trajectories)")
        if markers.n_frames == 0:
            raise FormatError(src, "no frames")
        if markers.n_markers == 0:
            # e.g. a Vicon analysis file: model outputs (angles, forces) and analogs only
            raise FormatError(src, _no_markers_reason(markers))
        if reference_frame is not None and not 0 <= reference_frame < markers.n_frames:
            raise FormatError(
                src, f"--reference-frame {reference_frame} is outside 0..{markers.n_frames - 1}"
            )
        user_surface = (
            None if surface is None else read_marker_surface(surface, markers, reference_frame)
        )
        truth = None if fragment_truth is None else read_fragment_truth(fragment_truth)
        settings = CleanSettings(
            reference_frame=reference_frame,
            recover_hidden=recover_hidden,
            fill=FillSettings(method=method, rigid_blend=rigid_blend),
            smooth=SmoothSettings(enabled=smooth, lam=lam, iterations=iterations),
        )
        cleaned, clean_report = clean_markers(
            markers, settings, surface=user_surface, fragment_truth=truth, progress=progress
        )
        summary = clean_report.as_dict()
        summary["input"] = str(src)
        summary["output"] = str(output)
        io.write(cleaned, output, force=force)
        if report is not None:
            write_json(report, summary, force=force)
        return summary


def clean_summary(report: dict[str, Any]) -> dict[str, Any]:
    """The figures of ``clean``'s summary line, as a dict (what ``--json`` prints)."""
    merge, guard = report["merge"], report["guard"]
    return {
        "input": report["input"],
        "output": report["output"],
        "frames": report["frames"],
        "trajectories_before": merge["trajectories_before"],
        "trajectories_after": merge["trajectories_after"],
        "fragments_merged": merge["merged"],
        "filled_samples": guard["filled_samples"],
        "unfilled_samples": guard["unfilled_samples"],
        "unfilled_warning": guard["unfilled_warning"],
        "outlier_samples": guard["outlier_samples"],
        "outliers_replaced": guard["outliers_replaced"],
        "relabelled_fragments": guard["relabelled_fragments"],
        "label_swaps_repaired": guard["label_swaps_repaired"],
        "largest_move_mm": guard["largest_move_mm"],
        "hidden_markers_labelled": report["hidden"]["new_markers"],
        "wrongly_merged": merge["wrongly_merged"],
    }
