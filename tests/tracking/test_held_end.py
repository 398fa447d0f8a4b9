"""A hidden held end follows the hand that holds it (skincap.tracking._hand_*, issue #15)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import blank_state
from skincap.evaluate.gap_repair import crop_frames, gap_errors, hold_back_points
from skincap.evaluate.tracking import match_traces_to_truth, rope_tracker_from_truth
from skincap.io.c3d import read_c3d
from skincap.synth.real_capture import real_capture_with_rope
from skincap.tracking.init import init_rope
from skincap.tracking.tracker import track_rope
from skincap.types import PointCloud

STILL, FRAMES, RATE = 60, 110, 100.0
HIDDEN = slice(75, 95)


def _hand_take(hide: bool) -> tuple[PointCloud, np.ndarray, np.ndarray]:
    """A bent rope held at marker 0 by a hand of four markers; hand and rope turn
    together about a vertical axis 40 cm away and drift sideways after the still
    window. Returns the cloud, the rope's points of frame 0 and the true rope (T, 8, 3)."""
    angle = np.linspace(0.0, 1.4, 8)  # an arc of radius 0.3 m: 10 cm spacings, sharply bent
    rope = np.stack([0.3 * np.cos(angle), 1.2 + 0.3 * np.sin(angle), np.zeros(8)], axis=1)
    hand = rope[0] + np.array(
        [[0.04, 0.0, 0.03], [0.0, 0.05, -0.03], [0.06, 0.04, 0.0], [0.02, -0.06, 0.04]]
    )
    body = np.stack([np.linspace(-0.6, -0.3, 6), np.full(6, 0.9), np.full(6, 0.2)], axis=1)
    rigid = np.concatenate([rope, hand])  # (12, 3): they move together
    s = np.maximum(np.arange(FRAMES) - STILL, 0) / RATE  # (T,) s
    turn = Rotation.from_rotvec(np.outer(1.5 * s, [0.0, 1.0, 0.0]))  # 1.5 rad/s about y
    pivot = np.array([0.7, 1.2, 0.0])
    moved = np.stack([turn[i].apply(rigid - pivot) + pivot for i in range(FRAMES)])
    moved += (0.2 * s)[:, None, None] * np.array([0.0, 0.0, 1.0])
    frames = []
    for t in range(FRAMES):
        keep = np.ones(12, dtype=bool)
        if hide and HIDDEN.start <= t < HIDDEN.stop:
            keep[0] = False
        frames.append(np.concatenate([moved[t, keep], body]))
    counts = np.array([f.shape[0] for f in frames])
    cloud = PointCloud(
        points=np.concatenate(frames), offsets=np.concatenate([[0], np.cumsum(counts)]), rate=RATE
    )
    return cloud, np.arange(8), moved[:, :8]


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_hidden_held_end_moves_with_its_hand(backend: str) -> None:
    if backend == "numba":
        pytest.importorskip("numba")
    cloud, markers, truth = _hand_take(hide=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        track = track_rope(cloud, init_rope(cloud, markers=markers), backend=backend)
    j = int(np.argmin(np.linalg.norm(track.positions[0] - truth[0, 0], axis=1)))  # its trace
    assert j in (0, 7)
    assert track.invented[HIDDEN, j].all()
    err = np.linalg.norm(track.positions[HIDDEN, j] - truth[HIDDEN, 0], axis=1)
    # the hand turns 0.3 rad while the end is hidden: carried rigidly, not straight on
    assert err.max() < 0.005, err
    assert not track.invented[HIDDEN.stop :, j].any()


def _slipping_hand_take() -> tuple[PointCloud, np.ndarray, np.ndarray]:
    """A straight rope (8 markers, 10 cm apart) drifting sideways, held at marker 0 by a
    hand of four markers that also spins (4 rad/s) about a vertical axis 10 cm beside
    the end, so that their rigid motion would swing the end straight out along the
    rope, away from marker 1: the hand does not carry the rope (a wrist turning under
    a handle). Marker 0 hidden in ``HIDDEN``. Returns the cloud, the rope's points of
    frame 0 and the true rope (T, 8, 3)."""
    rope = np.stack([0.1 * np.arange(8), np.full(8, 1.2), np.zeros(8)], axis=1)
    hand = rope[0] + np.array(
        [[-0.07, 0.0, 0.03], [0.0, 0.08, -0.03], [-0.06, 0.05, 0.0], [0.0, -0.07, 0.05]]
    )  # 7-8 cm from the end: beyond the wide gate, so only the carry brings it near them
    body = np.stack([np.linspace(-0.6, -0.3, 6), np.full(6, 0.9), np.full(6, 0.5)], axis=1)
    s = np.maximum(np.arange(FRAMES) - STILL, 0) / RATE  # (T,) s
    drift = (0.3 * s)[:, None, None] * np.array([0.0, 0.0, 1.0])
    pivot = rope[0] + np.array([0.0, 0.0, 0.1])
    spin = Rotation.from_rotvec(np.outer(4.0 * s, [0.0, 1.0, 0.0]))
    hands = np.stack([spin[i].apply(hand - pivot) + pivot for i in range(FRAMES)]) + drift
    ropes = rope[None] + drift
    frames = []
    for t in range(FRAMES):
        keep = np.ones(8, dtype=bool)
        keep[0] = not (HIDDEN.start <= t < HIDDEN.stop)
        frames.append(np.concatenate([ropes[t, keep], hands[t], body]))
    counts = np.array([f.shape[0] for f in frames])
    cloud = PointCloud(
        points=np.concatenate(frames), offsets=np.concatenate([[0], np.cumsum(counts)]), rate=RATE
    )
    return cloud, np.arange(8), ropes


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_hand_that_would_stretch_the_rope_does_not_carry_the_end(backend: str) -> None:
    if backend == "numba":
        pytest.importorskip("numba")
    cloud, markers, truth = _slipping_hand_take()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        init = init_rope(cloud, markers=markers)
        track = track_rope(cloud, init, backend=backend)
    j = int(np.argmin(np.linalg.norm(track.positions[0] - truth[0, 0], axis=1)))
    assert j in (0, 7)
    inner = 1 if j == 0 else 6
    assert track.invented[HIDDEN, j].all()
    assert not track.invented[HIDDEN, inner].any()
    # the hand swings the carry out along the rope (8 cm over the gap): past the reach
    # the rope allows from marker 1 it is refused, and F keeps the end on the rope
    link = np.linalg.norm(track.positions[HIDDEN, j] - track.positions[HIDDEN, inner], axis=1)
    assert link.max() <= 0.1 + 0.4 * init.gamma + 1e-9, link
    err = np.linalg.norm(track.positions[HIDDEN, j] - truth[HIDDEN, 0], axis=1)
    assert err.max() < 0.01, err
    assert err.mean() < 0.003, err
    assert not track.invented[HIDDEN.stop :, j].any()


def test_the_carry_keeps_the_rope_to_the_measured_neighbour(steps) -> None:  # type: ignore[no-untyped-def]
    end = np.array([0.0, 1.0, 0.0])
    hand0 = end + np.array([[0.05, 0, 0], [0, 0.06, 0], [0, 0, 0.07], [0.03, 0.03, 0.0]])
    hand1 = hand0 + np.array([-0.08, 0.0, 0.0])  # the hand slid 8 cm out along the rope
    cloud = _two_frames(hand0, hand1, end)
    state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03)
    state.positions[0, 0] = end
    state.hand_index[0, :4] = np.arange(5, 9)  # frame 1's hand points
    state.hand_then[0, :4] = hand0
    steps_hand = _hand_module(steps)
    f_end = end + np.array([0.001, 0.0, 0.0])  # where F put it
    for nb, carried in ((end + [0.1, 0, 0], False), (end + [0.02, 0, 0], True)):
        state.known[:] = [False, True, False]  # marker 1 measured in frame 1 at nb
        state.cur[:] = 0.0
        state.cur[1] = nb
        state.cur[0] = f_end
        steps_hand.carry_with_hand(state, 1, state.cur, p)
        want = end + np.array([-0.08, 0.0, 0.0]) if carried else f_end
        np.testing.assert_allclose(state.cur[0], want, atol=1e-9)


def test_both_backends_carry_a_held_end_alike() -> None:
    pytest.importorskip("numba")
    cloud, markers, _ = _hand_take(hide=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = track_rope(cloud, init_rope(cloud, markers=markers), backend="numpy")
        b = track_rope(cloud, init_rope(cloud, markers=markers), backend="numba")
    np.testing.assert_array_equal(a.point_index, b.point_index)
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-9)


def _two_frames(hand0: np.ndarray, hand1: np.ndarray, end: np.ndarray) -> PointCloud:
    """Frame 0: the end, then the hand points; frame 1: the hand points only."""
    f0 = np.concatenate([end[None], hand0])
    return PointCloud(
        points=np.concatenate([f0, hand1]),
        offsets=np.array([0, f0.shape[0], f0.shape[0] + hand1.shape[0]]),
        rate=RATE,
    )


def test_hand_anchors_are_the_free_points_within_reach_and_follow_rigidly(steps) -> None:  # type: ignore[no-untyped-def]
    end = np.array([0.0, 1.0, 0.0])
    hand0 = end + np.array(
        [[0.05, 0, 0], [0, 0.06, 0], [0, 0, 0.07], [0.03, 0.03, 0.0], [0.5, 0, 0]]
    )
    rot = Rotation.from_rotvec([0.0, 0.0, 0.2])
    hand1 = rot.apply(hand0 - end) + end + np.array([0.005, 0.0, 0.0])
    cloud = _two_frames(hand0, hand1, end)
    state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03)
    # frame 0 committed with the end measured on point 0; frame 1: the end hidden.
    # Its anchors are frame 0's 4 free points within reach, followed into frame 1
    state.point_index[0] = [0, -1, -1]
    state.positions[0, 0] = end
    state.temp_count[:] = 0
    state.known[:] = False
    steps_hand = _hand_module(steps)
    steps_hand.seat_hand(state, 1, p)
    assert sorted(i for i in state.hand_index[0].tolist() if i >= 0) == [6, 7, 8, 9]
    np.testing.assert_allclose(  # where they were: not the far one (5)
        np.sort(state.hand_then[0, :4], axis=0), np.sort(hand0[:4], axis=0), atol=1e-12
    )
    assert (state.hand_index[1] == -1).all()  # trace 2 was not measured in frame 0
    seated = state.hand_index.copy()
    steps_hand.seat_hand(state, 1, p)  # again in the same frame: nothing changes
    np.testing.assert_array_equal(state.hand_index, seated)
    state.known[:] = False
    state.temp_count[:] = 0
    cur = np.zeros((3, 3))
    steps_hand.carry_with_hand(state, 1, cur, p)
    np.testing.assert_allclose(cur[0], end + np.array([0.005, 0.0, 0.0]), atol=1e-9)


def test_an_ambiguous_anchor_is_dropped(steps) -> None:  # type: ignore[no-untyped-def]
    end = np.array([0.0, 1.0, 0.0])
    hand0 = end + np.array([[0.05, 0, 0]])
    # frame 1: two points equally near the anchor's prediction: no evidence which it is
    hand1 = end + np.array([[0.05, 0.01, 0], [0.05, -0.01, 0]])
    cloud = _two_frames(hand0, hand1, end)
    state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03)
    state.point_index[0] = [0, -1, -1]
    state.positions[0, 0] = end
    steps_hand = _hand_module(steps)
    steps_hand.seat_hand(state, 1, p)  # seated on point 1, then dropped in frame 1
    assert (state.hand_index[0] == -1).all()
    np.testing.assert_allclose(state.hand_then[0, 0], hand0[0], atol=1e-12)


def test_a_measured_end_drops_its_hand_and_takes_none_while_measured(steps) -> None:  # type: ignore[no-untyped-def]
    end = np.array([0.0, 1.0, 0.0])
    hand0 = end + np.array([[0.05, 0, 0], [0, 0.06, 0]])
    cloud = _two_frames(hand0, hand0, end)
    state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03)
    state.point_index[0] = [0, -1, -1]
    state.positions[0, 0] = end
    steps_hand = _hand_module(steps)
    state.known[:] = [True, False, False]  # measured in frame 1: no hand work
    steps_hand.seat_hand(state, 1, p)
    assert (state.hand_index == -1).all()
    state.known[:] = False  # hidden after all (a refusal): seated from frame 0
    steps_hand.seat_hand(state, 1, p)
    assert sorted(i for i in state.hand_index[0].tolist() if i >= 0) == [3, 4]
    state.known[:] = [True, False, False]  # committed measured: the hand is dropped
    steps_hand.release_hand(state, 1, p)
    assert (state.hand_index == -1).all()


def _hand_module(steps):  # type: ignore[no-untyped-def]
    if steps.__name__.endswith("_numpy"):
        from skincap.tracking import _hand_numpy

        return _hand_numpy
    from skincap.tracking import _hand_numba

    return _hand_numba


@pytest.mark.slow
def test_a_hidden_held_end_follows_the_foot_on_real_motion(data_dir) -> None:
    """A jump rope held by both feet of a real take (c3d.org sample01): each held end
    held back 20 frames at eight starts. Carried with the foot it is 3.6 cm off on
    average, 16.7 cm at the worst start (F alone, pointing the end straight out from its
    last links where the rope bends at the foot: 8.6 cm, 45.7 cm). Not yet the issue's
    2 cm: the simulated end swings about the grip rather than turning with the foot,
    and a stamp (frame 151) loses the end before some gaps start."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = read_c3d(data_dir / "c3dorg_sample01_Eb015pr.c3d")
    take = real_capture_with_rope(m, rope="jump", hands=[["LFT1"], ["RFT1"]], seed=0)
    labels = [x for x in take.truth.labels if x.startswith("rope_")]
    truth = take.truth.positions[:, [take.truth.labels.index(x) for x in labels]]
    track = rope_tracker_from_truth(take.points, take.point_truth)
    errors = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = track(take.points)
        trace_of, _ = match_traces_to_truth(base.positions, base.invented, truth, max_distance=0.06)
        for end in (0, len(labels) - 1):
            (trace,) = np.flatnonzero(trace_of == end)
            for start in range(80, 400, 40):
                held, _ = hold_back_points(take.points, take.point_truth, [labels[end]], start, 20)
                result = track(crop_frames(held, start + 30))
                err = gap_errors(result.positions[:, [trace]], truth[:, [end]], start, 20)
                errors.append(float(err.mean()))
    errors_arr = np.asarray(errors)
    assert np.isfinite(errors_arr).all()
    assert errors_arr.max() < 0.2, errors
    assert errors_arr.mean() < 0.045, errors


@pytest.mark.parametrize(
    ("case", "taken"),
    [
        ("swung", True),  # swung 4.5 cm off the carry, 5 cm off V: searched for there
        ("hidden before", False),  # hidden since frame 1: no velocity of its own confirms it
        ("off its velocity", False),  # V (moving away) lies 9 cm from the point
        ("rope too far", False),  # marker 1 measured 30 cm off: beyond the rope's reach
        ("beyond the gate", False),  # 7 cm off the carry: beyond the wide gate (6 cm)
        ("hand marker", False),  # a point the rope did not take lay 1 cm off in frame 1
    ],
)
def test_an_end_gone_missing_is_searched_for_at_the_free_point_nearest_its_carry(
    steps, case: str, taken: bool
) -> None:  # type: ignore[no-untyped-def]
    """An end that swings about its grip (a foot stamping) lies 4-5 cm from where the
    hand's rigid motion carries it, beyond γ / 2, and its own velocity misses the new
    direction by more than γ. The search looks for it at the free point nearest the
    carry only when the end was measured in the frame before and that point lies within
    the wide gate of both the carry and V, within the rope's reach of the marker
    measured nearest the end, and continues no other point; else at F as before."""
    end = np.array([0.0, 1.0, 0.0])
    hand0 = end + np.array([[0.05, 0, 0], [0, 0.06, 0], [0, 0, 0.07], [0.03, 0.03, 0.0]])
    shift = np.array([0.0, -0.02, 0.01])
    f_end = end + np.array([0.12, 0.0, 0.0])  # F: straight out from the rope, far off
    off = np.array([-0.07 if case == "beyond the gate" else -0.045, 0.0, 0.0])
    point = end + shift + off
    far = end + np.array([0.3, 0.0, 0.0])
    f0 = np.concatenate([end[None], hand0])
    before = [point[None] - np.array([0.0, 0.01, 0.0])] if case == "hand marker" else []
    hidden = case == "hidden before"
    f1 = np.concatenate(([] if hidden else [end[None]]) + [hand0] + before)
    f2 = np.concatenate([hand0 + shift, point[None], far[None]])
    n0, n1 = f0.shape[0], f1.shape[0]
    cloud = PointCloud(
        points=np.concatenate([f0, f1, f2]),
        offsets=np.array([0, n0, n0 + n1, n0 + n1 + 6]),
        rate=RATE,
    )
    state, p = blank_state(cloud, [0.1, 0.1], gamma=0.03)
    state.positions[:2, 0] = end
    state.point_index[0] = [0, -1, -1]
    state.point_index[1] = [-1 if hidden else n0, -1, -1]
    if hidden:  # a temporary marker in frame 1, where it was last seen
        state.invented[1, 0] = True
        state.temp_count[0] = 1
    if case == "off its velocity":
        state.velocity[0] = [0.04, 0.0, 0.0]
    a2 = n0 + n1
    state.body[a2 : a2 + 4] = True  # the hand's markers are body points
    state.hand_index[0, :4] = np.arange(a2, a2 + 4)
    state.hand_then[0, :4] = hand0
    state.known[:] = False
    if case == "rope too far":  # marker 1 measured on the far point (and before)
        state.known[1] = True
        state.taken[1] = a2 + 5
        state.cur[1] = far
    pred = np.zeros((3, 3))
    pred[0] = f_end
    _hand_module(steps).search_with_hand(state, 2, pred, p)
    np.testing.assert_allclose(pred[0], point if taken else f_end, atol=1e-12)


@pytest.mark.slow
def test_no_rope_marker_in_the_cloud_goes_untracked_for_long_on_real_motion(data_dir) -> None:
    """A jump rope held by both feet of a real take (c3d.org sample01), nothing held
    back: no trace is invented for more than 8 frames in a row while its marker's point
    is in the cloud. The right foot stamps at frame 151 and the end held beside it
    swings 6 cm about its grip, beyond γ of both its velocity and the foot's rigid
    carry: missed there, the end and the three markers beside it were invented for
    20-28 frames."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = read_c3d(data_dir / "c3dorg_sample01_Eb015pr.c3d")
        take = real_capture_with_rope(m, rope="jump", hands=[["LFT1"], ["RFT1"]], seed=0)
        labels = [x for x in take.truth.labels if x.startswith("rope_")]
        truth = take.truth.positions[:, [take.truth.labels.index(x) for x in labels]]
        track = rope_tracker_from_truth(take.points, take.point_truth)(take.points)
    trace_of, _ = match_traces_to_truth(track.positions, track.invented, truth, max_distance=0.06)
    frame = take.points.frame_index
    point_truth = np.asarray(take.point_truth).astype(str)
    longest = {}
    for c, label in enumerate(labels):
        (trace,) = np.flatnonzero(trace_of == c)
        seen = np.zeros(take.points.n_frames, dtype=bool)
        seen[frame[point_truth == label]] = True
        missed = np.concatenate([[0], (track.invented[:, trace] & seen).astype(int), [0]])
        edges = np.flatnonzero(np.diff(missed))  # starts and ends of the missed runs
        longest[label] = int(np.max(edges[1::2] - edges[::2], initial=0))
    assert max(longest.values()) <= 8, longest


def test_the_zipper_looks_for_a_hidden_held_end_at_its_hand_carry(steps) -> None:  # type: ignore[no-untyped-def]
    # a rope bent 30 degrees at the hand: the zipper continues its measured links
    # straight on, 5.2 cm from where the hand carries the end hidden since frame 1; a
    # leg marker back from a dropout lies 0.5 cm from that straight-on prediction (kt
    # jump frame 965: Knee_Marker4 taken, and the trace rode the knee for ~500 frames)
    theta = np.radians(30.0)
    end = np.array([-0.1 * np.cos(theta), 1.0 + 0.1 * np.sin(theta), 0.0])
    rope0 = np.array([end, [0.0, 1.0, 0.0], [0.1, 1.0, 0.0], [0.2, 1.0, 0.0]])
    hand0 = end + np.array([[0.05, 0, 0], [0, 0.06, 0], [0, 0, 0.07], [0.03, 0.03, 0.0]])
    shift = np.array([0.0, 0.0, 0.01])  # rope and hand move 1 cm a frame together
    leg = np.array([[-0.1, 0.995, 0.0]]) + 2 * shift
    f0 = np.concatenate([rope0, hand0])
    f1 = np.concatenate([rope0[1:], hand0]) + shift  # the end hidden from frame 1
    f2 = np.concatenate([np.concatenate([rope0[1:], hand0]) + 2 * shift, leg])
    counts = [f0.shape[0], f1.shape[0], f2.shape[0]]
    cloud = PointCloud(
        points=np.concatenate([f0, f1, f2]),
        offsets=np.concatenate([[0], np.cumsum(counts)]),
        rate=RATE,
    )
    state, p = blank_state(cloud, [0.1, 0.1, 0.1], gamma=0.03)
    hand = _hand_module(steps)
    state.positions[0] = rope0
    state.point_index[0] = [0, 1, 2, 3]
    state.known[:] = [False, True, True, True]
    hand.seat_hand(state, 1, p)  # frame 1: the end goes missing and takes its hand
    state.positions[1] = rope0 + shift
    state.point_index[1] = [-1, 8, 9, 10]
    state.invented[1, 0] = True
    state.temp_count[0] = 1
    hand.follow_hand(state, 2, p)
    a = counts[0] + counts[1]
    state.known[:] = [False, True, True, True]  # frame 2: the end still hidden
    state.taken[1:] = [a, a + 1, a + 2]
    state.cur[:] = rope0 + 2 * shift
    pred = rope0 + 2 * shift + np.array([0.0, 0.1, 0.0])  # F, strayed 10 cm
    steps.match_missing(state, 2, pred, p)
    assert not state.known[0]  # the leg marker stays a body point
    # the zipper's prediction moved to the hand's carry, where the end is, held to γ
    rows, zpred = steps.zipper_predictions(state, p)
    tight = hand.zip_with_hand(state, 2, rows, zpred, p)
    assert tight.tolist() == [True, False, False, False]
    np.testing.assert_allclose(zpred[0], end + 2 * shift, atol=1e-9)
    state.temp_count[0] = 0  # an end that goes missing this frame keeps the zipper's
    assert not hand.zip_with_hand(state, 2, rows, zpred, p).any()
