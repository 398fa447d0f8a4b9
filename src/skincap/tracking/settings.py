"""The rope tracker's tuning constants, as one frozen object (:class:`TrackSettings`).

γ (the search radius) and ``maxTempMarkers`` come from the initialisation
(:class:`~skincap.tracking.init.RopeInit`); everything else the per-frame steps use
is here, with the values the tracker was tuned with as defaults. Distances are in
units of γ or of the rope's rest spacings, so the same settings serve any rope.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from skincap.errors import ValidationError
from skincap.tracking.body_points import _RIGID_PARTNERS, _RIGID_RADIUS, _RIGID_RANGE

__all__ = ["TrackSettings"]


@dataclass(frozen=True)
class TrackSettings:
    """How :func:`~skincap.tracking.tracker.track_rope` searches and invents, frame by frame.

    Every field beyond ``candidates`` is a mechanism beyond Porter (2012); see
    :mod:`skincap.tracking.tracker` for what each one is for.

    Examples
    --------
    >>> TrackSettings(settle=0.0).settle  # invented lone markers left on the curve
    0.0
    """

    candidates: int = 3
    """Nearest points per trace handed to the one-to-one assignment (before those
    already taken this frame are added back)."""

    retry_rounds: int = 3
    """Rounds of the second chance for measured traces not found at V: V corrected by
    the prediction errors of the traces found, interpolated along the rope."""

    wide_gate: float = 2.0
    """Gate of the second-chance, curve/F and zipper searches, in γ. Beyond γ a point
    is taken there only at its rest spacing (± γ) from a measured neighbour."""

    stretch: float = 1.1
    """Two measured markers ``a < b`` that are not neighbours lie at most
    ``stretch (s_b - s_a) + γ`` apart (a rope does not stretch)."""

    adjacent_stretch: float = 0.4
    """Two neighbouring measured markers lie at most their rest spacing plus this many
    γ apart (a body point beside the rope sits farther)."""

    body_chain_gate: float = 1.0 / 3.0
    """Gate of the body chains, in γ: a point continues a body point of the previous
    frame when it lies this close to where that point's velocity takes it."""

    rigid_window_s: float = 0.25
    """Window of the rigidity test (a point moving rigidly with body points), seconds."""

    rigid_move: float = 0.3
    """The rigidity test needs the point to move this many rest spacings in its
    window (a still point moves "rigidly" with everything still)."""

    rigid_radius: float = _RIGID_RADIUS
    """Partners of the rigidity test are searched within this many rest spacings."""

    rigid_range: float = _RIGID_RANGE
    """A partner keeps its distance within this many rest spacings (and is followed
    back to points within this many spacings of its prediction)."""

    rigid_partners: int = _RIGID_PARTNERS
    """Rigid partners that make a point body-like."""

    zipper_rounds: int = 3
    """Rounds of the zipper: a run of invented inner markers is searched from its
    measured ends inward, one marker per side and round."""

    swing_gate: float = 0.5
    """When the matching at V leaves a steady trace unfound or farther than this many
    γ from V, and some trace's acceleration moves V by more than this many γ, the
    steady traces are matched again at their accelerated prediction (V plus the last
    change of velocity) and the matching that finds more traces is kept. A swinging
    rope's markers move on curves: constant velocity misses them by several γ."""

    lone_after: int = 20
    """An inner trace missing this many frames takes the only free point on the shell
    around a measured neighbour, whatever its direction (a rope end dragged along the
    floor while hidden folds its links far from the previous frame's): the
    re-acquisition otherwise looks only within 60° of the previous link. Not the
    end traces, held among hand markers."""

    settle: float = 0.5
    """Share of the way a lone invented inner marker moves from the curve to its rest
    spacings from both neighbours (0: stays on the curve, which cuts a sharp bend)."""

    carry_tolerance: float = 0.05
    """A hidden marker between measured markers is also carried from where it was last
    seen by the rigid motion of its nearest measured neighbours
    (:func:`~skincap.tracking.curve.carry_last_seen`); the fit residual, in median
    rest spacings, at which that and the curve weigh the same. 0 turns the carry off."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "int":
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ValidationError(f"{f.name}: expected an int, got {type(value).__name__}")
                least = 1 if f.name in ("candidates", "rigid_partners") else 0
                if value < least:
                    raise ValidationError(f"{f.name}: expected at least {least}, got {value}")
            else:
                if isinstance(value, bool) or not isinstance(value, int | float):
                    raise ValidationError(
                        f"{f.name}: expected a number, got {type(value).__name__}"
                    )
                if not math.isfinite(value) or value < 0:
                    raise ValidationError(f"{f.name}: expected a finite number >= 0, got {value}")
        if not self.wide_gate >= 1.0:
            raise ValidationError(f"wide_gate: expected at least 1 (γ), got {self.wide_gate}")
        if not self.settle <= 1.0:
            raise ValidationError(f"settle: expected a share in [0, 1], got {self.settle}")
