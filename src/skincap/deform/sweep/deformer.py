"""The sweep-based deformer (Hyun et al. 2005) driven by a skinned mesh's skeleton.

Per frame, from the skinning matrices ``S = W @ inverse_bind`` (J, 4, 4):

1. every key ellipse moves with the joints (§4.1): a key along a bone turns with the
   bone, about the bone's first joint, with the bone's own turn about its axis
   relative to the bone above (a forearm's pronation, a humerus' rotation) faded in
   along it -- none at its first joint, all of it at the next -- and, on the last
   bone, the end joint's turn about that bone (pronation carried by the hand) faded in
   the same way; a joint's key turns by the rotation halfway (slerp at 1/2) between
   the bone above and the bone below as they meet at the joint, so its plane bisects
   the two bones;
2. each limb's radii are scaled so its swept volume stays at the rest value
   (§4.4, :class:`~skincap.deform.sweep.volume.LimbVolume`; ``volume=False`` skips it):
   a vertex on or outside its ellipse moves with the ellipse's rim (its displacement
   kept), one inside it scales with it;
3. each bound vertex is rebuilt from its binding, ``C(t_V) + R(t_V) local_V``;
4. the result is blended with skeletal skinning (DQS or LBS) of the whole mesh by the
   binding's weight (§3.5): the hands, feet, head and torso follow skinning, the limbs
   their sweeps, and the shoulders, hips, wrists and ankles a smooth mix.

All of it is vectorised over frames and vertices; the only Python loops are over the
limbs (four) and the volume steps (four).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, Literal

import numpy as np

from skincap.deform.skeletal.deformers import (
    Backend,
    _check_chunk,
    _check_same_skeleton,
    deformed_chunks,
    make_deformer,
)
from skincap.deform.sweep.basis import align_hemispheres
from skincap.deform.sweep.bind import LimbBinding, bind_limb
from skincap.deform.sweep.chains import limb_chains
from skincap.deform.sweep.fit import LimbSweep, fit_limb
from skincap.deform.sweep.volume import LimbVolume
from skincap.errors import ValidationError
from skincap.geometry.rotations import matrix_to_quat, quat_apply, quat_conjugate, quat_multiply
from skincap.types import Mesh, MeshAnimation, Motion

__all__ = ["SweepDeformer", "sweep_motion"]

Skinning = Literal["dqs", "lbs"]


def _twist(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions turning by ``angle`` (...) radians about the unit ``axis`` (3,)."""
    half = 0.5 * angle
    return np.concatenate([np.sin(half)[..., None] * axis, np.cos(half)[..., None]], axis=-1)


def _axial(rel: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Twist angle (...) radians of unit quaternions (..., 4) about unit ``axis`` (..., 3).

    The twist of the swing-twist split ``rel = swing * twist``, taken the shorter way
    (within +-180 degrees).
    """
    rel = np.where(rel[..., 3:] < 0, -rel, rel)
    return 2.0 * np.arctan2(np.sum(rel[..., :3] * axis, axis=-1), rel[..., 3])


def _halfway(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Slerp at 1/2 of unit quaternions (..., 4): the normalised sum, short arc."""
    sign = np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    h = a + sign * b
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


class SweepDeformer:
    """Sweep-based deformation of a skinned mesh's arms and legs, skinning elsewhere.

    Parameters
    ----------
    mesh : Mesh
        With a :class:`~skincap.types.Skin`; rest vertices (V, 3) metres in the bind pose.
    chains : mapping name -> joint names, optional
        Limbs to sweep (each at least 3 joints down one limb). Default: both arms
        (shoulder, elbow, wrist) and both legs (hip, knee, ankle) found by joint names
        (:func:`~skincap.deform.sweep.chains.limb_chains`).
    n_between : int, default 3
        Key ellipses along each link between the joints' keys.
    skinning : {"dqs", "lbs"}, default "dqs"
        What moves the vertices outside the sweeps and blends with them.
    volume : bool, default True
        Keep each limb's swept volume at its rest value (§4.4).
    backend : {"auto", "numba", "numpy"}
        Of the skinning deformer.

    Attributes
    ----------
    limbs : list of LimbSweep
    bindings : list of LimbBinding

    Raises
    ------
    ValidationError
        No limb chain on the skeleton, or a limb whose sections the mesh does not
        cover (the message names the limb and the joint).
    """

    method = "sweep"

    def __init__(
        self,
        mesh: Mesh,
        *,
        chains: Mapping[str, Sequence[str]] | None = None,
        n_between: int = 3,
        skinning: Skinning = "dqs",
        volume: bool = True,
        backend: Backend = "auto",
    ) -> None:
        if skinning not in ("dqs", "lbs"):
            raise ValidationError(f"skinning: expected 'dqs' or 'lbs', got {skinning!r}")
        self.skinner = make_deformer(skinning, mesh, backend=backend)
        skin = mesh.skin
        assert skin is not None  # make_deformer checked it
        self.mesh = mesh
        self.skinning = skinning
        self.preserve_volume = bool(volume)
        self.limbs: list[LimbSweep] = [
            fit_limb(mesh, c, n_between=n_between) for c in limb_chains(skin.skeleton, chains)
        ]
        self.bindings: list[LimbBinding] = [bind_limb(mesh, limb) for limb in self.limbs]
        self.volumes: list[LimbVolume] | None = (
            [LimbVolume(limb) for limb in self.limbs] if self.preserve_volume else None
        )
        self._rest_q = [align_hemispheres(limb.keys.rotations) for limb in self.limbs]

    @property
    def backend(self) -> str:
        return self.skinner.backend

    @property
    def n_vertices(self) -> int:
        return self.skinner.n_vertices

    # ------------------------------------------------------------------ keys
    def key_poses(self, k: int, matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posed key centres (T, K, 3) metres and quaternions (T, K, 4) of limb ``k``.

        ``matrices`` (T, J, 4, 4) are skinning matrices (identity in the bind pose);
        the quaternions are hemisphere-aligned along the sweep.
        """
        limb = self.limbs[k]
        chain = limb.chain
        joints = chain.joints
        m = joints.size
        s = matrices[:, joints]  # (T, m, 4, 4)
        q = matrix_to_quat(s[..., :3, :3])  # (T, m, 4)
        posed = np.einsum("tmij,mj->tmi", s[..., :3, :3], limb.joint_pos) + s[..., :3, 3]
        if chain.parent >= 0:
            q_parent = matrix_to_quat(matrices[:, chain.parent, :3, :3])
        else:
            q_parent = q[:, 0]
        axes = np.diff(limb.joint_pos, axis=0)
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)  # (m-1, 3) rest link directions
        before = np.concatenate([q_parent[:, None], q[:, :-1]], axis=1)  # (T, m, 4)
        rel = quat_multiply(quat_conjugate(before), q)  # each joint against the one above
        # a joint's turn about its own bone fades in along that bone (0 at the joint, all
        # of it at the next); the end joint's turn about the last bone (a wrist's
        # pronation) fades in along the last bone
        fade_in = _axial(rel[:, :-1], axes)  # (T, m-1)
        end_turn = np.zeros_like(fade_in)
        end_turn[:, -1] = _axial(rel[:, -1], axes[-1])
        link_start = quat_multiply(q[:, :-1], _twist(axes, -fade_in))  # (T, m-1, 4)
        link_end = quat_multiply(q[:, :-1], _twist(axes, end_turn))
        incoming = np.concatenate([q_parent[:, None], link_end], axis=1)  # (T, m, 4)
        outgoing = np.concatenate([link_start, q[:, -1:]], axis=1)
        joint_rot = _halfway(incoming, outgoing)
        pivot, frac = limb.pivot, limb.frac
        is_joint = frac < 0
        li = np.minimum(pivot, m - 2)
        f = np.clip(frac, 0.0, 1.0)[None]
        turn = (f - 1.0) * fade_in[:, li] + f * end_turn[:, li]  # (T, K) about the link
        along = quat_multiply(q[:, li], _twist(axes[li], turn))  # (T, K, 4)
        delta = np.where(is_joint[None, :, None], joint_rot[:, pivot], along)
        arm = limb.keys.centres - limb.joint_pos[pivot]  # (K, 3) from the pivot, rest
        centres = posed[:, pivot] + quat_apply(delta, arm)
        quats = align_hemispheres(quat_multiply(delta, self._rest_q[k]))
        return centres, quats

    # --------------------------------------------------------------- vertices
    def _limb_vertices(self, k: int, matrices: np.ndarray) -> np.ndarray:
        """(T, n, 3) positions of limb ``k``'s bound vertices on its posed sweep."""
        bound = self.bindings[k]
        centres, quats = self.key_poses(k, matrices)
        basis = bound.basis
        local = np.broadcast_to(bound.local, (matrices.shape[0],) + bound.local.shape)
        if self.volumes is not None:
            beta = self.volumes[k].scales(centres, quats)  # (T, K)
            s = 1.0 + beta @ basis.hat.T  # (T, n) radius scale at t_V
            rho = bound.rho[None]
            # inside the ellipse scale with it; outside keep the displacement from its rim
            f = np.where(rho <= 1.0, s, 1.0 + (s - 1.0) / np.maximum(rho, 1.0))
            local = local * np.stack([f, f, np.ones_like(f)], axis=-1)
        return basis.centres(centres) + quat_apply(basis.quaternions(quats), local)

    def deform(self, matrices: np.ndarray) -> np.ndarray:
        """Deform the rest mesh by one pose or a batch of frames.

        Parameters
        ----------
        matrices : (J, 4, 4) or (T, J, 4, 4) float
            Skinning matrices ``S = W @ inverse_bind`` (metres; identity in the bind
            pose), rigid.

        Returns
        -------
        (V, 3) or (T, V, 3) float64, metres
        """
        out = self.skinner.deform(matrices)
        m = np.asarray(matrices, dtype=np.float64)
        single = m.ndim == 3
        if single:
            m, out = m[None], out[None]
        for k, bound in enumerate(self.bindings):
            swept = self._limb_vertices(k, m)
            idx = bound.vertices
            out[:, idx] += bound.weight[None, :, None] * (swept - out[:, idx])
        return out[0] if single else out

    def deform_chunks(self, matrices: np.ndarray, chunk: int = 64) -> Iterator[np.ndarray]:
        """(T, J, 4, 4) skinning matrices -> (t, V, 3) blocks of at most ``chunk`` frames."""
        m = np.asarray(matrices, dtype=np.float64)
        if m.ndim != 4 or m.shape[-2:] != (4, 4):
            raise ValidationError(f"matrices: expected shape (T, J, 4, 4), got {m.shape}")
        step = _check_chunk(chunk)
        return (self.deform(m[s : s + step]) for s in range(0, m.shape[0], step))


def sweep_motion(
    mesh: Mesh,
    motion: Motion,
    *,
    chunk: int = 64,
    progress: Callable[[float], object] | None = None,
    skinning: Skinning = "dqs",
    volume: bool = True,
    chains: Mapping[str, Sequence[str]] | None = None,
    n_between: int = 3,
    backend: Backend = "auto",
) -> MeshAnimation:
    """Deform a motion on a skinned mesh with sweeps, streaming chunk by chunk.

    Parameters
    ----------
    mesh : Mesh
        With a skin (rest vertices in the bind pose, metres).
    motion : Motion
        On the skin's own skeleton (same joint names, order and parents).
    chunk : int, default 64
        Frames per block.
    progress : callable, optional
        Called with the fraction of frames done after each block.
    skinning, volume, chains, n_between, backend
        See :class:`SweepDeformer`.

    Returns
    -------
    MeshAnimation
        ``frames`` a one-shot iterator of (t, V, 3) float64 chunks, metres; ``meta``
        has ``skinning_method`` (``"sweep"``), ``skinning_backend``, ``sweep_limbs``
        and ``sweep_volume``.

    Raises
    ------
    ValidationError
        As :class:`SweepDeformer`, or a motion on another skeleton; raised before
        any frame is computed.
    """
    step = _check_chunk(chunk)
    if not isinstance(motion, Motion):
        raise ValidationError(f"motion: expected a Motion, got {type(motion).__name__}")
    if progress is not None and not callable(progress):
        raise ValidationError("progress: expected a callable taking a fraction, or None")
    deformer = SweepDeformer(
        mesh, chains=chains, n_between=n_between, skinning=skinning, volume=volume, backend=backend
    )
    _check_same_skeleton(mesh, motion)
    frames = deformed_chunks(deformer, mesh, motion, step, progress)

    meta: dict[str, Any] = {
        "skinning_method": "sweep",
        "skinning_backend": deformer.backend,
        "sweep_skinning": skinning,
        "sweep_limbs": [limb.chain.name for limb in deformer.limbs],
        "sweep_volume": deformer.preserve_volume,
    }
    return MeshAnimation(
        rest=mesh, frames=frames, rate=motion.rate, n_frames=motion.n_frames, meta=meta
    )
