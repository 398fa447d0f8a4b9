"""``clean`` fills a sample kilometres off the body like any other hole.

Ground truth: the real CMU 85_02 take (every marker measured in every frame) with
samples moved kilometres away; the cleaned take must put them back near the measured
values and keep the surface the clean take builds. A marker that travels off the body
(a prop carried across the room) is not a leap and stays as measured.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skincap.cleanup.off_body import off_body_leaps
from skincap.cleanup.pipeline import clean_markers
from skincap.errors import SkincapWarning
from skincap.io import read

CMU = Path(__file__).resolve().parents[1] / "data" / "cmu_85_02.c3d"


@pytest.fixture(scope="module")
def cmu():
    return read(CMU)


def _clean(markers):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        return clean_markers(markers)


def _corrupt(markers, column: int, frames: list[int], value: float):
    pos = markers.positions.copy()
    pos[frames, column] = [value, 0.0, 0.0]
    return replace(markers, positions=pos)


@pytest.mark.parametrize(
    ("column", "frames", "value"),
    [(3, [200], 5000.0), (10, [400, 401, 402], -5000.0), (20, [0], 50.0), (5, [809], 9e6)],
)
def test_far_samples_are_filled_near_the_measured_ones(cmu, column, frames, value) -> None:
    assert np.isfinite(cmu.positions).all()  # every sample measured: the truth
    cleaned, report = _clean(_corrupt(cmu, column, frames, value))
    _, clean_report = _clean(cmu)
    assert np.isfinite(cleaned.positions[:, : cmu.n_markers]).all()  # nothing left unfilled
    error = np.linalg.norm(
        cleaned.positions[frames, column] - cmu.positions[frames, column], axis=-1
    )
    assert error.max() < 0.01  # metres
    assert cleaned.invented[frames, column].all()
    assert report.guard.outliers_replaced >= len(frames)
    assert report.fill.unfilled_samples == 0
    # the surface is the one the uncorrupted take gets: no marker loses its edges
    assert report.surface.edges == clean_report.surface.edges
    assert report.surface.markers_without_neighbours == 0


def test_a_marker_travelling_off_the_body_is_not_a_leap(cmu) -> None:
    # one marker walks 3 m away over two seconds and back: off the body, but no leap
    pos = cmu.positions.copy()
    t = np.arange(pos.shape[0])
    away = 3.0 * np.sin(np.pi * np.clip((t - 200) / 400.0, 0.0, 1.0))
    pos[:, 7, 0] += away
    travelled = replace(cmu, positions=pos)
    assert not off_body_leaps(pos).any()
    leapt = pos.copy()
    leapt[300, 7, 0] += 5.0  # now one sample leaps a further 5 m
    flagged = off_body_leaps(leapt)
    assert np.argwhere(flagged).tolist() == [[300, 7]]
    cleaned, report = _clean(travelled)
    # the travelling marker keeps its measured samples (smoothing moves them < 1.5 mm)
    moved = np.linalg.norm(cleaned.positions[:, 7] - pos[:, 7], axis=-1)
    assert np.nanmax(moved) < 0.0016


def test_runs_are_taken_whole_and_gaps_do_not_split_them() -> None:
    rng = np.random.default_rng(3)
    t_count, n = 60, 6
    pos = rng.normal(scale=0.2, size=(1, n, 3)) + np.zeros((t_count, 1, 3))
    pos[:, :, 1] += 1.0
    pos[10:14, 2] = [4000.0, 0.0, 0.0]  # a run of four, with a gap inside it
    pos[12, 2] = np.nan
    pos[30, 4] = np.nan  # a plain gap elsewhere
    flagged = off_body_leaps(pos)
    assert np.argwhere(flagged).tolist() == [[10, 2], [11, 2], [13, 2]]
    # a leap at the very start of a track (no previous sample) counts by its exit
    pos2 = pos.copy()
    pos2[:3, 5] = [0.0, -3000.0, 0.0]
    assert off_body_leaps(pos2)[:3, 5].all()
