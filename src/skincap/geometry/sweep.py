"""Sweep surfaces of moving ellipses (Hyun, Yoon, Chwa & Kim, *Sweep-based human deformation*, §3).

A standard ellipse of variable size ``E_t(θ) = (a(t) cos θ, b(t) sin θ, 0)`` moving
under a rotation ``R(t)`` and a translation ``C(t)`` sweeps the surface::

    S(θ, t) = R(t) E_t(θ) + C(t)                                        (eq. 1)

The first two columns of ``R(t)`` are the directions of the half-axes ``a`` and
``b``; the third is the normal ``N(t)`` of the ellipse's plane ``P(t)``. The sweep
bounds the volume ``∫ π a(t) b(t) <N(t), C'(t)> dt`` when it does not intersect
itself.

*Key ellipses* (:class:`KeyEllipses`) fix ``C``, ``R``, ``a`` and ``b`` at parameters
``t_0 < ... < t_K-1`` (one per joint plus intermediate ones along a link, §3.2); a
:class:`Sweep` interpolates them:

- centres by an interpolating cubic B-spline (not-a-knot) over the key parameters,
  which default to the chord length of the key centres (§3.2's knot spacing);
- orientations by spherical linear interpolation of consecutive key quaternions
  (``"slerp"``) or by the paper's normalised linear interpolation ``Q_i(t) / |Q_i(t)|``
  (``"nlerp"``);
- half-axes by monotone piecewise-cubic Hermite interpolation (PCHIP), which passes
  through the keys like the paper's B-splines but never overshoots, so the radii
  stay positive.

The ends may be closed by half-ellipsoid *caps* of a given length (0 = a flat cut).
A sweep can be sampled ring by ring into a closed triangle tube (:meth:`Sweep.tube`),
integrated for its volume (:meth:`Sweep.volume`), and asked where a point lies
(:meth:`Sweep.locate`: the paper's binding of a point to the plane ``P(t)`` that
contains it, §3.3, with its coordinates in that ellipse's frame) and how deep inside
the swept volume it is (:meth:`Sweep.signed_distance`). :func:`smooth_union` blends
several such fields into one implicit body.

Units are whatever the centres and radii are in (metres inside skincap). Quaternions
are scalar-last ``(x, y, z, w)``. Inputs must be finite (ValidationError otherwise);
query points with NaN give NaN outputs for those points.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.interpolate import PchipInterpolator, make_interp_spline

from skincap._arrays import as_finite_array
from skincap.errors import ValidationError
from skincap.geometry.rotations import matrix_to_quat, quat_to_matrix

__all__ = [
    "KeyEllipses",
    "Sweep",
    "chord_length_params",
    "frames_from_axes",
    "rotation_minimising_frames",
    "smooth_union",
]

Orientation = Literal["slerp", "nlerp"]

#: Points are processed in blocks of this many rows in :meth:`Sweep.locate`.
_BLOCK = 32768


def _array(name: str, value: object, shape: tuple[int | None, ...]) -> np.ndarray:
    return as_finite_array(value, name, shape, copy=True)


def chord_length_params(centres: np.ndarray) -> np.ndarray:
    """Cumulative chord length of a polyline, scaled to ``[0, 1]``.

    Parameters
    ----------
    centres : (K, 3) float
        Points in order (K >= 2), finite.

    Returns
    -------
    (K,) float64
        ``0`` at the first point, ``1`` at the last, increasing with the distance
        travelled along the polyline.

    Raises
    ------
    ValidationError
        Fewer than two points, or two consecutive points coincide.
    """
    c = _array("centres", centres, (None, 3))
    if c.shape[0] < 2:
        raise ValidationError(f"centres: need at least 2 points, got {c.shape[0]}")
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    if (seg <= 0).any():
        k = int(np.argmin(seg))
        raise ValidationError(f"centres: points {k} and {k + 1} coincide")
    s = np.concatenate([[0.0], np.cumsum(seg)])
    return s / s[-1]


def frames_from_axes(normals: np.ndarray, major: np.ndarray) -> np.ndarray:
    """Ellipse frames ``R = [a-axis, b-axis, N]`` from plane normals and major directions.

    Parameters
    ----------
    normals : (..., 3) float
        Plane normals ``N`` (need not be unit).
    major : (..., 3) float
        Direction of the ``a`` half-axis; its component along ``N`` is removed.

    Returns
    -------
    (..., 3, 3) float64
        Right-handed rotation matrices with columns ``(e_a, e_b, N)``,
        ``e_b = N x e_a``.

    Raises
    ------
    ValidationError
        A zero normal or a major direction parallel to its normal.
    """
    n = np.asarray(normals, dtype=np.float64)
    m = np.asarray(major, dtype=np.float64)
    if n.shape[-1:] != (3,) or m.shape[-1:] != (3,):
        raise ValidationError(
            f"normals, major: expected (..., 3) arrays, got {n.shape} and {m.shape}"
        )
    n, m = np.broadcast_arrays(n, m)
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    if (nn <= 1e-12).any():
        raise ValidationError("normals: must be non-zero")
    n = n / nn
    m = m - np.sum(m * n, axis=-1, keepdims=True) * n
    mn = np.linalg.norm(m, axis=-1, keepdims=True)
    if (mn <= 1e-9).any():
        raise ValidationError("major: must not be parallel to the normal")
    ea = m / mn
    eb = np.cross(n, ea)
    return np.stack([ea, eb, n], axis=-1)


def rotation_minimising_frames(
    points: np.ndarray,
    tangents: np.ndarray | None = None,
    first_axis: np.ndarray | None = None,
) -> np.ndarray:
    """Rotation-minimising frames along a sampled curve (double reflection).

    Wang, Jüttler, Zheng & Liu, *Computation of rotation minimizing frames*, ACM TOG
    27(1), 2008: each frame is carried to the next sample by two reflections, which
    approximates the parallel transport (no twist about the tangent) to fourth order.

    Parameters
    ----------
    points : (n, 3) float
        Curve samples in order, n >= 2, consecutive samples distinct.
    tangents : (n, 3) float, optional
        Tangents at the samples (need not be unit). Default: central differences.
    first_axis : (3,) float, optional
        Direction of the first frame's ``a`` axis (projected off the first tangent).
        Default: the world axis least aligned with the first tangent.

    Returns
    -------
    (n, 3, 3) float64
        Frames with columns ``(e_a, e_b, T)``: ``T`` the unit tangent (the ellipse
        normal ``N``), right-handed, orthonormal to rounding.

    Raises
    ------
    ValidationError
        Bad shapes, non-finite values, coincident samples or a zero tangent.
    """
    x = _array("points", points, (None, 3))
    n = x.shape[0]
    if n < 2:
        raise ValidationError(f"points: need at least 2 samples, got {n}")
    if (np.linalg.norm(np.diff(x, axis=0), axis=1) <= 0).any():
        raise ValidationError("points: consecutive samples coincide")
    t = np.gradient(x, axis=0) if tangents is None else _array("tangents", tangents, (n, 3))
    tn = np.linalg.norm(t, axis=1, keepdims=True)
    if (tn <= 1e-12).any():
        raise ValidationError("tangents: must be non-zero")
    t = t / tn
    if first_axis is None:
        first = np.eye(3)[int(np.argmin(np.abs(t[0])))]
    else:
        first = _array("first_axis", first_axis, (3,))
    r = np.empty((n, 3))
    r[0] = frames_from_axes(t[0], first)[:, 0]
    # sequential by construction: each frame is transported from the previous one
    v1 = x[1:] - x[:-1]
    c1 = np.einsum("ij,ij->i", v1, v1)
    for i in range(n - 1):
        rl = r[i] - (2.0 / c1[i]) * np.dot(v1[i], r[i]) * v1[i]
        tl = t[i] - (2.0 / c1[i]) * np.dot(v1[i], t[i]) * v1[i]
        v2 = t[i + 1] - tl
        c2 = np.dot(v2, v2)
        r[i + 1] = rl if c2 <= 1e-30 else rl - (2.0 / c2) * np.dot(v2, rl) * v2
    return frames_from_axes(t, r)


@dataclass(frozen=True, eq=False)
class KeyEllipses:
    """Key ellipses of a sweep (Hyun et al. §3.2).

    Attributes
    ----------
    params : (K,) float64
        Sweep parameter of each key, strictly increasing.
    centres : (K, 3) float64
        Ellipse centres ``C(t_i)`` (metres).
    rotations : (K, 4) float64
        Unit quaternions ``(x, y, z, w)`` of ``R(t_i)``: the matrix columns are the
        ``a`` half-axis direction, the ``b`` half-axis direction and the plane normal
        ``N`` (pointing along the sweep).
    radii : (K, 2) float64
        Half-axis lengths ``(a, b)`` > 0 (metres).
    """

    params: np.ndarray
    centres: np.ndarray
    rotations: np.ndarray
    radii: np.ndarray

    def __post_init__(self) -> None:
        c = _array("centres", self.centres, (None, 3))
        k = c.shape[0]
        if k < 2:
            raise ValidationError(f"centres: a sweep needs at least 2 key ellipses, got {k}")
        p = _array("params", self.params, (k,))
        if (np.diff(p) <= 0).any():
            raise ValidationError("params: must be strictly increasing")
        q = _array("rotations", self.rotations, (k, 4))
        norms = np.linalg.norm(q, axis=1)
        if np.abs(norms - 1.0).max() > 1e-6:
            raise ValidationError(
                f"rotations: expected unit quaternions, norms range {norms.min():.6g}..{norms.max():.6g}"
            )
        r = _array("radii", self.radii, (k, 2))
        if (r <= 0).any():
            raise ValidationError("radii: half-axis lengths must be positive")
        object.__setattr__(self, "centres", c)
        object.__setattr__(self, "params", p)
        object.__setattr__(self, "rotations", q / norms[:, None])
        object.__setattr__(self, "radii", r)

    @classmethod
    def from_frames(
        cls,
        centres: np.ndarray,
        frames: np.ndarray,
        radii: np.ndarray,
        params: np.ndarray | None = None,
    ) -> KeyEllipses:
        """Key ellipses from rotation matrices.

        Parameters
        ----------
        centres : (K, 3) float
        frames : (K, 3, 3) float
            Columns ``(e_a, e_b, N)`` (e.g. from :func:`frames_from_axes`).
        radii : (K, 2) float
        params : (K,) float, optional
            Default: :func:`chord_length_params` of the centres.
        """
        f = _array("frames", frames, (None, 3, 3))
        if (
            np.abs(np.einsum("kji,kjl->kil", f, f) - np.eye(3)).max() > 1e-6
            or (np.linalg.det(f) <= 0).any()
        ):
            raise ValidationError("frames: must be rotation matrices (orthonormal, det +1)")
        p = chord_length_params(centres) if params is None else params
        return cls(params=p, centres=centres, rotations=matrix_to_quat(f), radii=radii)

    @property
    def n_keys(self) -> int:
        return int(self.centres.shape[0])

    @property
    def frames(self) -> np.ndarray:
        """(K, 3, 3) rotation matrices of the keys."""
        return quat_to_matrix(self.rotations)

    def mirrored(self, axis: int = 0) -> KeyEllipses:
        """The mirror image in the plane ``x[axis] = 0`` (a left limb -> the right one).

        The ``b`` axis is flipped so the frames stay right-handed: a point with
        ellipse coordinates ``(x, y)`` on this sweep mirrors to ``(x, -y)`` on the
        returned one's, with the same ``t``.
        """
        flip = np.ones(3)
        flip[axis] = -1.0
        f = self.frames * flip[None, :, None]  # reflect every column
        f[:, :, 1] *= -1.0  # keep det +1
        return KeyEllipses(
            params=self.params,
            centres=self.centres * flip,
            rotations=matrix_to_quat(f),
            radii=self.radii,
        )


def _check_t(t: object) -> np.ndarray:
    arr = np.asarray(t, dtype=np.float64)
    if arr.ndim > 1:
        raise ValidationError(f"t: expected a scalar or a 1-D array, got shape {arr.shape}")
    return np.atleast_1d(arr)


class Sweep:
    """A sweep surface interpolating key ellipses (Hyun et al. §3.1-3.2).

    Parameters
    ----------
    keys : KeyEllipses
    orientation : {"slerp", "nlerp"}, default "slerp"
        How orientations are interpolated between consecutive keys: spherical
        linear interpolation, or the paper's normalised linear interpolation.
    caps : (float, float), default (0, 0)
        Lengths (metres) of the half-ellipsoid caps closing the start and the end of
        the swept volume, measured along ``-N(t_0)`` and ``N(t_K-1)``; 0 cuts the
        end flat.

    Notes
    -----
    The sweep is defined for ``t`` in ``[t_0, t_K-1]``; evaluation clamps to it.
    """

    def __init__(
        self,
        keys: KeyEllipses,
        *,
        orientation: Orientation = "slerp",
        caps: tuple[float, float] | Sequence[float] = (0.0, 0.0),
    ) -> None:
        if not isinstance(keys, KeyEllipses):
            raise ValidationError(f"keys: expected KeyEllipses, got {type(keys).__name__}")
        if orientation not in ("slerp", "nlerp"):
            raise ValidationError(f"orientation: expected 'slerp' or 'nlerp', got {orientation!r}")
        cap = _array("caps", caps, (2,))
        if (cap < 0).any():
            raise ValidationError(f"caps: lengths must be >= 0, got {cap.tolist()}")
        self.keys = keys
        self.orientation = orientation
        self.caps = cap
        p = keys.params
        self._centre = make_interp_spline(p, keys.centres, k=min(3, keys.n_keys - 1), axis=0)
        self._radii = PchipInterpolator(p, keys.radii, axis=0)
        q = keys.rotations.copy()
        # consecutive keys in the same hemisphere: interpolate along the short arc
        dots = np.einsum("ij,ij->i", q[1:], q[:-1])
        signs = np.cumprod(np.concatenate([[1.0], np.where(dots < 0, -1.0, 1.0)]))
        self._quats = q * signs[:, None]

    # ------------------------------------------------------------------ evaluation
    @property
    def t_range(self) -> tuple[float, float]:
        """``(t_0, t_K-1)``."""
        return float(self.keys.params[0]), float(self.keys.params[-1])

    def _clamp(self, t: object) -> np.ndarray:
        lo, hi = self.t_range
        return np.clip(_check_t(t), lo, hi)

    def centres(self, t: object) -> np.ndarray:
        """(n,) parameters -> (n, 3) centres ``C(t)`` (metres)."""
        return np.asarray(self._centre(self._clamp(t)), dtype=np.float64)

    def tangents(self, t: object) -> np.ndarray:
        """(n,) parameters -> (n, 3) derivatives ``C'(t)`` (metres per unit of t)."""
        return np.asarray(self._centre.derivative()(self._clamp(t)), dtype=np.float64)

    def radii(self, t: object) -> np.ndarray:
        """(n,) parameters -> (n, 2) half-axes ``(a(t), b(t))`` (metres), always > 0."""
        return np.maximum(np.asarray(self._radii(self._clamp(t)), dtype=np.float64), 1e-12)

    def quaternions(self, t: object) -> np.ndarray:
        """(n,) parameters -> (n, 4) unit quaternions of ``R(t)`` (x, y, z, w)."""
        tt = self._clamp(t)
        p = self.keys.params
        i = np.clip(np.searchsorted(p, tt, side="right") - 1, 0, p.size - 2)
        u = ((tt - p[i]) / (p[i + 1] - p[i]))[:, None]
        q0, q1 = self._quats[i], self._quats[i + 1]
        if self.orientation == "nlerp":
            q = (1.0 - u) * q0 + u * q1  # Q_i(t), then normalised (§3.2)
        else:
            cos = np.clip(np.einsum("ij,ij->i", q0, q1), -1.0, 1.0)[:, None]
            omega = np.arccos(cos)
            sin = np.sin(omega)
            small = sin < 1e-9
            safe = np.where(small, 1.0, sin)
            w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * omega) / safe)
            w1 = np.where(small, u, np.sin(u * omega) / safe)
            q = w0 * q0 + w1 * q1
        return q / np.linalg.norm(q, axis=1, keepdims=True)

    def frames(self, t: object) -> np.ndarray:
        """(n,) parameters -> (n, 3, 3) rotations ``R(t)``, columns ``(e_a, e_b, N)``."""
        return quat_to_matrix(self.quaternions(t))

    def evaluate(self, t: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centres (n, 3), frames (n, 3, 3) and radii (n, 2) at parameters ``t`` (n,)."""
        return self.centres(t), self.frames(t), self.radii(t)

    def surface_points(self, theta: object, t: object) -> np.ndarray:
        """``S(θ, t)`` (eq. 1) on the grid of angles ``theta`` (m,) radians and ``t`` (n,).

        Returns
        -------
        (n, m, 3) float64
            Points in metres.
        """
        th = np.atleast_1d(np.asarray(theta, dtype=np.float64))
        c, r, ab = self.evaluate(t)
        e = np.stack(
            [ab[:, :1] * np.cos(th)[None], ab[:, 1:] * np.sin(th)[None]], axis=-1
        )  # (n, m, 2)
        return c[:, None, :] + np.einsum("nij,nmj->nmi", r[:, :, :2], e)

    # --------------------------------------------------------------------- volume
    def volume(self, n: int = 512) -> float:
        """Swept volume ``∫ π a b <N, C'> dt`` plus the half-ellipsoid caps (m³).

        Gauss-Legendre quadrature of order 4 on ``n`` equal sub-intervals. Valid when
        the sweep does not intersect itself.
        """
        if int(n) < 1:
            raise ValidationError(f"n: expected a positive integer, got {n!r}")
        lo, hi = self.t_range
        edges = np.linspace(lo, hi, int(n) + 1)
        x, w = np.polynomial.legendre.leggauss(4)
        half = 0.5 * np.diff(edges)
        tt = (0.5 * (edges[:-1] + edges[1:])[:, None] + half[:, None] * x[None]).ravel()
        ww = (half[:, None] * w[None]).ravel()
        ab = self.radii(tt)
        nrm = self.frames(tt)[:, :, 2]
        body = float(
            np.sum(ww * np.pi * ab[:, 0] * ab[:, 1] * np.einsum("ij,ij->i", nrm, self.tangents(tt)))
        )
        end_ab = self.radii(np.array([lo, hi]))
        caps = float(np.sum((2.0 / 3.0) * np.pi * end_ab[:, 0] * end_ab[:, 1] * self.caps))
        return body + caps

    # ----------------------------------------------------------------------- tube
    def tube(
        self, n_rings: int = 64, n_around: int = 32, *, cap_rings: int = 8
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sample the sweep ring by ring into a closed triangle mesh.

        Parameters
        ----------
        n_rings : int, default 64
            Rings at equally spaced parameters over ``[t_0, t_K-1]`` (>= 2).
        n_around : int, default 32
            Vertices per ring at ``θ = 2π j / n_around`` (>= 3).
        cap_rings : int, default 8
            Extra rings per half-ellipsoid cap (a cap of length 0 is a flat fan).

        Returns
        -------
        vertices : (V, 3) float64, metres
        faces : (F, 3) int64
            Closed, consistently oriented (counter-clockwise seen from outside when
            ``N`` points along increasing ``t``): a watertight genus-0 surface when the
            sweep does not intersect itself.
        """
        nr, na, nc = int(n_rings), int(n_around), int(cap_rings)
        if nr < 2 or na < 3 or nc < 1:
            raise ValidationError(
                f"n_rings >= 2, n_around >= 3 and cap_rings >= 1 required, got {n_rings}, {n_around}, {cap_rings}"
            )
        lo, hi = self.t_range
        theta = 2.0 * np.pi * np.arange(na) / na
        rings = [self.surface_points(theta, np.linspace(lo, hi, nr))]  # (nr, na, 3)
        apexes = []
        for end, t_end, sign in ((0, lo, -1.0), (1, hi, 1.0)):
            c, r, ab = (x[0] for x in self.evaluate(np.array([t_end])))
            length = self.caps[end]
            if length > 0:
                phi = 0.5 * np.pi * np.arange(1, nc) / nc
                local = np.stack(
                    [
                        ab[0] * np.cos(phi)[:, None] * np.cos(theta)[None],
                        ab[1] * np.cos(phi)[:, None] * np.sin(theta)[None],
                        np.broadcast_to(sign * length * np.sin(phi)[:, None], (nc - 1, na)),
                    ],
                    axis=-1,
                )
                cap = c + local @ r.T  # (nc-1, na, 3)
                apex = c + sign * length * r[:, 2]
            else:
                cap = np.zeros((0, na, 3))
                apex = c
            if end == 0:
                rings.insert(0, cap[::-1])
            else:
                rings.append(cap)
            apexes.append(apex)
        grid = np.concatenate(rings, axis=0)  # (R, na, 3) from start apex side to end
        n_grid = grid.shape[0]
        vertices = np.concatenate([grid.reshape(-1, 3), np.stack(apexes)], axis=0)
        i = np.arange(n_grid - 1)[:, None]
        j = np.arange(na)[None]
        jn = (j + 1) % na
        a, b = i * na + j, i * na + jn
        c_, d = (i + 1) * na + j, (i + 1) * na + jn
        # with N along +t and (e_a, e_b, N) right-handed, θ increases counter-clockwise
        # about N: (a, b, d) and (a, d, c) face outwards
        side = np.concatenate(
            [np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c_], -1).reshape(-1, 3)]
        )
        start_apex, end_apex = n_grid * na, n_grid * na + 1
        j1 = np.arange(na)
        start_cap = np.stack([np.full(na, start_apex), (j1 + 1) % na, j1], -1)
        last = (n_grid - 1) * na
        end_cap = np.stack([np.full(na, end_apex), last + j1, last + (j1 + 1) % na], -1)
        faces = np.concatenate([side, start_cap, end_cap]).astype(np.int64)
        return vertices, faces

    # ------------------------------------------------------------- point queries
    def _plane_samples(self, n_planes: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        k = self.keys.n_keys
        n = max(64, 16 * (k - 1)) if n_planes is None else int(n_planes)
        if n < 2:
            raise ValidationError(f"n_planes: expected >= 2, got {n_planes!r}")
        lo, hi = self.t_range
        ts = np.linspace(lo, hi, n)
        c = self.centres(ts)
        nrm = self.frames(ts)[:, :, 2]
        return ts, c, nrm

    def locate(
        self, points: np.ndarray, *, n_planes: int | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bind points to the moving ellipse whose plane contains them (§3.3).

        The planes ``P(t_j)`` are sampled at ``n_planes`` equal steps of ``t``; a point
        between ``P(t_j)`` and ``P(t_j+1)`` (signed distances of opposite sign ``d_j``,
        ``d_j+1``) gets ``t_V = (|d_j+1| t_j + |d_j| t_j+1) / (|d_j| + |d_j+1|)``. When
        several plane pairs straddle the point (a bent sweep), the pair whose centres
        are nearest wins. A point before the first plane or past the last one is bound
        to the end ellipse.

        Parameters
        ----------
        points : (P, 3) float
            Query points, metres. NaN rows give NaN outputs.
        n_planes : int, optional
            Plane samples; default ``max(64, 16 (K - 1))``.

        Returns
        -------
        t : (P,) float64
            Binding parameter in ``[t_0, t_K-1]``.
        local : (P, 3) float64
            ``R(t)^T (p - C(t))``: coordinates along ``e_a``, ``e_b`` and ``N``
            (metres); the third is ``c_V`` ≈ 0 inside, the signed distance past the
            end plane for points bound to an end.
        end : (P,) int8
            -1 bound to the start (before ``P(t_0)``), +1 to the end (past
            ``P(t_K-1)``), 0 between.
        """
        p = _array_points(points)
        ts, c, nrm = self._plane_samples(n_planes)
        cn = np.einsum("ij,ij->i", c, nrm)
        mids = 0.5 * (c[:-1] + c[1:])
        mid2 = np.einsum("ij,ij->i", mids, mids)
        n_pts = p.shape[0]
        t_out = np.empty(n_pts)
        end = np.zeros(n_pts, dtype=np.int8)
        finite = np.isfinite(p).all(axis=1)
        pf = np.where(finite[:, None], p, 0.0)
        for s in range(0, n_pts, _BLOCK):
            blk = pf[s : s + _BLOCK]
            d = blk @ nrm.T - cn[None]  # (b, n) signed distances to the planes
            cross = (d[:, :-1] >= 0) != (d[:, 1:] >= 0)  # (b, n-1) straddling pairs
            dist2 = np.einsum("ij,ij->i", blk, blk)[:, None] - 2.0 * blk @ mids.T + mid2[None]
            j = np.argmin(np.where(cross, dist2, np.inf), axis=1)
            has = cross[np.arange(blk.shape[0]), j]
            r = np.arange(blk.shape[0])
            d0 = np.abs(d[r, j])
            d1 = np.abs(d[r, j + 1])
            den = d0 + d1
            u = np.where(den > 0, d0 / np.where(den > 0, den, 1.0), 0.0)
            t_blk = ts[j] + u * (ts[j + 1] - ts[j])
            before = ~has & (d[:, 0] < 0)
            after = ~has & ~before
            t_blk[before] = ts[0]
            t_blk[after] = ts[-1]
            t_out[s : s + _BLOCK] = t_blk
            end[s : s + _BLOCK] = np.where(before, -1, np.where(after, 1, 0))
        cc, rr, _ = self.evaluate(t_out)
        local = np.einsum("nji,nj->ni", rr, pf - cc)
        t_out[~finite] = np.nan
        local[~finite] = np.nan
        return t_out, local, end

    def signed_distance(self, points: np.ndarray, *, n_planes: int | None = None) -> np.ndarray:
        """Approximate signed distance to the swept volume (negative inside), metres.

        With ``(x, y, z)`` from :meth:`locate` and ``(a, b)`` the half-axes at the
        bound ``t``, the point's elliptic radius is ``ρ = |(x/a, y/b, w/c)|`` where
        ``w`` is the distance past an end plane (0 between the ends) and ``c`` that
        end's cap length; the returned value is the distance along the ray from the
        ellipse centre, ``|(x, y, w)| (1 - 1/ρ)``: exact for circular sections and
        spherical caps, a close approximation for moderate eccentricity, and always
        of the right sign (``ρ < 1`` inside). Past a flat end (cap 0) the larger of
        the in-plane value and ``w`` is taken.

        Parameters
        ----------
        points : (P, 3) float
            NaN rows give NaN.
        n_planes : int, optional
            See :meth:`locate`.

        Returns
        -------
        (P,) float64
        """
        t, local, end = self.locate(points, n_planes=n_planes)
        ab = self.radii(np.where(np.isnan(t), self.t_range[0], t))
        x, y = local[:, 0], local[:, 1]
        w = np.where(end != 0, np.maximum(np.abs(local[:, 2]), 0.0), 0.0)
        cap = np.where(end < 0, self.caps[0], np.where(end > 0, self.caps[1], 0.0))
        capped = cap > 0
        u2 = (x / ab[:, 0]) ** 2 + (y / ab[:, 1]) ** 2
        w_ell = np.where(capped, w, 0.0)
        rho2 = u2 + np.where(capped, (w_ell / np.where(capped, cap, 1.0)) ** 2, 0.0)
        r = np.sqrt(x * x + y * y + w_ell * w_ell)
        rho = np.sqrt(rho2)
        ok = rho > 1e-12
        # r / ρ is the ellipse's radius in the point's direction
        dist = np.where(ok, r - r / np.where(ok, rho, 1.0), -np.min(ab, axis=1))
        flat = (end != 0) & ~capped
        dist = np.where(flat, np.maximum(dist, w), dist)
        dist[np.isnan(t)] = np.nan
        return dist

    def contains(self, points: np.ndarray, *, n_planes: int | None = None) -> np.ndarray:
        """(P,) bool: points strictly inside the swept volume (NaN rows: False)."""
        with np.errstate(invalid="ignore"):
            return self.signed_distance(points, n_planes=n_planes) < 0


def _array_points(points: object) -> np.ndarray:
    try:
        p = np.array(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValidationError("points: expected a float array of shape (P, 3)") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValidationError(f"points: expected shape (P, 3), got {p.shape}")
    return p


def smooth_union(distances: np.ndarray, k: float, axis: int = 0) -> np.ndarray:
    """Smooth minimum of signed distances: ``-k log Σ exp(-d_i / k)``.

    Blends the surfaces where they meet within a few ``k`` (a fillet of radius ~k)
    and equals the plain minimum to within ``k exp(-Δ/k)`` where one part is ``Δ``
    nearer than the others. Never larger than ``min(d)``, never smaller than
    ``min(d) - k log(n)``.

    Parameters
    ----------
    distances : (n, ...) float
        Signed distances of ``n`` parts along ``axis`` (metres); ``+inf`` for a part
        that is absent at a point. NaN propagates.
    k : float
        Blend length (metres), > 0.
    axis : int, default 0

    Returns
    -------
    (...) float64
        The blended distance (``+inf`` where every part is ``+inf``).
    """
    kk = float(k)
    if not np.isfinite(kk) or kk <= 0:
        raise ValidationError(f"k: expected a positive blend length, got {k!r}")
    d = np.asarray(distances, dtype=np.float64)
    m = np.min(d, axis=axis, keepdims=True)
    finite = np.isfinite(m)
    shift = np.where(finite, m, 0.0)
    with np.errstate(invalid="ignore"):
        s = np.sum(np.exp(-(d - shift) / kk), axis=axis, keepdims=True)
    out = np.where(finite, shift - kk * np.log(np.where(finite, s, 1.0)), m)
    return np.squeeze(out, axis=axis)
