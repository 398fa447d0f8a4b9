"""Key ellipses fitted to a skinned mesh's limbs, automatically (Hyun et al. §3.2).

The paper places one key ellipse at each joint and more along each link, each fitted by
hand to a cross-section of the model. Here every key is fitted to the rest mesh:

- the section plane at an interior joint bisects its two links (its normal is the sum
  of their unit directions), at the chain's first joint it is orthogonal to the first
  link and at its last joint to the last link; ``n_between`` more planes are
  orthogonal to each link at equal steps along it;
- the section is the slab of vertices within ``h`` of the plane (``h`` a fraction of
  the link's length, widened until it holds enough vertices) among the vertices the
  skin weights give to this limb, so a plane that also cuts the torso or the other
  leg does not catch it; vertices farther from the section's median radius than
  ``outlier`` times it are dropped;
- the ellipse: centre at the section's centroid (projected into the plane), axes the
  eigenvectors of the in-plane covariance, half-axes ``sqrt(2 lambda)`` (exact for
  points spread evenly round an ellipse). Among the four frames describing one
  ellipse (turns by 90 degrees about the normal, swapping the half-axes), the one
  closest to the previous key's is kept, so the sweep does not spin between keys.

All sections of a limb are fitted at once (arrays of shape (K, n)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincap.deform.sweep.chains import LimbChain, subtree
from skincap.errors import ValidationError
from skincap.geometry.sweep import KeyEllipses, frames_from_axes
from skincap.types import Mesh

__all__ = ["LimbSweep", "fit_limb", "key_layout"]

#: Fewest vertices a section must hold for its ellipse to be fitted.
MIN_SECTION = 8


@dataclass(frozen=True, eq=False)
class LimbSweep:
    """A limb's rest sweep and how each key ellipse is carried by the skeleton.

    Attributes
    ----------
    chain : LimbChain
    keys : KeyEllipses
        K rest key ellipses, metres; parameters by chord length in ``[0, 1]``.
    joint_pos : (m, 3) float64
        Rest (bind-pose) positions of the chain's m joints, metres.
    pivot : (K,) int64
        Chain position (0..m-1) of the joint a key turns about: the joint itself for a
        joint key, the link's first joint for a key along a link.
    frac : (K,) float64
        Fraction of the link's length from its first joint (0 < frac < 1) for keys
        along a link; -1 for joint keys.
    """

    chain: LimbChain
    keys: KeyEllipses
    joint_pos: np.ndarray
    pivot: np.ndarray
    frac: np.ndarray

    @property
    def is_joint(self) -> np.ndarray:
        """(K,) bool: keys sitting at a joint."""
        return self.frac < 0


def key_layout(n_joints: int, n_between: int) -> tuple[np.ndarray, np.ndarray]:
    """Pivots (K,) and fractions (K,) of the keys of a chain of ``n_joints`` joints.

    Joint keys have fraction -1; ``n_between`` keys per link at ``(i + 1) / (n_between + 1)``.
    """
    pivot: list[int] = []
    frac: list[float] = []
    for i in range(n_joints):
        pivot.append(i)
        frac.append(-1.0)
        if i < n_joints - 1:
            for s in range(n_between):
                pivot.append(i)
                frac.append((s + 1) / (n_between + 1))
    return np.array(pivot, dtype=np.int64), np.array(frac)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _section_planes(
    pos: np.ndarray, pivot: np.ndarray, frac: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (K, 3), unit normals (K, 3) and link lengths (K,) of the section planes."""
    link = np.diff(pos, axis=0)  # (m-1, 3)
    length = np.linalg.norm(link, axis=1)
    if (length <= 1e-6).any():
        raise ValidationError("chain: two consecutive joints coincide in the bind pose")
    d = link / length[:, None]
    m = pos.shape[0]
    joint_normal = np.empty((m, 3))
    joint_normal[0] = d[0]
    joint_normal[-1] = d[-1]
    joint_normal[1:-1] = _unit(d[:-1] + d[1:])
    joint_len = np.concatenate([[length[0]], 0.5 * (length[:-1] + length[1:]), [length[-1]]])
    is_joint = frac < 0
    li = np.minimum(pivot, m - 2)
    points = np.where(
        is_joint[:, None], pos[pivot], pos[li] + np.clip(frac, 0.0, 1.0)[:, None] * link[li]
    )
    normals = np.where(is_joint[:, None], joint_normal[pivot], d[li])
    lengths = np.where(is_joint, joint_len[pivot], length[li])
    if (np.abs(joint_normal).sum(axis=1) < 1e-9).any():
        raise ValidationError(
            "chain: a joint folds its links back onto each other in the bind pose"
        )
    return points, normals, lengths


def _plane_bases(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    u = _unit(np.cross(normals, helper))
    return u, np.cross(normals, u)


def _moments(
    u: np.ndarray, v: np.ndarray, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Counts (K,), means (K, 2) and covariances (K, 2, 2) of the masked in-plane points."""
    w = mask.astype(np.float64)
    n = w.sum(axis=1)
    nn = np.maximum(n, 1.0)
    mu = np.stack([(w * u).sum(1), (w * v).sum(1)], axis=1) / nn[:, None]
    du = u - mu[:, :1]
    dv = v - mu[:, 1:]
    cov = np.empty((u.shape[0], 2, 2))
    cov[:, 0, 0] = (w * du * du).sum(1) / nn
    cov[:, 1, 1] = (w * dv * dv).sum(1) / nn
    cov[:, 0, 1] = cov[:, 1, 0] = (w * du * dv).sum(1) / nn
    return n, mu, cov


def _consistent_frames(frames: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn each key's frame by a multiple of 90 degrees about its normal to follow the previous."""
    out_f, out_r = frames.copy(), radii.copy()
    for k in range(1, frames.shape[0]):  # a loop over K keys, each chosen from the last
        prev = out_f[k - 1]
        ea, eb, n = frames[k, :, 0], frames[k, :, 1], frames[k, :, 2]
        options = [
            (np.stack([ea, eb, n], 1), radii[k]),
            (np.stack([eb, -ea, n], 1), radii[k, ::-1]),
            (np.stack([-ea, -eb, n], 1), radii[k]),
            (np.stack([-eb, ea, n], 1), radii[k, ::-1]),
        ]
        score = [float(np.sum(f[:, :2] * prev[:, :2])) for f, _ in options]
        best = int(np.argmax(score))
        out_f[k], out_r[k] = options[best]
    return out_f, out_r


def fit_limb(
    mesh: Mesh,
    chain: LimbChain,
    *,
    n_between: int = 3,
    slab: float = 0.04,
    outlier: float = 2.5,
) -> LimbSweep:
    """Fit the key ellipses of one limb to a skinned rest mesh.

    Parameters
    ----------
    mesh : Mesh
        With a :class:`~skincap.types.Skin`; vertices (V, 3) metres in the bind pose.
    chain : LimbChain
        The limb's joints (see :func:`~skincap.deform.sweep.chains.limb_chains`).
    n_between : int, default 3
        Key ellipses along each link between its joints' keys.
    slab : float, default 0.04
        Half-thickness of a section slab as a fraction of its link's length (doubled,
        up to three times, until it holds :data:`MIN_SECTION` vertices).
    outlier : float, default 2.5
        Section vertices farther from the section's centroid than this many times
        the median distance are left out of the fit.

    Returns
    -------
    LimbSweep

    Raises
    ------
    ValidationError
        A section holds too few of the limb's vertices (the mesh does not cover the
        limb where the skeleton puts it), or the joints coincide.
    """
    if mesh.skin is None:
        raise ValidationError("mesh: has no skin (bind it to a skeleton first)")
    if int(n_between) < 0:
        raise ValidationError(f"n_between: expected >= 0, got {n_between!r}")
    skin = mesh.skin
    names = skin.skeleton.names
    pos = skin.bind_matrices[chain.joints, :3, 3]
    pivot, frac = key_layout(chain.joints.size, int(n_between))
    points, normals, lengths = _section_planes(pos, pivot, frac)
    limb_w = (skin.joint_weights * chain.bones[skin.joint_indices]).sum(axis=1)
    end = subtree(skin.skeleton.parents, int(chain.joints[-1]))
    end_w = (skin.joint_weights * end[skin.joint_indices]).sum(axis=1)
    cand = (limb_w >= 0.5) | (end_w + limb_w >= 0.5)
    idx = np.nonzero(cand)[0]
    x = mesh.vertices[idx]  # (n, 3)
    on_limb = limb_w[idx] >= 0.5
    # the last key's section may hold the hand's or the foot's vertices too
    allowed = np.where((np.arange(pivot.size) == pivot.size - 1)[:, None], True, on_limb[None])
    rel = x[None] - points[:, None]  # (K, n, 3)
    dist = np.einsum("knj,kj->kn", rel, normals)
    bu, bv = _plane_bases(normals)
    u = np.einsum("knj,kj->kn", rel, bu)
    v = np.einsum("knj,kj->kn", rel, bv)
    reach = np.hypot(u, v) <= np.max(lengths)
    h = slab * lengths
    for _ in range(4):
        mask = allowed & reach & (np.abs(dist) <= h[:, None])
        count = mask.sum(axis=1)
        if (count >= MIN_SECTION).all():
            break
        h = np.where(count < MIN_SECTION, 2.0 * h, h)
    else:
        k = int(np.argmin(count))
        j = chain.joints[pivot[k]]
        where = "at" if frac[k] < 0 else f"{frac[k]:.2f} of the way down from"
        raise ValidationError(
            f"mesh: cannot fit the {chain.name} sweep: its section {where} joint "
            f"'{names[j]}' holds {int(count[k])} of the limb's vertices (need {MIN_SECTION}); "
            "is the mesh around this skeleton?"
        )
    _, mu, _ = _moments(u, v, mask)
    r = np.hypot(u - mu[:, :1], v - mu[:, 1:])
    med = np.nanmedian(np.where(mask, r, np.nan), axis=1)
    mask &= r <= outlier * med[:, None]
    n, mu, cov = _moments(u, v, mask)
    if (n < 3).any():  # pragma: no cover - the median keeps at least half the section
        raise ValidationError(f"mesh: cannot fit the {chain.name} sweep: a section is degenerate")
    lam, vec = np.linalg.eigh(cov)  # ascending
    major = vec[:, 0, 1:2] * bu + vec[:, 1, 1:2] * bv
    radii = np.sqrt(2.0 * np.clip(lam[:, ::-1], 0.0, None))
    radii = np.maximum(radii, 1e-3 * lengths[:, None])  # a flat section still gets a width
    frames = frames_from_axes(normals, major)
    frames, radii = _consistent_frames(frames, radii)
    centres = points + mu[:, :1] * bu + mu[:, 1:] * bv
    keys = KeyEllipses.from_frames(centres, frames, radii)
    return LimbSweep(chain=chain, keys=keys, joint_pos=pos, pivot=pivot, frac=frac)
