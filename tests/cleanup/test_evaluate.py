from __future__ import annotations

import json

import numpy as np
import pytest

from skincap.cleanup.fill import motion_neighbours
from skincap.errors import OutputExistsError, ValidationError
from skincap.evaluate.bench.cleanup import run_clean_benchmark, synthetic_dense_take
from skincap.evaluate.cleanup import (
    evaluate_fill,
    format_fill_table,
    plot_fill_evaluation,
    punch_gaps,
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
