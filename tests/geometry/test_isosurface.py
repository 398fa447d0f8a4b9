"""Marching tetrahedra and relaxation on analytic fields."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from skincap.errors import ValidationError
from skincap.geometry.isosurface import marching_tetrahedra, relax_on_isosurface, taubin_smooth


def _grid(h=0.05, n=16):
    x = np.arange(-n, n + 1) * h
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return X, Y, Z, np.full(3, x[0]), h


def test_sphere_closed_oriented_accurate():
    X, Y, Z, o, h = _grid()
    f = np.sqrt(X**2 + Y**2 + Z**2) - 0.5
    v, faces = marching_tetrahedra(f, o, h)
    tm = trimesh.Trimesh(v, faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent and tm.euler_number == 2
    assert tm.volume == pytest.approx(4 / 3 * np.pi * 0.125, rel=0.01)  # positive: outward
    assert np.abs(np.linalg.norm(v, axis=1) - 0.5).max() < 0.1 * h
    r = relax_on_isosurface(v, faces, f, o, h)
    assert np.abs(np.linalg.norm(r, axis=1) - 0.5).max() < 0.05 * h
    tr = trimesh.Trimesh(r, faces, process=False)
    assert tr.area_faces.min() > 0.01 * h * h  # the slivers are gone
    assert tm.area_faces.min() < 1e-3 * h * h


def test_torus_genus_one_and_two_components():
    X, Y, Z, o, h = _grid(0.04, 20)
    torus = np.sqrt((np.sqrt(X**2 + Y**2) - 0.45) ** 2 + Z**2) - 0.15
    tm = trimesh.Trimesh(*marching_tetrahedra(torus, o, h), process=False)
    assert tm.is_watertight and tm.euler_number == 0
    balls = np.minimum(
        np.sqrt((X - 0.4) ** 2 + Y**2 + Z**2) - 0.2, np.sqrt((X + 0.4) ** 2 + Y**2 + Z**2) - 0.2
    )
    tb = trimesh.Trimesh(*marching_tetrahedra(balls, o, h), process=False)
    assert tb.is_watertight and tb.euler_number == 4 and len(tb.split()) == 2


def test_field_negative_on_border_is_closed():
    f = -np.ones((4, 5, 6))
    v, faces = marching_tetrahedra(f, np.zeros(3), 1.0)
    tm = trimesh.Trimesh(v, faces, process=False)
    assert tm.is_watertight and tm.volume > 0
    assert v.min(axis=0) == pytest.approx([-0.5, -0.5, -0.5])


def test_empty_field():
    v, faces = marching_tetrahedra(np.ones((3, 3, 3)), np.zeros(3), 1.0)
    assert v.shape == (0, 3) and faces.shape == (0, 3)


def test_taubin_keeps_volume_and_smooths():
    X, Y, Z, o, h = _grid()
    f = np.sqrt(X**2 + Y**2 + Z**2) - 0.5
    v, faces = marching_tetrahedra(f, o, h)
    noisy = v + 0.01 * np.random.default_rng(0).standard_normal(v.shape)
    s = taubin_smooth(noisy, faces, iterations=10)
    err = lambda p: np.abs(np.linalg.norm(p, axis=1) - 0.5).mean()  # noqa: E731
    assert err(s) < 0.5 * err(noisy)
    vol = trimesh.Trimesh(s, faces, process=False).volume
    assert vol == pytest.approx(4 / 3 * np.pi * 0.125, rel=0.03)


@pytest.mark.parametrize(
    "values, origin, spacing, match",
    [
        (np.ones((3, 3)), np.zeros(3), 1.0, "shape"),
        (np.full((3, 3, 3), np.nan), np.zeros(3), 1.0, "finite"),
        (np.ones((3, 3, 3)), np.zeros(2), 1.0, "origin"),
        (np.ones((3, 3, 3)), np.zeros(3), 0.0, "spacing"),
    ],
)
def test_bad_input(values, origin, spacing, match):
    with pytest.raises(ValidationError, match=match):
        marching_tetrahedra(values, origin, spacing)
