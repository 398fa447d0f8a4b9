"""Local part reference frames (Park & Hodgins 2006, §5.3).

Each near-rigid part has an origin (the mean reference position of its member markers)
and three axes (the eigenvectors of their covariance); a marker's *local part
reference position* is its reference position in that frame. The dilation σ of the
part's RBF is twice the largest nearest-member distance (eq. 7).

The members of part ``p`` are the markers with ``α[i, p] > 0`` (inside markers and the
boundary markers assigned to it); they are stored padded to the largest part, so every
later step is one array operation over frames, parts and members.

**Seam centres.** Given the marker-surface triangles, a part also carries the markers
one surface edge away from its members, with weight 0: they take no part in its rigid
and quadratic fits but are centres of a second RBF residual (eq. 7) of the part, which
passes through the measured surface on the far side of its seam as well. Without them
a vertex on a seam triangle blends parts whose fields each know only their own side's
markers, and the blend there is no better than the rigid blend of the parts' motions
(the β-interpolation error, up to 3 cm at the front of a shoulder). Inside a part the
members alone describe the skin, and the seam centres' pull would only disturb it (a
rigid head wobbled by 1 mm), so the deformer blends the two fields per vertex
(:func:`skincap.deform.dense.weights.seam_vertex_weights`: the seam field on the seam
triangles, the members' field inside). On the synthetic jumprope take (240 frames,
ROM 240 frames, 5000 vertices) the vertex RMS of ``rigid_rbf`` goes from 2.62 to
2.26 mm and of ``quadratic_rbf`` from 2.83 to 2.57 mm (flex 2.24 -> 2.04, punch 2.53 ->
2.33); σ stays the paper's, from the members alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.rbf import dilation_from_spacing

__all__ = ["PartFrames", "part_frames"]


@dataclass(eq=False)
class PartFrames:
    """The static, reference-pose description of the parts.

    Attributes
    ----------
    members : (P, K) int64
        Marker columns of each part's members, padded with 0 (see ``valid``): the
        fitted members (α > 0) first, then the part's seam centres (α = 0).
    valid : (P, K) bool
        False on padding; True slots are the first ones of each row.
    member_weights : (P, K) float64
        α of each member for its part (0 on padding and on seam centres, which the
        rigid and quadratic fits leave out).
    origin : (P, 3) float64, metres
        Mean reference position of the members (``-d̃⁰``).
    axes : (P, 3, 3) float64
        Rows are the covariance eigenvectors, largest first, right-handed (``R̃⁰``):
        ``local = axes @ (x - origin)``.
    local_reference : (P, K, 3) float64, metres
        ``p̂⁰``: members' reference positions in their part's frame (0 on padding).
    sigma : (P,) float64, metres
        RBF dilation σ_p from the fitted members (NaN for a part with fewer than two).
    """

    members: np.ndarray
    valid: np.ndarray
    member_weights: np.ndarray
    origin: np.ndarray
    axes: np.ndarray
    local_reference: np.ndarray
    sigma: np.ndarray

    @property
    def n_parts(self) -> int:
        return int(self.members.shape[0])

    @property
    def has_seam_centres(self) -> bool:
        return bool((self.valid & (self.member_weights <= 0)).any())

    @property
    def fitted(self) -> np.ndarray:
        """(P, K) bool: the members the rigid and quadratic fits use (α > 0)."""
        return self.valid & (self.member_weights > 0)

    def to_local(self, points: np.ndarray, part: np.ndarray) -> np.ndarray:
        """Reference-pose positions in the frame of a part.

        Parameters
        ----------
        points : (M, 3) float, metres
        part : (M,) int, the part of each point

        Returns
        -------
        (M, 3) float64, metres
        """
        p = np.asarray(part, dtype=np.int64)
        return np.einsum("mab,mb->ma", self.axes[p], np.asarray(points, float) - self.origin[p])


def part_frames(
    reference: np.ndarray,
    marker_weights: np.ndarray,
    *,
    surface_faces: np.ndarray | None = None,
) -> PartFrames:
    """Build the local part reference frames from the reference pose and the weights α.

    Parameters
    ----------
    reference : (N, 3) float, metres
        Marker positions in the reference pose; a member must be finite.
    marker_weights : (N, P) float
        α: weight of every marker for every part (rows sum to 1; 0 = not a member).
    surface_faces : (F, 3) int, optional
        Marker-surface triangles (marker columns). With them every part also gets its
        seam centres: the markers (with a finite reference position) one edge away
        from its members, RBF centres only (see the module notes). Without, none.

    Returns
    -------
    PartFrames

    Raises
    ------
    ValidationError
        Shapes, a member with no reference position, or a part with no member.
    """
    ref = np.asarray(reference, dtype=np.float64)
    alpha = np.asarray(marker_weights, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 3:
        raise ValidationError(f"reference must have shape (N, 3); got {ref.shape}")
    if alpha.ndim != 2 or alpha.shape[0] != ref.shape[0]:
        raise ValidationError(
            f"marker_weights must have shape ({ref.shape[0]}, P); got {alpha.shape}"
        )
    if not np.isfinite(alpha).all() or (alpha < 0).any():
        raise ValidationError("marker_weights must be finite and non-negative")
    member = alpha > 0  # (N, P)
    counts = member.sum(axis=0)
    if (counts == 0).any():
        empty = np.flatnonzero(counts == 0).tolist()
        raise ValidationError(f"marker_weights: parts {empty} have no member marker")
    bad = member.any(axis=1) & ~np.isfinite(ref).all(axis=1)
    if bad.any():
        raise ValidationError(
            f"reference: member markers {np.flatnonzero(bad)[:10].tolist()} have no reference position"
        )
    n_parts = alpha.shape[1]
    seam = _seam_centres(member, np.asarray(np.isfinite(ref).all(axis=1)), surface_faces)
    k = int((counts + seam.sum(axis=0)).max())
    # padded member table: for part p the markers i with alpha[i, p] > 0, in column
    # order, then its seam centres
    part_of, marker_of = np.nonzero((member | seam).T)  # sorted by part, then marker
    order = np.lexsort((marker_of, ~member[marker_of, part_of], part_of))  # members first
    part_of, marker_of = part_of[order], marker_of[order]
    slot = np.arange(part_of.size) - np.searchsorted(part_of, part_of)
    members = np.zeros((n_parts, k), dtype=np.int64)
    valid = np.zeros((n_parts, k), dtype=bool)
    members[part_of, slot] = marker_of
    valid[part_of, slot] = True
    weights = np.where(valid, alpha[members, np.arange(n_parts)[:, None]], 0.0)
    fitted = weights > 0

    pos = np.where(valid[..., None], ref[members], 0.0)  # (P, K, 3)
    total = weights.sum(axis=1)  # (P,)
    origin = np.einsum("pk,pkx->px", weights, pos) / total[:, None]
    centred = np.where(valid[..., None], pos - origin[:, None], 0.0)
    cov = np.einsum("pk,pka,pkb->pab", weights, centred, centred) / total[:, None, None]
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues, vectors in columns
    axes = np.swapaxes(vecs[..., ::-1], -1, -2)  # rows, largest first
    flip = np.linalg.det(axes) < 0
    axes[flip, 2] *= -1.0
    local = np.where(valid[..., None], np.einsum("pab,pkb->pka", axes, centred), 0.0)
    sigma = np.array(
        [dilation_from_spacing(local[p, fitted[p]]) for p in range(n_parts)]
    )  # one KD-tree per part: P is small (17)
    return PartFrames(members, valid, weights, origin, axes, local, sigma)


def _seam_centres(
    member: np.ndarray, usable: np.ndarray, surface_faces: np.ndarray | None
) -> np.ndarray:
    """(N, P) bool: markers one marker-surface edge from a member of a part, not members.

    ``member`` (N, P) bool; ``usable`` (N,) bool, markers with a reference position;
    ``surface_faces`` (F, 3) int or None (then no seam centre).
    """
    if surface_faces is None:
        return np.zeros_like(member)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    n = member.shape[0]
    if f.size and (f.min() < 0 or f.max() >= n):
        raise ValidationError(f"surface_faces: indices must be in 0..{n - 1}")
    near = np.zeros_like(member)
    for a, b in ((0, 1), (1, 2), (2, 0), (1, 0), (2, 1), (0, 2)):  # both ways of each edge
        np.logical_or.at(near, f[:, a], member[f[:, b]])
    return near & ~member & usable[:, None]
