"""Marker and vertex part weights (§5.2) and the automatic near-rigid segmentation."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mesh_grids import grid_triangles
from real_parts import segmented_real_take
from skincap.deform.dense.segmentation import segment_marker_surface, triangle_rotations
from skincap.deform.dense.weights import (
    candidates_from_marker_parts,
    candidates_from_triangle_parts,
    marker_blend_weights,
    marker_part_weights,
    spread_candidates,
    vertex_part_weights,
)
from skincap.errors import ValidationError


def _strip(nx: int = 12, ny: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A flat strip of markers 4 cm apart along x, triangulated."""
    x, y = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    ref = np.stack([0.04 * x.ravel(), 0.04 * y.ravel(), np.zeros(x.size)], axis=1)
    return ref, grid_triangles(nx, ny)


def _hinge(ref: np.ndarray, n_frames: int = 40, hinge_x: float = 0.22) -> np.ndarray:
    """The half of the strip beyond ``hinge_x`` bends up to 80° about the y axis there."""
    angle = np.radians(80.0) * np.sin(np.linspace(0, np.pi, n_frames)) ** 2
    rot = Rotation.from_rotvec(angle[:, None] * [0.0, -1.0, 0.0]).as_matrix()  # (T, 3, 3)
    pivot = np.array([hinge_x, 0.0, 0.0])
    moved = np.einsum("tab,nb->tna", rot, ref - pivot) + pivot
    outer = ref[:, 0] > hinge_x
    return np.where(outer[None, :, None], moved, ref[None])


def test_triangle_rotations_of_a_rigid_motion_are_that_rotation() -> None:
    ref, faces = _strip()
    rot = Rotation.random(3, random_state=0).as_matrix()
    pos = np.einsum("tab,nb->tna", rot, ref) + 1.0
    got = triangle_rotations(pos, ref, faces)
    np.testing.assert_allclose(got, np.repeat(rot[:, None], faces.shape[0], axis=1), atol=1e-12)


def test_a_hinged_strip_splits_at_the_hinge_into_two_connected_parts() -> None:
    ref, faces = _strip()
    pos = _hinge(ref)
    seg = segment_marker_surface(pos, ref, faces, n_parts=2)
    assert seg.n_parts == 2
    outer = ref[:, 0] > 0.22
    inner_part = np.bincount(seg.marker_parts[~outer]).argmax()
    # every marker away from the hinge row is on its side's part
    away = np.abs(ref[:, 0] - 0.22) > 0.05
    assert (seg.marker_parts[away & ~outer] == inner_part).all()
    assert (seg.marker_parts[away & outer] != inner_part).all()


def _arm_with_hand(ref: np.ndarray, n_frames: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """An elbow at x = 0.22 bends 80° about y in the first half of the take, a wrist at
    x = 0.42 turns 50° about z in the second; returns positions and the true segment
    of every marker (0 upper arm, 1 forearm, 2 hand: the strip's last column)."""
    t = np.linspace(0.0, 1.0, n_frames)
    bump = np.sin(2 * np.pi * t) ** 2
    elbow = Rotation.from_rotvec(
        (np.radians(80.0) * np.where(t < 0.5, bump, 0.0))[:, None] * [0, -1.0, 0]
    ).as_matrix()
    wrist = Rotation.from_rotvec(
        (np.radians(50.0) * np.where(t >= 0.5, bump, 0.0))[:, None] * [0, 0, 1.0]
    ).as_matrix()
    p1, p2 = np.array([0.22, 0, 0]), np.array([0.42, 0, 0])
    fore = np.einsum("tab,nb->tna", elbow, ref - p1) + p1
    hand = np.einsum("tab,nb->tna", wrist, ref - p2) + p2
    hand = np.einsum("tab,tnb->tna", elbow, hand - p1) + p1
    segment = np.digitize(ref[:, 0], [0.22, 0.42])
    pos = np.where(
        (segment == 0)[None, :, None],
        ref[None],
        np.where((segment == 1)[None, :, None], fore, hand),
    )
    return pos, segment


@pytest.mark.parametrize("seed", [1, 3, 4])
def test_a_three_marker_hand_is_its_own_part(seed: int) -> None:
    """The hand's few markers are judged by the rigid merge, not absorbed into the
    forearm beforehand by their triangles' rotations (which put one hand marker on
    the forearm for these seeds)."""
    ref, faces = _strip(12, 3)
    pos, segment = _arm_with_hand(ref)
    pos = pos + np.random.default_rng(seed).normal(scale=0.003, size=pos.shape)
    seg = segment_marker_surface(pos, ref, faces, n_parts=3)
    assert seg.n_parts == 3
    assert len(set(zip(segment, seg.marker_parts, strict=True))) == 3  # the true partition


def test_boundary_markers_follow_the_part_they_move_with() -> None:
    ref, faces = _strip()
    pos = _hinge(ref)
    truth = (ref[:, 0] > 0.22).astype(int)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    cand = candidates_from_marker_parts(truth, edges)
    assert (cand.sum(1) == 2).sum() > 0  # the rows either side of the hinge
    alpha = marker_part_weights(pos, ref, cand)
    np.testing.assert_allclose(alpha.sum(1), 1.0)
    # a boundary marker rigidly on the inner side weighs (almost) only for it
    boundary = cand.sum(1) == 2
    np.testing.assert_allclose(alpha[boundary & (truth == 0), 0], 1.0, atol=1e-6)
    np.testing.assert_allclose(alpha[boundary & (truth == 1), 1], 1.0, atol=1e-6)
    inside = cand.sum(1) == 1
    np.testing.assert_array_equal(alpha[inside], cand[inside].astype(float))


def test_a_marker_between_two_motions_is_shared() -> None:
    ref, faces = _strip()
    pos = _hinge(ref)
    truth = (ref[:, 0] > 0.22).astype(int)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    cand = candidates_from_marker_parts(truth, edges)
    mid = np.flatnonzero(cand.sum(1) == 2)[0]
    inner = _hinge(ref, hinge_x=10.0)  # the inner part's (static) motion
    pos = pos.copy()
    pos[:, mid] = 0.5 * (pos[:, mid] + inner[:, mid])  # halfway between the two motions
    alpha = marker_part_weights(pos, ref, cand, noise_floor=0.02)
    assert 0.2 < alpha[mid, 0] < 0.8 and 0.2 < alpha[mid, 1] < 0.8


def test_vertex_weights_interpolate_the_nearest_triangle() -> None:
    ref, faces = _strip()
    alpha = np.zeros((ref.shape[0], 2))
    alpha[:, 0] = ref[:, 0] / ref[:, 0].max()
    alpha[:, 1] = 1.0 - alpha[:, 0]
    vertices = np.array([[0.1, 0.05, 0.003], [0.3, 0.07, -0.002]])
    beta = vertex_part_weights(vertices, ref, faces, alpha)
    np.testing.assert_allclose(beta[:, 0], vertices[:, 0] / ref[:, 0].max(), atol=1e-12)
    np.testing.assert_allclose(beta.sum(1), 1.0)


def test_candidates_from_triangles_and_bad_input() -> None:
    ref, faces = _strip(3, 2)
    cand = candidates_from_triangle_parts(faces, np.arange(faces.shape[0]) % 2, ref.shape[0])
    assert cand.shape == (6, 2) and cand.any(1).all()
    with pytest.raises(ValidationError, match="triangle_parts"):
        candidates_from_triangle_parts(faces, np.zeros(1), ref.shape[0])
    with pytest.raises(ValidationError, match="faces"):
        segment_marker_surface(np.zeros((2, 6, 3)), np.zeros((6, 3)), faces[:1])


def test_principal_coordinates_keep_every_distance() -> None:
    """Mean shift runs on the rows' principal coordinates: pairwise distances unchanged."""
    from scipy.spatial.distance import pdist

    from skincap.deform.dense.segmentation import _principal_coordinates

    rng = np.random.default_rng(1)
    feat = rng.normal(size=(60, 5)) @ rng.normal(size=(5, 900))  # rank 5 in 900 columns
    reduced = _principal_coordinates(feat)
    assert reduced.shape == (60, 5)
    np.testing.assert_allclose(pdist(reduced), pdist(feat), rtol=1e-6, atol=1e-9)


def _two_motions(ref: np.ndarray, n_frames: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """(T, N, 3) positions of the strip under two rigid motions: static and a hinge."""
    return ref[None].repeat(n_frames, axis=0), _hinge(ref, n_frames, hinge_x=-1.0)


def test_blend_weights_recover_the_mix_of_two_rigid_motions() -> None:
    ref, faces = _strip()
    still, hinged = _two_motions(ref)
    side = (ref[:, 0] > 0.22).astype(int)
    members = np.stack([side == 0, side == 1], axis=1)
    # the outer part moves with the hinge; three middle markers mix both motions
    pos = np.where(members[None, :, 1, None], hinged, still)
    mix = {13: 0.3, 20: 0.5, 27: 0.85}  # marker -> weight of the hinge motion
    for i, w in mix.items():
        pos[:, i] = (1.0 - w) * still[:, i] + w * hinged[:, i]
    cand = np.ones_like(members)
    members[list(mix)] = False  # the parts' motions come from their rigid markers
    alpha = marker_blend_weights(pos, ref, members, cand)
    np.testing.assert_allclose(alpha.sum(1), 1.0)
    for i, w in mix.items():
        np.testing.assert_allclose(alpha[i], [1.0 - w, w], atol=1e-6)
    rigid = [i for i in range(ref.shape[0]) if i not in mix]
    np.testing.assert_allclose(alpha[rigid, 1], side[rigid], atol=1e-6)


def test_blend_weights_keep_a_missing_sample_out_and_a_single_candidate_whole() -> None:
    ref, faces = _strip()
    still, hinged = _two_motions(ref)
    side = (ref[:, 0] > 0.22).astype(int)
    members = np.stack([side == 0, side == 1], axis=1)
    pos = np.where(members[None, :, 1, None], hinged, still)
    pos[:, 20] = 0.4 * still[:, 20] + 0.6 * hinged[:, 20]
    pos[5:9, 20] = np.nan
    members[20] = False
    cand = members.copy()
    cand[20] = True
    alpha = marker_blend_weights(pos, ref, members, cand)
    np.testing.assert_allclose(alpha[20], [0.4, 0.6], atol=1e-6)
    single = cand.sum(1) == 1
    np.testing.assert_array_equal(alpha[single], cand[single])
    with pytest.raises(ValidationError, match="fewer than three"):
        marker_blend_weights(pos, ref, np.zeros_like(members), cand)


def test_simplex_least_squares_is_the_constrained_minimum() -> None:
    from scipy.optimize import minimize

    from skincap.geometry.simplex import simplex_least_squares as _simplex_least_squares

    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 4, 3))  # rank 3: some Gram matrices are singular on 4
    gram = a @ np.swapaxes(a, 1, 2)  # (40, 4, 4)
    usable = rng.random((40, 4)) < 0.8
    usable[:, 0] = True
    w = _simplex_least_squares(gram, usable)
    assert (w >= 0).all() and np.allclose(w.sum(1), 1.0) and (w[~usable] == 0).all()
    for g, u, got in zip(gram, usable, w, strict=True):
        idx = np.flatnonzero(u)
        sub = g[np.ix_(idx, idx)]
        ref = minimize(
            lambda v, s=sub: v @ s @ v,
            np.full(idx.size, 1.0 / idx.size),
            bounds=[(0, 1)] * idx.size,
            constraints=[{"type": "eq", "fun": lambda v: v.sum() - 1.0}],
            method="SLSQP",
            options={"ftol": 1e-14},
        )
        assert got[idx] @ sub @ got[idx] <= ref.fun + 1e-7


def test_spread_candidates_add_the_neighbours_parts() -> None:
    ref, faces = _strip(3, 2)  # markers 0..5, two per column
    cand = np.zeros((6, 2), dtype=bool)
    cand[:4, 0] = True
    cand[4:, 1] = True
    spread = spread_candidates(cand, faces)
    assert spread[2:4, 1].all() and not spread[:2, 1].any()  # column 1 touches column 2
    assert spread[4:, 0].all() and (spread | cand == spread).all()


def test_every_part_holds_three_markers_and_is_connected() -> None:
    """Noise makes mean shift split the strip into slivers; the fix-up leaves none: every
    part holds three markers, is one piece of the marker surface, and each triangle
    takes the part of most of its corners."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    from skincap.deform.dense.rigid_groups import surface_edges

    ref, faces = _strip()
    pos = _hinge(ref) + np.random.default_rng(4).normal(scale=0.004, size=(40, ref.shape[0], 3))
    seg = segment_marker_surface(pos, ref, faces, n_parts=6, bandwidth=0.02)
    counts = np.bincount(seg.marker_parts[seg.marker_parts >= 0], minlength=seg.n_parts)
    assert counts.min() >= 3, counts
    edges = surface_edges(faces)
    for part in range(seg.n_parts):
        inside = seg.marker_parts == part
        keep = inside[edges[:, 0]] & inside[edges[:, 1]]
        graph = sparse.coo_matrix(
            (np.ones(keep.sum()), (edges[keep, 0], edges[keep, 1])), shape=(ref.shape[0],) * 2
        )
        n_pieces = connected_components(graph.tocsr()[inside][:, inside], directed=False)[0]
        assert n_pieces == 1, part
    corner = seg.marker_parts[faces]  # (F, 3)
    votes = (corner == seg.triangle_parts[:, None]).sum(axis=1)
    two_agree = (
        (corner[:, 0] == corner[:, 1])
        | (corner[:, 1] == corner[:, 2])
        | (corner[:, 0] == corner[:, 2])
    )
    assert (votes[two_agree] >= 2).all() and (votes >= 1).all()


@pytest.mark.parametrize("capture", ["cmu_85_02.c3d", "c3dorg_sample01_Eb015pr.c3d"])
def test_segmentation_and_blend_weights_invariants_on_a_real_capture(data_dir, capture) -> None:
    """On a real take: parts of >= 3 markers; α on the simplex, a marker with one
    candidate whole, no weight outside a marker's candidates."""
    real = segmented_real_take(data_dir / capture, step=4)
    seg, cand, alpha, faces = real["seg"], real["cand"], real["alpha"], real["faces"]
    on = seg.marker_parts >= 0
    assert np.bincount(seg.marker_parts[on]).min() >= 3
    assert np.isfinite(alpha).all() and (alpha >= 0).all()
    np.testing.assert_allclose(alpha.sum(axis=1), 1.0)
    spread = spread_candidates(cand, faces)  # the parts of its and its neighbours' triangles
    single = spread.sum(axis=1) == 1
    np.testing.assert_array_equal(alpha[single], spread[single])
    assert not (alpha > 0)[~spread & spread.any(axis=1)[:, None]].any()


def test_simplex_least_squares_ignores_the_entries_a_row_cannot_use() -> None:
    # row 0 may use entries 0 and 1; its entry 2 (a part it is no candidate of) is
    # empty, so every subset with it is singular. Row 1 may use all three. No warning
    # escapes, and row 0's answer is the one of its own 2x2 problem.
    from skincap.geometry.simplex import simplex_least_squares as _simplex_least_squares

    gram = np.array(
        [
            [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0]],
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        ]
    )
    usable = np.array([[True, True, False], [True, True, True]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        w = _simplex_least_squares(gram, usable)
    np.testing.assert_allclose(w, [[0.5, 0.5, 0.0], [1 / 3, 1 / 3, 1 / 3]], atol=1e-6)
