"""One synthetic capture, start to finish, with every piece of its ground truth.

body + motion -> skinned skin (DQS) + soft tissue -> markers on the skin -> rope
(optional) -> camera model (occlusion, fragments, noise, ghosts, swaps) -> the
capture as a labelled-first-frame :class:`~skincap.types.MarkerSet` of fragments and
as an un-indexed :class:`~skincap.types.PointCloud`, plus the truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.deform.skeletal.deformers import skin_motion
from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics
from skincap.synth._settings import settings_with
from skincap.synth.cameras import CameraRig, CaptureResult, simulate_capture
from skincap.synth.capture_settings import CaptureSettings
from skincap.synth.marker_parts import true_marker_parts
from skincap.synth.markers import (
    MarkerLayout,
    dense_marker_layout,
    place_markers,
    place_rigid_markers,
    sparse_marker_layout,
)
from skincap.synth.rope import RopeResult, rope_occluders, simulate_rope
from skincap.synth.soft_tissue import SoftTissue
from skincap.types import MarkerSet, Mesh, MeshAnimation, Motion

__all__ = ["CaptureSettings", "SynthCapture", "generate_capture", "hand_joints"]

#: Names of the hand joints in the skeleton conventions skincap knows, per side.
_HAND_NAMES = {
    "left": ("LeftHand", "lhand", "LeftWrist", "wrist.L", "hand.L", "LHand"),
    "right": ("RightHand", "rhand", "RightWrist", "wrist.R", "hand.R", "RHand"),
}


@dataclass
class SynthCapture:
    """A generated capture and its ground truth.

    Attributes
    ----------
    capture : MarkerSet
        What capture software would give: first-frame labels, ``*N`` fragments
        (body markers and rope markers alike), NaN where unseen, noise added.
    points : PointCloud
        The same reconstruction un-indexed, one row per point; ``ids`` are fragment
        column indices of ``capture``.
    point_truth : (M,) str array
        True label of every point of ``points`` (a body marker, ``rope_NN``) or ``ghost``.
    fragment_truth : dict of str to str
        Fragment label -> true label or ``ghost``.
    truth : MarkerSet
        Clean labelled positions of every marker (body then rope), no noise, no gaps.
    marker_surface : Mesh or None
        Ground-truth marker surface: vertices are the body markers in frame 0,
        faces the layout's triangulation (dense layouts).
    skin : MeshAnimation or None
        The moving skin the markers ride on, (T, V, 3) metres (None for a real
        capture's markers, :mod:`skincap.synth.real_capture`).
    motion : Motion or None
        The motion on the body's skeleton (None for a real capture's markers).
    rope : RopeResult or None
    summary : dict
        Counts for ``summary.json``: frames, rate, markers, fragments, missing
        fraction, ghosts, rope markers, …
    marker_parts : list of str or None
        The true near-rigid part of every body marker (the first markers of
        ``truth``, rope markers excluded), from the body's skin weights
        (:func:`skincap.synth.marker_parts.true_marker_parts`); None when the body's
        skeleton follows no known naming or the markers are a real capture's.
    """

    capture: MarkerSet
    points: Any
    point_truth: np.ndarray
    fragment_truth: dict[str, str]
    truth: MarkerSet
    marker_surface: Mesh | None
    skin: MeshAnimation | None
    motion: Motion | None
    rope: RopeResult | None
    summary: dict[str, Any] = field(default_factory=dict)
    marker_parts: list[str] | None = None


def hand_joints(motion: Motion) -> tuple[int, int]:
    """Indices of the left and right hand joints of ``motion``'s skeleton."""
    names = motion.skeleton.names
    found = []
    for side in ("left", "right"):
        idx = next((names.index(n) for n in _HAND_NAMES[side] if n in names), None)
        if idx is None:
            raise ValidationError(
                f"motion: no {side} hand joint (looked for {', '.join(_HAND_NAMES[side])})"
            )
        found.append(idx)
    return found[0], found[1]


def generate_capture(
    body: Mesh,
    motion: Motion,
    settings: CaptureSettings | None = None,
    *,
    seed: int = 0,
    progress: Progress | None = None,
    **options: Any,
) -> SynthCapture:
    """Generate a capture of ``body`` moving with ``motion``.

    Parameters
    ----------
    body : Mesh
        A closed skinned mesh in its bind pose (metres, Y up, facing +Z).
    motion : Motion
        On ``body.skin.skeleton`` (same joint names), starting in the bind pose.
    settings : CaptureSettings, optional
        Marker set, rope, soft-tissue amplitudes, camera ring and camera model (see
        :class:`~skincap.synth.capture_settings.CaptureSettings`; defaults when omitted).
    seed : int
        Every random choice derives from it: the same seed gives the same capture.
    progress : callable(fraction, label), optional
    **options
        Any :class:`CaptureSettings` field by name (``markers="sparse"``,
        ``rope="jump"``, ``noise_mm=0.2``), replacing the one in ``settings``.

    Returns
    -------
    SynthCapture
    """
    cfg = settings_with(CaptureSettings, settings, options, caller="generate_capture")
    if body.skin is None:
        raise ValidationError("body: needs a skin (skinned mesh)")
    rng = np.random.default_rng(seed)
    seeds = rng.integers(0, 2**31 - 1, size=6)

    def step(fraction: float, label: str) -> None:
        if progress is not None:
            progress(fraction, label)

    step(0.0, "skinning")
    skin = _moving_skin(body, motion, cfg, int(seeds[0]), step)
    frames = skin.frames
    step(0.25, "markers")
    layout = _marker_layout(body, cfg.markers, int(seeds[1]))
    true_positions, normals = place_markers(layout, frames, body.faces)
    if "rigid" in layout.meta:  # the sparse set's pelvis markers ride the pelvis bone
        order = [motion.skeleton.index(n) for n in body.skin.skeleton.names]
        world = forward_kinematics(motion)[:, order]  # (T, J, 4, 4) in the skin's order
        place_rigid_markers(layout, body, world, true_positions, normals)
    rope_result = None
    extra_points = extra_labels = extra_segments = None
    if cfg.rope != "none":
        step(0.35, "rope")
        rope_result = _held_rope(motion, cfg, int(seeds[2]))
        extra_points, extra_labels = rope_result.markers, rope_result.labels
        a, b, _radius = rope_occluders(rope_result.particles)
        extra_segments = np.stack([a, b], axis=2)  # (T, P - 1, 2, 3)

    step(0.45, "camera model")
    rig = _camera_ring_under(frames, cfg, int(seeds[3]))
    result: CaptureResult = simulate_capture(
        true_positions,
        normals,
        layout.labels,
        rig,
        frames,
        body.faces,
        settings=cfg,
        rate=motion.rate,
        extra_points=extra_points,
        extra_labels=extra_labels,
        extra_segments=extra_segments,
        seed=int(seeds[4]),
        progress=lambda f: step(0.45 + 0.5 * f, "camera model"),
    )

    truth_positions = (
        true_positions
        if extra_points is None
        else np.concatenate([true_positions, extra_points], axis=1)
    )
    truth_labels = list(layout.labels) + (list(extra_labels) if extra_labels is not None else [])
    truth = MarkerSet(
        truth_positions, truth_labels, motion.rate, meta={"source": "skincap.synth", "seed": seed}
    )
    surface = None
    if layout.surface_faces is not None and len(layout.surface_faces):
        surface = Mesh(
            true_positions[0], layout.surface_faces, meta={"labels": list(layout.labels)}
        )
    capture = result.markers
    capture.meta.update({"source": "skincap.synth", "seed": seed})
    summary = _summary(body, motion, cfg, seed, true_positions, result, rope_result)
    step(1.0, "done")
    return SynthCapture(
        capture=capture,
        points=result.points,
        point_truth=np.asarray(result.point_truth),
        fragment_truth=dict(result.fragment_truth),
        truth=truth,
        marker_surface=surface,
        skin=skin,
        motion=motion,
        rope=rope_result,
        summary=summary,
        marker_parts=_true_parts(body, layout),
    )


def _true_parts(body: Mesh, layout: MarkerLayout) -> list[str] | None:
    """The true part of every body marker, or None for a skeleton of unknown naming."""
    try:
        return true_marker_parts(body, layout.face, layout.bary)
    except ValidationError:
        return None


def _moving_skin(
    body: Mesh,
    motion: Motion,
    cfg: CaptureSettings,
    seed: int,
    step: Callable[[float, str], None],
) -> MeshAnimation:
    """DQS skinning plus soft tissue, (T, V, 3) metres in memory.

    Skinned with the NumPy reference: the numba kernel contracts multiply-adds
    (differs in the last bits), and ``backend="auto"`` picks it only once numba's
    cache holds it, so the same seed would write other bytes after a compile.
    """
    skinned = skin_motion(body, motion, method="dqs", backend="numpy")
    frames = np.concatenate(list(skinned.iter_chunks(128)), axis=0)
    step(0.15, "soft tissue")
    if cfg.bulge or cfg.jiggle or cfg.breathing:
        tissue = SoftTissue(
            body, bulge=cfg.bulge, jiggle=cfg.jiggle, breathing=cfg.breathing, seed=seed
        )
        frames += tissue.displacements(motion, frames)
    return MeshAnimation(body, frames, motion.rate, meta={"deformer": "dqs+soft_tissue"})


def _marker_layout(body: Mesh, markers: str, seed: int) -> MarkerLayout:
    """The dense grid (seeded) or the sparse landmark set on ``body``."""
    if markers == "dense":
        return dense_marker_layout(body, seed=seed)
    return sparse_marker_layout(body, body.skin)


def _held_rope(motion: Motion, cfg: CaptureSettings, seed: int) -> RopeResult:
    """The rope simulated from the hands of ``motion`` (first end in the right hand)."""
    left, right = hand_joints(motion)
    world = forward_kinematics(motion)[:, :, :3, 3]  # (T, J, 3)
    hands = np.stack([world[:, right], world[:, left]], axis=1)  # (T, 2, 3)
    return simulate_rope(
        hands,
        motion.rate,
        mode=cfg.rope,
        length=cfg.rope_length,
        marker_spacing=cfg.rope_marker_spacing,
        seed=seed,
    )


def _camera_ring_under(frames: np.ndarray, cfg: CaptureSettings, seed: int) -> CameraRig:
    """The camera ring standing on the floor under the take.

    Centred on where the body is on average, its floor at the lowest skin point (the
    MakeHuman bind pose has its origin at the hips, retargeted takes stand on y = 0).
    """
    centroid = frames.mean(axis=1)  # (T, 3)
    center = (
        float(centroid[:, 0].mean()),
        float(frames[..., 1].min()),
        float(centroid[:, 2].mean()),
    )
    return CameraRig.ring(n=cfg.n_cameras, n_up=cfg.n_cameras_up, center=center, seed=seed)


def _summary(
    body: Mesh,
    motion: Motion,
    cfg: CaptureSettings,
    seed: int,
    true_positions: np.ndarray,
    result: CaptureResult,
    rope_result: RopeResult | None,
) -> dict[str, Any]:
    """The counts written to ``summary.json``."""
    capture = result.markers
    stats = dict(result.stats)
    summary = {
        "frames": int(motion.n_frames),
        "rate": float(motion.rate),
        "markers": int(true_positions.shape[1]),
        "marker_set": cfg.markers,
        "rope_markers": 0 if rope_result is None else len(rope_result.labels),
        "rope": cfg.rope,
        "fragments": int(capture.n_markers),
        "labelled_fragments": int((~capture.unlabelled).sum()),
        "missing_fraction": float(stats.get("missing_fraction", np.nan)),
        "ghosts": int(stats.get("n_ghosts", 0)),
        "swaps": int(stats.get("n_swaps", 0)),
        "points": int(result.points.points.shape[0]),
        "mesh_vertices": int(body.n_vertices),
        "cameras": int(cfg.n_cameras),
        "noise_mm": float(cfg.noise_mm),
        "soft_tissue": {"bulge": cfg.bulge, "jiggle": cfg.jiggle, "breathing": cfg.breathing},
        "seed": int(seed),
        "camera_stats": {k: v for k, v in stats.items() if isinstance(v, int | float | str)},
    }
    if rope_result is not None:
        summary["rope_max_length_error"] = float(rope_result.meta.get("max_length_error", np.nan))
    return summary
