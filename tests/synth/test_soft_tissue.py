"""Soft tissue on the MakeHuman body: bulge, jiggle, breathing, regions, switches."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from skincap.deform.skeletal.deformers import skin_motion
from skincap.deform.skeletal.retarget import retarget
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics
from skincap.io.makehuman import read_makehuman
from skincap.synth.clips import make_clip
from skincap.synth.skeleton import synth_skeleton
from skincap.synth.soft_tissue import SoftTissue, vertex_normals
from skincap.types import Mesh, Motion

ONLY = {
    "bulge": {"jiggle": 0.0, "breathing": 0.0},
    "jiggle": {"bulge": 0.0, "breathing": 0.0},
    "breathing": {"bulge": 0.0, "jiggle": 0.0},
}


@pytest.fixture(scope="module")
def body(data_dir) -> Mesh:
    return read_makehuman(data_dir / "makehuman_base.obj")


def _posed(body: Mesh, motion: Motion) -> np.ndarray:
    return np.concatenate(list(skin_motion(body, motion).iter_chunks(128)), axis=0)


@pytest.fixture(scope="module")
def takes(body) -> dict:
    sk = synth_skeleton()
    out = {}
    for name, frames in (("flex", 260), ("squat", 240), ("jumprope", 360)):
        motion = retarget(make_clip(name, sk, frames=frames), body)
        out[name] = (motion, _posed(body, motion))
    return out


@pytest.fixture(scope="module")
def hop(body) -> tuple[Motion, np.ndarray]:
    """Standing still, one 5 cm hop of the whole body at 1.0..1.3 s, then still."""
    motion = retarget(make_clip("tpose", synth_skeleton(), frames=480), body)
    t = np.arange(motion.n_frames) / motion.rate
    s = np.clip((t - 1.0) / 0.3, 0.0, 1.0)
    translations = motion.translations.copy()
    translations[:, 0, 1] += 0.05 * np.sin(np.pi * s) ** 2
    moved = Motion(
        motion.skeleton, motion.rotations, translations, motion.rate, motion.channels, motion.meta
    )
    return moved, _posed(body, moved)


def _fixed_segments(tissue: SoftTissue, names: tuple[str, ...]) -> np.ndarray:
    """(V,) bool: vertices weighted only to the given body segments."""
    total = sum(tissue.segments.get(k, 0.0) for k in tissue.segments if k.startswith(names))
    return np.asarray(total) > 1.0 - 1e-9


def test_zero_amplitudes_give_exact_zeros(body, takes):
    motion, posed = takes["jumprope"]
    d = SoftTissue(body, bulge=0.0, jiggle=0.0, breathing=0.0).displacements(motion, posed)
    assert d.shape == posed.shape
    assert not d.any()


def test_regions_sit_where_they_should(body):
    tissue = SoftTissue(body)
    v = body.vertices
    skel = body.skin.skeleton
    heads = body.skin.bind_matrices[:, :3, 3]
    hip_y = heads[skel.index("upperleg01.L"), 1]
    neck_y = heads[skel.index("neck01"), 1]
    belly, chest = tissue.regions["belly"] > 0.3, tissue.regions["chest"] > 0.3
    assert belly.sum() > 50 and chest.sum() > 200
    spine_z = heads[[skel.index(k) for k in ("spine05", "spine03", "spine01")], 2].max()
    assert np.all(v[belly, 2] > spine_z + 0.05) and np.all(v[chest, 2] > spine_z + 0.02)
    assert np.all(v[belly, 1] > hip_y) and np.median(v[chest, 1]) > np.median(v[belly, 1])
    assert np.all(v[chest, 1] < neck_y)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        arm = tissue.regions[f"upperarm_{side}"] > 0.3
        thigh = tissue.regions[f"thigh_{side}"] > 0.3
        assert arm.sum() > 100 and thigh.sum() > 100
        assert np.all(sign * v[arm, 0] > 0.12) and np.all(v[arm, 1] > 0.3)
        assert np.all(sign * v[thigh, 0] > 0.0) and np.all(v[thigh, 1] < hip_y)
    for w in tissue.regions.values():
        assert w.min() >= 0.0 and w.max() <= 1.0


def test_bulge_grows_with_elbow_angle(body, takes):
    motion, posed = takes["flex"]
    tissue = SoftTissue(body, **ONLY["bulge"])
    d = tissue.displacements(motion, posed)
    mag = np.linalg.norm(d, axis=-1)  # (T, V)
    world = forward_kinematics(motion)
    flex = tissue.flexion(world)
    for side in ("l", "r"):
        angle, bind_angle, fold = flex[f"upperarm_{side}"]
        assert np.degrees(angle).max() == pytest.approx(150.0, abs=3.0)
        arm = tissue.regions[f"upperarm_{side}"] > 0
        peak = mag[:, arm].max(axis=1)  # (T,)
        order = np.argsort(angle)
        assert np.all(np.diff(peak[order]) >= -1e-4)  # monotone in the angle
        assert peak[angle <= bind_angle].max() == 0.0
        assert 0.006 < peak.max() < 0.02  # about a centimetre at 150 degrees
        # the bulge is on the biceps side: towards where the forearm folds
        t = int(np.argmax(angle))
        j_sh = body.skin.skeleton.index(f"upperarm01.{side.upper()}")
        j_el = body.skin.skeleton.index(f"lowerarm01.{side.upper()}")
        j_wr = body.skin.skeleton.index(f"wrist.{side.upper()}")
        sh, el, wr = (world[t, j, :3, 3] for j in (j_sh, j_el, j_wr))
        top = np.argsort(mag[t] * arm)[-20:]
        mid = 0.5 * (sh + el)
        toward = wr - el - np.dot(wr - el, el - sh) / np.dot(el - sh, el - sh) * (el - sh)
        assert np.all((posed[t, top] - mid) @ toward > 0)
        # outward: along the surface normal
        normals = vertex_normals(posed[t], body.faces)
        assert np.all(np.sum(d[t, top] * normals[top], axis=-1) > 0)


def test_quadriceps_bulge_in_squat(body, takes):
    motion, posed = takes["squat"]
    tissue = SoftTissue(body, **ONLY["bulge"])
    mag = np.linalg.norm(tissue.displacements(motion, posed), axis=-1)
    for side in ("l", "r"):
        thigh = tissue.regions[f"thigh_{side}"] > 0
        assert 0.004 < mag[:, thigh].max() < 0.02
    assert mag[:30].max() == 0.0  # T-pose hold: straight legs, no bulge


def test_jiggle_responds_to_a_hop_and_decays(body, hop):
    motion, posed = hop
    tissue = SoftTissue(body, **ONLY["jiggle"])
    mag = np.linalg.norm(tissue.displacements(motion, posed), axis=-1)
    belly = tissue.regions["belly"] > 0.3
    curve = mag[:, belly].max(axis=1)
    t = np.arange(motion.n_frames) / motion.rate
    assert curve[t < 1.0].max() == 0.0  # still before the hop
    peak = curve.max()
    assert 0.002 < peak < 0.03
    assert 1.0 < t[np.argmax(curve)] < 1.6
    late = curve[t > 3.0].max()
    assert late < 0.1 * peak  # damped
    # it oscillates: the spring overshoots, the belly moves both up and down
    d = tissue.displacements(motion, posed)
    vertical = d[:, np.nonzero(belly)[0][0], 1]
    assert vertical.max() > 0.1 * peak and vertical.min() < -0.1 * peak


def test_jiggle_in_jumprope_is_millimetres_to_centimetres(body, takes):
    motion, posed = takes["jumprope"]
    tissue = SoftTissue(body, **ONLY["jiggle"])
    mag = np.linalg.norm(tissue.displacements(motion, posed), axis=-1)
    for region in ("belly", "chest", "thigh_l", "upperarm_r"):
        sel = tissue.regions[region] > 0.3
        assert 0.001 < mag[:, sel].max() < 0.03, region


def test_breathing_is_periodic_and_seeded(body):
    motion = retarget(make_clip("tpose", synth_skeleton(), frames=600), body)
    posed = _posed(body, motion)
    tissue = SoftTissue(body, **ONLY["breathing"], seed=5)
    d = tissue.displacements(motion, posed)
    period = int(4.0 * motion.rate)  # 0.25 Hz
    np.testing.assert_allclose(d[period:], d[:-period], atol=1e-12)
    mag = np.linalg.norm(d, axis=-1)
    assert 0.002 < mag.max() < 0.006
    chest = tissue.regions["chest"] > 0.5
    curve = mag[:, chest].mean(axis=1)
    assert curve.max() - curve.min() > 0.5 * curve.max()  # it breathes in and out
    other = SoftTissue(body, **ONLY["breathing"], seed=6).displacements(motion, posed)
    assert not np.allclose(other[0], d[0])
    again = SoftTissue(body, **ONLY["breathing"], seed=5).displacements(motion, posed)
    assert again.tobytes() == d.tobytes()


def test_head_hands_feet_never_move(body, takes):
    tissue = SoftTissue(body)
    fixed = _fixed_segments(
        tissue, ("head", "neck", "hand", "forearm", "foot", "toe", "shin", "clavicle")
    )
    assert fixed.sum() > 3000
    for motion, posed in takes.values():
        d = tissue.displacements(motion, posed)
        assert not d[:, fixed].any()
        mag = np.linalg.norm(d, axis=-1)
        assert mag.max() < 0.04
        assert np.isfinite(d).all()


def test_scales_are_linear(body, takes):
    motion, posed = takes["squat"]
    one = SoftTissue(body, **ONLY["jiggle"]).displacements(motion, posed)
    half = SoftTissue(body, jiggle=0.5, bulge=0.0, breathing=0.0).displacements(motion, posed)
    np.testing.assert_allclose(half, 0.5 * one, atol=1e-15)


def test_vertex_normals_of_a_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    v = np.asarray(sphere.vertices)
    n = vertex_normals(v, np.asarray(sphere.faces))
    np.testing.assert_allclose(n, v / 0.1, atol=0.02)
    frames = np.stack([v, v * 2.0 + 1.0])
    nn = vertex_normals(frames, np.asarray(sphere.faces))
    np.testing.assert_allclose(nn[0], nn[1], atol=1e-12)


def test_bad_input(body, takes):
    motion, posed = takes["flex"]
    bare = Mesh(body.vertices, body.faces)
    with pytest.raises(ValidationError, match="skin"):
        SoftTissue(bare)
    for kwargs in ({"bulge": -1.0}, {"jiggle": float("nan")}, {"breathing": "lots"}, {"seed": -2}):
        with pytest.raises(ValidationError):
            SoftTissue(body, **kwargs)
    tissue = SoftTissue(body)
    with pytest.raises(ValidationError, match="posed"):
        tissue.displacements(motion, posed[:-1])
    bad = posed.copy()
    bad[3, 7, 0] = np.nan
    with pytest.raises(ValidationError, match="finite"):
        tissue.displacements(motion, bad)
    other = make_clip("flex", synth_skeleton(), frames=posed.shape[0])
    with pytest.raises(ValidationError, match="skeleton"):
        tissue.displacements(other, posed)
    with pytest.raises(ValidationError, match="Motion"):
        tissue.displacements("motion", posed)  # type: ignore[arg-type]


def test_procedural_body_with_cmu_names():
    """The sweep body's skin uses CMU names: the same regions and effects appear."""
    from skincap.synth.body import procedural_body

    sk = synth_skeleton()
    body = procedural_body(sk, n_vertices=6000)
    tissue = SoftTissue(body)
    for name in ("belly", "chest", "thigh_l", "thigh_r", "upperarm_l", "upperarm_r"):
        assert (tissue.regions[name] > 0.3).sum() > 30, name
    motion = make_clip("flex", sk, frames=240)
    posed = _posed(body, motion)
    bulge = SoftTissue(body, **ONLY["bulge"]).displacements(motion, posed)
    assert 0.008 < np.linalg.norm(bulge, axis=-1).max() < 0.02
    d = tissue.displacements(motion, posed)
    fixed = _fixed_segments(tissue, ("head", "neck", "hand", "forearm", "foot", "toe", "shin"))
    assert fixed.sum() > 500 and not d[:, fixed].any()
