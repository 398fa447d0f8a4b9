"""Vertices bound to a limb's sweep, with their displacements (Hyun et al. §3.3-3.5).

Each vertex the skin weights give (partly) to the limb is bound to the moving ellipse
whose plane contains it (:meth:`skincap.geometry.sweep.Sweep.locate`, parameter
``t_V``) and keeps its coordinates in that ellipse's frame, ``R(t_V)^T (V - C(t_V))``.
The paper keeps the in-plane part as a displacement from the ellipse,
``d_V = ((a_V - a(t_V)) cos θ, (b_V - b(t_V)) sin θ)``, and drops the small offset
``c_V`` along the normal; here the full local vector is kept -- the in-plane part is
the ellipse point plus ``d_V``, the third coordinate ``c_V`` -- so the rest pose is
reproduced to rounding, not approximately.

The blend weight of a vertex (§3.5's ``1 - w_V``) is the sum of its skin weights on the
limb's bones: 1 inside the limb, falling smoothly to 0 across the shoulder or hip and
the wrist or ankle exactly where the skin weights hand the surface over to the torso
and the hand or foot, so the sweep and skinning meet without a seam.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincap.deform.sweep.basis import SweepBasis, align_hemispheres
from skincap.deform.sweep.fit import LimbSweep
from skincap.geometry.rotations import quat_apply, quat_conjugate
from skincap.geometry.sweep import Sweep
from skincap.types import Mesh

__all__ = ["LimbBinding", "bind_limb"]


@dataclass(frozen=True, eq=False)
class LimbBinding:
    """The vertices of one limb bound to its sweep.

    Attributes
    ----------
    vertices : (n,) int64
        Mesh indices of the bound vertices.
    weight : (n,) float64
        Blend weight of the sweep (1: the sweep alone; 0: skinning alone).
    basis : SweepBasis
        The sweep's interpolation at each vertex's ``t_V``.
    local : (n, 3) float64
        ``R(t_V)^T (V - C(t_V))`` in the rest pose, metres.
    rho : (n,) float64
        Elliptic radius ``|(x / a(t_V), y / b(t_V))|`` of the in-plane part: 1 on the
        ellipse, < 1 inside.
    """

    vertices: np.ndarray
    weight: np.ndarray
    basis: SweepBasis
    local: np.ndarray
    rho: np.ndarray


def bind_limb(mesh: Mesh, limb: LimbSweep, *, n_planes: int | None = None) -> LimbBinding:
    """Bind the vertices a limb's bones weight to its rest sweep.

    Parameters
    ----------
    mesh : Mesh
        With a skin; rest vertices (V, 3) metres, the pose ``limb`` was fitted in.
    limb : LimbSweep
    n_planes : int, optional
        Planes sampled by :meth:`Sweep.locate` (default there).

    Returns
    -------
    LimbBinding
    """
    skin = mesh.skin
    assert skin is not None  # fit_limb checked it
    weight = (skin.joint_weights * limb.chain.bones[skin.joint_indices]).sum(axis=1)
    idx = np.nonzero(weight > 0)[0]
    points = mesh.vertices[idx]
    sweep = Sweep(limb.keys, orientation="nlerp")
    t, _, _ = sweep.locate(points, n_planes=n_planes)
    basis = SweepBasis.at(sweep, t)
    keys_q = align_hemispheres(limb.keys.rotations)
    centre = basis.centres(limb.keys.centres)
    q = basis.quaternions(keys_q)
    local = quat_apply(quat_conjugate(q), points - centre)
    rho = np.hypot(local[:, 0] / basis.radii[:, 0], local[:, 1] / basis.radii[:, 1])
    return LimbBinding(
        vertices=idx, weight=np.clip(weight[idx], 0.0, 1.0), basis=basis, local=local, rho=rho
    )
