"""The position-based-dynamics rope (Müller et al. 2007) used with real captures."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.synth.rope_pbd import simulate_rope_pbd

RATE = 120.0


def _still(frames: int, *points: tuple[float, float, float]) -> np.ndarray:
    hands = np.array(points, dtype=float)  # (H, 3)
    return np.repeat(hands[None], frames, axis=0)


def test_whip_hangs_straight_down_at_rest_spacing() -> None:
    rope = simulate_rope_pbd(_still(10, (0.0, 2.0, 0.0)), RATE, length=1.1, n_markers=11)
    assert rope.markers.shape == (10, 11, 3) and rope.labels[0] == "rope_00"
    # hanging still: straight below the hand, one marker every 10 cm, the last at the tip
    np.testing.assert_allclose(rope.markers[:, :, [0, 2]], 0.0, atol=1e-6)
    np.testing.assert_allclose(rope.markers[-1, :, 1], 2.0 - 0.1 * np.arange(1, 12), atol=2e-3)
    np.testing.assert_allclose(rope.marker_param, 0.1 * np.arange(1, 12))
    assert np.abs(np.diff(rope.markers, axis=0)).max() < 1e-4  # nothing moves


def test_jump_rope_sags_between_the_hands_and_ends_follow_them() -> None:
    t = np.arange(240) / RATE
    left = np.stack([0.4 + 0.1 * np.sin(6 * t), 1.0 + 0.05 * np.cos(9 * t), 0 * t], axis=1)
    right = left * [-1, 1, 1]
    hands = np.stack([left, right], axis=1)
    rope = simulate_rope_pbd(hands, RATE, mode="jump", length=2.0, n_markers=9, floor=0.0)
    np.testing.assert_allclose(rope.particles[:, 0], left, atol=1e-12)  # pinned exactly
    np.testing.assert_allclose(rope.particles[:, -1], right, atol=1e-12)
    assert rope.particles[..., 1].min() >= 0.0  # never through the floor
    assert rope.meta["simulator"] == "pbd" and rope.meta["max_length_error"] < 0.02
    assert rope.markers[0, 4, 1] < 0.5  # the middle hangs low


def test_a_jerked_hand_stretches_the_rope_only_a_little() -> None:
    """A hand that reverses at 10 m/s (a real fast take's hands): the rope keeps its length."""
    t = np.arange(360) / RATE
    # 0.5 m side to side three times a second: 9.4 m/s and 178 m/s², as CMU 85_02's hands
    hand = np.stack([0.5 * np.sin(2 * np.pi * 3.0 * t), 1.5 + 0 * t, 0 * t], axis=1)
    rope = simulate_rope_pbd(hand, RATE, length=1.1, n_markers=12)
    speed = np.linalg.norm(np.diff(hand, axis=0), axis=1).max() * RATE
    assert speed > 9.0
    assert rope.meta["max_length_error"] < 0.08
    np.testing.assert_allclose(rope.particles[:, 0], hand, atol=1e-12)
    assert np.isfinite(rope.markers).all()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mode": "swing"}, "mode"),
        ({"mode": "jump"}, "both hands"),
        ({"n_markers": 2}, "n_markers"),
        ({"length": -1.0}, "length"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ValidationError, match=match):
        simulate_rope_pbd(_still(5, (0.0, 1.0, 0.0)), RATE, **kwargs)


def test_hands_with_a_gap_are_refused() -> None:
    hands = _still(5, (0.0, 1.0, 0.0))
    hands[2, 0] = np.nan
    with pytest.raises(ValidationError, match="finite"):
        simulate_rope_pbd(hands, RATE)


def test_a_rope_laid_out_far_from_rest_opens_the_take_at_rest() -> None:
    """Hands low and apart over a floor (a seated performer's, pyomeca's): the rope,
    laid out along the floor before it settles, is still by frame 0 (it fell 40 cm in
    the still window when the settling stopped after a fixed second)."""
    hands = _still(40, (0.0, 0.06, 0.0), (0.5, 0.56, 0.0))
    rope = simulate_rope_pbd(hands, 100.0, mode="jump", length=2.8, n_markers=22, floor=0.05)
    moved = np.linalg.norm(rope.particles - rope.particles[:1], axis=2).max()
    assert moved < 1e-3
    assert rope.particles[..., 1].min() >= 0.05 - 1e-9


def _far_pairs_closer_than(markers: np.ndarray, distance: float) -> int:
    """How many markers of ``markers`` (R, 3) lie within ``distance`` of one two or
    more places along the rope."""
    d = np.linalg.norm(markers[:, None] - markers[None], axis=2)
    index = np.arange(markers.shape[0])
    far = np.abs(index[:, None] - index[None]) >= 2
    return int(np.count_nonzero(np.where(far, d, np.inf).min(axis=1) < distance))


def test_a_rope_held_at_a_foot_and_a_shin_opens_laid_in_an_open_loop() -> None:
    """Ends held one above the other near the floor (an OptiTrack walking take's foot
    and shin markers): the V start hung both arms along one vertical line and laid
    them on the floor on top of each other, the settled rope doubled with markers
    3 mm apart (the rope tracker's initial order then wrong from frame 0)."""
    hands = _still(40, (0.0, 0.38, 0.0), (0.01, 0.03, 0.0))
    rope = simulate_rope_pbd(hands, 160.0, mode="jump", length=2.8, n_markers=22, floor=0.0)
    spacing = 2.8 / 23
    first = rope.markers[0]
    assert _far_pairs_closer_than(first, 0.5 * spacing) == 0
    chords = np.linalg.norm(np.diff(first, axis=0), axis=1)
    assert chords.min() > 0.5 * spacing  # no link folded onto itself
    assert np.linalg.norm(rope.particles - rope.particles[:1], axis=2).max() < 1e-3


def test_a_start_in_two_arms_keeps_the_rest_spacing() -> None:
    """Hands at different heights: every link of the start laid in an open loop is the
    rest length (but the one across the low point, shorter), so no part of the rope
    starts stretched (the V's links are off by the height difference over P - 1)."""
    from skincap.synth.rope_pbd import _arms_start

    for b in ((0.5, 1.0, 0.0), (0.01, 0.65, 0.0), (0.3, 0.9, 0.2), (0.5, 1.5, 0.0)):
        held = np.array([(0.0, 1.5, 0.0), b])
        x = _arms_start(held, 47, 2.8 / 46)
        links = np.linalg.norm(np.diff(x, axis=0), axis=1)
        assert np.allclose(x[[0, -1]], held)
        assert np.count_nonzero(~np.isclose(links, 2.8 / 46, rtol=1e-9)) <= 1
        assert links.max() <= 2.8 / 46 * (1 + 1e-9)


def test_arms_held_apart_keep_their_lay_and_an_open_loop_is_not_stretched() -> None:
    from skincap.synth.rope_pbd import _arms_start, _hanging_start, _laid_on_floor

    rest = 2.8 / 46
    apart = _hanging_start(np.array([(0.0, 0.9, 0.0), (0.5, 0.9, 0.0)]), "jump", 47, rest)
    lay = np.array([0.0, 0.0, 1.0])
    # hands 0.5 m apart across the lay direction: an arm gap up to that changes nothing
    assert np.array_equal(_laid_on_floor(apart, 0.0, lay, 0.5), _laid_on_floor(apart, 0.0, lay))
    stacked = _arms_start(np.array([(0.0, 0.4, 0.0), (0.0, 0.02, 0.0)]), 47, rest)
    laid = _laid_on_floor(stacked, 0.0, lay, 0.36)
    assert laid[:, 1].min() >= 0.0
    assert np.linalg.norm(np.diff(laid, axis=0), axis=1).max() <= rest * (1 + 1e-9)
    across = laid[:, 0]  # side-to-side on the floor (the lay is +Z)
    assert across.max() - across.min() == pytest.approx(0.36)
    with pytest.raises(ValidationError, match="arm_gap"):
        simulate_rope_pbd(
            _still(3, (0, 1, 0), (0.5, 1, 0)), RATE, mode="jump", floor=0.0, arm_gap=-1
        )
