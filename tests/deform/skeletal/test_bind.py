"""bind_mesh, fit_skeleton_to_mesh, transform_skeleton."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import trimesh.remesh

from skincap.deform.skeletal.bind import (
    bind_mesh,
    fit_skeleton_to_mesh,
    rest_transforms,
    transform_skeleton,
)
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics, rest_positions
from skincap.types import Mesh, Motion, Skeleton


def _tube_mesh() -> Mesh:
    """A closed cylinder of radius 6 cm along Y from -0.5 to 0.5 m, edges <= 5 cm."""
    tube = trimesh.creation.cylinder(radius=0.06, height=1.0, sections=12)
    v, f = trimesh.remesh.subdivide_to_size(tube.vertices, tube.faces, max_edge=0.05)
    # stand it up: Z -> Y
    return Mesh(vertices=np.asarray(v)[:, [1, 2, 0]], faces=f)


def _tube_skeleton() -> Skeleton:
    return Skeleton(
        names=["hip", "knee", "ankle"],
        parents=[-1, 0, 1],
        offsets=[[0.0, 0.5, 0.0], [0.0, -0.5, 0.0], [0.0, -0.5, 0.0]],
    )


def _dense(idx: np.ndarray, w: np.ndarray, n_joints: int) -> np.ndarray:
    out = np.zeros((idx.shape[0], n_joints))
    np.add.at(out, (np.repeat(np.arange(idx.shape[0]), idx.shape[1]), idx.ravel()), w.ravel())
    return out


@pytest.fixture(scope="module")
def makehuman(data_dir) -> Mesh:
    from skincap.io.makehuman import read_makehuman

    return read_makehuman(data_dir / "makehuman_base.obj")


# ---------------------------------------------------------------------- auto
def test_auto_bind_on_a_skeleton() -> None:
    mesh = _tube_mesh()
    sk = _tube_skeleton()
    out = bind_mesh(mesh, sk)
    skin = out.skin
    assert skin is not None and skin.skeleton is sk
    assert out.meta["skin_weights"] == "auto"
    assert out.vertices is mesh.vertices and mesh.skin is None  # input untouched
    # bind matrices: identity rotations at the rest positions
    np.testing.assert_allclose(skin.bind_matrices[:, :3, :3], np.tile(np.eye(3), (3, 1, 1)))
    np.testing.assert_allclose(skin.bind_matrices[:, :3, 3], rest_positions(sk))
    # the rest pose gives identity skinning matrices
    rest = Motion(
        skeleton=sk,
        rotations=np.tile([0.0, 0, 0, 1], (1, 3, 1)),
        translations=sk.offsets[None],
        rate=30.0,
    )
    s = np.einsum("tjab,jbc->tjac", forward_kinematics(rest), skin.inverse_bind)
    np.testing.assert_allclose(s, np.tile(np.eye(4), (1, 3, 1, 1)), atol=1e-12)
    dense = _dense(skin.joint_indices, skin.joint_weights, 3)
    y = mesh.vertices[:, 1]
    assert dense[y > 0.3, 0].min() > 0.99  # the thigh belongs to the hip joint
    assert dense[y < -0.3, 1].min() > 0.99  # the shin to the knee joint
    assert dense[:, 2].max() == 0.0  # the end joint owns no bone


def test_auto_bind_from_a_motion_pose() -> None:
    mesh = _tube_mesh()
    sk = _tube_skeleton()
    # frame 0 rotates the hip by 90 degrees about Y: joint positions stay on the axis
    q = np.tile([0.0, 0, 0, 1], (2, 3, 1))
    q[0, 0] = [0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5)]
    motion = Motion(
        skeleton=sk, rotations=q, translations=np.tile(sk.offsets, (2, 1, 1)), rate=30.0
    )
    out = bind_mesh(mesh, motion)
    np.testing.assert_allclose(out.skin.bind_matrices, forward_kinematics(motion)[0], atol=1e-12)
    np.testing.assert_allclose(rest_transforms(motion), forward_kinematics(motion)[0])
    ref = bind_mesh(mesh, sk)
    np.testing.assert_allclose(
        _dense(out.skin.joint_indices, out.skin.joint_weights, 3),
        _dense(ref.skin.joint_indices, ref.skin.joint_weights, 3),
        atol=1e-12,
    )


def test_auto_bind_with_explicit_rest_world() -> None:
    mesh = _tube_mesh()
    sk = _tube_skeleton()
    rw = rest_transforms(sk)
    rw[:, :3, :3] = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    out = bind_mesh(mesh, sk, rest_world=rw, max_influences=2)
    np.testing.assert_allclose(out.skin.inverse_bind, np.linalg.inv(rw), atol=1e-12)
    assert out.skin.joint_weights.shape == (mesh.n_vertices, 2)


def test_auto_bind_refuses_a_skeleton_off_the_mesh() -> None:
    mesh = _tube_mesh()
    sk = _tube_skeleton()
    far = transform_skeleton(sk, 100.0, np.array([0.0, 0.0, 0.0]))  # centimetres
    with pytest.raises(ValidationError, match="fit_skeleton_to_mesh"):
        bind_mesh(mesh, far)
    scale, translation = fit_skeleton_to_mesh(far, mesh)
    fitted = transform_skeleton(far, scale, translation)
    np.testing.assert_allclose(rest_positions(fitted), rest_positions(sk), atol=1e-9)
    assert bind_mesh(mesh, fitted).skin is not None


# ---------------------------------------------------------------------- file
def test_file_weights_kept(makehuman: Mesh) -> None:
    out = bind_mesh(makehuman, weights="file")
    skin, orig = out.skin, makehuman.skin
    assert skin.skeleton is orig.skeleton
    np.testing.assert_allclose(skin.inverse_bind, orig.inverse_bind)
    j = orig.skeleton.n_joints
    np.testing.assert_allclose(
        _dense(skin.joint_indices, skin.joint_weights, j),
        _dense(orig.joint_indices, orig.joint_weights, j),
        atol=1e-12,
    )
    # same result when the skeleton is passed: the file's bone-roll bind matrices stay
    again = bind_mesh(makehuman, orig.skeleton, weights="file")
    np.testing.assert_allclose(again.skin.inverse_bind, orig.inverse_bind)


def test_file_weights_limited(makehuman: Mesh) -> None:
    out = bind_mesh(makehuman, weights="file", max_influences=2)
    skin, orig = out.skin, makehuman.skin
    assert skin.joint_weights.shape == (makehuman.n_vertices, 2)
    np.testing.assert_allclose(skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    dense_orig = _dense(orig.joint_indices, orig.joint_weights, orig.skeleton.n_joints)
    assert np.array_equal(skin.joint_indices[:, 0], dense_orig.argmax(axis=1))
    # the two largest weights in the original proportion
    top2 = np.sort(dense_orig, axis=1)[:, -2:][:, ::-1]
    np.testing.assert_allclose(skin.joint_weights, top2 / top2.sum(axis=1, keepdims=True))


def test_file_weights_mapped_by_name(makehuman: Mesh) -> None:
    orig = makehuman.skin
    sk = orig.skeleton
    # the same joints in another (still topological) order: children of the root first
    # reversed within each depth is complex; a simple valid reorder: move the last leaf
    order = list(range(sk.n_joints))
    leaf = int(np.nonzero(sk.is_leaf)[0][0])
    order.remove(leaf)
    order.append(leaf)
    inv = np.argsort(order)
    parents = np.array([inv[sk.parents[j]] if sk.parents[j] >= 0 else -1 for j in order])
    reordered = Skeleton(
        names=[sk.names[j] for j in order], parents=parents, offsets=sk.offsets[order]
    )
    out = bind_mesh(makehuman, reordered, weights="file")
    dense = _dense(out.skin.joint_indices, out.skin.joint_weights, sk.n_joints)
    dense_orig = _dense(orig.joint_indices, orig.joint_weights, sk.n_joints)
    np.testing.assert_allclose(dense, dense_orig[:, order], atol=1e-12)
    np.testing.assert_allclose(out.skin.inverse_bind, orig.inverse_bind[order])


def test_file_weights_errors(makehuman: Mesh) -> None:
    bare = Mesh(vertices=makehuman.vertices, faces=makehuman.faces)
    with pytest.raises(ValidationError, match="no skin"):
        bind_mesh(bare, makehuman.skin.skeleton, weights="file")
    with pytest.raises(ValidationError, match="skeleton"):
        bind_mesh(bare)
    sk = makehuman.skin.skeleton
    # a skeleton lacking the weighted hand joints
    keep = [j for j in range(sk.n_joints) if "finger" not in sk.names[j]]
    remap = {j: k for k, j in enumerate(keep)}
    small = Skeleton(
        names=[sk.names[j] for j in keep],
        parents=[remap[int(sk.parents[j])] if sk.parents[j] >= 0 else -1 for j in keep],
        offsets=sk.offsets[keep],
    )
    with pytest.raises(ValidationError, match="finger"):
        bind_mesh(makehuman, small, weights="file")


def test_bad_arguments() -> None:
    mesh = _tube_mesh()
    sk = _tube_skeleton()
    with pytest.raises(ValidationError, match="weights"):
        bind_mesh(mesh, sk, weights="nearest")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="max_influences"):
        bind_mesh(mesh, sk, max_influences=0)
    with pytest.raises(ValidationError, match="rest_world"):
        bind_mesh(mesh, sk, rest_world=np.zeros((2, 4, 4)))
    with pytest.raises(ValidationError, match="singular"):
        bind_mesh(mesh, sk, rest_world=np.tile(np.diag([0.0, 0, 0, 1]), (3, 1, 1)))
    bad = rest_transforms(sk)
    bad[0, 3, 0] = 1.0
    with pytest.raises(ValidationError, match="last row"):
        bind_mesh(mesh, sk, rest_world=bad)
    with pytest.raises(ValidationError, match="skeleton"):
        bind_mesh(mesh, "hips")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="mesh"):
        bind_mesh(mesh.vertices, sk)  # type: ignore[arg-type]


# ----------------------------------------------------------------------- fit
def test_fit_cmu_skeleton_to_makehuman(makehuman: Mesh, data_dir) -> None:
    from skincap.io.bvh import read_bvh

    motion = read_bvh(data_dir / "cmu_131_01_bvh11.bvh", units="cmu")
    scale, translation = fit_skeleton_to_mesh(motion.skeleton, makehuman)
    fitted = transform_skeleton(motion.skeleton, scale, translation)
    pos = rest_positions(fitted)
    lo, hi = makehuman.bounds
    assert np.ptp(pos[:, 1]) == pytest.approx(hi[1] - lo[1], rel=1e-12)
    np.testing.assert_allclose(0.5 * (pos.min(0) + pos.max(0)), 0.5 * (lo + hi), atol=1e-12)
    np.testing.assert_allclose(
        pos, scale * rest_positions(motion.skeleton) + translation, atol=1e-12
    )
    s2, _ = fit_skeleton_to_mesh(motion.skeleton, makehuman, joint_span_ratio=0.9)
    assert s2 == pytest.approx(0.9 * scale)
    with pytest.raises(ValidationError, match="joint_span_ratio"):
        fit_skeleton_to_mesh(motion.skeleton, makehuman, joint_span_ratio=0.0)
    flat = Mesh(vertices=[[0.0, 0, 0], [1, 0, 0], [0, 0, 1]], faces=[[0, 1, 2]])
    with pytest.raises(ValidationError, match="height"):
        fit_skeleton_to_mesh(motion.skeleton, flat)
    with pytest.raises(ValidationError, match="scale"):
        transform_skeleton(motion.skeleton, -1.0, translation)
