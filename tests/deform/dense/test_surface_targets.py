"""Targets on the smoothed marker surface (registration's reverse data term)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

import skincap.deform.dense.surface_targets as surface_targets
from skincap.deform.dense.surface_targets import (
    _closest_on_surface_near,
    lift_normals,
    marker_surface_normals,
    marker_surface_targets,
    phong_shape,
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


def _cylinder(
    radius: float, around: int, rings: int, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Markers in staggered rings on an open cylinder along Y (a limb), and its triangles."""
    angle = 2 * np.pi * np.arange(around) / around
    points = np.concatenate(
        [
            np.stack(
                [
                    radius * np.cos(angle + (i % 2) * np.pi / around),
                    np.full(around, i * spacing),
                    radius * np.sin(angle + (i % 2) * np.pi / around),
                ],
                axis=1,
            )
            for i in range(rings)
        ]
    )
    i, k = np.meshgrid(np.arange(rings - 1), np.arange(around), indexing="ij")
    i, k = i.ravel(), k.ravel()
    a, b = i * around + k, i * around + (k + 1) % around
    c = (i + 1) * around + (k + i % 2) % around
    d = (i + 1) * around + (k + 1 + i % 2) % around
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)])


def test_exact_on_a_sphere_and_a_cylinder_where_a_fixed_shape_factor_is_not(
    sphere_markers, monkeypatch
) -> None:
    """The per-point shape factor with Max's normals puts the target on the sphere and
    on a limb-like cylinder (markers 4-5 cm apart) to rounding; a fixed α = 1/2 leaves
    it under the surface by a fraction of a millimetre, α = 3/4 over it by a millimetre."""
    markers, faces = sphere_markers
    query = _sphere_points(2000, R, seed=3)
    r = 0.04
    cyl, cyl_faces = _cylinder(r, 6, 9, 0.045)
    rng = np.random.default_rng(8)
    turn, height = rng.uniform(0, 2 * np.pi, 2000), rng.uniform(0.09, 0.27, 2000)
    on_cyl = np.stack([r * np.cos(turn), height, r * np.sin(turn)], axis=1)
    cyl_normals = np.stack([np.cos(turn), np.zeros_like(turn), np.sin(turn)], axis=1)

    def misses() -> tuple[np.ndarray, np.ndarray]:
        t, ok = marker_surface_targets(
            query, query / R, markers, faces, marker_radius=0.0, max_distance=0.03
        )
        tc, okc = marker_surface_targets(
            on_cyl, cyl_normals, cyl, cyl_faces, marker_radius=0.0, max_distance=0.03
        )
        assert ok.all() and okc.all()
        return np.linalg.norm(t, axis=1) - R, np.linalg.norm(tc[:, [0, 2]], axis=1) - r

    sphere_miss, cyl_miss = misses()
    assert np.abs(sphere_miss).max() < 1e-9 and np.abs(cyl_miss).max() < 1e-9
    monkeypatch.setattr(surface_targets, "PHONG_SHAPE", 0.5)
    sphere_miss, cyl_miss = misses()
    assert sphere_miss.min() < -2e-4 and cyl_miss.min() < -5e-4 and cyl_miss.max() <= 1e-9
    monkeypatch.setattr(surface_targets, "PHONG_SHAPE", 0.75)
    _, cyl_miss = misses()
    assert cyl_miss.max() > 5e-4


def test_phong_shape_is_one_half_in_the_flat_limit_and_bounded() -> None:
    rng = np.random.default_rng(9)
    bary = rng.dirichlet(np.ones(3), 500)
    # corner normals tilted by a small angle around +Z: the flat limit
    tilt = 1e-4 * rng.normal(size=(500, 3, 3))
    normals = np.array([0.0, 0.0, 1.0]) + tilt
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    np.testing.assert_allclose(phong_shape(bary, normals), 0.5, atol=1e-3)
    flat = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (500, 3, 3))
    np.testing.assert_array_equal(phong_shape(bary, flat), 0.5)
    wild = rng.normal(size=(500, 3, 3))
    wild /= np.linalg.norm(wild, axis=2, keepdims=True)
    alpha = phong_shape(bary, wild)
    assert np.isfinite(alpha).all() and (alpha >= 0.5).all() and (alpha <= 1.0).all()


def test_marker_normals_are_exact_on_a_sphere_however_uneven_the_star() -> None:
    """Max's weights: a marker whose neighbours lie on a sphere gets the sphere's normal
    exactly, where area weights tilt it toward the bigger triangles."""
    rng = np.random.default_rng(10)
    turn = np.sort(rng.uniform(0, 2 * np.pi, 7))
    polar = rng.uniform(0.15, 0.7, 7)
    ring = np.stack([np.sin(polar) * np.cos(turn), np.cos(polar), np.sin(polar) * np.sin(turn)], 1)
    points = R * np.concatenate([[[0.0, 1.0, 0.0]], ring])
    faces = np.stack([np.zeros(7, int), 1 + np.arange(7), 1 + (np.arange(7) + 1) % 7], axis=1)
    normals = marker_surface_normals(points, faces, points, points / R)
    np.testing.assert_allclose(normals[0], [0.0, 1.0, 0.0], atol=1e-12)


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


def _ellipsoid_gap(points: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(N,) signed distance of points near an ellipsoid to it (first order: F / |∇F|)."""
    value = ((points / axes) ** 2).sum(axis=1) - 1.0
    return value / np.linalg.norm(2.0 * points / axes**2, axis=1)


def test_template_patch_normals_lift_the_surface_onto_an_elongated_body() -> None:
    """An elongated ellipsoid (a foot or a head: 12 x 5 x 4 cm) under 30 uneven markers:
    Max's normals from the few far neighbours tilt, and the Phong lift misses the skin
    by millimetres; the template's normals around each marker (here the true surface,
    as a registered template passing through the markers) put the targets on it."""
    rng = np.random.default_rng(21)
    axes = np.array([0.05, 0.04, 0.12])
    markers = _sphere_points(30, 1.0, seed=4) * axes
    markers += 0.3 * rng.normal(size=markers.shape) * axes  # uneven spacing...
    markers /= np.sqrt(((markers / axes) ** 2).sum(axis=1, keepdims=True))  # ...on the surface
    faces = _hull_faces(markers)
    template = _sphere_points(4000, 1.0, seed=5) * axes
    gradient = template / axes**2
    template_normals = gradient / np.linalg.norm(gradient, axis=1, keepdims=True)
    misses = {}
    for ratio in (0.0, 0.5):
        targets, valid = marker_surface_targets(
            template, template_normals, markers, faces,
            marker_radius=0.0, max_distance=0.03, patch_ratio=ratio,
        )  # fmt: skip
        assert valid.mean() > 0.9
        misses[ratio] = np.abs(_ellipsoid_gap(targets[valid], axes))
    assert misses[0.0].mean() > 1e-3  # Max's normals: a millimetre off on average
    assert misses[0.5].mean() < 0.6 * misses[0.0].mean()
    assert np.percentile(misses[0.5], 95) < 0.6 * np.percentile(misses[0.0], 95)


def test_template_patch_normals_fall_back_where_the_template_is_away() -> None:
    """A marker with no template vertex in its patch keeps Max's normal; the patch of
    the others is the template's normal there (a plane: exactly its normal)."""
    from skincap.deform.dense.surface_targets import template_patch_normals

    markers = np.array([[0.0, 0, 0], [0.04, 0, 0], [0, 0.04, 0], [0.04, 0.04, 0], [1, 1, 0]])
    fallback = np.tile([0.0, 0.6, 0.8], (5, 1))
    grid = np.stack(np.meshgrid(np.linspace(-0.05, 0.09, 30), np.linspace(-0.05, 0.09, 30)), -1)
    plane = np.concatenate([grid.reshape(-1, 2), np.zeros((900, 1))], axis=1)
    normals = template_patch_normals(
        markers, np.arange(5), fallback, plane, np.tile([0.0, 0.0, 1.0], (900, 1)), 0.5
    )
    np.testing.assert_allclose(normals[:4], np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-12)
    np.testing.assert_array_equal(normals[4], fallback[4])


def test_given_marker_normals_replace_the_lift_normals() -> None:
    """``lift_normals`` are the normals the lift uses (given back, nothing changes; a
    zero row keeps its marker's; a marker in no triangle gets none), and the true
    normals at the markers of an elongated ellipsoid put the targets closer to it than
    Max's from the markers do."""
    rng = np.random.default_rng(21)
    axes = np.array([0.05, 0.04, 0.12])
    markers = _sphere_points(30, 1.0, seed=4) * axes
    markers += 0.3 * rng.normal(size=markers.shape) * axes
    markers /= np.sqrt(((markers / axes) ** 2).sum(axis=1, keepdims=True))
    faces = _hull_faces(markers)
    template = _sphere_points(4000, 1.0, seed=5) * axes
    gradient = template / axes**2
    template_normals = gradient / np.linalg.norm(gradient, axis=1, keepdims=True)
    kw = {"marker_radius": 0.0, "max_distance": 0.03}
    for ratio in (0.0, 0.5):
        own = lift_normals(template, template_normals, markers, faces, patch_ratio=ratio)
        plain = marker_surface_targets(
            template, template_normals, markers, faces, patch_ratio=ratio, **kw
        )
        for given in (own, np.zeros_like(own)):
            again = marker_surface_targets(
                template, template_normals, markers, faces, patch_ratio=ratio,
                marker_normals=given, **kw,
            )  # fmt: skip
            np.testing.assert_array_equal(again[0], plain[0])
            np.testing.assert_array_equal(again[1], plain[1])
    exact = markers / axes**2
    exact /= np.linalg.norm(exact, axis=1, keepdims=True)
    misses = {}
    for name, given in (("max", None), ("exact", exact)):
        t, ok = marker_surface_targets(
            template, template_normals, markers, faces, marker_normals=given, **kw
        )
        misses[name] = np.abs(_ellipsoid_gap(t[ok], axes))
    assert misses["max"].mean() > 1e-3
    assert misses["exact"].mean() < 0.5 * misses["max"].mean()
    # a marker in no triangle (unseen, its triangles dropped) gets no normal
    unseen = markers.copy()
    unseen[0] = np.nan
    out = lift_normals(template, template_normals, unseen, faces)
    assert not out[0].any()
    np.testing.assert_allclose(np.linalg.norm(out[1:], axis=1), 1.0)
