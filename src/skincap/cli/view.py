"""``skincap view``: show files in the browser (the viser viewer, imported when it runs)."""

from __future__ import annotations

import socket
import time
from pathlib import Path
from typing import Annotated

import typer

from skincap.cli._app import _user_errors, app, err, out
from skincap.errors import ValidationError


@app.command()
def view(
    paths: Annotated[
        list[Path],
        typer.Argument(
            help="Files or folders: C3D, TRC, CSV, BVH, OBJ/PLY (+PC2), glTF/GLB, "
            "or a 'skincap track' / 'skincap demo' output folder."
        ),
    ],
    host: Annotated[
        str, typer.Option(help="Interface to listen on (0.0.0.0 for the local network).")
    ] = "127.0.0.1",
    port: Annotated[
        int, typer.Option(help="First port to try; the next free one is used if taken.")
    ] = 8080,
    no_browser: Annotated[
        bool, typer.Option("--no-browser", help="Do not open a web browser.")
    ] = False,
    frame: Annotated[
        int | None,
        typer.Option(help="Start paused at this frame of the scene clock (default: play from 0)."),
    ] = None,
    units: Annotated[
        str | None,
        typer.Option(help="Length unit for BVH/OBJ/PLY/CSV files without one (m, cm, mm, in)."),
    ] = None,
) -> None:
    """Show captures, skeletons, meshes and rope curves in the browser, overlaid.

    Markers are coloured by label (the same label has the same colour in every
    file), invented samples are grey diamonds, missing ones are not drawn. The
    panel has play/pause, a frame slider, the playback speed, one checkbox per
    file and layer, and a per-file marker tint for raw-against-cleaned overlays.
    Serves until Ctrl-C.

    Example: skincap view raw.c3d cleaned.c3d body.glb --no-browser
    """
    with _user_errors():
        if not 0 <= port <= 65535:
            raise ValidationError(f"--port: expected 0..65535, got {port}")
        _check_host(host)
        from skincap.viz.scene import load_scene
        from skincap.viz.viewer import serve_scene

        scene = load_scene(paths, units=units)
        if frame is not None and not 0 <= frame < scene.n_frames:
            raise ValidationError(f"--frame: expected 0 <= frame < {scene.n_frames}, got {frame}")
        handle = serve_scene(
            scene,
            host=host,
            port=port,
            open_browser=not no_browser,
            play=frame is None,
            frame=0 if frame is None else frame,
        )
    kinds = ", ".join(f"{layer.name} ({layer.kind})" for layer in scene.layers)
    out.print(f"skincap view: {handle.url}", markup=False, soft_wrap=True)
    err.print(
        f"{len(scene.layers)} layers: {kinds}; {scene.n_frames} frames at {scene.rate:g} Hz. "
        "Ctrl-C to stop.",
        markup=False,
        soft_wrap=True,
    )
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        handle.stop()


def _check_host(host: str) -> None:
    """Refuse a --host this machine cannot listen on, before the scene loads: the
    server's thread would die on it and leave the command waiting forever."""
    try:
        family, kind, _, _, address = socket.getaddrinfo(
            host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
        with socket.socket(family, kind) as probe:
            probe.bind(address)
    except (OSError, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ValidationError(f"--host: cannot listen on {host!r} ({reason})") from None
