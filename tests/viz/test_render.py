"""The offscreen renderer: what is drawn where, occlusion, clips, and the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.viz.render import Camera, label_colours, render_image, write_picture
from skincap.viz.scene import MarkerLayer, MeshLayer, Scene, load_scene

DATA = Path(__file__).resolve().parents[1] / "data"
BACKGROUND = np.array([247, 247, 245])


def _marker_scene(positions, labels, invented=None, rate=100.0) -> Scene:
    positions = np.asarray(positions, dtype=float)
    if invented is None:
        invented = np.zeros(positions.shape[:2], dtype=bool)
    return Scene(
        [MarkerLayer("m", rate, None, positions=positions, labels=labels, invented=invented)]
    )


def _colour_near_centre(picture: np.ndarray) -> np.ndarray:
    h, w = picture.shape[:2]
    return picture[h // 2 - 1 : h // 2 + 2, w // 2 - 1 : w // 2 + 2].reshape(-1, 3).mean(axis=0)


def test_label_colours_are_stable_and_fragments_grey():
    a = label_colours(["LKNE", "RKNE", "*3"])
    b = label_colours(["RKNE", "LKNE"])
    np.testing.assert_array_equal(a[0], b[1])
    np.testing.assert_array_equal(a[1], b[0])
    np.testing.assert_allclose(a[2], [178 / 255] * 3)


def test_a_marker_is_drawn_in_its_label_colour_at_the_centre():
    # two markers straddling the centre keep the view from degenerating; the first one
    # is at the centre of the bounds, where the camera aims
    pos = np.array([[[0.0, 1.0, 0.0], [0.0, 0.5, 0.0], [0.0, 1.5, 0.0]]])
    scene = _marker_scene(pos, ["A", "B", "C"])
    picture = render_image(scene, 0.0, camera=Camera(follow=False), size=(200, 200), title=False)
    expected = label_colours(["A"])[0] * 255
    assert np.abs(_colour_near_centre(picture) - expected).max() < 30
    # invented samples are white
    scene = _marker_scene(pos, ["A", "B", "C"], invented=np.array([[True, False, False]]))
    picture = render_image(scene, 0.0, camera=Camera(follow=False), size=(200, 200), title=False)
    assert _colour_near_centre(picture).min() > 240


def test_a_mesh_in_front_hides_a_marker_behind_it():
    # the camera looks from +Z (azimuth 0, elevation 0): a square at z=+0.2 hides z=0
    square = np.array([[-0.3, 0.7, 0.2], [0.3, 0.7, 0.2], [0.3, 1.3, 0.2], [-0.3, 1.3, 0.2]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    markers = MarkerLayer(
        "m", 30.0, None, positions=np.array([[[0.0, 1.0, 0.0]]]), labels=["A"],
        invented=np.zeros((1, 1), bool),
    )  # fmt: skip
    wall = MeshLayer("wall", 30.0, None, faces=faces, frames=square[None].astype(np.float32))
    camera = Camera(azimuth=0.0, elevation=0.0, follow=False)
    hidden = render_image(Scene([markers, wall]), 0.0, camera=camera, size=(200, 200), title=False)
    marker_rgb = label_colours(["A"])[0] * 255
    centre = _colour_near_centre(hidden)
    assert np.abs(centre - marker_rgb).max() > 40  # skin-coloured, not the marker
    behind = square + [0.0, 0.0, -0.4]
    wall_behind = MeshLayer("wall", 30.0, None, faces=faces, frames=behind[None].astype(np.float32))
    shown = render_image(
        Scene([markers, wall_behind]), 0.0, camera=camera, size=(200, 200), title=False
    )
    assert np.abs(_colour_near_centre(shown) - marker_rgb).max() < 30


def test_real_capture_png_and_gif(tmp_path):
    scene = load_scene([DATA / "kt_optitrack_walking.c3d"])
    png = write_picture(scene, tmp_path / "walk.png", time=5.0, size=(320, 240))
    from PIL import Image

    picture = np.asarray(Image.open(png).convert("RGB"))
    assert picture.shape == (240, 320, 3)
    coloured = (np.abs(picture.astype(int) - BACKGROUND).sum(axis=2) > 120).sum()
    assert coloured > 50  # the markers are on the picture
    gif = write_picture(scene, tmp_path / "walk.gif", start=1.0, end=2.0, fps=5, size=(160, 120))
    with Image.open(gif) as im:
        assert im.n_frames == 6
        frames = []
        for k in (0, 5):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB")).astype(int))
    assert np.abs(frames[0] - frames[1]).sum() > 0  # the subject moved


def test_mp4_has_the_frames(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="needs skincap[video]")
    moving = np.zeros((20, 2, 3))
    moving[:, 0] = np.stack([np.linspace(0, 1, 20), np.ones(20), np.zeros(20)], axis=1)
    moving[:, 1] = [0.0, 0.0, 0.0]
    scene = _marker_scene(moving, ["A", "B"], rate=10.0)
    mp4 = write_picture(scene, tmp_path / "clip.mp4", fps=10, size=(64, 48))
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    n = sum(1 for _ in reader)
    assert meta["size"] == (64, 48) and n == 20


def test_cli_render_and_its_errors(tmp_path):
    runner = CliRunner()
    c3d = DATA / "kt_optitrack_walking.c3d"
    out = tmp_path / "frame.png"
    result = runner.invoke(
        app, ["render", str(c3d), "-o", str(out), "--frame", "10", "--size", "160x120"]
    )
    assert result.exit_code == 0, result.output
    assert out.is_file()
    again = runner.invoke(app, ["render", str(c3d), "-o", str(out)])
    assert again.exit_code == 2 and "exists" in again.output
    bad = runner.invoke(app, ["render", str(c3d), "-o", str(tmp_path / "x.jpg")])
    assert bad.exit_code == 2 and "x.jpg" in bad.output
    assert not (tmp_path / "x.jpg").exists()
    size = runner.invoke(app, ["render", str(c3d), "-o", str(tmp_path / "y.png"), "--size", "big"])
    assert size.exit_code == 2 and "--size" in size.output
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(b"")
    broken = runner.invoke(app, ["render", str(empty), "-o", str(tmp_path / "z.png")])
    assert broken.exit_code == 2 and "empty.c3d" in broken.output
    assert not (tmp_path / "z.png").exists()
