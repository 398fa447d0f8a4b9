"""The browser viewer: a viser server showing a :class:`skincap.viz.scene.Scene`.

:func:`serve_scene` starts a viser web server (a three.js client) in background
threads and returns a :class:`ViewerHandle`. The page shows every layer of the scene
(markers coloured by label, invented samples as grey diamonds, point clouds, skeletons,
deforming meshes, rope curves) over a ground grid, Y up, with the camera framing the
scene bounds, and a GUI panel:

* **Timeline**: play/pause, step buttons, a frame slider (scrubbing pauses), the time, and a
  speed dropdown. Playback runs in real time at the scene's rate and loops.
* **Layers**: one checkbox per file and one per layer of a file with several.
* **Display**: tint markers per file (raw against cleaned) and the point size.

Per frame only changed arrays travel (positions; colours only when the set of drawn
markers changes; nothing for hidden layers or static meshes), and viser drops queued
updates a newer one supersedes, so long takes stay responsive.
"""

from __future__ import annotations

import contextlib
import io
import math
import re
import threading
import time
import webbrowser
from collections.abc import Iterator
from typing import Any

import numpy as np

from skincap.errors import MissingDependencyError, SkincapError, ValidationError
from skincap.viz.colours import file_tint
from skincap.viz.viewer.guard import AccessGuard, guarding_viser
from skincap.viz.viewer.layers import DrawStyle, LayerDrawer, make_drawer
from skincap.viz.viewer.timeline import SPEEDS, PlaybackClock, parse_speed, speed_label

__all__ = ["serve_scene", "ViewerHandle", "camera_framing", "default_point_size"]

#: Colours of non-marker layers, by kind (RGB uint8).
_KIND_COLOURS = {
    "points": (40, 40, 40),
    "skeleton": (60, 90, 200),
    "mesh": (225, 185, 160),
    "curve": (230, 120, 20),
    "markers": (40, 40, 40),
}

#: Most frame updates per second the playback thread sends (frames are skipped above).
MAX_UPDATES_PER_SECOND = 60.0


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Swallow viser's own banner lines (library code never prints)."""
    with contextlib.redirect_stdout(io.StringIO()):
        yield


def _node_name(text: str) -> str:
    """A viser node name component: no slash, no spaces."""
    return re.sub(r"[^A-Za-z0-9_.:+-]+", "_", text).strip("_") or "layer"


#: Width over height of the page the viewer is usually opened in (a laptop window).
PAGE_ASPECT = 1.6
#: How far right of the content the camera aims, as a fraction of the view's half
#: width: the content's centre lands at about 37 % of the page width, mid-way across
#: the part the GUI panel leaves free.
PANEL_SHIFT = 0.27


def camera_framing(
    bounds: np.ndarray, *, fov_radians: float = 50.0 * math.pi / 180.0
) -> tuple[np.ndarray, np.ndarray]:
    """A camera position and look-at point that frame ``bounds`` (Y up).

    The camera looks at the box from the side facing its longest horizontal extent,
    20 degrees above the horizon and 30 degrees round, far enough that the bounding
    sphere fits the vertical field of view, aimed a little right of the box centre so
    the box sits left of the GUI panel.

    Parameters
    ----------
    bounds : (2, 3) float, metres
        Lower and upper corners. Non-finite bounds (an empty scene) frame a 2 m box
        standing at the origin.
    fov_radians : float
        Vertical field of view.

    Returns
    -------
    position, look_at : (3,) float64, metres
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    if not np.isfinite(b).all():
        b = np.array([[-0.5, 0.0, -0.5], [0.5, 2.0, 0.5]])
    centre = b.mean(axis=0)
    size = np.maximum(b[1] - b[0], 1e-3)
    radius = max(0.5 * float(np.linalg.norm(size)), 0.25)
    # look along -Z when the take spreads along X (see it from the side), else along -X
    azimuth = math.radians(30.0) + (0.0 if size[0] >= size[2] else math.pi / 2)
    elevation = math.radians(20.0)
    direction = np.array(
        [
            math.sin(azimuth) * math.cos(elevation),
            math.sin(elevation),
            math.cos(azimuth) * math.cos(elevation),
        ]
    )
    distance = 0.95 * radius / math.sin(0.5 * fov_radians)  # the box fills the view
    # viser's control panel floats over the right quarter of the page: aim right of
    # the content so it sits in the free part, left of the page centre
    right = np.array([math.cos(azimuth), 0.0, -math.sin(azimuth)])
    half_width = distance * math.tan(0.5 * fov_radians) * PAGE_ASPECT
    look_at = centre + PANEL_SHIFT * half_width * right
    return look_at + distance * direction, look_at


def default_point_size(bounds: np.ndarray) -> float:
    """A marker diameter in metres for a scene of these bounds (12 mm for a person).

    Parameters
    ----------
    bounds : (2, 3) float, metres

    Returns
    -------
    float, metres: 0.6 % of the bounding-box diagonal, clipped to [4 mm, 50 mm].
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    if not np.isfinite(b).all():
        return 0.015
    return float(np.clip(0.006 * np.linalg.norm(b[1] - b[0]), 0.004, 0.05))


def _floor_height(bounds: np.ndarray) -> float:
    """Height of the ground grid: y = 0 unless the data is far from it, then its bottom."""
    lo, hi = bounds[0, 1], bounds[1, 1]
    height = max(hi - lo, 1e-3)
    return 0.0 if abs(lo) <= 0.25 * height else float(lo)


class ViewerHandle:
    """A running viewer; returned by :func:`serve_scene`.

    Attributes
    ----------
    scene : Scene
    server : viser.ViserServer
    url : str
        The page to open, ``http://host:port/<token>/``: only requests carrying the
        token, and WebSockets from the page's own Origin, are served
        (:mod:`skincap.viz.viewer.guard`).
    guard : AccessGuard
        The token and the checks.
    drawers : dict[str, LayerDrawer]
        One per layer, by layer name; ``drawers[name].children`` are its viser nodes.
    """

    def __init__(
        self,
        scene: Any,
        viser: Any,
        *,
        host: str,
        port: int,
        play: bool,
        frame: int,
    ) -> None:
        if not scene.layers:
            raise ValidationError("scene: no layers to show")
        n_frames = int(scene.n_frames)
        if not 0 <= int(frame) < max(n_frames, 1):
            raise ValidationError(f"frame: expected 0 <= frame < {n_frames}, got {frame}")
        self.scene = scene
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._frame = int(frame)
        self._playing = False
        self.clock = PlaybackClock(scene.rate, max(n_frames, 1))

        self.guard = AccessGuard(host)
        with _quiet(), guarding_viser(self.guard):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if not self.guard.installed:
            with _quiet():
                self.server.stop()
            raise SkincapError(
                f"viser {getattr(viser, '__version__', '?')} started its server in a way "
                "skincap cannot guard (token and Origin checks); not serving the capture open"
            )
        self.host = host
        self.port = int(self.server.get_port())
        shown_host = "localhost" if host in ("0.0.0.0", "::", "") else host
        if ":" in shown_host:  # an IPv6 address in a URL goes in brackets
            shown_host = f"[{shown_host}]"
        self.url = f"http://{shown_host}:{self.port}/{self.guard.token}/"

        try:
            self._build_scene()
            self._build_gui(n_frames)
            self._show(self._frame)
        except BaseException:
            with _quiet():
                self.server.stop()
            raise
        self._player = threading.Thread(target=self._play_loop, name="skincap-view", daemon=True)
        self._player.start()
        if play and n_frames > 1:
            self.play()

    # ----------------------------------------------------------------- scene nodes
    def _build_scene(self) -> None:
        scene_api = self.server.scene
        scene_api.set_up_direction("+y")
        bounds = np.asarray(self.scene.bounds(), dtype=np.float64).reshape(2, 3)
        if not np.isfinite(bounds).all():
            bounds = np.array([[-0.5, 0.0, -0.5], [0.5, 2.0, 0.5]])
        self.bounds = bounds
        position, look_at = camera_framing(bounds)
        self.server.initial_camera.fov = 50.0 * math.pi / 180.0
        self.server.initial_camera.position = position
        self.server.initial_camera.look_at = look_at
        self.server.initial_camera.near = 0.01
        self.server.initial_camera.far = max(1000.0, 20.0 * float(np.linalg.norm(position)))

        centre = bounds.mean(axis=0)
        span = float(np.max(bounds[1, [0, 2]] - bounds[0, [0, 2]]))
        width = float(max(4.0, math.ceil(1.5 * span + 1.0)))
        cell = 0.25 if width <= 20 else 1.0
        scene_api.add_grid(
            "/ground",
            width=width,
            height=width,
            plane="xz",
            cell_size=cell,
            section_size=4 * cell,
            position=(
                float(np.round(centre[0])),
                _floor_height(bounds),
                float(np.round(centre[2])),
            ),
        )

        size = default_point_size(bounds)
        self.point_size = size
        # group layers by file, in the scene's order
        self.files: dict[str, list[Any]] = {}
        sources: dict[Any, str] = {}
        for layer in self.scene.layers:
            key = _file_key(layer)
            if key not in sources:
                sources[key] = _unique(_node_name(_file_label(layer)), set(sources.values()))
                self.files[sources[key]] = []
            self.files[sources[key]].append(layer)
        self.file_nodes: dict[str, Any] = {}
        self.drawers: dict[str, LayerDrawer] = {}
        for index, (file_node, layers) in enumerate(self.files.items()):
            self.file_nodes[file_node] = scene_api.add_frame(f"/{file_node}", show_axes=False)
            used: set[str] = set()
            for layer in layers:
                name = _unique(_node_name(_short_name(layer)), used)
                used.add(name)
                style = DrawStyle(
                    point_size=size,
                    line_thickness=0.5 * size,
                    colour=np.array(_KIND_COLOURS.get(layer.kind, (40, 40, 40)), np.uint8),
                    file_tint=file_tint(index),
                )
                if len(self.files) > 1 and layer.kind in ("points", "skeleton", "curve"):
                    style.colour = file_tint(index)
                self.drawers[layer.name] = make_drawer(
                    scene_api, f"/{file_node}/{name}", layer, style
                )

    # ------------------------------------------------------------------------- GUI
    def _build_gui(self, n_frames: int) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="medium", show_share_button=False)
        single = n_frames <= 1
        with gui.add_folder("Timeline"):
            self.play_button = gui.add_button(
                "Play", icon=self._icon("PLAYER_PLAY"), disabled=single
            )
            self.step_buttons = gui.add_button_group("Step", ("-10", "-1", "+1", "+10"))
            self.frame_slider = gui.add_slider(
                "Frame",
                min=0,
                max=max(n_frames - 1, 1),
                step=1,
                initial_value=self._frame,
                disabled=single,
            )
            self.time_text = gui.add_text("Time", initial_value=self._time_text(self._frame))
            self.time_text.disabled = True
            self.speed_dropdown = gui.add_dropdown(
                "Speed", tuple(speed_label(s) for s in SPEEDS), initial_value=speed_label(1.0)
            )
        self.file_boxes: dict[str, Any] = {}
        self.layer_boxes: dict[str, Any] = {}
        with gui.add_folder("Layers"):
            for file_node, layers in self.files.items():
                file_label = _file_label(layers[0])
                box = gui.add_checkbox(file_label, initial_value=True, hint=_file_key(layers[0]))
                self.file_boxes[file_node] = box
                box.on_update(self._file_toggle(file_node))
                if len(layers) > 1:
                    for layer in layers:
                        sub = gui.add_checkbox(f"  {file_label}: {_short_name(layer)}", True)
                        self.layer_boxes[layer.name] = sub
                        sub.on_update(self._layer_toggle(layer.name))
        with gui.add_folder("Display"):
            self.tint_box = gui.add_checkbox(
                "Tint markers per file",
                initial_value=False,
                hint="Colour markers by file (raw against cleaned) instead of by label",
            )
            self.size_slider = gui.add_slider(
                "Point size (mm)",
                min=1,
                max=60,
                step=1,
                initial_value=int(np.clip(round(self.point_size * 1000), 1, 60)),
            )

        self.play_button.on_click(lambda _event: self.toggle_play())
        self.step_buttons.on_click(self._on_step)
        self.frame_slider.on_update(self._on_slider)
        self.speed_dropdown.on_update(lambda event: self.set_speed(parse_speed(event.target.value)))
        self.tint_box.on_update(lambda event: self.set_tint_markers(bool(event.target.value)))
        self.size_slider.on_update(lambda event: self.set_point_size(event.target.value / 1000.0))

    @staticmethod
    def _icon(name: str) -> Any:
        from viser import Icon

        return getattr(Icon, name)

    def _time_text(self, frame: int) -> str:
        return f"{self.scene.time_of(frame):.3f} s / {self.scene.duration:.3f} s"

    def _file_toggle(self, file_node: str) -> Any:
        def toggle(event: Any) -> None:
            self.set_visible(file_node, bool(event.target.value))

        return toggle

    def _layer_toggle(self, layer_name: str) -> Any:
        def toggle(event: Any) -> None:
            self.set_visible(layer_name, bool(event.target.value))

        return toggle

    def _on_step(self, event: Any) -> None:
        self.pause()
        self.frame = (self.frame + int(event.target.value)) % max(self.scene.n_frames, 1)

    def _on_slider(self, event: Any) -> None:
        frame = int(event.target.value)
        if event.client is not None:
            # the user scrubbed: pause, or the playback thread's next slider update
            # would pull the handle back from under the user's drag
            self.pause()
            self.clock.anchor(frame, time.monotonic())
        self._show(frame)

    # ------------------------------------------------------------------- drawing
    def _show(self, frame: int) -> None:
        with self._lock, self.server.atomic():
            self._frame = int(frame)
            t = self.scene.time_of(self._frame)
            for drawer in self.drawers.values():
                if self._drawer_shown(drawer):
                    drawer.draw(self.scene.layer_frame(drawer.layer, t))
            self.time_text.value = self._time_text(self._frame)

    def _drawer_shown(self, drawer: LayerDrawer) -> bool:
        file_node = drawer.node.split("/")[1]
        return drawer.visible and bool(self.file_nodes[file_node].visible)

    def _play_loop(self) -> None:
        min_interval = 1.0 / MAX_UPDATES_PER_SECOND
        while not self._stop.is_set():
            if not self._playing:
                self._stop.wait(0.05)
                continue
            now = time.monotonic()
            due = self.clock.frame_at(now)
            if due != self._frame:
                self.frame_slider.value = due  # draws through the slider callback
            wait = max(self.clock.seconds_until_next(time.monotonic()), min_interval)
            self._stop.wait(wait)

    # ------------------------------------------------------------------ public API
    @property
    def frame(self) -> int:
        """The scene frame shown (at :attr:`Scene.rate`); assign to jump there."""
        return self._frame

    @frame.setter
    def frame(self, frame: int) -> None:
        n = max(int(self.scene.n_frames), 1)
        frame = int(frame)
        if not 0 <= frame < n:
            raise ValidationError(f"frame: expected 0 <= frame < {n}, got {frame}")
        self.clock.anchor(frame, time.monotonic())
        if frame == self.frame_slider.value:
            self._show(frame)
        else:
            self.frame_slider.value = frame

    @property
    def playing(self) -> bool:
        return self._playing

    def play(self) -> None:
        """Start playback from the current frame, in real time at the scene's rate."""
        if self.scene.n_frames <= 1:
            return
        self.clock.anchor(self._frame, time.monotonic())
        self._playing = True
        self.play_button.label = "Pause"
        self.play_button.icon = self._icon("PLAYER_PAUSE")

    def pause(self) -> None:
        """Stop playback at the current frame."""
        self._playing = False
        self.play_button.label = "Play"
        self.play_button.icon = self._icon("PLAYER_PLAY")

    def toggle_play(self) -> None:
        """Pause when playing, play when paused (the GUI's play button)."""
        if self._playing:
            self.pause()
        else:
            self.play()

    @property
    def speed(self) -> float:
        """Playback speed, a multiple of real time."""
        return self.clock.speed

    def set_speed(self, speed: float) -> None:
        """Set the playback speed (a positive multiple of real time)."""
        speed = float(speed)
        if not math.isfinite(speed) or speed <= 0:
            raise ValidationError(f"speed: expected a positive multiple of real time, got {speed}")
        self.clock.set_speed(speed, time.monotonic())
        label = speed_label(speed)
        if label in self.speed_dropdown.options and self.speed_dropdown.value != label:
            self.speed_dropdown.value = label

    def set_visible(self, name: str, visible: bool) -> None:
        """Show or hide a whole file (its node name) or one layer (its layer name).

        Raises
        ------
        ValidationError
            When ``name`` is neither a file node nor a layer name.
        """
        with self._lock:
            if name in self.file_nodes:
                self.file_nodes[name].visible = bool(visible)
                box = self.file_boxes[name]
            elif name in self.drawers:
                self.drawers[name].visible = bool(visible)
                box = self.layer_boxes.get(name)
            else:
                known = sorted(self.file_nodes) + sorted(self.drawers)
                raise ValidationError(f"name: expected a file or layer name {known}, got {name!r}")
            if box is not None and box.value != bool(visible):
                box.value = bool(visible)
            if visible:
                self._show(self._frame)  # hidden layers were not updated

    def set_tint_markers(self, tint: bool) -> None:
        """Colour markers by file (True) or by label (False)."""
        with self._lock, self.server.atomic():
            for drawer in self.drawers.values():
                drawer.set_tint_markers(tint)
            if self.tint_box.value != bool(tint):
                self.tint_box.value = bool(tint)

    def set_point_size(self, size: float) -> None:
        """Set the marker and point diameter in metres."""
        size = float(size)
        if not math.isfinite(size) or size <= 0:
            raise ValidationError(f"size: expected a positive diameter in metres, got {size}")
        with self._lock, self.server.atomic():
            self.point_size = size
            for drawer in self.drawers.values():
                drawer.set_point_size(size)

    def client_count(self) -> int:
        """Number of browsers connected now."""
        return len(self.server.get_clients())

    def stop(self) -> None:
        """Stop playback and the server (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._player.join(timeout=2.0)
        with _quiet():
            self.server.stop()

    def __enter__(self) -> ViewerHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _file_key(layer: Any) -> str:
    """What groups layers into one file toggle: the source path, else the layer name."""
    return str(layer.source) if layer.source is not None else str(layer.name)


def _file_label(layer: Any) -> str:
    """The file's display name: the source file name, else the layer name."""
    return layer.source.name if layer.source is not None else str(layer.name)


def _short_name(layer: Any) -> str:
    """A layer's name within its file (``capture.glb:skeleton`` -> ``skeleton``)."""
    name = str(layer.name)
    prefix = f"{_file_label(layer)}:"
    if name.startswith(prefix) and len(name) > len(prefix):
        return name[len(prefix) :]
    return str(layer.kind)


def _unique(name: str, used: set[str]) -> str:
    if name not in used:
        return name
    k = 2
    while f"{name}_{k}" in used:
        k += 1
    return f"{name}_{k}"


def serve_scene(
    scene: Any,
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    open_browser: bool = False,
    play: bool = True,
    frame: int = 0,
) -> ViewerHandle:
    """Serve ``scene`` in the browser and return at once (the server runs in threads).

    Parameters
    ----------
    scene : skincap.viz.scene.Scene
        Layers in metres, Y up (markers, points, skeleton, mesh, curve).
    host : str
        Interface to listen on; ``0.0.0.0`` serves the local network.
    port : int
        First port to try; the next free one is used when it is taken, and 0 lets the
        system choose. :attr:`ViewerHandle.port` says which.
    open_browser : bool
        Open the page in the default web browser.
    play : bool
        Start playing (real time at ``scene.rate``, looping); else stay at ``frame``.
    frame : int
        The scene frame shown first, ``0 <= frame < scene.n_frames``.

    Returns
    -------
    ViewerHandle
        ``handle.url`` to open, ``handle.frame`` to read or set the frame,
        ``handle.play()``/``pause()``, ``handle.stop()`` (also a context manager).

    Raises
    ------
    MissingDependencyError
        When viser is not installed (``pip install 'skincap[view]'``).
    ValidationError
        For an empty scene or a frame out of range.

    Examples
    --------
    >>> from skincap.viz.scene import load_scene  # doctest: +SKIP
    >>> handle = serve_scene(load_scene(["walk.c3d"]), port=0)  # doctest: +SKIP
    >>> handle.frame = 100; handle.stop()  # doctest: +SKIP
    """
    try:
        import viser
    except ImportError:
        raise MissingDependencyError("viser", "view", "the browser viewer") from None
    handle = ViewerHandle(scene, viser, host=host, port=port, play=play, frame=frame)
    if open_browser:
        webbrowser.open(handle.url)
    return handle
