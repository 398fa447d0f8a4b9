"""A PBD rope in the hands of a real capture (``skincap synth --real-markers``)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.errors import SkincapWarning, ValidationError
from skincap.io.c3d import read_c3d
from skincap.synth.real_capture import find_hand_markers, hand_path, real_capture_with_rope
from skincap.types import MarkerSet


def _first(path, frames: int) -> MarkerSet:  # type: ignore[no-untyped-def]
    m = read_c3d(path)
    return MarkerSet(m.positions[:frames], m.labels, m.rate, meta=dict(m.meta))


@pytest.fixture(scope="module")
def cmu(data_dir) -> MarkerSet:  # type: ignore[no-untyped-def]
    return _first(data_dir / "cmu_85_02.c3d", 120)


@pytest.fixture(scope="module")
def cmu_whip(cmu):  # type: ignore[no-untyped-def]
    return real_capture_with_rope(cmu, rope="whip", seed=3)


@pytest.mark.parametrize(
    ("name", "side", "expected"),
    [
        ("cmu_85_02.c3d", "right", {"Male:RWRA", "Male:RWRB", "Male:RFIN"}),
        ("btk_pig_calibration_hole_unlabeled_fragments.c3d", "left", {"LWRA", "LWRB", "LFIN"}),
        ("aml_PronetoRun01_labeled.c3d", "right", {"RHAND", "RRAD", "RULN"}),
        (
            "pyomeca_markers_analogs.c3d",
            "either",
            {"Daphnee:WRIST", "Daphnee:INDEX", "Daphnee:STYLr", "Daphnee:STYLu"},
        ),
        ("kt_optitrack_walking.c3d", "right", set()),
    ],
)
def test_hand_markers_are_found_by_name(data_dir, name: str, side: str, expected: set) -> None:  # type: ignore[no-untyped-def]
    labels = read_c3d(data_dir / name).labels
    assert {labels[i] for i in find_hand_markers(labels, side)} == expected  # type: ignore[arg-type]


def test_hand_centre_does_not_jump_when_a_hand_marker_drops_out() -> None:
    t = np.arange(50)
    centre = np.stack([0.01 * t, 1.0 + 0 * t, 0 * t], axis=1)  # (T, 3)
    offsets = np.array([[0.03, 0, 0], [-0.03, 0, 0], [0, 0.05, 0]])
    pos = centre[:, None] + offsets[None]
    pos[20:30, 2] = np.nan  # one marker hidden
    pos[40:45] = np.nan  # all hidden
    m = MarkerSet(pos, ["A", "B", "C"], 100.0)
    np.testing.assert_allclose(hand_path(m, [0, 1, 2]), centre + [0, 0.05 / 3, 0], atol=1e-12)


def test_body_points_are_the_real_samples_unchanged(cmu, cmu_whip) -> None:  # type: ignore[no-untyped-def]
    take = cmu_whip
    still = take.summary["still_frames"]
    assert still == 60 and take.points.n_frames == 120 + still
    frame = take.points.frame_index
    body = ~np.char.startswith(take.point_truth, "rope_") & (take.point_truth != "ghost")
    col = np.array([cmu.labels.index(label) for label in take.point_truth[body]])
    source_frame = np.maximum(frame[body] - still, 0)  # the held first pose, then the take
    np.testing.assert_array_equal(take.points.points[body], cmu.positions[source_frame, col])
    # ~3 % of the body's samples dropped in runs, the take's own samples otherwise all there
    present = np.isfinite(cmu.positions[..., 0]).sum() + still * cmu.n_markers
    assert 0.94 < body.sum() / present < 0.99


def test_rope_points_lie_on_the_rope_held_by_the_right_hand(cmu, cmu_whip) -> None:  # type: ignore[no-untyped-def]
    take = cmu_whip
    rope = np.char.startswith(take.point_truth, "rope_")
    index = {label: i for i, label in enumerate(take.truth.labels)}
    cols = np.array([index[label] for label in take.point_truth[rope]])
    err = np.linalg.norm(
        take.points.points[rope] - take.truth.positions[take.points.frame_index[rope], cols], axis=1
    )
    assert err.max() < 0.004  # 0.5 mm noise
    body = MarkerSet(take.truth.positions[:, : cmu.n_markers], cmu.labels, cmu.rate)
    hand = hand_path(body, find_hand_markers(cmu.labels, "right"))
    np.testing.assert_allclose(take.rope.particles[:, 0], hand, atol=1e-12)
    np.testing.assert_allclose(
        hand[60:], hand_path(cmu, find_hand_markers(cmu.labels, "right")), atol=0.005
    )
    # the first rope marker one spacing (1.1 m / 12) from the hand, the tip 1.1 m along
    gap = np.linalg.norm(take.rope.markers[:, 0] - take.rope.particles[:, 0], axis=1)
    np.testing.assert_allclose(gap, 1.1 / 12, rtol=0.1)
    # the still window: the rope hangs without moving and every rope marker is seen
    assert np.abs(np.diff(take.rope.markers[:60], axis=0)).max() < 1e-3
    assert (np.bincount(take.points.frame_index[rope], minlength=180)[:60] == 12).all()


def test_fragments_and_same_seed_same_take(cmu, cmu_whip) -> None:  # type: ignore[no-untyped-def]
    again = real_capture_with_rope(cmu, rope="whip", seed=3)
    np.testing.assert_array_equal(again.points.points, cmu_whip.points.points)
    cap = cmu_whip.capture
    for label, truth in cmu_whip.fragment_truth.items():
        assert label == truth or label.startswith("*")
    assert set(cmu_whip.fragment_truth.values()) >= {f"rope_{i:02d}" for i in range(12)}
    assert cap.n_frames == 180 and cmu_whip.summary["ghosts"] > 0


def test_a_capture_without_hands_names_the_option(data_dir) -> None:  # type: ignore[no-untyped-def]
    legs = _first(data_dir / "kt_optitrack_walking.c3d", 20)
    with pytest.raises(ValidationError, match="give --hands"):
        real_capture_with_rope(legs, rope="whip")
    with pytest.raises(ValidationError, match="no single marker named 'NOSE'"):
        real_capture_with_rope(legs, rope="whip", hands=[["NOSE"]])


def test_a_rope_hanging_from_hands_side_by_side_lies_doubled_and_says_so() -> None:
    # hands 1.5 m up and 4 cm apart: the 2.8 m jump rope hangs doubled in the air, its
    # arms centimetres apart, beyond any rope tracker
    pos = np.array([[0.0, 1.5, 0.0], [0.04, 1.5, 0.0], [0.1, 0.0, -0.3], [0.1, 0.4, -0.2]])
    high = MarkerSet(np.repeat(pos[None], 10, axis=0), ["LHAND", "RHAND", "TOE", "KNEE"], 120.0)
    with pytest.warns(SkincapWarning, match="lies doubled"):
        take = real_capture_with_rope(high, rope="jump", seed=0)
    assert take.summary["rope_doubled_markers"] > 22 // 4


def test_a_rope_held_at_the_floor_is_laid_out_in_an_open_loop() -> None:
    # "hands" 5 cm above the floor and 6 cm apart (a take without hands, leg markers
    # named instead, as the OptiTrack take's knee and foot): the 2.8 m jump rope used
    # to lie doubled on the floor, its arms laid on top of each other; a performer
    # lays it out in an open loop, its arms apart
    pos = np.array([[0.0, 0.05, 0.0], [0.06, 0.05, 0.0], [0.1, 0.0, -0.3], [0.1, 0.4, -0.2]])
    low = MarkerSet(np.repeat(pos[None], 10, axis=0), ["LHAND", "RHAND", "TOE", "KNEE"], 120.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        take = real_capture_with_rope(low, rope="jump", seed=0)
    assert take.summary["rope_doubled_markers"] == 0


def test_a_jump_rope_in_real_hands_is_not_doubled(cmu) -> None:  # type: ignore[no-untyped-def]
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        take = real_capture_with_rope(
            MarkerSet(cmu.positions[:20], cmu.labels, cmu.rate), rope="jump", seed=1
        )
    assert take.summary["rope_doubled_markers"] == 0


@pytest.mark.slow
def test_cli_writes_a_take_that_track_and_eval_read(data_dir, tmp_path) -> None:  # type: ignore[no-untyped-def]
    runner = CliRunner()
    out = tmp_path / "real"
    source = data_dir / "btk_pig_calibration_hole_unlabeled_fragments.c3d"
    r = runner.invoke(
        app,
        [
            "synth",
            "--real-markers",
            str(source),
            "--rope",
            "jump",
            "--frames",
            "60",
            "-o",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "LWRA+LWRB+LFIN" in r.output
    assert not (out / "truth" / "motion.bvh").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["marker_set"] == "real" and summary["rope_markers"] == 22
    truth = (out / "truth" / "points.csv").read_text().splitlines()
    first = [ln.split(",") for ln in truth[1:] if ln.split(",")[1] == "0"]
    rope = sorted((lab, row) for row, _, lab in first if lab.startswith("rope_"))
    r = runner.invoke(
        app,
        [
            "track",
            str(out / "capture_points.csv"),
            "--rope-markers",
            ",".join(row for _, row in rope),
            "-o",
            str(tmp_path / "tracked"),
            "--json",
        ],
    )
    assert r.exit_code == 0, r.output
    report = json.loads((tmp_path / "tracked" / "report.json").read_text())
    assert report["lost_traces"] == [] and report["frames"] == 110


def test_cli_refuses_an_unlabelled_capture(data_dir, tmp_path) -> None:  # type: ignore[no-untyped-def]
    r = CliRunner().invoke(
        app,
        [
            "synth",
            "--real-markers",
            str(data_dir / "aml_S09_KneeltoRun02_unlabeled.c3d"),
            "--rope",
            "whip",
            "-o",
            str(tmp_path / "x"),
        ],
    )
    assert r.exit_code == 2 and "labelled markers" in r.output
    assert not (tmp_path / "x" / "capture_points.csv").exists()
