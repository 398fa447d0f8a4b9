"""Joint world positions of a motion as a wide CSV: one row per frame.

Columns: ``frame,time`` then ``<joint>_x,<joint>_y,<joint>_z`` for every joint
(end sites included), metres, skincap's Y-up frame.
"""

from __future__ import annotations

import os

import numpy as np

from skincap.geometry.kinematics import joint_positions
from skincap.io._common import atomic_output
from skincap.types import Motion

__all__ = ["write_joint_positions_csv"]


def write_joint_positions_csv(
    motion: Motion, path: str | os.PathLike[str], *, force: bool = False, precision: int = 9
) -> None:
    """Write the world position of every joint in every frame of ``motion``.

    Parameters
    ----------
    motion : Motion
        T frames of J joints.
    path : path-like
        Output ``.csv``; written atomically, replaced only with ``force``.
    precision : int
        Significant digits per coordinate (9 keeps micrometres for a 1 km range).

    The file has a header row and T data rows of ``2 + 3 J`` fields.
    """
    positions = joint_positions(motion)  # (T, J, 3) metres
    t = positions.shape[0]
    header = ["frame", "time"] + [
        f"{name}_{axis}" for name in motion.skeleton.names for axis in "xyz"
    ]
    table = np.column_stack([np.arange(t), np.arange(t) / motion.rate, positions.reshape(t, -1)])
    fmt = ["%d", f"%.{precision}g"] + [f"%.{precision}g"] * (table.shape[1] - 2)
    with atomic_output(path, force=force) as tmp:
        np.savetxt(tmp, table, fmt=fmt, delimiter=",", header=",".join(header), comments="")
