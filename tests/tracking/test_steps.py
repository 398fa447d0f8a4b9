"""The rope tracker's per-frame steps on hand-made frames, each run on both backends."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import blank_state, rope_truth_indices
from skincap.tracking import _steps_numpy
from skincap.types import PointCloud


def _cloud(*frames: np.ndarray) -> PointCloud:
    counts = [f.shape[0] for f in frames]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return PointCloud(points=np.concatenate(frames), offsets=offsets, rate=120.0)


def test_leave_one_out_weights_match_the_curve() -> None:
    from skincap.tracking.curve import fill_interior_on_curve, rest_arclength
    from skincap.tracking.state import leave_one_out_weights

    rng = np.random.default_rng(4)
    s = rest_arclength(rng.uniform(0.08, 0.15, size=9))
    x = rng.normal(size=(10, 3))
    w = leave_one_out_weights(s)
    for j in range(1, 9):
        known = np.ones(10, dtype=bool)
        known[j] = False
        curve, _ = fill_interior_on_curve(x, known, s)
        np.testing.assert_allclose(w[j] @ x, curve[j], atol=1e-12)
    assert not w[[0, 9]].any()


def test_a_point_that_continues_a_slow_object_is_refused(steps) -> None:  # type: ignore[no-untyped-def]
    gamma = 0.03
    rope_prev = np.array([[0.0, 0, 0], [0.12, 0, 0], [0.24, 0, 0]])
    body_prev = np.array([[0.12, 0.30, 0.0]])  # a body marker, not taken by the rope
    candidate = np.array([[0.12, 0.31, 0.0]])  # the body marker moved 1 cm
    cloud = _cloud(np.concatenate([rope_prev, body_prev]), candidate)

    def run(row: int, last: np.ndarray, pred_row: np.ndarray, steady: bool) -> bool:
        state, p = blank_state(cloud, [0.12, 0.12], gamma=gamma)
        state.positions[0] = rope_prev
        state.positions[0, row] = last
        state.point_index[0] = [0, 1, 2]
        state.temp_count[row] = 0 if steady else 1
        pred = state.positions[0].copy()
        pred[row] = pred_row
        return bool(
            steps.match_traces(
                state, 1, np.array([row]), pred, False, np.zeros(state.known.size, dtype=bool), p
            )
        )

    here = candidate[0] + [0.0, 0.01, 0.0]
    # an inner trace predicted to move 32 cm: the point continues the body marker
    assert not run(1, rope_prev[1], here, True)
    # a slow rope (predicted to move <= γ) judges nothing: taken
    assert run(1, here - [0.0, 0.025, 0.0], here, True)
    # a steady end trace (held in a hand, among hand markers) is exempt; once it is
    # coming back from a gap it is judged
    assert run(0, rope_prev[0], here, True)
    assert not run(0, rope_prev[0], here, False)


def test_body_chains_continue_unambiguous_body_points_only(steps) -> None:  # type: ignore[no-untyped-def]
    prev = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [1.004, 0.0, 0.0]])
    pts = np.array(
        [
            [0.011, 0.0, 0.0],  # continues point 0 by its velocity
            [0.5, 0.0, 0.0],  # continues a point that was not body
            [1.002, 0.0, 0.0],  # near two body predictions: ambiguous
            [2.0, 0.0, 0.0],  # new
        ]
    )
    cloud = _cloud(prev, pts)

    def run(rope_measured_at: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        # body_chain_gate γ = 1 cm
        state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03, body_chain_gate=1.0 / 3.0)
        state.body[:4] = [True, False, True, True]
        state.body_vel[0] = [0.01, 0.0, 0.0]
        state.body[4:] = True  # overwritten
        v_pred = np.full((3, 3), 9.0)
        if rope_measured_at is not None:
            state.point_index[0, 0] = 1
            v_pred[0] = rope_measured_at
        steps.continue_body_chains(state, 1, v_pred, p)
        return state.body[4:], state.body_vel[4:]

    body, vel = run(None)
    np.testing.assert_array_equal(body, [True, False, False, False])
    np.testing.assert_allclose(vel[0], [0.011, 0.0, 0.0])
    assert not vel[1:].any()
    # a measured trace predicted beside it makes it ambiguous too
    body, _ = run(np.array([0.012, 0.0, 0.0]))
    assert not body.any()


def test_a_hidden_traces_prediction_stops_a_body_chain(steps) -> None:  # type: ignore[no-untyped-def]
    # a body marker drops out beside a rope marker hidden at the same time; the rope
    # marker's point comes back where the body marker's velocity would have taken it.
    # The hidden trace predicts it there (its invented position plus its velocity), so
    # the point is ambiguous, not body: the trace, back from its gap, refuses body
    # points, and the chain would otherwise hold the rope marker's point from then on
    prev = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    pts = np.array([[0.011, 0.0, 0.0], [0.5, 0.002, 0.0]])
    cloud = _cloud(prev, pts)

    def run(v_hidden: np.ndarray) -> np.ndarray:
        state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03, body_chain_gate=1.0 / 3.0)
        state.body[:2] = [True, True]
        state.body_vel[0] = [0.01, 0.0, 0.0]
        state.point_index[0] = -1  # no trace measured in frame 0: all hidden
        state.invented[0] = True
        v_pred = np.array([v_hidden, [np.nan, np.nan, np.nan], [9.0, 9.0, 9.0]])
        steps.continue_body_chains(state, 1, v_pred, p)
        return state.body[2:].copy()

    np.testing.assert_array_equal(run(np.array([9.0, 0.0, 0.0])), [True, True])
    np.testing.assert_array_equal(run(np.array([0.012, 0.0, 0.0])), [False, True])


def _zipper(steps, cur: np.ndarray, known: np.ndarray, spacing: np.ndarray):  # type: ignore[no-untyped-def]
    state, p = blank_state(_cloud(np.zeros((1, 3))), spacing)
    state.cur[:] = cur
    state.known[:] = known
    return steps.zipper_predictions(state, p)


def test_zipper_continues_the_measured_side_of_a_run_at_the_rest_spacing(steps) -> None:  # type: ignore[no-untyped-def]
    # 9 markers on a circle of radius 1 (0.2 rad apart): markers 3, 4 and 5 unknown
    m, r, step = 9, 1.0, 0.2
    ang = step * np.arange(m)
    cur = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros(m)], axis=1)
    chord = 2 * r * np.sin(step / 2)
    spacing = np.full(m - 1, chord)
    known = np.ones(m, dtype=bool)
    known[3:6] = False
    rows, pred = _zipper(steps, cur, known, spacing)
    # the run's ends, from their measured sides; the middle waits for the next round
    np.testing.assert_array_equal(rows, [3, 5])
    # three measured markers on each side: bent as the rope bends, at the rest spacing
    np.testing.assert_allclose(np.linalg.norm(pred[3] - cur[2]), chord)
    np.testing.assert_allclose(np.linalg.norm(pred[5] - cur[6]), chord)
    assert np.linalg.norm(pred[3] - cur[3]) < 0.002 and np.linalg.norm(pred[5] - cur[5]) < 0.002
    assert not pred[[0, 1, 2, 4, 6, 7, 8]].any()
    # two measured markers only (marker 1 unknown too): straight on, as the thesis' N
    known[1] = False
    rows, pred = _zipper(steps, cur, known, spacing)
    np.testing.assert_array_equal(rows, [5])  # 3 has one measured marker before it
    known[1], known[0] = True, False
    rows, pred = _zipper(steps, cur, known, spacing)
    np.testing.assert_array_equal(rows, [0, 3, 5])  # the unknown end too
    straight = cur[2] + chord * (cur[2] - cur[1]) / np.linalg.norm(cur[2] - cur[1])
    np.testing.assert_allclose(pred[3], straight)
    # a run at the end of the rope is left to F; a single unknown marker to the curve
    known = np.ones(m, dtype=bool)
    known[5:] = False
    assert _zipper(steps, cur, known, spacing)[0].size == 0
    # an unknown end of the rope beside measured markers: bent as the rope bends
    for end in (0, m - 1):
        known = np.ones(m, dtype=bool)
        known[end] = False
        rows, pred = _zipper(steps, cur, known, spacing)
        np.testing.assert_array_equal(rows, [end])
        assert np.linalg.norm(pred[end] - cur[end]) < 0.002
    known = np.ones(m, dtype=bool)
    known[4] = False
    assert _zipper(steps, cur, known, spacing)[0].size == 0
    # random frames: the same as the reference
    rng = np.random.default_rng(3)
    for _ in range(50):
        known = rng.random(m) < 0.6
        pts = rng.normal(size=(m, 3))
        rows, pred = _zipper(steps, pts, known, spacing)
        ref_rows, ref_pred = _zipper(_steps_numpy, pts, known, spacing)
        np.testing.assert_array_equal(rows, ref_rows)
        np.testing.assert_allclose(pred, ref_pred, atol=1e-12)


def test_a_slow_steady_trace_takes_no_point_beyond_gamma_in_the_wide_gate(steps) -> None:  # type: ignore[no-untyped-def]
    gamma = 0.03
    prev = np.array([[0.0, 0, 0], [0.12, 0, 0], [0.24, 0, 0]])
    # frame 1: markers 0 and 2 measured; marker 1 hidden, a body point 4.5 cm from
    # where it was, at its rest spacing from both neighbours
    body_pt = np.array([0.12, 0.0, 0.045])
    cloud = _cloud(prev, np.concatenate([prev[[0, 2]], [body_pt]]))

    def run(pred: np.ndarray) -> bool:
        state, p = blank_state(cloud, [0.12, 0.12], gamma=gamma)
        state.positions[0] = prev
        state.point_index[0] = [0, 1, 2]
        state.cur[[0, 2]] = prev[[0, 2]]
        state.known[:] = [True, False, True]
        state.taken[:] = [3, -1, 4]
        return bool(
            steps.match_traces(
                state, 1, np.array([1]), pred, True, np.zeros(state.known.size, dtype=bool), p
            )
        )

    assert not run(prev.copy())  # predicted still: the body point 4.5 cm off is refused
    fast = prev.copy()
    fast[1] = [0.12, 0.0, 0.05]  # predicted to move 5 cm (> γ): taken 0.5 cm from there
    assert run(fast)


def _segment_and_rope(frames: int = 40) -> tuple[PointCloud, np.ndarray]:
    """A body segment (three markers turning slowly while it moves 12 cm) beside a rope
    marker swinging on its own; points in shuffled order per frame.

    Returns the cloud and (frames, 4) the global index of each object's point: columns
    0-2 the segment, 3 the rope marker.
    """
    rng = np.random.default_rng(3)
    t = np.arange(frames) / 120.0
    base = np.array([[0.0, 1.0, 0.0], [0.10, 1.0, 0.0], [0.0, 1.0, 0.12]])
    ang = 0.5 * t  # rad, slow turn about y
    c, s_ = np.cos(ang), np.sin(ang)
    rot = np.zeros((frames, 3, 3))
    rot[:, 0, 0], rot[:, 0, 2], rot[:, 2, 0], rot[:, 2, 2] = c, s_, -s_, c
    rot[:, 1, 1] = 1.0
    seg = np.einsum("tij,kj->tki", rot, base) + np.stack([0.36 * t, 0 * t, 0 * t], 1)[:, None]
    rope = np.stack([0.05 + 0.02 * np.sin(20 * t), 0.9 + 0.15 * t, 0.06 * np.cos(15 * t)], 1)
    objs = np.concatenate([seg, rope[:, None]], axis=1)  # (F, 4, 3)
    pts, where = [], np.zeros((frames, 4), dtype=np.int64)
    for f in range(frames):
        order = rng.permutation(4)
        pts.append(objs[f, order])
        where[f, order] = 4 * f + np.arange(4)
    cloud = PointCloud(points=np.concatenate(pts), offsets=np.arange(frames + 1) * 4, rate=120.0)
    return cloud, where


def test_a_point_moving_rigidly_with_body_points_is_body_like(steps) -> None:  # type: ignore[no-untyped-def]
    cloud, where = _segment_and_rope()
    t = 39  # the window: 0.25 s = 30 frames; median spacing 0.12 m
    for obj, body_like in [(0, True), (3, False)]:
        # a trace that followed the object (its history), and a point followed by itself
        state, p = blank_state(cloud, [0.12, 0.12])
        assert (p.rigid_window, p.median_spacing) == (30, 0.12)
        state.point_index[:, 0] = where[:, obj]
        state.point_index[t] = -1
        state.taken[0] = where[t, obj]
        for j in (0, -1):
            assert steps.rigid_with_body(state, t, j, where[t, obj], p) == body_like, (obj, j)
    # the segment still (moving less than rigid_move spacings): no evidence
    still = PointCloud(
        points=np.tile(cloud.points[:4], (cloud.n_frames, 1)), offsets=cloud.offsets, rate=120.0
    )
    state, p = blank_state(still, [0.12, 0.12])
    state.taken[0] = 4 * t
    assert not steps.rigid_with_body(state, t, -1, 4 * t, p)
    # before a whole window: no evidence
    state, p = blank_state(cloud, [0.12, 0.12])
    assert not steps.rigid_with_body(state, 20, -1, where[20, 0], p)


def test_points_a_hidden_trace_predicts_are_not_rigidity_partners(steps) -> None:  # type: ignore[no-untyped-def]
    # rope markers hidden together move together: a point within γ of a hidden
    # trace's prediction is that trace's marker, not a body point confirming another
    cloud, where = _segment_and_rope()
    t = 39
    state, p = blank_state(cloud, [0.12, 0.12])
    state.point_index[:t, 0] = where[:t, 0]
    state.taken[0] = where[t, 0]
    state.known[0] = True
    x1 = cloud.points[where[t - 1 : t + 1, 1]]  # segment marker 1 in frames t - 1, t
    assert steps.rigid_with_body(state, t, 0, where[t, 0], p)  # partners 1 and 2
    state.positions[t - 1, 1] = x1[0]
    state.velocity[1] = x1[1] - x1[0]  # trace 1, hidden in frame t - 1, predicted on it
    assert not steps.rigid_with_body(state, t, 0, where[t, 0], p)  # partner 2 alone
    state.known[1] = True  # found already (its point taken or not): its prediction is spent
    assert steps.rigid_with_body(state, t, 0, where[t, 0], p)
    state.known[1] = False
    state.point_index[t - 1, 1] = where[t - 1, 3]  # measured in frame t - 1: not hidden
    assert steps.rigid_with_body(state, t, 0, where[t, 0], p)


def test_rigidity_test_agrees_between_backends() -> None:
    pytest.importorskip("numba")
    from skincap.tracking import _steps_numba

    cloud, where = _segment_and_rope()
    for t in (20, 30, 39):
        for obj in range(4):
            state, p = blank_state(cloud, [0.12, 0.12])
            state.point_index[:t, 0] = where[:t, obj]
            state.taken[0] = where[t, obj]
            for j in (0, -1):
                args = (state, t, j, where[t, obj], p)
                assert _steps_numba.rigid_with_body(*args) == _steps_numpy.rigid_with_body(*args)


def _truth_state(take, t: int):  # type: ignore[no-untyped-def]
    """(state, params) of a synthetic take as if tracked perfectly up to frame t: each
    trace's points from the truth labels, frame t's rope points taken."""
    from skincap.tracking.init import init_rope
    from skincap.tracking.settings import TrackSettings
    from skincap.tracking.state import start_tracking

    cloud = take.points
    state, p = start_tracking(
        cloud, init_rope(cloud, markers=rope_truth_indices(take)), TrackSettings()
    )
    labels = take.point_truth.astype(str)
    names = np.unique(labels[np.char.startswith(labels, "rope_")])
    for j, name in enumerate(names):
        rows = np.nonzero(labels == name)[0]
        frames = cloud.frame_index[rows]
        state.point_index[frames[frames < t], j] = rows[frames < t]
        state.taken[j] = rows[frames == t][0] if np.any(frames == t) else -1
    return state, p


def test_backward_scans_agree_between_backends_on_every_point(whip_take) -> None:  # type: ignore[no-untyped-def]
    """The compiled backward scans search each past frame's grid, not every point: on
    every point of three frames of a dense take they answer as the reference does."""
    pytest.importorskip("numba")
    from skincap.tracking import _refusals_numba, _refusals_numpy

    cloud = whip_take.points
    body_like = asked = reached = 0
    for t in (45, 120, 190):
        state, p = _truth_state(whip_take, t)
        for point in range(int(cloud.offsets[t]), int(cloud.offsets[t + 1])):
            for j in (-1, 3):
                want = _steps_numpy.rigid_with_body(state, t, j, point, p)
                assert _refusals_numba.rigid_with_body(state, t, j, point, p) == want, (t, point)
                body_like += want
                asked += 1
            for j in (0, 11):
                want = _refusals_numpy.path_back_to_trace(state, t, j, point, p)
                got = _refusals_numba.path_back_to_trace(state, t, j, point, p)
                # the same point and frame; the distance to rounding (the backends add
                # the squares in different orders)
                assert got[:2] == want[:2], (t, point, j)
                assert got[2] == pytest.approx(want[2], rel=1e-12), (t, point, j)
                reached += want[0] >= 0
    assert 0 < body_like < asked and reached > 0  # both answers were asked for


def test_backward_scans_break_ties_to_the_lower_row() -> None:
    """Two points equally near the prediction on either side of it along the grid's
    axis, the far-side one first in the frame: the scan of every point takes the first,
    the compiled grid search (which meets the lower cell first) must too."""
    pytest.importorskip("numba")
    from skincap.tracking import _refusals_numba, _refusals_numpy
    from skincap.tracking._numba_grid import build_grid

    half = 3.0 / 128.0  # m; dyadic coordinates: both distances exactly equal
    frames = []
    for f in range(40):
        centre = np.array([f / 64.0, 1.0, 0.0])  # moving along x
        pair = centre + np.array([[half, 0.0, 0.0], [-half, 0.0, 0.0]])  # + side first
        line = centre + np.stack(
            [np.arange(30) * 0.05 - 0.75, 0 * np.ones(30), 0.8 * np.ones(30)], 1
        )
        frames.append(np.concatenate([pair, line]))
    t = 39
    frames[t] = np.concatenate([frames[t], (frames[t - 1][0] + frames[t - 1][1])[None] / 2])
    cloud = _cloud(*frames)
    state, p = blank_state(cloud, [0.12, 0.12])
    a = int(cloud.offsets[t - 1])
    axis, lo, inv, _, _ = build_grid(cloud.points, a, int(cloud.offsets[t]), p.gamma)
    cells = np.floor((cloud.points[[a, a + 1], axis] - lo) * inv)
    assert axis == 0 and cells[1] < cells[0]  # the + side's cell is met second
    state.point_index[:t, 0] = cloud.offsets[:t] + 5  # the trace's own points, far off
    point = int(cloud.offsets[t + 1]) - 1  # exactly between frame t - 1's pair
    want = _refusals_numpy.path_back_to_trace(state, t, 0, point, p)
    assert want[0] == a and want[1] == t - 1  # the first of the pair, the + side
    assert _refusals_numba.path_back_to_trace(state, t, 0, point, p) == want
    for j in (-1, 0):
        assert _refusals_numba.rigid_with_body(state, t, j, point, p) == (
            _steps_numpy.rigid_with_body(state, t, j, point, p)
        )


def test_a_stretched_link_drops_its_body_like_side(steps) -> None:  # type: ignore[no-untyped-def]
    from skincap.tracking._refusals_numpy import _keep_best_chain

    gamma = 0.03
    s = np.array([0.0, 0.12, 0.24])
    # marker 2 one γ beyond its rest spacing from marker 1 (the limit is 0.4 γ)
    cur = np.array([[0.0, 0, 0], [0.12, 0, 0], [0.24 + gamma, 0, 0]])
    idx = np.arange(3)

    def keep(body_like: int) -> np.ndarray:
        return _keep_best_chain(cur, s, idx, idx == body_like, gamma, 1.1, 0.4)

    np.testing.assert_array_equal(keep(-1), [True, True, False])  # no evidence: least stretch
    np.testing.assert_array_equal(keep(2), [True, True, False])
    np.testing.assert_array_equal(keep(1), [True, False, True])  # marker 1 on a body point
    # the step, without rigidity evidence (frame 1, before a whole window)
    state, p = blank_state(_cloud(cur, cur), [0.12, 0.12], gamma=gamma)
    state.cur[:] = cur
    state.known[:] = True
    state.taken[:] = [3, 4, 5]
    steps.reject_overstretched(state, 1, p)
    np.testing.assert_array_equal(state.known, [True, True, False])
    np.testing.assert_array_equal(state.taken, [3, 4, -1])


def test_odd_motion_is_refused_for_steady_inner_markers(steps) -> None:  # type: ignore[no-untyped-def]
    prev = np.array([[0.0, 0, 0], [0.12, 0, 0], [0.24, 0, 0], [0.36, 0, 0]])
    cur = prev + [0.0, 0.05, 0.0]
    cur[1, 1] += 0.06  # marker 1 moves 6 cm more than its neighbours (5 cm off their mean > γ)
    cur[2, 1] += 0.02  # marker 2 moves 2 cm more (1 cm off its neighbours' mean < γ)

    def run(steady1: bool) -> np.ndarray:
        state, p = blank_state(_cloud(prev, cur), [0.12, 0.12, 0.12], gamma=0.03)
        state.positions[0] = prev
        state.cur[:] = cur
        state.known[:] = True
        state.taken[:] = [4, 5, 6, 7]
        state.temp_count[1] = 0 if steady1 else 2
        steps.reject_odd_motion(state, 1, p)
        np.testing.assert_array_equal(state.taken < 0, ~state.known)
        return state.known.copy()

    np.testing.assert_array_equal(run(True), [True, False, True, True])
    np.testing.assert_array_equal(run(False), [True, True, True, True])  # back from a gap


def test_traces_back_from_a_gap_refuse_rigid_body_points(steps) -> None:  # type: ignore[no-untyped-def]
    cloud, where = _segment_and_rope()
    t = 39
    target = cloud.points[where[t, 0]]  # the segment's first marker

    def run(steady: bool, **settings: int) -> bool:
        state, p = blank_state(cloud, [0.12, 0.12], **settings)
        pred = np.zeros((3, 3))
        pred[0] = target + 0.005
        state.positions[t - 1, 0] = pred[0]  # predicted still: the slow-object test is off
        state.temp_count[0] = 0 if steady else 3
        return bool(
            steps.match_traces(
                state, t, np.array([0]), pred, True, np.zeros(state.known.size, dtype=bool), p
            )
        )

    assert not run(False)  # back from a gap: refused
    assert run(False, rigid_partners=99)  # no point has 99 rigid partners: taken
    assert run(True)  # a steady trace keeps it (the held end moves with the hand)


def test_commit_frame_writes_the_row_and_advances_the_state(steps) -> None:  # type: ignore[no-untyped-def]
    cloud = _cloud(np.zeros((3, 3)), np.ones((3, 3)))
    state, p = blank_state(cloud, [0.1, 0.1])
    state.positions[0] = [[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]]
    state.temp_count[:] = [0, 10, 10]  # maxTempMarkers 10
    state.cur[:] = [[0.0, 0.01, 0], [0.1, 0.02, 0], [0.2, 0.03, 0]]
    state.known[:] = [True, False, False]
    state.taken[:] = [3, -1, -1]
    steps.commit_frame(state, 1, p)
    np.testing.assert_array_equal(state.temp_count, [0, 11, 11])
    np.testing.assert_array_equal(state.invented[1], [False, True, True])
    # over maxTempMarkers, but pinned by marker 0, measured within two markers
    np.testing.assert_array_equal(state.lost_frames[1], [False, False, False])
    np.testing.assert_array_equal(state.point_index[1], [3, -1, -1])
    np.testing.assert_array_equal(state.positions[1], state.cur)
    np.testing.assert_allclose(state.velocity, [[0.0, 0.01, 0], [0.0, 0.02, 0], [0.0, 0.03, 0]])
    state.known[:] = False  # nothing measured (the frame again): those over the limit are lost
    steps.commit_frame(state, 1, p)
    np.testing.assert_array_equal(state.lost_frames[1], [False, True, True])


def test_link_rest_learns_the_longest_accepted_chord_up_to_the_stretch(steps) -> None:  # type: ignore[no-untyped-def]
    cur = np.array([[0.0, 0, 0], [0.105, 0, 0], [0.305, 0, 0], [0.395, 0, 0]])
    state, p = blank_state(_cloud(cur, cur), [0.1, 0.1, 0.1], gamma=0.03)
    state.cur[:] = cur
    state.known[:] = [True, True, True, False]
    steps.learn_link_rest(state, 1, p)
    # a longer chord raises the link; one beyond the stretch (1.1) stops there; a link
    # with an unmeasured end learns nothing
    np.testing.assert_allclose(state.link_rest, [0.105, 0.11, 0.1])
    state.cur[1] = [0.09, 0, 0]  # a shorter chord never lowers it
    steps.learn_link_rest(state, 1, p)
    np.testing.assert_allclose(state.link_rest, [0.105, 0.11, 0.1])


@pytest.mark.parametrize("measured_before", [True, False])
def test_a_link_started_slack_learns_up_to_the_stretch_of_the_tape_spacing(
    steps, measured_before: bool
) -> None:  # type: ignore[no-untyped-def]
    """A link whose still-window chord was slack (8 cm on 10 cm tape spacing) learns the
    chord the rope shows taut, up to ``stretch`` times the median spacing, not
    ``stretch`` times its own slack start (8.8 cm), when both its markers were
    measured in the frame before too; no link beyond that."""
    cur = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.32, 0, 0], [0.42, 0, 0]])
    state, p = blank_state(_cloud(cur, cur), [0.08, 0.1, 0.1, 0.1], gamma=0.03)
    state.invented[0, 0] = not measured_before
    state.cur[:] = cur
    state.known[:] = True
    steps.learn_link_rest(state, 1, p)
    first = 0.1 if measured_before else 0.088
    np.testing.assert_allclose(state.link_rest, [first, 0.1, 0.11, 0.1])
    state.cur[0] = [-0.02, 0, 0]  # 12 cm: stops at 1.1 x the 10 cm median
    steps.learn_link_rest(state, 1, p)
    first = 0.11 if measured_before else 0.088
    np.testing.assert_allclose(state.link_rest, [first, 0.1, 0.11, 0.1])


def test_the_stretch_rule_uses_the_learnt_link_rest(steps) -> None:  # type: ignore[no-untyped-def]
    gamma = 0.03
    # marker 2 sits 0.4 γ + 3 mm beyond the still window's (slack) spacing from marker 1
    cur = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2 + 0.4 * gamma + 0.003, 0, 0]])

    def kept(link_rest: float) -> np.ndarray:
        state, p = blank_state(_cloud(cur, cur), [0.1, 0.1], gamma=gamma)
        state.link_rest[:] = link_rest
        state.cur[:] = cur
        state.known[:] = True
        state.taken[:] = [3, 4, 5]
        steps.reject_overstretched(state, 1, p)
        return state.known.copy()

    np.testing.assert_array_equal(kept(0.1), [True, True, False])
    np.testing.assert_array_equal(kept(0.105), [True, True, True])  # the rope showed 10.5 cm


def test_reacquire_follows_the_rope_out_along_its_spacing(steps) -> None:  # type: ignore[no-untyped-def]
    gamma, spacing, m = 0.03, 0.1, 6
    before = np.zeros((m, 3))
    before[:, 0] = spacing * np.arange(m)
    # the rope moved 8 cm (beyond every gate of V) and bent 45° at marker 2
    after = before + [0.0, 0.08, 0.0]
    turn = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0])
    after[3:] = after[2] + spacing * np.arange(1, m - 2)[:, None] * turn
    body_point = before[0] + [0.0, 0.05, 0.0]  # nearer marker 0's V than the rope: body
    off_shell = after[2] + [spacing, 0.0, 0.06]  # 6 cm from the straight link: off the shell
    frame1 = np.concatenate([after[::-1], [body_point, off_shell]])
    cloud = _cloud(before, frame1)
    state, p = blank_state(cloud, [spacing] * (m - 1), gamma=gamma)
    state.positions[0] = before
    state.body[m + m] = True  # frame 1's body point (frame 0 has m points)
    assert steps.reacquire_on_shell(state, 1, p)
    assert state.known.all()
    np.testing.assert_array_equal(state.taken, m + np.arange(m)[::-1])
    np.testing.assert_allclose(state.cur, after)
    # nothing on the shell: nothing taken
    state, p = blank_state(_cloud(before, np.array([[5.0, 5.0, 5.0]])), [spacing] * (m - 1))
    state.positions[0] = before
    assert not steps.reacquire_on_shell(state, 1, p)
    assert not state.known.any()


def test_reacquire_leaves_a_point_seen_beside_the_trace_alone(steps) -> None:  # type: ignore[no-untyped-def]
    spacing, m = 0.1, 6
    rope = np.zeros((m, 3))
    rope[:, 0] = spacing * np.arange(m)
    hand = rope[0] + [0.0, 0.04, 0.0]  # on marker 1's shell, 4 cm from where marker 0 was
    still = np.concatenate([rope, [hand]])
    cloud = _cloud(still, still, np.concatenate([rope[1:], [hand]]))  # marker 0 drops out

    def reacquired(measured_before: bool) -> bool:
        state, p = blank_state(cloud, [spacing] * (m - 1), gamma=0.03)
        state.positions[:2] = rope
        state.point_index[0] = np.arange(m)
        state.point_index[1] = m + 1 + np.arange(m)
        if not measured_before:
            state.point_index[:2, 0] = -1
        state.cur[1:] = rope[1:]
        state.known[1:] = True
        state.taken[1:] = 2 * (m + 1) + np.arange(m - 1)
        return bool(steps.reacquire_on_shell(state, 2, p))

    # the hand marker stood beside marker 0 while it was measured: not the rope
    assert not reacquired(True)
    # with no such evidence (marker 0 never measured) the point on the shell is taken
    assert reacquired(False)


def test_reacquire_takes_nothing_when_every_point_is_taken_or_body(steps) -> None:  # type: ignore[no-untyped-def]
    spacing, m = 0.1, 6
    rope = np.zeros((m, 3))
    rope[:, 0] = spacing * np.arange(m)
    # marker 2 hidden; the point where it would be is a body point, the rest are the rope's
    frame1 = np.concatenate([np.delete(rope, 2, axis=0), rope[2:3]])
    state, p = blank_state(_cloud(rope, frame1), [spacing] * (m - 1), gamma=0.03)
    state.positions[0] = rope
    mine = [0, 1, 3, 4, 5]
    state.known[mine] = True
    state.taken[mine] = m + np.arange(m - 1)
    state.cur[mine] = rope[mine]
    state.body[m + m - 1] = True
    taken, cur = state.taken.copy(), state.cur.copy()
    assert not steps.reacquire_on_shell(state, 1, p)
    np.testing.assert_array_equal(state.known, np.isin(np.arange(m), mine))
    np.testing.assert_array_equal(state.taken, taken)
    np.testing.assert_array_equal(state.cur, cur)
    # the same point, no longer a body point, is taken from either neighbour's shell
    state.body[m + m - 1] = False
    assert steps.reacquire_on_shell(state, 1, p)
    assert state.taken[2] == m + m - 1


def _swinging_rope(angles: np.ndarray) -> np.ndarray:
    """(F, 5, 3) metres: a rope of 5 markers 12 cm apart along x, hanging 0.8-1.0 m
    below the x axis and turned about it by ``angles`` (F,) radians (a jump rope's
    bottom swinging)."""
    radius = np.array([0.8, 0.9, 1.0, 0.9, 0.8])
    x = 0.12 * np.arange(5)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    return np.stack([np.broadcast_to(x, c.shape * np.array([1, 5])), -radius * c, radius * s], -1)


def _swing_state(frames: np.ndarray, gamma: float = 0.03):  # type: ignore[no-untyped-def]
    """State after frames[:-1] (all measured), frame -1 in the cloud to be matched."""
    n, m = frames.shape[:2]
    cloud = _cloud(*frames)
    spacing = np.linalg.norm(np.diff(frames[0], axis=0), axis=1)
    state, p = blank_state(cloud, spacing, gamma=gamma)
    state.positions[: n - 1] = frames[: n - 1]
    state.point_index[: n - 1] = np.arange(n - 1)[:, None] * m + np.arange(m)
    state.velocity[:] = frames[n - 2] - frames[n - 3]
    return state, p


def test_accelerated_prediction_follows_a_turning_rope(steps) -> None:  # type: ignore[no-untyped-def]
    # turning 0.25 rad a frame about the x axis (the bottom moves 25 cm a frame)
    frames = _swinging_rope(0.25 * np.arange(4))
    state, p = _swing_state(frames)
    v = state.positions[2] + state.velocity
    acc = steps.accelerated_prediction(state, 3, v, p)
    # constant velocity misses by about r ω² (5-6 cm, 2 γ); the second order by r ω³
    miss_v = np.linalg.norm(v - frames[3], axis=1)
    miss_acc = np.linalg.norm(acc - frames[3], axis=1)
    assert miss_v.min() > 1.5 * p.gamma and miss_acc.max() < 0.6 * p.gamma
    np.testing.assert_allclose(acc - v, frames[2] - 2 * frames[1] + frames[0], atol=1e-12)
    # a trace invented in any of the last three frames, and frames before 3, keep V
    state.invented[1, 2] = True
    acc = steps.accelerated_prediction(state, 3, v, p)
    np.testing.assert_array_equal(acc[2], v[2])
    np.testing.assert_array_equal(steps.accelerated_prediction(state, 2, v, p), v)


# slow with an empty numba cache: match_measured_best compiles as an entry point of its own
@pytest.mark.slow
def test_the_matching_at_the_prediction_that_finds_more_is_kept(steps) -> None:  # type: ignore[no-untyped-def]
    # a swinging rope: V misses every marker by 2 γ, the accelerated prediction finds all
    state, p = _swing_state(_swinging_rope(0.25 * np.arange(4)))
    steps.match_measured_best(state, 3, state.positions[2] + state.velocity, p)
    np.testing.assert_array_equal(state.taken, 15 + np.arange(5))
    # a jerk: still, then a 5 cm step, then on at that velocity: the last change of
    # velocity overshoots by 5 cm, V finds every marker
    frames = _swinging_rope(np.array([0.0, 0.0, 0.05, 0.10]))
    state, p = _swing_state(frames)
    steps.match_measured_best(state, 3, state.positions[2] + state.velocity, p)
    np.testing.assert_array_equal(state.taken, 15 + np.arange(5))
    # with swing_gate beyond every acceleration only V is tried: the swinging rope is missed
    state, p = _swing_state(_swinging_rope(0.25 * np.arange(4)))
    p = p._replace(swing_gate=100.0)
    steps.match_measured_best(state, 3, state.positions[2] + state.velocity, p)
    assert not state.known.any()


def test_a_bent_link_is_taken_near_its_prediction_and_refused_beyond(steps) -> None:  # type: ignore[no-untyped-def]
    gamma, rest = 0.03, 0.12
    # a rope folded at marker 1 (on the floor): 12 cm of rope per link, 8.5 cm chords
    # (more than γ short of the spacing); marker 1 hidden in frame 1
    bent = [0.06, 0.0, -np.sqrt(0.085**2 - 0.06**2)]
    prev = np.array([[0.0, 0, 0], bent, [0.12, 0, 0]])

    def taken(candidate: list[float], pred: list[float]) -> bool:
        cloud = _cloud(prev, np.array([prev[0], prev[2], candidate]))
        state, p = blank_state(cloud, [rest, rest], gamma=gamma)
        state.positions[0] = prev
        state.point_index[0] = [0, 1, 2]
        state.temp_count[1] = 3  # back from a gap: the wide gate's spacing rules apply
        state.cur[[0, 2]] = prev[[0, 2]]
        state.known[:] = [True, False, True]
        state.taken[:] = [3, -1, 4]
        guess = prev.copy()
        guess[1] = pred
        return bool(
            steps.match_traces(
                state, 1, np.array([1]), guess, True, np.zeros(state.known.size, dtype=bool), p
            )
        )

    assert taken(bent, np.add(bent, [0.0, 0.0, 0.02]))  # within γ of its prediction: taken
    assert not taken(bent, np.add(bent, [0.0, 0.0, 1.5 * gamma]))  # beyond γ: refused
    # a chord more than γ beyond the rest spacing is refused even at the prediction
    far = [0.06, 0.0, 0.15]  # chords 16.2 cm
    assert not taken(far, far)


def test_a_long_missing_inner_trace_takes_the_only_point_on_its_shell(steps) -> None:  # type: ignore[no-untyped-def]
    spacing = 0.1
    rope = np.zeros((6, 3))
    rope[:, 0] = spacing * np.arange(6)
    # markers 4 and 5 hidden while the rope folded back at marker 3 by 130° (a rope end
    # dragged along the floor); marker 4 is back, 18 cm from where the link put it
    turn = np.radians(130.0)
    folded = rope[3] + spacing * np.array([np.cos(turn), np.sin(turn), 0.0])
    other = rope[3] + [0.0, -spacing, 0.0]  # a second free point on the shell

    def reacquired(m: int, missing: int, *extra: np.ndarray) -> bool:
        frame1 = np.concatenate([rope[:4], [folded], *[[e] for e in extra]])
        state, p = blank_state(_cloud(rope, frame1), [spacing] * (m - 1), gamma=0.03)
        state.positions[0] = rope[:m]
        state.temp_count[4:] = missing
        state.known[:4] = True
        state.taken[:4] = 6 + np.arange(4)
        state.cur[:4] = rope[:4]
        found = bool(steps.reacquire_on_shell(state, 1, p))
        assert found == bool(state.known[4])
        if found:
            np.testing.assert_allclose(state.cur[4], folded)
        return found

    assert reacquired(6, 20)  # missing lone_after frames: the only point on the shell
    assert not reacquired(6, 19)  # missing fewer: only within 60° of the previous link
    assert not reacquired(6, 20, other)  # two points on the shell: neither
    assert not reacquired(5, 20)  # marker 4 is the rope's end (held among hand markers)


def test_reacquire_takes_a_folded_end_where_its_last_seen_link_puts_it(steps) -> None:  # type: ignore[no-untyped-def]
    spacing, m, gamma = 0.1, 6, 0.03
    rope = np.zeros((m, 3))
    rope[:, 0] = spacing * np.arange(m)
    # the end link lies folded on the floor beside the hand: a 4 cm chord for 10 cm of
    # rope; marker 0 was hidden in frame 1 and invented straight on at the rest spacing
    folded = rope.copy()
    folded[0] = rope[1] + [-0.02, 0.0, 0.0346]
    invented = rope.copy()  # F: 10 cm from marker 1, 3.5-6 cm from where the end lies

    def reacquired(end: np.ndarray, *, last_seen_link: bool = True) -> bool:
        cloud = _cloud(folded, folded[1:], np.concatenate([folded[1:], [end]]))
        state, p = blank_state(cloud, [spacing] * (m - 1), gamma=gamma)
        state.positions[0], state.positions[1] = folded, invented
        state.point_index[0] = np.arange(m)
        state.point_index[1] = [-1, *(m + np.arange(m - 1))]
        state.invented[1, 0] = True
        state.invented[0, 1] = not last_seen_link  # marker 1 unseen when 0 was last seen
        state.temp_count[0] = 1
        state.cur[1:] = folded[1:]
        state.known[1:] = True
        state.taken[1:] = 2 * m - 1 + np.arange(m - 1)
        found = bool(steps.reacquire_on_shell(state, 2, p))
        assert found == bool(state.known[0])
        if found:
            assert state.taken[0] == 3 * m - 2
            np.testing.assert_allclose(state.cur[0], end)
        return found

    # off the shell (more than γ short of the spacing) and beyond the wide gate of F,
    # taken within γ of where the link lay when last measured
    assert np.linalg.norm(folded[0] - folded[1]) < spacing - gamma
    assert reacquired(folded[0])
    assert reacquired(folded[0] + [0.0, 0.02, 0.0])
    assert not reacquired(folded[0] + [0.0, 1.2 * gamma, 0.0])  # beyond γ of that link
    assert not reacquired(folded[0], last_seen_link=False)  # no link measured: no evidence


def test_reacquire_gives_a_point_two_traces_reach_to_the_nearer_link(steps) -> None:  # type: ignore[no-untyped-def]
    spacing, m, gamma = 0.1, 6, 0.03
    # a rope folded back over itself at marker 2 lying still (a jump rope doubled on the
    # floor): markers 0-2 along x, markers 3-5 back above them
    rope = np.zeros((m, 3))
    rope[:3, 0] = spacing * np.arange(3)
    rope[3] = [0.15, 0.0, 0.08]
    rope[4:] = rope[3] - spacing * np.arange(1, 3)[:, None] * [1.0, 0.0, 0.0]
    # marker 3 was hidden in frame 0 (invented where it lies) and is back in frame 1;
    # marker 2 drops out in frame 1: its previous link from marker 1 reaches marker 3's
    # point (9.4 cm, within one rest length), marker 3's link from marker 4 puts it there
    seen0 = [0, 1, 2, 4, 5]
    seen1 = [0, 1, 3, 4, 5]
    cloud = _cloud(rope[seen0], rope[seen1])
    state, p = blank_state(cloud, [spacing] * (m - 1), gamma=gamma)
    state.positions[0] = rope
    state.invented[0, 3] = True
    state.point_index[0] = [0, 1, 2, -1, 3, 4]
    state.temp_count[3] = 3
    mine = [0, 1, 4, 5]
    state.known[mine] = True
    state.taken[mine] = [5, 6, 8, 9]
    state.cur[mine] = rope[mine]
    assert np.linalg.norm(rope[3] - rope[2]) <= spacing  # marker 2's gate reaches it
    assert np.linalg.norm(rope[3] - rope[1]) >= spacing - gamma  # on marker 1's shell
    assert steps.reacquire_on_shell(state, 1, p)
    assert state.known[3] and state.taken[3] == 7  # the trace whose link puts it there
    np.testing.assert_allclose(state.cur[3], rope[3])
    assert not state.known[2]  # its marker is hidden: nothing else on its shell


def test_a_trace_back_from_a_gap_takes_its_neighbours_velocity(steps) -> None:  # type: ignore[no-untyped-def]
    m = 5
    rope = np.zeros((m, 3))
    rope[:, 0] = 0.1 * np.arange(m)
    step = np.array([0.0, 0.01, 0.0])  # the rope moves 1 cm a frame
    cloud = _cloud(rope, rope + step, rope + 2 * step)
    state, p = blank_state(cloud, [0.1] * (m - 1))
    state.positions[0] = rope
    state.positions[1] = rope + step
    state.positions[1, 0] += [0.0, 0.0, 0.06]  # marker 0 invented 6 cm off
    state.invented[1, 0] = True
    state.temp_count[0] = 1
    state.cur[:] = rope + 2 * step
    state.known[:] = True
    state.taken[:] = 2 * m + np.arange(m)
    steps.commit_frame(state, 2, p)
    # not its own jump from the invented position (6 cm): its neighbour's 1 cm a frame
    np.testing.assert_allclose(state.velocity, np.broadcast_to(step, (m, 3)), atol=1e-12)
    assert state.temp_count[0] == 0 and not state.invented[2].any()


# slow with an empty numba cache: match_measured_best compiles as an entry point of its own
@pytest.mark.slow
def test_disputed_traces_keep_the_matching_nearer_its_predictions(steps) -> None:  # type: ignore[no-untyped-def]
    # a rope accelerating sideways (y 0, 2, 6 cm): V at 10 cm, the accelerated
    # prediction at 12 cm, where markers 0-2 are (3 and 4 hidden); beside V lie five
    # other points (a second arm of the rope): 1.2 cm from V for traces 0-2, 1.8 cm for
    # 3 and 4 (more than 1.5 γ from the accelerated prediction)
    m, gamma = 5, 0.03
    x = 0.12 * np.arange(m)
    history = [np.stack([x, np.full(m, y), np.zeros(m)], axis=1) for y in (0.0, 0.02, 0.06)]
    true = np.stack([x, np.full(m, 0.12), np.zeros(m)], axis=1)[:3]
    arm = np.stack([x, np.r_[[0.10] * 3, [0.09] * 2], np.r_[[0.012] * 3, [0.015] * 2]], axis=1)
    state, p = blank_state(_cloud(*history, np.concatenate([true, arm])), [0.12] * (m - 1))
    p = p._replace(gamma=gamma, retry_rounds=0)
    state.positions[:3] = history
    state.point_index[:3] = np.arange(3)[:, None] * m + np.arange(m)
    state.velocity[:] = history[2] - history[1]
    steps.match_measured_best(state, 3, state.positions[2] + state.velocity, p)
    # V finds five (three on the other arm), the accelerated prediction three: the three
    # traces both found lie 1.2 cm from V and on the mark of the accelerated one
    np.testing.assert_array_equal(state.known, [True, True, True, False, False])
    np.testing.assert_array_equal(state.taken[:3], 3 * m + np.arange(3))


def test_an_unconfirmed_return_keeps_its_own_jump(steps) -> None:  # type: ignore[no-untyped-def]
    # synthetic jump frames 81-90: a trace never measured is seated on a still body point
    # 7 cm from its temporary marker while the rope moves 1 cm a frame; given the rope's
    # velocity it would lie within γ of every next prediction and keep the wrong point
    m = 5
    rope = np.zeros((m, 3))
    rope[:, 0] = 0.1 * np.arange(m)
    step = np.array([0.0, 0.01, 0.0])
    body_point = rope[2] + [0.0, 0.0, 0.07]
    now = rope + 2 * step
    now[2] = body_point

    def velocity_after_return(*, measured_before: bool) -> np.ndarray:
        cloud = _cloud(rope, rope + step, now)
        state, p = blank_state(cloud, [0.1] * (m - 1))
        state.positions[0], state.positions[1] = rope, rope + step
        state.invented[1, 2] = True  # hidden in frame 1, invented on the rope
        state.invented[0, 2] = not measured_before
        state.temp_count[2] = 1 if measured_before else 2
        state.cur[:] = now
        state.known[:] = True
        state.taken[:] = 2 * m + np.arange(m)
        steps.commit_frame(state, 2, p)
        return state.velocity[2].copy()

    # unconfirmed (no measured link, 7 cm from the temporary marker moved by ṽ): its jump
    np.testing.assert_allclose(
        velocity_after_return(measured_before=False), body_point - (rope[2] + step), atol=1e-12
    )
    # measured in frame 0, but its links to 1 and 3 then differ by 7 cm: its jump too
    np.testing.assert_allclose(
        velocity_after_return(measured_before=True), body_point - (rope[2] + step), atol=1e-12
    )


@pytest.mark.parametrize(
    ("case", "taken"),
    [
        ("missed at V", False),  # trace 1's V lies 3.1 cm from the point, trace 2's 4.5
        ("hidden too", True),  # trace 1 was not measured in frame 0: no V of its own
        ("found", True),  # trace 1 found its point elsewhere this frame
        ("V far", True),  # trace 1's V lies 6.6 cm off: beyond the wide gate
        ("nearer own", True),  # trace 2 is predicted 2 cm from the point
    ],
)
def test_a_returning_trace_leaves_the_point_of_a_trace_missed_at_v(
    steps, case: str, taken: bool
) -> None:  # type: ignore[no-untyped-def]
    """Marker 1 moves 3.1 cm in a frame, just beyond γ of V; marker 2, hidden for two
    frames, is predicted on the curve 4.5 cm from marker 1's point. In the wide gate
    trace 2 does not take a point that lies nearer V of a trace measured in the frame
    before and not found yet (within the wide gate) than its own prediction."""
    prev = np.array([[0.0, 0, 0], [0.12, 0, 0], [0.24, 0, 0], [0.36, 0, 0]])
    q = prev[1] + [0.0, 0.031, 0.0]  # marker 1's point in frame 1
    p3 = np.array([0.24, 0.031, 0.0])  # marker 3, folded back to a spacing from q
    other = q + [0.0, 0.1, 0.0]  # where trace 1 is found in case "found"
    cloud = _cloud(prev, np.stack([prev[0], q, p3, other]))
    state, p = blank_state(cloud, [0.12, 0.12, 0.12], gamma=0.03)
    state.positions[0] = prev
    state.point_index[0] = [0, 1, 2, 3]
    state.temp_count[2] = 2
    state.invented[0, 2] = True
    state.known[:] = [True, False, False, True]
    state.taken[:] = [4, -1, -1, 6]
    state.cur[[0, 3]] = [prev[0], p3]
    if case == "hidden too":
        state.temp_count[1] = 1
        state.invented[0, 1] = True
    if case == "found":
        state.known[1], state.taken[1], state.cur[1] = True, 7, other
    if case == "V far":
        state.velocity[1] = [0.0, -0.035, 0.0]
    pred = np.zeros((4, 3))
    pred[2] = q + [0.02 if case == "nearer own" else 0.045, 0.0, 0.0]
    steps.match_traces(
        state, 1, np.array([2]), pred, True, np.zeros(state.known.size, dtype=bool), p
    )
    assert bool(state.known[2]) == taken
    if taken:
        assert state.taken[2] == 5
