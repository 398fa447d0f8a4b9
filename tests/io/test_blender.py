"""Blender as the second reader of the exports (headless ``blender -b``).

Each test writes a file, runs a script from ``blender_scripts/`` inside Blender and
compares what Blender evaluated with skincap's own result. Blender is Z up: a skincap
(Y-up) point ``(x, y, z)`` is ``(x, -z, y)`` in Blender, the turn both Blender's glTF
importer and its OBJ importer (default axes, as an object rotation) apply.

Skipped when ``blender`` is not on PATH, or when Blender's Python has no NumPy (its
glTF importer needs it: ``apt-get install blender python3-numpy`` on Debian).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from skinned_cylinder import bend_motion, bind_local, lbs_reference

from skincap.io.bvh import read_bvh
from skincap.io.gltf.writer import write_glb
from skincap.io.makehuman import read_makehuman
from skincap.io.mesh import write_obj
from skincap.io.pc2 import write_pc2
from skincap.types import MeshAnimation, Motion

BLENDER = shutil.which("blender")
SCRIPTS = Path(__file__).parent / "blender_scripts"
DATA = Path(__file__).resolve().parents[1] / "data"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(BLENDER is None, reason="Blender is not on PATH (apt-get install blender)"),
]


def blender_to_y_up(p: np.ndarray) -> np.ndarray:
    """Blender (Z up) -> skincap (Y up): (x, y, z) -> (x, z, -y)."""
    return np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)


@pytest.fixture(scope="module")
def blender() -> str:
    probe = subprocess.run(
        [BLENDER, "-b", "--factory-startup", "--python-exit-code", "1",
         "--python-expr", "import numpy"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    if probe.returncode != 0:
        pytest.skip("Blender's Python has no numpy (apt-get install python3-numpy)")
    return str(BLENDER)


def run_blender(blender: str, script: str, *args: object) -> None:
    cmd = [blender, "-b", "--factory-startup", "--python-exit-code", "1",
           "--python", str(SCRIPTS / script), "--", *map(str, args)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        pytest.fail(
            f"Blender failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        )


def test_glb_cylinder(blender, tmp_path, cylinder, bend):
    glb = tmp_path / "bend.glb"
    write_glb(cylinder, bend, glb)
    out = tmp_path / "report.npz"
    run_blender(blender, "import_gltf.py", glb, out, 24, 0, 12, 24)
    r = np.load(out)
    assert r["vertex_counts"].tolist() == [cylinder.n_vertices]
    # one action, keys at frames 0..24 (time 0 is frame 0), one key per motion frame
    np.testing.assert_array_equal(r["action_ranges"], [[0.0, 24.0]])
    assert r["key_counts"].tolist() == [bend.n_frames]
    ref = lbs_reference(cylinder, bend)
    got = blender_to_y_up(r["positions"])
    assert np.abs(ref[24] - ref[0]).max() > 0.2
    np.testing.assert_allclose(got, ref[[0, 12, 24]], atol=1e-6)
    # Blender's own coordinates are the Z-up turn of skincap's
    np.testing.assert_allclose(
        r["positions"][1, :, 2], ref[12][:, 1], atol=1e-6
    )  # skincap y is Blender z


def test_glb_keys_are_in_seconds(blender, tmp_path, cylinder):
    """A 30 Hz motion in a 24 fps scene: motion frame k shows at scene frame 0.8 k."""
    motion = bend_motion(cylinder, n_frames=31, rate=30.0)
    glb = tmp_path / "bend30.glb"
    write_glb(cylinder, motion, glb)
    out = tmp_path / "report.npz"
    run_blender(blender, "import_gltf.py", glb, out, 24, 8, 16, 24)
    r = np.load(out)
    np.testing.assert_allclose(r["action_ranges"], [[0.0, 24.0]], atol=1e-4)
    ref = lbs_reference(cylinder, motion)
    np.testing.assert_allclose(blender_to_y_up(r["positions"]), ref[[10, 20, 30]], atol=1e-6)


def test_pc2_on_obj_imported_with_default_settings(blender, tmp_path, cylinder, cylinder_animation):
    """Y-up PC2 + Blender's default OBJ import + Mesh Cache with its default axes."""
    obj = tmp_path / "rest.obj"
    pc2 = tmp_path / "bend.pc2"
    write_obj(cylinder, obj)
    write_pc2(cylinder_animation, pc2)
    out = tmp_path / "report.npz"
    frames = list(range(27))
    run_blender(blender, "mesh_cache_pc2.py", obj, pc2, out, "new", "POS_Y", "POS_Z", 0, *frames)
    r = np.load(out)
    assert r["vertex_counts"].tolist() == [cylinder.n_vertices]
    ref = cylinder_animation.frames
    np.testing.assert_allclose(blender_to_y_up(r["rest_positions"]), cylinder.vertices, atol=1e-6)
    got = blender_to_y_up(r["positions"])
    # scene frame f shows sample f; past the 25 samples the last one holds
    np.testing.assert_allclose(got, ref[np.minimum(frames, 24)], atol=1e-6)
    assert np.abs(got[24] - got[23]).max() > 1e-3  # 25 distinct samples


def test_pc2_z_up_on_z_up_mesh(blender, tmp_path, cylinder, cylinder_animation):
    """up="z" PC2 on a mesh whose data is already Z up (OBJ imported without a turn)."""
    obj = tmp_path / "rest_zup.obj"
    pc2 = tmp_path / "bend_z.pc2"
    write_obj(cylinder, obj, up="z")
    write_pc2(cylinder_animation, pc2, up="z")
    out = tmp_path / "report.npz"
    run_blender(blender, "mesh_cache_pc2.py", obj, pc2, out, "new_zup", "POS_Y", "POS_Z", 1, 1, 13)
    r = np.load(out)
    ref = cylinder_animation.frames
    # frame start 1: scene frame 1 shows sample 0
    np.testing.assert_allclose(blender_to_y_up(r["positions"]), ref[[0, 12]], atol=1e-6)


def _makehuman_motion(mesh, n: int) -> Motion:
    q0, t0 = bind_local(mesh.skin)
    rot = np.tile(q0, (n, 1, 1))
    tra = np.tile(t0, (n, 1, 1))
    names = mesh.skin.skeleton.names
    for name, axis in (("lowerarm01.L", "x"), ("upperarm01.R", "z"), ("spine03", "x")):
        j = names.index(name)
        turn = Rotation.from_euler(axis, np.linspace(0, 70, n)[:, None], degrees=True)
        rot[:, j] = (Rotation.from_quat(q0[j]) * turn).as_quat()
    tra[:, 0, 2] = np.linspace(0.0, 0.4, n)
    return Motion(mesh.skin.skeleton, rot, tra, 30.0)


def test_makehuman_glb(blender, tmp_path):
    mesh = read_makehuman(DATA / "makehuman_base.obj")
    motion = _makehuman_motion(mesh, 10)
    glb = tmp_path / "mh.glb"
    write_glb(mesh, motion, glb)
    out = tmp_path / "report.npz"
    run_blender(blender, "import_gltf.py", glb, out, 30, 0, 9)
    r = np.load(out)
    assert r["vertex_counts"].tolist() == [13380]
    np.testing.assert_array_equal(r["action_ranges"], [[0.0, 9.0]])
    assert r["key_counts"].tolist() == [10]
    ref = lbs_reference(mesh, motion)
    assert np.abs(ref[9] - ref[0]).max() > 0.3
    np.testing.assert_allclose(blender_to_y_up(r["positions"]), ref[[0, 9]], atol=1e-5)


def test_makehuman_dqs_pc2(blender, tmp_path):
    deformers = pytest.importorskip(
        "skincap.deform.skeletal.deformers",
        reason="skincap.deform.skeletal.deformers not in the tree yet",
    )
    mesh = read_makehuman(DATA / "makehuman_base.obj")
    motion = _makehuman_motion(mesh, 10)
    anim = deformers.skin_motion(mesh, motion, method="dqs", chunk=4)
    assert isinstance(anim, MeshAnimation)
    obj = tmp_path / "mh.obj"
    pc2 = tmp_path / "mh.pc2"
    write_obj(mesh, obj, units="m")
    write_pc2(anim, pc2)
    out = tmp_path / "report.npz"
    run_blender(blender, "mesh_cache_pc2.py", obj, pc2, out, "new", "POS_Y", "POS_Z", 0, 0, 9)
    r = np.load(out)
    assert r["vertex_counts"].tolist() == [13380]
    ref = deformers.skin_motion(mesh, motion, method="dqs").frames
    ref = np.concatenate(list(ref)) if not isinstance(ref, np.ndarray) else ref
    np.testing.assert_allclose(blender_to_y_up(r["positions"]), ref[[0, 9]], atol=1e-5)


def test_makehuman_walks_cmu_bvh(blender, tmp_path):
    """The issue's goal: the MakeHuman body walking the CMU take, as a .glb Blender plays."""
    retarget = pytest.importorskip(
        "skincap.deform.skeletal.retarget",
        reason="skincap.deform.skeletal.retarget not in the tree yet",
    )
    mesh = read_makehuman(DATA / "makehuman_base.obj")
    walk = retarget.retarget(read_bvh(DATA / "cmu_131_01_bvh11.bvh", units="cmu"), mesh)
    glb = tmp_path / "walk.glb"
    write_glb(mesh, walk, glb)
    out = tmp_path / "report.npz"
    last = walk.n_frames - 1
    # the take is 120.0005 Hz: in a 120 fps scene key k sits at frame 120 k / rate, so
    # compare at the first and last keys' own (fractional) frames
    run_blender(blender, "import_gltf.py", glb, out, 120, 0, 120.0 * last / walk.rate)
    r = np.load(out)
    assert r["vertex_counts"].tolist() == [13380]
    assert r["key_counts"].tolist() == [walk.n_frames] == [994]
    np.testing.assert_allclose(r["action_ranges"][0, 1], 120.0 * last / walk.rate, atol=1e-3)
    pose = Motion(walk.skeleton, walk.rotations[[0, last]], walk.translations[[0, last]], walk.rate)
    ref = lbs_reference(mesh, pose)
    assert np.linalg.norm(ref[1].mean(0) - ref[0].mean(0)) > 2.0  # walked over 2 m
    np.testing.assert_allclose(blender_to_y_up(r["positions"]), ref, atol=2e-5)


def test_blender_plays_our_bvh(blender, tmp_path):
    """A BVH skincap writes, imported by Blender's own BVH importer: every joint where FK puts it."""
    from skincap.geometry.kinematics import joint_positions
    from skincap.io.bvh import write_bvh

    motion = read_bvh(DATA / "cmu_131_01_bvh11.bvh", units="cmu")
    walk = slice(450, 750)  # the clean walk of this take
    short = Motion(
        motion.skeleton, motion.rotations[walk], motion.translations[walk], motion.rate,
        motion.channels, motion.meta,
    )  # fmt: skip
    ours = tmp_path / "walk.bvh"
    write_bvh(short, ours)
    out = tmp_path / "bvh.npz"
    frames = [0, 150, 299]
    run_blender(blender, "import_bvh.py", ours, out, *frames)
    r = np.load(out)
    assert r["frame_range"].tolist() == [1.0, 300.0]
    # Blender works in the file's numbers: read our file back in its own units
    file_units = read_bvh(ours, units="m")
    ref = joint_positions(file_units)[frames]  # (3, J, 3)
    names = list(file_units.skeleton.names)
    cols = [names.index(n) for n in r["names"]]
    assert len(cols) >= 25  # every joint with channels became a bone
    np.testing.assert_allclose(blender_to_y_up(r["heads"]), ref[:, cols], atol=1e-3)
    assert np.linalg.norm(ref[2, 0] - ref[0, 0]) > 20  # walked over 1 m (CMU units of 5.6 cm)


_DEFAULT_IMPORT = """
import sys
import bpy

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=sys.argv[sys.argv.index("--") + 1])  # every default
meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
assert len(meshes) == 1 and len(meshes[0].data.vertices) > 0, meshes
"""


def test_glb_with_the_importers_defaults_fails_only_inside_blender(
    blender, tmp_path, cylinder, bend
):
    """What a user runs: File > Import > glTF with every default, NumPy unpatched.

    Either Blender imports our file, or it fails at its own ``np.bool`` (Blender 3.4's
    importer with NumPy >= 1.24, in its default shading mode, before it looks at the
    file's normals): nothing in our file may be the cause. We write NORMAL, so the
    failure cannot be avoided from our side; README.md gives the working option
    (Shading: Smooth), which the other glTF tests use.
    """
    glb = tmp_path / "bend.glb"
    write_glb(cylinder, bend, glb)
    done = subprocess.run(
        [blender, "-b", "--factory-startup", "--python-exit-code", "1",
         "--python-expr", _DEFAULT_IMPORT, "--", str(glb)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    if done.returncode != 0:
        text = done.stdout + done.stderr
        assert "module 'numpy' has no attribute 'bool'" in text, text[-3000:]
        assert "dtype=np.bool)" in text and "set_poly_smoothing" in text, text[-3000:]
