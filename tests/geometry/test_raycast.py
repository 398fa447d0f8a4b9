"""Tests of skincap.geometry.raycast against brute force and analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from skincap.deform.skeletal import weights
from skincap.errors import ValidationError
from skincap.geometry import raycast
from skincap.geometry.raycast import (
    closest_points_on_mesh,
    first_ray_hits,
    segments_cross_surface,
    segments_near_capsules,
)
from skincap.geometry.viewpoint_occlusion import occluded_from_viewpoints


def _two_spheres() -> tuple[np.ndarray, np.ndarray]:
    a = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    b = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    v = np.concatenate([a.vertices, b.vertices + [0.5, 0.1, 0.0]])
    f = np.concatenate([a.faces, b.faces + len(a.vertices)]).astype(np.int64)
    return v.astype(float), f


def _brute(v, f, o, t, skip=0.0, min_t=1e-9) -> np.ndarray:
    """(Q,) bool: segment o -> t meets a triangle at a distance > skip from o (and t > min_t)."""
    out = np.zeros(len(o), dtype=bool)
    tri = v[f]
    for k in range(len(o)):
        d = t[k] - o[k]
        length = np.linalg.norm(d)
        o2 = o[k] + d / length * skip
        d2 = t[k] - o2
        p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        pvec = np.cross(d2, e2)
        det = (e1 * pvec).sum(1)
        ok = det != 0
        inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        tv = o2 - p0
        u = (tv * pvec).sum(1) * inv
        q = np.cross(tv, e1)
        w = (d2 * q).sum(1) * inv
        s = (e2 * q).sum(1) * inv
        out[k] = (ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (s > min_t) & (s <= 1)).any()
    return out


def test_moved_from_weights() -> None:
    # bone-heat weights use the same implementation, now in geometry.raycast
    assert weights.segments_cross_surface is raycast.segments_cross_surface


@pytest.mark.parametrize("cull", [False, True])
def test_occluded_from_viewpoints_matches_brute_force(cull) -> None:
    v, f = _two_spheres()
    rng = np.random.default_rng(3)
    # points on or just outside the spheres' surfaces, and some in free space
    s = trimesh.Trimesh(v, f, process=False)
    pts, fi = trimesh.sample.sample_surface(s, 150, seed=4)
    pts = pts + 0.004 * s.face_normals[fi]
    pts = np.concatenate([pts, rng.uniform(-0.6, 0.9, (50, 3))])
    ang = np.linspace(0, 2 * np.pi, 7, endpoint=False)
    cams = np.stack([2.0 * np.cos(ang), 0.5 + 0.3 * np.sin(3 * ang), 2.0 * np.sin(ang)], 1)
    cams = np.concatenate([cams, [[0.0, 0.45, 0.0]]])  # a viewpoint amid the points
    pairs = rng.random((len(pts), len(cams))) < 0.8
    got = occluded_from_viewpoints(
        v, f, pts, cams, pairs=pairs, cull_back_faces=cull, grid=16, max_pairs=500
    )
    n, c = np.nonzero(pairs)
    want = np.zeros_like(pairs)
    want[n, c] = _brute(v, f, pts[n], cams[c])
    if cull:
        # exact for a closed mesh when the points lie outside it
        outside = np.linalg.norm(pts, axis=1) > 0.3 + 1e-3
        outside &= np.linalg.norm(pts - [0.5, 0.1, 0.0], axis=1) > 0.2 + 1e-3
        np.testing.assert_array_equal(got[outside], want[outside])
    else:
        np.testing.assert_array_equal(got, want)
    assert not got[~pairs].any()
    assert 0.1 < got[pairs].mean() < 0.9


def test_start_offset_skips_hits_near_the_point() -> None:
    v, f = _two_spheres()
    # a point just inside the big sphere: its own surface is 5 mm away
    p = np.array([[0.0, 0.0, 0.295]])
    cam = np.array([[0.0, 0.0, 3.0]])
    assert occluded_from_viewpoints(v, f, p, cam)[0, 0]
    assert not occluded_from_viewpoints(v, f, p, cam, start_offset=0.02)[0, 0]
    np.testing.assert_array_equal(
        occluded_from_viewpoints(v, f, p, cam, start_offset=0.02)[:, 0],
        _brute(v, f, p, cam, skip=0.02),
    )


def test_segments_cross_surface_on_long_segments() -> None:
    v, f = _two_spheres()
    o = np.array([[-1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    t = np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.1, 0.0, 0.0]])
    np.testing.assert_array_equal(segments_cross_surface(v, f, o, t), [True, False, False])


def test_first_ray_hits_sphere() -> None:
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(40, 3))
    face, t, bary = first_ray_hits(v, f, np.zeros((40, 3)), d, max_pairs=10_000)
    assert (face >= 0).all()
    hit = np.einsum("nk,nkx->nx", bary, v[f[face]])
    np.testing.assert_allclose(hit, t[:, None] * d, atol=1e-12)
    assert (np.abs(np.linalg.norm(hit, axis=1) - 0.5) < 0.01).all()
    np.testing.assert_allclose(bary.sum(1), 1.0)
    # from outside, pointing away: a miss
    face, t, bary = first_ray_hits(v, f, [[0, 0, 2.0]], [[0, 0, 1.0]])
    assert face[0] == -1 and np.isinf(t[0]) and np.isnan(bary).all()
    # from outside, pointing in: the near side
    face, t, _ = first_ray_hits(v, f, [[0, 0, 2.0]], [[0, 0, -1.0]])
    assert abs(t[0] - 1.5) < 0.01


def test_closest_points_match_dense_sampling() -> None:
    rng = np.random.default_rng(5)
    tri = rng.normal(size=(3, 3))
    v = tri
    f = np.array([[0, 1, 2]])
    # a fine sampling of the triangle
    a, b = np.meshgrid(np.linspace(0, 1, 301), np.linspace(0, 1, 301))
    m = a + b <= 1
    samples = (1 - a[m] - b[m])[:, None] * tri[0] + a[m][:, None] * tri[1] + b[m][:, None] * tri[2]
    q = rng.normal(scale=2.0, size=(60, 3))
    dist, face, bary = closest_points_on_mesh(v, f, q)
    ref = np.min(np.linalg.norm(q[:, None] - samples[None], axis=2), axis=1)
    assert (dist <= ref + 1e-12).all()
    assert np.abs(dist - ref).max() < 0.01
    assert (bary >= -1e-12).all()
    np.testing.assert_allclose(np.linalg.norm(bary @ tri - q, axis=1), dist, atol=1e-12)


def test_closest_points_exact_on_a_mesh_of_fine_and_long_edges(monkeypatch) -> None:
    """A fine sphere beside one long sliver (the MakeHuman case: fine face, coarse body):
    the per-vertex radius groups and the query blocks give the brute-force answer."""
    from skincap.geometry.raycast import _closest_on_triangles

    monkeypatch.setattr(raycast, "_QUERY_BLOCK", 64)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    v = np.concatenate([sphere.vertices, [[0.3, 0.0, 0.0], [-0.3, 0.0, 0.02], [0.0, 0.25, 0.0]]])
    n = sphere.vertices.shape[0]
    f = np.concatenate([sphere.faces, [[n, n + 1, n + 2]]]).astype(np.int64)
    rng = np.random.default_rng(11)
    q = rng.uniform(-0.35, 0.35, size=(300, 3))  # five query blocks
    dist, face, bary = closest_points_on_mesh(v, f, q)
    tri = v[f]  # brute force: every point against every triangle
    bc = _closest_on_triangles(
        np.repeat(q, len(f), axis=0), *(np.tile(tri[:, c], (len(q), 1)) for c in range(3))
    )
    d_all = np.linalg.norm(
        np.einsum("kc,kcx->kx", bc, np.tile(tri, (len(q), 1, 1))) - np.repeat(q, len(f), axis=0),
        axis=1,
    ).reshape(len(q), len(f))
    np.testing.assert_allclose(dist, d_all.min(axis=1), atol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(np.einsum("kc,kcx->kx", bary, tri[face]) - q, axis=1), dist, atol=1e-12
    )


def test_segments_near_capsules_matches_sampling() -> None:
    rng = np.random.default_rng(8)
    s0, s1 = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    a, b = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    a[0] = b[0]  # a degenerate capsule: a sphere
    s1[0] = s0[0]  # a degenerate segment: a point
    r = 0.3
    got = segments_near_capsules(s0, s1, a, b, r, max_pairs=64)
    u = np.linspace(0, 1, 201)
    ps = s0[:, None] + u[None, :, None] * (s1 - s0)[:, None]  # (Q, U, 3)
    pc = a[:, None] + u[None, :, None] * (b - a)[:, None]  # (K, U, 3)
    d = np.stack(
        [
            np.linalg.norm(ps[:, :, None] - pc[k][None, None], axis=-1).min(axis=(1, 2))
            for k in range(5)
        ],
        axis=1,
    )
    dmin = d.min(axis=1)
    sure = np.abs(dmin - r) > 0.03
    np.testing.assert_array_equal(got[sure], (dmin < r)[sure])
    assert got.any() and not got.all()


def test_bad_input() -> None:
    v, f = _two_spheres()
    with pytest.raises(ValidationError):
        occluded_from_viewpoints(v, f, np.zeros((3, 2)), np.ones((1, 3)))
    with pytest.raises(ValidationError):
        occluded_from_viewpoints(
            v, f, np.zeros((3, 3)), np.ones((2, 3)), pairs=np.ones((3, 3), bool)
        )
    with pytest.raises(ValidationError):
        occluded_from_viewpoints(v, f, [[np.nan, 0, 0]], np.ones((1, 3)))
    with pytest.raises(ValidationError):
        first_ray_hits(v, f, np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValidationError):
        closest_points_on_mesh(v, np.zeros((0, 3), np.int64), np.zeros((1, 3)))
    with pytest.raises(ValidationError):
        segments_near_capsules(
            np.zeros((1, 3)), np.zeros((2, 3)), np.zeros((1, 3)), np.ones((1, 3)), 0.1
        )
    assert occluded_from_viewpoints(v, f, np.zeros((0, 3)), np.ones((2, 3))).shape == (0, 2)


# ------------------------------------------------ hostile meshes (issue 13, item 5)
def test_grid_without_triangles_blocks_nothing() -> None:
    v = np.random.default_rng(0).normal(size=(20, 3))
    f = np.zeros((0, 3), dtype=np.int64)
    grid = raycast.TriangleGrid(v, f, None)
    blocked = grid.crossed(v, v + 1.0, np.arange(20), 1000)
    assert blocked.shape == (20,) and not blocked.any()


def test_far_vertex_and_far_segments_match_brute_force() -> None:
    """A vertex 1e12 m out and segments reaching 1e9 m: coarse cells, exact answers, bounded probes."""
    v, f = _two_spheres()
    far = len(v)
    v = np.concatenate([v, [[1e12, -3e11, 2e11]]])
    f = np.concatenate([f, [[0, 1, far]]])  # one sliver triangle reaching the far vertex
    rng = np.random.default_rng(5)
    o = rng.uniform(-0.6, 0.8, size=(300, 3))
    t = rng.uniform(-0.6, 0.8, size=(300, 3))
    t[::3] = o[::3] + rng.normal(size=(100, 3)) * 1e9  # leaves the meshes' neighbourhood
    got = segments_cross_surface(v, f, o, t)
    # segments_cross_surface ignores hits at t <= 1e-6 (1 km along a 1e9 m segment)
    np.testing.assert_array_equal(got, _brute(v, f, o, t, min_t=1e-6))
    assert 0 < got.sum() < len(got)


def test_segment_far_outside_the_mesh_costs_no_probes() -> None:
    v, f = _two_spheres()
    grid = raycast.TriangleGrid(v, f, None)
    o = np.array([[1e6, 1e6, 1e6], [-0.5, 0.0, 0.0]])
    t = np.array([[1e6, -1e6, 1e6], [1e4, 0.0, 0.0]])  # misses the box / crosses, then far
    t0, t1 = grid._clip_to_box(o, t - o)
    assert t0[0] > t1[0]  # never enters the box: not probed at all
    assert 0.0 <= t0[1] < t1[1] < 2e-4  # only the first 2 m of 10 km lie in the box
    np.testing.assert_array_equal(grid.crossed(o, t, np.full(2, -1), 1000), [False, True])


@pytest.mark.parametrize("x", [-4e307, 1e151, np.inf, np.nan])
def test_vertex_beyond_the_coordinate_limit_is_refused(x: float) -> None:
    from skincap.types import Mesh

    v, f = _two_spheres()
    v[7, 0] = x
    with pytest.raises(ValidationError, match="vertex 7"):
        segments_cross_surface(v, f, v[:3], v[3:6])
    if np.isfinite(x):
        with pytest.raises(ValidationError, match="vertex 7 lies at"):
            weights.bone_heat_weight_matrix(
                Mesh(vertices=v, faces=f), np.array([[0.0, -0.2, 0], [0.0, 0.2, 0]]), [-1, 0]
            )


def test_bone_heat_on_a_mesh_without_faces_takes_the_nearest_bone() -> None:
    from skincap.types import Mesh

    y = np.linspace(-0.4, 0.4, 9)
    v = np.stack([np.full(9, 0.05), y, np.zeros(9)], axis=1)
    joints = np.array([[0.0, -0.5, 0.0], [0.0, 0.0, 0.0], [0.0, 0.5, 0.0]])
    w = weights.bone_heat_weight_matrix(
        Mesh(vertices=v, faces=np.zeros((0, 3), dtype=np.int64)), joints, [-1, 0, 1]
    )
    # no surface to diffuse over: each vertex belongs to the joint owning its nearest bone
    # (bone 0 -> 1 owned by joint 0 below y = 0, bone 1 -> 2 owned by joint 1 above)
    np.testing.assert_allclose(w[y < 0], [[1.0, 0.0, 0.0]] * 4, atol=1e-12)
    np.testing.assert_allclose(w[y > 0], [[0.0, 1.0, 0.0]] * 4, atol=1e-12)


def test_closest_points_refuses_queries_beyond_the_coordinate_limit():
    from skincap.geometry.raycast import closest_points_on_mesh

    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    d, _, _ = closest_points_on_mesh(v, f, np.array([[0.0, 0, 2.0], [0, 0, -1e149]]))
    np.testing.assert_allclose(d, [2.0, 1e149])
    for bad in (-1e300, np.inf, np.nan):
        with pytest.raises(ValidationError, match="point 1 lies at"):
            closest_points_on_mesh(v, f, np.array([[0.0, 0, 2.0], [0, 0, bad]]))
