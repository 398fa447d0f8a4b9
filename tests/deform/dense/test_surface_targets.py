"""Targets on the smoothed marker surface (registration's reverse data term)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from skincap.deform.dense.surface_targets import (
    _closest_on_surface_near,
    marker_surface_normals,
    marker_surface_targets,
)
from skincap.geometry.raycast import closest_points_on_mesh


def _sphere_points(n: int, radius: float, seed: int = 0) -> np.ndarray:
    """n points spread evenly over a sphere (Fibonacci lattice, then a random turn)."""
    k = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * k / n)
    azimuth = np.pi * (1 + 5**0.5) * k
    p = np.stack(
        [np.sin(polar) * np.cos(azimuth), np.cos(polar), np.sin(polar) * np.sin(azimuth)], 1
    )
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return radius * p @ q.T


def _hull_faces(points: np.ndarray) -> np.ndarray:
    return ConvexHull(points).simplices.astype(np.int64)  # unoriented on purpose


R = 0.1  # sphere radius, metres


@pytest.fixture(scope="module")
def sphere_markers() -> tuple[np.ndarray, np.ndarray]:
    markers = _sphere_points(60, R, seed=1)  # ~4.5 cm apart, like the dense limbs
    return markers, _hull_faces(markers)


def test_normals_point_outward_whatever_the_triangle_order(sphere_markers) -> None:
    markers, faces = sphere_markers
    faces = faces.copy()
    faces[::2] = faces[::2, ::-1]  # half the triangles flipped
    ref = _sphere_points(500, R, seed=2)
    normals = marker_surface_normals(markers, faces, ref, ref / R)
    cosine = np.einsum("mx,mx->m", normals, markers / R)
    assert cosine.min() > 0.95


def test_phong_targets_lie_on_the_sphere_where_flat_triangles_cut_under_it(sphere_markers) -> None:
    markers, faces = sphere_markers
    query = _sphere_points(2000, R, seed=3)
    targets, valid = marker_surface_targets(
        query, query / R, markers, faces, marker_radius=0.0, max_distance=0.03
    )
    assert valid.all()  # closed surface, agreeing normals, all near
    flat, _, _ = closest_points_on_mesh(markers, faces, query)
    phong_miss = np.abs(np.linalg.norm(targets, axis=1) - R)
    # the flat triangles miss the sphere by the sagitta (mm); the smoothed surface by far less
    assert flat.mean() > 2e-3
    assert phong_miss.mean() < 0.2 * flat.mean()
    assert phong_miss.max() < 0.35 * flat.max()


def test_marker_radius_moves_the_target_inward(sphere_markers) -> None:
    markers, faces = sphere_markers
    query = _sphere_points(500, R, seed=4)
    kwargs = {"max_distance": 0.03}
    t0, _ = marker_surface_targets(query, query / R, markers, faces, marker_radius=0.0, **kwargs)
    t5, _ = marker_surface_targets(query, query / R, markers, faces, marker_radius=0.005, **kwargs)
    depth = np.linalg.norm(t0, axis=1) - np.linalg.norm(t5, axis=1)
    np.testing.assert_allclose(depth, 0.005, atol=2e-4)


def test_no_target_beyond_the_border_far_away_or_facing_the_other_way(sphere_markers) -> None:
    markers, faces = sphere_markers
    # keep the upper cap only: an open surface with a border
    upper = markers[:, 1] > 0.0
    cap = faces[upper[faces].all(axis=1)]
    query = _sphere_points(800, R, seed=5)
    normals = query / R
    _, valid = marker_surface_targets(
        query, normals, markers, cap, marker_radius=0.0, max_distance=0.03
    )
    assert valid[query[:, 1] > 0.06].all()
    assert not valid[query[:, 1] < -0.03].any()  # their closest point is on the border
    # a point facing away from the surface there (every tenth) gets nothing
    flipped = np.zeros(len(query), dtype=bool)
    flipped[::10] = True
    _, facing = marker_surface_targets(
        query, np.where(flipped[:, None], -normals, normals), markers, cap,
        marker_radius=0.0, max_distance=0.03,
    )  # fmt: skip
    assert not facing[flipped].any()
    np.testing.assert_array_equal(facing[~flipped], valid[~flipped])
    _, far = marker_surface_targets(
        1.5 * query, normals, markers, cap, marker_radius=0.0, max_distance=0.03
    )
    assert not far.any()


def test_unseen_markers_drop_their_triangles(sphere_markers) -> None:
    markers, faces = sphere_markers
    markers = markers.copy()
    markers[7] = np.nan
    query = _sphere_points(400, R, seed=6)
    targets, valid = marker_surface_targets(
        query, query / R, markers, faces, marker_radius=0.0, max_distance=0.03
    )
    assert np.isfinite(targets).all()
    near_hole = np.linalg.norm(query - _sphere_points(60, R, seed=1)[7], axis=1) < 0.01
    assert near_hole.any() and not valid[near_hole].any()  # now on the hole's border
    assert valid.mean() > 0.8


def test_local_closest_points_match_the_exact_search(sphere_markers) -> None:
    markers, faces = sphere_markers
    query = _sphere_points(3000, 1.1 * R, seed=7)
    exact, _, _ = closest_points_on_mesh(markers, faces, query)
    local, face, bary = _closest_on_surface_near(markers, faces, query)
    np.testing.assert_allclose(local, exact, atol=1e-12)
    point = np.einsum("kc,kcx->kx", bary, markers[faces[face]])
    np.testing.assert_allclose(np.linalg.norm(point - query, axis=1), local, atol=1e-12)
