"""Summaries of skincap objects: what ``skincap info`` reports.

Each ``summarize_*`` returns a plain, JSON-ready dict (numbers, strings, lists).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap._arrays import interior_runs, track_largest_step
from skincap.geometry.kinematics import joint_positions_arrays
from skincap.types import MarkerSet, Mesh, Motion, PointCloud, Skeleton

__all__ = [
    "summarize",
    "summarize_markers",
    "summarize_points",
    "summarize_motion",
    "summarize_mesh",
    "summarize_point_cache",
    "mesh_height",
]


def summarize_markers(markers: MarkerSet) -> dict[str, Any]:
    """Frames, rate, duration, label counts, missing fraction and gaps of ``markers``."""
    missing = markers.missing
    _, _, lengths = interior_runs(missing)
    unlabelled = int(markers.unlabelled.sum())
    model_outputs = markers.meta.get("model_outputs") or {}
    return {
        "kind": "markers",
        "frames": markers.n_frames,
        "rate": markers.rate,
        "duration": markers.duration,
        "markers": markers.n_markers,
        "labelled": markers.n_markers - unlabelled,
        "unlabelled": unlabelled,
        "missing_fraction": float(missing.mean()) if missing.size else 0.0,
        "gaps": int(lengths.size),
        "longest_gap": int(lengths.max()) if lengths.size else 0,
        "source_units": markers.meta.get("source_units"),
        "up": markers.meta.get("up"),
        "first_frame": markers.meta.get("first_frame", 0),
        "model_outputs": {k: len(v) for k, v in model_outputs.items()},
        **_c3d_content_summary(markers),
    }


def _c3d_content_summary(markers: MarkerSet) -> dict[str, Any]:
    """What a C3D source carries besides its points: analog channels (with their
    rate, Hz), force plates and events; empty for other sources."""
    from skincap.io.c3d.content import C3dContent

    content = markers.meta.get("c3d")
    if not isinstance(content, C3dContent):
        return {}
    events = content.n_parameter_events() + (content.events.count if content.events else 0)
    return {
        "analog_channels": content.n_analog_channels,
        "analog_rate": float(markers.rate) * content.analog_ratio if content.analog_ratio else 0.0,
        "force_plates": content.n_force_plates(),
        "events": events,
    }


def summarize_points(cloud: PointCloud) -> dict[str, Any]:
    """Frames, rate and points-per-frame statistics of an un-indexed ``cloud``."""
    counts = cloud.counts
    return {
        "kind": "points",
        "frames": cloud.n_frames,
        "rate": cloud.rate,
        "duration": cloud.n_frames / cloud.rate,
        "points": int(cloud.points.shape[0]),
        "points_per_frame_min": int(counts.min()) if counts.size else 0,
        "points_per_frame_mean": float(counts.mean()) if counts.size else 0.0,
        "points_per_frame_max": int(counts.max()) if counts.size else 0,
        "has_ids": cloud.ids is not None,
    }


def _skeleton_height(skeleton: Skeleton) -> float:
    """Rest-pose vertical (Y) extent of the joints, metres."""
    world = np.zeros((skeleton.n_joints, 3))
    for j, p in enumerate(skeleton.parents):
        world[j] = skeleton.offsets[j] + (world[p] if p >= 0 else 0.0)
    return float(np.ptp(world[:, 1]))


def _motion_height(motion: Motion) -> float:
    """The figure's vertical (Y) extent, metres: the rest pose's, or the first frame's
    when the BVH reader found the rest pose to be no figure (``meta
    ["rest_pose_is_figure"]``, the pose its unit guess read)."""
    if motion.meta.get("rest_pose_is_figure", True) or motion.n_frames == 0:
        return _skeleton_height(motion.skeleton)
    posed = joint_positions_arrays(motion.skeleton, motion.rotations[:1], motion.translations[:1])[
        0
    ]  # (J, 3)
    return float(np.ptp(posed[:, 1]))


def summarize_motion(motion: Motion) -> dict[str, Any]:
    """Joints, frames, rate, units and channel orders of ``motion``."""
    sk = motion.skeleton
    channels = motion.channels or []
    end_sites = sum(1 for c in channels if not c)
    orders = sorted({"".join(c[0] for c in ch if c.endswith("rotation")) for ch in channels if ch})
    return {
        "kind": "motion",
        "joints": sk.n_joints - end_sites,
        "end_sites": end_sites,
        "frames": motion.n_frames,
        "rate": motion.rate,
        "frame_time": motion.frame_time,
        "duration": motion.duration,
        "source_units": motion.meta.get("source_units"),
        "height_m": _motion_height(motion),
        "root": sk.names[0],
        "rotation_orders": orders,
        "channels": int(sum(len(c) for c in channels)),
    }


def mesh_height(mesh: Mesh) -> float:
    """The mesh's vertical (Y) extent, metres: a standing body's height."""
    if mesh.n_vertices == 0:
        return 0.0
    lo, hi = mesh.bounds
    return float(hi[1] - lo[1])


def summarize_mesh(mesh: Mesh) -> dict[str, Any]:
    """Vertices, faces, bounds, height, groups and skin joints of ``mesh``.

    ``mesh`` as :func:`skincap.io.read_mesh` gives it (a MakeHuman body with its rig,
    in metres), so the counts are the ones ``skincap skin`` works with.
    """
    b = mesh.bounds
    out: dict[str, Any] = {
        "kind": "mesh",
        "vertices": mesh.n_vertices,
        "faces": mesh.n_faces,
        "polygons": mesh.n_polygons,
        "bounds_min": b[0].tolist(),
        "bounds_max": b[1].tolist(),
        "size_m": (b[1] - b[0]).tolist(),
        "height_m": mesh_height(mesh),
        "groups": len(mesh.groups),
        "skin_joints": mesh.skin.skeleton.n_joints if mesh.skin is not None else 0,
        "source_units": mesh.meta.get("source_units"),
    }
    if mesh.skin is not None:
        out["max_influences"] = int(mesh.skin.joint_weights.shape[1])
    return out


#: Frames of a point cache differenced at once for its speed (bounds the memory).
_SPEED_CHUNK_FRAMES = 64


def summarize_point_cache(
    frames: np.ndarray, *, start_frame: float, frame_step: float, rate: float | None
) -> dict[str, Any]:
    """Samples, points, bounds and fastest point of a point cache (PC2: what ``skin``
    and ``animate`` write).

    Parameters
    ----------
    frames : (T, V, 3) float, metres, finite (:func:`skincap.io.pc2.read_pc2` refuses NaN)
    start_frame, frame_step : float
        The header's first frame number and frames between two samples.
    rate : float or None
        Frame rate, Hz, when known (``skin``/``animate`` note it in the OBJ beside the
        cache); None leaves the duration and the speed in metres per frame.

    Returns
    -------
    dict
        ``kind`` ``"point_cache"``, ``frames``, ``points``, ``start_frame``,
        ``frame_step``, ``rate`` (or None), ``duration_s``, ``bounds_min``/``bounds_max``
        over every sample (m), ``size_m`` their difference, ``largest_frame_size_m`` the
        longest side of one sample's bounding box, and ``max_point_speed`` (m/s, or
        m/frame without a rate): a body a few metres tall moving at hundreds of m/s is
        an exploded deformation, not a take.
    """
    x = np.asarray(frames, dtype=np.float64)
    n_t, n_v = int(x.shape[0]), int(x.shape[1])
    out: dict[str, Any] = {
        "kind": "point_cache",
        "frames": n_t,
        "points": n_v,
        "start_frame": float(start_frame),
        "frame_step": float(frame_step),
        "rate": rate,
        "duration_s": None if rate is None else n_t * float(frame_step) / rate,
    }
    if n_t == 0 or n_v == 0:
        return out
    lo, hi = x.min(axis=(0, 1)), x.max(axis=(0, 1))
    frame_size = (x.max(axis=1) - x.min(axis=1)).max(axis=1)  # (T,)
    fastest: list[tuple[float, int]] = []
    chunks = (x[t0 : t0 + _SPEED_CHUNK_FRAMES] for t0 in range(0, n_t, _SPEED_CHUNK_FRAMES))
    for _ in track_largest_step(chunks, fastest):  # chunks of frames, not vertices
        pass
    step = fastest[0][0] if fastest else 0.0
    per_second = 1.0 if rate is None else rate / float(frame_step)
    out.update(
        bounds_min=lo.tolist(),
        bounds_max=hi.tolist(),
        size_m=(hi - lo).tolist(),
        largest_frame_size_m=float(frame_size.max()),
        max_point_speed=step * per_second,
        max_point_speed_unit="m/s" if rate is not None else "m/frame",
    )
    return out


def summarize(obj: object) -> dict[str, Any]:
    """Dispatch to the summary of ``obj``'s type."""
    if isinstance(obj, MarkerSet):
        return summarize_markers(obj)
    if isinstance(obj, PointCloud):
        return summarize_points(obj)
    if isinstance(obj, Motion):
        return summarize_motion(obj)
    if isinstance(obj, Mesh):
        return summarize_mesh(obj)
    raise TypeError(f"no summary for {type(obj).__name__}")
