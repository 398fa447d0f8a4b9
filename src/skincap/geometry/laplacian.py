"""Discrete Laplace-Beltrami operators on triangle meshes.

The cotangent Laplacian ``L`` (V, V) is the stiffness matrix of piecewise-linear finite
elements: for an edge ``(i, j)`` with opposite angles ``alpha`` and ``beta``,
``L[i, j] = (cot(alpha) + cot(beta)) / 2`` and ``L[i, i] = -sum_j L[i, j]``. It is
symmetric, negative semi-definite, its rows sum to zero and it annihilates functions
that are linear over a flat patch -- the same convention as libigl's ``cotmatrix``.
The mass matrix ``M`` (V, V) is diagonal: the area each vertex stands for (mixed
Voronoi areas, Meyer et al. 2003, as libigl's ``MASSMATRIX_TYPE_VORONOI``, or a third
of each incident triangle). ``M^-1 L`` is the pointwise Laplace-Beltrami operator.

Everything is assembled at once from per-face arrays (no loop over faces or vertices).
Degenerate triangles are harmless: a triangle of zero area contributes nothing to the
mass matrix, cotangents are clamped to ``[-cot_max, cot_max]`` so slivers cannot
produce infinities, and no NaN is ever produced.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components as _csgraph_components

from skincap.errors import ValidationError

__all__ = [
    "cotangent_weights",
    "cotangent_laplacian",
    "mass_matrix",
    "vertex_areas",
    "connected_components",
]

#: Default bound on the magnitude of a cotangent (an angle of about 0.06 degrees).
COT_MAX = 1e3


def _check_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert ``vertices`` (V, 3) float and ``faces`` (F, 3) int."""
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"vertices: expected a (V, 3) float array: {exc}") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValidationError(f"vertices: expected shape (V, 3), got {v.shape}")
    if not np.isfinite(v).all():
        raise ValidationError("vertices: must be finite (no NaN or inf)")
    f = np.asarray(faces)
    if f.size == 0:
        f = f.reshape(0, 3).astype(np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValidationError(f"faces: expected shape (F, 3) (triangles), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise ValidationError(f"faces: expected an integer array, got dtype {f.dtype}")
    f = f.astype(np.int64, copy=False)
    if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
        raise ValidationError(
            f"faces: vertex indices must be in 0..{v.shape[0] - 1}, range is {f.min()}..{f.max()}"
        )
    return v, f


def _face_geometry(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-corner dot products, double areas and squared opposite edge lengths.

    Returns ``dots`` (F, 3): ``dot(e1, e2)`` of the two edges leaving corner ``c``;
    ``dbl_area`` (F,): twice the triangle area; ``l2`` (F, 3): squared length of
    the edge opposite corner ``c``.
    """
    p = v[f]  # (F, 3 corners, 3 xyz)
    # edge opposite corner c runs from corner c+1 to corner c+2
    e = np.roll(p, -2, axis=1) - np.roll(p, -1, axis=1)  # (F, 3, 3): e[c] = p[c+2] - p[c+1]
    l2 = np.einsum("fcx,fcx->fc", e, e)
    # the two edges leaving corner c are p[c+1] - p[c] = -e[c+2] and p[c+2] - p[c] = e[c+1]
    dots = -np.einsum("fcx,fcx->fc", np.roll(e, -2, axis=1), np.roll(e, -1, axis=1))
    dbl_area = np.linalg.norm(np.cross(e[:, 0], e[:, 1]), axis=1)
    return dots, dbl_area, l2


def cotangent_weights(
    vertices: np.ndarray, faces: np.ndarray, *, cot_max: float = COT_MAX
) -> np.ndarray:
    """Cotangent of every corner angle of every triangle.

    Parameters
    ----------
    vertices : (V, 3) float, any length unit
        Finite positions.
    faces : (F, 3) int
        Triangles as vertex indices.
    cot_max : float, default 1e3
        Cotangents are clamped to ``[-cot_max, cot_max]``; a triangle of zero area
        gets ``sign(dot) * cot_max`` at corners between two non-zero edges and 0
        where an edge has zero length.

    Returns
    -------
    (F, 3) float64
        ``cot[f, c]`` is the cotangent of the angle at corner ``c`` of face ``f``;
        dimensionless, never NaN.
    """
    v, f = _check_mesh(vertices, faces)
    if not (cot_max > 0 and np.isfinite(cot_max)):
        raise ValidationError(f"cot_max: expected a positive finite number, got {cot_max!r}")
    dots, dbl_area, _ = _face_geometry(v, f)
    den = np.broadcast_to(dbl_area[:, None], dots.shape)
    cot = np.divide(dots, den, out=np.zeros_like(dots), where=den > 0)
    cot = np.where(den > 0, cot, np.sign(dots) * cot_max)
    return np.clip(cot, -cot_max, cot_max)


def cotangent_laplacian(
    vertices: np.ndarray, faces: np.ndarray, *, cot_max: float = COT_MAX
) -> sp.csr_matrix:
    """The cotangent Laplacian (stiffness matrix) of a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float, any length unit
    faces : (F, 3) int
    cot_max : float, default 1e3
        Bound on each cotangent (see :func:`cotangent_weights`).

    Returns
    -------
    (V, V) scipy.sparse.csr_matrix of float64
        ``L[i, j] = (cot(alpha_ij) + cot(beta_ij)) / 2`` for every edge (one angle on
        a boundary edge), ``L[i, i] = -sum_j L[i, j]``; dimensionless (scale
        invariant). Symmetric, rows sum to zero, negative semi-definite when no
        cotangent is negative. Vertices in no face have an empty row. Equal to
        libigl's ``cotmatrix`` on non-degenerate meshes.

    Examples
    --------
    >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> cotangent_laplacian(v, np.array([[0, 1, 2]])).toarray()[0]
    array([-1. ,  0.5,  0.5])
    """
    v, f = _check_mesh(vertices, faces)
    cot = cotangent_weights(v, f, cot_max=cot_max)
    n = v.shape[0]
    # corner c's cotangent weighs the opposite edge (c+1, c+2)
    i = np.roll(f, -1, axis=1).ravel()
    j = np.roll(f, -2, axis=1).ravel()
    w = 0.5 * cot.ravel()
    # assemble the upper triangle once and mirror it: exactly symmetric whatever the
    # summation order of duplicate entries; an edge from a vertex to itself is dropped
    keep = i != j
    lo = np.minimum(i, j)[keep]
    hi = np.maximum(i, j)[keep]
    upper = sp.coo_matrix((w[keep], (lo, hi)), shape=(n, n)).tocsr()
    upper.sum_duplicates()
    off = (upper + upper.T).tocsr()
    diag = -np.asarray(off.sum(axis=1)).ravel()
    return (off + sp.diags(diag, format="csr")).tocsr()


def vertex_areas(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    kind: Literal["voronoi", "barycentric"] = "voronoi",
) -> np.ndarray:
    """Area each vertex stands for: the diagonal of :func:`mass_matrix`.

    Parameters
    ----------
    vertices : (V, 3) float, length unit u
    faces : (F, 3) int
    kind : {"voronoi", "barycentric"}, default "voronoi"
        ``"voronoi"``: mixed Voronoi areas (Meyer et al. 2003): the Voronoi cell of
        each corner in a non-obtuse triangle; in an obtuse triangle half the area to
        the obtuse corner and a quarter to each other corner. ``"barycentric"``: a
        third of each incident triangle.

    Returns
    -------
    (V,) float64, u^2
        Non-negative; they sum to the surface area. Zero for vertices in no face
        (and for vertices only in zero-area triangles). Never NaN.
    """
    v, f = _check_mesh(vertices, faces)
    if kind not in ("voronoi", "barycentric"):
        raise ValidationError(f"kind: expected 'voronoi' or 'barycentric', got {kind!r}")
    dots, dbl_area, l2 = _face_geometry(v, f)
    area = 0.5 * dbl_area
    if kind == "barycentric":
        corner = np.repeat(area[:, None] / 3.0, 3, axis=1)
    else:
        good = dbl_area > 0
        den = np.broadcast_to(dbl_area[:, None], dots.shape)
        cot = np.divide(dots, den, out=np.zeros_like(dots), where=den > 0)
        # Voronoi part of corner c: (|e_{c,c+1}|^2 cot(c+2) + |e_{c,c+2}|^2 cot(c+1)) / 8;
        # the edge (c, c+1) is opposite corner c+2.
        voronoi = (
            np.roll(l2, -2, axis=1) * np.roll(cot, -2, axis=1)
            + np.roll(l2, -1, axis=1) * np.roll(cot, -1, axis=1)
        ) / 8.0
        obtuse = dots < 0  # (F, 3): the corner's angle is above 90 degrees
        any_obtuse = obtuse.any(axis=1, keepdims=True)
        mixed = np.where(obtuse, 0.5, 0.25) * area[:, None]
        corner = np.where(any_obtuse, mixed, voronoi)
        corner = np.where(good[:, None], corner, 0.0)
    out = np.zeros(v.shape[0])
    np.add.at(out, f.ravel(), corner.ravel())
    return out


def mass_matrix(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    kind: Literal["voronoi", "barycentric"] = "voronoi",
) -> sp.csr_matrix:
    """The lumped (diagonal) mass matrix of a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float, length unit u
    faces : (F, 3) int
    kind : {"voronoi", "barycentric"}, default "voronoi"
        See :func:`vertex_areas`. ``"voronoi"`` equals libigl's
        ``massmatrix(V, F, MASSMATRIX_TYPE_VORONOI)``.

    Returns
    -------
    (V, V) scipy.sparse.csr_matrix of float64, u^2
        Diagonal, non-negative, trace = surface area.
    """
    return sp.diags(vertex_areas(vertices, faces, kind=kind), format="csr")


def connected_components(faces: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of a mesh through its edges.

    Parameters
    ----------
    faces : (F, 3) int
        Triangles.
    n_vertices : int
        V; vertices in no face are components of their own.

    Returns
    -------
    n_components : int
    labels : (V,) int64
        Component of each vertex, numbered from 0 in order of first vertex.
    """
    n = int(n_vertices)
    if n < 0:
        raise ValidationError(f"n_vertices: expected a non-negative integer, got {n_vertices!r}")
    _, f = _check_mesh(np.zeros((n, 3)), faces)
    if n == 0:
        return 0, np.zeros(0, dtype=np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    graph = sp.coo_matrix((np.ones(i.size, dtype=np.int8), (i, j)), shape=(n, n)).tocsr()
    count, labels = _csgraph_components(graph, directed=False)
    # renumber in order of first appearance so the numbering does not depend on scipy
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first)
    remap = np.zeros(count, dtype=np.int64)
    remap[order] = np.arange(count)
    return int(count), remap[labels].astype(np.int64)
