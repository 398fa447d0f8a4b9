"""Analytic scenes built in memory: exact truth in milliseconds, for benchmarks and tests.

Unlike :func:`skincap.synth.generate.generate_capture` (a body, cameras, occlusion), these
are closed-form motions with a known answer, cheap enough to build inside a benchmark.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError
from skincap.types import PointCloud

__all__ = ["jump_rope_scene"]


def jump_rope_scene(
    *,
    frames: int = 1200,
    rate: float = 120.0,
    points_per_frame: int = 400,
    rope_markers: int = 24,
    hang_seconds: float = 0.5,
    turns_per_second: float = 1.5,
    dropout: float = 0.03,
    ghosts_per_frame: float = 4.0,
    noise_m: float = 0.0005,
    seed: int = 0,
) -> tuple[PointCloud, np.ndarray, np.ndarray]:
    """An analytic jump-rope take as an un-indexed cloud, with its rope truth.

    The hands are 0.9 m apart at hip height; the rope is an arc of depth
    ``sin(π s)`` (s along the rope) that hangs straight down for ``hang_seconds``,
    then turns about the line between the hands, easing in over half a second to
    ``turns_per_second``. The body is ``points_per_frame - rope_markers`` markers on
    an ellipsoid that hops 5 cm twice a second. Every point is dropped with
    probability ``dropout`` (never in the hanging window, where the tracker is
    initialised), ``ghosts_per_frame`` random ghosts are added on average, and
    Gaussian noise ``noise_m`` is added; each frame's order is shuffled.

    Returns
    -------
    cloud : PointCloud
        T frames of about ``points_per_frame`` points, metres, Y up; ``ids`` are the
        true marker numbers (rope ``0 … R-1``, body ``R …``, ghosts -1).
    rope : (T, R, 3) float64, metres
        Exact rope marker positions, in order along the rope.
    first_rope : (R,) int64
        Indices of the rope's points among frame 0's points, in rope order.
    """
    if frames < 2 or rope_markers < 3 or points_per_frame <= rope_markers:
        raise ValidationError(
            "scene: need frames >= 2, rope_markers >= 3 and points_per_frame > rope_markers"
        )
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / rate
    # Rope: angle about the x axis through the hands (π = hanging down).
    tau = np.clip(t - hang_seconds, 0.0, None)
    # Turn rate eases in linearly over 0.5 s: phase = integral of min(tau / 0.5, 1).
    phase = np.where(tau < 0.5, tau**2, tau - 0.25)
    theta = np.pi + 2 * np.pi * turns_per_second * phase
    s = np.linspace(0.0, 1.0, rope_markers)
    depth = 1.0 * np.sin(np.pi * s)  # (R,) distance from the hands' axis
    hop = 0.05 * np.abs(np.sin(2 * np.pi * 1.0 * tau))  # (T,)
    rope = np.zeros((frames, rope_markers, 3))
    rope[:, :, 0] = -0.45 + 0.9 * s[None, :]
    rope[:, :, 1] = 1.0 + hop[:, None] + depth[None, :] * np.cos(theta)[:, None]
    rope[:, :, 2] = depth[None, :] * np.sin(theta)[:, None]
    # Body: markers on an ellipsoid around the hands' axis, hopping with the rope.
    n_body = points_per_frame - rope_markers
    u = rng.normal(size=(n_body, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    body0 = u * np.array([0.18, 0.75, 0.13]) + np.array([0.0, 1.0, 0.0])
    body = (
        body0[None, :, :]
        + np.stack([np.zeros(frames), hop, 0.01 * np.sin(2 * np.pi * 0.5 * t)], axis=1)[:, None, :]
    )
    every = np.concatenate([rope, body], axis=1)  # (T, P, 3)
    ids = np.arange(every.shape[1])
    present = rng.random(every.shape[:2]) >= dropout
    present[t < hang_seconds] = True
    n_ghost = rng.poisson(ghosts_per_frame, size=frames)
    g_max = int(n_ghost.max()) if frames else 0
    ghosts = rng.uniform([-1.5, 0.0, -1.5], [1.5, 2.2, 1.5], size=(frames, g_max, 3))
    g_present = np.arange(g_max)[None, :] < n_ghost[:, None]
    all_pts = np.concatenate([every, ghosts], axis=1)
    all_ids = np.concatenate([ids, np.full(g_max, -1)])
    all_present = np.concatenate([present, g_present], axis=1)
    order = np.argsort(rng.random(all_present.shape), axis=1)
    keep = np.take_along_axis(all_present, order, axis=1)
    pts = np.take_along_axis(all_pts, order[:, :, None], axis=1)[keep]
    pid = all_ids[order][keep]
    pts = pts + rng.normal(scale=noise_m, size=pts.shape)
    offsets = np.concatenate([[0], np.cumsum(keep.sum(axis=1))]).astype(np.int64)
    cloud = PointCloud(points=pts, offsets=offsets, rate=rate, ids=pid)
    ids0 = pid[offsets[0] : offsets[1]]
    rows0 = np.flatnonzero((ids0 >= 0) & (ids0 < rope_markers))  # every rope point is in frame 0
    first_rope = rows0[np.argsort(ids0[rows0])].astype(np.int64)
    return cloud, rope, first_rope
