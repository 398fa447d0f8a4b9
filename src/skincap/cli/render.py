"""``skincap render``: offscreen pictures (PNG) and clips (GIF, MP4) of any files."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from skincap.cli._app import _user_errors, app, err, out
from skincap.cli._options import ForceOption
from skincap.errors import ValidationError


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValidationError(f"--size: expected WIDTHxHEIGHT like 960x720, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise ValidationError(f"--size: each side must be 16..8192 pixels, got {text!r}")
    return w, h


#: Most pictures one clip may hold (an hour at 30 fps), so --fps cannot ask for millions.
MAX_CLIP_FRAMES = 108_000


def _check_view_and_rate(*, azimuth: float, elevation: float, rate: float | None) -> None:
    """ValidationError for a camera angle that is not a number or a PC2 rate that is not
    a positive one (a NaN angle drew an empty picture, a 0 Hz rate divided by zero)."""
    for name, degrees in (("--azimuth", azimuth), ("--elevation", elevation)):
        if not math.isfinite(degrees):
            raise ValidationError(f"{name}: expected a finite angle in degrees, got {degrees:g}")
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise ValidationError(f"--rate: expected a positive frame rate in Hz, got {rate:g}")


def _check_times(
    scene: object,
    output: Path,
    *,
    time: float | None,
    frame: int | None,
    start: float,
    end: float | None,
    fps: float,
) -> None:
    """ValidationError unless --time/--frame/--start/--end/--fps fall inside the take."""
    duration = float(scene.duration)  # type: ignore[attr-defined]
    n_frames = int(scene.n_frames)  # type: ignore[attr-defined]
    still = output.suffix.lower() == ".png"
    if not still and (time is not None or frame is not None):
        raise ValidationError("--time and --frame pick a PNG's frame; a clip takes --start/--end")
    if frame is not None and not 0 <= frame < n_frames:
        raise ValidationError(f"--frame: the scene's frames are 0 to {n_frames - 1}, got {frame}")
    if time is not None and not 0.0 <= time <= duration:
        raise ValidationError(f"--time: the take runs from 0 to {duration:.6g} s, got {time:g}")
    if not (0.0 < fps < float("inf")):  # a PNG too: the scene is built with it
        raise ValidationError(f"--fps: expected a positive number, got {fps:g}")
    if still:
        return
    if not 0.0 <= start <= duration:
        raise ValidationError(f"--start: the take runs from 0 to {duration:.6g} s, got {start:g}")
    if end is not None and not start <= end:
        raise ValidationError(f"--end ({end:g} s) must not come before --start ({start:g} s)")
    stop = duration if end is None else min(end, duration)
    pictures = (stop - start) * fps + 1
    if pictures > MAX_CLIP_FRAMES:
        raise ValidationError(
            f"--fps {fps:g} over {stop - start:.6g} s makes {pictures:.0f} pictures; "
            f"a clip holds at most {MAX_CLIP_FRAMES}"
        )


@app.command()
def render(
    paths: Annotated[
        list[Path],
        typer.Argument(
            metavar="PATH...", help="Files or folders to draw together (any file skincap reads)."
        ),
    ],
    output: Annotated[
        Path,
        typer.Option("-o", "--output", help="out.png (one frame), out.gif or out.mp4 (a clip)."),
    ],
    time: Annotated[
        float | None, typer.Option(help="Seconds: the frame of a PNG (default: mid-take).")
    ] = None,
    frame: Annotated[
        int | None, typer.Option(help="Scene frame of a PNG (at the highest layer rate).")
    ] = None,
    start: Annotated[float, typer.Option(help="Clip start, seconds.")] = 0.0,
    end: Annotated[float | None, typer.Option(help="Clip end, seconds (default: the end).")] = None,
    fps: Annotated[float, typer.Option(help="Clip frames per second.")] = 30.0,
    size: Annotated[str, typer.Option(help="WIDTHxHEIGHT in pixels.")] = "960x720",
    azimuth: Annotated[float, typer.Option(help="Camera azimuth about +Y, degrees.")] = 30.0,
    elevation: Annotated[float, typer.Option(help="Camera elevation, degrees.")] = 12.0,
    fixed: Annotated[
        bool, typer.Option("--fixed", help="Frame the whole take once instead of following.")
    ] = False,
    units: Annotated[
        str | None, typer.Option(help="Length unit for files that do not say (BVH, OBJ…).")
    ] = None,
    rate: Annotated[
        float | None,
        typer.Option(
            help="Frame rate of PC2 caches, Hz (default: the rate skin/animate noted in the OBJ "
            "beside the cache, else a motion's in the scene, else 30 with a warning).",
        ),
    ] = None,
    force: ForceOption = False,
) -> None:
    """Draw captures, skeletons, meshes and rope curves offscreen to a PNG, GIF or MP4.

    Markers take a stable colour per label; invented samples are white; the camera
    follows the subject unless --fixed. No display is needed.

    Example: skincap render capture.c3d walk.glb -o frame.png --time 2.5
    """
    from rich.progress import Progress

    from skincap.io.output_safety import guard_outputs
    from skincap.viz.render import Camera, write_picture
    from skincap.viz.scene import load_scene

    with _user_errors(), guard_outputs(paths, [output], force=force):
        if time is not None and frame is not None:
            raise ValidationError("give --time or --frame, not both")
        width_height = _parse_size(size)
        _check_view_and_rate(azimuth=azimuth, elevation=elevation, rate=rate)
        scene = load_scene(paths, units=units, rate=rate)
        _check_times(scene, output, time=time, frame=frame, start=start, end=end, fps=fps)
        at = scene.time_of(frame) if frame is not None else time
        camera = Camera(azimuth=azimuth, elevation=elevation, follow=not fixed)
        with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task("render", total=None)

            def advance(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            written = write_picture(
                scene,
                output,
                time=at,
                start=start,
                end=end,
                fps=fps,
                camera=camera,
                size=width_height,
                force=force,
                progress=advance,
            )
    out.print(f"render: wrote {written}", markup=False)
