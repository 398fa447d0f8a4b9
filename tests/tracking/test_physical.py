"""Invented rope samples stay where the rope's length allows (issue #15, item 3)."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.tracking.physical import STRETCH_ALLOWANCE, bound_invented, physics_excess


def _straight(frames: int, markers: int, spacing: float) -> np.ndarray:
    x = np.zeros((frames, markers, 3))
    x[:, :, 0] = spacing * np.arange(markers)
    return x


def test_wild_extrapolations_are_pulled_back_within_the_rope() -> None:
    rng = np.random.default_rng(1)
    t, m, gap = 60, 12, 0.1
    truth = _straight(t, m, gap)
    invented = rng.random((t, m)) < 0.35
    invented[:, 3:6] = True  # a run of three hidden markers
    wild = truth.copy()
    wild[invented] += rng.normal(scale=5.0, size=(int(invented.sum()), 3))  # metres away
    spacing = np.full(m - 1, gap)
    assert np.nanmax(physics_excess(wild, invented, spacing)) > 5.0

    bounded, moved = bound_invented(wild, invented, spacing)
    # measured samples never move; every invented one is within reach of the others
    np.testing.assert_array_equal(bounded[~invented], wild[~invented])
    ok = np.isfinite(bounded).all(axis=2)
    assert ok.all()  # a measured marker in every frame: nothing is NaN
    excess = physics_excess(bounded, invented, spacing, stretch=STRETCH_ALLOWANCE)
    assert np.nanmax(excess) <= 1e-3
    # never farther from a measured marker than the rope between them (+10 %) allows
    s = gap * np.arange(m)
    for j in range(m):
        d = np.linalg.norm(bounded[:, j : j + 1] - bounded, axis=2)
        limit = 1.1 * np.abs(s[j] - s)[None, :] + 1e-3
        check = invented[:, j : j + 1] & ~invented & ok[:, j : j + 1]
        assert (d[check] <= np.broadcast_to(limit, d.shape)[check]).all()
    assert moved[invented].mean() > 0.9 and not moved[~invented].any()


def test_physical_samples_are_left_alone() -> None:
    x = _straight(10, 8, 0.12)
    x[:, 4, 1] += 0.02  # a bent rope is fine
    invented = np.zeros((10, 8), dtype=bool)
    invented[:, 4] = True
    bounded, moved = bound_invented(x, invented, np.full(7, 0.12))
    np.testing.assert_array_equal(bounded, x)
    assert not moved.any()


def test_an_invented_end_stays_within_the_rope_length_of_the_held_end() -> None:
    x = _straight(3, 5, 0.1)
    invented = np.zeros((3, 5), dtype=bool)
    invented[:, 1:] = True  # only the held end is seen
    x[:, 4] = [40.0, 0.0, 0.0]  # the tip extrapolated 40 m away
    bounded, _ = bound_invented(x, invented, np.full(4, 0.1))
    reach = np.linalg.norm(bounded[:, 4] - bounded[:, 0], axis=1)
    assert (reach <= 1.1 * 0.4 + 1e-3).all()


def test_bad_shapes_are_named() -> None:
    with pytest.raises(ValidationError, match="spacing"):
        bound_invented(np.zeros((2, 3, 3)), np.zeros((2, 3), bool), np.ones(3))
    with pytest.raises(ValidationError, match="invented"):
        bound_invented(np.zeros((2, 3, 3)), np.zeros((2, 4), bool), np.ones(2))


def test_a_frame_with_nothing_measured_is_not_extrapolated() -> None:
    x = _straight(4, 5, 0.1)
    invented = np.zeros((4, 5), dtype=bool)
    invented[2] = True  # the whole rope unseen in frame 2
    x[2] += 12.0  # extrapolated 12 m away, the rope intact
    bounded, moved = bound_invented(x, invented, np.full(4, 0.1))
    assert np.isnan(bounded[2]).all() and moved[2].all()
    np.testing.assert_array_equal(bounded[[0, 1, 3]], x[[0, 1, 3]])


@pytest.mark.parametrize("sweeps", [1, 3, 20])
def test_each_frame_is_bounded_as_if_alone(sweeps: int) -> None:
    # frames converge after different numbers of sweeps (a converged frame leaves the
    # work): the take bounded at once equals each frame bounded on its own, bit for bit
    rng = np.random.default_rng(7)
    t, m, gap = 40, 10, 0.1
    wild = _straight(t, m, gap)
    invented = rng.random((t, m)) < 0.4
    invented[::5] = False  # frames with nothing to bound
    invented[3, :-1] = True  # one measured marker: the others all pulled onto it
    scale = rng.choice([0.01, 0.3, 4.0], size=(t, 1, 1))  # near, far, very far
    wild = wild + np.where(invented[:, :, None], rng.normal(size=(t, m, 3)) * scale, 0.0)
    spacing = np.full(m - 1, gap)
    bounded, moved = bound_invented(wild, invented, spacing, sweeps=sweeps)
    for f in range(t):
        alone, alone_moved = bound_invented(
            wild[f : f + 1], invented[f : f + 1], spacing, sweeps=sweeps
        )
        np.testing.assert_array_equal(bounded[f], alone[0])
        np.testing.assert_array_equal(moved[f], alone_moved[0])
    assert moved.any() and not moved.all()
