"""Radial basis interpolation with the cubic B-spline kernel (Park & Hodgins 2006, eqs. 7-8), batched.

Given centres ``c_i`` and values ``r_i``, find weights ``w_i`` with
``Σ_i w_i φ(||c_i - c_j|| / σ) = r_j`` for every centre ``j`` (eq. 7), then evaluate
``f(x) = Σ_i w_i φ(||c_i - x|| / σ)`` anywhere (the sum in eq. 8). φ is the cubic
B-spline scaled to the support ``[0, 1)``, so σ is the radius of influence::

    φ(u) = B(2u),  B(s) = (2 - s)³/6 - 4 (1 - s)³/6  for 0 ≤ s < 1
                   B(s) = (2 - s)³/6                 for 1 ≤ s < 2,   0 beyond

The paper does not say how the kernel is scaled by σ. With the B-spline's own
support ``[0, 2)`` (radius 2σ = four nearest-member distances) the kernel matrix of a
marker lattice has eigenvalues ~1e-4 of the largest and crosses zero as the centres
move (vertex errors of 10-25 mm on a synthetic take); with radius σ (two such
distances, each centre reaching its neighbours) the smallest is ~4e-2.

The radial cubic B-spline is not positive definite in 3-D: its kernel matrix can have
eigenvalues near zero or below it (coincident centres, or a too wide support, above).
The system is solved
through its eigen-decomposition with the near-zero modes left out (:func:`fit_rbf`),
so interpolation is exact for a well-conditioned matrix and stays bounded for a
near-singular one.

That is not enough when the support is wide against the spacing (an irregular part
whose largest nearest-member distance, hence σ, is twice its typical spacing): the
matrix is then indefinite with eigenvalues of ~1e-4 of the largest, kept by the
cutoff, and the solve multiplies the residuals along them a thousandfold, so the
field swings by metres between its centres (a 120-marker part of the demo's 12-frame
rig: weights of 26 m, vertices thrown 35 cm). :func:`fit_rbf_ridge` fits the
Tikhonov-regularised system instead, ``w = argmin ||Φ w - r||² + μ ||w||²`` with
``μ = ρ max|λ|²`` (through the eigen-decomposition, so an indefinite matrix is no
harm: each mode is multiplied by ``λ / (λ² + μ)``, at most ``1 / (2 √μ)``; given
``max|λ|`` (:func:`rbf_kernel_scale`), the same from one complex LU of ``Φ + i √μ I``
instead, several times cheaper), and
:func:`choose_ridge_gcv` picks ρ from the data by generalised cross-validation
(Golub, Heath & Wahba 1979), closed-form from the same decomposition: a mode that
only an amplified fit passes through predicts the centres left out badly and is
damped; a well-conditioned system with smooth values keeps ρ tiny and interpolates
to within rounding of the values' scale. GCV reads whatever the field cannot follow
as noise, though, and the dense deformer's residuals are signal (the markers sample the
skin): there it smoothed them away (ρ up to 1e-2), so the deformer fits a small fixed
ρ by default and offers GCV as an option.

Every function takes a validity mask so that a batch of frames with different missing
centres is one array operation: an invalid centre gets weight 0 and does not constrain
the others.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.spatial import cKDTree

from skincap.errors import ValidationError

__all__ = [
    "RIDGE_GRID",
    "choose_ridge_gcv",
    "cubic_bspline",
    "dilation_from_spacing",
    "evaluate_rbf",
    "fit_rbf",
    "fit_rbf_fixed_centres",
    "fit_rbf_ridge",
    "fit_rbf_ridge_nested",
    "rbf_kernel_scale",
]


def cubic_bspline(u: np.ndarray) -> np.ndarray:
    """The cubic B-spline kernel φ(u) = B(2u), support ``[0, 1)``, ``φ(0) = 2/3``.

    Parameters
    ----------
    u : (...) float
        Scaled distances ``||x - c|| / σ`` (non-negative).

    Returns
    -------
    (...) float64
    """
    s = 2.0 * np.abs(np.asarray(u, dtype=np.float64))
    a = np.maximum(2.0 - s, 0.0)  # in place below: this runs on (frames, vertices, members)
    b = np.maximum(np.subtract(1.0, s, out=s), 0.0, out=s)
    cube_a = np.multiply(a, a)
    cube_a *= a
    cube_b = np.multiply(b, b)
    cube_b *= b
    cube_b *= 4.0
    cube_a -= cube_b
    cube_a *= 1.0 / 6.0
    return cube_a


def dilation_from_spacing(centres: np.ndarray, *, factor: float = 2.0) -> float:
    """σ = ``factor`` × the largest nearest-neighbour distance among ``centres`` (eq. 7).

    Park & Hodgins set σ to twice the maximum distance between two nearest member
    markers of a part. NaN rows are ignored.

    Parameters
    ----------
    centres : (K, 3) float, metres

    Returns
    -------
    float, metres (NaN with fewer than two valid centres)
    """
    c = np.asarray(centres, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValidationError(f"centres must have shape (K, 3); got {c.shape}")
    c = c[np.isfinite(c).all(axis=1)]
    if c.shape[0] < 2:
        return float("nan")
    d, _ = cKDTree(c).query(c, k=2)
    return float(factor) * float(d[:, 1].max())


#: Entries per block of :func:`_spline_of_squared`: its scratch stays in cache (~0.5 MB).
_BLOCK = 1 << 16


def _spline_of_squared(s2: np.ndarray) -> np.ndarray:
    """``φ`` from ``s² = (2 d / σ)²`` in place, block by block (a (..., M, K) array).

    ``φ = ((2 - s)³ - 4 max(1 - s, 0)³) / 6`` with ``s`` clipped at 2, where both cubes
    vanish: the same values as :func:`cubic_bspline` without its full-size temporaries.
    """
    flat = s2.reshape(-1)  # s2 is C-contiguous: a view
    scratch = np.empty(min(flat.size, _BLOCK))
    for i0 in range(0, flat.size, _BLOCK):
        x = flat[i0 : i0 + _BLOCK]
        b = scratch[: x.size]
        np.clip(x, 0.0, 4.0, out=x)
        np.sqrt(x, out=x)  # s
        np.subtract(1.0, x, out=b)
        np.maximum(b, 0.0, out=b)
        np.subtract(2.0, x, out=x)
        cube_b = np.multiply(b, b)
        b *= cube_b
        b *= 4.0
        np.multiply(x, x, out=cube_b)
        x *= cube_b
        x -= b
        x *= 1.0 / 6.0
    return s2


def _kernel_matrix(a: np.ndarray, b: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    # scaled by 2/σ, squared distances are s² = |a|² + |b|² - 2 a·b: batched products,
    # no (..., M, K, 3) array
    g = (2.0 / sigma)[..., None, None]
    a, b = a * g, b * g
    s2 = (a * a).sum(-1)[..., :, None] + (b * b).sum(-1)[..., None, :]
    s2 -= 2.0 * (a @ np.swapaxes(b, -1, -2))
    return _spline_of_squared(np.ascontiguousarray(s2))


def fit_rbf(
    centres: np.ndarray,
    values: np.ndarray,
    sigma: np.ndarray | float,
    mask: np.ndarray | None = None,
    *,
    cutoff: float = 1e-6,
) -> np.ndarray:
    """Weights that make the cubic B-spline RBF interpolate ``values`` at ``centres`` (eq. 7).

    The kernel matrix is symmetric but, the radial cubic B-spline not being positive
    definite in 3-D, it can have eigenvalues near (or below) zero, where a plain solve
    gives huge weights that swing the surface between the centres. The system is
    solved through its eigen-decomposition, leaving out the modes whose eigenvalue
    is below ``cutoff`` times the largest in magnitude: exact interpolation whenever the
    matrix is well conditioned, and the best bounded approximation otherwise. (A
    matrix whose Frobenius condition number proves that no mode would be left out is
    solved through its inverse instead, which is the same to rounding and several
    times cheaper than the decomposition.)

    Parameters
    ----------
    centres : (..., K, 3) float, metres
    values : (..., K, D) float
        Values to interpolate (the residuals, metres, D = 3).
    sigma : float or (...) float, metres
        The dilation σ (positive).
    mask : (..., K) bool, optional
        False (or a non-finite centre or value) excludes a centre: its weight is 0.
    cutoff : float
        Relative eigenvalue below which a mode is left out (0 = plain solve); the
        default drops only (nearly) coincident centres.

    Returns
    -------
    weights : (..., K, D) float64
        Zero for excluded centres and for batches with a non-positive or NaN σ.
    """
    c = np.asarray(centres, dtype=np.float64)
    r = np.asarray(values, dtype=np.float64)
    if c.ndim < 2 or c.shape[-1] != 3 or r.ndim < 2 or r.shape[-2] != c.shape[-2]:
        raise ValidationError(
            f"centres must be (..., K, 3) and values (..., K, D) with the same K; "
            f"got {c.shape} and {r.shape}"
        )
    cut = float(cutoff)
    if not (0 <= cut < 1):
        raise ValidationError(f"cutoff must be in [0, 1); got {cutoff!r}")
    lead = np.broadcast_shapes(c.shape[:-2], r.shape[:-2])
    k = c.shape[-2]
    s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), lead)
    valid = np.isfinite(c).all(-1) & np.isfinite(r).all(-1)
    if mask is not None:
        valid = valid & np.asarray(mask, dtype=bool)
    valid = np.broadcast_to(valid, (*lead, k)) & (np.isfinite(s) & (s > 0))[..., None]
    c0 = np.broadcast_to(np.where(np.isfinite(c), c, 0.0), (*lead, k, 3))
    r_finite = np.where(np.isfinite(r), r, 0.0)
    r0 = np.where(valid[..., None], np.broadcast_to(r_finite, (*lead, k, r.shape[-1])), 0.0)
    s_safe = np.where(np.isfinite(s) & (s > 0), s, 1.0)
    phi = _kernel_matrix(c0, c0, s_safe)  # (..., K, K)
    pair = valid[..., :, None] & valid[..., None, :]
    eye = np.eye(k, dtype=bool)
    # an excluded centre gets a lone diagonal entry φ(0): it decouples with weight 0
    phi = np.where(pair, phi, 0.0) + np.where(eye & ~valid[..., :, None], 2.0 / 3.0, 0.0)
    w = _solve_dropping_small_modes(phi, r0, cut)
    return np.where(valid[..., None], w, 0.0)


def _solve_dropping_small_modes(phi: np.ndarray, values: np.ndarray, cut: float) -> np.ndarray:
    """``Φ w = r`` through the eigen-decomposition, modes with ``|λ| <= cut max|λ|`` left out.

    Where ``||Φ||_F ||Φ⁻¹||_F < 1 / cut`` no mode can be left out (it bounds
    ``max|λ| / min|λ|``), so the plain inverse gives the same weights (to rounding) at
    a fraction of the cost of ``eigh``; only the other batches are decomposed.
    """
    w = np.zeros(values.shape)
    decompose = np.ones(phi.shape[:-2], dtype=bool)
    if cut > 0:
        try:
            inv = np.linalg.inv(phi)
        except np.linalg.LinAlgError:  # an exactly singular matrix in the batch
            inv = None
        if inv is not None:
            # a near-singular matrix's inverse may overflow: it is decomposed instead
            with np.errstate(over="ignore", invalid="ignore"):
                size = np.sqrt((phi * phi).sum(axis=(-1, -2)) * (inv * inv).sum(axis=(-1, -2)))
                decompose = ~(size * cut < 1.0)  # NaN: decompose
                w = np.where(decompose[..., None, None], 0.0, inv @ values)
    if decompose.any():
        lam, vec = np.linalg.eigh(phi[decompose])  # (n, K), (n, K, K)
        scale = np.abs(lam).max(axis=-1, keepdims=True)
        keep = np.abs(lam) > cut * scale
        inv_lam = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
        coeff = (np.swapaxes(vec, -1, -2) @ values[decompose]) * inv_lam[..., None]
        w[decompose] = vec @ coeff
    return w


#: Default largest share of a system's centres that may be missing in a frame for
#: :func:`fit_rbf_fixed_centres` to downdate the full inverse (O(K² m + m³)) rather than
#: refit the frame (O(K³)).
MAX_MISSING_SHARE = 0.25


def _invert_full_kernels(
    c: np.ndarray, finite_c: np.ndarray, s: np.ndarray, good_sigma: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The full kernel matrices (P, K, K), their inverses (P, K, K), which inverses are finite (P,)."""
    n_sys, k = c.shape[0], c.shape[1]
    # the full matrices, shaped as fit_rbf shapes them (a non-finite centre decoupled)
    c0 = np.where(finite_c[..., None], c, 0.0)
    full = _kernel_matrix(c0, c0, np.where(good_sigma, s, 1.0))  # (P, K, K)
    pair = finite_c[:, :, None] & finite_c[:, None, :]
    eye = np.eye(k, dtype=bool)
    full = np.where(pair, full, 0.0) + np.where(eye & ~finite_c[:, :, None], 2.0 / 3.0, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            inverse = np.linalg.inv(full)
            fine = np.asarray(np.isfinite(inverse).all(axis=(-1, -2)))  # (P,)
        except np.linalg.LinAlgError:  # an exactly singular one: every system refitted
            inverse, fine = np.zeros_like(full), np.zeros(n_sys, dtype=bool)
    return full, inverse, fine


def fit_rbf_fixed_centres(
    centres: np.ndarray,
    values: np.ndarray,
    sigma: np.ndarray | float,
    mask: np.ndarray | None = None,
    *,
    cutoff: float = 1e-6,
    max_missing_share: float = MAX_MISSING_SHARE,
) -> np.ndarray:
    """:func:`fit_rbf` for centres fixed over many frames, only the mask changing.

    Each system's full kernel matrix ``A`` (every finite centre) is inverted once,
    ``B = A⁻¹``; a frame with the present set ``S`` and missing set ``M`` gets the
    inverse of its reduced matrix from the block-inverse downdate
    ``(A_SS)⁻¹ = B_SS - B_SM (B_MM)⁻¹ B_MS``: O(K² m + m³) per frame for ``m`` missing
    instead of O(K³), vectorised over the frames with the same ``m``. The downdated
    inverse also gives ``||Φ||_F ||Φ⁻¹||_F`` exactly as :func:`fit_rbf` tests it, so a
    frame :func:`fit_rbf` would solve by its eigen-decomposition (modes possibly left
    out) is handed to :func:`fit_rbf`, as are systems whose full matrix fails that test,
    frames with more than ``max_missing_share`` of the centres missing and systems
    with a non-positive or NaN σ. The weights equal :func:`fit_rbf`'s to rounding.

    Parameters
    ----------
    centres : (..., K, 3) float, metres
        The same centres for every frame (non-finite: never a centre).
    values : (T, ..., K, D) float
        Values to interpolate at each frame (non-finite: excluded at that frame).
    sigma : float or (...) float, metres
    mask : (T, ..., K) bool, optional
        False excludes a centre at a frame.
    cutoff : float
        As :func:`fit_rbf`.
    max_missing_share : float
        Largest share of a system's finite centres missing in a frame that is
        downdated (in [0, 1]).

    Returns
    -------
    weights : (T, ..., K, D) float64
        As :func:`fit_rbf` with ``centres`` broadcast over the frames.
    """
    c = np.asarray(centres, dtype=np.float64)
    r = np.asarray(values, dtype=np.float64)
    if c.ndim < 2 or c.shape[-1] != 3 or r.ndim != c.ndim + 1 or r.shape[-2] != c.shape[-2]:
        raise ValidationError(
            f"centres must be (..., K, 3) and values (T, ..., K, D) with the same K; "
            f"got {c.shape} and {r.shape}"
        )
    cut = float(cutoff)
    if not (0 <= cut < 1):
        raise ValidationError(f"cutoff must be in [0, 1); got {cutoff!r}")
    if not (0 <= max_missing_share <= 1):
        raise ValidationError(f"max_missing_share must be in [0, 1]; got {max_missing_share!r}")
    lead = np.broadcast_shapes(c.shape[:-2], r.shape[1:-2])
    n_t, k, d = r.shape[0], c.shape[-2], r.shape[-1]
    c = np.broadcast_to(c, (*lead, k, 3)).reshape(-1, k, 3)  # (P, K, 3): the systems
    r = np.broadcast_to(r, (n_t, *lead, k, d)).reshape(n_t, -1, k, d)
    s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), lead).reshape(-1)
    n_sys = c.shape[0]
    finite_c = np.asarray(np.isfinite(c).all(axis=-1))  # (P, K)
    valid = finite_c[None] & np.isfinite(r).all(-1)  # (T, P, K)
    if mask is not None:
        valid = valid & np.broadcast_to(np.asarray(mask, dtype=bool), (n_t, *lead, k)).reshape(
            n_t, n_sys, k
        )
    r0 = np.where(valid[..., None], r, 0.0)
    good_sigma = np.isfinite(s) & (s > 0)
    full, inverse, fine = _invert_full_kernels(c, finite_c, s, good_sigma)
    fine &= good_sigma
    # the matrix of a frame: present pairs of `full`, 2/3 on every other diagonal slot
    n_out = k - valid.sum(-1)  # (T, P) slots decoupled at that frame
    missing = finite_c[None] & ~valid  # (T, P, K): downdated
    n_missing = missing.sum(-1)
    phi_sq = np.einsum("tpk,pkl,tpl->tp", valid * 1.0, full * full, valid * 1.0)
    phi_sq += n_out * (4.0 / 9.0)
    limit = np.floor(max_missing_share * finite_c.sum(-1))[None, :]  # (1, P)
    todo = fine[None, :] & (n_missing <= limit)  # (T, P)
    w = np.zeros((n_t, n_sys, k, d))
    refit = ~todo
    for m in np.unique(n_missing[todo]):
        t_idx, p_idx = np.nonzero(todo & (n_missing == m))
        b = inverse[p_idx]  # (n, K, K)
        if m == 0:
            inv_s = b
        else:
            # the m missing slots of each frame, in order (a stable sort puts them first)
            slots = np.argsort(~missing[t_idx, p_idx], axis=-1, kind="stable")[:, :m]
            b_km = np.take_along_axis(b, slots[:, None, :], axis=2)  # (n, K, m)
            b_mm = np.take_along_axis(b_km, slots[:, :, None], axis=1)  # (n, m, m)
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                try:
                    c_mm = np.linalg.inv(b_mm)
                except np.linalg.LinAlgError:  # refit the whole group: rare
                    refit[t_idx, p_idx] = True
                    continue
                inv_s = b - b_km @ c_mm @ np.swapaxes(b_km, -1, -2)  # B_MS = B_SMᵀ
        keep = valid[t_idx, p_idx]  # (n, K)
        inv_s = np.where(keep[:, :, None] & keep[:, None, :], inv_s, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):
            inv_sq = (inv_s * inv_s).sum(axis=(-1, -2)) + n_out[t_idx, p_idx] * (9.0 / 4.0)
            size = np.sqrt(phi_sq[t_idx, p_idx] * inv_sq)
        # the test of _solve_dropping_small_modes: other frames are fit_rbf's to decide
        ok = size * cut < 1.0 if cut > 0 else np.isfinite(size)
        w[t_idx[ok], p_idx[ok]] = inv_s[ok] @ r0[t_idx[ok], p_idx[ok]]
        refit[t_idx[~ok], p_idx[~ok]] = True
    if refit.any():
        t_idx, p_idx = np.nonzero(refit)
        w[t_idx, p_idx] = fit_rbf(
            c[p_idx], r[t_idx, p_idx], s[p_idx], valid[t_idx, p_idx], cutoff=cut
        )
    w = np.where(valid[..., None], w, 0.0)
    return w.reshape(n_t, *lead, k, d)


#: Relative ridge strengths ρ (``μ = ρ max|λ|²``) :func:`choose_ridge_gcv` searches:
#: from 1e-12 (interpolation to rounding) to 1 (every mode at least halved), 4 per decade.
RIDGE_GRID = np.logspace(-12.0, 0.0, 49)


def _flat_systems(
    centres: np.ndarray, values: np.ndarray, sigma: np.ndarray | float, mask: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[int, ...]]:
    """Broadcast a batch of RBF systems and flatten it as :func:`fit_rbf` reads it.

    Returns ``centres (S, K, 3)`` (0 where not finite), ``values (S, K, D)`` (0 where
    excluded), ``valid (S, K)``, ``sigma (S,)`` (1 where unusable, its systems
    all-invalid) and the batch shape.
    """
    c = np.asarray(centres, dtype=np.float64)
    r = np.asarray(values, dtype=np.float64)
    if c.ndim < 2 or c.shape[-1] != 3 or r.ndim < 2 or r.shape[-2] != c.shape[-2]:
        raise ValidationError(
            f"centres must be (..., K, 3) and values (..., K, D) with the same K; "
            f"got {c.shape} and {r.shape}"
        )
    k, d = c.shape[-2], r.shape[-1]
    lead = np.broadcast_shapes(c.shape[:-2], r.shape[:-2])
    if mask is not None:
        lead = np.broadcast_shapes(lead, np.shape(mask)[:-1])
    s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), lead)
    good_sigma = np.isfinite(s) & (s > 0)
    valid = np.isfinite(c).all(-1) & np.isfinite(r).all(-1)
    if mask is not None:
        valid = valid & np.asarray(mask, dtype=bool)
    valid = np.broadcast_to(valid, (*lead, k)) & good_sigma[..., None]
    c0 = np.broadcast_to(np.where(np.isfinite(c), c, 0.0), (*lead, k, 3)).reshape(-1, k, 3)
    r0 = np.broadcast_to(np.where(np.isfinite(r), r, 0.0), (*lead, k, d))
    r0 = np.where(valid[..., None], r0, 0.0).reshape(-1, k, d)
    return c0, r0, valid.reshape(-1, k), np.where(good_sigma, s, 1.0).reshape(-1), lead


def _spectra(
    c0: np.ndarray, r0: np.ndarray, valid: np.ndarray, sigma: np.ndarray, cut: float
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The eigen-decompositions of flattened systems, grouped by size.

    A system's slots after its last valid centre are decoupled (weight 0), so it is
    decomposed cut to its first ``n`` slots, and the systems with the same ``n`` in
    one batched ``eigh``: the cost follows each part's own size, not the largest.

    Yields, per group, ``idx (m,)`` (rows of the flattened batch), ``lam (m, n)``
    (eigenvalues, those with ``|λ| <= cut max|λ|`` set to 0: left out), ``vec (m, n, n)``,
    ``beta (m, n, D)`` (the values in the eigenbasis), ``on_valid (m, n)`` (each mode's
    share on the valid slots, for the trace of the smoother) and ``scale (m,)`` (max|λ|).
    """
    k = valid.shape[1]
    n_eff = np.where(valid.any(-1), k - np.argmax(valid[:, ::-1], axis=-1), 0)
    for n in np.unique(n_eff[n_eff > 0]):
        idx = np.flatnonzero(n_eff == n)
        v = valid[idx, :n]
        phi = _kernel_matrix(c0[idx, :n], c0[idx, :n], sigma[idx])  # (m, n, n)
        # an excluded centre gets a lone diagonal entry φ(0): it decouples with weight 0
        eye = np.eye(n, dtype=bool)
        phi = np.where(v[:, :, None] & v[:, None, :], phi, 0.0)
        phi += np.where(eye & ~v[:, :, None], 2.0 / 3.0, 0.0)
        lam, vec = np.linalg.eigh(phi)
        scale = np.abs(lam).max(axis=-1)
        lam = np.where(np.abs(lam) > cut * scale[:, None], lam, 0.0)
        beta = np.swapaxes(vec, -1, -2) @ r0[idx, :n]
        on_valid = np.einsum("mjn,mj->mn", vec * vec, v.astype(np.float64))
        yield idx, lam, vec, beta, on_valid, scale


def _check_cutoff(cutoff: float) -> float:
    cut = float(cutoff)
    if not (0 <= cut < 1):
        raise ValidationError(f"cutoff must be in [0, 1); got {cutoff!r}")
    return cut


def fit_rbf_ridge(
    centres: np.ndarray,
    values: np.ndarray,
    sigma: np.ndarray | float,
    mask: np.ndarray | None = None,
    *,
    ridge: np.ndarray | float,
    cutoff: float = 1e-6,
    kernel_scale: np.ndarray | float | None = None,
) -> np.ndarray:
    """Weights of the Tikhonov-regularised RBF fit: ``argmin ||Φ w - r||² + μ ||w||²``.

    ``μ = ρ max|λ|²`` with ``λ`` the eigenvalues of the system's kernel matrix ``Φ``
    (the centres' :func:`fit_rbf` matrix), so ρ is dimensionless and means the same
    for every part. Solved through the eigen-decomposition, each mode multiplied by
    ``λ / (λ² + μ)``: an indefinite or near-singular ``Φ`` (the radial cubic B-spline
    is not positive definite in 3-D) amplifies no residual by more than
    ``1 / (2 √μ)``. With ``ρ = 0`` this is :func:`fit_rbf` (exact interpolation,
    modes below ``cutoff`` left out) to rounding; with ``ρ > 0`` the field passes
    near its centres, not through them (:func:`choose_ridge_gcv` chooses ρ).

    Parameters
    ----------
    centres : (..., K, 3) float, metres
    values : (..., K, D) float
        The residuals to fit (metres, D = 3); non-finite: excluded.
    sigma : float or (...) float, metres
        The dilation σ (positive; otherwise the system gets zero weights).
    mask : (..., K) bool, optional
        False excludes a centre: its weight is 0.
    ridge : float or (...) float
        ρ of each system (non-negative, finite).
    cutoff : float
        As :func:`fit_rbf`: modes with ``|λ| <= cutoff max|λ|`` are left out.
    kernel_scale : float or (...) float, optional
        The ``max|λ|`` that scales μ, per system (:func:`rbf_kernel_scale`; a
        non-finite or non-positive one: 1). Default: each system's own, from its
        eigen-decomposition. Given, a system with ``ρ > 0`` is solved with no
        eigen-decomposition at all: ``w = Re[(Φ + i √μ I)⁻¹ r]``, the same
        ``λ / (λ² + μ)`` on every mode (the real part of ``(λ + i √μ)⁻¹``) from one
        batched complex LU, several times cheaper than ``eigh`` and as accurate (its
        condition number is at most ``max|λ| / √μ``); no mode is left out by
        ``cutoff`` there, the ridge already bounds each mode's gain by ``1 / (2 √μ)``.
        Systems with ``ρ = 0`` are solved exactly as without it. The dense deformer
        passes its parts' scales at rest, so that μ stays one number per part over a
        take.

    Returns
    -------
    weights : (..., K, D) float64
        Zero for excluded centres and for systems with a non-positive or NaN σ.
    """
    cut = _check_cutoff(cutoff)
    c0, r0, valid, s, lead = _flat_systems(centres, values, sigma, mask)
    rho_in = np.asarray(ridge, dtype=np.float64)
    if not (np.isfinite(rho_in).all() and (rho_in >= 0).all()):
        raise ValidationError("ridge must be finite and non-negative")
    rho = np.broadcast_to(rho_in, lead).reshape(-1)
    scale = None
    if kernel_scale is not None:
        scale = np.broadcast_to(np.asarray(kernel_scale, dtype=np.float64), lead).reshape(-1)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    w = np.zeros(r0.shape)
    todo = np.ones(len(rho), dtype=bool)
    c = np.asarray(centres)
    if len(lead) >= 2 and c.ndim == np.ndim(values) and c.shape[0] == 1 and lead[0] > 1:
        # centres fixed over the leading (frames) axis: the frames where a system has
        # all its centres share one operator, V diag(λ / (λ² + μ)) Vᵀ, found once
        n_t, k = lead[0], c0.shape[1]
        s_t, rho_t, valid_t = s.reshape(n_t, -1), rho.reshape(n_t, -1), valid.reshape(n_t, -1, k)
        scale_t = None if scale is None else scale.reshape(n_t, -1)
        same_scale = scale_t is None or bool((scale_t == scale_t[:1]).all())
        if (s_t == s_t[:1]).all() and (rho_t == rho_t[:1]).all() and same_scale:
            full = np.asarray(valid_t.any(axis=0))  # (P, K): every centre a frame can have
            n_sys = full.shape[0]
            identity = np.broadcast_to(np.eye(k), (n_sys, k, k))
            operator = _ridge_solve(
                c0[:n_sys], identity, full, s_t[0], rho_t[0], cut,
                None if scale_t is None else scale_t[0],
            )  # fmt: skip
            same = (valid_t == full[None]).all(-1).reshape(-1)  # (T P,)
            system = np.tile(np.arange(n_sys), n_t)[same]
            w[same] = operator[system] @ r0[same]
            todo = ~same
    if todo.all():  # no copies of the whole batch
        w = _ridge_solve(c0, r0, valid, s, rho, cut, scale)
    else:
        rows = np.flatnonzero(todo)
        w[rows] = _ridge_solve(
            c0[rows], r0[rows], valid[rows], s[rows], rho[rows], cut,
            None if scale is None else scale[rows],
        )  # fmt: skip
    w = np.where(valid[..., None], w, 0.0)
    return w.reshape(*lead, *w.shape[-2:])


def _ridge_solve(
    c0: np.ndarray,
    r0: np.ndarray,
    valid: np.ndarray,
    s: np.ndarray,
    rho: np.ndarray,
    cut: float,
    kernel_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Ridge weights (S, K, D) of flattened systems (:func:`_flat_systems`), ρ (S,);
    with ``kernel_scale`` (S,) the systems with ρ > 0 by :func:`_ridge_solve_shifted`."""
    w = np.zeros(r0.shape)
    shifted = np.zeros(rho.shape, dtype=bool) if kernel_scale is None else rho > 0
    if shifted.any():
        mu = rho * kernel_scale * kernel_scale
        if shifted.all():
            w = _ridge_solve_shifted(c0, r0, valid, s, mu)
        else:
            w[shifted] = _ridge_solve_shifted(
                c0[shifted], r0[shifted], valid[shifted], s[shifted], mu[shifted]
            )
    rest = np.flatnonzero(~shifted)
    if rest.size:
        c0, r0, valid, s, rho = c0[rest], r0[rest], valid[rest], s[rest], rho[rest]
        for idx, lam, vec, beta, _, scale in _spectra(c0, r0, valid, s, cut):
            mu = (rho[idx] * scale * scale)[:, None]  # (m, 1)
            nonzero = lam != 0.0
            gain = np.where(nonzero, lam / np.where(nonzero, lam * lam + mu, 1.0), 0.0)  # λ/(λ²+μ)
            w[rest[idx], : lam.shape[1]] = vec @ (beta * gain[..., None])
    return w


def _masked_kernel_matrix(c0: np.ndarray, valid: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(S, K, K) kernel matrices of flattened systems, an excluded centre decoupled
    (a lone diagonal entry φ(0) = 2/3: weight 0, no constraint on the others)."""
    phi = _kernel_matrix(c0, c0, s)
    phi *= valid[:, :, None] & valid[:, None, :]
    diagonal = np.einsum("skk->sk", phi)  # a writeable view
    diagonal[~valid] = 2.0 / 3.0
    return phi


def _size_groups(valid: np.ndarray) -> Iterator[tuple[np.ndarray, int]]:
    """Flattened systems grouped by size: ``(idx, n)``, the systems whose last valid
    slot is ``n - 1`` (the slots after it are decoupled, weight 0, so a group is solved
    cut to ``n``: the cost follows each part's own size, not the largest). Systems
    with no valid slot are in no group."""
    k = valid.shape[1]
    n_eff = np.where(valid.any(-1), k - np.argmax(valid[:, ::-1], axis=-1), 0)
    for n in np.unique(n_eff[n_eff > 0]):
        yield np.flatnonzero(n_eff == n), int(n)


def _ridge_solve_shifted(
    c0: np.ndarray, r0: np.ndarray, valid: np.ndarray, s: np.ndarray, mu: np.ndarray
) -> np.ndarray:
    """Ridge weights (S, K, D) of flattened systems, μ (S,) given: no eigenvectors."""
    w = np.zeros(r0.shape)
    for idx, n in _size_groups(valid):
        phi = _masked_kernel_matrix(c0[idx, :n], valid[idx, :n], s[idx])
        w[idx, :n] = _solve_shifted(phi, r0[idx, :n], mu[idx])
    return w


def _solve_shifted(phi: np.ndarray, r0: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """``Re[(Φ + i √μ I)⁻¹ r]`` of (S, K, K) kernel matrices, (S, K, D) values, μ (S,).

    ``(Φ + i√μ)(Φ - i√μ) = Φ² + μ``, so the real part of the shifted solve is
    ``(Φ² + μ)⁻¹ Φ r``, the normal equations of the ridge fit, with the condition
    number of ``Φ + i√μ`` (at most ``max|λ| / √μ``) rather than its square.
    """
    shifted = phi.astype(np.complex128)
    diagonal = np.einsum("skk->sk", shifted)
    diagonal += 1j * np.sqrt(mu)[:, None]
    return np.linalg.solve(shifted, r0.astype(np.complex128)).real


def fit_rbf_ridge_nested(
    centres: np.ndarray,
    values: np.ndarray,
    sigma: np.ndarray | float,
    mask: np.ndarray | None,
    inner_mask: np.ndarray,
    *,
    ridge: np.ndarray,
    kernel_scale: np.ndarray,
    cutoff: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_rbf_ridge` through all the centres and through the leading ones alone.

    The second field's kernel matrix is the leading block of the first's, so with
    moving centres and every ``ρ > 0`` it is taken from it rather than computed again
    (the dense deformer's two fields of a part: its members come first, its seam
    centres after). Otherwise, the two fits of :func:`fit_rbf_ridge`.

    Parameters
    ----------
    centres, values, sigma, mask
        As :func:`fit_rbf_ridge` (values non-finite: excluded from both fields).
    inner_mask : (..., J) bool, J <= K
        The inner field's centres among the first ``J`` (those also in ``mask``).
    ridge : (2, ...) float
        ρ of each system's fields: row 0 through all its centres, row 1 the inner.
    kernel_scale : (2, ...) float
        ``max|λ|`` scaling each field's μ (:func:`rbf_kernel_scale`), rows as ``ridge``.
    cutoff : float
        As :func:`fit_rbf_ridge` (only for systems with ``ρ = 0``).

    Returns
    -------
    weights : (..., K, D) float64
        Through all the centres.
    inner_weights : (..., J, D) float64
        Through the inner centres alone.
    """
    c = np.asarray(centres, dtype=np.float64)
    r = np.asarray(values, dtype=np.float64)
    inner = np.asarray(inner_mask, dtype=bool)
    rho = np.asarray(ridge, dtype=np.float64)
    scale = np.asarray(kernel_scale, dtype=np.float64)
    if rho.shape[:1] != (2,) or scale.shape[:1] != (2,) or inner.shape[-1] > c.shape[-2]:
        raise ValidationError(
            f"ridge and kernel_scale must have a leading axis of 2 and inner_mask at most "
            f"{c.shape[-2]} centres; got {rho.shape}, {scale.shape}, {inner.shape}"
        )
    k_in = inner.shape[-1]
    if mask is not None:  # the inner centres are among the outer ones
        inner = inner & np.asarray(mask, dtype=bool)[..., :k_in]
    fixed = c.ndim == r.ndim and c.shape[0] == 1 and r.shape[0] > 1
    if fixed or not (rho > 0).all() or not np.isfinite(rho).all():
        return (
            fit_rbf_ridge(c, r, sigma, mask, ridge=rho[0], kernel_scale=scale[0], cutoff=cutoff),
            fit_rbf_ridge(
                c[..., :k_in, :], r[..., :k_in, :], sigma, inner,
                ridge=rho[1], kernel_scale=scale[1], cutoff=cutoff,
            ),
        )  # fmt: skip
    c0, r0, valid, s, lead = _flat_systems(c, r, sigma, mask)
    valid_in = valid[:, :k_in] & np.broadcast_to(inner, (*lead, k_in)).reshape(-1, k_in)
    mu = []
    for field in range(2):
        field_scale = np.broadcast_to(scale[field], lead).reshape(-1)
        field_scale = np.where(np.isfinite(field_scale) & (field_scale > 0), field_scale, 1.0)
        mu.append(np.broadcast_to(rho[field], lead).reshape(-1) * field_scale**2)
    w, w_in = np.zeros(r0.shape), np.zeros((r0.shape[0], k_in, r0.shape[2]))
    for idx, n in _size_groups(valid):  # each group at its own size, both fields
        v = valid[idx, :n]
        phi = _kernel_matrix(c0[idx, :n], c0[idx, :n], s[idx])
        has_in = valid_in[idx].any(-1)
        n_in = int((k_in - np.argmax(valid_in[idx, ::-1], axis=-1))[has_in].max(initial=0))
        if n_in:  # the inner field's matrix: the leading block, re-masked
            v_in = valid_in[idx, :n_in]
            phi_in = phi[:, :n_in, :n_in] * (v_in[:, :, None] & v_in[:, None, :])
            np.einsum("skk->sk", phi_in)[~v_in] = 2.0 / 3.0  # decoupled
            r_in = np.where(v_in[..., None], r0[idx, :n_in], 0.0)
            w_in[idx, :n_in] = _solve_shifted(phi_in, r_in, mu[1][idx])
        phi *= v[:, :, None] & v[:, None, :]
        np.einsum("skk->sk", phi)[~v] = 2.0 / 3.0
        w[idx, :n] = _solve_shifted(phi, r0[idx, :n], mu[0][idx])
    # an inner field whose outer one has no valid centre has none either (inner ⊆ outer)
    w = np.where(valid[..., None], w, 0.0).reshape(*lead, *w.shape[-2:])
    w_in = np.where(valid_in[..., None], w_in, 0.0).reshape(*lead, *w_in.shape[-2:])
    return w, w_in


def rbf_kernel_scale(
    centres: np.ndarray, sigma: np.ndarray | float, mask: np.ndarray | None = None
) -> np.ndarray:
    """``max|λ|`` of each system's kernel matrix, the scale of :func:`fit_rbf_ridge`'s μ.

    Parameters
    ----------
    centres : (..., K, 3) float, metres (non-finite: not a centre)
    sigma : float or (...) float, metres
    mask : (..., K) bool, optional
        False excludes a centre.

    Returns
    -------
    (...) float64
        NaN for a system with no valid centre or a non-positive or NaN σ.
    """
    c = np.asarray(centres, dtype=np.float64)
    if c.ndim >= 2 and c.shape[-2] == 0:  # no centre slot: no system has a matrix
        lead = np.broadcast_shapes(c.shape[:-2], np.shape(sigma))
        return np.full(lead, np.nan)
    c0, _, valid, s, lead = _flat_systems(c, np.zeros(c.shape[:-1] + (1,)), sigma, mask)
    lam = np.linalg.eigvalsh(_masked_kernel_matrix(c0, valid, s))
    scale = np.where(valid.any(-1), np.abs(lam).max(axis=-1), np.nan)
    return scale.reshape(lead)


def choose_ridge_gcv(
    centres: np.ndarray,
    values: np.ndarray,
    sigma: np.ndarray | float,
    mask: np.ndarray | None = None,
    *,
    cutoff: float = 1e-6,
    grid: np.ndarray = RIDGE_GRID,
    kernel_scale: np.ndarray | float | None = None,
) -> np.ndarray:
    """ρ of :func:`fit_rbf_ridge` for each system, by generalised cross-validation pooled over frames.

    For a ridge ρ the fitted values at the centres are ``H r`` with the smoother
    ``H = Φ (Φ² + μ)⁻¹ Φ``, whose eigenvalues are ``f = λ² / (λ² + μ)``. GCV scores
    ``G(ρ) = N Σ_t ||(I - H_t) r_t||² / (Σ_t tr(I - H_t))²`` (N valid centre-frames),
    the rotation-invariant form of leave-one-out cross-validation, and the ρ of
    ``grid`` with the lowest score is kept (the smallest on a tie, e.g. all-zero values).
    One ρ per system over all its frames: a field that changed its smoothness from
    frame to frame would flicker.

    Parameters
    ----------
    centres : (T or 1, ..., K, 3) float, metres
        The centres at each frame (a leading 1: the same at every frame).
    values : (T, ..., K, D) float
        The values at each frame (non-finite: excluded at that frame).
    sigma : float or (...) float, metres
    mask : (T, ..., K) bool, optional
    cutoff : float
        As :func:`fit_rbf`.
    grid : (G,) float
        Candidate ρ, ascending, non-negative.
    kernel_scale : float or (...) float, optional
        The ``max|λ|`` that scales μ for each system, as :func:`fit_rbf_ridge` takes
        it (default: each frame's own), so that the ρ chosen means the same there.

    Returns
    -------
    (...) float64
        The chosen ρ of each system (``grid[0]`` for a system with no valid centre).
    """
    cut = _check_cutoff(cutoff)
    c = np.asarray(centres, dtype=np.float64)
    r = np.asarray(values, dtype=np.float64)
    if r.ndim < 3 or c.ndim != r.ndim:
        raise ValidationError(
            f"centres must be (T or 1, ..., K, 3) and values (T, ..., K, D); "
            f"got {c.shape} and {r.shape}"
        )
    g = np.asarray(grid, dtype=np.float64).reshape(-1)
    if g.size == 0 or not (np.isfinite(g).all() and (g >= 0).all()):
        raise ValidationError("grid must hold finite non-negative ridge strengths")
    s = np.asarray(sigma, dtype=np.float64)
    c0, r0, valid, s_flat, lead = _flat_systems(c, r, s[None] if s.ndim else s, mask)
    n_t = lead[0]
    n_sys = int(np.prod(lead[1:], dtype=np.int64))
    residual = np.zeros((n_t * n_sys, g.size))  # Σ ||(I - H) r||² of every row
    trace = np.zeros((n_t * n_sys, g.size))  # tr(I - H) over the valid centres
    given = None
    if kernel_scale is not None:
        given = np.broadcast_to(np.asarray(kernel_scale, dtype=np.float64), lead[1:])
        given = np.tile(np.where(np.isfinite(given) & (given > 0), given, 1.0).reshape(-1), n_t)
    for idx, lam, _, beta, on_valid, scale in _spectra(c0, r0, valid, s_flat, cut):
        scale = scale if given is None else given[idx]
        lam2 = lam * lam
        beta2 = (beta * beta).sum(-1)  # (m, n)
        n_valid = valid[idx].sum(-1)
        for j, rho in enumerate(g):  # G (~50) steps over (m, n)
            mu = (rho * scale * scale)[:, None]
            # 1 - f = μ / (λ² + μ), without the cancellation of 1 - f near f = 1
            damped = np.divide(mu, lam2 + mu, out=np.ones_like(lam2), where=lam2 > 0)
            residual[idx, j] = (damped * damped * beta2).sum(-1)
            trace[idx, j] = n_valid - ((1.0 - damped) * on_valid).sum(-1)
    residual = residual.reshape(n_t, n_sys, g.size).sum(0)
    trace = trace.reshape(n_t, n_sys, g.size).sum(0)
    n_obs = valid.reshape(n_t, n_sys, -1).sum(axis=(0, 2))[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.where(trace > 1e-12 * n_obs, n_obs * residual / trace**2, np.inf)
    score = np.where(np.isfinite(score).any(-1, keepdims=True), score, 0.0)  # no data: grid[0]
    return g[np.argmin(score, axis=-1)].reshape(lead[1:])


def evaluate_rbf(
    centres: np.ndarray,
    weights: np.ndarray,
    sigma: np.ndarray | float,
    points: np.ndarray,
) -> np.ndarray:
    """``f(x) = Σ_i w_i φ(||c_i - x|| / σ)`` at every point, batched.

    Parameters
    ----------
    centres : (..., K, 3) float, metres (non-finite centres must have zero weight)
    weights : (..., K, D) float (from :func:`fit_rbf`)
    sigma : float or (...) float, metres
    points : (..., M, 3) float, metres

    Returns
    -------
    (..., M, D) float64
    """
    c = np.asarray(centres, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    x = np.asarray(points, dtype=np.float64)
    if c.shape[-1] != 3 or x.shape[-1] != 3 or w.shape[-2] != c.shape[-2]:
        raise ValidationError(
            f"centres (..., K, 3), weights (..., K, D), points (..., M, 3) expected; "
            f"got {c.shape}, {w.shape}, {x.shape}"
        )
    lead = np.broadcast_shapes(c.shape[:-2], w.shape[:-2], x.shape[:-2])
    s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), lead)
    s_safe = np.where(np.isfinite(s) & (s > 0), s, 1.0)
    c0 = np.where(np.isfinite(c), c, 0.0)
    phi = _kernel_matrix(x, c0, s_safe)  # (..., M, K)
    return phi @ w
