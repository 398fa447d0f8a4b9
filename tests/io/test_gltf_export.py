"""write_glb: round trip through skincap's glTF reader and trimesh, and the animation
played back by hand (node TRS -> FK -> joint matrices -> LBS) against a reference."""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation
from skinned_cylinder import RATE, bend_motion, bind_local, cylinder_mesh, lbs_reference

from skincap.errors import OutputExistsError, SkincapWarning, ValidationError
from skincap.geometry.kinematics import forward_kinematics_arrays
from skincap.io.gltf.reader import read_gltf
from skincap.io.gltf.writer import write_glb
from skincap.io.makehuman import read_makehuman
from skincap.types import Mesh, Motion, Skeleton, Skin

DATA = Path(__file__).resolve().parents[1] / "data"
_DTYPES = {5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


# ----------------------------------------------------------------- a tiny GLB parser
def parse_glb(path: Path) -> tuple[dict, bytes]:
    """The JSON document and binary chunk of a GLB (independent of skincap.io.gltf.reader)."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    jlen, jtype = struct.unpack_from("<II", data, 12)
    assert jtype == 0x4E4F534A and jlen % 4 == 0
    doc = json.loads(data[20 : 20 + jlen])
    blen, btype = struct.unpack_from("<II", data, 20 + jlen)
    assert btype == 0x004E4942 and blen % 4 == 0
    return doc, data[28 + jlen : 28 + jlen + blen]


def accessor(doc: dict, blob: bytes, i: int) -> np.ndarray:
    acc = doc["accessors"][i]
    view = doc["bufferViews"][acc["bufferView"]]
    assert "byteStride" not in view and view["byteOffset"] % 4 == 0
    width = _WIDTH[acc["type"]]
    arr = np.frombuffer(
        blob, dtype=_DTYPES[acc["componentType"]], count=acc["count"] * width,
        offset=view["byteOffset"] + acc.get("byteOffset", 0),
    )  # fmt: skip
    assert arr.nbytes == view["byteLength"]
    return arr.reshape(acc["count"], width).astype(np.float64)


def play_glb(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(T,) key times and (T, V, 3) skinned positions at the keys, as glTF defines them.

    Node local = T @ R from the animation channels; global = parent global @ local;
    jointMatrix = global @ inverseBind; vertex = sum_k w_k jointMatrix[j_k] @ v.
    """
    doc, blob = parse_glb(path)
    nodes = doc["nodes"]
    n = len(nodes)
    parent = np.full(n, -1)
    for i, node in enumerate(nodes):
        for c in node.get("children", []):
            parent[c] = i
    anim = doc["animations"][0]
    times = None
    q = np.array([nd.get("rotation", [0, 0, 0, 1]) for nd in nodes], float)
    t = np.array([nd.get("translation", [0, 0, 0]) for nd in nodes], float)
    rot_keys: dict[int, np.ndarray] = {}
    tra_keys: dict[int, np.ndarray] = {}
    for ch in anim["channels"]:
        smp = anim["samplers"][ch["sampler"]]
        assert smp["interpolation"] == "LINEAR"
        tk = accessor(doc, blob, smp["input"])[:, 0]
        times = tk if times is None else times
        np.testing.assert_array_equal(tk, times)
        out = accessor(doc, blob, smp["output"])
        target = ch["target"]
        (rot_keys if target["path"] == "rotation" else tra_keys)[target["node"]] = out
    nt = times.size
    qs = np.tile(q, (nt, 1, 1))
    ts = np.tile(t, (nt, 1, 1))
    for k, v in rot_keys.items():
        qs[:, k] = v
    for k, v in tra_keys.items():
        ts[:, k] = v
    # parents come first in our files; check and then run FK over the node tree
    assert all(parent[i] < i for i in range(n))
    world = forward_kinematics_arrays(parent, qs, ts)  # (T, n, 4, 4)
    skin = doc["skins"][0]
    ibm = accessor(doc, blob, skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    jm = np.einsum("tjab,jbc->tjac", world[:, skin["joints"]], ibm)
    prim = doc["meshes"][0]["primitives"][0]
    pos = accessor(doc, blob, prim["attributes"]["POSITION"])
    joints = accessor(doc, blob, prim["attributes"]["JOINTS_0"]).astype(int)
    weights = accessor(doc, blob, prim["attributes"]["WEIGHTS_0"])
    vh = np.concatenate([pos, np.ones((pos.shape[0], 1))], axis=1)
    posed = np.einsum("tvkab,vb,vk->tva", jm[:, joints], vh, weights)[..., :3]
    return times, posed


# ---------------------------------------------------------------------------- tests
def test_round_trip_through_skincap_reader(tmp_path, cylinder, bend):
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    back = read_gltf(out)
    assert back.n_vertices == cylinder.n_vertices
    np.testing.assert_allclose(back.vertices, cylinder.vertices, atol=1e-7)
    np.testing.assert_array_equal(back.faces, cylinder.faces)
    np.testing.assert_allclose(back.uv, cylinder.uv, atol=1e-7)
    skin, ref = back.skin, cylinder.skin
    order = [skin.skeleton.names.index(n) for n in ref.skeleton.names]
    np.testing.assert_allclose(skin.inverse_bind[order], ref.inverse_bind, atol=1e-6)
    # dense (V, J) weights compare whatever the padding and joint order
    dense_back = np.zeros((back.n_vertices, 3))
    np.add.at(
        dense_back, (np.arange(back.n_vertices)[:, None], skin.joint_indices), skin.joint_weights
    )
    dense_ref = np.zeros((cylinder.n_vertices, 3))
    np.add.at(
        dense_ref, (np.arange(cylinder.n_vertices)[:, None], ref.joint_indices), ref.joint_weights
    )
    np.testing.assert_allclose(dense_back[:, order], dense_ref, atol=1e-7)
    # the node rest pose is the bind pose: the reader's joint rest world == bind matrices
    np.testing.assert_allclose(back.meta["joint_rest_world"][order], ref.bind_matrices, atol=1e-6)
    parents_by_name = {
        n: (skin.skeleton.names[p] if p >= 0 else None)
        for n, p in zip(skin.skeleton.names, skin.skeleton.parents, strict=True)
    }
    assert parents_by_name == {"root": None, "elbow": "root", "tip": "elbow"}


def test_second_reader_trimesh(tmp_path, cylinder, bend):
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    scene = trimesh.load(out)
    geoms = list(scene.geometry.values())
    assert len(geoms) == 1
    geom = geoms[0]
    assert geom.vertices.shape == (cylinder.n_vertices, 3)
    assert geom.faces.shape == cylinder.faces.shape
    # trimesh may merge or reorder vertices: compare the triangles as point sets
    np.testing.assert_allclose(
        np.sort(geom.vertices[geom.faces].reshape(-1, 9), axis=0),
        np.sort(cylinder.vertices[cylinder.faces].reshape(-1, 9), axis=0),
        atol=1e-7,
    )


def test_animation_plays_back_as_linear_blend_skinning(tmp_path, cylinder, bend):
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    times, posed = play_glb(out)
    np.testing.assert_allclose(times, np.arange(bend.n_frames) / RATE, rtol=1e-7)
    ref = lbs_reference(cylinder, bend)
    assert np.abs(ref[-1] - cylinder.vertices).max() > 0.2  # the bend moves the tip a lot
    np.testing.assert_allclose(posed, ref, atol=2e-6)


def test_agrees_with_skincap_deformer(tmp_path, cylinder, bend):
    deformers = pytest.importorskip(
        "skincap.deform.skeletal.deformers",
        reason="skincap.deform.skeletal.deformers not in the tree yet",
    )
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    _, posed = play_glb(out)
    s = np.einsum(
        "tjab,jbc->tjac",
        forward_kinematics_arrays(bend.skeleton, bend.rotations, bend.translations),
        cylinder.skin.inverse_bind,
    )
    lbs = deformers.LinearBlendSkinning(
        cylinder.vertices, cylinder.skin.joint_indices, cylinder.skin.joint_weights
    )
    np.testing.assert_allclose(posed, lbs.deform(s), atol=2e-6)


def test_rotation_keys_are_sign_continuous(tmp_path, cylinder, bend):
    flipped = bend.rotations.copy()
    flipped[1::2] *= -1.0  # the same rotations with alternating signs
    motion = Motion(bend.skeleton, flipped, bend.translations, bend.rate)
    out = tmp_path / "flip.glb"
    write_glb(cylinder, motion, out)
    doc, blob = parse_glb(out)
    anim = doc["animations"][0]
    for ch in anim["channels"]:
        if ch["target"]["path"] == "rotation":
            keys = accessor(doc, blob, anim["samplers"][ch["sampler"]]["output"])
            assert (np.einsum("tk,tk->t", keys[1:], keys[:-1]) > 0).all()
    _, posed = play_glb(out)
    np.testing.assert_allclose(posed, lbs_reference(cylinder, bend), atol=2e-6)


def test_four_influences_padding_and_truncation(tmp_path, bend):
    one = cylinder_mesh(n_influences=1)
    out = tmp_path / "one.glb"
    write_glb(one, bend_motion(one), out)
    doc, blob = parse_glb(out)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    assert doc["accessors"][attrs["JOINTS_0"]]["componentType"] == 5123
    assert doc["accessors"][attrs["WEIGHTS_0"]]["componentType"] == 5126
    w = accessor(doc, blob, attrs["WEIGHTS_0"])
    assert w.shape == (one.n_vertices, 4)
    np.testing.assert_array_equal(w[:, 1:], 0.0)
    np.testing.assert_allclose(w[:, 0], 1.0)

    # nine influences over three joints (each weight split 0.5/0.3/0.2): the 4 largest
    # are kept and renormalised; blend-zone vertices have 6 non-zero weights
    base = cylinder_mesh(n_influences=3)
    idx = np.concatenate([base.skin.joint_indices] * 3, axis=1)
    wts = np.concatenate([f * base.skin.joint_weights for f in (0.5, 0.3, 0.2)], axis=1)
    six = Mesh(
        vertices=base.vertices, faces=base.faces,
        skin=Skin(base.skin.skeleton, idx, wts, base.skin.inverse_bind),
    )  # fmt: skip
    out6 = tmp_path / "six.glb"
    lossy = int(((wts > 0).sum(axis=1) > 4).sum())
    assert lossy > 0
    with pytest.warns(SkincapWarning, match=f"4 influences per vertex: {lossy} vertices"):
        write_glb(six, bend_motion(six), out6)
    doc, blob = parse_glb(out6)
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    w6 = accessor(doc, blob, attrs["WEIGHTS_0"])
    j6 = accessor(doc, blob, attrs["JOINTS_0"]).astype(int)
    np.testing.assert_allclose(w6.sum(axis=1), 1.0, atol=1e-6)
    expect = np.sort(wts, axis=1)[:, ::-1][:, :4]
    expect = expect / expect.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(np.sort(w6, axis=1)[:, ::-1], expect, atol=1e-6)
    assert (j6[w6 == 0] == 0).all()


def test_non_rigid_bind_uses_first_frame_as_rest(tmp_path, cylinder, bend):
    bind = cylinder.skin.bind_matrices.copy()
    bind[:, :3, :3] *= 1.5  # a scaled bind pose has no TRS without scale
    skin = Skin(cylinder.skin.skeleton, cylinder.skin.joint_indices,
                cylinder.skin.joint_weights, np.linalg.inv(bind))  # fmt: skip
    mesh = Mesh(vertices=cylinder.vertices, faces=cylinder.faces, skin=skin)
    out = tmp_path / "scaled.glb"
    write_glb(mesh, bend, out)
    doc, _ = parse_glb(out)
    for j in range(3):
        np.testing.assert_allclose(doc["nodes"][j]["rotation"], bend.rotations[0, j], atol=1e-12)
        np.testing.assert_allclose(doc["nodes"][j]["translation"], bend.translations[0, j])
    _, posed = play_glb(out)
    np.testing.assert_allclose(posed, lbs_reference(mesh, bend), atol=2e-6)


def test_single_frame_motion(tmp_path, cylinder):
    q0, t0 = bind_local(cylinder.skin)
    rest = Motion(cylinder.skin.skeleton, q0[None], t0[None], 30.0)
    out = tmp_path / "rest.glb"
    write_glb(cylinder, rest, out)
    times, posed = play_glb(out)
    np.testing.assert_array_equal(times, [0.0])
    np.testing.assert_allclose(posed[0], cylinder.vertices, atol=1e-6)


def test_validation(tmp_path, cylinder, bend):
    out = tmp_path / "x.glb"
    bare = Mesh(vertices=cylinder.vertices, faces=cylinder.faces)
    with pytest.raises(ValidationError, match="no skin"):
        write_glb(bare, bend, out)
    renamed = Skeleton(["root", "forearm", "tip"], bend.skeleton.parents, bend.skeleton.offsets)
    other = Motion(renamed, bend.rotations, bend.translations, bend.rate)
    with pytest.raises(ValidationError, match="joint 1 is 'forearm'.*'elbow'"):
        write_glb(cylinder, other, out)
    short = Skeleton(["root", "elbow"], [-1, 0], bend.skeleton.offsets[:2])
    with pytest.raises(ValidationError, match="2 joints"):
        write_glb(cylinder, Motion(short, bend.rotations[:, :2], bend.translations[:, :2], 24), out)
    flat = Skeleton(["root", "elbow", "tip"], [-1, 0, 0], bend.skeleton.offsets)
    with pytest.raises(ValidationError, match="parent"):
        write_glb(cylinder, Motion(flat, bend.rotations, bend.translations, 24), out)
    assert not out.exists()
    write_glb(cylinder, bend, out)
    with pytest.raises(OutputExistsError):
        write_glb(cylinder, bend, out)
    write_glb(cylinder, bend, out, force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.glb"]  # no temporaries left


def test_makehuman_body(tmp_path):
    mesh = read_makehuman(DATA / "makehuman_base.obj")
    q0, t0 = bind_local(mesh.skin)
    n = 6
    rot = np.tile(q0, (n, 1, 1))
    tra = np.tile(t0, (n, 1, 1))
    names = mesh.skin.skeleton.names
    for name, axis in (("lowerarm01.L", "x"), ("upperarm01.R", "z"), ("spine03", "x")):
        j = names.index(name)
        turn = Rotation.from_euler(axis, np.linspace(0, 70, n)[:, None], degrees=True)
        rot[:, j] = (Rotation.from_quat(q0[j]) * turn).as_quat()
    tra[:, 0, 2] = np.linspace(0.0, 0.4, n)
    motion = Motion(mesh.skin.skeleton, rot, tra, 30.0)
    out = tmp_path / "mh.glb"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_glb(mesh, motion, out)
    back = read_gltf(out)
    assert back.n_vertices == 13380 and back.skin.skeleton.n_joints == 163
    _, posed = play_glb(out)
    ref = lbs_reference(mesh, motion)
    assert np.abs(ref[-1] - mesh.vertices).max() > 0.3
    np.testing.assert_allclose(posed, ref, atol=1e-5)  # float32 over a 1.7 m body
