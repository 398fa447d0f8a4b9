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

A take built on a real capture's markers (``--real-markers``,
:mod:`skincap.synth.real_capture`) has no skin, motion or marker surface: the
marker_surface, motion, mesh and body files are not written.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import OutputExistsError
from skincap.io._common import atomic_output
from skincap.synth.corrupt import CorruptionTruth
from skincap.synth.generate import SynthCapture

__all__ = ["write_synth_outputs", "OUTPUT_FILES"]

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
