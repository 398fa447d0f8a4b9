"""Triangulated grids for tests (shared by tests/geometry and tests/deform).

Importable from any test as ``from mesh_grids import grid_triangles``: pytest puts
this folder on ``sys.path`` when it loads ``tests/conftest.py``.
"""

from __future__ import annotations

import numpy as np


def grid_triangles(nx: int, ny: int) -> np.ndarray:
    """Two triangles per cell of an ``nx`` x ``ny`` grid of vertices.

    Vertex ``(i, j)`` is number ``i * ny + j`` (``np.meshgrid(..., indexing="ij")``
    raveled). Each cell ``a=(i, j), b=(i+1, j), c=(i+1, j+1), d=(i, j+1)`` gives the
    triangles ``(a, b, c)`` and ``(a, c, d)``, counter-clockwise seen from +z when
    ``i`` runs along +x and ``j`` along +y; all the first triangles come first.

    Returns
    -------
    (2 * (nx - 1) * (ny - 1), 3) int64
    """
    idx = np.arange(nx * ny).reshape(nx, ny)
    a = idx[:-1, :-1].ravel()
    b = idx[1:, :-1].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def tube(
    n_along: int, n_around: int, radius: float, length: float = 0.6
) -> tuple[np.ndarray, np.ndarray]:
    """A tube along x in ``[0, length]`` (metres), closed around, open at both ends.

    Returns
    -------
    vertices : (n_along * n_around, 3) float64, metres; ring ``i`` at ``x = i * length /
        (n_along - 1)``
    faces : (2 * (n_along - 1) * n_around, 3) int64, facing outward
    """
    x = np.linspace(0.0, length, n_along)
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    xx, aa = np.meshgrid(x, a, indexing="ij")
    pts = np.stack([xx.ravel(), radius * np.cos(aa).ravel(), radius * np.sin(aa).ravel()], 1)
    idx = np.arange(n_along * n_around).reshape(n_along, n_around)
    nxt = np.roll(idx, -1, axis=1)
    a0, b0, c0, d0 = idx[:-1].ravel(), idx[1:].ravel(), nxt[1:].ravel(), nxt[:-1].ravel()
    return pts, np.concatenate([np.stack([a0, c0, b0], 1), np.stack([a0, d0, c0], 1)])
