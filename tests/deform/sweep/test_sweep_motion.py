"""The sweep deformer on real motion: a CMU capture drives the MakeHuman body."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skincap.deform.skeletal.deformers import skin_motion
from skincap.deform.skeletal.pipeline import prepare_skinning
from skincap.deform.sweep import sweep_motion
from skincap.errors import ValidationError
from skincap.evaluate.bench.sweep import subdivide_skinned
from skincap.io.bvh import read_bvh
from skincap.io.mesh_animation_files import write_mesh_animation
from skincap.io.pc2 import read_pc2
from skincap.types import Motion


@pytest.fixture(scope="module")
def walk_setup(body, data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        walk = read_bvh(data_dir / "cmu_131_01_bvh11.bvh", units="cmu")
    short = Motion(walk.skeleton, walk.rotations[:240], walk.translations[:240], walk.rate,
                   walk.channels, walk.meta)  # fmt: skip
    return prepare_skinning(body, short)


@pytest.mark.slow
def test_real_walk_is_finite_continuous_and_reads_back(walk_setup, tmp_path) -> None:
    setup = walk_setup
    done: list[float] = []
    anim = sweep_motion(setup.mesh, setup.motion, chunk=50, progress=done.append)
    assert anim.meta["skinning_method"] == "sweep"
    assert anim.meta["sweep_limbs"] == ["arm_l", "arm_r", "leg_l", "leg_r"]
    frames = np.concatenate(list(anim.frames))
    assert frames.shape == (240, setup.mesh.n_vertices, 3)
    assert np.isfinite(frames).all()
    assert done[-1] == 1.0 and done == sorted(done)
    dqs = np.concatenate(list(skin_motion(setup.mesh, setup.motion, method="dqs").frames))
    # no vertex jumps between frames beyond what the skeleton moves it (DQS's steps of
    # the same frame, which follow the joints rigidly), plus 2 cm
    step = np.linalg.norm(np.diff(frames, axis=0), axis=2)
    joint_step = np.linalg.norm(np.diff(dqs, axis=0), axis=2)
    assert (step.max(axis=1) <= joint_step.max(axis=1) + 0.02).all()
    # the sweep is a different deformer, yet the body stays where the skeleton puts it
    assert np.linalg.norm(frames - dqs, axis=2).max() < 0.1
    # the streamed chunks do not depend on the chunk size
    again = np.concatenate(list(sweep_motion(setup.mesh, setup.motion, chunk=64).frames))
    np.testing.assert_allclose(again, frames, atol=1e-12)
    # and the output reads back (PC2 stores float32)
    anim = sweep_motion(setup.mesh, setup.motion)
    write_mesh_animation(anim, tmp_path / "walk.pc2", force=False)
    cache = read_pc2(tmp_path / "walk.pc2")
    np.testing.assert_allclose(cache.frames, frames, atol=1e-5)


def test_motion_on_another_skeleton_is_refused(walk_setup, body, data_dir) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        other = read_bvh(data_dir / "bvhtoolbox_test_mocapbank.bvh", units="cm")
    with pytest.raises(ValidationError, match="not on the mesh's skeleton"):
        sweep_motion(walk_setup.mesh, other)
    with pytest.raises(ValidationError, match="chunk"):
        sweep_motion(walk_setup.mesh, walk_setup.motion, chunk=0)


def test_subdivided_body_keeps_its_skin(walk_setup) -> None:
    mesh = walk_setup.mesh
    fine = subdivide_skinned(mesh)
    assert fine.faces.shape[0] == 4 * mesh.faces.shape[0]
    n_edges = fine.n_vertices - mesh.n_vertices
    assert n_edges == 3 * mesh.faces.shape[0] // 2  # a closed manifold: E = 3F/2
    np.testing.assert_allclose(fine.skin.joint_weights.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(fine.vertices[: mesh.n_vertices], mesh.vertices)
