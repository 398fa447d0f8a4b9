"""The rigged MakeHuman body: real base mesh / default rig, a tiny synthetic rig, bad input."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from byte_mutations import mutate as _mutate
from byte_mutations import mutation_ops
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import FormatError, SkincapError, SkincapWarning, ValidationError
from skincap.io._common import to_y_up
from skincap.io.makehuman import bone_rest_frames, read_makehuman
from skincap.types import Mesh

MUTATIONS = mutation_ops(max_size=5)

DATA = Path(__file__).resolve().parents[1] / "data"
OBJ = DATA / "makehuman_base.obj"
SKEL = DATA / "makehuman_default.mhskel"
WEIGHTS = DATA / "makehuman_default_weights.mhw"
BVH = DATA / "makehuman_tpose.bvh"


@pytest.fixture(scope="module")
def human() -> Mesh:
    return read_makehuman(OBJ)


def _mirror_index(names: list[str]) -> np.ndarray:
    swap = {".L": ".R", ".R": ".L"}
    return np.array(
        [names.index(n[:-2] + swap[n[-2:]]) if n[-2:] in swap else i for i, n in enumerate(names)]
    )


# --------------------------------------------------------------------------- real rig
def test_body_only_mesh(human: Mesh) -> None:
    assert human.n_vertices == 13380  # the 'body' group; 5,778 helper vertices dropped
    assert human.n_polygons == 13378
    assert np.all(np.diff(human.polygon_offsets) == 4)
    assert human.n_faces == 2 * 13378
    assert list(human.groups) == ["body"]
    np.testing.assert_array_equal(human.groups["body"], np.arange(13378))
    # the body vertices are the first 13,380 of base.obj, in order
    np.testing.assert_array_equal(human.meta["source_vertex"], np.arange(13380))
    assert human.meta["corner_uv"].shape == (4 * 13378,)
    height = human.bounds[1, 1] - human.bounds[0, 1]
    assert 1.6 < height < 1.9
    assert height == pytest.approx(0.84913 + 0.81676, abs=1e-9)
    assert human.meta["source_units"] == "dm" and human.meta["up"] == "y"


def test_weights_normalised_four_influences(human: Mesh) -> None:
    skin = human.skin
    assert skin is not None
    assert skin.joint_weights.shape == (13380, 4)
    np.testing.assert_allclose(skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    assert ((skin.joint_weights > 0).sum(axis=1) <= 4).all()
    assert (skin.joint_weights >= 0).all()
    # the raw sums of the body (not normalised in the file)
    sums = human.meta["weight_sums"]
    assert sums.min() == pytest.approx(0.954) and sums.max() == pytest.approx(1.063)
    # check one vertex with more than four raw influences against the file itself
    raw = json.loads(WEIGHTS.read_text())["weights"]
    per_vertex: dict[int, dict[str, float]] = {}
    for bone, pairs in raw.items():
        for v, w in pairs:
            per_vertex.setdefault(v, {})[bone] = per_vertex.get(v, {}).get(bone, 0.0) + w
    v = next(v for v in sorted(per_vertex) if v < 13380 and len(per_vertex[v]) > 5)
    top = sorted(per_vertex[v].items(), key=lambda kv: -kv[1])[:4]
    names = skin.skeleton.names
    expect = {b: w / sum(w for _, w in top) for b, w in top}
    got = {
        names[j]: w
        for j, w in zip(skin.joint_indices[v], skin.joint_weights[v], strict=True)
        if w > 0
    }
    assert got.keys() == expect.keys()
    for b in expect:
        assert got[b] == pytest.approx(expect[b], abs=1e-12)


def test_skeleton_structure(human: Mesh) -> None:
    sk = human.skin.skeleton
    assert sk.n_joints == 163
    assert sk.names[0] == "root" and sk.parents[0] == -1
    assert (sk.parents[1:] >= 0).all()  # a single root
    assert set(sk.names) == set(json.loads(SKEL.read_text())["bones"])
    spine = [
        sk.names[sk.parents[sk.index(n)]]
        for n in ("spine05", "spine04", "spine03", "neck01", "head")
    ]
    assert spine == ["root", "spine05", "spine04", "spine01", "neck03"]
    # offsets chain back to the bone heads (forward kinematics of the rest pose)
    heads = human.meta["bone_heads"]
    world = np.zeros_like(sk.offsets)
    for j in range(sk.n_joints):
        world[j] = sk.offsets[j] + (world[sk.parents[j]] if sk.parents[j] >= 0 else 0.0)
    np.testing.assert_allclose(world, heads, atol=1e-12)
    assert human.meta["bone_tails"].shape == (163, 3)


def test_joints_inside_body_and_symmetric(human: Mesh) -> None:
    heads = human.meta["bone_heads"]
    tails = human.meta["bone_tails"]
    lo, hi = human.bounds
    for p in (heads, tails):
        assert (p >= lo - 1e-9).all() and (p <= hi + 1e-9).all()
    mirror = _mirror_index(human.skin.skeleton.names)
    assert (mirror != np.arange(163)).sum() == 2 * 70  # 70 left/right pairs, 23 central bones
    np.testing.assert_allclose(heads[mirror] * [-1, 1, 1], heads, atol=1e-3)
    np.testing.assert_allclose(tails[mirror] * [-1, 1, 1], tails, atol=1e-3)
    centre = mirror == np.arange(163)
    np.testing.assert_allclose(heads[centre, 0], 0.0, atol=1e-3)
    # rolls are mirrored too: X_R = -M X_L, Y_R = M Y_L for the mirror M = diag(-1, 1, 1)
    bind = human.skin.bind_matrices
    m = np.diag([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(bind[mirror, :3, 0], -bind[:, :3, 0] @ m, atol=1e-9)
    np.testing.assert_allclose(bind[mirror, :3, 1], bind[:, :3, 1] @ m, atol=1e-9)


def test_bind_matrices(human: Mesh) -> None:
    skin = human.skin
    bind = skin.bind_matrices
    heads = human.meta["bone_heads"]
    tails = human.meta["bone_tails"]
    # the bind matrices take the bone-local origin to the bone heads
    np.testing.assert_allclose(
        np.einsum("jab,b->ja", bind, [0, 0, 0, 1.0])[:, :3], heads, atol=1e-12
    )
    np.testing.assert_allclose(
        bind @ skin.inverse_bind, np.broadcast_to(np.eye(4), bind.shape), atol=1e-12
    )
    r = bind[:, :3, :3]
    np.testing.assert_allclose(
        np.transpose(r, (0, 2, 1)) @ r, np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    # local Y runs from head to tail; local X leans towards the rotation-plane normal
    d = tails - heads
    np.testing.assert_allclose(r[:, :, 1], d / np.linalg.norm(d, axis=1, keepdims=True), atol=1e-12)
    assert (np.einsum("ja,ja->j", r[:, :, 0], human.meta["bone_normals"]) > 0).all()
    # legs bend about +X on both sides, as in MakeHuman / Blender
    names = skin.skeleton.names
    for n in ("upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R", "spine03"):
        assert r[names.index(n), 0, 0] > 0.95


def _bvh_rest_positions(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str | None]]:
    """World rest positions (file units and axes) and parents of a BVH's joints."""
    toks = path.read_text().split("MOTION")[0].split()
    pos: dict[str, np.ndarray] = {}
    parent: dict[str, str | None] = {}
    stack: list[tuple[str, np.ndarray]] = []
    name = ""
    i = 0
    while i < len(toks):
        t = toks[i]
        if t in ("ROOT", "JOINT"):
            name, i = toks[i + 1], i + 2
        elif t == "End":
            name, i = stack[-1][0] + "_end", i + 2
        elif t == "{":
            parent[name] = stack[-1][0] if stack else None
            stack.append((name, np.zeros(3)))
            i += 1
        elif t == "}":
            stack.pop()
            i += 1
        elif t == "OFFSET":
            base = stack[-2][1] if len(stack) > 1 else np.zeros(3)
            stack[-1] = (stack[-1][0], base + np.array(toks[i + 1 : i + 4], dtype=float))
            pos[stack[-1][0]] = stack[-1][1]
            i += 4
        else:
            i += 1
    return pos, parent


def test_matches_makehuman_tpose_bvh(human: Mesh) -> None:
    pos, parent = _bvh_rest_positions(BVH)
    sk = human.skin.skeleton
    bvh_joints = {n for n in pos if not n.endswith("_end")}
    # every rig bone is a BVH joint; the BVH (an older default rig) adds 10 metatarsals
    assert set(sk.names) <= bvh_joints
    assert sorted(bvh_joints - set(sk.names)) == [
        f"metatarsal{k}.{s}" for k in range(1, 6) for s in "LR"
    ]

    def rig_parent(n: str) -> str | None:
        p = parent[n]
        while p is not None and p not in sk.names:
            p = parent[p]
        return p

    for j, n in enumerate(sk.names):
        assert rig_parent(n) == (sk.names[sk.parents[j]] if sk.parents[j] >= 0 else None)
    # BVH offsets are decimetres, Z up; its rest is MakeHuman's default character,
    # whose modifiers move joints a few centimetres away from the raw base mesh's
    bvh = to_y_up(np.array([pos[n] for n in sk.names]), "z") * 0.1
    dist = np.linalg.norm(bvh - human.meta["bone_heads"], axis=1)
    assert np.median(dist) < 0.04
    assert dist.max() < 0.06


def test_keep_helpers_and_influence_count() -> None:
    full = read_makehuman(OBJ, SKEL, WEIGHTS, keep_helpers=True, max_influences=8)
    assert full.n_vertices == 19158 and full.n_polygons == 18486
    assert len(full.groups) == 139
    sums = full.meta["weight_sums"]
    assert sums.min() == pytest.approx(0.32, abs=0.005) and sums.max() == pytest.approx(
        1.67, abs=0.005
    )
    assert full.skin.joint_weights.shape == (19158, 8)
    np.testing.assert_allclose(full.skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    assert (full.skin.joint_weights > 0).sum(axis=1).max() == 8
    one = read_makehuman(OBJ, SKEL, WEIGHTS, max_influences=1)
    np.testing.assert_array_equal(one.skin.joint_weights, 1.0)
    # the rig itself does not depend on which vertices are kept
    np.testing.assert_array_equal(one.skin.inverse_bind, full.skin.inverse_bind)
    with pytest.raises(ValidationError):
        read_makehuman(OBJ, max_influences=0)


def test_default_file_names(tmp_path: Path) -> None:
    shutil.copy(OBJ, tmp_path / "base.obj")
    shutil.copy(SKEL, tmp_path / "default.mhskel")
    shutil.copy(WEIGHTS, tmp_path / "default_weights.mhw")
    m = read_makehuman(tmp_path / "base.obj")
    assert m.meta["skeleton_file"].endswith("default.mhskel")
    assert m.meta["weights_file"].endswith("default_weights.mhw")
    (tmp_path / "default.mhskel").unlink()
    with pytest.raises(FormatError, match="no skeleton"):
        read_makehuman(tmp_path / "base.obj")


def test_body_only_obj_written_beside_the_rig_reads_as_a_plain_mesh(tmp_path: Path) -> None:
    """``skincap skin ... -o walk.pc2`` in a folder holding the MakeHuman rig writes the
    body-only ``walk.obj`` (13,380 of the 19,158 vertices) beside it: it reads back as
    the plain mesh it is, not as the rigged base mesh (whose rig names helper
    vertices it does not have), so ``info``, ``view`` and ``render`` open it."""
    from skincap.io import read_mesh, write
    from skincap.io.makehuman import is_rigged_base_mesh

    for src in (OBJ, SKEL, WEIGHTS):
        shutil.copy(src, tmp_path / src.name)
    base = tmp_path / OBJ.name
    rigged = read_mesh(base)
    assert rigged.skin is not None and is_rigged_base_mesh(base)
    out = tmp_path / "walk.obj"
    write(Mesh(vertices=rigged.vertices, faces=rigged.faces), out)
    assert not is_rigged_base_mesh(out)
    plain = read_mesh(out)
    assert plain.skin is None and plain.n_vertices == rigged.n_vertices == 13380
    np.testing.assert_allclose(plain.vertices, rigged.vertices, atol=1e-6)


# ------------------------------------------------------------------------ synthetic rig
TINY_OBJ = """\
v 0 0 0
v 1 0 0
v 1 10 0
v 0 10 0
v 1 10 1
v 0 20 0
v 1 20 0
v 5 5 5
v 5 6 5
v 6 5 5
g body
f 1 2 3 4
f 4 3 7 6
g joint-helper
f 8 9 10
"""


def _tiny_rig() -> dict:
    return {
        "name": "tiny",
        "bones": {
            "upper": {
                "head": "a",
                "tail": "b",
                "parent": "base",
                "rotation_plane": "pl",
                "reference": None,
            },
            "base": {
                "head": "o",
                "tail": "a",
                "parent": None,
                "rotation_plane": "none",
                "reference": None,
            },
        },
        # joint a = vertex 0 (0,0,0), b = (0,10,0), c = (1,10,0) in decimetres
        "joints": {"o": [7, 8, 9], "a": [0], "b": [3], "c": [2]},
        "planes": {"pl": ["a", "b", "c"], "none": ["a", "a", "a"]},
        "weights_file": "tiny_weights.mhw",
    }


def _tiny_weights() -> dict:
    return {
        "weights": {
            "upper": [[2, 0.5], [3, 2.0], [5, 1.0], [6, 0.3]],
            "base": [[0, 0.3], [1, 0.3], [2, 0.5], [6, 0.1]],
        }
    }


def _write_tiny(folder: Path, rig: dict | None = None, weights: dict | None = None) -> Path:
    (folder / "tiny.obj").write_text(TINY_OBJ)
    (folder / "tiny.mhskel").write_text(json.dumps(rig or _tiny_rig()))
    (folder / "tiny_weights.mhw").write_text(json.dumps(weights or _tiny_weights()))
    return folder / "tiny.obj"


def test_tiny_rig_roll_weights_and_cut(tmp_path: Path) -> None:
    m = read_makehuman(_write_tiny(tmp_path))  # rig and weights found beside the OBJ
    sk = m.skin.skeleton
    assert sk.names == ["base", "upper"]  # parents first, whatever the file order
    np.testing.assert_array_equal(sk.parents, [-1, 0])
    # helper vertices 4 (unused), 7, 8, 9 dropped: 6 vertices, re-indexed
    np.testing.assert_array_equal(m.meta["source_vertex"], [0, 1, 2, 3, 5, 6])
    assert m.n_polygons == 2 and list(m.groups) == ["body"]
    np.testing.assert_array_equal(m.polygon_indices, [0, 1, 2, 3, 3, 2, 5, 4])
    # joint o is the centroid of the (dropped) helper vertices, in metres
    np.testing.assert_allclose(m.meta["rig_joints"]["o"], np.array([16 / 3, 16 / 3, 5]) * 0.1)
    np.testing.assert_allclose(m.meta["bone_heads"], [m.meta["rig_joints"]["o"], [0, 0, 0]])
    np.testing.assert_allclose(sk.offsets[1], -m.meta["rig_joints"]["o"])
    # plane a, b, c: normal = unit(c - b) x unit(b - a) = (1,0,0) x (0,1,0) = (0,0,1);
    # bone along +Y: X = normal, Z = normal x Y = (-1, 0, 0)
    upper = m.skin.bind_matrices[1]
    np.testing.assert_allclose(upper[:3, :3], [[0, 0, -1], [0, 1, 0], [1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(upper[:3, 3], [0, 0, 0], atol=1e-12)
    # weights: vertex 2 has 0.5 / 0.5 -> 0.5 / 0.5; vertex 3 only 'upper'; vertex 1 only 'base'
    w = m.skin.joint_weights
    idx = m.skin.joint_indices
    assert w.shape == (6, 4)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(w[2, :2], [0.5, 0.5])
    assert idx[3, 0] == 1 and w[3, 0] == 1.0
    assert idx[1, 0] == 0 and w[1, 0] == 1.0
    np.testing.assert_allclose(w[5, :2], [0.75, 0.25])  # source vertex 6: 0.3 upper, 0.1 base
    np.testing.assert_array_equal(idx[5, :2], [1, 0])


def test_bone_rest_frames_degenerate_normal() -> None:
    # normal parallel to the bone and a zero-length bone: still orthonormal frames, no NaN
    m = bone_rest_frames(
        np.zeros((2, 3)), np.array([[0, 1.0, 0], [0, 0, 0]]), np.array([[0, 1.0, 0], [0, 0, 0]])
    )
    assert np.isfinite(m).all()
    r = m[:, :3, :3]
    np.testing.assert_allclose(
        np.transpose(r, (0, 2, 1)) @ r, np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0)


def test_unweighted_vertex_goes_to_root_with_warning(tmp_path: Path) -> None:
    weights = {
        "weights": {"upper": [[2, 0.5], [3, 2.0], [5, 1.0]], "base": [[0, 0.3], [1, 0.3], [2, 0.5]]}
    }
    with pytest.warns(SkincapWarning, match="1 vertices have no weight"):
        m = read_makehuman(_write_tiny(tmp_path, weights=weights))
    assert m.skin.joint_indices[5, 0] == 0 and m.skin.joint_weights[5, 0] == 1.0


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        (lambda r: r["bones"]["upper"].update(head="nowhere"), "is not a joint"),
        (lambda r: r["bones"]["upper"].update(parent="ghost"), "is not a bone"),
        (lambda r: r["bones"]["base"].update(parent="upper"), "cycle"),
        (lambda r: r["joints"].update(a=[99]), "out of range"),
        (lambda r: r["joints"].update(a=[]), "non-empty list"),
        (lambda r: r["planes"].update(pl=["a", "b"]), "three joint names"),
        (lambda r: r["bones"]["upper"].update(rotation_plane="nope"), "not in 'planes'"),
        (lambda r: r.pop("bones"), "'bones'"),
    ],
)
def test_bad_rig(tmp_path: Path, change, fragment: str) -> None:
    rig = _tiny_rig()
    change(rig)
    obj = _write_tiny(tmp_path, rig=rig)
    with pytest.raises(FormatError, match=fragment) as err:
        read_makehuman(obj)
    assert "tiny.mhskel" in str(err.value)


def test_bad_json_and_weights(tmp_path: Path) -> None:
    obj = _write_tiny(tmp_path)
    (tmp_path / "tiny.mhskel").write_text('{"bones": {\n "a": [1,\n}')
    with pytest.raises(FormatError, match="invalid JSON") as err:
        read_makehuman(obj)
    assert err.value.line == 3
    for weights, fragment in [
        ({"weights": {"upper": [[99, 1.0]]}}, "vertex index"),
        ({"weights": {"upper": [[1, -1.0]]}}, "negative"),
        ({"weights": {"upper": [[1, "x"]]}}, "expected \\[\\[vertex"),
        ({"weights": [1, 2]}, "'weights' must be"),
    ]:
        _write_tiny(tmp_path, weights=weights)
        with pytest.raises(FormatError, match=fragment):
            read_makehuman(obj)
    _write_tiny(tmp_path, weights={"weights": {"ghost": [[1, 1.0]], **_tiny_weights()["weights"]}})
    with pytest.warns(SkincapWarning, match="not in the skeleton"):
        read_makehuman(obj)
    _write_tiny(tmp_path)
    (tmp_path / "tiny.obj").write_text(TINY_OBJ.replace("g body", "g skin"))
    with pytest.raises(FormatError, match="no 'body' group"):
        read_makehuman(obj)


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(ops=MUTATIONS, which=st.sampled_from(["tiny.obj", "tiny.mhskel", "tiny_weights.mhw"]))
def test_fuzz(tmp_path: Path, ops: list[tuple[int, int, int]], which: str) -> None:
    obj = _write_tiny(tmp_path)
    target = tmp_path / which
    target.write_bytes(_mutate(target.read_bytes(), ops))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkincapWarning)
            m = read_makehuman(obj)
    except SkincapError:
        return
    assert isinstance(m, Mesh)
    np.testing.assert_allclose(m.skin.joint_weights.sum(axis=1), 1.0)
