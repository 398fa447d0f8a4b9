"""Dense-deformation benchmark: ms/frame of the four variants against our LBS, in one run.

The scene is a chain of ``n_parts`` tube segments (a limb-like body along x) carrying
``n_markers`` markers on rings and ``n_vertices`` skin vertices; each segment turns
about the end of the previous one (a kinematic chain of sinusoidal joint angles), so
every part moves rigidly and the markers near a joint are shared. The dense deformer
(:class:`skincap.deform.dense.deformer.DenseDeformer`) deforms ``n_frames`` frames per
run (the per-frame fits and the vertices), once with each backend: the numba kernel
and its NumPy reference. The parts and vertices are set up as a subject rig's deformer
sets them up (:func:`default_parts`): each part with its seam centres (the markers one
tube-surface edge beyond it, centres of its second RBF field) and each vertex with its
seam weights, so the figures are those of the default ``animate``. The baseline is our linear blend skinning of the same
vertices with the same part weights as joint weights (two influences), on the same
backend, timed in the same process. Also timed: the first call in a fresh process
(import, binding and one deform with the default backend) with a cold and a warm numba
cache, the automatic segmentation of a ``rom_frames``-frame take of the same markers,
and the registration of §5.1.

Also timed alone: the per-frame fits of ``quadratic_rbf`` (rigid, quadratic, RBF: NumPy
on both backends) and, on each backend, the vertex pass of eqs. 8-9 given those fits
(:meth:`~skincap.deform.dense.deformer.DenseDeformer.deform_block`), so a frame splits
into the fits, the vertex pass and the rest (the streaming's own work per chunk).

Ratios are ``dense / LBS`` of CPU times (how many times LBS's cost a frame of each
variant is), NumPy / numba and fits / frame; the ms figures are for the record of this
machine only.
Nothing is printed: ``lines`` holds the text for the CLI.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any, Literal, cast

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.deform.dense.deformer import METHODS, DenseDeformer, Method, fit_part_motion
from skincap.deform.dense.parts import PartFrames, part_frames
from skincap.deform.dense.segmentation import segment_marker_surface
from skincap.deform.dense.weights import seam_vertex_weights
from skincap.deform.skeletal.deformers import LinearBlendSkinning
from skincap.errors import MissingDependencyError, ValidationError
from skincap.evaluate.bench.common import (
    BENCH_MAX_FRAMES,
    BENCH_MAX_REPEAT,
    BENCH_MAX_ROM_FRAMES,
    BENCH_MAX_VERTICES,
    check_bench_count,
)

__all__ = ["GOALS_MS", "chain_scene", "default_parts", "run_animate_benchmark"]

#: Goals of issue #16 (2 cores): ms/frame at 50k vertices, seconds for the fits.
GOALS_MS = {"quadratic_rbf_numpy": 20.0, "quadratic_rbf_numba": 5.0}
GOALS_S = {"segmentation_1000_frames": 30.0, "registration_20k_vertices": 60.0}
_BACKENDS: tuple[Literal["numpy", "numba"], ...] = ("numpy", "numba")


def _ring_tube(
    n_rings: int, n_around: int, radius: float, length: float
) -> tuple[np.ndarray, np.ndarray]:
    x = np.linspace(0.0, length, n_rings)
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    xx, aa = np.meshgrid(x, a, indexing="ij")
    pts = np.stack([xx.ravel(), radius * np.cos(aa).ravel(), radius * np.sin(aa).ravel()], 1)
    idx = np.arange(n_rings * n_around).reshape(n_rings, n_around)
    nxt = np.roll(idx, -1, axis=1)
    a0, b0, c0, d0 = idx[:-1].ravel(), idx[1:].ravel(), nxt[1:].ravel(), nxt[:-1].ravel()
    return pts, np.concatenate([np.stack([a0, c0, b0], 1), np.stack([a0, d0, c0], 1)])


def _chain_transforms(n_parts: int, n_frames: int, length: float, seed: int) -> np.ndarray:
    """(T, P, 4, 4) world transforms of a chain of parts hinged at x = p * length / P."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 120.0
    amp = rng.uniform(0.2, 0.8, size=(n_parts, 3))
    freq = rng.uniform(0.3, 1.5, size=(n_parts, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(n_parts, 3))
    angles = amp[None] * np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None])
    local = np.tile(np.eye(4), (n_frames, n_parts, 1, 1))
    local[..., :3, :3] = (
        Rotation.from_rotvec(angles.reshape(-1, 3)).as_matrix().reshape(n_frames, n_parts, 3, 3)
    )
    world = np.empty_like(local)
    seg = length / n_parts
    for p in range(n_parts):  # the chain: P (17) steps, vectorised over frames
        pivot = np.eye(4)
        pivot[0, 3] = p * seg
        back = np.eye(4)
        back[0, 3] = -p * seg
        step = pivot @ local[:, p] @ back
        world[:, p] = step if p == 0 else world[:, p - 1] @ step
    return world


def chain_scene(
    n_vertices: int = 50_000,
    n_parts: int = 17,
    n_markers: int = 350,
    n_frames: int = 64,
    *,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """The benchmark's body: markers, surface, weights, vertices and frames.

    Returns
    -------
    dict
        ``reference`` (N, 3), ``faces`` (F, 3) marker-surface triangles, ``alpha``
        (N, P), ``vertices`` (V, 3), ``beta`` (V, P), ``markers`` (T, N, 3),
        ``transforms`` (T, P, 4, 4): every array in metres.
    """
    check_bench_count("n_vertices", n_vertices, 1, BENCH_MAX_VERTICES)
    check_bench_count("n_frames", n_frames, 1, BENCH_MAX_FRAMES)
    check_bench_count("n_parts", n_parts, 1, 200)
    check_bench_count("n_markers", n_markers, 1, 100_000)
    if n_parts < 1 or n_markers < 6 * n_parts or n_vertices < 1 or n_frames < 1:
        raise ValidationError(
            f"need parts >= 1, markers >= 6 per part, vertices and frames >= 1; got "
            f"{n_parts}, {n_markers}, {n_vertices}, {n_frames}"
        )
    length = 0.1 * n_parts
    around = 10
    rings = max(2, n_markers // around)
    reference, faces = _ring_tube(rings, around, 0.06, length)
    seg = length / n_parts

    def part_weights(x: np.ndarray) -> np.ndarray:
        """Hard parts by x, linear ramps 1 cm either side of each joint."""
        u = np.clip(x / seg - 0.5, 0.0, n_parts - 1.0)
        lo = np.floor(u).astype(int)
        ramp = np.clip((u - lo - 0.5) * seg / 0.02 + 0.5, 0.0, 1.0)  # the joint at u - lo = 0.5
        w = np.zeros((x.size, n_parts))
        w[np.arange(x.size), lo] = 1.0 - ramp
        w[np.arange(x.size), np.minimum(lo + 1, n_parts - 1)] += ramp
        return w

    alpha = part_weights(reference[:, 0])
    rng = np.random.default_rng(seed)
    vx = rng.uniform(0.0, length, n_vertices)
    va = rng.uniform(0.0, 2 * np.pi, n_vertices)
    vertices = np.stack([vx, 0.05 * np.cos(va), 0.05 * np.sin(va)], 1)
    beta = part_weights(vx)
    world = _chain_transforms(n_parts, n_frames, length, seed)
    owner = np.argmax(alpha, axis=1)
    moved = world[:, owner]  # (T, N, 4, 4)
    markers = np.einsum("tnab,nb->tna", moved[..., :3, :3], reference) + moved[..., :3, 3]
    return {
        "reference": reference,
        "faces": faces,
        "alpha": alpha,
        "vertices": vertices,
        "beta": beta,
        "markers": markers,
        "transforms": world,
    }


def default_parts(scene: dict[str, np.ndarray]) -> tuple[PartFrames, np.ndarray]:
    """The parts and seam weights of ``scene`` as a rig's deformer builds them.

    Like :meth:`skincap.deform.dense.rig.DenseRig.deformer`: the parts carry their seam
    centres (the marker-surface triangles given), and every vertex its seam weights,
    so the fits solve both RBF fields of every part and the kernels blend them.

    Returns
    -------
    parts : PartFrames
    seam_weights : (V, P) float64 in [0, 1]
    """
    parts = part_frames(scene["reference"], scene["alpha"], surface_faces=scene["faces"])
    seam = seam_vertex_weights(
        scene["vertices"], scene["reference"], scene["faces"], scene["alpha"] > 0
    )
    return parts, seam


def _best_wall_and_cpu(run: Callable[[], object], repeat: int) -> tuple[float, float]:
    """One warm-up call, then the smallest wall-clock and the smallest CPU seconds
    (every thread of this process) of ``repeat`` calls."""
    run()
    wall = cpu = float("inf")
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        run()
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def _first_call(n_vertices: int, n_parts: int, n_markers: int, n_frames: int, seed: int) -> Any:
    """Import, binding and the first ``quadratic_rbf`` deform in a fresh process."""
    from skincap.evaluate.bench.common import first_call_in_fresh_process

    return first_call_in_fresh_process(
        "from skincap.deform.dense.deformer import DenseDeformer",
        "from skincap.evaluate.bench.animate import chain_scene, default_parts\n"
        f"s = chain_scene({n_vertices}, {n_parts}, {n_markers}, {n_frames}, seed={seed})\n"
        "parts, seam = default_parts(s)",
        "list(DenseDeformer(parts, s['vertices'], s['beta'], seam_weights=seam)"
        f".deform(s['markers'], chunk={n_frames}))",
    )


def run_animate_benchmark(
    n_vertices: int = 50_000,
    n_parts: int = 17,
    n_markers: int = 350,
    n_frames: int = 32,
    repeat: int = 3,
    *,
    rom_frames: int = 1000,
    seed: int = 0,
    first_call: bool = True,
    registration: bool = True,
) -> dict[str, Any]:
    """Milliseconds per frame of the dense variants on each backend and of our LBS; fit times.

    Parameters
    ----------
    n_vertices, n_parts, n_markers : int
        The scene (:func:`chain_scene`).
    n_frames : int
        Frames deformed per timed run (one chunk: the fits and the vertices).
    repeat : int
        Timed runs after one warm-up; the best is kept.
    rom_frames : int
        Frames of the take the segmentation is timed on (0: not timed).
    seed : int
    first_call : bool
        Also time the first call as a user meets it: a fresh Python process importing
        skincap, binding the mesh and deforming the ``n_frames`` with ``quadratic_rbf``
        and the default backend, with a cold numba cache and with a warm one
        (:func:`skincap.evaluate.bench.common.first_call_in_fresh_process`).
    registration : bool
        Also time the registration of a 20k-vertex tube to the markers.

    Returns
    -------
    dict
        ``ms_per_frame`` and ``cpu_ms_per_frame`` (``<method>_numpy``,
        ``<method>_numba``, ``lbs_numpy``, ``lbs_numba``, ``fits_quadratic_rbf``:
        the per-frame rigid, quadratic and RBF fits alone, part of every dense figure,
        and ``vertices_quadratic_rbf_<backend>``: the vertex pass alone, given the fits;
        None when not measured: CPU counts every thread, the figure a loaded machine
        distorts least), ``ratios`` (``<method>_<backend> / lbs_<backend>`` of CPU
        times, numba's speed-up over NumPy, and the fits' and the vertex pass's shares
        of a ``quadratic_rbf`` frame on each backend), ``max_abs_diff`` (numba against NumPy, metres),
        ``first_call`` (``cold_s``, ``warm_s``, ``cold_cpu_s``, ``warm_cpu_s`` or
        None), ``seconds`` (``segmentation``, ``registration`` or None), ``goals``,
        ``config``, ``notes``, ``lines``.
    """
    if repeat < 1:
        raise ValidationError(f"repeat must be >= 1; got {repeat}")
    check_bench_count("repeat", repeat, 1, BENCH_MAX_REPEAT)
    check_bench_count("rom_frames", rom_frames, 0, BENCH_MAX_ROM_FRAMES)
    scene = chain_scene(n_vertices, n_parts, n_markers, n_frames, seed=seed)
    notes: list[str] = []
    parts, seam = default_parts(scene)
    ms: dict[str, float | None] = {}
    cpu_ms: dict[str, float | None] = {}
    outputs = _time_dense_variants(scene, parts, seam, n_frames, repeat, ms, cpu_ms, notes)
    _time_lbs(scene, n_parts, n_vertices, n_frames, repeat, ms, cpu_ms, notes)
    fits = partial(fit_part_motion, scene["markers"], parts, "quadratic_rbf")
    _time_per_frame("fits_quadratic_rbf", fits, repeat, n_frames, ms, cpu_ms)
    ratios = _cpu_ratios(cpu_ms)
    max_abs_diff = _numba_vs_numpy_diff(outputs)
    first = _first_call(n_vertices, n_parts, n_markers, n_frames, seed) if first_call else None
    default_backend = DenseDeformer(
        parts, scene["vertices"][:1], scene["beta"][:1], seam_weights=seam[:1]
    ).backend
    seconds: dict[str, float | None] = {"segmentation": None, "registration": None}
    if rom_frames > 0:
        seconds["segmentation"] = _segmentation_seconds(n_parts, n_markers, rom_frames, seed)
    if registration:
        seconds["registration"] = _registration_seconds(scene, notes)
    config = {
        "vertices": n_vertices,
        "parts": n_parts,
        "markers": int(scene["reference"].shape[0]),
        "frames": n_frames,
        "rom_frames": rom_frames,
        "repeat": repeat,
        "default_backend": default_backend,
    }
    report = {
        "ms_per_frame": ms,
        "cpu_ms_per_frame": cpu_ms,
        "ratios": ratios,
        "max_abs_diff": max_abs_diff,
        "first_call": first,
        "seconds": seconds,
        "goals": _goals_met(ms, seconds, rom_frames),
        "config": config,
        "notes": notes,
    }
    report["lines"] = _summary_lines(report)
    return report


def _time_per_frame(
    key: str,
    run: Callable[[], object],
    repeat: int,
    n_frames: int,
    ms: dict[str, float | None],
    cpu_ms: dict[str, float | None],
) -> None:
    """Store under ``key`` in ``ms`` / ``cpu_ms`` the best wall / CPU milliseconds per
    frame of ``run`` (one warm-up, then ``repeat`` calls of ``n_frames`` frames each)."""
    wall, cpu = _best_wall_and_cpu(run, repeat)
    ms[key], cpu_ms[key] = 1e3 * wall / n_frames, 1e3 * cpu / n_frames


def _time_dense_variants(
    scene: dict[str, np.ndarray],
    parts: PartFrames,
    seam: np.ndarray,
    n_frames: int,
    repeat: int,
    ms: dict[str, float | None],
    cpu_ms: dict[str, float | None],
    notes: list[str],
) -> dict[str, np.ndarray]:
    """Time every dense method on each backend (the parts with seam centres and the
    vertices' seam weights ``seam``, as a rig deforms) into ``ms`` / ``cpu_ms`` (ms/frame,
    ``<method>_<backend>``; None and a note when the backend is missing).

    Returns
    -------
    dict
        ``<method>_<backend>`` -> (T, V, 3) float64 deformed vertices, metres.
    """
    outputs: dict[str, np.ndarray] = {}
    for backend in _BACKENDS:
        try:
            deformer = DenseDeformer(
                parts, scene["vertices"], scene["beta"], seam_weights=seam, backend=backend
            )
        except MissingDependencyError as exc:  # numba missing: reported, not fatal
            notes.append(f"dense {backend} not measured: {exc}")
            for key in (*METHODS, "vertices_quadratic_rbf"):
                ms[f"{key}_{backend}"] = cpu_ms[f"{key}_{backend}"] = None
            continue
        motion = fit_part_motion(scene["markers"], deformer.parts, "quadratic_rbf")
        vertex_pass = partial(deformer.deform_block, motion)
        _time_per_frame(
            f"vertices_quadratic_rbf_{backend}", vertex_pass, repeat, n_frames, ms, cpu_ms
        )
        for method in METHODS:

            def deform_all(
                deformer: DenseDeformer = deformer, method: Method = cast("Method", method)
            ) -> list[np.ndarray]:
                return list(deformer.deform(scene["markers"], method, chunk=n_frames))

            _time_per_frame(f"{method}_{backend}", deform_all, repeat, n_frames, ms, cpu_ms)
            outputs[f"{method}_{backend}"] = np.concatenate(deform_all())
    return outputs


def _time_lbs(
    scene: dict[str, np.ndarray],
    n_parts: int,
    n_vertices: int,
    n_frames: int,
    repeat: int,
    ms: dict[str, float | None],
    cpu_ms: dict[str, float | None],
    notes: list[str],
) -> None:
    """Time our LBS of the same vertices on each backend into ``ms`` / ``cpu_ms``
    (ms/frame, ``lbs_<backend>``): the parts as joints, β as two-influence weights."""
    order = np.argsort(-scene["beta"], axis=1)[:, :2]
    weights = np.take_along_axis(scene["beta"], order, axis=1)
    weights /= weights.sum(axis=1, keepdims=True)
    for backend in _BACKENDS:
        try:
            lbs = LinearBlendSkinning(
                scene["vertices"], order, weights, n_joints=n_parts, backend=backend
            )
        except MissingDependencyError as exc:
            notes.append(f"LBS {backend} not measured: {exc}")
            ms[f"lbs_{backend}"] = cpu_ms[f"lbs_{backend}"] = None
            continue
        buffer = np.zeros((n_frames, n_vertices, 3))
        run = partial(lbs.deform, scene["transforms"], out=buffer)
        _time_per_frame(f"lbs_{backend}", run, repeat, n_frames, ms, cpu_ms)


def _cpu_ratios(cpu_ms: dict[str, float | None]) -> dict[str, float | None]:
    """``<method>_<backend> / lbs_<backend>`` and ``<method>_numpy / <method>_numba`` of
    the CPU ms/frame (None when either is missing or the divisor is 0)."""

    def ratio(a: str, b: str) -> float | None:
        x, y = cpu_ms.get(a), cpu_ms.get(b)
        return None if x is None or not y else x / y

    ratios = {
        f"{m}_{b} / lbs_{b}": ratio(f"{m}_{b}", f"lbs_{b}")
        for b in ("numpy", "numba")
        for m in METHODS
    }
    ratios.update({f"{m}_numpy / {m}_numba": ratio(f"{m}_numpy", f"{m}_numba") for m in METHODS})
    # the shares of the per-frame fits (NumPy on both backends) and of the vertex pass
    # in a deformed frame
    for b in ("numpy", "numba"):
        for part in ("fits_quadratic_rbf", f"vertices_quadratic_rbf_{b}"):
            ratios[f"{part} / quadratic_rbf_{b}"] = ratio(part, f"quadratic_rbf_{b}")
    return ratios


def _numba_vs_numpy_diff(outputs: dict[str, np.ndarray]) -> dict[str, float | None]:
    """Largest absolute difference (metres) of each method's numba output from its NumPy
    output (None unless both were measured)."""
    return {
        f"{m}_numba vs {m}_numpy": float(
            np.abs(outputs[f"{m}_numba"] - outputs[f"{m}_numpy"]).max()
        )
        if f"{m}_numba" in outputs and f"{m}_numpy" in outputs
        else None
        for m in METHODS
    }


def _segmentation_seconds(n_parts: int, n_markers: int, rom_frames: int, seed: int) -> float:
    """Wall-clock seconds of segmenting a ``rom_frames``-frame take of the chain's markers."""
    rom = chain_scene(1, n_parts, n_markers, rom_frames, seed=seed + 1)
    t0 = time.perf_counter()
    segment_marker_surface(rom["markers"], rom["reference"], rom["faces"], n_parts=n_parts)
    return time.perf_counter() - t0


def _goals_met(
    ms: dict[str, float | None], seconds: dict[str, float | None], rom_frames: int
) -> dict[str, bool | None]:
    """Whether each goal of :data:`GOALS_MS` / :data:`GOALS_S` is met (None: not measured,
    or the segmentation was not timed on 1000 frames)."""

    def met(key: str) -> bool | None:
        value = ms.get(key)
        return None if value is None else value <= GOALS_MS[key]

    return {
        "quadratic_rbf_numpy": met("quadratic_rbf_numpy"),
        "quadratic_rbf_numba": met("quadratic_rbf_numba"),
        "segmentation": None
        if seconds["segmentation"] is None or rom_frames != 1000
        else seconds["segmentation"] <= GOALS_S["segmentation_1000_frames"],
    }


def _summary_lines(report: dict[str, Any]) -> list[str]:
    """The printable summary of :func:`run_animate_benchmark`'s result."""
    cfg, ms, cpu_ms, goals = (
        report["config"],
        report["ms_per_frame"],
        report["cpu_ms_per_frame"],
        report["goals"],
    )
    lines = [
        f"dense deformation, {cfg['vertices']} vertices, {cfg['parts']} parts, "
        f"{cfg['markers']} markers, {cfg['frames']} frames a run (fits + vertices; "
        f"best of {cfg['repeat']}; CPU = every thread):"
    ]
    for key, value in ms.items():
        if value is None:
            lines.append(f"  {key:28s} not measured")
            continue
        goal = GOALS_MS.get(key)
        tag = (
            "" if goal is None else f"  (goal <= {goal:g} ms: {'met' if goals[key] else 'MISSED'})"
        )
        lines.append(f"  {key:28s} {value:9.3f} ms/frame  CPU {cpu_ms[key]:9.3f} ms/frame{tag}")
    for key, value in report["ratios"].items():
        if value is not None:
            lines.append(f"  CPU ratio {key:34s} {value:7.2f}x")
    for key, value in report["max_abs_diff"].items():
        if value is not None:
            lines.append(f"  max |diff| {key:34s} {value:.2e} m")
    first = report["first_call"]
    if first is not None:
        cold_runs = (
            "NumPy while numba compiles in the background"
            if cfg["default_backend"] == "numba"
            else "NumPy"
        )
        lines.append(
            f"  first call quadratic_rbf (fresh process, import + binding + {cfg['frames']} "
            f"frames, backend='auto'): cold cache {first['cold_s']:.2f} s (CPU "
            f"{first['cold_cpu_s']:.2f} s; {cold_runs}), warm cache {first['warm_s']:.2f} s "
            f"(CPU {first['warm_cpu_s']:.2f} s; {cfg['default_backend']})"
        )
    for key, value in report["seconds"].items():
        lines.append(f"  {key:22s} " + ("not measured" if value is None else f"{value:.2f} s"))
    lines += [f"  note: {n}" for n in report["notes"]]
    return lines


def _registration_seconds(scene: dict[str, np.ndarray], notes: list[str]) -> float | None:
    try:
        from skincap.deform.dense import registration
    except ImportError:
        notes.append(
            "registration not measured: skincap.deform.dense.registration is not in this build"
        )
        return None
    verts, faces = _ring_tube(200, 100, 0.05, float(scene["reference"][:, 0].max()))  # 20k vertices
    labels = [f"M{i:03d}" for i in range(scene["reference"].shape[0])]
    t0 = time.perf_counter()
    registration.register_mesh(verts, faces, scene["reference"], labels)
    return time.perf_counter() - t0
