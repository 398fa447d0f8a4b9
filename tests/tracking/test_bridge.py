"""Bridging short runs of hidden inner traces (``bridge_hidden_runs``), on both backends."""

from __future__ import annotations

import numpy as np

from conftest import blank_state
from skincap.types import PointCloud

SPACING, GAMMA, M = 0.12, 0.03, 7
ROPE = np.stack([SPACING * np.arange(M), np.zeros(M), np.zeros(M)], axis=1)  # (7, 3) frame 0
# frame 1: markers 5 and 6 pulled in by 8 cm, markers 3 and 4 landed folded on the
# floor between 2 and 5: chords 8.9, 12 and 8.9 cm for 12 cm of rope (more than γ
# short), their predictions 1.5 γ above them
MEASURED = np.concatenate([ROPE[:3], ROPE[5:] - [0.08, 0.0, 0.0]])  # markers 0, 1, 2, 5, 6
LANDED = np.array([[0.32, 0.04, 0.0], [0.44, 0.04, 0.0]])  # markers 3, 4
MISS = np.array([0.0, 0.0, 1.5 * GAMMA])
OWN = np.array([7, 8, 9, 12, 13, 10, 11])  # each trace's point in frame 1


def _bridge(steps, extra=(), hidden=(3, 4), temp=3, body=(), beside=()):  # type: ignore[no-untyped-def]
    """Run ``bridge_hidden_runs`` on frame 1, whose points are markers 0, 1, 2, 5, 6,
    the two landed markers (points 7-13) and ``extra`` (14…); the traces ``hidden`` are
    missing for ``temp`` frames, the others measured; ``body`` indexes frame 1's body
    points; ``beside`` are points of frame 0 the rope did not take. Returns (found, state)."""
    frame0 = np.concatenate([ROPE, np.reshape(beside, (-1, 3))])
    frame1 = np.concatenate([MEASURED, LANDED, np.reshape(extra, (-1, 3))])
    n0, n1 = frame0.shape[0], frame1.shape[0]
    cloud = PointCloud(
        points=np.concatenate([frame0, frame1]),
        offsets=np.array([0, n0, n0 + n1], np.int64),
        rate=120.0,
    )
    state, p = blank_state(cloud, [SPACING] * (M - 1), gamma=GAMMA)
    state.positions[0] = ROPE
    state.point_index[0] = np.arange(M)
    state.temp_count[list(hidden)] = temp
    own = OWN - 7 + n0
    measured = np.setdiff1d(np.arange(M), hidden)
    state.known[measured] = True
    state.taken[measured] = own[measured]
    state.cur[measured] = cloud.points[own[measured]]
    state.body[[n0 + b for b in body]] = True
    pred = cloud.points[own].copy()
    pred[[3, 4]] += MISS
    return bool(steps.bridge_hidden_runs(state, 1, pred, p)), state, n0


def test_a_hidden_run_takes_the_chain_that_fits_between_its_ends(steps) -> None:  # type: ignore[no-untyped-def]
    # beyond γ of their predictions at chords more than γ short: every other search
    # refuses them; here the only chain within the rope's length of markers 2 and 5
    # (the swapped fold, marker 4's point for 3, is 20 cm from marker 2)
    found, state, n0 = _bridge(steps)
    assert found
    np.testing.assert_array_equal(state.taken, OWN - 7 + n0)
    np.testing.assert_array_equal(state.cur[[3, 4]], LANDED)
    # a point beyond the rope's reach of marker 2 changes nothing
    found, state, n0 = _bridge(steps, extra=[[0.6, 0.3, 0.0]])
    assert found and state.taken[3] == n0 + 5


def test_a_hidden_run_is_left_alone_when_two_chains_fit_alike(steps) -> None:  # type: ignore[no-untyped-def]
    # a second point 4 cm below marker 4 (6 cm from its prediction, its chord to
    # marker 5 shorter): the two chains cost within γ of each other, nothing says
    # which is the rope
    decoy = LANDED[1] - [0.0, 0.04, 0.0]
    found, state, _ = _bridge(steps, extra=[decoy])
    assert not found and not state.known[[3, 4]].any()
    # the same point as a body point is no candidate
    found, state, n0 = _bridge(steps, extra=[decoy], body=(7,))
    assert found and state.taken[4] == n0 + 6
    # nor where it stood in frame 0, a point the rope did not take, beside marker 4
    found, state, n0 = _bridge(steps, extra=[decoy], beside=[decoy])
    assert found and state.taken[4] == n0 + 6


def test_a_point_seen_beside_the_trace_as_another_object_is_refused(steps) -> None:  # type: ignore[no-untyped-def]
    # marker 4's landed point stood there in frame 0 too, apart from marker 4: a foot
    # marker the rope fell beside, not the rope
    assert not _bridge(steps, beside=[LANDED[1]])[0]


def test_only_short_inner_runs_missing_since_an_earlier_frame_are_bridged(steps) -> None:  # type: ignore[no-untyped-def]
    assert not _bridge(steps, temp=0)[0]  # steady traces: the matching's job
    # a single hidden marker between its two measured neighbours
    found, state, n0 = _bridge(steps, hidden=(3,))
    assert found and state.taken[3] == n0 + 5
    # its point a body point, the only other 14 cm from marker 2 (beyond the rest
    # length and the stretch allowance, 12 + 1.2 cm): nothing
    assert not _bridge(steps, extra=[[0.38, 0.0, 0.0]], hidden=(3,), body=(5,))[0]
    assert not _bridge(steps, hidden=(2, 3, 4))[0]  # a run of three
    # a run beside a held end (marker 1, between the end marker 0 and marker 2) lies
    # among hand markers: left to the other searches
    assert not _bridge(steps, hidden=(1,))[0]
