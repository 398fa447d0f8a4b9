"""Local reference frames (eq. 1) and greedy neighbour estimates of missing markers (eq. 2)."""

from __future__ import annotations

import numpy as np
import pytest
from cleanup_takes import dense_jumprope_take
from scipy.spatial.transform import Rotation

from skincap.cleanup.local_frames import (
    estimate_missing,
    local_reference_coordinates,
    local_reference_frames,
    neighbour_table,
)
from skincap.cleanup.surface import build_marker_surface, surface_from_edges
from skincap.errors import ValidationError


def _rigid_sheet(frames: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A curved 5x5 sheet moving rigidly: (T, 25, 3) positions and its rest pose."""
    g = np.stack(np.meshgrid(np.arange(5), np.arange(5), indexing="ij"), -1).reshape(-1, 2)
    xy = g * 0.05
    rest = np.column_stack([xy, 0.3 * ((xy - 0.1) ** 2).sum(axis=1)])
    rot = Rotation.from_rotvec(np.outer(np.linspace(0, 2, frames), [0.3, 1.0, 0.2])).as_matrix()
    shift = np.outer(np.linspace(0, 1, frames), [0.5, 0.1, -0.2])
    return np.einsum("tij,kj->tki", rot, rest) + shift[:, None, :], rest


def test_rigid_motion_is_recovered_exactly_including_chains() -> None:
    pos, rest = _rigid_sheet()
    surface = build_marker_surface(pos, reference_frame=0)
    holed = pos.copy()
    rng = np.random.default_rng(1)
    holes = rng.random(pos.shape[:2]) < 0.3
    block = [6, 7, 8, 11, 12, 13, 16, 17, 18]  # the middle 3x3: 12 needs estimated ones
    holes[5] = False
    holes[5, block] = True
    holed[holes] = np.nan
    est, mask = estimate_missing(holed, surface, surface.reference)
    assert np.array_equal(mask, holes & mask)  # only missing samples are estimated
    assert mask[5, block].all()
    assert np.allclose(est[mask], pos[mask], atol=1e-9)
    assert np.array_equal(est[~holes], pos[~holes])
    # without a reference: each marker's own best frame; the temporal variant too
    for kwargs in ({"reference": None}, {"reference": surface.reference, "temporal": True}):
        est2, mask2 = estimate_missing(holed, surface, **kwargs)
        assert np.allclose(est2[mask2], pos[mask2], atol=1e-9)
        assert mask2.sum() >= 0.95 * holes.sum()


def test_greedy_order_uses_the_best_supported_marker_first() -> None:
    # marker 0 has neighbours 1, 2, 3 (measured); marker 4 has neighbours 0, 1, 2
    ref = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], dtype=float)
    edges = np.array([[0, 1], [0, 2], [0, 3], [4, 0], [4, 1], [4, 2]])
    surface = surface_from_edges(edges, ref)
    pos = np.broadcast_to(ref + [2.0, 0.0, 0.0], (3, 5, 3)).copy()
    pos[:, [0, 4]] = np.nan
    est, mask = estimate_missing(pos, surface, ref)
    assert mask[:, [0, 4]].all()  # 4 only became possible once 0 was estimated
    assert np.allclose(est, ref + [2.0, 0.0, 0.0])
    # at least three neighbours are needed
    pos[:, 3] = np.nan
    est, mask = estimate_missing(pos, surface, ref)
    assert not mask[:, [0, 3, 4]].any() and np.isnan(est[:, [0, 3, 4]]).all()


def test_local_frames_are_orthonormal_and_follow_eq1() -> None:
    _, rest = _rigid_sheet(2)
    surface = build_marker_surface(np.stack([rest, rest]), reference_frame=0)
    rot = local_reference_frames(surface.reference, surface)
    assert np.allclose(np.einsum("nij,nkj->nik", rot, rot), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(rot), 1.0)
    local = local_reference_coordinates(surface.reference, surface)
    table, valid = neighbour_table(surface, surface.n_markers)
    # the first neighbour lies on the +t axis (b = 0 up to the normal component)
    assert np.allclose(local[:, 0, 1], 0.0, atol=1e-12) and (local[:, 0, 0] > 0).all()
    # distances are preserved; normals are nearly perpendicular to the sheet's edges
    dist = np.linalg.norm(surface.reference[table] - surface.reference[:, None], axis=2)
    assert np.allclose(np.linalg.norm(local, axis=2)[valid], dist[valid])
    assert np.isnan(local[~valid]).all()
    assert np.abs(local[..., 2][valid]).max() < 0.5 * dist[valid].max()


def test_dense_take_estimates_and_the_temporal_option() -> None:
    take = dense_jumprope_take()
    truth = take.truth.positions[:, : take.marker_surface.n_vertices]
    rng = np.random.default_rng(0)
    noisy = truth + rng.normal(scale=5e-4, size=truth.shape)
    surface = build_marker_surface(noisy, reference_frame=0)
    holes = rng.random(truth.shape[:2]) < 0.1
    holed = noisy.copy()
    holed[holes] = np.nan
    norm = surface.mean_neighbour_distance[None, :]
    errs = {}
    for temporal in (False, True):
        est, mask = estimate_missing(holed, surface, surface.reference, temporal=temporal)
        assert mask.sum() >= 0.99 * holes.sum()
        errs[temporal] = (np.linalg.norm(est - truth, axis=2) / norm)[mask].mean()
    # measured: 0.040 (reference pose, like the paper) and 0.012 (bracketing frames)
    assert errs[False] < 0.06
    assert errs[True] < 0.02
    assert errs[True] < 0.5 * errs[False]


def test_bad_arguments() -> None:
    pos, _ = _rigid_sheet(3)
    surface = build_marker_surface(pos, reference_frame=0)
    with pytest.raises(ValidationError, match="min_neighbours"):
        estimate_missing(pos, surface, min_neighbours=2)
    with pytest.raises(ValidationError, match="positions"):
        estimate_missing(pos[0], surface)
    with pytest.raises(ValidationError, match="reference"):
        estimate_missing(pos, surface, np.zeros((3, 3)))
    with pytest.raises(ValidationError, match="offsets"):
        estimate_missing(pos, (np.zeros(3, int), np.zeros(0, int)))
    with pytest.raises(ValidationError, match="MarkerSurface"):
        estimate_missing(pos, 5)  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="inf"):
        estimate_missing(np.full_like(pos, np.inf), surface)
