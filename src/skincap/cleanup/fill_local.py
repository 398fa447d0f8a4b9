"""Local-PCA gap filling (Park & Hodgins 2006 §4.3, eqs. 4-5) and its variants.

For every marker a *group* of it and its neighbours is expressed, frame by frame, in
a local frame (the rigid fit of the group's reference shape, eq. 5); a PCA of the local
coordinates models the group's deformation, and a missing member is the PCA
reconstruction that best fits the present members, mapped back. Variants: weighted
averaging of the groups' estimates and missing-data PCA (the paper's discussion), and
one model per gap trained around it (``local_pca_window``). Every estimate can be
joined to the measured samples at the gap's ends. :func:`skincap.cleanup.fill.fill_gaps`
chooses the variant and blends with the rigid fill; its module docstring describes
the methods.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from skincap._arrays import Progress, missing_runs
from skincap.cleanup.frame_continuity import (
    WELL_SPREAD,
    fit_rigid_with_prior,
    line_axis,
    take_noise,
    twist_prior,
)
from skincap.cleanup.neighbours import CSR
from skincap.geometry.rigid import apply_rigid, fit_rigid

__all__ = ["fill_local_pca", "fill_local_window"]


def _reference_shape(pos: np.ndarray, present: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Procrustes mean shape (m, 3) of a group over ``rows``, tolerating missing members.

    pos (T, m, 3), present (T, m). Starts from the row with most members present and
    alternates rigid alignment to the current mean with re-averaging (members absent
    in the start row are added when aligned rows see them). NaN for never-seen members.
    """
    if rows.size > 150:  # the mean shape needs no more than a spread of frames
        rows = rows[np.linspace(0, rows.size - 1, 150).round().astype(np.int64)]
    sub = pos[rows]
    ok = present[rows]
    start = int(np.argmax(ok.sum(axis=1)))
    ref = np.where(ok[start][:, None], sub[start], np.nan)
    for _ in range(3):
        known = ~np.isnan(ref[:, 0])
        use = ok & known[None, :]
        rot, tr = fit_rigid(sub, np.where(known[:, None], ref, 0.0)[None], mask=use)
        # align every row onto the reference: inverse map current -> reference
        fine = ~np.isnan(tr[:, 0])
        if not fine.any():
            break
        aligned = apply_rigid(rot[fine], tr[fine], sub[fine])  # rows in the reference pose
        w = ok[fine]
        cnt = w.sum(axis=0)
        total = np.where(w[..., None], aligned, 0.0).sum(axis=0)
        ref = np.where(cnt[:, None] > 0, total / np.maximum(cnt, 1)[:, None], np.nan)
        ref = ref - np.nanmean(ref, axis=0) if np.isfinite(ref).any() else ref
    return ref


def _pca(y: np.ndarray, variance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """PCA of complete rows y (F, D): mean (D,), basis (D, q), eigenvalues (q,), noise σ²."""
    mu = y.mean(axis=0)
    c = y - mu
    # eigen-decomposition of the small (D, D) covariance: far cheaper than an SVD of
    # the (F, D) data for the few-dozen-dimensional neighbourhoods
    ev, vec = np.linalg.eigh(c.T @ c / max(y.shape[0] - 1, 1))
    ev, vec = np.maximum(ev[::-1], 0.0), vec[:, ::-1]
    total = ev.sum()
    if total <= 0:
        return mu, np.zeros((y.shape[1], 0)), np.zeros(0), 1e-10
    frac = np.cumsum(ev) / total
    q = int(min(np.searchsorted(frac, variance) + 1, len(ev)))
    rest = ev[q:]
    noise = float(rest.mean()) if rest.size else float(ev[-1]) * 0.01
    return mu, vec[:, :q], np.maximum(ev[:q], 1e-12), max(noise, 1e-10)


def _pca_solve(
    basis: np.ndarray, evals: np.ndarray, noise: float, resid: np.ndarray, obs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients fitting the observed entries with a PPCA prior, batched.

    basis (D, q), resid (F, D) (NaN-free where obs), obs (F, D) bool.
    Returns coefficients (F, q) and the posterior covariance (F, q, q) / noise.
    """
    q = basis.shape[1]
    ow = obs.astype(np.float64)
    a = np.einsum("dq,fd,dr->fqr", basis, ow, basis)  # (F, q, q)
    a += np.diag(noise / evals)[None]
    b = np.einsum("dq,fd->fq", basis, np.where(obs, resid, 0.0))
    ainv = np.linalg.inv(a)
    coef = np.einsum("fqr,fr->fq", ainv, b)
    del q
    return coef, ainv


def _group_estimates(
    pos: np.ndarray,
    present: np.ndarray,
    want: np.ndarray,
    *,
    variance: float,
    missing_data: bool,
    refits: int = 1,
    em_iterations: int = 15,
    max_train: int = 400,
    query_frame: np.ndarray | None = None,
    query_member: np.ndarray | None = None,
    member_weights: np.ndarray | None = None,
    frame_prior: float | None = None,
    noise: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Estimates of the missing members of one group.

    pos (T, m, 3) with NaN, present (T, m), want (T, m) targets. ``query_frame`` /
    ``query_member`` (Q,) int: measured samples to estimate as if that member alone
    were missing in that frame (the anchors at a gap's ends). ``member_weights`` (m,)
    float >= 0, optional: the members' weights in the local-frame fits (default 1).
    ``frame_prior``: the twist (radians) the local frame's temporal-continuity prior
    may be off by (:func:`_continuity_prior`), for members of measurement noise
    ``noise`` (metres); None fits each row's frame alone.

    Returns (rows (F + Q,), estimates (F + Q, m, 3) NaN where not estimated, variance
    (F + Q, m), centre observed (F + Q,) bool, local-frame rotations (F + Q, 3, 3)),
    the Q query rows last (``rows`` holds their frames), or None when the group has no
    model.
    """
    t, m, _ = pos.shape
    count = present.sum(axis=1)
    complete = count == m
    if missing_data:
        train = count >= max(3, m // 2 + 1)
    else:
        train = complete
    if train.sum() < 4:
        return None
    ref = _reference_shape(pos, present, np.nonzero(train)[0])
    if np.isnan(ref).any():
        return None
    d = 3 * m
    # local coordinates of training rows (eqs. 4-5)
    rows_tr = np.nonzero(train)[0]
    if rows_tr.size > max_train:  # an even spread of frames trains the model as well
        rows_tr = rows_tr[np.linspace(0, rows_tr.size - 1, max_train).round().astype(np.int64)]
    mw = np.ones(m) if member_weights is None else member_weights
    rot, tr = fit_rigid(ref[None], pos[rows_tr], weights=present[rows_tr] * mw)
    local = np.einsum("fji,fkj->fki", rot, pos[rows_tr] - tr[:, None, :])  # R^T (x - t)
    y = local.reshape(len(rows_tr), d)
    yobs = np.repeat(present[rows_tr], 3, axis=1)
    if missing_data and not yobs.all():
        y = _em_pca_impute(y, yobs, variance, em_iterations)
    mu, basis, evals, noise = _pca(y, variance)
    if basis.shape[1] == 0:
        return None
    # rows to estimate: a wanted member missing and >= 3 members present
    rows = np.nonzero(want.any(axis=1) & (count >= 3))[0]
    if query_frame is None or query_member is None:
        query_frame = query_member = np.zeros(0, dtype=np.int64)
    n_rows = rows.size
    rows = np.concatenate([rows, query_frame])
    if rows.size == 0:
        return None
    cur = pos[rows]  # (F + Q, m, 3)
    obs = present[rows].copy()
    obs[n_rows + np.arange(query_frame.size), query_member] = False  # as if missing
    cur[~obs] = np.nan
    # a query row left with fewer than three members gets NaN from the rigid fit
    fit_pts = cur.copy()
    fit_mask = obs.copy()
    est = cur.copy()
    prior = None
    if frame_prior is not None and noise > 0:
        _, row_cond = line_axis(np.broadcast_to(ref, (rows.size, m, 3)), obs * mw)
        if (np.nan_to_num(row_cond) < WELL_SPREAD).any():  # else no row takes a prior
            rot0, _ = fit_rigid(ref[None], fit_pts, weights=fit_mask * mw)
            prior = _continuity_prior(ref, pos, present, rows, obs * mw, rot0, mw)
    for _ in range(refits + 1):
        if prior is None:
            rot, tr = fit_rigid(ref[None], fit_pts, weights=fit_mask * mw)
        else:
            src = np.broadcast_to(ref, fit_pts.shape)
            rot, tr = fit_rigid_with_prior(
                src, fit_pts, fit_mask * mw, prior, noise=noise, twist_sd=frame_prior
            )
        yl = np.einsum("fji,fkj->fki", rot, cur - tr[:, None, :]).reshape(len(rows), d)
        o = np.repeat(obs, 3, axis=1)
        coef, ainv = _pca_solve(basis, evals, noise, yl - mu, o)
        yhat = (mu + coef @ basis.T).reshape(len(rows), m, 3)
        est = apply_rigid(rot, tr, yhat)  # (F, m, 3)
        fit_pts = np.where(obs[..., None], cur, est)
        fit_mask = np.ones_like(obs)
    # predictive variance per member: noise * (1 + trace(U_j A^-1 U_j^T))
    bj = basis.reshape(m, 3, -1)
    var = noise * (3.0 + np.einsum("jcq,fqr,jcr->fj", bj, ainv, bj))
    est = np.where(obs[..., None], np.nan, est)
    return rows, est, var, obs[:, 0], rot


def _continuity_prior(
    ref: np.ndarray,
    pos: np.ndarray,
    present: np.ndarray,
    rows: np.ndarray,
    fit_weights: np.ndarray,
    rot_fit: np.ndarray,
    mw: np.ndarray,
) -> np.ndarray:
    """Prior local-frame rotations (F, 3, 3) for a group's estimation ``rows`` (F,).

    The frame is well determined in the frames whose present members are spread off
    a line (:func:`~skincap.cleanup.frame_continuity.line_axis` conditioning at least
    :data:`~skincap.cleanup.frame_continuity.WELL_SPREAD`, where the prior fades out):
    its rotations at the last such
    frame at or before each row and the first at or after it (the fit of the
    reference shape ``ref`` (m, 3) to ``pos`` (T, m, 3), present (T, m), member
    weights ``mw`` (m,)) give the prior through
    :func:`~skincap.cleanup.frame_continuity.twist_prior`, about the principal axis of
    the members fitted in the row (``fit_weights`` (F, m), ``rot_fit`` (F, 3, 3) their
    plain fit). NaN rows: no such frame on either side.
    """
    t, m = present.shape
    w_all = present * mw  # (T, m)
    _, cond = line_axis(np.broadcast_to(ref, (t, m, 3)), w_all)
    good = (present.sum(axis=1) >= 3) & (np.nan_to_num(cond) >= WELL_SPREAD)
    frames = np.arange(t)
    prev_c = np.maximum.accumulate(np.where(good, frames, -1))
    next_c = np.minimum.accumulate(np.where(good, frames, t)[::-1])[::-1]
    a, b = prev_c[rows], next_c[rows]
    need = np.unique(np.concatenate([a[a >= 0], b[b < t]]))
    rot_at = np.full((t, 3, 3), np.nan)
    if need.size:
        rot_at[need] = fit_rigid(ref[None], pos[need], weights=w_all[need])[0]
    r_start = np.where((a >= 0)[:, None, None], rot_at[np.maximum(a, 0)], np.nan)
    r_end = np.where((b < t)[:, None, None], rot_at[np.minimum(b, t - 1)], np.nan)
    span = np.where(b > a, b - a, 1)
    u = (rows - a) / span
    axis, _ = line_axis(np.broadcast_to(ref, (rows.size, m, 3)), fit_weights)
    return twist_prior(rot_fit, axis, r_start, r_end, u)


def _em_pca_impute(y: np.ndarray, obs: np.ndarray, variance: float, iterations: int) -> np.ndarray:
    """Missing-data PCA (EM / alternating least squares): fill the unobserved entries
    of y (F, D) by repeated PCA and per-row least-squares fits of the observed entries."""
    mu = np.nanmean(np.where(obs, y, np.nan), axis=0)
    z = np.where(obs, y, mu)
    complete = obs.all(axis=1)
    for _ in range(iterations):
        mu_i, basis, evals, noise = _pca(z, variance)
        if basis.shape[1] == 0:
            break
        part = ~complete
        coef, _ = _pca_solve(basis, evals, noise, z[part] - mu_i, obs[part])
        recon = mu_i + coef @ basis.T
        zp = z[part]
        new = np.where(obs[part], zp, recon)
        change = float(np.abs(new - zp).max()) if new.size else 0.0
        z[part] = new
        if change < 1e-7:
            break
    return z


def fill_local_pca(
    positions: np.ndarray,
    target: np.ndarray,
    neighbours: CSR,
    *,
    weighted: bool = False,
    missing_data: bool = False,
    variance: float = 0.99,
    estimated_centre_weight: float = 0.5,
    anchor_ends: bool = True,
    anchor_window: int = 1,
    rigid_frame: float | None = None,
    frame_prior: float | None = 0.05,
    spread: np.ndarray | None = None,
    progress: Progress | None = None,
) -> np.ndarray:
    """Local-PCA hole filling (Park & Hodgins 2006, §4.3, eqs. 4-5).

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Missing samples to fill.
    neighbours : CSR (offsets (N + 1,), indices (E,))
        Each marker's neighbourhood (one-ring on a dense surface, motion-consistent
        cluster on a sparse set).
    weighted : bool
        Average the group estimates with inverse-predictive-variance weights, and
        ``estimated_centre_weight`` times less for groups whose centre marker is
        missing in that frame (the discussion's first improvement).
    missing_data : bool
        Train each group's PCA with its partial frames too (EM PCA; the discussion's
        second improvement).
    variance : float
        Fraction of the variance each model keeps (the paper: 0.99).
    estimated_centre_weight : float
        See ``weighted``.
    anchor_ends : bool
        Join each gap to its measured ends. For every run of missing frames of a
        marker, the model also estimates the marker in the last measured frame before
        the run and the first measured frame after it, as if it were missing there;
        the offsets ``measured - estimate`` at the two ends, expressed in the marker's
        local frame (the rotation of its own group's eq. 5 fit; world axes when that
        group has no model), are interpolated linearly across the run, turned back
        into world axes frame by frame and added to the estimates. A run at the start
        or end of the take (or whose other end has no estimate) takes the one end's
        offset unchanged. This removes the slow drift the neighbourhood model cannot
        explain and makes the filled trajectory continuous with the measured one.
    anchor_window : int
        Each end's offset is a weighted mean over up to this many measured frames next
        to the gap (as many as are measured in a row; weights falling linearly with
        the distance to the gap). 1 (the default) uses the frame next to the gap
        only. Wider windows damp the measurement noise of a single frame (better on
        the synthetic takes: 3 frames cut the mean error by a sixth) but follow fast
        real motion less closely (worse on the real takes).
    rigid_frame : float, optional
        Fit each group's local frame (training and estimation alike) with its members
        weighted by how rigidly they moved with the others over the take: ``1 /
        (v_j + (rigid_frame * d)²)``, ``v_j`` the mean variance of member ``j``'s
        distances to the other members (over at most about 400 frames sampled
        evenly), ``d`` the group's mean member distance; a member sliding over the
        body then hardly moves the frame. None (default): equal weights, the paper's
        frame.
    frame_prior : float, optional
        Beyond the paper: where a group's present members lie nearly on a line, its
        local frame's twist about the line is left to their small spread off it and
        measurement noise turns it (and the missing members with it). Each
        estimation row's frame is then pulled towards temporal continuity: the
        frames fitted at the nearest frames before and after whose present members
        are well spread, swung onto the row's line, their twist interpolated in time
        (:mod:`~skincap.cleanup.frame_continuity`), as far as the take's
        measurement noise (:func:`~skincap.cleanup.frame_continuity.take_noise`)
        leaves the twist less certain than the prior. The value is the prior's
        twist uncertainty, radians. None: each row's frame from its own members
        alone (the paper).
    spread : (T, N) float array, optional
        With ``anchor_ends``, written in place on the samples of a gap anchored at
        both ends: the distance (metres) between the two end offsets, i.e. between
        the fill anchored at the start alone and the one anchored at the end alone;
        left unchanged elsewhere.
    progress : callable(fraction, label), optional

    Returns
    -------
    (T, N, 3) float64
        A filled copy; targets no group can estimate stay NaN (see :func:`fill_gaps`
        for the rigid fallback).
    """
    p = np.array(positions, dtype=np.float64)
    present = ~np.isnan(p[..., 0])
    gaps, queries = _anchor_queries(present, target, anchor_ends, anchor_window)
    noise = take_noise(p) if frame_prior is not None else 0.0
    sums = _sum_group_estimates(
        p,
        present,
        target,
        neighbours,
        queries,
        variance=variance,
        missing_data=missing_data,
        rigid_frame=rigid_frame,
        frame_prior=frame_prior,
        noise=noise,
        centre_weight=estimated_centre_weight if weighted else None,
        progress=progress,
    )
    done = sums.weight > 0
    p[done] = sums.total[done] / sums.weight[done][:, None]
    if queries.frame.size:
        _anchor_gaps(
            p,
            done,
            gaps,
            (
                queries.end,
                queries.frame,
                queries.weight,
                sums.q_total,
                sums.q_weight,
                sums.q_rot,
            ),
            sums.rot_at,
            sums.sample_id,
            spread,
        )
    return p


def _sum_group_estimates(
    p: np.ndarray,
    present: np.ndarray,
    target: np.ndarray,
    neighbours: CSR,
    queries: _AnchorQueries,
    *,
    variance: float,
    missing_data: bool,
    rigid_frame: float | None,
    frame_prior: float | None,
    noise: float,
    centre_weight: float | None,
    progress: Progress | None,
) -> _Sums:
    """Every group's estimates of its targets and anchor queries, summed with weights:
    1 each, or (``centre_weight`` given) the inverse predictive variance, times
    ``centre_weight`` where the group's centre was itself estimated. Arguments as in
    :func:`fill_local_pca`."""
    t, n, _ = p.shape
    sums = _Sums.empty(target, queries.frame.size)
    groups = _local_groups(target, neighbours)
    for gi, members in enumerate(groups):
        # the anchor queries of this group's members, and their member index
        mine, q_member = _member_queries(members, queries.marker, n)
        res = _group_estimates(
            p[:, members],
            present[:, members],
            target[:, members],
            variance=variance,
            missing_data=missing_data,
            query_frame=queries.frame[mine],
            query_member=q_member,
            member_weights=(
                None
                if rigid_frame is None
                else _member_rigidity(p[:: max(1, t // 400), members], rigid_frame)
            ),
            frame_prior=frame_prior,
            noise=noise,
        )
        if progress is not None:
            progress((gi + 1) / len(groups), "local PCA")
        if res is None:
            continue
        rows, est, var, centre_obs, rot = res
        w = (
            1.0 / var * np.where(centre_obs, 1.0, centre_weight)[:, None]
            if centre_weight is not None
            else np.ones(var.shape)
        )
        sums.add_group(target, members, (rows, est, w, rot), mine, q_member, queries.marker)
    return sums


def _member_queries(
    members: np.ndarray, q_marker: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """The anchor queries (indices into ``q_marker`` (Q,)) on a group's members, and
    each one's member index in the group."""
    where = np.full(n, -1, dtype=np.int64)
    where[members] = np.arange(members.size)
    mine = np.nonzero(where[q_marker] >= 0)[0]
    return mine, where[q_marker[mine]]


class _AnchorQueries(NamedTuple):
    """Measured samples next to each gap's ends, to be estimated as if missing.

    ``end`` (Q,) the end each belongs to (gap index for the before end, G + gap for the
    after end); ``frame`` and ``marker`` (Q,); ``weight`` (Q,) its weight in the end's
    mean, falling linearly with the distance to the gap.
    """

    end: np.ndarray
    frame: np.ndarray
    marker: np.ndarray
    weight: np.ndarray


def _anchor_queries(
    present: np.ndarray, target: np.ndarray, anchor_ends: bool, anchor_window: int
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], _AnchorQueries]:
    """The gaps (runs of missing frames holding a target: marker, start, end (G,)) and
    their anchor queries: up to ``anchor_window`` measured frames in a row next to
    each end. No gaps and no queries without ``anchor_ends``."""
    t = present.shape[0]
    g_marker, g_start, g_len = missing_runs(~present)
    hit = target[g_start, g_marker] if g_marker.size else np.zeros(0, dtype=bool)
    g_marker, g_start, g_end = g_marker[hit], g_start[hit], (g_start + g_len)[hit]
    if not anchor_ends:
        g_marker = g_start = g_end = np.zeros(0, dtype=np.int64)
    g = g_marker.size
    frame = np.arange(t)[:, None]
    last_missing = np.maximum.accumulate(np.where(present, -1, frame), axis=0)
    next_missing = np.minimum.accumulate(np.where(present, t, frame)[::-1], axis=0)[::-1]
    before = np.maximum(g_start - 1, 0)
    after = np.minimum(g_end, t - 1)
    avail = np.concatenate(
        [
            np.where(g_start > 0, before - last_missing[before, g_marker], 0),
            np.where(g_end < t, next_missing[after, g_marker] - after, 0),
        ]
    )  # (2G,) measured frames in a row next to each end
    k = np.arange(max(int(anchor_window), 1))
    q_end = np.repeat(np.arange(2 * g), k.size)
    q_k = np.tile(k, 2 * g)
    q_ok = q_k < avail[q_end]
    q_end, q_k = q_end[q_ok], q_k[q_ok]
    side_after = q_end >= g
    gap_of = np.where(side_after, q_end - g, q_end)
    q_frame = np.where(side_after, g_end[gap_of] + q_k, g_start[gap_of] - 1 - q_k)
    weight = (k.size - q_k).astype(np.float64)
    return (g_marker, g_start, g_end), _AnchorQueries(q_end, q_frame, g_marker[gap_of], weight)


def _local_groups(target: np.ndarray, neighbours: CSR) -> list[np.ndarray]:
    """The groups worth modelling: each marker with its neighbours (centre first), at
    least four members and one of them with a target."""
    offsets, indices = neighbours
    has_target = target.any(axis=0)
    groups = []
    for i in range(target.shape[1]):
        members = np.concatenate([[i], indices[offsets[i] : offsets[i + 1]]])
        if members.size >= 4 and has_target[members].any():
            groups.append(members)
    return groups


@dataclass
class _Sums:
    """The groups' weighted estimates, summed.

    ``total`` (T, N, 3) and ``weight`` (T, N) on the target samples; ``q_total`` (Q, 3),
    ``q_weight`` (Q,) on the anchor queries; ``q_rot`` (Q, 3, 3) the marker's own
    group's local rotation at each query and ``rot_at`` (S, 3, 3) at each target sample
    (its row in ``sample_id`` (T, N), -1 off target); NaN where unknown.
    """

    total: np.ndarray
    weight: np.ndarray
    q_total: np.ndarray
    q_weight: np.ndarray
    q_rot: np.ndarray
    rot_at: np.ndarray
    sample_id: np.ndarray

    @classmethod
    def empty(cls, target: np.ndarray, n_queries: int) -> _Sums:
        t, n = target.shape
        sample_id = np.full((t, n), -1, dtype=np.int64)
        sample_id[target] = np.arange(int(target.sum()))
        return cls(
            total=np.zeros((t, n, 3)),
            weight=np.zeros((t, n)),
            q_total=np.zeros((n_queries, 3)),
            q_weight=np.zeros(n_queries),
            q_rot=np.full((n_queries, 3, 3), np.nan),
            rot_at=np.full((int(target.sum()) if n_queries else 0, 3, 3), np.nan),
            sample_id=sample_id,
        )

    def add_group(
        self,
        target: np.ndarray,
        members: np.ndarray,
        estimates: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        mine: np.ndarray,
        q_member: np.ndarray,
        q_marker: np.ndarray,
    ) -> None:
        """Add one group's estimates (:func:`_group_estimates`' rows, estimates and
        rotations, with weights (F + Q', m)) on the targets and on its queries ``mine``
        (indices into all queries; ``q_member`` their member index)."""
        rows, est, w, rot = estimates
        nq = mine.size
        nr = rows.size - nq
        sel = target[rows[:nr]][:, members] & ~np.isnan(est[:nr, :, 0])  # (F, m)
        fr, mj = np.nonzero(sel)
        tt, nn = rows[fr], members[mj]
        np.add.at(self.total, (tt, nn), est[fr, mj] * w[fr, mj][:, None])
        np.add.at(self.weight, (tt, nn), w[fr, mj])
        if nq:
            qe = est[nr + np.arange(nq), q_member]  # (Q', 3)
            qwt = w[nr + np.arange(nq), q_member]
            good = ~np.isnan(qe[:, 0])
            np.add.at(self.q_total, mine[good], qe[good] * qwt[good, None])
            np.add.at(self.q_weight, mine[good], qwt[good])
            # the centre's own group gives the marker's local frame
            own = q_marker[mine] == members[0]
            self.q_rot[mine[own]] = rot[nr:][own]
            sid = self.sample_id[rows[:nr], members[0]]
            self.rot_at[sid[sid >= 0]] = rot[:nr][sid >= 0]


def _member_rigidity(pos: np.ndarray, floor: float) -> np.ndarray:
    """Weights (m,) for a group's members in its local-frame fit: ``1 / (v_j + (floor
    d)²)``, ``v_j`` the mean over the other members of the variance of their distance
    to member ``j`` over the frames both are seen (pos (F, m, 3) metres, NaN where
    missing), ``d`` the mean member distance; members never seen with another get
    the smallest weight found."""
    diff = pos[:, :, None, :] - pos[:, None, :, :]
    dist = np.sqrt((diff**2).sum(axis=-1))  # (F, m, m), NaN where either is missing
    ok = np.isfinite(dist)
    cnt = ok.sum(axis=0)
    dz = np.where(ok, dist, 0.0)
    mean = dz.sum(axis=0) / np.maximum(cnt, 1)
    var = np.maximum((dz**2).sum(axis=0) / np.maximum(cnt, 1) - mean**2, 0.0)
    m = pos.shape[1]
    pair = (cnt >= 3) & ~np.eye(m, dtype=bool)
    n_pair = pair.sum(axis=1)
    v = np.where(pair, var, 0.0).sum(axis=1) / np.maximum(n_pair, 1)
    d = mean[pair].mean() if pair.any() else 0.0
    w = 1.0 / (v + (floor * d) ** 2 + 1e-18)
    return np.where(n_pair > 0, w, w[n_pair > 0].min() if (n_pair > 0).any() else 1.0)


def fill_local_window(
    positions: np.ndarray,
    target: np.ndarray,
    neighbours: CSR,
    *,
    window: float = 8.0,
    variance: float = 0.99,
    rigid_frame: bool = True,
    rigidity_floor: float = 0.1,
    frame_prior: float | None = 0.05,
    spread: np.ndarray | None = None,
) -> np.ndarray:
    """Own-group local PCA trained around each gap (the ``local_pca_window`` method).

    For each missing run ``[s, e)`` of marker ``i`` (length ``L``) one local-PCA model
    (eqs. 4-5, missing-data PCA) of ``i`` and its neighbours is trained on the frames
    ``[s - window * L, e + window * L)`` only, and only ``i``'s own group estimates
    it (no averaging over the neighbours' groups). The estimate is joined to the
    measured samples at the run's ends: the model re-estimates ``x_i(s - 1)`` and
    ``x_i(e)`` as if missing, and the two offsets (measured - estimate) are
    interpolated linearly across the run. The local frame (the Kabsch fit of the
    group's reference shape, in training and in estimation alike) weighs each member
    by how rigidly it moved with the others in the window (``rigid_frame``), so a
    member sliding over the body does not drag the frame. One loop over runs; all
    frames of a run are solved in one batch.

    Parameters
    ----------
    positions : (T, N, 3) float, metres; NaN where missing
    target : (T, N) bool
        Samples to fill.
    neighbours : CSR (offsets (N + 1,), indices (E,))
    window : float
        Training frames each side of a run, in run lengths (at least 10 frames).
    variance : float
        Fraction of the variance the PCA keeps.
    rigid_frame : bool
        Weigh the members in the local-frame fit by ``1 / (v_j + (rigidity_floor *
        d)²)``, ``v_j`` the mean variance (over the window) of member ``j``'s
        distances to the other members, ``d`` the mean member distance. False:
        equal weights, as the other local methods.
    rigidity_floor : float
        See ``rigid_frame``: distance spread, as a fraction of the mean member
        distance, below which members count as equally rigid. 0.1 measured best
        over 0.001-0.4 on the three real takes' punched gaps (smaller helps
        aml_PronetoRun01 a little and costs cmu_85_02 and kt_optitrack_walking).
    frame_prior : float, optional
        As :func:`fill_local_pca`: the local frame's twist about a near-line of
        present members falls back on temporal continuity; the prior's twist
        uncertainty, radians. None: no prior.
    spread : (T, N) float array, optional
        Written in place on the filled samples of runs anchored at both ends: the
        distance (metres) between the two end offsets, how far the model strays
        across the run; left unchanged elsewhere.

    Returns
    -------
    (T, N, 3) float64 : a filled copy; samples with fewer than three present group
    members (or a group without a model) stay NaN.
    """
    p = np.array(positions, dtype=np.float64)
    t = p.shape[0]
    present = ~np.isnan(p[..., 0])
    offsets, indices = neighbours
    marker, start, length = missing_runs(~present)
    keep = target[start, marker] if marker.size else np.zeros(0, dtype=bool)
    noise = take_noise(p) if frame_prior is not None and keep.any() else 0.0
    for i, s, ln in zip(marker[keep], start[keep], length[keep], strict=True):
        members = np.concatenate([[i], indices[offsets[i] : offsets[i + 1]]])
        if members.size < 4:
            continue
        e = s + ln
        w = max(10, int(round(window * ln)))
        lo, hi = max(0, s - w), min(t, e + w)
        ends = [f for f in (s - 1, e) if 0 <= f < t]
        want = np.zeros((hi - lo, members.size), dtype=bool)
        want[s - lo : e - lo, 0] = target[s:e, i]
        res = _group_estimates(
            p[lo:hi, members],
            present[lo:hi, members],
            want,
            variance=variance,
            missing_data=True,
            query_frame=np.asarray(ends, dtype=np.int64) - lo,
            query_member=np.zeros(len(ends), dtype=np.int64),
            member_weights=(
                _member_rigidity(p[lo:hi, members], rigidity_floor) if rigid_frame else None
            ),
            frame_prior=frame_prior,
            noise=noise,
        )
        if res is None:
            continue
        rows, est, _, _, _ = res
        nr = rows.size - len(ends)
        frames = rows[:nr] + lo
        val = est[:nr, 0]
        ok = (frames >= s) & (frames < e) & ~np.isnan(val[:, 0]) & target[frames, i]
        frames, val = frames[ok], val[ok]
        off = {f: p[f, i] - est[nr + k, 0] for k, f in enumerate(ends)}
        off = {f: o for f, o in off.items() if np.isfinite(o).all()}
        before, after = off.get(s - 1), off.get(e)
        wa = ((frames - s + 1) / (ln + 1.0))[:, None]
        if before is not None and after is not None:
            val = val + (1.0 - wa) * before + wa * after
            if spread is not None:
                spread[frames, i] = np.linalg.norm(after - before)
        elif before is not None or after is not None:
            val = val + (before if before is not None else after)
        p[frames, i] = val
    return p


def _anchor_gaps(
    p: np.ndarray,
    done: np.ndarray,
    gaps: tuple[np.ndarray, np.ndarray, np.ndarray],
    queries: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    rot_at: np.ndarray,
    sample_id: np.ndarray,
    spread: np.ndarray | None = None,
) -> None:
    """Add to each gap's estimates the end offsets (measured - estimate), interpolated
    linearly across the gap in the marker's local frame; in place on p (T, N, 3).

    gaps: (marker, start, end) (G,) each. queries (Q,) each: the end they belong to
    (gap index for the before end, G + gap for the after end), frame, weight in the
    end's mean (falling linearly with the distance to the gap), summed weighted
    estimates (Q, 3), summed weights (Q,), the marker's local rotation (Q, 3, 3) NaN
    where unknown. An end's offset is the weighted mean over its queries. rot_at (S, 3, 3): the
    local rotation of each target sample (its row in sample_id (T, N), -1 off target),
    NaN where unknown; done (T, N): the samples the model estimated. spread (T, N),
    optional: receives |after offset - before offset| on two-sided gap samples.
    """
    g_marker, g_start, g_end = gaps
    q_end, q_frame, q_weight, q_acc, q_w, q_rot = queries
    g = g_marker.size
    est = np.where((q_w > 0)[:, None], q_acc / np.maximum(q_w, 1e-300)[:, None], np.nan)
    marker_of = np.concatenate([g_marker, g_marker])[q_end]
    off = p[q_frame, marker_of] - est  # (Q, 3) world; NaN where unestimated
    q_has = ~np.isnan(q_rot[:, 0, 0])
    rot0 = np.where(q_has[:, None, None], q_rot, 0.0)
    off_l = np.einsum("qji,qj->qi", rot0, np.nan_to_num(off))  # R^T off: local axes
    good = ~np.isnan(off[:, 0])
    # per end: mean world offset over its estimated queries, and mean local offset
    # when every one of them has the marker's local frame
    n_ok = np.bincount(q_end[good], minlength=2 * g)
    n_rot = np.bincount(q_end[good & q_has], minlength=2 * g)
    ok = n_ok > 0
    has_rot = ok & (n_rot == n_ok)
    w_ok = np.bincount(q_end[good], weights=q_weight[good], minlength=2 * g)
    wq = q_weight[good]
    off_w, off_local = (
        np.stack(
            [np.bincount(q_end[good], weights=wq * v[good, c], minlength=2 * g) for c in range(3)],
            1,
        )
        / np.maximum(w_ok, 1e-300)[:, None]
        for v in (np.nan_to_num(off), off_l)
    )
    off = np.where(ok[:, None], off_w, np.nan)
    before_ok, after_ok = ok[:g], ok[g:]
    # one row per (gap, gap frame)
    length = g_end - g_start
    rep = np.repeat(np.arange(g), length)
    first = np.cumsum(length) - length
    frame = g_start[rep] + np.arange(rep.size) - first[rep]
    mk = g_marker[rep]
    sel = done[frame, mk] & (before_ok | after_ok)[rep]
    rep, frame, mk = rep[sel], frame[sel], mk[sel]
    if rep.size == 0:
        return
    # weight of the after end: 0 next to the before end, 1 next to the after end
    w_after = (frame - g_start[rep] + 1) / (length[rep] + 1.0)
    w_after = np.where(before_ok[rep], np.where(after_ok[rep], w_after, 0.0), 1.0)
    rot = rot_at[sample_id[frame, mk]]  # (S, 3, 3); done samples are targets
    # local axes only when the gap frame's rotation and every end used have one
    local = (
        ~np.isnan(rot[:, 0, 0])
        & (~before_ok[rep] | has_rot[rep])
        & (~after_ok[rep] | has_rot[g + rep])
    )
    ob = np.where(
        before_ok[rep][:, None],
        np.nan_to_num(np.where(local[:, None], off_local[rep], off[rep])),
        0.0,
    )
    oa = np.where(
        after_ok[rep][:, None],
        np.nan_to_num(np.where(local[:, None], off_local[g + rep], off[g + rep])),
        0.0,
    )
    o = (1.0 - w_after)[:, None] * ob + w_after[:, None] * oa
    world = np.where(
        local[:, None], np.einsum("sij,sj->si", np.where(local[:, None, None], rot, 0), o), o
    )
    p[frame, mk] += world
    if spread is not None:
        two = before_ok[rep] & after_ok[rep]
        spread[frame[two], mk[two]] = np.linalg.norm(off[rep[two]] - off[g + rep[two]], axis=1)
