"""The skinning artefacts measured: volume and cross-section loss, LBS against DQS."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from skincap.deform.skeletal.artefacts import (
    artefact_table,
    capped_cylinder,
    capped_volume,
    enclosed_volume,
    joint_pose_matrices,
    section_radius,
    two_bone_cylinder,
)
from skincap.errors import ValidationError
from skincap.io.makehuman import read_makehuman


@pytest.fixture(scope="module")
def body(data_dir):
    return read_makehuman(data_dir / "makehuman_base.obj")


@pytest.fixture(scope="module")
def table(body) -> dict[tuple[str, str], dict]:
    return {(r["case"], r["method"]): r for r in artefact_table(body)}


def test_cylinder_mesh_is_closed_and_outward() -> None:
    m = capped_cylinder(0.04, 0.5, n_around=48, n_along=101)
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    exact = 0.5 * 48 * 0.04**2 * np.sin(2 * np.pi / 48) * 0.5  # prism over the 48-gon
    assert enclosed_volume(m.vertices, m.faces) == pytest.approx(exact, rel=1e-12)
    assert tm.volume == pytest.approx(exact, rel=1e-12)
    # origin-independent for a closed surface, and capped_volume of it is the same
    shifted = m.vertices + np.array([3.0, -2.0, 7.0])
    assert enclosed_volume(shifted, m.faces) == pytest.approx(exact, rel=1e-9)
    assert capped_volume(m.vertices, m.faces) == pytest.approx(exact, rel=1e-12)
    # frames broadcast
    both = np.stack([m.vertices, 2.0 * m.vertices])
    np.testing.assert_allclose(enclosed_volume(both, m.faces), [exact, 8 * exact], rtol=1e-12)


def test_capped_region_volume_is_the_sub_prism() -> None:
    m = capped_cylinder(0.04, 0.5, n_around=32, n_along=51)
    x = m.vertices[:, 0]
    region = (x >= 0.1 - 1e-12) & (x <= 0.3 + 1e-12)
    exact = 0.5 * 32 * 0.04**2 * np.sin(2 * np.pi / 32) * 0.2
    shifted = m.vertices + np.array([1.0, 2.0, -3.0])
    assert capped_volume(m.vertices, m.faces, region) == pytest.approx(exact, rel=1e-12)
    assert capped_volume(shifted, m.faces, region) == pytest.approx(exact, rel=1e-9)
    with pytest.raises(ValidationError, match="no face"):
        capped_volume(m.vertices, m.faces, np.zeros(m.n_vertices, dtype=bool))
    with pytest.raises(ValidationError, match="vertex_mask"):
        capped_volume(m.vertices, m.faces, np.ones(3, dtype=bool))


def test_section_radius() -> None:
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = np.stack([np.zeros(64), 0.3 * np.cos(t), 0.3 * np.sin(t)], axis=1)
    assert section_radius(circle) == pytest.approx(0.3, rel=1e-12)
    ellipse = circle * np.array([1.0, 1.0, 0.5])
    assert section_radius(ellipse) == pytest.approx(0.15, rel=1e-12)
    assert section_radius(np.zeros((10, 3))) == 0.0


def test_two_bone_cylinder_rig_and_rest_pose() -> None:
    m = two_bone_cylinder()
    w = m.skin.joint_weights
    joint_ring = m.meta["rings"][50]
    np.testing.assert_allclose(w[joint_ring], 0.5)
    assert (w[m.vertices[:, 0] < 0.2][:, 1] == 0).all() and (
        w[m.vertices[:, 0] > 0.3][:, 1] == 1
    ).all()
    ident = joint_pose_matrices(m.skin, 1, np.eye(3))
    np.testing.assert_allclose(ident, np.tile(np.eye(4), (3, 1, 1)))


def test_cylinder_twist_candy_wrapper(table) -> None:
    lbs = table[("cylinder twist 180 deg", "lbs")]
    dqs = table[("cylinder twist 180 deg", "dqs")]
    # LBS: the ring at the joint collapses onto the axis; a quarter of the joint region is lost
    assert lbs["min_radius_ratio"] < 1e-9
    assert -30.0 < lbs["volume_change_pct"] < -20.0
    # DQS keeps it (the small loss is the chords of the twisted triangles)
    assert abs(dqs["volume_change_pct"]) < 1.5
    assert dqs["min_radius_ratio"] > 0.999


def test_cylinder_bend_collapsing_elbow(table) -> None:
    lbs = table[("cylinder bend 150 deg", "lbs")]
    dqs = table[("cylinder bend 150 deg", "dqs")]
    # LBS at the joint: the ring is flattened to sin(15 deg) of its radius
    assert lbs["min_radius_ratio"] == pytest.approx(np.sin(np.radians(15.0)), rel=1e-6)
    assert -16.0 < lbs["volume_change_pct"] < -8.0
    assert abs(dqs["volume_change_pct"]) < 1.5
    assert dqs["min_radius_ratio"] > 0.99


def test_makehuman_forearm_and_elbow(table) -> None:
    twist_l = table[("body forearm twist 180 deg", "lbs")]
    twist_d = table[("body forearm twist 180 deg", "dqs")]
    assert twist_l["volume_change_pct"] < -40.0 and twist_l["min_radius_ratio"] < 0.4
    assert abs(twist_d["volume_change_pct"]) < 3.0 and twist_d["min_radius_ratio"] > 0.95
    # the whole forearm twisted at a bent elbow: DQS loses much less than LBS
    el = table[("body elbow twist 180 deg", "lbs")]
    ed = table[("body elbow twist 180 deg", "dqs")]
    assert el["volume_change_pct"] < -20.0
    assert ed["volume_change_pct"] > el["volume_change_pct"] + 15.0
    assert ed["min_radius_ratio"] > el["min_radius_ratio"] + 0.15
    # the strongly bent elbow: both lose volume where the inner side folds through
    # itself; LBS more, and only LBS flattens the cross-sections
    bl = table[("body elbow bend 150 deg", "lbs")]
    bd = table[("body elbow bend 150 deg", "dqs")]
    assert bl["rotation_deg"] == pytest.approx(103.8, abs=0.5)
    assert bl["volume_change_pct"] == pytest.approx(-21.1, abs=3.0)
    assert bd["volume_change_pct"] == pytest.approx(-17.9, abs=3.0)
    assert bl["min_radius_ratio"] < 0.7 and bd["min_radius_ratio"] > 0.85


def test_sweep_keeps_volume_and_sections(table) -> None:
    """The sweep deformer (Hyun et al.): constant volume and no collapse, the paper's claim.

    Bounds: the cylinder's twist and bend regions within 5 % of their rest volume and
    the body's within 5 % (LBS loses 12-53 %, DQS up to 18 % at the bent elbow); no
    section thinner than 0.9 of its rest radius where LBS goes to 0-0.6.
    """
    for case in (
        "cylinder twist 180 deg",
        "cylinder bend 150 deg",
        "body forearm twist 180 deg",
        "body elbow twist 180 deg",
        "body elbow bend 150 deg",
    ):
        sweep, lbs = table[(case, "sweep")], table[(case, "lbs")]
        assert abs(sweep["volume_change_pct"]) < 5.0, (case, sweep)
        assert sweep["min_radius_ratio"] > 0.9, (case, sweep)
        assert abs(sweep["volume_change_pct"]) < abs(lbs["volume_change_pct"]) / 3.0
        assert sweep["min_radius_ratio"] > lbs["min_radius_ratio"]
    # at the strongly bent elbow the sweep keeps what DQS loses
    bent = table[("body elbow bend 150 deg", "dqs")]
    assert (
        abs(table[("body elbow bend 150 deg", "sweep")]["volume_change_pct"])
        < abs(bent["volume_change_pct"]) - 10.0
    )


def test_table_rows_and_body_closed(body) -> None:
    rows = artefact_table()
    assert [(r["case"], r["method"]) for r in rows] == [
        ("cylinder twist 180 deg", "lbs"),
        ("cylinder twist 180 deg", "dqs"),
        ("cylinder twist 180 deg", "sweep"),
        ("cylinder bend 150 deg", "lbs"),
        ("cylinder bend 150 deg", "dqs"),
        ("cylinder bend 150 deg", "sweep"),
    ]
    assert set(rows[0]) == {
        "case",
        "method",
        "volume_change_pct",
        "min_radius_ratio",
        "rest_volume_m3",
        "rotation_deg",
    }
    # the MakeHuman body is a closed surface: 55 litres
    assert enclosed_volume(body.vertices, body.faces) == pytest.approx(0.0549, abs=0.0005)
    assert capped_volume(body.vertices, body.faces) == pytest.approx(
        enclosed_volume(body.vertices, body.faces), rel=1e-12
    )
