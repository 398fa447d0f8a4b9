"""What the OBJ and PLY readers and writers share: polygon triangulation, units and axes, float text."""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError
from skincap.io._common import from_y_up, unit_scale
from skincap.types import Mesh


def triangulate_polygons(
    polygon_indices: np.ndarray, polygon_offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fan-triangulate polygons given in CSR layout.

    Parameters
    ----------
    polygon_indices : (P,) int64
        Vertex indices of all polygons, one polygon after the other.
    polygon_offsets : (G + 1,) int64
        Polygon ``g`` is ``polygon_indices[polygon_offsets[g]:polygon_offsets[g + 1]]``;
        every polygon has at least 3 corners.

    Returns
    -------
    faces : (F, 3) int64
        Triangles ``(c0, ck, ck+1)`` for ``k = 1 .. n-2`` of each polygon, in order.
    face_polygon : (F,) int64
        Index of the polygon each triangle comes from.
    """
    idx = np.asarray(polygon_indices, dtype=np.int64)
    off = np.asarray(polygon_offsets, dtype=np.int64)
    sizes = np.diff(off)
    n_tri = sizes - 2
    face_polygon = np.repeat(np.arange(sizes.size, dtype=np.int64), n_tri)
    first = np.repeat(off[:-1], n_tri)
    # k runs 1 .. n-2 inside each polygon
    tri_start = np.concatenate([[0], np.cumsum(n_tri)])[:-1]
    k = np.arange(face_polygon.size, dtype=np.int64) - np.repeat(tri_start, n_tri) + 1
    faces = np.stack([idx[first], idx[first + k], idx[first + k + 1]], axis=1)
    return faces.reshape(-1, 3), face_polygon


def scale_and_up(units: str, up: str) -> tuple[float, str]:
    """Metres per ``units`` and the up axis key (``"y"`` or ``"z"``); ValidationError otherwise."""
    scale = unit_scale(units)
    up_key = up.strip().lower().lstrip("+")
    if up_key not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up!r}")
    return scale, up_key


def restore_units(mesh: Mesh, units: str | None, up: str | None) -> tuple[np.ndarray, str, str]:
    """Vertices in the file's unit and axes, with the unit and up names used."""
    units = units if units is not None else str(mesh.meta.get("source_units", "m"))
    up = up if up is not None else str(mesh.meta.get("up", "y"))
    scale, up = scale_and_up(units, up)
    return from_y_up(mesh.vertices, up) / scale, units, up


def polygons_of(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's source polygons in CSR layout (indices (P,), offsets (G + 1,)), else its triangles."""
    if mesh.polygon_indices is not None and mesh.polygon_offsets is not None:
        return mesh.polygon_indices, mesh.polygon_offsets
    return mesh.faces.reshape(-1), np.arange(0, 3 * mesh.n_faces + 1, 3, dtype=np.int64)


def format_floats(values: np.ndarray, exact: bool) -> list[str]:
    """Shortest round-trip text of each float (``exact``) or 15 significant digits."""
    if exact:
        return [repr(x) for x in values.tolist()]
    return [f"{x:.15g}" for x in values.tolist()]
