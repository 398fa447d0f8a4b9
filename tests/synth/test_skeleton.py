"""synth_skeleton: CMU bvh11 hierarchy, T-pose, proportions, retargetable."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skincap.deform.skeletal.name_maps import detect_convention
from skincap.deform.skeletal.retarget import retarget
from skincap.deform.skeletal.rig import rest_motion
from skincap.errors import UnitWarning, ValidationError
from skincap.geometry.kinematics import rest_positions
from skincap.io.bvh import read_bvh
from skincap.io.makehuman import read_makehuman
from skincap.synth.skeleton import synth_skeleton


def _cmu(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        return read_bvh(data_dir / "cmu_131_01_bvh11.bvh")


def test_same_hierarchy_as_cmu_bvh11(data_dir):
    cmu = _cmu(data_dir).skeleton
    sk = synth_skeleton()
    assert sk.names == cmu.names
    np.testing.assert_array_equal(sk.parents, cmu.parents)
    assert detect_convention(sk.names) == "cmu_bvh11"


@pytest.mark.parametrize("height", [1.5, 1.75, 1.92])
def test_tpose_proportions(height):
    sk = synth_skeleton(height)
    p = rest_positions(sk)
    pos = {n: p[k] for k, n in enumerate(sk.names)}
    # feet near the floor, nothing below it, crown inside the head below the height
    assert p[:, 1].min() >= 0.0
    assert pos["LeftToe"][1] == pytest.approx(0.012 * height)
    assert pos["LeftAnkle"][1] == pytest.approx(0.045 * height)
    assert 0.94 * height < pos["Head_end"][1] < height
    # arms straight out along +-X (left on +X), at shoulder height
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        sh, el, wr = pos[f"{side}Shoulder"], pos[f"{side}Elbow"], pos[f"{side}Wrist"]
        np.testing.assert_allclose((el - sh) / np.linalg.norm(el - sh), [sign, 0, 0], atol=1e-12)
        np.testing.assert_allclose((wr - el) / np.linalg.norm(wr - el), [sign, 0, 0], atol=1e-12)
        assert sh[1] == pytest.approx(0.80 * height)
        assert np.linalg.norm(el - sh) == pytest.approx(0.186 * height)
        assert np.linalg.norm(wr - el) == pytest.approx(0.146 * height)
        hip, knee, ankle = pos[f"{side}Hip"], pos[f"{side}Knee"], pos[f"{side}Ankle"]
        np.testing.assert_allclose(
            (knee - hip) / np.linalg.norm(knee - hip), [0, -1, 0], atol=1e-12
        )
        np.testing.assert_allclose(
            (ankle - knee) / np.linalg.norm(ankle - knee), [0, -1, 0], atol=1e-12
        )
        assert sign * hip[0] > 0
        toe = pos[f"{side}Toe_end"]
        assert toe[2] > ankle[2] + 0.1 * height  # feet point forward (+Z)
    # spine straight up
    spine = np.array([pos[n] for n in ("Hips", "Chest", "Chest2", "Neck", "Head", "Head_end")])
    np.testing.assert_allclose(spine[:, [0, 2]], 0.0, atol=1e-12)
    assert (np.diff(spine[:, 1]) > 0).all()


def test_mirror_symmetric():
    sk = synth_skeleton()
    p = rest_positions(sk)
    for k, name in enumerate(sk.names):
        if name.startswith(("Left", "L", "l")) and name not in ("lowerback", "lowerneck"):
            other = (
                name.replace("Left", "Right")
                .replace("LHip", "RHip")
                .replace("LF", "RF")
                .replace("LT", "RT")
                .replace("lhand", "rhand")
            )
            q = p[sk.index(other)]
            np.testing.assert_allclose(q, p[k] * [-1, 1, 1], atol=1e-12)
        elif not name.startswith(("Right", "R", "r")):
            assert p[k][0] == 0.0


def test_scales_with_height():
    a = rest_positions(synth_skeleton(1.6))
    b = rest_positions(synth_skeleton(1.9))
    np.testing.assert_allclose(a * (1.9 / 1.6), b, atol=1e-12)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 5.0, "tall", None])
def test_bad_height(bad):
    with pytest.raises(ValidationError, match="height"):
        synth_skeleton(bad)


def test_retargets_onto_makehuman(data_dir):
    sk = synth_skeleton()
    body = read_makehuman(data_dir / "makehuman_base.obj")
    out = retarget(rest_motion(sk), body)
    info = out.meta["retarget"]
    assert info["source_convention"] == "cmu_bvh11"
    assert info["target_convention"] == "makehuman"
    # every landmark of the convention got paired (hips, spine, arms, legs, head)
    assert len(info["name_map"]) >= 20
    assert np.isfinite(out.rotations).all()


def test_cmu_motion_plays_on_it(data_dir):
    cmu = _cmu(data_dir)
    out = retarget(cmu, synth_skeleton())
    assert out.skeleton.names == synth_skeleton().names
    assert out.n_frames == cmu.n_frames
