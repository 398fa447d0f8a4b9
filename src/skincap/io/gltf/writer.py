"""Skinned, animated glTF 2.0 binary (``.glb``) export.

One mesh node carries the triangles (positions, normals, ``TEXCOORD_0`` when the mesh
has UVs) and one skin; the skeleton becomes one node per joint in the joint hierarchy,
and the :class:`~skincap.types.Motion` becomes one animation with a LINEAR rotation and
a LINEAR translation sampler per joint node, keyed at ``t / rate`` seconds.

How the pieces line up (the skinning contract)
-----------------------------------------------
A joint node's local transform is ``T(translation) @ R(rotation)`` -- exactly the
local transform a :class:`~skincap.types.Motion` gives to forward kinematics -- so the
nodes' global transforms in the glTF are the world transforms ``W`` of
:func:`skincap.geometry.kinematics.forward_kinematics`, and the joint matrices a glTF
viewer computes, ``global(node) @ inverseBind``, are skincap's skinning matrices
``S = W @ skin.inverse_bind``. glTF defines skinning as linear blend skinning, so a
viewer shows what :class:`skincap.deform.skeletal.deformers.LinearBlendSkinning` computes.

glTF is metres and Y up like skincap: no unit or axis conversion happens. Quaternions
are written ``(x, y, z, w)``, the order both glTF and skincap use. The nodes' rest
(non-animated) transforms are the bind pose, ``local = inv(parent bind) @ bind``, when
that is rigid, else the motion's first frame. Rotation keys are made sign-continuous
(``q`` and ``-q`` are the same rotation, but importers that interpolate components
would swing the long way round between keys of opposite sign).
"""

from __future__ import annotations

import json
import os
import struct
import warnings
from typing import Any

import numpy as np

from skincap.errors import SkincapWarning, ValidationError
from skincap.geometry.rotations import matrix_to_quat
from skincap.io._common import atomic_output
from skincap.io.narrowing import check_float32
from skincap.types import Mesh, Motion, Skin

__all__ = ["write_glb", "GLTF_MAX_INFLUENCES"]

#: Influences per vertex in the written file (one JOINTS_0 / WEIGHTS_0 pair).
GLTF_MAX_INFLUENCES = 4

_GLB_MAGIC = 0x46546C67  # "glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_FLOAT, _USHORT, _UINT = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
_RIGID_TOLERANCE = 1e-6


class _Builder:
    """Accumulates bufferViews and accessors over one binary buffer."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = path  # named when a value does not fit float32
        self.blob = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def add(
        self,
        data: np.ndarray,
        component: int,
        *,
        target: int | None = None,
        minmax: bool = False,
        name: str = "value",
    ) -> int:
        """Append ``data`` (n, k) or (n,) as one accessor; return its index.

        Float data beyond float32's range is refused (FormatError naming ``name``).
        """
        dtype = {_FLOAT: "<f4", _USHORT: "<u2", _UINT: "<u4"}[component]
        if component == _FLOAT:
            check_float32(data, self.path, lambda idx: f"{name} {list(idx)}")
        arr = np.ascontiguousarray(data, dtype=dtype)
        n = arr.shape[0]
        width = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
        raw = arr.tobytes()
        pad = (-len(self.blob)) % 4
        self.blob += b"\0" * pad
        view: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        self.blob += raw
        self.views.append(view)
        acc: dict[str, Any] = {
            "bufferView": len(self.views) - 1,
            "componentType": component,
            "count": int(n),
            "type": _TYPE[width],
        }
        if minmax and n:
            flat = arr.reshape(n, width)
            cast = float if component == _FLOAT else int
            acc["min"] = [cast(x) for x in flat.min(axis=0)]
            acc["max"] = [cast(x) for x in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float64 unit area-weighted vertex normals; +Y for isolated vertices."""
    tri = vertices[faces]  # (F, 3, 3)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # (F, 3), |fn| = 2 area
    acc = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(acc, faces[:, corner], fn)
    norm = np.linalg.norm(acc, axis=1)
    out = np.tile([0.0, 1.0, 0.0], (vertices.shape[0], 1))
    ok = norm > 1e-300
    out[ok] = acc[ok] / norm[ok, None]
    return out


def _four_influences(
    indices: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """(V, 4) joints and weights: pad with zero weights or keep the 4 largest.

    Returns the number of vertices whose dropped weights were non-zero.
    """
    v, k = weights.shape
    n = GLTF_MAX_INFLUENCES
    if k <= n:
        j4 = np.zeros((v, n), dtype=np.int64)
        w4 = np.zeros((v, n))
        j4[:, :k] = indices
        w4[:, :k] = weights
        return j4, w4, 0
    order = np.argsort(-weights, axis=1, kind="stable")
    keep, drop = order[:, :n], order[:, n:]
    w4 = np.take_along_axis(weights, keep, axis=1)
    j4 = np.take_along_axis(indices, keep, axis=1)
    lost = np.take_along_axis(weights, drop, axis=1).sum(axis=1)
    w4 = w4 / w4.sum(axis=1, keepdims=True)
    return j4, w4, int(np.count_nonzero(lost > 0))


def _rigid_trs(local: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(J, 4) quaternions and (J, 3) translations of rigid (J, 4, 4) transforms, else None."""
    r = local[:, :3, :3]
    ortho = np.einsum("jab,jcb->jac", r, r) - np.eye(3)
    if (
        np.abs(ortho).max() > _RIGID_TOLERANCE
        or np.abs(np.linalg.det(r) - 1.0).max() > _RIGID_TOLERANCE
        or np.abs(local[:, 3, :] - [0.0, 0.0, 0.0, 1.0]).max() > _RIGID_TOLERANCE
    ):
        return None
    return matrix_to_quat(r), local[:, :3, 3].copy()


def _continuous(q: np.ndarray) -> np.ndarray:
    """(T, J, 4) quaternions with signs flipped so consecutive keys have dot >= 0."""
    if q.shape[0] < 2:
        return q.copy()
    dots = np.einsum("tjk,tjk->tj", q[1:], q[:-1])  # (T-1, J)
    flips = np.concatenate([np.zeros((1, q.shape[1]), dtype=np.int64), (dots < 0).astype(np.int64)])
    sign = np.where(np.cumsum(flips, axis=0) % 2 == 1, -1.0, 1.0)  # (T, J)
    return q * sign[..., None]


def _check_inputs(mesh: Mesh, motion: Motion) -> Skin:
    if not isinstance(mesh, Mesh):
        raise ValidationError(f"mesh: expected a skincap Mesh, got {type(mesh).__name__}")
    if not isinstance(motion, Motion):
        raise ValidationError(f"motion: expected a skincap Motion, got {type(motion).__name__}")
    skin = mesh.skin
    if skin is None:
        raise ValidationError(
            "mesh: has no skin; bind it to a skeleton first (skincap.deform.skeletal)"
        )
    if mesh.n_vertices == 0 or mesh.n_faces == 0:
        raise ValidationError(
            f"mesh: needs vertices and triangles, got {mesh.n_vertices} vertices and {mesh.n_faces} triangles"
        )
    skel = skin.skeleton
    mnames, snames = motion.skeleton.names, skel.names
    if mnames != snames:
        if len(mnames) != len(snames):
            raise ValidationError(
                f"motion: has {len(mnames)} joints, the mesh's skin has {len(snames)}; "
                "retarget the motion onto the skin's skeleton first"
            )
        k = next(i for i, (a, b) in enumerate(zip(mnames, snames, strict=True)) if a != b)
        raise ValidationError(
            f"motion: joint {k} is '{mnames[k]}' but the skin's joint {k} is '{snames[k]}'; "
            "retarget the motion onto the skin's skeleton first"
        )
    if not np.array_equal(motion.skeleton.parents, skel.parents):
        k = int(np.nonzero(motion.skeleton.parents != skel.parents)[0][0])
        raise ValidationError(
            f"motion: joint '{mnames[k]}' has parent {int(motion.skeleton.parents[k])} "
            f"but {int(skel.parents[k])} in the skin's skeleton"
        )
    if skel.n_joints > 65535:
        raise ValidationError(
            f"skin: glTF JOINTS_0 holds at most 65535 joints, got {skel.n_joints}"
        )
    if motion.n_frames < 1:
        raise ValidationError("motion: has no frames")
    ibm = skin.inverse_bind
    if not np.isfinite(ibm).all() or np.abs(ibm[:, 3, :] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise ValidationError(
            "skin.inverse_bind: must be finite affine matrices with last row (0, 0, 0, 1)"
        )
    return skin


def write_glb(
    mesh: Mesh,
    motion: Motion,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
) -> None:
    """Write a skinned mesh and its joint animation as a glTF 2.0 binary (``.glb``).

    Parameters
    ----------
    mesh : Mesh
        ``vertices`` (V, 3) float64 metres, Y up, in the bind pose; ``faces`` (F, 3)
        int64; optional ``uv`` (V, 2) (bottom-left origin, flipped to glTF's
        top-left: ``v_gltf = 1 - v``); ``skin`` required: ``joint_indices`` /
        ``joint_weights`` (V, K) and ``inverse_bind`` (J, 4, 4) metres. Written as
        float32 positions (area-weighted unit normals computed from the faces),
        UNSIGNED_SHORT ``JOINTS_0`` and FLOAT ``WEIGHTS_0`` with exactly 4 influences
        per vertex: fewer are padded with zero weights; with more, the 4 largest are
        kept and renormalised (a :class:`~skincap.errors.SkincapWarning` says how
        many vertices lost weight).
    motion : Motion
        On the skin's skeleton: the same joint names, order and parents as
        ``mesh.skin.skeleton``. ``rotations`` (T, J, 4) ``(x, y, z, w)`` and
        ``translations`` (T, J, 3) metres become LINEAR samplers at ``t / rate``
        seconds (float32). A one-frame motion gives one key per channel.
    path : str or PathLike
        Output ``.glb``; refused when it exists unless ``force``.
    force : bool
        Replace an existing file.

    Raises
    ------
    ValidationError
        The mesh has no skin or no triangles, the motion's joints differ from the
        skin's (the first mismatch is named), more than 65535 joints, or a
        non-affine inverse bind matrix.
    OutputExistsError
        ``path`` exists and ``force`` is False.

    Notes
    -----
    Nothing is NaN here: :class:`Mesh`, :class:`Skin` and :class:`Motion` refuse
    non-finite data. Joint ``j`` is node ``j`` (named after the joint); the mesh is
    the last node, at the scene root with no transform (glTF ignores the transform
    of a skinned mesh's node).
    """
    skin = _check_inputs(mesh, motion)
    skel = skin.skeleton
    nj = skel.n_joints
    b = _Builder(path)
    # accessor order is the file's byte order: mesh, inverse binds, animation
    attributes, idx_acc = _mesh_primitive(b, mesh, skin)
    # ---- skin: column-major MAT4
    ibm_acc = b.add(
        skin.inverse_bind.transpose(0, 2, 1).reshape(nj, 16), _FLOAT, name="inverse bind matrix"
    )
    nodes = _joint_nodes(skin, motion)
    mesh_node = nj
    nodes.append({"name": str(mesh.meta.get("name") or "mesh"), "mesh": 0, "skin": 0})
    samplers, channels = _animation(b, motion, nj)

    skin_obj: dict[str, Any] = {"joints": list(range(nj)), "inverseBindMatrices": ibm_acc}
    roots = [int(r) for r in np.nonzero(skel.parents < 0)[0]]
    if len(roots) == 1:
        skin_obj["skeleton"] = roots[0]
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "skincap"},
        "scene": 0,
        "scenes": [{"nodes": [mesh_node] + roots}],
        "nodes": nodes,
        "meshes": [
            {
                "name": str(mesh.meta.get("name") or "mesh"),
                "primitives": [{"attributes": attributes, "indices": idx_acc, "mode": 4}],
            }
        ],
        "skins": [skin_obj],
        "animations": [
            {
                "name": str(motion.meta.get("name") or "motion"),
                "samplers": samplers,
                "channels": channels,
                "extras": {"rate": motion.rate, "frames": motion.n_frames},
            }
        ],
        "buffers": [{"byteLength": len(b.blob)}],
        "bufferViews": b.views,
        "accessors": b.accessors,
    }
    _write_glb_chunks(path, doc, bytes(b.blob), force=force)


def _mesh_primitive(b: _Builder, mesh: Mesh, skin: Skin) -> tuple[dict[str, int], int]:
    """Add the mesh's accessors to ``b``: float32 positions and normals, uv (flipped to
    glTF's top-left origin), 4 joints and weights per vertex and the triangle indices.

    Returns the primitive's attributes (name -> accessor) and its index accessor;
    warns (SkincapWarning, at write_glb's caller) when vertices lose influences.
    """
    verts = mesh.vertices
    pos_acc = b.add(verts, _FLOAT, target=_ARRAY_BUFFER, minmax=True, name="vertex")
    nrm_acc = b.add(_vertex_normals(verts, mesh.faces), _FLOAT, target=_ARRAY_BUFFER, name="normal")
    attributes: dict[str, int] = {"POSITION": pos_acc, "NORMAL": nrm_acc}
    if mesh.uv is not None:
        uv = np.stack([mesh.uv[:, 0], 1.0 - mesh.uv[:, 1]], axis=1)
        attributes["TEXCOORD_0"] = b.add(uv, _FLOAT, target=_ARRAY_BUFFER, name="uv")
    j4, w4, n_lost = _four_influences(skin.joint_indices, skin.joint_weights)
    if n_lost:
        warnings.warn(
            f"glTF keeps {GLTF_MAX_INFLUENCES} influences per vertex: {n_lost} vertices "
            f"lost their smaller weights (the {GLTF_MAX_INFLUENCES} largest were renormalised)",
            SkincapWarning,
            stacklevel=3,
        )
    j4 = np.where(w4 > 0, j4, 0)
    attributes["JOINTS_0"] = b.add(j4, _USHORT, target=_ARRAY_BUFFER)
    attributes["WEIGHTS_0"] = b.add(w4, _FLOAT, target=_ARRAY_BUFFER)
    index_type = _USHORT if verts.shape[0] <= 65535 else _UINT
    idx_acc = b.add(mesh.faces.reshape(-1), index_type, target=_ELEMENT_ARRAY_BUFFER)
    return attributes, idx_acc


def _joint_nodes(skin: Skin, motion: Motion) -> list[dict[str, Any]]:
    """One node per joint (node j is joint j) with its children and rest TRS: the
    bind pose's local transforms when rigid, else the motion's frame 0."""
    skel = skin.skeleton
    bind = skin.bind_matrices  # (J, 4, 4)
    parents = skel.parents
    has = parents >= 0
    local_bind = bind.copy()
    local_bind[has] = np.linalg.solve(bind[parents[has]], bind[has])
    rest = _rigid_trs(local_bind)
    if rest is None:
        rest = (motion.rotations[0], motion.translations[0])
    rest_q, rest_t = rest
    nodes: list[dict[str, Any]] = []
    for j in range(skel.n_joints):
        node: dict[str, Any] = {
            "name": skel.names[j],
            "rotation": [float(x) for x in rest_q[j]],
            "translation": [float(x) for x in rest_t[j]],
        }
        kids = np.nonzero(parents == j)[0]
        if kids.size:
            node["children"] = [int(c) for c in kids]
        nodes.append(node)
    return nodes


def _animation(
    b: _Builder, motion: Motion, nj: int
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Add the key times (T,) s and each joint's rotation and translation keys to ``b``;
    the LINEAR samplers and their channels, joint by joint."""
    times = np.arange(motion.n_frames, dtype=np.float64) / motion.rate
    time_acc = b.add(times, _FLOAT, minmax=True, name="key time")
    q = _continuous(motion.rotations / np.linalg.norm(motion.rotations, axis=-1, keepdims=True))
    samplers: list[dict[str, Any]] = []
    channels: list[dict[str, Any]] = []
    for j in range(nj):
        for path_name, values in (
            ("rotation", q[:, j]),
            ("translation", motion.translations[:, j]),
        ):
            out_acc = b.add(values, _FLOAT, name="animation key")
            samplers.append({"input": time_acc, "output": out_acc, "interpolation": "LINEAR"})
            channels.append(
                {"sampler": len(samplers) - 1, "target": {"node": j, "path": path_name}}
            )
    return samplers, channels


def _write_glb_chunks(
    path: str | os.PathLike[str], doc: dict[str, Any], blob: bytes, *, force: bool
) -> None:
    """The GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded)."""
    json_bytes = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    json_bytes += b" " * ((-len(json_bytes)) % 4)
    bin_bytes = blob + b"\0" * ((-len(blob)) % 4)
    total = 12 + 8 + len(json_bytes) + 8 + len(bin_bytes)
    with atomic_output(path, force=force) as tmp, open(tmp, "wb") as fh:
        fh.write(struct.pack("<III", _GLB_MAGIC, 2, total))
        fh.write(struct.pack("<II", len(json_bytes), _CHUNK_JSON))
        fh.write(json_bytes)
        fh.write(struct.pack("<II", len(bin_bytes), _CHUNK_BIN))
        fh.write(bin_bytes)
