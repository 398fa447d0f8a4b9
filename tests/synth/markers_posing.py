"""A posed MakeHuman body for the marker and camera tests (not a test module)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.deform.skeletal.deformers import skin_motion
from skincap.deform.skeletal.rig import motion_from_world, rest_motion
from skincap.geometry.kinematics import forward_kinematics
from skincap.types import Mesh


def arm_across_belly(body: Mesh, frames: int = 1) -> np.ndarray:
    """(frames, V, 3): the left arm swung forward and the forearm across the belly."""
    skin = body.skin
    sk = skin.skeleton
    world = forward_kinematics(rest_motion(skin))[0]  # (J, 4, 4)
    rot = np.repeat(world[None, :, :3, :3], frames, axis=0).copy()
    pos = world[:, :3, 3]

    def subtree(name: str) -> np.ndarray:
        j = sk.index(name)
        inside = np.zeros(sk.n_joints, dtype=bool)
        inside[j] = True
        for k in range(j + 1, sk.n_joints):
            inside[k] |= sk.parents[k] >= 0 and inside[sk.parents[k]]
        return inside

    sh, el, wr = (pos[sk.index(n)] for n in ("upperarm01.L", "lowerarm01.L", "wrist.L"))
    blend = np.linspace(0.0, 1.0, frames) if frames > 1 else np.ones(1)
    r_upper, _ = Rotation.align_vectors([[0.1, -0.55, 0.83]], [el - sh])
    fore_after = r_upper.apply(wr - el)
    r_fore, _ = Rotation.align_vectors([[-1.0, 0.15, 0.05]], [fore_after])
    up = subtree("upperarm01.L")
    lo = subtree("lowerarm01.L")
    for t, s in enumerate(blend):
        ru = Rotation.from_rotvec(s * r_upper.as_rotvec()).as_matrix()
        rf = Rotation.from_rotvec(s * r_fore.as_rotvec()).as_matrix()
        rot[t, up] = ru @ rot[t, up]
        rot[t, lo] = rf @ rot[t, lo]
    motion = motion_from_world(skin, rot, np.repeat(pos[None, 0], frames, 0), rate=120.0)
    return np.concatenate(list(skin_motion(body, motion).iter_chunks()))
