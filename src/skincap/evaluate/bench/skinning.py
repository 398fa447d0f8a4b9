"""Skinning benchmark: our LBS and DQS kernels against libigl (and usd-core) in one run.

Every contender deforms the same random rig -- ``n_vertices`` vertices with
``n_influences`` influences each over ``n_joints`` joints, ``n_frames`` random rigid
poses -- and the best of ``repeat`` runs is reported as milliseconds per frame,
with ratios (peer time / our time: above 1 means we are faster). Outputs are
written into preallocated buffers by every contender, so the figures compare the
kernels, not the allocator.

Peers: libigl's ``lbs_matrix`` (a dense ``(V, 4 J)`` matrix built once, outside
the timing) times the stacked transposed matrices -- libigl's own LBS, a BLAS
product; libigl's ``dqs`` when the Python bindings have it (libigl 2.6's do not);
usd-core's ``UsdSkel.SkinPoints`` (``classicLinear`` and ``dualQuaternion``,
multi-threaded, float32 points) when ``pxr`` is installed. Missing peers are
reported as ``None`` with the reason in ``notes``. Nothing is printed: ``lines``
holds the text for the CLI.
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.deform.skeletal.deformers import (
    DualQuaternionSkinning,
    LinearBlendSkinning,
    numba_available,
)
from skincap.errors import ValidationError
from skincap.evaluate.bench.common import (
    BENCH_MAX_FRAMES,
    BENCH_MAX_REPEAT,
    BENCH_MAX_VERTICES,
    best_seconds,
    check_bench_count,
)

__all__ = ["run_skinning_benchmark"]

#: Goals of the skinning issue, ms/frame for 50k vertices x 4 influences on 2 cores.
GOALS_MS = {"lbs_numba": 1.0, "dqs_numba": 2.0, "lbs_numpy": 10.0, "dqs_numpy": 10.0}
#: Goal of issue 18 for any verb's first call in a fresh process (import + compile + run).
FIRST_CALL_GOAL_S = 5.0


def _random_rig(
    n_vertices: int, n_influences: int, n_joints: int, n_frames: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    rest = rng.normal(scale=0.5, size=(n_vertices, 3))
    idx = np.stack([rng.permutation(n_joints)[:n_influences] for _ in range(16)])
    idx = idx[rng.integers(0, 16, size=n_vertices)]
    idx = (idx + rng.integers(0, n_joints, size=(n_vertices, 1))) % n_joints  # distinct per row
    w = rng.random((n_vertices, n_influences))
    w /= w.sum(axis=1, keepdims=True)
    m = np.tile(np.eye(4), (n_frames, n_joints, 1, 1))
    m[..., :3, :3] = (
        Rotation.random(n_frames * n_joints, random_state=seed)
        .as_matrix()
        .reshape(n_frames, n_joints, 3, 3)
    )
    m[..., :3, 3] = rng.normal(scale=0.3, size=(n_frames, n_joints, 3))
    return rest, idx, w, m


def run_skinning_benchmark(
    n_vertices: int = 50_000,
    n_influences: int = 4,
    n_frames: int = 64,
    repeat: int = 5,
    *,
    n_joints: int = 64,
    seed: int = 0,
    first_call: bool = True,
) -> dict[str, Any]:
    """Milliseconds per frame of our LBS/DQS kernels and of libigl (and UsdSkel).

    Parameters
    ----------
    n_vertices : int, default 50_000
    n_influences : int, default 4
        Influences per vertex (K).
    n_frames : int, default 64
        Frames deformed per run (one batched call for our kernels).
    repeat : int, default 5
        Timed runs per contender after one warm-up; the best is kept.
    n_joints : int, default 64
    seed : int, default 0
    first_call : bool, default True
        Also time the first call as a user meets it, with the default backend: a
        fresh Python process importing skincap and deforming the ``n_frames`` once,
        with a cold numba cache (compilation included) and with a warm one
        (:func:`skincap.evaluate.bench.common.first_call_in_fresh_process`).

    Returns
    -------
    dict
        ``ms_per_frame``: dict of contender -> float or None (``lbs_numba``,
        ``lbs_numpy``, ``dqs_numba``, ``dqs_numpy``, ``igl_lbs``, ``igl_dqs``,
        ``usd_lbs``, ``usd_dqs``); ``ratios``: dict of "peer / ours" speed-ups;
        ``goals``: dict of contender -> bool (goal met); ``max_abs_diff``: dict of
        agreement checks in metres (ours against each peer, and numba against
        NumPy); ``first_call``: dict of method -> ``cold_s``/``warm_s`` (import
        plus first call, seconds) or None when not measured; ``config``: the
        sizes, ``cpu_count``, numba's thread count and ``default_backend`` (what
        ``backend="auto"`` runs); ``notes``: list of str; ``lines``: list of str, a
        printable summary.
    """
    _check_sizes(n_vertices, n_influences, n_frames, repeat, n_joints)
    rest, idx, w, m = _random_rig(n_vertices, n_influences, n_joints, n_frames, seed)
    measured = _Measured({}, {}, [])
    ms, results, notes = measured.ms, measured.results, measured.notes
    rig = _Rig(rest, idx, w, m)
    threads = _time_ours(rig, repeat, measured)
    _time_libigl(rig, repeat, measured)
    _time_usdskel(rig, repeat, measured)
    default_backend = LinearBlendSkinning(rest[:1], idx[:1], w[:1]).backend
    first: dict[str, dict[str, float] | None] = {"lbs": None, "dqs": None}
    if first_call:
        first = _first_calls(n_vertices, n_influences, n_joints, n_frames, seed)

    def ratio(peer: str, ours: str) -> float | None:
        a, b = ms.get(peer), ms.get(ours)
        return None if a is None or b is None else a / b

    ratios = {
        f"{peer} / {ours}": ratio(peer, ours)
        for peer, ours in (
            ("igl_lbs", "lbs_numba"), ("igl_lbs", "lbs_numpy"), ("usd_lbs", "lbs_numba"),
            ("usd_lbs", "lbs_numpy"), ("usd_dqs", "dqs_numba"), ("usd_dqs", "dqs_numpy"),
            ("igl_dqs", "dqs_numba"), ("lbs_numpy", "lbs_numba"), ("dqs_numpy", "dqs_numba"),
        )
    }  # fmt: skip
    goals = {k: (ms[k] is not None and ms[k] <= v) for k, v in GOALS_MS.items()}

    def diff(a: str, b: str) -> float | None:
        if a not in results or b not in results:
            return None
        return float(np.abs(results[a] - results[b]).max())

    max_abs_diff = {
        "lbs_numpy vs igl_lbs": diff("lbs_numpy", "igl_lbs"),
        "lbs_numba vs lbs_numpy": diff("lbs_numba", "lbs_numpy"),
        "dqs_numba vs dqs_numpy": diff("dqs_numba", "dqs_numpy"),
        "lbs_numpy vs usd_lbs (float32)": diff("lbs_numpy", "usd_lbs"),
        "dqs_numpy vs usd_dqs (float32)": diff("dqs_numpy", "usd_dqs"),
    }
    config = {
        "n_vertices": int(n_vertices),
        "n_influences": int(n_influences),
        "n_joints": int(n_joints),
        "n_frames": int(n_frames),
        "repeat": int(repeat),
        "cpu_count": os.cpu_count(),
        "numba_threads": threads,
        "default_backend": default_backend,
    }
    report = {
        "first_call": first,
        "ms_per_frame": ms,
        "ratios": ratios,
        "goals": goals,
        "max_abs_diff": max_abs_diff,
        "config": config,
        "notes": notes,
    }
    return {**report, "lines": _summary_lines(report)}


class _Rig(NamedTuple):
    """The benchmark's rig: rest (V, 3), indices and weights (V, K), transforms (T, J, 4, 4)."""

    rest: np.ndarray
    idx: np.ndarray
    w: np.ndarray
    m: np.ndarray


class _Measured(NamedTuple):
    """What the contenders fill in: ms per frame, their outputs (T, V, 3), notes."""

    ms: dict[str, float | None]
    results: dict[str, np.ndarray]
    notes: list[str]


def _check_sizes(
    n_vertices: int, n_influences: int, n_frames: int, repeat: int, n_joints: int
) -> None:
    for name, value, high in (
        ("n_vertices", n_vertices, BENCH_MAX_VERTICES),
        ("n_influences", n_influences, 10_000),
        # one batch of (frames, vertices, 3) float64 is held per backend
        ("n_frames", n_frames, BENCH_MAX_FRAMES),
        ("repeat", repeat, BENCH_MAX_REPEAT),
        ("n_joints", n_joints, 10_000),
    ):
        check_bench_count(name, value, 1, high)
    if n_influences > n_joints:
        raise ValidationError(
            f"n_influences: {n_influences} influences need at least as many joints, got {n_joints}"
        )


def _time_ours(rig: _Rig, repeat: int, out: _Measured) -> int | None:
    """Time our LBS and DQS on every backend into ``ms``/``results``; numba's threads."""
    rest, idx, w, m = rig
    ms, results, notes = out.ms, out.results, out.notes
    n_frames, n_joints = m.shape[:2]
    buffer = np.zeros((n_frames, rest.shape[0], 3))
    threads = None
    backends = ["numpy"] + (["numba"] if numba_available() else [])
    if not numba_available():
        notes.append(
            "numba cannot be imported (a core dependency: broken install?): numba kernels not measured"
        )
        ms["lbs_numba"] = ms["dqs_numba"] = None
    else:
        import numba

        threads = int(numba.get_num_threads())
    for method, cls in (("lbs", LinearBlendSkinning), ("dqs", DualQuaternionSkinning)):
        for backend in backends:
            deformer = cls(rest, idx, w, n_joints=n_joints, backend=backend)
            key = f"{method}_{backend}"
            sec = best_seconds(lambda d=deformer: d.deform(m, out=buffer), repeat)
            ms[key] = 1e3 * sec / n_frames
            results[key] = buffer.copy()
    return threads


def _time_libigl(rig: _Rig, repeat: int, out: _Measured) -> None:
    """libigl's LBS: its ``lbs_matrix`` (built once) times the stacked transforms."""
    rest, idx, w, m = rig
    ms, results, notes = out.ms, out.results, out.notes
    n_frames, n_joints = m.shape[:2]
    n_vertices = rest.shape[0]
    ms["igl_lbs"] = ms["igl_dqs"] = None
    try:
        import igl
    except ImportError:
        notes.append("libigl (python module igl) not installed: peer not measured")
        return
    dense = np.zeros((n_vertices, n_joints))
    np.add.at(dense, (np.arange(n_vertices)[:, None], idx), w)
    lbs_matrix = igl.lbs_matrix(rest, dense)  # (V, 4 J), built once
    igl_out = np.zeros((n_vertices, 3 * n_frames))

    def igl_lbs() -> None:
        # stack of transposed transforms (4 J, 3 T): what libigl multiplies by
        stacked = np.ascontiguousarray(m[:, :, :3, :].transpose(1, 3, 0, 2)).reshape(
            4 * n_joints, 3 * n_frames
        )
        np.matmul(lbs_matrix, stacked, out=igl_out)

    ms["igl_lbs"] = 1e3 * best_seconds(igl_lbs, repeat) / n_frames
    results["igl_lbs"] = igl_out.reshape(n_vertices, n_frames, 3).transpose(1, 0, 2)
    if hasattr(igl, "dqs"):
        notes.append("igl.dqs exists but its call signature is not wired here")
    else:
        notes.append("igl.dqs: not in libigl's Python bindings (libigl 2.6): not measured")


def _time_usdskel(rig: _Rig, repeat: int, out: _Measured) -> None:
    """usd-core's ``UsdSkel.SkinPoints``, one pose per call, float32 points."""
    rest, idx, w, m = rig
    ms, results, notes = out.ms, out.results, out.notes
    n_frames = m.shape[0]
    n_vertices, n_influences = idx.shape
    ms["usd_lbs"] = ms["usd_dqs"] = None
    try:
        from pxr import Gf, UsdSkel, Vt
    except ImportError:
        notes.append("usd-core (module pxr) not installed: UsdSkel not measured")
        return
    rest32 = rest.astype(np.float32)
    usd_idx = Vt.IntArray.FromNumpy(idx.astype(np.int32).ravel())
    usd_w = Vt.FloatArray.FromNumpy(w.astype(np.float32).ravel())
    usd_out = np.zeros((n_frames, n_vertices, 3))
    identity = Gf.Matrix4d(1.0)

    for method, token in (("lbs", "classicLinear"), ("dqs", "dualQuaternion")):

        def usd_run(token: str = token) -> None:
            for t in range(n_frames):  # UsdSkel skins one pose per call
                xf = Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(m[t].transpose(0, 2, 1)))
                pts = Vt.Vec3fArray.FromNumpy(rest32)
                UsdSkel.SkinPoints(token, identity, xf, usd_idx, usd_w, n_influences, pts, False)
                usd_out[t] = np.asarray(pts)

        ms[f"usd_{method}"] = 1e3 * best_seconds(usd_run, repeat) / n_frames
        results[f"usd_{method}"] = usd_out.copy()


def _first_calls(
    n_vertices: int, n_influences: int, n_joints: int, n_frames: int, seed: int
) -> dict[str, dict[str, float] | None]:
    """Import plus first deform in a fresh process, cold and warm numba cache."""
    from skincap.evaluate.bench.common import first_call_in_fresh_process

    first: dict[str, dict[str, float] | None] = {}
    for method, cls_name in (("lbs", "LinearBlendSkinning"), ("dqs", "DualQuaternionSkinning")):
        first[method] = first_call_in_fresh_process(
            f"from skincap.deform.skeletal.deformers import {cls_name}",
            "from skincap.evaluate.bench.skinning import _random_rig\n"
            f"rest, idx, w, m = _random_rig({n_vertices}, {n_influences}, {n_joints}, "
            f"{n_frames}, {seed})",
            f"{cls_name}(rest, idx, w, n_joints={n_joints}).deform(m)",
        )
    return first


_LABELS = {
    "lbs_numba": "LBS  skincap numba",
    "lbs_numpy": "LBS  skincap NumPy",
    "igl_lbs": "LBS  libigl lbs_matrix @ T",
    "usd_lbs": "LBS  UsdSkel classicLinear",
    "dqs_numba": "DQS  skincap numba",
    "dqs_numpy": "DQS  skincap NumPy",
    "igl_dqs": "DQS  libigl dqs",
    "usd_dqs": "DQS  UsdSkel dualQuaternion",
}


def _summary_lines(report: dict[str, Any]) -> list[str]:
    """The printable summary of :func:`run_skinning_benchmark`'s result."""
    cfg, ms, goals = report["config"], report["ms_per_frame"], report["goals"]
    threads, default_backend = cfg["numba_threads"], cfg["default_backend"]
    n_frames = cfg["n_frames"]

    def fmt(v: float | None, unit: str = " ms/frame") -> str:
        return "n/a" if v is None else f"{v:.3f}{unit}"

    lines = [
        f"skinning: {cfg['n_vertices']} vertices x {cfg['n_influences']} influences, "
        f"{cfg['n_joints']} joints, {n_frames} frames, best of {cfg['repeat']}; numba threads: "
        f"{threads if threads else 'n/a'}; the default backend (backend='auto') is {default_backend}",
    ]
    for key, label in _LABELS.items():
        goal = GOALS_MS.get(key)
        tag = (
            ""
            if goal is None
            else ("  (goal <= {:g}: {})".format(goal, "met" if goals[key] else "MISSED"))
        )
        lines.append(f"  {label:30s} {fmt(ms.get(key))}{tag}")
    for key, value in report["ratios"].items():
        if value is not None:
            lines.append(f"  ratio {key:26s} {value:.2f}x")
    for key, value in report["max_abs_diff"].items():
        if value is not None:
            lines.append(f"  max |diff| {key:30s} {value:.2e} m")
    cold_runs = (
        "NumPy while numba compiles in the background" if default_backend == "numba" else "numpy"
    )
    for method, times in report["first_call"].items():
        if times is not None:
            met = max(times["cold_s"], times["warm_s"]) <= FIRST_CALL_GOAL_S
            lines.append(
                f"  first call {method.upper()} (fresh process, import + {n_frames} frames, "
                f"backend='auto'): cold cache {times['cold_s']:.2f} s (CPU "
                f"{times['cold_cpu_s']:.2f} s; {cold_runs}), "
                f"warm cache {times['warm_s']:.2f} s (CPU {times['warm_cpu_s']:.2f} s; "
                f"{default_backend}) (goal <= {FIRST_CALL_GOAL_S:g} s: "
                + ("met" if met else "MISSED")
                + ")"
            )
    lines += [f"  note: {n}" for n in report["notes"]]
    return lines
