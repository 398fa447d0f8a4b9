"""Scene-node drawers: one per layer kind, each turning a layer frame into viser nodes.

A drawer owns one viser frame node (its visibility toggle) and the children under it.
:meth:`LayerDrawer.draw` sends only what changed since the last call: new positions
always, colours only when the set of drawn samples changes, nothing for a static mesh
or a frame already shown. Every update is a whole-array numpy operation (masking,
fancy indexing); nothing loops over markers, joints or vertices in Python.

This module imports viser lazily: it receives the viser ``SceneApi`` from the server.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any

import numpy as np

from skincap.errors import ValidationError
from skincap.viz.colours import INVENTED_COLOUR, label_colours

__all__ = [
    "DrawStyle",
    "LayerDrawer",
    "MarkerDrawer",
    "PointDrawer",
    "SkeletonDrawer",
    "MeshDrawer",
    "CurveDrawer",
    "make_drawer",
]

#: Invented samples are drawn this much larger than measured ones.
INVENTED_SIZE_FACTOR = 1.6


@dataclass
class DrawStyle:
    """How a layer is drawn.

    Attributes
    ----------
    point_size : float, metres
        Diameter of a marker or point.
    line_thickness : float, metres
        Thickness of bones and curves.
    colour : (3,) uint8
        The layer's own colour (points, skeleton, mesh, curve).
    file_tint : (3,) uint8
        The colour of the layer's file, used for markers when ``tint_markers``.
    tint_markers : bool
        Colour markers by file instead of by label.
    """

    point_size: float
    line_thickness: float
    colour: np.ndarray
    file_tint: np.ndarray
    tint_markers: bool = False


class LayerDrawer(abc.ABC):
    """Base class: a frame node holding a layer's viser nodes.

    Parameters
    ----------
    scene_api : viser SceneApi
        ``server.scene``.
    node : str
        The layer's node path, e.g. ``/capture_c3d/markers``.
    layer : Layer
        A :mod:`skincap.viz.scene` layer.
    style : DrawStyle
    """

    def __init__(self, scene_api: Any, node: str, layer: Any, style: DrawStyle) -> None:
        self.scene_api = scene_api
        self.node = node
        self.layer = layer
        self.style = style
        self.root = scene_api.add_frame(node, show_axes=False)
        self.children: dict[str, Any] = {}
        self.shown_frame: int | None = None

    @property
    def visible(self) -> bool:
        return bool(self.root.visible)

    @visible.setter
    def visible(self, value: bool) -> None:
        self.root.visible = bool(value)

    def draw(self, frame: int, *, force: bool = False) -> None:
        """Show layer frame ``frame`` (clipped to the layer); skip if already shown."""
        frame = int(np.clip(frame, 0, max(self.layer.n_frames - 1, 0)))
        if frame == self.shown_frame and not force:
            return
        self._draw(frame, force=force)
        self.shown_frame = frame

    @abc.abstractmethod
    def _draw(self, frame: int, *, force: bool) -> None:
        """Send layer frame ``frame`` to the client (``force``: resend colours too)."""

    def set_point_size(self, size: float) -> None:
        """Change the point diameter in metres (markers, points, joints)."""
        self.style.point_size = float(size)

    def set_tint_markers(self, tint: bool) -> None:
        """Colour markers by file (True) or by label (False)."""
        self.style.tint_markers = bool(tint)


def _cloud(scene_api: Any, name: str, size: float, shape: str) -> Any:
    """A point cloud node, hidden until it has points (the client rejects empty buffers)."""
    return scene_api.add_point_cloud(
        name,
        points=np.zeros((1, 3), dtype=np.float32),
        colors=np.zeros((1, 3), dtype=np.uint8),
        point_size=size,
        point_shape=shape,
        precision="float32",
        visible=False,
    )


def _set_cloud(handle: Any, points: np.ndarray, colours: np.ndarray | None) -> None:
    """Update a point cloud; ``colours`` None means the count and colours are unchanged.

    An empty frame hides the node and keeps its last arrays; the next non-empty
    frame must pass ``colours`` (its count differs from zero, so callers do).
    """
    if points.shape[0] == 0:
        if handle.visible:
            handle.visible = False
        return
    handle.points = np.ascontiguousarray(points, dtype=np.float32)
    if colours is not None:
        handle.colors = np.ascontiguousarray(colours, dtype=np.uint8)
    if not handle.visible:
        handle.visible = True


class MarkerDrawer(LayerDrawer):
    """Labelled markers: measured samples in the label's colour, invented ones grey.

    Missing samples (NaN) are not drawn. Invented samples (``layer.invented``) are
    drawn larger, as grey diamonds. Colours follow
    :func:`skincap.viz.colours.label_colours`, or the file tint when
    ``style.tint_markers``.
    """

    def __init__(self, scene_api: Any, node: str, layer: Any, style: DrawStyle) -> None:
        super().__init__(scene_api, node, layer, style)
        self.label_rgb = label_colours(layer.labels)  # (N, 3) uint8
        self.measured = _cloud(scene_api, f"{node}/measured", style.point_size, "circle")
        self.invented = _cloud(
            scene_api, f"{node}/invented", style.point_size * INVENTED_SIZE_FACTOR, "diamond"
        )
        self.children = {"measured": self.measured, "invented": self.invented}
        self._masks: tuple[np.ndarray, np.ndarray] | None = None

    def masks(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """(N,) bool measured and (N,) bool invented samples of layer frame ``frame``."""
        present = ~np.isnan(self.layer.positions[frame]).any(axis=-1)
        invented = self.layer.invented
        if invented is None:
            flags = np.zeros_like(present)
        else:
            flags = np.asarray(invented[frame], dtype=bool)
        return present & ~flags, present & flags

    def _base_colours(self) -> np.ndarray:
        if self.style.tint_markers:
            return np.broadcast_to(self.style.file_tint, self.label_rgb.shape)
        return self.label_rgb

    def _draw(self, frame: int, *, force: bool) -> None:
        pos = self.layer.positions[frame]  # (N, 3) metres
        measured, invented = self.masks(frame)
        same = (
            not force
            and self._masks is not None
            and np.array_equal(measured, self._masks[0])
            and np.array_equal(invented, self._masks[1])
        )
        base = self._base_colours()
        _set_cloud(self.measured, pos[measured], None if same else base[measured])
        grey = np.broadcast_to(INVENTED_COLOUR, (int(invented.sum()), 3))
        _set_cloud(self.invented, pos[invented], None if same else grey)
        self._masks = (measured, invented)

    def set_point_size(self, size: float) -> None:
        super().set_point_size(size)
        self.measured.point_size = float(size)
        self.invented.point_size = float(size) * INVENTED_SIZE_FACTOR

    def set_tint_markers(self, tint: bool) -> None:
        super().set_tint_markers(tint)
        if self.shown_frame is not None:
            self.draw(self.shown_frame, force=True)


class PointDrawer(LayerDrawer):
    """An un-indexed point cloud (``layer.cloud``), one colour for the layer."""

    def __init__(self, scene_api: Any, node: str, layer: Any, style: DrawStyle) -> None:
        super().__init__(scene_api, node, layer, style)
        self.points = _cloud(scene_api, f"{node}/points", style.point_size, "circle")
        self.children = {"points": self.points}
        self._count: int | None = None

    def _draw(self, frame: int, *, force: bool) -> None:
        pts = np.asarray(self.layer.cloud.frame(frame))  # (m, 3) metres
        changed = force or pts.shape[0] != self._count
        colours = np.broadcast_to(self.style.colour, pts.shape) if changed else None
        _set_cloud(self.points, pts, colours)
        self._count = pts.shape[0]

    def set_point_size(self, size: float) -> None:
        super().set_point_size(size)
        self.points.point_size = float(size)


def _lines(scene_api: Any, name: str, colour: np.ndarray, thickness: float) -> Any:
    """A line-segments node in one colour, hidden until it has segments."""
    return scene_api.add_line_segments(
        name,
        points=np.zeros((1, 2, 3), dtype=np.float32),
        colors=tuple(int(c) for c in colour),
        thickness=thickness,
        visible=False,
    )


def _set_lines(handle: Any, segments: np.ndarray) -> None:
    """Update line segments (S, 2, 3); no segment hides the node."""
    if segments.shape[0] == 0:
        if handle.visible:
            handle.visible = False
        return
    handle.points = segments
    if not handle.visible:
        handle.visible = True


def _segments(points: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """(S, 2, 3) float32 segments ``points[start] -> points[end]`` with no NaN end."""
    seg = np.stack([points[start], points[end]], axis=1)
    keep = np.isfinite(seg).all(axis=(1, 2))
    return np.ascontiguousarray(seg[keep], dtype=np.float32)


class SkeletonDrawer(LayerDrawer):
    """A skeleton: one line segment per bone (joint to parent) and a dot per joint."""

    def __init__(self, scene_api: Any, node: str, layer: Any, style: DrawStyle) -> None:
        super().__init__(scene_api, node, layer, style)
        parents = np.asarray(layer.parents, dtype=np.int64)
        self.child = np.flatnonzero(parents >= 0)
        self.parent = parents[self.child]
        self.bones = _lines(scene_api, f"{node}/bones", style.colour, style.line_thickness)
        self.joints = _cloud(scene_api, f"{node}/joints", style.point_size, "circle")
        self.children = {"bones": self.bones, "joints": self.joints}
        self._count: int | None = None

    def _draw(self, frame: int, *, force: bool) -> None:
        joints = np.asarray(self.layer.joints[frame], dtype=np.float64)  # (J, 3) metres
        _set_lines(self.bones, _segments(joints, self.parent, self.child))
        pts = joints[np.isfinite(joints).all(axis=1)]
        changed = force or pts.shape[0] != self._count
        _set_cloud(
            self.joints, pts, np.broadcast_to(self.style.colour, pts.shape) if changed else None
        )
        self._count = pts.shape[0]

    def set_point_size(self, size: float) -> None:
        super().set_point_size(size)
        self.joints.point_size = float(size)


class MeshDrawer(LayerDrawer):
    """A triangle mesh; vertices are re-sent per frame when the mesh deforms (T > 1)."""

    def __init__(self, scene_api: Any, node: str, layer: Any, style: DrawStyle) -> None:
        super().__init__(scene_api, node, layer, style)
        frames = layer.frames
        self.mesh = scene_api.add_mesh_simple(
            f"{node}/mesh",
            vertices=np.nan_to_num(np.asarray(frames[0], dtype=np.float32)),
            faces=np.asarray(layer.faces, dtype=np.uint32),
            color=tuple(int(c) for c in style.colour),
            side="double",
        )
        self.children = {"mesh": self.mesh}
        self.shown_frame = 0

    def _draw(self, frame: int, *, force: bool) -> None:
        if self.layer.n_frames > 1 or force:
            # NaN vertices would break the client's normals; a missing vertex goes to 0
            self.mesh.vertices = np.nan_to_num(np.asarray(self.layer.frames[frame], np.float32))


class CurveDrawer(LayerDrawer):
    """A polyline per frame (the tracked rope)."""

    def __init__(self, scene_api: Any, node: str, layer: Any, style: DrawStyle) -> None:
        super().__init__(scene_api, node, layer, style)
        k = int(np.asarray(layer.curves).shape[1])
        self.start = np.arange(max(k - 1, 0))
        self.end = self.start + 1
        self.line = _lines(scene_api, f"{node}/curve", style.colour, style.line_thickness)
        self.children = {"curve": self.line}

    def _draw(self, frame: int, *, force: bool) -> None:
        curve = np.asarray(self.layer.curves[frame], dtype=np.float64)  # (K, 3) metres
        _set_lines(self.line, _segments(curve, self.start, self.end))


_DRAWERS: dict[str, type[LayerDrawer]] = {
    "markers": MarkerDrawer,
    "points": PointDrawer,
    "skeleton": SkeletonDrawer,
    "mesh": MeshDrawer,
    "curve": CurveDrawer,
}


def make_drawer(scene_api: Any, node: str, layer: Any, style: DrawStyle) -> LayerDrawer:
    """The drawer for ``layer.kind`` (markers, points, skeleton, mesh or curve).

    Raises
    ------
    ValidationError
        For a kind the viewer does not know.
    """
    try:
        cls = _DRAWERS[layer.kind]
    except KeyError:
        raise ValidationError(f"layer {layer.name!r}: no drawer for kind {layer.kind!r}") from None
    return cls(scene_api, node, layer, style)
