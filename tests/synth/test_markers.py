"""Tests of skincap.synth.markers on the MakeHuman body."""

from __future__ import annotations

import numpy as np
import pytest
from markers_posing import arm_across_belly
from scipy.spatial import cKDTree

from skincap.errors import ValidationError
from skincap.geometry.raycast import closest_points_on_mesh
from skincap.io.makehuman import read_makehuman
from skincap.synth.inputs import build_body
from skincap.synth.markers import (
    PELVIS_BOUND_WEIGHT,
    SPARSE_LABELS,
    MarkerLayout,
    _joint_positions,
    _landmark_joints,
    _pelvis_weight,
    dense_marker_layout,
    place_markers,
    sparse_marker_layout,
)
from skincap.synth.surface_sampling import vertex_normals
from skincap.types import Mesh

DATA = "tests/data/makehuman_base.obj"


@pytest.fixture(scope="module")
def body() -> Mesh:
    return read_makehuman(DATA)


@pytest.fixture(scope="module")
def dense(body) -> MarkerLayout:
    return dense_marker_layout(body)


# ---------------------------------------------------------------- dense layout
def test_dense_count_regions_and_spacing(dense, body) -> None:
    n = dense.n_markers
    assert 315 <= n <= 385  # target 350 within 10 %
    assert len(set(dense.labels)) == n and dense.labels[0] == "D000"
    region = np.array(dense.meta["region"])
    # Park & Hodgins: torso, arms and legs densely; head, hands, feet sparsely
    assert (region == "body").mean() > 0.85
    assert 0 < (region == "hand").sum() <= 16
    assert (region == "head").sum() <= 20
    roles = dense.meta["role"]
    for extra in ("L_elbow_tip", "R_elbow_tip", "L_knee_front", "R_knee_front", "L_scapula_low"):
        assert roles.count(extra) == 1
    pos, _ = place_markers(dense, body.vertices, body.faces)
    d, _ = cKDTree(pos).query(pos, k=2)
    # 350 markers on a 1.61 m^2 body: nearest neighbours about 5 cm apart
    assert 0.04 <= d[:, 1].mean() <= 0.065
    assert d[:, 1].min() > 0.015


def test_dense_marker_surface(dense, body) -> None:
    tri = dense.surface_faces
    n = dense.n_markers
    assert tri.shape[0] > 1.8 * n  # a closed triangulation has ~2N triangles
    e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, cnt = np.unique(e, axis=0, return_counts=True)
    assert cnt.max() <= 2  # no non-manifold edge
    assert (cnt == 1).mean() < 0.03  # few holes
    assert len(np.unique(tri)) >= n - 3  # (almost) every marker is a vertex of it
    stats = dense.meta["surface_stats"]
    assert stats["n_nonmanifold_edges"] == 0
    # edges connect neighbours: short compared to the spacing
    pos, nrm = place_markers(dense, body.vertices, body.faces)
    ue = np.unique(e, axis=0)
    length = np.linalg.norm(pos[ue[:, 0]] - pos[ue[:, 1]], axis=1)
    assert np.median(length) < 1.8 * dense.meta["spacing"]
    assert (length < 3.0 * dense.meta["spacing"]).mean() > 0.95
    # oriented like the mesh: outward
    fn = np.cross(pos[tri[:, 1]] - pos[tri[:, 0]], pos[tri[:, 2]] - pos[tri[:, 0]])
    vn = nrm[tri].sum(axis=1)
    assert (np.einsum("fx,fx->f", fn, vn) > 0).mean() > 0.95


def test_dense_is_deterministic(body, dense) -> None:
    again = dense_marker_layout(body, seed=0)
    assert again.face.tobytes() == dense.face.tobytes()
    assert again.bary.tobytes() == dense.bary.tobytes()
    assert again.surface_faces.tobytes() == dense.surface_faces.tobytes()
    other = dense_marker_layout(body, seed=1, target=None, spacing=0.08, n_candidates=6000)
    assert other.n_markers < dense.n_markers
    assert other.meta["spacing"] == 0.08


# ---------------------------------------------------------------- placement
def test_markers_lie_on_the_skin_at_rest(dense, body) -> None:
    pos, nrm = place_markers(dense, body.vertices, body.faces, radius=0.0015)
    dist, _, _ = closest_points_on_mesh(body.vertices, body.faces, pos)
    # exactly the radius above their own triangle, never further from the skin
    assert dist.max() <= 0.0015 + 1e-9
    assert dist.min() >= 0.0015 - 0.001
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0)
    surf = np.einsum("nk,nkx->nx", dense.bary, body.vertices[body.faces[dense.face]])
    np.testing.assert_allclose(np.linalg.norm(pos - surf, axis=1), 0.0015, atol=1e-12)


def test_markers_lie_on_the_skin_in_every_frame(dense, body) -> None:
    frames = arm_across_belly(body, frames=4)
    pos, nrm = place_markers(dense, frames, body.faces)
    assert pos.shape == (4, dense.n_markers, 3) and nrm.shape == pos.shape
    for t in (1, 3):
        dist, _, _ = closest_points_on_mesh(frames[t], body.faces, pos[t])
        assert dist.max() <= 0.0015 + 0.001
        # a marker may sit in a crease where another part of the skin is closer
        assert np.mean(dist >= 0.0015 - 0.001) > 0.97
    # one frame at a time gives the same result as the batch
    p1, n1 = place_markers(dense, frames[2], body.faces)
    np.testing.assert_allclose(p1, pos[2], atol=1e-12)
    # the normals are the interpolated vertex normals
    vn = vertex_normals(frames[3], body.faces)
    want = np.einsum("nk,nkx->nx", dense.bary, vn[body.faces[dense.face]])
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(nrm[3], want, atol=1e-12)


def test_place_markers_rejects_bad_input(dense, body) -> None:
    with pytest.raises(ValidationError):
        place_markers(dense, body.vertices[:, :2], body.faces)
    bad = body.vertices.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValidationError):
        place_markers(dense, bad, body.faces)
    with pytest.raises(ValidationError):
        place_markers(dense, body.vertices, body.faces[:10])
    with pytest.raises(ValidationError):
        place_markers(dense, body.vertices, body.faces, radius=-1.0)


# --------------------------------------------------------------- sparse layout
def test_sparse_layout_landmarks(body) -> None:
    layout = sparse_marker_layout(body)
    assert layout.labels == list(SPARSE_LABELS) and len(layout.labels) == 41
    assert layout.surface_faces is None
    pos, _ = place_markers(layout, body.vertices, body.faces)
    at = dict(zip(layout.labels, pos, strict=True))
    sk = body.skin.skeleton
    joint = dict(zip(sk.names, body.skin.bind_matrices[:, :3, 3], strict=True))
    near = {
        "LELB": "lowerarm01.L",
        "RELB": "lowerarm01.R",
        "LKNE": "lowerleg01.L",
        "RKNE": "lowerleg01.R",
        "LANK": "foot.L",
        "LWRA": "wrist.L",
        "LSHO": "upperarm01.L",
    }
    for label, name in near.items():
        assert np.linalg.norm(at[label] - joint[name]) < 0.08, label
    for label, p in at.items():
        if label[0] == "L":
            assert p[0] > 0.01, label  # body's left is +X
        elif label[0] == "R":
            assert p[0] < -0.01, label
    # front and back
    assert at["LFHD"][2] > at["LBHD"][2] + 0.05
    assert at["CLAV"][2] > at["C7"][2] + 0.05
    assert at["STRN"][2] > at["T10"][2] + 0.1
    assert at["LASI"][2] > at["LPSI"][2] + 0.1
    assert at["LTOE"][2] > at["LHEE"][2] + 0.1
    assert at["LFHD"][1] > at["CLAV"][1] > at["LASI"][1] > at["LKNE"][1] > at["LANK"][1]


def test_sparse_layout_from_cmu_names(body) -> None:
    # the same body with its landmark joints renamed to CMU (cgspeed) names
    joint = dict(zip(body.skin.skeleton.names, body.skin.bind_matrices[:, :3, 3], strict=True))
    rename = {
        "Hips": "root", "Neck": "neck01", "Head": "head",
        "LeftArm": "upperarm01.L", "LeftForeArm": "lowerarm01.L", "LeftHand": "wrist.L",
        "RightArm": "upperarm01.R", "RightForeArm": "lowerarm01.R", "RightHand": "wrist.R",
        "LeftUpLeg": "upperleg01.L", "LeftLeg": "lowerleg01.L", "LeftFoot": "foot.L",
        "RightUpLeg": "upperleg01.R", "RightLeg": "lowerleg01.R", "RightFoot": "foot.R",
        "LeftToeBase": "toe3-1.L", "RightToeBase": "toe3-1.R",
        "LeftShoulder": "clavicle.L", "RightShoulder": "clavicle.R",
        "LowerBack": "spine05", "Spine": "spine03", "Spine1": "spine01", "Neck1": "neck03",
        "LeftFingerBase": "finger3-1.L", "RightFingerBase": "finger3-1.R",
    }  # fmt: skip
    cmu = {k: joint[v] for k, v in rename.items()}
    layout = sparse_marker_layout(body, cmu)
    pos, _ = place_markers(layout, body.vertices, body.faces)
    ref, _ = place_markers(sparse_marker_layout(body), body.vertices, body.faces)
    # same landmarks except where the joint sets differ (toes: mean vs middle toe; fingers)
    diff = np.linalg.norm(pos - ref, axis=1)
    assert np.median(diff) < 0.01
    assert len(set(layout.labels)) == 41


def test_layouts_need_joints() -> None:
    bare = Mesh(vertices=np.eye(3), faces=[[0, 1, 2]])
    with pytest.raises(ValidationError):
        sparse_marker_layout(bare)
    with pytest.raises(ValidationError):
        dense_marker_layout(bare)
    with pytest.raises(ValidationError):
        sparse_marker_layout(bare, {"foo": [0, 0, 0]})


def _pelvis_weight_of_markers(mesh: Mesh, layout, hips) -> dict[str, float]:
    """Each sparse marker's skinning weight on the pelvis joints."""
    w = _pelvis_weight(mesh.skin, hips)
    w_marker = np.einsum("nk,nk->n", layout.bary, w[mesh.faces[layout.face]])
    return dict(zip(layout.labels, w_marker, strict=True))


def test_sparse_pelvis_markers_ride_the_pelvis_over_the_iliac_spines() -> None:
    # the procedural body binds skin around the hips to its pelvis (MakeHuman's weights
    # give that skin to spine04/05 at most 0.51 to the pelvis: its landmarks stay put)
    mesh = build_body("procedural", n_vertices=4000, seed=0)
    layout = sparse_marker_layout(mesh)
    hips = _landmark_joints(_joint_positions(mesh, None))
    weight = _pelvis_weight_of_markers(mesh, layout, np.stack([hips["thigh_l"], hips["thigh_r"]]))
    for label in ("LASI", "RASI", "LPSI", "RPSI"):
        assert weight[label] >= PELVIS_BOUND_WEIGHT, (label, weight[label])
    pos, _ = place_markers(layout, mesh.vertices, mesh.faces)
    at = dict(zip(layout.labels, pos, strict=True))
    hip_height = 0.5 * (hips["thigh_l"][1] + hips["thigh_r"][1])
    for side in "LR":
        # above the hip joints, ASIS in front of PSIS, each on its own side
        assert at[f"{side}ASI"][1] > hip_height and at[f"{side}PSI"][1] > hip_height
        assert at[f"{side}ASI"][2] > at[f"{side}PSI"][2] + 0.1
    assert at["LASI"][0] > 0.02 > -0.02 > at["RASI"][0]
    assert at["LPSI"][0] > 0.02 > -0.02 > at["RPSI"][0]
