"""Analytic skinned limbs for the sweep deformer's tests (ground truth known)."""

from __future__ import annotations

import dataclasses

import numpy as np

from skincap.deform.skeletal.artefacts import two_bone_cylinder
from skincap.types import Mesh, Skeleton, Skin

#: The two-bone cylinder's chain: root bone, the joint's bone, the end site.
CYLINDER_CHAIN = {"limb": ("upper", "lower", "lower_end")}


def elliptic_limb(a: float = 0.05, b: float = 0.03) -> Mesh:
    """The two-bone cylinder (axis x, 0.5 m, joint at x = 0.25) with half-axes a (y), b (z)."""
    mesh = two_bone_cylinder(1.0, 0.5, blend=0.04, n_around=64, n_along=101)
    v = mesh.vertices * np.array([1.0, a, b])
    return dataclasses.replace(mesh, vertices=v)


def limb_beside_another(gap: float = 0.01) -> Mesh:
    """The elliptic limb and a second parallel cylinder ``gap`` away, skinned to its own root.

    The limb's section planes cut both; only the limb's skin weights say which is which.
    """
    limb = elliptic_limb()
    other = elliptic_limb(0.05, 0.05)
    shift = np.array([0.0, 0.05 + gap + 0.05, 0.0])
    n = limb.n_vertices
    skin = limb.skin
    sk = Skeleton(
        names=[*skin.skeleton.names, "other"],
        parents=np.array([-1, 0, 1, -1]),
        offsets=np.vstack([skin.skeleton.offsets, shift]),
    )
    inverse_bind = np.vstack([skin.inverse_bind, np.eye(4)[None]])
    inverse_bind[3, :3, 3] = -shift
    idx = np.vstack([skin.joint_indices, np.tile([3, 3], (other.n_vertices, 1))])
    w = np.vstack([skin.joint_weights, np.tile([1.0, 0.0], (other.n_vertices, 1))])
    return Mesh(
        vertices=np.vstack([limb.vertices, other.vertices + shift]),
        faces=np.vstack([limb.faces, other.faces + n]),
        skin=Skin(skeleton=sk, joint_indices=idx, joint_weights=w, inverse_bind=inverse_bind),
    )
