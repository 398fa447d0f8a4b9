"""Area-weighted vertex normals against shapes whose normals are known."""

import numpy as np

from skincap.geometry.normals import area_weighted_vertex_normals


def test_a_flat_fan_points_up_and_an_unused_vertex_gets_zero():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [5, 5, 5]])
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    n = area_weighted_vertex_normals(v, f)
    np.testing.assert_allclose(n[:5], np.tile([0.0, 0, 1], (5, 1)), atol=1e-15)
    np.testing.assert_array_equal(n[5], 0.0)


def test_a_box_corner_normal_is_the_area_weighted_diagonal():
    # an octahedron: each vertex is shared by four equal faces, its normal points outward
    v = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    n = area_weighted_vertex_normals(v, f)
    np.testing.assert_allclose(n, v, atol=1e-12)


def test_the_larger_triangle_weighs_more():
    # vertex 0 is a corner of a big triangle facing +z and a small one facing -y
    v = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0.1, 0, 0], [0, 0, 0.1]])
    f = np.array([[0, 1, 2], [0, 3, 4]])
    n = area_weighted_vertex_normals(v, f)
    big, small = 4.0, 0.01  # twice the areas
    want = np.array([0.0, -small, big]) / np.hypot(small, big)
    np.testing.assert_allclose(n[0], want, atol=1e-12)
