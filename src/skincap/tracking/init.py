"""Initialisation of the rope traces (Porter 2012, §3.4).

The user identifies the rope in a short window at the start of the take where it
hangs still: by a box in space, by the indices of its points among the first frame's
points, or (beyond the thesis) automatically, as the longest chain of still points
with near-uniform spacing that behaves as a 1-D curve. The selected points start one
trace each; the traces are followed through the window (each takes the point nearest
its average position within γ, else a temporary marker at that average), traces with
too many temporary markers are discarded, the rest are ordered along the rope, and
the mean distance between neighbouring traces gives the spacings ``l_j``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from skincap.errors import ValidationError
from skincap.tracking.body_points import body_like
from skincap.tracking.chain_order import off_chain_points, shortest_open_path, typical_spacing
from skincap.tracking.curve import fill_interior_on_curve, rest_arclength
from skincap.tracking.rest_spacing import _rest_spacing
from skincap.types import PointCloud

__all__ = [
    "RopeInit",
    "find_rope_chain",
    "gated_assignment",
    "init_rope",
]

#: A rope point's third-nearest neighbour lies beyond this many spacings (1-D test).
_ISOLATION = 1.35
#: A rope point's nearest neighbour lies at least this many spacings away.
_ISOLATION_NEAREST = 0.5
#: A sharp turn (beyond 45°, up to ``max_turn_degrees``) needs a point this isolated.
_ISOLATION_SHARP_TURN = 0.8
_COS_SOFT_TURN = float(np.cos(np.radians(45.0)))
#: How far (in spacings per step) the next chain point may lie from the extrapolation.
_GUESS_TOLERANCE = 1.5
#: Default γ as a fraction of the median neighbour spacing of the selected points.
GAMMA_FRACTION = 0.25


@dataclass(eq=False)
class RopeInit:
    """The rope traces after initialisation, ordered along the rope.

    Attributes
    ----------
    indices : (M,) int64
        Index of each rope marker's point among frame 0's points (file order of that
        frame, ``cloud.frame(0)[indices]``), in order along the rope: ``indices[0]`` is
        the end that hangs highest (the thesis orders by height; along a chain it is
        the same for a rope hanging from one end). -1 for a trace added where a
        marker was unseen in frame 0 (a link of twice the spacing, beyond the thesis).
    positions : (M, 3) float64, metres
        Average position of each trace over the initialisation window.
    spacing : (M - 1,) float64, metres
        ``l_j``: mean distance between traces ``j`` and ``j + 1`` over the window.
    gamma : float, metres
        γ: the largest distance between a trace's predicted position and a point it
        may take.
    max_temp_markers : int
        maxTempMarkers: consecutive temporary markers after which a trace is lost.
    window : (int, int)
        First and one-past-last frame of the initialisation window.
    meta : dict
        How the rope was selected (``method``), discarded traces, ….
    """

    indices: np.ndarray
    positions: np.ndarray
    spacing: np.ndarray
    gamma: float
    max_temp_markers: int
    window: tuple[int, int] = (0, 1)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.indices = np.asarray(self.indices, dtype=np.int64).reshape(-1)
        m = self.indices.size
        if np.any(self.indices < -1):
            raise ValidationError("RopeInit: indices must be >= -1 (-1: unseen in frame 0)")
        if m < 3:
            raise ValidationError(f"rope: need at least 3 rope markers, got {m}")
        self.positions = np.asarray(self.positions, dtype=np.float64)
        self.spacing = np.asarray(self.spacing, dtype=np.float64)
        if self.positions.shape != (m, 3) or self.spacing.shape != (m - 1,):
            raise ValidationError(
                f"RopeInit: expected positions ({m}, 3) and spacing ({m - 1},), got "
                f"{self.positions.shape} and {self.spacing.shape}"
            )
        if not (np.all(np.isfinite(self.spacing)) and np.all(self.spacing > 0)):
            raise ValidationError("RopeInit: spacing must be finite and positive")
        self.gamma = float(self.gamma)
        if not (np.isfinite(self.gamma) and self.gamma > 0):
            raise ValidationError(f"gamma: expected a positive distance, got {self.gamma}")
        self.max_temp_markers = int(self.max_temp_markers)
        if self.max_temp_markers < 1:
            raise ValidationError("max_temp_markers: expected >= 1")
        self.window = (int(self.window[0]), int(self.window[1]))
        self.meta = dict(self.meta)

    @property
    def n_markers(self) -> int:
        return int(self.indices.size)

    @property
    def labels(self) -> list[str]:
        """``rope_00``, ``rope_01``… in order along the rope."""
        width = max(2, len(str(self.n_markers - 1)))
        return [f"rope_{j:0{width}d}" for j in range(self.n_markers)]


# --------------------------------------------------------------------------- helpers
def gated_assignment(
    dist: np.ndarray, cand: np.ndarray, gate: float
) -> tuple[np.ndarray, np.ndarray]:
    """Match rows to candidate points one-to-one, minimising the summed distance.

    Parameters
    ----------
    dist : (R, K) float, metres
        Distance from row ``r`` to its ``k``-th candidate; ``inf`` for none.
    cand : (R, K) int
        Candidate point index (any integer id); ignored where ``dist`` is inf.
    gate : float, metres
        Pairs at or beyond this distance are never made.

    Returns
    -------
    rows : (P,) int64
        Matched rows.
    points : (P,) int64
        The point each matched row takes; all distinct.
    """
    ok = dist < gate
    if not ok.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    first = np.where(ok[:, 0], cand[:, 0], -1)
    taken = first[first >= 0]
    # fast path: every row's nearest candidate is free of conflicts
    if taken.size == np.unique(taken).size and ok[:, 0].sum() == ok.any(axis=1).sum():
        rows = np.nonzero(first >= 0)[0]
        return rows.astype(np.int64), first[rows].astype(np.int64)
    r_idx, k_idx = np.nonzero(ok)
    pts, col = np.unique(cand[r_idx, k_idx], return_inverse=True)
    rows_u, row = np.unique(r_idx, return_inverse=True)
    big = 1e6 * max(gate, 1.0)
    cost = np.full((rows_u.size, pts.size), big)
    cost[row, col] = dist[r_idx, k_idx]
    ri, ci = linear_sum_assignment(cost)
    keep = cost[ri, ci] < gate
    return rows_u[ri[keep]].astype(np.int64), pts[ci[keep]].astype(np.int64)


def _window_frames(cloud: PointCloud, window_seconds: float) -> int:
    if not (np.isfinite(window_seconds) and window_seconds > 0):
        raise ValidationError(f"window_seconds: expected > 0, got {window_seconds}")
    return int(max(2, min(cloud.n_frames, round(window_seconds * cloud.rate))))


def _follow_window(
    cloud: PointCloud, start: np.ndarray, n_window: int, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """Thesis window tracking: each trace takes the point nearest its predicted position.

    The thesis predicts every trace at its average position so far, which holds for a
    rope that hangs still. Beyond it, a trace measured in the last two frames is
    predicted at constant velocity, one measured in the last frame where it was: a
    rope still settling (swinging down into its hang) is followed instead of losing
    its traces, and a still rope is predicted where it is, as before.

    Returns the (W, S, 3) trace positions and the (W, S) temporary-marker flags.
    """
    s = start.shape[0]
    pos = np.empty((n_window, s, 3))
    temp = np.zeros((n_window, s), dtype=bool)
    pos[0] = start
    total = start.copy()
    for t in range(1, n_window):
        predicted = total / t
        seen1 = ~temp[t - 1]
        predicted[seen1] = pos[t - 1, seen1]
        if t >= 2:
            seen2 = seen1 & ~temp[t - 2]
            predicted[seen2] += pos[t - 1, seen2] - pos[t - 2, seen2]
        frame = cloud.frame(t)
        pos[t] = predicted
        temp[t] = True
        if frame.shape[0]:
            k = min(3, frame.shape[0])
            d, i = cKDTree(frame).query(predicted, k=k, distance_upper_bound=gamma)
            rows, pts = gated_assignment(d.reshape(s, k), i.reshape(s, k), gamma)
            pos[t, rows] = frame[pts]
            temp[t, rows] = False
        total += pos[t]
    return pos, temp


def _chain_order(points: np.ndarray) -> np.ndarray:
    """Order points along the chain they form: the shortest open path through them
    (:func:`~skincap.tracking.chain_order.shortest_open_path`; a U whose arms pass
    closer than the spacing stays one U). The first end is the higher one (largest y).
    """
    order = shortest_open_path(points, spacing=typical_spacing(points))
    if points[order[-1], 1] > points[order[0], 1]:
        order = order[::-1]
    return order.astype(np.int64)


# ------------------------------------------------------------------------- auto find
def find_rope_chain(
    cloud: PointCloud,
    *,
    window_seconds: float = 0.5,
    still_tolerance: float = 0.01,
    min_spacing: float = 0.08,
    max_spacing: float = 0.30,
    uniformity: float = 0.15,
    min_markers: int = 5,
) -> np.ndarray:
    """Find the rope automatically: the longest still chain of near-uniform spacing.

    1. Still points: a frame-0 point is still if every frame of the window has a
       point within ``still_tolerance`` of it.
    2. Seeds: every pair of still points that are mutual nearest-or-second-nearest
       neighbours at a distance within ``[min_spacing, max_spacing]``, both ways.
    3. Each seed grows a chain as a 1-D curve (all seeds at once): the next point is
       still point nearest the second-order extrapolation
       ``x_j + 2 (x_j - x_{j-1}) - (x_{j-1} - x_{j-2})`` among those whose link differs
       from the seed's by at most ``uniformity`` (relative) and turns by at most 100°
       from the last link (a rope lying down on the floor bends sharply; beyond 45° only
       onto a point with no other within 0.8 spacings); when there is none, one marker may be skipped (a point near two
       steps ahead, as when a tape marker is unseen). A seed's chain is its growth
       backwards joined with its growth forwards.
    4. The chain with the largest total length is the rope (a rope of tape markers
       every 10-15 cm is far longer than any straight row of body markers); other
       chains of the same spacing whose ends lie within 5 spacings of its ends are
       joined to it (where the rope passes close to the body it fails the 1-D test).

    Parameters
    ----------
    cloud : PointCloud
        The take; frame 0 must be in the still window.
    window_seconds : float
        Length of the still window, seconds.
    still_tolerance : float, metres
    min_spacing, max_spacing : float, metres
        Range of plausible rope-marker spacings.
    uniformity : float
        Allowed relative deviation of a link from the seed's.
    min_markers : int

    Returns
    -------
    (M,) int64
        Indices among frame 0's points, in chain order (a skipped marker leaves a
        link of twice the spacing; :func:`init_rope` inserts a trace there).

    Raises
    ------
    ValidationError
        No chain of ``min_markers`` points is found.
    """
    p0 = cloud.frame(0)
    n0 = p0.shape[0]
    if n0 < min_markers:
        raise ValidationError(
            f"rope auto: frame 0 has {n0} points, fewer than min_markers={min_markers}"
        )
    n_window = _window_frames(cloud, window_seconds)
    still = np.ones(n0, dtype=bool)
    for t in range(1, n_window):
        frame = cloud.frame(t)
        if frame.shape[0] == 0:
            continue
        d, _ = cKDTree(frame).query(p0, k=1)
        still &= d <= still_tolerance
    cand = np.nonzero(still)[0]
    if cand.size < min_markers:
        raise ValidationError(
            f"rope auto: only {cand.size} points of frame 0 stay still over the first "
            f"{n_window} frames; select the rope with a box or point indices"
        )
    pc = p0[cand]
    n = cand.size
    k = min(3, n)
    tree = cKDTree(pc)
    dist, nn = tree.query(pc, k=k)  # nn[:, 0] is the point itself
    # 1-D: a rope point has only its two chain neighbours near it
    third = tree.query(pc, k=min(4, n))[0].reshape(n, -1)[:, -1] if n >= 4 else np.full(n, np.inf)
    a_idx = np.arange(n)
    seeds_a, seeds_b = [], []
    for col in range(1, k):  # the first and second nearest neighbour
        b_idx = nn[:, col]
        mutual = (nn[b_idx, 1:k] == a_idx[:, None]).any(axis=1)
        ok = mutual & (dist[:, col] >= min_spacing) & (dist[:, col] <= max_spacing)
        ok &= (third > _ISOLATION * dist[:, col]) & (third[b_idx] > _ISOLATION * dist[:, col])
        seeds_a.append(a_idx[ok])
        seeds_b.append(b_idx[ok])
    sa = np.concatenate(seeds_a)
    sb = np.concatenate(seeds_b)
    if sa.size == 0:
        raise ValidationError(
            "rope auto: no still points at rope-marker spacing found; "
            "select the rope with a box or point indices"
        )
    # directed seeds a -> b; each grows forward from b
    chains = _grow_chains(
        pc, tree, sa, sb, uniformity, dist[:, 1] if k > 1 else np.full(n, np.inf)
    )  # (S, L) int, -1 padded
    found = _join_seed_chains(pc, chains, sa, sb)
    best = found[0][1] if found else np.zeros(0, np.int64)
    best = _bridge_chains(pc, best, [c for _, c in found[1:]], min_markers, uniformity)
    if best.size < min_markers:
        raise ValidationError(
            f"rope auto: the longest chain has {best.size} points, fewer than "
            f"min_markers={min_markers}; select the rope with a box or point indices"
        )
    return cand[best.astype(np.int64)]


def _join_seed_chains(
    pc: np.ndarray, chains: np.ndarray, sa: np.ndarray, sb: np.ndarray
) -> list[tuple[float, np.ndarray]]:
    """Each directed seed ``a -> b`` joined with its reverse, longest first.

    ``chains`` (S, L) int, -1 padded, is each seed's forward growth over the still
    points ``pc`` (N, 3); the chain of a seed is reverse(grow(b -> a)) + grow(a -> b).
    Returns (total length in metres, (C,) indices into ``pc``) for every chain that
    visits no point twice, sorted by length, longest first.
    """
    lengths = (chains >= 0).sum(axis=1)
    key = {(int(x), int(y)): r for r, (x, y) in enumerate(zip(sa, sb, strict=True))}
    found: list[tuple[float, np.ndarray]] = []
    for r in range(sa.size):
        back = key.get((int(sb[r]), int(sa[r])))
        fwd = chains[r, : lengths[r]]
        if back is not None:
            bwd = chains[back, : lengths[back]][::-1]  # ends ... a, b
            chain = np.concatenate([bwd, fwd[2:]])
        else:
            chain = fwd
        if np.unique(chain).size != chain.size:
            continue
        found.append((float(np.linalg.norm(np.diff(pc[chain], axis=0), axis=1).sum()), chain))
    found.sort(key=lambda item: -item[0])
    return found


def _bridge_chains(
    pts: np.ndarray,
    best: np.ndarray,
    others: list[np.ndarray],
    min_markers: int,
    uniformity: float,
    max_bridge: float = 5.0,
) -> np.ndarray:
    """Join the best chain with other chains of the same spacing across short breaks.

    Where the rope passes close to the body (its middle between the legs) its
    markers fail the 1-D test and the chain breaks; a disjoint chain of at least
    ``min_markers`` points with the same spacing whose end lies within
    ``max_bridge`` spacings of an end of the best chain continues it (the missing
    markers between become traces in :func:`init_rope`).
    """
    if best.size < 2:
        return best
    spacing = float(np.median(np.linalg.norm(np.diff(pts[best], axis=0), axis=1)))
    for _ in range(4):
        joined = False
        for other in others:
            if other.size < min_markers or np.intersect1d(other, best).size:
                continue
            sp = float(np.median(np.linalg.norm(np.diff(pts[other], axis=0), axis=1)))
            if abs(sp - spacing) > uniformity * spacing:
                continue
            ends = [
                (best[-1], other[0], False, False),
                (best[-1], other[-1], False, True),
                (best[0], other[0], True, False),
                (best[0], other[-1], True, True),
            ]
            gaps = [float(np.linalg.norm(pts[a] - pts[b])) for a, b, _, _ in ends]
            g = int(np.argmin(gaps))
            if gaps[g] > max_bridge * spacing:
                continue
            _, _, at_head, flip = ends[g]
            piece = other[::-1] if flip else other
            best = np.concatenate([piece[::-1], best]) if at_head else np.concatenate([best, piece])
            joined = True
            break
        if not joined:
            break
    return best


def _grow_chains(
    pts: np.ndarray,
    tree: cKDTree,
    sa: np.ndarray,
    sb: np.ndarray,
    uniformity: float,
    nearest: np.ndarray,
    max_turn_degrees: float = 100.0,
) -> np.ndarray:
    """Grow every directed seed ``sa -> sb`` forward as a smooth chain (all at once).

    Returns (S, L) int64 point indices in order (``sa``, ``sb``, …), -1 padded.
    """
    s = sa.size
    n = pts.shape[0]
    out = np.full((s, n + 2), -1, dtype=np.int64)
    out[:, 0], out[:, 1] = sa, sb
    last = pts[sb].copy()
    step = pts[sb] - pts[sa]
    prev_step = step.copy()
    link = np.linalg.norm(step, axis=1)  # (S,) the seed's spacing
    visited = np.zeros((s, n), dtype=bool)
    visited[np.arange(s), sa] = True
    visited[np.arange(s), sb] = True
    alive = np.ones(s, dtype=bool)
    length = np.full(s, 2)
    skipped = np.zeros(s, dtype=bool)  # the last step passed over an unseen marker
    for _ in range(n):
        rows = np.nonzero(alive)[0]
        if rows.size == 0:
            break
        found = np.full(rows.size, -1, dtype=np.int64)
        new_step = np.zeros((rows.size, 3))
        hop_skip = np.zeros(rows.size, dtype=bool)
        for skip in (1, 2):  # the next marker, else the one after (one unseen)
            todo = found < 0
            if skip == 2:  # never two unseen markers in a row: a bridge joins those
                todo &= ~skipped[rows]
            if not todo.any():
                break
            r = rows[todo]
            guess = last[r] + skip * (2 * step[r] - prev_step[r])
            kq = min(8, n)
            d, i = tree.query(guess, k=kq)
            d, i = d.reshape(r.size, kq), i.reshape(r.size, kq)
            vec = pts[i] - last[r][:, None]  # (R, kq, 3)
            hop = np.linalg.norm(vec, axis=2) / skip
            cos = np.einsum("rkc,rc->rk", vec, step[r]) / np.maximum(
                hop * skip * link[r][:, None], 1e-12
            )
            lonely = nearest[i] >= _ISOLATION_SHARP_TURN * link[r][:, None]
            ok = (
                (cos >= np.where(lonely, np.cos(np.radians(max_turn_degrees)), _COS_SOFT_TURN))
                & (d <= _GUESS_TOLERANCE * skip * link[r][:, None])
                & (np.abs(hop - link[r][:, None]) <= uniformity * link[r][:, None])
                & ~visited[r[:, None], i]
                & (nearest[i] >= _ISOLATION_NEAREST * link[r][:, None])
            )
            first = np.where(ok.any(axis=1), np.argmax(ok, axis=1), -1)
            got = first >= 0
            pick = i[np.arange(r.size), np.maximum(first, 0)]
            idx_todo = np.nonzero(todo)[0]
            found[idx_todo[got]] = pick[got]
            new_step[idx_todo[got]] = (pts[pick[got]] - last[r[got]]) / skip
            hop_skip[idx_todo[got]] = skip == 2
        ok_rows = rows[found >= 0]
        alive[rows[found < 0]] = False
        f = found[found >= 0]
        prev_step[ok_rows] = step[ok_rows]
        step[ok_rows] = new_step[found >= 0]
        skipped[ok_rows] = hop_skip[found >= 0]
        last[ok_rows] = pts[f]
        visited[ok_rows, f] = True
        out[ok_rows, length[ok_rows]] = f
        length[ok_rows] += 1
    return out


# ------------------------------------------------------------------------------ init
def _insert_unseen(
    sel: np.ndarray, mean: np.ndarray, spacing: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Add traces for markers unseen in frame 0 (beyond the thesis).

    A link about ``k >= 2`` times the median spacing (within 30 %) holds ``k - 1``
    unseen markers: they get traces with index -1, placed on the curve through the
    traces at their rest arc length, and the link is split into ``k`` equal spacings.
    """
    med = float(np.median(spacing))
    ratio = spacing / med
    k = np.rint(ratio).astype(np.int64)
    split = (k >= 2) & (np.abs(ratio - k) <= 0.3)
    if not split.any():
        return sel, mean, spacing, 0
    reps = np.where(split, k, 1)  # each link becomes reps[j] links
    new_spacing = np.repeat(spacing / reps, reps)
    seen = np.zeros(new_spacing.size + 1, dtype=bool)
    seen[np.concatenate([[0], np.cumsum(reps)])] = True
    new_sel = np.full(seen.size, -1, dtype=np.int64)
    new_sel[seen] = sel
    pos = np.zeros((seen.size, 3))
    pos[seen] = mean
    pos, _ = fill_interior_on_curve(pos, seen, rest_arclength(new_spacing))
    return new_sel, pos, new_spacing, int((~seen).sum())


def _adopt_at_inserted(
    p0: np.ndarray, sel: np.ndarray, positions: np.ndarray, gamma: float, rejected: np.ndarray
) -> np.ndarray:
    """Which inserted traces have their marker in frame 0 after all (automatic init).

    A bridge across hidden markers inserts traces on the curve through the chain;
    a rope marker seen between two hidden ones fails the chain's 1-D test (it is
    alone among body points) but lies on that curve. An inserted trace adopts the
    frame-0 point nearest it when that point is within γ, not already a trace nor
    rejected as body-like, and unambiguous: the next point is at least twice as far.

    Returns
    -------
    (M,) bool
        True for an inserted trace (``sel == -1``) that adopts a point.
    """
    out = np.zeros(sel.size, dtype=bool)
    ins = np.flatnonzero(sel < 0)
    if ins.size == 0 or p0.shape[0] < 2:
        return out
    d, i = cKDTree(p0).query(positions[ins], k=2)
    taken = np.isin(i[:, 0], np.concatenate([sel[sel >= 0], rejected]))
    ok = (d[:, 0] <= gamma) & (d[:, 1] >= 2.0 * d[:, 0]) & ~taken
    first, count = np.unique(i[ok, 0], return_counts=True)
    ok[ok] &= np.isin(i[ok, 0], first[count == 1])
    out[ins[ok]] = True
    return out


def _select_rope_points(
    cloud: PointCloud,
    box: Sequence[float] | np.ndarray | None,
    markers: Sequence[int] | np.ndarray | None,
    window_seconds: float,
) -> tuple[np.ndarray, str, np.ndarray]:
    """The rope's points among frame 0's: inside ``box``, the given ``markers``, or
    (neither given) found automatically without its body-like points.

    Returns the (K,) int64 indices, the method (``box``, ``markers``, ``auto``) and the
    (R,) int64 body-like points dropped from the automatic chain.
    """
    p0 = cloud.frame(0)
    n0 = p0.shape[0]
    rejected = np.zeros(0, dtype=np.int64)
    if box is not None:
        b = np.asarray(box, dtype=np.float64).reshape(-1)
        if b.shape != (6,) or not np.all(np.isfinite(b)):
            raise ValidationError(
                f"box: expected 6 finite numbers x0,y0,z0,x1,y1,z1 (metres), got {b.tolist()}"
            )
        lo = np.minimum(b[:3], b[3:])
        hi = np.maximum(b[:3], b[3:])
        sel = np.nonzero(np.all((p0 >= lo) & (p0 <= hi), axis=1))[0]
        method = "box"
    elif markers is not None:
        sel = np.asarray(markers).reshape(-1)
        if sel.size and not np.issubdtype(sel.dtype, np.integer):
            raise ValidationError("markers: expected integer point indices")
        sel = sel.astype(np.int64)
        bad = (sel < 0) | (sel >= n0)
        if bad.any():
            raise ValidationError(
                f"markers: index {int(sel[bad][0])} is out of range: frame 0 has {n0} points"
            )
        if np.unique(sel).size != sel.size:
            raise ValidationError("markers: an index is given twice")
        method = "markers"
    else:
        sel = find_rope_chain(cloud, window_seconds=window_seconds)
        if sel.size >= 2:
            link = float(np.median(np.linalg.norm(np.diff(p0[sel], axis=0), axis=1)))
            body = body_like(cloud, sel, link)
            rejected = sel[body]
            sel = sel[~body]
        method = "auto"
    return sel, method, rejected


def _default_gamma(start: np.ndarray) -> float:
    """γ, metres: ``GAMMA_FRACTION`` of the median nearest-neighbour distance of the
    selected points ``start`` (K, 3)."""
    nn, _ = cKDTree(start).query(start, k=2)
    gamma = GAMMA_FRACTION * float(np.median(nn[:, 1]))
    if not gamma > 0:
        raise ValidationError("rope: the selected points coincide; cannot derive γ")
    return gamma


def _check_rope_request(
    cloud: PointCloud,
    box: Sequence[float] | np.ndarray | None,
    markers: Sequence[int] | np.ndarray | None,
    auto: bool,
) -> None:
    """Raise unless exactly one of ``box``, ``markers`` or ``auto`` selects the rope
    and ``cloud`` has at least 2 frames."""
    chosen = sum([box is not None, markers is not None, bool(auto)])
    if chosen != 1:
        raise ValidationError(
            "rope: give exactly one of box=, markers= or auto=True to select the rope"
        )
    if cloud.n_frames < 2:
        raise ValidationError(f"cloud: need at least 2 frames to track, got {cloud.n_frames}")


def _followed_traces(
    temp: np.ndarray, max_temp_markers: int, n_window: int, n_selected: int
) -> np.ndarray:
    """(K,) bool: the traces with at most ``min(max_temp_markers, n_window // 2)``
    temporary markers in ``temp`` (W, K) bool; raises if fewer than 3 remain."""
    limit = min(max_temp_markers, n_window // 2)
    keep = temp.sum(axis=0) <= limit
    if keep.sum() < 3:
        raise ValidationError(
            f"rope: only {int(keep.sum())} of {n_selected} selected points could be followed "
            f"through the first {n_window} frames; is the rope still there?"
        )
    return keep


def _ordered_chain(
    sel: np.ndarray, pos: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The followed traces ordered along the rope, ghosts beside a marker dropped.

    ``sel`` (K,) int64 frame-0 indices and ``pos`` (W, K, 3) metres, the traces
    through the window. Returns the kept indices (M,) and mean positions (M, 3) in
    order along the rope, the mean chord of each link over the window (M - 1,)
    metres, and the (K,) bool off-chain mask (in chain order) of the dropped traces.
    Raises if fewer than 3 points form the chain or two traces coincide.
    """
    mean = pos.mean(axis=0)
    order = _chain_order(mean)
    sel, pos, mean = sel[order], pos[:, order], mean[order]
    chord = np.linalg.norm(np.diff(mean, axis=0), axis=1)
    off = off_chain_points(mean, float(np.median(chord)))  # a ghost beside a marker
    if (~off).sum() < 3:
        raise ValidationError(f"rope: only {int((~off).sum())} selected points form a chain")
    sel, pos, mean = sel[~off], pos[:, ~off], mean[~off]
    chord = np.linalg.norm(np.diff(pos, axis=1), axis=2).mean(axis=0)
    if np.any(chord <= 0):
        raise ValidationError("rope: two selected traces coincide")
    return sel, mean, chord, off


def init_rope(
    cloud: PointCloud,
    *,
    box: Sequence[float] | np.ndarray | None = None,
    markers: Sequence[int] | np.ndarray | None = None,
    auto: bool = False,
    window_seconds: float = 0.5,
    gamma: float | None = None,
    max_temp_markers: int | None = None,
) -> RopeInit:
    """Identify the rope in the still window at the start and set up its traces.

    Exactly one of ``box``, ``markers`` or ``auto`` selects the rope's points in
    frame 0. Then (thesis §3.4) every selected point starts a trace; through the
    window each trace takes the point nearest its running average position within γ
    (conflicts resolved one-to-one, :func:`gated_assignment`), else a temporary
    marker at the average. Traces with more than ``min(max_temp_markers, W // 2)``
    temporary markers in the W-frame window are discarded. The rest are ordered
    along the rope (the longest path of the spanning tree of their average
    positions, starting at the higher end; for a rope hanging from one end this is
    the thesis' ordering by height) and ``l_j`` is the mean distance between
    neighbouring traces over the window.

    Parameters
    ----------
    cloud : PointCloud
        The take; its first ``window_seconds`` should show the rope hanging still.
    box : (6,) float, metres, optional
        ``x0, y0, z0, x1, y1, z1`` (Y up, skincap's frame): frame-0 points inside the
        axis-aligned box (bounds in either order, inclusive) are the rope.
    markers : sequence of int, optional
        Indices of the rope's points among frame 0's points (file order).
    auto : bool
        Find the rope automatically (:func:`find_rope_chain`).
    window_seconds : float
        Length of the still window, seconds (0.5 s: 60 frames at 120 Hz).
    gamma : float, metres, optional
        γ. Default ``0.25 × median`` nearest-neighbour distance of the selected points
        (3 cm for tape every 12 cm).
    max_temp_markers : int, optional
        maxTempMarkers. Default one second of frames (``round(rate)``).

    Returns
    -------
    RopeInit

    Raises
    ------
    ValidationError
        Not exactly one selection given, a bad box or index, fewer than 3 rope points
        selected or surviving the window.
    """
    _check_rope_request(cloud, box, markers, auto)
    p0 = cloud.frame(0)
    sel, method, rejected = _select_rope_points(cloud, box, markers, window_seconds)
    if sel.size < 3:
        raise ValidationError(
            f"rope: {sel.size} points selected in frame 0 ({method}); need at least 3"
        )
    start = p0[sel]
    if gamma is None:
        gamma = _default_gamma(start)
    n_window = _window_frames(cloud, window_seconds)
    if max_temp_markers is None:
        max_temp_markers = max(1, int(round(cloud.rate)))
    pos, temp = _follow_window(cloud, start, n_window, float(gamma))
    keep = _followed_traces(temp, int(max_temp_markers), n_window, sel.size)
    sel, mean, chord, off = _ordered_chain(sel[keep], pos[:, keep])
    spacing, folded_links = _rest_spacing(chord, mean)
    folded = int(np.count_nonzero(folded_links))
    bent = int(np.count_nonzero((spacing != chord) & ~folded_links))
    sel, mean, spacing, inserted = _insert_unseen(sel, mean, spacing)
    if method == "auto" and inserted:
        adopt = _adopt_at_inserted(p0, sel, mean, float(gamma), rejected)
        if adopt.any():
            sel = sel.copy()
            sel[adopt] = cKDTree(p0).query(mean[adopt], k=1)[1]
            again = init_rope(
                cloud,
                markers=sel[sel >= 0],
                window_seconds=window_seconds,
                gamma=gamma,
                max_temp_markers=max_temp_markers,
            )
            again.meta.update(
                method="auto",
                discarded=again.meta["discarded"] + int((~keep).sum()),
                body_like=rejected.tolist(),
                adopted=int(adopt.sum()),
            )
            return again
    return RopeInit(
        indices=sel,
        positions=mean,
        spacing=spacing,
        gamma=float(gamma),
        max_temp_markers=int(max_temp_markers),
        window=(0, n_window),
        meta={
            "method": method,
            "discarded": int((~keep).sum()),
            "inserted": inserted,
            "off_chain": int(off.sum()),
            "folded": folded,
            "bent": bent,
            "body_like": rejected.tolist(),
        },
    )
