"""The rope tracker's per-frame steps on hand-made frames, each run on both backends."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import blank_state
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
        return bool(steps.match_traces(state, 1, np.array([row]), pred, False, p))

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
        return bool(steps.match_traces(state, 1, np.array([1]), pred, True, p))

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
        return bool(steps.match_traces(state, t, np.array([0]), pred, True, p))

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
    steps.learn_link_rest(state, p)
    # a longer chord raises the link; one beyond the stretch (1.1) stops there; a link
    # with an unmeasured end learns nothing
    np.testing.assert_allclose(state.link_rest, [0.105, 0.11, 0.1])
    state.cur[1] = [0.09, 0, 0]  # a shorter chord never lowers it
    steps.learn_link_rest(state, p)
    np.testing.assert_allclose(state.link_rest, [0.105, 0.11, 0.1])


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
