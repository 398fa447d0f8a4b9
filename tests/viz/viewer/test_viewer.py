"""The browser viewer: colours, the playback clock, the scene nodes per layer kind (a
viser server without a browser), the ``skincap view`` command, and the page itself in
headless Chromium (screenshots at two frames, saved as test artefacts)."""

from __future__ import annotations

import colorsys
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner
from viewer_scenes import DATA, GAP_COLUMNS, blob_mesh, full_scene, raw_and_cleaned, rope_curve

from skincap.errors import ValidationError
from skincap.viz.colours import INVENTED_COLOUR, file_tint, hsv_to_rgb, label_colours
from skincap.viz.scene import Scene
from skincap.viz.viewer.server import camera_framing, default_point_size
from skincap.viz.viewer.timeline import PlaybackClock, parse_speed, speed_label

pytest.importorskip("viser", reason="the viewer needs viser (pip install 'skincap[view]')")

from skincap.viz.viewer import serve_scene  # noqa: E402

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    # software WebGL (SwiftShader through ANGLE): a real three.js canvas, no GPU
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]


# ------------------------------------------------------------------------ colours
def test_label_colours_are_stable_per_label_across_files_and_orders() -> None:
    labels = ["LASI", "RASI", "LPSI", "RPSI", "LKNE", "RKNE"]
    a = label_colours(labels)
    b = label_colours(labels[::-1])[::-1]
    assert a.shape == (6, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    # a subject prefix does not change the colour (Vicon names against plain ones)
    np.testing.assert_array_equal(label_colours(["Alice:LASI", " LASI "]), a[[0, 0]])
    # fixed across sessions: CRC-32, not the salted built-in hash
    np.testing.assert_array_equal(label_colours(["LASI"]), label_colours(["LASI"]))
    code = subprocess.run(
        [sys.executable, "-c", "from skincap.viz.colours import label_colours as c;"
         "print(c(['LASI']).tolist())"],
        capture_output=True, text=True, check=True, env={**os.environ, "PYTHONHASHSEED": "7"},
    )  # fmt: skip
    assert code.stdout.strip() == str(a[:1].tolist())


def test_label_colours_are_saturated_and_mostly_distinct() -> None:
    labels = [f"M{i:03d}" for i in range(60)]
    rgb = label_colours(labels).astype(np.float64) / 255.0
    sat = np.array([colorsys.rgb_to_hsv(*c)[1] for c in rgb])
    assert sat.min() >= 0.55  # never the grey of invented samples
    assert len({tuple(c) for c in label_colours(labels)}) == 60
    r, g, b = INVENTED_COLOUR.astype(float) / 255
    assert colorsys.rgb_to_hsv(r, g, b)[1] < 0.05
    assert label_colours([]).shape == (0, 3)


def test_hsv_to_rgb_matches_colorsys() -> None:
    rng = np.random.default_rng(0)
    hsv = rng.uniform(size=(200, 3))
    expected = np.array([colorsys.hsv_to_rgb(*c) for c in hsv]) * 255
    np.testing.assert_allclose(hsv_to_rgb(hsv), expected, atol=0.51)


def test_file_tints_differ_and_cycle() -> None:
    tints = np.array([file_tint(i) for i in range(8)])
    assert len({tuple(t) for t in tints}) == 8
    np.testing.assert_array_equal(file_tint(8), file_tint(0))


# -------------------------------------------------------------------------- clock
def test_playback_clock_runs_in_real_time_and_loops() -> None:
    clock = PlaybackClock(160.0, 1000)
    clock.anchor(10, wall=100.0)
    assert clock.frame_at(100.0) == 10
    assert clock.frame_at(101.0) == 170  # one second = 160 frames
    assert clock.frame_at(99.0) == 10  # never before the anchor
    assert clock.frame_at(100.0 + 1000 / 160) == 10  # wraps after the whole take
    clock.set_speed(0.5, wall=101.0)  # no jump when the speed changes
    assert clock.frame_at(101.0) == 170
    assert clock.frame_at(102.0) == 250
    assert 0 < clock.seconds_until_next(102.0) <= 1 / 80 + 1e-9


def test_playback_clock_and_speed_validation() -> None:
    with pytest.raises(ValidationError, match="rate"):
        PlaybackClock(0.0, 10)
    with pytest.raises(ValidationError, match="n_frames"):
        PlaybackClock(30.0, 0)
    assert parse_speed(speed_label(0.25)) == 0.25
    assert speed_label(1.0) == "1x"
    for bad in ("fast", "0x", "-1x", "nanx"):
        with pytest.raises(ValidationError, match="speed"):
            parse_speed(bad)


# ------------------------------------------------------------------------ framing
def test_camera_framing_sees_the_whole_box_from_above() -> None:
    bounds = np.array([[-4.0, 0.0, -0.5], [4.0, 1.8, 0.5]])  # a walk along x
    position, look_at = camera_framing(bounds, fov_radians=np.radians(50))
    centre = np.array([0.0, 0.9, 0.0])
    assert look_at[1] == pytest.approx(0.9)
    view = position - look_at
    assert view[1] > 0  # above the horizon
    assert abs(view[2]) > abs(view[0])  # from the side of a walk along x
    # the box centre lies left of the page centre, clear of the GUI panel on the right
    forward = -view / np.linalg.norm(view)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    assert np.dot(centre - position, right) < 0
    assert np.linalg.norm(np.cross(centre - position, forward)) < np.linalg.norm(view)
    radius = 0.5 * np.linalg.norm(bounds[1] - bounds[0])
    assert np.linalg.norm(view) > radius  # outside the box
    assert default_point_size(bounds) == pytest.approx(0.006 * 2 * radius)
    assert default_point_size(np.array([[0, 0, 0], [0.01, 0.01, 0.01]])) == 0.004
    position, look_at = camera_framing(np.full((2, 3), np.nan))
    assert np.isfinite(position).all() and np.isfinite(look_at).all()


# ------------------------------------------------------------ server, no browser
@pytest.fixture(scope="module")
def scene() -> Scene:
    return full_scene()


@pytest.fixture(scope="module")
def viewer(scene: Scene) -> Iterator[object]:
    handle = serve_scene(scene, port=0, play=False)
    yield handle
    handle.stop()


def test_every_layer_kind_adds_nodes_with_the_frame_data(viewer, scene: Scene) -> None:  # type: ignore[no-untyped-def]
    assert {layer.kind for layer in scene.layers} == {
        "markers", "points", "skeleton", "mesh", "curve"
    }  # fmt: skip
    viewer.frame = 200
    t = scene.time_of(200)
    for layer in scene.layers:
        drawer = viewer.drawers[layer.name]
        f = scene.layer_frame(layer, t)
        assert drawer.shown_frame == f
        assert drawer.children, layer.name
        for child in drawer.children.values():
            assert child.name.startswith(drawer.node + "/")
        if layer.kind == "markers":
            pos = layer.positions[f]
            present = ~np.isnan(pos[:, 0])
            inv = layer.invented[f]
            np.testing.assert_allclose(
                drawer.measured.points, pos[present & ~inv].astype(np.float32)
            )
            np.testing.assert_array_equal(
                drawer.measured.colors, label_colours(layer.labels)[present & ~inv]
            )
            if (present & inv).any():
                assert drawer.invented.visible
                np.testing.assert_allclose(drawer.invented.points, pos[inv].astype(np.float32))
                assert (drawer.invented.colors == INVENTED_COLOUR).all()
                assert drawer.invented.point_size > drawer.measured.point_size
            else:
                assert not drawer.invented.visible  # nothing invented: nothing drawn
        elif layer.kind == "points":
            np.testing.assert_allclose(drawer.points.points, layer.cloud.frame(f), atol=1e-6)
        elif layer.kind == "skeleton":
            joints = layer.joints[f]
            child = np.flatnonzero(layer.parents >= 0)
            np.testing.assert_allclose(
                drawer.bones.points[:, 0], joints[layer.parents[child]], atol=1e-6
            )
            np.testing.assert_allclose(drawer.bones.points[:, 1], joints[child], atol=1e-6)
        elif layer.kind == "mesh":
            np.testing.assert_allclose(drawer.mesh.vertices, layer.frames[f], atol=1e-6)
            np.testing.assert_array_equal(drawer.mesh.faces, layer.faces)
        elif layer.kind == "curve":
            finite = np.isfinite(layer.curves[f]).all(axis=1)
            # a NaN point removes its two segments
            k = layer.curves.shape[1]
            assert drawer.line.points.shape == (k - 1 - 2 * int((~finite).sum()), 2, 3)


def test_cleaned_gap_is_drawn_as_invented_and_raw_gap_is_missing(viewer) -> None:  # type: ignore[no-untyped-def]
    viewer.frame = 500  # inside the synthetic gap
    raw, cleaned = viewer.drawers["raw.c3d"], viewer.drawers["cleaned.c3d"]
    n_raw = raw.measured.points.shape[0]
    n_inv = cleaned.invented.points.shape[0]
    assert n_inv == len(GAP_COLUMNS)
    assert cleaned.measured.points.shape[0] == n_raw  # the measured ones are the same
    assert not raw.invented.visible
    viewer.frame = 2000  # after the gap: nothing invented
    assert not cleaned.invented.visible
    assert cleaned.measured.points.shape[0] == raw.measured.points.shape[0]


def test_frame_maps_to_each_layers_nearest_frame_and_clips(viewer, scene: Scene) -> None:  # type: ignore[no-untyped-def]
    last = scene.n_frames - 1
    viewer.frame = last
    for layer in scene.layers:
        assert viewer.drawers[layer.name].shown_frame == layer.n_frames - 1
    viewer.frame = 16  # 0.1 s at 160 Hz
    assert viewer.drawers["blob.obj"].shown_frame == 6  # 60 Hz
    assert viewer.drawers["cmu_131_01_bvh11.bvh"].shown_frame == 12  # 120 Hz
    assert viewer.frame_slider.value == 16
    assert viewer.time_text.value.startswith("0.100 s")
    for bad in (-1, scene.n_frames):
        with pytest.raises(ValidationError, match="frame"):
            viewer.frame = bad
    viewer.step_buttons.value = "+10"  # the step buttons move and wrap
    assert viewer.frame == 26
    viewer.frame = 3
    viewer.step_buttons.value = "-10"
    assert viewer.frame == scene.n_frames - 7


def test_missing_viser_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    from skincap.errors import MissingDependencyError

    monkeypatch.setitem(sys.modules, "viser", None)  # import viser -> ImportError
    with pytest.raises(MissingDependencyError, match=r"skincap\[view\]"):
        serve_scene(Scene([rope_curve()]), port=0)


def test_hidden_layers_are_not_updated_until_shown(viewer) -> None:  # type: ignore[no-untyped-def]
    viewer.frame = 100
    viewer.set_visible("blob.obj", False)
    assert not viewer.file_nodes["blob.obj"].visible
    assert viewer.file_boxes["blob.obj"].value is False
    viewer.frame = 130
    mesh = viewer.drawers["blob.obj"]
    assert mesh.shown_frame == round(100 / 160 * 60)  # not sent while hidden
    viewer.set_visible("blob.obj", True)
    assert mesh.shown_frame == round(130 / 160 * 60)
    with pytest.raises(ValidationError, match="nope"):
        viewer.set_visible("nope", True)


def test_tint_markers_per_file_and_point_size(viewer) -> None:  # type: ignore[no-untyped-def]
    viewer.frame = 50
    viewer.set_tint_markers(True)
    assert viewer.tint_box.value is True
    raw, cleaned = viewer.drawers["raw.c3d"], viewer.drawers["cleaned.c3d"]
    assert (raw.measured.colors == file_tint(0)).all()
    assert (cleaned.measured.colors == file_tint(1)).all()
    viewer.set_tint_markers(False)
    np.testing.assert_array_equal(
        raw.measured.colors,
        label_colours(raw.layer.labels)[~np.isnan(raw.layer.positions[50, :, 0])],
    )
    viewer.size_slider.value = 20  # the GUI slider is in millimetres
    assert raw.measured.point_size == pytest.approx(0.020)
    assert viewer.drawers["points.csv"].points.point_size == pytest.approx(0.020)
    with pytest.raises(ValidationError, match="size"):
        viewer.set_point_size(0.0)


def test_playback_advances_in_real_time(viewer, scene: Scene) -> None:  # type: ignore[no-untyped-def]
    viewer.frame = 0
    viewer.set_speed(1.0)
    start = time.monotonic()
    viewer.play()
    assert viewer.playing and viewer.play_button.label == "Pause"
    time.sleep(0.5)
    viewer.pause()
    elapsed = time.monotonic() - start
    # frames shown = elapsed * rate, less at most one update interval and scheduling slack
    assert scene.rate * (elapsed - 0.25) <= viewer.frame <= scene.rate * elapsed + 1
    stopped = viewer.frame
    time.sleep(0.1)
    assert viewer.frame == stopped and viewer.play_button.label == "Play"
    viewer.speed_dropdown.value = "0.5x"
    assert viewer.speed == 0.5
    viewer.set_speed(1.0)


def test_scrubbing_the_slider_pauses_playback(viewer) -> None:  # type: ignore[no-untyped-def]
    # a drag from the page arrives as a slider update with a client; playback must stop,
    # or the playback thread would pull the handle back from under the user's drag
    viewer.frame = 0
    viewer.play()
    drag = SimpleNamespace(target=SimpleNamespace(value=7), client=object())
    viewer._on_slider(drag)
    assert not viewer.playing and viewer.play_button.label == "Play"
    assert viewer.frame == 7
    time.sleep(0.2)
    assert viewer.frame == 7


def test_scene_with_one_static_mesh_and_bad_arguments() -> None:
    mesh = blob_mesh(n_frames=1)
    with serve_scene(Scene([mesh]), port=0) as handle:
        assert handle.frame == 0 and not handle.playing  # nothing to play
        assert handle.frame_slider.disabled
        np.testing.assert_allclose(handle.drawers["blob.obj"].mesh.vertices, mesh.frames[0])
    with pytest.raises(ValidationError, match="no layers"):
        serve_scene(Scene([]), port=0)
    with pytest.raises(ValidationError, match="frame"):
        serve_scene(Scene([rope_curve()]), port=0, frame=240)


def test_layers_of_one_file_share_a_file_toggle() -> None:
    raw, _ = raw_and_cleaned()
    mesh = blob_mesh()
    mesh.name, mesh.source = "take.glb:mesh", Path("take.glb")
    curve = rope_curve()
    curve.name, curve.source = "take.glb:skeleton", Path("take.glb")
    with serve_scene(Scene([raw, mesh, curve]), port=0, play=False) as handle:
        assert sorted(handle.file_nodes) == ["raw.c3d", "take.glb"]
        assert sorted(handle.layer_boxes) == ["take.glb:mesh", "take.glb:skeleton"]
        assert handle.drawers["take.glb:mesh"].node == "/take.glb/mesh"
        handle.set_visible("take.glb:mesh", False)
        assert not handle.drawers["take.glb:mesh"].visible
        assert handle.layer_boxes["take.glb:mesh"].value is False
        assert handle.drawers["take.glb:skeleton"].visible


# --------------------------------------------------------------------------- CLI
def _cli(*args: object):  # type: ignore[no-untyped-def]
    import skincap.cli.view  # noqa: F401  (registers 'view' until cli.py imports it)
    from skincap.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_cli_view_bad_inputs_exit_2_with_one_line(tmp_path: Path) -> None:
    result = _cli("view", tmp_path / "missing.c3d", "--no-browser")
    assert result.exit_code == 2
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("skincap: error: ")
    assert "missing.c3d" in lines[0]
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x02\x50garbage")
    result = _cli("view", bad, "--no-browser")
    assert result.exit_code == 2 and "bad.c3d" in result.output
    result = _cli("view", DATA / "kt_optitrack_walking.c3d", "--frame", "999999", "--no-browser")
    assert result.exit_code == 2 and "--frame" in result.output
    result = _cli("view", "--help")
    assert result.exit_code == 0 and "Example: skincap view" in result.output


@pytest.mark.parametrize("host", ["999.1.1.1", "192.0.2.1", "a" * 300])
def test_cli_view_refuses_a_host_it_cannot_listen_on(tmp_path: Path, host: str) -> None:
    # an unknown name, an address not on this machine, a name IDNA refuses: the server
    # thread died on them with a traceback and the command waited forever; checked
    # before the files are read (here a missing one, so the old code fails, not hangs)
    result = _cli("view", tmp_path / "missing.c3d", "--no-browser", "--host", host)
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--host: cannot listen on" in lines[0], result.output


@pytest.mark.slow  # a fresh Python importing the viewer: 21 s on CI
def test_cli_view_serves_until_interrupted() -> None:
    # a shell's background job (CI run with ``&``) inherits SIGINT ignored: give the child
    # Python's handler, as an interactive Ctrl-C has
    code = "import signal; signal.signal(signal.SIGINT, signal.default_int_handler); from skincap.cli import main; main()"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "view", str(DATA / "kt_optitrack_walking.c3d"),
         "--no-browser", "--port", "0", "--frame", "10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("skincap view: http://127.0.0.1:"), line
        url = line.split(": ", 1)[1].strip()
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
        assert "viser" not in proc.stdout.read()  # viser's own banner is swallowed
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# ----------------------------------------------------------- headless Chromium
def _artefact_dir() -> Path:
    env = os.environ.get("SKINCAP_ARTIFACTS")
    folder = Path(env) if env else Path(__file__).resolve().parents[2] / "artifacts"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _scene_pixels(png: bytes, panel_left: float) -> np.ndarray:
    """(H, W', 3) uint8: the 3D view of a page screenshot, left of the GUI panel and
    without the axes gizmo in the bottom-left corner."""
    import io

    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    view = img[:, : int(panel_left) - 10].copy()
    view[-90:, :90] = view[0, 0]  # the orientation gizmo is not the scene
    return view


def _wait_stable(page, panel_left: float, timeout: float = 30.0) -> bytes:  # type: ignore[no-untyped-def]
    """A screenshot taken once two in a row agree (the client has drawn the frame)."""
    last = page.screenshot()
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        time.sleep(0.4)
        shot = page.screenshot()
        a, b = _scene_pixels(shot, panel_left), _scene_pixels(last, panel_left)
        if a.shape == b.shape and np.array_equal(a, b):
            return shot
        last = shot
    raise AssertionError("the page kept changing for 30 s")


def _saturated(view: np.ndarray) -> int:
    """Pixels with a clear colour (markers, skeleton, rope, mesh), not the grey grid."""
    v = view.astype(np.float64)
    spread = v.max(axis=-1) - v.min(axis=-1)
    return int((spread > 60).sum())


@pytest.mark.slow
def test_viewer_in_headless_chromium(tmp_path: Path) -> None:
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install playwright)")
    if not CHROMIUM.exists():
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    pytest.importorskip("PIL", reason="Pillow decodes the screenshots")

    frame_a, frame_b = 200, 2400
    handle = serve_scene(full_scene(), port=0, play=False, frame=frame_a)
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(handle.url)
                page.wait_for_selector("canvas", timeout=30_000)
                deadline = time.monotonic() + 30
                while handle.client_count() < 1 and time.monotonic() < deadline:
                    time.sleep(0.1)
                assert handle.client_count() == 1, "the page never connected"
                page.get_by_text("Timeline").wait_for(timeout=30_000)
                # the "software WebGL" notice covers the scene; close it as a user would
                for close in page.locator(".mantine-Notification-closeButton").all():
                    close.click()
                panel_left = page.get_by_text("Timeline").bounding_box()["x"] - 20
                shot_a = _wait_stable(page, panel_left)

                # second frame through the GUI: type it into the frame slider's box
                frame_box = page.locator(
                    "xpath=//label[text()='Frame']/ancestor::div[contains(@class,"
                    "'mantine-Flex-root')][1]//input[contains(@class,'NumberInput-input')]"
                )
                frame_box.fill(str(frame_b))
                frame_box.press("Enter")
                deadline = time.monotonic() + 15
                while handle.frame != frame_b and time.monotonic() < deadline:
                    time.sleep(0.1)
                assert handle.frame == frame_b, "the GUI slider did not reach the server"
                shot_b = _wait_stable(page, panel_left)

                # the play button plays and pauses
                page.get_by_role("button", name="Play").click()
                deadline = time.monotonic() + 10
                while not handle.playing and time.monotonic() < deadline:
                    time.sleep(0.1)
                assert handle.playing
                handle.pause()
            finally:
                browser.close()
    finally:
        handle.stop()

    folder = _artefact_dir()
    for name, shot in (
        (f"viewer_frame{frame_a:04d}.png", shot_a),
        (f"viewer_frame{frame_b:04d}.png", shot_b),
    ):
        (tmp_path / name).write_bytes(shot)
        shutil.copyfile(tmp_path / name, folder / name)

    view_a, view_b = _scene_pixels(shot_a, panel_left), _scene_pixels(shot_b, panel_left)
    background = view_a[5, view_a.shape[1] // 2]
    for view in (view_a, view_b):
        not_background = np.abs(view.astype(int) - background).max(axis=-1) > 20
        assert not_background.mean() > 0.05, "the canvas is (nearly) blank"
        assert view.std() > 10
        assert _saturated(view) > 1500, "no coloured geometry (markers, skeleton, mesh, rope)"
    changed = np.abs(view_a.astype(int) - view_b.astype(int)).max(axis=-1) > 40
    assert changed.sum() > 2000, "frames 200 and 2400 look the same"
