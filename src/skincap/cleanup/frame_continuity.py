"""Rigid fits that stay determined when the seen points are nearly collinear.

A rotation fitted to points on (or near) a line leaves the twist about that line to the
points' small spread off it, so measurement noise turns it freely; every point off the
line that the fit carries (a missing marker estimated from three seen neighbours in a
row, a local frame fitted to them) swings with it. Here the twist falls back on
temporal continuity: a prior rotation ``Q`` is built from two well-determined
rotations at the ends of the interval the fit lies in (frames where enough markers are
seen), each carried by the smallest rotation that turns the line onto its present
direction (the line's direction itself is well determined by the points), their twist
about the line interpolated in time. The fit then minimises

    Σ_k w_k ||R s_k + t - d_k||² + μ ||R - Q||²_F,
    μ = w̄ σ² / (2 θ0²) · max(0, 1 - c / c0)

the maximum a posteriori rotation for points of noise ``σ`` (per axis, metres; ``w̄``
the points' mean weight) and a prior whose twist is off by ``θ0`` radians
(``||R - Q||²_F ≈ 2 θ²`` for a rotation ``θ`` away): the points decide the twist
where their spread off the line fixes it better than ``θ0``, the prior where noise
would turn it further. ``c`` is the points' conditioning (:func:`line_axis`: about
``f²`` for points spread ``f`` of their length off a line); the prior fades out by
``c0`` (:data:`WELL_SPREAD`), leaving the fits of well-spread points exactly as they
were. The extra term adds ``μ Q^T`` to the Kabsch cross-covariance; it is entered as
six virtual correspondences ``c_s ± h e_j -> c_d ± h Q e_j`` (symmetric about the
centroids, so the translation is unchanged) and solved by
:func:`skincap.geometry.rigid.fit_rigid`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.cleanup.outliers import measurement_noise
from skincap.geometry.rigid import fit_rigid

__all__ = ["WELL_SPREAD", "line_axis", "take_noise", "twist_prior", "fit_rigid_with_prior"]

#: Conditioning (:func:`line_axis`) from which a point set fixes its own rotation and
#: takes no prior: points spread a fifth of their length off their line.
WELL_SPREAD = 0.2**2


def take_noise(positions: np.ndarray) -> float:
    """The take's typical measurement noise σ per axis (metres): the median over its
    markers of :func:`~skincap.cleanup.outliers.measurement_noise`; 0 when unknown.

    positions (T, N, 3) metres, NaN where missing.
    """
    sigma = measurement_noise(positions)
    return float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else 0.0


def _weighted_centred(
    points: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights (..., K) zeroed where a point is not finite, centroids (..., 3) and the
    centred points (..., K, 3) (0 where excluded)."""
    w = np.where(np.isfinite(points).all(axis=-1) & np.isfinite(weights), weights, 0.0)
    w = np.maximum(w, 0.0)
    pz = np.where(w[..., None] > 0, points, 0.0)
    wsum = w.sum(axis=-1)
    c = np.einsum("...k,...kc->...c", w, pz) / np.maximum(wsum, 1e-300)[..., None]
    return w, c, np.where(w[..., None] > 0, pz - c[..., None, :], 0.0)


def line_axis(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point set's principal direction and how poorly it fixes the twist about it.

    Parameters
    ----------
    points : (..., K, 3) float, metres; NaN points are ignored
    weights : (..., K) float >= 0

    Returns
    -------
    axis : (..., 3) float64
        Unit principal axis of the weighted centred points (sign arbitrary).
    conditioning : (..., ) float64
        ``(σ2² + σ3²) / (σ1² + σ2²)`` from the singular values of the weighted centred
        points: the smallest over the largest moment of inertia, i.e. how well the
        rotation about ``axis`` is determined relative to the best-determined axis
        (0 for collinear points; NaN without any spread).
    """
    w, _, cen = _weighted_centred(np.asarray(points, dtype=np.float64), np.asarray(weights))
    cov = np.einsum("...k,...ki,...kj->...ij", w, cen, cen)  # (..., 3, 3)
    ev, vec = np.linalg.eigh(cov)  # ascending: σ3², σ2², σ1²
    ev = np.maximum(ev, 0.0)
    top = ev[..., 2] + ev[..., 1]
    cond = np.where(top > 0, (ev[..., 0] + ev[..., 1]) / np.where(top > 0, top, 1.0), np.nan)
    return vec[..., :, 2], cond


def _swing(frm: np.ndarray, to: np.ndarray) -> Rotation:
    """The smallest rotations (batch) turning unit vectors ``frm`` (S, 3) onto ``to``."""
    cross = np.cross(frm, to)
    sin = np.linalg.norm(cross, axis=-1)
    cos = np.einsum("si,si->s", frm, to)
    angle = np.arctan2(sin, cos)
    axis = cross / np.where(sin > 1e-12, sin, 1.0)[:, None]
    return Rotation.from_rotvec(axis * np.where(sin > 1e-12, angle, 0.0)[:, None])


def twist_prior(
    rot_fit: np.ndarray,
    axis: np.ndarray,
    rot_start: np.ndarray,
    rot_end: np.ndarray,
    u: np.ndarray,
) -> np.ndarray:
    """Prior rotations: the end rotations swung onto the fitted line, twist interpolated.

    Parameters
    ----------
    rot_fit : (S, 3, 3) float
        The plain fit in each row: only its image of ``axis`` is used.
    axis : (S, 3) float
        The line's unit direction in source coordinates (:func:`line_axis`).
    rot_start, rot_end : (S, 3, 3) float
        Well-determined rotations at the interval's start and end; NaN where that end
        is unknown (the other end alone is then used; both NaN: NaN prior).
    u : (S,) float in [0, 1]
        Position between the start (0) and the end (1).

    Returns
    -------
    (S, 3, 3) float64 proper rotations; NaN where the row has neither end or no fit.
    """
    s = axis.shape[0]
    out = np.full((s, 3, 3), np.nan)
    has_s = np.isfinite(rot_start).all(axis=(1, 2))
    has_e = np.isfinite(rot_end).all(axis=(1, 2))
    fit_ok = np.isfinite(rot_fit).all(axis=(1, 2)) & np.isfinite(axis).all(axis=1)
    rows = np.nonzero(fit_ok & (has_s | has_e))[0]
    if rows.size == 0:
        return out
    a = axis[rows]
    d = np.einsum("sij,sj->si", rot_fit[rows], a)  # the line's present direction
    eye = np.broadcast_to(np.eye(3), (rows.size, 3, 3))
    r0 = np.where(has_s[rows][:, None, None], rot_start[rows], eye)
    r1 = np.where(has_e[rows][:, None, None], rot_end[rows], eye)
    q0 = _swing(np.einsum("sij,sj->si", r0, a), d) * Rotation.from_matrix(r0)
    q1 = _swing(np.einsum("sij,sj->si", r1, a), d) * Rotation.from_matrix(r1)
    # q1 q0⁻¹ turns about d only: interpolate that twist from q0 (u = 0) to q1 (u = 1)
    uu = np.where(has_s[rows], np.where(has_e[rows], np.clip(u[rows], 0.0, 1.0), 0.0), 1.0)
    rel = (q1 * q0.inv()).as_rotvec()
    out[rows] = (Rotation.from_rotvec(rel * uu[:, None]) * q0).as_matrix()
    return out


def fit_rigid_with_prior(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray,
    prior: np.ndarray,
    *,
    noise: float,
    twist_sd: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid fits ``dst ≈ R src + t`` pulled towards prior rotations (module docstring).

    Parameters
    ----------
    src, dst : (S, K, 3) float, metres
        Correspondences; a point NaN in either is ignored.
    weights : (S, K) float >= 0
    prior : (S, 3, 3) float
        Prior rotations; a NaN row is fitted without a prior.
    noise : float >= 0, metres
        The points' measurement noise σ per axis (0: no prior).
    twist_sd : float > 0, radians
        ``θ0``: how far the prior's twist may be off.

    Returns
    -------
    R : (S, 3, 3), t : (S, 3) as :func:`skincap.geometry.rigid.fit_rigid` (NaN with
    fewer than three points).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    both = np.isfinite(src).all(axis=-1) & np.isfinite(dst).all(axis=-1)
    w = np.where(both, np.asarray(weights, dtype=np.float64), 0.0)
    w, cs, cen = _weighted_centred(src, w)
    _, cd, _ = _weighted_centred(dst, w)
    count = (w > 0).sum(axis=-1)
    wsum = w.sum(axis=-1)
    h = np.sqrt(np.einsum("sk,skc,skc->s", w, cen, cen) / np.maximum(wsum, 1e-300))
    _, cond = line_axis(src, w)
    fade = np.clip(1.0 - np.nan_to_num(cond, nan=1.0) / WELL_SPREAD, 0.0, 1.0)
    mu = wsum / np.maximum(count, 1) * noise**2 / (2.0 * twist_sd**2) * fade
    use = np.isfinite(prior).all(axis=(1, 2)) & (h > 0) & (count >= 3) & (mu > 0)
    # six virtual pairs of weight wv each add 2 wv h² Q^T = μ Q^T to the cross-covariance
    wv = np.where(use, mu / (2.0 * np.where(h > 0, h, 1.0) ** 2), 0.0)
    e = np.concatenate([np.eye(3), -np.eye(3)])  # (6, 3)
    q = np.where(use[:, None, None], prior, np.eye(3))
    vs = cs[:, None, :] + h[:, None, None] * e[None]  # (S, 6, 3)
    vd = cd[:, None, :] + h[:, None, None] * np.einsum("sij,vj->svi", q, e)
    src_all = np.concatenate([np.where(w[..., None] > 0, src, 0.0), vs], axis=1)
    dst_all = np.concatenate([np.where(w[..., None] > 0, dst, 0.0), vd], axis=1)
    w_all = np.concatenate([w, np.repeat(wv[:, None], 6, axis=1)], axis=1)
    rot, tr = fit_rigid(src_all, dst_all, weights=w_all)
    few = count < 3
    rot[few] = np.nan
    tr[few] = np.nan
    return rot, tr
