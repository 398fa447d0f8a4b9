"""RopeSettings: checked once, stored as numbers, the keyword API of simulate_rope kept."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.synth.rope import jump_rope_hands, simulate_rope
from skincap.synth.rope_settings import RopeSettings


def test_default_particles_one_per_four_and_a_half_centimetres() -> None:
    assert RopeSettings().particles() == 64
    assert RopeSettings(length=0.05, marker_spacing=0.01).particles() == 3
    assert RopeSettings(n_particles=10).particles() == 10


def test_values_are_checked_and_stored_as_numbers() -> None:
    s = RopeSettings(length=3, substeps=np.int64(4), lay_direction=np.array([1, 0, 1]))
    assert isinstance(s.length, float) and type(s.substeps) is int
    assert s.lay_direction == (1.0, 0.0, 1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.length = 2.0  # type: ignore[misc]
    for bad, name in (
        ({"length": 0.0}, "length"),
        ({"marker_spacing": 3.0}, "marker_spacing"),
        ({"n_particles": 2}, "n_particles"),
        ({"substeps": 1.5}, "substeps"),
        ({"damping": -1.0}, "damping"),
        ({"gravity": float("nan")}, "gravity"),
        ({"floor": float("inf")}, "floor"),
        ({"lay_direction": (0.0, 2.0, 0.0)}, "lay_direction"),
    ):
        with pytest.raises(ValidationError, match=name):
            RopeSettings(**bad)


def test_settings_object_and_keywords_give_the_same_rope() -> None:
    hands = jump_rope_hands(30, 120.0)
    opts = {"length": 2.6, "substeps": 4, "settle_seconds": 0.2, "damping": 0.5}
    a = simulate_rope(hands, 120.0, seed=1, **opts)
    b = simulate_rope(hands, 120.0, RopeSettings(**opts), seed=1)
    assert a.particles.tobytes() == b.particles.tobytes()
    assert a.meta == b.meta
    with pytest.raises(TypeError, match="unexpected keyword argument 'stiffness'"):
        simulate_rope(hands, 120.0, stiffness=3.0)
