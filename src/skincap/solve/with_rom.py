"""Calibrate a body model on one take (a range of motion) and solve another with it.

A take that moves few joints (a jump rope barely bends the spine) calibrates a poor
skeleton; the same subject's range-of-motion take turns every joint, so the model is
found there and the take is only posed by inverse kinematics. Both takes must carry the
same labelled markers; the model's marker columns are matched by label.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.errors import ValidationError
from skincap.solve.pipeline import SolveResult, solve_markers
from skincap.types import MarkerSet

__all__ = ["solve_with_range_of_motion"]


def _without_off_body(markers: MarkerSet) -> MarkerSet:
    """The take with samples too far from the body to be on it set missing."""
    from skincap.solve.outliers import off_body_samples

    off = off_body_samples(markers.positions)
    if not off.any():
        return markers
    return replace(markers, positions=np.where(off[..., None], np.nan, markers.positions))


def solve_with_range_of_motion(
    markers: MarkerSet,
    rom: MarkerSet | None = None,
    *,
    template: Any = "auto",
    progress: Progress | None = None,
) -> SolveResult:
    """Calibrate on ``rom`` (default ``markers``), solve ``markers``.

    Parameters
    ----------
    markers : MarkerSet
        The take to solve, metres, NaN where missing.
    rom : MarkerSet, optional
        The calibration take: every label of ``markers`` that the model uses must be
        in it.
    template : str or Template
        ``"auto"`` (segments and joints found from the markers' own motion,
        :func:`skincap.solve.auto.calibrate_auto`), a built-in name or a JSON file.
    progress : callable(fraction, label), optional

    Returns
    -------
    SolveResult
        Of ``markers``, posed by the model calibrated on ``rom``.

    Raises
    ------
    ValidationError
        The take lacks a marker the calibrated model uses.
    """
    from skincap.solve.calibrate import calibrate
    from skincap.solve.templates import Template, load_template

    source = markers if rom is None else rom
    if progress is not None:
        progress(0.0, "skeleton calibration")
    if isinstance(template, str) and template == "auto":
        from skincap.solve.auto import calibrate_auto

        model = calibrate_auto(_without_off_body(source))
    else:
        tpl = template if isinstance(template, Template) else load_template(template)
        model = calibrate(source, tpl)
    if rom is not None:
        where = {str(lab): k for k, lab in enumerate(markers.labels)}
        missing = [lab for lab in model.marker_labels if lab not in where]
        if missing:
            raise ValidationError(
                f"the take lacks {len(missing)} marker(s) the skeleton uses ({missing[0]!r})"
            )
        model = replace(
            model, marker_columns=np.array([where[lab] for lab in model.marker_labels], np.int64)
        )

    def ik_progress(fraction: float, label: str) -> None:
        if progress is not None:
            progress(0.3 + 0.7 * fraction, label)

    return solve_markers(markers, model, progress=ik_progress)
