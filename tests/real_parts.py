"""A real capture cut into near-rigid parts of its marker surface, for the dense tests.

Importable from any test as ``from real_parts import segmented_real_take`` (pytest puts
``tests/`` on ``sys.path``, as for ``mesh_grids``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skincap import io
from skincap.cleanup.surface import build_marker_surface, choose_reference_frame
from skincap.deform.dense.rig import marker_weights_of
from skincap.deform.dense.segmentation import segment_marker_surface
from skincap.deform.dense.weights import candidates_from_triangle_parts


def segmented_real_take(path: Path, *, step: int, n_parts: int = 6) -> dict[str, Any]:
    """Every ``step``-th frame of a labelled capture's markers seen in its reference frame,
    its marker surface, a segmentation into ``n_parts`` and the markers' part weights.

    Returns a dict: ``x`` (T, N, 3) metres, ``frame`` the reference frame, ``faces``
    (F, 3), ``seg`` the segmentation, ``cand`` (N, P) candidate parts, ``alpha`` (N, P).
    """
    take = io.read(path)
    keep = [i for i, lab in enumerate(take.labels) if not str(lab).startswith("*")]
    x = take.positions[::step, keep]
    frame = choose_reference_frame(x)
    x = x[:, np.isfinite(x[frame]).all(axis=1)]
    faces = build_marker_surface(x, reference_frame=frame).faces
    seg = segment_marker_surface(x, x[frame], faces, n_parts=n_parts)
    cand = candidates_from_triangle_parts(faces, seg.triangle_parts, x.shape[1], seg.n_parts)
    alpha = marker_weights_of(x, x[frame], cand, faces)
    return {"x": x, "frame": frame, "faces": faces, "seg": seg, "cand": cand, "alpha": alpha}
