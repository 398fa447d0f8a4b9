"""A camera model for synthetic optical capture: visibility, broken trajectories, ghosts.

Park & Hodgins (2006, section 4) captured ~350 markers with 12 near-infrared cameras at
120 Hz around a small volume (about 2 m x 2 m x 2.5 m high), two of the cameras aimed
up to see markers facing the ground. Their Table 1 counts what such a capture gives
before clean-up: 859-5006 trajectory pieces for 574-974 frames of 350 markers and
23k-42k holes (missing samples, 5-15 %).

This module reproduces that process with exact ground truth:

- :class:`CameraRig` -- pinhole cameras (position, aim, field of view);
  :meth:`CameraRig.ring` builds the 12-camera ring.
- :func:`visibility` -- a marker is seen by a camera when it is inside the frustum,
  faces the camera (angle between its normal and the direction to the camera below a
  limit) and the segment to the camera does not cross the body (exact ray casting
  against the posed mesh, or a coarse proxy of it, :func:`occlusion_proxy`) nor an
  extra occluder such as the rope (capsules).
- :func:`simulate_capture` -- a marker is reconstructed in a frame when at least
  ``min_cameras`` cameras see it. Trajectories break at every gap and at a share of
  close confusions; only pieces present in frame 0 keep their label, every other
  piece becomes an unlabelled ``*<id>`` column as capture software does. Gaussian
  noise, ghost points and occasional label swaps complete the picture.

Conventions: metres, seconds, Y up.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincap._arrays import as_finite_array
from skincap.errors import ValidationError
from skincap.geometry.raycast import segments_near_capsules
from skincap.geometry.viewpoint_occlusion import occluded_from_viewpoints
from skincap.synth._settings import settings_with
from skincap.synth.capture_settings import CaptureSettings
from skincap.synth.reconstruction import (
    Confusions,
    Fragments,
    Samples,
    chain_pieces,
    confusions,
    draw_ghosts,
    fragment_columns,
    noisy_samples,
    reconstructed,
    shuffled_point_cloud,
)
from skincap.synth.surface_sampling import greedy_blue_noise, vertex_normals, voronoi_dual
from skincap.types import MarkerSet, PointCloud

__all__ = [
    "CameraRig",
    "OcclusionProxy",
    "CaptureResult",
    "occlusion_proxy",
    "visibility",
    "simulate_capture",
]

#: Vicon MX40 (4 megapixel) sensor, pixels (width, height).
MX40_RESOLUTION = (2352, 1728)


def _rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


def _array(name: str, value: object, shape: tuple[int | None, ...]) -> np.ndarray:
    return as_finite_array(value, name, shape)


# ------------------------------------------------------------------------ rig
@dataclass(eq=False)
class CameraRig:
    """Pinhole cameras looking at targets.

    Attributes
    ----------
    positions : (C, 3) float64, metres
        Optical centres.
    targets : (C, 3) float64, metres
        Points each camera looks at (the image centre).
    fov_deg : (C,) float64, degrees
        Horizontal field of view.
    resolution : (C, 2) int64, pixels
        Sensor width and height (gives the aspect ratio, hence the vertical field).
    up : (3,) float64
        World up used to roll the cameras level (default +Y).
    meta : dict
    """

    positions: np.ndarray
    targets: np.ndarray
    fov_deg: np.ndarray
    resolution: np.ndarray | None = None
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions = _array("positions", self.positions, (None, 3))
        c = self.positions.shape[0]
        if c == 0:
            raise ValidationError("positions: a rig needs at least one camera")
        self.targets = _array("targets", self.targets, (c, 3))
        self.fov_deg = np.broadcast_to(
            _array("fov_deg", self.fov_deg, ())
            if np.ndim(self.fov_deg) == 0
            else _array("fov_deg", self.fov_deg, (c,)),
            (c,),
        ).copy()
        if ((self.fov_deg <= 0) | (self.fov_deg >= 180)).any():
            raise ValidationError("fov_deg: expected angles in (0, 180) degrees")
        res = MX40_RESOLUTION if self.resolution is None else self.resolution
        r = np.asarray(res)
        r = np.broadcast_to(r, (c, 2)) if r.shape == (2,) else r
        if r.shape != (c, 2) or (r <= 0).any():
            raise ValidationError(f"resolution: expected (2,) or ({c}, 2) positive pixel sizes")
        self.resolution = np.asarray(r, dtype=np.int64).copy()
        self.up = _array("up", self.up, (3,))
        fwd = self.targets - self.positions
        if (np.linalg.norm(fwd, axis=1) == 0).any():
            raise ValidationError("targets: a camera's target equals its position")
        if (
            np.linalg.norm(np.cross(fwd, self.up), axis=1) <= 1e-9 * np.linalg.norm(fwd, axis=1)
        ).any():
            raise ValidationError("targets: a camera looks straight along the up axis")
        self.meta = dict(self.meta)

    @property
    def n_cameras(self) -> int:
        return int(self.positions.shape[0])

    @property
    def rotations(self) -> np.ndarray:
        """(C, 3, 3) float64 world-to-camera: rows are right, up and forward (unit)."""
        fwd = self.targets - self.positions
        fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right, axis=1, keepdims=True)
        up = np.cross(right, fwd)
        return np.stack([right, up, fwd], axis=1)

    @property
    def tan_half_fov(self) -> np.ndarray:
        """(C, 2) float64: tangent of the horizontal and vertical half fields of view."""
        th = np.tan(np.radians(self.fov_deg) / 2.0)
        res = np.asarray(self.resolution, dtype=np.float64)
        return np.stack([th, th * res[:, 1] / res[:, 0]], axis=1)

    def in_frustum(self, points: np.ndarray, *, near: float = 0.1) -> np.ndarray:
        """(..., C) bool: the points (..., 3) project inside each camera's image.

        A point must also be at least ``near`` metres in front of the camera.
        """
        p = np.asarray(points, dtype=np.float64)
        rel = p[..., None, :] - self.positions  # (..., C, 3)
        cam = np.einsum("cax,...cx->...ca", self.rotations, rel)
        z = cam[..., 2]
        tan = self.tan_half_fov
        zs = np.where(z > 0, z, 1.0)
        return (
            (z >= near)
            & (np.abs(cam[..., 0]) <= tan[:, 0] * zs)
            & (np.abs(cam[..., 1]) <= tan[:, 1] * zs)
        )

    @classmethod
    def ring(
        cls,
        n: int = 12,
        n_up: int = 2,
        *,
        volume: Sequence[float] = (2.0, 2.0, 2.5),
        center: Sequence[float] = (0.0, 0.0, 0.0),
        radius: float | None = None,
        height: float | None = None,
        low_height: float = 0.3,
        fov_deg: float | None = None,
        resolution: Sequence[int] = MX40_RESOLUTION,
        jitter: float = 0.0,
        seed: int | np.random.Generator | None = 0,
    ) -> CameraRig:
        """Park & Hodgins' ring: ``n`` cameras around the volume, ``n_up`` low and aimed up.

        Parameters
        ----------
        n : int, default 12
        n_up : int, default 2
            Cameras placed low (``low_height``) and aimed up at the upper part of the
            volume, spread evenly around the ring (to see downward-facing markers).
        volume : (3,) float, default (2, 2, 2.5)
            Capture volume width (x), depth (z) and height (y), metres.
        center : (3,) float, default (0, 0, 0)
            Centre of the volume's floor (the subject stands here), metres.
        radius : float, optional
            Horizontal distance of the cameras from the centre; default the floor's
            half diagonal plus 1.5 m.
        height : float, optional
            Height of the high cameras above the floor; default the volume height
            plus 0.3 m. They aim at the volume centre at 40 % of its height.
        low_height : float, default 0.3
            Height of the low cameras; they aim at the centre at 60 % of the height.
        fov_deg : float, optional
            Horizontal field of view; default the smallest angle (plus 5 %) at which
            every camera sees the whole volume.
        resolution : (2,) int, default (2352, 1728)
        jitter : float, default 0
            Random displacement of each camera (metres, uniform per axis), seeded.
        seed : int or Generator

        Returns
        -------
        CameraRig
            ``meta["aimed_up"]`` (C,) bool marks the low cameras.
        """
        n = int(n)
        n_up = int(n_up)
        if n < 2 or not 0 <= n_up <= n:
            raise ValidationError(f"n, n_up: expected n >= 2 and 0 <= n_up <= n, got {n}, {n_up}")
        w, d, h = (float(x) for x in volume)
        if min(w, d, h) <= 0:
            raise ValidationError(f"volume: expected three positive lengths, got {volume!r}")
        c0 = np.asarray(center, dtype=np.float64).reshape(3)
        r = float(radius) if radius is not None else 0.5 * float(np.hypot(w, d)) + 1.5
        hh = float(height) if height is not None else h + 0.3
        az = 2.0 * np.pi * (np.arange(n) + 0.5) / n
        pos = np.stack([c0[0] + r * np.sin(az), np.full(n, c0[1] + hh), c0[2] + r * np.cos(az)], 1)
        up_idx = (np.round(np.arange(n_up) * n / max(n_up, 1)).astype(np.int64) + n // 4) % n
        aimed_up = np.zeros(n, dtype=bool)
        aimed_up[up_idx] = True
        pos[aimed_up, 1] = c0[1] + float(low_height)
        tgt = np.tile(c0 + [0.0, 0.4 * h, 0.0], (n, 1))
        tgt[aimed_up, 1] = c0[1] + 0.6 * h
        if jitter:
            pos = pos + _rng(seed).uniform(-jitter, jitter, size=pos.shape)
        if fov_deg is None:
            # the volume's inscribed cylinder (where the subject moves), top and bottom rims
            ang = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
            rim = np.stack([np.cos(ang) * w / 2, np.zeros(32), np.sin(ang) * d / 2], axis=1)
            corners = c0 + np.concatenate([rim, rim + [0.0, h, 0.0]])
            probe = cls(pos, tgt, np.full(n, 90.0), resolution=resolution)
            rel = corners[None] - pos[:, None]
            cam = np.einsum("cax,ckx->cka", probe.rotations, rel)
            aspect = probe.resolution[:, 1] / probe.resolution[:, 0]
            tan_h = np.maximum(
                np.abs(cam[..., 0] / cam[..., 2]).max(axis=1),
                np.abs(cam[..., 1] / cam[..., 2]).max(axis=1) / aspect,
            )
            fov = float(np.degrees(2 * np.arctan(1.05 * tan_h.max())))
        else:
            fov = float(fov_deg)
        return cls(
            pos,
            tgt,
            np.full(n, fov),
            resolution=resolution,
            meta={"aimed_up": aimed_up, "volume": (w, d, h), "center": c0.tolist()},
        )


# ------------------------------------------------------------------ occlusion
@dataclass(eq=False)
class OcclusionProxy:
    """A coarse occluder standing in for a dense mesh.

    Attributes
    ----------
    vertex_ids : (S,) int64
        Mesh vertices used as proxy vertices (so the proxy follows any pose exactly:
        ``proxy_vertices = posed_vertices[..., vertex_ids, :]``).
    faces : (P, 3) int64
        Proxy triangles over ``vertex_ids`` indices, counter-clockwise from outside.
    stats : dict
    """

    vertex_ids: np.ndarray
    faces: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)


def occlusion_proxy(
    vertices: np.ndarray, faces: np.ndarray, *, n_vertices: int = 2500, seed: int = 0
) -> OcclusionProxy:
    """A coarse remesh of a closed mesh for fast occlusion tests.

    Blue-noise vertex subset (about ``n_vertices``), geodesic Voronoi regions and their
    dual triangulation (:func:`~skincap.synth.surface_sampling.voronoi_dual`): the proxy's
    vertices lie on the surface and it keeps the topology (a limb close to the torso
    does not fuse with it). Chords cut corners by roughly ``s^2 / (8 R)`` (spacing
    ``s``, curvature radius ``R``): a few millimetres at 2500 vertices for a body.

    Parameters
    ----------
    vertices : (V, 3) float, metres (rest pose)
    faces : (F, 3) int
    n_vertices : int, default 2500
    seed : int, default 0

    Returns
    -------
    OcclusionProxy
    """
    v = _array("vertices", vertices, (None, 3))
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or f.size == 0 or f.min() < 0 or f.max() >= v.shape[0]:
        raise ValidationError(f"faces: expected (F, 3) indices into {v.shape[0]} vertices")
    k = int(n_vertices)
    if k < 4:
        raise ValidationError(f"n_vertices: expected at least 4, got {n_vertices!r}")
    used = np.unique(f)
    if k >= used.size:
        return OcclusionProxy(used, np.searchsorted(used, f), {"exact": True})
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    rng = np.random.default_rng(seed)
    pri = rng.permutation(used.size).astype(np.float64)
    nrm = vertex_normals(v, f)[used]
    r = float(np.sqrt(area.sum() / (0.3 * k)))  # a first guess; refined from the count
    none = np.zeros(used.size, dtype=bool)
    pick = greedy_blue_noise(v[used], nrm, np.full(used.size, r), pri, none)
    for _ in range(6):
        if abs(pick.size - k) <= 0.05 * k:
            break
        r *= float(np.sqrt(pick.size / k))
        pick = greedy_blue_noise(v[used], nrm, np.full(used.size, r), pri, none)
    ids = used[pick]
    _, tri, stats = voronoi_dual(v, f, ids)
    return OcclusionProxy(ids, tri, {**stats, "spacing": r})


def visibility(
    points: np.ndarray,
    normals: np.ndarray | None,
    rig: CameraRig,
    occluder_vertices: np.ndarray,
    faces: np.ndarray,
    *,
    facing_limit_deg: float = 80.0,
    extra_segments: np.ndarray | None = None,
    extra_radius: float = 0.01,
    extra_markers: np.ndarray | None = None,
    proxy: OcclusionProxy | bool | None = None,
    start_offset: float | None = None,
    near: float = 0.1,
    progress: Callable[[float], object] | None = None,
) -> np.ndarray:
    """Which camera sees which marker in every frame.

    Parameters
    ----------
    points : (T, N, 3) float, metres
        Marker centres. Must be finite.
    normals : (T, N, 3) float or None
        Unit outward normals (the facing test); None for omnidirectional markers
        (rope tape), which skip the facing test.
    rig : CameraRig
    occluder_vertices : (T, V, 3) float, metres
        The posed body, assumed closed and outward-oriented (back faces are culled).
    faces : (F, 3) int
    facing_limit_deg : float, default 80
        A camera sees a marker when the angle between its normal and the direction to
        the camera is below this.
    extra_segments : (T, K, 2, 3) float, optional
        Extra occluders as capsule axes (e.g. consecutive rope particles), metres.
    extra_radius : float, default 0.01
        Capsule radius, metres.
    extra_markers : (N,) bool, optional
        Markers carried by the extra occluders (rope tape): omnidirectional (no facing
        test; their rows of ``normals`` are ignored) and not hidden by the extra
        segments. Lets body and rope markers share one pass over the body.
    proxy : OcclusionProxy, bool or None, default None
        Occlude with a coarse proxy of the body: an :class:`OcclusionProxy`, True
        (build one with :func:`occlusion_proxy`) or None (automatic: a proxy when the
        mesh has more than 6000 faces). False: the exact mesh.
    start_offset : float, optional
        Metres of each marker-to-camera segment next to the marker that cannot
        occlude it; default 2 mm with the exact mesh, 1 cm with a proxy (whose chords
        may pass just above the skin).
    near : float, default 0.1
        Near clipping distance, metres.
    progress : callable, optional
        Called with the fraction of frames done.

    Returns
    -------
    (T, N, C) bool
        True where camera ``c`` sees marker ``n`` in frame ``t``.

    Notes
    -----
    The body is tested exactly (ray casting against the mesh or its proxy, frame by
    frame). The capsules are tested exactly too, but only for the marker-camera pairs
    whose ray passes within the bounding sphere of some capsule, found for all frames
    at once (:func:`_capsule_candidates`); the others cannot meet a capsule.
    """
    pts = _array("points", points, (None, None, 3))
    t_n, n_m, _ = pts.shape
    nrm = None if normals is None else _array("normals", normals, (t_n, n_m, 3))
    ov = _array("occluder_vertices", occluder_vertices, (t_n, None, 3))
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= ov.shape[1])):
        raise ValidationError(f"faces: expected (F, 3) indices into {ov.shape[1]} vertices")
    if not isinstance(rig, CameraRig):
        raise ValidationError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    lim = float(facing_limit_deg)
    if not 0 < lim <= 180:
        raise ValidationError(f"facing_limit_deg: expected (0, 180], got {facing_limit_deg!r}")
    segs = None
    if extra_segments is not None:
        segs = _array("extra_segments", extra_segments, (t_n, None, 2, 3))
    on_extra = np.zeros(n_m, dtype=bool)
    if extra_markers is not None:
        on_extra = np.asarray(extra_markers)
        if on_extra.shape != (n_m,) or on_extra.dtype != bool:
            raise ValidationError(
                f"extra_markers: expected a ({n_m},) bool array, got {on_extra.shape} {on_extra.dtype}"
            )
    if proxy is None:
        proxy = f.shape[0] > 6000
    if proxy is True:
        proxy = occlusion_proxy(ov[0], f)
    if isinstance(proxy, OcclusionProxy):
        occ_ids, occ_f = proxy.vertex_ids, proxy.faces
        off = 0.01 if start_offset is None else float(start_offset)
    else:
        occ_ids, occ_f = None, f
        off = 0.002 if start_offset is None else float(start_offset)

    cams = rig.positions
    vis = rig.in_frustum(pts, near=near)  # (T, N, C)
    if nrm is not None:
        to_cam = cams[None, None] - pts[:, :, None]  # (T, N, C, 3)
        cosang = np.einsum("tnx,tncx->tnc", nrm, to_cam) / np.maximum(
            np.linalg.norm(to_cam, axis=3), 1e-12
        )
        vis &= (cosang > np.cos(np.radians(lim))) | on_extra[None, :, None]
    for t in range(t_n):  # per frame: the body moves; the work inside is vectorised
        if vis[t].any():
            verts = ov[t] if occ_ids is None else ov[t, occ_ids]
            vis[t] &= ~occluded_from_viewpoints(
                verts, occ_f, pts[t], cams, pairs=vis[t], start_offset=off, cull_back_faces=True
            )
        if progress is not None:
            progress((t + 1) / t_n)
    if segs is not None and segs.shape[1]:
        _hide_behind_capsules(vis, pts, cams, segs, float(extra_radius), ~on_extra)
    return vis


def _capsule_candidates(
    points: np.ndarray,
    cameras: np.ndarray,
    segments: np.ndarray,
    radius: float,
    pairs: np.ndarray,
    *,
    max_elements: int = 4_000_000,
) -> np.ndarray:
    """(T, N, C) bool: the ``pairs`` whose camera ray passes near some capsule's sphere.

    ``points`` (T, N, 3), ``cameras`` (C, 3), ``segments`` (T, K, 2, 3) capsule axes,
    metres. A segment from a marker to a camera that comes within ``radius`` of a
    capsule's axis comes within ``R = half axis + radius`` of its midpoint ``m``, so the
    ray from the camera makes an angle with ``m`` whose cosine is at least
    ``sqrt(1 - (R / |m - camera|)^2)`` (a camera inside the sphere: any ray). Pairs
    failing that for every capsule cannot be hidden by one; the test is one batched
    product per frame block instead of the exact segment-capsule distance (a margin
    of 1e-6 on the cosine keeps it conservative against rounding).
    """
    t_n, n_m, _ = points.shape
    c_n, k_n = cameras.shape[0], segments.shape[1]
    mid = 0.5 * (segments[:, :, 0] + segments[:, :, 1])  # (T, K, 3)
    reach = 0.5 * np.linalg.norm(segments[:, :, 1] - segments[:, :, 0], axis=2) + radius  # (T, K)
    to_mid = mid[:, None] - cameras[None, :, None]  # (T, C, K, 3)
    dist = np.linalg.norm(to_mid, axis=3)  # (T, C, K)
    inside = dist <= reach[:, None]
    unit_mid = to_mid / np.where(inside, 1.0, dist)[..., None]
    cos_min = np.where(
        inside, -np.inf, np.sqrt(np.clip(1.0 - (reach[:, None] / dist) ** 2, 0.0, 1.0)) - 1e-6
    )  # (T, C, K)
    out = np.zeros((t_n, n_m, c_n), dtype=bool)
    block = max(1, int(max_elements) // max(c_n * n_m * k_n, 1))  # frames per block
    for t0 in range(0, t_n, block):
        sl = slice(t0, t0 + block)
        ray = points[sl, None] - cameras[None, :, None]  # (t, C, N, 3)
        ray /= np.maximum(np.linalg.norm(ray, axis=3, keepdims=True), 1e-300)
        cosang = np.matmul(ray, unit_mid[sl].transpose(0, 1, 3, 2))  # (t, C, N, K)
        near = (cosang >= cos_min[sl][:, :, None, :]).any(axis=3)  # (t, C, N)
        out[sl] = near.transpose(0, 2, 1)
    return out & pairs


def _hide_behind_capsules(
    vis: np.ndarray,
    points: np.ndarray,
    cameras: np.ndarray,
    segments: np.ndarray,
    radius: float,
    tested: np.ndarray,
) -> None:
    """Clear ``vis`` (T, N, C) where the segment to the camera passes through a capsule.

    Only markers ``tested`` (N,) bool are occluded; exact per frame on the candidate
    pairs of :func:`_capsule_candidates`.
    """
    pairs = vis & tested[None, :, None]
    if not pairs.any():
        return
    near = _capsule_candidates(points, cameras, segments, radius, pairs)
    for t in np.nonzero(near.any(axis=(1, 2)))[0]:
        ni, ci = np.nonzero(near[t])
        hit = segments_near_capsules(
            points[t, ni], cameras[ci], segments[t, :, 0], segments[t, :, 1], radius
        )
        vis[t, ni[hit], ci[hit]] = False


# -------------------------------------------------------------------- capture
@dataclass(eq=False)
class CaptureResult:
    """A simulated optical capture and its ground truth.

    Attributes
    ----------
    markers : MarkerSet
        One column per trajectory fragment (T, K, 3), metres, NaN where missing.
        Fragments present in frame 0 carry the true label of the marker they start
        on; every other fragment (and every ghost) is ``*<id>``.
    fragment_truth : dict of str to str
        Fragment label -> the true marker label it follows, or ``"ghost"``. A
        fragment that went through a label swap follows two markers; it maps to the
        one it follows in most frames (ties: the first).
    points : PointCloud
        Every reconstructed point (fragments and ghosts), frame by frame, in a random
        order within each frame; ``ids`` are fragment column indices.
    point_truth : (M,) str array
        True label of each point (the marker it was measured on), or ``"ghost"``.
    point_truth_index : (M,) int64
        Index into ``truth_labels`` of each point, -1 for ghosts.
    truth_labels : list of str
        Body marker labels, then extra point labels.
    visible : (T, N_all, C) bool
        Camera visibility of every true marker (body then extra points).
    reconstructed : (T, N_all) bool
        Where a marker was reconstructed (before noise; ghosts excluded).
    stats : dict
        ``n_frames``, ``n_markers``, ``n_fragments``, ``n_labelled``, ``n_ghosts``,
        ``n_swaps``, ``n_confusion_breaks``, ``missing_fraction`` (body markers),
        ``holes`` (missing body samples).
    """

    markers: MarkerSet
    fragment_truth: dict[str, str]
    points: PointCloud
    point_truth: np.ndarray
    point_truth_index: np.ndarray
    truth_labels: list[str]
    visible: np.ndarray
    reconstructed: np.ndarray
    stats: dict[str, Any]


def _capture_inputs(
    true_positions: np.ndarray,
    normals: np.ndarray,
    labels: Sequence[str],
    extra_points: np.ndarray | None,
    extra_labels: Sequence[str] | None,
) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray, list[str]]:
    """Checked body positions and normals, body labels, extra points, all truth labels."""
    pos = _array("true_positions", true_positions, (None, None, 3))
    t_n, n_b, _ = pos.shape
    nrm = _array("normals", normals, (t_n, n_b, 3))
    body_labels = [str(s) for s in labels]
    if len(body_labels) != n_b or len(set(body_labels)) != n_b:
        raise ValidationError(f"labels: expected {n_b} unique labels, got {len(body_labels)}")
    if extra_points is not None:
        extra = _array("extra_points", extra_points, (t_n, None, 3))
    else:
        extra = np.zeros((t_n, 0, 3))
    n_x = extra.shape[1]
    xl = [f"extra_{k:02d}" for k in range(n_x)] if extra_labels is None else list(extra_labels)
    if len(xl) != n_x:
        raise ValidationError(f"extra_labels: expected {n_x} labels, got {len(xl)}")
    truth_labels = body_labels + [str(s) for s in xl]
    if len(set(truth_labels)) != len(truth_labels):
        raise ValidationError("labels, extra_labels: must be unique together")
    return pos, nrm, body_labels, extra, truth_labels


def _fragment_stats(
    seen_body: np.ndarray, frags: Fragments, n_ghost: int, conf: Confusions, samples: Samples
) -> dict[str, Any]:
    """Counts of the reconstruction; ``seen_body`` (T, N) bool of the body markers."""
    holes = int((~seen_body).sum())
    return {
        "n_fragments": int(frags.n_columns - n_ghost),
        "n_columns": int(frags.n_columns),
        "n_labelled": int(frags.labelled.sum()),
        "n_ghosts": n_ghost,
        "n_swaps": int(conf.swapped.size),
        "n_confusion_breaks": int(conf.is_break.sum()),
        "holes": holes,
        "missing_fraction": holes / max(seen_body.size, 1),
        "n_points": int(samples.frame.size),
    }


def simulate_capture(
    true_positions: np.ndarray,
    normals: np.ndarray,
    labels: Sequence[str],
    rig: CameraRig,
    occluder_vertices: np.ndarray,
    faces: np.ndarray,
    *,
    settings: CaptureSettings | None = None,
    rate: float = 120.0,
    extra_points: np.ndarray | None = None,
    extra_labels: Sequence[str] | None = None,
    extra_segments: np.ndarray | None = None,
    proxy: OcclusionProxy | bool | None = None,
    seed: int | np.random.Generator | None = 0,
    progress: Callable[[float], object] | None = None,
    **options: Any,
) -> CaptureResult:
    """Simulate an optical capture of markers on a moving body.

    Parameters
    ----------
    true_positions : (T, N, 3) float, metres
        Marker centres (e.g. from :func:`~skincap.synth.markers.place_markers`).
    normals : (T, N, 3) float
        Their unit outward normals.
    labels : sequence of N str
        True marker labels (unique).
    rig : CameraRig
    occluder_vertices : (T, V, 3) float, metres
        The posed body (closed, outward-oriented).
    faces : (F, 3) int
    settings : CaptureSettings, optional
        The camera model: ``min_cameras``, ``facing_limit_deg``, ``noise_mm``,
        ``marginal_dropout``, ``confusion_distance``, ``confusion_share``,
        ``swap_rate``, ``ghost_rate``, ``ghost_frames``, ``extra_radius`` (the other
        fields belong to :func:`~skincap.synth.generate.generate_capture`).
    rate : float, default 120
        Frame rate, Hz.
    extra_points : (T, M, 3) float, optional
        Other markers (rope tape): omnidirectional (no facing test), never labelled.
    extra_labels : sequence of M str, optional
        Their true labels (default ``extra_00``...).
    extra_segments : (T, K, 2, 3) float, optional
        Extra occluders (rope capsule axes), metres; ``settings.extra_radius`` their
        radius.
    proxy : see :func:`visibility`
    seed : int or Generator
        The same seed gives the same bytes.
    progress : callable, optional
        Fraction of the visibility pass done.
    **options
        Any :class:`CaptureSettings` field by name (``noise_mm=0.2``), replacing the
        one in ``settings``.

    Returns
    -------
    CaptureResult
    """
    cfg = settings_with(CaptureSettings, settings, options, caller="simulate_capture")
    pos, nrm, body_labels, extra, truth_labels = _capture_inputs(
        true_positions, normals, labels, extra_points, extra_labels
    )
    t_n, n_b, _ = pos.shape
    n_x = extra.shape[1]
    rng = _rng(seed)

    allpos = np.concatenate([pos, extra], axis=1)  # (T, N_all, 3)
    # body and extra markers in one pass over the body (the body's occlusion costs the
    # same for 20 markers as for 350); extra markers are omnidirectional and not hidden
    # by the extra segments they are on
    vis = visibility(
        allpos, np.concatenate([nrm, np.zeros_like(extra)], axis=1), rig, occluder_vertices,
        faces, facing_limit_deg=cfg.facing_limit_deg, extra_segments=extra_segments,
        extra_radius=cfg.extra_radius, extra_markers=np.arange(n_b + n_x) >= n_b,
        proxy=proxy, progress=progress,
    )  # fmt: skip
    n_all = allpos.shape[1]
    seen = reconstructed(vis, cfg, rng)
    conf = confusions(allpos, seen, cfg, rng)
    piece_of, n_pieces, chain = chain_pieces(seen, conf)
    ghosts = draw_ghosts(t_n, n_b, cfg, rng)
    samples = noisy_samples(allpos, n_b, seen, piece_of, n_pieces, chain, ghosts, cfg.noise_mm, rng)
    n_ghost = int(ghosts.start.size)
    frags = fragment_columns(samples, n_ghost, t_n, n_all, body_labels)
    s_col = frags.column[samples.group]

    positions = np.full((t_n, frags.n_columns, 3), np.nan)
    positions[samples.frame, s_col] = samples.noisy
    markers = MarkerSet(
        positions=positions,
        labels=frags.labels,
        rate=rate,
        meta={"source": "skincap.synth.simulate_capture", "up": "Y", "source_units": "m"},
    )
    names = np.array(truth_labels + ["ghost"], dtype=object)
    fragment_truth = {
        lab: str(names[m]) for lab, m in zip(frags.labels, frags.majority, strict=True)
    }
    points, p_truth = shuffled_point_cloud(samples, s_col, frags.labels, t_n, rate, rng)
    stats = {
        "n_frames": t_n,
        "n_markers": n_b,
        "n_extra": n_x,
        **_fragment_stats(seen[:, :n_b], frags, n_ghost, conf, samples),
    }
    return CaptureResult(
        markers=markers,
        fragment_truth=fragment_truth,
        points=points,
        point_truth=names[p_truth].astype(str),
        point_truth_index=p_truth.astype(np.int64),
        truth_labels=truth_labels,
        visible=vis,
        reconstructed=seen,
        stats=stats,
    )
