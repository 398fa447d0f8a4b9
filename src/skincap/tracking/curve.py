"""A rope as a smooth curve through its markers, parameterised by rest arc length.

Beyond Porter (2012): the thesis invents a missing rope marker from the velocities of
its neighbours and by extrapolating the chain (eqs. 3.3-3.6). When the missing marker
has measured markers on *both* sides, a smooth curve through the measured markers,
evaluated at the missing marker's position along the rope, is both simpler and more
accurate, and it keeps the neighbour spacings near their rest values ``l_j``. This
module holds that curve: a non-uniform Catmull-Rom (cubic Hermite) spline whose
parameter is the rest arc length ``s_j = l_0 + … + l_{j-1}`` of each marker.

Everything is vectorised over leading (frame) axes.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError

__all__ = [
    "rest_arclength",
    "fill_interior_on_curve",
    "settle_single_gaps",
    "carry_last_seen",
    "end_is_free",
    "drag_free_ends",
    "HELD_END_REACH",
    "polyline_length",
    "resample_by_arclength",
]


def rest_arclength(spacing: np.ndarray) -> np.ndarray:
    """Rest arc length of every marker along the rope.

    Parameters
    ----------
    spacing : (M - 1,) float, metres
        Rest distance ``l_j`` between markers ``j`` and ``j + 1``; finite, > 0.

    Returns
    -------
    (M,) float64, metres
        ``s_0 = 0`` and ``s_j = l_0 + … + l_{j-1}``.
    """
    spacing = np.asarray(spacing, dtype=np.float64)
    if spacing.ndim != 1 or not np.all(np.isfinite(spacing)) or np.any(spacing <= 0):
        raise ValidationError("spacing: expected (M - 1,) finite positive distances in metres")
    return np.concatenate([[0.0], np.cumsum(spacing)])


def _prev_known(known: np.ndarray) -> np.ndarray:
    """(..., M) int: index of the last known marker at or before j, -1 if none."""
    m = known.shape[-1]
    idx = np.where(known, np.arange(m), -1)
    return np.maximum.accumulate(idx, axis=-1)


def _next_known(known: np.ndarray) -> np.ndarray:
    """(..., M) int: index of the first known marker at or after j, M if none."""
    m = known.shape[-1]
    idx = np.where(known, np.arange(m), m)
    return np.flip(np.minimum.accumulate(np.flip(idx, axis=-1), axis=-1), axis=-1)


def fill_interior_on_curve(
    positions: np.ndarray, known: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Place unknown markers that lie between known ones on a smooth curve.

    Each unknown marker ``j`` with a known marker ``a < j`` before it and ``b > j``
    after it is put at ``C(s_j)``, where ``C`` is the cubic Hermite segment from
    ``x_a`` to ``x_b`` whose tangents are the slopes of the parabolas through the
    neighbouring known markers (``pa, a, b`` at ``a`` with ``pa`` the known marker
    before ``a``, ``a, b, nb`` at ``b``; the chord slope where there is none).
    With one marker missing between two straight neighbours it lands on the straight
    line at its rest fraction; on a bent rope it follows the bend.

    Parameters
    ----------
    positions : (..., M, 3) float, metres
        Marker positions; entries where ``known`` is False are ignored (may be NaN).
    known : (..., M) bool
        True where the position is measured (trusted).
    s : (M,) float, metres
        Rest arc length of each marker (:func:`rest_arclength`), increasing.

    Returns
    -------
    filled : (..., M, 3) float64, metres
        ``positions`` with the interior unknown markers replaced; others untouched
        (end runs of unknown markers keep their input values, NaN stays NaN).
    interior : (..., M) bool
        True where a marker was placed on the curve.
    """
    positions = np.asarray(positions, dtype=np.float64)
    known = np.asarray(known, dtype=bool)
    s = np.asarray(s, dtype=np.float64)
    m = positions.shape[-2]
    if positions.shape[-1] != 3 or known.shape != positions.shape[:-1] or s.shape != (m,):
        raise ValidationError(
            f"positions/known/s: expected (..., M, 3), (..., M), (M,), got "
            f"{positions.shape}, {known.shape}, {s.shape}"
        )
    filled = positions.copy()
    prev = _prev_known(known)
    nxt = _next_known(known)
    interior = (~known) & (prev >= 0) & (nxt < m)
    if not interior.any():
        return filled, interior
    lead = np.nonzero(interior)  # tuple of index arrays over (..., M)
    batch, j = lead[:-1], lead[-1]
    a = prev[lead]  # (K,) known before
    b = nxt[lead]  # (K,) known after
    # the known markers beyond a and b (or a, b themselves at the ends)
    a_m1 = np.maximum(a - 1, 0)
    pa = np.where(a > 0, prev[(*batch, a_m1)], a)
    pa = np.where(pa < 0, a, pa)
    b_p1 = np.minimum(b + 1, m - 1)
    nb = np.where(b < m - 1, nxt[(*batch, b_p1)], b)
    nb = np.where(nb >= m, b, nb)
    xa = positions[(*batch, a)]  # (K, 3)
    xb = positions[(*batch, b)]
    xpa = positions[(*batch, pa)]
    xnb = positions[(*batch, nb)]
    sa, sb, spa, snb = s[a], s[b], s[pa], s[nb]
    h = sb - sa  # (K,) segment length in s
    ta = _three_point_slope(xpa, xa, xb, spa, sa, sb)  # tangent dx/ds at a
    tb = _three_point_slope(xa, xb, xnb, sa, sb, snb)  # ... and at b
    u = ((s[j] - sa) / h)[:, None]  # (K, 1) in (0, 1)
    u2, u3 = u * u, u * u * u
    h00 = 2 * u3 - 3 * u2 + 1
    h10 = u3 - 2 * u2 + u
    h01 = -2 * u3 + 3 * u2
    h11 = u3 - u2
    filled[lead] = h00 * xa + h10 * h[:, None] * ta + h01 * xb + h11 * h[:, None] * tb
    return filled, interior


def settle_single_gaps(
    positions: np.ndarray, known: np.ndarray, spacing: np.ndarray, weight: float
) -> np.ndarray:
    """Pull each lone unknown marker toward its rest spacings from both neighbours.

    A smooth curve through the measured markers cuts a sharp bend (a whip's wave): a
    lone missing marker ``j`` (``j - 1`` and ``j + 1`` known) lands too near the chord
    between its neighbours. The points at the rest spacings ``l_{j-1}`` from ``x_{j-1}``
    and ``l_j`` from ``x_{j+1}`` form a circle around that chord; ``j`` keeps the
    direction of its offset from the chord and moves its distance from the chord
    ``weight`` of the way to the circle's radius (and onto the circle's plane)::

        x_j = c + ((1 - w) |o| + w r) o / |o|

    with ``c`` the circle's centre on the chord, ``r`` its radius and ``o`` the
    marker's offset from the chord. Markers whose neighbours are farther apart than
    ``l_{j-1} + l_j`` (no circle) or that lie on the chord (no direction) are left.

    Parameters
    ----------
    positions : (..., M, 3) float, metres
        Marker positions, the unknown ones already placed (e.g. by
        :func:`fill_interior_on_curve`); NaN propagates.
    known : (..., M) bool
        True where the position is measured.
    spacing : (M - 1,) float, metres
        Rest spacings ``l_j``.
    weight : float
        ``w`` in [0, 1]: 0 leaves the markers, 1 puts them on the circle.

    Returns
    -------
    (..., M, 3) float64, metres
        ``positions`` with the lone unknown markers moved; others untouched.
    """
    positions = np.asarray(positions, dtype=np.float64)
    known = np.asarray(known, dtype=bool)
    spacing = np.asarray(spacing, dtype=np.float64)
    m = positions.shape[-2]
    if positions.shape[-1] != 3 or known.shape != positions.shape[:-1] or spacing.shape != (m - 1,):
        raise ValidationError(
            f"positions/known/spacing: expected (..., M, 3), (..., M), (M - 1,), got "
            f"{positions.shape}, {known.shape}, {spacing.shape}"
        )
    out = positions.copy()
    if m < 3 or weight == 0.0:
        return out
    lone = ~known[..., 1:-1] & known[..., :-2] & known[..., 2:]  # (..., M - 2)
    if not lone.any():
        return out
    lead = np.nonzero(lone)
    batch, j = lead[:-1], lead[-1] + 1
    xa = positions[(*batch, j - 1)]
    xb = positions[(*batch, j + 1)]
    xj = positions[(*batch, j)]
    l1, l2 = spacing[j - 1], spacing[j]
    d = xb - xa
    c = np.sqrt(np.einsum("ij,ij->i", d, d))
    ok = c > 0
    c_safe = np.where(ok, c, 1.0)
    u = d / c_safe[:, None]
    along = (c * c + l1 * l1 - l2 * l2) / (2.0 * c_safe)
    r2 = l1 * l1 - along * along
    centre = xa + along[:, None] * u
    off = xj - centre
    off = off - np.einsum("ij,ij->i", off, u)[:, None] * u
    on = np.sqrt(np.einsum("ij,ij->i", off, off))
    ok &= (r2 > 0) & (on > 1e-12)
    radius = np.sqrt(np.where(ok, r2, 0.0))
    on_safe = np.where(ok, on, 1.0)
    scale = ((1.0 - weight) * on + weight * radius) / on_safe
    moved = centre + scale[:, None] * off
    out[(*batch, j)] = np.where(ok[:, None], moved, xj)
    return out


#: Offsets along the rope of the markers a hidden marker is carried with, nearest first.
CARRY_OFFSETS = np.array([-1, 1, -2, 2, -3, 3, -4, 4], dtype=np.int64)
#: How many of them (the nearest measured in both frames) the rigid fit uses.
CARRY_NEIGHBOURS = 4


def carry_last_seen(
    pred: np.ndarray,
    cur: np.ndarray,
    known: np.ndarray,
    rows: np.ndarray,
    then: np.ndarray,
    then_measured: np.ndarray,
    tolerance: float,
) -> np.ndarray:
    """Blend the predictions of hidden markers with where their neighbours carry them.

    Beyond Porter (2012), whose F forgets the marker's own last position after one
    frame: a hidden marker ``j`` was last seen in some frame ``t'``, together with
    its neighbours. The rigid motion (least squares, Kabsch) that takes the
    :data:`CARRY_NEIGHBOURS` nearest markers along the rope (at most four markers
    away) measured both in ``t'`` and now from where they were to where they are
    carries ``x_j(t')`` to ``r_j``; where the rope keeps its local shape (a segment
    lying still, a bend travelling with the hand) this is near exact, where the
    shape changes the fit's residual grows. The prediction becomes::

        x_j = w r_j + (1 - w) pred_j,   w = 1 / (1 + (e / tolerance)^2),
        e = rms sqrt(1 + |x_j(t') - c|^2 / g^2)

    with ``rms`` the fit's root-mean-square residual, ``c`` the neighbours' centroid
    in ``t'`` and ``g`` their radius of gyration about it (a marker carried beyond
    its neighbours, at an end, is moved by the fit's rotation error times its lever):
    the spatial prediction (the curve, F) takes over as the neighbourhood deforms. Fewer than three such
    neighbours leave ``pred_j`` as it is.

    Parameters
    ----------
    pred : (M, 3) float, metres
        The spatial predictions of every marker (curve inside, F at the ends).
    cur : (M, 3) float, metres
        This frame's measured markers (where ``known``).
    known : (M,) bool
        Measured this frame.
    rows : (U,) int
        The hidden markers to carry.
    then : (U, M, 3) float, metres
        The rope in the frame each of them was last seen (``then[u, rows[u]]`` is
        that marker's last measured position).
    then_measured : (U, M) bool
        Which markers were measured in that frame.
    tolerance : float, metres
        Fit residual at which the carried and the spatial prediction weigh the same.

    Returns
    -------
    (M, 3) float64, metres
        ``pred`` with the rows blended; the other rows untouched.
    """
    out = np.array(pred, dtype=np.float64)
    rows = np.asarray(rows, dtype=np.int64)
    m = known.size
    if rows.size == 0 or m < 4:
        return out
    nb = rows[:, None] + CARRY_OFFSETS[None, :]  # (U, 8)
    inside = (nb >= 0) & (nb < m)
    nbc = np.clip(nb, 0, m - 1)
    u_idx = np.arange(rows.size)[:, None]
    usable = inside & known[nbc] & then_measured[u_idx, nbc]
    usable &= np.cumsum(usable, axis=1) <= CARRY_NEIGHBOURS  # the nearest four
    count = usable.sum(axis=1)  # (U,)
    w = usable.astype(np.float64)
    p_then = then[u_idx, nbc]  # (U, 8, 3)
    q_now = cur[nbc]
    denom = np.maximum(count, 1)[:, None]
    pc = np.einsum("uk,ukc->uc", w, p_then) / denom
    qc = np.einsum("uk,ukc->uc", w, q_now) / denom
    h = np.einsum("uk,uka,ukb->uab", w, p_then - pc[:, None], q_now - qc[:, None])  # (U, 3, 3)
    u_svd, _, vt = np.linalg.svd(h)
    det = np.sign(np.linalg.det(np.einsum("uab,ubc->uac", u_svd, vt)))
    vt = vt * np.where(np.arange(3)[None, :, None] == 2, det[:, None, None], 1.0)
    rot = np.einsum("uba,ucb->uac", vt, u_svd)  # R = V D U^T, q ≈ R (p - pc) + qc
    moved = np.einsum("uab,ukb->uka", rot, p_then - pc[:, None]) + qc[:, None]
    rms = np.sqrt(np.einsum("uk,uk->u", w, np.sum((moved - q_now) ** 2, axis=2)) / denom[:, 0])
    last = then[np.arange(rows.size), rows] - pc  # (U, 3) the marker from the centroid
    carried = np.einsum("uab,ub->ua", rot, last) + qc
    # an end is carried beyond its neighbours: a rotation error grows with the lever
    spread = np.einsum("uk,uk->u", w, np.sum((p_then - pc[:, None]) ** 2, axis=2)) / denom[:, 0]
    lever = np.einsum("uc,uc->u", last, last) / np.maximum(spread, 1e-300)
    error = rms * np.sqrt(1.0 + lever)
    weight = np.where(count >= 3, 1.0 / (1.0 + (error / tolerance) ** 2), 0.0)[:, None]
    out[rows] = weight * carried + (1.0 - weight) * out[rows]
    return out


def drag_free_ends(
    pred: np.ndarray,
    known: np.ndarray,
    prev: np.ndarray,
    velocity: np.ndarray,
    spacing: np.ndarray,
    runs: np.ndarray,
) -> np.ndarray:
    """Hidden markers at a free rope end, moved as a rope moves its loose end.

    Beyond Porter (2012), whose F (eq. 3.6) turns a hidden end towards the straight
    continuation of its last measured links: a loose end is not pushed along the
    rope's direction, it keeps going as it went (a tip lying on the floor stays, a
    tip in the air swings on) and is pulled only when its inner neighbour draws the
    link beyond its length. Outward from the measured part of the rope, each marker
    ``j`` of ``runs`` is put at its own prediction ``x_j^{t-1} + v_j`` (eqs. 3.1-3.2;
    the velocity of an invented marker is that of its invented positions) and, if
    that lies farther than the rest spacing ``l`` from its inner neighbour ``i``
    (measured, or placed just before), pulled onto the sphere of radius ``l`` around
    it (a position-based dynamics step of the end's links, no bending or gravity)::

        x_j = x_i + l (y - x_i) / |y - x_i|   where |y - x_i| > l,  y = x_j^{t-1} + v_j

    Parameters
    ----------
    pred : (M, 3) float, metres
        This frame's markers: the measured ones (``known``) and the inner predictions.
    known : (M,) bool
        Measured this frame; at least one.
    prev : (M, 3) float, metres
        The markers in frame t - 1.
    velocity : (M, 3) float, metres per frame
        Their last displacement.
    spacing : (M - 1,) float, metres
        Rest spacings ``l_j``.
    runs : (M,) bool
        The hidden markers of the free end runs (each run from an end of the rope up
        to its first measured marker); others are left.

    Returns
    -------
    (M, 3) float64, metres
        ``pred`` with the markers of ``runs`` placed.
    """
    out = np.array(pred, dtype=np.float64)
    known = np.asarray(known, dtype=bool)
    runs = np.asarray(runs, dtype=bool) & ~known
    m = known.size
    measured = np.flatnonzero(known)
    if measured.size == 0 or not runs.any():
        return out
    order = [(j, j + 1) for j in range(measured[0] - 1, -1, -1)]
    order += [(j, j - 1) for j in range(measured[-1] + 1, m)]
    for j, inner in order:
        if not runs[j]:
            continue
        d = prev[j] + velocity[j] - out[inner]
        dist = float(np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))
        rest = float(spacing[min(j, inner)])
        out[j] = out[inner] + (rest / dist if dist > rest else 1.0) * d
    return out


#: A rope end with a point that is not the rope's this near it (metres) when it was last
#: seen is held: a hand's markers lie within 3-20 cm of the end it holds on every real
#: and synthetic take in tests/data, a whip's free end is 15-140 cm from the body.
HELD_END_REACH = 0.2


def end_is_free(
    end: np.ndarray, points: np.ndarray, is_rope: np.ndarray, reach: float = HELD_END_REACH
) -> bool:
    """Whether a rope end swings free rather than being held, from one frame's points.

    A held end moves with the hand that holds it, and the hand's markers are beside
    it; a free end (a whip's tip, a dropped handle) is away from every body point.
    The end is free when no point of the frame that is not the rope's lies within
    ``reach`` of it. A free end passing a body point reads as held (the cautious side:
    a held end keeps F, which follows the hand).

    Parameters
    ----------
    end : (3,) float, metres
        The end marker's measured position in that frame.
    points : (P, 3) float, metres
        Every point of the frame.
    is_rope : (P,) bool
        The points the rope's traces took in that frame.
    reach : float, metres

    Returns
    -------
    bool
    """
    other = np.asarray(points, dtype=np.float64)[~np.asarray(is_rope, dtype=bool)]
    d2 = np.sum((other - np.asarray(end, dtype=np.float64)) ** 2, axis=1)
    return not bool((d2 <= reach * reach).any())


def _three_point_slope(
    x0: np.ndarray, x1: np.ndarray, x2: np.ndarray, s0: np.ndarray, s1: np.ndarray, s2: np.ndarray
) -> np.ndarray:
    """(K, 3) slope at ``s1`` of the parabola through three samples (non-uniform).

    Where ``s0 == s1`` (no sample before) it is the chord slope to ``x2``, and where
    ``s1 == s2`` the chord slope from ``x0``.
    """
    h0 = (s1 - s0)[:, None]
    h1 = (s2 - s1)[:, None]
    safe0 = np.where(h0 > 0, h0, 1.0)
    safe1 = np.where(h1 > 0, h1, 1.0)
    d0 = (x1 - x0) / safe0
    d1 = (x2 - x1) / safe1
    both = (h0 > 0) & (h1 > 0)
    mixed = (d0 * h1 + d1 * h0) / np.where(both, h0 + h1, 1.0)
    return np.where(both, mixed, np.where(h0 > 0, d0, d1))


def polyline_length(positions: np.ndarray) -> np.ndarray:
    """Length of the polyline through the markers of each frame.

    Parameters
    ----------
    positions : (..., M, 3) float, metres; NaN propagates.

    Returns
    -------
    (...,) float64, metres
    """
    positions = np.asarray(positions, dtype=np.float64)
    return np.linalg.norm(np.diff(positions, axis=-2), axis=-1).sum(axis=-1)


def resample_by_arclength(
    positions: np.ndarray, n_samples: int = 50, *, subdivisions: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """Resample each frame's rope at uniformly spaced arc length.

    The curve through the M markers is the uniform Catmull-Rom spline (it passes
    through every marker; the end segments use mirrored phantom points), sampled
    ``subdivisions`` times per segment; its arc length is measured on that dense
    polyline and ``n_samples`` points are placed at equal arc length from the first
    marker to the last.

    Parameters
    ----------
    positions : (T, M, 3) float, metres
        Finite marker positions in order along the rope, M >= 2.
    n_samples : int
        Samples per frame, >= 2.
    subdivisions : int
        Dense samples per segment used to measure the arc length, >= 1.

    Returns
    -------
    s : (T, n_samples) float64, metres
        Arc length of each sample from the first marker (``s[:, -1]`` is the curve's
        length in that frame).
    points : (T, n_samples, 3) float64, metres
        The samples; ``points[:, 0]`` and ``points[:, -1]`` are the end markers.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3 or positions.shape[1] < 2:
        raise ValidationError(f"positions: expected (T, M, 3) with M >= 2, got {positions.shape}")
    if not np.all(np.isfinite(positions)):
        raise ValidationError("positions: must be finite to resample the rope curve")
    n_samples = int(n_samples)
    subdivisions = int(subdivisions)
    if n_samples < 2 or subdivisions < 1:
        raise ValidationError("n_samples must be >= 2 and subdivisions >= 1")
    t_frames, m, _ = positions.shape
    # phantom end points mirror the end segments: p_-1 = 2 p_0 - p_1
    ext = np.concatenate(
        [
            2 * positions[:, :1] - positions[:, 1:2],
            positions,
            2 * positions[:, -1:] - positions[:, -2:-1],
        ],
        axis=1,
    )  # (T, M + 2, 3)
    p0, p1, p2, p3 = ext[:, :-3], ext[:, 1:-2], ext[:, 2:-1], ext[:, 3:]  # (T, M-1, 3)
    u = np.arange(subdivisions) / subdivisions  # (S,)
    u2, u3 = u * u, u * u * u
    # uniform Catmull-Rom basis, (S, 4)
    basis = 0.5 * np.stack(
        [-u3 + 2 * u2 - u, 3 * u3 - 5 * u2 + 2, -3 * u3 + 4 * u2 + u, u3 - u2], axis=1
    )
    ctrl = np.stack([p0, p1, p2, p3], axis=2)  # (T, M-1, 4, 3)
    dense = np.einsum("sk,tmkc->tmsc", basis, ctrl).reshape(t_frames, -1, 3)
    dense = np.concatenate([dense, positions[:, -1:]], axis=1)  # (T, D, 3)
    seg = np.linalg.norm(np.diff(dense, axis=1), axis=2)  # (T, D-1)
    cum = np.concatenate([np.zeros((t_frames, 1)), np.cumsum(seg, axis=1)], axis=1)  # (T, D)
    total = cum[:, -1]
    target = total[:, None] * np.linspace(0.0, 1.0, n_samples)[None, :]  # (T, n)
    # index of the dense segment holding each target, per frame
    d = dense.shape[1]
    flat_cum = cum + (np.arange(t_frames) * (total.max() + 1.0))[:, None]
    flat_target = target + (np.arange(t_frames) * (total.max() + 1.0))[:, None]
    k = np.searchsorted(flat_cum.ravel(), flat_target.ravel(), side="right") - 1
    k = k.reshape(t_frames, n_samples) - (np.arange(t_frames) * d)[:, None]
    k = np.clip(k, 0, d - 2)
    rows = np.arange(t_frames)[:, None]
    c0 = cum[rows, k]
    length = seg[rows, k]
    w = np.divide(target - c0, length, out=np.zeros_like(target), where=length > 0)
    w = np.clip(w, 0.0, 1.0)[..., None]
    points = (1 - w) * dense[rows, k] + w * dense[rows, k + 1]
    return target, points
