"""``skincap demo``: the chain that exists so far, run on real data skincap ships.

It reads a real OptiTrack C3D and a real BVH, summarises them and writes converted
copies. Later stages (cleanup, tracking, skinning, deformation) join it as they land.
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

    step(0.5, "reading BVH")
    motion = io.read(bvh_path, units="cm")  # bvhtoolbox mocapbank file: centimetres
    step(0.7, "writing motion copies")
    io.write(motion, folder / "motion.bvh", force=force)
    outputs.append(folder / "motion.bvh")
    write_joint_positions_csv(motion, folder / "motion_joints.csv", force=force)
    outputs.append(folder / "motion_joints.csv")
    step(1.0, "done")
    return {
        "summaries": {str(c3d_path): summarize(markers), str(bvh_path): summarize(motion)},
        "outputs": [str(p) for p in outputs],
    }
