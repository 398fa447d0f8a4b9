"""Marker groups by rigid residual: the closed-form residual, merging, seam refinement."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mesh_grids import grid_triangles
from skincap.deform.dense.rigid_groups import (
    connect_parts,
    merge_groups_by_rigid_residual,
    refine_marker_parts,
    rigid_residuals,
    surface_edges,
    triangle_parts_from_markers,
)
from skincap.geometry.rigid import fit_rigid


def _strip(nx: int = 12, ny: int = 4) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    ref = np.stack([0.04 * x.ravel(), 0.04 * y.ravel(), np.zeros(x.size)], axis=1)
    return ref, grid_triangles(nx, ny)


def _three_segments(ref: np.ndarray, n_frames: int = 30) -> np.ndarray:
    """Strip cut at x = 0.14 and 0.30: the middle turns about y, the end turns about z
    on top of it (a hinged limb of three rigid segments)."""
    t = np.sin(np.linspace(0, np.pi, n_frames)) ** 2
    first = Rotation.from_rotvec(np.radians(60.0) * t[:, None] * [0, -1.0, 0]).as_matrix()
    second = Rotation.from_rotvec(np.radians(45.0) * t[:, None] * [0, 0, 1.0]).as_matrix()
    p1, p2 = np.array([0.14, 0, 0]), np.array([0.30, 0, 0])
    mid = np.einsum("tab,nb->tna", first, ref - p1) + p1
    far_local = np.einsum("tab,nb->tna", second, ref - p2) + p2
    far = np.einsum("tab,tnb->tna", first, far_local - p1) + p1
    seg = np.digitize(ref[:, 0], [0.14, 0.30])
    return np.where(
        (seg == 0)[None, :, None], ref[None], np.where((seg == 1)[None, :, None], mid, far)
    )


def test_residual_from_sums_equals_a_direct_rigid_fit() -> None:
    rng = np.random.default_rng(1)
    ref = rng.normal(size=(40, 3))
    rot = Rotation.random(6, random_state=2).as_matrix()
    x = np.einsum("tab,nb->tna", rot, ref) + rng.normal(size=(6, 1, 3))
    x = x + rng.normal(scale=0.01, size=x.shape)
    x[2, 5] = np.nan  # a missing sample counts nowhere
    groups = np.repeat([0, 1, -1, 2], 10)
    got = rigid_residuals(x, ref, groups)
    for g in range(3):
        m = groups == g
        r, t = fit_rigid(ref[m][None], x[:, m])
        sq = ((np.einsum("tab,nb->tna", r, ref[m]) + t[:, None] - x[:, m]) ** 2).sum(-1)
        np.testing.assert_allclose(got[g], np.nansum(sq) / x.shape[0], rtol=1e-6, atol=1e-12)


def test_rigid_groups_have_no_residual() -> None:
    ref, _ = _strip()
    x = _three_segments(ref)
    truth = np.digitize(ref[:, 0], [0.14, 0.30])
    np.testing.assert_allclose(rigid_residuals(x, ref, truth), 0.0, atol=1e-12)
    assert rigid_residuals(x, ref, np.zeros(ref.shape[0], int))[0] > 1e-4


def test_merging_single_markers_finds_the_rigid_segments() -> None:
    ref, faces = _strip()
    x = _three_segments(ref)
    truth = np.digitize(ref[:, 0], [0.14, 0.30])
    got = merge_groups_by_rigid_residual(np.arange(ref.shape[0]), surface_edges(faces), x, ref, 3)
    assert got.max() == 2
    # the same partition up to names (each true segment is one group and vice versa)
    assert len(set(zip(truth.tolist(), got.tolist(), strict=True))) == 3


def test_merging_keeps_a_loose_tiny_group_out() -> None:
    ref, faces = _strip()
    x = _three_segments(ref)
    groups = np.digitize(ref[:, 0], [0.14, 0.30])
    edges = surface_edges(faces)
    edges = edges[~np.isin(edges, [0, 1]).any(axis=1)]  # markers 0 and 1: an island
    groups[[0, 1]] = 3
    got = merge_groups_by_rigid_residual(groups, edges, x, ref, 3)
    assert (got[[0, 1]] == -1).all() and got.max() == 2


def test_refinement_moves_seam_markers_to_the_segment_they_move_with() -> None:
    ref, faces = _strip()
    x = _three_segments(ref)
    truth = np.digitize(ref[:, 0], [0.14, 0.30])
    start = np.digitize(ref[:, 0], [0.10, 0.34])  # seams one column off
    edges = surface_edges(faces)
    parts, err = refine_marker_parts(start, edges, x, ref)
    np.testing.assert_array_equal(parts, truth)
    assert err.shape == (ref.shape[0], 3)
    np.testing.assert_allclose(err[np.arange(ref.shape[0]), parts], 0.0, atol=1e-12)


def test_a_stray_piece_joins_the_part_it_touches_and_follows() -> None:
    ref, faces = _strip(6, 2)  # markers 0..11, column-major: x index = i // 2
    edges = surface_edges(faces)
    parts = np.repeat([0, 0, 1, 1, 0, 2], 2)  # part 0 has a stray piece at column 4
    err = np.zeros((12, 3))
    err[8:10, 1] = 1.0  # the stray piece follows part 2 better than part 1
    got = connect_parts(parts, edges, err)
    np.testing.assert_array_equal(got, np.repeat([0, 0, 1, 1, 2, 2], 2))


def test_triangle_parts_take_the_majority_then_the_best_follower() -> None:
    faces = np.array([[0, 1, 2], [0, 1, 3], [3, 4, 5]])
    parts = np.array([0, 0, 1, 2, -1, -1])
    err = np.zeros((6, 3))
    err[:, 0] = 1.0  # corners 0, 1 follow part 0 badly
    got = triangle_parts_from_markers(faces, parts, err)
    assert got[0] == 0  # two corners of part 0
    assert got[1] == 0  # 0, 0, 2: two of part 0
    faces3 = np.array([[0, 2, 3]])
    assert triangle_parts_from_markers(faces3, parts, err)[0] in (1, 2)  # three parts: not 0
    assert triangle_parts_from_markers(np.array([[4, 5, 4]]), parts, err)[0] == -1


def test_a_take_that_does_not_move_warns_that_it_cannot_be_segmented() -> None:
    import warnings

    from skincap.deform.dense.rig import build_dense_rig
    from skincap.errors import SkincapWarning

    ref, faces = _strip()
    still = np.repeat(ref[None], 10, axis=0)
    with pytest.warns(SkincapWarning, match="1 near-rigid parts found of the 3 asked"):
        rig = build_dense_rig(
            ref, faces, [f"m{i}" for i in range(ref.shape[0])], ref, faces, still, n_parts=3
        )
    assert rig.n_parts == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a moving take with enough parts: quiet
        build_dense_rig(
            ref,
            faces,
            [f"m{i}" for i in range(ref.shape[0])],
            ref,
            faces,
            _three_segments(ref),
            n_parts=3,
        )


def test_more_parts_than_asked_from_a_surface_in_pieces_are_warned_about() -> None:
    """Two strips 1 m apart, each its own piece of the marker surface: --parts 1 gives
    two parts (a part is connected on the surface), and now says why."""
    from skincap.deform.dense.rig import build_dense_rig
    from skincap.errors import SkincapWarning

    ref, faces = _strip()
    two = np.concatenate([ref, ref + [0.0, 1.0, 0.0]])
    two_faces = np.concatenate([faces, faces + ref.shape[0]])
    take = np.concatenate([_three_segments(ref), _three_segments(ref) + [0.0, 1.0, 0.0]], axis=1)
    labels = [f"m{i}" for i in range(two.shape[0])]
    with pytest.warns(
        SkincapWarning, match="2 near-rigid parts of the 1 asked: the marker surface"
    ):
        rig = build_dense_rig(two, two_faces, labels, two, two_faces, take, n_parts=1)
    assert rig.n_parts == 2
    pieces = rig.marker_weights.argmax(axis=1)
    assert len(set(pieces[: ref.shape[0]])) == 1 and len(set(pieces[ref.shape[0] :])) == 1
    assert pieces[0] != pieces[-1]


def test_refinement_never_leaves_a_part_under_three_markers() -> None:
    ref, faces = _strip()
    x = _three_segments(ref)
    start = np.digitize(ref[:, 0], [0.14, 0.30])
    start[ref[:, 0] < 0.01] = 3  # a column of 4 markers as its own part, rigid with part 0
    start[(ref[:, 0] < 0.01) & (ref[:, 1] > 0.05)] = 0  # ... then cut to 2 markers
    parts, err = refine_marker_parts(start, surface_edges(faces), x, ref, min_markers=3)
    counts = np.bincount(parts[parts >= 0])
    assert counts.min() >= 3 and err.shape[1] == parts.max() + 1


def test_seam_markers_are_judged_where_the_parts_turn_apart() -> None:
    """The inner part's flesh wobbles 3 cm while the hinge is still (pulling the inner
    part's rigid fit), then the hinge bends 15°: the still seam markers by the hinge
    are the inner part's. By plain mean errors the outer part's clean fit "follows" the
    two inner columns by the hinge (8 markers) better and they move to it; weighed by
    how far the two parts turn apart, the truth stays."""
    import skincap.deform.dense.rigid_groups as rigid_groups

    ref, faces = _strip()
    t = np.arange(120)
    bend = np.where(t >= 90, np.sin(np.pi * (t - 90) / 30) ** 2, 0.0)  # the last quarter
    rot = Rotation.from_rotvec((np.radians(15.0) * bend)[:, None] * [0, -1.0, 0]).as_matrix()
    pivot = np.array([0.22, 0.0, 0.0])
    outer = ref[:, 0] > 0.22
    x = np.where(
        outer[None, :, None], np.einsum("tab,nb->tna", rot, ref - pivot) + pivot, ref[None]
    )
    flesh = np.clip((0.17 - ref[:, 0]) / 0.06, 0.0, 1.0) * ~outer  # fades before the seam
    wobble = 0.03 * np.sin(2 * np.pi * t / 12) * (t < 90)
    x = x + (flesh[None, :, None] * wobble[:, None, None]) * np.array([0.0, 0.0, 1.0])
    truth = outer.astype(int)
    edges = surface_edges(faces)
    parts, _ = refine_marker_parts(truth, edges, x, ref)
    np.testing.assert_array_equal(parts, truth)
    # the same with every frame weighing alike (a floor far above any turn): markers move
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rigid_groups, "_TURN_FLOOR", 1e6)
        plain, _ = refine_marker_parts(truth, edges, x, ref)
    assert (plain != truth).sum() >= 4


def test_a_brief_hard_turn_outweighs_flesh_that_jiggles_all_take() -> None:
    """A strip whose body (x < 0.36 m) jiggles all take (a 2 cm bump oscillating at
    6 Hz, zero at its ends) and whose tip turns 40 degrees for 0.1 s of the 1.7 s:
    over the take the tip adds less residual to the body than the body's two halves
    add to each other, so the residual merges the tip away; at its peak frame the tip
    turns far more, so the peak-turn cost keeps it and joins the halves."""
    ref, faces = _strip()
    n_frames = 200
    t = np.arange(n_frames) / 120.0
    body = ref[:, 0] < 0.36
    bump = np.where(body, np.sin(np.pi * ref[:, 0] / 0.36) ** 2, 0.0)  # (N,)
    wobble = 0.02 * np.stack([np.sin(2 * np.pi * 6.0 * t), np.cos(2 * np.pi * 6.0 * t)], 1)
    x = np.repeat(ref[None], n_frames, axis=0)
    x[:, :, 1:3] += bump[None, :, None] * wobble[:, None, :]  # across the strip and out of it
    pulse = np.where((t > 0.7) & (t < 0.8), np.sin(np.pi * (t - 0.7) / 0.1) ** 2, 0.0)
    turn = Rotation.from_rotvec(np.radians(40.0) * pulse[:, None] * [0, 0, 1.0]).as_matrix()
    hinge = np.array([0.36, 0.06, 0.0])
    tip = ~body
    x[:, tip] = np.einsum("tab,nb->tna", turn, ref[tip] - hinge) + hinge
    pieces = np.where(tip, 2, (ref[:, 0] >= 0.18).astype(int))
    edges = surface_edges(faces)
    by_residual = merge_groups_by_rigid_residual(pieces, edges, x, ref, 2)
    assert len(np.unique(by_residual[tip])) == 1 and by_residual[tip][0] in by_residual[body]
    got = merge_groups_by_rigid_residual(pieces, edges, x, ref, 2, peak_turn_above=2)
    assert got.max() == 1
    assert len(set(zip(got.tolist(), tip.tolist(), strict=True))) == 2  # tip alone, body whole


def test_a_brief_turn_outweighs_slivers_of_jiggling_flesh_beyond_their_jiggle() -> None:
    """A strip of 16 x 4 markers: a still base (x < 0.32 m, four rigid pieces), a body
    (0.32-0.48 m, cut into two slivers) that bends 45° away from the base over the
    take and jiggles all take (a 2 cm bump out of the strip at 6 Hz), and a tip
    (x >= 0.52 m) that turns 20° on the body for 0.1 s. The jiggle turns the slivers'
    fitted rotations apart further than the tip turns, so both the residual and the
    peak turn join the tip to the nearer sliver; weighed by how far each pair moves
    apart beyond the jiggle of its markers, the slivers join and the tip stays."""
    nx, ny = 16, 4
    ref, faces = _strip(nx, ny)
    col = np.repeat(np.arange(nx), ny)
    t = np.arange(200) / 120.0
    base, body, tip = col < 8, (col >= 8) & (col < 13), col >= 13
    bump = np.where(body, np.sin(np.pi * np.clip((ref[:, 0] - 0.30) / 0.20, 0, 1)) ** 2, 0.0)
    x = np.repeat(ref[None], t.size, axis=0)
    x[:, :, 2] += 0.02 * bump[None, :] * np.sin(2 * np.pi * 6.0 * t)[:, None]
    pulse = np.where((t > 0.7) & (t < 0.8), np.sin(np.pi * (t - 0.7) / 0.1) ** 2, 0.0)
    turn = Rotation.from_rotvec(np.radians(20.0) * pulse[:, None] * [0, 0, 1.0]).as_matrix()
    hinge = np.array([0.50, 0.06, 0.0])
    x[:, tip] = np.einsum("tab,nb->tna", turn, ref[tip] - hinge) + hinge
    bend = np.sin(np.pi * t / t[-1]) ** 2
    slow = Rotation.from_rotvec(np.radians(45.0) * bend[:, None] * [0, -1.0, 0]).as_matrix()
    knee = np.array([0.30, 0.0, 0.0])
    x[:, ~base] = np.einsum("tab,tnb->tna", slow, x[:, ~base] - knee) + knee
    pieces = np.where(base, col // 2, np.where(body, np.where(col < 11, 4, 5), 6))
    truth = np.where(base, 0, np.where(body, 1, 2))
    edges = surface_edges(faces)

    def right(got: np.ndarray) -> bool:
        return got.max() == 2 and len(set(zip(got.tolist(), truth.tolist(), strict=True))) == 3

    assert not right(merge_groups_by_rigid_residual(pieces, edges, x, ref, 3))
    assert not right(merge_groups_by_rigid_residual(pieces, edges, x, ref, 3, peak_turn_above=3))
    got = merge_groups_by_rigid_residual(
        pieces, edges, x, ref, 3, peak_turn_above=3, jiggle_scaled=True
    )
    assert right(got)


def test_a_joint_explains_a_turn_and_no_joint_explains_a_jiggle() -> None:
    """The unjointed share of a pair's relative motion: a tip turning 40° about a hinge
    is all joint (share ~0, whatever the hinge's place); a sliver whose flesh swings
    2 cm on a spring beside a still one (an offset that turns it a few degrees too)
    has no fixed point the two carry alike (about half of it unexplained)."""
    from skincap.deform.dense.rigid_groups import (
        _centred_take,
        _group_sums,
        _marker_sums,
        _unjointed_share,
    )

    ref, _ = _strip()
    t = np.arange(200) / 120.0
    col = np.round(ref[:, 0] / 0.04).astype(int)
    x = np.repeat(ref[None], t.size, axis=0)
    tip = col >= 6
    pulse = np.sin(np.pi * t / t[-1]) ** 2
    turn = Rotation.from_rotvec(np.radians(40.0) * pulse[:, None] * [0, 0, 1.0]).as_matrix()
    hinge = np.array([0.22, 0.05, 0.0])
    x[:, tip] = np.einsum("tab,nb->tna", turn, ref[tip] - hinge) + hinge
    jiggle = np.repeat(ref[None], t.size, axis=0)
    swing = 0.02 * np.stack([np.sin(2 * np.pi * 6.0 * t), np.cos(2 * np.pi * 4.0 * t)], 1)
    flesh = col >= 6
    weight = np.where(flesh, 0.5 + 0.5 * ref[:, 1] / ref[:, 1].max(), 0.0)  # uneven: it turns
    jiggle[:, :, 1:3] += weight[None, :, None] * swing[:, None, :]
    groups = tip.astype(np.int64)
    pairs = np.array([[0, 1]])
    shares = []
    for take in (x, jiggle):
        xc, rc = _centred_take(take, ref)
        sums = _group_sums(_marker_sums(xc, rc), groups, 2)
        shares.append(float(_unjointed_share(sums, pairs)[0]))
    assert shares[0] < 0.01, shares
    assert shares[1] > 0.3, shares
