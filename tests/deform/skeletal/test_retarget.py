"""Retargeting onto the MakeHuman rig and onto skeletons-as-skins, built-in and user maps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from skincap.deform.skeletal.name_maps import CONVENTIONS, convention_joints, detect_convention
from skincap.deform.skeletal.retarget import joint_name_map, retarget
from skincap.deform.skeletal.rig import skeleton_bind_matrices, skinning_matrices
from skincap.errors import FormatError, ValidationError
from skincap.geometry.kinematics import forward_kinematics, joint_positions
from skincap.io.bvh import read_bvh
from skincap.io.makehuman import read_makehuman
from skincap.types import Motion, Skeleton, Skin

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def makehuman():
    return read_makehuman(DATA / "makehuman_base.obj")


@pytest.fixture(scope="module")
def cmu():
    return read_bvh(DATA / "cmu_131_01_bvh11.bvh", units="cmu")


@pytest.fixture(scope="module")
def mocapbank():
    return read_bvh(DATA / "bvhtoolbox_test_mocapbank.bvh", units="cm")


@pytest.fixture(scope="module")
def cmu_on_makehuman(makehuman, cmu):
    return retarget(cmu, makehuman)


@pytest.fixture(scope="module")
def mocapbank_on_makehuman(makehuman, mocapbank):
    return retarget(mocapbank, makehuman)


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def segment_angles(src_pos, src_names, tgt_pos, tgt_names, segments):
    """Max over frames of the angle between each source and target segment, degrees."""
    out = {}
    for s0, s1, t0, t1 in segments:
        u = src_pos[:, src_names.index(s1)] - src_pos[:, src_names.index(s0)]
        v = tgt_pos[:, tgt_names.index(t1)] - tgt_pos[:, tgt_names.index(t0)]
        out[(s0, s1)] = float(angles_deg(u, v).max())
    return out


def skinned_foot_vertices(mesh, motion, frames):
    """Posed positions (t, k, 3) of the vertices mostly bound to feet and toes."""
    skin = mesh.skin
    names = skin.skeleton.names
    foot = np.array([n.startswith(("foot.", "toe")) for n in names])
    major = skin.joint_indices[np.arange(mesh.n_vertices), np.argmax(skin.joint_weights, axis=1)]
    v = np.nonzero(foot[major])[0]
    s = skinning_matrices(motion, skin)[frames]  # (t, J, 4, 4)
    m = np.einsum("vk,tvkab->tvab", skin.joint_weights[v], s[:, skin.joint_indices[v]])
    return np.einsum("tvab,vb->tva", m[..., :3, :3], mesh.vertices[v]) + m[..., :3, 3]


# ------------------------------------------------------------------ name maps
def test_conventions_detected_on_the_data(makehuman, cmu, mocapbank):
    assert detect_convention(cmu.skeleton.names) == "cmu_bvh11"
    assert detect_convention(mocapbank.skeleton.names) == "biovision"
    assert detect_convention(makehuman.skin.skeleton.names) == "makehuman"
    tpose = read_bvh(DATA / "makehuman_tpose.bvh", units="dm", up="z", position_channels="add")
    assert detect_convention(tpose.skeleton.names) == "makehuman"
    assert detect_convention(convention_joints("cmu_cgspeed") + ["LHipJoint"]) == "cmu_cgspeed"
    assert detect_convention(["a", "b", "Hips"]) is None
    # every built-in joint of the MakeHuman map is a bone of the shipped rig
    assert set(convention_joints("makehuman")) <= set(makehuman.skin.skeleton.names)
    assert set(convention_joints("cmu_bvh11")) <= set(cmu.skeleton.names)
    assert set(convention_joints("biovision")) <= set(mocapbank.skeleton.names)


def test_builtin_map_cmu_to_makehuman(makehuman, cmu):
    m = joint_name_map(cmu, makehuman)
    assert m["Hips"] == ("root",)
    assert m["LeftHip"] == ("upperleg01.L",)
    assert m["LeftShoulder"] == ("upperarm01.L",)
    assert m["RightElbow"] == ("lowerarm01.R",)
    assert m["lowerback"] == ("spine05",)
    assert m["LeftToe"] == CONVENTIONS["makehuman"]["toe_l"]
    assert "LHipJoint" not in m and "LeftWrist" not in m
    assert len(m) == 23


# ------------------------------------------------------------------ identity
def test_identity_onto_own_skeleton(cmu):
    out = retarget(cmu, cmu.skeleton)
    assert out.meta["retarget"]["scale"] == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(joint_positions(out), joint_positions(cmu), atol=1e-9)
    assert out.skeleton is cmu.skeleton
    assert out.rate == cmu.rate


def test_identity_onto_skin_with_rolled_bind_frames(mocapbank):
    """Same joint positions, but every bind frame carries an arbitrary rotation."""
    skel = mocapbank.skeleton
    bind = skeleton_bind_matrices(skel)
    rng = np.random.default_rng(11)
    bind[:, :3, :3] = Rotation.random(skel.n_joints, random_state=rng).as_matrix()
    skin = Skin(skel, np.zeros((1, 1), dtype=np.int64), np.ones((1, 1)), np.linalg.inv(bind))
    out = retarget(mocapbank, skin)
    np.testing.assert_allclose(joint_positions(out), joint_positions(mocapbank), atol=1e-9)
    # world frames are the source's world rotations times the bind rolls
    w_out = forward_kinematics(out)[..., :3, :3]
    w_src = forward_kinematics(mocapbank)[..., :3, :3]
    np.testing.assert_allclose(w_out, w_src @ bind[:, :3, :3], atol=1e-9)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 10))
def test_identity_on_random_skeletons(seed, n):
    rng = np.random.default_rng(seed)
    parents = np.array([-1] + [int(rng.integers(0, k)) for k in range(1, n)])
    offsets = rng.normal(size=(n, 3)) * 0.3
    offsets[rng.random(n) < 0.2] = 0.0  # zero-length bones, as in CMU files
    offsets[1] = [0.1, 0.5, 0.0]  # not all in one point
    skel = Skeleton([f"bone{k}" for k in range(n)], parents, offsets)
    t = 5
    q = Rotation.random(t * n, random_state=rng).as_quat().reshape(t, n, 4)
    tr = np.broadcast_to(offsets, (t, n, 3)).copy()
    tr[:, 0] = rng.normal(size=(t, 3))
    motion = Motion(skel, q, tr, 60.0)
    out = retarget(motion, skel)
    np.testing.assert_allclose(joint_positions(out), joint_positions(motion), atol=1e-9)


# ------------------------------------------------------------------ CMU walk on MakeHuman
CMU_SEGMENTS = [
    ("LeftHip", "LeftKnee", "upperleg01.L", "lowerleg01.L"),
    ("LeftKnee", "LeftAnkle", "lowerleg01.L", "foot.L"),
    ("RightHip", "RightKnee", "upperleg01.R", "lowerleg01.R"),
    ("RightKnee", "RightAnkle", "lowerleg01.R", "foot.R"),
    ("LeftShoulder", "LeftElbow", "upperarm01.L", "lowerarm01.L"),
    ("LeftElbow", "LeftWrist", "lowerarm01.L", "wrist.L"),
    ("RightShoulder", "RightElbow", "upperarm01.R", "lowerarm01.R"),
    ("RightElbow", "RightWrist", "lowerarm01.R", "wrist.R"),
    ("LeftCollar", "LeftShoulder", "clavicle.L", "upperarm01.L"),
    ("lowerback", "Chest", "spine05", "spine03"),
    ("Chest", "Chest2", "spine03", "spine01"),
    ("Neck", "Head", "neck03", "head"),
]


def test_cmu_mapped_bones_follow_the_source(cmu, cmu_on_makehuman):
    src = joint_positions(cmu)
    tgt = joint_positions(cmu_on_makehuman)
    got = segment_angles(
        src, cmu.skeleton.names, tgt, cmu_on_makehuman.skeleton.names, CMU_SEGMENTS
    )
    # single-bone segments are aligned exactly, in every frame
    assert max(got.values()) < 1e-4, got
    # composite segments (the pair ends differ between the rigs) stay close
    loose = segment_angles(
        src,
        cmu.skeleton.names,
        tgt,
        cmu_on_makehuman.skeleton.names,
        [
            ("Chest2", "Neck", "spine01", "neck03"),
            ("lowerneck", "Head", "neck01", "head"),
            ("LeftAnkle", "LeftToe", "foot.L", "toe3-1.L"),
            ("RightAnkle", "RightToe", "foot.R", "toe3-1.R"),
        ],
    )
    assert max(loose.values()) < 10.0, loose


def test_cmu_bone_lengths_never_change(makehuman, cmu_on_makehuman):
    pos = joint_positions(cmu_on_makehuman)
    heads = makehuman.skin.bind_matrices[:, :3, 3]
    p = makehuman.skin.skeleton.parents
    has = p >= 0
    lengths = np.linalg.norm(pos[:, has] - pos[:, p[has]], axis=-1)
    want = np.linalg.norm(heads[has] - heads[p[has]], axis=-1)
    assert np.abs(lengths - want).max() < 1e-9


def test_cmu_scale_and_root_motion(cmu, cmu_on_makehuman):
    names = cmu_on_makehuman.skeleton.names
    scale = cmu_on_makehuman.meta["retarget"]["scale"]
    # leg lengths: CMU hip-ankle 0.802 m along the bones, MakeHuman 0.805 m
    assert scale == pytest.approx(1.0038, abs=1e-3)
    src = joint_positions(cmu)
    tgt = joint_positions(cmu_on_makehuman)
    sn = cmu.skeleton.names
    src_pelvis = (src[:, sn.index("LeftHip")] + src[:, sn.index("RightHip")]) / 2
    tgt_pelvis = (tgt[:, names.index("upperleg01.L")] + tgt[:, names.index("upperleg01.R")]) / 2
    np.testing.assert_allclose(tgt_pelvis, scale * src_pelvis, atol=1e-9)
    # the walk travels: 2.6 m forwards (+z) over the take, scaled
    travel_src = src[-1, 0] - src[0, 0]
    travel_tgt = tgt[-1, 0] - tgt[0, 0]
    assert travel_src[2] > 2.5
    assert np.linalg.norm(travel_tgt[[0, 2]] - scale * travel_src[[0, 2]]) < 0.1


def test_cmu_feet_on_the_floor_and_alternating(makehuman, cmu, cmu_on_makehuman):
    names = cmu_on_makehuman.skeleton.names
    tgt = joint_positions(cmu_on_makehuman)
    toes = [
        names.index(n)
        for n in CONVENTIONS["makehuman"]["toe_l"] + CONVENTIONS["makehuman"]["toe_r"]
    ]
    toe_y = tgt[:, toes, 1]
    # toe joints never sink more than 1 cm under the floor; every frame some toe
    # is within 8 cm of it (the take has no jumps)
    assert toe_y.min() > -0.01
    assert toe_y.min(axis=1).max() < 0.08
    # skinned soles over the walking stretch: between 1.8 and 5 cm above the floor
    # (the CMU ankle sits 8-9 cm above it, MakeHuman's 7.2 cm above its sole)
    feet = skinned_foot_vertices(makehuman, cmu_on_makehuman, np.arange(470, 700, 3))
    lowest = feet[..., 1].min(axis=1)
    assert lowest.min() > 0.0
    assert lowest.max() < 0.06
    assert np.median(lowest) < 0.04
    # over the whole take, the kneel (frames 380-410) presses the toes 4.8 cm in:
    # there the source's own toe tip is 2.2 cm under its floor
    feet = skinned_foot_vertices(makehuman, cmu_on_makehuman, np.arange(0, cmu.n_frames, 7))
    assert feet[..., 1].min() > -0.05
    assert joint_positions(cmu)[:, :, 1].min() < -0.02
    # the walking stretch (frames 470..700): the feet lift in turn, R L R L
    fl = tgt[470:700, names.index("foot.L"), 1]
    fr = tgt[470:700, names.index("foot.R"), 1]
    swing = np.where(fl - fr > 0.08, "L", np.where(fr - fl > 0.08, "R", ""))
    steps = [s for k, s in enumerate(swing) if s and (k == 0 or swing[k - 1] != s)]
    steps = [s for k, s in enumerate(steps) if k == 0 or steps[k - 1] != s]
    assert steps[:4] == ["R", "L", "R", "L"]
    # the source's own pattern
    sn = cmu.skeleton.names
    src = joint_positions(cmu)
    sl = src[470:700, sn.index("LeftAnkle"), 1]
    sr = src[470:700, sn.index("RightAnkle"), 1]
    assert np.corrcoef(sl - sr, fl - fr)[0, 1] > 0.99


def test_cmu_arms_hang_and_swing(cmu, cmu_on_makehuman):
    names = cmu_on_makehuman.skeleton.names
    sn = cmu.skeleton.names
    tgt = joint_positions(cmu_on_makehuman)
    src = joint_positions(cmu)
    for s_hand, s_sh, t_hand, t_sh in [
        ("lhand", "LeftShoulder", "wrist.L", "upperarm01.L"),
        ("rhand", "RightShoulder", "wrist.R", "upperarm01.R"),
    ]:
        src_drop = src[:, sn.index(s_hand), 1] - src[:, sn.index(s_sh), 1]
        tgt_drop = tgt[:, names.index(t_hand), 1] - tgt[:, names.index(t_sh), 1]
        hanging = src_drop < -0.05
        assert hanging.sum() > 600
        assert (tgt_drop[hanging] < 0).all()
        # the swing: the hand moves forwards and back relative to the shoulder
        swing = tgt[470:700, names.index(t_hand), 2] - tgt[470:700, names.index(t_sh), 2]
        assert np.ptp(swing) > 0.1
    # the left hand hangs for the whole take
    drop = tgt[:, names.index("wrist.L"), 1] - tgt[:, names.index("upperarm01.L"), 1]
    assert drop.max() < -0.1


def test_unmapped_target_bones_keep_their_bind_relation(makehuman, cmu_on_makehuman):
    w = forward_kinematics(cmu_on_makehuman)
    bind = makehuman.skin.bind_matrices
    names = makehuman.skin.skeleton.names
    for child, parent in [
        ("finger2-1.L", "metacarpal1.L"),
        ("jaw", "head"),
        ("breast.L", "spine02"),
    ]:
        c, p = names.index(child), names.index(parent)
        local = np.linalg.inv(w[:, p]) @ w[:, c]
        np.testing.assert_allclose(
            local, np.broadcast_to(np.linalg.inv(bind[p]) @ bind[c], local.shape), atol=1e-9
        )
    # chain bones move rigidly with the first bone of their chain
    for chain_bone, first in [
        ("upperarm02.L", "upperarm01.L"),
        ("spine04", "spine05"),
        ("neck02", "neck01"),
    ]:
        c, p = names.index(chain_bone), names.index(first)
        rel = np.linalg.inv(w[:, p]) @ w[:, c]
        np.testing.assert_allclose(
            rel, np.broadcast_to(np.linalg.inv(bind[p]) @ bind[c], rel.shape), atol=1e-9
        )


def test_retargeted_motion_is_on_the_skin_and_meta(makehuman, cmu, cmu_on_makehuman):
    out = cmu_on_makehuman
    assert out.skeleton.names == makehuman.skin.skeleton.names
    assert out.n_frames == cmu.n_frames and out.rate == cmu.rate
    assert out.meta["source_units"] == cmu.meta["source_units"]
    assert out.meta["retarget"]["source_convention"] == "cmu_bvh11"
    assert out.meta["retarget"]["target_convention"] == "makehuman"
    s = skinning_matrices(out, makehuman.skin)
    assert s.shape == (cmu.n_frames, 163, 4, 4) and np.isfinite(s).all()


# ------------------------------------------------------------------ Biovision on MakeHuman
def test_mocapbank_on_makehuman(makehuman, mocapbank, mocapbank_on_makehuman):
    out = mocapbank_on_makehuman
    names = out.skeleton.names
    src = joint_positions(mocapbank)
    tgt = joint_positions(out)
    got = segment_angles(
        src,
        mocapbank.skeleton.names,
        tgt,
        names,
        [
            ("LeftHip", "LeftKnee", "upperleg01.L", "lowerleg01.L"),
            ("RightKnee", "RightAnkle", "lowerleg01.R", "foot.R"),
            ("LeftShoulder", "LeftElbow", "upperarm01.L", "lowerarm01.L"),
            ("RightElbow", "RightWrist", "lowerarm01.R", "wrist.R"),
            ("Chest", "Chest2", "spine03", "spine01"),
        ],
    )
    assert max(got.values()) < 1e-4, got
    # the pelvis (a segment with three ends, aligned by its facing) turns with the source
    sn = mocapbank.skeleton.names
    src_lat = src[:, sn.index("LeftHip")] - src[:, sn.index("RightHip")]
    tgt_lat = tgt[:, names.index("upperleg01.L")] - tgt[:, names.index("upperleg01.R")]
    src_up = (
        src[:, sn.index("Chest")] - (src[:, sn.index("LeftHip")] + src[:, sn.index("RightHip")]) / 2
    )
    tgt_up = (
        tgt[:, names.index("spine03")]
        - (tgt[:, names.index("upperleg01.L")] + tgt[:, names.index("upperleg01.R")]) / 2
    )
    lat, up = angles_deg(src_lat, tgt_lat), angles_deg(src_up, tgt_up)
    assert lat.max() < 0.2
    # the rest skeletons differ: mocapbank's hip joints sit 3.3 cm in front of its spine,
    # MakeHuman's straight under it (18.4 deg); the pelvis keeps that, frame after frame
    assert np.ptp(up) < 0.01 and up.max() < 20.0
    scale = out.meta["retarget"]["scale"]
    assert 0.85 < scale < 1.0
    # the take crouches: the pelvis drops 0.5 m and comes back, scaled
    pelvis = (tgt[:, names.index("upperleg01.L")] + tgt[:, names.index("upperleg01.R")]) / 2
    src_pelvis = (src[:, sn.index("LeftHip")] + src[:, sn.index("RightHip")]) / 2
    np.testing.assert_allclose(pelvis, scale * src_pelvis, atol=1e-9)
    assert np.ptp(pelvis[:, 1]) > 0.4
    feet = skinned_foot_vertices(makehuman, out, np.arange(0, out.n_frames, 5))
    lowest = feet[..., 1].min(axis=1)
    assert lowest.min() > -0.03
    assert lowest.max() < 0.04


# ------------------------------------------------------------------ user maps
def _arm_mirror():
    left = ["LeftCollar", "LeftShoulder", "LeftElbow", "lhand"]
    right = ["RightCollar", "RightShoulder", "RightElbow", "rhand"]
    tl = ["clavicle.L", "upperarm01.L", "lowerarm01.L", "wrist.L"]
    tr = ["clavicle.R", "upperarm01.R", "lowerarm01.R", "wrist.R"]
    return {**dict(zip(left, tr, strict=True)), **dict(zip(right, tl, strict=True))}


def test_user_json_map_overrides(tmp_path, makehuman, cmu):
    path = tmp_path / "mirror.json"
    path.write_text(json.dumps(_arm_mirror()))
    short = Motion(cmu.skeleton, cmu.rotations[::20], cmu.translations[::20], cmu.rate / 20)
    out = retarget(short, makehuman, name_map=path)
    assert out.meta["retarget"]["name_map"]["LeftShoulder"] == ["upperarm01.R"]
    assert out.meta["retarget"]["name_map"]["LeftHip"] == ["upperleg01.L"]  # built-in kept
    src = joint_positions(short)
    tgt = joint_positions(out)
    got = segment_angles(
        src,
        cmu.skeleton.names,
        tgt,
        out.skeleton.names,
        [
            ("LeftShoulder", "LeftElbow", "upperarm01.R", "lowerarm01.R"),
            ("RightElbow", "RightWrist", "lowerarm01.L", "wrist.L"),
            ("LeftHip", "LeftKnee", "upperleg01.L", "lowerleg01.L"),
        ],
    )
    assert max(got.values()) < 1e-4, got
    # null removes a pair: the unmapped forearm then keeps its bind relation
    out2 = retarget(short, makehuman, name_map={"LeftElbow": None})
    assert "LeftElbow" not in out2.meta["retarget"]["name_map"]
    w = forward_kinematics(out2)
    names = makehuman.skin.skeleton.names
    bind = makehuman.skin.bind_matrices
    p, c = names.index("upperarm02.L"), names.index("lowerarm01.L")
    rel = np.linalg.inv(w[:, p]) @ w[:, c]
    np.testing.assert_allclose(
        rel, np.broadcast_to(np.linalg.inv(bind[p]) @ bind[c], rel.shape), atol=1e-9
    )


def test_user_map_on_unknown_names_matches_builtin(makehuman, cmu, cmu_on_makehuman):
    rename = {n: f"j{k:02d}" for k, n in enumerate(cmu.skeleton.names)}
    skel = Skeleton(
        [rename[n] for n in cmu.skeleton.names], cmu.skeleton.parents, cmu.skeleton.offsets
    )
    renamed = Motion(skel, cmu.rotations, cmu.translations, cmu.rate)
    with pytest.raises(ValidationError, match="no joints to pair"):
        retarget(renamed, makehuman)
    builtin = joint_name_map(cmu, makehuman)
    user = {rename[s]: list(t) for s, t in builtin.items()}
    out = retarget(renamed, makehuman, name_map=user)
    np.testing.assert_allclose(out.rotations, cmu_on_makehuman.rotations, atol=1e-12)
    np.testing.assert_allclose(out.translations, cmu_on_makehuman.translations, atol=1e-12)


def test_cgspeed_names_drive_makehuman(makehuman, cmu, cmu_on_makehuman):
    """The same take under the cgspeed names gives the same result."""
    to_cgspeed = {
        "LeftHip": "LeftUpLeg", "LeftKnee": "LeftLeg", "LeftAnkle": "LeftFoot",
        "LeftToe": "LeftToeBase", "RightHip": "RightUpLeg", "RightKnee": "RightLeg",
        "RightAnkle": "RightFoot", "RightToe": "RightToeBase", "lowerback": "LowerBack",
        "Chest": "Spine", "Chest2": "Spine1", "lowerneck": "Neck", "Neck": "Neck1",
        "LeftCollar": "LeftShoulder", "LeftShoulder": "LeftArm", "LeftElbow": "LeftForeArm",
        "LeftWrist": "LeftWristRoll", "lhand": "LeftHand", "RightCollar": "RightShoulder",
        "RightShoulder": "RightArm", "RightElbow": "RightForeArm",
        "RightWrist": "RightWristRoll", "rhand": "RightHand",
    }  # fmt: skip
    names = [to_cgspeed.get(n, n) for n in cmu.skeleton.names]
    assert detect_convention(names) == "cmu_cgspeed"
    skel = Skeleton(names, cmu.skeleton.parents, cmu.skeleton.offsets)
    out = retarget(Motion(skel, cmu.rotations, cmu.translations, cmu.rate), makehuman)
    np.testing.assert_allclose(out.rotations, cmu_on_makehuman.rotations, atol=1e-12)
    np.testing.assert_allclose(out.translations, cmu_on_makehuman.translations, atol=1e-12)


def test_bad_maps_and_arguments(tmp_path, makehuman, cmu):
    short = Motion(cmu.skeleton, cmu.rotations[:3], cmu.translations[:3], cmu.rate)
    with pytest.raises(ValidationError, match="source joint 'Nope'"):
        retarget(short, makehuman, name_map={"Nope": "root"})
    with pytest.raises(ValidationError, match="target joint 'nope'"):
        retarget(short, makehuman, name_map={"Hips": "nope"})
    with pytest.raises(ValidationError, match="driven by two source joints"):
        retarget(short, makehuman, name_map={"LeftHip": "upperleg01.L", "RightHip": "upperleg01.L"})
    with pytest.raises(ValidationError, match="breaks the hierarchy"):
        retarget(short, makehuman, name_map={"LeftKnee": "upperleg01.L", "LeftHip": "lowerleg01.L"})
    with pytest.raises(ValidationError, match="expected a target joint name"):
        retarget(short, makehuman, name_map={"Hips": 3})
    with pytest.raises(ValidationError, match="target root 'root'"):
        retarget(short, makehuman, name_map={"Hips": None})
    bad = tmp_path / "bad.json"
    bad.write_text('{"Hips": "root",\n "LeftHip": }')
    with pytest.raises(FormatError, match=r"bad\.json: line 2: invalid JSON"):
        retarget(short, makehuman, name_map=bad)
    bad.write_bytes(b'{"Hips": "r\xffoot"}')
    with pytest.raises(FormatError, match="not UTF-8"):
        retarget(short, makehuman, name_map=bad)
    bad.write_text('["Hips", "root"]')
    with pytest.raises(FormatError, match="expected an object"):
        retarget(short, makehuman, name_map=bad)
    with pytest.raises(FormatError, match="cannot read"):
        retarget(short, makehuman, name_map=tmp_path / "missing.json")
    for scale in (0.0, -1.0, float("nan"), "tall"):
        with pytest.raises(ValidationError, match="scale"):
            retarget(short, makehuman, scale=scale)
    with pytest.raises(ValidationError, match="the mesh has no skin"):
        retarget(short, type(makehuman)(makehuman.vertices, makehuman.faces))
    with pytest.raises(ValidationError, match="source: expected a Motion"):
        retarget(cmu.skeleton, makehuman)


def test_explicit_scale_scales_root_motion(makehuman, cmu):
    short = Motion(cmu.skeleton, cmu.rotations[::50], cmu.translations[::50], cmu.rate / 50)
    a = joint_positions(retarget(short, makehuman, scale=1.0))
    b = joint_positions(retarget(short, makehuman, scale=0.5))
    names = makehuman.skin.skeleton.names
    legs = [names.index("upperleg01.L"), names.index("upperleg01.R")]
    np.testing.assert_allclose(b[:, legs].mean(1), 0.5 * a[:, legs].mean(1), atol=1e-9)
    # the pose itself does not depend on the scale
    np.testing.assert_allclose(b - b[:, :1], a - a[:, :1], atol=1e-9)


def test_retargeted_motion_writes_as_bvh(tmp_path, cmu_on_makehuman):
    from skincap.io.bvh import write_bvh

    out = cmu_on_makehuman
    short = Motion(
        out.skeleton,
        out.rotations[::25],
        out.translations[::25],
        out.rate / 25,
        channels=out.channels,
    )
    path = tmp_path / "mh.bvh"
    write_bvh(short, path, units="m")
    back = read_bvh(path, units="m")
    order = [back.skeleton.names.index(n) for n in short.skeleton.names]
    np.testing.assert_allclose(joint_positions(back)[:, order], joint_positions(short), atol=1e-5)


def test_mixamo_namespace_drives_makehuman(makehuman):
    """A Mixamo BVH (``mixamorig:Hips``..., 20tab/bvh-python's test file) is recognised
    past its namespace and its walk drives the MakeHuman rig: the feet lift in turn
    as the source's do and the hands hang under the shoulders."""
    walk = read_bvh(DATA / "external" / "bvhpython_mixamo_walk.bvh", units="cm")
    bare = [n.split(":")[-1] for n in walk.skeleton.names]
    assert detect_convention(bare) == "mixamo"
    assert detect_convention(walk.skeleton.names) is None
    m = joint_name_map(walk, makehuman)
    assert m["mixamorig:Hips"] == ("root",)
    assert m["mixamorig:LeftUpLeg"] == ("upperleg01.L",)
    assert m["mixamorig:RightArm"] == ("upperarm01.R",)
    assert m["mixamorig:LeftForeArm"] == ("lowerarm01.L",)
    assert m["mixamorig:Spine2"] == ("spine01",)
    assert m["mixamorig:RightToeBase"] == CONVENTIONS["makehuman"]["toe_r"]
    out = retarget(walk, makehuman)
    tn, sn = out.skeleton.names, walk.skeleton.names
    tgt, src = joint_positions(out), joint_positions(walk)
    t_lr = tgt[:, tn.index("foot.L"), 1] - tgt[:, tn.index("foot.R"), 1]
    s_lr = src[:, sn.index("mixamorig:LeftFoot"), 1] - src[:, sn.index("mixamorig:RightFoot"), 1]
    assert np.ptp(s_lr) > 0.05 and np.corrcoef(s_lr, t_lr)[0, 1] > 0.95
    for hand, shoulder in (("wrist.L", "upperarm01.L"), ("wrist.R", "upperarm01.R")):
        assert (tgt[:, tn.index(hand), 1] < tgt[:, tn.index(shoulder), 1] - 0.2).all()
