"""Functional joint centres and axes on exact synthetic rotations (no noise)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.solve import joint_centres as jc


def _two_segments(
    rng, child_rot, t=200, centre_p=(0.03, -0.08, 0.05), centre_c=(-0.01, 0.22, 0.02)
):
    """Parent moving freely; child turning about a centre fixed in both frames."""
    r_p = Rotation.from_rotvec(rng.normal(scale=0.4, size=(t, 3))).as_matrix()
    t_p = rng.normal(scale=0.5, size=(t, 3))
    r_c = r_p @ child_rot
    cp, cc = np.array(centre_p), np.array(centre_c)
    world = np.einsum("tij,j->ti", r_p, cp) + t_p
    t_c = world - np.einsum("tij,j->ti", r_c, cc)
    return r_p, t_p, r_c, t_c, cp, cc


def test_score_recovers_the_centre_exactly():
    rng = np.random.default_rng(1)
    rel = Rotation.from_rotvec(rng.normal(scale=0.6, size=(200, 3))).as_matrix()
    r_p, t_p, r_c, t_c, cp, cc = _two_segments(rng, rel)
    got_p, got_c, rms = jc.score_centre(r_p, t_p, r_c, t_c)
    np.testing.assert_allclose(got_p, cp, atol=1e-9)
    np.testing.assert_allclose(got_c, cc, atol=1e-9)
    assert rms < 1e-9


def test_score_with_a_prior_keeps_the_data_where_the_joint_turns_and_the_prior_where_not():
    rng = np.random.default_rng(11)
    # wide motion about every axis: the prior (3 cm off) changes nothing
    rel = Rotation.from_rotvec(rng.normal(scale=0.6, size=(200, 3))).as_matrix()
    r_p, t_p, r_c, t_c, cp, cc = _two_segments(rng, rel)
    prior = (cp + 0.03, cc - 0.03)
    got_p, got_c, _ = jc.score_centre(r_p, t_p, r_c, t_c, prior=prior, prior_spread_deg=10.0)
    np.testing.assert_allclose(got_p, cp, atol=1e-9)
    np.testing.assert_allclose(got_c, cc, atol=1e-9)
    # a hinge about z with 1 deg of wobble: along z the data barely speak, the prior does
    axis = np.array([0.0, 0.0, 1.0])
    turn = rng.uniform(-0.8, 0.8, size=(200, 1)) * axis + rng.normal(scale=0.017, size=(200, 3))
    r_p, t_p, r_c, t_c, cp, cc = _two_segments(rng, Rotation.from_rotvec(turn).as_matrix())
    prior = (cp + [0.004, -0.003, 0.02], cc + [0.004, -0.003, 0.02])
    got_p, got_c, _ = jc.score_centre(r_p, t_p, r_c, t_c, prior=prior, prior_spread_deg=10.0)
    # across the axis the data: the true centre (the weak direction is z up to the
    # wobble: 0.05 mm); along it the prior's 2 cm
    np.testing.assert_allclose(got_p[:2], cp[:2], atol=2e-4)
    assert got_p[2] - cp[2] == pytest.approx(0.02, abs=1e-3)
    # without a prior the exact data still give the centre (the wobble determines it)
    plain_p, _, _ = jc.score_centre(r_p, t_p, r_c, t_c)
    np.testing.assert_allclose(plain_p, cp, atol=1e-9)


def test_score_skips_frames_with_nan():
    rng = np.random.default_rng(2)
    rel = Rotation.from_rotvec(rng.normal(scale=0.6, size=(100, 3))).as_matrix()
    r_p, t_p, r_c, t_c, cp, cc = _two_segments(rng, rel, t=100)
    r_p[::7] = np.nan
    t_c[3::11] = np.nan
    got_p, got_c, _ = jc.score_centre(r_p, t_p, r_c, t_c)
    np.testing.assert_allclose(got_p, cp, atol=1e-9)


def test_sara_recovers_the_axis_exactly_and_the_point_nearest_the_prior():
    rng = np.random.default_rng(3)
    axis_c = np.array([0.2, 0.1, 0.97])
    axis_c /= np.linalg.norm(axis_c)
    angles = rng.uniform(-1.2, 0.2, size=150)
    rel = Rotation.from_rotvec(angles[:, None] * axis_c).as_matrix()
    r_p, t_p, r_c, t_c, cp, cc = _two_segments(rng, rel, t=150)
    # the child's axis in the parent's frame: rel maps child to parent coordinates
    # and rel @ axis_c = axis_c, so the axis has the same coordinates in both
    prior_p, prior_c = cp + 0.05 * axis_c + [0.01, 0.0, 0.0], cc + 0.05 * axis_c
    ap, ac, got_p, got_c = jc.sara_axis(r_p, t_p, r_c, t_c, prior_p, prior_c)
    assert abs(abs(ap @ axis_c) - 1.0) < 1e-9
    assert abs(abs(ac @ axis_c) - 1.0) < 1e-9
    # the chosen centre is on the true axis ...
    for got, c in ((got_p, cp), (got_c, cc)):
        off = (got - c) - axis_c * ((got - c) @ axis_c)
        assert np.linalg.norm(off) < 1e-9
    # ... at the priors' place along it, least squares over both frames (5 cm along
    # the axis, plus half the parent prior's 1 cm x-offset projected on the axis)
    np.testing.assert_allclose((got_p - cp) @ axis_c, 0.05 + 0.005 * axis_c[0], atol=1e-9)
    # and the two frames agree on it in every frame
    wp = np.einsum("tij,j->ti", r_p, got_p) + t_p
    wc = np.einsum("tij,j->ti", r_c, got_c) + t_c
    assert np.abs(wp - wc).max() < 1e-9


def test_sphere_fit_recovers_the_centre_from_one_or_two_markers():
    rng = np.random.default_rng(4)
    centre = np.array([0.05, -0.09, 0.02])
    rot = Rotation.from_rotvec(rng.normal(scale=0.5, size=(120, 3))).as_matrix()
    markers = np.array([[0.0, -0.2, 0.05], [0.04, -0.4, 0.0]])
    pts = centre + np.einsum("tij,kj->tki", rot, markers)
    pts[5, 0] = np.nan
    for k in (1, 2):
        got, axis = jc.sphere_centre(pts[:, :k])
        np.testing.assert_allclose(got, centre, atol=1e-9)
        assert axis is None


def test_sphere_fit_of_a_hinge_finds_its_axis():
    rng = np.random.default_rng(5)
    centre = np.array([0.0, -0.42, 0.01])
    axis = np.array([1.0, 0.05, -0.1])
    axis /= np.linalg.norm(axis)
    rot = Rotation.from_rotvec(rng.uniform(0, 1.5, size=(90, 1)) * axis).as_matrix()
    markers = np.array([[0.02, -0.2, 0.05], [0.05, -0.38, 0.0]])
    pts = centre + np.einsum("tij,kj->tki", rot, markers)
    prior = centre + 0.03 * axis + np.array([0.0, 0.01, 0.0])
    got, got_axis = jc.sphere_centre(pts, prior, hinge=True)
    assert abs(abs(got_axis @ axis) - 1.0) < 1e-9
    off = (got - centre) - axis * ((got - centre) @ axis)
    assert np.linalg.norm(off) < 1e-9


def test_motion_spread_measures_the_range_per_axis():
    rng = np.random.default_rng(6)
    r_p = Rotation.from_rotvec(rng.normal(scale=0.4, size=(400, 3))).as_matrix()
    angles = np.radians(20.0) * np.sin(np.linspace(0, 20 * np.pi, 400))
    rel = Rotation.from_rotvec(angles[:, None] * [0.0, 0.0, 1.0]).as_matrix()
    spread = jc.motion_spread(r_p, r_p @ rel)
    # RMS of a 20 deg sine is 20 / sqrt(2); the other axes do not move
    assert spread[0] == pytest.approx(20.0 / np.sqrt(2.0), rel=0.02)
    assert spread[1] < 1e-6


def test_harrington_matches_the_published_regression():
    # pelvis frame = world: x anterior -> world +Z, y up, right -> world -X (left on +X)
    lasi, rasi = np.array([[0.12, 1.0, 0.1]]), np.array([[-0.12, 1.0, 0.1]])
    lpsi, rpsi = np.array([[0.05, 1.0, -0.06]]), np.array([[-0.05, 1.0, -0.06]])
    left, right = jc.harrington_hip_centres(lasi, rasi, lpsi, rpsi)
    pw, pd = 0.24, 0.16
    expected_right = np.array(
        [-(0.33 * pw + 0.0073), 1.0 - 0.30 * pw - 0.0109, 0.1 - 0.24 * pd - 0.0099]
    )
    np.testing.assert_allclose(right[0], expected_right, atol=1e-12)
    np.testing.assert_allclose(left[0], expected_right * [-1, 1, 1], atol=1e-12)


def test_too_few_frames_is_an_error():
    eye = np.repeat(np.eye(3)[None], 2, axis=0)
    with pytest.raises(ValidationError):
        jc.score_centre(eye, np.zeros((2, 3)), eye, np.zeros((2, 3)))


def test_principal_axis_is_the_axis_the_joint_turns_about_most():
    rng = np.random.default_rng(21)
    axis = np.array([0.6, 0.0, 0.8])
    # a hinge about a fixed axis, in a mean pose turned away from the parent's frame
    turn = Rotation.from_rotvec(
        np.radians(40) * np.sin(np.linspace(0, 6 * np.pi, 300))[:, None] * axis
    )
    mean = Rotation.from_rotvec([0.3, -0.5, 0.2])
    r_p, t_p, r_c, t_c, _, _ = _two_segments(rng, (mean * turn).as_matrix(), t=300)
    ap, ac = jc.principal_axis(r_p, r_c)
    # the axis in the child's frame, and in the parent's the same line (a_p = M a_c)
    assert abs(ac @ axis) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(ap, mean.apply(ac), atol=1e-9)
    assert np.linalg.norm(ap) == pytest.approx(1.0)
    nan = np.full((2, 3, 3), np.nan)
    assert np.isnan(jc.principal_axis(nan, nan)[0]).all()


def test_slide_along_axis_changes_the_centre_only_along_the_axis():
    rng = np.random.default_rng(22)
    axis_c = np.array([0.0, 0.0, 1.0])
    turn = rng.uniform(-0.8, 0.8, size=(200, 1)) * axis_c
    r_p, t_p, r_c, t_c, cp, cc = _two_segments(rng, Rotation.from_rotvec(turn).as_matrix())
    ap, ac, got_p, got_c = jc.sara_axis(r_p, t_p, r_c, t_c)
    # a prior 2 cm along the axis and 1 cm across it: the centre goes 2 cm along, exactly
    prior_p = cp + 0.02 * ap + 0.01 * np.cross(ap, [1.0, 0.0, 0.0])
    prior_c = cc + 0.02 * ac
    sp, sc = jc.slide_along_axis(cp, cc, ap, ac, prior_p, prior_c)
    np.testing.assert_allclose(sp, cp + 0.02 * ap, atol=1e-9)
    np.testing.assert_allclose(sc, cc + 0.02 * ac, atol=1e-9)
    # the slid centre is still on the joint's axis: both frames place it at one point
    world_p = np.einsum("tij,j->ti", r_p, sp) + t_p
    world_c = np.einsum("tij,j->ti", r_c, sc) + t_c
    np.testing.assert_allclose(world_p, world_c, atol=1e-9)


def test_fit_singular_values_measure_the_range_about_each_axis():
    rng = np.random.default_rng(23)
    rel = Rotation.from_rotvec(rng.normal(scale=0.6, size=(400, 3))).as_matrix()
    r_p, t_p, r_c, t_c, _, _ = _two_segments(rng, rel, t=400)
    wide = jc.fit_singular_values(r_p, t_p, r_c, t_c)
    axis = np.array([0.0, 0.0, 1.0])
    hinge = Rotation.from_rotvec(rng.uniform(-0.8, 0.8, size=(400, 1)) * axis).as_matrix()
    r_p, t_p, r_c, t_c, _, _ = _two_segments(rng, hinge, t=400)
    narrow = jc.fit_singular_values(r_p, t_p, r_c, t_c)
    assert np.all(np.diff(wide) <= 0) and wide[0] < np.sqrt(2) + 1e-9
    assert wide[5] > 0.3  # turned well about every axis
    assert narrow[5] < 1e-9 < narrow[4]  # a hinge: its axis is the one direction not determined
    eye = np.repeat(np.eye(3)[None], 2, axis=0)
    assert not jc.fit_singular_values(eye, np.zeros((2, 3)), eye, np.zeros((2, 3))).any()
