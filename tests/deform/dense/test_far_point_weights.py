"""Part weights of points far from a sparse marker surface (issue #16 on sparse captures).

The scene is a sparse capture in small: a trunk of markers on a triangulated grid and
an arm of markers on no triangle (a sparse set's marker surface leaves the limbs out),
the arm swinging about a shoulder. A point by the arm's end is far from every
triangle, and the nearest one is the trunk's.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mesh_grids import grid_triangles
from skincap.deform.dense.deformer import DenseDeformer
from skincap.deform.dense.parts import part_frames
from skincap.deform.dense.weights import (
    seam_vertex_weights,
    surface_interpolation,
    vertex_part_weights,
)
from skincap.geometry.raycast import closest_points_on_mesh

SHOULDER = np.array([0.2, 0.0, 0.0])


def _trunk_and_arm() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference markers (25, 3): a 4 x 4 trunk grid 5 cm apart in z = 0 (triangulated)
    and nine arm markers, three rings of three about the arm's axis (+x from the
    shoulder), on no triangle; α: trunk part 0, arm part 1."""
    x, y = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    trunk = np.stack([0.05 * x.ravel(), 0.05 * y.ravel() - 0.075, np.zeros(x.size)], axis=1)
    ring = np.radians([90.0, 210.0, 330.0])
    arm = np.array(
        [[ax, 0.03 * np.cos(a), 0.03 * np.sin(a)] for ax in (0.3, 0.4, 0.5) for a in ring]
    )
    ref = np.concatenate([trunk, arm])
    alpha = np.zeros((ref.shape[0], 2))
    alpha[:16, 0] = 1.0
    alpha[16:, 1] = 1.0
    return ref, grid_triangles(4, 4), alpha


def _swing(points: np.ndarray, is_arm: np.ndarray, n_frames: int = 30) -> np.ndarray:
    """(T, N, 3): the arm points turn up to 90° about z at the shoulder, the rest stay."""
    angle = np.radians(90.0) * np.sin(np.linspace(0.0, np.pi / 2, n_frames))
    rot = Rotation.from_rotvec(angle[:, None] * [0.0, 0.0, 1.0]).as_matrix()
    moved = np.einsum("tab,nb->tna", rot, points - SHOULDER) + SHOULDER
    return np.where(is_arm[None, :, None], moved, points[None])


def test_a_point_far_from_the_surface_takes_its_nearest_markers_part() -> None:
    ref, faces, alpha = _trunk_and_arm()
    hand = np.array([[0.56, 0.0, 0.0], [0.45, 0.01, -0.01]])  # by the arm, 0.3 m off the trunk
    beta = vertex_part_weights(hand, ref, faces, alpha)
    np.testing.assert_allclose(beta, [[0.0, 1.0], [0.0, 1.0]], atol=1e-12)
    seam = seam_vertex_weights(hand, ref, faces, alpha > 0)
    np.testing.assert_allclose(seam, 0.0)  # the arm markers are at no seam


def test_a_point_within_reach_keeps_the_triangles_weights_exactly() -> None:
    """The dense case: near the surface, β is the paper's barycentric interpolation."""
    rng = np.random.default_rng(4)
    ref, faces, _ = _trunk_and_arm()
    alpha = rng.dirichlet(np.ones(3), size=ref.shape[0])
    points = np.column_stack(
        [rng.uniform(0.0, 0.15, 200), rng.uniform(-0.075, 0.075, 200), rng.normal(0, 0.01, 200)]
    )
    _, face, bary = closest_points_on_mesh(ref[:16], faces, points)
    expected = np.einsum("vk,vkp->vp", bary, alpha[faces[face]])
    got = vertex_part_weights(points, ref, faces, alpha)
    np.testing.assert_allclose(got, expected / expected.sum(1, keepdims=True), atol=1e-14)


def test_weights_fade_continuously_from_the_triangle_to_the_nearest_markers() -> None:
    ref, faces, alpha = _trunk_and_arm()
    steps = {}
    for n in (901, 9001):  # 0.5 mm and 0.05 mm steps, off the arm's axis (its markers tie)
        path = np.column_stack([np.linspace(0.15, 0.6, n), np.full(n, 0.007), np.full(n, 0.004)])
        markers, w = surface_interpolation(path, ref, faces)
        assert markers.shape == (n, 6)
        np.testing.assert_allclose(w.sum(1), 1.0)
        beta = vertex_part_weights(path, ref, faces, alpha)
        assert beta[0, 0] == 1.0 and beta[-1, 1] == 1.0
        steps[n] = np.abs(np.diff(beta, axis=0)).max()
    # continuous: ten times finer steps, about ten times smaller changes (a jump stays)
    assert steps[9001] < 0.2 * steps[901]


def test_a_far_point_follows_its_own_limb_through_the_deformer() -> None:
    ref, faces, alpha = _trunk_and_arm()
    is_arm = alpha[:, 1] > 0
    hand = np.array([[0.56, 0.0, 0.0], [0.52, 0.02, 0.0]])
    markers = _swing(ref, is_arm)
    truth = _swing(hand, np.ones(2, dtype=bool))
    beta = vertex_part_weights(hand, ref, faces, alpha)
    seam = seam_vertex_weights(hand, ref, faces, alpha > 0)
    deformer = DenseDeformer(
        part_frames(ref, alpha, surface_faces=faces), hand, beta, seam_weights=seam
    )
    got = np.concatenate(list(deformer.deform(markers, "rigid_rbf")))
    # the trunk's weights left it where it was: 0.5 m off at 90°
    assert np.linalg.norm(got - truth, axis=-1).max() < 1e-3
