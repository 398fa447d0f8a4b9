"""Cotangent Laplacian, mass matrix and components: analytic cases, libigl, robustness."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from mesh_grids import grid_triangles
from skincap.errors import ValidationError
from skincap.geometry.laplacian import (
    connected_components,
    cotangent_laplacian,
    cotangent_weights,
    mass_matrix,
    vertex_areas,
)

igl = pytest.importorskip("igl")


def _grid(
    n: int = 9, jitter: float = 0.3, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A planar (z = 0) triangulated grid with jittered interior vertices.

    Returns vertices (V, 3), faces (F, 3) and the (V,) interior mask.
    """
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    interior = ((x > 0) & (x < n - 1) & (y > 0) & (y < n - 1)).ravel()
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    v[interior, :2] += rng.uniform(-jitter, jitter, size=(int(interior.sum()), 2))
    return v, grid_triangles(n, n), interior


def _sphere(subdivisions: int = 3, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.ascontiguousarray(s.vertices, dtype=float), np.ascontiguousarray(
        s.faces, dtype=np.int64
    )


# ------------------------------------------------------------------ analytic cases
def test_single_right_triangle() -> None:
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    cot = cotangent_weights(v, f)
    np.testing.assert_allclose(cot, [[0.0, 1.0, 1.0]], atol=1e-15)
    lap = cotangent_laplacian(v, f).toarray()
    np.testing.assert_allclose(lap, [[-1, 0.5, 0.5], [0.5, -0.5, 0], [0.5, 0, -0.5]], atol=1e-15)
    # right angle at vertex 0: Voronoi areas 1/4, 1/8, 1/8 of the half-unit triangle
    np.testing.assert_allclose(vertex_areas(v, f), [0.25, 0.125, 0.125], atol=1e-15)
    np.testing.assert_allclose(vertex_areas(v, f, kind="barycentric"), [1 / 6] * 3, atol=1e-15)


def test_obtuse_triangle_mixed_areas() -> None:
    v = np.array([[0.0, 0, 0], [2, 0, 0], [1, 0.2, 0]])  # obtuse at vertex 2
    areas = vertex_areas(v, np.array([[0, 1, 2]]))
    area = 0.5 * 2 * 0.2
    np.testing.assert_allclose(areas, [area / 4, area / 4, area / 2], rtol=1e-14)


def test_linear_functions_are_harmonic_on_a_planar_grid() -> None:
    v, f, interior = _grid()
    lap = cotangent_laplacian(v, f)
    rng = np.random.default_rng(1)
    for _ in range(3):
        a, b, c = rng.normal(size=3)
        u = a * v[:, 0] + b * v[:, 1] + c
        lu = lap @ u
        np.testing.assert_allclose(lu[interior], 0.0, atol=1e-11)
        assert np.abs(lu[~interior]).max() > 1e-3  # the boundary is not harmonic
    # a quadratic is not: its Laplacian integrates to 4 x the interior area
    u = v[:, 0] ** 2 + v[:, 1] ** 2
    m = vertex_areas(v, f)
    pointwise = (lap @ u)[interior] / m[interior]
    np.testing.assert_allclose(pointwise.mean(), 4.0, rtol=0.05)


def test_sphere_area_and_laplacian_of_coordinates() -> None:
    r = 0.7
    v, f = _sphere(4, r)
    m = vertex_areas(v, f)
    exact_mesh_area = trimesh.Trimesh(v, f, process=False).area
    assert m.sum() == pytest.approx(exact_mesh_area, rel=1e-12)
    assert m.sum() == pytest.approx(4 * np.pi * r**2, rel=5e-3)
    # Laplace-Beltrami of the position is the mean curvature normal: -2/r * n = -2 x / r^2
    lap = cotangent_laplacian(v, f)
    hn = (lap @ v) / m[:, None]
    np.testing.assert_allclose(hn, -2.0 * v / r**2, atol=0.05 * 2 / r)


def test_structure_symmetric_rows_sum_to_zero() -> None:
    v, f = _sphere(2)
    lap = cotangent_laplacian(v, f)
    assert abs(lap - lap.T).max() == 0.0
    np.testing.assert_allclose(np.asarray(lap.sum(axis=1)).ravel(), 0.0, atol=1e-12)
    eig = np.linalg.eigvalsh(lap.toarray())
    assert eig.max() < 1e-9  # negative semi-definite
    assert mass_matrix(v, f).format == "csr"


# --------------------------------------------------------------------- libigl
@pytest.mark.parametrize("case", ["sphere", "grid", "makehuman"])
def test_matches_libigl(case: str, data_dir) -> None:
    if case == "sphere":
        v, f = _sphere(3)
        v = v * np.array([1.0, 0.6, 1.3])  # not a round sphere: obtuse triangles appear
    elif case == "grid":
        v, f, _ = _grid(jitter=0.45, seed=3)
        v[:, 2] = np.sin(v[:, 0]) * 0.5
    else:
        from skincap.io.makehuman import read_makehuman

        mesh = read_makehuman(data_dir / "makehuman_base.obj")
        v, f = mesh.vertices, mesh.faces
    v = np.ascontiguousarray(v, dtype=np.float64)
    f = np.ascontiguousarray(f, dtype=np.int64)
    ours = cotangent_laplacian(v, f)
    ref = igl.cotmatrix(v, f)
    assert abs(ours - ref).max() <= 1e-10 * max(1.0, abs(ref).max())
    for kind, igl_kind in [
        ("voronoi", igl.MASSMATRIX_TYPE_VORONOI),
        ("barycentric", igl.MASSMATRIX_TYPE_BARYCENTRIC),
    ]:
        m_ours = mass_matrix(v, f, kind=kind)
        m_ref = igl.massmatrix(v, f, igl_kind)
        assert abs(m_ours - m_ref).max() <= 1e-10 * abs(m_ref).max()
    if case == "sphere":
        assert (cotangent_weights(v, f) < 0).any()  # the obtuse branch was exercised


# ---------------------------------------------------------------- robustness
def test_degenerate_triangles_stay_finite() -> None:
    v = np.array(
        [
            [0.0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [2, 0, 0],  # collinear with 0 and 1: zero-area triangle (0, 1, 3)
            [1, 0, 0],  # duplicate of vertex 1
            [0.5, 1e-12, 0],  # sliver
        ]
    )
    f = np.array([[0, 1, 2], [0, 1, 3], [1, 4, 2], [0, 1, 5]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cot = cotangent_weights(v, f, cot_max=100.0)
        lap = cotangent_laplacian(v, f, cot_max=100.0)
        m = vertex_areas(v, f)
    assert np.isfinite(cot).all() and np.abs(cot).max() <= 100.0
    assert np.isfinite(lap.toarray()).all()
    assert np.isfinite(m).all() and (m >= 0).all()
    # the zero-area triangle adds no area; the sliver adds almost none
    assert m.sum() == pytest.approx(0.5 + 0.5 * 1e-12, rel=1e-9)
    np.testing.assert_allclose(np.asarray(lap.sum(axis=1)).ravel(), 0.0, atol=1e-9)


def test_unreferenced_vertices_have_empty_rows() -> None:
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    lap = cotangent_laplacian(v, np.array([[0, 1, 2]]))
    assert lap.shape == (4, 4)
    assert lap[3].nnz == 0 or np.all(lap[3].toarray() == 0)
    assert vertex_areas(v, np.array([[0, 1, 2]]))[3] == 0.0


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(3, 12),
    n_faces=st.integers(1, 25),
    seed=st.integers(0, 2**31 - 1),
    scale=st.sampled_from([1e-3, 1.0, 1e3]),
)
def test_random_soups_invariants(n: int, n_faces: int, seed: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3)) * scale
    # near-degenerate samples: some vertices pushed onto others or onto a line
    v[rng.random(n) < 0.2] = v[0]
    f = np.array([rng.choice(n, 3, replace=False) for _ in range(n_faces)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lap = cotangent_laplacian(v, f)
        m = vertex_areas(v, f)
    dense = lap.toarray()
    assert np.isfinite(dense).all()
    assert np.array_equal(dense, dense.T)
    np.testing.assert_allclose(dense.sum(axis=1), 0.0, atol=1e-9 * max(1.0, np.abs(dense).max()))
    assert (m >= 0).all()
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    assert m.sum() == pytest.approx(area.sum(), rel=1e-9, abs=1e-300)
    # the Laplacian is scale invariant
    lap2 = cotangent_laplacian(v * 7.0, f).toarray()
    np.testing.assert_allclose(lap2, dense, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(dense).max()))


# ---------------------------------------------------------------- components
def test_connected_components() -> None:
    a, fa = _sphere(1)
    b, fb = _sphere(1)
    v = np.concatenate([a, b + 5.0, [[9.0, 9, 9]]])
    f = np.concatenate([fa, fb + len(a)])
    n, labels = connected_components(f, len(v))
    assert n == 3
    assert (labels[: len(a)] == 0).all() and (labels[len(a) : -1] == 1).all() and labels[-1] == 2
    assert labels.dtype == np.int64
    assert connected_components(np.zeros((0, 3), dtype=int), 0)[0] == 0
    assert connected_components(np.zeros((0, 3), dtype=int), 2)[0] == 2


def test_bad_input() -> None:
    v, f = _sphere(1)
    with pytest.raises(ValidationError, match="vertices"):
        cotangent_laplacian(v[:, :2], f)
    with pytest.raises(ValidationError, match="faces"):
        cotangent_laplacian(v, f[:, :2])
    with pytest.raises(ValidationError, match="faces"):
        cotangent_laplacian(v, f + len(v))
    with pytest.raises(ValidationError, match="faces"):
        cotangent_laplacian(v, f.astype(float))
    bad = v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValidationError, match="finite"):
        mass_matrix(bad, f)
    with pytest.raises(ValidationError, match="kind"):
        mass_matrix(v, f, kind="cotan")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="cot_max"):
        cotangent_weights(v, f, cot_max=0.0)
    with pytest.raises(ValidationError, match="n_vertices"):
        connected_components(f, -1)
