"""Soft tissue: the skin motion that rigid bones plus skinning cannot explain.

Three effects are added on top of skinned vertices, each with its own amplitude
(0 switches it off exactly):

**Muscle bulge.** The biceps bulges with elbow flexion and the quadriceps with knee
flexion, outwards along the posed surface normal. The flexion angle ``theta`` is the
angle between the two bone directions (from forward kinematics) minus its bind-pose
value; the height is ``A (1 - cos theta) / (1 - cos theta_ref)`` (1.2 cm at a 150
degree elbow, 0.8 cm at a 105 degree knee), spread over the region as a smooth bump:
a ``sin^2`` profile along the bone (zero at both joints) times ``max(0, r . f)^2``
around it, where ``r`` is the vertex's radial direction from the bone axis in the
bind pose and ``f`` the flexion direction (the side the forearm folds towards; the
opposite side for the thigh), times the vertex's skin weight on the bone.

**Jiggle.** Each fleshy region -- belly, chest, both thighs, both upper arms -- is a
damped spring ``x'' + 2 zeta omega x' + omega^2 x = -g a(t)`` driven by the
acceleration ``a`` of its bone (second differences of the bone's world position from
forward kinematics), starting at rest. The spring is integrated exactly for
piecewise-linear forcing as a second-order IIR filter (``scipy.signal.lfilter``), so
no frame loop runs in Python. A vertex moves by its region weight times the region's
spring offset (a 3-vector, metres): millimetres when walking, one to two centimetres
on the landings of a hop.

**Breathing.** Chest and belly expand along the normals with a 0.25 Hz cycle,
``A (1 - cos(2 pi f t + phi)) / 2`` (3 mm chest, 4 mm belly, the belly a little
later), ``phi`` drawn from ``seed``.

Regions
-------
Joints are grouped into body segments by the nearest landmark at or above them
(:func:`skincap.synth.clips.find_landmarks`, which knows the CMU, Biovision and
MakeHuman names: ``upperarm01.L`` and ``upperarm02.L`` are both upper arm), with a
keyword fallback for other rigs (``upperarm``/``arm``, ``forearm``/``lowerarm``,
``upleg``/``upperleg``/``thigh``, ``lowerleg``/``shin``/``leg``, ``spine``/``chest``/
``belly``, the side from the joint's position). A vertex's segment weight is the sum
of its skin weights on the segment's joints. Geometry in the bind pose then
restricts: the belly is the front of the lower torso (pelvis and lower spine
weights, front-facing normals, above the hip joints), the chest the front of the
upper torso; the limb regions fade out towards both joints. Head, neck, hands,
forearms, shins and feet carry no region, so they never move.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse
from scipy.signal import lfilter

from skincap.errors import ValidationError
from skincap.geometry.kinematics import forward_kinematics
from skincap.synth.clips import find_landmarks
from skincap.types import Mesh, Motion, Skeleton

__all__ = ["SoftTissue", "vertex_normals", "JIGGLE_REGIONS"]

#: Regions with a spring: (name, natural frequency Hz, damping ratio, coupling g).
JIGGLE_REGIONS: tuple[tuple[str, float, float, float], ...] = (
    ("belly", 5.0, 0.2, 0.5),
    ("chest", 5.5, 0.25, 0.4),
    ("thigh_l", 7.0, 0.25, 0.4),
    ("thigh_r", 7.0, 0.25, 0.4),
    ("upperarm_l", 6.0, 0.2, 0.5),
    ("upperarm_r", 6.0, 0.2, 0.5),
)

#: Bulge height at the reference angle (metres) and the reference angle (degrees).
_BULGE = {"upperarm": (0.012, 150.0), "thigh": (0.008, 105.0)}
#: Breathing: frequency (Hz), chest and belly amplitudes (metres), belly lag (radians).
_BREATH_HZ = 0.25
_BREATH_CHEST = 0.003
_BREATH_BELLY = 0.004
_BREATH_LAG = 0.6
#: Frames per block when computing normals (bounds the temporaries).
_CHUNK = 64
#: Maximal magnitude of one jiggle spring offset (metres): keeps extreme input sane.
_JIGGLE_LIMIT = 0.05

_KEYWORDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("forearm", ("forearm", "lowerarm")),
    ("upperarm", ("upperarm", "uparm", "humerus")),
    ("thigh", ("upleg", "upperleg", "thigh")),
    ("shin", ("lowerleg", "shin", "calf")),
    ("foot", ("foot", "ankle", "toe")),
    ("hand", ("hand", "wrist", "finger", "thumb")),
    ("head", ("head", "neck", "jaw", "eye")),
    ("chest", ("chest", "breast", "thorax")),
    ("spine", ("spine", "belly", "abdomen", "lowerback")),
)

_TORSO_LOW = ("hips", "spine")
_TORSO_HIGH = ("chest", "upper_chest")


# ------------------------------------------------------------------ helpers
def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of one or many poses.

    Parameters
    ----------
    vertices : (..., V, 3) float, metres
    faces : (F, 3) int
        Counter-clockwise seen from outside.

    Returns
    -------
    (..., V, 3) float64
        Unit normals (zero for vertices in no face or with degenerate faces only).
        NaN in a vertex spreads to the normals of its neighbours.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    return _normals_with(_incidence(f, v.shape[-2]), v, f)


def _incidence(faces: np.ndarray, n_vertices: int) -> scipy.sparse.csr_matrix:
    """(V, F) sparse matrix with a 1 where a vertex is a corner of a face."""
    rows = faces.reshape(-1)
    cols = np.repeat(np.arange(faces.shape[0]), 3)
    return scipy.sparse.csr_matrix(
        (np.ones(rows.size), (rows, cols)), shape=(n_vertices, faces.shape[0])
    )


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) arrays (faster than np.cross for large batches)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _normals_with(incidence: Any, v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Vertex normals (..., V', 3) through a (V', F) incidence matrix of the faces ``f``."""
    lead = v.shape[:-2]
    vm = np.moveaxis(v.reshape((-1,) + v.shape[-2:]), 0, 1)  # (V, N, 3) vertex-major
    a, b, c = vm[f[:, 0]], vm[f[:, 1]], vm[f[:, 2]]  # (F, N, 3)
    face_n = _cross(b - a, c - a)  # (F, N, 3), twice the area
    acc = incidence @ face_n.reshape(face_n.shape[0], -1)  # (V', N * 3)
    acc = np.moveaxis(acc.reshape(acc.shape[0], -1, 3), 1, 0)  # (N, V', 3)
    norm = np.linalg.norm(acc, axis=-1, keepdims=True)
    out = acc / np.where(norm > 0, norm, 1.0)
    return out.reshape(lead + out.shape[-2:])


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _keyword_segment(name: str) -> str | None:
    low = "".join(ch for ch in name.lower() if ch.isalnum())
    for seg, words in _KEYWORDS:
        if any(w in low for w in words):
            return seg
    if low.endswith("arm") or low.endswith("arml") or low.endswith("armr"):
        return "upperarm"
    if low.endswith("leg") or low.endswith("legl") or low.endswith("legr"):
        return "shin"
    return None


def joint_segments(skeleton: Skeleton, bind_positions: np.ndarray) -> list[str]:
    """Body segment of every joint: its nearest landmark at or above it.

    Parameters
    ----------
    skeleton : Skeleton
    bind_positions : (J, 3) float, metres
        Joint positions in the bind pose (for the side of keyword-matched limbs).

    Returns
    -------
    list of J str
        Landmark names (``hips``, ``spine``, ``chest``, ``upper_chest``, ``neck``,
        ``head``, ``upperarm_l``, ``forearm_r``, ``thigh_l``...); limbs matched only
        by keyword get ``<segment>_l`` / ``_r`` from the sign of their x coordinate.
    """
    lm = find_landmarks(skeleton)
    by_joint = {j: k for k, j in lm.items()}
    out: list[str] = []
    for j in range(skeleton.n_joints):
        p = int(skeleton.parents[j])
        seg = by_joint.get(j, out[p] if p >= 0 else "hips")
        if j not in by_joint and seg in ("hips", "spine", "chest", "upper_chest"):
            key = _keyword_segment(skeleton.names[j])
            if key in ("upperarm", "forearm", "thigh", "shin", "foot", "hand"):
                seg = f"{key}_{'l' if bind_positions[j, 0] >= 0 else 'r'}"
            elif key == "head":
                seg = "head"
            elif key == "chest" and seg in _TORSO_LOW:
                seg = "chest"
        out.append(seg)
    return out


@dataclass(frozen=True)
class _Limb:
    """A two-bone limb: the region's bone ``a -> b`` and the next bone ``b -> c``."""

    region: str  # "upperarm_l", "thigh_r"...
    a: int
    b: int
    c: int
    fold_sign: float  # +1: muscle on the side the next bone folds to; -1: opposite


# ------------------------------------------------------------------ the model
class SoftTissue:
    """Muscle bulge, jiggle and breathing of a skinned mesh.

    Parameters
    ----------
    mesh : Mesh
        With a :class:`~skincap.types.Skin`; ``mesh.vertices`` is the bind pose
        (metres, Y up, facing +Z).
    bulge, jiggle, breathing : float, default 1.0
        Non-negative scales of the three effects (1 = realistic, 0 = off).
    seed : int, default 0
        Draws the breathing phase.

    Attributes
    ----------
    regions : dict of str to (V,) float64
        Region weights in 0..1 of the jiggle regions ``belly``, ``chest``,
        ``thigh_l``, ``thigh_r``, ``upperarm_l``, ``upperarm_r`` (all zero for a
        region the rig lacks); breathing uses ``chest`` and ``belly``.
    segments : dict of str to (V,) float64
        Skin weight of each vertex on each body segment (rows sum to 1).

    Examples
    --------
    >>> tissue = SoftTissue(body, jiggle=0.5)                  # doctest: +SKIP
    >>> posed = posed + tissue.displacements(motion, posed)   # doctest: +SKIP
    """

    def __init__(
        self,
        mesh: Mesh,
        *,
        bulge: float = 1.0,
        jiggle: float = 1.0,
        breathing: float = 1.0,
        seed: int = 0,
    ) -> None:
        if not isinstance(mesh, Mesh) or mesh.skin is None:
            raise ValidationError("mesh: expected a Mesh with a skin (bind it first)")
        amps = {}
        for key, value in (("bulge", bulge), ("jiggle", jiggle), ("breathing", breathing)):
            try:
                x = float(value)
            except (TypeError, ValueError):
                raise ValidationError(
                    f"{key}: expected a non-negative number, got {value!r}"
                ) from None
            if not np.isfinite(x) or x < 0:
                raise ValidationError(f"{key}: expected a non-negative finite scale, got {value!r}")
            amps[key] = x
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValidationError(f"seed: expected a non-negative integer, got {seed!r}")
        self.mesh = mesh
        self.skin = mesh.skin
        self.bulge = amps["bulge"]
        self.jiggle = amps["jiggle"]
        self.breathing = amps["breathing"]
        self.seed = int(seed)
        self.breath_phase = float(np.random.default_rng(self.seed).uniform(0.0, 2.0 * np.pi))

        skel = self.skin.skeleton
        bind = self.skin.bind_matrices  # (J, 4, 4)
        self._bind = bind
        self._bind_pos = bind[:, :3, 3]  # (J, 3)
        seg_of = joint_segments(skel, self._bind_pos)
        self._seg_of = seg_of
        v = mesh.n_vertices
        names = sorted(set(seg_of))
        col = np.array([names.index(s) for s in seg_of])  # (J,)
        seg_w = np.zeros((v, len(names)))
        rows = np.repeat(np.arange(v), self.skin.joint_indices.shape[1])
        np.add.at(
            seg_w,
            (rows, col[self.skin.joint_indices.reshape(-1)]),
            self.skin.joint_weights.reshape(-1),
        )
        self.segments = {n: seg_w[:, k] for k, n in enumerate(names)}
        self._limbs = self._find_limbs(seg_of)
        self.regions = self._build_regions()
        self._bulge_profiles = self._build_bulge_profiles()
        # vertices any normal-based effect can touch, and their incident faces
        active = np.zeros(v, dtype=bool)
        for prof in self._bulge_profiles.values():
            active |= prof[0] > 0
        active |= (self.regions["belly"] > 0) | (self.regions["chest"] > 0)
        self._active = np.nonzero(active)[0]
        faces = mesh.faces
        touching = np.isin(faces, self._active).any(axis=1)
        self._faces = faces[touching]
        inc = _incidence(self._faces, v).tocsr()
        self._incidence_active = inc[self._active]

    # -------------------------------------------------------------- set-up
    def _seg(self, name: str) -> np.ndarray:
        return self.segments.get(name, np.zeros(self.mesh.n_vertices))

    def _first_joint(self, seg_of: list[str], seg: str) -> int | None:
        for j, s in enumerate(seg_of):
            if s == seg:
                return j
        return None

    def _find_limbs(self, seg_of: list[str]) -> list[_Limb]:
        limbs = []
        for side in ("l", "r"):
            for first, second, third, sign in (
                ("upperarm", "forearm", "hand", 1.0),
                ("thigh", "shin", "foot", -1.0),
            ):
                a = self._first_joint(seg_of, f"{first}_{side}")
                b = self._first_joint(seg_of, f"{second}_{side}")
                c = self._first_joint(seg_of, f"{third}_{side}")
                if a is None or b is None or c is None:
                    continue
                if (
                    min(
                        np.linalg.norm(self._bind_pos[b] - self._bind_pos[a]),
                        np.linalg.norm(self._bind_pos[c] - self._bind_pos[b]),
                    )
                    < 1e-4
                ):
                    continue
                limbs.append(_Limb(f"{first}_{side}", a, b, c, sign))
        return limbs

    def _axial(self, limb: _Limb) -> tuple[np.ndarray, np.ndarray]:
        """Position along the bone ``a -> b`` (V,) in 0..1 and radial unit vectors (V, 3)."""
        pa, pb = self._bind_pos[limb.a], self._bind_pos[limb.b]
        axis = pb - pa
        length2 = float(axis @ axis)
        rel = self.mesh.vertices - pa
        s = rel @ axis / length2
        radial = _unit(rel - np.clip(s, 0.0, 1.0)[:, None] * axis)
        return s, radial

    def _build_regions(self) -> dict[str, np.ndarray]:
        v = self.mesh.vertices
        normals = vertex_normals(v, self.mesh.faces)
        front = _smoothstep((normals[:, 2] - 0.05) / 0.55)
        lm = find_landmarks(self.skin.skeleton)
        hip_y = [self._bind_pos[lm[k], 1] for k in ("thigh_l", "thigh_r") if k in lm]
        low = sum(self._seg(s) for s in _TORSO_LOW)
        high = sum(self._seg(s) for s in _TORSO_HIGH)
        regions: dict[str, np.ndarray] = {}
        above_hips = _smoothstep((v[:, 1] - (np.mean(hip_y) if hip_y else v[:, 1].min())) / 0.08)
        regions["belly"] = np.clip(low * front * above_hips, 0.0, 1.0)
        # the chest ends at the base of the neck or the shoulder line, whichever is higher
        tops = [self._bind_pos[lm[k], 1] for k in ("neck", "upperarm_l", "upperarm_r") if k in lm]
        below_neck = _smoothstep((max(tops) - v[:, 1]) / 0.1) if tops else 1.0
        regions["chest"] = np.clip(high * front * below_neck, 0.0, 1.0)
        for limb in self._limbs:
            s, _ = self._axial(limb)
            along = np.sin(np.pi * np.clip(s, 0.0, 1.0)) ** 2
            regions[limb.region] = np.clip(
                self._seg(limb.region) * _smoothstep(along / 0.5), 0.0, 1.0
            )
        for name, *_ in JIGGLE_REGIONS:
            regions.setdefault(name, np.zeros(self.mesh.n_vertices))
        return regions

    def _build_bulge_profiles(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per limb: (V,) bump along the bone times the skin weight, and (V, 3) radial."""
        out = {}
        for limb in self._limbs:
            s, radial = self._axial(limb)
            along = np.sin(np.pi * np.clip((s - 0.1) / 0.8, 0.0, 1.0)) ** 2
            out[limb.region] = (along * self._seg(limb.region), radial)
        return out

    # -------------------------------------------------------------- effects
    def _check(self, motion: Motion, posed: Any) -> np.ndarray:
        if not isinstance(motion, Motion):
            raise ValidationError(f"motion: expected a Motion, got {type(motion).__name__}")
        skel = self.skin.skeleton
        if motion.skeleton.names != skel.names:
            other = next(
                (a for a, b in zip(motion.skeleton.names, skel.names, strict=False) if a != b),
                None,
            )
            raise ValidationError(
                f"motion: must be on the mesh's skeleton ({skel.n_joints} joints); "
                f"got {motion.skeleton.n_joints} joints"
                + (f", first differing joint {other!r}" if other else "")
            )
        arr = np.asarray(posed, dtype=np.float64)
        shape = (motion.n_frames, self.mesh.n_vertices, 3)
        if arr.shape != shape:
            raise ValidationError(f"posed: expected shape {shape}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValidationError("posed: must be finite (no NaN or inf)")
        return arr

    def flexion(self, world: np.ndarray) -> dict[str, tuple[np.ndarray, float, np.ndarray]]:
        """Flexion of each limb's joint from world joint transforms.

        Parameters
        ----------
        world : (T, J, 4, 4) float, metres
            Forward kinematics of a motion on the mesh's skeleton.

        Returns
        -------
        dict of region name to ((T,) radians, float radians, (T, 3) unit vectors)
            The flexion angle (between the two bone directions, 0 for a straight
            limb), its bind-pose value, and the muscle side (the fold direction,
            reversed for the thigh) in bind-pose coordinates of the region's bone
            (zero while the limb is straight).
        """
        out = {}
        p = world[:, :, :3, 3]
        for limb in self._limbs:
            u = _unit(p[:, limb.b] - p[:, limb.a])  # (T, 3)
            w = _unit(p[:, limb.c] - p[:, limb.b])
            ub = _unit(self._bind_pos[limb.b] - self._bind_pos[limb.a])
            wb = _unit(self._bind_pos[limb.c] - self._bind_pos[limb.b])
            bind_angle = float(np.arccos(np.clip(ub @ wb, -1.0, 1.0)))
            angle = np.arccos(np.clip(np.sum(u * w, axis=-1), -1.0, 1.0))
            fold = _unit(w - np.sum(u * w, axis=-1, keepdims=True) * u) * limb.fold_sign
            # world -> bone -> bind: B_a R_a(t)^T fold
            r = world[:, limb.a, :3, :3]
            local = np.einsum("tji,tj->ti", r, fold)
            side = np.einsum("ij,tj->ti", self._bind[limb.a, :3, :3], local)
            out[limb.region] = (angle, bind_angle, _unit(side))
        return out

    def _bulge_heights(self, world: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(T, len(idx)) outward bulge heights of the vertices ``idx``, metres.

        The height follows ``(1 - cos theta)`` of the flexion, minus its bind-pose
        value (the bind mesh already has that much), never negative.
        """
        height = np.zeros((world.shape[0], idx.size))
        for region, (angle, bind_angle, side) in self.flexion(world).items():
            amp, ref = _BULGE[region.rsplit("_", 1)[0]]
            gain = amp / (1.0 - np.cos(np.radians(ref)))
            scale = gain * np.maximum(np.cos(bind_angle) - np.cos(angle), 0.0)  # (T,)
            along, radial = self._bulge_profiles[region]
            around = np.maximum(side @ radial[idx].T, 0.0) ** 2  # (T, n)
            height += scale[:, None] * along[idx][None, :] * around
        return height

    def _breath_heights(self, n_frames: int, rate: float, idx: np.ndarray) -> np.ndarray:
        """(T, len(idx)) breathing expansion of the vertices ``idx``, metres."""
        t = np.arange(n_frames) / rate
        phase = 2.0 * np.pi * _BREATH_HZ * t + self.breath_phase
        chest = 0.5 * (1.0 - np.cos(phase))  # (T,)
        belly = 0.5 * (1.0 - np.cos(phase - _BREATH_LAG))
        return (
            _BREATH_CHEST * chest[:, None] * self.regions["chest"][idx][None, :]
            + _BREATH_BELLY * belly[:, None] * self.regions["belly"][idx][None, :]
        )

    def spring_offsets(self, world: np.ndarray, rate: float) -> dict[str, np.ndarray]:
        """Jiggle spring offsets of every region.

        Parameters
        ----------
        world : (T, J, 4, 4) float, metres
        rate : float, Hz

        Returns
        -------
        dict of region name to (T, 3) float64, metres
            The offset of the region's tissue from its rest place on the bone,
            zero in the first two frames (the spring starts at rest), clipped to
            5 cm.
        """
        t = world.shape[0]
        p = world[:, :, :3, 3]
        lm = find_landmarks(self.skin.skeleton)
        anchors: dict[str, np.ndarray] = {}
        torso_low = lm.get("spine", lm["hips"])
        torso_high = lm.get("upper_chest", lm.get("chest", torso_low))
        anchors["belly"] = p[:, torso_low]
        anchors["chest"] = p[:, torso_high]
        for limb in self._limbs:
            anchors[limb.region] = 0.5 * (p[:, limb.a] + p[:, limb.b])
        dt = 1.0 / rate
        out = {}
        for name, freq, zeta, gain in JIGGLE_REGIONS:
            if name not in anchors or t < 3:
                out[name] = np.zeros((t, 3))
                continue
            x = anchors[name]
            acc = np.zeros((t, 3))
            acc[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / (dt * dt)
            b, a = _spring_filter(freq, zeta, gain, dt)
            off = lfilter(b, a, acc, axis=0)
            norm = np.linalg.norm(off, axis=1, keepdims=True)
            out[name] = off * np.minimum(1.0, _JIGGLE_LIMIT / np.where(norm > 0, norm, 1.0))
        return out

    def displacements(self, motion: Motion, posed: np.ndarray) -> np.ndarray:
        """Soft-tissue displacement of every vertex in every frame.

        Parameters
        ----------
        motion : Motion
            On the mesh's skeleton (same joint names and order), metres.
        posed : (T, V, 3) float, metres
            The skinned vertices of ``motion`` (e.g. from
            :func:`skincap.deform.skeletal.deformers.skin_motion`); they give the surface
            normals. Must be finite.

        Returns
        -------
        (T, V, 3) float64, metres
            Add to ``posed``. Exactly zero when all three amplitudes are 0, and on
            vertices outside every region (head, hands, feet...). Never NaN.

        Raises
        ------
        ValidationError
            A motion on another skeleton, or ``posed`` of the wrong shape or not finite.
        """
        arr = self._check(motion, posed)
        n_frames, n_vertices = arr.shape[:2]
        out = np.zeros((n_frames, n_vertices, 3))
        if n_frames == 0:
            return out
        world = forward_kinematics(motion)
        idx = self._active
        if (self.bulge > 0 or self.breathing > 0) and idx.size:
            height = np.zeros((n_frames, idx.size))
            if self.bulge > 0:
                height += self.bulge * self._bulge_heights(world, idx)
            if self.breathing > 0:
                height += self.breathing * self._breath_heights(n_frames, motion.rate, idx)
            for s in range(0, n_frames, _CHUNK):
                e = min(n_frames, s + _CHUNK)
                normals = _normals_with(self._incidence_active, arr[s:e], self._faces)
                out[s:e, idx] = height[s:e, :, None] * normals  # (t, A, 3)
        if self.jiggle > 0:
            springs = self.spring_offsets(world, motion.rate)
            for name, offset in springs.items():
                weight = self.regions[name]
                idx = np.nonzero(weight > 0)[0]
                out[:, idx] += self.jiggle * weight[idx][None, :, None] * offset[:, None, :]
        return out


def _spring_filter(
    freq: float, zeta: float, gain: float, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """IIR coefficients of ``x'' + 2 zeta w x' + w^2 x = -gain * a`` sampled every ``dt``.

    Discretised with the bilinear (Tustin) transform with frequency pre-warping at the
    natural frequency, which keeps the filter stable for any rate.
    """
    w = 2.0 * np.pi * freq
    k = w / np.tan(w * dt / 2.0)  # pre-warped 2/dt
    # H(s) = -gain / (s^2 + 2 zeta w s + w^2), s = k (1 - z^-1) / (1 + z^-1)
    a0 = k * k + 2.0 * zeta * w * k + w * w
    a1 = 2.0 * (w * w - k * k)
    a2 = k * k - 2.0 * zeta * w * k + w * w
    b = -gain * np.array([1.0, 2.0, 1.0]) / a0
    a = np.array([1.0, a1 / a0, a2 / a0])
    return b, a
