"""A labelled capture's marker surface, as the held-out tests on real captures build it."""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = ["labelled_capture_surface"]


def labelled_capture_surface(markers: Any) -> tuple[np.ndarray, list[str], int, np.ndarray]:
    """The labelled columns of a capture and the marker surface built on them.

    Parameters
    ----------
    markers : MarkerSet
        Unlabelled fragments (``*N`` labels) are left out.

    Returns
    -------
    positions : (T, N, 3) float, metres, NaN where missing (the labelled columns)
    labels : N strings
    reference_frame : int, the frame with the most markers
    faces : (F, 3) int, the marker surface's triangles (F >= 1)

    Raises
    ------
    ValidationError
        When the surface has no triangles.
    """
    from skincap.cleanup.surface import build_marker_surface, choose_reference_frame

    keep = [i for i, lab in enumerate(markers.labels) if not str(lab).startswith("*")]
    x = markers.positions[:, keep]
    frame = choose_reference_frame(x)
    surface = build_marker_surface(x, reference_frame=frame)
    if surface.faces.shape[0] == 0:
        raise ValidationError("the capture's marker surface has no triangles")
    return x, [str(markers.labels[i]) for i in keep], int(frame), surface.faces
