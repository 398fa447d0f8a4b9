"""The browser viewer behind ``skincap view``: a viser server showing a scene.

:func:`serve_scene` serves a :class:`skincap.viz.scene.Scene` (markers, point clouds,
skeletons, meshes, rope curves) with a timeline; viser is imported only when it is
called, so importing this package needs no optional dependency.
"""

from __future__ import annotations

from skincap.viz.colours import file_tint, label_colours
from skincap.viz.viewer.server import ViewerHandle, camera_framing, default_point_size, serve_scene
from skincap.viz.viewer.timeline import PlaybackClock

__all__ = [
    "serve_scene",
    "ViewerHandle",
    "camera_framing",
    "default_point_size",
    "label_colours",
    "file_tint",
    "PlaybackClock",
]
