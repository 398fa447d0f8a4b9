"""The ``jumprope`` clip turns a simulated jump rope: the real chain, body to rope.

body (procedural, 6000 vertices) -> ``build_motion(body, "jumprope")`` -> the hands'
world positions by forward kinematics -> :func:`skincap.synth.rope.simulate_rope`.
"""

from __future__ import annotations

import numpy as np
import pytest

from skincap.geometry.kinematics import forward_kinematics
from skincap.synth.clips import HOLD_SECONDS, JUMP_HZ, find_landmarks
from skincap.synth.generate import hand_joints
from skincap.synth.inputs import build_body, build_motion
from skincap.synth.rope import RopeResult, simulate_rope

RATE = 120.0
N_FRAMES = 1000
#: The hands start the wind-up 0.6 s after the hold and skip steadily 2.5 s later.
STEADY = HOLD_SECONDS + 0.6 + 2.5


@pytest.fixture(scope="module")
def take() -> tuple[np.ndarray, np.ndarray, dict[str, int], RopeResult]:
    body = build_body("procedural", n_vertices=6000)
    motion = build_motion(body, "jumprope", frames=N_FRAMES)
    world = forward_kinematics(motion)[:, :, :3, 3]  # (T, J, 3)
    left, right = hand_joints(motion)
    hands = np.stack([world[:, right], world[:, left]], axis=1)  # rope's first end: right
    rope = simulate_rope(hands, RATE, mode="jump")
    return hands, world, find_landmarks(motion.skeleton), rope


def _rope_angle(hands: np.ndarray, rope: RopeResult) -> np.ndarray:
    """(T,) unwrapped angle of the rope's farthest point about the hands' axis, radians.

    0 = straight up, pi = straight down; it grows as the rope turns forward.
    """
    rel = rope.particles - hands.mean(axis=1)[:, None]
    radial = np.hypot(rel[..., 1], rel[..., 2])
    far = rel[np.arange(len(rel)), radial.argmax(axis=1)]
    return np.unwrap(np.arctan2(far[:, 2], far[:, 1]))


def test_the_hands_turn_the_rope_ten_times(take) -> None:
    hands, _, _, rope = take
    angle = _rope_angle(hands, rope)
    turns = (angle[-1] - angle[0]) / (2.0 * np.pi)
    assert turns >= 10.0
    # steady skipping: the rope follows the hands' rate
    t = np.arange(N_FRAMES) / RATE
    steady = t > STEADY + 0.5
    rate = np.diff(angle[steady]).sum() / (2.0 * np.pi) / (steady.sum() / RATE)
    assert rate == pytest.approx(JUMP_HZ, rel=0.08)
    assert rope.meta["max_length_error"] < 0.02
    # the hands are still during the hanging window and the rope hangs still
    hang = rope.meta["hang_frames"]
    assert np.ptp(hands[:hang], axis=0).max() == 0.0
    assert rope.meta["max_hang_speed"] < 0.01
    # T-pose: the hands 1.51 m apart; skipping: ~0.68 m apart
    span = np.linalg.norm(hands[:, 0] - hands[:, 1], axis=1)
    assert span[0] == pytest.approx(1.51, abs=0.02)
    assert 0.6 < span[t > STEADY].min() and span[t > STEADY].max() < 0.8


def test_rope_goes_over_the_head_and_under_the_feet(take) -> None:
    hands, world, lm, rope = take
    head_top = world[:, lm["head"], 1] + 0.12  # skull base + 12 cm: the crown
    mid = rope.particles[:, rope.particles.shape[1] // 2]
    low = rope.particles[:, :, 1].min(axis=1)
    high = rope.particles[:, :, 1].max(axis=1)
    period = int(round(RATE / JUMP_HZ))
    for a in range(int(STEADY * RATE), N_FRAMES - period, period):
        win = slice(a, a + period)
        assert low[win].min() < 0.03  # it sweeps the floor every turn
        assert high[win].max() > head_top[win].max() + 0.2
        near = np.abs(mid[win, 2] - world[win, lm["hips"], 2]) < 0.3
        assert (mid[win, 1][near] > head_top[win].max()).any()  # over the head
        assert (mid[win, 1][near] < 0.1).any()  # under the feet


def test_feet_are_in_the_air_when_the_rope_passes_under(take) -> None:
    hands, world, lm, rope = take
    angle = _rope_angle(hands, rope)
    t = np.arange(N_FRAMES) / RATE
    # frames where the rope's far point passes straight down (angle = pi mod 2 pi)
    down = np.nonzero(np.diff(np.floor((angle - np.pi) / (2.0 * np.pi))) > 0)[0] + 1
    down = down[t[down] > STEADY]
    assert len(down) >= 7
    for s in ("l", "r"):
        for key in ("foot", "toe"):
            j = lm[f"{key}_{s}"]
            lift = world[down, j, 1] - world[0, j, 1]
            assert lift.min() > 0.02, (key, s, lift)


def test_rope_clears_the_torso_and_head(take) -> None:
    """Without colliders the rope may cut through the body; these hands keep it clear."""
    hands, world, lm, rope = take
    p = rope.particles
    t = np.arange(N_FRAMES) / RATE

    def depth(a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
        """(T,) deepest penetration of any particle into a capsule a-b (T, 3), metres."""
        ab = b - a
        rel = p - a[:, None]
        s = np.clip(
            np.einsum("tpk,tk->tp", rel, ab) / np.maximum((ab * ab).sum(axis=1), 1e-12)[:, None],
            0.0,
            1.0,
        )
        dist = np.linalg.norm(rel - s[..., None] * ab[:, None], axis=2)
        return np.maximum(radius - dist.min(axis=1), 0.0)

    torso = depth(world[:, lm["hips"]] + [0, 0.08, 0], world[:, lm["neck"]] - [0, 0.05, 0], 0.11)
    head = depth(world[:, lm["head"]] + [0, 0.08, 0], world[:, lm["head"]] + [0, 0.08, 0], 0.09)
    moving = t > HOLD_SECONDS
    assert np.mean(torso[moving] > 0.0) < 0.05
    assert np.mean(head[moving] > 0.0) < 0.02
    steady = t > STEADY
    assert torso[steady].max() < 0.02
    # skipping steadily the rope passes under the feet, not through the legs
    for s in ("l", "r"):
        leg = depth(world[:, lm[f"thigh_{s}"]], world[:, lm[f"foot_{s}"]], 0.06)
        assert leg[steady].max() < 0.01
