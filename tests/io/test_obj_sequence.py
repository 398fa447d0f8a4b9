"""OBJ sequences: every frame reads back (skincap and trimesh), topology kept, folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from skincap.errors import FormatError, OutputExistsError, ValidationError
from skincap.io.makehuman import read_makehuman
from skincap.io.mesh import read_obj
from skincap.io.obj_sequence import write_obj_sequence
from skincap.types import MeshAnimation

DATA = Path(__file__).resolve().parents[1] / "data"


def test_round_trip_every_frame(tmp_path, cylinder, cylinder_animation):
    folder = tmp_path / "seq"
    paths = write_obj_sequence(cylinder_animation, folder)
    frames = cylinder_animation.frames
    assert [p.name for p in paths] == [f"frame_{k:04d}.obj" for k in range(25)]
    assert sorted(folder.iterdir()) == paths
    for k in (0, 7, 24):
        back = read_obj(paths[k])
        np.testing.assert_allclose(back.vertices, frames[k], rtol=1e-8, atol=1e-9)
        # quads stay quads, UVs and the triangulation come back unchanged
        np.testing.assert_array_equal(back.polygon_offsets, cylinder.polygon_offsets)
        np.testing.assert_array_equal(back.polygon_indices, cylinder.polygon_indices)
        np.testing.assert_allclose(back.uv, cylinder.uv, atol=1e-15)
    text = paths[3].read_text()
    assert text.startswith("# skincap OBJ, units m, up y\n")
    assert text.count("\nv ") == cylinder.n_vertices and "\nvn " not in text


def test_second_reader_trimesh(tmp_path, cylinder_animation):
    paths = write_obj_sequence(cylinder_animation, tmp_path / "seq")
    tm = trimesh.load(paths[12], process=False)
    np.testing.assert_allclose(tm.vertices, cylinder_animation.frames[12], atol=1e-9)
    assert len(tm.faces) == cylinder_animation.rest.n_faces


def test_exact_digits_units_up_and_stem(tmp_path, cylinder, cylinder_animation):
    frames = cylinder_animation.frames
    paths = write_obj_sequence(cylinder_animation, tmp_path / "exact", digits=None, stem="bend")
    assert paths[0].name == "bend_0000.obj"
    np.testing.assert_array_equal(read_obj(paths[9]).vertices, frames[9])
    paths = write_obj_sequence(cylinder_animation, tmp_path / "zcm", units="cm", up="z")
    back = read_obj(paths[9], units="cm", up="z")
    np.testing.assert_allclose(back.vertices, frames[9], rtol=1e-8, atol=1e-10)
    # the rest mesh's own unit and axes are the default, as write_obj does
    rest = type(cylinder)(
        vertices=cylinder.vertices, faces=cylinder.faces, meta={"source_units": "mm", "up": "z"}
    )
    anim = MeshAnimation(rest, frames[:2], 24.0)
    paths = write_obj_sequence(anim, tmp_path / "mm")
    assert paths[0].read_text().startswith("# skincap OBJ, units mm, up z\n")
    np.testing.assert_allclose(
        read_obj(paths[1], units="mm", up="z").vertices, frames[1], atol=1e-9
    )


def test_folder_rules(tmp_path, cylinder, cylinder_animation):
    folder = tmp_path / "seq"
    folder.mkdir()
    (folder / "notes.txt").write_text("keep me")
    with pytest.raises(OutputExistsError):
        write_obj_sequence(cylinder_animation, folder)
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]
    write_obj_sequence(cylinder_animation, folder, force=True)
    assert len(list(folder.glob("frame_*.obj"))) == 25
    # a shorter take over a longer one: stale frames go, other files stay
    short = MeshAnimation(cylinder, cylinder_animation.frames[:5], 24.0)
    write_obj_sequence(short, folder, force=True)
    assert sorted(p.name for p in folder.iterdir()) == [f"frame_{k:04d}.obj" for k in range(5)] + [
        "notes.txt"
    ]
    # an empty folder is fine without force; a file or a missing parent is not
    empty = tmp_path / "empty"
    empty.mkdir()
    write_obj_sequence(short, empty)
    (tmp_path / "afile").write_text("x")
    with pytest.raises(FormatError, match="not a folder"):
        write_obj_sequence(short, tmp_path / "afile")
    with pytest.raises(FormatError, match="does not exist"):
        write_obj_sequence(short, tmp_path / "no" / "such")
    with pytest.raises(ValidationError, match="stem"):
        write_obj_sequence(short, tmp_path / "s", stem="../x")


def test_streaming_progress_and_bad_frames(tmp_path, cylinder, cylinder_animation):
    frames = cylinder_animation.frames
    calls = []
    anim = MeshAnimation(
        cylinder, (frames[s : s + 10] for s in range(0, 25, 10)), 24.0, n_frames=25
    )
    paths = write_obj_sequence(
        anim, tmp_path / "s", chunk=10, progress=lambda d, n: calls.append((d, n))
    )
    assert len(paths) == 25 and calls == [(10, 25), (20, 25), (25, 25)]
    np.testing.assert_allclose(read_obj(paths[24]).vertices, frames[24], atol=1e-9)
    bad = frames.copy()
    bad[4, 0, 0] = np.inf
    with pytest.raises(ValidationError, match="frame 4"):
        write_obj_sequence(MeshAnimation(cylinder, bad, 24.0), tmp_path / "bad", chunk=2)
    assert sorted(p.name for p in (tmp_path / "bad").iterdir()) == [
        f"frame_{k:04d}.obj" for k in range(4)
    ]  # chunks before the bad one were written whole; no temporary files
    too_long = MeshAnimation(cylinder, iter([frames, frames]), 24.0, n_frames=25)
    with pytest.raises(ValidationError, match="n_frames"):
        write_obj_sequence(too_long, tmp_path / "long")


def test_makehuman_quads_and_groups(tmp_path):
    mesh = read_makehuman(DATA / "makehuman_base.obj")
    frames = np.stack([mesh.vertices, mesh.vertices + [0.0, 0.1, 0.0]])
    paths = write_obj_sequence(MeshAnimation(mesh, frames, 30.0), tmp_path / "mh", units="m")
    back = read_obj(paths[1])
    assert back.n_vertices == 13380
    np.testing.assert_allclose(back.vertices, frames[1], atol=1e-8)
    np.testing.assert_array_equal(back.polygon_offsets, mesh.polygon_offsets)
    assert set(back.groups) == set(mesh.groups)


def test_paths_and_size_are_known_before_writing(tmp_path, cylinder, cylinder_animation):
    from skincap.io.obj_sequence import estimate_obj_sequence_bytes, obj_sequence_paths

    n = cylinder_animation.n_frames
    planned = obj_sequence_paths(tmp_path / "seq", n)
    estimate = estimate_obj_sequence_bytes(cylinder, n)
    written = write_obj_sequence(cylinder_animation, tmp_path / "seq")
    assert planned == written
    size = sum(p.stat().st_size for p in written)
    # the cylinder's base does not move and prints shorter than the estimate assumes
    assert size <= estimate <= 1.05 * size  # 239,225 said, 229,608 written
    # 10,000 frames take five digits, as the writer names them
    assert obj_sequence_paths("x", 10_001)[-1].name == "frame_10000.obj"
    assert obj_sequence_paths("x", 10_000)[-1].name == "frame_9999.obj"
