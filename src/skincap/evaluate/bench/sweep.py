"""Sweep-deformer benchmark: ms/frame on the MakeHuman body against LBS and DQS, in one run.

The shipped MakeHuman base mesh (13,380 vertices, its own rig and weights) walks the
shipped CMU capture (``cmu_131_01_bvh11.bvh``); ``subdivide`` splits every triangle in
four that many times (edge midpoints, their skin weights the average of the edge's two
ends, four influences kept) to reach the size of Hyun et al.'s models (72,712 vertices:
one split gives 53k, two 213k). Timed on the same skinning matrices, in the same
process, per backend of the skinning kernels (the default, and the NumPy reference):
our LBS, our DQS, and the sweep deformer (fit and bind once, then ``n_frames`` frames
per call) with and without volume preservation; the figure is CPU seconds
(``time.process_time``), the smallest of ``repeat`` runs, per frame. Ratios are
``sweep / LBS`` and ``sweep / DQS`` (how many times their cost a sweep frame is). The
paper's figure is for the record beside ours: ~7 frames per second for 72,712 vertices
on a 2 GHz Pentium 4 in 2005, rendering included, volume preservation excluded.

Nothing is printed: ``lines`` holds the text for the CLI.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from skincap.evaluate.bench.common import best_cpu_seconds, check_bench_count
from skincap.types import Mesh, Skin

__all__ = ["run_sweep_benchmark", "subdivide_skinned"]

#: Hyun et al. 2005, §5: vertices of their models and frames per second.
PAPER_VERTICES = 72_712
PAPER_FPS = 7.0


def subdivide_skinned(mesh: Mesh) -> Mesh:
    """Split every triangle in four at its edge midpoints, skin weights averaged.

    Parameters
    ----------
    mesh : Mesh
        With a :class:`~skincap.types.Skin`; vertices (V, 3) metres, faces (F, 3).

    Returns
    -------
    Mesh
        V + E vertices (E unique edges) and 4 F faces; a new vertex's weights are the
        mean of its edge's ends' (dense over the joints, the largest
        ``skin.n_influences`` kept and renormalised).
    """
    from skincap.deform.skeletal.weights import limit_influences

    skin = mesh.skin
    assert skin is not None
    f = mesh.faces
    pairs = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges, inverse = np.unique(np.sort(pairs, axis=1), axis=0, return_inverse=True)
    n_v, n_f = mesh.n_vertices, f.shape[0]
    mid = n_v + inverse.reshape(3, n_f)  # (3, F): the midpoints of edges 01, 12, 20
    faces = np.concatenate(
        [
            np.stack([f[:, 0], mid[0], mid[2]], 1),
            np.stack([mid[0], f[:, 1], mid[1]], 1),
            np.stack([mid[2], mid[1], f[:, 2]], 1),
            np.stack([mid[0], mid[1], mid[2]], 1),
        ]
    )
    vertices = np.vstack([mesh.vertices, 0.5 * mesh.vertices[edges].sum(axis=1)])
    k = skin.joint_indices.shape[1]
    idx = np.concatenate([skin.joint_indices[edges[:, 0]], skin.joint_indices[edges[:, 1]]], 1)
    w = 0.5 * np.concatenate([skin.joint_weights[edges[:, 0]], skin.joint_weights[edges[:, 1]]], 1)
    new_idx, new_w = limit_influences(idx, w, k)
    skin2 = Skin(
        skeleton=skin.skeleton,
        joint_indices=np.vstack([skin.joint_indices, new_idx[:, :k]]),
        joint_weights=np.vstack([skin.joint_weights, new_w[:, :k]]),
        inverse_bind=skin.inverse_bind,
    )
    return Mesh(vertices=vertices, faces=faces.astype(np.int64), skin=skin2)


def _cpu_per_frame(run: Callable[[], object], repeat: int, n_frames: int) -> float:
    """The least CPU milliseconds per frame of ``repeat`` calls of ``run`` (after a warm-up)."""
    return 1e3 * best_cpu_seconds(run, repeat) / n_frames


def run_sweep_benchmark(
    *, n_frames: int = 64, repeat: int = 5, subdivide: int = 0
) -> dict[str, Any]:
    """Time the sweep deformer against LBS and DQS on the MakeHuman body walking.

    Parameters
    ----------
    n_frames : int, default 64
        Frames per timed call (the first ``n_frames`` of the walk), 1..994.
    repeat : int, default 5
        Timed calls per contender (the smallest counts), 1..100.
    subdivide : int, default 0
        Times every triangle is split in four (0..2).

    Returns
    -------
    dict
        ``vertices``, ``frames``, ``setup_cpu_s`` (fit + bind, CPU seconds),
        ``ms_per_frame`` (backend -> contender -> CPU ms: ``lbs``, ``dqs``, ``sweep``,
        ``sweep_no_volume``), ``ratios`` (backend -> ``sweep / lbs``, ``sweep / dqs``),
        ``paper`` (vertices, fps), ``lines``.
    """
    from skincap.data import path as shipped_file
    from skincap.deform.skeletal.deformers import make_deformer
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.deform.skeletal.rig import skinning_matrices
    from skincap.deform.sweep import SweepDeformer
    from skincap.io.bvh import read_bvh
    from skincap.io.makehuman import read_makehuman
    from skincap.types import Motion

    n_frames = check_bench_count("n_frames", n_frames, 1, 994)
    repeat = check_bench_count("repeat", repeat, 1, 100)
    subdivide = check_bench_count("subdivide", subdivide, 0, 2)
    body = read_makehuman(shipped_file("makehuman_base.obj"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        walk = read_bvh(shipped_file("cmu_131_01_bvh11.bvh"), units="cmu")
    short = Motion(
        walk.skeleton, walk.rotations[:n_frames], walk.translations[:n_frames], walk.rate,
        walk.channels, walk.meta,
    )  # fmt: skip
    setup = prepare_skinning(body, short)
    mesh = setup.mesh
    for _ in range(subdivide):
        mesh = subdivide_skinned(mesh)
    matrices = skinning_matrices(setup.motion, mesh.skin)  # type: ignore[arg-type]
    c0 = time.process_time()
    SweepDeformer(mesh, backend="numpy")
    setup_cpu = time.process_time() - c0
    ms: dict[str, dict[str, float]] = {}
    ratios: dict[str, dict[str, float]] = {}
    backends: dict[str, str] = {}
    for requested in ("auto", "numpy"):
        lbs = make_deformer("lbs", mesh, backend=requested)  # type: ignore[arg-type]
        name = lbs.backend if requested == "auto" else "numpy"
        if name in ms:
            continue
        backends[name] = requested
        dqs = make_deformer("dqs", mesh, backend=requested)  # type: ignore[arg-type]
        sweep = SweepDeformer(mesh, backend=requested)  # type: ignore[arg-type]
        flat = SweepDeformer(mesh, backend=requested, volume=False)  # type: ignore[arg-type]
        row = {
            "lbs": _cpu_per_frame(lambda d=lbs: d.deform(matrices), repeat, n_frames),
            "dqs": _cpu_per_frame(lambda d=dqs: d.deform(matrices), repeat, n_frames),
            "sweep": _cpu_per_frame(lambda d=sweep: d.deform(matrices), repeat, n_frames),
            "sweep_no_volume": _cpu_per_frame(lambda d=flat: d.deform(matrices), repeat, n_frames),
        }
        ms[name] = row
        ratios[name] = {
            "sweep / lbs": row["sweep"] / row["lbs"],
            "sweep / dqs": row["sweep"] / row["dqs"],
        }
    lines = [
        f"sweep deformer: MakeHuman body, {mesh.n_vertices} vertices"
        f"{f' ({subdivide}x subdivided)' if subdivide else ''}, CMU walk, {n_frames} frames per "
        f"call, best of {repeat}, CPU ms per frame (same run)",
        f"  fit + bind once: {setup_cpu:.3f} s CPU",
    ]
    for name, row in ms.items():
        r = ratios[name]
        lines.append(
            f"  skinning kernels {name:5s}: LBS {row['lbs']:.2f}  DQS {row['dqs']:.2f}  "
            f"sweep {row['sweep']:.2f} ({1e3 / row['sweep']:.0f} fps; {r['sweep / lbs']:.2f}x LBS, "
            f"{r['sweep / dqs']:.2f}x DQS)  sweep without volume {row['sweep_no_volume']:.2f}"
        )
    lines.append(
        f"  Hyun et al. 2005: {PAPER_VERTICES} vertices at ~{PAPER_FPS:g} fps "
        "(P4 2 GHz, rendering included, volume preservation excluded)"
    )
    return {
        "vertices": mesh.n_vertices,
        "frames": n_frames,
        "setup_cpu_s": setup_cpu,
        "ms_per_frame": ms,
        "ratios": ratios,
        "backends": backends,
        "paper": {"vertices": PAPER_VERTICES, "fps": PAPER_FPS},
        "lines": lines,
    }
