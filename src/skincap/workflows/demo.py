"""``skincap demo``: the whole chain on data skincap makes or ships, with an HTML report.

1. A synthetic jump-rope capture (procedural soft-tissue body, dense markers, a rope,
   a camera ring with occlusion, broken trajectories, ghosts), written with its truth.
2. Cleanup (Park & Hodgins §4): marker surface, merge, local-PCA fill, smoothing;
   then every fill method scored on punched gaps against the truth.
3. Rope tracking (Porter): found automatically among the un-indexed points, tracked,
   gaps repaired; classification and gap repair scored against the truth.
4. Dense skin (Park & Hodgins §5): the synthetic take's markers drive its body by the
   four part-deformer variants and one global RBF, scored against the true skin.
4b. Skinning: the shipped CC0 MakeHuman body walks a real CMU capture (glTF with LBS,
   PC2 point cache with DQS), with the LBS/DQS artefact table.
5. The shipped real captures converted between formats.
6. ``report.html``: missing-data maps, error plots, tables, timings and rendered frames.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.data import path as shipped_file

__all__ = ["run_demo", "DEMO_FRAMES"]

DEMO_C3D = "kt_optitrack_walking.c3d"
DEMO_BVH = "bvhtoolbox_test_mocapbank.bvh"
DEMO_BODY = "makehuman_base.obj"  # with makehuman_default.mhskel/.mhw beside it
DEMO_WALK = "cmu_131_01_bvh11.bvh"  # CMU units
#: Frames of the walk baked into the DQS point cache (2 s at 120 Hz keeps it ~30 MB).
DEMO_PC2_FRAMES = 240
#: Frames of the synthetic take (120 Hz): 4 s, about five turns of the rope.
DEMO_FRAMES = 480
#: Vertices of the synthetic body (the camera model's occlusion cost grows with it).
DEMO_BODY_VERTICES = 8000


class _Steps:
    """Progress reporting and timing of the demo's steps: wall-clock seconds, and the
    CPU seconds of this process (what a busy machine distorts least)."""

    def __init__(self, progress: Progress | None) -> None:
        self.progress = progress
        self.timings: dict[str, float] = {}
        self.cpu_timings: dict[str, float] = {}

    @contextmanager
    def step(self, fraction: float, label: str) -> Iterator[None]:
        if self.progress is not None:
            self.progress(fraction, label)
        start, cpu_start = time.perf_counter(), time.process_time()
        yield
        self.timings[label] = time.perf_counter() - start
        self.cpu_timings[label] = time.process_time() - cpu_start

    def within(self, lo: float, hi: float, label: str) -> Callable[[float], None]:
        """A fraction callback mapping 0..1 of a step onto lo..hi of the whole demo."""

        def report(f: float, *_: Any) -> None:
            if self.progress is not None:
                self.progress(lo + (hi - lo) * float(f), label)

        return report


#: The shipped files the demo reads (protected: no output may replace them).
DEMO_INPUTS = (
    DEMO_C3D,
    DEMO_BVH,
    DEMO_BODY,
    "makehuman_default.mhskel",
    "makehuman_default_weights.mhw",
    DEMO_WALK,
    "cmu_85_02.c3d",
)
#: Files and folders the demo writes (checked before anything is written).
DEMO_OUTPUTS = (
    "report.html",
    "cleaned.c3d",
    "results.json",
    "walk.glb",
    "walk_dqs.pc2",
    "real/solved.bvh",
)


def run_demo(
    output: str | os.PathLike[str],
    *,
    force: bool = False,
    frames: int = DEMO_FRAMES,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Run the whole chain and write every output plus ``report.html`` into ``output``.

    Parameters
    ----------
    output : path-like
        Folder for the outputs; created if missing.
    force : bool
        Replace outputs of an earlier run (otherwise an existing one is refused
        before anything is written).
    frames : int
        Frames of the synthetic take at 120 Hz (at least 240: the rope needs a
        still start and a few turns).
    progress : callable(fraction, label), optional
        Called as the steps advance.

    Returns
    -------
    dict
        ``outputs`` (written paths), ``timings`` (wall-clock seconds per step),
        ``cpu_timings`` (CPU seconds of this process per step), ``figures`` (the
        measured numbers of the report), ``report`` (its path), ``view`` (the
        ``skincap view`` command lines: raw against cleaned capture with the rope;
        the walking body; the body on the skeleton solved from the real capture), ``summaries`` (real inputs).
    """
    from skincap.errors import ValidationError

    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 240:
        raise ValidationError(f"frames: at least 240, got {frames!r}")
    from skincap.synth.clips import clip_frame_count

    clip_frame_count(frames, None, 120.0)  # the synthetic take's upper bound, before any work
    from skincap.io.output_safety import guard_outputs

    folder = Path(output)
    shipped = [shipped_file(name) for name in DEMO_INPUTS]
    with guard_outputs(
        shipped, [folder / name for name in DEMO_OUTPUTS], folders=[folder], force=force
    ):
        return _run_demo(folder, force=force, frames=frames, progress=progress)


def _run_demo(
    folder: Path, *, force: bool, frames: int, progress: Progress | None
) -> dict[str, Any]:
    folder.mkdir(parents=True, exist_ok=True)
    steps = _Steps(progress)
    figures: dict[str, Any] = {}
    outputs: list[Path] = []
    t_start, cpu_start = time.perf_counter(), time.process_time()
    # the numba kernels not compiled yet compile in the background from now on, beside
    # the synthetic capture, instead of when tracking and skinning first need them
    from skincap.backends import start_pending_compiles

    start_pending_compiles()

    take = _synthetic_take(folder, steps, frames, force, outputs, figures)
    cleaned = _clean(folder, steps, take, force, outputs, figures)
    fill_eval = _evaluate_fill(folder, steps, take, force, outputs, figures)
    track_eval = _track(folder, steps, take, force, outputs, figures)
    _dense(folder, steps, take, force, outputs, figures)
    body = _skin(folder, steps, force, outputs, figures)
    artefacts = _artefacts(steps, body, figures)
    _solve_real(folder, steps, body, force, outputs, figures)
    summaries = _convert_real_data(folder, steps, force, outputs)
    pictures = _render(folder, steps, force, outputs)
    figures["total_seconds"] = time.perf_counter() - t_start
    figures["total_cpu_seconds"] = time.process_time() - cpu_start
    with steps.step(0.98, "writing the report"):
        from skincap.workflows.demo_report import write_demo_report

        report = write_demo_report(
            folder,
            take=take,
            cleaned=cleaned,
            fill_eval=fill_eval,
            track_eval=track_eval,
            artefacts=artefacts,
            pictures=pictures,
            figures=figures,
            timings=steps.timings,
            cpu_timings=steps.cpu_timings,
            force=force,
        )
    results = {"figures": figures, "timings": steps.timings, "cpu_timings": steps.cpu_timings}
    _write_json(folder / "results.json", results, force)
    outputs += [report, folder / "results.json"]
    if progress is not None:
        progress(1.0, "done")
    views = [
        f"skincap view {folder / 'synth' / 'capture.c3d'} {folder / 'cleaned.c3d'} "
        f"{folder / 'track' / 'rope_curve.csv'}",
        f"skincap view {folder / 'walk.glb'}",
        f"skincap view {folder / 'real' / 'cleaned.c3d'} {folder / 'real' / 'solved_body.glb'}",
    ]
    return {
        "outputs": [str(p) for p in outputs],
        "timings": steps.timings,
        "cpu_timings": steps.cpu_timings,
        "figures": figures,
        "report": str(report),
        "view": views,
        "summaries": summaries,
    }


def _write_json(path: Path, data: Any, force: bool) -> None:
    from skincap.io._common import atomic_output

    with atomic_output(path, force=force) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=_jsonable) + "\n", encoding="utf-8")


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON: {type(value).__name__}")


def _body_columns(labels: list[str]) -> list[int]:
    return [i for i, lab in enumerate(labels) if not lab.startswith(("rope_", "*"))]


def _synthetic_take(
    folder: Path, steps: _Steps, frames: int, force: bool, outputs: list[Path], figures: dict
) -> Any:
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion
    from skincap.workflows.synth_folder import write_synth_outputs

    with steps.step(0.0, "synthetic capture"):
        body = build_body("procedural", n_vertices=DEMO_BODY_VERTICES)
        motion = build_motion(body, "jumprope", frames=frames)
        take = generate_capture(
            body,
            motion,
            markers="dense",
            rope="jump",
            seed=0,
            progress=steps.within(0.0, 0.3, "synthetic capture"),
        )
        outputs += write_synth_outputs(take, folder / "synth", force=force)
    s = take.summary
    figures["synthetic"] = {
        key: s[key]
        for key in (
            "frames", "rate", "markers", "rope_markers", "fragments", "missing_fraction",
            "ghosts", "points", "mesh_vertices", "cameras",
        )
    }  # fmt: skip
    return take


def _clean(
    folder: Path, steps: _Steps, take: Any, force: bool, outputs: list[Path], figures: dict
) -> Any:
    from skincap.cleanup.pipeline import clean_markers
    from skincap.io.c3d import write_c3d

    with steps.step(0.3, "cleanup"):
        cleaned, report = clean_markers(
            take.capture,
            fragment_truth=take.fragment_truth,
            progress=steps.within(0.3, 0.42, "cleanup"),
        )
        write_c3d(cleaned, folder / "cleaned.c3d", force=force)
        _write_json(folder / "clean_report.json", report.as_dict(), force)
    outputs += [folder / "cleaned.c3d", folder / "clean_report.json"]
    from skincap.workflows.demo_report import labelled_missing_maps

    before, after, filled = labelled_missing_maps(take.capture, cleaned)
    merge, fill = report.merge, report.fill
    figures["cleanup"] = {
        # over the raw capture's labelled columns, as the report's table and figure
        "labelled_missing_before": float(before.mean()),
        "labelled_missing_after": float(after.mean()),
        "labelled_filled": float(filled.mean()),
        "surface_edges": report.surface.edges,
        "trajectories_before": merge.trajectories_before,
        "trajectories_after": merge.trajectories_after,
        "fragments_before": merge.fragments_before,
        "fragments_after": merge.fragments_after,
        "merged": merge.merged,
        "wrongly_merged": merge.wrongly_merged,
        "wrong_rate": merge.wrong_rate,
        "left_unmerged": merge.left_unmerged,
        "holes_before": fill.holes_before,
        "invented_samples": fill.invented_samples,
        "unfilled_samples": fill.unfilled_samples,
    }
    return cleaned


def _evaluate_fill(
    folder: Path, steps: _Steps, take: Any, force: bool, outputs: list[Path], figures: dict
) -> dict:
    from skincap.evaluate.cleanup import evaluate_fill

    with steps.step(0.42, "gap-fill evaluation"):
        # the measured labelled markers, noise and real occlusions included; the take is
        # synthetic, so the fills are scored against its noise-free truth (the fill's own
        # error) and, beside it, against the measured samples they replace (the paper's
        # and `skincap eval fill capture.c3d`'s reference, which adds the samples' own
        # noise); only the punched gaps are filled (a fifth of this take is missing, and
        # filling it all for every method and round would take minutes), and the gaps
        # of all lengths share rounds: each method fills 2 rounds instead of 4 on the
        # default take (the whole-body PCA alone refits the take on every fill)
        labels = list(take.capture.labels)
        cols = _body_columns(labels)
        body = take.capture.select(cols)
        truth_col = {lab: i for i, lab in enumerate(take.truth.labels)}
        truth = take.truth.positions[:, [truth_col[labels[i]] for i in cols]]
        result = evaluate_fill(
            body,
            gap_lengths=(10, 30, 60, 90),
            gaps=3,
            seed=0,
            truth=truth,
            fill_own_gaps=False,
            lengths_together=True,
            progress=steps.within(0.42, 0.55, "gap-fill evaluation"),
        )
        _write_json(folder / "fill_evaluation.json", result, force)
    outputs.append(folder / "fill_evaluation.json")

    def summary(results: dict) -> dict:
        return {
            method: {
                "mean_normalised": per["all"]["normalised"]["mean"],
                "max_normalised": per["all"]["normalised"]["max"],
                "mean_mm": per["all"]["mm"]["mean"],
            }
            for method, per in results.items()
        }

    figures["fill"] = summary(result["results"])
    figures["fill_measured"] = summary(result["results_measured"])
    from skincap.workflows.demo_report import fill_verdict

    figures["fill_verdict"] = fill_verdict(figures["fill"])
    figures["fill_verdict_measured"] = fill_verdict(figures["fill_measured"])
    return result


def _track(
    folder: Path, steps: _Steps, take: Any, force: bool, outputs: list[Path], figures: dict
) -> dict:
    from skincap.evaluate.tracking import classify_points, evaluate_tracking
    from skincap.tracking.init import init_rope
    from skincap.tracking.tracker import track_rope
    from skincap.workflows.track_file import write_track_outputs

    with steps.step(0.55, "rope tracking"):
        init = init_rope(take.points, auto=True)
        track = track_rope(take.points, init)
        report = write_track_outputs(take.points, track, folder / "track", force=force)
        scores = classify_points(track, take.points, take.point_truth)
    outputs += [folder / "track" / n for n in ("rope.c3d", "body_points.csv", "rope_curve.csv")]
    with steps.step(0.6, "rope gap-repair evaluation"):
        result = evaluate_tracking(
            take.points,
            take.point_truth,
            take.truth,
            gaps=(10, 20, 30, 60),
            starts=2,
            seed=0,
            progress=steps.within(0.6, 0.7, "rope gap-repair evaluation"),
        )
        _write_json(folder / "track_evaluation.json", result, force)
    outputs.append(folder / "track_evaluation.json")
    figures["tracking"] = {
        "rope_markers_found": int(track.positions.shape[1]),
        "rope_markers_true": int(take.summary["rope_markers"]),
        "invented_fraction": float(track.invented.mean()),
        "lost_samples": int(track.lost_frames.sum()),
        "precision": scores["precision"],
        "recall": scores["recall"],
        "f1": scores["f1"],
        "points": report.get("points", int(take.points.points.shape[0])),
    }
    return result


def _dense(
    folder: Path, steps: _Steps, take: Any, force: bool, outputs: list[Path], figures: dict
) -> None:
    from skincap.synth.inputs import build_body
    from skincap.workflows.demo_dense import dense_comparison, rom_markers

    with steps.step(0.68, "dense skin (Park & Hodgins §5)"):
        body = _body_columns(list(take.truth.labels))
        labels = [str(take.truth.labels[i]) for i in body]
        (folder / "figures").mkdir(exist_ok=True)
        png = folder / "figures" / "dense_errors.png"
        # the take's body again (deterministic), through its range of motion
        rom = rom_markers(build_body("procedural", n_vertices=DEMO_BODY_VERTICES), labels)
        figures["dense"] = dense_comparison(
            take.truth.positions[:, body],
            labels,
            take.marker_surface.faces,
            np.asarray(take.skin.frames),
            take.skin.rest.faces,
            png,
            force=force,
            rom=rom,
        )
        figures["dense"]["rom_frames"] = int(rom.shape[0])
    outputs.append(png)


def _skin(folder: Path, steps: _Steps, force: bool, outputs: list[Path], figures: dict) -> Any:
    with steps.step(0.7, "skinning (DQS)"):
        paths, body, frames = _skin_body(
            folder, force=force, progress=steps.within(0.7, 0.85, "skinning (DQS)")
        )
    outputs += paths
    figures["skinning"] = {
        "vertices": body.n_vertices,
        "joints": body.skin.skeleton.n_joints,
        "pc2_frames": frames,
    }
    return body


def _solve_real(
    folder: Path, steps: _Steps, body: Any, force: bool, outputs: list[Path], figures: dict
) -> None:
    from skincap.workflows.demo_solve import clean_solve_skin

    with steps.step(0.86, "real capture: clean, solve, skin"):
        figures["solve"], paths = clean_solve_skin(
            folder, body, force=force, progress=steps.within(0.86, 0.88, "real capture")
        )
    outputs += paths


def _artefacts(steps: _Steps, body: Any, figures: dict) -> list[dict[str, Any]]:
    from skincap.deform.skeletal.artefacts import artefact_table

    with steps.step(0.85, "skinning artefacts"):
        rows = artefact_table(body)
    figures["artefacts"] = rows
    return rows


def _convert_real_data(
    folder: Path, steps: _Steps, force: bool, outputs: list[Path]
) -> dict[str, Any]:
    from skincap import io
    from skincap.evaluate.summary import summarize
    from skincap.io.joints_csv import write_joint_positions_csv

    with steps.step(0.88, "converting real captures"):
        formats = folder / "formats"
        formats.mkdir(exist_ok=True)
        c3d_path, bvh_path = shipped_file(DEMO_C3D), shipped_file(DEMO_BVH)
        markers = io.read(c3d_path)
        for name in ("walking.trc", "walking.csv", "walking.c3d"):
            io.write(markers, formats / name, force=force)
            outputs.append(formats / name)
        motion = io.read(bvh_path, units="cm")  # bvhtoolbox mocapbank file: centimetres
        io.write(motion, formats / "motion.bvh", force=force)
        write_joint_positions_csv(motion, formats / "motion_joints.csv", force=force)
        outputs += [formats / "motion.bvh", formats / "motion_joints.csv"]
    return {str(c3d_path): summarize(markers), str(bvh_path): summarize(motion)}


def _render(folder: Path, steps: _Steps, force: bool, outputs: list[Path]) -> dict[str, list]:
    """Rendered frames for the report: raw vs cleaned capture with the rope, and the walk."""
    import warnings

    from skincap.viz.render import Camera, write_picture
    from skincap.viz.scene import load_scene

    pictures: dict[str, list] = {"capture": [], "walk": [], "solve": []}
    with steps.step(0.9, "rendering frames"):
        frames_dir = folder / "frames"
        frames_dir.mkdir(exist_ok=True)
        raw = load_scene([folder / "synth" / "capture.c3d"])
        clean = load_scene([folder / "cleaned.c3d", folder / "track" / "rope_curve.csv"])
        camera = Camera(azimuth=25.0, elevation=10.0)
        for t in (0.2 * clean.duration, 0.55 * clean.duration, 0.85 * clean.duration):
            for name, scene in (("raw", raw), ("cleaned", clean)):
                path = frames_dir / f"capture_{name}_{t:05.2f}s.png"
                write_picture(scene, path, time=t, camera=camera, size=(480, 480), force=force)
                pictures["capture"].append((path, f"{name} capture at {t:.2f} s"))
                outputs.append(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # nothing to warn about in our own glb
            walk = load_scene([folder / "walk.glb"])
        # frames 470-700 of the CMU take are its clean walk (it also kicks and kneels)
        for t in np.clip((4.0, 4.8, 5.6), 0.0, walk.duration):
            path = frames_dir / f"walk_{t:05.2f}s.png"
            write_picture(
                walk, path, time=t, camera=Camera(azimuth=60.0), size=(480, 480), force=force
            )
            pictures["walk"].append((path, f"walk.glb (LBS) at {t:.2f} s"))
            outputs.append(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            solved = load_scene([folder / "real" / "cleaned.c3d", folder / "real" / "solved.bvh"])
            skinned = load_scene([folder / "real" / "solved_body.glb"])
        for t in (0.25 * solved.duration, 0.6 * solved.duration):
            for name, scene, what in (
                ("skeleton", solved, "markers and the solved skeleton"),
                ("body", skinned, "the MakeHuman body on the solved skeleton"),
            ):
                path = frames_dir / f"solve_{name}_{t:05.2f}s.png"
                write_picture(
                    scene, path, time=t, camera=Camera(azimuth=40.0), size=(480, 480), force=force
                )
                pictures["solve"].append((path, f"{what} at {t:.2f} s"))
                outputs.append(path)
    return pictures


def _skin_body(
    folder: Path, *, force: bool, progress: Callable[[float], None]
) -> tuple[list[Path], Any, int]:
    """MakeHuman body + CMU walk -> walk.glb (LBS in the viewer) and walk_dqs.pc2 + .obj.

    Returns the written paths, the body and the frames in the point cache."""
    from skincap.deform.skeletal.deformers import skin_motion
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.io.bvh import read_bvh
    from skincap.io.gltf.writer import write_glb
    from skincap.io.makehuman import read_makehuman
    from skincap.io.mesh import write_obj
    from skincap.io.pc2 import write_pc2
    from skincap.types import Motion

    for name in ("makehuman_default.mhskel", "makehuman_default_weights.mhw"):
        shipped_file(name)
    body = read_makehuman(shipped_file(DEMO_BODY))
    walk = read_bvh(shipped_file(DEMO_WALK), units="cmu")
    setup = prepare_skinning(body, walk)
    write_glb(setup.mesh, setup.motion, folder / "walk.glb", force=force)
    m = setup.motion
    n = min(DEMO_PC2_FRAMES, m.n_frames)
    short = Motion(m.skeleton, m.rotations[:n], m.translations[:n], m.rate, m.channels, m.meta)
    write_obj(setup.mesh, folder / "walk_dqs.obj", force=force, units="m", up="y")
    write_pc2(
        skin_motion(setup.mesh, short, method="dqs", progress=progress),
        folder / "walk_dqs.pc2",
        force=force,
    )
    paths = [folder / "walk.glb", folder / "walk_dqs.obj", folder / "walk_dqs.pc2"]
    return paths, body, n
