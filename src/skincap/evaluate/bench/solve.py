"""Benchmark behind ``skincap bench solve``: inverse-kinematics speed and a one-minute take.

Ratios measured in one run:

* the batched Levenberg-Marquardt IK (:func:`skincap.solve.ik.solve_poses`) against
  the same least-squares problem solved frame by frame with SciPy's
  ``least_squares`` (the per-frame loop a straightforward solver runs), on the same
  frames and start poses;
* the whole C3D -> BVH solve (read, calibrate, IK, write) of a one-minute 120 Hz take
  against the take's own duration.

The 41-marker take is a labelled synthetic sparse take made in memory (or any
labelled capture given); the one-minute take plays it forwards and backwards
(no jump at the joins) until it lasts 60 s.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from skincap.evaluate.solve import ik_frames_per_second
from skincap.io import read, write
from skincap.solve import solve_markers
from skincap.solve.ik import model_markers
from skincap.types import MarkerSet

__all__ = ["run_solve_benchmark", "per_frame_reference", "one_minute"]


def per_frame_reference(model: Any, measured: np.ndarray, frames: np.ndarray) -> float:
    """Seconds to solve ``frames`` one by one with ``scipy.optimize.least_squares``."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    s = model.n_segments
    # The link segments' springs (``solve.ik``): the same residuals, so both solve one problem
    # (without them a link's rotation is free and least_squares runs to its evaluation limit).
    stiffness = np.asarray(getattr(model, "link_stiffness", np.zeros(s)), dtype=np.float64)
    links = np.flatnonzero(stiffness > 0)
    link_parents = np.asarray(model.segment_parents)[links]
    start = time.perf_counter()
    for t in frames:
        y = measured[t]
        seen = np.isfinite(y).all(axis=1)
        r0 = model.init_rotations[t]
        r0 = np.where(np.isfinite(r0), r0, np.eye(3))
        x0 = np.concatenate([np.nan_to_num(model.init_origins[t]), np.zeros(3 * s)])

        def resid(x: np.ndarray, y=y, seen=seen, r0=r0) -> np.ndarray:
            rot = Rotation.from_rotvec(x[3:].reshape(s, 3)).as_matrix() @ r0
            pos = model_markers(
                model.segment_parents, model.joint_offsets, model.marker_segments,
                model.marker_offsets, rot[None], x[None, :3],
            )[0]  # fmt: skip
            res = (pos - y)[seen].ravel()
            if links.size == 0:
                return res
            rel = rot[links] @ rot[link_parents].transpose(0, 2, 1)
            springs = stiffness[links, None] * Rotation.from_matrix(rel).as_rotvec()
            return np.concatenate([res, springs.ravel()])

        least_squares(resid, x0, method="lm")
    return time.perf_counter() - start


def one_minute(markers: MarkerSet, seconds: float = 60.0) -> MarkerSet:
    """``markers`` played forwards and backwards until it lasts ``seconds``."""
    pingpong = np.concatenate([markers.positions, markers.positions[::-1]], axis=0)
    n = int(round(seconds * markers.rate))
    reps = int(np.ceil(n / pingpong.shape[0]))
    pos = np.tile(pingpong, (reps, 1, 1))[:n]
    return MarkerSet(pos, list(markers.labels), markers.rate, meta={"source_units": "mm"})


def run_solve_benchmark(
    markers: MarkerSet,
    *,
    template: str = "synth-sparse",
    reference_frames: int = 8,
    repeat: int = 3,
    long_take_seconds: float = 60.0,
) -> dict[str, Any]:
    """Time the IK against a per-frame SciPy loop, and a one-minute C3D -> BVH solve.

    Returns
    -------
    dict with ``ik_frames_per_second`` (wall and CPU), ``speedup_vs_per_frame``,
    ``one_minute`` (seconds, and the ratio to the take's duration) and ``lines``.
    """
    result = solve_markers(markers, template)
    model = result.model
    measured = markers.positions[:, model.marker_columns]
    fps = ik_frames_per_second(result, markers, repeat=repeat)
    wall, cpu = markers.n_frames / fps["wall"], markers.n_frames / fps["cpu"]
    frames = np.linspace(0, markers.n_frames - 1, min(reference_frames, markers.n_frames)).astype(
        int
    )
    ref = per_frame_reference(model, measured, frames) / frames.size  # s per frame
    ours = wall / markers.n_frames
    take = one_minute(markers, long_take_seconds)
    with tempfile.TemporaryDirectory() as tmp:
        c3d = Path(tmp) / "minute.c3d"
        write(take, c3d)
        w0, c0 = time.perf_counter(), time.process_time()
        whole = solve_markers(read(c3d), template)
        write(whole.motion, Path(tmp) / "minute.bvh", units="cm")
        whole_wall, whole_cpu = time.perf_counter() - w0, time.process_time() - c0
        rms = whole.report()["overall"]["rms_m"]
    duration = take.n_frames / take.rate
    lines = [
        f"solve: {len(model.marker_labels)} markers, {model.n_segments} segments, {markers.n_frames} frames",
        f"  IK {markers.n_frames / wall:,.0f} frames/s wall, {markers.n_frames / cpu:,.0f} frames/s CPU "
        f"per pass (goal >= 2,000; {fps['backend']}); {ref / ours:.0f}x SciPy least_squares frame by frame "
        f"({frames.size} frames, same starts)",
        f"  a solve's IK: {fps['passes']} passes over all frames, {fps['solve_wall']:,.0f} frames/s wall, "
        f"{fps['solve_cpu']:,.0f} frames/s CPU",
        f"  {duration:g}-second take ({take.n_frames} frames at {take.rate:g} Hz) C3D -> BVH: {whole_wall:.1f} s wall, "
        f"{whole_cpu:.1f} s CPU = {duration / whole_wall:.1f}x real time; RMS residual {rms * 100:.2f} cm",
    ]
    return {
        "ik_frames_per_second": fps,
        "speedup_vs_per_frame": ref / ours,
        "one_minute": {
            "frames": take.n_frames,
            "wall_s": whole_wall,
            "cpu_s": whole_cpu,
            "real_time_ratio": duration / whole_wall,
        },  # fmt: skip
        "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "lines": lines,
    }
