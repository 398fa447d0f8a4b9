"""No command overwrites its input: every case of issue 12 item 3, as a user runs it.

Each refusal is exit status 2 with one ``skincap: error:`` line, and nothing is written.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from skincap.cli import app

DATA = Path(__file__).parents[1] / "data"


def run(*args):  # type: ignore[no-untyped-def]
    return CliRunner().invoke(app, [str(a) for a in args])


def _refused(result, *words: str) -> None:  # type: ignore[no-untyped-def]
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())
    assert text.startswith("skincap: error:"), text
    for word in words:
        assert word in text, text


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    path = tmp_path / "in.c3d"
    shutil.copy(DATA / "kt_optitrack_walking.c3d", path)
    return path


@pytest.fixture
def bare_mesh(tmp_path: Path) -> Path:
    path = tmp_path / "body.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    return path


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


def test_clean_report_onto_its_input_is_refused(capture, tmp_path):
    before = _listing(tmp_path)
    result = run("clean", capture, "-o", tmp_path / "c.c3d", "--report", capture, "--force")
    _refused(result, "in.c3d", "inputs are never modified")
    assert _listing(tmp_path) == before  # input intact, no c.c3d, no .part


def test_clean_report_and_output_the_same_file_is_refused(capture, tmp_path):
    out = tmp_path / "c.c3d"
    result = run("clean", capture, "-o", out, "--report", out, "--force")
    _refused(result, "is also the output")
    assert not out.exists()


def test_skin_rest_mesh_beside_the_cache_cannot_replace_the_input_mesh(bare_mesh, tmp_path):
    before = _listing(tmp_path)
    bvh = DATA / "makehuman_tpose.bvh"
    result = run("skin", bare_mesh, bvh, "-o", tmp_path / "body.pc2", "--force")
    _refused(result, "body.obj", "inputs are never modified")
    assert _listing(tmp_path) == before  # neither body.pc2 nor a new body.obj


def test_skin_refusal_for_an_existing_cache_leaves_no_rest_mesh(bare_mesh, tmp_path):
    (tmp_path / "sk.pc2").write_bytes(b"earlier run")
    bvh = DATA / "makehuman_tpose.bvh"
    result = run("skin", bare_mesh, bvh, "-o", tmp_path / "sk.pc2")
    _refused(result, "sk.pc2", "exists")
    assert not (tmp_path / "sk.obj").exists()
    assert (tmp_path / "sk.pc2").read_bytes() == b"earlier run"


def test_skin_rig_files_beside_a_makehuman_body_are_inputs(tmp_path):
    for name in ("makehuman_base.obj", "makehuman_default.mhskel", "makehuman_default_weights.mhw"):
        shutil.copy(DATA / name, tmp_path / name)
    rig = tmp_path / "makehuman_default.mhskel"
    before = rig.read_bytes()
    out = tmp_path / "makehuman_default.usd"
    os.link(rig, out)  # the output is the rig file under another name
    result = run("skin", tmp_path / "makehuman_base.obj", DATA / "makehuman_tpose.bvh",
                 "-o", out, "--force")  # fmt: skip
    _refused(result, "hard link", "makehuman_default.mhskel")
    assert rig.read_bytes() == before


@pytest.mark.parametrize("link", ["symbolic", "hard"])
def test_convert_onto_a_link_to_its_input_is_refused(capture, tmp_path, link):
    before = capture.read_bytes()
    alias = tmp_path / "alias.c3d"
    if link == "symbolic":
        alias.symlink_to(capture)
    else:
        os.link(capture, alias)
    result = run("convert", capture, alias, "--force")
    _refused(result, f"{link} link to the input")
    assert capture.read_bytes() == before and alias.read_bytes() == before


def test_convert_onto_a_dangling_link_is_refused(capture, tmp_path):
    link = tmp_path / "out.trc"
    link.symlink_to(tmp_path / "gone" / "out.trc")
    result = run("convert", capture, link, "--force")
    _refused(result, "symbolic link to a missing file")
    assert link.is_symlink() and not link.exists()
    assert not (tmp_path / "gone").exists()


def test_track_output_folder_holding_its_input_is_refused(tmp_path):
    from skincap.io.csv import write_points_csv
    from skincap.types import PointCloud

    points = tmp_path / "points.csv"
    write_points_csv(PointCloud.from_markerset(_tiny_markers()), points)
    out = tmp_path / "out"
    out.mkdir()
    os.link(points, out / "body_points.csv")  # the output folder holds the input
    result = run("track", points, "--rope", "auto", "-o", out, "--force")
    _refused(result, "body_points.csv", "hard link to the input")
    assert sorted(p.name for p in out.iterdir()) == ["body_points.csv"]


def test_render_onto_its_input_is_refused(capture, tmp_path):
    link = tmp_path / "frame.png"
    link.symlink_to(capture)
    result = run("render", capture, "-o", link, "--force")
    _refused(result, "symbolic link to the input")


def _tiny_markers():  # type: ignore[no-untyped-def]
    import numpy as np

    from skincap.types import MarkerSet

    pos = np.random.default_rng(0).normal(size=(5, 4, 3))
    return MarkerSet(pos, [f"*{i}" for i in range(4)], 100.0)


# ---------------------------------------------------------------- signals mid-write
_INTERRUPTED_CONVERT = """
import os, signal, sys
import skincap.io._common as common
from skincap.cli import main

real_replace = os.replace
which = getattr(signal, sys.argv[1])
# a shell's background job inherits SIGINT ignored, and Python then never raises
# KeyboardInterrupt: give this child the handler an interactive run has
signal.signal(signal.SIGINT, signal.default_int_handler)

def replace_after_signal(src, dst):
    # the whole file is in the .part; the signal arrives before it is renamed
    os.kill(os.getpid(), which)
    real_replace(src, dst)

common.os.replace = replace_after_signal
sys.argv = ["skincap", "convert", sys.argv[2], sys.argv[3]]
main()
"""


@pytest.mark.parametrize(("name", "status"), [("SIGTERM", 143), ("SIGHUP", 129), ("SIGINT", 130)])
def test_signal_during_a_write_leaves_no_part_file(capture, tmp_path, name, status):
    if not hasattr(signal, name):
        pytest.skip(f"no {name} here")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run(
        [sys.executable, "-c", _INTERRUPTED_CONVERT, name, str(capture), str(out_dir / "x.trc")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == status, done.stderr
    assert list(out_dir.iterdir()) == []  # neither x.trc nor .x.trc.*.part


# ------------------------------------------------------------------ item 7 basics
def test_version():
    from importlib.metadata import version

    result = run("--version")
    assert result.exit_code == 0
    assert result.stdout.strip() == f"skincap {version('skincap')}"


def test_convert_json(capture, tmp_path):
    out = tmp_path / "walk.trc"
    result = run("convert", capture, out, "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    from skincap import io

    assert summary == {
        "input": str(capture),
        "output": str(out),
        "frames": io.read(out).n_frames,
    }
    assert summary["frames"] == io.read(capture).n_frames
