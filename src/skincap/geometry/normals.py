"""Vertex normals of a triangle mesh."""

from __future__ import annotations

import numpy as np

__all__ = ["area_weighted_vertex_normals"]


def area_weighted_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals, each the sum of its triangles' area-weighted normals.

    Parameters
    ----------
    vertices : (V, 3) float, any length unit
    faces : (F, 3) int
        Counter-clockwise seen from outside.

    Returns
    -------
    (V, 3) float
        Unit normals; (0, 0, 0) at a vertex in no triangle or only in degenerate ones.
    """
    fn = np.cross(
        vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
    )  # (F, 3), length = twice the area
    n = np.zeros_like(vertices)
    for corner in range(3):  # 3 scatter-adds, not a loop over vertices
        np.add.at(n, faces[:, corner], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)
