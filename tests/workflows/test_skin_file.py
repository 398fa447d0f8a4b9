"""skin_file refuses a motion it cannot animate before writing anything."""

from __future__ import annotations

from pathlib import Path

import pytest

from skincap.errors import FormatError
from skincap.workflows.skin_file import skin_file

BVH = Path(__file__).parents[1] / "data" / "cmu_131_01_bvh11.bvh"


@pytest.mark.parametrize("output", ["out.pc2", "out.glb", "out.usda", "frames"])
def test_bvh_without_frames_is_refused_for_every_output(tmp_path, output):
    lines = BVH.read_text().splitlines()
    at = lines.index("MOTION")
    still = tmp_path / "still.bvh"
    still.write_text("\n".join([*lines[: at + 1], "Frames: 0", lines[at + 2]]) + "\n")
    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 0.1 1.5 0\nv 0.2 0 0.1\nf 1 2 3\n")
    with pytest.raises(FormatError, match=r"still\.bvh.*no motion frames"):
        skin_file(mesh, still, tmp_path / output, units="cmu")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["still.bvh", "tri.obj"]
