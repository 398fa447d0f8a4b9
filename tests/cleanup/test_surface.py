"""Automatic marker surface: edge precision/recall on a synthetic take, rigid clusters, user surfaces."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from cleanup_takes import dense_jumprope_take
from scipy.spatial.transform import Rotation

from skincap.cleanup.surface import (
    build_marker_surface,
    choose_reference_frame,
    complete_reference_pose,
    pair_distance_cv,
    surface_edge_scores,
    surface_from_edges,
    surface_from_faces,
)
from skincap.errors import SkincapWarning, ValidationError
from skincap.io import read


def _labelled(take):  # noqa: ANN001, ANN202
    cap = take.capture
    cols = np.flatnonzero([not lab.startswith("*") for lab in cap.labels])
    return cap.positions[:, cols], [cap.labels[c] for c in cols]


def _truth_edges(take, labels: list[str]) -> np.ndarray:  # noqa: ANN001
    """Ground-truth surface edges renumbered to the labelled columns (others dropped)."""
    names = list(take.truth.labels)
    col = {lab: k for k, lab in enumerate(labels)}
    to_col = np.array([col.get(name, -1) for name in names[: take.marker_surface.n_vertices]])
    f = take.marker_surface.faces
    e = to_col[np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])]
    return e[(e >= 0).all(axis=1)]


def test_dense_take_edge_precision_and_recall() -> None:
    take = dense_jumprope_take()
    pos, labels = _labelled(take)
    surface = build_marker_surface(pos, reference_frame=0)
    truth = _truth_edges(take, labels)
    precision, recall = surface_edge_scores(surface.edges, truth)
    face_edges = np.concatenate([surface.faces[:, [0, 1]], surface.faces[:, [1, 2]]])
    face_precision, _ = surface_edge_scores(face_edges, truth)
    # measured on this take: all edges 0.84 / 0.80, face edges precision 0.88
    # (most misses are the other diagonal of a near-square grid cell)
    assert precision >= 0.80
    assert recall >= 0.76
    assert face_precision >= 0.85
    assert surface.degree.min() >= 3
    # edge-manifold: no edge in more than two triangles
    f = surface.faces
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [0, 2]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert counts.max() <= 2
    # the neighbour distances are the dense grid's 4-8 cm
    assert 0.04 < np.median(surface.mean_neighbour_distance) < 0.09


def _two_limbs(frames: int = 60) -> np.ndarray:
    """Two rigid 4x4 grids 3 cm apart at the start; the second one turns and slides
    against the first (two limbs), so distances across the seam change."""
    g = np.stack(np.meshgrid(np.arange(4), np.arange(4), indexing="ij"), -1).reshape(-1, 2)
    sheet = np.column_stack([g * 0.05, np.zeros(16)])  # (16, 3) in the x-y plane
    b = sheet + [0.18, 0.0, 0.0]
    phase = np.linspace(0, 2 * np.pi, frames)
    rot = Rotation.from_rotvec(np.outer(0.8 * np.sin(phase), [1, 0, 0])).as_matrix()
    centre = b.mean(axis=0)
    slide = np.outer(np.sin(phase), [0.0, 0.0, 0.12])
    moved = np.einsum("tij,kj->tki", rot, b - centre) + centre + slide[:, None, :]
    pos = np.concatenate([np.broadcast_to(sheet, (frames, 16, 3)), moved], axis=1)
    return pos + np.random.default_rng(0).normal(scale=2e-4, size=pos.shape)


def test_pairs_across_a_moving_joint_are_rejected() -> None:
    pos = _two_limbs()
    surface = build_marker_surface(pos, reference_frame=0, k=8)
    across = (surface.edges[:, 0] < 16) != (surface.edges[:, 1] < 16)
    assert not across.any()
    assert surface.degree.min() >= 3
    # and with the joint frozen the limbs connect across the 3 cm seam
    still = np.broadcast_to(pos[:1], pos.shape)
    s2 = build_marker_surface(still, reference_frame=0, k=8)
    assert ((s2.edges[:, 0] < 16) != (s2.edges[:, 1] < 16)).any()


def test_pair_distance_cv() -> None:
    pos = _two_limbs()
    cv, overlap = pair_distance_cv(pos, np.array([[0, 1], [12, 16]]))
    assert cv[0] < 0.01 and cv[1] > 0.1
    assert list(overlap) == [60, 60]
    pos2 = pos.copy()
    pos2[:, 1] = np.nan
    cv, overlap = pair_distance_cv(pos2, np.array([[0, 1]]))
    assert np.isnan(cv[0]) and overlap[0] == 0


def test_sparse_real_capture_gets_three_motion_consistent_neighbours(data_dir) -> None:  # noqa: ANN001
    markers = _read_quietly(data_dir / "cmu_85_02.c3d")
    surface = build_marker_surface(markers.positions)
    assert surface.n_markers == markers.n_markers
    assert surface.degree.min() >= 3
    cv, _ = pair_distance_cv(markers.positions, surface.edges)
    # most neighbourhood pairs keep their distance (same segment)
    assert np.median(cv) < 0.1


def _read_quietly(path):  # noqa: ANN001, ANN202
    """Read a capture, ignoring unit guesses (SkincapWarning)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        return read(path)


def test_reference_frame_choice_and_missing_markers() -> None:
    pos = _two_limbs(20)
    pos[0, :5] = np.nan
    assert choose_reference_frame(pos) == 1
    pos[:, 7] = np.nan  # a marker never seen: no neighbours, NaN mean distance
    surface = build_marker_surface(pos)
    assert surface.reference_frame == 1
    assert surface.degree[7] == 0 and np.isnan(surface.mean_neighbour_distance[7])
    assert not np.isin(7, surface.indices)


def test_user_surfaces_and_csr() -> None:
    ref = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [5, 5, 5]], dtype=float)
    s = surface_from_faces(np.array([[0, 1, 2], [1, 3, 2]]), ref)
    assert s.edges.tolist() == [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]
    assert s.neighbours_of(1).tolist() == [0, 3, 2]  # nearest first, ties by index
    assert s.degree.tolist() == [2, 3, 3, 2, 0]
    assert s.mean_neighbour_distance[0] == pytest.approx(1.0)
    assert s.mean_neighbour_distance[1] == pytest.approx((2 + np.sqrt(2)) / 3)
    table, valid = s.padded()
    assert table.shape == (5, 3) and valid.sum() == 10
    offsets, indices = s.neighbours
    assert offsets.tolist() == [0, 2, 5, 8, 10, 10] and indices.size == 10
    e = surface_from_edges(np.array([[1, 0], [0, 1], [2, 2], [3, 4]]), ref)
    assert e.edges.tolist() == [[0, 1], [3, 4]] and e.faces.shape == (0, 3)
    with pytest.raises(ValidationError, match="outside"):
        surface_from_faces(np.array([[0, 1, 9]]), ref)
    with pytest.raises(ValidationError, match="integers"):
        surface_from_edges(np.array([[0.0, 1.0]]), ref)
    with pytest.raises(ValidationError, match=r"\(F, 3\)"):
        surface_from_faces(np.array([0, 1, 2]), ref)


def test_bad_inputs() -> None:
    with pytest.raises(ValidationError, match="positions"):
        build_marker_surface(np.zeros((3, 4)))
    with pytest.raises(ValidationError, match="inf"):
        build_marker_surface(np.full((2, 4, 3), np.inf))
    with pytest.raises(ValidationError, match="reference_frame"):
        build_marker_surface(np.zeros((2, 4, 3)), reference_frame=5)
    assert surface_edge_scores(np.zeros((0, 2), int), np.array([[0, 1]])) == (
        pytest.approx(np.nan, nan_ok=True),
        0.0,
    )


def test_complete_reference_pose_places_hidden_markers() -> None:
    rng = np.random.default_rng(4)
    rest = rng.normal(0.0, 0.1, (12, 3))
    frames = 50
    rot = Rotation.from_rotvec(np.outer(np.linspace(0, 1.2, frames), [0.3, 1, 0])).as_matrix()
    truth = (
        np.einsum("tij,kj->tki", rot, rest)
        + np.outer(np.linspace(0, 1, frames), [1, 0, 0])[:, None]
    )
    pos = truth.copy()
    pos[:20, 3] = np.nan  # hidden in the reference frame 5, seen from frame 20 on
    pos[:, 7] = np.nan  # never seen
    ref = complete_reference_pose(pos, 5)
    np.testing.assert_allclose(ref[3], truth[5, 3], atol=1e-9)
    assert np.isnan(ref[7]).all()
    np.testing.assert_array_equal(np.delete(ref, [3, 7], 0), np.delete(truth[5], [3, 7], 0))
    with pytest.raises(ValidationError, match="reference_frame"):
        complete_reference_pose(pos, 50)
