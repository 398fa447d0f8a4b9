"""Rig helpers: bind pose as a Motion, skinning matrices, motions from world rotations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from skincap.deform.skeletal.rig import (
    ALL_CHANNELS,
    bind_local_transforms,
    motion_from_world,
    rest_motion,
    skeleton_bind_matrices,
    skinning_matrices,
)
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics, joint_positions, rest_positions
from skincap.io.makehuman import read_makehuman
from skincap.types import Motion, Skeleton, Skin

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def makehuman():
    return read_makehuman(DATA / "makehuman_base.obj")


def random_rig(rng: np.random.Generator, n_joints: int = 7) -> Skin:
    """A branching skeleton with random bind rotations (rolls) at its joint heads."""
    parents = np.array([-1] + [int(rng.integers(0, k)) for k in range(1, n_joints)])
    offsets = rng.normal(size=(n_joints, 3)) * 0.2
    skel = Skeleton([f"j{k}" for k in range(n_joints)], parents, offsets)
    bind = skeleton_bind_matrices(skel)
    bind[:, :3, :3] = Rotation.random(n_joints, random_state=rng).as_matrix()
    v = 5
    return Skin(
        skel,
        np.zeros((v, 1), dtype=np.int64),
        np.ones((v, 1)),
        np.linalg.inv(bind),
    )


def test_rest_motion_reproduces_makehuman_bind(makehuman):
    skin = makehuman.skin
    motion = rest_motion(skin, rate=24.0)
    assert motion.n_frames == 1 and motion.rate == 24.0
    assert motion.skeleton.names == skin.skeleton.names
    assert all(ch == ALL_CHANNELS for ch in motion.channels)
    world = forward_kinematics(motion)[0]
    np.testing.assert_allclose(world, skin.bind_matrices, atol=1e-9)
    s = skinning_matrices(motion, skin)
    np.testing.assert_allclose(s, np.broadcast_to(np.eye(4), s.shape), atol=1e-9)
    # the bones carry rolls: local translations are not the world offsets
    _, local_t = bind_local_transforms(skin)
    assert np.abs(local_t[1:] - skin.skeleton.offsets[1:]).max() > 1e-3
    # but bone lengths are
    np.testing.assert_allclose(
        np.linalg.norm(local_t[1:], axis=1),
        np.linalg.norm(skin.skeleton.offsets[1:], axis=1),
        atol=1e-12,
    )


def test_rest_motion_of_bare_skeleton_uses_offsets():
    skel = Skeleton(
        ["a", "b", "c"], [-1, 0, 1], [[0.1, 1.0, 0.0], [0.0, 0.5, 0.0], [0.2, 0.0, 0.1]]
    )
    motion = rest_motion(skel)
    np.testing.assert_allclose(motion.translations[0], skel.offsets, atol=1e-15)
    np.testing.assert_allclose(motion.rotations[0], np.tile([0, 0, 0, 1.0], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(joint_positions(motion)[0], rest_positions(skel), atol=1e-15)


def test_skinning_matrices_of_a_rigid_root_motion_are_that_motion():
    rng = np.random.default_rng(3)
    skin = random_rig(rng)
    rest = rest_motion(skin)
    t = 6
    rots = Rotation.random(t, random_state=rng)
    shift = rng.normal(size=(t, 3))
    q = np.repeat(rest.rotations, t, axis=0)
    tr = np.repeat(rest.translations, t, axis=0)
    bind0 = skin.bind_matrices[0]
    # root world = G @ bind0 with G = [R | shift]
    q[:, 0] = (rots * Rotation.from_matrix(bind0[:3, :3])).as_quat()
    tr[:, 0] = rots.apply(bind0[:3, 3]) + shift
    motion = Motion(rest.skeleton, q, tr, 30.0, channels=rest.channels)
    s = skinning_matrices(motion, skin)
    g = np.tile(np.eye(4), (t, 1, 1))
    g[:, :3, :3] = rots.as_matrix()
    g[:, :3, 3] = shift
    np.testing.assert_allclose(s, np.broadcast_to(g[:, None], s.shape), atol=1e-9)


def test_skinning_matrices_name_mismatch_names_the_joint(makehuman):
    skin = makehuman.skin
    motion = rest_motion(skin)
    names = list(skin.skeleton.names)
    names[5] = "not_a_bone"
    other = Skeleton(names, skin.skeleton.parents, skin.skeleton.offsets)
    bad = Motion(other, motion.rotations, motion.translations, 30.0)
    with pytest.raises(ValidationError, match="joint 5 is 'not_a_bone'.*'upperleg01.R'"):
        skinning_matrices(bad, skin)
    short = Skeleton(names[:3], skin.skeleton.parents[:3], skin.skeleton.offsets[:3])
    with pytest.raises(ValidationError, match="joint 3 is None"):
        skinning_matrices(
            Motion(short, motion.rotations[:, :3], motion.translations[:, :3], 30.0), skin
        )
    with pytest.raises(ValidationError, match="expected a Skin"):
        skinning_matrices(motion, skin.skeleton)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 9), t=st.integers(1, 4))
def test_motion_from_world_round_trip(seed, n, t):
    rng = np.random.default_rng(seed)
    skin = random_rig(rng, n)
    world = Rotation.random(t * n, random_state=rng).as_quat().reshape(t, n, 4)
    root = rng.normal(size=(t, 3))
    motion = motion_from_world(skin, world, root, rate=50.0)
    fk = forward_kinematics(motion)
    got = Rotation.from_matrix(fk[..., :3, :3].reshape(-1, 3, 3))
    want = Rotation.from_quat(world.reshape(-1, 4))
    assert (got.inv() * want).magnitude().max() < 1e-9
    np.testing.assert_allclose(fk[:, 0, :3, 3], root, atol=1e-12)
    # bone lengths are the bind lengths in every frame
    bind_pos = skin.bind_matrices[:, :3, 3]
    p = skin.skeleton.parents
    has = p >= 0
    if has.any():
        pos = fk[..., :3, 3]
        lengths = np.linalg.norm(pos[:, has] - pos[:, p[has]], axis=-1)
        want_len = np.linalg.norm(bind_pos[has] - bind_pos[p[has]], axis=-1)
        np.testing.assert_allclose(lengths, np.tile(want_len, (t, 1)), atol=1e-9)
    # matrices give the same motion as quaternions
    again = motion_from_world(
        skin,
        Rotation.from_quat(world.reshape(-1, 4)).as_matrix().reshape(t, n, 3, 3),
        root,
        rate=50.0,
    )
    np.testing.assert_allclose(forward_kinematics(again), fk, atol=1e-9)


def test_motion_from_world_bind_rotations_give_rest(makehuman):
    skin = makehuman.skin
    bind = skin.bind_matrices
    u, _, vt = np.linalg.svd(bind[:, :3, :3])
    motion = motion_from_world(skin, (u @ vt)[None], bind[None, 0, :3, 3], rate=30.0)
    np.testing.assert_allclose(forward_kinematics(motion)[0], bind, atol=1e-9)


def test_motion_from_world_rejects_bad_input(makehuman):
    skin = makehuman.skin
    j = skin.skeleton.n_joints
    ok = np.tile([0, 0, 0, 1.0], (2, j, 1))
    with pytest.raises(ValidationError, match="world_rotations: expected shape"):
        motion_from_world(skin, ok[:, :-1], np.zeros((2, 3)), rate=30.0)
    with pytest.raises(ValidationError, match="root_translation: expected shape"):
        motion_from_world(skin, ok, np.zeros((3, 3)), rate=30.0)
    zero = ok.copy()
    zero[1, 4] = 0.0
    with pytest.raises(ValidationError, match="finite and non-zero"):
        motion_from_world(skin, zero, np.zeros((2, 3)), rate=30.0)
    nan = np.zeros((2, 3))
    nan[0, 1] = np.nan
    with pytest.raises(ValidationError, match="root_translation: must be finite"):
        motion_from_world(skin, ok, nan, rate=30.0)
    with pytest.raises(ValidationError, match="rig: expected a Skin or a Skeleton"):
        motion_from_world("skin", ok, np.zeros((2, 3)), rate=30.0)
    with pytest.raises(ValidationError, match="rate"):
        motion_from_world(skin, ok, np.zeros((2, 3)), rate=0.0)
