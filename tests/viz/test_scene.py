"""load_scene: every kind of file skincap reads or writes becomes drawable layers."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from skincap.errors import FormatError, SkincapWarning
from skincap.io.bvh import read_bvh
from skincap.io.c3d import read_c3d
from skincap.io.csv import write_points_csv
from skincap.io.mesh import read_obj, write_obj
from skincap.io.pc2 import write_pc2
from skincap.types import Mesh, MeshAnimation, PointCloud
from skincap.viz.scene import MarkerLayer, load_scene, scene_from_objects

DATA = Path(__file__).resolve().parents[1] / "data"


def test_real_c3d_and_bvh_on_one_clock():
    c3d = DATA / "kt_optitrack_walking.c3d"
    bvh = DATA / "cmu_131_01_bvh11.bvh"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the BVH unit guess
        scene = load_scene([c3d, bvh])
    markers, skeleton = scene.layers
    ref = read_c3d(c3d)
    assert markers.kind == "markers" and skeleton.kind == "skeleton"
    np.testing.assert_array_equal(markers.positions, ref.positions)
    assert markers.labels == list(ref.labels)
    assert scene.rate == max(ref.rate, skeleton.rate)
    # the scene clock maps a time to each layer's own nearest frame
    t = 1.0
    assert scene.layer_frame(markers, t) == round(t * ref.rate)
    assert scene.layer_frame(markers, 1e6) == markers.n_frames - 1
    lo, hi = scene.bounds()
    assert (hi > lo).all()


def test_points_csv_and_rope_curve(tmp_path):
    rng = np.random.default_rng(0)
    counts = np.array([3, 0, 5, 4])
    pts = rng.normal(size=(counts.sum(), 3))
    cloud = PointCloud(points=pts, offsets=np.concatenate([[0], np.cumsum(counts)]), rate=120.0)
    write_points_csv(cloud, tmp_path / "points.csv")
    curve = tmp_path / "rope_curve.csv"
    rows = ["frame,s,x,y,z"] + [f"{f},{k * 0.1},{k},{f},0" for f in range(4) for k in range(6)]
    curve.write_text("\n".join(rows) + "\n")
    (tmp_path / "report.json").write_text('{"rate": 60.0}')
    scene = load_scene([tmp_path / "points.csv", curve])
    points, rope = scene.layers
    assert points.kind == "points" and points.n_frames == 4
    np.testing.assert_allclose(points.cloud.frame(2), pts[3:8])
    assert rope.kind == "curve" and rope.curves.shape == (4, 6, 3) and rope.rate == 60.0
    np.testing.assert_array_equal(rope.curves[3, :, 0], np.arange(6))
    ragged = tmp_path / "bad" / "rope_curve.csv"
    ragged.parent.mkdir()
    ragged.write_text("frame,s,x,y,z\n0,0,0,0,0\n0,1,1,0,0\n1,0,0,0,0\n")
    with pytest.raises(FormatError, match="same number of samples"):
        load_scene([ragged])


def test_point_cache_with_its_mesh_and_folder_loading(tmp_path):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    mesh = Mesh(vertices=verts, faces=np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))
    frames = verts[None] + np.linspace(0, 1, 10)[:, None, None] * np.array([0, 0.5, 0])
    write_obj(mesh, tmp_path / "tet.obj")
    write_pc2(MeshAnimation(rest=mesh, frames=frames, rate=24.0), tmp_path / "tet.pc2")
    (tmp_path / "notes.csv").write_text("something,else\n1,2\n")
    with pytest.warns(SkincapWarning) as record:
        scene = load_scene([tmp_path])
    messages = " ".join(str(w.message) for w in record)
    assert "notes.csv" in messages and "30 Hz" in messages  # skipped file; PC2 rate fallback
    (layer,) = scene.layers  # the OBJ is shown once, animated by its cache
    assert layer.kind == "mesh" and layer.frames.shape == (10, 4, 3) and layer.rate == 30.0
    np.testing.assert_allclose(layer.frames, frames, atol=1e-6)
    scene = load_scene([tmp_path / "tet.pc2"], rate=24.0)
    assert scene.layers[0].rate == 24.0


def test_errors_name_the_file(tmp_path):
    with pytest.raises(FormatError, match="no such file"):
        load_scene([tmp_path / "missing.c3d"])
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(FormatError, match="x.txt"):
        load_scene([tmp_path / "x.txt"])
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FormatError, match="no file skincap shows"):
        load_scene([empty])
    lonely = tmp_path / "lonely.pc2"
    lonely.write_bytes(b"POINTCACHE2\x00")
    with pytest.raises(FormatError, match="lonely.obj"):
        load_scene([lonely])


def test_frameless_takes_are_refused_naming_the_file(tmp_path):
    lines = (DATA / "cmu_131_01_bvh11.bvh").read_text().splitlines()
    at = lines.index("MOTION")
    bvh = tmp_path / "still.bvh"
    bvh.write_text("\n".join([*lines[: at + 1], "Frames: 0", lines[at + 2]]) + "\n")
    points = tmp_path / "none.csv"
    points.write_text("# rate=100\n# frames=0\nframe,time,x,y,z\n")
    for path, units in ((bvh, "cmu"), (points, None)):
        with pytest.raises(FormatError, match=rf"{path.name}: has no frames to show"):
            load_scene([path], units=units)
    # next to a take with frames, too: the empty one is named
    with pytest.raises(FormatError, match=r"still\.bvh: has no frames to show"):
        load_scene([DATA / "cmu_85_02.c3d", bvh], units="cmu")


def test_units_for_files_that_do_not_say_leave_csv_files_alone(tmp_path):
    # every CSV says its unit; --units (for BVH, OBJ) used to reach the CSV readers
    points = tmp_path / "p.csv"
    points.write_text("frame,time,x,y,z\n0,0,1,2,3\n1,0.01,1,2,4\n")
    vicon = DATA / "pyomeca_vicon_nexus_trajectories.csv"
    scene = load_scene([points, vicon], units="cm")
    np.testing.assert_array_equal(scene.layers[0].points_at(1), [[1.0, 2.0, 4.0]])
    assert scene.layers[1].n_frames == load_scene([vicon]).layers[0].n_frames


def test_overlay_names_stay_unique_and_invented_flags_survive():
    markers = read_c3d(DATA / "kt_optitrack_walking.c3d")
    motion = read_bvh(DATA / "cmu_131_01_bvh11.bvh", units="cmu")
    scene = scene_from_objects([("take", markers), ("take", markers), ("walk", motion)])
    assert [lay.name for lay in scene.layers] == ["take", "take (2)", "walk"]
    first = scene.layers[0]
    assert isinstance(first, MarkerLayer)
    assert first.invented.shape == markers.positions.shape[:2] and not first.invented.any()


def _tet_animation():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    mesh = Mesh(vertices=verts, faces=np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))
    frames = verts[None] + np.linspace(0, 1, 6)[:, None, None] * np.array([0.2, 0.5, 0])
    return mesh, frames


def test_obj_sequence_folder_is_one_animated_mesh(tmp_path):
    from skincap.io.obj_sequence import write_obj_sequence

    mesh, frames = _tet_animation()
    write_obj_sequence(MeshAnimation(rest=mesh, frames=frames, rate=24.0), tmp_path / "seq")
    scene = load_scene([tmp_path / "seq"], rate=24.0)
    (layer,) = scene.layers
    assert layer.kind == "mesh" and layer.frames.shape == (6, 4, 3)
    np.testing.assert_allclose(layer.frames, frames, atol=1e-6)


def test_usd_stage_points_play_back(tmp_path):
    pytest.importorskip("pxr", reason="USD needs usd-core (skincap[usd])")
    from skincap.io.usd import write_usd

    mesh, frames = _tet_animation()
    write_usd(MeshAnimation(rest=mesh, frames=frames, rate=24.0), tmp_path / "tet.usda")
    scene = load_scene([tmp_path / "tet.usda"])
    (layer,) = scene.layers
    assert layer.rate == 24.0 and layer.frames.shape == (6, 4, 3)
    np.testing.assert_allclose(layer.frames, frames, atol=1e-6)
    np.testing.assert_array_equal(np.sort(layer.faces, axis=1), np.sort(mesh.faces, axis=1))


def test_point_cache_plays_at_the_rate_its_writer_noted(tmp_path):
    # skin/animate outputs played at 30 Hz whatever the take's rate (a 120 Hz walk 4x slow)
    from skincap.io.mesh_animation_files import write_mesh_animation
    from skincap.io.pc2 import recorded_pc2_rate

    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    mesh = Mesh(vertices=verts, faces=np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))
    frames = verts[None] + np.linspace(0, 1, 12)[:, None, None] * np.array([0, 0.5, 0])
    out = tmp_path / "walk.pc2"
    write_mesh_animation(MeshAnimation(rest=mesh, frames=frames, rate=119.88), out, force=False)
    assert recorded_pc2_rate(tmp_path / "walk.obj") == 119.88
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        (layer,) = load_scene([out]).layers
        (again,) = load_scene([tmp_path / "walk.obj"]).layers  # the OBJ finds its cache
    assert layer.rate == again.rate == 119.88 and layer.n_frames == 12
    assert load_scene([out], rate=24.0).layers[0].rate == 24.0  # --rate still decides
    obj_text = (tmp_path / "walk.obj").read_text()
    assert read_obj(tmp_path / "walk.obj").n_vertices == 4  # the comment is skipped
    # a note that is not a positive number is ignored: the 30 Hz fallback, with a warning
    for bad in ("nan", "-5", "0", "1e400", "fast"):
        (tmp_path / "walk.obj").write_text(
            obj_text.replace("rate 119.88 Hz", f"rate {bad} Hz"), encoding="utf-8"
        )
        with pytest.warns(SkincapWarning, match="30 Hz"):
            assert load_scene([out]).layers[0].rate == 30.0


def test_obj_sequence_plays_at_the_rate_its_writer_noted(tmp_path):
    # a skin/animate OBJ-sequence folder played at 30 Hz, or at another motion's rate
    from skincap.io.mesh_animation_files import write_mesh_animation

    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    mesh = Mesh(vertices=verts, faces=np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))
    frames = verts[None] + np.linspace(0, 1, 5)[:, None, None] * np.array([0, 0.5, 0])
    seq = tmp_path / "seq"
    write_mesh_animation(MeshAnimation(rest=mesh, frames=frames, rate=59.94), seq, force=False)
    assert read_obj(seq / "frame_0000.obj").n_vertices == 4
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        bvh = DATA / "cmu_131_01_bvh11.bvh"  # a 120 Hz motion beside it does not decide
        layers = load_scene([seq, bvh], units="cmu").layers
    (layer,) = [lay for lay in layers if lay.name == "seq"]
    assert layer.rate == 59.94 and layer.n_frames == 5
    assert load_scene([seq], rate=24.0).layers[0].rate == 24.0
