"""Vectorised quaternion helpers, scalar-last ``(x, y, z, w)`` like scipy's ``Rotation``.

Every function broadcasts over leading axes and never loops in Python. A quaternion
``q`` acts on a vector ``v`` as ``q v q*``; the product ``quat_multiply(a, b)`` is the
rotation that applies ``b`` first and then ``a`` (the same as ``Rotation(a) * Rotation(b)``
and as the matrix product ``quat_to_matrix(a) @ quat_to_matrix(b)``).

Euler angles go through :class:`scipy.spatial.transform.Rotation`. The axis strings
follow scipy: UPPERCASE letters are *intrinsic* rotations (about the axes of the frame
as it turns), which is the BVH convention -- channels ``Zrotation Yrotation Xrotation``
mean ``R = Rz @ Ry @ Rx`` and are the sequence ``"ZYX"``.

NaN behaviour: NaN in an input quaternion or vector propagates to the outputs of the
same element (no warnings are raised for it), except in the Euler helpers, which use
scipy and reject non-finite input with a ValidationError.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError

__all__ = [
    "quat_identity",
    "quat_multiply",
    "quat_conjugate",
    "quat_inverse",
    "quat_normalize",
    "quat_canonical",
    "quat_apply",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_angle",
    "euler_to_quat",
    "quat_to_euler",
]


def _quat(name: str, q: np.ndarray) -> np.ndarray:
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 4:
        raise ValidationError(
            f"{name}: expected quaternions of shape (..., 4) (x, y, z, w), got {arr.shape}"
        )
    return arr


def _vec3(name: str, v: np.ndarray) -> np.ndarray:
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValidationError(f"{name}: expected vectors of shape (..., 3), got {arr.shape}")
    return arr


def quat_identity(shape: tuple[int, ...] | int = ()) -> np.ndarray:
    """Identity quaternions.

    Parameters
    ----------
    shape : tuple of int or int
        Leading shape ``S``.

    Returns
    -------
    (*S, 4) float64
        ``(0, 0, 0, 1)`` everywhere.
    """
    lead = (shape,) if isinstance(shape, int) else tuple(shape)
    q = np.zeros(lead + (4,), dtype=np.float64)
    q[..., 3] = 1.0
    return q


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b``: the rotation applying ``b`` first, then ``a``.

    Parameters
    ----------
    a, b : (..., 4) float, scalar-last
        Broadcast against each other. Need not be unit quaternions.

    Returns
    -------
    (..., 4) float64
        The product (unit when both inputs are unit). NaN propagates.

    Examples
    --------
    >>> z90 = np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    >>> np.round(quat_multiply(z90, z90), 12)  # 180 degrees about z
    array([0., 0., 1., 0.])
    """
    a = _quat("a", a)
    b = _quat("b", b)
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """``(-x, -y, -z, w)``: the inverse rotation of a unit quaternion.

    Parameters
    ----------
    q : (..., 4) float

    Returns
    -------
    (..., 4) float64
    """
    q = _quat("q", q)
    out = -q
    out[..., 3] = q[..., 3]
    return out


def quat_inverse(q: np.ndarray) -> np.ndarray:
    """Multiplicative inverse ``q* / |q|^2`` (equals the conjugate for unit quaternions).

    Parameters
    ----------
    q : (..., 4) float
        A zero quaternion gives NaN (without a warning).

    Returns
    -------
    (..., 4) float64
    """
    q = _quat("q", q)
    n2 = np.sum(q * q, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return quat_conjugate(q) / np.where(n2 > 0, n2, np.nan)


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale quaternions to unit length.

    Parameters
    ----------
    q : (..., 4) float
        A zero quaternion gives NaN (without a warning).

    Returns
    -------
    (..., 4) float64
    """
    q = _quat("q", q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return q / np.where(n > 0, n, np.nan)


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """The representative of ``{q, -q}`` with ``w >= 0`` (ties broken on x, then y, then z).

    ``q`` and ``-q`` are the same rotation; this picks one so quaternions can be compared
    element-wise.

    Parameters
    ----------
    q : (..., 4) float

    Returns
    -------
    (..., 4) float64
    """
    q = _quat("q", q)
    # first non-zero component among w, x, y, z decides the sign
    order = q[..., [3, 0, 1, 2]]
    nonzero = order != 0
    first = np.argmax(nonzero, axis=-1)
    lead = np.take_along_axis(order, first[..., None], axis=-1)[..., 0]
    sign = np.where(lead < 0, -1.0, 1.0)
    return q * sign[..., None]


def quat_apply(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors: ``q v q*``.

    Parameters
    ----------
    q : (..., 4) float
        Unit quaternions, scalar-last.
    v : (..., 3) float
        Vectors, any unit; broadcast against ``q``'s leading axes.

    Returns
    -------
    (..., 3) float64
        Rotated vectors, same unit as ``v``. NaN propagates.
    """
    q = _quat("q", q)
    v = _vec3("v", v)
    u = q[..., :3]
    w = q[..., 3:4]
    uv = np.cross(u, v)
    return v + 2.0 * (w * uv + np.cross(u, uv))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions.

    Parameters
    ----------
    q : (..., 4) float
        Scalar-last; need not be normalised (the matrix of ``q / |q|`` is returned).
        A zero quaternion gives NaN (without a warning).

    Returns
    -------
    (..., 3, 3) float64
        ``R`` such that ``R @ v == quat_apply(q, v)``.
    """
    q = _quat("q", q)
    flat = q.reshape(-1, 4)
    n2 = np.einsum("ij,ij->i", flat, flat)
    usable = np.isfinite(n2) & (n2 > 0)
    # scipy's compiled loop: one allocation instead of ~30 numpy temporaries
    if flat.shape[0] and usable.all():
        out = Rotation.from_quat(flat).as_matrix()
    else:
        out = np.full((flat.shape[0], 3, 3), np.nan)
        if usable.any():
            out[usable] = Rotation.from_quat(flat[usable]).as_matrix()
    return out.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation matrices (Shepperd's method, branch per element).

    Parameters
    ----------
    m : (..., 3, 3) float
        Proper rotation matrices. Slightly non-orthogonal input gives the quaternion of
        a nearby rotation; the result is always normalised.

    Returns
    -------
    (..., 4) float64
        Scalar-last, canonical (``w >= 0``; see :func:`quat_canonical`). NaN anywhere in
        a matrix gives NaN for that quaternion.
    """
    m = np.asarray(m, dtype=np.float64)
    if m.ndim < 2 or m.shape[-2:] != (3, 3):
        raise ValidationError(f"m: expected rotation matrices of shape (..., 3, 3), got {m.shape}")
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    # candidates for 4*q_i^2 - the largest one is divided by, for stability
    diag = np.stack([m00, m11, m22, trace], axis=-1)
    choice = np.argmax(np.where(np.isnan(diag), -np.inf, diag), axis=-1)
    q = np.zeros(m.shape[:-2] + (4,), dtype=np.float64)
    # w largest
    qw = np.stack(
        [
            m[..., 2, 1] - m[..., 1, 2],
            m[..., 0, 2] - m[..., 2, 0],
            m[..., 1, 0] - m[..., 0, 1],
            1.0 + trace,
        ],
        axis=-1,
    )
    qx = np.stack(
        [
            1.0 + m00 - m11 - m22,
            m[..., 0, 1] + m[..., 1, 0],
            m[..., 0, 2] + m[..., 2, 0],
            m[..., 2, 1] - m[..., 1, 2],
        ],
        axis=-1,
    )
    qy = np.stack(
        [
            m[..., 0, 1] + m[..., 1, 0],
            1.0 - m00 + m11 - m22,
            m[..., 1, 2] + m[..., 2, 1],
            m[..., 0, 2] - m[..., 2, 0],
        ],
        axis=-1,
    )
    qz = np.stack(
        [
            m[..., 0, 2] + m[..., 2, 0],
            m[..., 1, 2] + m[..., 2, 1],
            1.0 - m00 - m11 + m22,
            m[..., 1, 0] - m[..., 0, 1],
        ],
        axis=-1,
    )
    q = np.where((choice == 0)[..., None], qx, q)
    q = np.where((choice == 1)[..., None], qy, q)
    q = np.where((choice == 2)[..., None], qz, q)
    q = np.where((choice == 3)[..., None], qw, q)
    return quat_canonical(quat_normalize(q))


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations ``a`` and ``b`` in radians, in ``[0, pi]``.

    ``q`` and ``-q`` are the same rotation: their angle is 0.

    Parameters
    ----------
    a, b : (..., 4) float
        Unit quaternions; broadcast against each other.

    Returns
    -------
    (...,) float64, radians
        NaN where an input is NaN.
    """
    a = _quat("a", a)
    b = _quat("b", b)
    # rel = a* b turns a into b; |rel_w| = cos(theta / 2), |rel_xyz| = sin(theta / 2).
    # atan2 of both keeps full precision near 0 and near pi (unlike arccos).
    rel = quat_multiply(quat_conjugate(a), b)
    s = np.linalg.norm(rel[..., :3], axis=-1)
    return 2.0 * np.arctan2(s, np.abs(rel[..., 3]))


_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}
_AXES_RE = re.compile(r"^(?:[XYZ]{1,3}|[xyz]{1,3})$")


def _check_seq(seq: str) -> str:
    if (
        not isinstance(seq, str)
        or not _AXES_RE.match(seq)
        or any(seq[i] == seq[i + 1] for i in range(len(seq) - 1))
    ):
        raise ValidationError(
            f"seq: expected 1 to 3 axes from 'XYZ' (uppercase: intrinsic, lowercase: extrinsic) "
            f"with no axis twice in a row, got {seq!r}"
        )
    return seq


def euler_to_quat(angles: np.ndarray, seq: str, *, degrees: bool = True) -> np.ndarray:
    """Quaternions from Euler angles, identical to scipy ``Rotation.from_euler`` (vectorised).

    Parameters
    ----------
    angles : (..., k) float
        Angles, ``k = len(seq)``; degrees unless ``degrees=False``. Must be finite.
    seq : str
        Axis sequence, e.g. ``"ZYX"``. UPPERCASE = intrinsic (BVH channel order:
        ``Zrotation Yrotation Xrotation`` is ``"ZYX"`` and means ``Rz @ Ry @ Rx``).
    degrees : bool
        Angle unit.

    Returns
    -------
    (..., 4) float64
        Unit quaternions, scalar-last.
    """
    seq = _check_seq(seq)
    a = np.asarray(angles, dtype=np.float64)
    k = len(seq)
    if a.ndim == 0 or a.shape[-1] != k:
        raise ValidationError(
            f"angles: expected shape (..., {k}) for sequence {seq!r}, got {a.shape}"
        )
    if not np.isfinite(a).all():
        raise ValidationError("angles: must be finite")
    half = (np.radians(a) if degrees else a) * 0.5
    # product of elementary rotations: intrinsic "ABC" is qA * qB * qC, extrinsic
    # "abc" is qc * qb * qa (scipy's Rotation.from_euler, without its per-call cost)
    axes = [_AXIS_INDEX[c.upper()] for c in seq]
    steps = list(range(k)) if seq.isupper() else list(range(k))[::-1]
    q = None
    for i in steps:
        qi = np.zeros(a.shape[:-1] + (4,))
        qi[..., axes[i]] = np.sin(half[..., i])
        qi[..., 3] = np.cos(half[..., i])
        q = qi if q is None else quat_multiply(q, qi)
    if q is None:  # pragma: no cover - _check_seq allows 1 to 3 axes
        raise ValidationError(f"seq: expected 1 to 3 axes, got {seq!r}")
    return q


def quat_to_euler(q: np.ndarray, seq: str, *, degrees: bool = True) -> np.ndarray:
    """Euler angles of quaternions (scipy ``Rotation.as_euler``), gimbal lock tolerated.

    Parameters
    ----------
    q : (..., 4) float
        Non-zero finite quaternions, scalar-last (normalised by scipy).
    seq : str
        Three axes, e.g. ``"ZYX"`` (UPPERCASE = intrinsic, the BVH convention).
    degrees : bool
        Angle unit of the result.

    Returns
    -------
    (..., 3) float64
        Angles with ``euler_to_quat(angles, seq)`` the same rotation as ``q``. First and
        third angles in ``[-180, 180]``; the middle one in ``[-90, 90]`` (Tait-Bryan) or
        ``[0, 180]`` (proper Euler). At gimbal lock the third angle is set to 0 and the
        rotation is still reproduced; scipy's gimbal-lock warning is suppressed. Within
        about 1e-7 rad of the lock scipy treats the angles as locked, so the rotation
        is reproduced to about 2e-7 rad there (to ~1e-15 elsewhere).
    """
    seq = _check_seq(seq)
    if len(seq) != 3:
        raise ValidationError(f"seq: as_euler needs three axes, got {seq!r}")
    q = _quat("q", q)
    if not np.isfinite(q).all():
        raise ValidationError("q: must be finite")
    lead = q.shape[:-1]
    flat = q.reshape(-1, 4)
    if flat.shape[0] == 0:
        return np.zeros(lead + (3,), dtype=np.float64)
    norms = np.linalg.norm(flat, axis=-1)
    if (norms == 0).any():
        raise ValidationError("q: zero quaternion has no rotation")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*[Gg]imbal.*")
        ang = Rotation.from_quat(flat).as_euler(seq, degrees=degrees)
    return ang.reshape(lead + (3,))
