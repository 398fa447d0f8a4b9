"""LBS and DQS deformers: agreement with libigl and usd-core, rigid cases, kernels, streaming."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.deform.skeletal.deformers import (
    DualQuaternionSkinning,
    LinearBlendSkinning,
    make_deformer,
    numba_available,
    skin_motion,
)
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics_arrays
from skincap.geometry.rotations import matrix_to_quat, quat_multiply
from skincap.io.makehuman import read_makehuman
from skincap.types import Mesh, Motion, Skeleton

BACKENDS = ["numpy"] + (["numba"] if numba_available() else [])
needs_numba = pytest.mark.skipif(not numba_available(), reason="numba cannot be imported")


# ------------------------------------------------------------------ random rigs
def random_rig(seed: int, n_vertices: int = 400, n_joints: int = 12, k: int = 4, n_frames: int = 5):
    """A random joint tree, a bind pose, posed frames and vertices scattered around the bones.

    Returns rest vertices (V, 3), indices (V, K), weights (V, K) (sorted by
    decreasing weight, rows summing to 1) and skinning matrices (T, J, 4, 4).
    """
    rng = np.random.default_rng(seed)
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, n_joints)])
    offsets = rng.normal(scale=0.3, size=(n_joints, 3))
    bind_rot = Rotation.random(n_joints, random_state=seed).as_quat()
    bind = forward_kinematics_arrays(parents, bind_rot, offsets)  # (J, 4, 4)
    heads = bind[:, :3, 3]
    pose_rot = Rotation.random(n_frames * n_joints, random_state=seed + 1).as_quat()
    pose_t = offsets + rng.normal(scale=0.05, size=(n_frames, n_joints, 3))
    world = forward_kinematics_arrays(parents, pose_rot.reshape(n_frames, n_joints, 4), pose_t)
    matrices = world @ np.linalg.inv(bind)
    near = rng.integers(0, n_joints, size=n_vertices)
    rest = heads[near] + rng.normal(scale=0.15, size=(n_vertices, 3))
    idx = np.stack([rng.permutation(n_joints)[:k] for _ in range(n_vertices)])
    idx[:, 0] = near
    w = rng.random((n_vertices, k)) ** 2
    w /= w.sum(axis=1, keepdims=True)
    order = np.argsort(-w, axis=1)
    return (
        rest,
        np.take_along_axis(idx, order, axis=1),
        np.take_along_axis(w, order, axis=1),
        matrices,
    )


def model_size(points: np.ndarray) -> float:
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def antipodal_matrices(n_joints: int, seed: int) -> np.ndarray:
    """Joints turned by +-179.9 / 180.1 degrees about one axis: canonical quaternions nearly antipodal."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angles = np.where(np.arange(n_joints) % 2 == 0, 179.9, 180.1)
    angles = angles + rng.normal(scale=0.02, size=n_joints)
    m = np.tile(np.eye(4), (n_joints, 1, 1))
    m[:, :3, :3] = Rotation.from_rotvec(np.radians(angles)[:, None] * axis).as_matrix()
    m[:, :3, 3] = rng.normal(scale=0.01, size=(n_joints, 3)) + np.array([0.3, -0.2, 0.1])
    return m


# ------------------------------------------------------------------ libigl
def igl_lbs(rest: np.ndarray, idx: np.ndarray, w: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    igl = pytest.importorskip("igl", reason="libigl (python module igl) not installed")
    n_j = matrices.shape[-3]
    dense = np.zeros((rest.shape[0], n_j))
    np.add.at(dense, (np.arange(rest.shape[0])[:, None], idx), w)
    lbs = igl.lbs_matrix(rest, dense)  # (V, 4 J): column 4 j + c holds w_j [x, y, z, 1]_c
    # stack of transposed transforms: rows 4 j .. 4 j + 3 are S_j[:3, :].T
    stacked = matrices[:, :, :3, :].transpose(0, 1, 3, 2).reshape(matrices.shape[0], 4 * n_j, 3)
    return np.einsum("va,tab->tvb", lbs, stacked)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lbs_agrees_with_libigl(seed: int, backend: str) -> None:
    rest, idx, w, matrices = random_rig(seed)
    ours = LinearBlendSkinning(rest, idx, w, backend=backend).deform(matrices)
    ref = igl_lbs(rest, idx, w, matrices)
    assert np.abs(ours - ref).max() <= 1e-6 * model_size(rest)
    assert np.abs(ours - ref).max() <= 1e-12 * model_size(rest)  # both double precision


@pytest.mark.parametrize("backend", BACKENDS)
def test_lbs_agrees_with_libigl_antipodal_and_affine(backend: str) -> None:
    rest, idx, w, _ = random_rig(5, n_joints=8)
    anti = antipodal_matrices(8, 5)[None]
    affine = anti.copy()
    affine[0, :, :3, :3] *= np.array([1.5, 0.7, 1.1])  # scale + shear: LBS applies it as is
    for m in (anti, affine):
        ours = LinearBlendSkinning(rest, idx, w, backend=backend).deform(m)
        assert np.abs(ours - igl_lbs(rest, idx, w, m)).max() <= 1e-12 * model_size(rest)


# ------------------------------------------------------------------ usd-core UsdSkel
def usd_skin(
    method: str, rest: np.ndarray, idx: np.ndarray, w: np.ndarray, matrices: np.ndarray
) -> np.ndarray:
    """UsdSkel's own skinning (float32 points; row-vector matrices, hence the transpose)."""
    pytest.importorskip("pxr", reason="usd-core (module pxr) not installed")
    from pxr import Gf, UsdSkel, Vt

    token = {"lbs": "classicLinear", "dqs": "dualQuaternion"}[method]
    out = []
    for frame in matrices:
        xforms = Vt.Matrix4dArray([Gf.Matrix4d(*m.T.ravel().tolist()) for m in frame])
        pts = Vt.Vec3fArray.FromNumpy(rest.astype(np.float32))
        ok = UsdSkel.SkinPoints(
            token,
            Gf.Matrix4d(1.0),
            xforms,
            Vt.IntArray.FromNumpy(idx.astype(np.int32).ravel()),
            Vt.FloatArray.FromNumpy(w.astype(np.float32).ravel()),
            idx.shape[1],
            pts,
            True,
        )
        assert ok
        out.append(np.array(pts, dtype=np.float64))
    return np.stack(out)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("method", ["lbs", "dqs"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agrees_with_usdskel(seed: int, method: str, backend: str) -> None:
    rest, idx, w, matrices = random_rig(seed)
    cls = LinearBlendSkinning if method == "lbs" else DualQuaternionSkinning
    ours = cls(rest, idx, w, backend=backend).deform(matrices)
    ref = usd_skin(method, rest, idx, w, matrices)
    # UsdSkel keeps points (and weights) in float32: agreement to float32 rounding
    assert np.abs(ours - ref).max() <= 1e-6 * model_size(rest)


@pytest.mark.parametrize("backend", BACKENDS)
def test_dqs_antipodal_quaternions(backend: str) -> None:
    rest, idx, w, _ = random_rig(7, n_joints=8)
    m = antipodal_matrices(8, 7)[None]
    q = matrix_to_quat(m[0, :, :3, :3])
    assert (q[0::2] @ q[1::2].T < -0.99).all()  # neighbouring joints' quaternions nearly antipodal
    dqs = DualQuaternionSkinning(rest, idx, w, backend=backend)
    ours = dqs.deform(m)
    size = model_size(rest)
    assert np.abs(ours - usd_skin("dqs", rest, idx, w, m)).max() <= 1e-6 * size
    # all joints are within 0.2 degrees and 2 cm of each other: every vertex moves
    # (almost) rigidly, nowhere near the collapse a sign-less blend would give
    rigid = rest @ m[0, 0, :3, :3].T + m[0, 0, :3, 3]
    assert np.abs(ours[0] - rigid).max() < 0.05 * size
    assert np.allclose(
        np.linalg.norm(ours[0] - ours[0].mean(axis=0), axis=1),
        np.linalg.norm(rest - rest.mean(axis=0), axis=1),
        atol=0.05 * size,
    )


# ------------------------------------------------------------------ rigid cases
@pytest.mark.parametrize("backend", BACKENDS)
def test_rest_pose_reproduces_rest_mesh(backend: str) -> None:
    rest, idx, w, _ = random_rig(3)
    ident = np.tile(np.eye(4), (12, 1, 1))
    for cls in (LinearBlendSkinning, DualQuaternionSkinning):
        out = cls(rest, idx, w, backend=backend).deform(ident)
        assert out.shape == rest.shape
        assert np.abs(out - rest).max() <= 1e-14 * model_size(rest)


@pytest.mark.parametrize("backend", BACKENDS)
def test_pure_rigid_lbs_equals_dqs(backend: str) -> None:
    rest, idx, w, matrices = random_rig(4, n_joints=12, n_frames=3)
    size = model_size(rest)
    # (a) all joints share one transform per frame, including 180-degree turns
    one = matrices[:, :1].repeat(12, axis=1)
    one[1] = antipodal_matrices(1, 1)[0]
    one[2, :, :3, :3] = np.diag([-1.0, -1.0, 1.0])  # exactly 180 degrees (w = 0)
    for m in (one,):
        lbs = LinearBlendSkinning(rest, idx, w, backend=backend).deform(m)
        dqs = DualQuaternionSkinning(rest, idx, w, backend=backend).deform(m)
        exact = np.einsum("tab,vb->tva", m[:, 0, :3, :3], rest) + m[:, None, 0, :3, 3]
        assert np.abs(lbs - exact).max() <= 1e-12 * size
        assert np.abs(dqs - exact).max() <= 1e-12 * size
    # (b) joints in groups of 3 share a transform and each vertex draws from one group
    group_idx = (idx[:, :1] // 3) * 3 + np.arange(3)[None] % 3
    grouped = matrices[:, (np.arange(12) // 3) * 3]
    w3 = w[:, :3] / w[:, :3].sum(axis=1, keepdims=True)
    lbs = LinearBlendSkinning(rest, group_idx, w3, backend=backend).deform(grouped)
    dqs = DualQuaternionSkinning(rest, group_idx, w3, backend=backend).deform(grouped)
    assert np.abs(lbs - dqs).max() <= 1e-12 * size


def test_dqs_differs_from_lbs_when_not_rigid() -> None:
    rest, idx, w, matrices = random_rig(6)
    lbs = LinearBlendSkinning(rest, idx, w, backend="numpy").deform(matrices)
    dqs = DualQuaternionSkinning(rest, idx, w, backend="numpy").deform(matrices)
    assert np.abs(lbs - dqs).max() > 1e-2 * model_size(rest)


def test_dqs_twist_has_no_candy_wrapper() -> None:
    """Half-way between 0 and 180 degrees: DQS turns by 90 degrees, LBS collapses to the axis."""
    ring = np.stack(
        [
            np.zeros(16),
            np.cos(np.linspace(0, 2 * np.pi, 16)),
            np.sin(np.linspace(0, 2 * np.pi, 16)),
        ],
        axis=1,
    )
    idx = np.tile([0, 1], (16, 1))
    w = np.full((16, 2), 0.5)
    m = np.stack([np.eye(4), np.diag([1.0, -1.0, -1.0, 1.0])])  # 180 degrees about x
    lbs = LinearBlendSkinning(ring, idx, w, backend="numpy").deform(m)
    dqs = DualQuaternionSkinning(ring, idx, w, backend="numpy").deform(m)
    assert np.abs(lbs).max() < 1e-15
    np.testing.assert_allclose(np.linalg.norm(dqs[:, 1:], axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(
        dqs, ring @ Rotation.from_euler("x", 90, degrees=True).as_matrix().T, atol=1e-14
    )


# ------------------------------------------------------------------ non-rigid DQS
@pytest.mark.parametrize("backend", BACKENDS)
def test_dqs_non_rigid_matrices(backend: str) -> None:
    rest, idx, w, matrices = random_rig(8, n_frames=2)
    size = model_size(rest)
    # one influence per vertex: DQS applies the full affine matrix exactly
    scaled = matrices.copy()
    scaled[..., :3, :3] = scaled[..., :3, :3] @ np.diag([1.3, 0.8, 1.1])
    scaled[1, 3, :3, :3] = scaled[1, 3, :3, :3] @ np.diag([1.0, 1.0, -1.0])  # a reflection
    one = DualQuaternionSkinning(rest, idx[:, :1], np.ones((rest.shape[0], 1)), backend=backend)
    exact = (
        np.einsum("tvab,vb->tva", scaled[:, idx[:, 0], :3, :3], rest)
        + scaled[:, idx[:, 0]][..., :3, 3]
    )
    assert np.abs(one.deform(scaled) - exact).max() <= 1e-12 * size
    # a uniform scale shared by all joints commutes with the blend: DQS(s R, t) = s-scaled DQS
    uni = matrices.copy()
    uni[..., :3, :3] *= 2.0
    dqs = DualQuaternionSkinning(rest, idx, w, backend=backend)
    blended_rigid = DualQuaternionSkinning(2.0 * rest, idx, w, backend=backend).deform(matrices)
    assert np.abs(dqs.deform(uni) - blended_rigid).max() <= 1e-12 * size


@needs_numba
@pytest.mark.parametrize("cls", [LinearBlendSkinning, DualQuaternionSkinning])
def test_numba_equals_numpy_reference(cls: type) -> None:
    rest, idx, w, matrices = random_rig(9, n_vertices=3000, n_joints=20, n_frames=7)
    m = matrices.copy()
    m[3, 5, :3, :3] *= np.array([1.2, 0.9, 1.0])  # one non-rigid joint in one frame
    m[4, 7] = np.nan  # NaN joint
    ref = cls(rest, idx, w, backend="numpy").deform(m)
    fast = cls(rest, idx, w, backend="numba").deform(m)
    assert np.array_equal(np.isnan(ref), np.isnan(fast))
    ok = ~np.isnan(ref)
    assert np.abs(ref[ok] - fast[ok]).max() <= 1e-12 * model_size(rest)
    # NaN only where joint 7 is listed, only in frame 4
    touched = (idx == 7).any(axis=1)
    assert np.isnan(ref[4, touched]).all() and not np.isnan(ref[4, ~touched]).any()
    assert not np.isnan(np.delete(ref, 4, axis=0)).any()


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_pose_batches_and_out(backend: str) -> None:
    rest, idx, w, matrices = random_rig(10, n_frames=6)
    for cls in (LinearBlendSkinning, DualQuaternionSkinning):
        d = cls(rest, idx, w, n_joints=12, backend=backend)
        all_frames = d.deform(matrices)
        assert all_frames.shape == (6, rest.shape[0], 3)
        np.testing.assert_array_equal(d.deform(matrices[2]), all_frames[2])
        buf = np.zeros((6, rest.shape[0], 3))
        assert d.deform(matrices, out=buf) is buf
        np.testing.assert_array_equal(buf, all_frames)
        chunks = list(d.deform_chunks(matrices, chunk=4))
        assert [c.shape[0] for c in chunks] == [4, 2]
        np.testing.assert_array_equal(np.concatenate(chunks), all_frames)
        assert d.deform(matrices[:0]).shape == (0, rest.shape[0], 3)
        assert d.n_vertices == rest.shape[0] and d.n_influences == 4 and d.method in ("lbs", "dqs")


def test_validation() -> None:
    rest, idx, w, matrices = random_rig(11, n_vertices=10)
    with pytest.raises(ValidationError, match="rest_vertices"):
        LinearBlendSkinning(rest[:, :2], idx, w)
    with pytest.raises(ValidationError, match="rest_vertices"):
        LinearBlendSkinning(np.full_like(rest, np.nan), idx, w)
    with pytest.raises(ValidationError, match="joint_weights"):
        LinearBlendSkinning(rest, idx, w[:5])
    with pytest.raises(ValidationError, match="joint_indices"):
        LinearBlendSkinning(rest, idx[:, :2], w)
    with pytest.raises(ValidationError, match="non-negative"):
        LinearBlendSkinning(rest, idx, -w)
    zero = w.copy()
    zero[3] = 0.0
    with pytest.raises(ValidationError, match="vertex 3 has no influence"):
        DualQuaternionSkinning(rest, idx, zero)
    with pytest.raises(ValidationError, match="out of range"):
        LinearBlendSkinning(rest, idx, w, n_joints=5)
    with pytest.raises(ValidationError, match="integers"):
        LinearBlendSkinning(rest, idx.astype(float), w)
    with pytest.raises(ValidationError, match="backend"):
        LinearBlendSkinning(rest, idx, w, backend="cuda")  # type: ignore[arg-type]
    d = DualQuaternionSkinning(rest, idx, w, n_joints=12)
    with pytest.raises(ValidationError, match="expected 12 joints"):
        d.deform(matrices[:, :11])
    with pytest.raises(ValidationError, match=r"\(J, 4, 4\)"):
        d.deform(matrices[..., :3, :])
    with pytest.raises(ValidationError, match="out"):
        d.deform(matrices, out=np.zeros((1, 10, 3)))
    with pytest.raises(ValidationError, match="chunk"):
        list(d.deform_chunks(matrices, chunk=0))
    loose = LinearBlendSkinning(rest, idx, w)
    with pytest.raises(ValidationError, match="only 3 joints"):
        loose.deform(matrices[:, :3])


# ------------------------------------------------------------------ meshes and motions
@pytest.fixture(scope="module")
def makehuman(data_dir) -> Mesh:
    return read_makehuman(data_dir / "makehuman_base.obj")


def rest_motion_of(mesh: Mesh, n_frames: int = 1) -> Motion:
    """A motion whose forward kinematics is the bind pose (local = inv(parent bind) @ bind)."""
    skin = mesh.skin
    bind = skin.bind_matrices
    parents = skin.skeleton.parents
    local = bind.copy()
    has = parents >= 0
    local[has] = np.linalg.inv(bind[parents[has]]) @ bind[has]
    q = matrix_to_quat(local[:, :3, :3])
    return Motion(
        skeleton=skin.skeleton,
        rotations=np.repeat(q[None], n_frames, axis=0),
        translations=np.repeat(local[None, :, :3, 3], n_frames, axis=0),
        rate=30.0,
    )


@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_skin_motion_streams_makehuman(makehuman: Mesh, method: str) -> None:
    motion = rest_motion_of(makehuman, n_frames=5)
    rng = np.random.default_rng(0)
    # turn every joint by a random small rotation in frames 1..4
    j = makehuman.skin.skeleton.n_joints
    turn = Rotation.from_rotvec(rng.normal(scale=0.3, size=(4 * j, 3))).as_quat().reshape(4, j, 4)
    new = quat_multiply(turn, motion.rotations[1:])
    motion = Motion(
        skeleton=motion.skeleton,
        rotations=np.concatenate([motion.rotations[:1], new]),
        translations=motion.translations,
        rate=30.0,
    )
    seen: list[float] = []
    anim = skin_motion(makehuman, motion, method=method, chunk=2, progress=seen.append)
    assert anim.n_frames == 5 and anim.rate == 30.0 and anim.is_streamed
    assert anim.meta["skinning_method"] == method
    assert seen == []  # lazy: nothing computed yet
    chunks = list(anim.iter_chunks())
    assert [c.shape for c in chunks] == [(2, 13380, 3), (2, 13380, 3), (1, 13380, 3)]
    assert seen == [0.4, 0.8, 1.0]
    frames = np.concatenate(chunks)
    size = model_size(makehuman.vertices)
    # frame 0 is the bind pose: the rest mesh
    assert np.abs(frames[0] - makehuman.vertices).max() <= 1e-9 * size
    # the whole motion at once through make_deformer gives the same frames
    world = forward_kinematics_arrays(motion.skeleton, motion.rotations, motion.translations)
    direct = make_deformer(method, makehuman).deform(world @ makehuman.skin.inverse_bind)
    np.testing.assert_allclose(frames, direct, atol=1e-12 * size)
    assert np.abs(frames[1] - makehuman.vertices).max() > 0.05


def test_skin_motion_rejects_other_skeletons(makehuman: Mesh) -> None:
    motion = rest_motion_of(makehuman)
    sk = motion.skeleton
    names = list(sk.names)
    names[5] = "not_a_joint"
    renamed = Motion(
        skeleton=Skeleton(names=names, parents=sk.parents, offsets=sk.offsets),
        rotations=motion.rotations,
        translations=motion.translations,
        rate=30.0,
    )
    with pytest.raises(
        ValidationError, match=f"joint 5 is 'not_a_joint', the skin's is '{sk.names[5]}'"
    ):
        skin_motion(makehuman, renamed)
    short = Motion(
        skeleton=Skeleton(names=sk.names[:10], parents=sk.parents[:10], offsets=sk.offsets[:10]),
        rotations=motion.rotations[:, :10],
        translations=motion.translations[:, :10],
        rate=30.0,
    )
    with pytest.raises(ValidationError, match="10 joints against the skin's 163"):
        skin_motion(makehuman, short)
    with pytest.raises(ValidationError, match="method"):
        skin_motion(makehuman, motion, method="slerp")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="chunk"):
        skin_motion(makehuman, motion, chunk=0)
    bare = Mesh(vertices=makehuman.vertices, faces=makehuman.faces)
    with pytest.raises(ValidationError, match="no skin"):
        make_deformer("lbs", bare)


def test_without_numba_falls_back_to_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    from skincap.deform.skeletal import deformers
    from skincap.errors import MissingDependencyError

    monkeypatch.setattr(deformers, "numba_available", lambda: False)
    rest, idx, w, matrices = random_rig(12, n_vertices=50)
    d = DualQuaternionSkinning(rest, idx, w)
    assert d.backend == "numpy"
    assert d.deform(matrices).shape == (5, 50, 3)
    with pytest.raises(MissingDependencyError, match=r"skincap\[fast\]"):
        LinearBlendSkinning(rest, idx, w, backend="numba")


# ------------------------------------------------------ compile policy of "auto"
@needs_numba
@pytest.mark.parametrize(
    ("cls", "name"),
    [(LinearBlendSkinning, "skinning.lbs"), (DualQuaternionSkinning, "skinning.dqs")],
)
def test_auto_on_a_cold_cache_runs_numpy_and_compiles_in_the_background(
    monkeypatch: pytest.MonkeyPatch, cls: type, name: str
) -> None:
    from skincap import backends

    started: list[str] = []
    monkeypatch.delenv("SKINCAP_COMPILE", raising=False)
    monkeypatch.setattr(backends, "kernel_ready", lambda dispatcher: False)
    monkeypatch.setattr(backends, "compile_in_background", lambda n, d: started.append(n) or True)
    rest, idx, w, matrices = random_rig(13, n_vertices=60)
    d = cls(rest, idx, w)
    assert d.backend == "numpy" and started == [name]
    ref = cls(rest, idx, w, backend="numba").deform(matrices)  # explicit: compiles inline
    np.testing.assert_allclose(d.deform(matrices), ref, rtol=0, atol=1e-12)
    monkeypatch.setenv("SKINCAP_COMPILE", "inline")  # the old behaviour: compile on first use
    assert cls(rest, idx, w).backend == "numba" and started == [name]
    monkeypatch.delenv("SKINCAP_COMPILE")
    monkeypatch.setattr(backends, "kernel_ready", lambda dispatcher: True)
    assert cls(rest, idx, w).backend == "numba" and started == [name]


@needs_numba
@pytest.mark.parametrize("cls", [LinearBlendSkinning, DualQuaternionSkinning])
def test_auto_takes_the_kernel_once_the_background_compile_lands(
    monkeypatch: pytest.MonkeyPatch, cls: type
) -> None:
    from skincap import backends

    compiled = False
    monkeypatch.delenv("SKINCAP_COMPILE", raising=False)
    monkeypatch.setattr(backends, "kernel_ready", lambda dispatcher: compiled)
    monkeypatch.setattr(backends, "compile_in_background", lambda n, d: True)
    monkeypatch.setattr(backends, "RECHECK_SECONDS", 0.0)
    rest, idx, w, matrices = random_rig(16, n_vertices=40)
    ref = cls(rest, idx, w, backend="numpy").deform(matrices)
    d = cls(rest, idx, w)
    first = d.deform(matrices)
    assert d.backend == "numpy"  # still compiling
    compiled = True
    second = d.deform(matrices)
    assert d.backend == "numba"
    np.testing.assert_allclose(first, ref, rtol=0, atol=0)
    np.testing.assert_allclose(second, ref, rtol=0, atol=1e-12)
    # an explicit NumPy deformer never switches
    pinned = cls(rest, idx, w, backend="numpy")
    pinned.deform(matrices)
    assert pinned.backend == "numpy"


@needs_numba
def test_kernel_ready_sees_a_compiled_kernel() -> None:
    from skincap.backends import kernel_ready
    from skincap.deform.skeletal.deformers import _lbs_dispatcher

    rest, idx, w, matrices = random_rig(14, n_vertices=30)
    LinearBlendSkinning(rest, idx, w, backend="numba").deform(matrices)
    assert kernel_ready(_lbs_dispatcher())


@needs_numba
@pytest.mark.slow
def test_background_compile_fills_the_cache_for_the_next_process(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """End to end, in fresh processes on an empty numba cache: the first run of
    ``auto`` gets NumPy and starts the compile; once it is done, the next run gets numba."""
    import os
    import subprocess
    import sys
    import time

    probe = (
        "from skincap.deform.skeletal.deformers import LinearBlendSkinning as L\n"
        "print(L([[0.0, 0.0, 0.0]], [[0]], [[1.0]]).backend)"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("SKINCAP_COMPILE", None)

    def backend_of_a_fresh_process() -> str:
        done = subprocess.run(
            [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
        )
        return done.stdout.strip()

    assert backend_of_a_fresh_process() == "numpy"
    deadline = time.monotonic() + 600
    while list(tmp_path.rglob("skincap-compiling-*.lock")) and time.monotonic() < deadline:
        time.sleep(0.5)
    assert not list(tmp_path.rglob("skincap-compiling-*.lock"))
    assert list(tmp_path.rglob("*lbs_kernel*.nbi"))  # numba's cache, not ours
    assert backend_of_a_fresh_process() == "numba"


@needs_numba
def test_auto_warns_and_uses_numpy_when_numba_cannot_set_up_the_kernel(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from skincap.deform.skeletal import deformers
    from skincap.errors import SkincapWarning

    def no_cache_folder() -> None:
        raise RuntimeError("cannot cache function 'lbs_kernel': no locator available")

    monkeypatch.delenv("SKINCAP_COMPILE", raising=False)
    monkeypatch.setitem(deformers._KERNELS, "lbs", ("skinning.lbs", no_cache_folder))
    rest, idx, w, matrices = random_rig(15, n_vertices=20)
    with pytest.warns(SkincapWarning, match="no locator available"):
        d = LinearBlendSkinning(rest, idx, w)
    assert d.backend == "numpy"
    assert np.isfinite(d.deform(matrices)).all()


@needs_numba
def test_start_pending_compiles_starts_each_kernel_not_compiled(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from skincap import backends

    started: list[str] = []
    monkeypatch.delenv("SKINCAP_COMPILE", raising=False)
    monkeypatch.setattr(backends, "compile_in_background", lambda n, d: started.append(n) or True)
    monkeypatch.setattr(
        backends, "kernel_ready", lambda d: d.py_func.__name__ == "lbs_kernel"
    )  # LBS compiled already
    assert (
        backends.start_pending_compiles() == ["skinning.dqs", "tracking", "dense", "ik"] == started
    )
    monkeypatch.setenv("SKINCAP_COMPILE", "inline")
    assert backends.start_pending_compiles() == []
    with pytest.raises(ValidationError, match="names"):
        monkeypatch.delenv("SKINCAP_COMPILE")
        backends.start_pending_compiles(("skinning.slerp",))
