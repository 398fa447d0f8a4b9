"""The compiled tracker (numba, extra ``fast``) against the NumPy reference: same result."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from conftest import rope_truth_indices
from skincap.errors import MissingDependencyError, ValidationError
from skincap.evaluate.tracking import hold_back_points
from skincap.synth.scenes import jump_rope_scene
from skincap.tracking import tracker
from skincap.tracking.init import gated_assignment, init_rope
from skincap.tracking.tracker import RopeTrack, track_rope

pytest.importorskip("numba")


def _assert_same(a: RopeTrack, b: RopeTrack) -> None:
    np.testing.assert_array_equal(a.point_index, b.point_index)
    np.testing.assert_array_equal(a.invented, b.invented)
    np.testing.assert_array_equal(a.lost_frames, b.lost_frames)
    np.testing.assert_allclose(a.positions, b.positions, rtol=0.0, atol=1e-9)


@pytest.mark.parametrize("rope", ["jump", "whip"])
def test_numba_and_numpy_track_alike_on_synthetic_takes(rope: str, jump_take, whip_take) -> None:  # type: ignore[no-untyped-def]
    take = jump_take if rope == "jump" else whip_take
    init = init_rope(take.points, markers=rope_truth_indices(take))
    # two adjacent markers and one near the free end held back: gaps to repair
    held, kept = hold_back_points(take.points, take.point_truth, ["rope_05", "rope_06"], 120, 30)
    held, _ = hold_back_points(held, take.point_truth[kept], ["rope_20"], 90, 40)
    for cloud in (take.points, held):
        fast: list[float] = []
        ref: list[float] = []
        a = track_rope(cloud, init, backend="numba", progress=fast.append)
        b = track_rope(cloud, init, backend="numpy", progress=ref.append)
        _assert_same(a, b)
        assert fast == ref  # the same progress calls
        assert (a.point_index >= 0).any()
    assert a.invented[120:150].sum() >= 40


def test_numba_and_numpy_track_alike_through_dropouts_and_an_empty_frame() -> None:
    cloud, _, first = jump_rope_scene(
        frames=300, points_per_frame=160, rope_markers=12, dropout=0.08, ghosts_per_frame=8, seed=4
    )
    # frame 200 empty, frame 201 a single point: the no-candidate paths
    keep = (cloud.frame_index != 200) & ~(
        (cloud.frame_index == 201) & (np.arange(cloud.points.shape[0]) > cloud.offsets[201])
    )
    counts = np.bincount(cloud.frame_index[keep], minlength=cloud.n_frames)
    held = type(cloud)(
        points=cloud.points[keep], offsets=np.concatenate([[0], np.cumsum(counts)]), rate=cloud.rate
    )
    assert held.counts[200] == 0 and held.counts[201] == 1
    init = init_rope(held, markers=first)
    a = track_rope(held, init, backend="numba")
    _assert_same(a, track_rope(held, init, backend="numpy"))
    assert a.invented[200].all()


def test_kernel_assignment_matches_scipy_and_the_reference() -> None:
    from skincap.tracking._kernel import _gated_assignment, _lsa

    rng = np.random.default_rng(0)
    for shape in [(1, 1), (3, 5), (5, 3), (6, 6), (8, 2), (2, 9)]:
        for _ in range(20):
            cost = rng.random(shape)
            ri, ci = _lsa(cost)
            sr, sc = linear_sum_assignment(cost)
            np.testing.assert_array_equal(ri, sr)
            np.testing.assert_array_equal(ci, sc)
    for _ in range(200):
        r, k = rng.integers(1, 7), rng.integers(1, 5)
        dist = rng.random((r, k)) * 0.05
        dist[rng.random((r, k)) < 0.3] = np.inf
        dist.sort(axis=1)
        cand = rng.integers(0, 6, size=(r, k))
        ra, pa = _gated_assignment(dist, cand, 0.03)
        rb, pb = gated_assignment(dist, cand, 0.03)
        assert dict(zip(ra.tolist(), pa.tolist(), strict=True)) == dict(
            zip(rb.tolist(), pb.tolist(), strict=True)
        )


def test_backend_is_validated(monkeypatch: pytest.MonkeyPatch) -> None:
    cloud, _, first = jump_rope_scene(frames=20, points_per_frame=40, rope_markers=6)
    init = init_rope(cloud, markers=first)
    with pytest.raises(ValidationError, match="backend"):
        track_rope(cloud, init, backend="fortran")
    monkeypatch.setattr(tracker, "numba_available", lambda: False)
    with pytest.raises(MissingDependencyError):
        track_rope(cloud, init, backend="numba")
    # auto falls back to the NumPy reference
    assert track_rope(cloud, init, backend="auto").n_frames == 20
