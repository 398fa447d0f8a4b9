"""Inverse kinematics: the body model's pose per frame from its measured markers.

Pose of frame t: the root origin ``o_0`` (metres) and every segment's world rotation
``R_s`` (the anatomical frame). Segment origins follow the tree,
``o_s = o_parent + R_parent d_s`` (``d_s`` the calibrated joint offset, so bone lengths
are constant), and a marker sits at ``x_m = o_seg(m) + R_seg(m) l_m``.

The fit minimises ``sum_m w_m |x_m - y_m|^2`` over the measured markers ``y_m`` (a
missing marker has ``w_m = 0`` in that frame) by Levenberg-Marquardt, batched over
frames: the Jacobian of a marker with respect to a rotation increment ``dw_a``
(``R_a <- exp(dw_a) R_a``) of any segment ``a`` on its path to the root is
``-[v]_x`` with ``v`` the world vector that segment carries on the path (its child's
joint offset, or the marker's own offset); with respect to the root origin it is
the identity. Each frame's normal equations are solved together (``np.linalg.solve``
over a ``(T, P, P)`` stack), with a per-frame damping that grows on a rejected step.

Frames start from the calibration's measured poses; where it gave none (a segment
seen by too few markers) from the last frame that had one (warm start), so such a
segment keeps the pose it had -- its undetermined directions are damped, never NaN.
A ``link`` segment (a neck, a clavicle: see :mod:`skincap.solve.templates`) adds the
spring residual ``k_s log(R_s R_parent^T)`` (``k_s`` metres per radian, the rotation
vector in world axes) to its frame's cost: its Jacobian is ``k_s I`` for the link's
increment and ``-k_s I`` for its parent's (exact at zero, and LM accepts a step only
when the true cost falls), so it adds one constant matrix to every frame's normal
equations.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from skincap._arrays import Progress
from skincap.backends import numba_available, resolve_backend
from skincap.errors import ValidationError
from skincap.solve._ik_numba import ancestor_blocks, ik_dispatcher, lm_steps, rotated

__all__ = [
    "solve_poses",
    "model_markers",
    "segment_origins",
    "fill_poses",
    "refit_marker_offsets",
    "limited_angle",
    "LOSSES",
    "ik_backend",
]


def segment_origins(
    parents: np.ndarray, offsets: np.ndarray, rotations: np.ndarray, root: np.ndarray
) -> np.ndarray:
    """(T, S, 3) world origins of the segments (loop over segments, batched over frames)."""
    out = np.empty(rotations.shape[:2] + (3,))
    out[:, 0] = root
    for s in range(1, parents.size):
        p = parents[s]
        out[:, s] = out[:, p] + rotations[:, p] @ offsets[s]
    return out


def model_markers(
    parents: np.ndarray,
    offsets: np.ndarray,
    marker_segments: np.ndarray,
    marker_offsets: np.ndarray,
    rotations: np.ndarray,
    root: np.ndarray,
) -> np.ndarray:
    """(T, M, 3) model marker positions for poses ``rotations (T, S, 3, 3)``, ``root (T, 3)``."""
    origins = segment_origins(parents, offsets, rotations, root)
    return origins[:, marker_segments] + np.einsum(
        "tmij,mj->tmi", rotations[:, marker_segments], marker_offsets
    )


def refit_marker_offsets(
    parents: np.ndarray,
    offsets: np.ndarray,
    marker_segments: np.ndarray,
    measured: np.ndarray,
    rotations: np.ndarray,
    root: np.ndarray,
    fallback: np.ndarray,
) -> np.ndarray:
    """Each marker's offset in its segment's frame that best fits solved poses.

    With the poses fixed, the least-squares offset of a marker is the mean over the
    frames that see it of ``R_seg^T (y - o_seg)``: one step of block-coordinate
    descent on the IK cost (poses, then offsets), so solving again from these poses
    can only lower the squared residual. The calibration measured the offsets in
    frames built from a few markers each; this puts them where the whole model,
    joint centres and neighbours included, carries them.

    Parameters
    ----------
    parents, offsets : the model's tree and joint offsets, as in :func:`solve_poses`
    marker_segments : (M,) int
    measured : (T, M, 3) float, metres, NaN where missing
    rotations : (T, S, 3, 3) float, solved world rotations
    root : (T, 3) float, metres
    fallback : (M, 3) float, metres
        The offset kept for a marker no frame sees.

    Returns
    -------
    (M, 3) float64, metres
    """
    origins = segment_origins(parents, offsets, rotations, root)
    seg = np.asarray(marker_segments, dtype=np.int64)
    seen = np.isfinite(measured).all(axis=2)  # (T, M)
    diff = np.where(seen[..., None], measured - origins[:, seg], 0.0)
    local = np.einsum("tmji,tmj->mi", rotations[:, seg], diff)  # sum over seen frames
    count = seen.sum(axis=0)
    return np.where(
        (count > 0)[:, None], local / np.maximum(count, 1)[:, None], np.asarray(fallback, float)
    )


def fill_poses(
    rotations: np.ndarray, root: np.ndarray, parents: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Replace NaN poses by the previous frame's (then the next's); a segment never
    posed takes its parent's rotation (the root: identity)."""
    rot = rotations.copy()
    org = root.copy()
    t = rot.shape[0]
    idx = np.arange(t)

    def ffill(ok: np.ndarray) -> np.ndarray:
        last = np.where(ok, idx, -1)
        np.maximum.accumulate(last, out=last)
        first = int(np.argmax(ok))
        return np.where(last < 0, first, last)

    ok = np.isfinite(org).all(axis=1)
    org = org[ffill(ok)] if ok.any() else np.zeros_like(org)
    for s in range(rot.shape[1]):
        ok = np.isfinite(rot[:, s]).all(axis=(1, 2))
        if ok.any():
            rot[:, s] = rot[ffill(ok), s]
        else:
            rot[:, s] = rot[:, parents[s]] if parents[s] >= 0 else np.eye(3)
    return rot, org


def _exp(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of rotation vectors (..., 3) (Rodrigues)."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = np.zeros(w.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def _log(r: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors of rotation matrices (..., 3, 3) (inverse of :func:`_exp`)."""
    cos = np.clip((np.einsum("...ii->...", r) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    # sin(angle) * axis from the antisymmetric part
    s = 0.5 * np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    sin = np.sin(angle)[..., None]
    out = s * np.where(sin > 1e-8, angle[..., None] / np.where(sin > 1e-8, sin, 1.0), 1.0)
    far = angle > 3.0  # near a half turn the antisymmetric part vanishes: SciPy's formula
    if far.any():
        out[far] = Rotation.from_matrix(r[far]).as_rotvec()
    return out


def limited_angle(rel: np.ndarray, axis: int, bone_axis: int) -> np.ndarray:
    """(...,) radians: the angle about coordinate ``axis`` of rotations ``rel (..., 3, 3)``
    (a child's frame in its parent's), as the first of intrinsic Euler angles turning
    about ``axis``, then the remaining axis, then the bone's own ``bone_axis`` last.

    For a knee (flexion about x, the shank along y) that is x-z-y: flexion, then
    ab/adduction, then the rotation about the bone, the joint coordinate system of
    Grood & Suntay; it stays continuous through any rotation about the bone (a forearm
    flexed and pronated at once), where a component of the rotation vector flips near a
    half turn. ``axis == bone_axis`` limits the rotation about the bone itself.
    """
    rest = [k for k in range(3) if k not in (axis, bone_axis)]
    order = [axis, rest[0], bone_axis] if axis != bone_axis else [axis, *rest]
    seq = "".join("XYZ"[k] for k in order)
    shape = rel.shape[:-2]
    with warnings.catch_warnings():  # gimbal lock: a 90 deg middle angle, not anatomical
        warnings.simplefilter("ignore", UserWarning)
        first = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_euler(seq)[:, 0]
    return first.reshape(shape)


_SKEW_SIGN = np.array([1.0, -1.0, -1.0, 1.0, 1.0, -1.0])


class _Paths:
    """For every (marker, segment-on-its-path) pair: which local vector that segment carries."""

    def __init__(
        self, parents: np.ndarray, offsets: np.ndarray, mseg: np.ndarray, moff: np.ndarray
    ) -> None:
        pair_m, pair_s, pair_v = [], [], []
        for m, s in enumerate(mseg):
            pair_m.append(m)
            pair_s.append(s)
            pair_v.append(moff[m])
            child = s
            while parents[child] >= 0:
                p = parents[child]
                pair_m.append(m)
                pair_s.append(p)
                pair_v.append(offsets[child])
                child = p
        self.marker = np.array(pair_m, dtype=np.int64)
        self.segment = np.array(pair_s, dtype=np.int64)
        self.local = np.array(pair_v, dtype=np.float64).reshape(-1, 3)
        # marker m's pairs are start[m]:start[m + 1] (they were appended marker by marker)
        self.start = np.concatenate([[0], np.cumsum(np.bincount(self.marker, minlength=len(mseg)))])


#: Robust losses of a marker's distance ``s`` (metres) with scale ``c``: ``rho(s)`` and the
#: IRLS weight ``rho'(s) / (2 s)`` (1 for a residual well inside the scale).
LOSSES = ("squared", "huber", "cauchy")


def _marker_loss(dist2: np.ndarray, loss: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Loss ``rho`` (m^2) and IRLS weight of squared marker distances ``dist2 (T, M)`` (m^2)."""
    if loss == "squared":
        return dist2, np.ones_like(dist2)
    c2 = scale * scale
    if loss == "huber":  # rho = s^2 inside the scale, 2 c s - c^2 beyond: linear growth
        dist = np.sqrt(dist2)
        far = dist > scale
        rho = np.where(far, 2.0 * scale * dist - c2, dist2)
        return rho, np.where(far, scale / np.where(far, dist, 1.0), 1.0)
    # cauchy: rho = c^2 log(1 + s^2 / c^2), grows only logarithmically
    return c2 * np.log1p(dist2 / c2), 1.0 / (1.0 + dist2 / c2)


def _cost(
    resid: np.ndarray, w: np.ndarray, loss: str = "squared", scale: float = 1.0
) -> np.ndarray:
    """(T,) robust cost (m^2) of marker residuals ``resid (T, M, 3)`` seen where ``w (T, M)`` is 1."""
    dist2 = np.einsum("tmi,tmi->tm", resid, resid)
    rho = dist2 if loss == "squared" else _marker_loss(dist2, loss, scale)[0]  # no IRLS weights
    return np.einsum("tm,tm->t", w, rho)


def _pose_cost(problem: _IKProblem, y: np.ndarray, rot: np.ndarray, root: np.ndarray) -> np.ndarray:
    """(T,) cost (m^2) of poses ``rot (T, S, 3, 3)``, ``root (T, 3)`` for measured markers
    ``y (T, M, 3)`` metres (NaN: missing)."""
    seen = np.isfinite(y).all(axis=2)
    x = problem.markers(rot, root)
    spring = problem.springs.residuals(rot)
    resid = np.where(seen[..., None], x - np.where(seen[..., None], y, 0.0), 0.0)
    return _cost(resid, seen.astype(np.float64), problem.loss, problem.loss_scale) + np.einsum(
        "tli,tli->t", spring, spring
    )


class _Springs:
    """The link segments' springs: residuals ``k log(R_s R_p^T)`` and their constant normal matrix."""

    def __init__(
        self,
        parents: np.ndarray,
        stiffness: np.ndarray,
        n_par: int,
        limits: np.ndarray | None = None,
        limit_stiffness: float = 1.0,
        bone_axes: np.ndarray | None = None,
    ) -> None:
        # joint limits (see solve_poses): one scalar residual per (segment, axis) bounded
        lim = np.full((parents.size, 3, 2), np.nan) if limits is None else limits
        self.lim_segment, self.lim_axis = np.nonzero(np.isfinite(lim).any(axis=2))
        self.lim_parent = parents[self.lim_segment]
        bones = np.ones(parents.size, dtype=np.int64) if bone_axes is None else bone_axes
        self.lim_bone = bones[self.lim_segment]
        lo_hi = lim[self.lim_segment, self.lim_axis]
        self.lim_lo = np.where(np.isfinite(lo_hi[:, 0]), lo_hi[:, 0], -np.inf)
        self.lim_hi = np.where(np.isfinite(lo_hi[:, 1]), lo_hi[:, 1], np.inf)
        self.lim_k = float(limit_stiffness)
        self.segment = np.flatnonzero(stiffness > 0)
        self.parent = parents[self.segment]
        self.k = stiffness[self.segment]
        self.normal = np.zeros((n_par, n_par))  # J^T J, the same for every frame
        eye = np.eye(3)
        for s, p, k in zip(self.segment, self.parent, self.k, strict=True):
            cs, cp = 3 + 3 * s, 3 + 3 * p
            self.normal[cs : cs + 3, cs : cs + 3] += k**2 * eye
            self.normal[cp : cp + 3, cp : cp + 3] += k**2 * eye
            self.normal[cs : cs + 3, cp : cp + 3] -= k**2 * eye
            self.normal[cp : cp + 3, cs : cs + 3] -= k**2 * eye

    def residuals(self, rot: np.ndarray) -> np.ndarray:
        """(T, L + K, 3) metres-equivalent residuals of world rotations (T, S, 3, 3): the
        L springs, then the K joint limits (their excess angle times the limit
        stiffness in the first component, zeros after)."""
        out = np.zeros(rot.shape[:1] + (self.segment.size + self.lim_segment.size, 3))
        if self.segment.size:
            rel = rot[:, self.segment] @ rot[:, self.parent].transpose(0, 1, 3, 2)
            out[:, : self.segment.size] = self.k[:, None] * _log(rel)
        if self.lim_segment.size:
            out[:, self.segment.size :, 0] = self.lim_k * self._excess(rot)
        return out

    def _excess(self, rot: np.ndarray) -> np.ndarray:
        """(T, K) radians beyond each joint limit (0 inside it)."""
        rel = np.einsum("tkji,tkjl->tkil", rot[:, self.lim_parent], rot[:, self.lim_segment])
        angle = np.stack(
            [
                limited_angle(rel[:, k], int(a), int(self.lim_bone[k]))
                for k, a in enumerate(self.lim_axis)
            ],
            axis=1,
        )
        return angle - np.clip(angle, self.lim_lo, self.lim_hi)

    def project(self, rot: np.ndarray) -> None:
        """Turn each limited segment back inside its limits in place (``rot (T, S, 3, 3)``
        world rotations, parents first): ``R_s <- exp(-excess u) R_s`` lowers the first
        Euler angle by exactly the excess, so the LM starts from poses that keep them."""
        for k in range(self.lim_segment.size):
            excess = self._excess(rot)[:, k]
            p, a = self.lim_parent[k], self.lim_axis[k]
            turn = _exp(-excess[:, None] * rot[:, p, :, a])
            rot[:, self.lim_segment[k]] = turn @ rot[:, self.lim_segment[k]]

    def add_limits(self, h: np.ndarray, g: np.ndarray, rot: np.ndarray, r: np.ndarray) -> None:
        """Add the joint limits' ``J^T J`` and ``J^T r`` to ``h (T, P, P)`` and ``g (T, P)``
        in place, for poses ``rot`` and residuals ``r`` (from :meth:`residuals`).

        The limited angle (:func:`limited_angle`) turns about the parent's axis
        ``u = R_p e_a``; its row is taken as ``u`` for the segment's increment and ``-u``
        for its parent's (exact for a pure hinge; LM accepts a step only when the true
        cost falls); a limit that holds adds nothing."""
        u, res = self.limit_rows(rot, r)
        for k in range(self.lim_segment.size):
            uu = np.einsum("ti,tj->tij", u[:, k], u[:, k])
            cs, cp = 3 + 3 * self.lim_segment[k], 3 + 3 * self.lim_parent[k]
            h[:, cs : cs + 3, cs : cs + 3] += uu
            h[:, cp : cp + 3, cp : cp + 3] += uu
            h[:, cs : cs + 3, cp : cp + 3] -= uu
            h[:, cp : cp + 3, cs : cs + 3] -= uu
        self.add_limit_gradient(g, u, res)

    def limit_rows(self, rot: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each joint limit's Jacobian row ``u`` for its segment's increment, ``(T, K, 3)``
        (the parent's is ``-u``; zero where the limit holds), and its residual ``(T, K)``
        (the limit stiffness times the excess angle), for poses ``rot`` and residuals
        ``r`` (from :meth:`residuals`)."""
        res = r[:, self.segment.size :, 0]  # (T, K)
        k = np.arange(self.lim_segment.size)
        axes = rot[:, self.lim_parent].transpose(0, 1, 3, 2)[:, k, self.lim_axis]  # (T, K, 3)
        return self.lim_k * axes * (res != 0.0)[..., None], res

    def add_limit_gradient(self, g: np.ndarray, u: np.ndarray, res: np.ndarray) -> None:
        """Add the joint limits' ``J^T r`` (rows ``u (T, K, 3)``, residuals ``res (T, K)``
        from :meth:`limit_rows`) to gradients ``g (T, P)`` in place."""
        for k in range(self.lim_segment.size):
            cs, cp = 3 + 3 * self.lim_segment[k], 3 + 3 * self.lim_parent[k]
            g[:, cs : cs + 3] += u[:, k] * res[:, k, None]
            g[:, cp : cp + 3] -= u[:, k] * res[:, k, None]

    def add_gradient(self, g: np.ndarray, r: np.ndarray) -> None:
        """Add the springs' ``J^T r`` for residuals ``r (T, L, 3)`` to gradients ``g (T, P)`` in place."""
        for k, (s, p) in enumerate(zip(self.segment, self.parent, strict=True)):
            g[:, 3 + 3 * s : 6 + 3 * s] += self.k[k] * r[:, k]
            g[:, 3 + 3 * p : 6 + 3 * p] -= self.k[k] * r[:, k]


@dataclass(frozen=True, eq=False)
class _IKProblem:
    """One inverse-kinematics problem: the model, its Jacobian paths and the LM settings.

    ``parents (S,)`` int64, ``offsets (S, 3)`` metres, ``mseg (M,)`` int64, ``moff (M, 3)``
    metres (as in :func:`solve_poses`); ``paths`` and ``springs`` precomputed from them;
    ``n_par = 3 + 3 S`` parameters per frame; the stopping rule (``iterations``,
    ``tolerance`` m^2, ``relative_tolerance``), the marker loss (``loss``,
    ``loss_scale`` metres) and whether the step's linear algebra runs in the numba
    kernels (``compiled``, :mod:`skincap.solve._ik_numba`)."""

    parents: np.ndarray
    offsets: np.ndarray
    mseg: np.ndarray
    moff: np.ndarray
    paths: _Paths
    springs: _Springs
    n_par: int
    iterations: int
    tolerance: float
    relative_tolerance: float
    loss: str
    loss_scale: float
    compiled: bool = False

    def markers(self, rot: np.ndarray, root: np.ndarray) -> np.ndarray:
        """(T, M, 3) model markers, metres, of poses ``rot (T, S, 3, 3)``, ``root (T, 3)``."""
        return model_markers(self.parents, self.offsets, self.mseg, self.moff, rot, root)


def solve_poses(
    parents: np.ndarray,
    offsets: np.ndarray,
    marker_segments: np.ndarray,
    marker_offsets: np.ndarray,
    measured: np.ndarray,
    init_rotations: np.ndarray,
    init_root: np.ndarray,
    *,
    iterations: int = 12,
    tolerance: float = 1e-7,
    relative_tolerance: float = 1e-3,
    chunk: int = 512,
    link_stiffness: np.ndarray | None = None,
    warm_start: bool = True,
    loss: str = "squared",
    loss_scale: float = 0.02,
    joint_limits: np.ndarray | None = None,
    limit_stiffness: float = 10.0,
    bone_axes: np.ndarray | None = None,
    backend: str = "auto",
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares poses of a marker model, all frames at once.

    Parameters
    ----------
    parents : (S,) int, -1 for the root, parents first
    offsets : (S, 3) float, metres, each segment's origin in its parent's frame
    marker_segments : (M,) int
    marker_offsets : (M, 3) float, metres, in the segment's frame
    measured : (T, M, 3) float, metres, NaN where missing
    init_rotations : (T, S, 3, 3) float, NaN allowed (filled from neighbouring frames)
    init_root : (T, 3) float, NaN allowed
    iterations : int
        Most Levenberg-Marquardt steps per frame.
    tolerance : float
        Stop a frame when a step improves its cost (sum of squared residuals, m^2) by
        less than this. The default 1e-7 m^2 changes the RMS residual of the real CMU
        and synthetic takes by under 1e-7 m against 1e-9 m^2, in 40-60 % fewer steps.
    relative_tolerance : float
        Also stop a frame when a step improves its cost by less than this fraction of
        the cost: the default 1e-3 changes the RMS residual of the real CMU 85_02 take
        by 1.6e-6 m (0.02 %) against running to convergence, in 27 % fewer solves
        (4.6 -> 3.3 per frame). 0 turns it off.
    chunk : int
        Frames solved together.
    warm_start : bool, default True
        Solve the even frames first, then start each odd frame from the midpoint of
        its solved neighbours' poses where that fits its markers better than its own
        start (in a smooth take it does): fewer steps for half the frames.
    link_stiffness : (S,) float, metres per radian, optional
        Spring of each link segment towards its parent's orientation; 0 (the
        default for every segment) for none.
    loss : {"squared", "huber", "cauchy"}, default "squared"
        Loss of each marker's distance ``s`` to its model marker: ``s^2``; Huber
        (``s^2`` up to ``loss_scale``, then linear) or Cauchy
        (``c^2 log(1 + s^2 / c^2)``), so one marker that slides on the skin or was
        mislabelled in a frame pulls its segment with a bounded force rather than
        one growing with its distance (iteratively reweighted: each step's normal
        equations weight a marker by ``rho'(s) / 2s``).
    loss_scale : float, default 0.02
        The robust loss's scale ``c``, metres: residuals well below it count as
        squares.
    joint_limits : (S, 3, 2) float, radians, optional
        Per segment and axis of its parent's frame, the least and greatest angle
        (NaN: unbounded) of ``R_parent^T R_segment`` about that axis
        (:func:`limited_angle`; for a hinge about the parent's x axis: its flexion).
        A pose beyond a limit pays ``(limit_stiffness * excess)^2``.
    limit_stiffness : float, default 10.0
        Metres per radian: 0.1 deg past a limit costs as much as a 1.7 cm marker
        residual. The poses start inside the limits (each limited segment turned back
        about its parent's axis), and the penalty keeps them there: on CMU 85_02 a knee
        limited to 60 deg that the take bends to 133 deg stays under 62.5 deg.
    bone_axes : (S,) int, optional
        Each segment's long axis (0, 1, 2 for x, y, z; default y), the last of the
        Euler angles of :func:`limited_angle`.
    backend : {"auto", "numba", "numpy"}, default "auto"
        Where each step's normal equations are built and solved: the numba kernels
        of :mod:`skincap.solve._ik_numba` (float64, the tree's sparsity exploited) or
        the NumPy reference (a dense single-precision Jacobian product and
        ``np.linalg.solve``); they agree to rounding. ``"auto"`` takes the kernels
        once compiled (:func:`skincap.backends.resolve_backend`: the first run on a
        machine compiles them in the background and runs NumPy).
    progress : callable(fraction, label), optional

    Returns
    -------
    rotations : (T, S, 3, 3) float64
        World rotations, never NaN.
    root : (T, 3) float64, metres
    """
    parents, offsets, mseg, moff, y = _checked_model_inputs(
        parents, offsets, marker_segments, marker_offsets, measured, init_rotations, init_root
    )
    s = parents.size
    rot, root = fill_poses(np.asarray(init_rotations, float), np.asarray(init_root, float), parents)
    paths = _Paths(parents, offsets, mseg, moff)
    n_par = 3 + 3 * s
    stiff, limits, bones = _checked_ik_options(
        s, link_stiffness, loss, loss_scale, joint_limits, limit_stiffness, bone_axes
    )
    springs = _Springs(parents, stiff, n_par, limits, float(limit_stiffness), bones)
    springs.project(rot)  # start inside the joint limits
    problem = _IKProblem(
        parents, offsets, mseg, moff, paths, springs, n_par, int(iterations), float(tolerance),
        float(relative_tolerance), loss, float(loss_scale), _resolve_backend(backend) == "numba",
    )  # fmt: skip
    return _solve_in_passes(problem, y, rot, root, chunk, warm_start, progress)


def warm_up_kernel() -> None:
    """Compile the IK kernels into numba's cache (run by the background compile)."""
    solve_poses(
        np.array([-1]), np.zeros((1, 3)), np.zeros(3, dtype=np.int64), np.eye(3),
        np.eye(3)[None], np.eye(3)[None, None], np.zeros((1, 3)), backend="numba",
    )  # fmt: skip


def ik_backend(backend: str = "auto") -> str:
    """``"numba"`` or ``"numpy"``: what :func:`solve_poses` runs with this ``backend``
    now (``"auto"`` on a machine that has not compiled the kernels yet starts their
    background compile and says ``"numpy"``; :func:`skincap.backends.resolve_backend`)."""
    return _resolve_backend(backend)


def _resolve_backend(backend: str) -> str:
    return resolve_backend(
        backend,
        numba_installed=numba_available(),
        feature="the numba inverse-kinematics kernels",
        kernel=("ik", ik_dispatcher),
    )


def _checked_model_inputs(
    parents: np.ndarray,
    offsets: np.ndarray,
    marker_segments: np.ndarray,
    marker_offsets: np.ndarray,
    measured: np.ndarray,
    init_rotations: np.ndarray,
    init_root: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The model and capture of :func:`solve_poses` as arrays, their shapes checked.

    Returns ``parents (S,) int64``, ``offsets (S, 3) float64`` metres,
    ``marker_segments (M,) int64``, ``marker_offsets (M, 3) float64`` metres and
    ``measured (T, M, 3) float64`` metres; raises :class:`ValidationError` when the
    markers or the initial poses ``(T, S, 3, 3)`` / ``(T, 3)`` do not fit them."""
    parents = np.asarray(parents, dtype=np.int64)
    offsets = np.asarray(offsets, dtype=np.float64)
    mseg = np.asarray(marker_segments, dtype=np.int64)
    moff = np.asarray(marker_offsets, dtype=np.float64)
    y = np.asarray(measured, dtype=np.float64)
    t_all, m, _ = y.shape
    s = parents.size
    if parents.ndim != 1 or (parents >= np.arange(s)).any() or (parents[1:] < 0).any():
        raise ValidationError("parents: expected one root first and every parent before its child")
    if mseg.shape != (m,) or moff.shape != (m, 3):
        raise ValidationError(
            f"marker_segments/offsets: expected ({m},) and ({m}, 3), got {mseg.shape} and {moff.shape}"
        )
    if init_rotations.shape != (t_all, s, 3, 3) or init_root.shape != (t_all, 3):
        raise ValidationError(
            "init_rotations/init_root: shapes do not match the frames and segments"
        )
    return parents, offsets, mseg, moff, y


def _checked_ik_options(
    s: int,
    link_stiffness: np.ndarray | None,
    loss: str,
    loss_scale: float,
    joint_limits: np.ndarray | None,
    limit_stiffness: float,
    bone_axes: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Check the options of :func:`solve_poses` for a model of ``s`` segments.

    Returns the link stiffness ``(S,) float64`` (metres per radian, zeros when none),
    the joint limits ``(S, 3, 2) float64`` radians or None, and the bone axes
    ``(S,) int64`` or None; raises :class:`ValidationError` on a bad option."""
    stiff = np.zeros(s) if link_stiffness is None else np.asarray(link_stiffness, dtype=np.float64)
    if stiff.shape != (s,) or not (np.isfinite(stiff).all() and (stiff >= 0).all()):
        raise ValidationError(
            f"link_stiffness: expected ({s},) finite values >= 0, got shape {stiff.shape}"
        )
    if loss not in LOSSES:
        raise ValidationError(f"loss: expected one of {', '.join(LOSSES)}, got {loss!r}")
    if not (np.isfinite(loss_scale) and loss_scale > 0):
        raise ValidationError(f"loss_scale: expected a positive number of metres, got {loss_scale}")
    limits = None
    if joint_limits is not None:
        limits = np.asarray(joint_limits, dtype=np.float64)
        lo, hi = limits[..., 0], limits[..., 1]
        if limits.shape != (s, 3, 2) or (np.isfinite(lo) & np.isfinite(hi) & (lo > hi)).any():
            raise ValidationError(
                f"joint_limits: expected ({s}, 3, 2) radians with low <= high (NaN: none), "
                f"got shape {limits.shape}"
            )
    if not (np.isfinite(limit_stiffness) and limit_stiffness > 0):
        raise ValidationError(f"limit_stiffness: expected a positive number, got {limit_stiffness}")
    bones = None if bone_axes is None else np.asarray(bone_axes, dtype=np.int64)
    if bones is not None and (bones.shape != (s,) or ((bones < 0) | (bones > 2)).any()):
        raise ValidationError(f"bone_axes: expected ({s},) values 0, 1 or 2")
    return stiff, limits, bones


def _solve_in_passes(
    problem: _IKProblem,
    y: np.ndarray,
    rot: np.ndarray,
    root: np.ndarray,
    chunk: int,
    warm_start: bool,
    progress: Progress | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve every frame of ``y (T, M, 3)`` metres in chunks of ``chunk`` frames.

    With ``warm_start`` (and 3 frames or more) the even frames are solved first and
    the odd ones then start where :func:`_start_odd_frames_between` says (``rot``
    ``(T, S, 3, 3)`` and ``root (T, 3)`` metres, the filled starting poses, are
    changed in place). Returns the solved ``(T, S, 3, 3)`` world rotations and
    ``(T, 3)`` root origins, metres."""
    t_all = y.shape[0]
    out_rot = np.empty_like(rot)
    out_root = np.empty_like(root)
    passes = [np.arange(t_all)]
    if warm_start and t_all >= 3:
        passes = [np.arange(0, t_all, 2), np.arange(1, t_all, 2)]
    done = 0
    for k, frames in enumerate(passes):
        if k == 1:
            _start_odd_frames_between(
                problem, y, rot, root, out_rot, out_root, frames, passes[0][-1]
            )
        for start in range(0, frames.size, chunk):
            sel = frames[start : start + chunk]
            out_rot[sel], out_root[sel] = _solve_chunk(problem, y[sel], rot[sel], root[sel])
            done += sel.size
            if progress is not None:
                progress(done / t_all, "inverse kinematics")
    return out_rot, out_root


def _start_odd_frames_between(
    problem: _IKProblem,
    y: np.ndarray,
    rot: np.ndarray,
    root: np.ndarray,
    out_rot: np.ndarray,
    out_root: np.ndarray,
    frames: np.ndarray,
    last_even: int,
) -> None:
    """Start the odd ``frames`` from the midpoint of their solved neighbours where that
    fits their markers better than their own start (a smooth motion).

    ``problem`` the model and its loss, ``y (T, M, 3)`` metres the
    capture, ``rot (T, S, 3, 3)`` / ``root (T, 3)`` metres the starting poses (the
    chosen frames are overwritten in place), ``out_rot`` / ``out_root`` the solved
    poses of the even frames, ``last_even`` the last even frame (the neighbour after
    an odd last frame)."""
    before = frames - 1
    after = np.minimum(frames + 1, last_even)
    rel = _log(np.einsum("tsji,tsjk->tsik", out_rot[before], out_rot[after]))
    mid_rot = out_rot[before] @ _exp(0.5 * rel)
    mid_root = 0.5 * (out_root[before] + out_root[after])
    use = _pose_cost(problem, y[frames], mid_rot, mid_root) < _pose_cost(
        problem, y[frames], rot[frames], root[frames]
    )
    rot[frames[use]] = mid_rot[use]
    root[frames[use]] = mid_root[use]


def _solve_chunk(
    problem: _IKProblem, y: np.ndarray, rot: np.ndarray, root: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the frames of ``y (T, M, 3)`` metres from poses ``rot``
    ``(T, S, 3, 3)`` / ``root (T, 3)`` metres (changed in place and returned)."""
    parents, offsets, mseg, moff = problem.parents, problem.offsets, problem.mseg, problem.moff
    paths, springs, n_par = problem.paths, problem.springs, problem.n_par
    loss, scale = problem.loss, problem.loss_scale
    tolerance, relative_tolerance = problem.tolerance, problem.relative_tolerance
    t, m, _ = y.shape
    seen = np.isfinite(y).all(axis=2)
    w_all = seen.astype(np.float64)  # (T, M)
    y_all = np.where(seen[..., None], y, 0.0)
    lam_all = np.full(t, 1e-3)
    x_all = model_markers(parents, offsets, mseg, moff, rot, root)
    spring_all = springs.residuals(rot)  # (T, L, 3)
    cost_all = _cost(x_all - y_all, w_all, loss, scale) + np.einsum(
        "tli,tli->t", spring_all, spring_all
    )
    # damping floor: keeps directions no marker constrains (a hidden hand) where they are
    floor = 1e-6
    active = np.arange(t)
    # single precision for the Jacobian products: they only choose the step (the cost and
    # the poses stay double), and halve the time of the dominant batched matmul
    jac_all = np.zeros((0 if problem.compiled else t, 3 * m, n_par), dtype=np.float32)
    ancestors = ancestor_blocks(parents)
    root_cols = np.tile(np.arange(3), m)
    all_rows = np.arange(3 * m)
    rows = 3 * paths.marker  # (Q,) first Jacobian row of each pair's marker
    cols = 3 + 3 * paths.segment
    # the six non-zero entries of each pair's 3x3 block, in the order of _SKEW_SIGN
    skew_rows = (rows[:, None] + np.array([0, 0, 1, 1, 2, 2])).reshape(-1)
    skew_cols = (cols[:, None] + np.array([1, 2, 0, 2, 0, 1])).reshape(-1)
    for _ in range(problem.iterations):
        if active.size == 0:
            break
        w, y0, lam = w_all[active], y_all[active], lam_all[active]
        r_a, o_a, x, cost = rot[active], root[active], x_all[active], cost_all[active]
        spring = spring_all[active]
        ta = active.size
        diff = x - y0
        if loss == "squared":
            sw = w  # 0/1: its own square root
        else:  # IRLS: rows scaled by the square root of each marker's weight
            _, irls = _marker_loss(np.einsum("tmi,tmi->tm", diff, diff), loss, scale)
            sw = w * np.sqrt(irls)
        resid = diff * sw[..., None]  # (Ta, M, 3), zero where missing
        if problem.compiled:
            g = np.zeros((ta, n_par))
            springs.add_gradient(g, spring)
            u, res = springs.limit_rows(r_a, spring)
            springs.add_limit_gradient(g, u, res)
            step = lm_steps(
                r_a, paths.local, paths.segment, paths.start, sw, resid, springs.normal, g,
                springs.lim_segment, springs.lim_parent, u, lam, floor, ancestors,
            )  # fmt: skip
        else:
            v = np.einsum("tqij,qj->tqi", r_a[:, paths.segment], paths.local)  # (Ta, Q, 3)
            v *= sw[:, paths.marker, None]  # rows of missing markers stay zero
            jac = jac_all[:ta]
            jac[:, all_rows, root_cols] = np.repeat(sw, 3, axis=1)  # d x / d root origin
            # d x / d w = w x v = -[v]x w,  -[v]x = [[0, vz, -vy], [-vz, 0, vx], [vy, -vx, 0]]
            jac[:, skew_rows, skew_cols] = (v[..., [2, 1, 2, 0, 1, 0]] * _SKEW_SIGN).reshape(ta, -1)
            jt = jac.transpose(0, 2, 1)
            h = (jt @ jac).astype(np.float64)  # (Ta, P, P), batched BLAS
            g = (jt @ resid.reshape(ta, -1, 1).astype(np.float32))[..., 0].astype(np.float64)
            h += springs.normal
            springs.add_gradient(g, spring)
            springs.add_limits(h, g, r_a, spring)
            diag = np.einsum("tii->ti", h)
            h[:, np.arange(n_par), np.arange(n_par)] += lam[:, None] * diag + floor
            step = -np.linalg.solve(h, g[..., None])[..., 0]  # (Ta, P)
        new_root = o_a + step[:, :3]
        if problem.compiled:
            new_rot = rotated(step[:, 3:].reshape(ta, -1, 3), r_a)
        else:
            new_rot = _exp(step[:, 3:].reshape(ta, -1, 3)) @ r_a
        new_x = model_markers(parents, offsets, mseg, moff, new_rot, new_root)
        new_spring = springs.residuals(new_rot)
        new_cost = _cost(new_x - y0, w, loss, scale) + np.einsum(
            "tli,tli->t", new_spring, new_spring
        )
        better = new_cost <= cost
        gain = cost - new_cost
        keep = active[better]
        root[keep] = new_root[better]
        rot[keep] = new_rot[better]
        x_all[keep] = new_x[better]
        spring_all[keep] = new_spring[better]
        cost_all[keep] = new_cost[better]
        lam_all[active] = np.where(better, np.maximum(lam / 10.0, 1e-9), lam * 10.0)
        # a frame is done when a step gains less than the tolerance (or damping is huge)
        limit = np.maximum(tolerance, relative_tolerance * new_cost)
        done = (better & (gain < limit)) | (lam_all[active] > 1e6)
        active = active[~done]
    return rot, root
