"""Cleanup speed benchmark: the whole ``clean`` (surface, merge, fill, smooth) of a dense
take, with its hole filling and local-frame smoothing timed apart.

A 350-marker take of ``frames`` frames (markers on ten rigidly moving, gently
deforming patches; a few percent of samples missing in runs of 5-60 frames) is filled
with the paper's local PCA (and its variants if asked) and smoothed in local frames.
Times are reported beside the linear-interpolation baseline measured in the same run,
and for 250, 500 and 1000 frames so the cost per frame shows whether it is linear.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from skincap.cleanup.fill import fill_gaps, motion_neighbours
from skincap.cleanup.pipeline import clean_markers
from skincap.cleanup.smooth import smooth_local
from skincap.errors import SkincapWarning
from skincap.types import MarkerSet

__all__ = ["synthetic_dense_take", "run_clean_benchmark"]


def synthetic_dense_take(
    n_markers: int = 350,
    frames: int = 1000,
    *,
    rate: float = 120.0,
    missing: float = 0.03,
    seed: int = 0,
) -> tuple[MarkerSet, np.ndarray]:
    """A cheap dense take for timing: (markers with gaps, (T, N, 3) truth in metres).

    Markers sit on ten patches of a 1.7 m body-sized box; each patch turns and
    translates smoothly (limb-like speeds) and breathes a little; ``missing`` of the
    samples are removed in runs of 5-60 frames.
    """
    rng = np.random.default_rng(seed)
    patch = rng.integers(0, 10, n_markers)
    local = rng.normal(0.0, 0.08, (n_markers, 3))
    centre = rng.uniform([-0.3, 0.0, -0.15], [0.3, 1.7, 0.15], (10, 3))
    t = np.arange(frames) / rate
    freq = rng.uniform(0.3, 1.5, (10, 3))
    phase = rng.uniform(0, 2 * np.pi, (10, 3))
    angles = 0.6 * np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None])  # (T, 10, 3)
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_rotvec(angles.reshape(-1, 3)).as_matrix().reshape(frames, 10, 3, 3)
    walk = np.stack([0.8 * t, 0.05 * np.sin(4 * np.pi * t), 0 * t], axis=1)  # (T, 3)
    breathe = 1.0 + 0.03 * np.sin(2 * np.pi * 0.3 * t)[:, None, None]
    pts = np.einsum("tnij,tnj->tni", rot[:, patch], local[None] * breathe)
    truth = pts + centre[patch][None] + walk[:, None, :]
    pos = truth + rng.normal(0.0, 0.0005, truth.shape)
    n_runs = int(missing * frames * n_markers / 30)
    who = rng.integers(0, n_markers, n_runs)
    start = rng.integers(0, frames, n_runs)
    length = rng.integers(5, 61, n_runs)
    holes = np.zeros((frames + 61, n_markers), dtype=np.int32)
    np.add.at(holes, (start, who), 1)
    np.add.at(holes, (start + length, who), -1)
    pos[np.cumsum(holes, axis=0)[:frames] > 0] = np.nan
    labels = [f"M{i:03d}" for i in range(n_markers)]
    return MarkerSet(pos, labels, rate), truth


def _timed(fn: Any) -> tuple[float, Any]:
    t0 = time.perf_counter()
    value = fn()
    return time.perf_counter() - t0, value


def run_clean_benchmark(
    *,
    n_markers: int = 350,
    frames: Sequence[int] = (250, 500, 1000),
    methods: Sequence[str] = ("local_pca",),
    smooth: bool = True,
    seed: int = 0,
) -> dict[str, Any]:
    """Time fill (+ smoothing) against the linear fill, per take length.

    Parameters
    ----------
    n_markers : int
    frames : sequence of int
        Take lengths; the last is the headline (the issue's 1000).
    methods : sequence of str
        Fill methods to time (each with smoothing when ``smooth``).
    smooth : bool
    seed : int

    Returns
    -------
    dict
        ``lines`` (printable), ``rows`` (per take length and method: ``clean_s`` for
        :func:`~skincap.cleanup.pipeline.clean_markers` end to end, and fill +
        smoothing alone: seconds, seconds per frame, ratio to the linear fill, fill
        RMSE in mm against the truth), and
        ``goal_s`` (the issue's 10 s for the whole clean of 350 x 1000).
    """
    rows = []
    lines = [
        f"cleanup benchmark: {n_markers} markers, fill + {'smoothing' if smooth else 'no smoothing'}"
    ]
    for t in frames:
        markers, truth = synthetic_dense_take(n_markers, int(t), seed=seed)
        missing = markers.missing
        t_nb, csr = _timed(lambda m=markers: motion_neighbours(m.positions))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkincapWarning)
            t_lin, (lin, _) = _timed(
                lambda m=markers, c=csr: fill_gaps(m, method="linear", neighbours=c)
            )
            for method in methods:
                t_fill, (filled, _) = _timed(
                    lambda m=markers, c=csr, k=method: fill_gaps(m, method=k, neighbours=c)
                )
                t_smooth = 0.0
                if smooth:
                    t_smooth, _ = _timed(lambda f=filled, c=csr: smooth_local(f, c))
                t_clean, _ = _timed(
                    lambda m=markers, k=method: clean_markers(m, method=k, smooth=smooth)
                )
                err = np.linalg.norm(filled - truth, axis=-1)[missing]
                err_lin = np.linalg.norm(lin - truth, axis=-1)[missing]
                total = t_nb + t_fill + t_smooth
                row = {
                    "frames": int(t),
                    "method": method,
                    "neighbours_s": t_nb,
                    "fill_s": t_fill,
                    "smooth_s": t_smooth,
                    "total_s": total,
                    "clean_s": t_clean,
                    "per_frame_ms": 1000.0 * total / t,
                    "linear_fill_s": t_lin,
                    "ratio_to_linear": total / max(t_lin, 1e-9),
                    "rmse_mm": float(np.sqrt(np.nanmean(err**2)) * 1000)
                    if np.isfinite(err).any()
                    else None,
                    "linear_rmse_mm": float(np.sqrt(np.nanmean(err_lin**2)) * 1000)
                    if np.isfinite(err_lin).any()
                    else None,
                    "missing_fraction": float(missing.mean()),
                }
                rows.append(row)
                lines.append(
                    f"{t:5d} frames {method:20s} whole clean {t_clean:6.2f} s; {total:7.2f} s (neighbours {t_nb:.2f}, fill {t_fill:.2f}, "
                    f"smooth {t_smooth:.2f}) = {row['per_frame_ms']:.2f} ms/frame, "
                    f"x{row['ratio_to_linear']:.0f} the linear fill ({t_lin * 1000:.1f} ms); "
                    f"RMSE {row['rmse_mm']:.2f} mm vs linear {row['linear_rmse_mm']:.2f} mm"
                )
    for method in methods:
        mine = [r for r in rows if r["method"] == method]
        if len(mine) >= 2:
            a, b = mine[0], mine[-1]
            growth = (b["clean_s"] / max(a["clean_s"], 1e-9)) / (b["frames"] / a["frames"])
            lines.append(
                f"{method}: whole clean, cost per frame {b['frames']} vs {a['frames']} frames: "
                f"x{growth:.2f} (1.0 = linear in frames; <= 1 when fixed costs dominate)"
            )
    return {"lines": lines, "rows": rows, "goal_s": 10.0, "n_markers": n_markers}
