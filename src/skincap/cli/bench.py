"""``skincap bench io|skin|synth``: speed ratios against peers measured in the same run.

``bench clean`` and ``bench track`` live beside their verbs (:mod:`skincap.cli.clean`,
:mod:`skincap.cli.track`)."""

from __future__ import annotations

from typing import Annotated

import typer

from skincap.cli._app import _user_errors, bench_app, print_bench_results
from skincap.cli._options import BenchJsonOption, PartsOption, RepeatOption


@bench_app.command("io")
def bench_io(
    repeat: RepeatOption = 5,
    json_output: BenchJsonOption = False,
) -> None:
    """BVH read and FK against bvhio, C3D read against raw ezc3d, OBJ read against trimesh.

    Example: skincap bench io --repeat 3
    """
    from skincap.evaluate.bench.common import run_io_benchmarks

    with _user_errors():
        results = run_io_benchmarks(repeat=repeat)
    print_bench_results(results, json_output)


@bench_app.command("skin")
def bench_skin(
    vertices: Annotated[int, typer.Option(help="Mesh vertices.")] = 50_000,
    influences: Annotated[int, typer.Option(help="Joints per vertex.")] = 4,
    frames: Annotated[int, typer.Option(help="Frames per timed batch.")] = 64,
    repeat: RepeatOption = 5,
    json_output: BenchJsonOption = False,
) -> None:
    """LBS and DQS milliseconds per frame (numba and NumPy) against libigl and UsdSkel, as ratios.

    Example: skincap bench skin --vertices 50000 --influences 4
    """
    from skincap.evaluate.bench.skinning import run_skinning_benchmark

    with _user_errors():
        results = run_skinning_benchmark(
            n_vertices=vertices, n_influences=influences, n_frames=frames, repeat=repeat
        )
    print_bench_results(results, json_output)


@bench_app.command("animate")
def bench_animate(
    vertices: Annotated[int, typer.Option(help="Skin vertices.")] = 50_000,
    parts: PartsOption = 17,
    markers: Annotated[int, typer.Option(help="Markers (rings of 10 on the body).")] = 350,
    frames: Annotated[int, typer.Option(help="Frames per timed run.")] = 32,
    rom_frames: Annotated[
        int, typer.Option(help="Frames of the take the segmentation is timed on (0: skip).")
    ] = 1000,
    repeat: RepeatOption = 3,
    json_output: BenchJsonOption = False,
) -> None:
    """Dense deformation ms/frame (wall and CPU) of the four variants on each backend (numba,
    NumPy) against our LBS on the same mesh and backend, as ratios; the first call in a
    fresh process (cold and warm numba cache); segmentation and registration times.

    Example: skincap bench animate --vertices 50000 --parts 17 --markers 350
    """
    from skincap.evaluate.bench.animate import run_animate_benchmark

    with _user_errors():
        from skincap.errors import ValidationError

        if rom_frames < 0:
            raise ValidationError(
                f"--rom-frames: expected 0 (skip) or a frame count, got {rom_frames}"
            )
        results = run_animate_benchmark(
            n_vertices=vertices,
            n_parts=parts,
            n_markers=markers,
            n_frames=frames,
            repeat=repeat,
            rom_frames=rom_frames,
        )
    print_bench_results(results, json_output)


@bench_app.command("synth")
def bench_synth(
    frames: Annotated[int, typer.Option(help="Frames of the take (120 Hz).")] = 1000,
    vertices: Annotated[int, typer.Option(help="Procedural body vertices.")] = 20_000,
) -> None:
    """Time a dense jump-rope synthetic take stage by stage, against the take's duration.

    Example: skincap bench synth --frames 1000
    """
    from skincap.evaluate.bench.synth import run_synth_benchmark

    with _user_errors():
        results = run_synth_benchmark(frames=frames, vertices=vertices)
    print_bench_results(results, json_output=False)


@bench_app.command("sweep")
def bench_sweep(
    frames: Annotated[int, typer.Option(help="Frames of the CMU walk per timed call.")] = 64,
    subdivide: Annotated[
        int,
        typer.Option(help="Split every triangle in four this many times (0-2; 1: 53k vertices)."),
    ] = 0,
    repeat: RepeatOption = 5,
    json_output: BenchJsonOption = False,
) -> None:
    """Sweep deformer CPU ms/frame on the MakeHuman body walking, against our LBS and DQS
    in the same run, as ratios, beside Hyun et al.'s 7 fps for 72,712 vertices.

    Example: skincap bench sweep --subdivide 1
    """
    from skincap.evaluate.bench.sweep import run_sweep_benchmark

    with _user_errors():
        results = run_sweep_benchmark(n_frames=frames, repeat=repeat, subdivide=subdivide)
    print_bench_results(results, json_output)
