"""The skinning artefacts Mazrimas & Beinaravicius name, measured: LBS, DQS and sweeps.

Linear blend skinning averages matrices. Where two joints' transforms differ by a
large rotation the average is no longer a rotation and the skin shrinks towards the
joint: a forearm twisted by 180 degrees collapses to a line at the elbow (the
"candy wrapper") and a strongly bent elbow loses volume on its inner side (the
"collapsing elbow"). Dual-quaternion skinning blends rigid transforms and keeps the
cross-sections.

Two measures, both on a *region* around the joint:

- **volume change**: the region (the faces whose three vertices are in it) is an
  open tube; each boundary loop is closed by a fan of triangles to the loop's
  centroid, and the enclosed volume follows from the divergence theorem
  ``V = sum_f a . (b x c) / 6``. The cut loops lie where the skin moves rigidly
  (weights 0 or 1), so the caps move with the limb and the change is the joint's
  own. The signed sum counts a region where the folded limb passes through
  itself twice -- it is ``integral of det(J)`` over the rest solid, the volume of
  the deformed material -- so self-contact at a strong bend does not hide a loss.
- **minimum radius ratio**: cross-sections near the joint (the rings of the
  cylinder; thin slabs of the arm perpendicular to the bones) are summarised by
  their minor radius ``sqrt(2 lambda_2)``, with ``lambda_2`` the middle
  eigenvalue of the section vertices' covariance (the minor semi-axis of the
  best-fitting ellipse; a circle of radius r gives r). The ratio deformed/rest,
  minimised over the sections, is 0 for a total collapse and 1 for none.

Cases: a closed capped cylinder with two bones and smooth weights across the joint,
twisted by 180 degrees about the second bone's axis and bent so that the two
segments' directions are 150 degrees apart; and the same on the MakeHuman body's
right forearm and elbow (the body mesh is passed in by the caller: this module does
not read files).

Each case is measured for LBS, DQS and the sweep-based deformer
(:mod:`skincap.deform.sweep`, Hyun et al. 2005), whose claim is a constant volume and
no collapsing cross-section.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from scipy.spatial.transform import Rotation

from skincap.deform.skeletal.deformers import Backend, make_deformer
from skincap.errors import ValidationError
from skincap.types import Mesh, Skeleton, Skin

__all__ = [
    "capped_cylinder",
    "two_bone_cylinder",
    "enclosed_volume",
    "capped_volume",
    "section_radius",
    "joint_pose_matrices",
    "cylinder_artefacts",
    "body_artefacts",
    "artefact_table",
]

#: The deformers compared: skeletal LBS and DQS, and the sweep-based deformer (Hyun et al.).
METHODS = ("lbs", "dqs", "sweep")

#: The MakeHuman default rig's right forearm bone (its head is the elbow).
MAKEHUMAN_FOREARM = "lowerarm01.R"
#: The MakeHuman default rig's right forearm twist bone (its head is mid-forearm).
MAKEHUMAN_FOREARM_TWIST = "lowerarm02.R"


# ------------------------------------------------------------------ geometry
def capped_cylinder(
    radius: float = 0.04,
    length: float = 0.5,
    *,
    n_around: int = 48,
    n_along: int = 101,
) -> Mesh:
    """A closed, manifold, outward-oriented cylinder along +x, capped by triangle fans.

    Parameters
    ----------
    radius, length : float, metres
        The cylinder spans ``x`` in ``[0, length]`` around the x axis.
    n_around : int, default 48
        Vertices per ring (>= 3).
    n_along : int, default 101
        Rings (>= 2), evenly spaced; an odd count puts a ring at ``length / 2``.

    Returns
    -------
    Mesh
        ``vertices`` (n_along * n_around + 2, 3) metres: ring ``i`` is
        ``vertices[i * n_around:(i + 1) * n_around]``, then the centres of the
        caps at ``x = 0`` and ``x = length``. ``faces`` (2 n_around (n_along - 1) +
        2 n_around, 3), counter-clockwise seen from outside. ``meta["rings"]``
        (n_along, n_around) int64 vertex indices and ``meta["ring_x"]`` (n_along,).
    """
    if not (np.isfinite(radius) and radius > 0 and np.isfinite(length) and length > 0):
        raise ValidationError(
            f"radius, length: expected positive lengths in metres, got {radius!r}, {length!r}"
        )
    if int(n_around) < 3 or int(n_along) < 2:
        raise ValidationError(
            f"n_around, n_along: need at least 3 and 2, got {n_around!r}, {n_along!r}"
        )
    n_around = int(n_around)
    n_along = int(n_along)
    theta = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    x = np.linspace(0.0, length, n_along)
    ring = np.stack([np.cos(theta), np.sin(theta)], axis=1) * radius  # (n_around, 2)
    side = np.concatenate(
        [
            np.repeat(x, n_around)[:, None],
            np.tile(ring, (n_along, 1)),
        ],
        axis=1,
    )  # (n_along * n_around, 3)
    centres = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])
    vertices = np.concatenate([side, centres])
    rings = np.arange(n_along * n_around).reshape(n_along, n_around)
    a = rings[:-1]  # (n_along - 1, n_around)
    b = rings[1:]
    a_next = np.roll(a, -1, axis=1)
    b_next = np.roll(b, -1, axis=1)
    # (a, b_next, b) and (a, a_next, b_next): outward normals (radial)
    quads = np.concatenate(
        [
            np.stack([a, b_next, b], axis=-1).reshape(-1, 3),
            np.stack([a, a_next, b_next], axis=-1).reshape(-1, 3),
        ]
    )
    c0, c1 = n_along * n_around, n_along * n_around + 1
    first, last = rings[0], rings[-1]
    cap0 = np.stack([np.full(n_around, c0), np.roll(first, -1), first], axis=1)  # normal -x
    cap1 = np.stack([np.full(n_around, c1), last, np.roll(last, -1)], axis=1)  # normal +x
    faces = np.concatenate([quads, cap0, cap1])
    return Mesh(vertices=vertices, faces=faces, meta={"rings": rings, "ring_x": x})


def _smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def two_bone_cylinder(
    radius: float = 0.04,
    length: float = 0.5,
    *,
    blend: float = 0.04,
    n_around: int = 48,
    n_along: int = 101,
) -> Mesh:
    """The capped cylinder of :func:`capped_cylinder` skinned to two bones.

    Bone ``"upper"`` (root) starts at the origin, bone ``"lower"`` at the joint
    ``(length / 2, 0, 0)``, and the end site ``"lower_end"`` (no weights) at
    ``(length, 0, 0)``; the bind frames are axis-aligned. The weight of
    ``"lower"`` rises smoothly (smoothstep) from 0 at ``x = length / 2 - blend`` to
    1 at ``length / 2 + blend``: 0.5 exactly at the joint.

    Parameters
    ----------
    radius, length, blend : float, metres
        ``0 < blend < length / 2``.
    n_around, n_along : int
        See :func:`capped_cylinder`.

    Returns
    -------
    Mesh
        With a :class:`~skincap.types.Skin` of 3 joints and 2 influences per vertex.
    """
    if not (np.isfinite(blend) and 0 < blend < length / 2):
        raise ValidationError(f"blend: expected 0 < blend < length / 2, got {blend!r}")
    mesh = capped_cylinder(radius, length, n_around=n_around, n_along=n_along)
    joint = length / 2.0
    w_lower = _smoothstep((mesh.vertices[:, 0] - (joint - blend)) / (2.0 * blend))
    skeleton = Skeleton(
        names=["upper", "lower", "lower_end"],
        parents=np.array([-1, 0, 1]),
        offsets=np.array([[0.0, 0.0, 0.0], [joint, 0.0, 0.0], [length - joint, 0.0, 0.0]]),
    )
    inverse_bind = np.tile(np.eye(4), (3, 1, 1))
    inverse_bind[1, 0, 3] = -joint
    inverse_bind[2, 0, 3] = -length
    skin = Skin(
        skeleton=skeleton,
        joint_indices=np.tile(np.array([0, 1]), (mesh.n_vertices, 1)),
        joint_weights=np.stack([1.0 - w_lower, w_lower], axis=1),
        inverse_bind=inverse_bind,
    )
    meta = dict(mesh.meta)
    meta.update({"joint_x": joint, "blend": blend, "radius": radius})
    return Mesh(vertices=mesh.vertices, faces=mesh.faces, skin=skin, meta=meta)


def enclosed_volume(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed volume enclosed by a closed triangle surface (divergence theorem).

    Parameters
    ----------
    vertices : (..., V, 3) float, metres
        One or more poses (leading axes, e.g. frames) of the same surface.
    faces : (F, 3) int
        Counter-clockwise seen from outside (outward normals give a positive volume).

    Returns
    -------
    (...) float64, cubic metres
        ``sum_f a . (b x c) / 6``; independent of the origin only for a closed
        surface. A surface passing through itself counts the overlap twice
        (winding number). NaN in a vertex gives NaN.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim < 2 or v.shape[-1] != 3:
        raise ValidationError(f"vertices: expected shape (..., V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValidationError(f"faces: expected shape (F, 3), got {f.shape}")
    a = v[..., f[:, 0], :]
    b = v[..., f[:, 1], :]
    c = v[..., f[:, 2], :]
    return np.einsum("...fi,...fi->...", a, np.cross(b, c)) / 6.0


def _boundary_loops(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Directed boundary edges (E, 2) of a triangle set, their loop id (E,), loop count."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = edges[:, 0] * n_vertices + edges[:, 1]
    reverse = edges[:, 1] * n_vertices + edges[:, 0]
    boundary = edges[~np.isin(key, reverse)]
    if boundary.shape[0] == 0:
        return boundary, np.zeros(0, dtype=np.int64), 0
    graph = scipy.sparse.coo_matrix(
        (np.ones(boundary.shape[0]), (boundary[:, 0], boundary[:, 1])),
        shape=(n_vertices, n_vertices),
    )
    _, label = scipy.sparse.csgraph.connected_components(graph, directed=False)
    used, loop = np.unique(label[boundary[:, 0]], return_inverse=True)
    return boundary, loop.astype(np.int64), int(used.size)


def capped_volume(
    vertices: np.ndarray, faces: np.ndarray, vertex_mask: np.ndarray | None = None
) -> np.ndarray:
    """Volume of a surface region whose holes are closed by fans to their centroids.

    Parameters
    ----------
    vertices : (..., V, 3) float, metres
        One or more poses of the same mesh.
    faces : (F, 3) int
        Consistently oriented (counter-clockwise seen from outside).
    vertex_mask : (V,) bool, optional
        The region: the faces with all three vertices in it. Default: every face.

    Returns
    -------
    (...) float64, cubic metres
        Divergence-theorem volume of the region plus, for each boundary loop, the
        triangles (b, a, centroid) over its directed boundary edges (a, b) -- the
        loop's centroid is taken in each pose, so the cap moves with the skin. For
        a closed surface this is :func:`enclosed_volume`.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim < 2 or v.shape[-1] != 3:
        raise ValidationError(f"vertices: expected shape (..., V, 3), got {v.shape}")
    n_v = v.shape[-2]
    if vertex_mask is not None:
        mask = np.asarray(vertex_mask, dtype=bool)
        if mask.shape != (n_v,):
            raise ValidationError(f"vertex_mask: expected shape ({n_v},), got {mask.shape}")
        f = f[mask[f].all(axis=1)]
    if f.shape[0] == 0:
        raise ValidationError("vertex_mask: the region contains no face")
    volume = enclosed_volume(v, f)
    boundary, loop, n_loops = _boundary_loops(f, n_v)
    if n_loops:
        # centroid of each loop's (unique) vertices, in every pose
        verts, first = np.unique(boundary[:, 0], return_index=True)
        member = scipy.sparse.csr_matrix(
            (np.ones(verts.size), (loop[first], verts)), shape=(n_loops, n_v)
        )
        member = scipy.sparse.diags(1.0 / np.asarray(member.sum(axis=1)).ravel()) @ member
        flat = np.moveaxis(v, -2, 0).reshape(n_v, -1)  # (V, ... * 3)
        centroid = np.moveaxis(
            (member @ flat).reshape((n_loops,) + v.shape[:-2] + (3,)), 0, -2
        )  # (..., L, 3)
        a = v[..., boundary[:, 0], :]
        b = v[..., boundary[:, 1], :]
        c = centroid[..., loop, :]
        volume = volume + np.einsum("...ei,...ei->...", b, np.cross(a, c)) / 6.0
    return volume


def section_radius(points: np.ndarray) -> np.ndarray:
    """Minor radius of a cross-section: ``sqrt(2 lambda_2)`` of its covariance.

    Parameters
    ----------
    points : (..., n, 3) float, metres
        The vertices of one section (a ring, or a thin slab of a limb's surface).

    Returns
    -------
    (...) float64, metres
        The minor semi-axis of the best-fitting ellipse (``r`` for a circle of
        radius ``r``; 0 for points collapsed onto a line or a point).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim < 2 or p.shape[-1] != 3 or p.shape[-2] < 3:
        raise ValidationError(f"points: expected shape (..., n >= 3, 3), got {p.shape}")
    centred = p - p.mean(axis=-2, keepdims=True)
    cov = np.einsum("...ni,...nj->...ij", centred, centred) / p.shape[-2]
    lam = np.linalg.eigvalsh(cov)  # ascending
    return np.sqrt(2.0 * np.clip(lam[..., 1], 0.0, None))


# ------------------------------------------------------------------ poses
def _descendants(parents: np.ndarray, joint: int) -> np.ndarray:
    """(J,) bool: ``joint`` and every joint below it (parents come first)."""
    inside = np.zeros(parents.size, dtype=bool)
    inside[joint] = True
    for k in range(joint + 1, parents.size):  # a loop over joints, in topological order
        if parents[k] >= 0 and inside[parents[k]]:
            inside[k] = True
    return inside


def joint_pose_matrices(skin: Skin, joint: int, rotation: np.ndarray) -> np.ndarray:
    """Skinning matrices that turn ``joint`` (and everything below it) about its head.

    Parameters
    ----------
    skin : Skin
    joint : int
        Index of the joint in ``skin.skeleton``.
    rotation : (3, 3) float
        World-space rotation applied about the joint's bind position.

    Returns
    -------
    (J, 4, 4) float64
        Identity for the other joints; ``T(h) R T(-h)`` for the joint's subtree
        (``h`` the joint's bind position in metres), which is what forward
        kinematics gives for that change of the joint's local rotation.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3):
        raise ValidationError(f"rotation: expected shape (3, 3), got {r.shape}")
    head = skin.bind_matrices[joint, :3, 3]
    g = np.eye(4)
    g[:3, :3] = r
    g[:3, 3] = head - r @ head
    out = np.tile(np.eye(4), (skin.skeleton.n_joints, 1, 1))
    out[_descendants(skin.skeleton.parents, joint)] = g
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _twist_and_bend(
    skin: Skin, joint: int, twist_deg: float, bend_deg: float
) -> dict[str, tuple[np.ndarray, float]]:
    """Matrices and applied rotation angles for the twist and the bend at ``joint``.

    The twist turns the joint's subtree about its own bone axis (towards its first
    child). The bend turns it about ``upper x lower`` (flexing the joint) so that
    the directions of the parent bone and the bone end ``bend_deg`` apart.
    """
    sk = skin.skeleton
    pos = skin.bind_matrices[:, :3, 3]
    parent = int(sk.parents[joint])
    children = sk.children(joint)
    if parent < 0 or children.size == 0:
        raise ValidationError(
            f"joint '{sk.names[joint]}': needs a parent and a child to define the two segments"
        )
    upper = _unit(pos[joint] - pos[parent])
    lower = _unit(pos[int(children[0])] - pos[joint])
    rest_angle = float(np.degrees(np.arccos(np.clip(upper @ lower, -1.0, 1.0))))
    axis = np.cross(upper, lower)
    if np.linalg.norm(axis) < 1e-9:  # straight: any perpendicular axis
        helper = np.eye(3)[int(np.argmin(np.abs(upper)))]
        axis = np.cross(upper, helper)
    axis = _unit(axis)
    turn = bend_deg - rest_angle
    twist = Rotation.from_rotvec(np.radians(twist_deg) * lower).as_matrix()
    bend = Rotation.from_rotvec(np.radians(turn) * axis).as_matrix()
    return {
        f"twist {twist_deg:g} deg": (joint_pose_matrices(skin, joint, twist), twist_deg),
        f"bend {bend_deg:g} deg": (joint_pose_matrices(skin, joint, bend), turn),
    }


def _rows(
    name: str,
    mesh: Mesh,
    poses: dict[str, tuple[np.ndarray, float]],
    region: np.ndarray,
    sections: list[np.ndarray],
    backend: Backend,
    sweep_chains: dict[str, tuple[str, ...]] | None = None,
) -> list[dict[str, Any]]:
    rest_volume = float(capped_volume(mesh.vertices, mesh.faces, region))
    rest_radius = np.array([section_radius(mesh.vertices[s]) for s in sections])
    from skincap.deform.sweep.deformer import SweepDeformer  # a peer deformer, measured here

    deformers: dict[str, Any] = {m: make_deformer(m, mesh, backend=backend) for m in ("lbs", "dqs")}
    deformers["sweep"] = SweepDeformer(mesh, chains=sweep_chains, backend=backend)
    rows: list[dict[str, Any]] = []
    for case, (matrices, angle) in poses.items():
        for method in METHODS:
            posed = deformers[method].deform(matrices)
            volume = float(capped_volume(posed, mesh.faces, region))
            radius = np.array([section_radius(posed[s]) for s in sections])
            rows.append(
                {
                    "case": f"{name} {case}",
                    "method": method,
                    "volume_change_pct": 100.0 * (volume - rest_volume) / rest_volume,
                    "min_radius_ratio": float(np.min(radius / rest_radius)),
                    "rest_volume_m3": rest_volume,
                    "rotation_deg": float(angle),
                }
            )
    return rows


def cylinder_artefacts(
    *,
    radius: float = 0.04,
    length: float = 0.5,
    blend: float = 0.04,
    twist_deg: float = 180.0,
    bend_deg: float = 150.0,
    backend: Backend = "auto",
) -> list[dict[str, Any]]:
    """Volume and cross-section loss of a twisted and a bent two-bone cylinder.

    The region is the part of the cylinder within ``2 * blend`` of the joint
    (cut where the weights are 0 or 1); the sections are its rings within ``blend``
    of the joint (where the weights blend).

    Parameters
    ----------
    radius, length, blend : float, metres
        See :func:`two_bone_cylinder` (a forearm-sized limb by default).
    twist_deg : float, default 180
        Twist of the second bone about its own axis.
    bend_deg : float, default 150
        Angle between the two segments' directions after the bend.
    backend : {"auto", "numba", "numpy"}

    Returns
    -------
    list of dict
        Rows as in :func:`artefact_table`, case ``"cylinder twist 180 deg"`` and
        ``"cylinder bend 150 deg"``.
    """
    mesh = two_bone_cylinder(radius, length, blend=blend)
    joint = mesh.meta["joint_x"]
    x = mesh.vertices[:, 0]
    region = np.abs(x - joint) <= 2.0 * blend + 1e-12
    rings = mesh.meta["rings"]
    ring_x = mesh.meta["ring_x"]
    sections = [rings[i] for i in np.nonzero(np.abs(ring_x - joint) <= blend + 1e-12)[0]]
    poses = _twist_and_bend(mesh.skin, 1, twist_deg, bend_deg)  # type: ignore[arg-type]
    chain = {"limb": ("upper", "lower", "lower_end")}
    return _rows("cylinder", mesh, poses, region, sections, backend, chain)


def _joint_region(
    body: Mesh, skin: Skin, joint: int, region_radius: float
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Region (V,) bool and cross-sections (index arrays) around a joint of ``body``."""
    sk = skin.skeleton
    parent = int(sk.parents[joint])
    pos = skin.bind_matrices[:, :3, 3]
    centre = pos[joint]
    limb = _descendants(sk.parents, joint)
    limb[parent] = True
    top = np.take_along_axis(
        skin.joint_indices, np.argmax(skin.joint_weights, axis=1)[:, None], axis=1
    )[:, 0]
    rel = body.vertices - centre
    region = limb[top] & (np.linalg.norm(rel, axis=1) <= region_radius)
    if not region.any():
        raise ValidationError(f"body: no vertex near joint '{sk.names[joint]}'")
    upper = _unit(centre - pos[parent])
    lower = _unit(pos[int(sk.children(joint)[0])] - centre)
    sections = []
    for direction in (-upper, lower):
        along = rel @ direction
        for d in np.arange(0.0, 0.0501, 0.01):
            s = np.nonzero(region & (np.abs(along - d) <= 0.004))[0]
            if s.size >= 8:
                sections.append(s)
    return region, sections


def body_artefacts(
    body: Mesh,
    *,
    elbow_joint: str = MAKEHUMAN_FOREARM,
    twist_joint: str = MAKEHUMAN_FOREARM_TWIST,
    region_radius: float = 0.10,
    twist_deg: float = 180.0,
    bend_deg: float = 150.0,
    backend: Backend = "auto",
) -> list[dict[str, Any]]:
    """Volume and cross-section loss at a skinned body's forearm and elbow (e.g. MakeHuman's).

    Three poses, each turning a joint and everything below it about the joint's
    bind position:

    - **forearm twist**: ``twist_joint`` (MakeHuman's forearm twist bone
      ``lowerarm02.R``, whose head is mid-forearm) by ``twist_deg`` about its own
      axis -- the wrist turned against the elbow, the classic candy wrapper;
    - **elbow twist**: the forearm bone ``elbow_joint`` (``lowerarm01.R``, head at
      the elbow) by ``twist_deg`` about its own axis;
    - **elbow bend**: ``elbow_joint`` about the flexion axis (upper arm x forearm)
      until the directions of the upper arm and the forearm are ``bend_deg`` apart.
      The MakeHuman base mesh's elbow is already bent by about 46 degrees, so its
      forearm turns by about 104 degrees (reported as ``rotation_deg``).

    Region: vertices within ``region_radius`` of the turned joint whose largest
    weight is on its parent, on it or on a joint below it -- a tube around the joint
    cut where the skin follows one side rigidly. Sections: 8 mm slabs of the region
    perpendicular to the parent bone and to the bone, 0 to 50 mm from the joint.

    Parameters
    ----------
    body : Mesh
        With a :class:`~skincap.types.Skin` (e.g. ``read_makehuman(...)``).
    elbow_joint, twist_joint : str
        Joint names; each needs a parent and a child (they define the directions).
    region_radius : float, metres, default 0.10
    twist_deg, bend_deg : float
    backend : {"auto", "numba", "numpy"}

    Returns
    -------
    list of dict
        Rows as in :func:`artefact_table`: ``"body forearm twist 180 deg"``,
        ``"body elbow twist 180 deg"``, ``"body elbow bend 150 deg"``.
    """
    if not isinstance(body, Mesh) or body.skin is None:
        raise ValidationError("body: expected a Mesh with a skin")
    skin = body.skin
    rows: list[dict[str, Any]] = []
    tj = skin.skeleton.index(twist_joint)
    twist_case = f"twist {twist_deg:g} deg"
    poses = _twist_and_bend(skin, tj, twist_deg, bend_deg)
    region, sections = _joint_region(body, skin, tj, region_radius)
    rows += _rows("body forearm", body, {twist_case: poses[twist_case]}, region, sections, backend)
    ej = skin.skeleton.index(elbow_joint)
    region, sections = _joint_region(body, skin, ej, region_radius)
    rows += _rows(
        "body elbow",
        body,
        _twist_and_bend(skin, ej, twist_deg, bend_deg),
        region,
        sections,
        backend,
    )
    return rows


def artefact_table(body: Mesh | None = None, *, backend: Backend = "auto") -> list[dict[str, Any]]:
    """The artefact table: LBS, DQS and the sweep deformer on the cylinder and, if given, the body.

    Parameters
    ----------
    body : Mesh, optional
        A skinned body with the MakeHuman default rig, e.g.
        ``skincap.io.makehuman.read_makehuman("tests/data/makehuman_base.obj")``;
        without it only the cylinder rows are returned.
    backend : {"auto", "numba", "numpy"}

    Returns
    -------
    list of dict
        One row per case and method, with keys ``case`` (str), ``method``
        (``"lbs"``/``"dqs"``/``"sweep"``, :data:`METHODS`; the sweep deformer is
        :class:`skincap.deform.sweep.SweepDeformer` with its defaults, the cylinder
        swept along its two bones), ``volume_change_pct`` (float, % of the region's rest
        volume; negative = lost), ``min_radius_ratio`` (float, smallest deformed /
        rest cross-section minor radius near the joint), ``rest_volume_m3`` (float)
        and ``rotation_deg`` (float, the rotation applied relative to the bind pose).
    """
    rows = cylinder_artefacts(backend=backend)
    if body is not None:
        rows += body_artefacts(body, backend=backend)
    return rows
