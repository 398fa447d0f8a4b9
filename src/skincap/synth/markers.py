"""Marker sets fixed to the skin: Park & Hodgins' dense grid and a conventional sparse set.

A marker is a point of the body surface given by a triangle and barycentric
coordinates, so it follows the skin in every pose; :func:`place_markers` puts it on
the posed mesh, lifted by the marker radius along the interpolated vertex normal.

Dense layout (Park & Hodgins 2006, section 4: ~350 markers of 3 mm on a 4-5 cm grid
over the whole body, with additional markers at the tip of the elbow and the lower
part of the shoulder blade; hands, feet and head sparsely): blue-noise (Poisson-disk)
sampling of the surface whose local spacing grows on hands, feet, head and neck
(found from the skin weights by joint-name keywords, CMU and MakeHuman names),
plus extra markers at elbows, knees and shoulder blades. The spacing is adjusted to
hit the target count. Its *marker surface* -- the triangulation whose vertices are the
markers, which Park & Hodgins built by hand from geodesic neighbours -- is the dual of
the geodesic Voronoi partition of the mesh by nearest marker.

Sparse layout: 41 markers on bony landmarks with CMU-like labels (LFHD, C7, CLAV,
LSHO, LELB, LWRA, LASI, LKNE, LANK, LHEE, LTOE, ...), each found by a ray from a joint
(or a point between joints) in an anatomical direction to the skin.

Conventions: metres, Y up, the body faces +Z and its left is +X.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from skincap.deform.skeletal.name_maps import CONVENTIONS, detect_convention
from skincap.errors import ValidationError
from skincap.geometry.kinematics import rest_positions
from skincap.geometry.raycast import closest_points_on_mesh, first_ray_hits
from skincap.synth.surface_sampling import (
    greedy_blue_noise,
    sample_surface,
    vertex_normals,
    voronoi_dual,
)
from skincap.types import Mesh, Skeleton, Skin

__all__ = [
    "MarkerLayout",
    "REGION_SPACING",
    "SPARSE_LABELS",
    "dense_marker_layout",
    "sparse_marker_layout",
    "place_markers",
    "marker_surface",
]

#: Spacing multiplier per body region (joint-name keywords decide the region).
REGION_SPACING: dict[str, float] = {"body": 1.0, "neck": 1.4, "head": 2.0, "hand": 2.2, "foot": 2.2}

_REGION_KEYWORDS: dict[str, tuple[str, ...]] = {
    # order matters: the first region whose keyword is in the (lower-case) name wins
    "hand": ("hand", "finger", "thumb", "metacarpal", "wrist", "palm"),
    "foot": ("foot", "toe", "ankle", "heel"),
    "head": (
        "head", "jaw", "eye", "tongue", "oris", "levator", "orbicularis", "oculi",
        "temporalis", "risorius", "special", "nose", "ear", "skull",
    ),
    "neck": ("neck",),
}  # fmt: skip


@dataclass(eq=False)
class MarkerLayout:
    """Markers attached to a mesh's surface.

    Attributes
    ----------
    face : (N,) int64
        Triangle of the mesh each marker sits on.
    bary : (N, 3) float64
        Barycentric coordinates in that triangle (non-negative, rows sum to 1).
    labels : list of N str
        Unique marker labels.
    surface_faces : (F, 3) int64 or None
        The marker surface: triangles over marker indices, counter-clockwise seen
        from outside (dense layouts); None for sparse layouts.
    meta : dict
        ``kind`` ("dense"/"sparse"), ``spacing`` (metres), ``region`` and ``role``
        lists per marker, surface statistics...
    """

    face: np.ndarray
    bary: np.ndarray
    labels: list[str]
    surface_faces: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.face = np.asarray(self.face, dtype=np.int64)
        n = self.face.shape[0]
        self.bary = np.asarray(self.bary, dtype=np.float64)
        if self.face.ndim != 1 or self.bary.shape != (n, 3):
            raise ValidationError(
                f"face, bary: expected (N,) and (N, 3), got {self.face.shape} and {self.bary.shape}"
            )
        if not np.isfinite(self.bary).all():
            raise ValidationError("bary: must be finite")
        self.labels = [str(s) for s in self.labels]
        if len(self.labels) != n or len(set(self.labels)) != n:
            raise ValidationError(f"labels: expected {n} unique labels, got {len(self.labels)}")
        if self.surface_faces is not None:
            sf = np.asarray(self.surface_faces, dtype=np.int64).reshape(-1, 3)
            if sf.size and (sf.min() < 0 or sf.max() >= n):
                raise ValidationError(f"surface_faces: marker indices must be in 0..{n - 1}")
            self.surface_faces = sf
        self.meta = dict(self.meta)

    @property
    def n_markers(self) -> int:
        return int(self.face.shape[0])


# ------------------------------------------------------------------ small helpers
def _check_mesh(mesh: Mesh) -> None:
    if not isinstance(mesh, Mesh):
        raise ValidationError(f"mesh: expected a Mesh, got {type(mesh).__name__}")
    if mesh.n_faces == 0:
        raise ValidationError("mesh: has no triangles")


def _joint_positions(
    mesh: Mesh, joints: Skeleton | Skin | Mapping[str, Any] | None
) -> dict[str, np.ndarray]:
    """Joint name -> (3,) world position in the mesh's pose."""
    if joints is None:
        if mesh.skin is None:
            raise ValidationError(
                "joints: the mesh has no skin; pass a Skeleton, a Skin or a {name: (3,)} mapping"
            )
        joints = mesh.skin
    if isinstance(joints, Skin):
        pos = joints.bind_matrices[:, :3, 3]
        names = joints.skeleton.names
    elif isinstance(joints, Skeleton):
        pos = rest_positions(joints)
        names = joints.names
    elif isinstance(joints, Mapping):
        names = [str(k) for k in joints]
        pos = np.asarray([np.asarray(joints[k], dtype=np.float64) for k in joints])
        if pos.shape != (len(names), 3) or not np.isfinite(pos).all():
            raise ValidationError("joints: expected finite (3,) positions per joint name")
    else:
        raise ValidationError(
            f"joints: expected a Skeleton, Skin or mapping, got {type(joints).__name__}"
        )
    return {n: p for n, p in zip(names, pos, strict=True)}


def _unit(x: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def _landmark_joints(pos: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Canonical landmark positions (hips, neck, head, per side shoulder, elbow, ...).

    Uses a built-in naming convention when one is recognised, else keywords.
    """
    names = list(pos)
    conv = detect_convention(names)
    out: dict[str, np.ndarray] = {}
    if conv is not None:
        for key, value in CONVENTIONS[conv].items():
            group = (value,) if isinstance(value, str) else value
            got = [pos[n] for n in group if n in pos]
            if got:
                out[key] = np.mean(got, axis=0)
        if conv == "cmu_bvh11":  # "lhand" sits past the wrist; the wrist joint is its parent
            for side, name in (("l", "LeftWrist"), ("r", "RightWrist")):
                if name in pos:
                    out[f"hand_{side}"] = pos[name]
    else:
        keys = {
            "head": ("head",),
            "neck": ("neck",),
            "upperarm": ("upperarm", "shoulder", "arm"),
            "forearm": ("forearm", "lowerarm", "elbow"),
            "hand": ("hand", "wrist"),
            "thigh": ("upleg", "upperleg", "thigh", "hip"),
            "shin": ("lowerleg", "knee", "shin", "leg"),
            "foot": ("foot", "ankle"),
            "toe": ("toe",),
        }
        low = {n: n.lower() for n in names}

        def side_of(n: str) -> str | None:
            s = low[n]
            if s.startswith("left") or s.endswith((".l", "_l")) or s.startswith(("l_", "l")):
                return "l" if not s.startswith(("r", "right")) else None
            if s.startswith("right") or s.endswith((".r", "_r")) or s.startswith(("r_", "r")):
                return "r"
            return None

        for key, kws in keys.items():
            for n in names:
                if any(k in low[n] for k in kws):
                    sd = side_of(n)
                    name = key if key in ("head", "neck") else f"{key}_{sd}" if sd else None
                    if name and name not in out:
                        out[name] = pos[n]
    needed = ["head", "neck"] + [
        f"{k}_{s}" for s in "lr" for k in ("upperarm", "forearm", "hand", "thigh", "shin", "foot")
    ]
    missing = [k for k in needed if k not in out]
    if missing:
        raise ValidationError(
            f"joints: cannot find the landmarks {missing} among the joint names "
            f"(known conventions: {sorted(CONVENTIONS)})"
        )
    for s in "lr":
        if f"toe_{s}" not in out:
            out[f"toe_{s}"] = out[f"foot_{s}"] + np.array([0.0, -0.05, 0.12])
    out["pelvis"] = 0.5 * (out["thigh_l"] + out["thigh_r"])
    return out


def _hand_end(pos: dict[str, np.ndarray], lm: dict[str, np.ndarray], side: str) -> np.ndarray:
    """Knuckles (finger bases): most distant joint beyond the wrist, at 65 %, or extrapolated."""
    wrist = lm[f"hand_{side}"]
    elbow = lm[f"forearm_{side}"]
    forearm = wrist - elbow
    cand = np.array(list(pos.values()))
    along = (cand - wrist) @ _unit(forearm)
    lateral = np.linalg.norm(cand - wrist - along[:, None] * _unit(forearm), axis=1)
    ok = (along > 0.02) & (along < 0.25) & (lateral < 0.08)
    if ok.any():
        far = cand[ok][np.argmax(along[ok])]
        return wrist + 0.65 * (far - wrist)
    return wrist + 0.085 * _unit(forearm)


def _perp(direction: np.ndarray, bone: np.ndarray) -> np.ndarray:
    """``direction`` with its component along ``bone`` removed, normalised.

    When ``direction`` is (nearly) parallel to the bone, up (then forward) is mixed in.
    """
    b = _unit(bone)
    for extra in (np.zeros(3), np.array([0.0, 0.5, 0.0]), np.array([0.0, 0.0, 0.5])):
        d = np.asarray(direction, dtype=np.float64) + extra
        r = d - (d @ b) * b
        if np.linalg.norm(r) > 1e-3 * max(np.linalg.norm(d), 1e-12):
            return _unit(r)
    return _unit(np.cross(b, [0.0, 0.0, 1.0]))


def _head_centre(mesh: Mesh, lm: dict[str, np.ndarray]) -> np.ndarray:
    head = lm["head"]
    near = np.linalg.norm(mesh.vertices[:, [0, 2]] - head[[0, 2]], axis=1) < 0.15
    top = mesh.vertices[near, 1].max() if near.any() else head[1] + 0.2
    return np.array([head[0], 0.5 * (head[1] + top), head[2]])


def _landmark_rays(
    mesh: Mesh, pos: dict[str, np.ndarray]
) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Labels, origins (K, 3) and directions (K, 3) of the sparse landmarks."""
    lm = _landmark_joints(pos)
    x, y, z = np.eye(3)
    hc = _head_centre(mesh, lm)
    pelvis, neck = lm["pelvis"], lm["neck"]
    trunk = neck - pelvis
    labels: list[str] = []
    origins: list[np.ndarray] = []
    dirs: list[np.ndarray] = []

    def add(label: str, origin: np.ndarray, direction: np.ndarray) -> None:
        labels.append(label)
        origins.append(np.asarray(origin, dtype=np.float64))
        dirs.append(_unit(np.asarray(direction, dtype=np.float64)))

    add("C7", pelvis + 1.0 * trunk, -z + 0.3 * y)
    add("T10", pelvis + 0.55 * trunk, -z)
    add("CLAV", pelvis + 0.92 * trunk, z)
    add("STRN", pelvis + 0.68 * trunk, z)
    add("RBAK", pelvis + 0.8 * trunk - 0.07 * x, -z)
    for s, sx in (("L", 1.0), ("R", -1.0)):
        k = s.lower()
        side = sx * x
        sh, el, wr = lm[f"upperarm_{k}"], lm[f"forearm_{k}"], lm[f"hand_{k}"]
        hip, kn, an, toe = lm[f"thigh_{k}"], lm[f"shin_{k}"], lm[f"foot_{k}"], lm[f"toe_{k}"]
        upper, fore = el - sh, wr - el
        add(f"{s}FHD", hc, 0.45 * side + 0.25 * y + 0.85 * z)
        add(f"{s}BHD", hc, 0.45 * side + 0.25 * y - 0.85 * z)
        add(f"{s}SHO", sh, y + 0.25 * side)
        add(f"{s}UPA", sh + 0.5 * upper, _perp(side - 0.5 * z, upper))
        add(f"{s}ELB", el, _perp(side - 0.3 * z, fore))
        add(f"{s}FRM", el + 0.55 * fore, _perp(side - 0.3 * z, fore))
        add(f"{s}WRA", wr, _perp(z + 0.2 * side, fore))
        add(f"{s}WRB", wr, _perp(-z + 0.2 * side, fore))
        add(f"{s}FIN", _hand_end(pos, lm, k), _perp(y + side, fore))
        # iliac spines: ASIS above and lateral of the hip joint, PSIS over the sacral
        # dimples (Harrington et al. 2007 place the hip ~9 cm below and ~3 cm medial of
        # the ASIS); sparse_marker_layout then keeps them on skin bound to the pelvis
        up = _unit(trunk)
        add(f"{s}ASI", hip + ASIS_ABOVE_HIP_M * up + ASIS_LATERAL_OF_HIP_M * side, z + 0.25 * side)
        add(f"{s}PSI", pelvis + ASIS_ABOVE_HIP_M * up + PSIS_FROM_MIDLINE_M * side, -z)
        thigh, shin = kn - hip, an - kn
        add(f"{s}THI", hip + 0.55 * thigh, _perp(side + 0.3 * z, thigh))
        add(f"{s}KNE", kn, _perp(side, shin))
        add(f"{s}TIB", kn + 0.55 * shin, _perp(side + 0.3 * z, shin))
        add(f"{s}ANK", an, _perp(side, shin))
        add(f"{s}HEE", an + 0.3 * (an[1] - toe[1]) * -y, -z - 0.2 * y)
        add(f"{s}TOE", toe, y + 0.6 * z)
        add(f"{s}MT5", toe - 0.02 * z, side)
    return labels, np.array(origins), np.array(dirs)


#: Iliac-spine landmarks (metres): ASIS above and lateral of the hip joint centre, PSIS
#: from the midline at the same height (the sparse set's pelvis markers).
ASIS_ABOVE_HIP_M = 0.07
ASIS_LATERAL_OF_HIP_M = 0.03
PSIS_FROM_MIDLINE_M = 0.045

#: A pelvis marker sits on skin that follows the pelvis (the skeleton's root and the
#: joints between it and the hip joints, e.g. CMU ``LHipJoint``, MakeHuman ``pelvis.L``)
#: with at least this skinning weight; a landmark whose skin the body's weights give
#: partly to the spine or the thighs moves to the nearest vertex that does, so the
#: pelvis markers are a rigid cluster as on a real pelvis. A body with no such skin
#: (MakeHuman's weights give the hips' skin to spine04/05) keeps the landmarks.
PELVIS_BOUND_WEIGHT = 0.9

_PELVIS_LABELS = ("LASI", "RASI", "LPSI", "RPSI")


def _pelvis_weight(skin: Skin, hip_positions: np.ndarray) -> np.ndarray:
    """(V,) skinning weight of each vertex on the pelvis joints: the root and every
    ancestor of the joints at ``hip_positions (2, 3)`` (the hip joint centres)."""
    parents = skin.skeleton.parents
    where = skin.bind_matrices[:, :3, 3]  # (J, 3)
    pelvis = set(np.flatnonzero(parents < 0).tolist())
    for hip in hip_positions:
        j = int(np.argmin(np.linalg.norm(where - hip, axis=1)))
        while parents[j] >= 0:
            j = int(parents[j])
            pelvis.add(j)
    members = np.isin(skin.joint_indices, sorted(pelvis))
    return np.where(members, skin.joint_weights, 0.0).sum(axis=1)


def _bind_to_pelvis(
    mesh: Mesh, face: np.ndarray, bary: np.ndarray, which: np.ndarray, hips: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move markers ``which`` (bool (N,)) whose skin is bound to the pelvis
    (:func:`_pelvis_weight`) with a weight under :data:`PELVIS_BOUND_WEIGHT` to the
    nearest vertex bound at least that much (unchanged without a skin or such a vertex)."""
    if mesh.skin is None or not which.any():
        return face, bary
    w_pelvis = _pelvis_weight(mesh.skin, hips)
    bound = np.flatnonzero(w_pelvis >= PELVIS_BOUND_WEIGHT)
    if bound.size == 0:
        return face, bary
    corners = mesh.faces[face]  # (N, 3)
    loose = which & (np.einsum("nk,nk->n", bary, w_pelvis[corners]) < PELVIS_BOUND_WEIGHT)
    if not loose.any():
        return face, bary
    hit = np.einsum("lk,lkx->lx", bary[loose], mesh.vertices[corners[loose]])
    _, nearest = cKDTree(mesh.vertices[bound]).query(hit)
    vertex = bound[nearest]  # (L,)
    # the marker on that vertex, as the corner of one of its triangles
    used, first = np.unique(mesh.faces.ravel(), return_index=True)
    face, bary = face.copy(), bary.copy()
    face[loose] = first[np.searchsorted(used, vertex)] // 3
    bary[loose] = (mesh.faces[face[loose]] == vertex[:, None]).astype(np.float64)
    return face, bary


def _surface_points_from_rays(
    mesh: Mesh, origins: np.ndarray, dirs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Face and barycentric of each ray's first hit; closest surface point on a miss."""
    face, _, bary = first_ray_hits(mesh.vertices, mesh.faces, origins, dirs)
    miss = face < 0
    if miss.any():
        _, f2, b2 = closest_points_on_mesh(mesh.vertices, mesh.faces, origins[miss])
        face[miss] = f2
        bary[miss] = b2
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    return face, bary


#: Labels of :func:`sparse_marker_layout`, in order.
SPARSE_LABELS: tuple[str, ...] = (
    "C7", "T10", "CLAV", "STRN", "RBAK",
    *[
        f"{s}{n}"
        for s in "LR"
        for n in (
            "FHD", "BHD", "SHO", "UPA", "ELB", "FRM", "WRA", "WRB", "FIN",
            "ASI", "PSI", "THI", "KNE", "TIB", "ANK", "HEE", "TOE", "MT5",
        )
    ],
)  # fmt: skip


def sparse_marker_layout(
    mesh: Mesh, joints: Skeleton | Skin | Mapping[str, Any] | None = None
) -> MarkerLayout:
    """A conventional 41-marker set on bony landmarks, CMU-like labels.

    Each landmark is a ray from a joint (or a point between joints) in an anatomical
    direction -- LELB from the left elbow joint laterally, LASI from above and lateral
    of the hip joint forwards, LHEE from the ankle backwards -- and the marker is where
    the ray leaves the skin (the closest surface point if the ray misses). The four
    pelvis markers (LASI, RASI, LPSI, RPSI) stay on skin the mesh's skin binds to the
    pelvis (weight >= :data:`PELVIS_BOUND_WEIGHT` on the root and the joints up to the
    hips), the nearest such point to the landmark, so they move rigidly with it.

    Parameters
    ----------
    mesh : Mesh
        Closed triangle mesh in metres, in the pose of ``joints`` (Y up, facing +Z,
        left = +X).
    joints : Skeleton, Skin or mapping name -> (3,) position, optional
        Joint positions in the mesh's pose: a Skin's bind positions, a Skeleton's rest
        positions, or explicit positions. Default: ``mesh.skin``. Joint names may follow
        the CMU (bvh11 or cgspeed), Biovision or MakeHuman conventions; others are
        matched by keywords (head, neck, arm/forearm, hand/wrist, upleg/thigh, leg/knee,
        foot/ankle, toe and a Left/Right or .L/.R side).

    Returns
    -------
    MarkerLayout
        41 markers labelled as :data:`SPARSE_LABELS` (C7, T10, CLAV, STRN, RBAK and per
        side FHD, BHD, SHO, UPA, ELB, FRM, WRA, WRB, FIN, ASI, PSI, THI, KNE, TIB, ANK,
        HEE, TOE, MT5); ``surface_faces`` is None; ``meta["landmark_origin"]`` (41, 3)
        holds the ray origins.

    Raises
    ------
    ValidationError
        No skin/joints, or the landmark joints cannot be found by name.
    """
    _check_mesh(mesh)
    pos = _joint_positions(mesh, joints)
    labels, origins, dirs = _landmark_rays(mesh, pos)
    face, bary = _surface_points_from_rays(mesh, origins, dirs)
    lm = _landmark_joints(pos)
    hips = np.stack([lm["thigh_l"], lm["thigh_r"]])
    on_pelvis = np.isin(labels, _PELVIS_LABELS)
    landmark_face, landmark_bary = face[on_pelvis], bary[on_pelvis]
    face, bary = _bind_to_pelvis(mesh, face, bary, on_pelvis, hips)
    order = [labels.index(s) for s in SPARSE_LABELS]
    meta: dict[str, Any] = {"kind": "sparse", "landmark_origin": origins[order]}
    if mesh.skin is not None:
        # the iliac spines at their landmarks, carried by the pelvis bone itself
        pelvis_labels = [labels[k] for k in np.flatnonzero(on_pelvis)]
        meta["rigid"] = {
            "index": np.array([SPARSE_LABELS.index(x) for x in pelvis_labels], dtype=np.int64),
            "joint": pelvis_joint(mesh.skin, hips),
            "face": landmark_face,
            "bary": landmark_bary,
        }
    return MarkerLayout(
        face=face[order],
        bary=bary[order],
        labels=list(SPARSE_LABELS),
        surface_faces=None,
        meta=meta,
    )


def pelvis_joint(skin: Skin, hip_positions: np.ndarray) -> int:
    """The joint both hips hang from: the deepest common ancestor of the joints nearest
    the hip joint centres ``hip_positions (2, 3)`` (CMU ``Hips``, MakeHuman ``root``)."""
    parents = skin.skeleton.parents
    where = skin.bind_matrices[:, :3, 3]
    chains = []
    for hip in hip_positions:
        j = int(np.argmin(np.linalg.norm(where - hip, axis=1)))
        chain = set()
        while parents[j] >= 0:
            j = int(parents[j])
            chain.add(j)
        chains.append(chain)
    common = chains[0] & chains[1]
    return max(common) if common else int(np.flatnonzero(parents < 0)[0])


def place_rigid_markers(
    layout: MarkerLayout,
    mesh: Mesh,
    world: np.ndarray,
    positions: np.ndarray,
    normals: np.ndarray,
    *,
    radius: float = 0.0015,
) -> None:
    """Move the layout's bone-carried markers (``meta["rigid"]``) with their joint, in place.

    Each such marker sits at its landmark on the bind-pose skin (``radius`` along the
    normal) and moves rigidly with the joint: ``W_t B^-1`` applied to it, ``W_t`` the
    joint's world transform in frame t and ``B`` its bind matrix -- on the bone rather
    than on skin that the body's weights share with the spine and the thighs, so the
    sparse set's pelvis markers are a rigid cluster over the pelvis's real width.

    Parameters
    ----------
    layout : MarkerLayout
    mesh : Mesh
        The skinned bind-pose body the layout was made on.
    world : (T, J, 4, 4) float
        World transforms of the skin's joints per frame (metres).
    positions, normals : (T, N, 3) float
        :func:`place_markers` of the layout on the posed frames; overwritten for the
        rigid markers. A layout without ``meta["rigid"]`` is left as it is.
    """
    rigid = layout.meta.get("rigid")
    if rigid is None or mesh.skin is None:
        return
    rest = MarkerLayout(
        face=rigid["face"], bary=rigid["bary"], labels=[str(k) for k in rigid["index"]]
    )
    p0, n0 = place_markers(rest, mesh.vertices, mesh.faces, radius=radius)  # (K, 3)
    move = world[:, rigid["joint"]] @ np.linalg.inv(mesh.skin.bind_matrices[rigid["joint"]])
    rot, shift = move[:, :3, :3], move[:, :3, 3]  # (T, 3, 3), (T, 3)
    positions[:, rigid["index"]] = np.einsum("tij,kj->tki", rot, p0) + shift[:, None]
    normals[:, rigid["index"]] = np.einsum("tij,kj->tki", rot, n0)


# ---------------------------------------------------------------- dense layout
def _region_spacing(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex spacing multiplier (V,) and region index (V,) (into REGION_SPACING)."""
    regions = list(REGION_SPACING)
    n_v = mesh.n_vertices
    if mesh.skin is None:
        return np.ones(n_v), np.zeros(n_v, dtype=np.int64)
    names = [n.lower() for n in mesh.skin.skeleton.names]
    joint_region = np.zeros(len(names), dtype=np.int64)
    for j, n in enumerate(names):
        for r, kws in _REGION_KEYWORDS.items():
            if any(k in n for k in kws):
                joint_region[j] = regions.index(r)
                break
    share = np.zeros((n_v, len(regions)))
    rows = np.repeat(np.arange(n_v), mesh.skin.joint_indices.shape[1])
    np.add.at(
        share,
        (rows, joint_region[mesh.skin.joint_indices.ravel()]),
        mesh.skin.joint_weights.ravel(),
    )
    scale = share @ np.array([REGION_SPACING[r] for r in regions])
    return scale, np.argmax(share, axis=1)


def _dense_extras(mesh: Mesh) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Extra markers (Park & Hodgins: elbow tip, lower shoulder blade; plus knees)."""
    pos = _joint_positions(mesh, None)
    lm = _landmark_joints(pos)
    x, y, z = np.eye(3)
    roles: list[str] = []
    origins: list[np.ndarray] = []
    dirs: list[np.ndarray] = []
    pelvis, neck = lm["pelvis"], lm["neck"]
    for s, sx in (("L", 1.0), ("R", -1.0)):
        k = s.lower()
        side = sx * x
        sh, el, wr = lm[f"upperarm_{k}"], lm[f"forearm_{k}"], lm[f"hand_{k}"]
        kn, an = lm[f"shin_{k}"], lm[f"foot_{k}"]
        fore, shin = wr - el, an - kn
        for role, o, dvec in (
            (f"{s}_elbow_tip", el, _perp(-z, fore)),
            (f"{s}_elbow_lateral", el, _perp(side + y, fore)),
            (f"{s}_elbow_medial", el, _perp(-side - y, fore)),
            (f"{s}_knee_front", kn, _perp(z, shin)),
            (f"{s}_knee_lateral", kn, _perp(side, shin)),
            (f"{s}_knee_medial", kn, _perp(-side, shin)),
            (
                f"{s}_scapula_low",
                pelvis + 0.72 * (neck - pelvis) + 0.5 * (sh - neck) * [1, 0, 0],
                -z,
            ),
        ):
            roles.append(role)
            origins.append(np.asarray(o, dtype=np.float64))
            dirs.append(_unit(np.asarray(dvec, dtype=np.float64)))
    return roles, np.array(origins), np.array(dirs)


def _unique_seed_vertices(mesh: Mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """A distinct mesh vertex per marker: its nearest corner, else the nearest free vertex."""
    corners = mesh.faces[face]  # (N, 3)
    order = np.argsort(-bary, axis=1)
    seed = corners[np.arange(face.size), order[:, 0]]
    _, first = np.unique(seed, return_index=True)
    dup = np.setdiff1d(np.arange(seed.size), first)
    if dup.size:
        pts = np.einsum("nk,nkx->nx", bary, mesh.vertices[corners])
        tree = cKDTree(mesh.vertices)
        taken = set(seed[first].tolist())
        _, near = tree.query(pts[dup], k=16)
        for row, m in enumerate(dup):  # a handful of markers at most
            free = [int(c) for c in near[row] if int(c) not in taken]
            if not free:
                raise ValidationError("markers: two markers are too close to separate on the mesh")
            seed[m] = free[0]
            taken.add(free[0])
    return seed


def marker_surface(mesh: Mesh, layout: MarkerLayout) -> tuple[np.ndarray, dict[str, int]]:
    """The ground-truth marker surface of a layout (see :func:`voronoi_dual`).

    Returns
    -------
    surface_faces : (P, 3) int64
        Triangles over marker indices, counter-clockwise seen from outside.
    stats : dict
        As :func:`voronoi_dual`.
    """
    seeds = _unique_seed_vertices(mesh, layout.face, layout.bary)
    _, tri, stats = voronoi_dual(mesh.vertices, mesh.faces, seeds)
    return tri, stats


def dense_marker_layout(
    mesh: Mesh,
    *,
    spacing: float = 0.045,
    target: int | None = 350,
    seed: int = 0,
    n_candidates: int | None = None,
) -> MarkerLayout:
    """Park & Hodgins' dense layout: a ~4-5 cm blue-noise grid plus elbow/knee extras.

    Candidates are area-weighted random surface points; a greedy Poisson-disk pass
    keeps a maximal subset whose local spacing is ``spacing`` times the region
    factor (:data:`REGION_SPACING`: torso, arms, legs 1; neck 1.4; head 2; hands and
    feet 2.2; from the skin weights, blended). Extra markers are placed first and the
    grid keeps clear of them: at each elbow (tip, lateral, medial), each knee (front,
    lateral, medial) and the lower part of each shoulder blade. With ``target`` the
    spacing is rescaled (count ~ 1 / spacing^2) until the count is within 3 % of it.

    Parameters
    ----------
    mesh : Mesh
        Closed triangle mesh in metres, with a Skin (joint names give the regions
        and the extra markers' joints). Y up, facing +Z, left = +X.
    spacing : float, default 0.045
        Grid spacing on the torso, metres (the start value when ``target`` is set).
    target : int or None, default 350
        Wanted number of markers (extras included); None keeps ``spacing``.
    seed : int, default 0
        Candidate sampling and priorities; the same seed gives the same layout.
    n_candidates : int, optional
        Surface candidates (default ``max(20000, 40 * target)``).

    Returns
    -------
    MarkerLayout
        Labels ``D000``...; ``surface_faces`` the marker surface
        (:func:`marker_surface`); ``meta``: ``spacing`` (final, metres), ``region``
        (N,) names, ``role`` (N,) ``"grid"`` or the extra's role (e.g.
        ``"L_elbow_tip"``), ``surface_stats``.

    Raises
    ------
    ValidationError
        Bad arguments or a mesh without a skin.
    """
    _check_mesh(mesh)
    if mesh.skin is None:
        raise ValidationError("mesh: the dense layout needs a skinned mesh (regions, joints)")
    s = float(spacing)
    if not (s > 0 and np.isfinite(s)):
        raise ValidationError(f"spacing: expected a positive length in metres, got {spacing!r}")
    if target is not None and int(target) < 20:
        raise ValidationError(f"target: expected at least 20 markers, got {target!r}")
    rng = np.random.default_rng(seed)
    n_cand = int(n_candidates) if n_candidates else max(20000, 40 * int(target or 350))
    v, f = mesh.vertices, mesh.faces
    scale_v, region_v = _region_spacing(mesh)
    cf, cb, cp = sample_surface(v, f, n_cand, rng)
    normals_v = vertex_normals(v, f)
    cn = _unit(np.einsum("nk,nkx->nx", cb, normals_v[f[cf]]))
    c_scale = np.einsum("nk,nk->n", cb, scale_v[f[cf]])
    c_region = region_v[f[cf, np.argmax(cb, axis=1)]]
    roles, eo, ed = _dense_extras(mesh)
    ef, eb = _surface_points_from_rays(mesh, eo, ed)
    ep = np.einsum("nk,nkx->nx", eb, v[f[ef]])
    en = _unit(np.einsum("nk,nkx->nx", eb, normals_v[f[ef]]))
    pts = np.concatenate([ep, cp])
    nrm = np.concatenate([en, cn])
    forced = np.zeros(pts.shape[0], dtype=bool)
    forced[: len(roles)] = True
    rel = np.concatenate([np.full(len(roles), 0.6), c_scale])
    priority = np.concatenate([np.zeros(len(roles)), rng.permutation(n_cand) + 1.0])

    keep = greedy_blue_noise(pts, nrm, s * rel, priority, forced)
    if target is not None:
        for _ in range(12):
            if abs(keep.size - target) <= 0.03 * target:
                break
            s *= float(np.sqrt(keep.size / target))
            keep = greedy_blue_noise(pts, nrm, s * rel, priority, forced)
    face = np.concatenate([ef, cf])[keep]
    bary = np.concatenate([eb, cb])[keep]
    regions = list(REGION_SPACING)
    reg = np.concatenate([region_v[f[ef, np.argmax(eb, axis=1)]], c_region])[keep]
    role = [roles[k] if k < len(roles) else "grid" for k in keep]
    labels = [f"D{i:03d}" for i in range(keep.size)]
    layout = MarkerLayout(
        face=face,
        bary=bary,
        labels=labels,
        meta={
            "kind": "dense",
            "spacing": s,
            "region": [regions[r] for r in reg],
            "role": role,
        },
    )
    tri, stats = marker_surface(mesh, layout)
    layout.surface_faces = tri
    layout.meta["surface_stats"] = stats
    return layout


# ------------------------------------------------------------------ placement
def place_markers(
    layout: MarkerLayout,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    radius: float = 0.0015,
) -> tuple[np.ndarray, np.ndarray]:
    """Marker centres on a posed mesh: barycentric point plus ``radius`` along the normal.

    Parameters
    ----------
    layout : MarkerLayout
    vertices : (T, V, 3) or (V, 3) float, metres
        The posed mesh (same topology as the layout's mesh). Must be finite.
    faces : (F, 3) int
    radius : float, default 0.0015
        Marker radius, metres (Park & Hodgins: 3 mm markers).

    Returns
    -------
    positions : (T, N, 3) or (N, 3) float64, metres
    normals : (T, N, 3) or (N, 3) float64
        Unit interpolated vertex normals (area-weighted vertex normals of the posed
        mesh, barycentrically blended and normalised).

    Raises
    ------
    ValidationError
        Shapes, non-finite vertices or a layout face outside the mesh.
    """
    v = np.asarray(vertices, dtype=np.float64)
    single = v.ndim == 2
    vt = v[None] if single else v
    if vt.ndim != 3 or vt.shape[2] != 3:
        raise ValidationError(f"vertices: expected (T, V, 3) or (V, 3), got {v.shape}")
    if not np.isfinite(vt).all():
        raise ValidationError("vertices: must be finite")
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= vt.shape[1])):
        raise ValidationError(f"faces: expected (F, 3) indices into {vt.shape[1]} vertices")
    if layout.n_markers and layout.face.max() >= f.shape[0]:
        raise ValidationError("layout: marker faces are outside the mesh (another topology?)")
    r = float(radius)
    if not (r >= 0 and np.isfinite(r)):
        raise ValidationError(f"radius: expected a non-negative length, got {radius!r}")
    corners = f[layout.face]  # (N, 3)
    need = np.unique(corners)
    # normals only of the vertices the markers use: their incident faces
    inc = np.isin(f, need).any(axis=1)
    sub_f = f[inc]
    fn = np.cross(
        vt[:, sub_f[:, 1]] - vt[:, sub_f[:, 0]], vt[:, sub_f[:, 2]] - vt[:, sub_f[:, 0]]
    )  # (T, Fs, 3)
    n_v = vt.shape[1]
    mat = sp.csr_matrix(
        (np.ones(sub_f.size), (sub_f.ravel(), np.repeat(np.arange(sub_f.shape[0]), 3))),
        shape=(n_v, sub_f.shape[0]),
    )[need]
    vn = (mat @ fn.transpose(1, 0, 2).reshape(sub_f.shape[0], -1)).reshape(need.size, -1, 3)
    vn = _unit(vn.transpose(1, 0, 2))  # (T, U, 3)
    local = np.searchsorted(need, corners)  # (N, 3)
    nrm = _unit(np.einsum("nk,tnkx->tnx", layout.bary, vn[:, local]))
    surf = np.einsum("nk,tnkx->tnx", layout.bary, vt[:, corners])
    pos = surf + r * nrm
    if single:
        return pos[0], nrm[0]
    return pos, nrm
