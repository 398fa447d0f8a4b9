"""Local part reference frames (Park & Hodgins 2006, §5.3).

Each near-rigid part has an origin (the mean reference position of its member markers)
and three axes (the eigenvectors of their covariance); a marker's *local part
reference position* is its reference position in that frame. The dilation σ of the
part's RBF is twice the largest nearest-member distance (eq. 7).

The members of part ``p`` are the markers with ``α[i, p] > 0`` (inside markers and the
boundary markers assigned to it); they are stored padded to the largest part, so every
later step is one array operation over frames, parts and members.
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
        Marker columns of each part's members, padded with 0 (see ``valid``).
    valid : (P, K) bool
        False on padding.
    member_weights : (P, K) float64
        α of each member for its part (0 on padding).
    origin : (P, 3) float64, metres
        Mean reference position of the members (``-d̃⁰``).
    axes : (P, 3, 3) float64
        Rows are the covariance eigenvectors, largest first, right-handed (``R̃⁰``):
        ``local = axes @ (x - origin)``.
    local_reference : (P, K, 3) float64, metres
        ``p̂⁰``: members' reference positions in their part's frame (0 on padding).
    sigma : (P,) float64, metres
        RBF dilation σ_p (NaN for a part with fewer than two members).
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


def part_frames(reference: np.ndarray, marker_weights: np.ndarray) -> PartFrames:
    """Build the local part reference frames from the reference pose and the weights α.

    Parameters
    ----------
    reference : (N, 3) float, metres
        Marker positions in the reference pose; a member must be finite.
    marker_weights : (N, P) float
        α: weight of every marker for every part (rows sum to 1; 0 = not a member).

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
    n_parts, k = alpha.shape[1], int(counts.max())
    # padded member table: for part p the markers i with alpha[i, p] > 0, in column order
    part_of, marker_of = np.nonzero(member.T)  # sorted by part, then marker
    slot = np.arange(part_of.size) - np.searchsorted(part_of, part_of)
    members = np.zeros((n_parts, k), dtype=np.int64)
    valid = np.zeros((n_parts, k), dtype=bool)
    members[part_of, slot] = marker_of
    valid[part_of, slot] = True
    weights = np.where(valid, alpha[members, np.arange(n_parts)[:, None]], 0.0)

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
        [dilation_from_spacing(local[p, valid[p]]) for p in range(n_parts)]
    )  # one KD-tree per part: P is small (17)
    return PartFrames(members, valid, weights, origin, axes, local, sigma)
