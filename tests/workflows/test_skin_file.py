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


ONE_JOINT = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  End Site
  {
    OFFSET 0 170 0
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 85 0 0 0 0
0 86 0 0 10 0
"""


def _box(height: float) -> str:
    """A closed box ``height`` units tall standing on y = 0, as OBJ text."""
    v = [(x, y, z) for x in (-0.12, 0.12) for y in (0.0, height) for z in (-0.06, 0.06)]
    v = [(x * height, y, z * height) for x, y, z in v]
    f = [(1, 2, 4), (1, 4, 3), (5, 7, 8), (5, 8, 6), (1, 5, 6), (1, 6, 2),
         (3, 4, 8), (3, 8, 7), (1, 3, 7), (1, 7, 5), (2, 6, 8), (2, 8, 4)]  # fmt: skip
    return "".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(
        f"f {a} {b} {c}\n" for a, b, c in f
    )


def test_a_bare_mesh_in_another_unit_is_a_warning_naming_the_unit(tmp_path):
    """MakeHuman's OBJ without its rig is in decimetres: read as metres it is a 17 m
    body, skinned without a word before; now a warning names --mesh-units dm."""
    import warnings

    from skincap.errors import UnitWarning

    motion = tmp_path / "one.bvh"
    motion.write_text(ONE_JOINT)
    mesh = tmp_path / "body.obj"
    mesh.write_text(_box(17.0))
    with pytest.warns(
        UnitWarning, match=r"body\.obj: the mesh is 17 m tall.*--mesh-units dm.*1\.70 m"
    ):
        out = skin_file(mesh, motion, tmp_path / "a.pc2", units="cm")
    assert out["height_m"] == pytest.approx(17.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        out = skin_file(mesh, motion, tmp_path / "b.pc2", units="cm", mesh_units="dm")
        assert out["height_m"] == pytest.approx(1.7)
        mesh.write_text(_box(1.7))  # a body in metres: no warning
        skin_file(mesh, motion, tmp_path / "c.pc2", units="cm", force=True)


def test_a_mesh_without_faces_is_refused_before_anything_is_written(tmp_path):
    """Bone heat on vertices alone used to bind each to its nearest bone and write a
    "skinned" point cloud; now one line names the mesh."""
    points = tmp_path / "points.obj"
    points.write_text("".join(line + "\n" for line in _box(1.7).splitlines() if line[0] == "v"))
    motion = tmp_path / "one.bvh"
    motion.write_text(ONE_JOINT)
    with pytest.raises(FormatError, match=r"points\.obj.*no faces"):
        skin_file(points, motion, tmp_path / "out.pc2", units="cm")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.bvh", "points.obj"]
