"""Near-rigid segmentation of the marker surface (Park & Hodgins 2006, §5.2; James & Twigg 2005).

1. **Rotation sequences.** For every marker-surface triangle and every frame of a
   range-of-motion take, the rotation that carries the triangle's reference frame
   (first edge, normal) onto its frame at that time.
2. **Mean shift.** Triangles are points in the space of their rotation sequences
   (flattened matrices over a subsample of frames, so ``||R_a - R_b||`` averaged over
   time is the distance); a Gaussian mean shift moves each to its mode and triangles
   whose modes meet form a group (James & Twigg's clustering).
3. **Pieces** (the paper's manual step starts here): every group is split into
   pieces connected on the surface, and triangles with no rotation (a corner never
   seen) join the adjacent piece whose rotations they follow best. Each marker takes
   the piece most of its triangles belong to, and the marker groups are split again
   into pieces connected through the surface's edges. The bandwidth is halved while
   there are fewer than :data:`PIECES_PER_PART` times ``n_parts`` of them: the merge
   below needs an over-segmentation to choose from, and at two a part some pieces
   still spanned two true parts (upper chest with chest, abdomen with pelvis).
4. **Merging and seams** (:mod:`.rigid_groups`): adjacent marker groups are merged,
   the pair with the least evidence of moving apart first, until ``n_parts`` remain:
   the geometric mean of how far the pair turns apart at its peak frame (the
   rotation difference of their fits, measured on the smaller group's extent, times
   Ward's size factor: a sliver of jiggling flesh adds residual over the whole take,
   a hand that turns hard for a few frames adds little) and of the residual their
   union adds at its worst frame in units of their markers' own jiggle (two slivers
   of a jiggling upper arm fit poorly apart and together alike, whatever their
   fitted rotations do; a hand fits exactly and its wrist's turn costs many markers'
   worth), discounted by the share of the pair's relative motion that no joint
   between them explains (two slivers of one jiggling mass move apart by the flesh's
   offset, which no fixed pivot absorbs; a hand turns about its wrist). A group with
   fewer than ``min_markers`` markers, too few for a rigid fit,
   merges first by the residual its union adds, whatever the count; then every seam
   marker moves to the adjacent part whose rigid motion
   predicts its trajectory best, judged on the frames where the two parts turn apart
   (soft tissue pulls a part's fit while its joints are still), a few rounds, every
   part kept connected on the marker surface (through its edges) and at
   ``min_markers`` markers or more. Small
   pieces are judged by the rigid residual too, never by their triangles' rotations:
   a hand of three or four markers was absorbed into its forearm by rotation before
   the merge could weigh it (the synthetic range of motion has 3-4 markers a hand).
   Against the true parts (adjusted Rand index, synthetic 240 / 720 / 1000-frame
   ranges of motion, seed 0, procedural body): merging by rotation-sequence means
   0.76 / 0.77 (720 / 1000); rigid merge after rotation absorption 0.815 / 0.891 /
   0.881; rigid merge of every piece 0.765 / 0.940 / 0.944 (seed 7: 0.667 -> 0.774 at
   240 frames, 0.870 -> 0.884 at 720; MakeHuman body: 0.686 -> 0.710 / 0.857 ->
   0.854); seams judged where the parts turn apart 0.865 / 0.952 / 0.942 (seed 7:
   0.792 / 0.867; MakeHuman 0.719 / 0.862). At 240 frames (each joint through its
   range in 0.17 s) the soft-tissue jiggle of the chest and upper arms costs a rigid
   fit as much as a wrist's turn, so by residual or peak turn alone the merge put
   each hand into its forearm and split an upper arm or the chest (hence the jiggle
   scale above); merging by the residual of a shared rotation (each group its
   own translation), by mean rotation distance (with or without Ward's size factor),
   or absorbing parts that are all seam and merging again did no better on the seven
   takes.

5. **Dissolving** (:func:`.rigid_groups.dissolve_parts_to_count`): the merge stops
   :data:`DISSOLVED_PARTS` groups above ``n_parts`` and, after the seams are refined,
   the part cheapest to do without is dissolved, each of its markers going to the
   adjacent part whose rigid motion follows it best, until ``n_parts`` remain (seams
   refined after each). Mean shift cuts some pieces across a seam of jiggling flesh
   (half hip, half thigh); merged whole, such a piece fits neither side, so it
   survived as a part while a true part with few markers (the pelvis, a hand) went
   into its neighbour. Dissolved, its markers go to both sides.

Each triangle takes the part of most of its corners (three parts: the one whose motion
follows its corners best); a marker on triangles of several parts is a boundary marker
(see :mod:`.weights`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from skincap.deform.dense.rigid_groups import (
    compact_labels,
    dissolve_parts_to_count,
    merge_groups_by_rigid_residual,
    surface_edges,
    triangle_parts_from_markers,
)
from skincap.errors import ValidationError

__all__ = [
    "DISSOLVED_PARTS",
    "PIECES_PER_PART",
    "Segmentation",
    "segment_marker_surface",
    "triangle_rotations",
]

#: The merge stops this many groups above ``n_parts``; the last ones are dissolved.
DISSOLVED_PARTS = 3
#: Mean shift narrows until it leaves this many marker groups per wanted part.
PIECES_PER_PART = 3


@dataclass(eq=False)
class Segmentation:
    """Near-rigid parts of a marker surface.

    Attributes
    ----------
    triangle_parts : (F,) int64
        Part of every marker-surface triangle, ``0 … P-1`` (the part of most of its
        corners); -1 when no corner has a part.
    marker_parts : (N,) int64
        Part of every marker; -1 for a marker on no triangle or on a loose piece of the
        surface holding fewer than ``min_markers`` markers. Every part's markers are
        connected through the surface's edges.
    n_parts : int
    mean_shift_groups : int
        Groups mean shift found before the fix-up (the paper's Fig. 5a).
    bandwidth : float
        The mean-shift bandwidth used.
    """

    triangle_parts: np.ndarray
    marker_parts: np.ndarray
    n_parts: int
    mean_shift_groups: int
    bandwidth: float


def _triangle_frames(p: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = p[..., faces[:, 0], :], p[..., faces[:, 1], :], p[..., faces[:, 2], :]
    e1 = b - a
    n = np.cross(e1, c - a)
    e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return np.stack([e1, np.cross(n, e1), n], axis=-1)  # columns: (..., F, 3, 3)


def triangle_rotations(
    positions: np.ndarray, reference: np.ndarray, faces: np.ndarray
) -> np.ndarray:
    """Rotation of every triangle from the reference pose to every frame.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    reference : (N, 3) float, metres
    faces : (F, 3) int, marker indices

    Returns
    -------
    (T, F, 3, 3) float64
        ``R`` with ``frame_t = R @ frame_ref`` (frames built from the first edge and the
        normal); NaN where a corner is missing or the triangle is degenerate.
    """
    f = np.asarray(faces, dtype=np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        ref_frames = _triangle_frames(np.asarray(reference, float), f)  # (F, 3, 3)
        cur = _triangle_frames(np.asarray(positions, float), f)  # (T, F, 3, 3)
    return np.einsum("tfab,fcb->tfac", cur, ref_frames)


def _principal_coordinates(feat: np.ndarray, *, energy: float = 1.0 - 1e-6) -> np.ndarray:
    """The rows of ``feat`` in the principal axes that hold ``energy`` of their spread.

    Mean shift and the merges only use distances between rows and means of rows, which
    live in the span of the centred rows; keeping the axes that hold all but 1e-6 of
    the variance changes a squared distance by at most 1e-6 of the total spread and
    cuts the mean-shift products from (frames x 9) columns to a few dozen.
    """
    centred = feat - feat.mean(axis=0)
    # the eigen-decomposition of the smaller Gram matrix (rows x rows or columns x
    # columns) gives the same coordinates as an SVD of the rows, up to each axis' sign,
    # at a fraction of the cost
    if centred.shape[0] <= centred.shape[1]:
        power, vecs = np.linalg.eigh(centred @ centred.T)  # ascending
        power, vecs = power[::-1].clip(0.0), vecs[:, ::-1]
        coords = vecs * np.sqrt(power)
    else:
        power, vecs = np.linalg.eigh(centred.T @ centred)
        power, vecs = power[::-1].clip(0.0), vecs[:, ::-1]
        coords = centred @ vecs
    share = np.cumsum(power) / max(float(power.sum()), 1e-300)
    k = int(np.searchsorted(share, energy)) + 1
    return coords[:, :k]


def _mean_shift(x: np.ndarray, bandwidth: float, iterations: int = 40) -> np.ndarray:
    """Gaussian mean shift of the rows of ``x``; returns a group id per row."""
    sq = (x * x).sum(1)
    y = x.copy()
    for _ in range(iterations):
        d2 = np.maximum((y * y).sum(1)[:, None] + sq[None, :] - 2.0 * y @ x.T, 0.0)
        w = np.exp(-d2 / (2.0 * bandwidth**2))
        y_new = (w @ x) / w.sum(1, keepdims=True)
        moved = np.sqrt(((y_new - y) ** 2).sum(1)).max()
        y = y_new
        if moved < 1e-4 * bandwidth:
            break
    # modes closer than half a bandwidth are one group (single linkage over modes)
    d2 = np.maximum((y * y).sum(1)[:, None] + (y * y).sum(1)[None, :] - 2.0 * y @ y.T, 0.0)
    close = sparse.csr_matrix(d2 < (0.5 * bandwidth) ** 2)
    return connected_components(close, directed=False)[1]


def _triangle_adjacency(faces: np.ndarray) -> sparse.csr_matrix:
    """(F, F) triangles sharing an edge."""
    n_f = faces.shape[0]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(n_f), 3)
    _, inv = np.unique(edges, axis=0, return_inverse=True)
    inc = sparse.csr_matrix((np.ones(owner.size), (inv.ravel(), owner)), shape=(inv.max() + 1, n_f))
    adj = (inc.T @ inc).tocsr()
    adj.setdiag(0)
    adj.eliminate_zeros()
    return (adj > 0).astype(np.float64).tocsr()


def segment_marker_surface(
    positions: np.ndarray,
    reference: np.ndarray,
    faces: np.ndarray,
    *,
    n_parts: int = 17,
    bandwidth: float = 0.05,
    min_markers: int = 3,
    max_frames: int = 200,
    progress: Callable[[float], None] | None = None,
) -> Segmentation:
    """Split the marker surface into ``n_parts`` connected near-rigid parts, automatically.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
        A range-of-motion take (every major joint moved).
    reference : (N, 3) float, metres
        The reference pose.
    faces : (F, 3) int
        Marker-surface triangles.
    n_parts : int, default 17
        Target number of parts (the paper's 17). Fewer come out only when the surface
        has fewer connected pieces to merge.
    bandwidth : float
        Mean-shift bandwidth in rotation-matrix distance (``||R_a - R_b||_F``, RMS over
        frames; 0.05 is about 2°). Halved (up to four times) while mean shift leaves
        fewer than ``PIECES_PER_PART * n_parts`` marker groups to merge.
    min_markers : int
        Fewest markers a part may hold; smaller groups join the neighbour whose rigid
        motion they follow best.
    max_frames : int
        Frames of the take used (evenly subsampled).
    progress : callable(fraction), optional

    Returns
    -------
    Segmentation
    """
    x = np.asarray(positions, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if x.ndim != 3 or x.shape[2] != 3 or ref.shape != x.shape[1:]:
        raise ValidationError(
            f"positions (T, N, 3) and reference (N, 3) expected; got {x.shape} and {ref.shape}"
        )
    if f.shape[0] < 2 or f.min() < 0 or f.max() >= ref.shape[0]:
        raise ValidationError(
            f"faces: need at least two triangles over the {ref.shape[0]} markers; got {f.shape[0]}"
        )
    if int(n_parts) < 1:
        raise ValidationError(f"n_parts must be at least 1; got {n_parts}")
    n_f = f.shape[0]
    step = max(1, x.shape[0] // int(max_frames))
    rot = triangle_rotations(x[::step], ref, f)  # (T', F, 3, 3)
    if progress:
        progress(0.2)
    feat = rot.transpose(1, 0, 2, 3).reshape(n_f, -1) / np.sqrt(rot.shape[0])
    seen = np.isfinite(feat)
    col_ok = seen.all(axis=0)  # frames every triangle has; others dropped
    good = seen.any(axis=1)
    if col_ok.sum() >= 9:
        feat = np.where(col_ok[None, :], feat, 0.0)[:, col_ok]
    else:  # fill a triangle's unseen frames with the identity, the reference pose
        ident = np.tile(np.eye(3).ravel(), rot.shape[0]) / np.sqrt(rot.shape[0])
        feat = np.where(seen, feat, ident[None, :])
    feat = _principal_coordinates(feat)
    adj = _triangle_adjacency(f)
    edges = surface_edges(f)
    n_markers = ref.shape[0]
    width = float(bandwidth)
    for _ in range(5):  # narrower until the merge has an over-segmentation to choose from
        labels = np.full(n_f, -1)
        labels[good] = _mean_shift(feat[good], width)
        n_groups = int(labels.max()) + 1
        tri_pieces = _surface_pieces(labels, adj, feat)
        groups = _marker_pieces(_marker_majority(f, tri_pieces, n_markers), edges)
        if int(groups.max()) + 1 >= PIECES_PER_PART * int(n_parts):
            break
        width *= 0.5
    if progress:
        progress(0.6)
    x_used = x[::step]
    # every merge weighs each pair's peak turn with how far the pair moves apart beyond
    # the flesh's jiggle (see the module docstring, step 4)
    groups = merge_groups_by_rigid_residual(
        groups,
        edges,
        x_used,
        ref,
        int(n_parts) + DISSOLVED_PARTS,
        min_markers=int(min_markers),
        peak_turn_above=int(n_parts),
        jiggle_scaled=True,
    )
    # the last few are dissolved marker by marker, not merged whole (step 5)
    marker_parts, errors = dissolve_parts_to_count(
        groups, edges, x_used, ref, int(n_parts), min_markers=int(min_markers)
    )
    if progress:
        progress(1.0)
    return Segmentation(
        triangle_parts=triangle_parts_from_markers(f, marker_parts, errors),
        marker_parts=marker_parts,
        n_parts=int(marker_parts.max()) + 1,
        mean_shift_groups=n_groups,
        bandwidth=width,
    )


def _surface_pieces(labels: np.ndarray, adj: sparse.csr_matrix, feat: np.ndarray) -> np.ndarray:
    """(F,) mean-shift groups split into surface-connected pieces, ``0 … G-1``.

    Triangles with no group (no rotation: a corner never seen) join, ring by ring, the
    adjacent piece whose mean rotation sequence they follow best; small pieces stay
    (the rigid merge judges them, :func:`.rigid_groups.merge_groups_by_rigid_residual`).
    """
    rows, cols = adj.nonzero()
    keep = labels >= 0
    inner = (labels[rows] == labels[cols]) & keep[rows]
    same = sparse.csr_matrix((np.ones(inner.sum()), (rows[inner], cols[inner])), shape=adj.shape)
    _, piece = connected_components(same, directed=False)
    return _join_unassigned(compact_labels(np.where(keep, piece, -1)), adj, feat)


def _marker_pieces(groups: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(N,) marker groups split into pieces connected through the surface's ``edges``
    (a majority vote can leave a group in two places), ``0 … G-1``; -1 kept."""
    n = groups.size
    same = (groups[edges[:, 0]] == groups[edges[:, 1]]) & (groups[edges[:, 0]] >= 0)
    graph = sparse.csr_matrix((np.ones(same.sum()), (edges[same, 0], edges[same, 1])), shape=(n, n))
    _, piece = connected_components(graph, directed=False)
    return compact_labels(np.where(groups >= 0, piece, -1))


def _group_means(labels: np.ndarray, feat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n_g = int(labels.max()) + 1
    ok = labels >= 0
    member = sparse.csr_matrix(
        (np.ones(ok.sum()), (labels[ok], np.flatnonzero(ok))), shape=(n_g, feat.shape[0])
    )
    size = np.asarray(member.sum(axis=1)).ravel()
    return (member @ feat) / np.maximum(size, 1)[:, None], size


def _join_unassigned(labels: np.ndarray, adj: sparse.csr_matrix, feat: np.ndarray) -> np.ndarray:
    """Unassigned triangles join, ring by ring, the adjacent group they follow best."""
    labels = labels.copy()
    rows, cols = adj.nonzero()
    while (labels < 0).any() and (labels >= 0).any():  # grows the labelled region by a ring
        means, _ = _group_means(labels, feat)
        sel = (labels[rows] < 0) & (labels[cols] >= 0)
        if not sel.any():
            break
        r, target = rows[sel], labels[cols[sel]]
        cost = ((feat[r] - means[target]) ** 2).sum(1)
        order = np.lexsort((cost, r))
        first = np.ones(order.size, dtype=bool)
        first[1:] = r[order][1:] != r[order][:-1]
        labels[r[order][first]] = target[order][first]
    return compact_labels(labels)


def _marker_majority(faces: np.ndarray, tri_parts: np.ndarray, n_markers: int) -> np.ndarray:
    n_p = max(int(tri_parts.max()) + 1, 1)
    votes = np.zeros((n_markers, n_p))
    on = tri_parts >= 0  # triangles of no part do not vote
    np.add.at(votes, (faces[on].ravel(), np.repeat(tri_parts[on], 3)), 1.0)
    return np.where(votes.sum(1) > 0, np.argmax(votes, axis=1), -1)
