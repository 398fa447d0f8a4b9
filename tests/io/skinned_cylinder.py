"""A small skinned cylinder bending at its middle joint, for the export tests.

The cylinder stands on the Y axis (metres, Y up). Three joints: ``root`` at the base,
``elbow`` half way up, ``tip`` at the top. Their bind frames carry a bone roll (a turn
about the bone's own axis) so that inverse bind matrices are not pure translations,
as in the MakeHuman rig. The motion bends the elbow about the world Z axis by up to
90 degrees while the root slides and turns, so rotation and translation channels both
matter.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.geometry.kinematics import forward_kinematics
from skincap.geometry.rotations import matrix_to_quat
from skincap.types import Mesh, Motion, Skeleton, Skin

RADIUS = 0.05
HEIGHT = 0.4
RINGS = 9  # rings of vertices along the height
SEGMENTS = 12  # vertices around a ring
N_FRAMES = 25
RATE = 24.0


def cylinder_mesh(n_influences: int = 2) -> Mesh:
    """Open cylinder with quads (kept as polygons) bound to root/elbow/tip.

    ``n_influences`` (1..3) joints per vertex, the largest weights kept.
    """
    ang = 2 * np.pi * np.arange(SEGMENTS) / SEGMENTS
    ys = np.linspace(0.0, HEIGHT, RINGS)
    yy, aa = np.meshgrid(ys, ang, indexing="ij")  # (RINGS, SEGMENTS)
    verts = np.stack([RADIUS * np.cos(aa), yy, -RADIUS * np.sin(aa)], axis=-1).reshape(-1, 3)
    r = np.arange(RINGS - 1)[:, None]
    s = np.arange(SEGMENTS)[None, :]
    a = r * SEGMENTS + s
    b = r * SEGMENTS + (s + 1) % SEGMENTS
    quads = np.stack([a, b, b + SEGMENTS, a + SEGMENTS], axis=-1).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    face_polygon = np.concatenate([np.arange(len(quads))] * 2)
    uv = np.stack([np.repeat(0, verts.shape[0]) + np.tile(ang / (2 * np.pi), RINGS),
                   np.repeat(ys / HEIGHT, SEGMENTS)], axis=1)  # fmt: skip

    heads = np.array([[0.0, 0.0, 0.0], [0.0, HEIGHT / 2, 0.0], [0.0, HEIGHT, 0.0]])
    roll = Rotation.from_euler("y", [[20.0], [-35.0], [50.0]], degrees=True).as_matrix()
    bind = np.tile(np.eye(4), (3, 1, 1))
    bind[:, :3, :3] = roll
    bind[:, :3, 3] = heads
    skel = Skeleton(
        names=["root", "elbow", "tip"],
        parents=np.array([-1, 0, 1]),
        offsets=np.diff(heads, axis=0, prepend=np.zeros((1, 3))),
    )
    y = verts[:, 1]
    # elbow weight ramps 0 -> 1 over the middle fifth; tip weight over the top ring
    w_elbow = np.clip((y - 0.15) / 0.1, 0.0, 1.0)
    w_tip = np.where(y > HEIGHT - 1e-9, 0.3, 0.0)
    dense = np.stack([1.0 - w_elbow, w_elbow - w_tip, w_tip], axis=1)
    order = np.argsort(-dense, axis=1, kind="stable")[:, :n_influences]
    w = np.take_along_axis(dense, order, axis=1)
    w = w / w.sum(axis=1, keepdims=True)
    skin = Skin(
        skeleton=skel, joint_indices=order, joint_weights=w, inverse_bind=np.linalg.inv(bind)
    )
    return Mesh(
        vertices=verts,
        faces=faces,
        polygon_indices=quads.reshape(-1),
        polygon_offsets=np.arange(0, quads.size + 1, 4),
        face_polygon=face_polygon,
        uv=uv,
        skin=skin,
        meta={"name": "cylinder", "source_units": "m", "up": "y"},
    )


def bind_local(skin: Skin) -> tuple[np.ndarray, np.ndarray]:
    """(J, 4) quaternions and (J, 3) translations with FK == the bind matrices."""
    bind = skin.bind_matrices
    parents = skin.skeleton.parents
    local = bind.copy()
    has = parents >= 0
    local[has] = np.linalg.solve(bind[parents[has]], bind[has])
    return matrix_to_quat(local[:, :3, :3]), local[:, :3, 3]


def bend_motion(mesh: Mesh, n_frames: int = N_FRAMES, rate: float = RATE) -> Motion:
    """The elbow bends 0 -> 90 degrees about world Z; the root slides along X and turns."""
    skin = mesh.skin
    q0, t0 = bind_local(skin)
    t = np.arange(n_frames)
    angle = np.linspace(0.0, 90.0, n_frames)
    rot = np.tile(q0, (n_frames, 1, 1))
    trans = np.tile(t0, (n_frames, 1, 1))
    # elbow: a bend about Z of the rest root frame, applied before the bind-local rotation
    root_r = Rotation.from_quat(q0[0])
    bend_world = Rotation.from_euler("z", angle[:, None], degrees=True)
    bend_in_root = root_r.inv() * bend_world * root_r
    rot[:, 1] = (bend_in_root * Rotation.from_quat(q0[1])).as_quat()
    # root: slides 0.1 m along X and turns 30 degrees about Y
    turn = Rotation.from_euler("y", np.linspace(0.0, 30.0, n_frames)[:, None], degrees=True)
    rot[:, 0] = (turn * root_r).as_quat()
    trans[:, 0, 0] = 0.1 * t / max(n_frames - 1, 1)
    return Motion(skeleton=skin.skeleton, rotations=rot, translations=trans, rate=rate)


def lbs_reference(mesh: Mesh, motion: Motion) -> np.ndarray:
    """(T, V, 3) linear blend skinning by a plain einsum (independent of skincap.deform.skeletal)."""
    skin = mesh.skin
    s = np.einsum("tjab,jbc->tjac", forward_kinematics(motion), skin.inverse_bind)
    vh = np.concatenate([mesh.vertices, np.ones((mesh.n_vertices, 1))], axis=1)
    per = np.einsum("tvkab,vb->tvka", s[:, skin.joint_indices], vh)[..., :3]  # (T, V, K, 3)
    return np.einsum("tvka,vk->tva", per, skin.joint_weights)
