"""The synthetic sparse walk against its true joints (issue #17's joint-centre row).

A walk turns most joints through little range: the knees and ankles flex about one
axis, the arms swing a little, the thorax bends between its markers (CLAV, STRN, RBAK
ride the lower chest, C7 and the shoulders the upper). These bounds sit between what
the calibration measured before its walk mechanisms and after them (``skincap eval
solve --synth tests/data/cmu_131_01_bvh11.bvh``, 600 frames, seed 0): the along-axis
priors and SCoRE without a loose parent marker (knees, ankles), then the shoulders by
SCoRE in a frame of ``parent_points`` (C7, a thorax centroid, the other shoulder's
centre) on an upper-thorax link, and the elbows placed along SARA's axis where the
bones cross it (``axis_point``):

=========  ==========  ==========  ==========  ===========
joint      first, mm   before, mm  now, mm     bound, mm
=========  ==========  ==========  ==========  ===========
knees      11.1, 13.2  4.2, 8.3    4.4, 8.9    10
ankles     21.1, 24.7  4.5, 7.8    4.5, 7.7    12
shoulders  34.0, 20.5  24.3, 18.8  11.6, 11.8  16
elbows     --          17.5, 20.8  12.1, 18.8  20
mean       16.3        11.5        9.0         10
=========  ==========  ==========  ==========  ===========
"""

from __future__ import annotations

import warnings

import pytest

from skincap.errors import SkincapWarning
from skincap.evaluate.solve import evaluate_synthetic


@pytest.mark.slow
def test_the_synthetic_walk_is_solved_near_its_true_joints(data_dir):
    from skincap.workflows.solve import synth_take_in_memory

    markers, truth = synth_take_in_memory(
        str(data_dir / "cmu_131_01_bvh11.bvh"), frames=600, vertices=8000, seed=0
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        result = evaluate_synthetic(markers, truth)
    mean_mm = {k: v["mean_m"] * 1e3 for k, v in result["joint_errors"].items()}
    for side in ("Left", "Right"):
        assert mean_mm[f"{side}Knee"] < 10.0
        assert mean_mm[f"{side}Ankle"] < 12.0
        assert mean_mm[f"{side}Shoulder"] < 16.0
        assert mean_mm[f"{side}Elbow"] < 20.0
        assert result["methods"][f"{side}Ankle"] == "SCoRE + regression along the axis"
        assert result["methods"][f"{side}Shoulder"] == "SCoRE in its parent_points frame"
        assert result["methods"][f"{side}Elbow"] == "SARA, centre where the bones cross the axis"
        # the ankle is the least determined: a walk turns it < 10 deg RMS about one axis
        assert result["fit_singular_values"][f"{side}Ankle"][5] < 0.175
    assert result["joint_mean_m"] < 0.010
    assert result["angle_median_deg"] < 3.0
