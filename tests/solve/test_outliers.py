"""Samples that jump off their segment (skincap.solve.outliers) against exact cases."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.solve.outliers import jumped_samples, off_body_samples


def _smooth_take(n_frames=200, n_markers=4, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None, None] / 120.0
    fitted = rng.uniform(-0.5, 0.5, (1, n_markers, 3)) + 0.3 * np.sin(2.0 * t + np.arange(3))
    # skin: a slow drift of up to 5 mm between the measured and the model marker
    drift = 0.005 * np.sin(0.7 * t + rng.uniform(0, 6, (1, n_markers, 3)))
    return fitted + drift, fitted


def test_a_short_swap_is_flagged_and_nothing_else():
    measured, fitted = _smooth_take()
    measured[50:55, 1] += 0.04  # 4 cm away for 5 frames, then back
    flagged = jumped_samples(measured, fitted)
    expected = np.zeros_like(flagged)
    expected[50:55, 1] = True
    np.testing.assert_array_equal(flagged, expected)


def test_a_swap_that_runs_into_a_gap_is_flagged():
    measured, fitted = _smooth_take()
    measured[120:130, 2] += [0.0, 0.03, 0.0]
    measured[130:140, 2] = np.nan  # the marker drops out while swapped
    flagged = jumped_samples(measured, fitted)
    assert flagged[120:130, 2].all() and flagged.sum() == 10


def test_a_constant_misfit_or_slow_drift_is_never_flagged():
    measured, fitted = _smooth_take()
    measured[:, 0] += 0.05  # 5 cm off all through: the model, not a swap
    measured[:, 3] += np.linspace(0, 0.08, measured.shape[0])[:, None]  # slides 8 cm
    measured[40:60, 2] = np.nan  # gaps are no jumps
    assert not jumped_samples(measured, fitted).any()


def test_small_jumps_are_kept():
    measured, fitted = _smooth_take()
    measured[80:90, 1] += [0.0, 0.012, 0.0]  # 1.2 cm: under the 2 cm jump
    assert not jumped_samples(measured, fitted).any()


def test_shapes_are_checked():
    with pytest.raises(ValidationError, match="measured/fitted"):
        jumped_samples(np.zeros((5, 2, 3)), np.zeros((5, 3, 3)))
    assert not jumped_samples(np.full((1, 2, 3), 0.1), np.zeros((1, 2, 3))).any()


def test_a_sample_far_off_the_body_is_flagged_and_nothing_else():
    measured, _ = _smooth_take(n_markers=6)
    measured[30, 2] = [5000.0, 3.0, 1.0]  # a corrupt sample, kilometres away
    measured[80, 4] += [1.6, 0.0, 0.0]  # a ghost 1.6 m off
    measured[90:100, 0] = np.nan  # a gap is not off the body
    flagged = off_body_samples(measured)
    expected = np.zeros_like(flagged)
    expected[30, 2] = expected[80, 4] = True
    np.testing.assert_array_equal(flagged, expected)


def test_frames_with_too_few_markers_are_not_judged():
    measured, _ = _smooth_take(n_markers=4)
    measured[10, 2:] = np.nan
    measured[10, 1] = [5000.0, 0.0, 0.0]  # two markers seen: no trusted centre
    assert not off_body_samples(measured).any()
    with pytest.raises(ValidationError):
        off_body_samples(np.zeros((3, 4)))


@pytest.mark.parametrize(
    "name",
    [
        "aml_PronetoRun01_labeled.c3d",
        "btk_pig_calibration_hole_unlabeled_fragments.c3d",
        "c3dorg_sample01_Eb015pr.c3d",
        "cmu_85_02.c3d",
        "kt_optitrack_walking.c3d",
        "pyomeca_markers_analogs.c3d",
    ],
)
def test_no_sample_of_a_real_labelled_capture_is_off_the_body(data_dir, name):
    import warnings

    from skincap.errors import SkincapWarning
    from skincap.io import read

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        take = read(data_dir / name)
    assert not off_body_samples(take.positions).any()
