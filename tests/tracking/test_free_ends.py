"""A hidden free rope end moves as a loose end does (it keeps its velocity and is pulled
only by a taut link); a held one (a point that is not the rope's beside it) keeps F
(both step backends)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import blank_state
from skincap.tracking._numba_curve import drag_free_ends as drag_free_ends_numba
from skincap.tracking._numba_curve import end_is_free as end_is_free_numba
from skincap.tracking.curve import HELD_END_REACH, drag_free_ends, end_is_free
from skincap.types import PointCloud

SPACING = 0.1
M = 6


def _rope() -> np.ndarray:
    """(M, 3) a straight rope along x, marker 0 at the origin."""
    return np.stack([np.arange(M) * SPACING, np.zeros(M), np.full(M, 1.0)], axis=1)


@pytest.mark.parametrize("free", [end_is_free, end_is_free_numba])
def test_an_end_is_held_when_a_point_not_the_ropes_lies_within_reach(free) -> None:  # type: ignore[no-untyped-def]
    rope = _rope()
    hand = rope[0] + [0.0, -0.08, 0.0]
    far = rope[0] + [0.0, -3 * HELD_END_REACH, 0.0]
    points = np.vstack([rope, far])
    is_rope = np.r_[np.ones(M, bool), False]
    assert free(rope[0], points, is_rope, HELD_END_REACH)  # the rope's own points do not hold it
    points = np.vstack([rope, far, hand])
    assert not free(rope[0], points, np.r_[is_rope, False], HELD_END_REACH)
    assert free(rope[0], points, np.r_[is_rope, True], HELD_END_REACH)  # the rope took it


def _place(
    steps,
    frame1: np.ndarray,
    frame2: np.ndarray,
    extra1: np.ndarray,
    extra2: np.ndarray,
    frame0=None,
):  # type: ignore[no-untyped-def]
    """Marker 0 measured in frames 0 (``frame0``, default ``frame1``) and 1 and hidden in
    frame 2; ``extra`` are the points that are not the rope's. Returns the temporary
    marker place_invented gives it in frame 2."""
    f1 = np.vstack([frame1, extra1])
    f2 = np.vstack([frame2[1:], extra2])
    f0 = f1.copy()
    cloud = PointCloud(
        np.vstack([f0, f1, f2]), np.cumsum([0, len(f0), len(f1), len(f2)]), rate=100.0
    )
    state, p = blank_state(cloud, [SPACING] * (M - 1))
    state.positions[0] = frame1 if frame0 is None else frame0
    state.positions[1] = frame1
    state.point_index[1] = cloud.offsets[1] + np.arange(M)
    state.known[:] = np.arange(M) > 0
    state.cur[1:] = frame2[1:]
    state.taken[1:] = cloud.offsets[2] + np.arange(M - 1)
    pred = state.cur.copy()
    pred[0] = frame1[0]  # a prediction that did not move
    steps.place_invented(state, 2, pred, False, p)
    return state.cur[0].copy()


@pytest.mark.parametrize("drag", [drag_free_ends, drag_free_ends_numba])
def test_a_loose_end_keeps_going_until_its_link_pulls_it(drag) -> None:  # type: ignore[no-untyped-def]
    rope = _rope()
    known = np.arange(M) < M - 2  # the last two markers hidden
    runs = ~known
    spacing = np.full(M - 1, SPACING)
    prev = rope.copy()
    velocity = np.zeros((M, 3))
    velocity[M - 2 :] = [0.0, 0.02, 0.0]  # the end sideways, 2 cm a frame
    pred = rope.copy()
    pred[: M - 2] += [0.01, 0.0, 0.0]  # the measured part slides 1 cm towards the end
    out = drag(pred, known, prev, velocity, spacing, runs)
    # within reach of their inner neighbours: each keeps going at its own velocity
    np.testing.assert_allclose(out[M - 2 :], rope[M - 2 :] + [0.0, 0.02, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[: M - 2], pred[: M - 2], atol=0)
    # the measured part pulled 5 cm away: the links go taut, each end marker on the
    # sphere of the rest spacing around its inner neighbour, towards its own prediction
    pred[: M - 2] = rope[: M - 2] - [0.05, 0.0, 0.0]
    out = drag(pred, known, prev, velocity, spacing, runs)
    for j in (M - 2, M - 1):
        y = prev[j] + velocity[j] - out[j - 1]
        np.testing.assert_allclose(out[j], out[j - 1] + SPACING * y / np.linalg.norm(y), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out[M - 3 :], axis=0), axis=1), SPACING)
    # markers not in ``runs`` are left as they are
    out = drag(pred, known, prev, velocity, spacing, np.zeros(M, bool))
    np.testing.assert_array_equal(out, pred)


def test_a_hidden_free_end_lying_still_stays_while_the_rope_beside_it_turns(steps) -> None:  # type: ignore[no-untyped-def]
    """The rope turns about the end's neighbour and slides 1 cm towards the end: the
    end's link slackens, nothing pulls it, and a loose end lying still stays (carried
    with its neighbours it would turn with them, 4.5 cm here)."""
    rope = _rope()
    turn = Rotation.from_euler("z", 25, degrees=True)
    turned = turn.apply(rope - rope[1]) + rope[1] - [0.01, 0.0, 0.0]
    body = np.array([[0.0, -2.0, 0.0]])  # far from the end: it is free
    placed = _place(steps, rope, turned, body, body)
    np.testing.assert_allclose(placed, rope[0], atol=1e-12)


def test_a_hidden_free_end_swings_on_at_its_measured_velocity(steps) -> None:  # type: ignore[no-untyped-def]
    rope = _rope()
    swing = np.array([0.0, 0.0, 0.01])  # the whole rope moving 1 cm a frame
    body = np.array([[0.0, -2.0, 0.0]])
    placed = _place(steps, rope, rope + swing, body, body, frame0=rope - swing)
    np.testing.assert_allclose(placed, rope[0] + swing, atol=1e-12)
    # held (a body point beside it that does not move), it keeps F's place instead
    hand = rope[0] + [0.0, -0.06, 0.0]
    placed = _place(
        steps, rope, rope + swing, hand[None], np.array([[5.0, 5.0, 5.0]]), frame0=rope - swing
    )
    np.testing.assert_allclose(placed, rope[0], atol=1e-12)
