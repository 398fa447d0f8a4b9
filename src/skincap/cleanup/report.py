"""What :func:`~skincap.cleanup.pipeline.clean_markers` did: a typed report.

:class:`CleanReport` holds one typed section per stage (surface, hidden markers, merge,
fill, guard, smoothing) plus per-marker counts and the invented runs.
:meth:`CleanReport.as_dict` gives the JSON-ready dict that ``skincap clean --report``
writes (keys and order are part of the CLI's contract).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from skincap.cleanup.guarded import GuardSummary
from skincap.cleanup.merge import MergeReport

__all__ = ["CleanReport", "SurfaceSummary", "HiddenReport", "FillSummary", "SmoothSummary"]


@dataclass(frozen=True)
class SurfaceSummary:
    """The marker surface the cleanup used.

    Attributes
    ----------
    markers, edges, faces : int
        Its vertices (the marker columns), edges and triangles.
    reference_frame : int
        The reference pose's frame.
    mean_neighbour_distance_m : float or None
        Median over markers of the mean neighbour distance in the reference pose,
        metres (None when no marker has a neighbour).
    markers_without_neighbours : int
    """

    markers: int
    edges: int
    faces: int
    reference_frame: int
    mean_neighbour_distance_m: float | None
    markers_without_neighbours: int


@dataclass(frozen=True)
class HiddenReport:
    """Markers hidden in the reference frame, labelled from leftover fragments.

    Attributes
    ----------
    enabled : bool
        Whether the recovery ran (an automatic surface over labelled columns).
    new_markers : int
    markers : dict of str to list of str
        New label ``U<n>`` -> its fragments' labels, the seed first.
    recovered, wrong_markers, wrong_fragments : int or None
        With fragment truth only: new markers that are a true marker not otherwise
        labelled; those that are not (or repeat one); fragments whose truth differs
        from their marker's seed.
    """

    enabled: bool
    new_markers: int
    markers: dict[str, list[str]]
    recovered: int | None = None
    wrong_markers: int | None = None
    wrong_fragments: int | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready; the truth counts only when known."""
        out: dict[str, Any] = {
            "enabled": self.enabled,
            "new_markers": self.new_markers,
            "markers": {k: list(v) for k, v in self.markers.items()},
        }
        if self.recovered is not None:
            out.update(
                recovered=self.recovered,
                wrong_markers=self.wrong_markers,
                wrong_fragments=self.wrong_fragments,
            )
        return out


@dataclass(frozen=True)
class FillSummary:
    """The hole filling.

    Attributes
    ----------
    method : str
    rigid_blend : float or str
        The fixed blend weight, or ``"per gap"``.
    holes_before : int
        Missing marker samples before filling (removed spikes included).
    invented_samples : int
        Samples flagged invented (fills, replaced spikes, swapped-back samples, and
        what the input flagged).
    filled_samples, unfilled_samples : int
    unfilled_fraction : float
    unstable_fills_dropped : int
        Fills dropped because they did not stay continuous.
    acceleration_limit_mm_per_frame2 : float or None
        The second-difference bound on fills.
    """

    method: str
    rigid_blend: float | str
    holes_before: int
    invented_samples: int
    filled_samples: int
    unfilled_samples: int
    unfilled_fraction: float
    unstable_fills_dropped: int
    acceleration_limit_mm_per_frame2: float | None


@dataclass(frozen=True)
class SmoothSummary:
    """The smoothing: whether it ran, λ, iterations and the bound on measured samples
    (``max_move_noise_multiple`` σ of the marker's noise, at most ``max_move_mm``)."""

    enabled: bool
    lam: float
    iterations: int
    max_move_noise_multiple: float
    max_move_mm: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "enabled": self.enabled,
            "lambda": self.lam,
            "iterations": self.iterations,
            "max_move_noise_multiple": self.max_move_noise_multiple,
            "max_move_mm": self.max_move_mm,
        }


@dataclass(frozen=True)
class CleanReport:
    """What one :func:`~skincap.cleanup.pipeline.clean_markers` run did.

    Attributes
    ----------
    frames : int
    rate : float
        Hz.
    surface : SurfaceSummary
    hidden : HiddenReport
    merge : MergeReport
        Table 1's counts; ``trajectories_before`` counts the input's columns (the hidden
        markers' columns are made of its fragments).
    fill : FillSummary
    guard : GuardSummary
        Take-wide: filled, unfilled, outliers, relabelled, largest move, noise.
    markers : dict of str to dict
        The same per marker column (:meth:`~skincap.cleanup.guarded.GuardedFill.per_marker`).
    smooth : SmoothSummary
    invented : dict of str to list of [start, end)
        Runs of invented samples per marker (:func:`~skincap.cleanup.pipeline.invented_runs`).
    """

    frames: int
    rate: float
    surface: SurfaceSummary
    hidden: HiddenReport
    merge: MergeReport
    fill: FillSummary
    guard: GuardSummary
    markers: dict[str, dict[str, Any]]
    smooth: SmoothSummary
    invented: dict[str, list[list[int]]]

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready dict ``skincap clean --report`` writes (keys in this order)."""
        return {
            "frames": self.frames,
            "rate": self.rate,
            "surface": asdict(self.surface),
            "hidden": self.hidden.as_dict(),
            "merge": self.merge.as_dict(),
            "fill": asdict(self.fill),
            "guard": asdict(self.guard),
            "markers": {k: dict(v) for k, v in self.markers.items()},
            "smooth": self.smooth.as_dict(),
            "invented": {k: [list(r) for r in v] for k, v in self.invented.items()},
        }
