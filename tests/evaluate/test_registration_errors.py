"""Surface-to-surface registration errors against an analytic case."""

from __future__ import annotations

import numpy as np
import pytest

from mesh_grids import grid_triangles
from skincap.errors import ValidationError
from skincap.evaluate.registration import (
    marker_normal_errors,
    marker_surface_bound,
    region_breakdown,
    registration_errors,
    true_marker_normals,
)


def _grid(n: int = 11, size: float = 0.5, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
    return v, grid_triangles(n, n)


def test_a_parallel_plane_is_its_offset_away_both_ways() -> None:
    true_v, true_f = _grid()
    reg_v, reg_f = _grid(n=7, z=0.004)  # other vertices, 4 mm above
    out = registration_errors(reg_v, reg_f, true_v, true_f, np.array([0.0005, np.nan, 0.0015]))
    for key in ("surface_to_true_skin", "true_skin_to_surface"):
        for stat in ("mean", "p95", "max"):
            assert out[f"{key}_{stat}_m"] == pytest.approx(0.004, abs=1e-12)
    assert out["markers_to_surface_mean_m"] == pytest.approx(0.001)
    assert out["targets"]["surface_to_true_skin_mean_m"]["met"] is False
    assert out["targets"]["markers_to_surface_mean_m"]["met"] is True


def test_a_missing_half_shows_only_from_the_true_side() -> None:
    true_v, true_f = _grid()
    half = true_v[:, 0] <= 0.25 + 1e-9
    keep = half[true_f].all(axis=1)
    remap = np.cumsum(half) - 1
    out = registration_errors(true_v[half], remap[true_f[keep]], true_v, true_f)
    assert out["surface_to_true_skin_max_m"] == pytest.approx(0.0, abs=1e-12)
    assert out["true_skin_to_surface_max_m"] == pytest.approx(0.25)
    assert "markers_to_surface_mean_m" not in out


def test_nan_vertices_are_refused() -> None:
    v, f = _grid()
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValidationError, match="registered"):
        registration_errors(bad, f, v, f)


def test_regions_say_where_the_tail_comes_from() -> None:
    # the true plane is split in two regions; the registered plane is 1 mm above over
    # x < 0.25 and 10 mm above beyond: the worst 5 % must all lie in the far region
    true_v, true_f = _grid(n=21)
    regions = np.where(true_v[:, 0] < 0.25, "near", "far")
    reg_v, reg_f = _grid(n=21)
    reg_v[:, 2] = np.where(reg_v[:, 0] < 0.25, 0.001, 0.010)
    out = registration_errors(reg_v, reg_f, true_v, true_f, regions=regions)
    rows = {r["region"]: r for r in out["regions"]}
    assert [r["region"] for r in out["regions"]][0] == "far"
    assert rows["far"]["tail_share"] == pytest.approx(1.0)
    assert rows["near"]["tail_share"] == 0.0
    assert rows["near"]["mean_m"] == pytest.approx(0.001, abs=1e-9)
    assert rows["far"]["p95_m"] == pytest.approx(0.010, abs=1e-9)
    assert sum(r["vertices"] for r in out["regions"]) == reg_v.shape[0]
    assert "regions" not in registration_errors(reg_v, reg_f, true_v, true_f)


def test_region_names_must_match_the_true_vertices() -> None:
    v, f = _grid()
    with pytest.raises(ValidationError, match="regions"):
        registration_errors(v, f, v, f, regions=np.array(["a", "b"]))
    with pytest.raises(ValidationError, match="regions"):
        region_breakdown(np.zeros(3), np.array(["a"]))


def _sphere(radius: float, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangulated sphere (Fibonacci points, hull faces turned outward)."""
    from scipy.spatial import ConvexHull

    k = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    v = np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1
    )
    f = ConvexHull(v).simplices
    outward = np.einsum(
        "fx,fx->f", np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), v[f].mean(axis=1)
    )
    f[outward < 0] = f[outward < 0][:, ::-1]
    return radius * v, f


@pytest.mark.parametrize(("scale", "inside"), [(0.97, 1.0), (1.03, 0.0)])
def test_a_shrunken_or_inflated_sphere_lies_on_its_side(scale: float, inside: float) -> None:
    true_v, true_f = _sphere(0.1)
    reg_v, reg_f = _sphere(0.1 * scale, n=150)  # other vertices
    regions = np.where(true_v[:, 2] > 0, "top", "bottom")
    out = registration_errors(reg_v, reg_f, true_v, true_f, regions=regions)
    assert out["surface_to_true_skin_inside_fraction"] == inside
    for row in out["regions"]:
        # the chords of the true sphere's triangles lie up to ~1 mm inside it
        assert row["signed_mean_m"] == pytest.approx(0.1 * (scale - 1.0), abs=1.5e-3)
        assert row["tail_inside_fraction"] in (inside, None)


def test_the_tail_says_whether_it_sank_or_bulged() -> None:
    # the registered plane sinks 1 mm under the skin over x < 0.25 and stands 10 mm
    # out of it beyond (the grid's triangles face +z: outside is +z)
    true_v, true_f = _grid(n=21)
    regions = np.where(true_v[:, 0] < 0.25, "near", "far")
    reg_v, reg_f = _grid(n=21)
    reg_v[:, 2] = np.where(reg_v[:, 0] < 0.25, -0.001, 0.010)
    out = registration_errors(reg_v, reg_f, true_v, true_f, regions=regions)
    rows = {r["region"]: r for r in out["regions"]}
    assert rows["near"]["signed_mean_m"] == pytest.approx(-0.001, abs=1e-9)
    assert rows["far"]["signed_mean_m"] == pytest.approx(0.010, abs=1e-9)
    assert rows["far"]["tail_inside_fraction"] == 0.0
    assert rows["near"]["tail_inside_fraction"] is None  # none of the worst 5 % there
    near = reg_v[:, 0] < 0.25
    assert out["surface_to_true_skin_inside_fraction"] == pytest.approx(near.mean())
    reg_v[:, 2] = -0.010  # all of it under the skin now
    rows = {
        r["region"]: r
        for r in registration_errors(reg_v, reg_f, true_v, true_f, regions=regions)["regions"]
    }
    assert rows["far"]["tail_inside_fraction"] == 1.0


_BOUND = {"marker_radius": 0.0015, "max_distance": 0.03, "patch_ratio": 0.5}


def _markers_on(radius: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Markers one marker radius above a sphere of ``radius``, and their triangles."""
    m, f = _sphere(radius + _BOUND["marker_radius"], n=n)
    return m, f


def test_the_marker_surface_of_a_sphere_speaks_for_all_of_it_closely() -> None:
    # 60 markers ~5 cm apart on a 10 cm head: the smoothed marker surface lands on the
    # sphere (its Phong lift is exact there) where flat triangles cut 3-5 mm under it
    skin_v, skin_f = _sphere(0.1, n=3000)
    markers, marker_f = _markers_on(0.1, 60)
    out = marker_surface_bound(skin_v, skin_f, markers, marker_f, **_BOUND)
    assert out["covered_area_fraction"] == pytest.approx(1.0)
    assert out["target_p95_m"] < 0.5e-3
    assert out["target_over_8mm_area_fraction"] == 0.0


def test_a_bump_between_markers_and_a_bare_half_show_in_their_regions() -> None:
    skin_v, skin_f = _sphere(0.1, n=3000)
    markers, marker_f = _markers_on(0.1, 60)
    # a 10 mm bump on the skin at the middle of a marker triangle: no marker sees it
    centre = markers[marker_f[0]].mean(axis=0)
    centre /= np.linalg.norm(centre)
    unit = skin_v / np.linalg.norm(skin_v, axis=1, keepdims=True)
    angle = np.arccos(np.clip(unit @ centre, -1.0, 1.0))
    height = 0.010 * np.clip(1.0 - angle / 0.25, 0.0, None) ** 2
    bumped = skin_v + height[:, None] * unit
    regions = np.where(angle < 0.1, "bump", "rest")
    out = marker_surface_bound(bumped, skin_f, markers, marker_f, regions=regions, **_BOUND)
    rows = {r["region"]: r for r in out["regions"]}
    assert out["regions"][0]["region"] == "bump"
    assert rows["bump"]["target_mean_m"] > 3e-3  # its 3.6-10 mm height, less its slope
    assert rows["rest"]["target_mean_m"] < 0.5e-3
    # markers on the upper half only: the lower half has no marker surface over it
    upper = markers[:, 2] > 0.0
    keep = upper[marker_f].all(axis=1)
    half = marker_surface_bound(
        skin_v, skin_f, np.where(upper[:, None], markers, np.nan), marker_f[keep], **_BOUND
    )
    assert 0.3 < half["covered_area_fraction"] < 0.6
    assert half["target_p95_m"] < 1e-3


def test_the_bound_refuses_a_broken_skin() -> None:
    skin_v, skin_f = _sphere(0.1, n=200)
    markers, marker_f = _markers_on(0.1, 60)
    bad = skin_v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValidationError, match="true_vertices"):
        marker_surface_bound(bad, skin_f, markers, marker_f, **_BOUND)
    with pytest.raises(ValidationError, match="regions"):
        marker_surface_bound(skin_v, skin_f, markers, marker_f, regions=np.array(["a"]), **_BOUND)


def test_normal_errors_are_the_tilt_of_a_shifted_template() -> None:
    """A registered sphere shifted 1 cm off the true one: its normals around each marker
    (the patch meets it in a cap about the line from its centre through the marker)
    are off the true radial normals by the angle between the two lines; Max's normals,
    from the markers alone, are exact on the sphere whatever the template."""
    skin_v, skin_f = _sphere(0.1, n=3000)
    markers, marker_f = _markers_on(0.1, 60)
    shift = np.array([0.0, 0.0, 0.01])
    reg_v, reg_f = _sphere(0.1, n=4000)
    truth = true_marker_normals(skin_v, skin_f, markers)
    np.testing.assert_allclose(
        truth, markers / np.linalg.norm(markers, axis=1, keepdims=True), atol=1e-2
    )
    regions = np.where(np.abs(skin_v[:, 2]) < 0.05, "equator", "poles")
    same = marker_normal_errors(reg_v, reg_f, skin_v, skin_f, markers, marker_f, patch_ratio=0.5)
    assert same["markers"] == 60 and same["error_mean_deg"] < 0.5
    moved = marker_normal_errors(
        reg_v + shift, reg_f, skin_v, skin_f, markers, marker_f, patch_ratio=0.5, regions=regions
    )
    away = markers - shift
    expected = np.degrees(
        np.arccos(np.einsum("kx,kx->k", away / np.linalg.norm(away, axis=1, keepdims=True), truth))
    )
    assert expected.mean() > 3.0
    assert moved["error_mean_deg"] == pytest.approx(expected.mean(), abs=0.3)
    assert moved["error_p95_deg"] == pytest.approx(np.percentile(expected, 95), abs=0.5)
    assert moved["regions"][0]["region"] == "equator"  # tilted most where the shift is sideways
    own = marker_normal_errors(
        reg_v + shift, reg_f, skin_v, skin_f, markers, marker_f, patch_ratio=0.0
    )
    assert own["error_mean_deg"] < 0.5
    with pytest.raises(ValidationError, match="regions"):
        marker_normal_errors(
            reg_v, reg_f, skin_v, skin_f, markers, marker_f, patch_ratio=0.5,
            regions=np.array(["a"]),
        )  # fmt: skip


def test_the_bound_with_the_true_normals_beats_the_patch_on_an_elongated_head() -> None:
    """An elongated ellipsoid skin (12 x 5 x 4 cm) under 30 uneven markers: the true
    normals at the markers lift the marker surface closer to the skin than the skin's
    own patch means do, and on a sphere both are exact."""
    axes = np.array([0.05, 0.04, 0.12])
    unit_v, skin_f = _sphere(1.0, n=3000)
    skin_v = unit_v * axes
    rng = np.random.default_rng(4)
    unit_m, marker_f = _sphere(1.0, n=30)
    on = unit_m + 0.25 * rng.normal(size=unit_m.shape)
    on /= np.linalg.norm(on, axis=1, keepdims=True)
    surface = on * axes
    gradient = surface / axes**2
    markers = surface + _BOUND["marker_radius"] * gradient / np.linalg.norm(
        gradient, axis=1, keepdims=True
    )
    from scipy.spatial import ConvexHull

    marker_f = ConvexHull(on).simplices
    out = marker_surface_bound(skin_v, skin_f, markers, marker_f, **_BOUND)
    exact = out["exact_normals"]
    assert exact["covered_area_fraction"] > 0.8
    assert exact["target_mean_m"] < 0.9 * out["target_mean_m"]  # 0.66 vs 0.77 mm
    sphere_v, sphere_f = _sphere(0.1, n=3000)
    ball, ball_f = _markers_on(0.1, 60)
    on_ball = marker_surface_bound(sphere_v, sphere_f, ball, ball_f, **_BOUND)["exact_normals"]
    assert on_ball["target_p95_m"] < 0.5e-3
