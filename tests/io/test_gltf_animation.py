"""read_gltf_animation: our own glb exports play back as the motion that made them."""

from __future__ import annotations

import json

import numpy as np
import pytest
from skinned_cylinder import RATE, lbs_reference

from skincap.errors import FormatError
from skincap.geometry.kinematics import forward_kinematics
from skincap.io.gltf.animation import read_gltf_animation
from skincap.io.gltf.reader import read_gltf
from skincap.io.gltf.writer import write_glb
from skincap.viz.scene import load_scene


def test_node_world_matrices_match_forward_kinematics(tmp_path, cylinder, bend):
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    anim = read_gltf_animation(out)
    assert anim is not None
    assert anim.rate == RATE
    np.testing.assert_allclose(anim.times, np.arange(bend.n_frames) / RATE, atol=1e-6)
    mesh = read_gltf(out)
    nodes = mesh.meta["joint_nodes"]
    order = [mesh.skin.skeleton.names.index(n) for n in bend.skeleton.names]
    world = anim.node_world[:, nodes][:, order]
    np.testing.assert_allclose(world, forward_kinematics(bend), atol=1e-6)


def test_scene_plays_the_skinned_glb_like_our_deformer(tmp_path, cylinder, bend):
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    scene = load_scene([out])
    kinds = {layer.kind: layer for layer in scene.layers}
    assert set(kinds) == {"mesh", "skeleton"}
    mesh_layer = kinds["mesh"]
    ref = lbs_reference(cylinder, bend)
    assert mesh_layer.frames.shape == ref.shape
    assert np.abs(ref[-1] - ref[0]).max() > 0.2
    np.testing.assert_allclose(mesh_layer.frames, ref, atol=2e-6)
    assert scene.rate == RATE and scene.n_frames == bend.n_frames


def test_resampling_at_another_rate_interpolates(tmp_path, cylinder, bend):
    out = tmp_path / "cyl.glb"
    write_glb(cylinder, bend, out)
    full = read_gltf_animation(out)
    half = read_gltf_animation(out, rate=RATE * 2)
    assert half.node_world.shape[0] == 2 * bend.n_frames - 1
    np.testing.assert_allclose(half.node_world[::2], full.node_world, atol=1e-9)
    # a midpoint lies between its neighbours (slerp/lerp of small steps)
    mid = half.node_world[1::2, :, :3, 3]
    avg = 0.5 * (full.node_world[:-1, :, :3, 3] + full.node_world[1:, :, :3, 3])
    assert np.abs(mid - avg).max() < 0.01


def _gltf_with_one_channel(tmp_path, interpolation, times, values):
    """A .gltf (JSON + data URI) with one node translated by one sampler."""
    import base64

    blob = np.asarray(times, "<f4").tobytes() + np.asarray(values, "<f4").tobytes()
    n_keys = len(times)
    n_out = len(values)
    doc = {
        "asset": {"version": "2.0"},
        "nodes": [{"name": "a"}],
        "scenes": [{"nodes": [0]}],
        "buffers": [
            {
                "byteLength": len(blob),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode(),
            }
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 4 * n_keys},
            {"buffer": 0, "byteOffset": 4 * n_keys, "byteLength": 12 * n_out},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n_keys, "type": "SCALAR"},
            {"bufferView": 1, "componentType": 5126, "count": n_out, "type": "VEC3"},
        ],
        "animations": [
            {
                "samplers": [{"input": 0, "output": 1, "interpolation": interpolation}],
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
            }
        ],
    }
    path = tmp_path / f"{interpolation}.gltf"
    path.write_text(json.dumps(doc))
    return path


def test_step_and_cubic_spline_samplers(tmp_path):
    step = _gltf_with_one_channel(tmp_path, "STEP", [0.0, 1.0], [[0, 0, 0], [1, 0, 0]])
    anim = read_gltf_animation(step, rate=4.0)
    np.testing.assert_allclose(anim.node_world[:, 0, 0, 3], [0, 0, 0, 0, 1])
    # cubic Hermite with zero tangents: smoothstep from 0 to 1
    cubic = _gltf_with_one_channel(
        tmp_path,
        "CUBICSPLINE",
        [0.0, 1.0],
        [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 0, 0]],
    )
    anim = read_gltf_animation(cubic, rate=4.0)
    u = np.arange(5) / 4.0
    np.testing.assert_allclose(anim.node_world[:, 0, 0, 3], 3 * u**2 - 2 * u**3, atol=1e-7)


def test_no_animation_and_bad_animation(tmp_path):
    bad = _gltf_with_one_channel(tmp_path, "LINEAR", [0.0, 1.0], [[0, 0, 0]])
    with pytest.raises(FormatError, match="outputs"):
        read_gltf_animation(bad)
    backwards = _gltf_with_one_channel(tmp_path, "STEP", [1.0, 0.0], [[0, 0, 0], [1, 0, 0]])
    with pytest.raises(FormatError, match="increase"):
        read_gltf_animation(backwards)
    doc = json.loads(bad.read_text())
    del doc["animations"]
    plain = tmp_path / "plain.gltf"
    plain.write_text(json.dumps(doc))
    assert read_gltf_animation(plain) is None
