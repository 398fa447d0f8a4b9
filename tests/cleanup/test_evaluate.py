from __future__ import annotations

import json

import numpy as np
import pytest

from skincap.cleanup.neighbours import motion_neighbours
from skincap.errors import OutputExistsError, ValidationError
from skincap.evaluate.bench.cleanup import run_clean_benchmark, synthetic_dense_take
from skincap.evaluate.cleanup import (
    evaluate_fill,
    format_fill_table,
    plot_fill_evaluation,
    punch_gaps,
    punch_gaps_together,
)


@pytest.fixture(scope="module")
def take():
    return synthetic_dense_take(150, 200, seed=5, missing=0.02)


def test_punched_gaps_sit_on_visible_data(take):
    markers, _ = take
    present = ~markers.missing
    off, idx = motion_neighbours(markers.positions)
    rounds = punch_gaps(present, (off, idx), 30, 6, simultaneous=2, rng=np.random.default_rng(0))
    rows = np.concatenate(rounds)
    assert len(np.unique(rows[:, 1])) == 6 and len(rows) == 12
    for r in rounds:
        punched = np.zeros_like(present)
        for c, s, ln in r:
            assert present[s - 1 : s + ln + 1, c].all()
            punched[s : s + ln, c] = True
        for c, s, ln in r:
            nb = idx[off[c] : off[c + 1]]
            ok = (present[s - 1 : s + ln + 1, nb] & ~punched[s : s + ln + 1, nb].any(0)).all(0)
            assert ok.sum() >= 3


def test_gaps_of_every_length_share_rounds_without_touching(take):
    markers, _ = take
    present = ~markers.missing
    off, idx = motion_neighbours(markers.positions)
    lengths = (10, 30, 60)
    rounds = punch_gaps_together(
        present, (off, idx), lengths, 3, rng=np.random.default_rng(0), margin=5
    )
    rows = np.concatenate(rounds)
    for length in lengths:  # every gap asked for, each of its own length
        assert (rows[:, 2] == length).sum() == 3
    # 3 x (12 + 32 + 62) frames of windows plus margins fit in the 150 frames only twice over
    assert 2 <= len(rounds) < 3 * len(lengths)
    assert any(len(np.unique(r[:, 2])) > 1 for r in rounds)  # lengths are mixed
    for r in rounds:
        windows = sorted((s - 1, s + ln) for _, s, ln in r)  # [first, last] kept frames
        for (_, end), (start, _) in zip(windows[:-1], windows[1:], strict=True):
            assert start - end > 2 * 5  # margins apart: no gap sees another's hole
        for c, s, ln in r:
            assert present[s - 1 : s + ln + 1, c].all()
            nb = idx[off[c] : off[c + 1]]
            assert present[s - 1 : s + ln + 1, nb].all(0).sum() >= 3


def test_lengths_together_scores_every_length_with_fewer_fills(take):
    markers, truth = take
    kw = dict(methods=["local_pca", "linear"], gap_lengths=(10, 20), gaps=2, seed=4, truth=truth)
    apart = evaluate_fill(markers, **kw)
    together = evaluate_fill(markers, lengths_together=True, **kw)
    assert apart["lengths_together"] is False and together["lengths_together"] is True
    assert together["rounds"] == 1 < apart["rounds"] == 2  # each method fills once, not twice
    for method in kw["methods"]:
        for length, samples in (("10", 20), ("20", 40)):
            per = together["results"][method][length]
            assert per["gaps"] == 2 and per["samples"] == samples
    # the same methods rank the same way, with errors of the same size
    a = apart["results"]["local_pca"]["all"]["mm"]["mean"]
    b = together["results"]["local_pca"]["all"]["mm"]["mean"]
    assert 0.3 < a / b < 3.0
    assert together["results"]["local_pca"]["all"]["mm"]["rmse"] < (
        0.2 * together["results"]["linear"]["all"]["mm"]["rmse"]
    )


def test_evaluate_fill_report(take, tmp_path):
    markers, truth = take
    r = evaluate_fill(
        markers,
        methods=["local_pca", "linear", "rigid"],
        gap_lengths=(20, 40),
        gaps=4,
        seed=2,
        truth=truth,
    )
    again = evaluate_fill(
        markers,
        methods=["local_pca", "linear", "rigid"],
        gap_lengths=(20, 40),
        gaps=4,
        seed=2,
        truth=truth,
    )
    assert json.dumps(r) == json.dumps(again)  # seeded
    res = r["results"]
    assert (
        res["local_pca"]["20"]["gaps"] == 4
        and res["local_pca"]["all"]["samples"] == 4 * 20 + 4 * 40
    )
    for m in r["methods"]:
        mm = res[m]["all"]["mm"]
        assert mm["mean"] <= mm["p95"] <= mm["max"] and mm["mean"] <= mm["rmse"]
        ratio = res[m]["all"]["normalised"]["mean"] / (mm["mean"] / 1000)
        assert ratio == pytest.approx(1 / (r["mean_neighbour_distance_mm"] / 1000), rel=0.5)
    assert res["local_pca"]["all"]["mm"]["rmse"] < 0.1 * res["linear"]["all"]["mm"]["rmse"]
    assert r["comparison"]["best"] in ("local_pca", "rigid")
    assert len(format_fill_table(r)) == 3 * 3
    png = plot_fill_evaluation(r, tmp_path / "f.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(OutputExistsError):
        plot_fill_evaluation(r, tmp_path / "f.png")
    with pytest.raises(ValidationError):
        evaluate_fill(markers, methods=["nope"])
    with pytest.raises(ValidationError):
        evaluate_fill(markers, gap_lengths=())


def test_benchmark_lines():
    r = run_clean_benchmark(n_markers=40, frames=(60, 120), smooth=True)
    assert len(r["rows"]) == 2 and r["goal_s"] == 10.0
    assert all(row["clean_s"] > 0 for row in r["rows"])
    assert any("linear in frames" in line for line in r["lines"])
    assert all(row["rmse_mm"] < row["linear_rmse_mm"] for row in r["rows"])


def test_rigid_blend_setting_is_passed_and_reported(take):
    markers, truth = take
    kw = dict(
        methods=["local_pca", "rigid", "rigid_weighted"],
        gap_lengths=(30,),
        gaps=3,
        seed=4,
        truth=truth,
    )
    auto = evaluate_fill(markers, **kw)
    paper = evaluate_fill(markers, rigid_blend=0.0, **kw)
    full = evaluate_fill(markers, rigid_blend=1.0, **kw)
    assert auto["rigid_blend"] == "per gap" and paper["rigid_blend"] == 0.0
    # the baselines do not change; the local method does, and with weight 1 it is the
    # donor-weighted rigid fill (every punched gap keeps >= 3 donors, so no sample differs)
    assert auto["results"]["rigid"] == paper["results"]["rigid"]
    assert auto["results"]["local_pca"] != paper["results"]["local_pca"]
    assert full["results"]["local_pca"]["all"]["mm"] == pytest.approx(
        full["results"]["rigid_weighted"]["all"]["mm"]
    )
    with pytest.raises(ValidationError):
        evaluate_fill(markers, rigid_blend=-0.1, **kw)


def test_scored_against_truth_also_scores_the_same_fills_against_the_measured(take):
    markers, truth = take
    kw = dict(methods=["local_pca", "linear"], gap_lengths=(10,), gaps=2, seed=3)
    both = evaluate_fill(markers, truth=truth, **kw)
    measured = evaluate_fill(markers, **kw)
    assert both["scored_against"] == "truth" and "results_measured" not in measured
    # the same gaps and fills: the measured-reference scores are those of a run without truth
    assert both["results_measured"] == measured["results"]
    assert both["results"] != measured["results"]
