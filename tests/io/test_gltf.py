"""glTF / GLB reader: hand-built skinned cylinder and static scenes, trimesh cross-check, bad input.

skincap's glTF writer comes later; these tests build their files with the tiny
writer below (plain JSON + numpy bytes), following the glTF 2.0 specification.
"""

from __future__ import annotations

import base64
import json
import os
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from byte_mutations import mutate as _mutate
from byte_mutations import mutation_ops
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from skincap.errors import FormatError, SkincapError, SkincapWarning
from skincap.io.gltf.reader import read_gltf
from skincap.types import Mesh

MUTATIONS = mutation_ops(max_size=6)

FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125


# ------------------------------------------------------------------ tiny glTF writer
class GltfBuilder:
    """Collects binary arrays into one buffer and writes .gltf / .glb files."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def _view(self, data: bytes, stride: int | None = None) -> int:
        self.blob += b"\x00" * (-len(self.blob) % 4)
        view = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if stride:
            view["byteStride"] = stride
        self.blob += data
        self.views.append(view)
        return len(self.views) - 1

    def add(self, arr: np.ndarray, comp: int, typ: str, *, normalized: bool = False) -> int:
        arr = np.ascontiguousarray(arr)
        acc: dict[str, Any] = {
            "bufferView": self._view(arr.tobytes()),
            "componentType": comp,
            "count": len(arr),
            "type": typ,
        }
        if normalized:
            acc["normalized"] = True
        if typ == "VEC3" and comp == FLOAT:
            acc["min"] = arr.min(axis=0).tolist()
            acc["max"] = arr.max(axis=0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_interleaved(self, a: np.ndarray, b: np.ndarray) -> tuple[int, int]:
        """Two float32 attributes interleaved in one view with a byteStride."""
        rec = np.zeros(len(a), dtype=[("a", "<f4", (a.shape[1],)), ("b", "<f4", (b.shape[1],))])
        rec["a"], rec["b"] = a, b
        view = self._view(rec.tobytes(), stride=rec.dtype.itemsize)
        out = []
        for off, arr in ((0, a), (a.shape[1] * 4, b)):
            acc = {
                "bufferView": view,
                "byteOffset": off,
                "componentType": FLOAT,
                "count": len(arr),
                "type": f"VEC{arr.shape[1]}",
            }
            if arr.shape[1] == 3:
                acc["min"] = arr.min(axis=0).tolist()
                acc["max"] = arr.max(axis=0).tolist()
            self.accessors.append(acc)
            out.append(len(self.accessors) - 1)
        return out[0], out[1]

    def document(
        self,
        nodes: list[dict],
        meshes: list[dict],
        skins: list[dict] | None = None,
        uri: str | None = None,
    ) -> dict:
        self.blob += b"\x00" * (-len(self.blob) % 4)
        buf: dict[str, Any] = {"byteLength": len(self.blob)}
        if uri is not None:
            buf["uri"] = uri
        doc = {
            "asset": {"version": "2.0", "generator": "skincap test writer"},
            "scene": 0,
            "scenes": [
                {
                    "nodes": [
                        i
                        for i in range(len(nodes))
                        if not any(i in n.get("children", []) for n in nodes)
                    ]
                }
            ],
            "nodes": nodes,
            "meshes": meshes,
            "buffers": [buf],
            "bufferViews": self.views,
            "accessors": self.accessors,
        }
        if skins:
            doc["skins"] = skins
        return doc

    def write_gltf(self, path: Path, nodes, meshes, skins=None, *, embed: bool) -> Path:
        self.blob += b"\x00" * (-len(self.blob) % 4)
        if embed:
            uri = (
                "data:application/octet-stream;base64,"
                + base64.b64encode(bytes(self.blob)).decode()
            )
        else:
            uri = path.stem + ".bin"
        doc = self.document(nodes, meshes, skins, uri)
        if not embed:
            (path.parent / uri).write_bytes(bytes(self.blob))
        path.write_text(json.dumps(doc, indent=1))
        return path

    def write_glb(self, path: Path, nodes, meshes, skins=None) -> Path:
        doc = self.document(nodes, meshes, skins)
        js = json.dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        binary = bytes(self.blob)
        total = 12 + 8 + len(js) + 8 + len(binary)
        out = struct.pack("<4sII", b"glTF", 2, total)
        out += struct.pack("<II", len(js), 0x4E4F534A) + js
        out += struct.pack("<II", len(binary), 0x004E4942) + binary
        path.write_bytes(out)
        return path


def cylinder(rings: int = 5, seg: int = 8, radius: float = 0.1, length: float = 1.0):
    """Open cylinder along +Y: (V, 3) float32 positions, (F, 3) uint16 triangles, (V, 2) uv."""
    a = np.linspace(0, 2 * np.pi, seg, endpoint=False)
    y = np.linspace(0, length, rings)
    pos = np.stack(
        [np.tile(radius * np.cos(a), rings), np.repeat(y, seg), np.tile(radius * np.sin(a), rings)],
        axis=1,
    ).astype(np.float32)
    r, s = np.meshgrid(np.arange(rings - 1), np.arange(seg), indexing="ij")
    v0 = (r * seg + s).ravel()
    v1 = (r * seg + (s + 1) % seg).ravel()
    v2, v3 = v0 + seg, v1 + seg
    tri = np.concatenate([np.stack([v0, v2, v1], 1), np.stack([v1, v2, v3], 1)]).astype(np.uint16)
    uv = np.stack(
        [np.tile(np.arange(seg) / seg, rings), np.repeat(y / length, seg)], axis=1
    ).astype(np.float32)
    return pos, tri, uv


TIP_ROT = Rotation.from_euler("z", 10, degrees=True)


def skinned_cylinder(weights_kind: str = "float") -> tuple[GltfBuilder, list, list, list, dict]:
    """Two-bone skinned cylinder: bone 'thigh' at the origin, 'shin' 0.5 m up (rotated 10° about Z).

    The skin lists the child joint first to exercise the reordering to parents-first.
    """
    pos, tri, uv = cylinder()
    nv = len(pos)
    t = np.clip((pos[:, 1] - 0.25) / 0.5, 0, 1)  # 0 below 0.25 m, 1 above 0.75 m
    # skin joint 0 = shin (node 2), skin joint 1 = thigh (node 1)
    joints = np.zeros((nv, 4), dtype=np.uint8)
    joints[:, 0], joints[:, 1] = 1, 0
    weights = np.zeros((nv, 4), dtype=np.float32)
    weights[:, 0], weights[:, 1] = 1 - t, t
    b = GltfBuilder()
    p_acc = b.add(pos, FLOAT, "VEC3")
    i_acc = b.add(tri.reshape(-1), USHORT, "SCALAR")
    uv_acc = b.add(uv, FLOAT, "VEC2")
    j_acc = b.add(joints, UBYTE, "VEC4")
    if weights_kind == "ubyte":
        w8 = np.round(weights * 255).astype(np.uint8)
        w_acc = b.add(w8, UBYTE, "VEC4", normalized=True)
    elif weights_kind == "double":
        w_acc = b.add(weights * 2, FLOAT, "VEC4")
    else:
        w_acc = b.add(weights, FLOAT, "VEC4")
    thigh_world = np.eye(4)
    shin_world = np.eye(4)
    shin_world[:3, :3] = TIP_ROT.as_matrix()
    shin_world[:3, 3] = [0, 0.5, 0]
    ibm = (
        np.stack([np.linalg.inv(shin_world), np.linalg.inv(thigh_world)])
        .transpose(0, 2, 1)
        .astype(np.float32)
    )
    ibm_acc = b.add(ibm.reshape(2, 16), FLOAT, "MAT4")
    nodes = [
        {"name": "armature", "children": [1, 3]},
        {"name": "thigh", "children": [2]},
        {"name": "shin", "translation": [0, 0.5, 0], "rotation": TIP_ROT.as_quat().tolist()},
        {"name": "leg_mesh", "mesh": 0, "skin": 0, "translation": [5, 0, 0]},  # ignored: skinned
    ]
    meshes = [
        {
            "name": "leg",
            "primitives": [
                {
                    "attributes": {
                        "POSITION": p_acc,
                        "TEXCOORD_0": uv_acc,
                        "JOINTS_0": j_acc,
                        "WEIGHTS_0": w_acc,
                    },
                    "indices": i_acc,
                }
            ],
        }
    ]
    skins = [{"joints": [2, 1], "inverseBindMatrices": ibm_acc}]
    expect = {
        "pos": pos.astype(float),
        "tri": tri.astype(np.int64),
        "uv": uv.astype(float),
        "t": t.astype(float),
    }
    return b, nodes, meshes, skins, expect


def write_skinned(tmp_path: Path, kind: str, weights_kind: str = "float") -> tuple[Path, dict]:
    b, nodes, meshes, skins, expect = skinned_cylinder(weights_kind)
    if kind == "glb":
        return b.write_glb(tmp_path / "leg.glb", nodes, meshes, skins), expect
    return b.write_gltf(
        tmp_path / f"leg_{kind}.gltf", nodes, meshes, skins, embed=kind == "embedded"
    ), expect


def static_scene(tmp_path: Path, kind: str) -> tuple[Path, np.ndarray, np.ndarray]:
    """A transformed parent with a child holding a 'matrix' and an interleaved mesh, plus a plain copy."""
    pos, tri, uv = cylinder(rings=3, seg=6)
    b = GltfBuilder()
    p_acc, uv_acc = b.add_interleaved(pos, uv)
    i_acc = b.add(tri.astype(np.uint32).reshape(-1), UINT, "SCALAR")
    parent_rot = Rotation.from_euler("xyz", [20, 30, 40], degrees=True)
    child = np.eye(4)
    child[:3, :3] = Rotation.from_euler("y", 90, degrees=True).as_matrix() * 0.5
    child[:3, 3] = [0.1, 0.2, 0.3]
    nodes = [
        {
            "name": "parent",
            "translation": [1, 2, 3],
            "rotation": parent_rot.as_quat().tolist(),
            "scale": [2, 2, 2],
            "children": [1],
        },
        {"name": "child", "matrix": child.T.reshape(-1).tolist(), "mesh": 0},
        {"name": "plain", "mesh": 0},
    ]
    meshes = [
        {
            "primitives": [
                {"attributes": {"POSITION": p_acc, "TEXCOORD_0": uv_acc}, "indices": i_acc}
            ]
        }
    ]
    parent_m = np.eye(4)
    parent_m[:3, :3] = parent_rot.as_matrix() * 2
    parent_m[:3, 3] = [1, 2, 3]
    w = parent_m @ child
    moved = pos.astype(float) @ w[:3, :3].T + w[:3, 3]
    expect_pos = np.concatenate([moved, pos.astype(float)])
    expect_tri = np.concatenate([tri, tri + len(pos)]).astype(np.int64)
    if kind == "glb":
        return b.write_glb(tmp_path / "scene.glb", nodes, meshes), expect_pos, expect_tri
    return (
        b.write_gltf(tmp_path / "scene.gltf", nodes, meshes, embed=kind == "embedded"),
        expect_pos,
        expect_tri,
    )


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("kind", ["external", "embedded", "glb"])
def test_skinned_cylinder(tmp_path: Path, kind: str) -> None:
    path, expect = write_skinned(tmp_path, kind)
    m = read_gltf(path)
    # skinned mesh: its node's translation (5, 0, 0) is ignored, as the spec says
    np.testing.assert_array_equal(m.vertices, expect["pos"])
    np.testing.assert_array_equal(m.faces, expect["tri"])
    np.testing.assert_allclose(m.uv, np.stack([expect["uv"][:, 0], 1 - expect["uv"][:, 1]], axis=1))
    assert list(m.groups) == ["leg_mesh"]
    assert m.meta["source_units"] == "m" and m.meta["up"] == "y"
    assert m.meta["source_format"] == ("glb" if kind == "glb" else "gltf")
    skin = m.skin
    assert skin is not None
    sk = skin.skeleton
    assert sk.names == ["thigh", "shin"]  # reordered parents-first
    np.testing.assert_array_equal(sk.parents, [-1, 0])
    np.testing.assert_allclose(sk.offsets, [[0, 0, 0], [0, 0.5, 0]], atol=1e-7)
    np.testing.assert_allclose(m.meta["joint_rest_rotations"][1], TIP_ROT.as_quat(), atol=1e-7)
    np.testing.assert_allclose(m.meta["joint_rest_rotations"][0], [0, 0, 0, 1], atol=1e-12)
    # inverse binds follow the reordering: bind of 'shin' is its rest world transform
    np.testing.assert_allclose(skin.bind_matrices, m.meta["joint_rest_world"], atol=1e-6)
    # weights: the skin's joint 1 ('thigh') became joint 0
    t = expect["t"]
    np.testing.assert_allclose(skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    w_thigh = np.where(skin.joint_indices == 0, skin.joint_weights, 0).sum(axis=1)
    w_shin = np.where(skin.joint_indices == 1, skin.joint_weights, 0).sum(axis=1)
    np.testing.assert_allclose(w_thigh, 1 - t, atol=1e-6)  # the lower part follows the thigh
    np.testing.assert_allclose(w_shin, t, atol=1e-6)


def test_skinned_cylinder_matches_trimesh(tmp_path: Path) -> None:
    for kind in ("external", "glb"):
        path, _ = write_skinned(tmp_path, kind)
        m = read_gltf(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tm = trimesh.load(path, force="mesh", process=False)
        assert tm.vertices.shape == m.vertices.shape
        np.testing.assert_allclose(tm.faces, m.faces)


@pytest.mark.parametrize("kind", ["external", "embedded", "glb"])
def test_static_scene_node_transforms_and_trimesh(tmp_path: Path, kind: str) -> None:
    path, expect_pos, expect_tri = static_scene(tmp_path, kind)
    m = read_gltf(path)
    assert m.skin is None
    np.testing.assert_allclose(m.vertices, expect_pos, atol=1e-6)
    np.testing.assert_array_equal(m.faces, expect_tri)
    assert list(m.groups) == ["child", "plain"]
    np.testing.assert_array_equal(m.groups["plain"], np.arange(m.n_faces // 2, m.n_faces))
    assert m.uv is not None and m.uv.shape == (m.n_vertices, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = trimesh.load(path, process=False)
    tm_all = scene.to_geometry() if isinstance(scene, trimesh.Scene) else scene
    # same point set as trimesh (trimesh may order the instances differently)
    ours = np.unique(np.round(m.vertices, 6), axis=0)
    theirs = np.unique(np.round(np.asarray(tm_all.vertices), 6), axis=0)
    np.testing.assert_allclose(ours, theirs, atol=2e-6)


def test_weights_normalised_with_warning(tmp_path: Path) -> None:
    path, expect = write_skinned(tmp_path, "glb", weights_kind="double")
    with pytest.warns(SkincapWarning, match="not normalised"):
        m = read_gltf(path)
    np.testing.assert_allclose(m.skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    # 8-bit normalized weights: quantised, no warning, still normalised exactly
    path, expect = write_skinned(tmp_path, "external", weights_kind="ubyte")
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        m = read_gltf(path)
    np.testing.assert_allclose(m.skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    w_thigh = np.where(m.skin.joint_indices == 0, m.skin.joint_weights, 0).sum(axis=1)
    np.testing.assert_allclose(w_thigh, 1 - expect["t"], atol=1 / 255)


def test_sparse_accessor_and_no_indices(tmp_path: Path) -> None:
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    b = GltfBuilder()
    p_acc = b.add(pos, FLOAT, "VEC3")
    sp_idx = b._view(np.array([2], dtype=np.uint16).tobytes())
    sp_val = b._view(np.array([[0, 2, 0]], dtype=np.float32).tobytes())
    b.accessors[p_acc]["sparse"] = {
        "count": 1,
        "indices": {"bufferView": sp_idx, "componentType": USHORT},
        "values": {"bufferView": sp_val},
    }
    path = b.write_gltf(
        tmp_path / "sparse.gltf",
        [{"mesh": 0}],
        [{"primitives": [{"attributes": {"POSITION": p_acc}}]}],
        embed=True,
    )
    m = read_gltf(path)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 2, 0]])
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])
    assert m.uv is None and m.skin is None


def _doc_and_bin(tmp_path: Path) -> Path:
    path, _ = write_skinned(tmp_path, "external")
    return path


@pytest.mark.parametrize(
    ("edit", "fragment"),
    [
        (lambda d: d["accessors"][0].update(count=10**6), "needs bytes"),
        (lambda d: d["accessors"][1].update(componentType=999), "unknown componentType"),
        (lambda d: d["bufferViews"][0].update(byteLength=10**8), "run past the buffer"),
        (lambda d: d["buffers"][0].update(uri="missing.bin"), "uri 'missing.bin': cannot read it"),
        (lambda d: d["buffers"][0].update(byteLength=10**8), "byteLength says"),
        (
            lambda d: d["meshes"][0]["primitives"][0].update(indices=99),
            r"accessors\[99\] does not exist",
        ),
        (lambda d: d["skins"][0].update(joints=[2, 7]), "distinct node indices"),
        (lambda d: d["nodes"][2].update(children=[1]), "more than one parent"),
        (lambda d: d["asset"].update(version="1.0"), "only glTF 2"),
        (lambda d: d["meshes"][0]["primitives"][0]["attributes"].pop("POSITION"), "no POSITION"),
        (lambda d: d["accessors"][0].update(type="VEC2"), "POSITION must be float VEC3"),
        # read as if uncompressed before: silent garbage (zeros where a view is absent)
        (
            lambda d: d.update(
                extensionsRequired=["KHR_materials_unlit", "EXT_meshopt_compression"]
            ),
            r"requires the glTF extension\(s\) EXT_meshopt_compression, which",
        ),
        (lambda d: d.update(extensionsRequired="KHR_draco"), "extensionsRequired must be a list"),
        # was SciPy's 'Non-positive determinant ... [[ 0. 0. 0.] ...' with the matrix
        (
            lambda d: d["nodes"][d["skins"][0]["joints"][0]].update(scale=[0, 0, 0]),
            r"joint node \d+ \('\w+'\) has a zero or negative scale",
        ),
    ],
)
def test_bad_documents(tmp_path: Path, edit, fragment: str) -> None:
    path = _doc_and_bin(tmp_path)
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=fragment) as err:
        read_gltf(path)
    assert str(path) in str(err.value)


def test_required_extensions_about_looks_alone_are_read(tmp_path: Path) -> None:
    path = _doc_and_bin(tmp_path)
    plain = read_gltf(path)
    doc = json.loads(path.read_text())
    doc["extensionsRequired"] = ["KHR_materials_unlit", "KHR_texture_transform"]
    path.write_text(json.dumps(doc))
    np.testing.assert_array_equal(read_gltf(path).vertices, plain.vertices)


def test_index_out_of_range_and_bad_json(tmp_path: Path) -> None:
    pos = np.eye(3, dtype=np.float32)
    b = GltfBuilder()
    p_acc = b.add(pos, FLOAT, "VEC3")
    i_acc = b.add(np.array([0, 1, 5], dtype=np.uint16), USHORT, "SCALAR")
    path = b.write_gltf(
        tmp_path / "idx.gltf",
        [{"mesh": 0}],
        [{"primitives": [{"attributes": {"POSITION": p_acc}, "indices": i_acc}]}],
        embed=True,
    )
    with pytest.raises(FormatError, match="vertex index 5 out of range"):
        read_gltf(path)
    bad = tmp_path / "bad.gltf"
    bad.write_text('{"asset": {"version": "2.0"},\n "nodes": [\n')
    with pytest.raises(FormatError, match="invalid glTF JSON") as err:
        read_gltf(bad)
    assert err.value.line == 3


def test_bad_glb_container(tmp_path: Path) -> None:
    path, _ = write_skinned(tmp_path, "glb")
    data = path.read_bytes()
    cases = [
        (data[:-10], "GLB header says"),
        (data[:4] + struct.pack("<I", 1) + data[8:], "GLB version 1"),
        (data[:12] + struct.pack("<II", 10**6, 0x4E4F534A) + data[20:], "runs past the end"),
        (data[:16] + struct.pack("<I", 0x004E4942) + data[20:], "first chunk must be JSON"),
    ]
    for i, (blob, fragment) in enumerate(cases):
        p = tmp_path / f"bad{i}.glb"
        p.write_bytes(blob)
        with pytest.raises(FormatError, match=fragment):
            read_gltf(p)


# ------------------------------------------------------------ buffer uris (issue 13)
def _gltf_in(folder: Path) -> tuple[Path, bytes, dict]:
    """A skinned cylinder .gltf in ``folder`` with its buffer in leg_external.bin."""
    folder.mkdir(parents=True, exist_ok=True)
    path, _ = write_skinned(folder, "external")
    blob = (folder / "leg_external.bin").read_bytes()
    return path, blob, json.loads(path.read_text())


def _with_uri(path: Path, doc: dict, uri: str) -> Path:
    doc["buffers"][0]["uri"] = uri
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("uri_of", "fragment"),
    [
        (lambda outside: str(outside), "must be a relative path inside"),
        (lambda outside: "../outside/leg.bin", "must be a relative path inside"),
        (lambda outside: "%2E%2E/outside/leg.bin", "must be a relative path inside"),
        (lambda outside: "sub/../../outside/leg.bin", "must be a relative path inside"),
        (lambda outside: "..\\outside\\leg.bin", "must be a relative path inside"),
        (lambda outside: outside.as_uri(), "only a relative file name or a data: URI"),
        (lambda outside: "http://example.com/leg.bin", "only a relative file name or a data: URI"),
        (lambda outside: "//example.com/leg.bin", "only a relative file name or a data: URI"),
        (lambda outside: "/dev/zero", "must be a relative path inside"),
        (lambda outside: "/dev/urandom", "must be a relative path inside"),
        (lambda outside: "/etc/passwd", "must be a relative path inside"),
    ],
)
def test_buffer_uri_outside_the_folder_is_refused(tmp_path: Path, uri_of, fragment: str) -> None:
    path, blob, doc = _gltf_in(tmp_path / "model")
    outside = tmp_path / "outside" / "leg.bin"
    outside.parent.mkdir()
    outside.write_bytes(blob)  # the right bytes: refused for where they are, not what they hold
    _with_uri(path, doc, uri_of(outside))
    with pytest.raises(FormatError, match=fragment) as err:
        read_gltf(path)
    assert str(path) in str(err.value)


def test_buffer_symlink_escaping_the_folder_is_refused(tmp_path: Path) -> None:
    path, blob, doc = _gltf_in(tmp_path / "model")
    outside = tmp_path / "secret.bin"
    outside.write_bytes(blob)
    (tmp_path / "model" / "link.bin").symlink_to(outside)
    _with_uri(path, doc, "link.bin")
    with pytest.raises(FormatError, match="leads outside the glTF's folder"):
        read_gltf(path)
    # a symlink that stays inside the folder is read
    (tmp_path / "model" / "inner.bin").symlink_to(tmp_path / "model" / "leg_external.bin")
    _with_uri(path, doc, "inner.bin")
    assert read_gltf(path).n_vertices == 40


def test_buffer_that_is_not_a_regular_file_is_refused(tmp_path: Path) -> None:
    path, _, doc = _gltf_in(tmp_path / "model")
    fifo = tmp_path / "model" / "pipe.bin"
    os.mkfifo(fifo)  # open() for reading would wait for a writer forever
    _with_uri(path, doc, "pipe.bin")
    with pytest.raises(FormatError, match="is not a regular file"):
        read_gltf(path)
    (tmp_path / "model" / "dir.bin").mkdir()
    _with_uri(path, doc, "dir.bin")
    with pytest.raises(FormatError, match="is not a regular file"):
        read_gltf(path)


def test_buffer_in_a_subfolder_is_read_only_up_to_its_byte_length(tmp_path: Path) -> None:
    path, blob, doc = _gltf_in(tmp_path / "model")
    sub = tmp_path / "model" / "sub dir"
    sub.mkdir()
    big = sub / "leg.bin"
    big.write_bytes(blob)
    # 4 GiB of holes after the buffer: reading the whole file would take seconds and
    # 4 GiB of memory; reading byteLength bytes takes none
    os.truncate(big, 2**32)
    _with_uri(path, doc, "sub%20dir/leg.bin")
    mesh = read_gltf(path)
    expect = read_gltf(_gltf_in(tmp_path / "plain")[0])
    np.testing.assert_array_equal(mesh.vertices, expect.vertices)
    np.testing.assert_array_equal(mesh.faces, expect.faces)


@pytest.mark.parametrize("zero", ["matrix", "linear part"])
def test_singular_inverse_bind_matrix_is_refused(tmp_path: Path, zero: str) -> None:
    b, nodes, meshes, skins, _ = skinned_cylinder()
    acc = b.accessors[skins[0]["inverseBindMatrices"]]
    start = b.views[acc["bufferView"]]["byteOffset"] + 64  # second joint's matrix
    ibm = np.frombuffer(bytes(b.blob[start : start + 64]), dtype="<f4").reshape(4, 4).copy()
    if zero == "matrix":
        ibm[:] = 0.0  # column-major in the file: the fourth row is ibm[:, 3]
        fragment = r"inverseBindMatrices\[1\] has a fourth row other than \(0, 0, 0, 1\)"
    else:
        ibm[:3, :3] = 0.0
        fragment = r"inverseBindMatrices\[1\] is singular"
    b.blob[start : start + 64] = ibm.astype("<f4").tobytes()
    path = b.write_glb(tmp_path / "leg.glb", nodes, meshes, skins)
    with pytest.raises(FormatError, match=fragment):
        read_gltf(path)


def _seed(kind: str) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path, _ = write_skinned(Path(d), kind)
        return path.read_bytes()


_SEEDS = {"glb": _seed("glb"), "embedded": _seed("embedded")}


@settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(ops=MUTATIONS, kind=st.sampled_from(["glb", "embedded"]))
def test_fuzz(tmp_path: Path, ops: list[tuple[int, int, int]], kind: str) -> None:
    p = tmp_path / ("f.glb" if kind == "glb" else "f.gltf")
    p.write_bytes(_mutate(_SEEDS[kind], ops))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkincapWarning)
            m = read_gltf(p)
    except SkincapError:
        return
    assert isinstance(m, Mesh)
