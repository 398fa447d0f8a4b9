"""clean_markers: surface -> merge -> fill -> smooth on the synthetic take; invented runs."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from cleanup_takes import dense_jumprope_take

from skincap.cleanup.pipeline import clean_markers, invented_runs
from skincap.cleanup.report import HiddenReport
from skincap.cleanup.settings import CleanSettings, FillSettings, SmoothSettings
from skincap.cleanup.surface import build_marker_surface
from skincap.errors import SkincapWarning, ValidationError
from skincap.types import MarkerSet


def _body_error(
    take, cleaned: MarkerSet, n: int, hidden: HiddenReport
) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """Errors (T, n) against truth for the marker columns, and their invented mask
    (a recovered hidden marker ``U<n>`` compared with its first fragment's truth)."""
    names = list(take.truth.labels)
    truth = {new: take.fragment_truth[frags[0]] for new, frags in hidden.markers.items()}
    idx = np.array([names.index(truth.get(lab, lab)) for lab in cleaned.labels[:n]])
    err = np.linalg.norm(cleaned.positions[:, :n] - take.truth.positions[:, idx], axis=2)
    return err, cleaned.invented[:, :n]


@pytest.mark.parametrize("method", ["linear", "local_pca"])
def test_clean_dense_take(method: str) -> None:
    take = dense_jumprope_take()
    cap = take.capture
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)  # a few unfillable end samples
        cleaned, report = clean_markers(
            cap,
            settings=CleanSettings(
                fill=FillSettings(method=method), smooth=SmoothSettings(enabled=False)
            ),
            fragment_truth=take.fragment_truth,
        )
    n = report.surface.markers
    hidden = report.hidden
    assert n == sum(not lab.startswith("*") for lab in cap.labels) + hidden.new_markers
    assert hidden.wrong_markers == 0 and hidden.recovered == hidden.new_markers
    merge = report.merge
    assert merge.merged >= 100 and merge.wrong_rate <= 0.02
    assert cleaned.n_markers == merge.trajectories_after
    fill = report.fill
    assert fill.method == method
    assert fill.invented_samples + fill.unfilled_samples == fill.holes_before
    # invented == the filled holes; measured samples untouched without smoothing
    err, inv = _body_error(take, cleaned, n, hidden)
    assert inv.sum() == fill.invented_samples
    assert np.isfinite(cleaned.positions[:, :n][inv]).all()
    assert not cleaned.invented[:, n:].any()
    measured = np.isfinite(err) & ~inv
    assert np.median(err[measured]) < 1.5e-3  # 0.5 mm noise, a few wrong merges
    runs = report.invented
    assert sum(e - s for spans in runs.values() for s, e in spans) == fill.invented_samples
    json.dumps(report.as_dict())  # JSON-ready
    if method == "local_pca":
        # the filled holes follow the truth: measured mean 0.21 of the spacing on
        # this short take (long holes at a crease dominate; linear: 0.39)
        norm = report.surface.mean_neighbour_distance_m
        assert np.nanmean(err[inv]) / norm < 0.3


def test_smoothing_changes_only_slightly_and_keeps_flags() -> None:
    take = dense_jumprope_take()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        raw, _ = clean_markers(
            take.capture,
            settings=CleanSettings(
                fill=FillSettings(method="linear"), smooth=SmoothSettings(enabled=False)
            ),
        )
        smooth, report = clean_markers(
            take.capture,
            settings=CleanSettings(
                fill=FillSettings(method="linear"), smooth=SmoothSettings(enabled=True)
            ),
        )
    assert report.smooth.as_dict() == {
        "enabled": True,
        "lambda": 0.02,
        "iterations": 10,
        "max_move_noise_multiple": 3.0,
        "max_move_mm": 1.5,
    }
    assert np.array_equal(raw.invented, smooth.invented)
    diff = np.linalg.norm(raw.positions - smooth.positions, axis=2)
    assert np.nanmax(diff) < 0.01 and np.nanmean(diff) < 1e-3
    # a measured sample moves by at most 1.5 mm (3 sigma of the 0.5 mm noise here)
    measured = ~raw.invented & np.isfinite(raw.positions[..., 0])
    assert diff[measured].max() <= 0.0015 + 1e-12


def test_user_surface_and_validation() -> None:
    take = dense_jumprope_take()
    cap = take.capture
    cols = [i for i, lab in enumerate(cap.labels) if not lab.startswith("*")]
    surface = build_marker_surface(cap.positions[:, cols], reference_frame=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        _, report = clean_markers(
            cap,
            settings=CleanSettings(
                fill=FillSettings(method="linear"), smooth=SmoothSettings(enabled=False)
            ),
            surface=surface,
        )
    assert report.surface.edges == surface.edges.shape[0]
    with pytest.raises(ValidationError, match="labelled markers"):
        clean_markers(cap.select(cols[:10]), surface=surface)
    with pytest.raises(ValidationError, match="reference_frame"):
        clean_markers(cap, settings=CleanSettings(reference_frame=10_000))
    with pytest.raises(ValidationError, match="MarkerSet"):
        clean_markers(cap.positions)  # type: ignore[arg-type]


def test_invented_runs() -> None:
    inv = np.zeros((6, 3), dtype=bool)
    inv[1:3, 0] = True
    inv[5, 0] = True
    inv[0:6, 2] = True
    assert invented_runs(inv, ["a", "b", "c"]) == {"a": [[1, 3], [5, 6]], "c": [[0, 6]]}
