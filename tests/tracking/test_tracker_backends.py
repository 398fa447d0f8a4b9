"""The compiled tracker steps (numba) against the NumPy reference: step by step and end to end."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from conftest import blank_state, rope_truth_indices
from skincap.errors import MissingDependencyError, ValidationError
from skincap.evaluate.gap_repair import hold_back_points
from skincap.synth.scenes import jump_rope_scene
from skincap.tracking import tracker
from skincap.tracking.init import gated_assignment, init_rope
from skincap.tracking.tracker import RopeTrack, track_rope
from skincap.types import PointCloud

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
    from skincap.tracking._numba_search import gated_assignment as kernel_assignment
    from skincap.tracking._numba_search import linear_sum_assignment as kernel_lsa

    rng = np.random.default_rng(0)
    for shape in [(1, 1), (3, 5), (5, 3), (6, 6), (8, 2), (2, 9)]:
        for _ in range(20):
            cost = rng.random(shape)
            ri, ci = kernel_lsa(cost)
            sr, sc = linear_sum_assignment(cost)
            np.testing.assert_array_equal(ri, sr)
            np.testing.assert_array_equal(ci, sc)
    for _ in range(200):
        r, k = rng.integers(1, 7), rng.integers(1, 5)
        dist = rng.random((r, k)) * 0.05
        dist[rng.random((r, k)) < 0.3] = np.inf
        dist.sort(axis=1)
        cand = rng.integers(0, 6, size=(r, k))
        ra, pa = kernel_assignment(dist, cand, 0.03)
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


# ------------------------------------------------------------------ step by step
_STEPS = (
    "track_frame",
    "follow_hand",
    "search_with_hand",
    "place_with_hand",
    "seat_hand",
    "release_hand",
    "begin_frame",
    "continue_body_chains",
    "match_measured_best",
    "accelerated_prediction",
    "match_measured",
    "match_traces",
    "rigid_with_body",
    "reject_overstretched",
    "reject_odd_motion",
    "residual_predictions",
    "gap_predictions",
    "match_missing",
    "zipper_predictions",
    "reacquire_on_shell",
    "unshift_chain",
    "swap_onto_curve",
    "place_invented",
    "commit_frame",
    "learn_link_rest",
)
# what a step may change: the take (points, offsets, arclength, spacing, weights) never;
# link_rest is learnt while tracking
_CHANGING = (
    "positions", "invented", "point_index", "lost_frames", "velocity", "temp_count",
    "body", "body_vel", "cur", "known", "taken", "link_rest",
    "hand_index", "hand_then", "hand_vel",
)  # fmt: skip


def _twin_state(state):  # type: ignore[no-untyped-def]
    return state._replace(**{name: getattr(state, name).copy() for name in _CHANGING})


def _assert_same_value(name: str, got, want) -> None:  # type: ignore[no-untyped-def]
    if isinstance(want, tuple):
        assert isinstance(got, tuple) and len(got) == len(want), name
        for g, w in zip(got, want, strict=True):
            _assert_same_value(name, g, w)
    elif isinstance(want, np.ndarray) and want.dtype.kind == "f":
        # a cheap check first: this runs ~10^4 times, and assert_allclose's own
        # bookkeeping dominated the test; it still reports any difference
        if not (
            isinstance(got, np.ndarray)
            and got.shape == want.shape
            and np.array_equal(np.isnan(got), np.isnan(want))
            and np.all(np.abs(np.nan_to_num(got - want, nan=0.0)) <= 1e-9)
        ):
            np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-9, err_msg=name)
    elif isinstance(want, np.ndarray):
        if not (isinstance(got, np.ndarray) and np.array_equal(got, want)):
            np.testing.assert_array_equal(got, want, err_msg=name)
    else:
        assert (want is None and got is None) or bool(got) == bool(want), name


def _replay_every_step(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Make every NumPy step, as the NumPy run calls it, also run its numba twin on a
    copy of the same state and input, and compare the outputs and the states."""
    from skincap.tracking import _steps_numba, _steps_numpy

    calls = dict.fromkeys(_STEPS, 0)

    def checked(name: str):  # type: ignore[no-untyped-def]
        reference, twin = getattr(_steps_numpy, name), getattr(_steps_numba, name)

        def run(state, *args):  # type: ignore[no-untyped-def]
            other = _twin_state(state)
            copies = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
            got = twin(other, *copies)
            want = reference(state, *args)
            _assert_same_value(name, got, want)
            for field in _CHANGING:
                _assert_same_value(
                    f"{name}: state.{field}", getattr(other, field), getattr(state, field)
                )
            calls[name] += 1
            return want

        return run

    for name in _STEPS:
        monkeypatch.setattr(_steps_numpy, name, checked(name))
    return calls


@pytest.mark.slow
def test_every_step_agrees_between_backends_on_real_runs(
    whip_take, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    init = init_rope(whip_take.points, markers=rope_truth_indices(whip_take))
    # two adjacent markers and one near the free end held back: gaps, the zipper, F
    held, kept = hold_back_points(
        whip_take.points, whip_take.point_truth, ["rope_05", "rope_06"], 60, 30
    )
    held, _ = hold_back_points(held, whip_take.point_truth[kept], ["rope_20"], 40, 40)
    # a take with dropouts, ghosts, an empty frame and a one-point frame
    cloud, _, first = jump_rope_scene(
        frames=160, points_per_frame=120, rope_markers=10, dropout=0.1, ghosts_per_frame=6, seed=5
    )
    keep = (cloud.frame_index != 100) & ~(
        (cloud.frame_index == 101) & (np.arange(cloud.points.shape[0]) > cloud.offsets[101])
    )
    counts = np.bincount(cloud.frame_index[keep], minlength=cloud.n_frames)
    sparse = type(cloud)(
        points=cloud.points[keep], offsets=np.concatenate([[0], np.cumsum(counts)]), rate=cloud.rate
    )
    expected = [
        track_rope(held, init, backend="numpy"),
        track_rope(sparse, init_rope(sparse, markers=first), backend="numpy"),
    ]
    calls = _replay_every_step(monkeypatch)
    replayed = [
        track_rope(held, init, backend="numpy"),
        track_rope(sparse, init_rope(sparse, markers=first), backend="numpy"),
    ]
    for a, b in zip(replayed, expected, strict=True):
        _assert_same(a, b)  # the checks change nothing
    # every step ran, most of them hundreds of times, and every one agreed
    assert all(n > 0 for n in calls.values()), calls
    assert calls["match_traces"] > 500 and calls["commit_frame"] == 199 + 159, calls


def test_background_compile_take_tracks_every_rope_marker() -> None:
    # the background compile (warm_up_kernel) runs track_rope on this take: if
    # init_rope refuses it, the kernel never reaches the cache and ``auto`` stays NumPy
    cloud, rope_markers = tracker.warm_up_take()
    track = track_rope(cloud, init_rope(cloud, markers=rope_markers), backend="numpy")
    assert track.positions.shape == (90, 8, 3)
    truth = cloud.points.reshape(90, 48, 3)[:, :8]
    assert np.abs(track.positions - truth).max() < 1e-9


def test_auto_takes_the_kernel_mid_run_once_the_background_compile_lands(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from skincap import backends
    from skincap.tracking import _steps_numpy

    ready = {"now": False}
    kernel_chunks: list[tuple[int, int]] = []

    def stand_in_kernel(state, t0, t1, p):  # type: ignore[no-untyped-def]
        kernel_chunks.append((t0, t1))  # the NumPy twin, so no compile in the test
        _steps_numpy.track_frames(state, t0, t1, p)

    def numpy_progress(fraction: float) -> None:
        ready["now"] = fraction >= 0.5  # the compile lands half-way through the take

    monkeypatch.delenv("SKINCAP_COMPILE", raising=False)
    monkeypatch.setattr(backends, "kernel_ready", lambda dispatcher: ready["now"])
    monkeypatch.setattr(backends, "compile_in_background", lambda name, dispatcher: True)
    monkeypatch.setattr(tracker, "_track_frames_dispatcher", lambda: stand_in_kernel)
    monkeypatch.setattr(backends, "RECHECK_SECONDS", 0.0)
    cloud, rope_markers = tracker.warm_up_take()
    init = init_rope(cloud, markers=rope_markers)
    mixed = track_rope(cloud, init, progress=numpy_progress)
    assert kernel_chunks and kernel_chunks[0][0] > 1 and kernel_chunks[-1][1] == 90
    reference = track_rope(cloud, init, backend="numpy")
    np.testing.assert_array_equal(mixed.positions, reference.positions)
    np.testing.assert_array_equal(mixed.point_index, reference.point_index)


def test_reacquire_agrees_between_backends_in_crowded_frames() -> None:
    """Re-acquisition in frames of a few hundred points spread over many grid cells, with
    the nearest candidate refused (seen beside the trace) and the true point doubled
    (a tie in distance): the numba twin, which searches the frame grid, seats what the
    reference's scan of every point does - the point behind the refused one, the
    lower row of a tie - and the clutter out of reach changes nothing."""
    from skincap.tracking import _steps_numba, _steps_numpy

    spacing, m, gamma = 0.1, 10, 0.03
    rope = np.zeros((m, 3))
    rope[:, 0] = spacing * np.arange(m)
    shift = np.array([0.0, 0.026, 0.0])  # the rope moved 2.6 cm: beyond γ of nothing
    rng = np.random.default_rng(7)
    for trial in range(12):
        hidden = np.sort(rng.choice(np.arange(1, m - 1), size=4, replace=False))
        seen = np.setdiff1d(np.arange(m), hidden)
        want = rope + shift  # where a measured neighbour's link puts each marker
        true = want + [0.008, 0.0, 0.0]  # 8 mm off: 2.7 cm from its frame-0 point
        decoy = want + [0.0, 0.006, 0.0]  # nearer, 3.2 cm from the trace's frame-0 point
        decoy_before = decoy[hidden] + [0.0, 0.025, 0.0]  # a marker it continues
        # clutter over 3 m along x, 30-90 cm off the rope: in the grid's cells, out of reach
        clutter = rng.uniform([-1.0, 0.3, 0.3], [2.0, 0.9, 0.9], size=(300, 3))
        frame0 = np.concatenate([rope, decoy_before, clutter])
        twin = hidden[trial % hidden.size]  # its true point twice: a tie
        rows = np.concatenate(
            [want[seen], true[hidden], decoy[hidden], true[[twin]], clutter + 0.002]
        )
        perm = rng.permutation(rows.shape[0])
        frame1 = rows[perm]
        at = np.argsort(perm) + frame0.shape[0]  # global row of each of `rows`
        cloud = PointCloud(
            points=np.concatenate([frame0, frame1]),
            offsets=np.array([0, frame0.shape[0], frame0.shape[0] + frame1.shape[0]]),
            rate=120.0,
        )
        out = []
        for steps in (_steps_numpy, _steps_numba):
            state, p = blank_state(cloud, [spacing] * (m - 1), gamma=gamma)
            state.positions[0] = rope
            state.point_index[0] = np.arange(m)
            state.known[seen] = True
            state.taken[seen] = at[: seen.size]
            state.cur[seen] = want[seen]
            found = bool(steps.reacquire_on_shell(state, 1, p))
            out.append((found, state.known.copy(), state.taken.copy(), state.cur.copy()))
        (found, known, taken, cur), numba_out = out
        expected = at[seen.size : seen.size + hidden.size].copy()  # the true points
        u = np.searchsorted(hidden, twin)
        expected[u] = min(expected[u], at[seen.size + 2 * hidden.size])  # a tie: lower row
        assert found and known.all()
        np.testing.assert_array_equal(taken[hidden], expected)
        np.testing.assert_allclose(cur[hidden], true[hidden])
        assert numba_out[0] == found
        for got, ref in zip(numba_out[1:], (known, taken, cur), strict=True):
            np.testing.assert_array_equal(got, ref)


def test_hand_anchors_agree_between_backends_in_crowded_frames() -> None:
    """A hidden end's hand seated among many points within reach (more than it keeps,
    some tied in distance, one a trace's point) in frames of a few hundred points over
    many grid cells, then followed into a frame where one anchor has a twin nearby: the
    numba twin, which searches the frame grid, keeps the nearest by (distance, row) as
    the reference's stable sort does and drops the ambiguous anchor alike."""
    from skincap.tracking import _hand_numba, _hand_numpy

    rng = np.random.default_rng(3)
    end = np.array([0.0, 1.0, 0.0])
    k_max = 8
    for trial in range(6):
        # offsets in 1/64 m: exact, so mirrored ones tie exactly in distance
        near = rng.integers(-8, 9, size=(14, 3)) / 64.0
        near = near[np.linalg.norm(near, axis=1) > 0.01]
        near = np.concatenate([near, -near[:3], near[:2]])  # mirrored and doubled: ties
        clutter = rng.uniform([-1.5, 1.4, -1.0], [1.5, 2.0, 1.0], size=(300, 3))
        frame0 = np.concatenate([[end], end + near, clutter])
        frame0[1:] = frame0[1 + rng.permutation(frame0.shape[0] - 1)]  # rows shuffled
        moved = frame0 + [0.004, 0.002, 0.0]  # the hand moved 4.5 mm
        # a second point beside one of the nearest anchors' next positions: ambiguous
        d2 = np.sum((frame0[1:] - end) ** 2, axis=1)
        nearest = 1 + np.lexsort((np.arange(d2.size), d2))[:k_max]
        twin = moved[nearest[trial % k_max]] + [0.0, 0.0, 0.003]
        frame1 = np.concatenate([moved, [twin]])
        n0 = frame0.shape[0]
        cloud = PointCloud(
            points=np.concatenate([frame0, frame1]),
            offsets=np.array([0, n0, n0 + frame1.shape[0]]),
            rate=120.0,
        )
        out = []
        for hand in (_hand_numpy, _hand_numba):
            state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03)
            state.point_index[0] = [0, -1, -1]  # the end measured on row 0 of frame 0
            state.positions[0, 0] = end
            state.velocity[0] = [0.001, 0.0, 0.0]
            hand.seat_hand(state, 1, p)
            out.append(state)
        ref, got = out
        d2 = np.sum((frame0[1:] - end) ** 2, axis=1)  # the reference's own sum
        nearest = 1 + np.lexsort((np.arange(d2.size), d2))[:k_max]
        np.testing.assert_array_equal(ref.hand_then[0], frame0[nearest])
        # followed into frame 1 but for the ambiguous ones: the one given a twin and
        # those doubled in the take (two points equally near)
        doubled = [np.sum(np.all(frame0 == frame0[i], axis=1)) > 1 for i in nearest]
        keep = np.array(doubled) == 0
        keep[trial % k_max] = False
        assert keep.sum() >= 2
        followed = ref.hand_index[0][ref.hand_index[0] >= 0]
        np.testing.assert_array_equal(np.sort(followed), np.sort(n0 + nearest[keep]))
        for field in ("hand_index", "hand_then", "hand_vel", "body", "body_vel"):
            np.testing.assert_array_equal(getattr(got, field), getattr(ref, field), err_msg=field)
