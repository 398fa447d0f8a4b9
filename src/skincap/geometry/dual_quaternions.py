"""Unit dual quaternions for rigid transforms, vectorised over leading axes.

A dual quaternion is stored as ``(..., 8)``: the real part ``r`` (a rotation
quaternion) then the dual part ``d``, both scalar-last ``(x, y, z, w)`` like
scipy's ``Rotation`` and :mod:`skincap.geometry.rotations`. The rigid transform
"rotate by ``q``, then translate by ``t``" (the matrix ``[R(q) | t]``) is

    r = q,        d = 0.5 * (t, 0) * q        (Hamilton products)

and ``(r, d)`` and ``(-r, -d)`` are the same transform (the double cover, as for
quaternions). The product ``dq_multiply(a, b)`` applies ``b`` first, then ``a``,
like the matrix product ``dq_to_matrices(a) @ dq_to_matrices(b)``.

Dual-quaternion skinning (Kavan et al. 2008) blends dual quaternions linearly and
re-normalises: :func:`dq_normalize` then :func:`dq_apply`. :func:`dq_apply` only
uses the vector part of ``2 d r*`` as the translation, so it gives the right answer
for a blended dual quaternion whose real part has been scaled to unit length even
when its dual part is not exactly orthogonal to the real part.

NaN behaviour: NaN in an input spreads to the outputs of the same element and
nowhere else, without warnings. A zero real part (which no rigid transform has)
gives NaN.
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import broadcast_leading
from skincap.errors import ValidationError
from skincap.geometry.rotations import (
    divide_or_nan,
    last_axis_array,
    matrix_to_quat,
    quat_conjugate,
    quat_identity,
    quat_multiply,
    quat_to_matrix,
)

__all__ = [
    "dq_identity",
    "dq_from_quat_translation",
    "dq_from_matrices",
    "dq_to_quat_translation",
    "dq_to_matrices",
    "dq_multiply",
    "dq_conjugate",
    "dq_normalize",
    "dq_apply",
]


def _dq(name: str, value: np.ndarray) -> np.ndarray:
    return last_axis_array(
        name, value, 8, "dual quaternions of shape (..., 8) (real x, y, z, w, dual x, y, z, w)"
    )


def dq_identity(shape: tuple[int, ...] | int = ()) -> np.ndarray:
    """Identity dual quaternions ``(0, 0, 0, 1, 0, 0, 0, 0)``.

    Parameters
    ----------
    shape : tuple of int or int
        Leading shape ``S``.

    Returns
    -------
    (*S, 8) float64
    """
    real = quat_identity(shape)
    return np.concatenate([real, np.zeros_like(real)], axis=-1)


def dq_from_quat_translation(quat: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Dual quaternions of "rotate by ``quat``, then translate by ``translation``".

    Parameters
    ----------
    quat : (..., 4) float
        Rotations, scalar-last; normalised here (a zero quaternion gives NaN).
    translation : (..., 3) float, any length unit
        Broadcast against ``quat``'s leading axes.

    Returns
    -------
    (..., 8) float64
        Unit dual quaternions (real part unit, dual part orthogonal to it); the
        dual part is in half the unit of ``translation``. NaN propagates.

    Examples
    --------
    >>> dq = dq_from_quat_translation([0.0, 0.0, 0.0, 1.0], [2.0, 0.0, 0.0])
    >>> dq_apply(dq, [1.0, 1.0, 1.0])
    array([3., 1., 1.])
    """
    q = last_axis_array("quat", quat, 4, "shape (..., 4) (x, y, z, w)")
    t = last_axis_array("translation", translation, 3, "shape (..., 3)")
    lead = broadcast_leading(
        q.shape[:-1],
        t.shape[:-1],
        error=f"quat {q.shape} and translation {t.shape}: leading axes do not broadcast",
    )
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.broadcast_to(divide_or_nan(q, n), lead + (4,))
    t = np.broadcast_to(t, lead + (3,))
    tq = np.concatenate([t, np.zeros(lead + (1,))], axis=-1)
    return np.concatenate([q, 0.5 * quat_multiply(tq, q)], axis=-1)


def dq_from_matrices(matrices: np.ndarray, *, atol: float = 1e-6) -> np.ndarray:
    """Dual quaternions of rigid homogeneous transforms.

    Parameters
    ----------
    matrices : (..., 4, 4) float
        Rigid transforms ``[R | t; 0 0 0 1]`` acting on column vectors (``R`` a
        proper rotation). The bottom row is not used. Matrices containing NaN give
        NaN and are not checked.
    atol : float, default 1e-6
        Largest accepted deviation of ``R.T @ R`` from the identity (and of
        ``det R`` from 1). Slightly non-orthogonal rotations within it are mapped
        to the quaternion of a nearby rotation.

    Returns
    -------
    (..., 8) float64
        Unit dual quaternions with canonical real part (``w >= 0``).

    Raises
    ------
    ValidationError
        Wrong shape, or a matrix is not rigid (scaled, sheared or reflecting): such
        transforms have no dual quaternion. :class:`~skincap.deform.skeletal.deformers.DualQuaternionSkinning`
        separates the non-rigid part first.
    """
    m = np.asarray(matrices, dtype=np.float64)
    if m.ndim < 2 or m.shape[-2:] != (4, 4):
        raise ValidationError(f"matrices: expected shape (..., 4, 4), got {m.shape}")
    rot = m[..., :3, :3]
    finite = np.isfinite(m).all(axis=(-2, -1))
    if finite.any():
        rf = rot[finite]
        gram_err = np.abs(np.einsum("nji,njk->nik", rf, rf) - np.eye(3)).max(axis=(-2, -1))
        det_err = np.abs(np.linalg.det(rf) - 1.0)
        bad = (gram_err > atol) | (det_err > atol)
        if bad.any():
            k = int(np.argmax(bad))
            where = np.argwhere(finite)[k]
            raise ValidationError(
                f"matrices: not a rigid transform at index {tuple(int(i) for i in where)} "
                f"(|R^T R - I| = {gram_err[k]:.3g}, det R = {det_err[k] + 1.0:.6g}); "
                "dual quaternions represent rotations and translations only"
            )
    with np.errstate(invalid="ignore"):
        q = matrix_to_quat(rot)
    return dq_from_quat_translation(q, m[..., :3, 3])


def dq_to_quat_translation(dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation of dual quaternions.

    Parameters
    ----------
    dq : (..., 8) float
        Need not be normalised: the real part's length is divided out.

    Returns
    -------
    quat : (..., 4) float64
        Unit rotation quaternions (the sign of the input is kept).
    translation : (..., 3) float64
        ``2 * vec(d r*) / |r|^2``, in twice the unit of the dual part.
    """
    dq = _dq("dq", dq)
    r = dq[..., :4]
    d = dq[..., 4:]
    n2 = np.sum(r * r, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(n2 > 0, n2, np.nan)
        q = r * np.sqrt(inv)
        rw, rv = r[..., 3:4], r[..., :3]
        dw, dv = d[..., 3:4], d[..., :3]
        t = 2.0 * (rw * dv - dw * rv + np.cross(rv, dv)) * inv
    return q, t


def dq_to_matrices(dq: np.ndarray) -> np.ndarray:
    """Homogeneous matrices of dual quaternions.

    Parameters
    ----------
    dq : (..., 8) float
        Need not be normalised (see :func:`dq_to_quat_translation`).

    Returns
    -------
    (..., 4, 4) float64
        ``[R | t; 0 0 0 1]`` acting on column vectors. NaN propagates.
    """
    q, t = dq_to_quat_translation(dq)
    out = np.zeros(q.shape[:-1] + (4, 4))
    with np.errstate(invalid="ignore"):
        out[..., :3, :3] = quat_to_matrix(q)
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def dq_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Product ``a * b``: the transform applying ``b`` first, then ``a``.

    Parameters
    ----------
    a, b : (..., 8) float
        Broadcast against each other.

    Returns
    -------
    (..., 8) float64
        ``(ar * br, ar * bd + ad * br)``; unit when both inputs are unit.
    """
    a = _dq("a", a)
    b = _dq("b", b)
    ar, ad = a[..., :4], a[..., 4:]
    br, bd = b[..., :4], b[..., 4:]
    return np.concatenate(
        [quat_multiply(ar, br), quat_multiply(ar, bd) + quat_multiply(ad, br)], axis=-1
    )


def dq_conjugate(dq: np.ndarray) -> np.ndarray:
    """Quaternion conjugate of both parts: the inverse transform of a unit dual quaternion.

    Parameters
    ----------
    dq : (..., 8) float

    Returns
    -------
    (..., 8) float64
    """
    dq = _dq("dq", dq)
    return np.concatenate([quat_conjugate(dq[..., :4]), quat_conjugate(dq[..., 4:])], axis=-1)


def dq_normalize(dq: np.ndarray) -> np.ndarray:
    """Nearest unit dual quaternions.

    The real part is scaled to unit length and the dual part is scaled by the same
    factor, then its component along the real part is removed (a unit dual
    quaternion has ``<r, d> = 0``). The rigid transform is that of
    :func:`dq_to_quat_translation` of the input.

    Parameters
    ----------
    dq : (..., 8) float
        A zero real part gives NaN (without a warning).

    Returns
    -------
    (..., 8) float64
    """
    dq = _dq("dq", dq)
    r = dq[..., :4]
    d = dq[..., 4:]
    n = np.linalg.norm(r, axis=-1, keepdims=True)
    inv = divide_or_nan(1.0, n)
    r = r * inv
    d = d * inv
    d = d - np.sum(r * d, axis=-1, keepdims=True) * r
    return np.concatenate([r, d], axis=-1)


def dq_apply(dq: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Transform points by unit dual quaternions.

    Parameters
    ----------
    dq : (..., 8) float
        Unit real part (a blended dual quaternion after dividing by the real
        part's length is fine; the dual part's component along the real part is
        ignored).
    points : (..., 3) float, any length unit
        Broadcast against ``dq``'s leading axes.

    Returns
    -------
    (..., 3) float64
        ``R p + t`` in the unit of ``points``. NaN propagates.
    """
    dq = _dq("dq", dq)
    p = last_axis_array("points", points, 3, "shape (..., 3)")
    rv, rw = dq[..., :3], dq[..., 3:4]
    dv, dw = dq[..., 4:7], dq[..., 7:8]
    # rotation q p q* (quat_apply's form), then translation 2 vec(d r*)
    uv = np.cross(rv, p)
    rotated = p + 2.0 * (rw * uv + np.cross(rv, uv))
    return rotated + 2.0 * (rw * dv - dw * rv + np.cross(rv, dv))
