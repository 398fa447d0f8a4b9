"""The demo report's numbers: one definition for the table and the figure, one verdict."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.types import MarkerSet
from skincap.workflows.demo_report import (
    FILL_TARGET_MAX,
    FILL_TARGET_MEAN,
    fill_verdict,
    labelled_missing_maps,
)

NAN = np.nan


def test_labelled_missing_maps_counts_the_labelled_columns_only():
    pos = np.zeros((4, 3, 3))
    pos[1:3, 0] = NAN  # A missing in frames 1-2
    pos[:, 2] = NAN  # the fragment *1 does not count
    raw = MarkerSet(pos, ["A", "B", "*1"], 100.0)
    cpos = np.zeros((4, 2, 3))
    cpos[2, 1] = NAN  # A (column 1 of the cleaned set) still missing in frame 2
    invented = np.zeros((4, 2), dtype=bool)
    invented[1, 1] = True  # A filled in frame 1
    cleaned = MarkerSet(cpos, ["B", "A"], 100.0, invented=invented)
    before, after, filled = labelled_missing_maps(raw, cleaned)
    np.testing.assert_array_equal(before, [[0, 0], [1, 0], [1, 0], [0, 0]])
    np.testing.assert_array_equal(after, [[0, 0], [0, 0], [1, 0], [0, 0]])
    np.testing.assert_array_equal(filled, [[0, 0], [1, 0], [0, 0], [0, 0]])
    assert before.mean() == pytest.approx(2 / 8)  # what the table and the figure print


def test_a_marker_cleanup_dropped_counts_as_missing_after():
    raw = MarkerSet(np.zeros((2, 2, 3)), ["A", "B"], 100.0)
    cleaned = MarkerSet(np.zeros((2, 1, 3)), ["A"], 100.0)
    _, after, filled = labelled_missing_maps(raw, cleaned)
    np.testing.assert_array_equal(after, [[0, 1], [0, 1]])
    assert not filled.any()


def _fill(mean, mx):  # type: ignore[no-untyped-def]
    return {
        "mean_normalised": mean,
        "max_normalised": mx,
        "mean_mm": None if mean is None else 70 * mean,
    }


def test_fill_verdict_is_the_reports_red_or_green_for_the_lowest_error():
    fills = {
        "local_pca": _fill(0.0253, 0.113),
        "linear": _fill(0.44, 1.6),
        "broken": _fill(None, None),  # filled nothing: not scored
    }
    verdict = fill_verdict(fills)
    assert verdict["method"] == "local_pca"
    assert not verdict["meets_mean"] and not verdict["meets_max"] and not verdict["meets_targets"]
    good = fill_verdict({**fills, "ideal": _fill(FILL_TARGET_MEAN, FILL_TARGET_MAX)})
    assert good["method"] == "ideal" and good["meets_targets"]  # the bounds are inclusive
    half = fill_verdict({"a": _fill(0.01, 2 * FILL_TARGET_MAX)})
    assert half["meets_mean"] and not half["meets_max"] and not half["meets_targets"]
    assert fill_verdict({"broken": _fill(None, None)}) is None


def test_timings_give_wall_and_cpu_seconds_per_step():
    from skincap.workflows.demo_report import _timings_section

    html = _timings_section(
        {"cleanup": 12.34, "tracking": 5.0}, 17.34, {"cleanup": 9.87}, 9.9
    ).render()
    assert "CPU seconds" in html
    assert "12.3" in html and "9.9" in html  # the step's wall and CPU seconds
    assert html.count("–") == 1  # a step without a CPU figure says so, no invented number


def test_fill_section_says_how_the_gaps_were_punched():
    from skincap.workflows.demo_report import _fill_rounds

    assert _fill_rounds({"lengths_together": False, "rounds": 4}) == ""
    assert _fill_rounds({}) == ""  # an older evaluation: nothing claimed
    text = _fill_rounds({"lengths_together": True, "rounds": 2})
    assert "punched together, 2 rounds" in text and "fills each round once" in text


def _fill_eval(scored_against, measured):  # type: ignore[no-untyped-def]
    def per(mean, mx):  # type: ignore[no-untyped-def]
        stats = {"normalised": {"mean": mean, "max": mx}, "mm": {"mean": mean * 100}}
        return {"10": stats, "all": stats}

    ev = {
        "gap_lengths": [10],
        "gaps_per_length": 3,
        "mean_neighbour_distance_mm": 80.0,
        "scored_against": scored_against,
        "results": {"local_pca": per(0.0123, 0.04)},
    }
    if measured:
        ev["results_measured"] = {"local_pca": per(0.0234, 0.05)}
    return ev


def test_fill_section_names_its_reference_and_shows_the_measured_one_beside_the_truth(tmp_path):
    from skincap.workflows.demo_report import _fill_section

    png = tmp_path / "f.png"
    png.write_bytes(b"")
    truth = " ".join(_fill_section(_fill_eval("truth", True), png).render().split())
    assert "noise-free truth" in truth and "average vs measured" in truth
    assert "0.0234" in truth  # the measured-reference score beside the truth's
    assert '<span class="met">0.0123</span>' in truth  # the marks are the truth's
    measured = " ".join(_fill_section(_fill_eval("measured", False), png).render().split())
    assert "noise-free truth" not in measured and "vs measured" not in measured
