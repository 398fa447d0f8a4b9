"""Benchmarks behind ``skincap bench``: speed ratios against a peer measured in the same run.

Never part of the pass/fail test suite. Every figure is the best of ``repeat`` runs
(``time.perf_counter``) and is printed as a ratio against a baseline timed in the same
process, so the numbers mean the same on a slow or a fast machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import MissingDependencyError, ValidationError

#: Largest sizes a benchmark is built with: a scene beyond them is a typo, and 1e14
#: vertices or frames asked NumPy for petabytes.
BENCH_MAX_VERTICES = 2_000_000
BENCH_MAX_FRAMES = 4096  # timed frames: (frames, vertices, 3) float64 outputs are held
BENCH_MAX_ROM_FRAMES = 20_000
BENCH_MAX_REPEAT = 1_000


def check_bench_count(name: str, value: Any, low: int, high: int) -> int:
    """``value`` as an int in ``low..high``; ValidationError naming ``name`` otherwise."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, np.integer))
        or not low <= value <= high
    ):
        raise ValidationError(f"{name}: expected an integer in {low}..{high}, got {value!r}")
    return int(value)


__all__ = [
    "best_time",
    "first_call_in_fresh_process",
    "run_io_benchmarks",
    "fk_per_frame_reference",
]

_DATA = Path(__file__).resolve().parents[4] / "tests" / "data"


def best_time(fn: Callable[[], Any], repeat: int) -> float:
    """Smallest wall-clock seconds of ``repeat`` calls of ``fn`` (its warnings muted)."""
    best = float("inf")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(max(1, repeat)):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
    return best


def _best_after_warm_up(
    run: Callable[[], object], repeat: int, clock: Callable[[], float]
) -> float:
    """One warm-up call (compilation, caches), then the smallest ``clock`` difference
    (seconds) over ``repeat`` calls of ``run``."""
    run()
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        run()
        best = min(best, clock() - t0)
    return best


def best_seconds(run: Callable[[], object], repeat: int) -> float:
    """One warm-up call (compilation, caches), then the smallest wall-clock seconds of
    ``repeat`` calls of ``run``."""
    return _best_after_warm_up(run, repeat, time.perf_counter)


def best_cpu_seconds(run: Callable[[], object], repeat: int) -> float:
    """One warm-up call, then the smallest CPU seconds of this process over ``repeat``
    calls of ``run`` (single-threaded work: the figure a loaded machine distorts least)."""
    return _best_after_warm_up(run, repeat, time.process_time)


_CHILD = """
import json, time
t0, c0 = time.perf_counter(), time.process_time()
{imports}
t1, c1 = time.perf_counter(), time.process_time()
{setup}
t2, c2 = time.perf_counter(), time.process_time()
{call}
t3, c3 = time.perf_counter(), time.process_time()
print(json.dumps({{"wall": [t1 - t0, t3 - t2], "cpu": [c1 - c0, c3 - c2]}}))
"""


def _stop_background_compiles(cache: str) -> int:
    """Kill the background compiles a child started in ``cache`` (their pid is in the lock)."""
    import signal

    stopped = 0
    for lock in Path(cache).rglob("skincap-compiling-*.lock"):
        try:
            pid = int(lock.read_text() or 0)
        except (OSError, ValueError):
            continue
        if pid > 0:
            try:
                os.kill(pid, signal.SIGTERM)
                stopped += 1
            except OSError:
                pass
    return stopped


def _run_child(code: str, env: dict[str, str], timeout_s: float) -> dict[str, list[float]]:
    done = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"first-call measurement failed in a child process: {tail}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def first_call_in_fresh_process(
    imports: str,
    setup: str,
    call: str,
    *,
    compile_policy: str = "background",
    timeout_s: float = 900.0,
) -> dict[str, float]:
    """The first call's cost as a user meets it: a new Python process, cold then warm cache.

    Cold: a fresh interpreter with a new, empty numba cache directory
    (``NUMBA_CACHE_DIR``), as on a fresh install, with ``SKINCAP_COMPILE`` set to
    ``compile_policy``: with ``"background"`` (the default policy) the call runs
    the NumPy reference and starts the kernel's background compile, which is
    stopped as soon as the child ends (nothing is left running); with ``"inline"``
    the child compiles its kernels itself. Warm: a fresh interpreter with the
    caller's own numba cache (which the caller has filled by running the kernel)
    and ``SKINCAP_COMPILE=inline``, so a missing cache entry would show as a
    compile in the figure rather than hide behind the NumPy path.

    Parameters
    ----------
    imports : str
        Python statements importing what the call needs (timed: a user pays them).
    setup : str
        Statements building the input (not timed).
    call : str
        The statement whose first execution is timed.
    compile_policy : {"background", "inline"}, default "background"
    timeout_s : float, default 900
        Per child process.

    Returns
    -------
    dict
        ``cold_s`` and ``warm_s``: import plus first call, wall-clock seconds;
        ``cold_call_s`` and ``warm_call_s``: the call alone; ``cold_cpu_s`` and
        ``warm_cpu_s``: the CPU seconds of import plus call (all threads of the
        child; a loaded machine inflates them far less than the wall clock).

    Raises
    ------
    RuntimeError
        The snippet failed in the child process (its stderr's last line is quoted).
    """
    if compile_policy not in ("background", "inline"):
        raise ValidationError(
            f"compile_policy: expected 'background' or 'inline', got {compile_policy!r}"
        )
    code = _CHILD.format(imports=imports, setup=setup, call=call)
    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="skincap-numba-cache-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, SKINCAP_COMPILE=compile_policy)
        try:
            cold = _run_child(code, env, timeout_s)
        finally:
            _stop_background_compiles(cache)
    warm_env = dict(os.environ, SKINCAP_COMPILE="inline")
    warm = _run_child(code, warm_env, timeout_s)
    for label, times in (("cold", cold), ("warm", warm)):
        result[f"{label}_s"] = sum(times["wall"])
        result[f"{label}_call_s"] = times["wall"][1]
        result[f"{label}_cpu_s"] = sum(times["cpu"])
    return result


def fk_per_frame_reference(
    parents: np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> np.ndarray:
    """Plain forward kinematics, one frame and one joint at a time (the baseline).

    Parameters
    ----------
    parents : (J,) int; rotations : (T, J, 4) x,y,z,w; translations : (T, J, 3) m.

    Returns
    -------
    (T, J, 3) world joint positions, metres.
    """
    from scipy.spatial.transform import Rotation

    t_count, j_count = rotations.shape[:2]
    out = np.zeros((t_count, j_count, 3))
    for t in range(t_count):
        world_r = [None] * j_count
        for j in range(j_count):
            local = Rotation.from_quat(rotations[t, j])
            p = parents[j]
            if p < 0:
                world_r[j] = local
                out[t, j] = translations[t, j]
            else:
                world_r[j] = world_r[p] * local
                out[t, j] = out[t, p] + world_r[p].apply(translations[t, j])
    return out


def _data_file(name: str) -> Path:
    path = _DATA / name
    if not path.is_file():
        from skincap.data import path as shipped_file

        return shipped_file(name)
    return path


def run_io_benchmarks(*, repeat: int = 5) -> dict[str, Any]:
    """Time BVH read + FK against bvhio, the C3D reader against raw ezc3d, OBJ against trimesh.

    Uses the 994-frame CMU BVH and the C3D files of ``tests/data`` (from a source
    checkout; an installed package falls back to its shipped demo files).

    Returns
    -------
    dict with the measured seconds, the ratios and ``lines`` of text to print.
    """
    repeat = check_bench_count("repeat", repeat, 1, BENCH_MAX_REPEAT)
    try:
        import bvhio
    except ImportError:
        raise MissingDependencyError("bvhio", "dev", "the BVH benchmark") from None
    import ezc3d

    from skincap.geometry.kinematics import joint_positions
    from skincap.io.bvh import read_bvh
    from skincap.io.c3d import read_c3d

    lines: list[str] = []
    results: dict[str, Any] = {"repeat": repeat}

    # --- BVH read: ours vs bvhio's parser ------------------------------------
    if (_DATA / "cmu_131_01_bvh11.bvh").is_file():
        bvh, units = _DATA / "cmu_131_01_bvh11.bvh", "cmu"
    else:
        bvh, units = _data_file("bvhtoolbox_test_mocapbank.bvh"), "cm"
    ours = best_time(lambda: read_bvh(bvh, units=units), repeat)
    peer = best_time(lambda: bvhio.readAsBvh(str(bvh)), repeat)
    peer_h = best_time(lambda: bvhio.readAsHierarchy(str(bvh)), max(1, repeat // 2))
    results["bvh_read"] = {
        "file": bvh.name,
        "skincap_s": ours,
        "bvhio_readAsBvh_s": peer,
        "bvhio_readAsHierarchy_s": peer_h,
        "speedup": peer / ours,
        "speedup_vs_hierarchy": peer_h / ours,
    }
    lines.append(
        f"BVH read  {bvh.name}: skincap is {peer / ours:.1f}x faster than bvhio.readAsBvh "
        f"and {peer_h / ours:.1f}x faster than bvhio.readAsHierarchy (goal >= 5x)"
    )

    # --- FK: vectorised vs a per-frame loop and vs bvhio's hierarchy ----------
    motion = read_bvh(bvh, units=units)
    t_count, j_count = motion.n_frames, motion.skeleton.n_joints
    fk = best_time(lambda: joint_positions(motion), repeat)
    n_ref = min(t_count, 100)
    # The baseline must compute the same thing as the vectorised version.
    reference = fk_per_frame_reference(
        motion.skeleton.parents, motion.rotations[:3], motion.translations[:3]
    )
    if not np.allclose(reference, joint_positions(motion)[:3], atol=1e-9):
        raise RuntimeError("vectorised FK disagrees with the per-frame reference")
    ref = best_time(
        lambda: fk_per_frame_reference(
            motion.skeleton.parents, motion.rotations[:n_ref], motion.translations[:n_ref]
        ),
        1,
    ) * (t_count / n_ref)
    root = bvhio.readAsHierarchy(str(bvh))
    layout = root.layout()
    n_peer = min(t_count, 200)

    def bvhio_fk() -> None:
        for frame in range(n_peer):
            root.loadPose(frame)
            [joint.PositionWorld for joint, _, _ in layout]

    peer_fk = best_time(bvhio_fk, 1) * (t_count / n_peer)
    rate = t_count * j_count / fk
    results["fk"] = {
        "joint_frames": t_count * j_count,
        "skincap_s": fk,
        "joint_frames_per_s": rate,
        "per_frame_loop_s": ref,
        "bvhio_s": peer_fk,
        "speedup_vs_loop": ref / fk,
        "speedup_vs_bvhio": peer_fk / fk,
    }
    lines.append(
        f"FK        {t_count} frames x {j_count} joints: {rate:.3g} joint-frames/s (goal >= 1e6); "
        f"{ref / fk:.0f}x the per-frame loop, {peer_fk / fk:.0f}x bvhio's hierarchy"
    )

    # --- C3D read: ours vs raw ezc3d --------------------------------------------
    c3d_files = sorted(_DATA.glob("*.c3d")) or [_data_file("kt_optitrack_walking.c3d")]
    ratios = {}
    for path in c3d_files:
        raw = best_time(lambda p=path: ezc3d.c3d(str(p)), repeat)
        ours_c3d = best_time(lambda p=path: read_c3d(p), repeat)
        ratios[path.name] = ours_c3d / raw
    worst = max(ratios, key=ratios.get)
    results["c3d_read"] = {"time_ratio_vs_ezc3d": ratios}
    lines.append(
        f"C3D read  {len(ratios)} files: skincap takes {min(ratios.values()):.2f}x..{ratios[worst]:.2f}x "
        f"raw ezc3d's time (worst {worst}; goal <= 1.2x)"
    )
    _obj_read_row(results, lines, repeat)
    results["lines"] = lines
    return results


def _obj_read_row(results: dict[str, Any], lines: list[str], repeat: int) -> None:
    """Our OBJ reader against ``trimesh.load`` on the MakeHuman base mesh (13k quads)."""
    try:
        import trimesh
    except ImportError:
        raise MissingDependencyError("trimesh", "dev", "the OBJ benchmark") from None

    from skincap.io.mesh import read_obj

    obj = _data_file("makehuman_base.obj")
    ours = best_time(lambda: read_obj(obj, units="dm"), repeat)
    with warnings.catch_warnings():  # trimesh warns about the file's unused groups
        warnings.simplefilter("ignore")
        peer = best_time(
            lambda: trimesh.load(
                obj, process=False, maintain_order=True, skip_materials=True, force="mesh"
            ),
            repeat,
        )
    results["obj_read"] = {"file": obj.name, "skincap_s": ours, "trimesh_s": peer}
    results["obj_read"]["speedup_vs_trimesh"] = peer / ours
    lines.append(
        f"OBJ read  {obj.name}: skincap reads at {peer / ours:.2f}x the speed of trimesh.load "
        "(process=False)"
    )
