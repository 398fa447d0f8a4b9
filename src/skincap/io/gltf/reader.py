"""glTF 2.0 meshes and skins: ``read_gltf`` (``.gltf`` and ``.glb``).

glTF is metres and Y up, like skincap; ``meta["source_units"]`` is ``"m"`` and
``meta["up"]`` ``"y"``. Texture coordinates are flipped from glTF's top-left origin
to the bottom-left origin of OBJ (``v = 1 - v_gltf``) so both readers agree. The
file itself is parsed by :mod:`skincap.io.gltf.document`.
"""

from __future__ import annotations

import os
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.errors import FormatError, SkincapWarning
from skincap.io._common import check_readable
from skincap.io.gltf.document import GltfDocument, load_document, node_tree, scene_nodes
from skincap.types import Mesh, Skeleton, Skin

__all__ = ["read_gltf"]


WEIGHT_SUM_TOLERANCE = 1e-2
#: Vertices, and vertex indices, the default scene may add up to over all its mesh
#: instances. Nodes and primitives may share one accessor, so the file's size bounds
#: one instance only: a 1.8 MB GLB instancing a 10,000-vertex mesh 100,000 times asked
#: for 24 GB. 2**24 vertices are 400 MB of float64 positions, over ten times a dense
#: scanned body.
MAX_SCENE_VERTICES = 2**24
MAX_SCENE_INDICES = 3 * 2**24


def _triangles(g: GltfDocument, mode: int, idx: np.ndarray, where: str) -> np.ndarray:
    if mode == 4:
        if idx.size % 3:
            raise g.fail(f"{where}: {idx.size} indices is not a multiple of 3")
        return idx.reshape(-1, 3)
    if mode == 5:  # strip: alternate the winding of every other triangle
        k = np.arange(max(idx.size - 2, 0))
        a = np.where(k % 2 == 0, idx[k], idx[k + 1])
        b = np.where(k % 2 == 0, idx[k + 1], idx[k])
        return np.stack([a, b, idx[k + 2]], axis=1)
    if mode == 6:  # fan
        k = np.arange(max(idx.size - 2, 0))
        return np.stack(
            [np.full(k.size, idx[0] if idx.size else 0), idx[k + 1], idx[k + 2]], axis=1
        )
    raise g.fail(f"{where}: mode {mode} draws no triangles")  # points and lines are skipped


def read_gltf(path: str | os.PathLike[str]) -> Mesh:
    """Read the meshes of a glTF 2.0 file (``.gltf`` or ``.glb``) as one Mesh.

    Every mesh instance of the default scene (all nodes when there is no scene) is
    added: triangle, strip and fan primitives (points and lines are skipped with a
    warning); non-skinned meshes are placed by their node's world transform, skinned
    meshes are kept in bind space as the glTF spec requires.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    Mesh
        ``vertices`` (V, 3) float64 metres, Y up; ``faces`` (F, 3) int64; ``groups``
        maps each mesh node (its name, else ``node<i>``) to its triangle indices;
        ``uv`` (V, 2) float64 from ``TEXCOORD_0`` (v flipped to a bottom-left
        origin) when every primitive has one. ``skin`` when every primitive is
        skinned by one and the same glTF skin: a :class:`Skeleton` of the skin's
        joints (node names; parents = nearest ancestor joint; depth-sorted so
        parents come first; ``offsets`` (J, 3) metres = rest world position minus
        the parent's, from the nodes' transforms), ``joint_indices`` /
        ``joint_weights`` (V, 4k) from ``JOINTS_n`` / ``WEIGHTS_n`` (rows
        normalised, a SkincapWarning when they were not), ``inverse_bind`` (J, 4, 4)
        from ``inverseBindMatrices`` (identity when absent). ``meta`` holds
        ``joint_rest_world`` (J, 4, 4) the joints' node world transforms and
        ``joint_rest_rotations`` (J, 4) their rest rotations relative to the parent
        joint (x, y, z, w). No NaN: non-finite float data is a format error.

    Raises
    ------
    FormatError
        Bad JSON or GLB container, missing or short buffers, accessors or views
        out of range, indices past the vertex count, inconsistent attributes.
    """
    p = check_readable(path)
    try:
        return _read_gltf(p)
    except FormatError:
        raise
    except (
        KeyError,
        TypeError,
        ValueError,
        IndexError,
        OverflowError,
        AttributeError,
        struct.error,
        MemoryError,
    ) as exc:
        raise FormatError(p, f"malformed glTF: {type(exc).__name__}: {exc}") from None


def _declared_count(g: GltfDocument, i: Any) -> int:
    """The ``count`` accessor ``i`` declares, 0 when it is not a valid one (decoding the
    accessor then says what is wrong)."""
    count = g.item("accessors", i).get("count")
    return count if isinstance(count, int) and not isinstance(count, bool) and count > 0 else 0


def _check_scene_size(g: GltfDocument, nodes: list[int]) -> None:
    """FormatError when the triangle primitives of the mesh instances on ``nodes`` declare
    more than MAX_SCENE_VERTICES vertices or MAX_SCENE_INDICES indices in total, from the
    accessors' counts, before any is decoded."""
    n_vertices = n_indices = 0
    for ni in nodes:
        node = g.item("nodes", ni)
        if "mesh" not in node:
            continue
        prims = g.item("meshes", node["mesh"]).get("primitives")
        for prim in prims if isinstance(prims, list) else []:
            if not isinstance(prim, dict) or not isinstance(prim.get("attributes"), dict):
                continue  # the decoding loop names what is wrong
            if prim.get("mode", 4) not in (4, 5, 6) or "POSITION" not in prim["attributes"]:
                continue
            nv = _declared_count(g, prim["attributes"]["POSITION"])
            n_vertices += nv
            n_indices += _declared_count(g, prim["indices"]) if "indices" in prim else nv
    if n_vertices > MAX_SCENE_VERTICES or n_indices > MAX_SCENE_INDICES:
        raise g.fail(
            f"the scene's mesh instances add up to {n_vertices} vertices and {n_indices} "
            f"indices; skincap reads at most {MAX_SCENE_VERTICES} and {MAX_SCENE_INDICES}"
        )


def _read_gltf(p: Path) -> Mesh:
    g = load_document(p)
    parent, world, order = node_tree(g)
    _check_scene_size(g, scene_nodes(g, parent, order))
    verts_l: list[np.ndarray] = []
    faces_l: list[np.ndarray] = []
    uv_l: list[np.ndarray | None] = []
    joints_l: list[np.ndarray | None] = []
    weights_l: list[np.ndarray | None] = []
    skins_used: list[int | None] = []
    groups: dict[str, list[np.ndarray]] = {}
    n_verts = n_faces = 0
    for ni in scene_nodes(g, parent, order):
        node = g.item("nodes", ni)
        if "mesh" not in node:
            continue
        mesh = g.item("meshes", node["mesh"])
        prims = mesh.get("primitives")
        if not isinstance(prims, list) or not prims:
            raise g.fail(f"meshes[{node['mesh']}]: 'primitives' must be a non-empty array")
        skin_i = node.get("skin")
        if skin_i is not None:
            g.item("skins", skin_i)
        name = str(node.get("name") or mesh.get("name") or f"node{ni}")
        for k, prim in enumerate(prims):
            where = f"meshes[{node['mesh']}].primitives[{k}]"
            if not isinstance(prim, dict) or not isinstance(prim.get("attributes"), dict):
                raise g.fail(f"{where}: missing 'attributes'")
            attrs = prim["attributes"]
            mode = prim.get("mode", 4)
            if mode not in range(7):
                raise g.fail(f"{where}: unknown mode {mode!r}")
            if mode < 4:
                warnings.warn(
                    f"{p}: {where} has points or lines (mode {mode}); skipped",
                    SkincapWarning,
                    stacklevel=3,
                )
                continue
            if "POSITION" not in attrs:
                raise g.fail(f"{where}: no POSITION attribute")
            pos = g.accessor(attrs["POSITION"], what="POSITION")
            if pos.shape[1] != 3 or pos.dtype.kind != "f":
                raise g.fail(f"{where}: POSITION must be float VEC3")
            nv = pos.shape[0]
            if "indices" in prim:
                idx = g.accessor(prim["indices"], what="indices")
                if idx.shape[1] != 1 or idx.dtype.kind == "f":
                    raise g.fail(f"{where}: indices must be an unsigned integer SCALAR accessor")
                idx = idx.reshape(-1)
            else:
                idx = np.arange(nv, dtype=np.int64)
            if idx.size and (idx.min() < 0 or idx.max() >= nv):
                raise g.fail(f"{where}: vertex index {int(idx.max())} out of range 0..{nv - 1}")
            tri = _triangles(g, mode, idx, where)
            if skin_i is None:
                pos = pos @ world[ni, :3, :3].T + world[ni, :3, 3]
            uv = None
            if "TEXCOORD_0" in attrs:
                uv = g.accessor(attrs["TEXCOORD_0"], what="TEXCOORD_0")
                if uv.shape != (nv, 2):
                    raise g.fail(f"{where}: TEXCOORD_0 must be VEC2 with {nv} elements")
                uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
            jnt, wgt = _skin_attributes(g, attrs, nv, where) if skin_i is not None else (None, None)
            verts_l.append(pos)
            faces_l.append(tri + n_verts)
            uv_l.append(uv)
            joints_l.append(jnt)
            weights_l.append(wgt)
            skins_used.append(skin_i)
            groups.setdefault(name, []).append(np.arange(n_faces, n_faces + tri.shape[0]))
            n_verts += nv
            n_faces += tri.shape[0]
    if not verts_l:
        raise g.fail("no triangle meshes in the scene")
    vertices = np.concatenate(verts_l)
    faces = np.concatenate(faces_l).astype(np.int64)
    uv_all = None
    if all(u is not None for u in uv_l):
        uv_all = np.concatenate([u for u in uv_l if u is not None])
    elif any(u is not None for u in uv_l):
        warnings.warn(
            f"{p}: only some primitives have TEXCOORD_0; UVs dropped", SkincapWarning, stacklevel=3
        )
    meta: dict[str, Any] = {
        "source_units": "m",
        "up": "y",
        "source_format": "glb" if g.glb_bin is not None or p.suffix.lower() == ".glb" else "gltf",
    }
    asset = g.doc.get("asset", {})
    if isinstance(asset.get("generator"), str):
        meta["generator"] = asset["generator"]
    skin = None
    distinct = set(skins_used)
    if distinct and distinct != {None}:
        if len(distinct) == 1:
            only_skin = next(s for s in distinct if s is not None)
            skin, skin_meta = _build_skin(g, int(only_skin), parent, world, joints_l, weights_l)
            meta.update(skin_meta)
        else:
            warnings.warn(
                f"{p}: meshes use different skins or are partly unskinned; skin not read",
                SkincapWarning,
                stacklevel=3,
            )
    return Mesh(
        vertices=vertices,
        faces=faces,
        groups={k: np.concatenate(v) for k, v in groups.items()},
        uv=uv_all,
        skin=skin,
        meta=meta,
    )


def _skin_attributes(
    g: GltfDocument, attrs: dict[str, Any], nv: int, where: str
) -> tuple[np.ndarray, np.ndarray]:
    """(nv, 4k) joints (skin-joint indices) and raw weights from JOINTS_n / WEIGHTS_n."""
    j_sets, w_sets = [], []
    n = 0
    while f"JOINTS_{n}" in attrs or f"WEIGHTS_{n}" in attrs:
        if f"JOINTS_{n}" not in attrs or f"WEIGHTS_{n}" not in attrs:
            raise g.fail(f"{where}: JOINTS_{n} and WEIGHTS_{n} must come together")
        j = g.accessor(attrs[f"JOINTS_{n}"], what=f"JOINTS_{n}")
        w = g.accessor(attrs[f"WEIGHTS_{n}"], what=f"WEIGHTS_{n}")
        if j.shape != (nv, 4) or j.dtype.kind == "f":
            raise g.fail(f"{where}: JOINTS_{n} must be unsigned integer VEC4 with {nv} elements")
        if w.shape != (nv, 4) or w.dtype.kind != "f":
            raise g.fail(
                f"{where}: WEIGHTS_{n} must be float or normalized VEC4 with {nv} elements"
            )
        j_sets.append(j)
        w_sets.append(w)
        n += 1
    if not j_sets:
        raise g.fail(f"{where}: skinned mesh without JOINTS_0 / WEIGHTS_0")
    return np.concatenate(j_sets, axis=1), np.concatenate(w_sets, axis=1)


#: Largest condition number of an inverse-bind matrix's 3x3 part: beyond it the bind
#: pose cannot be recovered from it (float32 storage carries ~7 digits).
MAX_BIND_CONDITION = 1e6


def _check_inverse_binds(g: GltfDocument, where: str, ibm: np.ndarray) -> None:
    """FormatError unless every (4, 4) inverse-bind matrix is an invertible affine transform.

    glTF 2.0 (section 3.7.3.2): their fourth row MUST be (0, 0, 0, 1); skinning inverts
    them to find the bind pose, so a singular one (all zero, a zero scale) is refused.
    """
    bottom_ok = np.abs(ibm[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= 1e-5
    singular = ~(np.linalg.cond(ibm[:, :3, :3]) <= MAX_BIND_CONDITION)  # inf when singular
    for bad, what in (
        (~bottom_ok, "has a fourth row other than (0, 0, 0, 1)"),
        (singular, "is singular (not invertible)"),
    ):
        if bad.any():
            k = int(np.argmax(bad))
            raise g.fail(
                f"{where}: inverseBindMatrices[{k}] {what} ({int(bad.sum())} of {len(ibm)})"
            )


def _build_skin(
    g: GltfDocument,
    skin_i: int,
    parent: np.ndarray,
    world: np.ndarray,
    joints_l: list[np.ndarray | None],
    weights_l: list[np.ndarray | None],
) -> tuple[Skin, dict[str, Any]]:
    sk = g.item("skins", skin_i)
    where = f"skins[{skin_i}]"
    joint_nodes = sk.get("joints")
    n_nodes = parent.size
    if (
        not isinstance(joint_nodes, list)
        or not joint_nodes
        or not all(
            isinstance(j, int) and not isinstance(j, bool) and 0 <= j < n_nodes for j in joint_nodes
        )
        or len(set(joint_nodes)) != len(joint_nodes)
    ):
        raise g.fail(f"{where}: 'joints' must be a non-empty array of distinct node indices")
    nj = len(joint_nodes)
    if "inverseBindMatrices" in sk:
        ibm = g.accessor(sk["inverseBindMatrices"], what=f"{where} inverseBindMatrices")
        if ibm.shape != (nj, 16) or ibm.dtype.kind != "f":
            raise g.fail(f"{where}: inverseBindMatrices must be {nj} float MAT4")
        ibm = ibm.reshape(nj, 4, 4).transpose(0, 2, 1)  # column-major in the file
        _check_inverse_binds(g, where, ibm)
    else:
        ibm = np.tile(np.eye(4), (nj, 1, 1))
    # nearest ancestor that is a joint of this skin
    slot = {node: k for k, node in enumerate(joint_nodes)}
    jparent = np.full(nj, -1, dtype=np.int64)
    depth = np.zeros(nj, dtype=np.int64)
    for k, node in enumerate(joint_nodes):
        a = parent[node]
        while a >= 0 and int(a) not in slot:
            a = parent[a]
        jparent[k] = slot[int(a)] if a >= 0 else -1
    for k in range(nj):
        a, d = jparent[k], 0
        while a >= 0:
            a, d = jparent[a], d + 1
        depth[k] = d
    new_order = np.argsort(depth, kind="stable")  # parents before children
    old_to_new = np.empty(nj, dtype=np.int64)
    old_to_new[new_order] = np.arange(nj)
    parents = np.array(
        [old_to_new[jparent[o]] if jparent[o] >= 0 else -1 for o in new_order], dtype=np.int64
    )
    nodes_sorted = [joint_nodes[o] for o in new_order]
    names, seen = [], set()
    for node in nodes_sorted:
        base = str(g.item("nodes", node).get("name") or f"joint{node}")
        nm, c = base, 1
        while nm in seen:
            nm, c = f"{base}.{c}", c + 1
        seen.add(nm)
        names.append(nm)
    jw = world[nodes_sorted]
    heads = jw[:, :3, 3]
    offsets = heads.copy()
    has = parents >= 0
    offsets[has] = heads[has] - heads[parents[has]]
    det = np.linalg.det(jw[:, :3, :3])  # (J,)
    if not (det > 0).all():  # a zero or mirroring scale: no rest rotation to take
        k = int(np.flatnonzero(~(det > 0))[0])
        raise g.fail(
            f"{where}: joint node {nodes_sorted[k]} ({names[k]!r}) has a zero or negative "
            f"scale in its world transform (determinant {det[k]:.3g}); its rest rotation "
            "is undefined"
        )
    rot_world = Rotation.from_matrix(jw[:, :3, :3])  # scale removed by projection
    rel = rot_world
    if has.any():
        parent_rot = Rotation.from_matrix(jw[np.where(has, parents, 0), :3, :3])
        rel = parent_rot.inv() * rot_world
    rest_quat = rel.as_quat()
    rest_quat[~has] = rot_world.as_quat()[~has]
    skeleton = Skeleton(names=names, parents=parents, offsets=offsets)

    jnt = np.concatenate([j for j in joints_l if j is not None])
    wgt = np.concatenate([w for w in weights_l if w is not None])
    if jnt.size and (jnt.min() < 0 or jnt.max() >= nj):
        raise g.fail(f"{where}: JOINTS value {int(jnt.max())} out of range 0..{nj - 1}")
    if (wgt < 0).any():
        raise g.fail(f"{where}: negative skin weight")
    jnt = old_to_new[jnt]
    sums = wgt.sum(axis=1)
    empty = sums <= 0
    if empty.any():
        warnings.warn(
            f"{g.path}: {int(empty.sum())} vertices have no skin weight; bound to joint '{names[0]}'",
            SkincapWarning,
            stacklevel=4,
        )
        wgt[empty] = 0.0
        wgt[empty, 0] = 1.0
        jnt[empty, 0] = 0
        sums[empty] = 1.0
    if np.abs(sums - 1.0).max() > WEIGHT_SUM_TOLERANCE:
        warnings.warn(
            f"{g.path}: skin weights were not normalised (row sums {sums.min():.4g}..{sums.max():.4g}); normalised",
            SkincapWarning,
            stacklevel=4,
        )
    wgt = wgt / sums[:, None]
    jnt = np.where(wgt > 0, jnt, 0)
    skin = Skin(
        skeleton=skeleton, joint_indices=jnt, joint_weights=wgt, inverse_bind=ibm[new_order]
    )
    meta = {
        "joint_rest_world": jw,
        "joint_rest_rotations": rest_quat,
        "joint_nodes": np.asarray(nodes_sorted, dtype=np.int64),
    }
    return skin, meta
