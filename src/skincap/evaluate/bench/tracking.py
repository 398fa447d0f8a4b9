"""``skincap bench track``: rope-tracking speed against real time and a naive tracker.

The take is an analytic jump-rope scene built in memory (no synthetic-capture run,
so the benchmark starts at once): a rope of tape markers hanging still for half a
second, then turning around a body of a few hundred markers, at 120 Hz, with 0.5 mm
noise, ghosts and dropped points — about 400 points per frame. Three numbers come
out of one run:

* frames per second of :func:`~skincap.tracking.tracker.track_rope` (initialisation
  included) and its ratio to real time (the target: at least 100×), with the compiled
  kernel (numba, a core dependency) and with the NumPy reference, which must take
  the same points;
* the same for a naive baseline measured in the same process: greedy nearest
  neighbour with constant-velocity prediction, a brute-force distance matrix per
  frame instead of a KD-tree, conflicts resolved greedily, no gap model, the same γ
  as the tracker's initialisation;
* both trackers' mean error against the scene's exact rope, so speed is not bought
  with accuracy;
* the first call in a fresh process, cold and warm numba cache (the first run of
  a fresh install, and every later one).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from skincap.synth.scenes import jump_rope_scene
from skincap.types import PointCloud

__all__ = ["track_greedy_nearest", "run_track_benchmark"]


def track_greedy_nearest(
    cloud: PointCloud, first: np.ndarray, *, gamma: float = 0.03
) -> tuple[np.ndarray, np.ndarray]:
    """The naive baseline: greedy nearest neighbour, constant velocity, no KD-tree.

    Every frame the traces' predicted positions (last position + last velocity) are
    compared with all of the frame's points (a full distance matrix); pairs are taken
    nearest first, each trace and point at most once, within ``gamma``. A trace that
    finds nothing keeps its prediction (invented).

    Parameters
    ----------
    cloud : PointCloud
    first : (K,) int
        Indices of the traced points among frame 0's points.
    gamma : float, metres

    Returns
    -------
    positions : (T, K, 3) float64, metres (never NaN)
    invented : (T, K) bool
    """
    first = np.asarray(first, dtype=np.int64)
    t_count, k = cloud.n_frames, first.size
    pos = np.zeros((t_count, k, 3))
    inv = np.zeros((t_count, k), dtype=bool)
    pos[0] = cloud.frame(0)[first]
    vel = np.zeros((k, 3))
    for t in range(1, t_count):
        pred = pos[t - 1] + vel
        pts = cloud.frame(t)
        cur = pred.copy()
        found = np.zeros(k, dtype=bool)
        if pts.shape[0]:
            d = np.sqrt(((pred[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2))  # (K, n)
            pairs = np.argsort(d, axis=None)
            pairs = pairs[d.ravel()[pairs] < gamma]
            used = np.zeros(pts.shape[0], dtype=bool)
            for flat in pairs:
                i, j = divmod(int(flat), pts.shape[0])
                if found[i] or used[j]:
                    continue
                found[i] = used[j] = True
                cur[i] = pts[j]
        pos[t] = cur
        inv[t] = ~found
        vel = np.where(found[:, None], pos[t] - pos[t - 1], vel)
    return pos, inv


def run_track_benchmark(
    *,
    frames: int = 1200,
    points_per_frame: int = 400,
    rope_markers: int = 24,
    rate: float = 120.0,
    repeat: int = 3,
    seed: int = 0,
    backend: str = "auto",
    first_call: bool = True,
) -> dict[str, Any]:
    """Time ``track_rope`` against real time and the naive baseline on one scene.

    Parameters
    ----------
    frames, points_per_frame, rope_markers, rate, seed
        The scene (:func:`jump_rope_scene`).
    repeat : int
        Timing repeats; the best is kept.
    backend : {"auto", "numba", "numpy"}
        The tracker timed as ``track_*`` (:func:`~skincap.tracking.tracker.track_rope`;
        ``auto`` times the compiled kernel, compiling it here first if needed, as
        every run after the first meets it); the NumPy reference is timed as well
        (``numpy_*``).
    first_call : bool, default True
        Also time the first call as a user meets it: a fresh Python process
        importing skincap and tracking the scene once with the default backend,
        with a cold numba cache and with a warm one
        (:func:`skincap.evaluate.bench.common.first_call_in_fresh_process`).

    Returns
    -------
    dict
        ``frames``, ``rate``, ``points_per_frame`` (measured mean), ``track_s`` and
        ``baseline_s`` (best seconds), ``track_fps``, ``baseline_fps``,
        ``track_realtime`` and ``baseline_realtime`` (× real time), ``track_cpu_s`` and
        ``track_realtime_cpu`` (CPU seconds of one run and the take's duration over
        them: the figure a loaded machine distorts least), ``speedup`` (ours
        vs the baseline), ``track_error_m`` / ``baseline_error_m`` (mean distance to
        the exact rope over all frames and markers), ``target_realtime`` (100),
        ``backend`` (the one timed as ``track``), ``numpy_s``, ``numpy_fps``,
        ``numpy_realtime``, ``speedup_vs_numpy`` (the NumPy reference, timed once
        per repeat too), ``same_as_numpy`` (both took the same points and invented the
        same markers), ``first_call`` (``cold_s``, ``warm_s``, ``cold_cpu_s``,
        ``warm_cpu_s``, seconds of import plus first call, or None when not
        measured), ``default_backend`` (what ``backend="auto"`` runs once its kernel
        is compiled), ``lines`` (text to print).
    """
    from skincap.backends import numba_available
    from skincap.tracking.tracker import _resolve_backend

    cloud, rope, first = jump_rope_scene(
        frames=frames, rate=rate, points_per_frame=points_per_frame,
        rope_markers=rope_markers, seed=seed,
    )  # fmt: skip

    # steady state: "auto" is the compiled kernel once it is in the cache
    used = _resolve_backend("numba" if backend == "auto" and numba_available() else backend)
    default_backend = "numba" if numba_available() else "numpy"

    track, ref, base_pos, (track_s, track_cpu_s, ref_s, base_s) = _time_trackers(
        cloud, first, used, repeat
    )
    same = _same_tracks(track, ref)

    first_call_s = (
        _first_call_of_scene(frames, rate, points_per_frame, rope_markers, seed)
        if first_call
        else None
    )
    track_err, base_err = _mean_errors(track, base_pos, rope)
    duration = frames / rate
    result: dict[str, Any] = {
        "frames": frames,
        "rate": rate,
        "points_per_frame": float(cloud.counts.mean()),
        "rope_markers": rope_markers,
        "repeat": repeat,
        "track_s": track_s,
        "baseline_s": base_s,
        "track_fps": frames / track_s,
        "baseline_fps": frames / base_s,
        "track_realtime": duration / track_s,
        "track_cpu_s": track_cpu_s,
        "track_realtime_cpu": duration / track_cpu_s,
        "baseline_realtime": duration / base_s,
        "speedup": base_s / track_s,
        "track_error_m": track_err,
        "baseline_error_m": base_err,
        "target_realtime": 100.0,
        "backend": used,
        "numpy_s": ref_s,
        "numpy_fps": frames / ref_s,
        "numpy_realtime": duration / ref_s,
        "speedup_vs_numpy": ref_s / track_s,
        "same_as_numpy": same,
        "first_call": first_call_s,
        "default_backend": default_backend,
    }
    result["lines"] = _summary_lines(result)
    return result


def _time_trackers(
    cloud: Any, first: np.ndarray, used: str, repeat: int
) -> tuple[Any, Any, np.ndarray, tuple[float, float, float, float]]:
    """Track the scene with ``used``, the NumPy reference and the naive baseline, then time them.

    Returns our track, the reference's, the baseline's (T, M, 3) positions and the
    seconds ``(track_s, track_cpu_s, numpy_s, baseline_s)``: best wall time of
    ``repeat`` runs each, and the CPU time of one run of ours.
    """
    from skincap.evaluate.bench.common import best_time
    from skincap.tracking.init import init_rope
    from skincap.tracking.tracker import track_rope

    def ours() -> Any:
        return track_rope(cloud, init_rope(cloud, markers=first), backend=used)

    def reference() -> Any:
        return track_rope(cloud, init_rope(cloud, markers=first), backend="numpy")

    gamma = init_rope(cloud, markers=first).gamma  # the same γ for both trackers

    def naive() -> Any:
        return track_greedy_nearest(cloud, first, gamma=gamma)

    track = ours()  # compiles the kernel (or loads it from numba's cache)
    ref = reference()
    base_pos, _ = naive()
    track_s = best_time(ours, repeat)
    # CPU seconds of one run (the tracker is one thread): what a loaded machine distorts least
    cpu0 = time.process_time()
    ours()
    track_cpu_s = time.process_time() - cpu0
    ref_s = track_s if used == "numpy" else best_time(reference, repeat)
    base_s = best_time(naive, max(1, repeat))
    return track, ref, base_pos, (track_s, track_cpu_s, ref_s, base_s)


def _first_call_of_scene(
    frames: int, rate: float, points_per_frame: int, rope_markers: int, seed: int
) -> dict[str, float]:
    """Import plus one ``track_rope`` of the scene with the default backend, in a fresh
    process, with a cold and a warm numba cache (seconds, wall and CPU)."""
    from skincap.evaluate.bench.common import first_call_in_fresh_process

    return first_call_in_fresh_process(
        "from skincap.tracking.init import init_rope\n"
        "from skincap.tracking.tracker import track_rope",
        "from skincap.synth.scenes import jump_rope_scene\n"
        f"cloud, _, first = jump_rope_scene(frames={frames}, rate={rate!r}, "
        f"points_per_frame={points_per_frame}, rope_markers={rope_markers}, seed={seed})",
        "track_rope(cloud, init_rope(cloud, markers=first))",
    )


def _same_tracks(a: Any, b: Any) -> bool:
    """Both trackers took the same points and invented the same markers."""
    return bool(
        np.array_equal(a.point_index, b.point_index)
        and np.array_equal(a.invented, b.invented)
        and np.allclose(a.positions, b.positions, rtol=0.0, atol=1e-9)
    )


def _mean_errors(track: Any, base_pos: np.ndarray, rope: np.ndarray) -> tuple[float, float]:
    """Mean distance (metres) of our traces and of the baseline's to the exact rope.

    Our traces (ordered along the rope by the tracker) are first paired with the
    truth columns; ``rope`` and ``base_pos`` are (T, M, 3).
    """
    from skincap.evaluate.tracking import match_traces_to_truth

    truth_of_trace, _ = match_traces_to_truth(
        track.positions, track.invented, rope, max_distance=np.inf
    )
    ok = truth_of_trace >= 0
    track_err = float(
        np.linalg.norm(track.positions[:, ok] - rope[:, truth_of_trace[ok]], axis=2).mean()
    )
    return track_err, float(np.linalg.norm(base_pos - rope, axis=2).mean())


def _summary_lines(result: dict[str, Any]) -> list[str]:
    """The printable summary of :func:`run_track_benchmark`'s result."""
    frames, rate, used = result["frames"], result["rate"], result["backend"]
    rope_markers, same = result["rope_markers"], result["same_as_numpy"]
    track_err, base_err = result["track_error_m"], result["baseline_error_m"]
    first = result["first_call"]
    lines = [
        f"track: {frames} frames at {rate:g} Hz, {result['points_per_frame']:.0f} points/frame, "
        f"{rope_markers} rope markers (analytic jump-rope scene)",
        f"track_rope ({used}): {result['track_fps']:.0f} frames/s = "
        f"{result['track_realtime']:.0f}x real time (goal >= 100x); mean error "
        f"{track_err * 1000:.1f} mm; per CPU second {result['track_realtime_cpu']:.0f}x real "
        "time",
        f"track_rope (numpy reference): {result['numpy_fps']:.0f} frames/s = "
        f"{result['numpy_realtime']:.0f}x real time; {used} is {result['speedup_vs_numpy']:.1f}x "
        f"the reference, same points taken: {'yes' if same else 'NO'}",
        f"naive greedy nearest neighbour (no KD-tree): {result['baseline_fps']:.0f} frames/s = "
        f"{result['baseline_realtime']:.0f}x real time; mean error {base_err * 1000:.1f} mm",
        f"track_rope is {result['speedup']:.2f}x the naive baseline's speed",
    ]
    if first is not None:
        lines.append(
            f"first call in a fresh process (import + track the take, backend='auto'): "
            f"cold cache {first['cold_s']:.2f} s (CPU {first['cold_cpu_s']:.2f} s; the NumPy "
            f"reference while the kernel compiles in the background), warm cache "
            f"{first['warm_s']:.2f} s (CPU {first['warm_cpu_s']:.2f} s) (goal <= 5 s: "
            + ("met" if max(first["cold_s"], first["warm_s"]) <= 5.0 else "MISSED")
            + ")"
        )
    return lines
