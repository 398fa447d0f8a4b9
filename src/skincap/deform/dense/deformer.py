"""Dense-marker skin deformation (Park & Hodgins 2006, §5.3, eqs. 6-9), batched.

For every frame and every near-rigid part ``p``:

1. **Rigid** (Horn): the rotation ``R̃_p`` and translation that carry the part's member
   markers onto their local part reference positions ``p̂⁰`` (the batched Kabsch of
   :mod:`skincap.geometry.rigid`, weighted by the markers' weights α); the aligned
   markers are the local positions ``p̂ᵗ``.
2. **Quadratic** (eq. 6): the field ``Ã_p`` with ``p̂ᵗ ≈ Ã_p q(p̂⁰)``: the paper's
   3x9 modes plus a constant column, without which a pure quadratic field is not
   reproduced after the rigid fit has matched centroids
   (:func:`skincap.geometry.quadratic.fit_quadratic`, regularised toward the identity
   for parts with fewer than ten well-spread markers). The rigid variants use
   ``Ã = [I 0 0 0]``.
3. **RBF** (eq. 7): weights that interpolate the residual ``p̂ᵗ - Ã q(p̂⁰)`` at the
   deformed centres ``p̃ = Ã q(p̂⁰)`` with the cubic B-spline kernel and the part's σ.
   (The paper writes the residual as ``p̃ - p̂``; the sign that makes eq. 8 reproduce
   the markers is ``p̂ - p̃``, used here.) Only the ``*_rbf`` variants. Parts built with
   seam centres (:func:`skincap.deform.dense.parts.part_frames` given the marker-surface
   triangles; a rig's deformer is) get a second RBF through them as well; a vertex's
   RBF term in such a part is its members' field and its seam field blended by its
   ``seam_weights`` (the kernels sum both in one pass over the centres).
   The fit is ridge-regularised (:func:`skincap.geometry.rbf.fit_rbf_ridge`,
   :data:`RBF_RIDGE`): σ = 2 × the largest nearest-member distance makes the kernel of
   an irregular part wide against its spacing and its matrix indefinite, and the exact
   solve then threw vertices of the demo's 12-frame rig 35 cm. The ridge is there for
   stability, not smoothing: the markers sample the skin, so their residuals are signal.
   ``rbf_regularisation=0`` is the paper's exact interpolation; ``"gcv"`` chooses a
   ridge per part by cross-validation (:func:`skincap.geometry.rbf.choose_ridge_gcv`).
   The ridge's μ = ρ max|λ|² takes ``max|λ|`` of the part's kernel matrix at rest
   (:func:`rbf_kernel_scales`), one μ per part and field over the take, so no frame
   needs an eigen-decomposition: the fits are one batched complex LU a field, all
   frames and parts at once (:func:`~skincap.geometry.rbf.fit_rbf_ridge`).

4. **Vertices** (eqs. 8-9): a vertex's local reference position in each of its parts is
   moved by that part's field and taken back to the world; the results are blended by
   the vertex's part weights β.

The four variants of the paper's Fig. 7 are ``rigid``, ``quadratic``, ``rigid_rbf`` and
``quadratic_rbf`` (the paper's method, the default).

**Which parts get the quadratic base.** The paper fits eq. 6 on every part. A part
whose quadratic field is poorly determined (few markers, a part that spans a wrist)
extrapolates it to the vertices beyond its markers (the fingers) by centimetres, which
the paper would have fixed by hand. :func:`choose_quadratic_parts` decides per part,
on the rig's range of motion, whether the rigid or the quadratic base under the RBF
predicts the part's own held-out markers better (each member alone, and the 20 % at
either end of each axis of the part frame together); ``quadratic_rbf`` then uses the quadratic
base on the parts that earned it (``quadratic_parts``; default every part, as the
paper). ``quadratic`` stays the paper's variant on every part.

Missing markers: a member missing at a frame is left out of that frame's fits. A part
with fewer than three measured members at a frame is held in the pose of the nearest
earlier frame where it had three (the nearest later one at the start of the take), so
it keeps moving with the take rather than vanish. Only a part never seen with three
members gives NaN, and a vertex is NaN only when every part it belongs to is.

Everything is one array operation over frames, parts, members and vertex-part pairs;
frames stream in chunks so a long take never holds all its vertex frames. The fits are
NumPy; the per-frame vertex evaluation (eqs. 8-9) runs the numba kernel of
:mod:`skincap.deform.dense._kernel_numba` or its NumPy reference
:mod:`skincap.deform.dense._kernel_numpy` (``backend=``, as the skinning deformers).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import sparse

from skincap import backends
from skincap.backends import numba_available, resolve_backend
from skincap.deform.dense._kernel_numba import deform_vertices_numba, dense_dispatcher
from skincap.deform.dense._kernel_numpy import Precision, blend_pairs, move_pairs_numpy
from skincap.deform.dense._pair_tiles import pair_tiles
from skincap.deform.dense.parts import PartFrames, part_frames
from skincap.errors import ValidationError
from skincap.geometry.quadratic import (
    QUADRATIC_TERMS,
    apply_quadratic,
    fit_quadratic,
)
from skincap.geometry.rbf import (
    choose_ridge_gcv,
    evaluate_rbf,
    fit_rbf,
    fit_rbf_fixed_centres,
    fit_rbf_ridge,
    fit_rbf_ridge_nested,
    rbf_kernel_scale,
)
from skincap.geometry.rigid import fit_rigid

__all__ = [
    "METHODS",
    "DenseDeformer",
    "Method",
    "PartMotion",
    "RBF_RIDGE",
    "RbfRegularisation",
    "choose_quadratic_parts",
    "fit_part_motion",
    "held_frames",
    "rbf_kernel_scales",
]

Method = Literal["rigid", "quadratic", "rigid_rbf", "quadratic_rbf"]
#: The four deformation variants of Park & Hodgins' Fig. 7, simplest first.
METHODS: tuple[str, ...] = ("rigid", "quadratic", "rigid_rbf", "quadratic_rbf")
#: Fewest measured members for a part's rigid fit at a frame.
MIN_PART_MARKERS = 3
Backend = Literal["auto", "numba", "numpy"]
#: λ_quad of eq. 6 (:func:`skincap.geometry.quadratic.fit_quadratic`). On a synthetic
#: range-of-motion take ``quadratic_rbf`` had 1.90 mm vertex RMS at 1e-5, 1.50 at 1e-2,
#: 1.48 at 1e-1. A stronger pull toward the identity suits well-segmented synthetic takes
#: (240 frames, ROM 240, 5000 vertices, seam centres; λ = 0.01 / 0.1 / 1: jumprope 2.61
#: / 2.42 / 2.38 mm, flex 2.02 / 2.14 / 1.93, punch 2.30 / 2.28 / 2.10) but takes away
#: the bend of a part that spans a joint, which is what a sparse real capture's few
#: parts do: held-out markers of the two-part arm of the ``eval animate`` tests 6.2 /
#: 8.9 / 14.1 mm. Hence 1e-2.
QUADRATIC_REGULARISATION = 1e-2
#: Frames of a range-of-motion take :func:`choose_quadratic_parts` tests the parts on.
MODEL_CHOICE_FRAMES = 24
#: Share of a part's members at either end of each part axis that
#: :func:`choose_quadratic_parts` also leaves out together.
MODEL_CHOICE_END_SHARE = 0.2
#: Most single-member folds :func:`choose_quadratic_parts` tries per part: a larger part
#: leaves its members out in this many interleaved groups instead of one at a time (the
#: test costs folds x K³ per frame; a still take segments into a few parts of 100-350
#: markers, where leaving each out alone took minutes).
MODEL_CHOICE_MAX_FOLDS = 32
#: The RBF fit's ridge ρ (:func:`skincap.geometry.rbf.fit_rbf_ridge`): a number (0: exact
#: interpolation), a (2, P) array (row 0: the field through all of a part's centres, row
#: 1: its members' field) or "gcv" to choose it per part by cross-validation.
RbfRegularisation = Literal["gcv"] | float | np.ndarray
#: Default ridge ρ (μ = ρ max|λ|²): modes with |λ| below ~1e-3 of the largest are
#: damped, no residual is amplified more than ~500 / max|λ| times. Vertex RMS of
#: rigid_rbf / quadratic_rbf on the demo's 12-frame rig and on ``eval animate jr240
#: --rom rom`` (held-out markers' mean in brackets): exact 21.91 / 11.27 and 2.289 /
#: 2.570 (1.843) mm; ρ 1e-6: 2.40 / 2.48 and 2.289 / 2.569 (1.934); 1e-5: 2.19 / 2.28
#: and 2.289 / 2.564 (2.099); 1e-4: 2.26 / 2.35 and 2.290 / 2.561; GCV over 1e-12..1
#: (it reads the residuals as noise): 2.34 / 2.48 and 2.465 / 2.944 (1.958). The
#: smallest that keeps the demo's rig from throwing vertices.
RBF_RIDGE = 1e-6
#: Frames (evenly spread) over which :meth:`DenseDeformer.deform` chooses the ridges.
RIDGE_FRAMES = 64


def warm_up_kernel() -> None:
    """Compile the dense kernels into numba's cache (run by the background compile):
    the default ``quadratic_rbf``'s first, then the one without an RBF field."""
    parts = part_frames(np.eye(3), np.ones((3, 1)))
    deformer = DenseDeformer(parts, np.zeros((1, 3)), np.ones((1, 1)), backend="numba")
    for method in ("quadratic_rbf", "rigid"):
        deformer.deform_block(fit_part_motion(np.eye(3)[None], parts, method))


def _resolve_backend(backend: str) -> str:
    return resolve_backend(
        backend,
        numba_installed=numba_available(),
        feature="the numba dense deformation kernel",
        kernel=("dense", dense_dispatcher),
    )


def _check_method(method: str) -> tuple[bool, bool]:
    if method not in METHODS:
        raise ValidationError(f"method: expected one of {', '.join(METHODS)}; got {method!r}")
    return method.startswith("quadratic"), method.endswith("_rbf")


@dataclass(eq=False)
class PartMotion:
    """The fitted per-frame fields of every part, for a block of frames.

    Attributes
    ----------
    rotation : (T, P, 3, 3) float64
        ``R̃_p^t``: world -> local rotation (``local = R x + translation``).
    translation : (T, P, 3) float64, metres
    quadratic : (T, P, 3, 10) float64
        ``Ã_p^t`` (``[I 0 0 0]`` for the rigid variants), with the constant column of
        :mod:`skincap.geometry.quadratic`.
    centres : (T, P, K, 3) float64, metres
        ``p̃``: the members' reference positions moved by the quadratic field (0 on padding).
    rbf_weights : (T, P, K, 3) float64, metres
        ``w_p^t`` of eq. 7 over the members and the seam centres (all 0 without RBF;
        0 for missing members).
    member_rbf_weights : (T, P, K, 3) float64 or None, metres
        The same fitted to the members alone (0 on the seam centres); None when the
        parts have no seam centre (then it is ``rbf_weights``).
    rbf_ridge : (2, P) float64 or None
        The ridge ρ of each part's RBF fits (row 0: through all its centres, row 1:
        its members alone); None for exact interpolation or no RBF.
    """

    rotation: np.ndarray
    translation: np.ndarray
    quadratic: np.ndarray
    centres: np.ndarray
    rbf_weights: np.ndarray
    member_rbf_weights: np.ndarray | None = None
    rbf_ridge: np.ndarray | None = None


def _identity_field() -> np.ndarray:
    """``[I 0 0 0]``, (3, 10): the quadratic field of a rigid base."""
    field = np.zeros((3, QUADRATIC_TERMS))
    field[:, :3] = np.eye(3)
    return field


def held_frames(member_present: np.ndarray) -> np.ndarray:
    """For every frame and part, the frame whose markers its fit uses.

    A frame where the part has at least three measured members uses itself; otherwise
    the nearest earlier such frame, or at the start the first later one; a part never
    seen with three members gets -1.

    Parameters
    ----------
    member_present : (T, P, K) bool
        Measured members (padding False).

    Returns
    -------
    (T, P) int64
    """
    ok = member_present.sum(axis=-1) >= MIN_PART_MARKERS  # (T, P)
    n_t = ok.shape[0]
    frame = np.arange(n_t)[:, None]
    last = np.maximum.accumulate(np.where(ok, frame, -1), axis=0)
    first = np.where(ok.any(axis=0), np.argmax(ok, axis=0), -1)  # (P,)
    return np.where(last >= 0, last, first[None, :])


def rbf_kernel_scales(parts: PartFrames) -> np.ndarray:
    """The scales of each part's RBF ridges: ``max|λ|`` of its kernel matrices at rest.

    The ridge of eq. 7's fit is ``μ = ρ max|λ|²`` (:func:`~skincap.geometry.rbf.fit_rbf_ridge`),
    with ``λ`` the eigenvalues of a part's kernel matrix over its centres at their
    reference positions, all present: one μ per part and field for the whole take. (The
    matrix of a frame differs from it by the frame's quadratic field and missing
    markers; its own ``max|λ|`` would take an eigen-decomposition of every part at every
    frame, the fits' main cost, and let μ flicker with them.)

    Parameters
    ----------
    parts : PartFrames

    Returns
    -------
    (2, P) float64
        Row 0: the kernel through all a part's centres (members and seam centres);
        row 1: through its fitted members alone. NaN for a part without σ.
    """
    k_fit = int(parts.fitted.sum(axis=1).max(initial=0))
    return np.stack(
        [
            rbf_kernel_scale(parts.local_reference, parts.sigma, parts.valid),
            rbf_kernel_scale(
                parts.local_reference[:, :k_fit], parts.sigma, parts.fitted[:, :k_fit]
            ),
        ]
    )


def _fit_part_rbfs(
    parts: PartFrames,
    local: np.ndarray,
    centres: np.ndarray,
    present: np.ndarray,
    use_quadratic: bool,
    rbf_regularisation: RbfRegularisation,
    kernel_scale: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The RBF fields of :func:`fit_part_motion` (eq. 7) through the residuals of its
    base fields.

    ``local`` (T, P, K, 3) the markers in each part's frame (NaN where missing),
    ``centres`` (T, P, K, 3) the base field applied to the rest positions, ``present``
    (T, P, K) bool, ``kernel_scale`` the (2, P) scales of the ridges
    (:func:`rbf_kernel_scales`; None: computed). Returns the weights (T, P, K, 3)
    through all centres, those through the members only (None without seam centres),
    and the (2, P) ridges (None: exact).
    """
    n_p = parts.members.shape[0]
    residual = local - centres  # NaN where missing: excluded by the fits
    member_present = present & parts.fitted
    k_fit = int(parts.fitted.sum(axis=1).max())  # the members fill the first slots
    # the quadratic variants' centres move with each frame's field; the rigid
    # ones' stay at the rest positions (padding: none)
    rest = np.where(parts.valid[..., None], parts.local_reference, np.nan)
    fit_centres = centres if use_quadratic else rest[None]
    fields = [(fit_centres, residual, present)]  # through all centres, then members'
    if parts.has_seam_centres:
        fields.append(
            (fit_centres[..., :k_fit, :], residual[..., :k_fit, :], member_present[..., :k_fit])
        )
    if kernel_scale is None:
        kernel_scale = rbf_kernel_scales(parts)
    elif np.shape(kernel_scale) != (2, n_p):
        raise ValidationError(
            f"rbf_kernel_scale must have shape (2, {n_p}); got {np.shape(kernel_scale)}"
        )
    ridge = _rbf_ridges(rbf_regularisation, fields, parts.sigma, kernel_scale)
    if ridge is None:  # exact interpolation (eq. 7)
        fitted = [
            fit_rbf(c, r, parts.sigma[None, :], m)
            if use_quadratic  # one inverse per part, downdated, for fixed centres
            else fit_rbf_fixed_centres(c[0], r, parts.sigma, m)
            for c, r, m in fields
        ]
    elif len(fields) == 2:  # both fields from one kernel matrix a part and frame
        fitted = list(
            fit_rbf_ridge_nested(
                fit_centres, residual, parts.sigma, present, member_present[..., :k_fit],
                ridge=ridge, kernel_scale=kernel_scale,
            )
        )  # fmt: skip
    else:
        fitted = [
            fit_rbf_ridge(c, r, parts.sigma, m, ridge=ridge[0], kernel_scale=kernel_scale[0])
            for c, r, m in fields
        ]
    rbf_w = fitted[0]
    member_rbf_w: np.ndarray | None = None
    if parts.has_seam_centres:
        member_rbf_w = np.zeros_like(rbf_w)
        member_rbf_w[:, :, :k_fit] = fitted[1]
    return rbf_w, member_rbf_w, ridge


def fit_part_motion(
    positions: np.ndarray,
    parts: PartFrames,
    method: Method = "quadratic_rbf",
    *,
    source_frames: np.ndarray | None = None,
    quadratic_regularisation: float = QUADRATIC_REGULARISATION,
    quadratic_parts: np.ndarray | None = None,
    rbf_regularisation: RbfRegularisation = RBF_RIDGE,
    rbf_kernel_scale: np.ndarray | None = None,
) -> PartMotion:
    """Fit the rigid, quadratic and RBF fields of every part at every frame (eqs. 6-7).

    Parameters
    ----------
    positions : (T, N, 3) float, metres
        Marker positions, NaN where missing.
    parts : PartFrames
    method : {"rigid", "quadratic", "rigid_rbf", "quadratic_rbf"}
    source_frames : (T', P) int, optional
        Row of ``positions`` each part's fit uses at each output frame (see
        :func:`held_frames`; default: computed from ``positions``, T' = T), -1 for none.
    quadratic_regularisation : float
        λ_quad of :func:`skincap.geometry.quadratic.fit_quadratic` (0 = the plain
        pseudo-inverse). The default (:data:`QUADRATIC_REGULARISATION`) keeps parts
        with few or poorly spread markers from inventing quadratic terms.
    quadratic_parts : (P,) bool, optional
        For ``quadratic_rbf`` only: the parts whose base field is quadratic; the others
        get the rigid base ``[I 0 0 0]`` under their RBF (:func:`choose_quadratic_parts`
        picks them; default every part, the paper's method). ``quadratic`` stays the
        paper's variant on every part.
    rbf_regularisation : float, (2, P) float or "gcv"
        The RBF fits' ridge ρ (:data:`RbfRegularisation`, default :data:`RBF_RIDGE`):
        0 interpolates the residuals exactly (the paper's eq. 7); "gcv" chooses it for
        each part and field from these frames (:func:`~skincap.geometry.rbf.choose_ridge_gcv`).
        A ridge's μ is ρ times the square of its part's :func:`rbf_kernel_scales`.
    rbf_kernel_scale : (2, P) float, optional
        ``rbf_kernel_scales(parts)``, which a caller fitting many blocks of frames
        computes once (default: computed here).

    Returns
    -------
    PartMotion
        T' frames; NaN fields for a part with ``source_frames == -1``.
    """
    use_quadratic, use_rbf = _check_method(method)
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValidationError(f"positions must have shape (T, N, 3); got {x.shape}")
    n_t = x.shape[0]
    n_p, k = parts.members.shape
    if parts.members.size and parts.members.max() >= x.shape[1]:
        raise ValidationError(
            f"positions has {x.shape[1]} markers; the parts use marker {int(parts.members.max())}"
        )
    gathered = x[:, parts.members]  # (T, P, K, 3)
    present = np.isfinite(gathered).all(-1) & parts.valid  # (T, P, K), seam centres too
    src = (
        held_frames(present & parts.fitted) if source_frames is None else np.asarray(source_frames)
    )
    if src.ndim != 2 or src.shape[1] != n_p or (src >= n_t).any():
        raise ValidationError(
            f"source_frames must have shape (T', {n_p}) with rows of positions ({n_t}); got {src.shape}"
        )
    n_t = src.shape[0]
    seen = src >= 0
    part_idx = np.arange(n_p)[None, :]
    gathered = gathered[np.where(seen, src, 0), part_idx]  # (T, P, K, 3), held frames
    present = present[np.where(seen, src, 0), part_idx] & seen[..., None]

    weights = np.where(present, parts.member_weights[None], 0.0)
    rot, trans = fit_rigid(gathered, parts.local_reference[None], weights, min_points=1)
    local = gathered @ np.swapaxes(rot, -1, -2) + trans[:, :, None, :]  # p̂ᵗ
    local = np.where(present[..., None], local, np.nan)
    if use_quadratic:
        quad = fit_quadratic(
            parts.local_reference[None],
            local,
            weights,
            quadratic_regularisation=quadratic_regularisation,
        )
        if use_rbf and quadratic_parts is not None:
            chosen = np.asarray(quadratic_parts, dtype=bool)
            if chosen.shape != (n_p,):
                raise ValidationError(
                    f"quadratic_parts must have shape ({n_p},); got {chosen.shape}"
                )
            quad = np.where(chosen[None, :, None, None], quad, _identity_field())
    else:
        quad = np.broadcast_to(_identity_field(), (n_t, n_p, 3, QUADRATIC_TERMS)).copy()
    quad = np.where(seen[..., None, None], quad, np.nan)
    centres = np.where(
        parts.valid[None, ..., None], apply_quadratic(quad, parts.local_reference[None]), 0.0
    )
    if use_rbf:
        rbf_w, member_rbf_w, ridge = _fit_part_rbfs(
            parts, local, centres, present, use_quadratic, rbf_regularisation, rbf_kernel_scale
        )
    else:
        rbf_w, member_rbf_w, ridge = np.zeros((n_t, n_p, k, 3)), None, None
    centres = np.where(np.isfinite(centres), centres, 0.0)
    return PartMotion(rot, trans, quad, centres, rbf_w, member_rbf_w, ridge)


def _rbf_ridges(
    regularisation: RbfRegularisation,
    fields: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    sigma: np.ndarray,
    kernel_scale: np.ndarray,
) -> np.ndarray | None:
    """(2, P) ridges of the fits in ``fields`` (chosen by GCV, or given), None for exact."""
    n_parts = sigma.shape[0]
    if isinstance(regularisation, str):
        if regularisation != "gcv":
            raise ValidationError(
                f"rbf_regularisation: expected 'gcv', a number or a (2, P) array; "
                f"got {regularisation!r}"
            )
        ridge = np.zeros((2, n_parts))
        for i, (c, r, m) in enumerate(fields):
            ridge[i] = choose_ridge_gcv(c, r, sigma, m, kernel_scale=kernel_scale[i])
        if len(fields) == 1:
            ridge[1] = ridge[0]
        return ridge
    given = np.asarray(regularisation, dtype=np.float64)
    try:
        ridge = np.broadcast_to(given, (2, n_parts))
    except ValueError:
        raise ValidationError(
            f"rbf_regularisation must be a number or have shape (2, {n_parts}); got {given.shape}"
        ) from None
    if not (np.isfinite(ridge).all() and (ridge >= 0).all()):
        raise ValidationError("rbf_regularisation must be finite and non-negative")
    return None if not ridge.any() else np.array(ridge)


def choose_quadratic_parts(
    positions: np.ndarray,
    parts: PartFrames,
    *,
    n_frames: int = MODEL_CHOICE_FRAMES,
    quadratic_regularisation: float = QUADRATIC_REGULARISATION,
) -> np.ndarray:
    """Which parts' quadratic base predicts their own held-out markers better than rigid.

    Park & Hodgins fit the quadratic field of eq. 6 on every part; a part with few or
    poorly spread markers (a hand, a foot) or one whose vertices reach far beyond its
    markers (the fingers beyond the hand's) extrapolates it badly, which the paper
    would have tuned by hand. Here each part is tested on ``n_frames`` frames spread
    over ``positions`` (the rig's range of motion) by leaving each of its fitted
    members out in turn: the rest give the rigid fit, the base field (rigid
    ``[I 0 0 0]`` or quadratic, eq. 6) and the members' RBF residual (eq. 7), which
    then predicts the left-out member. The quadratic base is kept where its summed
    squared prediction error is smaller by more than one standard error of the mean
    difference over the held-out samples (the one-standard-error rule of
    cross-validation: the simpler model unless the data clearly prefer the other).

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    parts : PartFrames
    n_frames : int
        Frames tested (evenly spaced; all when the take is shorter).
    quadratic_regularisation : float
        λ_quad of the quadratic fits (:func:`fit_part_motion`).

    Returns
    -------
    (P,) bool
        True where the quadratic base predicted clearly better; False for a part with
        fewer than five fitted members (one left out leaves too few to test the fit).
    """
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValidationError(f"positions must have shape (T, N, 3); got {x.shape}")
    if parts.members.size and parts.members.max() >= x.shape[1]:
        raise ValidationError(
            f"positions has {x.shape[1]} markers; the parts use marker {int(parts.members.max())}"
        )
    picks = np.unique(np.linspace(0, x.shape[0] - 1, max(1, int(n_frames))).round().astype(int))
    chosen = np.zeros(parts.n_parts, dtype=bool)
    for p in range(parts.n_parts):  # P (~17) steps, each batched over frames and left-out members
        fitted = np.flatnonzero(parts.fitted[p])
        k = fitted.size
        if k < MIN_PART_MARKERS + 2 or not np.isfinite(parts.sigma[p]):
            continue
        rigid, quadratic = _held_out_member_errors(
            x[picks][:, parts.members[p, fitted]],
            parts.local_reference[p, fitted],
            parts.member_weights[p, fitted],
            float(parts.sigma[p]),
            quadratic_regularisation,
        )
        gain = rigid - quadratic  # (samples,) m², > 0 where the quadratic base did better
        if gain.size > 1:  # the one-standard-error rule: the simpler base unless clearly beaten
            chosen[p] = bool(gain.mean() > gain.std(ddof=1) / np.sqrt(gain.size))
    return chosen


def _held_out_folds(
    reference: np.ndarray, end_share: float, max_folds: int = MODEL_CHOICE_MAX_FOLDS
) -> np.ndarray:
    """(L, K) bool: the member sets left out in turn, each member alone, then the ends.

    A part of more than ``max_folds`` members leaves them out in ``max_folds``
    interleaved groups instead of one at a time.

    The ends are the ``end_share`` of the members lowest and highest along each axis of
    the part frame (``reference`` is in it): a part's vertices reach beyond its markers
    (fingers beyond the hand's, toes beyond the foot's), and predicting an end from the
    rest tests that extrapolation, which single members inside do not.
    """
    k = reference.shape[0]
    n_end = max(1, int(round(end_share * k)))
    order = np.argsort(reference, axis=0, kind="stable")  # (K, 3)
    ends = np.zeros((6, k), dtype=bool)
    for axis in range(3):
        ends[2 * axis, order[:n_end, axis]] = True
        ends[2 * axis + 1, order[k - n_end :, axis]] = True
    if k <= max_folds:
        singles = np.eye(k, dtype=bool)
    else:  # interleaved along the part's long axis, so a group is spread over the part
        group = np.empty(k, dtype=np.int64)
        group[order[:, 0]] = np.arange(k) % max_folds
        singles = group[None, :] == np.arange(max_folds)[:, None]
    return np.concatenate([singles, ends])


def _held_out_member_errors(
    markers: np.ndarray,
    reference: np.ndarray,
    weights: np.ndarray,
    sigma: float,
    quadratic_regularisation: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Squared held-out errors (m²) of one part, rigid base and quadratic base: one per
    held-out sample (frame, fold, left-out member) where both are finite.

    ``markers`` (S, K, 3) world positions of the part's fitted members at the tested
    frames (NaN where missing), ``reference`` (K, 3) their local reference positions,
    ``weights`` (K,) α. Batch axes: frame s, fold l (:func:`_held_out_folds`), member k.
    """
    folds = _held_out_folds(reference, MODEL_CHOICE_END_SHARE)  # (L, K)
    present = np.isfinite(markers).all(-1)  # (S, K)
    keep = present[:, None, :] & ~folds[None]  # (S, L, K)
    w = np.where(keep, weights[None, None, :], 0.0)
    rot, trans = fit_rigid(markers[:, None], reference, w)  # (S, L, 3, 3), (S, L, 3)
    local = markers[:, None] @ np.swapaxes(rot, -1, -2) + trans[..., None, :]  # (S, L, K, 3)
    scored = present[:, None, :] & folds[None] & np.isfinite(local).all(-1)  # (S, L, K)
    # folds in chunks: the RBF fits hold (S, L, K, K) kernels, 0.7 GB each for one
    # 352-marker part (a still take is one part) on 2 frames; a chunk holds ~32 MB
    s_, l_, k_ = keep.shape
    step = max(1, _HELD_OUT_CHUNK_ELEMENTS // max(1, s_ * k_ * k_))
    chunks = [
        _held_out_fold_errors(
            reference,
            local[:, a : a + step],
            w[:, a : a + step],
            keep[:, a : a + step],
            sigma,
            quadratic_regularisation,
        )
        for a in range(0, l_, step)
    ]
    errors = [np.concatenate([c[i] for c in chunks], axis=1) for i in (0, 1)]
    both = scored & np.isfinite(errors[0]) & np.isfinite(errors[1])
    return errors[0][both], errors[1][both]


#: Elements (S x L x K x K) of the held-out RBF kernels computed at once.
_HELD_OUT_CHUNK_ELEMENTS = 4_000_000


def _held_out_fold_errors(
    reference: np.ndarray,
    local: np.ndarray,
    w: np.ndarray,
    keep: np.ndarray,
    sigma: float,
    quadratic_regularisation: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Squared prediction errors (S, L, K) of the rigid and the quadratic base on some folds.

    ``local`` (S, L, K, 3) the members in the part frame after each fold's rigid fit,
    ``w`` (S, L, K) the fitting weights (0 where left out or missing), ``keep`` (S, L, K)
    the members each fold fits.
    """
    errors = []
    for quadratic in (False, True):
        if quadratic:
            field = fit_quadratic(
                reference, np.where(keep[..., None], local, np.nan), w,
                quadratic_regularisation=quadratic_regularisation,
            )  # fmt: skip
        else:
            field = np.broadcast_to(_identity_field(), (*keep.shape[:2], 3, QUADRATIC_TERMS))
        centres = apply_quadratic(field, reference)  # (S, L, K, 3)
        centres = np.where(np.isfinite(centres), centres, 0.0)
        residual = np.where(keep[..., None], local - centres, 0.0)
        rbf_w = fit_rbf(centres, residual, sigma, keep)
        predicted = centres + evaluate_rbf(centres, rbf_w, sigma, centres)
        errors.append(((predicted - local) ** 2).sum(-1))  # (S, L, K)
    return errors[0], errors[1]


class DenseDeformer:
    """A body mesh bound to the parts of a marker set: vertices by eqs. 8-9.

    Parameters
    ----------
    parts : PartFrames
    rest_vertices : (V, 3) float, metres
        The (registered) mesh in the markers' reference pose.
    vertex_weights : (V, P) float
        β: part weights of every vertex (rows sum to 1; rows are renormalised).
    seam_weights : (V, P) float in [0, 1], optional
        Only for parts with seam centres (:func:`~skincap.deform.dense.parts.part_frames`
        with ``surface_faces``): how much of each (vertex, part) pair follows the part's
        field through its seam centres rather than its members' alone
        (:func:`skincap.deform.dense.weights.seam_vertex_weights`: 1 on the marker-surface
        triangles at a seam, 0 inside the part, continuous between). Default 1.
    quadratic_parts : (P,) bool, optional
        The parts ``quadratic_rbf`` gives a quadratic base (:func:`choose_quadratic_parts`,
        which a rig runs on its range of motion); default every part.
    backend : {"auto", "numba", "numpy"}, default "auto"
        The per-frame vertex evaluation: the compiled kernel
        (:mod:`skincap.deform.dense._kernel_numba`) or its NumPy reference
        (:mod:`skincap.deform.dense._kernel_numpy`), which agree to rounding.
    precision : {"mixed", "float64"}, default "mixed"
        The RBF sums of the vertex pass: "mixed" computes a tile's kernel values and
        sums in float32 where their modelled rounding error stays within
        :data:`~skincap.deform.dense._kernel_numpy.F32_TOLERANCE` (1e-6 m) and in
        float64 elsewhere; "float64" everywhere (the reference).
        ``"auto"`` runs the kernel when it is compiled (in this process or in numba's
        cache) and otherwise NumPy while it compiles in the background
        (:func:`skincap.backends.resolve_backend`), switching to it as soon as it is
        cached; ``"numba"`` compiles in this process.

    Attributes
    ----------
    backend : str
        The evaluation in use, ``"numba"`` or ``"numpy"``.
    quadratic_parts : (P,) bool or None
        The parts ``quadratic_rbf`` gives a quadratic base (None: every part).
    """

    def __init__(
        self,
        parts: PartFrames,
        rest_vertices: np.ndarray,
        vertex_weights: np.ndarray,
        *,
        seam_weights: np.ndarray | None = None,
        quadratic_parts: np.ndarray | None = None,
        backend: Backend = "auto",
        precision: Precision = "mixed",
    ):
        v = np.asarray(rest_vertices, dtype=np.float64)
        beta = np.asarray(vertex_weights, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise ValidationError(f"rest_vertices must be finite with shape (V, 3); got {v.shape}")
        if beta.shape != (v.shape[0], parts.n_parts):
            raise ValidationError(
                f"vertex_weights must have shape ({v.shape[0]}, {parts.n_parts}); got {beta.shape}"
            )
        if not np.isfinite(beta).all() or (beta < 0).any():
            raise ValidationError("vertex_weights must be finite and non-negative")
        total = beta.sum(axis=1)
        if (total <= 0).any():
            raise ValidationError(
                f"vertex_weights: {int((total <= 0).sum())} vertices belong to no part"
            )
        beta = beta / total[:, None]
        if quadratic_parts is not None:
            quadratic_parts = np.asarray(quadratic_parts, dtype=bool)
            if quadratic_parts.shape != (parts.n_parts,):
                raise ValidationError(
                    f"quadratic_parts must have shape ({parts.n_parts},); "
                    f"got {quadratic_parts.shape}"
                )
        self.quadratic_parts = quadratic_parts
        self.parts = parts
        self.n_vertices = int(v.shape[0])
        sigma = parts.sigma
        self._rbf_scale = np.where(np.isfinite(sigma) & (sigma > 0), 2.0 / sigma, 0.0)
        # every centre of a part (members first, then its seam centres); with seam
        # centres each part has two RBF fields through them (the members' weights are
        # 0 on the seam centres), the same rigid and quadratic fields, and each
        # (vertex, part) pair follows the seam field by its seam weight
        self._n_centres = parts.valid.sum(axis=1)
        self._split = parts.has_seam_centres
        seam = np.zeros_like(beta)
        if self._split and seam_weights is not None:
            seam = np.asarray(seam_weights, dtype=np.float64)
            if seam.shape != beta.shape or not ((seam >= 0) & (seam <= 1)).all():
                raise ValidationError(
                    f"seam_weights must be in [0, 1] with shape {beta.shape}; got {seam.shape}"
                )
        elif self._split:
            seam = np.ones_like(beta)
        self._rbf_kernel_scale: np.ndarray | None = None  # rbf_kernel_scales, on first use
        self._tiles = pair_tiles(parts, v, beta, seam)  # the (vertex, part) pairs of eq. 9
        self.pair_vertex = self._tiles.vertex
        self.pair_part = self._tiles.part
        self.pair_weight = self._tiles.weight
        self._blend = sparse.csr_matrix(
            (self.pair_weight, (self.pair_vertex, np.arange(self.pair_vertex.size))),
            shape=(self.n_vertices, self.pair_vertex.size),
        )
        if precision not in ("mixed", "float64"):
            raise ValidationError(f"precision: expected 'mixed' or 'float64'; got {precision!r}")
        self.precision = precision
        self.backend = _resolve_backend(backend)
        # "auto" got NumPy because the kernel is compiling in the background: take it
        # as soon as it lands in the cache, so a long take is not NumPy throughout
        self._kernel_watch = backends.KernelWatch(
            dense_dispatcher, backend == "auto" and self.backend == "numpy" and numba_available()
        )

    def deform_block(self, motion: PartMotion) -> np.ndarray:
        """Vertex positions for a block of fitted frames (eqs. 8-9).

        Parameters
        ----------
        motion : PartMotion (T frames)

        Returns
        -------
        (T, V, 3) float64, metres
            NaN only for a vertex all of whose parts are NaN at that frame.
        """
        use_rbf = bool(np.any(motion.rbf_weights))
        rbf_members = np.where(use_rbf & (self._rbf_scale > 0), self._n_centres, 0)
        member_weights = motion.member_rbf_weights
        if not self._split or member_weights is None:  # one field: every pair follows it
            member_weights = motion.rbf_weights
        fields = (
            motion.quadratic,
            motion.rotation,
            motion.translation,
            motion.centres,
            member_weights,
            motion.rbf_weights,
            self._rbf_scale,
            rbf_members,
        )
        if self._kernel_watch.landed():
            self.backend = "numba"
        if self.backend == "numba":
            return deform_vertices_numba(self._tiles, *fields, precision=self.precision)
        tiles = self._tiles
        moved = move_pairs_numpy(
            tiles.basis, tiles.seam, tiles.part_start, tiles.tile_start, *fields,
            precision=self.precision, rest_kernels=tiles.rest_kernels,
        )  # fmt: skip
        return blend_pairs(moved, self._blend)

    def deform(
        self,
        positions: np.ndarray,
        method: Method = "quadratic_rbf",
        *,
        chunk: int = 32,
        quadratic_regularisation: float = QUADRATIC_REGULARISATION,
        rbf_regularisation: RbfRegularisation = RBF_RIDGE,
        progress: Callable[[float], None] | None = None,
    ) -> Iterator[np.ndarray]:
        """Stream the deformed vertices of a take, ``chunk`` frames at a time.

        Parameters
        ----------
        positions : (T, N, 3) float, metres, NaN where missing
        method : {"rigid", "quadratic", "rigid_rbf", "quadratic_rbf"}
        chunk : int
            Frames per yielded block.
        quadratic_regularisation : float
            See :func:`fit_part_motion`.
        rbf_regularisation : float, (2, P) float or "gcv"
            See :func:`fit_part_motion`; "gcv" chooses each part's ridge once, over
            :data:`RIDGE_FRAMES` frames spread over the take, so it is the same in
            every chunk.
        progress : callable(fraction), optional

        Yields
        ------
        (t, V, 3) float64 blocks, metres, in frame order.
        """
        _check_method(method)
        x = np.asarray(positions, dtype=np.float64)
        if x.ndim != 3 or x.shape[2] != 3:
            raise ValidationError(f"positions must have shape (T, N, 3); got {x.shape}")
        present = np.isfinite(x[:, self.parts.members]).all(-1) & self.parts.fitted
        source = held_frames(present)  # over the whole take, so holds cross chunks
        n_t = x.shape[0]
        if self._rbf_kernel_scale is None and method.endswith("_rbf"):
            self._rbf_kernel_scale = rbf_kernel_scales(self.parts)
        if isinstance(rbf_regularisation, str) and method.endswith("_rbf") and n_t:
            sample = np.unique(np.linspace(0, n_t - 1, min(n_t, RIDGE_FRAMES)).round().astype(int))
            ridge = fit_part_motion(
                x[sample],
                self.parts,
                method,
                quadratic_regularisation=quadratic_regularisation,
                quadratic_parts=self.quadratic_parts,
                rbf_regularisation=rbf_regularisation,
                rbf_kernel_scale=self._rbf_kernel_scale,
            ).rbf_ridge
            rbf_regularisation = 0.0 if ridge is None else ridge
        for s0 in range(0, n_t, int(chunk)):
            s1 = min(n_t, s0 + int(chunk))
            block_src = source[s0:s1]
            rows = np.unique(block_src[block_src >= 0])
            local_src = np.where(block_src >= 0, np.searchsorted(rows, block_src), -1)
            if rows.size == 0:
                yield np.full((s1 - s0, self.n_vertices, 3), np.nan)
            else:
                motion = fit_part_motion(
                    x[rows],
                    self.parts,
                    method,
                    source_frames=local_src,
                    quadratic_regularisation=quadratic_regularisation,
                    quadratic_parts=self.quadratic_parts,
                    rbf_regularisation=rbf_regularisation,
                    rbf_kernel_scale=self._rbf_kernel_scale,
                )
                yield self.deform_block(motion)
            if progress is not None:
                progress(s1 / n_t)
