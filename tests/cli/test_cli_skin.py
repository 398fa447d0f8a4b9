"""``skincap skin`` as a user runs it, on the shipped MakeHuman body and real BVH files."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app

DATA = Path(__file__).parents[1] / "data"


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def makehuman_dir(tmp_path_factory) -> Path:
    """The MakeHuman OBJ with its rig beside it, as a user has it."""
    folder = tmp_path_factory.mktemp("mh")
    for name in ("makehuman_base.obj", "makehuman_default.mhskel", "makehuman_default_weights.mhw"):
        shutil.copy(DATA / name, folder / name)
    return folder


def test_skin_glb_from_makehuman_and_cmu(tmp_path, makehuman_dir):
    from skincap.io.gltf.reader import read_gltf

    out = tmp_path / "walk.glb"
    result = run(
        "skin",
        makehuman_dir / "makehuman_base.obj",
        DATA / "cmu_131_01_bvh11.bvh",
        "--units",
        "cmu",
        "-o",
        out,
    )
    assert result.exit_code == 0, result.output
    assert "994 frames" in result.stdout
    mesh = read_gltf(out)
    assert mesh.n_vertices == 13380
    assert mesh.skin is not None and mesh.skin.skeleton.n_joints == 163


def test_info_sees_the_body_skin_uses(tmp_path, makehuman_dir):
    """info and skin --json report one vertex count, height and rig for the MakeHuman OBJ."""
    import json

    from skincap.io.bvh import read_bvh, write_bvh
    from skincap.types import Motion

    walk = read_bvh(DATA / "cmu_131_01_bvh11.bvh", units="cmu")
    short = Motion(walk.skeleton, walk.rotations[:3], walk.translations[:3], walk.rate,
                   walk.channels, walk.meta)  # fmt: skip
    bvh = tmp_path / "short.bvh"
    write_bvh(short, bvh, units="m")
    obj = makehuman_dir / "makehuman_base.obj"
    skinned = run("skin", obj, bvh, "--units", "m", "-o", tmp_path / "w.glb", "--json")
    assert skinned.exit_code == 0, skinned.output
    used = json.loads(skinned.stdout)
    info = run("info", obj, "--json")
    assert info.exit_code == 0, info.output
    seen = json.loads(info.stdout)
    assert seen["vertices"] == used["vertices"] == 13380  # MakeHuman helpers left out
    assert seen["skin_joints"] == used["joints"] == 163
    assert seen["height_m"] == pytest.approx(used["height_m"], abs=1e-12)
    assert 1.5 < seen["height_m"] < 1.8 and seen["source_units"] == "dm"  # a body, in metres
    assert used["outputs"] == [str(tmp_path / "w.glb")] and used["frames"] == 3


def test_skin_dqs_pc2_matches_deformer(tmp_path, makehuman_dir):
    from skincap.deform.skeletal.deformers import make_deformer
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.deform.skeletal.rig import skinning_matrices
    from skincap.io.bvh import read_bvh
    from skincap.io.makehuman import read_makehuman
    from skincap.io.pc2 import read_pc2

    bvh = DATA / "bvhtoolbox_test_mocapbank.bvh"
    out = tmp_path / "mocap.pc2"
    result = run(
        "skin",
        makehuman_dir / "makehuman_base.obj",
        bvh,
        "--units",
        "cm",
        "--method",
        "dqs",
        "-o",
        out,
    )
    assert result.exit_code == 0, result.output
    cache = read_pc2(out)
    assert cache.frames.shape == (455, 13380, 3)
    rest = (tmp_path / "mocap.obj").read_text()
    assert rest.count("\nv ") == 13380
    # the same frame computed through the Python API
    setup = prepare_skinning(
        read_makehuman(makehuman_dir / "makehuman_base.obj"), read_bvh(bvh, units="cm")
    )
    frame = 200
    matrices = skinning_matrices(setup.motion, setup.mesh.skin)[frame]
    expected = make_deformer("dqs", setup.mesh).deform(matrices)
    np.testing.assert_allclose(cache.frames[frame], expected, atol=1e-5)  # PC2 stores float32


def test_skin_bare_mesh_gets_automatic_weights(tmp_path):
    from skincap.io.bvh import read_bvh, write_bvh
    from skincap.io.makehuman import read_makehuman
    from skincap.io.mesh import write_obj
    from skincap.types import Mesh, Motion

    body = read_makehuman(DATA / "makehuman_base.obj")
    bare = tmp_path / "body.obj"  # the body alone, no rig beside it
    write_obj(Mesh(body.vertices, body.faces), bare)
    full = read_bvh(DATA / "bvhtoolbox_test_mocapbank.bvh", units="cm")
    short = Motion(
        full.skeleton,
        full.rotations[:12],
        full.translations[:12],
        full.rate,
        full.channels,
        full.meta,
    )
    bvh = tmp_path / "short.bvh"
    write_bvh(short, bvh)
    out = tmp_path / "frames"
    result = run("skin", bare, bvh, "--units", "cm", "-o", out)
    assert result.exit_code == 0, result.output
    assert "auto weights" in result.stdout
    files = sorted(out.glob("*.obj"))
    assert len(files) == 12
    # the size is said before the frames are written, and it is right
    text = " ".join(result.output.split())
    said = float(text.split("12 OBJ files to ")[1].split("about ")[1].split(" MB")[0])
    written = sum(p.stat().st_size for p in files) / 1e6
    assert said == pytest.approx(written, rel=0.05)  # 11.9 said, 11.56 written
    # MakeHuman's body stands arms down; the mocapbank skeleton's zero pose is a T:
    # the warning names the joint furthest outside the body and how far
    from skincap.deform.skeletal.bind import fit_skeleton_to_mesh, transform_skeleton
    from skincap.deform.skeletal.rest_pose import rest_pose_misfit

    mesh = Mesh(body.vertices, body.faces)
    motion = read_bvh(bvh, units="cm")
    scale, shift = fit_skeleton_to_mesh(motion.skeleton, mesh)
    misfit = rest_pose_misfit(mesh, transform_skeleton(motion.skeleton, scale, shift))
    assert misfit["misfit"]
    assert (
        f"skincap: warning: the mesh does not stand in the BVH's rest pose: joint "
        f"'{misfit['worst_joint']}' is {100 * misfit['worst_distance_m']:.1f} cm outside"
    ) in text


def test_skin_rejects_dqs_in_gltf_and_bad_options(tmp_path, makehuman_dir):
    mesh = makehuman_dir / "makehuman_base.obj"
    bvh = DATA / "bvhtoolbox_test_mocapbank.bvh"
    maps = makehuman_dir.parent / "maps"  # beside, not in tmp_path: nothing written there
    maps.mkdir(exist_ok=True)
    (maps / "unknown.json").write_text('{"NoSuchJoint": "root"}')
    (maps / "target.json").write_text('{"Hips": "NoSuchBone"}')
    for extra, message in [
        (["--method", "dqs", "-o", tmp_path / "x.glb"], "linear blend"),
        (["--method", "cubic", "-o", tmp_path / "x.pc2"], "lbs, dqs or sweep"),
        (["--method", "sweep", "-o", tmp_path / "x.glb"], "bake sweep"),
        (["-o", tmp_path / "x.fbx"], "cannot write"),
        (
            ["--weights", "file", "-o", tmp_path / "x.glb", "--map", tmp_path / "missing.json"],
            "missing.json",
        ),
        # a joint neither skeleton has: the map is named (was the mesh and the BVH)
        (
            ["-o", tmp_path / "x.glb", "--map", maps / "unknown.json"],
            f"{maps / 'unknown.json'}: source joint 'NoSuchJoint' is not in the source",
        ),
        (
            ["-o", tmp_path / "x.glb", "--map", maps / "target.json"],
            f"{maps / 'target.json'}: target joint 'NoSuchBone' is not in the target",
        ),
    ]:
        result = run("skin", mesh, bvh, "--units", "cm", *extra)
        assert result.exit_code == 2, (extra, result.output)
        assert message in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
def test_skin_sweep_pc2_matches_the_api(tmp_path, makehuman_dir):
    """--method sweep bakes what SweepDeformer gives through the Python API."""
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.deform.skeletal.rig import skinning_matrices
    from skincap.deform.sweep import SweepDeformer
    from skincap.io.bvh import read_bvh
    from skincap.io.makehuman import read_makehuman
    from skincap.io.pc2 import read_pc2

    bvh = DATA / "bvhtoolbox_test_mocapbank.bvh"
    out = tmp_path / "mocap.pc2"
    mesh = makehuman_dir / "makehuman_base.obj"
    result = run("skin", mesh, bvh, "--units", "cm", "--method", "sweep", "-o", out)
    assert result.exit_code == 0, result.output
    assert "sweep" in result.stdout
    cache = read_pc2(out)
    assert cache.frames.shape == (455, 13380, 3)
    setup = prepare_skinning(read_makehuman(mesh), read_bvh(bvh, units="cm"))
    frame = 300
    matrices = skinning_matrices(setup.motion, setup.mesh.skin)[frame]
    expected = SweepDeformer(setup.mesh).deform(matrices)
    np.testing.assert_allclose(cache.frames[frame], expected, atol=1e-5)  # PC2 stores float32


def test_skin_sweep_refuses_a_mesh_without_limbs(tmp_path):
    """A closed tetrahedron has no arm or leg to fit a sweep to: one line naming it, exit 2."""
    tet = tmp_path / "in" / "tet.obj"
    tet.parent.mkdir()
    tet.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    out = tmp_path / "out"
    out.mkdir()
    result = run("skin", tet, DATA / "cmu_131_01_bvh11.bvh", "--units", "cmu",
                 "--method", "sweep", "-o", out / "t.pc2")  # fmt: skip
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert lines[-1].startswith(f"skincap: error: {tet}: cannot fit the arm_l sweep"), lines
    assert sum("error" in line for line in lines) == 1
    assert list(out.iterdir()) == []
