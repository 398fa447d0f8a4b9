"""A run of traces matched one marker along the rope moves back (``unshift_chain``).

A rope sliding along itself by about a spacing in one frame (a whip jerked lengthwise)
can be matched with every trace on its neighbour's marker; the end marker is then left
free beside the chain, within γ of its trace's own prediction. Both backends.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import blank_state
from skincap.types import PointCloud

SPACING = 0.12
M = 6


def _frames(slide: float, extra: np.ndarray | None = None) -> tuple[PointCloud, np.ndarray]:
    """Frame 0: a straight rope along x; frame 1: the rope slid by ``slide`` along
    itself, its points shuffled, then ``extra`` points. Returns the cloud and the
    global index of each marker's point in frame 1."""
    rope0 = np.column_stack([SPACING * np.arange(M), np.ones(M), np.zeros(M)])
    rope1 = rope0 + [slide, 0.0, 0.0]
    order = np.random.default_rng(0).permutation(M)
    frame1 = rope1[order] if extra is None else np.concatenate([rope1[order], extra])
    where = M + np.argsort(order)  # marker j's point in frame 1
    points = np.concatenate([rope0, frame1])
    offsets = np.array([0, M, M + frame1.shape[0]], dtype=np.int64)
    return PointCloud(points, offsets, 120.0), where


def _state_matched(cloud: PointCloud, where: np.ndarray, rows: np.ndarray, markers: np.ndarray):  # type: ignore[no-untyped-def]
    """Frame 0 tracked exactly, moving by ``slide`` a frame; in frame 1 traces ``rows``
    took the points of ``markers``."""
    state, p = blank_state(cloud, [SPACING] * (M - 1), gamma=0.03)
    state.positions[0] = cloud.points[:M]
    state.velocity[:] = cloud.points[where[0]] - cloud.points[0]  # the slide, known
    state.known[rows] = True
    state.taken[rows] = where[markers]
    state.cur[rows] = cloud.points[where[markers]]
    return state, p


@pytest.mark.parametrize("from_end", [0, M - 1])
def test_a_run_matched_one_marker_along_moves_back(steps, from_end: int) -> None:  # type: ignore[no-untyped-def]
    cloud, where = _frames(0.11)
    inward = 1 if from_end == 0 else -1
    rows = np.arange(M)[np.arange(M) != M - 1 - from_end]  # the far end found nothing
    state, p = _state_matched(cloud, where, rows, rows + inward)  # each on its neighbour
    assert steps.unshift_chain(state, 1, p)
    assert state.known.all()
    np.testing.assert_array_equal(state.taken, where)
    np.testing.assert_allclose(state.cur, cloud.points[where], atol=0.0)


def test_a_rightly_matched_chain_stays(steps) -> None:  # type: ignore[no-untyped-def]
    # the last marker hidden, a point one spacing beyond the first end (a hand marker
    # beside the held end): the first trace is on its prediction, nothing moves
    beyond = np.array([[0.11 - SPACING, 1.0, 0.0]])
    cloud, where = _frames(0.11, extra=beyond)
    rows = np.arange(M - 1)
    state, p = _state_matched(cloud, where, rows, rows)
    assert not steps.unshift_chain(state, 1, p)
    np.testing.assert_array_equal(state.taken[rows], where[rows])
    assert not state.known[M - 1]


def test_a_shift_with_every_trace_found_or_the_free_point_off_spacing_stays(steps) -> None:  # type: ignore[no-untyped-def]
    cloud, where = _frames(0.11)
    rows = np.arange(M - 1)
    # every trace found (the tip took some point): no run ends in a trace not found
    state, p = _state_matched(cloud, where, np.arange(M), np.r_[rows + 1, 0])
    assert not steps.unshift_chain(state, 1, p)
    # the free point within γ of the first trace's prediction but not at its link's
    # rest length from the point it took: a link of 2.5 spacings
    state, p = _state_matched(cloud, where, rows[:-1], rows[:-1] + 2)
    assert not steps.unshift_chain(state, 1, p)
