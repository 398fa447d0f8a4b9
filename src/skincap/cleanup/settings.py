"""The cleanup's settings: one frozen dataclass per stage, and :class:`CleanSettings` for all.

Each stage function takes one settings object (``merge_fragments(..., MergeSettings())``,
``find_hidden_markers(..., HiddenSettings())``, ``fill_gaps(..., FillSettings())``,
``clean_markers(..., CleanSettings())``) instead of a pile of keyword options, so the
pipeline, the CLI and a batch runner pass the same object. Defaults are the values the
cleanup was tuned with; each field's docstring says what it does. The values are checked
when the object is made (:class:`~skincap.errors.ValidationError`), so a bad setting fails
before any work starts. Change a field with :func:`dataclasses.replace`.

This module imports nothing heavy, so the CLI can build settings before numpy loads.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from skincap.cleanup.methods import FILL_METHODS, FillMethod
from skincap.errors import ValidationError

__all__ = ["MergeSettings", "HiddenSettings", "FillSettings", "SmoothSettings", "CleanSettings"]


@dataclass(frozen=True)
class MergeSettings:
    """How fragments merge into markers (Park & Hodgins 2006 §4.2; :func:`merge_fragments`).

    Distances are in units of a marker's neighbour spacing ``d̄`` (eq. 3).
    """

    alpha1: float = 0.5
    """α¹ of eq. 3: in its first frame a fragment lies within ``α¹ d̄`` of the estimate."""
    alpha2: float = 0.6
    """α² of eq. 3: in every frame it spans it lies within ``α² d̄`` of the estimate."""
    ambiguity_ratio: float = 0.7
    """A fragment matching two markers joins the closer only when its mean distance is
    below this fraction of the other's; otherwise it waits. In (0, 1]."""
    rival_ratio: float = 0.2
    """With ``neighbour_check``: the margin by which the marker's neighbourhood fit must
    explain the fragment better than the nearest missing rival (see
    :func:`~skincap.cleanup.merge.merge_fragments`). In (0, 1]."""
    calibrate: bool = True
    """With ``neighbour_check``: predict the marker from where its neighbourhood puts it
    across the frames it was measured in, not from its reference-pose position alone."""
    short_frames: int = 4
    """A fragment shorter than this needs a proportionally larger margin and a marker
    its neighbours predict within a fifth of its spacing (ghosts are short)."""
    max_passes: int = 10
    """Estimate-and-merge passes at most (they stop earlier when nothing merges)."""
    temporal: bool = True
    """Estimate missing markers from the neighbourhood shape in the frames bracketing
    each gap instead of the reference pose alone (fewer wrong merges at creases)."""
    robust_spacing: bool = True
    """Scale ε¹ and ε² by the median neighbour distance instead of the paper's mean."""
    neighbour_check: bool = True
    """Beyond the paper: refuse a fragment that lies nearly as close to where one of the
    marker's missing neighbours should be as to the marker."""
    prediction_factor: float | None = 2.0
    """Beyond the paper: a fragment's mean distance to the neighbourhood fit's prediction
    stays within this many times the fit's usual error for the marker. None: off."""
    min_frames: int = 2
    """Fragments shorter than this stay unmerged (the hole filler fills their samples)."""

    def __post_init__(self) -> None:
        if not (
            0 < self.alpha1
            and 0 < self.alpha2
            and 0 < self.ambiguity_ratio <= 1
            and 0 < self.rival_ratio <= 1
            and self.short_frames >= 1
            and self.max_passes >= 1
            and self.min_frames >= 1
        ):
            raise ValidationError(
                "need alpha1 > 0, alpha2 > 0, 0 < ambiguity_ratio <= 1, 0 < rival_ratio <= 1, "
                "short_frames >= 1, max_passes >= 1, min_frames >= 1"
            )


@dataclass(frozen=True)
class HiddenSettings:
    """How markers hidden in the reference frame are found among leftover fragments
    (:func:`~skincap.cleanup.hidden.find_hidden_markers`).

    Distances are in units of the fragment's neighbourhood's median spacing.
    """

    k: int = 8
    """Markers in a fragment's neighbourhood (at least 3)."""
    min_frames: int = 10
    """Shorter leftover columns are not considered (at least 1)."""
    max_spread: float = 0.1
    """Strict test: the fragment, carried by its neighbourhood's rigid fit, stays this
    close to where it is in its middle frame over its whole span."""
    max_fit: float = 0.1
    """Strict test: the neighbourhood fit's mean residual stays below this."""
    min_clearance: float = 0.45
    """The fragment never comes this close to a known marker (measured or estimated)."""
    group_radius: float = 0.5
    """A fragment joins a new marker's group within this distance of its seed in the
    reference pose (and continues its track in time within it)."""
    rival_radius: float = 1.5
    """A known marker this close that is never measured during the fragment could own it."""
    loose_spread: float = 0.5
    """Loose test for long fragments on creasing skin: spread and residual within this."""
    spread_ratio: float = 2.0
    """Loose test: the spread is at most this many times the fit's residual."""
    loose_min_frames: int = 20
    """Shortest fragment the loose test accepts (a ghost lasts about three frames)."""
    rule_out_gap: int = 5
    """Frames within which continuity in time is trusted to rule a rival out (0: off)."""
    rule_out_radius: float = 0.7
    """A rival is ruled out when the fragment, carried to the rival's nearest measured
    frame, lands this far or farther from it."""
    min_seed_frames: int = 15
    """Shortest fragment that starts a new marker; shorter ones can only join one."""
    grow: bool = True
    """Extend the groups by continuity in time after grouping."""
    grow_gap: int = 5
    """Frames within which continuity in time extends a group."""

    def __post_init__(self) -> None:
        if self.k < 3 or self.min_frames < 1:
            raise ValidationError(
                f"need k >= 3 and min_frames >= 1; got k={self.k}, min_frames={self.min_frames}"
            )


@dataclass(frozen=True)
class FillSettings:
    """How holes are filled (:func:`~skincap.cleanup.fill.fill_gaps`)."""

    method: FillMethod = "local_pca"
    """One of :data:`~skincap.cleanup.methods.FILL_METHODS` (see :mod:`skincap.cleanup.fill`)."""
    max_gap: int | None = None
    """Leave missing runs longer than this many frames unfilled. None: no limit."""
    anchor_ends: bool = True
    """Local methods: join each filled gap continuously to its measured ends."""
    rigid_blend: float | None = None
    """Local methods: the rigid fill's weight in ``(1 - w) local PCA + w rigid``, in
    [0, 1]; 0 the paper's local PCA alone; None (default) chosen per gap from the two
    methods' spreads."""
    rigid_weighted: bool = True
    """Local methods: blend with (and fall back to) the donor-weighted rigid fill
    (``rigid_weighted``); False: the equal-weight ``rigid`` fill."""

    def __post_init__(self) -> None:
        if self.method not in FILL_METHODS:
            raise ValidationError(
                f"method: expected one of {', '.join(FILL_METHODS)}, got {self.method!r}"
            )
        if self.rigid_blend is not None and not 0.0 <= self.rigid_blend <= 1.0:
            raise ValidationError(
                f"rigid_blend: expected a weight in [0, 1], got {self.rigid_blend!r}"
            )
        if self.max_gap is not None and (
            isinstance(self.max_gap, bool)
            or not hasattr(self.max_gap, "__index__")
            or self.max_gap < 1
        ):
            raise ValidationError(f"max_gap: expected a positive integer, got {self.max_gap!r}")


@dataclass(frozen=True)
class SmoothSettings:
    """Local-frame smoothing after filling (:func:`~skincap.cleanup.smooth.smooth_local`)."""

    enabled: bool = True
    """Smooth at all. Measured samples move at most 3 σ of their marker's noise (1.5 mm)."""
    lam: float = 0.02
    """Damping λ of each ``x̂ <- x̂ - λ Δ⁴ x̂`` update, in (0, 1/8]."""
    iterations: int = 10
    """Number of Δ⁴ updates (at least 1)."""


@dataclass(frozen=True)
class CleanSettings:
    """The whole cleanup (:func:`~skincap.cleanup.pipeline.clean_markers`): surface,
    hidden markers, merge, swap and spike repair, fill, smooth."""

    reference_frame: int | None = None
    """Reference pose frame; None: the first frame with the most labelled markers."""
    keep_fragments: bool = True
    """Keep the fragments left unmerged (unfilled, after the markers) in the output."""
    promote_fragments: bool | None = None
    """Let fragments seen in the reference frame that move with at least three skin
    neighbours become marker columns. None: only when the capture has no labelled column."""
    recover_hidden: bool = True
    """Beyond the paper: label markers hidden in the reference frame (``U<n>`` columns)."""
    repair_swaps: bool = True
    """Exchange label swaps between neighbouring markers back before filling."""
    remove_spikes: bool = True
    """Remove spikes before filling (the filler replaces them)."""
    merge: MergeSettings = field(default_factory=MergeSettings)
    """Fragment merging."""
    hidden: HiddenSettings = field(default_factory=HiddenSettings)
    """Hidden-marker recovery (with ``recover_hidden``)."""
    fill: FillSettings = field(default_factory=FillSettings)
    """Hole filling."""
    smooth: SmoothSettings = field(default_factory=SmoothSettings)
    """Smoothing."""

    def __post_init__(self) -> None:
        if self.reference_frame is not None and (
            isinstance(self.reference_frame, bool)
            or not hasattr(self.reference_frame, "__index__")
            or self.reference_frame < 0
        ):
            raise ValidationError(
                f"reference_frame: expected a frame number >= 0, got {self.reference_frame!r}"
            )
