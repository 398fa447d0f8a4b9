"""A hidden free rope end is carried with the rigid motion of its rope neighbours; a held
one (a point that is not the rope's beside it) keeps F (both step backends)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import blank_state
from skincap.tracking._numba_curve import end_is_free as end_is_free_numba
from skincap.tracking.curve import HELD_END_REACH, end_is_free
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


def _place(steps, frame1: np.ndarray, frame2: np.ndarray, extra1: np.ndarray, extra2: np.ndarray):  # type: ignore[no-untyped-def]
    """Marker 0 measured in frame 1 and hidden in frame 2; ``extra`` are the points that
    are not the rope's. Returns the temporary marker place_invented gives it in frame 2."""
    f1 = np.vstack([frame1, extra1])
    f2 = np.vstack([frame2[1:], extra2])
    f0 = f1.copy()
    cloud = PointCloud(
        np.vstack([f0, f1, f2]), np.cumsum([0, len(f0), len(f1), len(f2)]), rate=100.0
    )
    state, p = blank_state(cloud, [SPACING] * (M - 1))
    state.positions[0] = frame1
    state.positions[1] = frame1
    state.point_index[1] = cloud.offsets[1] + np.arange(M)
    state.known[:] = np.arange(M) > 0
    state.cur[1:] = frame2[1:]
    state.taken[1:] = cloud.offsets[2] + np.arange(M - 1)
    pred = state.cur.copy()
    pred[0] = frame1[0]  # a prediction that did not move
    steps.place_invented(state, 2, pred, False, p)
    return state.cur[0].copy()


def test_a_hidden_free_end_turns_with_its_neighbours(steps) -> None:  # type: ignore[no-untyped-def]
    rope = _rope()
    turn = Rotation.from_euler("z", 25, degrees=True)
    turned = turn.apply(rope - rope[-1]) + rope[-1]  # the rope swings about its far end
    body = np.array([[0.0, -2.0, 0.0]])  # far from the end: it is free
    placed = _place(steps, rope, turned, body, body)
    np.testing.assert_allclose(placed, turned[0], atol=1e-9)
    # held (a body point beside it that does not move), it keeps F's place instead
    hand = rope[0] + [0.0, -0.06, 0.0]
    placed = _place(steps, rope, turned, hand[None], np.array([[5.0, 5.0, 5.0]]))
    np.testing.assert_allclose(placed, rope[0], atol=1e-12)
