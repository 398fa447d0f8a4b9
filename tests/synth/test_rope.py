"""Tests of the simulated rope (skincap.synth.rope)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import SkincapWarning, ValidationError
from skincap.synth.rope import (
    RopeResult,
    jump_rope_hands,
    rope_occluders,
    simulate_rope,
    whip_hand,
)
from skincap.types import MarkerSet

RATE = 120.0
N_FRAMES = 1000


@pytest.fixture(scope="module")
def jump() -> tuple[np.ndarray, RopeResult]:
    hands = jump_rope_hands(N_FRAMES, RATE, seed=0)
    return hands, simulate_rope(hands, RATE, mode="jump", seed=0)


@pytest.fixture(scope="module")
def whip() -> tuple[np.ndarray, RopeResult]:
    hand = whip_hand(N_FRAMES, RATE, seed=0)
    return hand, simulate_rope(hand, RATE, mode="whip", seed=0)


def _relative_length_error(rope: RopeResult, length: float) -> np.ndarray:
    seg = np.linalg.norm(np.diff(rope.particles, axis=1), axis=2).sum(axis=1)
    return np.abs(seg / length - 1.0)


def _turns(hands: np.ndarray, rope: RopeResult) -> float:
    """Net turns of the rope about the axis through the hands (positive = forward)."""
    rel = rope.particles - hands.mean(axis=1)[:, None]
    radial = np.hypot(rel[..., 1], rel[..., 2])
    far = rel[np.arange(len(rel)), radial.argmax(axis=1)]
    angle = np.unwrap(np.arctan2(far[:, 2], far[:, 1]))
    return float((angle[-1] - angle[0]) / (2.0 * np.pi))


# ---------------------------------------------------------------------- length
def test_length_within_two_percent_both_modes(jump, whip) -> None:
    for _, rope in (jump, whip):
        err = _relative_length_error(rope, 2.8)
        assert err.max() < 0.02
        # The direct stretch solve does much better than the contract's 2 %.
        assert err.max() < 0.005
        assert rope.meta["max_length_error"] == pytest.approx(err.max())
        np.testing.assert_allclose(rope.chain_length(), 2.8, rtol=0.02)


@pytest.mark.parametrize("mode", ["jump", "whip"])
def test_length_under_vigorous_motion(mode: str) -> None:
    # Hands on 0.25 m circles at 3 turns/s (4.7 m/s) with a sudden start, plus jitter.
    n = 480
    t = np.arange(n) / RATE
    phase = 2.0 * np.pi * 3.0 * np.clip(t - 0.5, 0.0, None)
    circle = 0.25 * np.stack([np.zeros(n), np.sin(phase), 1.0 - np.cos(phase)], axis=1)
    jitter = np.random.default_rng(3).normal(scale=0.01, size=(n, 3)) * (t > 0.5)[:, None]
    base = np.array([[0.25, 1.0, 0.1], [-0.25, 1.0, 0.1]])
    hands = base[None] + (circle + jitter)[:, None, :]
    rope = simulate_rope(hands if mode == "jump" else hands[:, 0], RATE, mode=mode)
    assert np.isfinite(rope.particles).all()
    assert _relative_length_error(rope, 2.8).max() < 0.02


# ---------------------------------------------------------------------- hanging window
def test_still_hanging_window(jump, whip) -> None:
    for hands, rope in (jump, whip):
        hang = rope.meta["hang_frames"]
        assert hang == 60
        if hands.ndim == 3:
            assert np.ptp(hands[:hang], axis=0).max() == 0.0  # the caller's hands are still
        speed = np.linalg.norm(np.diff(rope.particles[:hang], axis=0), axis=2) * RATE
        assert speed.max() < 0.01  # m/s (the contract: a few cm/s)
        marker_speed = np.linalg.norm(np.diff(rope.markers[:hang], axis=0), axis=2) * RATE
        assert marker_speed.max() < 0.01
        assert rope.meta["max_hang_speed"] < 0.01
        # Hanging: nothing is above the hands, the lowest point rests on the floor.
        assert rope.particles[:hang, :, 1].max() <= hands[0].reshape(-1, 3)[:, 1].max() + 1e-6
        assert rope.particles[:hang, :, 1].min() == pytest.approx(0.004, abs=1e-3)


def test_held_ends_follow_the_hands(jump, whip) -> None:
    hands, rope = jump
    np.testing.assert_allclose(rope.particles[:, 0], hands[:, 0], atol=1e-12)
    np.testing.assert_allclose(rope.particles[:, -1], hands[:, 1], atol=1e-12)
    hand, rope = whip
    np.testing.assert_allclose(rope.particles[:, 0], hand, atol=1e-12)
    assert np.linalg.norm(rope.particles[:, -1] - hand, axis=1).max() > 1.0  # free end


# ---------------------------------------------------------------------- jump rope
def test_jump_rope_goes_over_the_head_and_under_the_feet(jump) -> None:
    hands, rope = jump
    turns = _turns(hands, rope)
    assert turns > 10.0  # ~1.8 turns/s once wound up
    mid = rope.particles[:, rope.particles.shape[1] // 2]
    low = rope.particles[:, :, 1].min(axis=1)
    high = rope.particles[:, :, 1].max(axis=1)
    period = int(round(RATE / 1.8))
    start = int(round((0.5 + 2.0) * RATE))  # after the hanging window and the wind-up
    for a in range(start, N_FRAMES - period, period):
        win = slice(a, a + period)
        # The rope's lowest point touches the floor every turn...
        assert low[win].min() < 0.02
        # ...and its highest point is far above the hands, over a 1.75 m head.
        assert high[win].max() > hands[win, :, 1].max() + 0.8
        assert high[win].max() > 1.9
        # Its middle passes over the head and under the feet (near z = 0).
        near = np.abs(mid[win, 2]) < 0.3
        assert (mid[win, 1][near] > 1.9).any()
        assert (mid[win, 1][near] < 0.1).any()


def test_turning_direction_follows_the_hands() -> None:
    hands = jump_rope_hands(600, RATE, seed=4)
    mirrored = hands.copy()
    mirrored[..., 2] = 0.24 - hands[..., 2]  # the same person turning backwards
    fwd = _turns(hands, simulate_rope(hands, RATE, lay_direction=[0, 0, -1]))
    back = _turns(mirrored, simulate_rope(mirrored, RATE, lay_direction=[0, 0, 1]))
    assert fwd > 4.0
    assert back < -4.0


# ---------------------------------------------------------------------- whip
def test_whip_free_end_moves(whip) -> None:
    hand, rope = whip
    end = rope.particles[:, -1]
    hang = rope.meta["hang_frames"]
    assert np.ptp(end[hang:], axis=0).max() > 1.0
    speed = np.linalg.norm(np.diff(end, axis=0), axis=1) * RATE
    assert speed.max() > 5.0  # the tip of a whip outruns the hand
    hand_speed = np.linalg.norm(np.diff(hand, axis=0), axis=1) * RATE
    assert speed.max() > 2.0 * hand_speed.max()
    assert (end[hang:, 1] > 0.05).mean() > 0.3  # it flies part of the time


def test_whip_free_end_falls_under_gravity() -> None:
    # The hand is high (the rope hangs clear of the floor), swings sideways for 0.4 s
    # and stops: the free end, thrown up, falls back to hang straight below the hand.
    n = int(5.0 * RATE)
    t = np.arange(n) / RATE
    u = np.clip((t - 0.5) / 0.4, 0.0, 1.0)
    hand = np.zeros((n, 3))
    hand[:, 1] = 4.0
    hand[:, 0] = 1.5 * (u - np.sin(2.0 * np.pi * u) / (2.0 * np.pi))
    rope = simulate_rope(hand, RATE, mode="whip", damping=1.0, floor=None)
    end = rope.particles[:, -1]
    np.testing.assert_allclose(end[0], [0.0, 4.0 - 2.8, 0.0], atol=0.01)
    stop = int(0.9 * RATE)
    peak = stop + int(np.argmax(end[stop:, 1]))
    assert end[peak, 1] > 1.2 + 0.3  # thrown up by the swing
    # It comes down: the height decreases from its peak and settles under the hand.
    assert end[peak:, 1].min() < end[peak, 1] - 0.3
    np.testing.assert_allclose(end[-1, 1], 4.0 - 2.8, atol=0.05)
    np.testing.assert_allclose(end[-1, 0], 1.5, atol=0.1)
    # Without gravity the same swing does not bring the end back down.
    weightless = simulate_rope(hand, RATE, mode="whip", damping=1.0, floor=None, gravity=0.0)
    assert weightless.particles[-1, -1, 1] > end[-1, 1] + 0.3


# ---------------------------------------------------------------------- markers
def test_markers_labels_order_spacing_count(jump) -> None:
    hands, rope = jump
    m = rope.markers.shape[1]
    assert m == math.floor(2.8 / 0.12) == 23
    assert rope.labels == [f"rope_{i:02d}" for i in range(m)]
    np.testing.assert_allclose(np.diff(rope.marker_param), 0.12)
    # centred on the rope
    assert rope.marker_param[0] == pytest.approx(2.8 - rope.marker_param[-1])
    # Neighbouring markers are one spacing apart along the rope (chords can only be
    # shorter, and only slightly where the rope bends).
    gaps = np.linalg.norm(np.diff(rope.markers, axis=1), axis=2)
    assert gaps.max() < 0.12 * 1.01
    assert np.median(gaps) > 0.119
    # Ordered from the first end: marker k sits at arc length marker_param[k].
    seg = rope.meta["segment_length"]
    for f in (0, 333, 999):
        p = rope.particles[f]
        arc = np.concatenate([[0.0], np.cumsum(np.full(len(p) - 1, seg))])
        expect = np.stack([np.interp(rope.marker_param, arc, p[:, k]) for k in range(3)], 1)
        np.testing.assert_allclose(rope.markers[f], expect, atol=1e-12)
    d_first = np.linalg.norm(rope.markers[:, 0] - hands[:, 0], axis=1)
    d_last = np.linalg.norm(rope.markers[:, -1] - hands[:, 0], axis=1)
    assert (d_first < d_last).all()


@pytest.mark.parametrize("spacing", [0.10, 0.15])
def test_marker_count_follows_spacing(spacing: float) -> None:
    hand = np.tile([0.0, 3.5, 0.0], (10, 1))
    rope = simulate_rope(hand, RATE, mode="whip", marker_spacing=spacing, settle_seconds=1.0)
    m = math.floor(2.8 / spacing + 1e-9)
    assert rope.markers.shape == (10, m, 3)
    assert len(rope.labels) == m
    gaps = np.linalg.norm(np.diff(rope.markers[-1], axis=0), axis=1)
    np.testing.assert_allclose(gaps, spacing, rtol=0.01)


def test_no_nan(jump, whip) -> None:
    for _, rope in (jump, whip):
        assert np.isfinite(rope.particles).all()
        assert np.isfinite(rope.markers).all()
        assert rope.particles.dtype == np.float64
        assert rope.particles.shape == (N_FRAMES, 64, 3)


def test_marker_set(jump) -> None:
    _, rope = jump
    ms = rope.marker_set()
    assert isinstance(ms, MarkerSet)
    assert ms.labels == rope.labels
    assert ms.rate == RATE
    np.testing.assert_array_equal(ms.positions, rope.markers)


# ---------------------------------------------------------------------- determinism
def test_determinism_by_seed() -> None:
    a = simulate_rope(jump_rope_hands(240, RATE, seed=7), RATE, seed=7)
    b = simulate_rope(jump_rope_hands(240, RATE, seed=7), RATE, seed=7)
    c = simulate_rope(jump_rope_hands(240, RATE, seed=7), RATE, seed=8)
    assert a.particles.tobytes() == b.particles.tobytes()
    assert a.markers.tobytes() == b.markers.tobytes()
    assert a.particles.tobytes() != c.particles.tobytes()
    assert (
        jump_rope_hands(300, RATE, seed=1).tobytes() == jump_rope_hands(300, RATE, seed=1).tobytes()
    )
    assert (
        jump_rope_hands(300, RATE, seed=1).tobytes() != jump_rope_hands(300, RATE, seed=2).tobytes()
    )
    assert whip_hand(300, RATE, seed=1).tobytes() == whip_hand(300, RATE, seed=1).tobytes()


# ---------------------------------------------------------------------- hand paths
def test_jump_rope_hands_shape_and_stillness() -> None:
    hands = jump_rope_hands(600, RATE, height=1.8, shoulder_width=0.42, hang_seconds=0.5)
    assert hands.shape == (600, 2, 3)
    assert np.ptp(hands[:60], axis=0).max() == 0.0
    assert np.ptp(hands[60:], axis=0).max() > 0.1
    # by the hips, left hand at +X, apart by 1.7 shoulder widths
    np.testing.assert_allclose(hands[0, :, 1], 0.53 * 1.8)
    np.testing.assert_allclose(hands[0, 0, 0] - hands[0, 1, 0], 1.7 * 0.42)
    # No jumps: hand speed stays human (< 4 m/s).
    speed = np.linalg.norm(np.diff(hands, axis=0), axis=2) * RATE
    assert speed.max() < 4.0
    # Steady skipping: wrist circles (~0.3 m across) after the wind-up.
    late = hands[int(3.0 * RATE) :, 0]
    assert np.ptp(late, axis=0).max() < 0.4


def test_whip_hand_shape() -> None:
    hand = whip_hand(300, RATE)
    assert hand.shape == (300, 3)
    assert np.ptp(hand[:60], axis=0).max() == 0.0
    assert np.ptp(hand[60:], axis=0).max() > 0.3


# ---------------------------------------------------------------------- colliders
def test_capsule_and_sphere_colliders_push_the_rope_out() -> None:
    # The hand holds the rope above a horizontal bar and then sweeps it over a ball.
    n = 360
    t = np.arange(n) / RATE
    hand = np.zeros((n, 3))
    hand[:, 1] = 3.0
    hand[:, 2] = 0.4 * np.sin(2.0 * np.pi * 0.5 * np.clip(t - 0.5, 0.0, None))
    bar = (np.array([-1.0, 2.4, 0.1]), np.array([1.0, 2.4, 0.1]), 0.15)
    ball_centre = np.zeros((n, 3))
    ball_centre[:, 1] = 1.2
    ball_centre[:, 2] = np.linspace(-0.2, 0.2, n)
    ball = (ball_centre, 0.3)
    rope = simulate_rope(hand, RATE, mode="whip", colliders=[bar, ball])
    p = rope.particles[:, 1:]  # free particles
    # distance to the bar axis (x from -1 to 1 covers the rope)
    d_bar = np.hypot(p[..., 1] - 2.4, p[..., 2] - 0.1)
    assert d_bar.min() > 0.15 + 0.004 - 0.01
    d_ball = np.linalg.norm(p - ball_centre[:, None], axis=2)
    assert d_ball.min() > 0.3 + 0.004 - 0.01
    # Without the colliders the rope passes right through both.
    free = simulate_rope(hand, RATE, mode="whip")
    q = free.particles[:, 1:]
    assert np.linalg.norm(q - ball_centre[:, None], axis=2).min() < 0.1
    assert np.hypot(q[..., 1] - 2.4, q[..., 2] - 0.1).min() < 0.05
    # The bar actually held the rope (it drapes over it rather than hanging straight).
    assert np.abs(free.particles[:60, :, 2]).max() < 0.05
    assert np.abs(rope.particles[:60, :, 2]).max() > 0.05
    assert _relative_length_error(rope, 2.8).max() < 0.02


def test_jump_rope_turns_around_a_capsule_body() -> None:
    # A standing body (torso, head, legs down to the ankles) inside the turning rope:
    # the rope keeps turning over the head and never enters the body.
    hands = jump_rope_hands(700, RATE, seed=2)
    body = [
        (np.array([0.1, 0.9, 0.0]), np.array([0.1, 0.17, 0.0]), 0.065),  # left leg
        (np.array([-0.1, 0.9, 0.0]), np.array([-0.1, 0.17, 0.0]), 0.065),  # right leg
        (np.array([0.0, 1.0, 0.0]), np.array([0.0, 1.45, 0.0]), 0.14),  # torso
        (np.array([0.0, 1.62, 0.0]), 0.11),  # head
    ]

    def clearance(particles: np.ndarray) -> np.ndarray:
        out = []
        for col in body:
            a, b = col[0], col[1] if len(col) == 3 else col[0]
            ab = b - a
            t = np.clip(((particles - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
            dist = np.linalg.norm(particles - (a + t[..., None] * ab), axis=2)
            out.append(dist.min() - col[-1])
        return np.array(out)

    rope = simulate_rope(hands, RATE, colliders=body)
    assert _turns(hands, rope) > 8.0
    assert clearance(rope.particles).min() > 0.004 - 0.01
    assert _relative_length_error(rope, 2.8).max() < 0.02
    # Without the body the same rope cuts through the torso.
    assert clearance(simulate_rope(hands, RATE).particles).min() < -0.03


# ---------------------------------------------------------------------- occluders
def test_rope_occluders(jump) -> None:
    _, rope = jump
    a, b, r = rope_occluders(rope.particles, radius=0.012)
    assert a.shape == b.shape == (N_FRAMES, 63, 3)
    assert r == 0.012
    np.testing.assert_array_equal(a[:, 1:], b[:, :-1])
    np.testing.assert_array_equal(a[:, 0], rope.particles[:, 0])
    np.testing.assert_array_equal(b[:, -1], rope.particles[:, -1])
    with pytest.raises(ValidationError):
        rope_occluders(np.zeros((3, 1, 3)))
    with pytest.raises(ValidationError):
        rope_occluders(rope.particles, radius=0.0)


# ---------------------------------------------------------------------- validation
def test_validation_errors() -> None:
    hands = jump_rope_hands(20, RATE)
    with pytest.raises(ValidationError, match="mode"):
        simulate_rope(hands, RATE, mode="lasso")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="hands"):
        simulate_rope(hands[:, 0], RATE, mode="jump")
    with pytest.raises(ValidationError, match="hands"):
        simulate_rope(np.zeros((20, 3, 3)), RATE, mode="whip")
    with pytest.raises(ValidationError, match="hands"):
        simulate_rope(np.zeros((0, 2, 3)), RATE)
    bad = hands.copy()
    bad[7, 1, 2] = np.nan
    with pytest.raises(ValidationError, match="frame 7"):
        simulate_rope(bad, RATE)
    far = hands.copy()
    far[5, 1, 0] = 5.0
    with pytest.raises(ValidationError, match="frame 5"):
        simulate_rope(far, RATE)
    with pytest.raises(ValidationError, match="rate"):
        simulate_rope(hands, 0.0)
    with pytest.raises(ValidationError, match="length"):
        simulate_rope(hands, RATE, length=-1.0)
    with pytest.raises(ValidationError, match="marker_spacing"):
        simulate_rope(hands, RATE, marker_spacing=3.0)
    with pytest.raises(ValidationError, match="n_particles"):
        simulate_rope(hands, RATE, n_particles=2)
    with pytest.raises(ValidationError, match="substeps"):
        simulate_rope(hands, RATE, substeps=0)
    with pytest.raises(ValidationError, match="colliders"):
        simulate_rope(hands, RATE, colliders=[(np.zeros((3, 3)), 0.1)])
    with pytest.raises(ValidationError, match="colliders"):
        simulate_rope(hands, RATE, colliders=[(np.zeros(3), np.ones(3), -0.1)])
    with pytest.raises(ValidationError, match="lay_direction"):
        simulate_rope(hands, RATE, lay_direction=[0.0, 1.0, 0.0])
    with pytest.raises(ValidationError, match="progress"):
        simulate_rope(hands, RATE, progress=3)  # type: ignore[arg-type]


def test_warns_when_hands_move_in_the_hanging_window() -> None:
    hands = jump_rope_hands(120, RATE, hang_seconds=0.0)
    with pytest.warns(SkincapWarning, match="hanging window"):
        simulate_rope(hands, RATE, hang_seconds=0.5, settle_seconds=0.5)


def test_whip_accepts_both_hand_shapes_and_progress() -> None:
    hands = jump_rope_hands(30, RATE)
    seen: list[float] = []
    a = simulate_rope(hands, RATE, mode="whip", settle_seconds=0.5, progress=seen.append)
    b = simulate_rope(hands[:, 0], RATE, mode="whip", settle_seconds=0.5)
    assert a.particles.tobytes() == b.particles.tobytes()
    assert seen[-1] == 1.0
    assert all(x <= y for x, y in zip(seen, seen[1:], strict=False))


def test_single_frame() -> None:
    rope = simulate_rope(jump_rope_hands(1, RATE), RATE, settle_seconds=0.5)
    assert rope.particles.shape == (1, 64, 3)
    assert rope.meta["hang_frames"] == 1


# ---------------------------------------------------------------------- property
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    mode=st.sampled_from(["jump", "whip"]),
    length=st.floats(1.5, 3.5),
    n_particles=st.integers(5, 80),
)
def test_random_hand_paths_keep_length(seed: int, mode: str, length: float, n_particles: int):
    # A smooth random walk of both hands (up to ~3 m/s), kept closer than the rope.
    rng = np.random.default_rng(seed)
    n = 90
    acc = rng.normal(scale=60.0, size=(n, 2, 3))
    vel = np.cumsum(acc, axis=0) / RATE
    vel -= vel.mean(axis=0)
    vel *= np.minimum(1.0, 3.0 / np.abs(vel).max())
    hands = np.array([[0.2, 1.0, 0.0], [-0.2, 1.0, 0.0]]) + np.cumsum(vel, axis=0) / RATE
    centre = hands.mean(axis=1, keepdims=True)
    hands = centre + (hands - centre) * np.minimum(
        1.0, 0.4 * length / np.linalg.norm(hands[:, :1] - hands[:, 1:], axis=2, keepdims=True)
    )
    rope = simulate_rope(
        hands if mode == "jump" else hands[:, 0],
        RATE,
        mode=mode,  # type: ignore[arg-type]
        length=length,
        n_particles=n_particles,
        hang_seconds=0.0,
        settle_seconds=0.5,
        seed=seed,
    )
    assert np.isfinite(rope.particles).all()
    assert _relative_length_error(rope, length).max() < 0.02
