"""The settings of one synthetic capture: what is on the body, and how the cameras see it.

:class:`CaptureSettings` is passed down from :func:`~skincap.synth.generate.generate_capture`
to :func:`~skincap.synth.cameras.simulate_capture`; each reads the fields of its stage.
The defaults are a Park & Hodgins-like studio (12 cameras, 0.5 mm noise, a few ghosts
and swaps). Values are checked once, when the object is built.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from skincap.errors import ValidationError

__all__ = ["CaptureSettings"]


@dataclass(frozen=True)
class CaptureSettings:
    """Every option of a synthetic capture, with today's defaults.

    Examples
    --------
    >>> CaptureSettings(rope="jump", noise_mm=0.0).swap_rate
    0.05
    """

    markers: Literal["dense", "sparse"] = "dense"
    """Park & Hodgins' ~350-marker grid with its marker surface, or ~41 markers on
    bony landmarks (CMU-like labels)."""

    rope: Literal["none", "jump", "whip"] = "none"
    """A rope held in both hands (jump rope), in the right hand (whip), or none; its tape
    markers join the un-indexed capture and occlude body markers."""

    bulge: float = 1.0
    """Muscle bulge amplitude of the soft tissue (1 = realistic, 0 = off)."""

    jiggle: float = 1.0
    """Flesh jiggle amplitude of the soft tissue (1 = realistic, 0 = off)."""

    breathing: float = 1.0
    """Breathing amplitude of the soft tissue (1 = realistic, 0 = off)."""

    rope_length: float = 2.8
    """Rope length, metres."""

    rope_marker_spacing: float = 0.12
    """Distance between the rope's tape markers along it, metres."""

    n_cameras: int = 12
    """Cameras in the ring around the capture volume."""

    n_cameras_up: int = 2
    """How many of the ring's cameras sit low, aimed up (to see markers facing down)."""

    min_cameras: int = 2
    """Cameras that must see a marker for it to be reconstructed in a frame."""

    facing_limit_deg: float = 80.0
    """A camera sees a marker when the angle between the marker's normal and the
    direction to the camera is below this, degrees."""

    noise_mm: float = 0.5
    """Standard deviation of the Gaussian noise per coordinate of a reconstructed
    point, millimetres."""

    marginal_dropout: float = 0.1
    """Probability that a marker seen by exactly ``min_cameras`` cameras is still lost
    in a frame (a two-ray reconstruction is fragile): flicker."""

    confusion_distance: float = 0.025
    """Two reconstructed markers closer than this may be confused, metres."""

    confusion_share: float = 0.5
    """Probability that a confusion (a pair coming closer than ``confusion_distance``)
    breaks both trajectories."""

    swap_rate: float = 0.05
    """Probability that a confusion swaps the two trajectories instead: each fragment
    continues on the other marker."""

    ghost_rate: float = 0.1
    """Expected ghost tracks starting per frame."""

    ghost_frames: float = 3.0
    """Mean ghost length in frames (geometric distribution)."""

    extra_radius: float = 0.01
    """Radius of the capsules around the extra occluders (rope segments), metres."""

    def __post_init__(self) -> None:
        if self.markers not in ("dense", "sparse"):
            raise ValidationError(f"markers: expected 'dense' or 'sparse', got {self.markers!r}")
        if self.rope not in ("none", "jump", "whip"):
            raise ValidationError(f"rope: expected 'none', 'jump' or 'whip', got {self.rope!r}")
        for name, lo, hi in (
            ("noise_mm", 0.0, np.inf),
            ("marginal_dropout", 0.0, 1.0),
            ("confusion_distance", 0.0, np.inf),
            ("confusion_share", 0.0, 1.0),
            ("swap_rate", 0.0, 1.0),
            ("ghost_rate", 0.0, np.inf),
        ):
            val = getattr(self, name)
            if not (lo <= float(val) <= hi):
                raise ValidationError(f"{name}: expected a value in [{lo}, {hi}], got {val!r}")
        if float(self.ghost_frames) < 1:
            raise ValidationError(f"ghost_frames: expected >= 1, got {self.ghost_frames!r}")
        if int(self.min_cameras) < 1:
            raise ValidationError(f"min_cameras: expected >= 1, got {self.min_cameras!r}")
        lim = float(self.facing_limit_deg)
        if not 0 < lim <= 180:
            raise ValidationError(
                f"facing_limit_deg: expected (0, 180], got {self.facing_limit_deg!r}"
            )
