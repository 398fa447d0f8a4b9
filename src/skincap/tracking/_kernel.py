"""numba kernel of :func:`skincap.tracking.tracker.track_rope` (numba is a core dependency).

The same per-frame algorithm as the NumPy reference in :mod:`skincap.tracking.tracker`,
step for step, compiled as one loop over frames: the KD-tree queries become a
brute-force k-nearest search over the frame's few hundred points, the conflicts are
resolved by the same shortest-augmenting-path assignment as
:func:`scipy.optimize.linear_sum_assignment` (Crouse 2016, ported with its
tie-breaking), and the leave-one-out curve is evaluated directly. It takes the same
points and invents the same markers as the reference; invented positions agree to
rounding (the order of a few additions differs).

Importing this module imports numba; :func:`track_frames` compiles on its first call
(about a minute of one core; cached on disk, loaded in about a second afterwards).
``track_rope(backend="auto")`` never waits for it: it runs the NumPy reference while
:func:`skincap.tracking.tracker.warm_up_kernel` compiles the kernel in a background process (:mod:`skincap.backends`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["track_frames"]

_INF = np.inf

_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


@numba.njit(**_JIT)
def _query(points, a, b, q, kk, bound, d_out, i_out):  # pragma: no cover - runs compiled
    """kk nearest of points[a:b] to q strictly within ``bound``, ascending; inf beyond."""
    bound2 = bound * bound
    for c in range(kk):
        d_out[c] = _INF
        i_out[c] = b  # cKDTree's "missing" index (n), made global below
    n_found = 0
    for p in range(a, b):
        dx = q[0] - points[p, 0]
        dy = q[1] - points[p, 1]
        dz = q[2] - points[p, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > bound2 * (1.0 + 1e-9):
            continue
        d = np.sqrt(d2)
        if not d < bound:
            continue
        if n_found == kk and d >= d_out[kk - 1]:
            continue
        pos = n_found if n_found < kk else kk - 1
        while pos > 0 and d_out[pos - 1] > d:
            d_out[pos] = d_out[pos - 1]
            i_out[pos] = i_out[pos - 1]
            pos -= 1
        d_out[pos] = d
        i_out[pos] = p
        if n_found < kk:
            n_found += 1


@numba.njit(**_JIT)
def _augmenting_path(nc, cost, u, v, path, row4col, spc, i, sr, sc, remaining):  # pragma: no cover
    min_val = 0.0
    num_remaining = nc
    for it in range(nc):
        remaining[it] = nc - it - 1
    sr[:] = False
    sc[:] = False
    spc[:] = _INF
    sink = -1
    while sink == -1:
        index = -1
        lowest = _INF
        sr[i] = True
        for it in range(num_remaining):
            j = remaining[it]
            r = min_val + cost[i, j] - u[i] - v[j]
            if r < spc[j]:
                path[j] = i
                spc[j] = r
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest = spc[j]
                index = it
        min_val = lowest
        if min_val == _INF:
            return -1, min_val
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
        sc[j] = True
        num_remaining -= 1
        remaining[index] = remaining[num_remaining]
    return sink, min_val


@numba.njit(**_JIT)
def _lsa(cost_in):  # pragma: no cover - runs compiled
    """(rows, cols) of the minimum-cost assignment, as scipy's linear_sum_assignment."""
    nr0, nc0 = cost_in.shape
    transpose = nc0 < nr0
    cost = cost_in.T.copy() if transpose else cost_in
    nr, nc = cost.shape
    u = np.zeros(nr)
    v = np.zeros(nc)
    spc = np.full(nc, _INF)
    path = np.full(nc, -1, np.int64)
    col4row = np.full(nr, -1, np.int64)
    row4col = np.full(nc, -1, np.int64)
    sr = np.zeros(nr, np.bool_)
    sc = np.zeros(nc, np.bool_)
    remaining = np.zeros(nc, np.int64)
    for cur_row in range(nr):
        sink, min_val = _augmenting_path(
            nc, cost, u, v, path, row4col, spc, cur_row, sr, sc, remaining
        )
        if sink < 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        u[cur_row] += min_val
        for i in range(nr):
            if sr[i] and i != cur_row:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if sc[j]:
                v[j] -= min_val - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            tmp = col4row[i]
            col4row[i] = j
            j = tmp
            if i == cur_row:
                break
    a = np.empty(nr, np.int64)
    b = np.empty(nr, np.int64)
    if transpose:
        order = np.argsort(col4row)
        for k in range(nr):
            a[k] = col4row[order[k]]
            b[k] = order[k]
    else:
        for k in range(nr):
            a[k] = k
            b[k] = col4row[k]
    return a, b


@numba.njit(**_JIT)
def _gated_assignment(dist, cand, gate):  # pragma: no cover - runs compiled
    """As :func:`skincap.tracking.init.gated_assignment`: (rows, points) one-to-one."""
    r_n, k_n = dist.shape
    any_ok = False
    n_first = 0
    n_any = 0
    for r in range(r_n):
        row_ok = False
        for c in range(k_n):
            if dist[r, c] < gate:
                row_ok = True
        if row_ok:
            n_any += 1
            any_ok = True
        if dist[r, 0] < gate:
            n_first += 1
    if not any_ok:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # fast path: every row's nearest candidate is free of conflicts
    distinct = True
    for r in range(r_n):
        if not dist[r, 0] < gate:
            continue
        for r2 in range(r + 1, r_n):
            if dist[r2, 0] < gate and cand[r2, 0] == cand[r, 0]:
                distinct = False
    if distinct and n_first == n_any:
        rows = np.empty(n_first, np.int64)
        pts = np.empty(n_first, np.int64)
        n = 0
        for r in range(r_n):
            if dist[r, 0] < gate:
                rows[n] = r
                pts[n] = cand[r, 0]
                n += 1
        return rows, pts
    # unique rows and unique points (sorted), as np.unique in the reference
    rows_u = np.empty(n_any, np.int64)
    n = 0
    all_pts = np.empty(r_n * k_n, np.int64)
    n_p = 0
    for r in range(r_n):
        row_ok = False
        for c in range(k_n):
            if dist[r, c] < gate:
                row_ok = True
                all_pts[n_p] = cand[r, c]
                n_p += 1
        if row_ok:
            rows_u[n] = r
            n += 1
    pts_u = np.unique(all_pts[:n_p])
    big = 1e6 * max(gate, 1.0)
    cost = np.full((n_any, pts_u.size), big)
    for ri in range(n_any):
        r = rows_u[ri]
        for c in range(k_n):
            if dist[r, c] < gate:
                col = np.searchsorted(pts_u, cand[r, c])
                cost[ri, col] = dist[r, c]
    ri, ci = _lsa(cost)
    keep = 0
    for k in range(ri.size):
        if cost[ri[k], ci[k]] < gate:
            keep += 1
    rows = np.empty(keep, np.int64)
    pts = np.empty(keep, np.int64)
    n = 0
    for k in range(ri.size):
        if cost[ri[k], ci[k]] < gate:
            rows[n] = rows_u[ri[k]]
            pts[n] = pts_u[ci[k]]
            n += 1
    return rows, pts


@numba.njit(**_JIT)
def _norm3(x, y, z):  # pragma: no cover - runs compiled
    return np.sqrt(x * x + y * y + z * z)


@numba.njit(**_JIT)
def _is_taken(p, known, taken):  # pragma: no cover - runs compiled
    for j in range(known.size):
        if known[j] and taken[j] == p:
            return True
    return False


@numba.njit(**_JIT)
def _follows_other(points, pa, pb, prev_taken, p, pred, last, gamma):  # pragma: no cover
    """As the reference ``_follows_other``: ``p`` lies within ``min(γ, D - γ)`` of a
    point of the previous frame that the rope did not take (``D = |pred - last|``)."""
    dx, dy, dz = pred[0] - last[0], pred[1] - last[1], pred[2] - last[2]
    lim = min(gamma, _norm3(dx, dy, dz) - gamma)
    if lim <= 0.0:
        return False
    lim2 = lim * lim
    for q in range(pa, pb):
        ex = p[0] - points[q, 0]
        ey = p[1] - points[q, 1]
        ez = p[2] - points[q, 2]
        if ex * ex + ey * ey + ez * ez < lim2:
            mine = False
            for j in range(prev_taken.size):
                if prev_taken[j] == q:
                    mine = True
            if not mine:
                return True
    return False


@numba.njit(**_JIT)
def _body_chains(points, pa, a, b, body, body_vel, rope_pred, n_rope, eps):  # pragma: no cover
    """As the reference ``_body_chains``: flag frame [a, b)'s points continuing the body
    points of frame [pa, a) (``body``/``body_vel`` are global, written in place)."""
    eps2 = eps * eps
    nq = a - pa
    q_count = np.zeros(nq, np.int64)
    p_q = np.full(b - a, -1, np.int64)
    p_count = np.zeros(b - a, np.int64)
    # the previous body points' predictions sorted by x: only those within eps in x
    n_body = 0
    for q in range(pa, a):
        if body[q]:
            n_body += 1
    qs = np.empty(n_body, np.int64)
    n_body = 0
    for q in range(pa, a):
        if body[q]:
            qs[n_body] = q
            n_body += 1
    px = np.empty(n_body)
    for r in range(n_body):
        px[r] = points[qs[r], 0] + body_vel[qs[r], 0]
    order = np.argsort(px)
    xs = px[order]
    for p in range(a, b):
        body[p] = False
        for c in range(3):
            body_vel[p, c] = 0.0
        lo = np.searchsorted(xs, points[p, 0] - eps)
        hi = np.searchsorted(xs, points[p, 0] + eps, side="right")
        for r in range(lo, hi):
            q = qs[order[r]]
            ex = points[p, 0] - (points[q, 0] + body_vel[q, 0])
            ey = points[p, 1] - (points[q, 1] + body_vel[q, 1])
            ez = points[p, 2] - (points[q, 2] + body_vel[q, 2])
            if ex * ex + ey * ey + ez * ez < eps2:
                p_count[p - a] += 1
                q_count[q - pa] += 1
                p_q[p - a] = q
    for p in range(a, b):
        if p_count[p - a] != 1 or q_count[p_q[p - a] - pa] != 1:
            continue
        near_rope = False
        for r in range(n_rope):
            ex = points[p, 0] - rope_pred[r, 0]
            ey = points[p, 1] - rope_pred[r, 1]
            ez = points[p, 2] - rope_pred[r, 2]
            if ex * ex + ey * ey + ez * ez < eps2:
                near_rope = True
        if near_rope:
            continue
        q = p_q[p - a]
        body[p] = True
        for c in range(3):
            body_vel[p, c] = points[p, c] - points[q, c]


@numba.njit(**_JIT)
def _rope_taken_at(point_index, f, q):  # pragma: no cover - runs compiled
    """True when a trace took the point q in frame f."""
    for j in range(point_index.shape[1]):
        if point_index[f, j] == q:
            return True
    return False


@numba.njit(**_JIT)
def _rigid_with_body(points, offsets, point_index, t, j, p, taken, rig):  # pragma: no cover
    """As the reference ``_rigid_with_body``; ``rig`` = (spacing, window, radius, range,
    partners, adjacent-link allowance, least move) as floats."""
    spacing = rig[0]
    window = int(rig[1])
    tol = rig[3] * spacing
    if t < window:
        return False
    traj = np.empty((window + 1, 3))
    traj[window] = points[p]
    whole = j >= 0
    if whole:
        for f in range(t - window, t):
            if point_index[f, j] < 0:
                whole = False
                break
    if whole:
        for f in range(t - window, t):
            traj[f - t + window] = points[point_index[f, j]]
    else:
        vx = 0.0
        vy = 0.0
        vz = 0.0
        for f in range(t - 1, t - window - 1, -1):
            fa, fb = offsets[f], offsets[f + 1]
            if fb - fa < 2:
                return False
            r = f - t + window
            qx = traj[r + 1, 0] - vx
            qy = traj[r + 1, 1] - vy
            qz = traj[r + 1, 2] - vz
            d1 = _INF
            d2 = _INF
            n1 = -1
            for q in range(fa, fb):
                dd = _norm3(points[q, 0] - qx, points[q, 1] - qy, points[q, 2] - qz)
                if dd < d1:
                    d2 = d1
                    d1 = dd
                    n1 = q
                elif dd < d2:
                    d2 = dd
            if not (d1 < 2.0 * tol and d2 > 2.0 * d1):
                return False
            traj[r] = points[n1]
            vx = traj[r + 1, 0] - traj[r, 0]
            vy = traj[r + 1, 1] - traj[r, 1]
            vz = traj[r + 1, 2] - traj[r, 2]
    far = 0.0
    for r in range(window):
        dd = _norm3(
            traj[r, 0] - traj[window, 0], traj[r, 1] - traj[window, 1], traj[r, 2] - traj[window, 2]
        )
        far = max(far, dd)
    if far < rig[6] * spacing:
        return False
    a, b = offsets[t], offsets[t + 1]
    found = 0
    m = taken.size
    for c in range(a, b):
        if c == p:
            continue
        dq = _norm3(
            points[c, 0] - traj[window, 0],
            points[c, 1] - traj[window, 1],
            points[c, 2] - traj[window, 2],
        )
        if not dq < rig[2] * spacing:
            continue
        mine = False
        for jj in range(m):
            if taken[jj] == c:
                mine = True
        if mine:
            continue
        qx = points[c, 0]
        qy = points[c, 1]
        qz = points[c, 2]
        ok = True
        for f in range(t - 1, t - window - 1, -1):
            fa, fb = offsets[f], offsets[f + 1]
            if fb == fa:
                ok = False
                break
            r = f - t + window
            px = qx + traj[r, 0] - traj[r + 1, 0]
            py = qy + traj[r, 1] - traj[r + 1, 1]
            pz = qz + traj[r, 2] - traj[r + 1, 2]
            best = _INF
            n = fa
            for q in range(fa, fb):
                dd = _norm3(points[q, 0] - px, points[q, 1] - py, points[q, 2] - pz)
                if dd < best and not _rope_taken_at(point_index, f, q):
                    best = dd
                    n = q
            qx = points[n, 0]
            qy = points[n, 1]
            qz = points[n, 2]
            to_p = _norm3(qx - traj[r, 0], qy - traj[r, 1], qz - traj[r, 2])
            if not (best < tol and abs(to_p - dq) < tol):
                ok = False
                break
        if ok:
            found += 1
            if found >= rig[4]:
                return True
    return False


@numba.njit(**_JIT)
def _match(
    points,
    a,
    b,
    rows,
    pred,
    k,
    gamma,
    cur,
    known,
    taken,
    gate,
    spacing,
    use_spacing,
    pa,
    pb,
    prev_taken,
    prev,
    steady,
    follow,
    body,
    slow,
    offsets,
    point_index,
    t,
    rig,
):  # pragma: no cover
    """As the reference ``_match``: rows to free points of the frame within the gate
    (``rig`` as :func:`_rigid_with_body`; ``t`` < 0 skips the rigidity test)."""
    r_n = rows.size
    if r_n == 0:
        return False
    m = known.size
    n_taken = 0
    for j in range(m):
        if known[j]:
            n_taken += 1
    kk = min(k + n_taken, b - a)
    d = np.empty((r_n, kk))
    ii = np.empty((r_n, kk), np.int64)
    for r in range(r_n):
        _query(points, a, b, pred[rows[r]], kk, gate, d[r], ii[r])
    if n_taken:
        for r in range(r_n):
            for c in range(kk):
                if d[r, c] < _INF and _is_taken(ii[r, c], known, taken):
                    d[r, c] = _INF
    for r in range(r_n):
        if steady[rows[r]]:
            continue
        for c in range(kk):
            if d[r, c] < _INF and body[ii[r, c]]:
                d[r, c] = _INF
    if slow and gate > gamma:
        for r in range(r_n):
            row = rows[r]
            if not steady[row]:
                continue
            ex = pred[row, 0] - prev[row, 0]
            ey = pred[row, 1] - prev[row, 1]
            ez = pred[row, 2] - prev[row, 2]
            if ex * ex + ey * ey + ez * ez <= gamma * gamma:
                for c in range(kk):
                    if d[r, c] >= gamma:
                        d[r, c] = _INF
    if follow:
        for r in range(r_n):
            row = rows[r]
            for c in range(kk):
                if (
                    (not steady[row] or 0 < row < m - 1)
                    and d[r, c] < _INF
                    and _follows_other(
                        points, pa, pb, prev_taken, points[ii[r, c]], pred[row], prev[row], gamma
                    )
                ):
                    d[r, c] = _INF
    if t >= 0:
        for r in range(r_n):
            if steady[rows[r]]:
                continue
            for c in range(kk):
                if d[r, c] < gate and _rigid_with_body(
                    points, offsets, point_index, t, -1, ii[r, c], taken, rig
                ):
                    d[r, c] = _INF
    if use_spacing:
        for r in range(r_n):
            row = rows[r]
            has_lo = row > 0 and known[row - 1]
            has_hi = row < m - 1 and known[row + 1]
            for c in range(kk):
                if d[r, c] == _INF:
                    continue
                if not has_lo and not has_hi and d[r, c] >= gamma:
                    d[r, c] = _INF
                    continue
                p = ii[r, c]
                for step in (-1, 1):
                    nb = row + step
                    if nb < 0 or nb >= m or not known[nb]:
                        continue
                    rest = spacing[min(min(row, nb), m - 2)]
                    chord = _norm3(
                        points[p, 0] - cur[nb, 0],
                        points[p, 1] - cur[nb, 1],
                        points[p, 2] - cur[nb, 2],
                    )
                    if abs(chord - rest) > gamma:
                        d[r, c] = _INF
    hit_rows, pts = _gated_assignment(d, ii, gate)
    if hit_rows.size == 0:
        return False
    for h in range(hit_rows.size):
        row = rows[hit_rows[h]]
        known[row] = True
        taken[row] = pts[h]
        cur[row] = points[pts[h]]
    return True


@numba.njit(**_JIT)
def _reject_overstretched(
    cur, known, taken, s, gamma, stretch, points, offsets, point_index, t, rig
):  # pragma: no cover
    """As the reference: keep the largest chain of measured markers obeying the rope's
    length, markers on points moving rigidly with body points counting against it."""
    m = known.size
    adj = rig[5]
    n = 0
    for j in range(m):
        if known[j]:
            n += 1
    if n < 2:
        return
    idx = np.empty(n, np.int64)
    n = 0
    for j in range(m):
        if known[j]:
            idx[n] = j
            n += 1
    ok = True
    for q in range(n - 1):
        a, b = idx[q], idx[q + 1]
        chord = _norm3(cur[b, 0] - cur[a, 0], cur[b, 1] - cur[a, 1], cur[b, 2] - cur[a, 2])
        lim = s[b] - s[a] + adj * gamma if b - a == 1 else stretch * (s[b] - s[a]) + gamma
        if not chord <= lim:
            ok = False
            break
    if ok:
        return
    w = np.ones(n)
    for q in range(n):
        if _rigid_with_body(points, offsets, point_index, t, idx[q], taken[idx[q]], taken, rig):
            w[q] = -1.0
    score = w.copy()
    back = np.full(n, -1, np.int64)
    for b in range(1, n):
        best = -_INF
        best_a = 0
        for a in range(b):
            ja, jb = idx[a], idx[b]
            ds = s[jb] - s[ja]
            dist = _norm3(cur[ja, 0] - cur[jb, 0], cur[ja, 1] - cur[jb, 1], cur[ja, 2] - cur[jb, 2])
            lim = ds + adj * gamma if jb - ja == 1 else stretch * ds + gamma
            if dist <= lim:
                dev = (ds - dist) / (ds if ds > 0 else 1.0)
                squeeze = min(max(dev, 0.0), 1.0) + min(max(-dev, 0.0), 1.0)
                gain = w[b] - 0.5 * squeeze
            else:
                gain = -_INF
            cand = score[a] + gain
            if cand > best:
                best = cand
                best_a = a
        if best > score[b]:
            score[b] = best
            back[b] = best_a
    keep = np.zeros(n, np.bool_)
    b = int(np.argmax(score))
    while b >= 0:
        keep[b] = True
        b = back[b]
    for q in range(n):
        if not keep[q]:
            known[idx[q]] = False
            taken[idx[q]] = -1


@numba.njit(**_JIT)
def _reject_odd_motion(cur, prev, known, taken, limit, steady):  # pragma: no cover - runs compiled
    """As the reference: refuse an inner marker that does not move with its neighbours."""
    m = known.size
    odd = np.zeros(m, np.bool_)
    for j in range(1, m - 1):
        if not (known[j] and known[j - 1] and known[j + 1]):
            continue
        if not steady[j]:
            continue
        e = np.empty(3)
        for c in range(3):
            e[c] = (cur[j, c] - prev[j, c]) - 0.5 * (
                (cur[j - 1, c] - prev[j - 1, c]) + (cur[j + 1, c] - prev[j + 1, c])
            )
        if _norm3(e[0], e[1], e[2]) > limit:
            odd[j] = True
    for j in range(m):
        if odd[j]:
            known[j] = False
            taken[j] = -1


@numba.njit(**_JIT)
def _side(known):  # pragma: no cover - runs compiled
    """Nearest known index strictly before (-1) and strictly after (M) each marker."""
    m = known.size
    before = np.empty(m, np.int64)
    after = np.empty(m, np.int64)
    last = -1
    for j in range(m):
        before[j] = last
        if known[j]:
            last = j
    nxt = m
    for j in range(m - 1, -1, -1):
        after[j] = nxt
        if known[j]:
            nxt = j
    return before, after


@numba.njit(**_JIT)
def _interp_along(known, values, s):  # pragma: no cover - runs compiled
    m = known.size
    before, after = _side(known)
    out = np.zeros((m, 3))
    for j in range(m):
        if known[j]:
            out[j] = values[j]
            continue
        hb, ha = before[j] >= 0, after[j] < m
        if not (hb or ha):
            continue
        b = min(max(before[j], 0), m - 1)
        a = min(max(after[j], 0), m - 1)
        if hb and ha:
            w = (s[j] - s[b]) / (s[a] - s[b])
        else:
            w = 0.0 if hb else 1.0
        for c in range(3):
            out[j, c] = (1.0 - w) * values[b, c] + w * values[a, c]
    return out


@numba.njit(**_JIT)
def _slope(x0, x1, x2, s0, s1, s2, out):  # pragma: no cover - runs compiled
    h0 = s1 - s0
    h1 = s2 - s1
    for c in range(3):
        d0 = (x1[c] - x0[c]) / (h0 if h0 > 0 else 1.0)
        d1 = (x2[c] - x1[c]) / (h1 if h1 > 0 else 1.0)
        if h0 > 0 and h1 > 0:
            out[c] = (d0 * h1 + d1 * h0) / (h0 + h1)
        elif h0 > 0:
            out[c] = d0
        else:
            out[c] = d1


@numba.njit(**_JIT)
def _curve_at(x, known, s, j, a, b, before, after, out):  # pragma: no cover - runs compiled
    """Hermite curve between known markers a < j < b at s_j (as fill_interior_on_curve)."""
    m = known.size
    pa = a
    if a > 0:
        pa = before[a] if not known[a - 1] else a - 1
        if pa < 0:
            pa = a
    nb = b
    if b < m - 1:
        nb = after[b] if not known[b + 1] else b + 1
        if nb >= m:
            nb = b
    ta = np.empty(3)
    tb = np.empty(3)
    _slope(x[pa], x[a], x[b], s[pa], s[a], s[b], ta)
    _slope(x[a], x[b], x[nb], s[a], s[b], s[nb], tb)
    h = s[b] - s[a]
    u = (s[j] - s[a]) / h
    u2 = u * u
    u3 = u * u * u
    h00 = 2 * u3 - 3 * u2 + 1
    h10 = u3 - 2 * u2 + u
    h01 = -2 * u3 + 3 * u2
    h11 = u3 - u2
    for c in range(3):
        out[c] = h00 * x[a, c] + h10 * h * ta[c] + h01 * x[b, c] + h11 * h * tb[c]


@numba.njit(**_JIT)
def _fill_interior(x, known, s, out):  # pragma: no cover - runs compiled
    """out = x with interior unknown markers on the curve; returns the interior mask."""
    m = known.size
    before, after = _side(known)
    interior = np.zeros(m, np.bool_)
    out[:] = x
    for j in range(m):
        if known[j] or before[j] < 0 or after[j] >= m:
            continue
        interior[j] = True
        _curve_at(x, known, s, j, before[j], after[j], before, after, out[j])
    return interior


@numba.njit(**_JIT)
def _settle(out, known, spacing, weight):  # pragma: no cover - runs compiled
    """As curve.settle_single_gaps on one frame, in place on ``out`` (M, 3)."""
    m = known.size
    if weight == 0.0:
        return
    for j in range(1, m - 1):
        if known[j] or not (known[j - 1] and known[j + 1]):
            continue
        l1 = spacing[j - 1]
        l2 = spacing[j]
        d = out[j + 1] - out[j - 1]
        c = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if not c > 0:
            continue
        u = d / c
        along = (c * c + l1 * l1 - l2 * l2) / (2.0 * c)
        r2 = l1 * l1 - along * along
        centre = out[j - 1] + along * u
        off = out[j] - centre
        off = off - (off[0] * u[0] + off[1] * u[1] + off[2] * u[2]) * u
        on = np.sqrt(off[0] * off[0] + off[1] * off[1] + off[2] * off[2])
        if not (r2 > 0 and on > 1e-12):
            continue
        scale = ((1.0 - weight) * on + weight * np.sqrt(r2)) / on
        out[j] = centre + scale * off


@numba.njit(**_JIT)
def _neighbour_velocity(known, velocity, fallback):  # pragma: no cover - runs compiled
    m = known.size
    before, after = _side(known)
    out = np.empty((m, 3))
    for j in range(m):
        hb, ha = before[j] >= 0, after[j] < m
        if not (hb or ha):
            out[j] = fallback[j]
            continue
        if hb and ha:
            n_b = float(j - before[j])
            n_a = float(after[j] - j)
            beta = n_a / (n_a + n_b)
        else:
            beta = 1.0 if hb else 0.0
        vb = velocity[min(max(before[j], 0), m - 1)]
        va = velocity[min(max(after[j], 0), m - 1)]
        for c in range(3):
            out[j, c] = beta * vb[c] + (1.0 - beta) * va[c]
    return out


@numba.njit(**_JIT)
def _zipper(cur, known, spacing, inner, quad, ends):  # pragma: no cover - runs compiled
    """As the reference ``_zipper_predictions``: (rows, (M, 3) predictions)."""
    m = known.size
    pred = np.zeros((m, 3))
    want = np.zeros(m, np.bool_)
    if m < 4:
        return np.nonzero(want)[0], pred
    before, after = _side(known)
    for j in range(m):
        if known[j]:
            continue
        if j == 0 or j == m - 1:
            if not ends:
                continue
        elif inner and (before[j] < 0 or after[j] >= m):
            continue
        for step in (-1, 1):
            j1, j2, j3 = j + step, j + 2 * step, j + 3 * step
            if not (0 <= j2 < m and known[j1] and known[j2]):
                continue
            jo = j - step
            if 0 <= jo < m and known[jo]:
                continue
            third = quad and 0 <= j3 < m and known[j3]
            e = np.empty(3)
            for c in range(3):
                if third:
                    e[c] = 3.0 * cur[j1, c] - 3.0 * cur[j2, c] + cur[j3, c]
                else:
                    e[c] = 2.0 * cur[j1, c] - cur[j2, c]
                e[c] -= cur[j1, c]
            norm = _norm3(e[0], e[1], e[2])
            if norm > 0:
                rest = spacing[min(j, j1)]
                for c in range(3):
                    pred[j, c] = cur[j1, c] + (rest / norm) * e[c]
                want[j] = True
    return np.nonzero(want)[0], pred


@numba.njit(**_JIT)
def _predict_end(cur, prev, v_tilde, temp_count, spacing, j, step):  # pragma: no cover
    m = cur.shape[0]
    j1, j2, j3 = j + step, j + 2 * step, j + 3 * step
    v_pred = prev[j] + v_tilde[j]
    l1 = spacing[min(j, j1)]
    if 0 <= j2 < m:
        far = j3 if 0 <= j3 < m else j2
        d = (cur[j1] - cur[far]) / 2.0
        norm = _norm3(d[0], d[1], d[2])
        n_pred = cur[j1] + l1 * d / norm if norm > 0 else v_pred
    else:
        n_pred = v_pred
    alpha = 1.0 / temp_count[j]
    f = alpha * v_pred + (1.0 - alpha) * n_pred
    r = f - cur[j1]
    rn = _norm3(r[0], r[1], r[2])
    cur[j] = cur[j1] + l1 * r / rn if rn > 0 else f


@numba.njit(**_JIT)
def _predict_ends(cur, known, prev, v_tilde, temp_count, spacing):  # pragma: no cover
    m = known.size
    first = -1
    last = -1
    for j in range(m):
        if known[j]:
            if first < 0:
                first = j
            last = j
    for j in range(first - 1, -1, -1):
        _predict_end(cur, prev, v_tilde, temp_count, spacing, j, 1)
    for j in range(last + 1, m):
        _predict_end(cur, prev, v_tilde, temp_count, spacing, j, -1)


@numba.njit(**_JIT)
def _check_on_curve(points, a, b, k, gamma, s, cur, known, taken):  # pragma: no cover
    """As the reference ``_check_on_curve``: move a trace off a body point onto the curve."""
    m = known.size
    before, after = _side(known)
    n_rows = 0
    for j in range(m):
        if known[j] and before[j] >= 0 and after[j] < m:
            n_rows += 1
    if n_rows == 0:
        return False
    x = np.zeros((m, 3))
    for j in range(m):
        if known[j]:
            x[j] = cur[j]
    rows = np.empty(n_rows, np.int64)
    c_all = np.empty((n_rows, 3))
    dev_all = np.empty(n_rows)
    n_odd = 0
    for j in range(m):
        if not (known[j] and before[j] >= 0 and after[j] < m):
            continue
        # the curve through every other measured marker, at s_j (marker j lies
        # outside the markers pa, a, b, nb that define it)
        c = np.empty(3)
        _curve_at(x, known, s, j, before[j], after[j], before, after, c)
        dev = _norm3(cur[j, 0] - c[0], cur[j, 1] - c[1], cur[j, 2] - c[2])
        if dev > 2.0 * gamma:
            rows[n_odd] = j
            c_all[n_odd] = c
            dev_all[n_odd] = dev
            n_odd += 1
    if n_odd == 0:
        return False
    n_taken = 0
    for j in range(m):
        if known[j]:
            n_taken += 1
    kk = min(k + n_taken, b - a)
    d = np.empty((n_odd, kk))
    ii = np.empty((n_odd, kk), np.int64)
    for r in range(n_odd):
        _query(points, a, b, c_all[r], kk, gamma, d[r], ii[r])
        for c in range(kk):
            if _is_taken(ii[r, c], known, taken) or d[r, c] > dev_all[r] - gamma:
                d[r, c] = _INF
    hit_rows, pts = _gated_assignment(d, ii, gamma)
    for h in range(hit_rows.size):
        row = rows[hit_rows[h]]
        taken[row] = pts[h]
        cur[row] = points[pts[h]]
    return hit_rows.size > 0


@numba.njit(**_JIT)
def track_frames(
    t0,
    t1,
    points,
    offsets,
    gamma,
    spacing,
    s,
    max_temp,
    stretch,
    n_cand,
    rounds,
    wide,
    follow,
    positions,
    invented,
    point_index,
    lost_frames,
    velocity,
    temp_count,
    chain,
    body,
    body_vel,
    zip_rounds,
    zip_inner,
    zip_quad,
    slow,
    rig,
    zip_ends,
    settle,
):  # pragma: no cover - runs compiled
    """Track frames ``t0 … t1 - 1`` (t0 >= 1), updating the output arrays and the state
    (``velocity``, ``temp_count``, the body chains ``body``/``body_vel`` over all
    points) in place, as the NumPy loop of ``track_rope``."""
    m = temp_count.size
    for t in range(t0, t1):
        prev = positions[t - 1]
        cur = np.zeros((m, 3))
        known = np.zeros(m, np.bool_)
        taken = np.full(m, -1, np.int64)
        a, b = offsets[t], offsets[t + 1]
        k = min(n_cand, b - a)
        v_pred = prev + velocity
        rope_pred = np.empty((m, 3))
        n_rope = 0
        for j in range(m):
            if point_index[t - 1, j] >= 0:
                rope_pred[n_rope] = v_pred[j]
                n_rope += 1
        _body_chains(points, offsets[t - 1], a, b, body, body_vel, rope_pred, n_rope, chain * gamma)
        active = temp_count == 0
        if k > 0:
            _match(
                points,
                a,
                b,
                np.nonzero(active)[0],
                v_pred,
                k,
                gamma,
                cur,
                known,
                taken,
                gamma,
                spacing,
                False,
                offsets[t - 1],
                a,
                point_index[t - 1],
                prev,
                active,
                follow,
                body,
                slow,
                offsets,
                point_index,
                -1,
                rig,
            )
            _reject_overstretched(
                cur, known, taken, s, gamma, stretch, points, offsets, point_index, t, rig
            )
            _reject_odd_motion(cur, prev, known, taken, gamma, active)
            tried = v_pred.copy()
            for _ in range(rounds):
                found = known & active
                want = active & ~known
                if not (found.any() and want.any()):
                    break
                resid = np.zeros((m, 3))
                for j in range(m):
                    if found[j]:
                        resid[j] = cur[j] - v_pred[j]
                pred = v_pred + _interp_along(found, resid, s)
                for j in range(m):
                    if want[j]:
                        e = pred[j] - tried[j]
                        if not (e[0] * e[0] + e[1] * e[1] + e[2] * e[2] > (0.5 * gamma) ** 2):
                            want[j] = False
                if not want.any():
                    break
                if not _match(
                    points,
                    a,
                    b,
                    np.nonzero(want)[0],
                    pred,
                    k,
                    gamma,
                    cur,
                    known,
                    taken,
                    wide * gamma,
                    spacing,
                    True,
                    offsets[t - 1],
                    a,
                    point_index[t - 1],
                    prev,
                    active,
                    follow,
                    body,
                    slow,
                    offsets,
                    point_index,
                    t,
                    rig,
                ):
                    break
                _reject_overstretched(
                    cur, known, taken, s, gamma, stretch, points, offsets, point_index, t, rig
                )
                _reject_odd_motion(cur, prev, known, taken, gamma, active)
                for j in range(m):
                    if want[j]:
                        tried[j] = pred[j]
        new_count = np.empty(m, np.int64)
        for j in range(m):
            new_count[j] = 0 if known[j] else temp_count[j] + 1
        pred = prev + velocity
        found_more = False
        if not known.all():
            meas_vel = np.zeros((m, 3))
            for j in range(m):
                if known[j]:
                    meas_vel[j] = cur[j] - prev[j]
            v_tilde = _neighbour_velocity(known, meas_vel, velocity)
            if known.any():
                x = np.zeros((m, 3))
                for j in range(m):
                    if known[j]:
                        x[j] = cur[j]
                _fill_interior(x, known, s, pred)
                _settle(pred, known, spacing, settle)
                _predict_ends(pred, known, prev, v_tilde, new_count, spacing)
            if k > 0:
                found_more = _match(
                    points,
                    a,
                    b,
                    np.nonzero(~known)[0],
                    pred,
                    k,
                    gamma,
                    cur,
                    known,
                    taken,
                    wide * gamma,
                    spacing,
                    True,
                    offsets[t - 1],
                    a,
                    point_index[t - 1],
                    prev,
                    active,
                    follow,
                    body,
                    slow,
                    offsets,
                    point_index,
                    t,
                    rig,
                )
                _reject_overstretched(
                    cur, known, taken, s, gamma, stretch, points, offsets, point_index, t, rig
                )
                _reject_odd_motion(cur, prev, known, taken, gamma, active)
                for _ in range(zip_rounds):
                    rows, zpred = _zipper(cur, known, spacing, zip_inner, zip_quad, zip_ends)
                    if rows.size == 0 or not _match(
                        points,
                        a,
                        b,
                        rows,
                        zpred,
                        k,
                        gamma,
                        cur,
                        known,
                        taken,
                        wide * gamma,
                        spacing,
                        True,
                        offsets[t - 1],
                        a,
                        point_index[t - 1],
                        prev,
                        active,
                        follow,
                        body,
                        slow,
                        offsets,
                        point_index,
                        t,
                        rig,
                    ):
                        break
                    found_more = True
                    _reject_overstretched(
                        cur, known, taken, s, gamma, stretch, points, offsets, point_index, t, rig
                    )
                    _reject_odd_motion(cur, prev, known, taken, gamma, active)
        swapped = False
        if k > 0 and known.sum() >= 3:
            swapped = _check_on_curve(points, a, b, k, gamma, s, cur, known, taken)
        if not known.all():
            if known.any() and (found_more or swapped):
                x = np.zeros((m, 3))
                for j in range(m):
                    if known[j]:
                        x[j] = cur[j]
                refit = np.empty((m, 3))
                interior = _fill_interior(x, known, s, refit)
                _settle(refit, known, spacing, settle)
                for j in range(m):
                    if not known[j]:
                        cur[j] = refit[j] if interior[j] else pred[j]
            else:
                for j in range(m):
                    if not known[j]:
                        cur[j] = pred[j]
        for j in range(m):
            temp_count[j] = 0 if known[j] else temp_count[j] + 1
            invented[t, j] = not known[j]
            lost_frames[t, j] = temp_count[j] > max_temp
            point_index[t, j] = taken[j]
            positions[t, j] = cur[j]
            velocity[j] = cur[j] - prev[j]
