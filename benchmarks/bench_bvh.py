"""Benchmark: BVH reading (ours vs bvhio) and forward kinematics (vectorised vs per frame).

Run ``python benchmarks/bench_bvh.py``; :func:`run` returns the numbers as a dict and is
self-contained so the CLI can import and call it. Ratios are measured in one run with
``time.perf_counter``, best of N repeats; they are not part of the test suite.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.geometry.kinematics import joint_positions
from skincap.io.bvh import read_bvh

DEFAULT_FILE = Path(__file__).resolve().parents[1] / "tests" / "data" / "cmu_131_01_bvh11.bvh"


def _best_of(fn: Callable[[], Any], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _naive_fk_positions(
    parents: np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> np.ndarray:
    """Baseline: a Python loop over frames and joints with 4x4 matrix products."""
    n_frames, n_joints = rotations.shape[:2]
    out = np.zeros((n_frames, n_joints, 3))
    for f in range(n_frames):
        world = [np.eye(4)] * n_joints
        for j in range(n_joints):
            local = np.eye(4)
            local[:3, :3] = Rotation.from_quat(rotations[f, j]).as_matrix()
            local[:3, 3] = translations[f, j]
            world[j] = local if parents[j] < 0 else world[parents[j]] @ local
            out[f, j] = world[j][:3, 3]
    return out


def run(
    path: str | Path = DEFAULT_FILE, repeats: int = 5, naive_frames: int = 100
) -> dict[str, float]:
    """Time BVH reading and forward kinematics on one file; return the measurements.

    Parameters
    ----------
    path : str or Path
        A BVH file (default: the 994-frame CMU walk in tests/data).
    repeats : int
        Best-of repeats for each timing.
    naive_frames : int
        Frames given to the per-frame FK baseline (it is slow); its rate is per
        joint-frame, so the comparison is fair.

    Returns
    -------
    dict
        ``read_ours_s``, ``read_bvhio_s`` (``bvhio.readAsBvh``: parse + per-joint
        quaternions), ``read_bvhio_hierarchy_s`` (``bvhio.readAsHierarchy``),
        ``read_speedup`` and ``read_speedup_hierarchy``; ``fk_joint_frames_per_s``,
        ``fk_naive_joint_frames_per_s``, ``fk_speedup``; ``frames``, ``joints``. bvhio
        entries are NaN when bvhio is not installed.
    """
    path = Path(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        motion = read_bvh(path)

        def read_ours() -> None:
            read_bvh(path)

        t_ours = _best_of(read_ours, repeats)
    try:
        import bvhio
    except ImportError:
        t_bvhio = t_bvhio_h = float("nan")
    else:
        t_bvhio = _best_of(lambda: bvhio.readAsBvh(str(path)), repeats)
        t_bvhio_h = _best_of(lambda: bvhio.readAsHierarchy(str(path)), max(1, repeats // 2))

    n_frames, n_joints = motion.rotations.shape[:2]
    t_fk = _best_of(lambda: joint_positions(motion), repeats)
    k = min(naive_frames, n_frames)
    sk = motion.skeleton
    t_naive = _best_of(
        lambda: _naive_fk_positions(sk.parents, motion.rotations[:k], motion.translations[:k]), 1
    )
    # the baseline must compute the same thing
    np.testing.assert_allclose(
        _naive_fk_positions(sk.parents, motion.rotations[:2], motion.translations[:2]),
        joint_positions(motion)[:2],
        atol=1e-9,
    )
    fk_rate = n_frames * n_joints / t_fk
    naive_rate = k * n_joints / t_naive
    return {
        "frames": float(n_frames),
        "joints": float(n_joints),
        "read_ours_s": t_ours,
        "read_bvhio_s": t_bvhio,
        "read_bvhio_hierarchy_s": t_bvhio_h,
        "read_speedup": t_bvhio / t_ours,
        "read_speedup_hierarchy": t_bvhio_h / t_ours,
        "fk_s": t_fk,
        "fk_joint_frames_per_s": fk_rate,
        "fk_naive_joint_frames_per_s": naive_rate,
        "fk_speedup": fk_rate / naive_rate,
    }


def main() -> None:
    r = run()
    print(f"BVH {int(r['frames'])} frames x {int(r['joints'])} joints")
    print(
        f"read: ours {r['read_speedup']:.1f}x faster than bvhio.readAsBvh, {r['read_speedup_hierarchy']:.1f}x than readAsHierarchy"
    )
    print(
        f"FK: {r['fk_joint_frames_per_s'] / 1e6:.2f}M joint-frames/s, {r['fk_speedup']:.0f}x the per-frame loop "
        f"({r['fk_naive_joint_frames_per_s'] / 1e3:.0f}k joint-frames/s)"
    )


if __name__ == "__main__":
    main()
