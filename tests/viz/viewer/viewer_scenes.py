"""Scenes for the viewer tests: every layer kind, from tests/data plus small synthetic layers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from skincap import io
from skincap.types import PointCloud
from skincap.viz.scene import CurveLayer, MarkerLayer, MeshLayer, PointLayer, Scene, load_scene

DATA = Path(__file__).resolve().parents[2] / "data"
#: The synthetic gap of the "raw" take: these marker columns over these frames.
GAP_COLUMNS = np.arange(3)
GAP_FRAMES = slice(100, 1500)


def raw_and_cleaned() -> tuple[MarkerLayer, MarkerLayer]:
    """The OptiTrack walk twice: "raw" with a gap knocked out, "cleaned" with it invented."""
    markers = io.read(DATA / "kt_optitrack_walking.c3d")
    cleaned_pos = markers.positions.copy()
    raw_pos = markers.positions.copy()
    invented = np.zeros(raw_pos.shape[:2], dtype=bool)
    present = ~np.isnan(cleaned_pos[..., 0])
    invented[GAP_FRAMES, GAP_COLUMNS] = present[GAP_FRAMES, GAP_COLUMNS]
    raw_pos[invented] = np.nan
    raw = MarkerLayer(
        "raw.c3d",
        markers.rate,
        Path("raw.c3d"),
        positions=raw_pos,
        labels=list(markers.labels),
        invented=np.zeros_like(invented),
    )
    cleaned = MarkerLayer(
        "cleaned.c3d",
        markers.rate,
        Path("cleaned.c3d"),
        positions=cleaned_pos,
        labels=list(markers.labels),
        invented=invented,
    )
    return raw, cleaned


def blob_mesh(n_frames: int = 240, rate: float = 60.0) -> MeshLayer:
    """An icosphere (642 vertices) that rolls along +x and breathes, 1 m up."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.25)
    v = np.asarray(sphere.vertices)  # (V, 3)
    t = np.arange(n_frames) / rate  # (T,)
    squash = 1.0 + 0.3 * np.sin(2 * np.pi * 0.5 * t)  # (T,)
    frames = v[None] * np.stack([1 / np.sqrt(squash), squash, 1 / np.sqrt(squash)], -1)[:, None]
    frames = frames + np.stack([-0.5 + 0.4 * t, np.ones_like(t), np.zeros_like(t)], -1)[:, None]
    return MeshLayer(
        "blob.obj",
        rate,
        Path("blob.obj"),
        faces=np.asarray(sphere.faces),
        frames=frames.astype(np.float32),
    )


def rope_curve(n_frames: int = 240, rate: float = 60.0, k: int = 41) -> CurveLayer:
    """A 2.4 m jump rope turning about the x axis at 1 turn per second."""
    s = np.linspace(0.0, 1.0, k)  # (K,)
    x = -0.6 + 1.2 * s
    sag = 1.0 * np.sin(np.pi * s)  # (K,) distance from the hand axis
    phase = 2 * np.pi * np.arange(n_frames) / rate  # (T,)
    y = 1.0 + sag[None] * np.cos(phase)[:, None]
    z = sag[None] * np.sin(phase)[:, None]
    curves = np.stack([np.broadcast_to(x, y.shape), y, z], axis=-1)
    curves[:, 5] = np.nan  # a gap in the curve is not drawn
    return CurveLayer("rope_curve.csv", rate, Path("rope_curve.csv"), curves=curves)


def point_layer(raw: MarkerLayer) -> PointLayer:
    """The raw markers' present samples as an un-indexed cloud, shifted 1 m along z."""
    pos = raw.positions + np.array([0.0, 0.0, 1.0])
    present = ~np.isnan(pos[..., 0])
    offsets = np.concatenate([[0], np.cumsum(present.sum(axis=1))])
    cloud = PointCloud(points=pos[present], offsets=offsets, rate=raw.rate)
    return PointLayer("points.csv", raw.rate, Path("points.csv"), cloud=cloud)


def full_scene() -> Scene:
    """Markers (raw + cleaned), points, the CMU skeleton, a deforming mesh and a rope."""
    raw, cleaned = raw_and_cleaned()
    skeleton = load_scene([DATA / "cmu_131_01_bvh11.bvh"], units="cmu").layers[0]
    return Scene([raw, cleaned, point_layer(raw), skeleton, blob_mesh(), rope_curve()])
