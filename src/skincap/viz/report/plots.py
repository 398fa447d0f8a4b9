"""The report's figures, drawn with matplotlib's Agg backend into PNG files."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from skincap.viz.plotting import agg_pyplot, save_png

__all__ = ["plot_missing_maps", "plot_fill_errors"]


def plot_missing_maps(
    before: np.ndarray,
    after: np.ndarray,
    after_invented: np.ndarray,
    rate: float,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
) -> Path:
    """Missing-data maps of a capture before and after cleanup, markers by frames.

    Parameters
    ----------
    before : (T, N) bool
        True where a labelled marker is missing in the raw capture.
    after : (T, N) bool
        True where it is still missing after cleanup (same columns).
    after_invented : (T, N) bool
        True where cleanup filled the sample.
    rate : float, Hz
        For the time axis.
    path : path-like
        The PNG, written atomically.
    """
    plt = agg_pyplot("the report's figures")
    from matplotlib.colors import ListedColormap

    cmap = ListedColormap([(0.93, 0.93, 0.91), (0.80, 0.10, 0.15), (0.20, 0.45, 0.85)])
    code_before = before.astype(np.int8).T
    code_after = np.where(after, 1, np.where(after_invented, 2, 0)).astype(np.int8).T
    t_end = before.shape[0] / rate
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    titles = (
        f"raw: {before.mean() * 100:.1f} % missing",
        f"cleaned: {after.mean() * 100:.1f} % missing, {after_invented.mean() * 100:.1f} % filled",
    )
    for ax, code, title in zip(axes, (code_before, code_after), titles, strict=True):
        ax.imshow(
            code,
            aspect="auto",
            interpolation="nearest",
            cmap=cmap,
            vmin=0,
            vmax=2,
            extent=(0, t_end, code.shape[0], 0),
        )
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("time (s)")
    axes[0].set_ylabel("marker (column)")
    from matplotlib.patches import Patch

    fig.legend(
        handles=[
            Patch(color=cmap(0), label="measured"),
            Patch(color=cmap(1), label="missing"),
            Patch(color=cmap(2), label="filled by cleanup"),
        ],
        loc="lower center",
        ncol=3,
        fontsize=9,
        frameon=False,
    )
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    out = save_png(fig, path, force=force, dpi=90)
    plt.close(fig)
    return out


def plot_fill_errors(
    result: dict[str, Any], path: str | os.PathLike[str], *, force: bool = False
) -> Path:
    """Mean fill error against gap length, one line per method, in Table 2's unit.

    Parameters
    ----------
    result : dict
        From :func:`skincap.evaluate.cleanup.evaluate_fill`.
    path : path-like
        The PNG, written atomically.
    """
    plt = agg_pyplot("the report's figures")
    lengths = [int(v) for v in result["gap_lengths"]]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for method, per_length in result["results"].items():
        means = [per_length[str(n)]["normalised"]["mean"] for n in lengths]
        values = np.array([np.nan if m is None else m for m in means], dtype=float)
        ax.plot(lengths, values, marker="o", label=method)
    paper = result.get("paper_table2") or {}
    if paper.get("avg"):
        lo, hi = min(paper["avg"]), max(paper["avg"])
        ax.axhspan(lo, hi, color=(0.2, 0.6, 0.2), alpha=0.15, label="paper Table 2: average")
    if paper.get("max"):
        lo, hi = min(paper["max"]), max(paper["max"])
        ax.axhspan(lo, hi, color=(0.8, 0.3, 0.1), alpha=0.12, label="paper Table 2: maximum")
    ax.set_yscale("log")
    ax.set_xlabel("gap length (frames)")
    ax.set_ylabel("mean error / mean neighbour distance")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    out = save_png(fig, path, force=force, dpi=90)
    plt.close(fig)
    return out
