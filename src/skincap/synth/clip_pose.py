"""The pose of a built-in clip, built segment by segment, and its small rotation maths.

:class:`ClipPose` holds the local rotations and root position of T frames on a
skeleton whose zero pose is a T-pose; the clips of :mod:`skincap.synth.clips` turn,
aim and solve its segments, found by name with :func:`find_landmarks` (CMU ``bvh11``,
CMU cgspeed, Biovision, MakeHuman). Quaternions are scalar-last ``(x, y, z, w)``;
metres, seconds, Y up, facing +Z.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.deform.skeletal.name_maps import CONVENTIONS, detect_convention
from skincap.geometry.kinematics import rest_positions
from skincap.geometry.rotations import (
    matrix_to_quat,
    quat_apply,
    quat_conjugate,
    quat_identity,
    quat_multiply,
)
from skincap.types import Motion, Skeleton

__all__ = [
    "ClipPose",
    "find_landmarks",
    "unit",
    "axis_angle",
    "swing",
    "quintic",
    "nlerp",
    "X_AXIS",
    "Y_AXIS",
    "Z_AXIS",
]


#: The next landmark down each segment's chain (its segment end).
_SEGMENT_END = {
    "hips": "spine",
    "spine": "chest",
    "chest": "upper_chest",
    "upper_chest": "neck",
    "neck": "neck_upper",
    "neck_upper": "head",
    **{
        f"{a}_{s}": f"{b}_{s}"
        for s in ("l", "r")
        for a, b in (
            ("clavicle", "upperarm"),
            ("upperarm", "forearm"),
            ("forearm", "hand"),
            ("thigh", "shin"),
            ("shin", "foot"),
            ("foot", "toe"),
        )
    },
}

X_AXIS = np.array([1.0, 0.0, 0.0])
Y_AXIS = np.array([0.0, 1.0, 0.0])
Z_AXIS = np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------ small maths
def unit(v: np.ndarray) -> np.ndarray:
    """Unit vectors along the last axis (zero vectors stay zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of rotations by ``angle`` (radians) about unit ``axis`` (..., 3)."""
    axis = np.asarray(axis, dtype=np.float64)
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    axis, half = np.broadcast_arrays(axis, half)
    return np.concatenate([axis * np.sin(half), np.cos(half[..., :1])], axis=-1)


def swing(u: np.ndarray, v: np.ndarray, weight: np.ndarray | float = 1.0) -> np.ndarray:
    """The shortest rotation carrying direction ``u`` onto ``v``, scaled by ``weight``.

    ``u``, ``v`` (..., 3) need not be unit; ``weight`` (...) in 0..1 turns only that
    share of the angle (0 gives the exact identity). Antiparallel vectors turn about
    an axis perpendicular to ``u``.
    """
    u = unit(np.asarray(u, dtype=np.float64))
    v = unit(np.asarray(v, dtype=np.float64))
    u, v = np.broadcast_arrays(u, v)
    axis = np.cross(u, v)
    sin = np.linalg.norm(axis, axis=-1)
    cos = np.sum(u * v, axis=-1)
    angle = np.arctan2(sin, cos)
    # antiparallel: any axis perpendicular to u
    fallback = np.cross(u, np.where(np.abs(u[..., :1]) < 0.9, X_AXIS, Y_AXIS))
    axis = np.where((sin < 1e-12)[..., None], fallback, axis)
    return axis_angle(unit(axis), angle * weight)


def quintic(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk smoothstep ``10 s^3 - 15 s^4 + 6 s^5`` on ``s`` clipped to 0..1."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def nlerp(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Directions from ``a`` to ``b`` (3,) at weights ``w`` (T,): normalised lerp, (T, 3)."""
    w = np.asarray(w)[..., None]
    return unit((1.0 - w) * a + w * b)


# ------------------------------------------------------------------ landmarks
def find_landmarks(skeleton: Skeleton) -> dict[str, int]:
    """Joint index of each body landmark the skeleton has.

    Parameters
    ----------
    skeleton : Skeleton

    Returns
    -------
    dict of str to int
        Keys from :data:`skincap.deform.skeletal.name_maps.LANDMARKS` (``hips``, ``spine``,
        ``chest``, ``upper_chest``, ``neck``, ``neck_upper``, ``head``, and per side
        ``clavicle_l``, ``upperarm_l``, ``forearm_l``, ``hand_l``, ``thigh_l``,
        ``shin_l``, ``foot_l``, ``toe_l``...). The skeleton's own convention is tried
        first, then the others; landmarks found under no convention are absent.
        ``hips`` falls back to the root joint.
    """
    names = skeleton.names
    index = {n: k for k, n in enumerate(names)}
    detected = detect_convention(names)
    order = ([detected] if detected else []) + [c for c in CONVENTIONS if c != detected]
    found: dict[str, int] = {}
    for conv in order:
        for landmark, value in CONVENTIONS[conv].items():
            if landmark in found:
                continue
            for name in (value,) if isinstance(value, str) else value:
                if name in index:
                    found[landmark] = index[name]
                    break
    if "hips" not in found:
        found["hips"] = int(np.nonzero(skeleton.parents < 0)[0][0])
    return found


class ClipPose:
    """Local rotations and root position of T frames, built segment by segment.

    All world rotations are identity in the rest pose, so a segment's rest direction
    in world coordinates is also its direction in its own joint frame.
    """

    def __init__(self, skeleton: Skeleton, n_frames: int) -> None:
        self.skeleton = skeleton
        self.parents = skeleton.parents
        self.rest = rest_positions(skeleton)  # (J, 3)
        self.lm = find_landmarks(skeleton)
        self.n = n_frames
        self.local = quat_identity((n_frames, skeleton.n_joints))
        self.root = int(np.nonzero(self.parents < 0)[0][0])
        self.root_offset = np.zeros((n_frames, 3))  # displacement from the rest, metres

    # ---------------------------------------------------------------- queries
    def has(self, *landmarks: str) -> bool:
        return all(k in self.lm for k in landmarks)

    def chain(self, j: int) -> list[int]:
        out = [j]
        while self.parents[out[-1]] >= 0:
            out.append(int(self.parents[out[-1]]))
        return out[::-1]

    def world(self, j: int) -> np.ndarray:
        """(T, 4) world rotation of joint ``j`` (identity for j = -1)."""
        w = quat_identity(self.n)
        if j < 0:
            return w
        for k in self.chain(j):
            w = quat_multiply(w, self.local[:, k])
        return w

    def position(self, j: int) -> np.ndarray:
        """(T, 3) world position of joint ``j``, metres."""
        chain = self.chain(j)
        p = self.skeleton.offsets[chain[0]] + self.root_offset
        w = self.local[:, chain[0]]
        for k in chain[1:]:
            p = p + quat_apply(w, self.skeleton.offsets[k])
            w = quat_multiply(w, self.local[:, k])
        return p

    def segment(self, landmark: str) -> np.ndarray:
        """(3,) rest vector of a landmark's segment: joint to its segment end, metres."""
        j = self.lm[landmark]
        end = _SEGMENT_END.get(landmark)
        if end is not None and end in self.lm:
            v = self.rest[self.lm[end]] - self.rest[j]
            if np.linalg.norm(v) > 1e-6:
                return v
        # fall back to the descendants: the first one away from the joint
        for k in range(j + 1, self.skeleton.n_joints):
            if j in self.chain(k):
                v = self.rest[k] - self.rest[j]
                if np.linalg.norm(v) > 1e-6:
                    return v
        return Y_AXIS.copy()

    # ---------------------------------------------------------------- setters
    def turn(self, landmark: str, q: np.ndarray) -> None:
        """Compose a local rotation ``q`` (T, 4) or (4,) onto a landmark's joint."""
        if landmark in self.lm:
            j = self.lm[landmark]
            self.local[:, j] = quat_multiply(self.local[:, j], q)

    def turn_world(self, landmark: str, q: np.ndarray) -> None:
        """Turn a landmark's segment by the world rotation ``q`` (T, 4) about its joint."""
        if landmark not in self.lm:
            return
        j = self.lm[landmark]
        wp = self.world(int(self.parents[j]))
        # W_new = q W_cur  =>  L_new = Wp* q Wp L_old
        self.local[:, j] = quat_multiply(
            quat_multiply(quat_conjugate(wp), quat_multiply(q, wp)), self.local[:, j]
        )

    def aim(self, landmark: str, target: np.ndarray, weight: np.ndarray | float = 1.0) -> None:
        """Swing a landmark's segment towards the world direction ``target`` (T, 3) or (3,).

        ``weight`` (T,) in 0..1 turns that share of the way (the minimal swing; the
        segment's twist is kept).
        """
        if landmark not in self.lm:
            return
        j = self.lm[landmark]
        current = quat_apply(self.world(j), self.segment(landmark))  # (T, 3)
        self.turn_world(landmark, swing(current, target, weight))

    def _bend_to_reach(
        self, upper: str, middle: str, end: str, target: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The hinge bend of the two-bone chain ``upper -> middle -> end`` that reaches ``target``.

        Returns the rest bones ``a0`` (``upper`` to ``middle`` joint) and ``b0``
        (``middle`` to ``end``), (3,) metres; the (T, 3) world position of the ``upper``
        joint; and the (T,) radians by which the ``middle`` joint must bend beyond its
        rest angle for the chain to span from there to ``target`` (T, 3) (law of
        cosines). Targets beyond reach give 0: the chain keeps its rest angle.
        """
        a0 = self.rest[self.lm[middle]] - self.rest[self.lm[upper]]
        b0 = self.rest[self.lm[end]] - self.rest[self.lm[middle]]
        l1, l2 = np.linalg.norm(a0), np.linalg.norm(b0)
        base = self.position(self.lm[upper])  # (T, 3)
        dist = np.linalg.norm(target - base, axis=-1)
        # interior angle at the middle joint now and at rest
        cos_now = np.clip((l1 * l1 + l2 * l2 - dist * dist) / (2 * l1 * l2), -1.0, 1.0)
        cos_rest = np.clip(np.dot(-a0, b0) / (l1 * l2), -1.0, 1.0)
        return a0, b0, base, np.maximum(np.arccos(cos_rest) - np.arccos(cos_now), 0.0)

    def leg_ik(self, side: str, ankle: np.ndarray, foot: np.ndarray | None = None) -> None:
        """Two-bone IK: put the ankle at ``ankle`` (T, 3), knee forward, foot at ``foot``.

        The knee bends about the axis perpendicular to the thigh nearest to the
        body's left-right axis; the thigh then swings the hip-to-ankle line onto the
        target. ``foot`` (T, 4) is the foot's world rotation (identity: flat as at
        rest). Targets beyond reach leave the knee straight (the ankle falls short).
        """
        thigh, shin, foot_lm = f"thigh_{side}", f"shin_{side}", f"foot_{side}"
        if not self.has(thigh, shin, foot_lm):
            return
        # a0 hip -> knee, b0 knee -> ankle at rest (3,); hip (T, 3)
        a0, b0, hip, bend = self._bend_to_reach(thigh, shin, foot_lm, ankle)
        l1 = np.linalg.norm(a0)
        hinge = unit(X_AXIS - np.dot(X_AXIS, a0) / (l1 * l1) * a0)  # knee axis, shin goes back
        self.local[:, self.lm[shin]] = axis_angle(hinge, bend)
        reach = a0 + quat_apply(self.local[:, self.lm[shin]], b0)  # (T, 3) thigh frame
        self.local[:, self.lm[thigh]] = quat_identity()
        wp = self.world(int(self.parents[self.lm[thigh]]))
        self.turn_world(thigh, swing(quat_apply(wp, reach), ankle - hip))
        w_foot = quat_identity() if foot is None else foot
        w_shin = self.world(int(self.parents[self.lm[foot_lm]]))
        self.local[:, self.lm[foot_lm]] = quat_multiply(quat_conjugate(w_shin), w_foot)

    def arm_ik(self, side: str, wrist: np.ndarray, pole: np.ndarray) -> None:
        """Two-bone IK: put the wrist at ``wrist`` (T, 3), the elbow towards ``pole``.

        The elbow is a hinge that bends the forearm forward (towards ``+Z`` in the
        T-pose, about the axis perpendicular to the upper arm and ``Z``); its angle
        comes from the shoulder-to-wrist distance (law of cosines). The upper arm is
        then turned so that the shoulder-to-wrist line points at the target and the
        elbow lies on the side of that line towards ``pole`` (T, 3) or (3,), a world
        direction (e.g. back and out: elbows by the sides). Targets beyond reach leave
        the arm straight, pointing at the target. The hand keeps its local rotation.
        A pole along the shoulder-to-target line is ill-defined: keep it well apart.
        """
        up, fore, hand = f"upperarm_{side}", f"forearm_{side}", f"hand_{side}"
        if not self.has(up, fore, hand):
            return
        # a0 shoulder -> elbow, b0 elbow -> wrist at rest (3,); shoulder (T, 3)
        a0, b0, shoulder, bend = self._bend_to_reach(up, fore, hand, wrist)
        reach_vec = wrist - shoulder
        hinge = unit(np.cross(a0, Z_AXIS))  # forearm bends towards +Z at rest
        self.local[:, self.lm[fore]] = axis_angle(hinge, bend)
        # the same two directions in the upper arm's rest frame and in the world:
        # shoulder-to-wrist, and the side of that line the elbow is on
        r = unit(a0 + quat_apply(self.local[:, self.lm[fore]], b0))  # (T, 3)
        o_rest = unit(np.cross(r, hinge))
        n = unit(reach_vec)
        pole = np.broadcast_to(np.asarray(pole, dtype=np.float64), n.shape)
        o_world = unit(pole - np.sum(pole * n, axis=-1, keepdims=True) * n)
        frame_rest = np.stack([r, o_rest, np.cross(r, o_rest)], axis=-1)  # (T, 3, 3) columns
        frame_world = np.stack([n, o_world, np.cross(n, o_world)], axis=-1)
        world = matrix_to_quat(frame_world @ np.swapaxes(frame_rest, -1, -2))
        wp = self.world(int(self.parents[self.lm[up]]))
        self.local[:, self.lm[up]] = quat_multiply(quat_conjugate(wp), world)

    # ---------------------------------------------------------------- output
    def motion(self, rate: float, meta: dict[str, Any]) -> Motion:
        q = self.local / np.linalg.norm(self.local, axis=-1, keepdims=True)
        translations = np.broadcast_to(
            self.skeleton.offsets, (self.n,) + self.skeleton.offsets.shape
        ).copy()
        translations[:, self.root] += self.root_offset
        channels = [
            (
                ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
                if p < 0
                else ()
                if leaf
                else ("Zrotation", "Yrotation", "Xrotation")
            )
            for p, leaf in zip(self.parents, self.skeleton.is_leaf, strict=True)
        ]
        return Motion(
            skeleton=self.skeleton,
            rotations=q,
            translations=translations,
            rate=rate,
            channels=channels,
            meta=meta,
        )
