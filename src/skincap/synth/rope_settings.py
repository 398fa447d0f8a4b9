"""The physical settings of the simulated rope (:func:`~skincap.synth.rope.simulate_rope`).

Defaults: a 2.8 m skipping rope of 60 g/m, stiff in stretch and soft in bending, solved in
8 substeps of 2 iterations per frame, above a floor at y = 0. Values are checked once,
when the object is built; numbers are stored as ``float`` (counts as ``int``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from skincap._arrays import check_count, check_finite, check_nonnegative, check_positive
from skincap.errors import ValidationError

__all__ = ["RopeSettings"]


@dataclass(frozen=True)
class RopeSettings:
    """How the rope is built and solved.

    Examples
    --------
    >>> RopeSettings(length=2.5, floor=None).n_particles is None
    True
    """

    length: float = 2.8
    """Rest length of the rope, metres (2.5-3 for a skipping rope)."""

    n_particles: int | None = None
    """Chain particles P (>= 3); None: one per ~4.5 cm (64 for 2.8 m)."""

    marker_spacing: float = 0.12
    """Arc length between tape markers, metres (0.10-0.15 in practice); the
    ``floor(length / marker_spacing)`` markers are centred on the rope."""

    hang_seconds: float = 0.5
    """Length of the hanging window at the start, seconds. The caller keeps the hands
    still there; a SkincapWarning is issued if they move more than 5 mm."""

    stretch_stiffness: float = 1.0e6
    """Spring constant of each chain segment, N/m (XPBD compliance = 1 / stiffness;
    ``inf`` makes the rope inextensible)."""

    bend_stiffness: float = 40.0
    """Spring constant between next-but-one particles, N/m (0 gives a limp chain)."""

    damping: float = 0.3
    """Velocity damping rate, 1/s (air drag; velocities decay as ``exp(-damping t)``)."""

    gravity: float = 9.81
    """Gravitational acceleration along -Y, m/s²."""

    substeps: int = 8
    """Solver substeps per frame."""

    iterations: int = 2
    """Constraint iterations per substep."""

    linear_density: float = 0.06
    """Rope mass per metre, kg/m (sets the particle masses the springs act on)."""

    rope_radius: float = 0.004
    """Rope radius for contacts, metres: particles stay this far from the floor and
    the colliders."""

    floor: float | None = 0.0
    """Floor height (y), metres; None for no floor."""

    floor_friction: float = 0.6
    """Coulomb friction coefficient of the floor (>= 0)."""

    settle_seconds: float = 3.0
    """Simulated time before frame 0, with the hands at their first positions and
    strong damping, so the take starts with the rope at rest."""

    lay_direction: Sequence[float] | None = None
    """Horizontal direction (3,) in which the rope's slack first lies on the floor
    before settling; None: -Z (behind the body) for "jump", +Z for "whip"."""

    def __post_init__(self) -> None:
        length = check_positive("length", self.length)
        spacing = check_positive("marker_spacing", self.marker_spacing)
        if spacing > length:
            raise ValidationError(
                f"marker_spacing: must not exceed the rope length {length} m, got {spacing}"
            )
        checked: dict[str, Any] = {
            "length": length,
            "marker_spacing": spacing,
            "hang_seconds": check_nonnegative("hang_seconds", self.hang_seconds),
            "stretch_stiffness": check_positive(
                "stretch_stiffness", self.stretch_stiffness, allow_inf=True
            ),
            "bend_stiffness": check_nonnegative(
                "bend_stiffness", self.bend_stiffness, allow_inf=True
            ),
            "damping": check_nonnegative("damping", self.damping),
            "gravity": check_finite("gravity", self.gravity),
            "substeps": check_count("substeps", self.substeps, minimum=1),
            "iterations": check_count("iterations", self.iterations, minimum=1),
            "linear_density": check_positive("linear_density", self.linear_density),
            "rope_radius": check_nonnegative("rope_radius", self.rope_radius),
            "floor": None if self.floor is None else check_finite("floor", self.floor),
            "floor_friction": check_nonnegative("floor_friction", self.floor_friction),
            "settle_seconds": check_nonnegative("settle_seconds", self.settle_seconds),
        }
        if self.n_particles is not None:
            checked["n_particles"] = check_count("n_particles", self.n_particles, minimum=3)
        if self.lay_direction is not None:
            lay = np.asarray(self.lay_direction, dtype=np.float64)
            if lay.shape != (3,) or not np.isfinite(lay).all():
                raise ValidationError(f"lay_direction: expected 3 finite numbers, got {lay!r}")
            if np.linalg.norm(lay - lay[1] * np.array([0.0, 1.0, 0.0])) < 1e-9:
                raise ValidationError("lay_direction: must have a horizontal component")
            checked["lay_direction"] = tuple(float(x) for x in lay)
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    def particles(self) -> int:
        """P: ``n_particles``, or one particle per ~4.5 cm of rope."""
        if self.n_particles is not None:
            return int(self.n_particles)
        return max(3, int(math.ceil(self.length / 0.045)) + 1)
