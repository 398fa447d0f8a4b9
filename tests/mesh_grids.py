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
