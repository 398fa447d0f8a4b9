"""Every skeleton skincap writes skins its own body back (issue #12 item 2).

``synth`` writes the motion it skinned as a BVH whose joints come in depth-first
order, not the rig's; reading it back and skinning the body must give the same skin.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skincap.deform.skeletal.deformers import skin_motion
from skincap.deform.skeletal.pipeline import prepare_skinning
from skincap.deform.skeletal.retarget import retarget
from skincap.io.bvh import read_bvh, write_bvh
from skincap.synth.inputs import build_body, build_motion

DATA = Path(__file__).resolve().parents[2] / "data"
FRAMES = 4


def _frames(mesh, motion) -> np.ndarray:
    return np.concatenate(list(skin_motion(mesh, motion, method="dqs").iter_chunks(64)))


@pytest.fixture(scope="module", params=["makehuman", "procedural"])
def body(request):
    return build_body(request.param, n_vertices=5000)


@pytest.mark.parametrize("clip", ["cmu_131_01_bvh11.bvh", "squat"])
def test_written_motion_skins_its_own_body_to_a_micrometre(body, clip, tmp_path):
    motion_name = str(DATA / clip) if clip.endswith(".bvh") else clip
    truth_motion = build_motion(body, motion_name, frames=FRAMES, units="cmu")
    truth = _frames(body, truth_motion)  # (T, V, 3) metres, what synth writes as mesh.pc2
    write_bvh(truth_motion, tmp_path / "motion.bvh", units="m")
    read_back = read_bvh(tmp_path / "motion.bvh", units="m")
    setup = prepare_skinning(body, read_back)
    again = _frames(setup.mesh, setup.motion)
    assert again.shape == truth.shape
    # the BVH keeps 7 decimals of metres; the old index pairing was off by 1.6 m
    assert float(np.linalg.norm(again - truth, axis=-1).max()) < 1e-5


def test_own_rig_pairs_by_name_not_by_index(tmp_path):
    body = build_body("makehuman")
    motion = build_motion(body, str(DATA / "cmu_131_01_bvh11.bvh"), frames=2, units="cmu")
    write_bvh(motion, tmp_path / "m.bvh", units="m")
    read_back = read_bvh(tmp_path / "m.bvh", units="m")
    rig_names = body.skin.skeleton.names
    assert read_back.skeleton.names != rig_names  # depth-first, another order
    out = retarget(read_back, body)
    assert out.skeleton.names == rig_names
    assert out.meta["retarget"]["same_rig"] is True
    src = {n: i for i, n in enumerate(read_back.skeleton.names)}
    for j, name in enumerate(rig_names):
        q_out, q_in = out.rotations[:, j], read_back.rotations[:, src[name]]
        # the same rotation (q and -q alike)
        assert np.allclose(np.abs(np.sum(q_out * q_in, axis=-1)), 1.0, atol=1e-9)


def test_moved_bones_take_the_general_path(tmp_path):
    """A motion with the rig's names but other bone lengths is retargeted, not copied."""
    body = build_body("makehuman")
    motion = build_motion(body, "squat", frames=2)
    motion.translations[:, 1:] *= 1.1  # another body with the same names
    out = retarget(motion, body)
    assert "same_rig" not in out.meta["retarget"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["makehuman", "procedural"])
def test_cli_synth_truth_skins_back_within_a_millimetre(kind, tmp_path):
    """The user's check: ``synth --soft-tissue 0`` then ``skin`` on its own rig."""
    from typer.testing import CliRunner

    from skincap.cli import app
    from skincap.io.pc2 import read_pc2

    runner = CliRunner()
    out = tmp_path / "S"
    r = runner.invoke(
        app,
        [
            "synth", "--body", kind, "--motion", str(DATA / "cmu_131_01_bvh11.bvh"),
            "--units", "cmu", "--frames", "3", "--vertices", "5000", "--markers", "sparse",
            "--soft-tissue", "0", "-o", str(out),
        ],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    body = DATA / "makehuman_base.obj" if kind == "makehuman" else out / "truth" / "body.glb"
    cache = tmp_path / "x.pc2"
    r = runner.invoke(
        app,
        ["skin", str(body), str(out / "truth" / "motion.bvh"), "--method", "dqs",
         "--units", "m", "-o", str(cache)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    truth = read_pc2(out / "truth" / "mesh.pc2").frames
    again = read_pc2(cache).frames
    assert again.shape == truth.shape
    assert float(np.linalg.norm(again - truth, axis=-1).max()) < 1e-3
