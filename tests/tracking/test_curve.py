"""The rope curve: rest arc length, interior fill, arc-length resampling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skincap.errors import ValidationError
from skincap.tracking._numba_curve import carry_last_seen as carry_last_seen_numba
from skincap.tracking.curve import (
    carry_last_seen,
    fill_interior_on_curve,
    polyline_length,
    resample_by_arclength,
    rest_arclength,
    settle_single_gaps,
)


def test_rest_arclength() -> None:
    np.testing.assert_allclose(rest_arclength(np.array([0.1, 0.2, 0.3])), [0, 0.1, 0.3, 0.6])
    with pytest.raises(ValidationError):
        rest_arclength(np.array([0.1, 0.0]))
    with pytest.raises(ValidationError):
        rest_arclength(np.array([0.1, np.nan]))


@settings(max_examples=60, deadline=None)
@given(
    mask=st.lists(st.booleans(), min_size=10, max_size=10),
    spacing=st.lists(st.floats(0.05, 0.2), min_size=9, max_size=9),
)
def test_fill_on_straight_line_is_exact(mask: list[bool], spacing: list[float]) -> None:
    s = rest_arclength(np.array(spacing))
    direction = np.array([0.3, -0.8, 0.52])
    direction /= np.linalg.norm(direction)
    truth = 0.5 + s[:, None] * direction
    known = np.array(mask)
    known[0] = known[-1] = True
    pos = np.where(known[:, None], truth, np.nan)
    filled, interior = fill_interior_on_curve(pos, known, s)
    np.testing.assert_array_equal(interior, ~known)
    np.testing.assert_allclose(filled, truth, atol=1e-12)


def test_fill_on_circle_close_and_ends_untouched() -> None:
    m = 24
    s = rest_arclength(np.full(m - 1, 0.12))
    radius = 0.8
    ang = s / radius
    truth = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(m)], axis=1)
    known = np.ones(m, dtype=bool)
    known[[0, 5, 11, 12]] = False
    pos = np.where(known[:, None], truth, np.nan)
    filled, interior = fill_interior_on_curve(pos, known, s)
    assert interior[[5, 11, 12]].all() and not interior[0]
    assert np.isnan(filled[0]).all()  # an end run is left alone
    err = np.linalg.norm(filled[[5, 11, 12]] - truth[[5, 11, 12]], axis=1)
    assert err.max() < 2e-3  # cubic on a 0.8 m circle, 12 cm spacing
    # batched: the same in a leading frame axis
    batch, _ = fill_interior_on_curve(np.stack([pos, pos]), np.stack([known, known]), s)
    np.testing.assert_allclose(batch[1, 1:], filled[1:])


def test_fill_checks_shapes() -> None:
    with pytest.raises(ValidationError):
        fill_interior_on_curve(np.zeros((5, 3)), np.ones(4, bool), np.arange(5.0))


def test_resample_straight_and_circle() -> None:
    line = np.stack([np.linspace(0, 1, 6), np.zeros(6), np.zeros(6)], axis=1)[None]
    s, pts = resample_by_arclength(line, 11)
    np.testing.assert_allclose(s[0], np.linspace(0, 1, 11), atol=1e-12)
    np.testing.assert_allclose(pts[0, :, 0], np.linspace(0, 1, 11), atol=1e-12)
    ang = np.linspace(0, np.pi, 25)
    arc = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
    s, pts = resample_by_arclength(np.stack([arc, arc * 2]), 50)
    assert s.shape == (2, 50) and pts.shape == (2, 50, 3)
    np.testing.assert_allclose(s[:, -1], [np.pi, 2 * np.pi], rtol=2e-3)
    np.testing.assert_allclose(pts[:, 0], [arc[0], 2 * arc[0]], atol=1e-12)
    np.testing.assert_allclose(pts[:, -1], [arc[-1], 2 * arc[-1]], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pts[0], axis=1), 1.0, atol=2e-3)
    assert polyline_length(arc) == pytest.approx(np.pi, rel=1e-3)


def test_resample_rejects_nan_and_bad_shapes() -> None:
    bad = np.zeros((2, 4, 3))
    bad[1, 2] = np.nan
    with pytest.raises(ValidationError):
        resample_by_arclength(bad)
    with pytest.raises(ValidationError):
        resample_by_arclength(np.zeros((2, 1, 3)))
    with pytest.raises(ValidationError):
        resample_by_arclength(np.zeros((2, 4, 3)), 1)


def _kinked_rope(m: int = 16, spacing: float = 0.12) -> np.ndarray:
    """(M, 3) a planar rope whose links are exactly ``spacing`` long, sharply waved."""
    theta = 1.1 * np.sin(2 * np.pi * np.arange(m - 1) / 5.0)
    links = spacing * np.stack([np.cos(theta), np.sin(theta), np.zeros(m - 1)], axis=1)
    return np.concatenate([np.zeros((1, 3)), np.cumsum(links, axis=0)]) + [0.2, 1.0, -0.3]


def test_settle_single_gaps_brings_a_lone_marker_back_to_the_bend() -> None:
    m, spacing = 16, np.full(15, 0.12)
    truth = _kinked_rope(m)
    s = rest_arclength(spacing)
    curve_err, settled_err = [], []
    for j in range(1, m - 1):
        known = np.ones(m, dtype=bool)
        known[j] = False
        filled, _ = fill_interior_on_curve(np.where(known[:, None], truth, np.nan), known, s)
        half = settle_single_gaps(filled, known, spacing, 0.5)
        full = settle_single_gaps(filled, known, spacing, 1.0)
        np.testing.assert_array_equal(half[known], filled[known])  # measured ones untouched
        np.testing.assert_array_equal(settle_single_gaps(filled, known, spacing, 0.0), filled)
        # weight 1: exactly at the rest spacings from both neighbours
        np.testing.assert_allclose(np.linalg.norm(full[j] - truth[[j - 1, j + 1]], axis=1), 0.12)
        curve_err.append(np.linalg.norm(filled[j] - truth[j]))
        settled_err.append(np.linalg.norm(half[j] - truth[j]))
    # the curve cuts the sharp bends; halfway to the rest spacings is nearer the truth
    assert np.mean(settled_err) < 0.6 * np.mean(curve_err)
    assert max(curve_err) > 0.01


def test_settle_single_gaps_leaves_runs_stretched_links_and_batches() -> None:
    m, spacing = 10, np.full(9, 0.12)
    truth = _kinked_rope(m)
    known = np.ones(m, dtype=bool)
    known[[3, 4]] = False  # a run of two: not lone
    known[7] = False
    pos = truth.copy()
    pos[[3, 4, 7]] += 0.01
    out = settle_single_gaps(pos, known, spacing, 1.0)
    np.testing.assert_array_equal(out[[3, 4]], pos[[3, 4]])
    assert not np.allclose(out[7], pos[7])
    # neighbours farther apart than two spacings: no circle, left alone
    far = pos.copy()
    far[8] = far[6] + [0.3, 0.0, 0.0]
    np.testing.assert_array_equal(settle_single_gaps(far, known, spacing, 1.0)[7], far[7])
    batch = settle_single_gaps(np.stack([pos, far]), np.stack([known, known]), spacing, 1.0)
    np.testing.assert_array_equal(batch[0], out)
    with pytest.raises(ValidationError):
        settle_single_gaps(pos, known, spacing[:-1], 0.5)


def test_kernel_settle_matches_the_reference() -> None:
    pytest.importorskip("numba")
    from skincap.tracking._numba_curve import settle as _settle

    rng = np.random.default_rng(3)
    m = 12
    spacing = rng.uniform(0.08, 0.14, m - 1)
    for _ in range(20):
        pos = _kinked_rope(m) + rng.normal(0, 0.02, (m, 3))
        known = rng.random(m) > 0.35
        ref = settle_single_gaps(pos, known, spacing, 0.5)
        out = pos.copy()
        _settle(out, known, spacing, 0.5)
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


# ---------------------------------------------------------------- carry_last_seen
def _bent_rope(m: int = 10) -> np.ndarray:
    """(M, 3) metres: a rope bent into a quarter circle and a kink, 10 cm apart."""
    angle = np.linspace(0.0, np.pi / 2, m)
    rope = np.stack([0.6 * np.cos(angle), 0.6 * np.sin(angle), 0.05 * (np.arange(m) % 3)], axis=1)
    return rope


@pytest.mark.parametrize("carry", [carry_last_seen, carry_last_seen_numba])
def test_carry_last_seen_is_exact_for_a_rope_moving_rigidly(carry) -> None:  # type: ignore[no-untyped-def]
    from scipy.spatial.transform import Rotation

    then = _bent_rope()
    rot = Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix()
    now = then @ rot.T + np.array([0.2, -0.5, 1.0])
    known = np.ones(10, dtype=bool)
    known[[0, 4, 5, 9]] = False  # an end, a run of two inside, the other end
    rows = np.array([0, 4, 5, 9])
    pred = np.zeros((10, 3))  # a spatial prediction far off
    out = carry(
        pred, now, known, rows, np.repeat(then[None], 4, axis=0), np.ones((4, 10), bool), 0.005
    )
    np.testing.assert_allclose(out[rows], now[rows], atol=1e-9)
    np.testing.assert_array_equal(out[known], pred[known])  # other rows untouched


@pytest.mark.parametrize("carry", [carry_last_seen, carry_last_seen_numba])
def test_carry_last_seen_gives_way_to_the_prediction_as_the_rope_deforms(carry) -> None:  # type: ignore[no-untyped-def]
    then = _bent_rope()
    known = np.ones(10, dtype=bool)
    known[5] = False
    rows = np.array([5])
    pred = then + np.array([0.0, 0.0, 0.01])  # spatial prediction 1 cm off
    measured = np.ones((1, 10), bool)
    errors = []
    for bend in (0.0, 0.006, 0.1):  # the neighbours deform more and more
        now = then + bend * np.sin(np.arange(10))[:, None] * np.array([1.0, 0.0, 0.0])
        now[5] = then[5]
        out = carry(pred, now, known, rows, then[None], measured, 0.005)
        errors.append(float(np.linalg.norm(out[5] - pred[5])))
    # undeformed: fully carried (1 cm from pred); then ever closer to pred
    assert errors[0] == pytest.approx(0.01, abs=1e-9)
    assert 0.002 < errors[1] < 0.009 and errors[2] < 0.0005


@pytest.mark.parametrize("carry", [carry_last_seen, carry_last_seen_numba])
def test_carry_last_seen_needs_three_neighbours_seen_in_both_frames(carry) -> None:  # type: ignore[no-untyped-def]
    then = _bent_rope()
    now = then + 0.3
    known = np.zeros(10, dtype=bool)
    known[[3, 5]] = True  # two measured neighbours now
    measured = np.ones((1, 10), bool)
    pred = np.full((10, 3), 7.0)
    out = carry(pred, now, known, np.array([4]), then[None], measured, 0.005)
    np.testing.assert_array_equal(out, pred)
    known[[2, 6]] = True  # four now, but only two of them measured in the frame it was seen
    measured[0, [2, 6]] = False
    out = carry(pred, now, known, np.array([4]), then[None], measured, 0.005)
    np.testing.assert_array_equal(out, pred)
    measured[0, 6] = True  # three: carried (a translation by 0.3)
    out = carry(pred, now, known, np.array([4]), then[None], measured, 0.005)
    np.testing.assert_allclose(out[4], then[4] + 0.3, atol=1e-9)
