"""Benchmark behind ``skincap bench synth``: one dense jump-rope take, stage by stage.

Prints each stage's share of the time and the whole generation against the take's
own duration (a ratio, measured in the same run), for the issue's goal: a
1000-frame dense take with a rope in under a minute on 2 cores.
"""

from __future__ import annotations

import time
from typing import Any

__all__ = ["run_synth_benchmark"]


def run_synth_benchmark(
    *, frames: int = 1000, vertices: int = 20_000, seed: int = 0
) -> dict[str, Any]:
    """Generate a dense jump-rope take and time its stages.

    Returns
    -------
    dict with ``seconds`` per stage, ``total_s``, ``take_s`` (its duration at 120 Hz),
    ``summary`` (the take's counts) and ``lines`` to print.
    """
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    stamps: list[tuple[float, str]] = []
    t0 = time.perf_counter()
    body = build_body("procedural", n_vertices=vertices, seed=seed)
    t_body = time.perf_counter() - t0
    motion = build_motion(body, "jumprope", frames=frames, seed=seed)
    t1 = time.perf_counter()

    def progress(fraction: float, label: str) -> None:
        if not stamps or stamps[-1][1] != label:
            stamps.append((time.perf_counter(), label))

    take = generate_capture(
        body, motion, markers="dense", rope="jump", seed=seed, progress=progress
    )
    t2 = time.perf_counter()
    stages: dict[str, float] = {"body": t_body, "motion": t1 - t0 - t_body}
    for (start, label), (end, _) in zip(stamps, [*stamps[1:], (t2, "")], strict=True):
        if label != "done":
            stages[label] = stages.get(label, 0.0) + (end - start)
    total = t2 - t0
    take_s = motion.n_frames / motion.rate
    lines = [
        f"synth: {motion.n_frames} frames, {take.summary['markers']} markers + {take.summary['rope_markers']} rope markers, "
        f"{body.n_vertices} vertices: {total:.1f} s in all (goal < 60 s), {total / take_s:.1f}x the take's own {take_s:.1f} s",
    ]
    lines += [
        f"  {label:<14} {seconds:7.2f} s  {100 * seconds / total:5.1f} %"
        for label, seconds in stages.items()
    ]
    lines.append(
        f"  -> {take.summary['fragments']} fragments, {100 * take.summary['missing_fraction']:.1f} % missing, "
        f"{take.summary['ghosts']} ghosts"
    )
    return {
        "seconds": stages,
        "total_s": total,
        "take_s": take_s,
        "summary": take.summary,
        "lines": lines,
    }
