"""A fragment joins a marker only when no missing rival explains it nearly as well, and
fragments of one hidden marker are grouped only where they meet in time."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.cleanup.hidden import _joins_in_time
from skincap.cleanup.merge import _prediction_error, merge_fragments
from skincap.cleanup.settings import MergeSettings
from skincap.cleanup.surface import build_marker_surface
from skincap.errors import ValidationError
from skincap.types import MarkerSet

FRAMES = 90
A, B = 24, 25  # the sheet's centre and its neighbour along +y (5 cm apart)


def _motion(points: np.ndarray) -> np.ndarray:
    """(FRAMES, K, 3): rest points (K, 3) turned and carried along, with 0.3 mm noise."""
    rot = Rotation.from_rotvec(np.outer(np.linspace(0, 1.2, FRAMES), [0.2, 1, 0.3])).as_matrix()
    move = np.outer(np.linspace(0, 0.8, FRAMES), [1, 0, 0.5])[:, None]
    out = np.einsum("tij,kj->tki", rot, points) + move
    return out + np.random.default_rng(1).normal(0, 3e-4, out.shape)


def _sheet() -> tuple[MarkerSet, dict[str, str], int]:
    """A 7x7 sheet (5 cm grid, labelled M00-M48) and a marker H hidden in the reference
    frame, 2 cm from A towards B (0.4 and 0.6 spacings). A and B are both missing in
    frames 30-49 and again in 60-79. In 30-49 H is measured (fragment *1, true label
    H); in 60-79 A's and B's own samples come back as fragments *2 and *3."""
    g = np.stack(np.meshgrid(np.arange(7), np.arange(7), indexing="ij"), -1).reshape(-1, 2)
    rest = np.column_stack([g * 0.05, np.zeros(49)])
    rest = np.vstack([rest, rest[A] + [0.0, 0.02, 0.0]])  # H
    pos = _motion(rest)
    sheet = pos[:, :49].copy()
    sheet[30:50, [A, B]] = np.nan
    sheet[60:80, [A, B]] = np.nan
    frag = np.full((FRAMES, 3, 3), np.nan)
    frag[30:50, 0] = pos[30:50, 49]
    frag[60:80, 1] = pos[60:80, A]
    frag[60:80, 2] = pos[60:80, B]
    labels = [f"M{i:02d}" for i in range(49)] + ["*1", "*2", "*3"]
    truth = {"*1": "H", "*2": f"M{A:02d}", "*3": f"M{B:02d}"}
    markers = MarkerSet(positions=np.concatenate([sheet, frag], axis=1), labels=labels, rate=100.0)
    return markers, truth, 49


def test_the_sheet_puts_b_next_to_a() -> None:
    # the construction itself: B is A's neighbour along the row H lies on
    markers, _, n = _sheet()
    ref = markers.positions[0]
    assert np.linalg.norm(ref[A] - ref[B]) == pytest.approx(0.05, abs=2e-3)
    assert ref[B, 1] - ref[A, 1] > 0.04  # B lies along +y, where H is
    assert not np.isfinite(ref[n]).any()  # H is not seen in the reference frame


def test_a_fragment_between_two_missing_markers_is_left_unmerged() -> None:
    markers, truth, n = _sheet()
    surface = build_marker_surface(markers.positions[:, :n], reference_frame=0)
    # the prediction test alone would refuse H on a rigid sheet; off, to test the margin
    _, loose = merge_fragments(
        markers,
        surface,
        settings=MergeSettings(prediction_factor=None, rival_ratio=0.7),
        fragment_truth=truth,
    )
    _, strict = merge_fragments(
        markers, surface, settings=MergeSettings(prediction_factor=None), fragment_truth=truth
    )
    # a margin of 0.7 takes H (0.4 spacings from A, 0.6 from B) for A: wrong
    assert loose.assignments.get("*1") == f"M{A:02d}" and loose.wrongly_merged == 1
    # the default margin (0.2) leaves it, and A's and B's own fragments still merge
    assert "*1" not in strict.assignments
    assert strict.assignments == {"*2": f"M{A:02d}", "*3": f"M{B:02d}"}
    assert strict.wrongly_merged == 0 and strict.left_unmerged == 0


def test_rival_ratio_is_checked() -> None:
    markers, _, n = _sheet()
    surface = build_marker_surface(markers.positions[:, :n], reference_frame=0)
    for bad in (0.0, 1.5):
        with pytest.raises(ValidationError, match="rival_ratio"):
            merge_fragments(markers, surface, settings=MergeSettings(rival_ratio=bad))


def test_fragments_of_two_hidden_markers_are_not_one_marker() -> None:
    # two hidden markers 1.5 spacings apart: where their fragments meet in time the
    # neighbourhood's fit between the two frames keeps them apart; a later fragment of
    # the first marker continues it
    g = np.stack(np.meshgrid(np.arange(5), np.arange(5), indexing="ij"), -1).reshape(-1, 2)
    rest = np.column_stack([g * 0.05, np.zeros(25)])
    hidden = np.array([[0.09, 0.1, 0.0], [0.165, 0.1, 0.0]])
    pts = _motion(np.vstack([rest, hidden]))
    est = pts[:, :25]
    nb = np.arange(25)
    x = np.full((FRAMES, 3), np.nan)
    y = np.full((FRAMES, 3), np.nan)
    x[10:40] = pts[10:40, 25]
    y[40:70] = pts[40:70, 26]
    later_x = np.full((FRAMES, 3), np.nan)
    later_x[72:85] = pts[72:85, 25]
    radius = 0.5 * 0.05
    assert not _joins_in_time(est, y, x, nb, radius)
    assert _joins_in_time(est, later_x, x, nb, radius)
    assert not _joins_in_time(est, later_x, np.full((FRAMES, 3), np.nan), nb, radius)


def _pair_missing(extra: np.ndarray, frames: slice) -> tuple[MarkerSet, np.ndarray]:
    """The 7x7 sheet with A and B missing in ``frames`` and one fragment *1 there:
    ``extra`` (FRAMES, 3) metres. Returns the capture and the clean positions."""
    g = np.stack(np.meshgrid(np.arange(7), np.arange(7), indexing="ij"), -1).reshape(-1, 2)
    pos = _motion(np.column_stack([g * 0.05, np.zeros(49)]))
    sheet = pos.copy()
    sheet[frames, A] = np.nan
    sheet[frames, B] = np.nan
    frag = np.full((FRAMES, 1, 3), np.nan)
    frag[frames, 0] = extra[frames]
    labels = [f"M{i:02d}" for i in range(49)] + ["*1"]
    markers = MarkerSet(positions=np.concatenate([sheet, frag], 1), labels=labels, rate=100.0)
    return markers, pos


def test_a_short_fragment_needs_a_wider_margin() -> None:
    # a two-frame ghost 6.5 mm from A towards B (B 7 times farther) while both are
    # missing: a margin of 0.2 takes it for A, the doubled margin of a two-frame
    # fragment (short_frames 4) does not; A's own two frames still merge
    g = np.stack(np.meshgrid(np.arange(7), np.arange(7), indexing="ij"), -1).reshape(-1, 2)
    rest = np.column_stack([g * 0.05, np.zeros(49)])
    ghost = _motion(np.vstack([rest, rest[A] + [0.0, 0.0065, 0.0]]))[:, 49]
    frames = slice(40, 42)
    markers, pos = _pair_missing(ghost, frames)
    surface = build_marker_surface(markers.positions[:, :49], reference_frame=0)
    truth = {"*1": "ghost"}
    _, loose = merge_fragments(
        markers, surface, settings=MergeSettings(short_frames=1), fragment_truth=truth
    )
    _, strict = merge_fragments(markers, surface, fragment_truth=truth)
    assert loose.assignments == {"*1": f"M{A:02d}"} and loose.wrongly_merged == 1
    assert strict.merged == 0
    own, _ = _pair_missing(pos[:, A], frames)
    _, report = merge_fragments(own, surface, fragment_truth={"*1": f"M{A:02d}"})
    assert report.assignments == {"*1": f"M{A:02d}"} and report.wrongly_merged == 0


def test_a_marker_misplaced_in_the_reference_pose_is_calibrated() -> None:
    # A's reference position is 2.75 cm (0.55 spacings) off, as for a marker placed in
    # the reference frame by its neighbours from another frame; where it is measured
    # its neighbourhood shows where it really sits
    g = np.stack(np.meshgrid(np.arange(7), np.arange(7), indexing="ij"), -1).reshape(-1, 2)
    frames = slice(50, 70)
    markers, pos = _pair_missing(_motion(np.column_stack([g * 0.05, np.zeros(49)]))[:, A], frames)
    ref = markers.positions[:, :49].copy()
    ref[0, A] = pos[0, A] + (pos[0, A] - pos[0, B]) * 0.55  # away from B
    surface = build_marker_surface(ref, reference_frame=0)
    present = np.isfinite(markers.positions[:, :49, 0])
    error, calibrated = _prediction_error(markers.positions[:, :49], present, surface)
    assert np.linalg.norm(calibrated[A] - pos[0, A]) < 1e-3
    assert np.linalg.norm(surface.reference[A] - pos[0, A]) > 0.025
    assert error[A] < 2e-3  # measured from the calibrated place, not the reference one
    truth = {"*1": f"M{A:02d}"}
    _, off = merge_fragments(
        markers, surface, settings=MergeSettings(calibrate=False), fragment_truth=truth
    )
    _, on = merge_fragments(markers, surface, fragment_truth=truth)
    assert off.merged == 0
    assert on.assignments == truth and on.wrongly_merged == 0
