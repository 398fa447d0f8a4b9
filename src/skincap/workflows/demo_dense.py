"""The demo's dense step: Park & Hodgins' Fig. 7 on the demo's synthetic take, as numbers.

The take's clean body markers (its truth: the comparison is about the deformation,
cleanup is scored in its own section) drive the body it was made on, placed in the
reference pose (frame 0 of the true skin): the rig is segmented on a range-of-motion take
of the same body and markers, as the paper did (``--parts 17``; a jump rope alone barely
moves the shoulders and hips, so parts learnt on it straddle them), and the four variants
plus one global RBF interpolation of the marker displacements are compared with the true
skin on :data:`DENSE_DEMO_FRAMES` frames spread over the take (~20 CPU s).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DENSE_DEMO_FRAMES", "DENSE_DEMO_ROM_FRAMES", "dense_comparison", "rom_markers"]

#: Frames of the take the dense comparison uses (evenly spread).
DENSE_DEMO_FRAMES = 48
#: Frames of the range-of-motion take the parts are learnt on (120 Hz).
DENSE_DEMO_ROM_FRAMES = 240


def rom_markers(body: Any, labels: list[str], *, frames: int = DENSE_DEMO_ROM_FRAMES) -> np.ndarray:
    """The true dense markers of ``body`` going through its range of motion.

    Parameters
    ----------
    body : Mesh
        The skinned body the take was made on (``skincap.synth.inputs.build_body``).
    labels : list of str
        The take's body-marker labels, in its column order.
    frames : int

    Returns
    -------
    (frames, len(labels), 3) float64, metres: the same seed places the same markers.
    """
    from skincap.errors import ValidationError
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_motion

    rom = generate_capture(body, build_motion(body, "rom", frames=frames), markers="dense", seed=0)
    where = {str(label): i for i, label in enumerate(rom.truth.labels)}
    missing = [label for label in labels if label not in where]
    if missing:
        raise ValidationError(f"range of motion: no marker {missing[0]!r} on this body")
    return np.asarray(rom.truth.positions[:, [where[label] for label in labels]], np.float64)


def dense_comparison(
    markers: np.ndarray,
    labels: list[str],
    surface_faces: np.ndarray,
    skin: np.ndarray,
    faces: np.ndarray,
    png: Path,
    *,
    n_frames: int = DENSE_DEMO_FRAMES,
    n_parts: int = 17,
    force: bool = False,
    rom: np.ndarray | None = None,
) -> dict[str, Any]:
    """Build the rig on the take, deform by every variant, score against the true skin.

    Parameters
    ----------
    markers : (T, N, 3) float, metres
        Clean body markers.
    labels : list of N str
    surface_faces : (S, 3) int
        Marker-surface triangles.
    skin : (T, V, 3) float, metres
        The true skin (frame 0: the reference pose).
    faces : (F, 3) int
    png : Path
        Where the error colour maps go.
    n_frames : int
    n_parts : int
    force : bool
    rom : (R, N, 3) float, metres, optional
        A range-of-motion take of the same markers to learn the parts on (default: the
        take itself, as ``skincap animate`` without ``--rom``).

    Returns
    -------
    dict
        ``frames``, ``vertices``, ``parts``, ``rows`` (method, RMS/mean/p95/max in
        metres), ``seconds`` (rig and per-variant deformation), ``png``.
    """
    from skincap.deform.dense.deformer import METHODS
    from skincap.deform.dense.rig import build_dense_rig
    from skincap.evaluate.animate import global_rbf_frames, plot_vertex_errors, vertex_errors

    pick = np.unique(np.linspace(0, markers.shape[0] - 1, n_frames).round().astype(int))
    x = np.asarray(markers, dtype=np.float64)[pick]
    truth = np.asarray(skin, dtype=np.float64)[pick]
    vertices = truth[0]
    t0 = time.perf_counter()
    # the parts are learnt on the range of motion, or the whole take as 'animate' does
    learn = np.asarray(markers if rom is None else rom, dtype=np.float64)
    rig = build_dense_rig(vertices, faces, labels, x[0], surface_faces, learn, n_parts=n_parts)
    seconds: dict[str, float] = {"rig": time.perf_counter() - t0}
    deformer = rig.deformer()
    rows: list[dict[str, Any]] = []
    per_vertex: dict[str, np.ndarray] = {}
    for method in (*METHODS, "global_rbf"):
        t0 = time.perf_counter()
        if method == "global_rbf":
            frames = global_rbf_frames(x[0], x, vertices)
        else:
            frames = np.concatenate(list(deformer.deform(x, method)))  # type: ignore[arg-type]
        seconds[method] = time.perf_counter() - t0
        figures = vertex_errors(frames, truth)
        per_vertex[method] = figures.pop("per_vertex_rms_m")
        rows.append({"method": method, **figures})
    plot_vertex_errors(
        vertices, per_vertex, png, force=force, title="Vertex RMS error against the true skin"
    )
    return {
        "frames": int(pick.size),
        "vertices": int(vertices.shape[0]),
        "markers": len(labels),
        "parts": rig.n_parts,
        "rows": rows,
        "seconds": seconds,
        "png": str(png),
    }
