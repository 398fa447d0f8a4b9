"""From camera visibility to what capture software reports: fragments, ghosts, noise.

The steps of :func:`~skincap.synth.cameras.simulate_capture` after visibility, in the
order they draw from the random generator (the order is part of the same-seed,
same-bytes contract):

1. :func:`reconstructed` -- enough cameras, minus flicker of two-camera markers;
2. :func:`confusions` -- close pairs break both trajectories or swap them;
3. :func:`chain_pieces` -- runs of reconstructed frames, linked across swaps;
4. :func:`draw_ghosts` -- short tracks near body markers;
5. :func:`noisy_samples` -- one row per reconstructed point, Gaussian noise added;
6. :func:`fragment_columns` -- order, label and truth of every fragment;
7. :func:`shuffled_point_cloud` -- the un-indexed cloud, random order per frame.

Conventions: metres, frames numbered from 0; ``N_all`` counts body then extra markers.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from skincap.synth.capture_settings import CaptureSettings
from skincap.types import PointCloud

__all__ = [
    "Confusions",
    "Ghosts",
    "Samples",
    "Fragments",
    "close_pair_onsets",
    "reconstructed",
    "confusions",
    "chain_pieces",
    "draw_ghosts",
    "noisy_samples",
    "fragment_columns",
    "shuffled_point_cloud",
]


def close_pair_onsets(
    pos: np.ndarray, seen: np.ndarray, distance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames and marker pairs that come within ``distance`` (not so in the frame before).

    One 4-D KD-tree over all frames (time as a far-apart fourth coordinate), no loop.
    ``pos`` (T, N, 3) metres, ``seen`` (T, N) bool; returns (frame, lower marker index,
    higher marker index), each (K,) int64, sorted by frame then pair.
    """
    t_idx, n_idx = np.nonzero(seen)
    if t_idx.size < 2:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    gap = 10.0 * distance + 1.0
    coords = np.concatenate([pos[t_idx, n_idx], (t_idx * gap)[:, None]], axis=1)
    pairs = cKDTree(coords).query_pairs(distance, output_type="ndarray")
    if pairs.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    t = t_idx[pairs[:, 0]]
    a = np.minimum(n_idx[pairs[:, 0]], n_idx[pairs[:, 1]])
    b = np.maximum(n_idx[pairs[:, 0]], n_idx[pairs[:, 1]])
    n = seen.shape[1]
    key = (t * n + a) * n + b
    prev = ((t - 1) * n + a) * n + b
    onset = ~np.isin(prev, key)
    order = np.argsort(key[onset], kind="stable")
    return t[onset][order], a[onset][order], b[onset][order]


def reconstructed(
    visible: np.ndarray, settings: CaptureSettings, rng: np.random.Generator
) -> np.ndarray:
    """(T, N_all) bool: seen by ``min_cameras`` or more cameras, minus flicker.

    ``visible`` (T, N_all, C) bool. A marker seen by exactly ``min_cameras`` cameras is
    lost with probability ``marginal_dropout``.
    """
    n_cams = visible.sum(axis=2)
    seen = n_cams >= int(settings.min_cameras)
    flicker = (n_cams == int(settings.min_cameras)) & (
        rng.random(seen.shape) < float(settings.marginal_dropout)
    )
    return seen & ~flicker


class Confusions(NamedTuple):
    """Close-pair onsets and what they did to the trajectories.

    ``frame``, ``a``, ``b`` (K,) int64 the onsets; ``swapped`` (S,) indices into them
    of the accepted swaps; ``is_break`` (K,) bool; ``breaks`` (T, N_all) bool where a
    trajectory piece is cut (breaks and both ends of swaps).
    """

    frame: np.ndarray
    a: np.ndarray
    b: np.ndarray
    swapped: np.ndarray
    is_break: np.ndarray
    breaks: np.ndarray


def confusions(
    allpos: np.ndarray, seen: np.ndarray, settings: CaptureSettings, rng: np.random.Generator
) -> Confusions:
    """Pairs coming within ``confusion_distance``: a share breaks, a few swap.

    A swap needs both markers seen in the frame before, and a marker takes part in
    at most one swap per frame. ``allpos`` (T, N_all, 3) metres, ``seen`` (T, N_all).
    """
    swap_rate = float(settings.swap_rate)
    n_all = seen.shape[1]
    ct, ca, cb = close_pair_onsets(allpos, seen, float(settings.confusion_distance))
    u = rng.random(ct.size)
    is_swap = (u < swap_rate) & (ct > 0)
    is_swap &= seen[np.maximum(ct - 1, 0), ca] & seen[np.maximum(ct - 1, 0), cb]
    # one swap per marker and frame
    ends = np.concatenate([ct[is_swap] * n_all + ca[is_swap], ct[is_swap] * n_all + cb[is_swap]])
    _, inv, cnt = np.unique(ends, return_inverse=True, return_counts=True)
    clash = (cnt[inv] > 1).reshape(2, -1).any(axis=0)
    sw = np.nonzero(is_swap)[0][~clash]
    is_break = (u < swap_rate + float(settings.confusion_share) * (1 - swap_rate)) & ~is_swap
    brk = np.zeros(seen.shape, dtype=bool)
    brk[ct[is_break], ca[is_break]] = True
    brk[ct[is_break], cb[is_break]] = True
    brk[ct[sw], ca[sw]] = True
    brk[ct[sw], cb[sw]] = True
    brk &= seen
    return Confusions(ct, ca, cb, sw, is_break, brk)


def chain_pieces(seen: np.ndarray, conf: Confusions) -> tuple[np.ndarray, int, np.ndarray]:
    """Runs of reconstructed frames per marker, cut at breaks, chained across swaps.

    Returns ``piece_of`` (T, N_all) int64 (the piece of each sample, -1 where unseen),
    the number of pieces, and ``chain`` (pieces,) the chain (future fragment) of each
    piece: a swap links a piece's end to the other marker's next piece.
    """
    t_n, n_all = seen.shape
    prev_seen = np.zeros_like(seen)
    prev_seen[1:] = seen[:-1]
    start = seen & (~prev_seen | conf.breaks)
    piece_of = (np.cumsum(start.T.ravel()).reshape(n_all, t_n) - 1).T  # (T, N_all)
    piece_of = np.where(seen, piece_of, -1)
    n_pieces = int(start.sum())
    ct, ca, cb, sw = conf.frame, conf.a, conf.b, conf.swapped
    succ_a = piece_of[ct[sw] - 1, ca[sw]]
    succ_b = piece_of[ct[sw] - 1, cb[sw]]
    nxt_a = piece_of[ct[sw], ca[sw]]
    nxt_b = piece_of[ct[sw], cb[sw]]
    links = sp.coo_matrix(
        (np.ones(2 * sw.size), (np.concatenate([succ_a, succ_b]), np.concatenate([nxt_b, nxt_a]))),
        shape=(n_pieces, n_pieces),
    )
    _, chain = connected_components(links, directed=False)
    return piece_of, n_pieces, chain


class Ghosts(NamedTuple):
    """Ghost tracks: ``start``, ``length``, ``anchor`` (body marker) (G,) int64 and
    ``offset`` (G, 3) metres from the anchor."""

    start: np.ndarray
    length: np.ndarray
    anchor: np.ndarray
    offset: np.ndarray


def draw_ghosts(
    n_frames: int, n_body: int, settings: CaptureSettings, rng: np.random.Generator
) -> Ghosts:
    """Short tracks 1-5 cm from a body marker: Poisson count, geometric lengths."""
    n_ghost = int(rng.poisson(float(settings.ghost_rate) * n_frames)) if n_body else 0
    g_start = rng.integers(0, n_frames, n_ghost)
    g_len = rng.geometric(1.0 / float(settings.ghost_frames), n_ghost)
    g_len = np.minimum(g_len, n_frames - g_start)
    g_anchor = rng.integers(0, max(n_body, 1), n_ghost)
    g_dir = rng.normal(size=(n_ghost, 3))
    g_dir /= np.maximum(np.linalg.norm(g_dir, axis=1, keepdims=True), 1e-12)
    g_off = g_dir * rng.uniform(0.01, 0.05, (n_ghost, 1))
    return Ghosts(g_start, g_len, g_anchor, g_off)


class Samples(NamedTuple):
    """Every reconstructed point, (M,) each: ``frame``; ``truth`` marker index or -1
    (ghost); ``group`` chain id, or ``n_chain + ghost``; ``noisy`` (M, 3) metres."""

    frame: np.ndarray
    truth: np.ndarray
    group: np.ndarray
    noisy: np.ndarray
    n_chain: int


def noisy_samples(
    allpos: np.ndarray,
    n_body: int,
    seen: np.ndarray,
    piece_of: np.ndarray,
    n_pieces: int,
    chain: np.ndarray,
    ghosts: Ghosts,
    noise_mm: float,
    rng: np.random.Generator,
) -> Samples:
    """One row per reconstructed marker sample, then the ghost samples, noise added."""
    st, sn = np.nonzero(seen)
    s_chain = chain[piece_of[st, sn]]
    n_chain = int(chain.max()) + 1 if n_pieces else 0
    gk = np.arange(ghosts.length.size).repeat(ghosts.length)
    first = np.cumsum(ghosts.length) - ghosts.length
    gi = np.arange(gk.size) - first[gk]
    gt = ghosts.start[gk] + gi
    sample_t = np.concatenate([st, gt])
    sample_truth = np.concatenate([sn, np.full(gt.size, -1)])
    sample_group = np.concatenate([s_chain, n_chain + gk])
    ghost_xyz = allpos[gt, ghosts.anchor[gk]] + ghosts.offset[gk] if n_body else np.zeros((0, 3))
    true_xyz = np.concatenate([allpos[st, sn], ghost_xyz])
    noisy = true_xyz + rng.normal(scale=float(noise_mm) / 1000.0, size=true_xyz.shape)
    return Samples(sample_t, sample_truth, sample_group, noisy, n_chain)


class Fragments(NamedTuple):
    """Columns of the capture: ``column`` (groups,) the column of each group;
    ``labels`` per column; ``majority`` (columns,) truth index or -1 (ghost);
    ``labelled`` (columns,) bool; ``n_columns``."""

    column: np.ndarray
    labels: list[str]
    majority: np.ndarray
    labelled: np.ndarray
    n_columns: int


def fragment_columns(
    samples: Samples, n_ghost: int, n_frames: int, n_all: int, body_labels: list[str]
) -> Fragments:
    """Order fragments by first frame then first truth; label and attribute them.

    Frame-0 body fragments keep their marker's label, every other one is ``*<k>``;
    each fragment maps to the marker of most of its samples (ghosts: -1).
    """
    n_b = len(body_labels)
    n_chain = samples.n_chain
    n_group = n_chain + n_ghost
    g_first = np.full(n_group, n_frames, dtype=np.int64)
    np.minimum.at(g_first, samples.group, samples.frame)
    first_truth = np.full(n_group, -1, dtype=np.int64)
    at_first = samples.frame == g_first[samples.group]
    first_truth[samples.group[at_first]] = samples.truth[at_first]
    order = np.lexsort((np.arange(n_group), first_truth, g_first))
    column = np.empty(n_group, dtype=np.int64)
    column[order] = np.arange(n_group)
    s_col = column[samples.group]
    # majority truth per fragment (ghost groups: -1)
    is_ghost_group = np.zeros(n_group, dtype=bool)
    is_ghost_group[n_chain:] = True
    body = samples.truth >= 0
    votes = sp.coo_matrix(
        (np.ones(int(body.sum())), (s_col[body], samples.truth[body])), shape=(n_group, n_all)
    ).tocsr()
    votes.sum_duplicates()
    majority = np.asarray(votes.argmax(axis=1)).ravel() if n_all else np.zeros(n_group, int)
    majority = np.where(is_ghost_group[order], -1, majority)
    col_first = g_first[order]
    col_first_truth = first_truth[order]
    labelled = (col_first == 0) & (col_first_truth >= 0) & (col_first_truth < n_b)
    col_labels: list[str] = []
    k = 0
    for c in range(n_group):  # string building only
        if labelled[c]:
            col_labels.append(body_labels[col_first_truth[c]])
        else:
            k += 1
            col_labels.append(f"*{k}")
    return Fragments(column, col_labels, majority, labelled, n_group)


def shuffled_point_cloud(
    samples: Samples,
    sample_column: np.ndarray,
    column_labels: list[str],
    n_frames: int,
    rate: float,
    rng: np.random.Generator,
) -> tuple[PointCloud, np.ndarray]:
    """The samples frame by frame, in a random order within each frame.

    Returns the cloud (``ids`` are fragment columns) and the truth index of each of
    its points (M,) int64, -1 for ghosts.
    """
    shuffle = rng.random(samples.frame.size)
    p_order = np.lexsort((shuffle, samples.frame))
    counts = np.bincount(samples.frame, minlength=n_frames)
    points = PointCloud(
        points=samples.noisy[p_order],
        offsets=np.concatenate([[0], np.cumsum(counts)]),
        rate=rate,
        ids=sample_column[p_order],
        meta={"id_labels": column_labels, "up": "Y", "source_units": "m"},
    )
    return points, samples.truth[p_order]
