"""Offscreen pictures of a scene: PNG stills and GIF/MP4 clips, no display needed.

The renderer is a painter's-algorithm projector on top of matplotlib's Agg canvas:
every primitive of a frame — mesh triangles, marker discs, skeleton bones and rope
segments as thin quads — becomes one polygon, and all polygons are sorted far to near
together, so markers behind the body are hidden by it and markers in front are not.
Triangles are flat shaded by a head light. The camera looks at the whole take's bounds
from ``azimuth`` / ``elevation`` (degrees; Y up, azimuth 0 looks along −Z, i.e. at the
subject's front when it faces +Z) and stays put for a clip so motion reads as motion.

Colours: markers take a stable colour from their label (:func:`label_colours`), the
same in every file, so raw and cleaned captures overlay label for label; invented
samples are white discs with a dark rim; unlabelled fragments are grey; missing
samples are not drawn.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skincap.errors import FormatError, MissingDependencyError, ValidationError
from skincap.io._common import atomic_output
from skincap.viz.colours import label_colours as shared_label_colours
from skincap.viz.plotting import agg_pyplot
from skincap.viz.scene import (
    CurveLayer,
    MarkerLayer,
    MeshLayer,
    PointLayer,
    Scene,
    SkeletonLayer,
)

__all__ = ["Camera", "label_colours", "render_image", "render_frames", "write_picture"]

#: Output types :func:`write_picture` knows.
PICTURE_EXTENSIONS = (".png", ".gif", ".mp4")

_SKIN = np.array([0.86, 0.72, 0.62])
_BACKGROUND = (0.97, 0.97, 0.96)
_POINT_COLOUR = np.array([0.35, 0.35, 0.38])
_BONE_COLOUR = np.array([0.15, 0.18, 0.25])
_CURVE_COLOUR = np.array([0.95, 0.45, 0.05])
_DISC_SIDES = 8


def label_colours(labels: Sequence[str]) -> np.ndarray:
    """(N, 3) float RGB in 0..1: the viewer's stable colour per label (fragments grey).

    See :func:`skincap.viz.colours.label_colours`; the same marker has the same colour in
    every file, in the viewer and in rendered pictures.
    """
    return shared_label_colours(labels).astype(np.float64) / 255.0


@dataclass(frozen=True)
class Camera:
    """A perspective camera aimed at the subject.

    Attributes
    ----------
    azimuth, elevation : float, degrees
        Direction the camera looks from: azimuth about +Y (0 = from +Z), elevation
        above the horizontal.
    fov : float, degrees
        Vertical field of view.
    follow : bool
        Keep the subject centred frame by frame (a walk stays big in the picture;
        the floor grid slides past). Otherwise frame the whole take's bounds once.
    """

    azimuth: float = 30.0
    elevation: float = 12.0
    fov: float = 30.0
    follow: bool = True

    def basis(
        self, centre: np.ndarray, radius: float, aspect: float
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Eye (3,), rows right/up/forward (3, 3), focal length in normalised units.

        The camera sits far enough from ``centre`` for a sphere of ``radius``
        metres to fit the narrower image direction.
        """
        az, el = np.radians(self.azimuth), np.radians(self.elevation)
        back = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
        forward = -back
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        f = 1.0 / np.tan(np.radians(self.fov) / 2)
        fit = min(1.0, aspect)
        distance = max(radius, 1e-3) * np.sqrt(1.0 + (f / fit) ** 2) * 1.05
        return centre + back * distance, np.stack([right, up, forward]), f


def _project(points: np.ndarray, eye: np.ndarray, rows: np.ndarray, f: float) -> np.ndarray:
    """(..., 3) world -> (..., 3) image x, y (normalised: y in -1..1) and depth."""
    cam = (points - eye) @ rows.T
    depth = cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = f * cam[..., :2] / depth[..., None]
    return np.concatenate([xy, depth[..., None]], axis=-1)


def _pad(polys: np.ndarray) -> np.ndarray:
    """(P, k, 2) -> (P, _DISC_SIDES, 2) by repeating the last corner."""
    k = polys.shape[1]
    if k == _DISC_SIDES:
        return polys
    return np.concatenate([polys, np.repeat(polys[:, -1:], _DISC_SIDES - k, axis=1)], axis=1)


def _discs(centres: np.ndarray, radius: float) -> np.ndarray:
    """(P, 2) image centres -> (P, 8, 2) octagons of ``radius`` (image units)."""
    ang = 2 * np.pi * np.arange(_DISC_SIDES) / _DISC_SIDES
    ring = np.stack([np.cos(ang), np.sin(ang)], axis=1) * radius
    return centres[:, None, :] + ring[None]


def _segments(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    """(P, 2) image endpoints -> (P, 4, 2) quads ``width`` wide (image units)."""
    d = b - a
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = n / np.where(norm > 0, norm, 1.0) * (width / 2)
    return np.stack([a + n, b + n, b - n, a - n], axis=1)


class _Primitives:
    """Polygons of one frame: corners (P, 8, 2), depth (P,), face colour (P, 4), edge (P, 4)."""

    def __init__(self) -> None:
        self.polys: list[np.ndarray] = []
        self.depth: list[np.ndarray] = []
        self.face: list[np.ndarray] = []
        self.edge: list[np.ndarray] = []

    def add(self, polys: np.ndarray, depth: np.ndarray, face: np.ndarray, edge: np.ndarray) -> None:
        keep = np.isfinite(polys).all(axis=(1, 2)) & (depth > 1e-6)
        if not keep.any():
            return
        self.polys.append(_pad(polys[keep]))
        self.depth.append(depth[keep])
        self.face.append(np.broadcast_to(face, (keep.size, 4))[keep])
        self.edge.append(np.broadcast_to(edge, (keep.size, 4))[keep])

    def sorted(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if not self.polys:
            return np.zeros((0, _DISC_SIDES, 2)), np.zeros((0, 4)), np.zeros((0, 4))
        depth = np.concatenate(self.depth)
        order = np.argsort(-depth, kind="stable")  # far first
        return (
            np.concatenate(self.polys)[order],
            np.concatenate(self.face)[order],
            np.concatenate(self.edge)[order],
        )


def _rgba(rgb: np.ndarray, alpha: float = 1.0) -> np.ndarray:
    rgb = np.atleast_2d(rgb)
    return np.concatenate([rgb, np.full((rgb.shape[0], 1), alpha)], axis=1)


def _frame_primitives(
    scene: Scene,
    t_seconds: float,
    eye: np.ndarray,
    rows: np.ndarray,
    f: float,
    px: float,
    label_rgb: dict[str, np.ndarray],
) -> _Primitives:
    """Every visible primitive of the scene at ``t_seconds``; ``px`` = image units per pixel."""
    prims = _Primitives()
    light = -rows[2]  # a head light: from the camera towards the scene
    # a skinned glTF's own skeleton would only poke through its skin: draw the skin
    skinned = {lay.source for lay in scene.layers if isinstance(lay, MeshLayer) and lay.source}
    for layer in scene.layers:
        if isinstance(layer, SkeletonLayer) and layer.source in skinned:
            continue
        k = scene.layer_frame(layer, t_seconds)
        if isinstance(layer, MeshLayer):
            v = layer.frames[k].astype(np.float64)
            tri = v[layer.faces]  # (F, 3, 3)
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            norm = np.linalg.norm(n, axis=1)
            ok = norm > 0
            n[ok] /= norm[ok, None]
            shade = 0.35 + 0.65 * np.abs(n @ light)  # two-sided: windings vary between files
            proj = _project(tri, eye, rows, f)
            rgb = np.clip(shade[:, None] * _SKIN[None], 0, 1)
            face = _rgba(rgb)
            prims.add(proj[..., :2], proj[..., 2].mean(axis=1), face, face)
        elif isinstance(layer, MarkerLayer):
            p = layer.positions[k]
            ok = np.isfinite(p).all(axis=1)
            proj = _project(p[ok], eye, rows, f)
            rgb = label_rgb[layer.name][ok]
            inv = layer.invented[k][ok]
            face = _rgba(np.where(inv[:, None], 1.0, rgb))
            edge = _rgba(np.where(inv[:, None], 0.1, rgb * 0.6))
            prims.add(_discs(proj[:, :2], 4.0 * px), proj[:, 2] - 0.01, face, edge)
        elif isinstance(layer, PointLayer):
            p = layer.cloud.frame(k)
            proj = _project(p, eye, rows, f)
            face = _rgba(_POINT_COLOUR)
            prims.add(_discs(proj[:, :2], 2.5 * px), proj[:, 2] - 0.01, face, face)
        elif isinstance(layer, SkeletonLayer):
            j = layer.joints[k]
            child = np.flatnonzero(layer.parents >= 0)
            a = _project(j[layer.parents[child]], eye, rows, f)
            b = _project(j[child], eye, rows, f)
            face = _rgba(_BONE_COLOUR)
            prims.add(
                _segments(a[:, :2], b[:, :2], 3.0 * px), 0.5 * (a[:, 2] + b[:, 2]), face, face
            )
            pj = _project(j, eye, rows, f)
            prims.add(_discs(pj[:, :2], 2.5 * px), pj[:, 2], face, face)
        elif isinstance(layer, CurveLayer):
            c = _project(layer.curves[k], eye, rows, f)
            face = _rgba(_CURVE_COLOUR)
            prims.add(
                _segments(c[:-1, :2], c[1:, :2], 3.5 * px), 0.5 * (c[:-1, 2] + c[1:, 2]), face, face
            )
    return prims


#: Most floor grid lines along one axis of a picture.
MAX_FLOOR_LINES = 200


def _floor_lines(bounds: np.ndarray, eye: np.ndarray, rows: np.ndarray, f: float) -> np.ndarray:
    """(L, 2, 2) image segments of a floor grid spanning ``bounds`` (2, 3) metres at its
    lowest y: lines 0.5 m apart, or a power of two times that so that an axis has at most
    :data:`MAX_FLOOR_LINES` (none when the bounds are not finite)."""
    lo, hi = bounds
    span = float(max(hi[0] - lo[0], hi[2] - lo[2], 0.0))
    if not np.isfinite(span):
        return np.zeros((0, 2, 2))
    # a fixed 0.5 m step turned one sample 1e9 m out into a grid of 6e9 points (44 GB)
    step = 0.5 * 2.0 ** max(0.0, np.ceil(np.log2(max(span, 1e-300) / (0.5 * MAX_FLOOR_LINES))))
    x0, x1 = np.floor(lo[0] / step) * step - step, np.ceil(hi[0] / step) * step + step
    z0, z1 = np.floor(lo[2] / step) * step - step, np.ceil(hi[2] / step) * step + step
    y = lo[1]
    xs, zs = np.arange(x0, x1 + 1e-9, step), np.arange(z0, z1 + 1e-9, step)
    a = np.concatenate([np.stack([xs, np.full_like(xs, y), np.full_like(xs, z0)], 1),
                        np.stack([np.full_like(zs, x0), np.full_like(zs, y), zs], 1)])  # fmt: skip
    b = np.concatenate([np.stack([xs, np.full_like(xs, y), np.full_like(xs, z1)], 1),
                        np.stack([np.full_like(zs, x1), np.full_like(zs, y), zs], 1)])  # fmt: skip
    pa, pb = _project(a, eye, rows, f), _project(b, eye, rows, f)
    ok = (pa[:, 2] > 1e-3) & (pb[:, 2] > 1e-3)
    return np.stack([pa[ok, :2], pb[ok, :2]], axis=1)


class _Renderer:
    """One figure reused for every frame of a clip (Agg, no display)."""

    def __init__(self, scene: Scene, camera: Camera, size: tuple[int, int], title: bool) -> None:
        agg_pyplot("rendering pictures")
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection, PolyCollection
        from matplotlib.figure import Figure

        width, height = size
        if width < 16 or height < 16:
            raise ValidationError(f"size: at least 16x16 pixels, got {width}x{height}")
        self.scene = scene
        self.camera = camera
        self.aspect = width / height
        self.bounds = scene.bounds()
        if camera.follow:
            # the largest single-frame extent over the take sets a fixed distance
            probe = np.linspace(0.0, scene.duration, 60)
            boxes = [b for b in (scene.bounds_at(t) for t in probe) if b is not None]
            self.radius = max(
                (0.5 * float(np.linalg.norm(b[1] - b[0])) for b in boxes), default=1.0
            )
        else:
            self.radius = 0.5 * float(np.linalg.norm(self.bounds[1] - self.bounds[0]))
        self.radius = max(self.radius, 0.25)
        self.px = 2.0 / height  # image units per pixel (y spans -1..1)
        self.labels = {
            lay.name: label_colours(lay.labels)
            for lay in scene.layers
            if isinstance(lay, MarkerLayer)
        }
        dpi = 100
        self.fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor=_BACKGROUND)
        ax = self.fig.add_axes((0, 0, 1, 1))
        ax.set_facecolor(_BACKGROUND)
        ax.set_xlim(-self.aspect, self.aspect)
        ax.set_ylim(-1, 1)
        ax.set_axis_off()
        self.grid = LineCollection([], colors=[(0.75, 0.75, 0.75)], linewidths=0.6, zorder=0)
        ax.add_collection(self.grid)
        self.polys = PolyCollection([], linewidths=0.3, antialiaseds=True, zorder=2)
        ax.add_collection(self.polys)
        self.text = ax.text(
            -self.aspect + 0.03,
            0.97,
            "",
            fontsize=9,
            color=(0.2, 0.2, 0.2),
            family="monospace",
            va="top",
        )
        self.show_title = title
        self.canvas = FigureCanvasAgg(self.fig)

    def draw(self, t_seconds: float) -> np.ndarray:
        """(H, W, 3) uint8 picture of the scene at ``t_seconds``."""
        centre = self.bounds.mean(axis=0)
        if self.camera.follow:
            box = self.scene.bounds_at(t_seconds)
            if box is not None:
                centre = box.mean(axis=0)
        eye, rows, f = self.camera.basis(centre, self.radius, self.aspect)
        floor = np.stack([centre - 3 * self.radius, centre + 3 * self.radius])
        floor[0, 1] = self.bounds[0, 1]
        self.grid.set_segments(_floor_lines(floor, eye, rows, f))
        prims = _frame_primitives(self.scene, t_seconds, eye, rows, f, self.px, self.labels)
        polys, face, edge = prims.sorted()
        self.polys.set_verts(polys)
        self.polys.set_facecolors(face)
        self.polys.set_edgecolors(edge)
        if self.show_title:
            frame = int(round(t_seconds * self.scene.rate))
            names = ", ".join(lay.name for lay in self.scene.layers)
            if len(names) > 70:
                names = names[:67] + "..."
            self.text.set_text(f"{names}\nt = {t_seconds:7.3f} s  frame {frame}")
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def render_image(
    scene: Scene,
    t_seconds: float = 0.0,
    *,
    camera: Camera | None = None,
    size: tuple[int, int] = (960, 720),
    title: bool = True,
) -> np.ndarray:
    """One picture of the scene.

    Parameters
    ----------
    scene : Scene
    t_seconds : float
        Time on the scene clock; each layer shows its nearest frame.
    camera : Camera, optional
    size : (width, height) pixels
    title : bool
        Print the layer names, time and frame in the corner.

    Returns
    -------
    (H, W, 3) uint8 RGB
    """
    return _Renderer(scene, camera or Camera(), size, title).draw(t_seconds)


def render_frames(
    scene: Scene,
    times: np.ndarray,
    *,
    camera: Camera | None = None,
    size: tuple[int, int] = (640, 480),
    title: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> list[np.ndarray]:
    """Pictures at several times with one fixed camera; ``progress(done, total)`` per frame.

    Returns a list of (H, W, 3) uint8 arrays (one per time).
    """
    renderer = _Renderer(scene, camera or Camera(), size, title)
    pictures = []
    for i, t in enumerate(np.asarray(times, dtype=np.float64)):  # one picture per frame
        pictures.append(renderer.draw(float(t)))
        if progress is not None:
            progress(i + 1, len(times))
    return pictures


def write_picture(
    scene: Scene,
    path: str | os.PathLike[str],
    *,
    time: float | None = None,
    start: float = 0.0,
    end: float | None = None,
    fps: float = 30.0,
    camera: Camera | None = None,
    size: tuple[int, int] = (960, 720),
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Render to ``.png`` (one frame) or ``.gif`` / ``.mp4`` (a clip), atomically.

    Parameters
    ----------
    scene : Scene
    path : path-like
        The extension chooses the output. MP4 needs the ``imageio-ffmpeg`` package
        (``pip install 'skincap[video]'``); GIF needs only matplotlib's Pillow.
    time : float, optional, seconds
        The frame of a PNG. Default: the middle of the take.
    start, end : float, seconds
        The span of a clip. Default: the whole take.
    fps : float
        Frames per second of a clip (the scene is resampled on its clock).
    camera, size, force, progress
        As :func:`render_frames`; ``force`` replaces an existing output.

    Returns
    -------
    Path of the written file.
    """
    out = Path(path)
    ext = out.suffix.lower()
    if ext not in PICTURE_EXTENSIONS:
        raise FormatError(
            out, f"cannot render to {ext or 'no extension'!r}; use .png, .gif or .mp4"
        )
    if not (np.isfinite(fps) and fps > 0):
        raise ValidationError(f"fps: must be positive, got {fps!r}")
    if ext == ".png":
        t = scene.duration / 2 if time is None else float(time)
        picture = render_image(scene, t, camera=camera, size=size)
        import matplotlib.image

        with atomic_output(out, force=force) as tmp:
            matplotlib.image.imsave(tmp, picture, format="png")
        return out
    stop = scene.duration if end is None else min(float(end), scene.duration)
    if stop < start:
        raise ValidationError(f"end ({stop:g} s) is before start ({start:g} s)")
    times = np.arange(start, stop + 1e-9, 1.0 / fps)
    if ext == ".mp4":
        try:
            import imageio_ffmpeg
        except ImportError:
            raise MissingDependencyError("imageio-ffmpeg", "video", "MP4 output") from None
    pictures = render_frames(scene, times, camera=camera, size=size, progress=progress)
    with atomic_output(out, force=force) as tmp:
        if ext == ".gif":
            from PIL import Image

            frames = [Image.fromarray(p) for p in pictures]
            frames[0].save(
                tmp,
                format="GIF",
                save_all=True,
                append_images=frames[1:],
                duration=int(round(1000 / fps)),
                loop=0,
            )
        else:
            h, w = pictures[0].shape[:2]
            writer = imageio_ffmpeg.write_frames(
                str(tmp), (w, h), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                macro_block_size=1, output_params=["-f", "mp4"],
            )  # fmt: skip
            writer.send(None)
            for p in pictures:
                writer.send(np.ascontiguousarray(p))
            writer.close()
    return out
