"""Hole-filling evaluation: punch gaps into visible data, fill them with every method,
and score the fills (Park & Hodgins 2006, Table 2, and the issue's targets).

Errors are reported in millimetres and normalised by each marker's mean distance to
its neighbours (Table 2's unit), per gap length and over all lengths: mean, 95th
percentile, maximum and RMSE over the punched samples.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.cleanup.fill import FILL_METHODS, fill_gaps
from skincap.cleanup.neighbours import as_csr, mean_neighbour_distance, motion_neighbours
from skincap.cleanup.settings import FillSettings
from skincap.errors import SkincapWarning, ValidationError
from skincap.types import MarkerSet

__all__ = [
    "PAPER_TABLE2",
    "punch_gaps",
    "punch_gaps_together",
    "evaluate_fill",
    "plot_fill_evaluation",
    "format_fill_table",
]

#: Park & Hodgins (2006) Table 2 (punching), error / mean neighbour distance.
PAPER_TABLE2 = {
    "regions": ["abdomen", "elbow", "thigh", "knee"],
    "avg": [0.017, 0.022, 0.020, 0.023],
    "max": [0.052, 0.062, 0.045, 0.051],
}


def punch_gaps(
    present: np.ndarray,
    neighbours: tuple[np.ndarray, np.ndarray],
    length: int,
    count: int,
    *,
    simultaneous: int = 1,
    min_neighbours: int = 3,
    margin: int = 5,
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """Choose gaps to punch, grouped into rounds whose windows do not overlap in time.

    A gap removes ``simultaneous`` markers over the same ``length`` frames. Each marker
    must be present throughout ``[start - 1, start + length]`` (so the truth is known
    and interpolation has both ends) with at least ``min_neighbours`` of its
    neighbours present there and not punched.

    Parameters
    ----------
    present : (T, N) bool
    neighbours : CSR (offsets (N + 1,), indices (E,))
    length : int, frames
    count : int
        Gaps wanted (fewer are returned when the take has no room).
    simultaneous : int
        Markers per gap.
    min_neighbours : int
    margin : int
        Frames kept between two gaps of one round.
    rng : numpy Generator

    Returns
    -------
    list of (G_r, 3) int64 arrays, one per round
        Rows ``(marker, start, length)``; all gaps of a round can be punched into the
        same copy of the take.
    """
    # the one-length case of punch_gaps_together: a round holds gaps of this length only
    return punch_gaps_together(
        present,
        neighbours,
        [length],
        count,
        simultaneous=simultaneous,
        min_neighbours=min_neighbours,
        margin=margin,
        rng=rng,
    )


def punch_gaps_together(
    present: np.ndarray,
    neighbours: tuple[np.ndarray, np.ndarray],
    lengths: Sequence[int],
    count: int,
    *,
    simultaneous: int = 1,
    min_neighbours: int = 3,
    margin: int = 5,
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """Gaps of every length packed into as few rounds as their windows allow.

    As :func:`punch_gaps` for each length in turn (longest first), but a round takes
    gaps of every length until none fits beside the others: the windows of one
    round (with ``margin`` frames either side) still never overlap in time, so every
    punched marker keeps its neighbours. Fewer rounds, fewer fills for the same gaps.

    Returns
    -------
    list of (G_r, 3) int64 arrays, one per round
        Rows ``(marker, start, length)``, lengths mixed.
    """
    t, n = present.shape
    wanted = sorted({int(v) for v in lengths if int(v) + 2 <= t}, reverse=True)
    cs = np.vstack([np.zeros((1, n), dtype=np.int64), np.cumsum(present, axis=0)])
    made = dict.fromkeys(wanted, 0)
    hopeless = {length: np.zeros(t, dtype=bool) for length in wanted}
    rounds: list[np.ndarray] = []
    while any(made[length] < count for length in wanted):
        busy = np.zeros(t, dtype=bool)
        rows: list[tuple[int, int, int]] = []
        for length in wanted:
            placed = _place_gaps(
                cs,
                neighbours,
                length,
                count - made[length],
                busy=busy,
                hopeless=hopeless[length],
                simultaneous=simultaneous,
                min_neighbours=min_neighbours,
                margin=margin,
                rng=rng,
            )
            made[length] += len(placed)
            rows.extend((c, s, length) for s, chosen in placed for c in chosen)
        if not rows:
            break
        rounds.append(np.array(rows, dtype=np.int64))
    return rounds


def _place_gaps(
    cs: np.ndarray,
    neighbours: tuple[np.ndarray, np.ndarray],
    length: int,
    wanted: int,
    *,
    busy: np.ndarray,
    hopeless: np.ndarray,
    simultaneous: int,
    min_neighbours: int,
    margin: int,
    rng: np.random.Generator,
) -> list[tuple[int, list[int]]]:
    """Up to ``wanted`` gaps of ``length`` frames placed into one round.

    Draws a free start (:func:`_free_starts`), then its markers
    (:func:`_choose_markers`), until ``wanted`` gaps are placed or no start is free.
    ``cs`` (T + 1, N) int64 is the running count of present samples. ``busy`` (T,)
    bool, the round's taken frames, gains each placed window with its margins;
    ``hopeless`` (T,) bool, the starts where no gap of this length fits, gains each
    start that finds too few markers. Both are updated in place.

    Returns
    -------
    list of (start, markers)
        In the order placed; ``markers`` holds ``simultaneous`` marker indices.
    """
    offsets, indices = neighbours
    starts_all = np.arange(1, busy.size - length)  # window [s-1, s+length] inside the take
    cb = np.concatenate([[0], np.cumsum(busy)])  # running count of busy frames
    placed: list[tuple[int, list[int]]] = []
    while len(placed) < wanted:
        free = _free_starts(starts_all, cb, length, margin, hopeless)
        if free.size == 0:
            break
        s = int(rng.choice(free))
        chosen = _choose_markers(cs, s, length, offsets, indices, simultaneous, min_neighbours, rng)
        if chosen is None:
            hopeless[s] = True
            continue
        busy[max(s - 1 - margin, 0) : s + length + 1 + margin] = True
        cb = np.concatenate([[0], np.cumsum(busy)])
        placed.append((s, chosen))
    return placed


def _free_starts(
    starts_all: np.ndarray, cb: np.ndarray, length: int, margin: int, hopeless: np.ndarray
) -> np.ndarray:
    """The starts (int, frames) among ``starts_all`` where a ``length``-frame gap fits.

    A start is free when its window ``[s - 1, s + length]`` widened by ``margin``
    frames either side (clipped to the T frames) touches no busy frame, given ``cb``
    (T + 1,) the running count of busy frames, and it is not ``hopeless`` (T,) bool.
    """
    t = cb.size - 1
    lo = np.maximum(starts_all - 1 - margin, 0)
    hi = np.minimum(starts_all + length + 1 + margin, t)
    return starts_all[(cb[hi] - cb[lo] == 0) & ~hopeless[starts_all]]


def _choose_markers(
    cs: np.ndarray,
    s: int,
    length: int,
    offsets: np.ndarray,
    indices: np.ndarray,
    simultaneous: int,
    min_neighbours: int,
    rng: np.random.Generator,
) -> list[int] | None:
    """Markers to punch at start ``s`` (random order), or None if too few qualify."""
    full = (cs[s + length + 1] - cs[s - 1]) == length + 2  # (N,) visible over the window
    chosen: list[int] = []
    for i in rng.permutation(np.nonzero(full)[0]):
        trial = [*chosen, int(i)]
        ok = True
        for c in trial:  # every punched marker keeps enough present, unpunched neighbours
            nb = indices[offsets[c] : offsets[c + 1]]
            if (full[nb] & ~np.isin(nb, trial)).sum() < min_neighbours:
                ok = False
                break
        if ok:
            chosen = trial
            if len(chosen) == simultaneous:
                return chosen
    return None


def _stats(err: np.ndarray) -> dict[str, float | None]:
    if err.size == 0:
        return {"mean": None, "p95": None, "max": None, "rmse": None}
    return {
        "mean": float(err.mean()),
        "p95": float(np.percentile(err, 95)),
        "max": float(err.max()),
        "rmse": float(np.sqrt(np.mean(err**2))),
    }


def evaluate_fill(
    markers: MarkerSet,
    *,
    methods: Sequence[str] | None = None,
    gap_lengths: Sequence[int] = (30, 60, 90, 120),
    gaps: int = 10,
    simultaneous: int = 1,
    seed: int = 0,
    neighbours: Any = None,
    truth: np.ndarray | None = None,
    min_neighbours: int = 3,
    rigid_blend: float | None = None,
    fill_own_gaps: bool = True,
    lengths_together: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Punch seeded gaps into visible data, fill them with each method and score them.

    Parameters
    ----------
    markers : MarkerSet
        The take (T, N, 3) metres, NaN where missing. Its own gaps stay (and are filled
        too); only punched samples are scored.
    methods : sequence of str, optional
        Default: every method of :data:`~skincap.cleanup.methods.FILL_METHODS`.
    gap_lengths : sequence of int, frames
    gaps : int
        Gaps per length.
    simultaneous : int
        Markers removed together in each gap.
    seed : int
        The same seed punches the same gaps.
    neighbours : CSR, MarkerSurface or None
        Neighbourhoods for the local methods, the rigid donors and the normalisation;
        None: :func:`~skincap.cleanup.neighbours.motion_neighbours`.
    truth : (T, N, 3) float, metres, optional
        What punched samples are scored against (a synthetic take's noise-free truth);
        default: the measured samples themselves. With a truth, the same fills are
        also scored against the measured samples they replace
        (``results_measured``), as a real take's are.
    min_neighbours : int
        Present, unpunched neighbours each punched marker keeps.
    rigid_blend : float in [0, 1], optional
        Passed to :func:`~skincap.cleanup.fill.fill_gaps` for the local methods: the
        rigid fill's weight; None (default) weighs it per gap, 0 is the paper's
        local PCA alone.
    fill_own_gaps : bool, default True
        Fill the take's own gaps too (as a cleanup would, so a punched marker's
        missing neighbours are estimated and used). False fills the punched samples
        only, the take's own holes left open: much faster on a take with many holes,
        and a harder test where neighbours are missing.
    lengths_together : bool, default False
        Punch the gaps of every length into shared rounds
        (:func:`punch_gaps_together`): each method fills each round once and the
        errors are scored per gap length, instead of one set of rounds per length.
        Far fewer fills (the whole-body PCA refits the take on every fill); a take
        holds more holes at a time, and the gaps fall elsewhere than with False
        (the same seed, another plan).
    progress : callable(fraction, label), optional

    Returns
    -------
    dict (JSON-ready)
        ``results[method][str(length) | "all"]`` holds ``mm`` and ``normalised``
        statistics (mean, p95, max, rmse), ``samples`` and ``unfilled`` (punched
        samples the method left NaN, excluded from the statistics); plus the
        settings, ``mean_neighbour_distance_mm`` and ``paper_table2``. With
        ``truth``, ``results_measured`` holds the same statistics of the same fills
        against the measured samples (``results`` is against the truth).
    """
    methods, lengths = _checked_fill_options(
        markers, methods, gap_lengths, gaps, simultaneous, rigid_blend
    )
    p = markers.positions
    t, n, _ = p.shape
    ref = p if truth is None else np.asarray(truth, dtype=np.float64)
    if ref.shape != p.shape:
        raise ValidationError(f"truth: expected shape {p.shape}, got {ref.shape}")
    csr = motion_neighbours(p) if neighbours is None else as_csr(neighbours, n)
    mnd = mean_neighbour_distance(p, csr)
    present = ~np.isnan(p[..., 0]) & ~np.isnan(ref[..., 0])
    rounds = _plan_rounds(
        present, csr, lengths, gaps, simultaneous, min_neighbours, seed, lengths_together
    )
    refs = [ref] if truth is None else [ref, p]
    errs, unfilled, punched_gaps = _fill_punched(
        markers, lengths, rounds, methods, csr, mnd, refs, rigid_blend, fill_own_gaps, progress
    )
    results = _fill_results(methods, lengths, *errs[0], unfilled, punched_gaps)
    best = _best(results, methods)
    extra: dict[str, Any] = {}
    if truth is not None:
        extra["results_measured"] = _fill_results(
            methods, lengths, *errs[1], unfilled, punched_gaps
        )
    return {
        "frames": t,
        "markers": n,
        "rate": markers.rate,
        "methods": methods,
        "gap_lengths": lengths,
        "gaps_per_length": gaps,
        "simultaneous": simultaneous,
        "seed": seed,
        "rigid_blend": "per gap" if rigid_blend is None else float(rigid_blend),
        "fill_own_gaps": bool(fill_own_gaps),
        "lengths_together": bool(lengths_together),
        "rounds": len(rounds),
        "scored_against": "measured" if truth is None else "truth",
        "mean_neighbour_distance_mm": float(np.nanmean(mnd) * 1000.0)
        if np.isfinite(mnd).any()
        else None,
        "results": results,
        **extra,
        "comparison": best,
        "paper_table2": PAPER_TABLE2,
    }


def _checked_fill_options(
    markers: MarkerSet,
    methods: Sequence[str] | None,
    gap_lengths: Sequence[int],
    gaps: int,
    simultaneous: int,
    rigid_blend: float | None,
) -> tuple[list[str], list[int]]:
    """The methods and gap lengths of :func:`evaluate_fill`, its options checked."""
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    methods = list(FILL_METHODS if methods is None else methods)
    bad = [m for m in methods if m not in FILL_METHODS]
    if bad or not methods:
        raise ValidationError(f"methods: unknown {bad}; expected some of {', '.join(FILL_METHODS)}")
    lengths = [int(v) for v in gap_lengths]
    if not lengths or min(lengths) < 1:
        raise ValidationError(
            f"gap_lengths: expected positive frame counts, got {list(gap_lengths)}"
        )
    if gaps < 1 or simultaneous < 1:
        raise ValidationError("gaps and simultaneous must be >= 1")
    if rigid_blend is not None and not 0.0 <= rigid_blend <= 1.0:
        raise ValidationError(f"rigid_blend: expected a weight in [0, 1], got {rigid_blend!r}")
    return methods, lengths


def _plan_rounds(
    present: np.ndarray,
    csr: tuple[np.ndarray, np.ndarray],
    lengths: list[int],
    gaps: int,
    simultaneous: int,
    min_neighbours: int,
    seed: int,
    lengths_together: bool,
) -> list[np.ndarray]:
    """The seeded rounds of gaps :func:`evaluate_fill` punches.

    ``present`` (T, N) bool, ``csr`` the neighbours (offsets (N + 1,), indices (E,)),
    ``lengths`` in frames. Returns (G_r, 3) int64 rows ``(marker, start, length)`` per
    round: shared rounds of every length (:func:`punch_gaps_together`) if
    ``lengths_together``, else the rounds of each length in turn (:func:`punch_gaps`).
    """
    rng = np.random.default_rng(seed)
    if lengths_together:
        return punch_gaps_together(
            present,
            csr,
            lengths,
            gaps,
            simultaneous=simultaneous,
            min_neighbours=min_neighbours,
            rng=rng,
        )
    return [
        rows
        for length in lengths
        for rows in punch_gaps(
            present,
            csr,
            length,
            gaps,
            simultaneous=simultaneous,
            min_neighbours=min_neighbours,
            rng=rng,
        )
    ]


_Errors = dict[str, dict[int, list[np.ndarray]]]


def _fill_punched(
    markers: MarkerSet,
    lengths: list[int],
    rounds: list[np.ndarray],
    methods: list[str],
    csr: Any,
    mnd: np.ndarray,
    refs: list[np.ndarray],
    rigid_blend: float | None,
    fill_own_gaps: bool,
    progress: Progress | None,
) -> tuple[list[tuple[_Errors, _Errors]], dict[str, dict[int, int]], dict[int, int]]:
    """Punch each planned round of gaps, fill it with every method, measure the errors.

    ``rounds`` holds (G_r, 3) rows ``(marker, start, length)``; ``refs`` the (T, N, 3)
    positions the fills are scored against (each gives its own errors). Returns, per
    reference, per method and gap length, the errors of the punched samples (metres)
    and the same divided by the marker's mean neighbour distance ``mnd`` (N,); the
    samples left unfilled, and the gaps punched per length.
    """
    p = markers.positions
    t, n, _ = p.shape
    n_fills = len(rounds) * len(methods)
    scores: list[tuple[_Errors, _Errors]] = [
        (
            {m: {L: [] for L in lengths} for m in methods},
            {m: {L: [] for L in lengths} for m in methods},
        )
        for _ in refs
    ]
    unfilled = {m: dict.fromkeys(lengths, 0) for m in methods}
    punched_gaps = dict.fromkeys(lengths, 0)
    done = 0
    for k, rows in enumerate(rounds):
        punched = p.copy()
        gap_length = np.zeros((t, n), dtype=np.int64)  # the length of the gap a sample is in
        for c, s, ln in rows:
            gap_length[s : s + ln, c] = ln
        mask = gap_length > 0
        round_lengths = [L for L in lengths if (rows[:, 2] == L).any()]
        for L in round_lengths:
            punched_gaps[L] += len(np.unique(rows[rows[:, 2] == L, 1]))
        punched[mask] = np.nan
        take = MarkerSet(punched, markers.labels, markers.rate)
        tt, nn = np.nonzero(mask)
        of_length = {L: gap_length[tt, nn] == L for L in round_lengths}
        for method in methods:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SkincapWarning)
                filled, _ = fill_gaps(
                    take,
                    settings=FillSettings(method=method, rigid_blend=rigid_blend),
                    neighbours=csr,
                    only=None if fill_own_gaps else mask,
                )
            for r, (ref, (errs, nerrs)) in enumerate(zip(refs, scores, strict=True)):
                e_all = np.linalg.norm(filled[tt, nn] - ref[tt, nn], axis=-1)
                for L, sel in of_length.items():
                    e, marker = e_all[sel], nn[sel]
                    ok = np.isfinite(e)
                    if r == 0:
                        unfilled[method][L] += int((~ok).sum())
                    errs[method][L].append(e[ok])
                    nerrs[method][L].append(e[ok] / mnd[marker[ok]])
            done += 1
            if progress is not None:
                what = f"{round_lengths[0]} frames" if len(round_lengths) == 1 else f"round {k + 1}"
                progress(done / max(n_fills, 1), f"{method}, {what}")
    return scores, unfilled, punched_gaps


def _fill_results(
    methods: list[str],
    lengths: list[int],
    errs: _Errors,
    nerrs: _Errors,
    unfilled: dict[str, dict[int, int]],
    punched_gaps: dict[int, int],
) -> dict[str, Any]:
    """Statistics per method, per gap length and over all (``"all"``)."""
    results: dict[str, Any] = {}
    for method in methods:
        per: dict[str, Any] = {}
        all_e, all_n = [], []
        for length in lengths:
            e = np.concatenate(errs[method][length]) if errs[method][length] else np.zeros(0)
            ne = np.concatenate(nerrs[method][length]) if nerrs[method][length] else np.zeros(0)
            all_e.append(e)
            all_n.append(ne)
            per[str(length)] = {
                "mm": _stats(e * 1000.0),
                "normalised": _stats(ne),
                "samples": int(e.size),
                "unfilled": unfilled[method][length],
                "gaps": punched_gaps[length],
            }
        e = np.concatenate(all_e)
        ne = np.concatenate(all_n)
        per["all"] = {
            "mm": _stats(e * 1000.0),
            "normalised": _stats(ne),
            "samples": int(e.size),
            "unfilled": int(sum(unfilled[method].values())),
            "gaps": int(sum(punched_gaps.values())),
        }
        results[method] = per
    return results


def _best(results: dict[str, Any], methods: list[str]) -> dict[str, Any]:
    """Best method by overall RMSE and its ratios to the spline and rigid baselines."""
    rmse = {
        m: results[m]["all"]["mm"]["rmse"]
        for m in methods
        if results[m]["all"]["mm"]["rmse"] is not None
    }
    if not rmse:
        return {}
    best = min(rmse, key=lambda m: rmse[m])
    out: dict[str, Any] = {"best": best, "best_rmse_mm": rmse[best]}
    for base in ("spline", "pchip", "rigid", "linear", "pca"):
        if base in rmse and base != best and rmse[base] > 0:
            out[f"ratio_to_{base}"] = rmse[best] / rmse[base]
    return out


def format_fill_table(result: dict[str, Any]) -> list[list[str]]:
    """Rows for a text table: method, gap length, mean/p95/max mm, mean/max normalised."""
    rows = []
    for method in result["methods"]:
        for key in [*map(str, result["gap_lengths"]), "all"]:
            r = result["results"][method][key]
            mm, nm = r["mm"], r["normalised"]

            def f(v: float | None, fmt: str) -> str:
                return "-" if v is None else format(v, fmt)

            rows.append(
                [
                    method,
                    key,
                    f(mm["mean"], ".2f"),
                    f(mm["p95"], ".2f"),
                    f(mm["max"], ".2f"),
                    f(mm["rmse"], ".2f"),
                    f(nm["mean"], ".4f"),
                    f(nm["max"], ".4f"),
                    str(r["unfilled"]),
                ]
            )
    return rows


def plot_fill_evaluation(result: dict[str, Any], path: str | Path, *, force: bool = False) -> Path:
    """Write a PNG: mean (solid) and 95th-percentile (dashed) error vs gap length per
    method, in mm (left) and normalised by the mean neighbour distance (right).

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed (extra ``plot``).
    """
    from skincap.viz.plotting import agg_pyplot, save_png

    plt = agg_pyplot("PNG plots")
    lengths = result["gap_lengths"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    try:
        for method in result["methods"]:
            for ax, unit in zip(axes, ("mm", "normalised"), strict=True):
                mean = [result["results"][method][str(L)][unit]["mean"] for L in lengths]
                p95 = [result["results"][method][str(L)][unit]["p95"] for L in lengths]
                xs = [L for L, v in zip(lengths, mean, strict=True) if v is not None]
                ys = [v for v in mean if v is not None]
                line = ax.plot(xs, ys, marker="o", label=method)[0]
                ys95 = [v for v in p95 if v is not None]
                ax.plot(xs, ys95, linestyle="--", color=line.get_color(), alpha=0.6)
        axes[0].set_ylabel("error, mm (solid: mean, dashed: 95th percentile)")
        axes[1].set_ylabel("error / mean neighbour distance")
        for v in PAPER_TABLE2["avg"]:
            axes[1].axhline(v, color="grey", linewidth=0.5, linestyle=":")
        for ax in axes:
            ax.set_xlabel("gap length, frames")
            ax.set_yscale("log")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(fontsize=8)
        axes[1].set_title("dotted: Park & Hodgins Table 2 averages", fontsize=9)
        fig.tight_layout()
        save_png(fig, path, force=force)
    finally:
        plt.close(fig)
    return Path(path)
