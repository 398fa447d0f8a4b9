"""``skincap bench batch``: N takes on a local cluster against the same N one after another.

Both runs clean the same copies of the real captures shipped in the package, in one
process's period, so the ratio is a same-run figure: the batch's wall-clock speed-up over the
sequential run. The CPU seconds of the takes (summed over the workers) say how much
of the speed-up the cores gave and how much the cluster's start cost.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from skincap.errors import ValidationError

__all__ = ["bench_takes", "run_batch_benchmark"]


def bench_takes(folder: Path, n_takes: int) -> list[Path]:
    """Copy ``n_takes`` real captures shipped with skincap into ``folder`` (cycling over them).

    The sources are the package's own real captures (:mod:`skincap.data`: CMU 85_02,
    Vicon, 41 labelled markers; the kineticstoolkit OptiTrack walk, 12 markers), so the
    benchmark runs on any install.
    """
    from skincap.data import path as data_path

    sources = [data_path("cmu_85_02.c3d"), data_path("kt_optitrack_walking.c3d")]
    folder.mkdir(parents=True, exist_ok=True)
    takes = []
    for i in range(n_takes):
        src = sources[i % len(sources)]
        dst = folder / f"take{i:03d}{src.suffix}"
        shutil.copyfile(src, dst)
        takes.append(dst)
    return takes


def run_batch_benchmark(*, n_takes: int = 4, workers: int = 2) -> dict[str, Any]:
    """Clean ``n_takes`` captures one after another, then as a batch on ``workers`` processes.

    Returns
    -------
    dict
        ``takes``, ``workers``, ``sequential_wall_s``, ``batch_wall_s`` (including the
        cluster's start), ``speedup`` (sequential / batch wall), ``sequential_cpu_s``
        and ``batch_task_cpu_s`` (CPU seconds of the takes), ``identical`` (the two
        runs wrote the same bytes), ``lines`` (the printed table).
    """
    from skincap.batch.runner import run_batch
    from skincap.workflows.clean_file import clean_file

    if not 1 <= n_takes <= 1000:
        raise ValidationError(f"--takes: expected 1..1000, got {n_takes}")
    if not 1 <= workers <= 64:
        raise ValidationError(f"--workers: expected 1..64, got {workers}")
    with tempfile.TemporaryDirectory(prefix="skincap-bench-batch-") as tmp:
        root = Path(tmp)
        takes = bench_takes(root / "in", n_takes)
        seq = root / "sequential"
        seq.mkdir()
        wall, cpu = time.perf_counter(), time.process_time()
        for take in takes:
            clean_file(take, seq / f"{take.stem}.c3d", report=seq / f"{take.stem}.report.json")
        seq_wall, seq_cpu = time.perf_counter() - wall, time.process_time() - cpu
        wall = time.perf_counter()
        result = run_batch("clean", [root / "in"], root / "batch", workers=workers)
        batch_wall = time.perf_counter() - wall
        task_cpu = sum(row.get("cpu_seconds", 0.0) for row in result.rows)
        identical = all(
            (seq / f"{t.stem}.c3d").read_bytes() == (root / "batch" / f"{t.stem}.c3d").read_bytes()
            for t in takes
        )
        failed = [row["error"] for row in result.rows if row["status"] != "done"]
        # the same batch on a cluster already up whose workers have run a batch: the
        # steady state of a long batch, without the start (processes, imports)
        warm_wall, warm_cpu = _warm_batch(root, workers)
    speedup = seq_wall / batch_wall if batch_wall > 0 else float("nan")
    warm_speedup = seq_wall / warm_wall if warm_wall > 0 else float("nan")
    lines = [
        f"batch clean, {n_takes} takes (real captures), {workers} workers, cores {os.cpu_count()}",
        f"  one after another : {seq_wall:8.2f} s wall, {seq_cpu:7.2f} s CPU",
        f"  batch on Dask     : {batch_wall:8.2f} s wall (cluster start included), "
        f"{task_cpu:7.2f} s CPU of the workers in the takes (Dask's threads included)",
        f"  batch, warm workers: {warm_wall:7.2f} s wall, {warm_cpu:7.2f} s CPU in the takes",
        f"  speed-up          : {speedup:.2f}x with the cluster's start, {warm_speedup:.2f}x "
        f"warm (same run); outputs identical: {identical}",
    ]
    if failed:
        lines.append(f"  failed takes: {failed}")
    return {
        "takes": n_takes,
        "workers": workers,
        "sequential_wall_s": seq_wall,
        "sequential_cpu_s": seq_cpu,
        "batch_wall_s": batch_wall,
        "batch_task_cpu_s": task_cpu,
        "speedup": speedup,
        "warm_batch_wall_s": warm_wall,
        "warm_batch_task_cpu_s": warm_cpu,
        "warm_speedup": warm_speedup,
        "identical": identical,
        "lines": lines,
    }


def _warm_batch(root: Path, workers: int) -> tuple[float, float]:
    """Wall and task CPU seconds of the batch run a second time (``force``) on one running
    local cluster, after a first run warmed its workers."""
    import logging

    from distributed import LocalCluster

    from skincap.batch.runner import run_batch

    with LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.ERROR,
    ) as cluster:
        address = cluster.scheduler_address
        run_batch("clean", [root / "in"], root / "warm", scheduler=address)
        wall = time.perf_counter()
        result = run_batch("clean", [root / "in"], root / "warm", scheduler=address, force=True)
        wall = time.perf_counter() - wall
    return wall, sum(row.get("cpu_seconds", 0.0) for row in result.rows)
