"""Sweep surfaces of key ellipses (Hyun et al. §3): cylinders, interpolation, frames, queries."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from skincap.errors import ValidationError
from skincap.geometry.rotations import quat_angle
from skincap.geometry.sweep import (
    KeyEllipses,
    Sweep,
    chord_length_params,
    frames_from_axes,
    rotation_minimising_frames,
    smooth_union,
)


def _straight(radius=0.1, length=1.0, n=4, caps=(0.0, 0.0), radii=None):
    z = np.linspace(0.0, length, n)
    c = np.stack([np.zeros(n), np.zeros(n), z], axis=1)
    fr = frames_from_axes(np.tile([0.0, 0.0, 1.0], (n, 1)), np.tile([1.0, 0.0, 0.0], (n, 1)))
    r = np.full((n, 2), radius) if radii is None else radii
    return Sweep(KeyEllipses.from_frames(c, fr, r), caps=caps)


def test_constant_circle_is_a_cylinder():
    r, length = 0.1, 1.0
    s = _straight(r, length)
    v, f = s.tube(n_rings=8, n_around=512)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.euler_number == 2
    assert mesh.volume == pytest.approx(np.pi * r * r * length, rel=1e-4)
    assert mesh.area == pytest.approx(2 * np.pi * r * length + 2 * np.pi * r * r, rel=1e-4)
    assert s.volume() == pytest.approx(np.pi * r * r * length, rel=1e-10)


def test_elliptic_cylinder_with_caps_volume():
    a, b, length, c0, c1 = 0.12, 0.05, 0.8, 0.05, 0.2
    s = _straight(length=length, caps=(c0, c1), radii=np.tile([a, b], (4, 1)))
    expect = np.pi * a * b * length + (2 / 3) * np.pi * a * b * (c0 + c1)
    assert s.volume() == pytest.approx(expect, rel=1e-10)
    v, f = s.tube(n_rings=4, n_around=512, cap_rings=256)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.volume == pytest.approx(expect, rel=1e-3)
    # the caps reach c0 before the start and c1 past the end
    assert v[:, 2].min() == pytest.approx(-c0)
    assert v[:, 2].max() == pytest.approx(length + c1)


def _curved_keys(n=6, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1.5, n)
    c = np.stack([np.sin(t), 0.3 * t, np.cos(t)], axis=1) + 0.01 * rng.standard_normal((n, 3))
    tang = np.gradient(c, axis=0)
    fr = frames_from_axes(tang, np.tile([0.0, 1.0, 0.0], (n, 1)))
    r = np.stack([0.08 + 0.02 * rng.random(n), 0.05 + 0.02 * rng.random(n)], axis=1)
    return KeyEllipses.from_frames(c, fr, r)


@pytest.mark.parametrize("orientation", ["slerp", "nlerp"])
def test_interpolation_passes_through_keys(orientation):
    keys = _curved_keys()
    s = Sweep(keys, orientation=orientation)
    c, fr, r = s.evaluate(keys.params)
    np.testing.assert_allclose(c, keys.centres, atol=1e-12)
    np.testing.assert_allclose(r, keys.radii, atol=1e-12)
    np.testing.assert_allclose(fr, keys.frames, atol=1e-9)
    assert quat_angle(s.quaternions(keys.params), keys.rotations).max() < 1e-7


def test_chord_length_params():
    c = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 3.0, 0]])
    np.testing.assert_allclose(chord_length_params(c), [0.0, 0.25, 1.0])
    with pytest.raises(ValidationError, match="coincide"):
        chord_length_params(np.zeros((3, 3)))


def test_frames_orthonormal_and_right_handed():
    s = Sweep(_curved_keys())
    t = np.linspace(*s.t_range, 101)
    fr = s.frames(t)
    np.testing.assert_allclose(
        np.einsum("nji,njk->nik", fr, fr), np.tile(np.eye(3), (101, 1, 1)), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(fr), 1.0, atol=1e-12)
    # radii interpolation never leaves the keys' range (monotone PCHIP)
    r = s.radii(t)
    assert (r >= s.keys.radii.min(axis=0) - 1e-12).all()
    assert (r <= s.keys.radii.max(axis=0) + 1e-12).all()


def test_slerp_constant_angular_speed():
    q0 = frames_from_axes(np.array([0.0, 0, 1]), np.array([1.0, 0, 0]))
    ang = np.pi / 2
    rot = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    c = np.array([[0.0, 0, 0], [0, 0, 1.0]])
    keys = KeyEllipses.from_frames(c, np.stack([q0, rot @ q0]), np.full((2, 2), 0.1))
    s = Sweep(keys)
    t = np.linspace(0, 1, 11)
    fr = s.frames(t)
    angles = np.arctan2(fr[:, 1, 0], fr[:, 0, 0])
    np.testing.assert_allclose(angles, ang * t, atol=1e-12)


def test_rotation_minimising_frames_on_a_helix():
    u = np.linspace(0, 4 * np.pi, 400)
    pts = np.stack([np.cos(u), np.sin(u), 0.3 * u], axis=1)
    tang = np.stack([-np.sin(u), np.cos(u), 0.3 * np.ones_like(u)], axis=1)
    fr = rotation_minimising_frames(pts, tang)
    np.testing.assert_allclose(
        np.einsum("nji,njk->nik", fr, fr), np.tile(np.eye(3), (400, 1, 1)), atol=1e-10
    )
    np.testing.assert_allclose(
        fr[:, :, 2], tang / np.linalg.norm(tang, axis=1, keepdims=True), atol=1e-12
    )
    # rotation minimising: the normal's derivative has no component along the binormal
    da = np.gradient(fr[:, :, 0], axis=0)
    twist = np.einsum("ij,ij->i", da, fr[:, :, 1])
    assert np.abs(twist[2:-2]).max() < 1e-4


def test_rmf_straight_line_keeps_first_axis():
    pts = np.stack([np.zeros(10), np.zeros(10), np.linspace(0, 1, 10)], axis=1)
    fr = rotation_minimising_frames(pts, first_axis=np.array([0.0, 1.0, 0.2]))
    np.testing.assert_allclose(fr[:, :, 0], np.tile([0.0, 1.0, 0.0], (10, 1)), atol=1e-12)


def test_signed_distance_of_a_capsule():
    r, length = 0.1, 1.0
    s = _straight(r, length, caps=(r, r))
    rng = np.random.default_rng(1)
    p = rng.uniform([-0.3, -0.3, -0.3], [0.3, 0.3, 1.3], size=(5000, 3))
    zc = np.clip(p[:, 2], 0.0, length)
    exact = np.linalg.norm(p - np.stack([0 * zc, 0 * zc, zc], axis=1), axis=1) - r
    np.testing.assert_allclose(s.signed_distance(p), exact, atol=1e-9)
    np.testing.assert_array_equal(s.contains(p), exact < 0)


def test_locate_binds_to_the_containing_plane():
    s = Sweep(_curved_keys())
    t = np.linspace(*s.t_range, 7)[1:-1]
    c, fr, r = s.evaluate(t)
    # points on the ellipses at those parameters
    theta = np.linspace(0, 2 * np.pi, 7)[:-1]
    pts = s.surface_points(theta, t).reshape(-1, 3)
    tt, local, end = s.locate(pts, n_planes=2000)
    np.testing.assert_allclose(tt, np.repeat(t, theta.size), atol=2e-3)
    assert (end == 0).all()
    assert np.abs(s.signed_distance(pts, n_planes=2000)).max() < 2e-3 * 0.1 + 1e-3


def test_mirrored_keys():
    keys = _curved_keys()
    m = keys.mirrored(0)
    np.testing.assert_allclose(m.centres, keys.centres * [-1, 1, 1])
    assert (np.linalg.det(m.frames) > 0).all()
    s, sm = Sweep(keys, caps=(0.02, 0.03)), Sweep(m, caps=(0.02, 0.03))
    p = np.random.default_rng(2).uniform(-1, 1.5, (2000, 3))
    np.testing.assert_allclose(sm.signed_distance(p * [-1, 1, 1]), s.signed_distance(p), atol=1e-9)


def test_nan_points_give_nan():
    s = _straight()
    p = np.array([[0.0, 0.0, 0.5], [np.nan, 0.0, 0.5]])
    d = s.signed_distance(p)
    assert d[0] == pytest.approx(-0.1) and np.isnan(d[1])
    assert s.contains(p).tolist() == [True, False]


@settings(max_examples=40, deadline=None)
@given(
    d=st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=6),
    k=st.floats(1e-3, 0.1),
)
def test_smooth_union_bounds(d, k):
    arr = np.array(d)
    u = smooth_union(arr, k)
    assert u <= arr.min() + 1e-12
    assert u >= arr.min() - k * np.log(arr.size) - 1e-12


def test_smooth_union_far_parts_and_inf():
    assert smooth_union(np.array([0.0, 1.0]), 0.01) == pytest.approx(0.0, abs=1e-30)
    assert smooth_union(np.array([np.inf, np.inf]), 0.01) == np.inf
    assert smooth_union(np.array([0.2, np.inf]), 0.01) == pytest.approx(0.2)
    with pytest.raises(ValidationError):
        smooth_union(np.zeros(2), 0.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"params": [0, 0], "radii": np.full((2, 2), 0.1)}, "increasing"),
        ({"params": [0, 1], "radii": np.array([[0.1, 0.1], [0.1, -0.1]])}, "positive"),
        ({"params": [0, 1], "radii": np.full((2, 2), np.nan)}, "finite"),
        ({"params": [0, 1, 2], "radii": np.full((2, 2), 0.1)}, "shape"),
    ],
)
def test_bad_keys(kwargs, match):
    c = np.array([[0.0, 0, 0], [0, 0, 1.0]])
    q = np.tile([0.0, 0, 0, 1.0], (2, 1))
    with pytest.raises(ValidationError, match=match):
        KeyEllipses(centres=c, rotations=q, **kwargs)


def test_bad_sweep_arguments():
    keys = _curved_keys()
    with pytest.raises(ValidationError, match="orientation"):
        Sweep(keys, orientation="linear")
    with pytest.raises(ValidationError, match="caps"):
        Sweep(keys, caps=(-1.0, 0.0))
    with pytest.raises(ValidationError, match="parallel"):
        frames_from_axes(np.array([0.0, 0, 1]), np.array([0.0, 0, 2]))
    with pytest.raises(ValidationError, match="points"):
        Sweep(keys).locate(np.zeros((3, 2)))
