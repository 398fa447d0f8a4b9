"""Batched weighted absolute orientation (Kabsch / Horn) over leading axes.

The rigid fit is the workhorse of the marker cleanup (Park & Hodgins 2006, eqs. 2 and
5): for every frame and every marker, the rotation and translation that carry a set of
neighbour positions onto their reference positions. All functions batch over any number
of leading axes, so one call solves all frames and all markers at once.

Method (Kabsch 1976, the SVD form of Horn 1987): with weights ``w_k``, centroids
``c_s = Σ w_k s_k / Σ w_k`` and ``c_d`` alike, the cross-covariance
``H = Σ w_k (s_k - c_s)(d_k - c_d)^T = U S V^T`` gives ``R = V diag(1, 1, δ) U^T`` with
``δ = sign det(V U^T)`` (the reflection fix: the best *proper* rotation) and
``t = c_d - R c_s``. This minimises ``Σ w_k ||R s_k + t - d_k||²`` over proper rotations.

The default solver finds the same rotation without a LAPACK call per 3x3 matrix
(those dominate the cleanup's cost): Horn's quaternion form, whose 4x4 symmetric
matrix has the best rotation's quaternion as its top eigenvector; the top eigenvalue is
the largest root of the characteristic polynomial, found by Newton's method from an
upper bound (Theobald 2005, "QCP"), and the eigenvector a column of the adjugate of
``N - λI``. All of it is elementwise arithmetic over the batch. Batches whose
eigenvector does not verify (a repeated top eigenvalue: collinear or coincident points)
are solved by the SVD, which stays available as ``method="svd"``, the reference.

Degenerate configurations (all points on a line, or coincident) have a family of
minimisers; the function still returns one of them, a proper rotation whose residual is
minimal. Fewer than three valid points give NaN.
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import broadcast_leading
from skincap.errors import ValidationError

__all__ = ["apply_rigid", "fit_rigid", "invert_rigid"]


def _points(name: str, value: np.ndarray) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-1] != 3:
        raise ValidationError(f"{name} must have shape (..., K, 3); got {arr.shape}")
    return arr


def fit_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    *,
    min_points: int = 3,
    method: str = "quaternion",
) -> tuple[np.ndarray, np.ndarray]:
    """Best proper rigid transform with ``dst ≈ R @ src + t``, batched.

    Parameters
    ----------
    src, dst : (..., K, 3) float, any length unit (the same for both)
        Corresponding points. Leading axes broadcast against each other. A point with a
        NaN/inf coordinate in either array is ignored.
    weights : (..., K) float, optional
        Non-negative weight per correspondence (default 1). Non-finite or zero weights
        exclude the point. Negative weights raise :class:`ValidationError`.
    mask : (..., K) bool, optional
        ``False`` excludes a point (default: all included).
    min_points : int, default 3
        Batches with fewer valid points than this get NaN in ``R`` and ``t``.
    method : {"quaternion", "svd"}, default "quaternion"
        How the rotation is found from the 3x3 cross-covariance. ``"quaternion"``:
        Horn's quaternion eigenproblem solved elementwise over the batch (Newton on
        the characteristic polynomial, Theobald's QCP), several times faster than a
        LAPACK call per 3x3 matrix, with an SVD fallback for the (nearly) degenerate
        batches it cannot verify. ``"svd"``: the plain Kabsch SVD, kept as the
        reference. Both return the same minimiser up to rounding.

    Returns
    -------
    R : (..., 3, 3) float64
        Proper rotations (``det R = +1``); NaN where the batch has too few points.
    t : (..., 3) float64, the unit of the inputs
        Translations; NaN where the batch has too few points.

    Notes
    -----
    Collinear or coincident valid points leave the rotation about the line (or all
    rotations) undetermined; a minimiser is still returned, so ``R @ src + t``
    reproduces ``dst`` as well as any rigid transform can.

    Examples
    --------
    >>> src = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> R, t = fit_rigid(src, src + [0.1, 0.2, 0.3])
    >>> np.allclose(R, np.eye(3)), np.allclose(t, [0.1, 0.2, 0.3])
    (True, True)
    """
    s = _points("src", src)
    d = _points("dst", dst)
    valid, w, lead = _valid_weighted_points(s, d, weights, mask)
    k = s.shape[-2]
    ok = valid.sum(axis=-1) >= min_points  # (...)
    w = np.where(valid, np.broadcast_to(w, (*lead, k)), 0.0)  # (..., K)
    # component-first copies (3, ..., K), NaN cleared: every reduction below runs over
    # contiguous vectors of the batch
    nd = len(lead) + 2
    sc = np.where(valid, np.moveaxis(s.reshape((1,) * (nd - s.ndim) + s.shape), -1, 0), 0.0)
    dc = np.where(valid, np.moveaxis(d.reshape((1,) * (nd - d.ndim) + d.shape), -1, 0), 0.0)
    wsum = np.einsum("...k->...", w)
    ok &= wsum > 0
    safe = np.where(ok, wsum, 1.0)
    cs = np.einsum("c...k,...k->c...", sc, w) / safe  # (3, ...)
    cd = np.einsum("c...k,...k->c...", dc, w) / safe
    sc -= cs[..., None]
    dc -= cd[..., None]
    dw = dc * w  # weighted, centred
    h = np.empty((3, 3, *lead))  # h[i, j] = Σ w s0_i d0_j, cross-covariance
    for i in range(3):
        for j in range(3):
            h[i, j] = np.einsum("...k,...k->...", sc[i], dw[j])
    eye = np.eye(3).reshape(3, 3, *([1] * len(lead)))
    h = np.where(ok, h, eye)
    if method == "svd":
        rot = _rotation_svd(np.moveaxis(h, (0, 1), (-2, -1)))
    elif method == "quaternion":
        e0 = 0.5 * (
            np.einsum("c...k,c...k->...", sc * w, sc) + np.einsum("c...k,c...k->...", dw, dc)
        )
        rot = _rotation_quaternion(h, np.where(ok, e0, 1.5))
    else:
        raise ValidationError(f"method must be 'quaternion' or 'svd'; got {method!r}")
    cs = np.moveaxis(cs, 0, -1)
    trans = np.moveaxis(cd, 0, -1) - (rot @ cs[..., None])[..., 0]
    rot = np.where(ok[..., None, None], rot, np.nan)
    trans = np.where(ok[..., None], trans, np.nan)
    return rot, trans


def _valid_weighted_points(
    s: np.ndarray, d: np.ndarray, weights: np.ndarray | None, mask: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Checked correspondences of :func:`fit_rigid`: ``valid`` (..., K) bool (finite in
    both, positive finite weight, in the mask), weights (..., K) (not yet broadcast)
    and the common leading shape."""
    if s.shape[-2] != d.shape[-2]:
        raise ValidationError(
            f"src and dst must have the same number of points K; got {s.shape} and {d.shape}"
        )
    lead = broadcast_leading(
        s.shape[:-2],
        d.shape[:-2],
        error=f"src {s.shape} and dst {d.shape} leading axes do not broadcast",
    )
    k = s.shape[-2]
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    if w is not None and w.shape[-1:] != (k,):
        raise ValidationError(f"weights must have shape (..., {k}); got {w.shape}")
    m = None if mask is None else np.asarray(mask)
    if m is not None:
        if m.dtype != bool:
            raise ValidationError(f"mask must be boolean; got dtype {m.dtype}")
        if m.shape[-1:] != (k,):
            raise ValidationError(f"mask must have shape (..., {k}); got {m.shape}")
    # before any combination, so a mismatch is this message rather than numpy's
    lead = broadcast_leading(
        lead,
        *(a.shape[:-1] for a in (w, m) if a is not None),
        error=(
            f"weights/mask leading axes do not broadcast with the points': weights "
            f"{None if w is None else w.shape}, mask {None if m is None else m.shape}, "
            f"points {lead + (k, 3)}"
        ),
    )
    valid = np.isfinite(s).all(axis=-1) & np.isfinite(d).all(axis=-1)
    if w is None:
        w = np.ones((*lead, k))
    else:
        if np.any(w < 0):
            raise ValidationError("weights must be non-negative")
        valid = valid & np.isfinite(w) & (w > 0)
    if m is not None:
        valid = valid & m
    valid = np.broadcast_to(valid, (*lead, k))
    return valid, w, lead


def _rotation_svd(h: np.ndarray) -> np.ndarray:
    """(..., 3, 3) proper rotations maximising ``trace(R H)`` by SVD (the reference)."""
    u, _, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, -1, -2)
    ut = np.swapaxes(u, -1, -2)
    det = np.linalg.det(v @ ut)  # (...)
    # reflection fix: flip the axis of the smallest singular value when det < 0
    v = v.copy()
    v[..., :, 2] *= np.where(det < 0, -1.0, 1.0)[..., None]
    return v @ ut


def _det3(a: np.ndarray) -> np.ndarray:
    """Determinants of 3x3 matrices stored component-first, ``a`` (3, 3, B) -> (B,)."""
    return (
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    )


def _horn_matrix(h: np.ndarray) -> np.ndarray:
    """Horn's (1987) symmetric 4x4 matrix, component-first: ``h`` (3, 3, B) holds the
    cross-covariances ``H = Σ s d^T``; returns (4, 4, B) whose top eigenvector is the
    quaternion (w, x, y, z) of the best rotation ``R s ≈ d``."""
    (sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz) = h
    return np.array(
        [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ]
    )


def _rotation_quaternion(h: np.ndarray, e0: np.ndarray) -> np.ndarray:
    """(..., 3, 3) proper rotations maximising ``trace(R H)``, elementwise, from
    cross-covariances stored component-first, ``h`` (3, 3, ...), and ``e0`` (...).

    Horn's quaternion method with the top eigenvalue of the 4x4 matrix found as the
    largest root of its characteristic polynomial by Newton's method from the upper
    bound ``e0 = (Σ w|s0|² + Σ w|d0|²) / 2`` (Theobald's QCP), and the eigenvector
    as the largest column of the adjugate of ``N - λI``. Rows where that eigenvector
    does not verify (``|N q - λ q|`` above a tiny fraction of ``e0``: a (nearly)
    repeated top eigenvalue, i.e. collinear or coincident points) are recomputed by
    :func:`_rotation_svd`, so the result is always a minimiser.
    """
    shape = h.shape[2:]
    hc = h.reshape(3, 3, -1)  # (3, 3, B): contiguous components
    e0f = np.maximum(e0.reshape(-1), 1e-300)
    n4 = _horn_matrix(hc)  # (4, 4, B), traceless
    # characteristic polynomial λ⁴ + c2 λ² + c1 λ + c0
    c2 = -2.0 * (hc * hc).sum(axis=(0, 1))
    c1 = -8.0 * _det3(hc)
    c0 = _det4(n4)
    lam = e0f.copy()
    tol = 1e-14 * e0f
    for _ in range(60):
        lam2 = lam * lam
        f = (lam2 + c2) * lam2 + c1 * lam + c0
        fp = 4.0 * lam2 * lam + 2.0 * c2 * lam + c1
        # from above the largest root Newton only descends (f is convex there); a
        # rounding-born negative step near a double root is cut to 0, and λmax >= 0
        # (N is traceless)
        # (a subnormal fp, at a near-double root, may overflow the quotient: the clip
        # then takes the step to 0, and a NaN λ fails the verification below)
        with np.errstate(over="ignore", invalid="ignore"):
            step = np.clip(f / np.where(fp > 0, fp, np.inf), 0.0, lam)
        lam -= step
        if not (np.abs(step) > tol).any():
            break
    a = n4 - lam * np.eye(4)[..., None]
    adj = _adjugate(a)  # (4, 4, B); symmetric, each column ∝ q
    norms = np.sqrt((adj * adj).sum(axis=0))  # (4, B) column norms
    best = np.argmax(norms, axis=0)  # (B,)
    cols = np.arange(best.size)
    q = adj[:, best, cols]  # (4, B)
    qn = norms[best, cols]
    q = q / np.where(qn > 0, qn, 1.0)
    nq = np.einsum("ijb,jb->ib", n4, q)
    resid = np.sqrt(((nq - lam * q) ** 2).sum(axis=0))
    # the eigenvector's angular error is at most resid / gap (Davis-Kahan), and the gap
    # to the next eigenvalue is at least p'(λ) / (2 e0)², the other two factors of
    # p'(λ) = Π (λ - λ_i) being at most 2 e0 (every eigenvalue lies in [-e0, e0]);
    # nearly collinear points have a tiny gap, and a residual that would verify a
    # well-separated eigenvector can then leave the rotation about the line off by
    # far more than rounding
    # (all in units of e0, so tiny or huge coordinates neither underflow nor overflow;
    # an underflowed gap only sends the batch to the SVD)
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        ln = lam / e0f
        gap = (4.0 * ln**3 + 2.0 * (c2 / e0f / e0f) * ln + c1 / e0f / e0f / e0f) / 4.0
    bad = ~(qn > 0) | ~(resid / e0f <= 1e-11 * gap) | ~np.isfinite(lam)
    rot = _quaternion_matrix(q)  # (B, 3, 3)
    if bad.any():
        rot[bad] = _rotation_svd(np.moveaxis(hc[:, :, bad], -1, 0))
    return rot.reshape(*shape, 3, 3)


def _det4(a: np.ndarray) -> np.ndarray:
    """Determinants of 4x4 matrices stored component-first, (4, 4, B) -> (B,), by
    Laplace expansion over the 2x2 minors of rows (0, 1) and (2, 3)."""
    total = np.zeros(a.shape[-1])
    for c in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)):
        r = tuple(k for k in range(4) if k not in c)
        top = a[0][c[0]] * a[1][c[1]] - a[0][c[1]] * a[1][c[0]]
        bottom = a[2][r[0]] * a[3][r[1]] - a[2][r[1]] * a[3][r[0]]
        sign = -1.0 if (1 + c[0] + c[1]) % 2 else 1.0
        total += sign * top * bottom
    return total


def _adjugate(a: np.ndarray) -> np.ndarray:
    """Adjugate of symmetric 4x4 matrices stored component-first, (4, 4, B)."""
    out = np.empty_like(a)
    for i in range(4):
        rows = [r for r in range(4) if r != i]
        for j in range(i, 4):
            cols = [c for c in range(4) if c != j]
            m = [[a[r][c] for c in cols] for r in rows]
            cof = (
                m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
            )
            out[j, i] = out[i, j] = -cof if (i + j) % 2 else cof
    return out


def _quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """(B, 3, 3) rotation matrices of unit quaternions stored component-first, (4, B)
    ordered (w, x, y, z)."""
    w, x, y, z = q
    m = np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )  # (3, 3, B)
    return np.ascontiguousarray(np.moveaxis(m, -1, 0))


def _rigid_arrays(rotation: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``rotation`` (..., 3, 3) and ``translation`` (..., 3) as float64, or a ValidationError."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    if r.shape[-2:] != (3, 3):
        raise ValidationError(f"rotation must have shape (..., 3, 3); got {r.shape}")
    if t.shape[-1:] != (3,):
        raise ValidationError(f"translation must have shape (..., 3); got {t.shape}")
    return r, t


def apply_rigid(rotation: np.ndarray, translation: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``R @ p + t`` to points, batched.

    Parameters
    ----------
    rotation : (..., 3, 3) float
    translation : (..., 3) float
    points : (..., M, 3) float
        Leading axes broadcast against those of ``rotation`` / ``translation``.

    Returns
    -------
    (..., M, 3) float64
        Transformed points; NaN propagates (a NaN transform or point gives NaN).
    """
    p = _points("points", points)
    r, t = _rigid_arrays(rotation, translation)
    return np.einsum("...ij,...mj->...mi", r, p) + t[..., None, :]


def invert_rigid(rotation: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``p -> R p + t``: ``(R^T, -R^T t)``, batched; NaN propagates.

    Parameters
    ----------
    rotation : (..., 3, 3) float
    translation : (..., 3) float

    Returns
    -------
    R_inv : (..., 3, 3) float64
    t_inv : (..., 3) float64
    """
    r, t = _rigid_arrays(rotation, translation)
    rt = np.swapaxes(r, -1, -2)
    return rt, -np.einsum("...ij,...j->...i", rt, t)
