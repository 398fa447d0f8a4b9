"""``skincap demo``: the chain that exists so far, run on real data skincap ships.

It reads a real OptiTrack C3D and a real BVH, summarises them and writes converted
copies; then it skins the CC0 MakeHuman body with a real CMU motion: a glTF that
Blender and three.js play (linear blend skinning) and a DQS point cache (PC2 with
its rest OBJ). Later stages (cleanup, tracking, deformation) join it as they land.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

from skincap.errors import FormatError

__all__ = ["run_demo", "demo_data_path"]

DEMO_C3D = "kt_optitrack_walking.c3d"
DEMO_BVH = "bvhtoolbox_test_mocapbank.bvh"
DEMO_BODY = "makehuman_base.obj"  # with makehuman_default.mhskel/.mhw beside it
DEMO_WALK = "cmu_131_01_bvh11.bvh"  # CMU units
#: Frames of the walk baked into the DQS point cache (2 s at 120 Hz keeps it ~30 MB).
DEMO_PC2_FRAMES = 240


def demo_data_path(name: str) -> Path:
    """Path of a data file shipped inside the skincap package."""
    path = Path(str(resources.files("skincap") / "data" / name))
    if not path.is_file():
        raise FormatError(path, "demo data missing from the installation; reinstall skincap")
    return path


def run_demo(
    output: str | os.PathLike[str],
    *,
    force: bool = False,
    progress: Callable[[float, str], None] | None = None,
) -> dict[str, Any]:
    """Read the shipped capture and motion, summarise them, write converted copies.

    Parameters
    ----------
    output : path-like
        Folder for the outputs; created if missing.
    force : bool
        Replace outputs of an earlier run.
    progress : callable(fraction, label), optional
        Called as the steps advance.

    Returns
    -------
    dict with ``summaries`` (input path -> summary dict) and ``outputs`` (written paths).
    """
    from skincap import io
    from skincap.io.joints_csv import write_joint_positions_csv
    from skincap.summary import summarize

    def step(fraction: float, label: str) -> None:
        if progress is not None:
            progress(fraction, label)

    folder = Path(output)
    folder.mkdir(parents=True, exist_ok=True)
    c3d_path, bvh_path = demo_data_path(DEMO_C3D), demo_data_path(DEMO_BVH)
    outputs: list[Path] = []

    step(0.0, "reading C3D")
    markers = io.read(c3d_path)
    step(0.2, "writing marker copies")
    for name in ("walking.trc", "walking.csv", "walking.c3d"):
        io.write(markers, folder / name, force=force)
        outputs.append(folder / name)

    step(0.3, "reading BVH")
    motion = io.read(bvh_path, units="cm")  # bvhtoolbox mocapbank file: centimetres
    step(0.35, "writing motion copies")
    io.write(motion, folder / "motion.bvh", force=force)
    outputs.append(folder / "motion.bvh")
    write_joint_positions_csv(motion, folder / "motion_joints.csv", force=force)
    outputs.append(folder / "motion_joints.csv")

    step(0.4, "skinning the MakeHuman body")
    outputs += _skin_body(
        folder, force=force, progress=lambda f: step(0.4 + 0.6 * f, "skinning (DQS)")
    )
    step(1.0, "done")
    return {
        "summaries": {str(c3d_path): summarize(markers), str(bvh_path): summarize(motion)},
        "outputs": [str(p) for p in outputs],
    }


def _skin_body(folder: Path, *, force: bool, progress: Callable[[float], None]) -> list[Path]:
    """MakeHuman body + CMU walk -> walk.glb (LBS in the viewer) and walk_dqs.pc2 + .obj."""
    from skincap.export.gltf import write_glb
    from skincap.export.pc2 import write_pc2
    from skincap.io.bvh import read_bvh
    from skincap.io.makehuman import read_makehuman
    from skincap.io.mesh import write_obj
    from skincap.skinning.deformers import skin_motion
    from skincap.skinning.pipeline import prepare_skinning
    from skincap.types import Motion

    for name in ("makehuman_default.mhskel", "makehuman_default_weights.mhw"):
        demo_data_path(name)
    body = read_makehuman(demo_data_path(DEMO_BODY))
    walk = read_bvh(demo_data_path(DEMO_WALK), units="cmu")
    setup = prepare_skinning(body, walk)
    write_glb(setup.mesh, setup.motion, folder / "walk.glb", force=force)
    m = setup.motion
    n = min(DEMO_PC2_FRAMES, m.n_frames)
    short = Motion(m.skeleton, m.rotations[:n], m.translations[:n], m.rate, m.channels, m.meta)
    write_obj(setup.mesh, folder / "walk_dqs.obj", force=force, units="m", up="y")
    write_pc2(
        skin_motion(setup.mesh, short, method="dqs", progress=progress),
        folder / "walk_dqs.pc2",
        force=force,
    )
    return [folder / "walk.glb", folder / "walk_dqs.obj", folder / "walk_dqs.pc2"]
