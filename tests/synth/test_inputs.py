"""build_motion's BVH branch checks frames/seconds as the built-in clips do."""

from __future__ import annotations

from pathlib import Path

import pytest

from skincap.errors import FormatError, ValidationError
from skincap.synth.inputs import build_body, build_motion

BVH = Path(__file__).parents[1] / "data" / "cmu_131_01_bvh11.bvh"


@pytest.fixture(scope="module")
def body():
    return build_body("procedural", n_vertices=2000)


@pytest.mark.parametrize(
    ("frames", "seconds", "match"),
    [
        (0, None, "frames: expected a positive integer, got 0"),
        (-3, None, "frames: expected a positive integer, got -3"),
        (2.5, None, "frames: expected a positive integer"),
        (None, -1.0, "seconds"),
        (None, float("nan"), "seconds"),
        (5, 1.0, "frames and seconds: give one or neither"),
    ],
)
def test_bvh_motion_refuses_bad_frames_or_seconds(body, frames, seconds, match):
    with pytest.raises(ValidationError, match=match):
        build_motion(body, str(BVH), units="cmu", frames=frames, seconds=seconds)


def test_bvh_motion_cut_to_frames_or_seconds(body):
    full = build_motion(body, str(BVH), units="cmu")
    assert build_motion(body, str(BVH), units="cmu", frames=7).n_frames == 7
    cut = build_motion(body, str(BVH), units="cmu", seconds=5 / full.rate)
    assert cut.n_frames == 5
    # more than the file holds: the whole file, as before
    assert build_motion(body, str(BVH), units="cmu", frames=10**6).n_frames == full.n_frames


def test_bvh_motion_without_frames_is_refused(body, tmp_path):
    # the header and the first line of MOTION kept, 'Frames: 0' and no rows
    lines = BVH.read_text().splitlines()
    at = lines.index("MOTION")
    empty = tmp_path / "empty_motion.bvh"
    empty.write_text("\n".join([*lines[: at + 1], "Frames: 0", lines[at + 2]]) + "\n")
    with pytest.raises(FormatError, match=r"empty_motion\.bvh.*no motion frames"):
        build_motion(body, str(empty), units="cmu")
