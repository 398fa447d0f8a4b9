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
        Fewer than 3 labelled markers ever seen, markers in fewer than 2 frames, or a
        surface without triangles.
    """
    from skincap.cleanup.surface import build_marker_surface, choose_reference_frame

    keep = [i for i, lab in enumerate(markers.labels) if not str(lab).startswith("*")]
    x = markers.positions[:, keep]
    seen = int(np.isfinite(x[..., 0]).any(axis=0).sum())
    if seen < 3:
        # say why there is no surface: an unlabelled or empty capture, not a geometry fault
        raise ValidationError(
            f"{seen} labelled markers (of {markers.n_markers} columns; *N fragments are left "
            "out); the held-out test needs a marker surface over at least 3 (label the "
            "capture first)"
        )
    moving = int(np.isfinite(x[..., 0]).any(axis=1).sum())
    if moving < 2:
        # the reference frame alone: every held-out marker sits where it was, error 0
        raise ValidationError(
            f"{moving} frame with markers; the held-out test needs frames besides the "
            "reference frame"
        )
    frame = choose_reference_frame(x)
    surface = build_marker_surface(x, reference_frame=frame)
    if surface.faces.shape[0] == 0:
        raise ValidationError("the capture's marker surface has no triangles")
    return x, [str(markers.labels[i]) for i in keep], int(frame), surface.faces
