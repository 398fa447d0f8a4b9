"""The rigged MakeHuman body: base mesh (OBJ), skeleton (``.mhskel``) and weights (``.mhw``).

MakeHuman (CC0 assets) describes its rig relative to its base mesh:

- ``.mhskel`` (JSON): ``"joints"`` maps a joint name to vertex indices of the base
  mesh; the joint sits at the centroid of those vertices. ``"bones"`` maps a bone
  name to ``head`` and ``tail`` joint names, a ``parent`` bone and a
  ``rotation_plane``: the name of an entry of ``"planes"``, three joint names whose
  triangle's normal fixes the bone's roll.
- ``.mhw`` (JSON): ``"weights"`` maps a bone name to ``[[vertex, weight], ...]``
  pairs; the per-vertex sums are not 1 and are normalised here.

The bone rest orientation follows MakeHuman's own construction (its
``skeleton.getMatrix`` / ``get_normal``): with joints p1, p2, p3 of the bone's plane,
the plane normal is ``n = unit(unit(p3 - p2) x unit(p2 - p1))``; the bone's local
Y axis is ``y = unit(tail - head)``, ``z = unit(n x y)`` and ``x = y x z`` (so the
local X axis is the plane normal made perpendicular to the bone). A bone with
several planes averages their normals; a bone without a plane (or a degenerate
one) uses ``n = (0, 1, 0)``. That world rest frame, translated to the bone head, is
the bind matrix of the joint.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from skincap.errors import FormatError, SkincapWarning, ValidationError
from skincap.io._common import check_readable, unit_scale
from skincap.io.json_file import parse_json
from skincap.io.mesh import read_obj, triangulate_polygons
from skincap.types import Mesh, Skeleton, Skin

__all__ = ["read_makehuman", "bone_rest_frames", "is_rigged_base_mesh", "read_mhskel", "read_mhw"]

#: Name of the group of the base mesh that is the body's skin.
BODY_GROUP = "body"


# --------------------------------------------------------------------------- files
def _find_beside(obj_path: Path, candidates: list[str], pattern: str | None) -> Path | None:
    folder = obj_path.parent
    for name in candidates:
        p = folder / name
        if p.is_file():
            return p
    if pattern is not None:
        found = sorted(folder.glob(pattern))
        if len(found) == 1:
            return found[0]
    return None


def _load_json(path: Path) -> dict[str, Any]:
    p = check_readable(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(p, f"not UTF-8 text ({exc.reason})", offset=exc.start) from None
    data = parse_json(p, text)
    if not isinstance(data, dict):
        raise FormatError(p, "expected a JSON object at the top level")
    return data


# ------------------------------------------------------------------------ skeleton
class _Rig:
    """Validated content of a ``.mhskel`` file."""

    def __init__(self, path: Path, data: dict[str, Any], n_vertices: int) -> None:
        bones = data.get("bones")
        joints = data.get("joints")
        planes = data.get("planes", {})
        if not isinstance(bones, dict) or not bones:
            raise FormatError(path, "'bones' must be a non-empty object")
        if not isinstance(joints, dict):
            raise FormatError(path, "'joints' must be an object of joint name -> vertex indices")
        if not isinstance(planes, dict):
            raise FormatError(path, "'planes' must be an object of plane name -> three joint names")
        self.name = str(data.get("name", "MakeHuman skeleton"))
        self.joint_vertices: dict[str, np.ndarray] = {}
        for jname, idx in joints.items():
            if (
                not isinstance(idx, list)
                or not idx
                or not all(isinstance(i, int) and not isinstance(i, bool) for i in idx)
            ):
                raise FormatError(
                    path, f"joint {jname!r}: expected a non-empty list of vertex indices"
                )
            if min(idx) < 0 or max(idx) >= n_vertices:
                raise FormatError(
                    path,
                    f"joint {jname!r}: vertex index out of range 0..{n_vertices - 1} of the base mesh",
                )
            self.joint_vertices[str(jname)] = np.asarray(idx, dtype=np.int64)
        self.planes: dict[str, list[str]] = {}
        for pname, pj in planes.items():
            if not isinstance(pj, list) or len(pj) != 3 or not all(isinstance(j, str) for j in pj):
                raise FormatError(path, f"plane {pname!r}: expected a list of three joint names")
            missing = [j for j in pj if j not in self.joint_vertices]
            if missing:
                raise FormatError(path, f"plane {pname!r}: unknown joint {missing[0]!r}")
            self.planes[str(pname)] = [str(j) for j in pj]
        for bname, bdef in bones.items():
            if not isinstance(bdef, dict):
                raise FormatError(path, f"bone {bname!r}: expected an object")
            for key in ("head", "tail"):
                if not isinstance(bdef.get(key), str) or bdef[key] not in self.joint_vertices:
                    raise FormatError(
                        path, f"bone {bname!r}: {key} {bdef.get(key)!r} is not a joint of 'joints'"
                    )
            parent = bdef.get("parent")
            if parent is not None and (not isinstance(parent, str) or parent not in bones):
                raise FormatError(path, f"bone {bname!r}: parent {parent!r} is not a bone")
            plane = bdef.get("rotation_plane")
            names = [plane] if isinstance(plane, str) else plane if isinstance(plane, list) else []
            for pn in names:
                if not isinstance(pn, str) or pn not in self.planes:
                    raise FormatError(
                        path, f"bone {bname!r}: rotation plane {pn!r} is not in 'planes'"
                    )
        # Breadth-first order from the roots, as MakeHuman orders its bones.
        children: dict[str | None, list[str]] = {}
        for bname, bdef in bones.items():
            children.setdefault(bdef.get("parent"), []).append(str(bname))
        order: list[str] = []
        queue = deque(children.get(None, []))
        while queue:
            b = queue.popleft()
            order.append(b)
            queue.extend(children.get(b, []))
        if len(order) != len(bones):
            stuck = sorted(set(bones) - set(order))
            raise FormatError(path, f"bones not reachable from a root (parent cycle): {stuck[:5]}")
        index = {b: i for i, b in enumerate(order)}
        self.bone_names = order
        self.parents = np.array(
            [index[bones[b]["parent"]] if bones[b].get("parent") else -1 for b in order],
            dtype=np.int64,
        )
        self.heads = [bones[b]["head"] for b in order]
        self.tails = [bones[b]["tail"] for b in order]
        self.rotation_planes: list[list[str]] = []
        for b in order:
            plane = bones[b].get("rotation_plane")
            self.rotation_planes.append(
                [plane]
                if isinstance(plane, str)
                else list(plane)
                if isinstance(plane, list)
                else []
            )

    def joint_positions(self, vertices: np.ndarray) -> dict[str, np.ndarray]:
        """Centroid of each joint's vertex group: name -> (3,) float64."""
        names = list(self.joint_vertices)
        idx = np.concatenate([self.joint_vertices[n] for n in names])
        sizes = np.array([self.joint_vertices[n].size for n in names])
        seg = np.repeat(np.arange(len(names)), sizes)
        sums = np.zeros((len(names), 3))
        np.add.at(sums, seg, vertices[idx])
        cent = sums / sizes[:, None]
        return dict(zip(names, cent, strict=True))


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` scaled to unit length; zero rows stay zero."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 1e-12)


def bone_rest_frames(heads: np.ndarray, tails: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """World rest transforms of bones, MakeHuman's construction.

    Parameters
    ----------
    heads, tails : (J, 3) float64, metres
        Bone head and tail positions.
    normals : (J, 3) float64
        Roll reference direction of each bone (the normal of its rotation plane).

    Returns
    -------
    (J, 4, 4) float64
        Columns: local X = the normal made perpendicular to the bone, local Y =
        ``unit(tail - head)``, local Z = ``unit(normal x Y)``; translation = head.
        When the normal is parallel to the bone (or zero), the world axis least
        aligned with the bone stands in for it. A zero-length bone points along
        world Y. No NaN is produced.
    """
    heads = np.asarray(heads, dtype=np.float64)
    tails = np.asarray(tails, dtype=np.float64)
    y = _unit(tails - heads)
    y[np.linalg.norm(y, axis=1) == 0] = (0.0, 1.0, 0.0)
    n = _unit(np.asarray(normals, dtype=np.float64))
    z = np.cross(n, y)
    weak = np.linalg.norm(z, axis=1) < 1e-6
    if weak.any():
        axis = np.eye(3)[np.argmin(np.abs(y[weak]), axis=1)]
        z[weak] = np.cross(axis, y[weak])
    z = _unit(z)
    x = _unit(np.cross(y, z))
    m = np.zeros((heads.shape[0], 4, 4))
    m[:, :3, 0] = x
    m[:, :3, 1] = y
    m[:, :3, 2] = z
    m[:, :3, 3] = heads
    m[:, 3, 3] = 1.0
    return m


def _plane_normals(rig: _Rig, pos: dict[str, np.ndarray]) -> np.ndarray:
    """(J, 3) roll normal of each bone, (0, 1, 0) when it has none."""
    plane_names = list(rig.planes)
    if plane_names:
        p = np.array([[pos[j] for j in rig.planes[name]] for name in plane_names])  # (P, 3, 3)
        pvec = _unit(p[:, 1] - p[:, 0])
        yvec = _unit(p[:, 2] - p[:, 1])
        plane_n = _unit(np.cross(yvec, pvec))
    else:
        plane_n = np.zeros((0, 3))
    where = {name: i for i, name in enumerate(plane_names)}
    normals = np.tile([0.0, 1.0, 0.0], (len(rig.bone_names), 1))
    for b, planes in enumerate(rig.rotation_planes):
        if not planes:
            continue
        ns = plane_n[[where[pn] for pn in planes]]
        ns = ns[np.linalg.norm(ns, axis=1) > 1e-5]
        if ns.shape[0]:
            avg = ns.mean(axis=0)
            if np.linalg.norm(avg) > 1e-5:
                normals[b] = avg
    return normals


# ------------------------------------------------------------------------- weights
#: Largest vertex index a weights file may name on its own: no mesh skincap can hold
#: has 2**31 vertices (OBJ, PLY and glTF index them with 32-bit integers).
MAX_VERTEX_INDEX = 2**31 - 1


def _weight_pairs(path: Path, bname: str, pairs: Any, n_vertices: int) -> np.ndarray:
    """(k, 2) float64 ``[vertex, weight]`` rows of one bone, validated.

    Vertices must be whole numbers in ``0 .. n_vertices - 1``, weights finite and >= 0.
    Nothing is allocated from the values: the rows are as many as the file holds.
    """
    try:
        arr = np.asarray(pairs, dtype=np.float64).reshape(-1, 2) if pairs else np.zeros((0, 2))
    except (ValueError, TypeError, OverflowError):
        raise FormatError(
            path, f"weights of bone {bname!r}: expected [[vertex, weight], ...]"
        ) from None
    if not np.isfinite(arr).all():
        raise FormatError(path, f"weights of bone {bname!r}: non-finite value")
    v = arr[:, 0]
    if arr.shape[0] and (np.any(v != np.round(v)) or v.min() < 0 or v.max() >= n_vertices):
        bad = v[(v != np.round(v)) | (v < 0) | (v >= n_vertices)][0]
        raise FormatError(
            path,
            f"weights of bone {bname!r}: vertex index {bad:.17g} is not an integer in 0..{n_vertices - 1}",
        )
    if (arr[:, 1] < 0).any():
        raise FormatError(path, f"weights of bone {bname!r}: negative weight")
    return arr


def _dense_weights(
    path: Path, data: dict[str, Any], bone_index: dict[str, int], n_vertices: int
) -> np.ndarray:
    """(V, J) float64 summed raw weights from a ``.mhw`` object (V from the base mesh)."""
    weights = data.get("weights")
    if not isinstance(weights, dict):
        raise FormatError(
            path, "'weights' must be an object of bone name -> [[vertex, weight], ...]"
        )
    dense = np.zeros((n_vertices, len(bone_index)))
    unknown = []
    for bname, pairs in weights.items():
        if bname not in bone_index:
            _weight_pairs(path, bname, pairs, MAX_VERTEX_INDEX + 1)  # well-formed all the same
            unknown.append(bname)
            continue
        arr = _weight_pairs(path, bname, pairs, n_vertices)
        np.add.at(dense[:, bone_index[bname]], arr[:, 0].astype(np.int64), arr[:, 1])
    if unknown:
        warnings.warn(
            f"{path}: weights for {len(unknown)} bone(s) not in the skeleton ignored: {sorted(unknown)[:5]}",
            SkincapWarning,
            stacklevel=3,
        )
    return dense


def _top_influences(dense: np.ndarray, k: int, root: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Keep the ``k`` largest weights per row and renormalise.

    Returns (V, k) int64 joint indices, (V, k) float64 weights (rows sum to 1, padded
    with joint 0 / weight 0) and how many rows had no weight (bound to ``root``).
    """
    v, j = dense.shape
    k_eff = min(k, j)
    if k_eff < j:
        top = np.argpartition(-dense, k_eff - 1, axis=1)[:, :k_eff]
    else:
        top = np.tile(np.arange(j), (v, 1))
    w = np.take_along_axis(dense, top, axis=1)
    order = np.argsort(-w, axis=1, kind="stable")
    top = np.take_along_axis(top, order, axis=1)
    w = np.take_along_axis(w, order, axis=1)
    sums = w.sum(axis=1)
    empty = sums <= 0
    w[empty] = 0.0
    w[empty, 0] = 1.0
    top[empty, 0] = root
    sums[empty] = 1.0
    w = w / sums[:, None]
    top = np.where(w > 0, top, 0)
    if k_eff < k:
        top = np.pad(top, ((0, 0), (0, k - k_eff)))
        w = np.pad(w, ((0, 0), (0, k - k_eff)))
    return top.astype(np.int64), w, int(empty.sum())


# ----------------------------------------------------------------------- mesh cut
def _keep_polygons(mesh: Mesh, keep: np.ndarray) -> tuple[Mesh, np.ndarray]:
    """The sub-mesh of polygons ``keep`` (P_all,) bool, vertices re-indexed compactly.

    Returns the new mesh (no skin) and the (V_new,) int64 source vertex indices.
    """
    if mesh.polygon_indices is None or mesh.polygon_offsets is None:
        raise ValidationError("mesh: source polygons are needed to cut the helper geometry")
    off = mesh.polygon_offsets
    sizes = np.diff(off)
    corner_keep = np.repeat(keep, sizes)
    idx = mesh.polygon_indices[corner_keep]
    new_off = np.concatenate([[0], np.cumsum(sizes[keep])]).astype(np.int64)
    used = np.unique(idx)
    remap = np.full(mesh.n_vertices, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    new_idx = remap[idx]
    faces, face_polygon = triangulate_polygons(new_idx, new_off)
    poly_remap = np.full(keep.size, -1, dtype=np.int64)
    poly_remap[keep] = np.arange(int(keep.sum()))

    def sub_groups(groups: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {}
        for name, g in groups.items():
            kept = poly_remap[np.asarray(g, dtype=np.int64)]
            kept = kept[kept >= 0]
            if kept.size:
                out[name] = kept
        return out

    meta = dict(mesh.meta)
    for key in ("corner_uv", "corner_normal"):
        if key in meta:
            meta[key] = np.asarray(meta[key])[corner_keep]
    for key in ("objects", "materials"):
        if key in meta:
            meta[key] = sub_groups(meta[key])
    uv = None if mesh.uv is None else mesh.uv[used]
    if uv is None and "corner_uv" in meta and "uv_table" in meta and (meta["corner_uv"] >= 0).all():
        # the cut may have removed every seam: per-vertex UVs when they now agree
        coords = np.asarray(meta["uv_table"])[meta["corner_uv"]]
        cand = np.zeros((used.size, 2))
        cand[new_idx] = coords
        if np.array_equal(cand[new_idx], coords):
            uv = cand
    sub = Mesh(
        vertices=mesh.vertices[used],
        faces=faces,
        polygon_indices=new_idx,
        polygon_offsets=new_off,
        face_polygon=face_polygon,
        groups=sub_groups(mesh.groups),
        uv=uv,
        meta=meta,
    )
    return sub, used


# --------------------------------------------------------------------------- public
def read_makehuman(
    obj_path: str | os.PathLike[str],
    skel_path: str | os.PathLike[str] | None = None,
    weights_path: str | os.PathLike[str] | None = None,
    *,
    keep_helpers: bool = False,
    units: str = "dm",
    max_influences: int = 4,
) -> Mesh:
    """Read the MakeHuman base mesh with its skeleton and skin weights.

    Parameters
    ----------
    obj_path : str or PathLike
        The base mesh, e.g. MakeHuman's ``base.obj`` (decimetres, Y up).
    skel_path : str or PathLike, optional
        The ``.mhskel`` rig. Default: ``default.mhskel``, then
        ``makehuman_default.mhskel`` beside the OBJ, then the only ``*.mhskel`` there.
    weights_path : str or PathLike, optional
        The ``.mhw`` weights. Default: the rig's ``"weights_file"`` beside the rig,
        then ``<rig name>_weights.mhw``, then the only ``*_weights.mhw`` there.
    keep_helpers : bool, default False
        Keep the ``helper-*`` and ``joint-*`` geometry. By default only the polygons
        of the ``body`` group are kept and the vertices re-indexed compactly.
    units : str, default "dm"
        Length unit of the OBJ (MakeHuman works in decimetres).
    max_influences : int, default 4
        Joints per vertex: the largest weights are kept and renormalised.

    Returns
    -------
    Mesh
        ``vertices`` (V, 3) float64 metres, Y up; quads in ``polygon_indices`` /
        ``polygon_offsets`` and triangles in ``faces``. ``skin``: a :class:`Skin`
        over a :class:`Skeleton` with one joint per bone at the bone head (names
        as in the rig, breadth-first, parents first; ``offsets`` (J, 3) metres =
        head minus the parent's head), ``joint_indices`` / ``joint_weights``
        (V, max_influences) with rows summing to 1, ``inverse_bind`` (J, 4, 4) the
        inverse of the bone rest frames (see :func:`bone_rest_frames`). ``meta``
        adds ``bone_heads``, ``bone_tails`` (J, 3) metres, ``bone_normals`` (J, 3),
        ``rig_joints`` (name -> (3,) metres, joint centroids on the full mesh),
        ``source_vertex`` (V,) int64 (vertex index in the OBJ), ``weight_sums``
        (V,) float64 (the file's per-vertex weight sums before normalising),
        ``skeleton_name`` and the OBJ reader's keys. No NaN.

    Raises
    ------
    FormatError
        A file is missing or malformed, the rig references unknown joints, planes,
        parents or out-of-range vertices, a bone cycle, or no ``body`` group.
    ValidationError
        ``max_influences`` < 1 or an unknown unit.
    """
    if int(max_influences) < 1:
        raise ValidationError(
            f"max_influences: expected a positive integer, got {max_influences!r}"
        )
    unit_scale(units)
    obj = check_readable(obj_path)
    skel = _skeleton_file(obj, skel_path)
    mesh = read_obj(obj, units=units, up="y")
    if mesh.polygon_indices is None:
        raise FormatError(obj, "the base mesh has no faces")
    skel_data = _load_json(skel)
    rig = _Rig(skel, skel_data, mesh.n_vertices)

    weights = _weights_file(skel, skel_data, weights_path)
    weights_data = _load_json(weights)

    # joints and bone frames on the full mesh, before anything is dropped
    pos = rig.joint_positions(mesh.vertices)
    heads = np.array([pos[j] for j in rig.heads])
    tails = np.array([pos[j] for j in rig.tails])
    normals = _plane_normals(rig, pos)
    inverse_bind = _inverse_rest_frames(heads, tails, normals)

    bone_index = {b: i for i, b in enumerate(rig.bone_names)}
    dense = _dense_weights(weights, weights_data, bone_index, mesh.n_vertices)

    out_mesh, used = (mesh, np.arange(mesh.n_vertices)) if keep_helpers else _body_only(obj, mesh)

    skin, sums = _bound_skin(rig, heads, inverse_bind, dense[used], int(max_influences), weights)

    meta = dict(out_mesh.meta)
    meta.update(
        {
            "source_format": "makehuman",
            "skeleton_name": rig.name,
            "skeleton_file": str(skel),
            "weights_file": str(weights),
            "bone_heads": heads,
            "bone_tails": tails,
            "bone_normals": normals,
            "rig_joints": pos,
            "source_vertex": used.astype(np.int64),
            "weight_sums": sums,
        }
    )
    return dataclasses.replace(out_mesh, skin=skin, meta=meta)


def _bound_skin(
    rig: _Rig,
    heads: np.ndarray,
    inverse_bind: np.ndarray,
    raw: np.ndarray,
    max_influences: int,
    weights: Path,
) -> tuple[Skin, np.ndarray]:
    """The Skin over the rig's skeleton and the file's weight sums (V',).

    ``raw`` (V', J) are the file's weights of the kept vertices, ``heads`` (J, 3) metres,
    ``inverse_bind`` (J, 4, 4); the ``max_influences`` largest weights are kept and
    renormalised; weightless vertices go to the root bone (SkincapWarning, at
    read_makehuman's caller).
    """
    sums = raw.sum(axis=1)
    root = int(np.nonzero(rig.parents < 0)[0][0])
    idx, w, n_empty = _top_influences(raw, max_influences, root)
    if n_empty:
        warnings.warn(
            f"{weights}: {n_empty} vertices have no weight; bound to the root bone '{rig.bone_names[root]}'",
            SkincapWarning,
            stacklevel=3,
        )
    has_parent = rig.parents >= 0
    offsets = heads.copy()  # (J, 3) metres: head minus the parent's head
    offsets[has_parent] = heads[has_parent] - heads[rig.parents[has_parent]]
    skeleton = Skeleton(names=rig.bone_names, parents=rig.parents, offsets=offsets)
    skin = Skin(skeleton=skeleton, joint_indices=idx, joint_weights=w, inverse_bind=inverse_bind)
    return skin, sums


def _obj_vertex_count(data: bytes) -> int:
    """Number of ``v`` lines of an OBJ file's bytes."""
    lines = data.replace(b"\r", b"\n")
    return lines.count(b"\nv ") + lines.count(b"\nv\t") + int(lines[:2] in (b"v ", b"v\t"))


def is_rigged_base_mesh(obj_path: str | os.PathLike[str]) -> bool:
    """Whether an ``.obj`` is to be read as the base mesh of the MakeHuman rig beside it.

    A rig (``.mhskel``) beside an OBJ names vertices of the full base mesh, helper
    geometry included; an OBJ with fewer vertices than the largest index it names
    cannot be that mesh (the body-only OBJ ``skincap skin`` or ``animate`` wrote into
    the same folder, another mesh) and reads as a plain OBJ. When no single rig is
    found beside it, or the rig cannot be read, True: :func:`read_makehuman` then says
    what is wrong.

    Parameters
    ----------
    obj_path : str or PathLike
        An ``.obj`` with at least one ``*.mhskel`` in its folder.
    """
    obj = Path(obj_path)
    skel = _find_beside(obj, ["default.mhskel", "makehuman_default.mhskel"], "*.mhskel")
    if skel is None:
        return True
    try:
        joints = json.loads(skel.read_bytes().decode("utf-8")).get("joints")
        largest = max(int(i) for idx in joints.values() for i in idx)
        count = _obj_vertex_count(obj.read_bytes())
    except (OSError, ValueError, TypeError, AttributeError):
        return True  # read_makehuman names the problem
    return count > largest


def _skeleton_file(obj: Path, skel_path: str | os.PathLike[str] | None) -> Path:
    """``skel_path``, else the default.mhskel (or a single *.mhskel) beside the OBJ."""
    if skel_path is not None:
        return Path(skel_path)
    found = _find_beside(obj, ["default.mhskel", "makehuman_default.mhskel"], "*.mhskel")
    if found is None:
        raise FormatError(
            obj, "no skeleton given and no default.mhskel / makehuman_default.mhskel beside it"
        )
    return found


def _weights_file(
    skel: Path, skel_data: dict[str, Any], weights_path: str | os.PathLike[str] | None
) -> Path:
    """``weights_path``, else the rig's ``weights_file``, ``<rig>_weights.mhw`` or a
    single *_weights.mhw beside the rig."""
    if weights_path is not None:
        return Path(weights_path)
    cands = []
    wf = skel_data.get("weights_file")
    if isinstance(wf, str) and wf:
        cands.append(Path(wf).name)
    cands.append(f"{skel.stem}_weights.mhw")
    found = _find_beside(skel, cands, "*_weights.mhw")
    if found is None:
        raise FormatError(
            skel, f"no weights given and none of {cands} or a single *_weights.mhw beside it"
        )
    return found


def _inverse_rest_frames(heads: np.ndarray, tails: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(J, 4, 4) inverses of the bone rest frames (rigid: transpose and -R^T head);
    ``heads``, ``tails`` (J, 3) metres, ``normals`` (J, 3)."""
    bind = bone_rest_frames(heads, tails, normals)
    rot_t = np.transpose(bind[:, :3, :3], (0, 2, 1))
    inverse_bind = np.zeros_like(bind)
    inverse_bind[:, :3, :3] = rot_t
    inverse_bind[:, :3, 3] = -np.einsum("jab,jb->ja", rot_t, heads)
    inverse_bind[:, 3, 3] = 1.0
    return inverse_bind


def _body_only(obj: Path, mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """The mesh cut to the BODY_GROUP polygons and the (V',) indices of the kept vertices."""
    if BODY_GROUP not in mesh.groups:
        raise FormatError(
            obj, f"no '{BODY_GROUP}' group: cannot tell the skin from the helper geometry"
        )
    keep = np.zeros(mesh.n_polygons, dtype=bool)
    keep[mesh.groups[BODY_GROUP]] = True
    return _keep_polygons(mesh, keep)


# ------------------------------------------------------------- rig files on their own
def read_mhskel(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Validate a ``.mhskel`` rig file on its own and summarise it.

    Joint positions need the base mesh (they are centroids of its vertex groups),
    so a rig alone reads as a summary; :func:`read_makehuman` builds the skinned mesh.

    Returns
    -------
    dict with ``kind`` ``"rig"``, ``name``, ``bones``, ``joints`` (vertex groups),
    ``planes``, ``root`` and ``max_vertex`` (the highest base-mesh vertex it uses).
    """
    p = Path(path)
    data = _load_json(p)
    joints = data.get("joints")
    if not isinstance(joints, dict):
        raise FormatError(p, "'joints' must be an object of joint name -> vertex indices")
    top = -1
    for idx in joints.values():
        if (
            isinstance(idx, list)
            and idx
            and all(isinstance(i, int) and not isinstance(i, bool) for i in idx)
        ):
            top = max(top, max(idx))
    rig = _Rig(p, data, top + 1)
    return {
        "kind": "rig",
        "name": rig.name,
        "bones": len(rig.bone_names),
        "joints": len(rig.joint_vertices),
        "planes": len(rig.planes),
        "root": rig.bone_names[int(np.nonzero(rig.parents < 0)[0][0])],
        "max_vertex": top,
    }


def read_mhw(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Validate a ``.mhw`` weights file on its own and summarise it.

    Returns
    -------
    dict with ``kind`` ``"weights"``, ``bones``, ``vertices`` (distinct vertices
    weighted), ``max_vertex``, and the range of per-vertex weight sums (MakeHuman's
    weights are not normalised; :func:`read_makehuman` normalises them).
    """
    p = Path(path)
    data = _load_json(p)
    weights = data.get("weights")
    if not isinstance(weights, dict) or not weights:
        raise FormatError(
            p, "'weights' must be a non-empty object of bone name -> [[vertex, weight], ...]"
        )
    # sparse: the summary never allocates by the largest vertex index (#13: an index
    # of 2**31 asked a dense table for 2.17 TiB)
    rows = [_weight_pairs(p, str(b), pairs, MAX_VERTEX_INDEX + 1) for b, pairs in weights.items()]
    allrows = np.concatenate(rows) if rows else np.zeros((0, 2))
    vertex = allrows[:, 0].astype(np.int64)
    uniq, inverse = np.unique(vertex, return_inverse=True)
    sums = np.bincount(inverse, weights=allrows[:, 1], minlength=uniq.size)
    used = sums > 0
    return {
        "kind": "weights",
        "bones": len(weights),
        "vertices": int(used.sum()),
        "max_vertex": int(vertex.max()) if vertex.size else 0,
        "weight_sum_min": float(sums[used].min()) if used.any() else 0.0,
        "weight_sum_max": float(sums[used].max()) if used.any() else 0.0,
    }
