"""Segmentation of a synthetic range-of-motion take against its true parts (issue #16).

The take is what ``skincap synth --motion rom --frames 240 --vertices 5000`` writes
(procedural body, seed 0, soft tissue on): the fast one, each joint through its range
in 0.17 s, where the chest's and upper arms' jiggle is as large as a wrist's turn.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.csgraph import connected_components


def _rom_take(seed: int, soft_tissue: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Marker positions (T, N, 3), surface triangles and true part of every marker."""
    from skincap.deform.skeletal.deformers import skin_motion
    from skincap.synth.inputs import build_body, build_motion
    from skincap.synth.marker_parts import PART_NAMES, true_marker_parts
    from skincap.synth.markers import dense_marker_layout, place_markers
    from skincap.synth.soft_tissue import SoftTissue

    body = build_body("procedural", n_vertices=5000, seed=seed)
    motion = build_motion(body, "rom", frames=240, seconds=None, rate=120.0, units=None, seed=seed)
    seeds = np.random.default_rng(seed).integers(0, 2**31 - 1, size=6)  # as generate_capture
    skin = np.concatenate(
        list(skin_motion(body, motion, method="dqs", backend="numpy").iter_chunks(128))
    )
    if soft_tissue:
        skin += SoftTissue(body, seed=int(seeds[0])).displacements(motion, skin)
    layout = dense_marker_layout(body, seed=int(seeds[1]))
    positions, _ = place_markers(layout, skin, body.faces)
    truth = [PART_NAMES.index(p) for p in true_marker_parts(body, layout.face, layout.bary)]
    return positions, np.asarray(layout.surface_faces), np.array(truth)


@pytest.fixture(scope="module")
def rom_take() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seed 0, soft tissue on (what ``skincap synth`` writes)."""
    return _rom_take(0, soft_tissue=True)


@pytest.mark.slow
def test_a_fast_range_of_motion_segments_into_the_true_parts(rom_take) -> None:
    """ARI >= 0.85 (the issue's target; 0.765 before seam evidence was weighed by how
    far two parts turn apart, 0.865 after), 17 connected parts of >= 3 markers."""
    _assert_segments_into_true_parts(*rom_take)


@pytest.mark.slow
def test_every_true_part_gets_a_part_of_its_own(rom_take) -> None:
    """Seed 0: each of the 17 true parts is the majority of exactly one part. Merging to
    the count, a piece of hip-and-thigh flesh and one of upper chest survived as parts
    while both hands went into their forearms; the last parts are now dissolved marker
    by marker instead of merged whole."""
    from skincap.deform.dense.segmentation import segment_marker_surface

    positions, faces, truth = rom_take
    seg = segment_marker_surface(positions, positions[0], faces)
    majority = [
        int(np.bincount(truth[seg.marker_parts == p], minlength=17).argmax())
        for p in range(seg.n_parts)
    ]
    assert sorted(majority) == list(range(17)), majority


@pytest.mark.slow
def test_a_fast_range_of_motion_with_jiggle_segments_on_another_seed() -> None:
    """Seed 7 with its soft tissue on: the upper arms' and thighs' jiggle turned their
    slivers apart as far as a wrist turns, so the merge by peak turn alone split them
    and put each hand into its forearm (short of 0.85); weighing each pair's peak turn
    by how far it moves apart beyond its markers' jiggle keeps the hands."""
    _assert_segments_into_true_parts(*_rom_take(7, soft_tissue=True))


@pytest.mark.slow
def test_a_seed_whose_mean_shift_leaves_few_pieces_segments_into_the_true_parts() -> None:
    """Seed 8: mean shift at its first bandwidth left 35 marker groups, two a part, and
    some spanned two true parts (upper chest with chest, abdomen with pelvis), so no
    merge could do better than 0.74; it now narrows until three a part (0.735 before,
    0.860 with that alone, 0.855 with the merge's joint discount as well)."""
    _assert_segments_into_true_parts(*_rom_take(8, soft_tissue=True))


@pytest.mark.slow
def test_skin_that_follows_the_bones_segments_into_the_true_parts_on_another_seed() -> None:
    """With the soft tissue off, a seed whose jiggling take falls short (seed 7) still
    segments into the true parts: what the fast range of motion lacks is rigidity of
    the flesh (its jiggle), not something the seed's body or marker layout does."""
    _assert_segments_into_true_parts(*_rom_take(7, soft_tissue=False))


def _assert_segments_into_true_parts(
    positions: np.ndarray, faces: np.ndarray, truth: np.ndarray
) -> None:
    from skincap.deform.dense.rigid_groups import surface_edges
    from skincap.deform.dense.segmentation import segment_marker_surface
    from skincap.evaluate.animate import adjusted_rand_index

    seg = segment_marker_surface(positions, positions[0], faces)
    assert seg.n_parts == 17
    assert (seg.marker_parts >= 0).all()
    assert adjusted_rand_index(truth, seg.marker_parts) >= 0.85
    counts = np.bincount(seg.marker_parts, minlength=seg.n_parts)
    assert counts.min() >= 3, counts
    edges = surface_edges(faces)
    n = positions.shape[1]
    for part in range(seg.n_parts):
        inside = seg.marker_parts == part
        keep = inside[edges[:, 0]] & inside[edges[:, 1]]
        graph = sparse.csr_matrix((np.ones(keep.sum()), (edges[keep, 0], edges[keep, 1])), (n, n))
        assert connected_components(graph[inside][:, inside], directed=False)[0] == 1, part
