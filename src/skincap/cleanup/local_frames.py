"""Local reference frames (Park & Hodgins 2006, eq. 1) and missing-marker estimates (eq. 2).

Each marker ``i`` has a local frame at its reference-pose position ``x_i^0`` with axes
``(t_i^0, b_i^0, n_i^0)``: ``n`` the marker-surface normal, ``t`` the direction to the
first neighbour projected on the tangent plane, ``b = n × t``. Its neighbours' reference
positions in that frame are ``x̂_{i,k}^0 = R_i^0 (x_{i,k}^0 - x_i^0)`` (eq. 1).

A missing marker is estimated from the neighbours available in a frame by the rigid
transform that carries their reference positions onto their current ones (eq. 2,
solved by :func:`skincap.geometry.rigid.fit_rigid`) applied to the marker's own
reference position. The frame rotation ``R_i^0`` cancels out of that estimate, so
:func:`estimate_missing` works directly with reference offsets ``x_{i,k}^0 - x_i^0``.
"""

from __future__ import annotations

import numpy as np

from skincap._arrays import Progress
from skincap.cleanup.surface import MarkerSurface
from skincap.errors import ValidationError
from skincap.geometry.rigid import fit_rigid

__all__ = [
    "estimate_missing",
    "fit_frames_robust",
    "local_reference_coordinates",
    "local_reference_frames",
    "neighbour_table",
]

Neighbours = MarkerSurface | tuple[np.ndarray, np.ndarray]


def fit_frames_robust(
    reference: np.ndarray,
    current: np.ndarray,
    present: np.ndarray,
    *,
    ratio: float = 3.0,
    floor: float = 0.005,
    window: int = 9,
) -> tuple[np.ndarray, np.ndarray]:
    """Local frames (rigid fits of neighbourhoods over time) that one bad neighbour cannot shake.

    A first rigid fit (:func:`~skincap.geometry.rigid.fit_rigid`) of each
    neighbourhood's reference shape onto its present members in every frame. A
    member's residual vector changes slowly where it deforms or slides with the skin
    and suddenly where it spikes or is swapped. Its *sudden* part is the residual less
    its running median over ``window`` frames
    (:func:`skincap.cleanup.outliers.running_median`); the median is its *usual*
    residual. Where some member's sudden part exceeds ``floor`` (and at least four
    are present), each member is left out in turn; the one whose absence lets every
    other member fit within ``floor`` of its usual residual (and ``ratio`` times
    closer than before) is the bad one. It is put back where the others' fit and its
    usual residual say and the frame fitted again. Dropping it instead would change
    the member set for that frame only, and in a neighbourhood that deforms that
    moves the frame; a steady misfit (a member across a joint) is left alone for the
    same reason.

    Parameters
    ----------
    reference : (N, K, 3) or (1, N, K, 3) float, metres
        Reference shapes (broadcast against ``current``).
    current : (T, N, K, 3) float, metres
        Members' positions, frames on axis 0.
    present : (T, N, K) bool
    ratio : float
    floor : float, metres
        A sudden change below this is left alone (default 5 mm).
    window : odd int, frames

    Returns
    -------
    R : (T, N, 3, 3), t : (T, N, 3)
        ``current ≈ R reference + t``; NaN where fewer than three members are present.
    """
    from skincap.cleanup.robust_stats import running_median

    ok = np.asarray(present, dtype=bool)
    cur = np.asarray(current, dtype=np.float64)
    rot, tr = fit_rigid(reference, cur, mask=ok)
    ref_full = np.broadcast_to(reference, cur.shape)
    fitted = np.einsum("...ij,...kj->...ki", rot, ref_full)
    resid = np.where(ok[..., None], fitted + tr[..., None, :] - cur, np.nan)  # (T, N, K, 3)
    t = cur.shape[0]
    flat = resid.reshape(t, -1, 3)
    jump = (flat - running_median(flat, window)).reshape(*ok.shape, 3)  # sudden part
    sudden = np.linalg.norm(jump, axis=-1)
    steady = resid - jump  # each member's usual residual around that frame
    # suspect frames: some member changed suddenly by more than the floor
    suspect = (np.nan_to_num(sudden, nan=0.0) > floor).any(axis=-1) & (ok.sum(axis=-1) >= 4)
    if not suspect.any():
        return rot, tr
    s_ref, s_cur, s_ok, s_steady = ref_full[suspect], cur[suspect], ok[suspect], steady[suspect]
    before = np.where(s_ok, np.nan_to_num(sudden[suspect], nan=0.0), 0.0).max(axis=-1)
    # leave each member out in turn: the bad one is the one whose absence makes the
    # others fit as usual again
    count, k_count = s_ok.shape[0], s_ok.shape[-1]
    score = np.full((count, k_count), np.inf)
    fits = []
    for k in range(k_count):
        without = s_ok.copy()
        without[:, k] = False
        r_k, t_k = fit_rigid(s_ref, s_cur, mask=without)
        fitted_k = np.einsum("sij,skj->ski", r_k, s_ref) + t_k[:, None, :]
        miss = np.linalg.norm(fitted_k - s_cur - s_steady, axis=-1)  # (S, K)
        miss = np.where(without, np.nan_to_num(miss, nan=np.inf), 0.0)
        score[:, k] = np.where(s_ok[:, k], miss.max(axis=-1), np.inf)
        fits.append((r_k, t_k))
    best = np.argmin(score, axis=-1)
    best_score = score[np.arange(count), best]
    # accept when the others then fit as usual (within the floor and well below before)
    accept = (best_score < np.minimum(floor, before / ratio)) & np.isfinite(best_score)
    if accept.any():
        rows = np.flatnonzero(accept)
        w = best[rows]
        r_o = np.stack([fits[k][0][i] for i, k in zip(rows.tolist(), w.tolist(), strict=True)])
        t_o = np.stack([fits[k][1][i] for i, k in zip(rows.tolist(), w.tolist(), strict=True)])
        fixed = s_cur[rows].copy()
        sub = np.arange(rows.size)
        # the member goes back to where the others' fit and its usual residual put it
        fixed[sub, w] = (
            np.einsum("sij,sj->si", r_o, s_ref[rows][sub, w]) + t_o - s_steady[rows][sub, w]
        )
        r_new, t_new = fit_rigid(s_ref[rows], fixed, mask=s_ok[rows])
        idx = np.flatnonzero(suspect.reshape(-1))[rows]
        lead = ok.shape[:-1]
        rot = rot.copy().reshape(-1, 3, 3)
        tr = tr.copy().reshape(-1, 3)
        rot[idx], tr[idx] = r_new, t_new
        rot = rot.reshape(*lead, 3, 3)
        tr = tr.reshape(*lead, 3)
    return rot, tr


def neighbour_table(neighbours: Neighbours, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A CSR neighbourhood as a padded table.

    Parameters
    ----------
    neighbours : MarkerSurface or (offsets (N+1,), indices (nnz,)) int
        Marker ``i``'s neighbours are ``indices[offsets[i]:offsets[i+1]]``.
    n : int
        Number of markers N the CSR must describe.

    Returns
    -------
    table : (N, D) int64
        Neighbour columns, padding 0; ``D`` the largest degree (0 if none).
    valid : (N, D) bool
        False on padding.
    """
    if isinstance(neighbours, MarkerSurface):
        offsets, indices = neighbours.offsets, neighbours.indices
    else:
        try:
            offsets, indices = neighbours
        except (TypeError, ValueError) as exc:
            raise ValidationError(
                "neighbours must be a MarkerSurface or an (offsets, indices) pair"
            ) from exc
    offsets = np.asarray(offsets)
    indices = np.asarray(indices)
    if offsets.shape != (n + 1,) or not np.issubdtype(offsets.dtype, np.integer):
        raise ValidationError(
            f"neighbour offsets must be ({n + 1},) integers; got {offsets.shape} {offsets.dtype}"
        )
    if indices.ndim != 1 or (indices.size and not np.issubdtype(indices.dtype, np.integer)):
        raise ValidationError(f"neighbour indices must be 1-D integers; got {indices.shape}")
    deg = np.diff(offsets)
    if offsets[0] != 0 or np.any(deg < 0) or offsets[-1] != indices.size:
        raise ValidationError("neighbour offsets must start at 0, not decrease, end at nnz")
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise ValidationError(f"neighbour indices must lie in 0..{n - 1}")
    d = int(deg.max()) if n else 0
    valid = np.arange(d)[None, :] < deg[:, None]
    table = np.zeros((n, d), dtype=np.int64)
    table[valid] = indices
    return table, valid


def local_reference_frames(reference: np.ndarray, surface: MarkerSurface) -> np.ndarray:
    """Rotations ``R_i^0 = [t b n]^T`` of the local reference frames (eq. 1).

    Parameters
    ----------
    reference : (N, 3) float, metres
        Reference-pose positions; NaN for unknown markers.
    surface : MarkerSurface
        Neighbourhoods (first neighbour defines ``t``) and faces (area-weighted
        vertex normals); without faces, the normal is the least-variance direction of
        the marker and its neighbours.

    Returns
    -------
    (N, 3, 3) float64
        Rows ``t, b, n`` per marker; NaN where the marker, its first neighbour or its
        normal is undefined. Normals of face-less surfaces have an arbitrary sign.
    """
    ref = np.asarray(reference, dtype=np.float64)
    n = surface.n_markers
    if ref.shape != (n, 3):
        raise ValidationError(f"reference must have shape ({n}, 3); got {ref.shape}")
    table, valid = neighbour_table(surface, n)
    normal = np.zeros((n, 3))
    if surface.faces.shape[0]:
        f = surface.faces
        fn = np.cross(ref[f[:, 1]] - ref[f[:, 0]], ref[f[:, 2]] - ref[f[:, 0]])  # area-weighted
        fn = np.where(np.isfinite(fn), fn, 0.0)
        for corner in range(3):
            np.add.at(normal, f[:, corner], fn)
    else:
        nb = np.where(valid[..., None], ref[table], np.nan)  # (N, D, 3)
        pts = np.concatenate([ref[:, None, :], nb], axis=1)
        ok = np.isfinite(pts).all(axis=2)
        cnt = ok.sum(axis=1)
        z = np.where(ok[..., None], pts, 0.0)
        mean = z.sum(axis=1) / np.maximum(cnt, 1)[:, None]
        dev = np.where(ok[..., None], pts - mean[:, None, :], 0.0)
        cov = np.einsum("nki,nkj->nij", dev, dev)
        _, vec = np.linalg.eigh(cov)
        normal = np.where((cnt >= 3)[:, None], vec[:, :, 0], 0.0)
    norm = np.linalg.norm(normal, axis=1)
    normal = np.where((norm > 0)[:, None], normal / np.where(norm > 0, norm, 1.0)[:, None], np.nan)
    first = np.where(valid[:, :1], ref[table[:, :1]][:, 0], np.nan) if table.shape[1] else None
    if first is None:
        return np.full((n, 3, 3), np.nan)
    v = first - ref
    tan = v - normal * np.einsum("ni,ni->n", v, normal)[:, None]
    tn = np.linalg.norm(tan, axis=1)
    good = np.isfinite(tn) & (tn > 1e-12)
    tan = np.where(good[:, None], tan / np.where(good, tn, 1.0)[:, None], np.nan)
    bit = np.cross(normal, tan)
    return np.stack([tan, bit, normal], axis=1)


def local_reference_coordinates(reference: np.ndarray, surface: MarkerSurface) -> np.ndarray:
    """Neighbours' reference positions in each local reference frame (eq. 1).

    Parameters
    ----------
    reference : (N, 3) float, metres
    surface : MarkerSurface

    Returns
    -------
    (N, D, 3) float64, metres
        ``x̂_{i,k}^0 = R_i^0 (x_{i,k}^0 - x_i^0)`` in CSR order (nearest first), NaN on
        padding (``D`` the largest degree) and where undefined.
    """
    ref = np.asarray(reference, dtype=np.float64)
    rot = local_reference_frames(ref, surface)
    table, valid = neighbour_table(surface, surface.n_markers)
    rel = np.where(valid[..., None], ref[table] - ref[:, None, :], np.nan)
    return np.einsum("nij,nkj->nki", rot, rel)


def _check_positions(positions: np.ndarray) -> np.ndarray:
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise ValidationError(f"positions must have shape (T, N, 3); got {pos.shape}")
    if np.isinf(pos).any():
        raise ValidationError("positions must not contain inf (use NaN for missing)")
    return pos


def estimate_missing(
    positions: np.ndarray,
    neighbours: Neighbours,
    reference: np.ndarray | None = None,
    *,
    min_neighbours: int = 3,
    estimated_weight: float = 1.0,
    temporal: bool = False,
    progress: Progress | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Estimate missing markers from their available neighbours (eq. 2), greedily.

    In every frame, the missing markers with the most available neighbours are
    estimated first (ties together, all frames at once); estimated markers then count
    as available neighbours for the rest (Park & Hodgins' greedy order). A marker needs
    ``min_neighbours`` available neighbours with known reference positions.

    Parameters
    ----------
    positions : (T, N, 3) float, metres
        Measured positions, NaN where missing.
    neighbours : MarkerSurface or (offsets, indices)
        CSR neighbourhoods over the N markers.
    reference : (N, 3) float, metres, optional
        Reference pose (e.g. ``surface.reference``). NaN entries are unknown. When
        None, each marker uses its own reference: the first frame in which it and the
        most of its neighbours are present.
    min_neighbours : int, default 3
        At least 3 (a rigid transform needs three points).
    estimated_weight : float, default 1.0
        Weight of an already-estimated neighbour in the fit (measured ones weigh 1).
    temporal : bool, default False
        Beyond the paper: use the neighbourhood's shape from the marker's own frames
        nearest in time -- the last frame before and the first after where it was
        measured with at least ``min_neighbours`` neighbours -- and blend the two
        estimates linearly in time. The skin deforms less over a gap than between the
        reference pose and the current frame. Where the marker has no such frame, the
        reference pose is used.
    progress : callable(fraction, label), optional
        Called after each greedy round.

    Returns
    -------
    estimates : (T, N, 3) float64, metres
        Measured positions where measured, estimates where estimated, NaN where the
        marker could not be estimated.
    estimated_mask : (T, N) bool
        True where ``estimates`` holds an estimate (not a measurement).
    """
    pos = _check_positions(positions)
    t_count, n, _ = pos.shape
    if min_neighbours < 3:
        raise ValidationError(f"min_neighbours must be at least 3; got {min_neighbours}")
    if not estimated_weight > 0:
        raise ValidationError(f"estimated_weight must be positive; got {estimated_weight}")
    table, valid = neighbour_table(neighbours, n)
    present = np.isfinite(pos).all(axis=2)  # (T, N)

    if reference is not None:
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != (n, 3):
            raise ValidationError(f"reference must have shape ({n}, 3); got {ref.shape}")
        rel = ref[table] - ref[:, None, :]  # (N, D, 3)
    else:
        if t_count == 0:
            rel = np.full((n, table.shape[1], 3), np.nan)
        else:
            nb_present = present[:, table] & valid[None]  # (T, N, D)
            score = np.where(present, nb_present.sum(axis=2), -1)  # (T, N)
            best = np.argmax(score, axis=0)  # (N,) first best frame per marker
            own = pos[best, np.arange(n)]  # (N, 3)
            rel = pos[best[:, None], table] - own[:, None, :]  # (N, D, 3)
    ref_ok = valid & np.isfinite(rel).all(axis=2)  # (N, D)
    rel = np.where(ref_ok[..., None], rel, 0.0)
    if temporal and t_count:
        prev_f, next_f = _bracketing_frames(present, table, valid, min_neighbours)
    else:
        prev_f = next_f = np.full((t_count, n), -1, dtype=np.int64)

    est = pos.copy()
    estimated = np.zeros((t_count, n), dtype=bool)
    available = present.copy()
    weight_of = np.where(present, 1.0, estimated_weight)  # (T, N)
    pending = ~present & (
        (ref_ok.sum(axis=1) >= min_neighbours)[None, :] | (prev_f >= 0) | (next_f >= 0)
    )
    ref_ok_any = ref_ok | temporal
    total = max(int(pending.sum()), 1)
    while True:
        pt, pi = np.nonzero(pending)
        if pt.size == 0:
            break
        nb = table[pi]  # (M, D)
        usable = (ref_ok_any[pi] & valid[pi]) & available[pt[:, None], nb]  # (M, D)
        count = usable.sum(axis=1)
        eligible = count >= min_neighbours
        if not eligible.any():
            break
        frame_best = np.zeros(t_count, dtype=np.int64)
        np.maximum.at(frame_best, pt[eligible], count[eligible])
        go = eligible & (count >= frame_best[pt])
        gt, gi, gnb, guse = pt[go], pi[go], nb[go], usable[go]
        dst = np.where(guse[..., None], est[gt[:, None], gnb], 0.0)  # (G, D, 3)
        w = weight_of[gt[:, None], gnb]
        # the marker sits at the local origin: its estimate is R·0 + t = t (eq. 2)
        _, trans = fit_rigid(rel[gi], dst, w, guse & ref_ok[gi])
        if temporal:
            trans = _temporal_estimate(pos, gt, gi, gnb, guse, dst, w, prev_f, next_f, trans)
        ok = np.isfinite(trans).all(axis=1)
        est[gt[ok], gi[ok]] = trans[ok]
        estimated[gt[ok], gi[ok]] = True
        available[gt[ok], gi[ok]] = True
        pending[gt, gi] = False
        if progress is not None:
            progress(1.0 - pending.sum() / total, "estimating missing markers")
    return est, estimated


def _bracketing_frames(
    present: np.ndarray, table: np.ndarray, valid: np.ndarray, min_neighbours: int
) -> tuple[np.ndarray, np.ndarray]:
    """(T, N) int: last frame <= t and first frame >= t where marker i was measured
    together with at least ``min_neighbours`` neighbours; -1 when none."""
    t_count, n = present.shape
    good = present & ((present[:, table] & valid[None]).sum(axis=2) >= min_neighbours)
    frames = np.arange(t_count)[:, None]
    prev_f = np.maximum.accumulate(np.where(good, frames, -1), axis=0)
    rev = np.where(good, frames, t_count)[::-1]
    next_f = np.minimum.accumulate(rev, axis=0)[::-1]
    next_f = np.where(next_f >= t_count, -1, next_f)
    return prev_f.astype(np.int64), next_f.astype(np.int64)


def _temporal_estimate(
    pos: np.ndarray,
    gt: np.ndarray,
    gi: np.ndarray,
    gnb: np.ndarray,
    guse: np.ndarray,
    dst: np.ndarray,
    w: np.ndarray,
    prev_f: np.ndarray,
    next_f: np.ndarray,
    fallback: np.ndarray,
) -> np.ndarray:
    """Estimates from the neighbourhood shapes of the bracketing frames, time-blended."""
    out = []
    frames = []
    for ref_frames in (prev_f[gt, gi], next_f[gt, gi]):
        f = np.maximum(ref_frames, 0)
        own = pos[f, gi]  # (G, 3)
        rel = pos[f[:, None], gnb] - own[:, None, :]  # (G, D, 3)
        use = guse & np.isfinite(rel).all(axis=2) & (ref_frames >= 0)[:, None]
        _, trans = fit_rigid(np.where(use[..., None], rel, 0.0), dst, w, use)
        out.append(trans)
        frames.append(np.where(np.isfinite(trans).all(axis=1), ref_frames, -1))
    (a, b), (fa, fb) = out, frames
    span = np.where((fa >= 0) & (fb >= 0), fb - fa, 1).astype(np.float64)
    u = np.clip((gt - fa) / np.where(span > 0, span, 1.0), 0.0, 1.0)[:, None]
    both = ((fa >= 0) & (fb >= 0))[:, None]
    blended = np.where(both, (1 - u) * np.nan_to_num(a) + u * np.nan_to_num(b), np.nan)
    one = np.where((fa >= 0)[:, None], a, np.where((fb >= 0)[:, None], b, fallback))
    return np.where(both, blended, one)
