"""An analytic dense take with exact ground truth, shared by the animate tests.

An "arm" of two tubes (upper arm and forearm, 5 cm radius, 30 cm each) with 60
markers 8 mm off the skin; the forearm bends at the elbow while the whole arm turns
and moves. Away from the elbow every skin vertex moves rigidly with its tube.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.io.mesh import write_obj
from skincap.types import MarkerSet, Mesh

ELBOW = 0.3  # metres along x


def _tube(n_along: int, n_around: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on a closed-ring tube x in [0, 0.6] and its triangles (open ends, facing out)."""
    x = np.linspace(0.0, 2 * ELBOW, n_along)
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    xx, aa = np.meshgrid(x, a, indexing="ij")
    pts = np.stack([xx.ravel(), radius * np.cos(aa).ravel(), radius * np.sin(aa).ravel()], 1)
    idx = np.arange(n_along * n_around).reshape(n_along, n_around)
    nxt = np.roll(idx, -1, axis=1)
    a0, b0, c0, d0 = idx[:-1].ravel(), idx[1:].ravel(), nxt[1:].ravel(), nxt[:-1].ravel()
    faces = np.concatenate([np.stack([a0, c0, b0], 1), np.stack([a0, d0, c0], 1)])
    return pts, faces


def _pose(points: np.ndarray, n_frames: int) -> np.ndarray:
    """(T, M, 3): the forearm (x > ELBOW) bends to 70° about z, the arm turns and moves."""
    t = np.linspace(0.0, 1.0, n_frames)
    bend = Rotation.from_rotvec(np.radians(70.0) * np.sin(np.pi * t)[:, None] * [0, 0, 1.0])
    pivot = np.array([ELBOW, 0.0, 0.0])
    bent = np.einsum("tab,mb->tma", bend.as_matrix(), points - pivot) + pivot
    pts = np.where((points[:, 0] > ELBOW)[None, :, None], bent, points[None])
    whole = Rotation.from_rotvec(0.6 * t[:, None] * [0.3, 1.0, 0.2]).as_matrix()
    move = np.stack([0.2 * t, 1.0 + 0.05 * np.sin(4 * t), -0.1 * t], 1)
    return np.einsum("tab,tmb->tma", whole, pts) + move[:, None]


def arm_take(folder: Path, n_frames: int = 24) -> tuple[Path, Path, np.ndarray, np.ndarray]:
    """Write ``arm.obj`` (rest = frame 0 pose), ``arm.c3d`` and the marker surface
    ``arm_surface.ply``; return the mesh and take paths, the true skin and its x."""
    from skincap import io
    from skincap.io.mesh import write_ply

    skin, faces = _tube(31, 16, 0.05)
    marker_ref, surface = _tube(10, 6, 0.058)
    marker_ref[:, 0] += 0.01  # not on the ring of the elbow
    markers = _pose(marker_ref, n_frames)
    truth = _pose(skin, n_frames)
    mesh_path, take_path = folder / "arm.obj", folder / "arm.c3d"
    write_obj(Mesh(vertices=truth[0], faces=faces), mesh_path, units="m", up="y")
    labels = [f"M{i:02d}" for i in range(markers.shape[1])]
    io.write(MarkerSet(positions=markers, labels=labels, rate=100.0), take_path)
    write_ply(Mesh(vertices=markers[0], faces=surface), folder / "arm_surface.ply")
    return mesh_path, take_path, truth, skin[:, 0]
