"""Joint centres and hinge axes from the motion of two segments.

Functional methods, all linear least squares over every frame at once:

* **SCoRE** (Ehrig et al. 2006, "A survey of formal methods for determining the centre
  of rotation of ball joints"): the centre is a point fixed in both segments, ``c_p``
  in the parent's frame and ``c_c`` in the child's, so for every frame
  ``R_p c_p + t_p = R_c c_c + t_c``; stacked, ``[R_p, -R_c] [c_p; c_c] = t_c - t_p``
  (3T equations, 6 unknowns).
* **SARA** (Ehrig et al. 2007, "A survey of formal methods for determining functional
  joint axes"): the same system; for a hinge its matrix has a one-dimensional null
  space ``(a_p, a_c)`` with ``R_p a_p = R_c a_c`` -- the axis, fixed in both segments --
  found as the right singular vector of the smallest singular value. The centre is
  then any point of the axis; we take the one nearest a prior point (a regression
  estimate), since the data cannot tell.
* **Sphere fit** (for a child carried by fewer than three markers, which has no frame
  of its own): in the parent's frame every child marker keeps its distance to the
  centre, ``|y_m - c|^2 = r_m^2``, linear in ``c`` and ``k_m = r_m^2 - |c|^2``
  (the algebraic fit of a common centre; Gamage & Lasenby 2002).

The range of motion decides which applies (:func:`motion_spread`): the RMS spread of
the relative rotation vectors (or of the marker directions, for a sphere fit) along its
principal axes, in degrees. A ball joint needs two axes with at least
:data:`MIN_SPREAD_DEG` of spread for its centre; one such axis gives an axis (the
centre is then taken on it nearest the regression estimate); none gives the regression
estimate alone. Units: whatever the positions are in (metres in skincap).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError

__all__ = [
    "MIN_SPREAD_DEG",
    "score_centre",
    "sara_axis",
    "sphere_centre",
    "motion_spread",
    "direction_spread",
    "harrington_hip_centres",
    "closest_on_line",
    "principal_axis",
    "slide_along_axis",
    "fit_singular_values",
]

#: Least RMS spread of the relative rotation (degrees) along a principal axis that
#: counts as motion about that axis for the functional methods.
MIN_SPREAD_DEG = 5.0


def _frames(
    rotations: np.ndarray, translations: np.ndarray, name: str
) -> tuple[np.ndarray, np.ndarray]:
    r = np.asarray(rotations, dtype=np.float64)
    t = np.asarray(translations, dtype=np.float64)
    if r.ndim != 3 or r.shape[1:] != (3, 3) or t.shape != (r.shape[0], 3):
        raise ValidationError(
            f"{name}: expected rotations (T, 3, 3) and translations (T, 3); got {r.shape} and {t.shape}"
        )
    return r, t


def _system(
    r_parent: np.ndarray, t_parent: np.ndarray, r_child: np.ndarray, t_child: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """SCoRE's stacked system (3T', 6), (3T',) over the frames where both poses are known."""
    r_p, t_p = _frames(r_parent, t_parent, "parent")
    r_c, t_c = _frames(r_child, t_child, "child")
    if r_p.shape[0] != r_c.shape[0]:
        raise ValidationError(
            f"parent and child: different frame counts {r_p.shape[0]} and {r_c.shape[0]}"
        )
    ok = (
        np.isfinite(r_p).all(axis=(1, 2))
        & np.isfinite(r_c).all(axis=(1, 2))
        & np.isfinite(t_p).all(axis=1)
        & np.isfinite(t_c).all(axis=1)
    )
    a = np.concatenate([r_p[ok], -r_c[ok]], axis=2).reshape(-1, 6)  # (3T', 6)
    b = (t_c[ok] - t_p[ok]).reshape(-1)
    return a, b


def fit_singular_values(
    r_parent: np.ndarray, t_parent: np.ndarray, r_child: np.ndarray, t_child: np.ndarray
) -> np.ndarray:
    """(6,) singular values of the SCoRE/SARA system over ``sqrt(T)``, descending.

    Each is the RMS rotation (radians, small angles) with which the take determines the
    centre along one direction of the solution: the three largest are about
    ``sqrt(2)`` (the centre's common translation), the three smallest measure the
    joint's range about each axis. Their ratio is the fit's condition: a centre error
    ``e`` along the last direction moves the fitted points by ``e * s[5]`` on average,
    so soft-tissue motion of ``d`` metres places it within about ``d / s[5]``. The last
    over the fifth near 0: a clean hinge (SARA's axis is well defined). Zeros for fewer
    than three frames with both poses.
    """
    a, _ = _system(r_parent, t_parent, r_child, t_child)
    if a.shape[0] < 9:
        return np.zeros(6)
    return np.linalg.svd(a, compute_uv=False) / np.sqrt(a.shape[0] / 3)


def score_centre(
    r_parent: np.ndarray,
    t_parent: np.ndarray,
    r_child: np.ndarray,
    t_child: np.ndarray,
    *,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
    prior_spread_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre of a ball joint by SCoRE.

    Parameters
    ----------
    r_parent, r_child : (T, 3, 3) float
        World rotations of the two segments' frames (NaN frames are skipped).
    t_parent, t_child : (T, 3) float, metres
        World origins of the frames.
    prior : ((3,), (3,)) float, optional
        A regression estimate of the centre in the parent's and the child's frame.
    prior_spread_deg : float, default 0
        With ``prior``: the directions of the solution (right singular vectors of the
        stacked system) whose singular value ``s`` has ``s^2 < T radians(spread)^2`` --
        a direction the joint determines through rotations of RMS spread ``s / sqrt(T)``
        -- take the prior's component; the others the data's. A take that turns the
        joint well about every axis is untouched (the exact-rotation recovery holds);
        a walking ankle, whose few degrees of inversion are mostly soft-tissue wobble
        and would place the centre anywhere along the dorsiflexion axis, keeps the
        prior along it. 0: plain SCoRE.

    Returns
    -------
    centre_parent : (3,) float64
        The centre in the parent's frame.
    centre_child : (3,) float64
        The centre in the child's frame.
    rms : float
        RMS distance between the two estimates of the world centre over the frames.

    Raises
    ------
    ValidationError
        Fewer than 3 frames with both poses.
    """
    a, b = _system(r_parent, t_parent, r_child, t_child)
    if a.shape[0] < 9:
        raise ValidationError("score_centre: fewer than 3 frames where both segments are seen")
    if prior is not None and prior_spread_deg > 0:
        # the system's singular directions: those with s^2 >= T spread^2 from the data,
        # the others (the take hardly turns the joint there) from the prior
        x_prior = np.concatenate([np.asarray(p, float) for p in prior])
        u, sv, vt = np.linalg.svd(a, full_matrices=False)
        strong = sv**2 >= (a.shape[0] / 3) * np.radians(prior_spread_deg) ** 2
        coef = np.where(strong, (u.T @ b) / np.where(strong, sv, 1.0), vt @ x_prior)
        x = vt.T @ coef
    else:
        x, *_ = np.linalg.lstsq(a, b, rcond=None)
    rms = float(np.sqrt(np.mean((a @ x - b).reshape(-1, 3) ** 2) * 3)) if b.size else 0.0
    return x[:3], x[3:], rms


def sara_axis(
    r_parent: np.ndarray,
    t_parent: np.ndarray,
    r_child: np.ndarray,
    t_child: np.ndarray,
    prior_parent: np.ndarray | None = None,
    prior_child: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Axis of a hinge by SARA, and the point of it nearest a prior centre.

    Parameters
    ----------
    r_parent, t_parent, r_child, t_child
        As for :func:`score_centre`.
    prior_parent, prior_child : (3,) float, optional
        A prior centre (e.g. a regression estimate) in each segment's frame; the
        returned centre is the point of the axis nearest them (least squares over
        both). Default: the minimum-norm solution.

    Returns
    -------
    axis_parent, axis_child : (3,) float64
        Unit axis direction in each frame (``R_p a_p = R_c a_c``); its sign is arbitrary.
    centre_parent, centre_child : (3,) float64
        The chosen point of the axis in each frame.
    """
    a, b = _system(r_parent, t_parent, r_child, t_child)
    if a.shape[0] < 9:
        raise ValidationError("sara_axis: fewer than 3 frames where both segments are seen")
    _, _, vt = np.linalg.svd(a, full_matrices=False)
    null = vt[-1]  # (6,) the direction the data do not constrain: the axis in both frames
    null = null / np.linalg.norm(null[:3])
    x0 = np.linalg.pinv(a, rcond=1e-10) @ b
    # x0 has no component along the null vector (minimum norm); slide along it
    x0 = x0 - null * (x0 @ null) / (null @ null)
    axis_p = null[:3] / np.linalg.norm(null[:3])
    axis_c = null[3:] / np.linalg.norm(null[3:])
    if prior_parent is not None and prior_child is not None:
        cp, cc = slide_along_axis(x0[:3], x0[3:], null[:3], null[3:], prior_parent, prior_child)
        return axis_p, axis_c, cp, cc
    return axis_p, axis_c, x0[:3], x0[3:]


def slide_along_axis(
    centre_parent: np.ndarray,
    centre_child: np.ndarray,
    axis_parent: np.ndarray,
    axis_child: np.ndarray,
    prior_parent: np.ndarray,
    prior_child: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The centre moved along the joint's axis to the point nearest a prior.

    The centre ``(c_p, c_c)`` and the axis ``(a_p, a_c)`` (``R_p a_p = R_c a_c``: one
    world line) are given in the parent's and the child's frame; the result is
    ``(c_p + s a_p, c_c + s a_c)`` with ``s`` the least-squares fit of the prior in
    both frames, so only the position along the axis -- the one a joint turning
    about that axis does not determine -- changes. All (3,) float, metres; the axes
    need not be unit (they are scaled alike).
    """
    c = np.concatenate([np.asarray(centre_parent, float), np.asarray(centre_child, float)])
    n = np.concatenate([np.asarray(axis_parent, float), np.asarray(axis_child, float)])
    prior = np.concatenate([np.asarray(prior_parent, float), np.asarray(prior_child, float)])
    c = c + n * ((prior - c) @ n) / (n @ n)
    return c[:3], c[3:]


def sphere_centre(
    points_parent: np.ndarray, prior: np.ndarray | None = None, *, hinge: bool = False
) -> tuple[np.ndarray, np.ndarray | None]:
    """Common centre of the spheres the child markers move on, in the parent's frame.

    Parameters
    ----------
    points_parent : (T, K, 3) float, metres
        Child markers expressed in the parent's frame; NaN where missing.
    prior : (3,) float, optional
        With ``hinge``: the centre is the point of the axis nearest this.
    hinge : bool
        The markers turn about one axis: the centre along it is undetermined, so the
        axis is found (the least-determined direction) and the prior picks the point.

    Returns
    -------
    centre : (3,) float64
    axis : (3,) float64 or None
        Unit hinge axis in the parent's frame when ``hinge``.
    """
    y = np.asarray(points_parent, dtype=np.float64)
    if y.ndim != 3 or y.shape[2] != 3:
        raise ValidationError(f"points_parent: expected (T, K, 3), got {y.shape}")
    k = y.shape[1]
    shift = np.nanmean(y.reshape(-1, 3), axis=0)  # centred columns condition the fit
    # |y - c|^2 = r^2  <=>  |ys|^2 = 2 ys.(c - shift) + (r^2 - |c - shift|^2), ys = y - shift
    rows = []
    rhs = []
    for m in range(k):
        ym = y[:, m][np.isfinite(y[:, m]).all(axis=1)] - shift
        block = np.zeros((ym.shape[0], 3 + k))
        block[:, :3] = 2.0 * ym
        block[:, 3 + m] = 1.0
        rows.append(block)
        rhs.append(np.einsum("ti,ti->t", ym, ym))
    a2 = np.concatenate(rows)
    b2 = np.concatenate(rhs)
    if a2.shape[0] < 3 + k + 1:
        raise ValidationError("sphere_centre: too few samples of the child markers")
    if not hinge:
        x, *_ = np.linalg.lstsq(a2, b2, rcond=None)
        return x[:3] + shift, None
    _, _, vt = np.linalg.svd(a2, full_matrices=False)
    null = vt[-1]
    axis = null[:3] / np.linalg.norm(null[:3])
    x0 = np.linalg.pinv(a2, rcond=1e-10) @ b2
    c0 = x0[:3] + shift
    if prior is not None:
        c0 = closest_on_line(c0, axis, np.asarray(prior, float))
    return c0, axis


def closest_on_line(
    point_on_line: np.ndarray, direction: np.ndarray, target: np.ndarray
) -> np.ndarray:
    """(3,) point of the line ``point_on_line + s * direction`` nearest ``target``."""
    d = direction / np.linalg.norm(direction)
    return point_on_line + d * ((target - point_on_line) @ d)


def _spread_deg(vectors: np.ndarray) -> np.ndarray:
    v = vectors[np.isfinite(vectors).all(axis=1)]
    if v.shape[0] < 3:
        return np.zeros(3)
    v = v - v.mean(axis=0)
    s = np.linalg.svd(v, compute_uv=False) / np.sqrt(v.shape[0])
    return np.degrees(np.pad(s, (0, 3 - s.size)))


def motion_spread(r_parent: np.ndarray, r_child: np.ndarray) -> np.ndarray:
    """(3,) RMS spread in degrees of the relative rotation along its principal axes.

    The relative rotations ``R_p^T R_c`` are taken relative to their (chordal) mean
    and turned into rotation vectors; the singular values of those vectors, divided by
    ``sqrt(T)``, descending. NaN frames are skipped.
    """
    r_p = np.asarray(r_parent, float)
    r_c = np.asarray(r_child, float)
    ok = np.isfinite(r_p).all(axis=(1, 2)) & np.isfinite(r_c).all(axis=(1, 2))
    if ok.sum() < 3:
        return np.zeros(3)
    rel = np.einsum("tji,tjk->tik", r_p[ok], r_c[ok])
    mean = Rotation.from_matrix(rel).mean()
    vec = (mean.inv() * Rotation.from_matrix(rel)).as_rotvec()
    return _spread_deg(vec)


def principal_axis(r_parent: np.ndarray, r_child: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The axis a joint turns about most, in the parent's and the child's frame.

    The first principal direction of the relative rotations ``R_p^T R_c`` about their
    mean (:func:`motion_spread`'s largest spread): ``(a_p, a_c)``, (3,) unit float64
    each, ``a_p = M a_c`` with ``M`` the mean relative rotation; the sign is arbitrary.
    Its RMS spread is :func:`motion_spread`'s first value. NaN frames are skipped;
    NaN axes with fewer than three frames.
    """
    r_p = np.asarray(r_parent, float)
    r_c = np.asarray(r_child, float)
    ok = np.isfinite(r_p).all(axis=(1, 2)) & np.isfinite(r_c).all(axis=(1, 2))
    if ok.sum() < 3:
        return np.full(3, np.nan), np.full(3, np.nan)
    rel = Rotation.from_matrix(np.einsum("tji,tjk->tik", r_p[ok], r_c[ok]))
    mean = rel.mean()
    vec = (mean.inv() * rel).as_rotvec()  # small turns about the mean, child's frame
    vec = vec - vec.mean(axis=0)
    axis_c = np.linalg.svd(vec, full_matrices=False)[2][0]
    return mean.apply(axis_c), axis_c


def direction_spread(points_parent: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(2,) RMS spread in degrees of the directions from ``centre`` to the markers.

    ``points_parent`` (T, K, 3): child markers in the parent's frame; the directions
    of all markers (each relative to its own mean direction) are pooled.
    """
    y = np.asarray(points_parent, float) - centre
    vecs = []
    for m in range(y.shape[1]):
        ym = y[:, m][np.isfinite(y[:, m]).all(axis=1)]
        if ym.shape[0] < 3:
            continue
        u = ym / np.linalg.norm(ym, axis=1, keepdims=True)
        mean = u.mean(axis=0)
        mean /= np.linalg.norm(mean)
        # small-angle tangent coordinates: the rotation vector carrying the mean onto u
        vecs.append(np.cross(mean, u))
    if not vecs:
        return np.zeros(2)
    return _spread_deg(np.concatenate(vecs))[:2]


def harrington_hip_centres(
    lasi: np.ndarray, rasi: np.ndarray, lpsi: np.ndarray, rpsi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Hip joint centres by Harrington et al. (2007) regression, per frame.

    In the pelvis frame (origin mid-ASIS, x anterior, y superior, z to the right):
    ``x = -0.24 PD - 9.9 mm``, ``y = -0.30 PW - 10.9 mm``, ``z = +-(0.33 PW + 7.3 mm)``,
    with PW the inter-ASIS and PD the mid-ASIS to mid-PSIS distance (both averaged
    over the take; mean error against MRI ~ 14 mm in the paper).

    Parameters
    ----------
    lasi, rasi, lpsi, rpsi : (T, 3) float, metres, Y up
        Pelvis markers (front and back of the iliac crests: PiG ``LASI``, CMU
        ``LFWT``...). NaN frames give NaN.

    Returns
    -------
    left, right : (T, 3) float64, metres
        World hip centres.
    """
    la, ra, lp, rp = (np.asarray(v, float) for v in (lasi, rasi, lpsi, rpsi))
    mid_asis = 0.5 * (la + ra)
    mid_psis = 0.5 * (lp + rp)
    right = ra - la
    pw = float(np.nanmedian(np.linalg.norm(right, axis=1)))
    pd = float(np.nanmedian(np.linalg.norm(mid_asis - mid_psis, axis=1)))
    z = right / np.linalg.norm(right, axis=1, keepdims=True)
    fwd = mid_asis - mid_psis
    x = fwd - z * np.einsum("ti,ti->t", fwd, z)[:, None]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    ax = -0.24 * pd - 0.0099
    ay = -0.30 * pw - 0.0109
    az = 0.33 * pw + 0.0073
    base = mid_asis + ax * x + ay * y
    return base - az * z, base + az * z
