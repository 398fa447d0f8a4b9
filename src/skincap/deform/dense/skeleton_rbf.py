"""``skeleton_rbf``: a solved skeleton's dual-quaternion skinning plus one interpolation of
the markers' residuals (beyond Park & Hodgins §5).

The paper's near-rigid parts cannot follow skin that stretches between markers 5 cm
apart at a joint (the shoulder caps); a skeleton's skinning does, and the markers then
only have to carry what the skeleton misses (soft tissue, the skinning's own error):

1. **Base.** A skeleton solved from the take's own markers (the caller solves it: this
   layer does not import :mod:`skincap.solve`) is bound to the mesh in the reference
   frame's pose (bind transforms = the solved pose there, since the mesh stands in it),
   with automatic skin weights (:func:`~skincap.deform.skeletal.bind.bind_mesh`),
   corrected by the markers' own motion when their trajectories are given (each
   marker's weights fitted to its trajectory, the corrections carried to the vertices
   near it: :func:`fitted_skin_weights`); every frame is dual-quaternion skinned.
2. **Markers on the body.** Each marker takes the skin weights of the surface point
   under it in the reference frame (the nearest point's barycentric blend of its
   triangle's vertex weights), so it is skinned like the skin it sits on.
3. **Residual.** Per frame a marker's residual is measured minus skinned position,
   turned back into the reference pose by the inverse of its blended rotation; the
   residuals are interpolated to every vertex in the reference pose (one kernel matrix
   for the whole take) and each vertex's displacement is carried by its own blended
   transform: ``x_v = T_v(t) (v + d_v(t))`` = DQS(v) + R_v(t) d_v(t). At a marker this is
   ``s + R (R^T r) = s + r``: the markers are reproduced exactly.

A marker missing at a frame is left out of that frame's fit (the system of the markers
seen; each distinct set of missing markers is solved once per chunk); with none seen
the frame is the skinning alone. Vertices are never NaN.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse
from scipy.spatial.distance import cdist

from skincap._arrays import Progress
from skincap.errors import ValidationError
from skincap.geometry.dual_quaternions import dq_from_matrices
from skincap.geometry.kinematics import forward_kinematics
from skincap.geometry.rbf import cubic_bspline, dilation_from_spacing
from skincap.types import Mesh, Motion

__all__ = [
    "KERNELS",
    "SKIN_WEIGHTS",
    "SkeletonRBFDeformer",
    "blend_dual_quaternions",
    "build_skeleton_rbf",
    "fitted_skin_weights",
    "residual_kernel",
    "surface_point_weights",
]

#: Residual interpolants: polyharmonic ``r`` (3-D biharmonic), ``r² log r``, ``r³`` (each
#: with a linear polynomial), and the paper's compact cubic B-spline (σ = 2 × the largest
#: nearest-marker distance, no polynomial: the residual decays to 0 away from markers).
KERNELS: tuple[str, ...] = ("linear", "thin_plate", "cubic", "bspline")
#: Where the skin weights come from: bone heat corrected by the markers' motion, or bone
#: heat alone.
SKIN_WEIGHTS: tuple[str, ...] = ("fitted", "bone_heat")
#: Factored interpolation systems kept (one per set of markers seen).
_MAX_FACTORS = 64


def residual_kernel(r: np.ndarray, kernel: str, sigma: float) -> np.ndarray:
    """The radial kernel of ``kernel`` at distances ``r`` (metres; same shape out)."""
    if kernel == "linear":
        return r
    if kernel == "cubic":
        return r**3
    if kernel == "thin_plate":
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(r > 0, r * r * np.log(np.where(r > 0, r, 1.0)), 0.0)
    if kernel == "bspline":
        return cubic_bspline(r / sigma)
    raise ValidationError(f"kernel: expected one of {', '.join(KERNELS)}, got {kernel!r}")


def surface_point_weights(
    points: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    joint_indices: np.ndarray,
    joint_weights: np.ndarray,
    n_joints: int,
    *,
    max_influences: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Skin weights of the surface point nearest each of ``points``.

    Parameters
    ----------
    points : (N, 3) float, metres
    vertices : (V, 3) float, metres; faces : (F, 3) int
    joint_indices, joint_weights : (V, K) int / float, the vertices' skin
    n_joints : int
    max_influences : int
        Joints kept per point (the largest, renormalised).

    Returns
    -------
    indices : (N, max_influences) int64; weights : (N, max_influences) float64, rows
        summing to 1 (padding joints weigh 0).
    """
    from skincap.geometry.raycast import closest_points_on_mesh

    _, face, bary = closest_points_on_mesh(vertices, faces, points)
    corners = np.asarray(faces, dtype=np.int64)[face]  # (N, 3)
    n, k = corners.shape[0], joint_indices.shape[1]
    dense = np.zeros((n, n_joints))
    rows = np.repeat(np.arange(n), 3 * k)
    cols = joint_indices[corners].reshape(n, 3 * k)  # (N, 3K)
    vals = (bary[:, :, None] * joint_weights[corners]).reshape(n, 3 * k)
    np.add.at(dense, (rows, cols.ravel()), vals.ravel())
    m = min(int(max_influences), n_joints)
    idx = np.argsort(-dense, axis=1)[:, :m]
    w = np.take_along_axis(dense, idx, axis=1)
    w /= w.sum(axis=1, keepdims=True)
    return idx.astype(np.int64), w


def blend_dual_quaternions(
    dq: np.ndarray, joint_indices: np.ndarray, joint_weights: np.ndarray
) -> np.ndarray:
    """Unit blended dual quaternions of every point and frame (Kavan et al. 2008).

    Parameters
    ----------
    dq : (t, J, 8) float, the joints' unit dual quaternions
    joint_indices, joint_weights : (P, K)

    Returns
    -------
    (t, P, 8) float64: ``sum_k s_k w_k q_{j_k}``, each term's sign ``s_k`` taken against
    the point's largest-weight joint (antipodality), normalised.
    """
    n_t, n_j = dq.shape[:2]
    n_p, n_k = joint_indices.shape
    pivot = np.take_along_axis(joint_indices, np.argmax(joint_weights, axis=1)[:, None], 1)
    real = dq[..., :4]
    gram = np.einsum("tjc,tkc->tjk", real, real).reshape(n_t, n_j * n_j)
    dots = np.take(gram, (pivot * n_j + joint_indices).ravel(), axis=1)  # (t, P*K)
    w = joint_weights.ravel()
    coef = np.where(dots < 0.0, -w, w)
    cols = np.arange(n_t)[:, None] * n_j + joint_indices.ravel()[None]
    rows = np.arange(0, n_t * n_p * n_k + 1, n_k)
    # frames block-diagonal: one sparse product blends every frame's points
    blend = scipy.sparse.csr_matrix(
        (coef.ravel(), cols.ravel(), rows), shape=(n_t * n_p, n_t * n_j)
    ) @ dq.reshape(n_t * n_j, 8)
    blend = blend.reshape(n_t, n_p, 8)
    norm = np.linalg.norm(blend[..., :4], axis=-1, keepdims=True)  # >= the pivot's weight
    r, d = blend[..., :4] / norm, blend[..., 4:] / norm
    d = d - np.sum(r * d, axis=-1, keepdims=True) * r
    return np.concatenate([r, d], axis=-1)


def _rotate(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Rotate ``p`` (..., 3) by unit quaternions ``q`` (..., 4), scalar last."""
    u = np.cross(q[..., :3], p)
    return p + 2.0 * (q[..., 3:4] * u + np.cross(q[..., :3], u))


def _apply(dq: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``R p + t`` of unit dual quaternions (..., 8) on points (..., 3)."""
    rv, rw, dv, dw = dq[..., :3], dq[..., 3:4], dq[..., 4:7], dq[..., 7:8]
    return _rotate(dq[..., :4], p) + 2.0 * (rw * dv - dw * rv + np.cross(rv, dv))


def _unrotate(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``R^T p`` of unit quaternions ``q`` (..., 4)."""
    return _rotate(q * np.array([-1.0, -1.0, -1.0, 1.0]), p)


@dataclass(eq=False)
class SkeletonRBFDeformer:
    """DQS of a bound skeleton plus the markers' interpolated residual, streamed.

    Parameters
    ----------
    vertices : (V, 3) float, metres, the mesh in the reference pose
    joint_indices, joint_weights : (V, K) the vertices' skin
    marker_reference : (N, 3) float, metres, the markers in the reference pose
    marker_joint_indices, marker_joint_weights : (N, K') the markers' skin
        (:func:`surface_point_weights`)
    bind_world : (J, 4, 4) float, the skeleton's world transforms in the reference pose
    kernel : one of :data:`KERNELS`, default ``"thin_plate"``
    """

    vertices: np.ndarray
    joint_indices: np.ndarray
    joint_weights: np.ndarray
    marker_reference: np.ndarray
    marker_joint_indices: np.ndarray
    marker_joint_weights: np.ndarray
    bind_world: np.ndarray
    kernel: str = "thin_plate"

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=np.float64)
        c = np.asarray(self.marker_reference, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or c.ndim != 2 or c.shape[1] != 3:
            raise ValidationError(
                f"vertices (V, 3) and marker_reference (N, 3) expected; got {v.shape}, {c.shape}"
            )
        if not (np.isfinite(v).all() and np.isfinite(c).all()):
            raise ValidationError("vertices and marker_reference must be finite")
        if self.kernel not in KERNELS:
            raise ValidationError(
                f"kernel: expected one of {', '.join(KERNELS)}, got {self.kernel!r}"
            )
        bw = np.asarray(self.bind_world, dtype=np.float64)
        if bw.ndim != 3 or bw.shape[1:] != (4, 4):
            raise ValidationError(f"bind_world: expected (J, 4, 4), got {bw.shape}")
        for name, idx, w, n in (
            ("joint", self.joint_indices, self.joint_weights, v.shape[0]),
            ("marker_joint", self.marker_joint_indices, self.marker_joint_weights, c.shape[0]),
        ):
            if np.shape(idx) != np.shape(w) or np.shape(idx)[0] != n:
                raise ValidationError(
                    f"{name}_indices {np.shape(idx)} and {name}_weights {np.shape(w)} "
                    f"must be ({n}, K)"
                )
            if np.size(idx) and (np.min(idx) < 0 or np.max(idx) >= bw.shape[0]):
                raise ValidationError(f"{name}_indices: joints must be in 0..{bw.shape[0] - 1}")
        self.vertices, self.marker_reference, self.bind_world = v, c, bw
        self._inverse_bind = np.linalg.inv(bw)
        self.sigma = dilation_from_spacing(c) if self.kernel == "bspline" else 0.0
        self._polynomial = self.kernel != "bspline"
        d_cc = cdist(c, c)
        self._phi_cc = residual_kernel(d_cc, self.kernel, self.sigma)  # (N, N)
        # the vertices' kernel rows, once for the take (V, N) and their polynomial (V, 4)
        # (cdist: no (V, N, 3) difference array, 0.4 GB at 50k vertices)
        self._phi_vc = residual_kernel(cdist(v, c), self.kernel, self.sigma)
        self._poly_v = np.hstack([np.ones((v.shape[0], 1)), v])
        self._poly_c = np.hstack([np.ones((c.shape[0], 1)), c])
        self._factors: dict[bytes, tuple[Any, bool]] = {}

    @property
    def n_markers(self) -> int:
        return int(self.marker_reference.shape[0])

    def _factor(self, seen: np.ndarray) -> tuple[Any, bool]:
        """The interpolation system of the seen markers, factored once per set of markers
        (cached: a take with few gaps reuses one factorisation for all its frames);
        ``(lu, True)``, or ``(pseudo-inverse, False)`` where it is singular (too few or
        coplanar markers seen)."""
        key = seen.tobytes()
        if key in self._factors:
            return self._factors[key]
        idx = np.flatnonzero(seen)
        phi = self._phi_cc[np.ix_(idx, idx)]
        if self._polynomial:
            p = self._poly_c[idx]
            system = np.block([[phi, p], [p.T, np.zeros((4, 4))]])
        else:
            system = phi
        with warnings.catch_warnings():
            warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
            try:
                lu = scipy.linalg.lu_factor(system)
                pivots = np.abs(np.diag(lu[0]))
                if not pivots.min() > 1e-12 * pivots.max():
                    raise np.linalg.LinAlgError
                factor: tuple[Any, bool] = (lu, True)
            except (scipy.linalg.LinAlgWarning, ValueError, np.linalg.LinAlgError):
                factor = (np.linalg.pinv(system), False)
        if len(self._factors) >= _MAX_FACTORS:
            self._factors.pop(next(iter(self._factors)))
        self._factors[key] = factor
        return factor

    def _coefficients(self, seen: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Kernel (N, m) and polynomial (4, m) coefficients interpolating ``values``
        (n_seen, m) at the seen markers; 0 for the others (stacked (N + 4, m))."""
        n = self.n_markers
        out = np.zeros((n + 4, values.shape[1]))
        idx = np.flatnonzero(seen)
        if idx.size == 0:
            return out
        rhs = values
        if self._polynomial:
            rhs = np.vstack([values, np.zeros((4, values.shape[1]))])
        factor, is_lu = self._factor(seen)
        sol = scipy.linalg.lu_solve(factor, rhs) if is_lu else factor @ rhs
        out[idx] = sol[: idx.size]
        if self._polynomial:
            out[n:] = sol[idx.size :]
        return out

    def _skinning_dq(self, world: np.ndarray) -> np.ndarray:
        """(t, J, 8) dual quaternions of the skinning transforms ``world @ bind^-1``."""
        return dq_from_matrices(np.einsum("tjab,jbc->tjac", world, self._inverse_bind), atol=1e-5)

    def local_residuals(self, positions: np.ndarray, world: np.ndarray) -> np.ndarray:
        """(t, N, 3) markers' residuals (measured - skinned) in the reference pose, NaN
        where a marker is missing; ``positions`` (t, N, 3), ``world`` (t, J, 4, 4)."""
        dq = self._skinning_dq(world)
        mq = blend_dual_quaternions(dq, self.marker_joint_indices, self.marker_joint_weights)
        skinned = _apply(mq, self.marker_reference[None])
        return _unrotate(mq[..., :4], positions - skinned)

    def deform_frames(
        self, positions: np.ndarray, world: np.ndarray, points: np.ndarray | None = None,
        point_joint_indices: np.ndarray | None = None,
        point_joint_weights: np.ndarray | None = None,
    ) -> np.ndarray:  # fmt: skip
        """One block of frames.

        Parameters
        ----------
        positions : (t, N, 3) float, metres, NaN where missing
        world : (t, J, 4, 4) float, the skeleton's world transforms
        points, point_joint_indices, point_joint_weights : optional
            Deform these reference-pose points (P, 3) with their skin instead of the
            vertices (for the held-out markers and the exactness test).

        Returns
        -------
        (t, V, 3) or (t, P, 3) float64, metres, finite.
        """
        x = np.asarray(positions, dtype=np.float64)
        w = np.asarray(world, dtype=np.float64)
        n_t, n = x.shape[0], self.n_markers
        if x.ndim != 3 or x.shape[1:] != (n, 3) or w.shape[0] != n_t:
            raise ValidationError(
                f"positions (t, {n}, 3) and world (t, J, 4, 4) of one length expected; "
                f"got {x.shape} and {w.shape}"
            )
        local = self.local_residuals(x, w)  # (t, N, 3)
        seen = np.isfinite(local).all(axis=-1)  # (t, N)
        coef = np.zeros((n + 4, n_t, 3))
        patterns, which = np.unique(seen, axis=0, return_inverse=True)
        for k, pattern in enumerate(patterns):  # one solve per set of markers seen
            frames = np.flatnonzero(np.ravel(which) == k)
            if not pattern.any():
                continue  # no marker seen: the skinning alone
            vals = local[frames][:, pattern].transpose(1, 0, 2).reshape(int(pattern.sum()), -1)
            coef[:, frames] = self._coefficients(pattern, vals).reshape(n + 4, frames.size, 3)
        if points is None:
            phi, poly = self._phi_vc, self._poly_v
            base, idx, jw = self.vertices, self.joint_indices, self.joint_weights
        else:
            if point_joint_indices is None or point_joint_weights is None:
                raise ValidationError("points need point_joint_indices and point_joint_weights")
            base = np.asarray(points, dtype=np.float64)
            d = cdist(base, self.marker_reference)
            phi = residual_kernel(d, self.kernel, self.sigma)
            poly = np.hstack([np.ones((base.shape[0], 1)), base])
            idx, jw = np.asarray(point_joint_indices), np.asarray(point_joint_weights)
        flat = coef.reshape(n + 4, 3 * n_t)
        disp = phi @ flat[:n]  # (V, 3t)
        if self._polynomial:
            disp += poly @ flat[n:]
        disp = disp.reshape(-1, n_t, 3).transpose(1, 0, 2)  # (t, V, 3)
        vq = blend_dual_quaternions(self._skinning_dq(w), np.asarray(idx), np.asarray(jw))
        return _apply(vq, base[None] + disp)

    def deform(
        self,
        positions: np.ndarray,
        motion: Motion,
        *,
        chunk: int = 16,
        progress: Progress | None = None,
    ) -> Iterator[np.ndarray]:
        """Deform the mesh by a take and the skeleton's motion over it, in frame chunks.

        Parameters
        ----------
        positions : (T, N, 3) float, metres, NaN where missing
        motion : Motion
            The skeleton bound here, T frames (the one ``bind_world`` came from).
        chunk : int
            Frames per block.
        progress : callable(fraction, label), optional

        Yields
        ------
        (t, V, 3) float64 blocks, metres.
        """
        x = np.asarray(positions, dtype=np.float64)
        if motion.n_frames != x.shape[0]:
            raise ValidationError(f"motion has {motion.n_frames} frames for a take of {x.shape[0]}")
        if motion.skeleton.n_joints != self.bind_world.shape[0]:
            raise ValidationError(
                f"motion has {motion.skeleton.n_joints} joints; the binding {self.bind_world.shape[0]}"
            )
        world = forward_kinematics(motion)  # (T, J, 4, 4): small beside the vertices
        step = max(1, int(chunk))
        for t0 in range(0, x.shape[0], step):
            yield self.deform_frames(x[t0 : t0 + step], world[t0 : t0 + step])
            if progress is not None:
                progress(min(1.0, (t0 + step) / x.shape[0]), "deformation")


def build_skeleton_rbf(
    vertices: np.ndarray,
    faces: np.ndarray,
    marker_reference: np.ndarray,
    motion: Motion,
    reference_frame: int,
    *,
    positions: np.ndarray | None = None,
    skin_weights: str = "fitted",
    kernel: str = "thin_plate",
    max_influences: int = 4,
) -> SkeletonRBFDeformer:
    """Bind the mesh to a solved skeleton in the reference frame's pose, skin the markers.

    With ``skin_weights="fitted"`` and the markers' trajectories (``positions``) the
    bone-heat weights are corrected by the markers' own motion: each marker's weights
    over the joints near it that best explain its trajectory under the solved skeleton
    (:func:`~skincap.deform.skeletal.fit_weights.fit_point_skin_weights`, a pull toward
    its bone-heat weights where the motion does not decide), carried to the vertices as
    corrections of their bone-heat weights
    (:func:`~skincap.deform.skeletal.fit_weights.carry_weight_corrections`). The markers
    then take the weights of the surface under them, as with bone heat (the residual is
    measured in the frame the vertices there are skinned in).

    Parameters
    ----------
    vertices : (V, 3) float, metres, the mesh in the pose of ``reference_frame``
    faces : (F, 3) int
    marker_reference : (N, 3) float, metres, the markers in that frame (finite)
    motion : Motion
        The skeleton solved from the take (metres).
    reference_frame : int
        The frame of ``motion`` the mesh stands in: its pose is the bind pose.
    positions : (T, N, 3) float, metres, optional
        The markers over ``motion``'s frames (NaN where missing): what the weights are
        fitted to. Without it the weights are bone heat.
    skin_weights : {"fitted", "bone_heat"}
    kernel : one of :data:`KERNELS`
    max_influences : int
        Joints per vertex and per marker.

    Returns
    -------
    SkeletonRBFDeformer
    """
    from skincap.deform.skeletal.bind import bind_mesh

    if not 0 <= reference_frame < motion.n_frames:
        raise ValidationError(
            f"reference_frame {reference_frame} is outside 0..{motion.n_frames - 1}"
        )
    if skin_weights not in SKIN_WEIGHTS:
        raise ValidationError(
            f"skin_weights: expected one of {', '.join(SKIN_WEIGHTS)}, got {skin_weights!r}"
        )
    f = np.asarray(faces, dtype=np.int64)
    world = forward_kinematics(motion)  # (T, J, 4, 4)
    bind_world = world[reference_frame]
    mesh = bind_mesh(
        Mesh(vertices=np.asarray(vertices, dtype=np.float64), faces=f),
        motion.skeleton,
        rest_world=bind_world,
        max_influences=max_influences,
    )
    assert mesh.skin is not None  # bind_mesh always gives one
    idx, w = mesh.skin.joint_indices, mesh.skin.joint_weights
    if skin_weights == "fitted" and positions is not None:
        idx, w = fitted_skin_weights(
            mesh.vertices, f, idx, w, marker_reference, positions, world, bind_world,
            motion.skeleton.parents, max_influences=max_influences,
        )  # fmt: skip
    m_idx, m_w = surface_point_weights(
        marker_reference, mesh.vertices, f, idx, w, motion.skeleton.n_joints,
        max_influences=max_influences,
    )  # fmt: skip
    return SkeletonRBFDeformer(
        mesh.vertices, idx, w, marker_reference, m_idx, m_w, bind_world, kernel=kernel
    )


def fitted_skin_weights(
    vertices: np.ndarray,
    faces: np.ndarray,
    joint_indices: np.ndarray,
    joint_weights: np.ndarray,
    marker_reference: np.ndarray,
    positions: np.ndarray,
    world: np.ndarray,
    bind_world: np.ndarray,
    parents: np.ndarray,
    *,
    max_influences: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """The vertices' bone-heat weights corrected by the markers' motion.

    Parameters
    ----------
    vertices : (V, 3) float, metres, bind pose; faces : (F, 3) int
    joint_indices, joint_weights : (V, K) the vertices' bone-heat skin
    marker_reference : (N, 3) float, metres, the markers in the bind pose
    positions : (T, N, 3) float, metres, the markers over the take, NaN where missing
    world : (T, J, 4, 4) float, the skeleton's world transforms over the same frames
    bind_world : (J, 4, 4) float
    parents : (J,) int
    max_influences : int

    Returns
    -------
    indices, weights : (V, max_influences) int64 / float64, rows summing to 1.
    """
    from skincap.deform.skeletal.fit_weights import (
        carry_weight_corrections,
        dense_weights,
        fit_point_skin_weights,
    )

    x = np.asarray(positions, dtype=np.float64)
    wr = np.asarray(world, dtype=np.float64)
    c = np.asarray(marker_reference, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != c.shape or wr.shape[0] != x.shape[0]:
        raise ValidationError(
            f"positions: expected ({wr.shape[0]}, {c.shape[0]}, 3) (the motion's frames), "
            f"got {x.shape}"
        )
    n_j = wr.shape[1]
    skinning = np.einsum("tjab,jbc->tjac", wr, np.linalg.inv(bind_world))
    prior_v = dense_weights(joint_indices, joint_weights, n_j)
    m_idx, m_w = surface_point_weights(
        c, vertices, faces, joint_indices, joint_weights, n_j, max_influences=max_influences
    )
    prior_m = dense_weights(m_idx, m_w, n_j)
    fitted = fit_point_skin_weights(c, x, skinning, prior_m, parents)
    return carry_weight_corrections(
        vertices, prior_v, c, prior_m, fitted, max_influences=max_influences
    )
