"""Rope initialisation (Porter 2012 §3.4): box, point indices, automatic."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import rope_truth_indices
from skincap.errors import ValidationError
from skincap.tracking.body_points import body_like, follow_points
from skincap.tracking.init import RopeInit, find_rope_chain, gated_assignment, init_rope
from skincap.types import PointCloud


def _frame0_labels(take) -> np.ndarray:  # type: ignore[no-untyped-def]
    return take.point_truth[: take.points.offsets[1]].astype(str)


def _assert_ordered(labels: list[str]) -> None:
    nums = [int(s.split("_")[1]) for s in labels]
    assert nums == sorted(nums) or nums == sorted(nums, reverse=True)


def test_markers_init_whip(whip_take) -> None:  # type: ignore[no-untyped-def]
    cloud = whip_take.points
    sel = rope_truth_indices(whip_take)
    rng = np.random.default_rng(1)
    init = init_rope(cloud, markers=rng.permutation(sel))  # any order in
    labels = _frame0_labels(whip_take)[init.indices]
    assert init.n_markers == 23 and sorted(init.indices) == sorted(sel)
    _assert_ordered(list(labels))
    assert labels[0] == "rope_00"  # the held end hangs highest
    np.testing.assert_allclose(init.spacing, 0.12, atol=0.01)
    assert init.gamma == pytest.approx(0.03, abs=0.003)
    assert init.labels[0] == "rope_00" and init.window == (0, 60)
    assert init.max_temp_markers == 120


def test_markers_init_inserts_unseen(jump_take) -> None:  # type: ignore[no-untyped-def]
    sel = rope_truth_indices(jump_take)
    init = init_rope(jump_take.points, markers=sel)
    n_missing = 23 - sel.size
    assert init.n_markers == 23
    assert (init.indices == -1).sum() == n_missing == init.meta["inserted"]
    np.testing.assert_allclose(init.spacing, 0.12, atol=0.012)
    # inserted traces sit where the truth has the unseen markers
    truth = jump_take.truth
    rope_cols = [i for i, s in enumerate(truth.labels) if s.startswith("rope_")]
    d = np.linalg.norm(init.positions[:, None] - truth.positions[0, rope_cols][None], axis=2)
    assert d.min(axis=1).max() < 0.01


def test_box_init(whip_take) -> None:  # type: ignore[no-untyped-def]
    cloud = whip_take.points
    p0 = cloud.frame(0)
    sel = rope_truth_indices(whip_take)
    lo = p0[sel].min(axis=0) - 0.01
    hi = p0[sel].max(axis=0) + 0.01
    lo[1] = p0[sel, 1].min() - 0.01
    hi[1] = 1.25  # below the hand: the top marker is left out
    init = init_rope(cloud, box=np.concatenate([hi, lo]))  # corners in any order
    labels = _frame0_labels(whip_take)[init.indices]
    assert all(s.startswith("rope_") for s in labels)
    assert init.n_markers == 22 and init.meta["method"] == "box"
    _assert_ordered(list(labels))


@pytest.mark.slow
@pytest.mark.parametrize("rope", ["whip", "jump"])
def test_auto_finds_exactly_the_rope(rope, whip_take, jump_take) -> None:  # type: ignore[no-untyped-def]
    take = whip_take if rope == "whip" else jump_take
    init = init_rope(take.points, auto=True)
    lab = _frame0_labels(take)
    seen = init.indices[init.indices >= 0]
    # every rope point of frame 0 and nothing else; hidden ones become inserted traces
    assert sorted(seen.tolist()) == sorted(rope_truth_indices(take).tolist())
    assert init.n_markers == 23 and init.meta["method"] == "auto"
    _assert_ordered(list(lab[seen]))
    truth = take.truth
    rope_cols = sorted(i for i, s in enumerate(truth.labels) if s.startswith("rope_"))
    d = np.linalg.norm(init.positions - truth.positions[0, rope_cols], axis=1)
    if lab[seen][0] != "rope_00":
        d = np.linalg.norm(init.positions[::-1] - truth.positions[0, rope_cols], axis=1)
    assert d.max() < 0.03  # each trace, inserted ones included, at its own marker


@pytest.mark.slow
def test_body_like_flags_exactly_the_body_markers(whip_take, jump_take) -> None:  # type: ignore[no-untyped-def]
    for take in (whip_take, jump_take):
        chain = find_rope_chain(take.points)
        is_rope = np.char.startswith(_frame0_labels(take)[chain], "rope_")
        p0 = take.points.frame(0)
        link = float(np.median(np.linalg.norm(np.diff(p0[chain], axis=0), axis=1)))
        body = body_like(take.points, chain, link)
        # hand markers (rigid with the hand) and still leg markers (their rope
        # neighbours move away beyond the rope's length) are caught, no rope marker
        assert (~is_rope).any()
        np.testing.assert_array_equal(body, ~is_rope)


def test_follow_points_stops_when_ambiguous() -> None:
    # two points moving apart at 1 cm/frame, then a third appears beside one of them
    t = np.arange(6)[:, None]
    a = np.hstack([0.01 * t, np.zeros((6, 2))])
    b = np.hstack([1.0 - 0.01 * t, np.zeros((6, 2))])
    frames = [np.vstack([a[k], b[k]]) for k in range(6)]
    frames[4] = np.vstack([a[4] + [0.003, 0.0, 0.0], b[4], a[4] + [0.0, 0.004, 0.0]])
    pts = np.vstack(frames)
    offsets = np.concatenate([[0], np.cumsum([f.shape[0] for f in frames])])
    traj = follow_points(PointCloud(pts, offsets, 120.0), 6, gate=0.02)
    assert traj.shape == (6, 2, 3)
    np.testing.assert_allclose(traj[:, 1], b)  # b is followed throughout
    np.testing.assert_allclose(traj[:4, 0], a[:4])
    assert np.isnan(traj[4:, 0]).all()  # a's run ends where it is ambiguous


def test_selection_errors(whip_take) -> None:  # type: ignore[no-untyped-def]
    cloud = whip_take.points
    with pytest.raises(ValidationError, match="exactly one"):
        init_rope(cloud)
    with pytest.raises(ValidationError, match="exactly one"):
        init_rope(cloud, markers=[0, 1, 2], auto=True)
    with pytest.raises(ValidationError, match="out of range"):
        init_rope(cloud, markers=[0, 1, 10_000])
    with pytest.raises(ValidationError, match="twice"):
        init_rope(cloud, markers=[0, 1, 1])
    with pytest.raises(ValidationError, match="box"):
        init_rope(cloud, box=[0, 0, 0, 1, 1])
    with pytest.raises(ValidationError, match="0 points selected"):
        init_rope(cloud, box=[50, 50, 50, 51, 51, 51])
    with pytest.raises(ValidationError, match="window_seconds"):
        init_rope(cloud, markers=rope_truth_indices(whip_take), window_seconds=0)


def test_auto_on_a_blob_fails_cleanly() -> None:
    rng = np.random.default_rng(0)
    pts = np.tile(rng.normal(size=(40, 3)) * 0.02, (10, 1))
    cloud = PointCloud(pts, np.arange(0, 401, 40), 120.0)
    with pytest.raises(ValidationError, match="rope auto"):
        init_rope(cloud, auto=True)


def test_gated_assignment_resolves_conflicts() -> None:
    # two rows want point 7; the globally best matching gives it to row 1
    dist = np.array([[0.010, 0.015], [0.005, 0.5], [np.inf, np.inf]])
    cand = np.array([[7, 8], [7, 9], [0, 0]])
    rows, pts = gated_assignment(dist, cand, 0.03)
    assert dict(zip(rows.tolist(), pts.tolist(), strict=True)) == {0: 8, 1: 7}
    rows, pts = gated_assignment(dist, cand, 0.001)
    assert rows.size == 0


def test_ropeinit_validates() -> None:
    with pytest.raises(ValidationError):
        RopeInit(np.array([0, 1]), np.zeros((2, 3)), np.ones(1), 0.03, 10)
    with pytest.raises(ValidationError):
        RopeInit(np.array([0, 1, 2]), np.zeros((3, 3)), np.array([0.1, 0.0]), 0.03, 10)
    with pytest.raises(ValidationError):
        RopeInit(np.array([0, 1, 2]), np.zeros((3, 3)), np.ones(2), -1.0, 10)
