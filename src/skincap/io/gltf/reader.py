"""glTF 2.0 reader (``.gltf`` with external or data-URI buffers, and binary ``.glb``).

The JSON and the binary buffers are parsed here with numpy (no glTF dependency):
accessors with every component type, ``normalized`` integers, interleaved buffer
views (``byteStride``), padded matrix columns and sparse substitution.

glTF is metres and Y up, like skincap; ``meta["source_units"]`` is ``"m"`` and
``meta["up"]`` ``"y"``. Texture coordinates are flipped from glTF's top-left origin
to the bottom-left origin of OBJ (``v = 1 - v_gltf``) so both readers agree.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import stat
import struct
import urllib.parse
import warnings
from pathlib import Path, PureWindowsPath
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.errors import FormatError, SkincapWarning, quote_excerpt
from skincap.io._common import check_readable
from skincap.types import Mesh, Skeleton, Skin

__all__ = ["read_gltf", "read_gltf_animation", "GltfAnimation"]

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942

_COMPONENT = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_N_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
# normalized integer -> float, glTF 2.0 section 3.11
_NORMALIZE = {
    "i1": lambda c: np.maximum(c / 127.0, -1.0),
    "u1": lambda c: c / 255.0,
    "i2": lambda c: np.maximum(c / 32767.0, -1.0),
    "u2": lambda c: c / 65535.0,
    "u4": lambda c: c / 4294967295.0,
}
#: Tolerance on skin weight row sums before a "not normalised" warning (quantised
#: 8-bit weights are off by up to 4 * 0.5 / 255).
WEIGHT_SUM_TOLERANCE = 1e-2


class _Doc:
    """A parsed glTF document with lazily loaded buffers."""

    def __init__(self, path: Path, doc: dict[str, Any], glb_bin: bytes | None) -> None:
        self.path = path
        self.doc = doc
        self.glb_bin = glb_bin
        self._buffers: dict[int, bytes] = {}

    # --------------------------------------------------------------- plumbing
    def fail(self, what: str) -> FormatError:
        return FormatError(self.path, what)

    def items(self, key: str) -> list[Any]:
        value = self.doc.get(key, [])
        if not isinstance(value, list):
            raise self.fail(f"'{key}' must be an array")
        return value

    def item(self, key: str, i: Any) -> dict[str, Any]:
        arr = self.items(key)
        if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i < len(arr):
            raise self.fail(f"{key}[{i!r}] does not exist (the file has {len(arr)} {key})")
        obj = arr[i]
        if not isinstance(obj, dict):
            raise self.fail(f"{key}[{i}] must be an object")
        return obj

    @staticmethod
    def as_int(obj: dict[str, Any], key: str, default: int | None, where: str, fail: Any) -> int:
        v = obj.get(key, default)
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise fail(f"{where}: '{key}' must be a non-negative integer, got {v!r}")
        return v

    # ---------------------------------------------------------------- buffers
    def buffer(self, i: int) -> bytes:
        if i in self._buffers:
            return self._buffers[i]
        buf = self.item("buffers", i)
        length = self.as_int(buf, "byteLength", None, f"buffers[{i}]", self.fail)
        uri = buf.get("uri")
        if uri is None:
            if i != 0 or self.glb_bin is None:
                raise self.fail(f"buffers[{i}] has no uri and there is no GLB binary chunk")
            data = self.glb_bin
        elif not isinstance(uri, str):
            raise self.fail(f"buffers[{i}]: uri must be a string")
        elif uri.startswith("data:"):
            head, sep, payload = uri.partition(",")
            if not sep or not head.endswith(";base64"):
                raise self.fail(f"buffers[{i}]: only base64 data URIs are supported")
            try:
                data = base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError):
                raise self.fail(f"buffers[{i}]: data URI is not valid base64") from None
        else:
            data = self._external_buffer(i, uri, length)
        if len(data) < length:
            raise self.fail(f"buffers[{i}]: holds {len(data)} bytes, byteLength says {length}")
        self._buffers[i] = data[:length]
        return self._buffers[i]

    def _external_buffer(self, i: int, uri: str, length: int) -> bytes:
        """The first ``length`` bytes of the file a buffer's relative ``uri`` names.

        A shared or downloaded ``.gltf`` must not make skincap read other files: the
        uri must be a relative path (no scheme, no absolute path, no ``..``) to a
        regular file inside the glTF's own folder once symlinks are resolved, and no
        more than ``byteLength`` bytes of it are read (``/dev/zero`` or a FIFO never
        get opened for reading: they are not regular files).
        """
        where = f"buffers[{i}]: uri {quote_excerpt(uri)}"
        parts = urllib.parse.urlsplit(uri)
        if parts.scheme or parts.netloc or parts.query or parts.fragment:
            raise self.fail(f"{where}: only a relative file name or a data: URI is read")
        rel = urllib.parse.unquote(parts.path)
        pieces = rel.replace("\\", "/").split("/")
        if (
            not rel
            or "\x00" in rel
            or rel.startswith(("/", "\\"))
            or PureWindowsPath(rel).drive
            or ".." in pieces
        ):
            raise self.fail(f"{where}: must be a relative path inside the glTF's folder")
        folder = self.path.parent.resolve()
        target = folder / rel
        try:
            real = target.resolve(strict=True)
        except (OSError, RuntimeError) as exc:  # missing, or a symlink loop
            reason = getattr(exc, "strerror", None) or "cannot be resolved"
            raise self.fail(f"{where}: cannot read it: {reason.lower()}") from None
        if not real.is_relative_to(folder):
            raise self.fail(f"{where}: leads outside the glTF's folder (a symlink)")
        if not real.is_file():  # a device, FIFO or socket is never opened
            raise self.fail(f"{where}: is not a regular file")
        try:
            # O_NONBLOCK: should a FIFO replace the file meanwhile, open() must not wait
            fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        except OSError as exc:
            reason = (exc.strerror or str(exc)).lower()
            raise self.fail(f"{where}: cannot read it: {reason}") from None
        with os.fdopen(fd, "rb") as fh:
            info = os.fstat(fh.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise self.fail(f"{where}: is not a regular file")
            if info.st_size < length:
                raise self.fail(f"{where}: holds {info.st_size} bytes, byteLength says {length}")
            return fh.read(length)

    def view(self, i: int) -> tuple[bytes, int, int, int | None]:
        """(buffer, byteOffset, byteLength, byteStride) of bufferView i, range-checked."""
        bv = self.item("bufferViews", i)
        where = f"bufferViews[{i}]"
        buf = self.buffer(self.as_int(bv, "buffer", None, where, self.fail))
        off = self.as_int(bv, "byteOffset", 0, where, self.fail)
        length = self.as_int(bv, "byteLength", None, where, self.fail)
        stride = bv.get("byteStride")
        if stride is not None:
            stride = self.as_int(bv, "byteStride", None, where, self.fail)
            if not 4 <= stride <= 252 or stride % 4:
                raise self.fail(f"{where}: byteStride {stride} must be a multiple of 4 in 4..252")
        if off + length > len(buf):
            raise self.fail(
                f"{where}: bytes {off}..{off + length} run past the buffer's {len(buf)} bytes"
            )
        return buf, off, length, stride

    # -------------------------------------------------------------- accessors
    def accessor(self, i: Any, *, what: str) -> np.ndarray:
        """(count, n_components) array: float64, or int64 for non-normalized integers."""
        acc = self.item("accessors", i)
        where = f"accessors[{i}] ({what})"
        ctype = acc.get("componentType")
        atype = acc.get("type")
        if ctype not in _COMPONENT:
            raise self.fail(f"{where}: unknown componentType {ctype!r}")
        if atype not in _N_COMPONENTS:
            raise self.fail(f"{where}: unknown type {atype!r}")
        count = self.as_int(acc, "count", None, where, self.fail)
        if count < 1:
            raise self.fail(f"{where}: count must be at least 1")
        dt = np.dtype("<" + _COMPONENT[ctype])
        ncomp = _N_COMPONENTS[atype]
        normalized = bool(acc.get("normalized", False))
        if normalized and dt.kind == "f":
            raise self.fail(f"{where}: float components cannot be 'normalized'")
        if "bufferView" in acc:
            out = self._read_dense(acc, where, dt, atype, ncomp, count)
        else:
            out = np.zeros((count, ncomp), dtype=dt)
        if "sparse" in acc:
            out = self._apply_sparse(acc["sparse"], where, out, dt, ncomp, count)
        if normalized:
            return _NORMALIZE[dt.str[1:]](out.astype(np.float64))
        if dt.kind == "f":
            res = out.astype(np.float64)
            if not np.isfinite(res).all():
                raise self.fail(f"{where}: contains non-finite values")
            return res
        return out.astype(np.int64)

    def _read_dense(
        self, acc: dict[str, Any], where: str, dt: np.dtype, atype: str, ncomp: int, count: int
    ) -> np.ndarray:
        buf, view_off, view_len, stride = self.view(acc["bufferView"])
        acc_off = self.as_int(acc, "byteOffset", 0, where, self.fail)
        csize = dt.itemsize
        if atype.startswith("MAT") and csize < 4:
            rows = {"MAT2": 2, "MAT3": 3, "MAT4": 4}[atype]
            col_bytes = -(-rows * csize // 4) * 4  # columns start on 4-byte boundaries
            elem = rows * col_bytes
            keep = np.concatenate(
                [np.arange(c * col_bytes, c * col_bytes + rows * csize) for c in range(rows)]
            )
        else:
            elem = ncomp * csize
            keep = None
        step = stride or elem
        if step < elem:
            raise self.fail(f"{where}: byteStride {step} is smaller than an element ({elem} bytes)")
        end = acc_off + step * (count - 1) + elem
        if end > view_len:
            raise self.fail(
                f"{where}: needs bytes {acc_off}..{end} of a {view_len}-byte bufferView"
            )
        raw = np.frombuffer(buf, dtype=np.uint8, count=end, offset=view_off)
        if step == elem and keep is None:
            block = raw[acc_off:end]
        else:
            rows_at = acc_off + np.arange(count)[:, None] * step
            cols = keep if keep is not None else np.arange(elem)
            block = raw[rows_at + cols[None, :]]
        return np.ascontiguousarray(block).view(dt).reshape(count, ncomp)

    def _apply_sparse(
        self, sparse: Any, where: str, out: np.ndarray, dt: np.dtype, ncomp: int, count: int
    ) -> np.ndarray:
        if (
            not isinstance(sparse, dict)
            or not isinstance(sparse.get("indices"), dict)
            or not isinstance(sparse.get("values"), dict)
        ):
            raise self.fail(f"{where}: malformed 'sparse'")
        n = self.as_int(sparse, "count", None, f"{where} sparse", self.fail)
        if n < 1:
            raise self.fail(f"{where}: sparse count must be at least 1")
        ind = sparse["indices"]
        it = ind.get("componentType")
        if it not in (5121, 5123, 5125):
            raise self.fail(f"{where}: sparse indices componentType {it!r} must be unsigned")
        idx = self._read_dense(
            {"bufferView": ind.get("bufferView"), "byteOffset": ind.get("byteOffset", 0)},
            f"{where} sparse indices",
            np.dtype("<" + _COMPONENT[it]),
            "SCALAR",
            1,
            n,
        ).reshape(-1)
        vals = self._read_dense(
            {
                "bufferView": sparse["values"].get("bufferView"),
                "byteOffset": sparse["values"].get("byteOffset", 0),
            },
            f"{where} sparse values",
            dt,
            "VEC" if ncomp > 1 else "SCALAR",
            ncomp,
            n,
        )
        if idx.max() >= count:
            raise self.fail(f"{where}: sparse index {int(idx.max())} out of range 0..{count - 1}")
        out = out.copy()
        out[idx.astype(np.int64)] = vals
        return out


# ------------------------------------------------------------------------- loading
def _load(path: Path) -> _Doc:
    data = path.read_bytes()
    glb_bin = None
    if data[:4] == _GLB_MAGIC:
        if len(data) < 20:
            raise FormatError(path, "GLB header truncated", offset=len(data))
        _, version, length = struct.unpack_from("<4sII", data, 0)
        if version != 2:
            raise FormatError(path, f"GLB version {version}, only 2 is supported", offset=4)
        if length > len(data):
            raise FormatError(
                path, f"GLB header says {length} bytes, the file has {len(data)}", offset=8
            )
        pos = 12
        chunks: list[tuple[int, bytes]] = []
        while pos + 8 <= length:
            clen, ctype = struct.unpack_from("<II", data, pos)
            if pos + 8 + clen > length:
                raise FormatError(path, f"GLB chunk of {clen} bytes runs past the end", offset=pos)
            chunks.append((ctype, data[pos + 8 : pos + 8 + clen]))
            pos += 8 + clen
        if not chunks or chunks[0][0] != _CHUNK_JSON:
            raise FormatError(path, "GLB: the first chunk must be JSON", offset=12)
        text_bytes = chunks[0][1]
        for ctype, cdata in chunks[1:]:
            if ctype == _CHUNK_BIN:
                glb_bin = cdata
                break
    else:
        text_bytes = data
    try:
        text = text_bytes.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(
            path, f"glTF JSON is not UTF-8 ({exc.reason})", offset=exc.start
        ) from None
    try:
        doc = json.loads(text.rstrip(" \x00"))
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid glTF JSON: {exc.msg}", line=exc.lineno) from None
    except RecursionError:
        raise FormatError(path, "invalid glTF JSON: nested too deeply") from None
    if not isinstance(doc, dict):
        raise FormatError(path, "glTF JSON must be an object")
    asset = doc.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if not isinstance(version, str) or not version.startswith("2"):
        raise FormatError(path, f"asset.version {version!r}: only glTF 2.x is supported")
    return _Doc(path, doc, glb_bin)


def _node_trs(g: _Doc, i: int, node: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked translation (3,), rotation (4,) x, y, z, w and scale (3,) of node i."""
    t = np.asarray(node.get("translation", [0, 0, 0]), dtype=np.float64)
    r = np.asarray(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
    s = np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64)
    if (
        t.shape != (3,)
        or r.shape != (4,)
        or s.shape != (3,)
        or not (np.isfinite(t).all() and np.isfinite(r).all() and np.isfinite(s).all())
    ):
        raise g.fail(f"nodes[{i}]: translation/rotation/scale must be 3/4/3 finite numbers")
    if np.linalg.norm(r) < 1e-8:
        raise g.fail(f"nodes[{i}]: rotation quaternion has zero length")
    return t, r, s


def _local_matrix(g: _Doc, i: int, node: dict[str, Any]) -> np.ndarray:
    """(4, 4) local transform of node i (its 'matrix' or T * R * S)."""
    if "matrix" in node:
        m = (
            np.asarray(node["matrix"], dtype=np.float64)
            if isinstance(node["matrix"], list)
            else None
        )
        if m is None or m.shape != (16,) or not np.isfinite(m).all():
            raise g.fail(f"nodes[{i}]: 'matrix' must be 16 finite numbers")
        return m.reshape(4, 4).T  # column-major in the file
    t, r, s = _node_trs(g, i, node)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(r).as_matrix() * s[None, :]  # (x, y, z, w), as scipy
    m[:3, 3] = t
    return m


def _node_tree(g: _Doc) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Parents (N,) (-1 for roots), world matrices (N, 4, 4) and nodes by depth order."""
    nodes = g.items("nodes")
    n = len(nodes)
    parent = np.full(n, -1, dtype=np.int64)
    local = np.zeros((n, 4, 4))
    for i in range(n):
        node = g.item("nodes", i)
        local[i] = _local_matrix(g, i, node)
        children = node.get("children", [])
        if not isinstance(children, list):
            raise g.fail(f"nodes[{i}]: 'children' must be an array")
        for c in children:
            if not isinstance(c, int) or isinstance(c, bool) or not 0 <= c < n:
                raise g.fail(f"nodes[{i}]: child {c!r} does not exist")
            if parent[c] >= 0 or c == i:
                raise g.fail(f"nodes[{c}] has more than one parent (or is its own child)")
            parent[c] = i
    # breadth-first from the roots; a node never reached sits on a cycle
    order: list[int] = [i for i in range(n) if parent[i] < 0]
    k = 0
    child_lists: dict[int, list[int]] = {}
    for c in range(n):
        if parent[c] >= 0:
            child_lists.setdefault(int(parent[c]), []).append(c)
    while k < len(order):
        order.extend(child_lists.get(order[k], []))
        k += 1
    if len(order) != n:
        raise g.fail("the node hierarchy has a cycle")
    world = np.zeros_like(local)
    for i in order:
        world[i] = local[i] if parent[i] < 0 else world[parent[i]] @ local[i]
    return parent, world, order


def _scene_nodes(g: _Doc, parent: np.ndarray, order: list[int]) -> list[int]:
    """Nodes of the default scene in node-index order (all nodes when there is no scene)."""
    scenes = g.items("scenes")
    if not scenes:
        return sorted(order)
    s = g.doc.get("scene", 0)
    roots = g.item("scenes", s).get("nodes", [])
    if not isinstance(roots, list):
        raise g.fail(f"scenes[{s}]: 'nodes' must be an array")
    keep = np.zeros(parent.size, dtype=bool)
    for r in roots:
        if not isinstance(r, int) or isinstance(r, bool) or not 0 <= r < parent.size:
            raise g.fail(f"scenes[{s}]: node {r!r} does not exist")
        keep[r] = True
    for i in order:  # parents come first in `order`
        if parent[i] >= 0 and keep[parent[i]]:
            keep[i] = True
    return [i for i in range(parent.size) if keep[i]]


def _triangles(g: _Doc, mode: int, idx: np.ndarray, where: str) -> np.ndarray | None:
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
    return None


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


def _read_gltf(p: Path) -> Mesh:
    g = _load(p)
    parent, world, order = _node_tree(g)
    verts_l: list[np.ndarray] = []
    faces_l: list[np.ndarray] = []
    uv_l: list[np.ndarray | None] = []
    joints_l: list[np.ndarray | None] = []
    weights_l: list[np.ndarray | None] = []
    skins_used: list[int | None] = []
    groups: dict[str, list[np.ndarray]] = {}
    n_verts = n_faces = 0
    for ni in _scene_nodes(g, parent, order):
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
            skin_i = skins_used[0]
            skin, skin_meta = _build_skin(g, int(skin_i), parent, world, joints_l, weights_l)
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
    g: _Doc, attrs: dict[str, Any], nv: int, where: str
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


def _check_inverse_binds(g: _Doc, where: str, ibm: np.ndarray) -> None:
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
    g: _Doc,
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


class GltfAnimation(NamedTuple):
    """What :func:`read_gltf_animation` returns.

    Attributes
    ----------
    times : (T,) float64, seconds
        The sample times: ``start + arange(T) / rate``.
    rate : float, Hz
    node_world : (T, N, 4, 4) float64
        World transform of every node of the file (metres, Y up) at each sample,
        column-vector convention like glTF.
    name : str
        The animation's name (``animation<i>`` when it has none).
    """

    times: np.ndarray
    rate: float
    node_world: np.ndarray
    name: str


def read_gltf_animation(
    path: str | os.PathLike[str], *, animation: int = 0, rate: float | None = None
) -> GltfAnimation | None:
    """Sample one animation of a glTF file into per-frame node world transforms.

    ``translation``, ``rotation`` and ``scale`` channels are evaluated with their
    sampler's interpolation (``LINEAR`` — spherical for rotations — ``STEP`` or
    ``CUBICSPLINE``, the Hermite form of the glTF spec); nodes without a channel keep
    their rest transform. Morph-target ``weights`` channels are ignored.

    Parameters
    ----------
    path : str or PathLike
    animation : int, default 0
        Which of the file's animations.
    rate : float, optional, Hz
        Sampling rate. Default: the rate of the keyframes (``1 / median`` spacing of
        all key times, e.g. the capture rate for files skincap writes), at most 240.

    Returns
    -------
    GltfAnimation or None
        None when the file has no animation.

    Raises
    ------
    FormatError
        Malformed animation data (bad sampler or channel references, key times not
        increasing, output counts that do not match).
    """
    p = check_readable(path)
    try:
        return _read_gltf_animation(p, animation, rate)
    except FormatError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, OverflowError, struct.error) as exc:
        raise FormatError(p, f"malformed glTF animation: {type(exc).__name__}: {exc}") from None


def _read_gltf_animation(p: Path, which: int, rate: float | None) -> GltfAnimation | None:
    g = _load(p)
    anims = g.items("animations")
    if not anims:
        return None
    anim = g.item("animations", which)
    where = f"animations[{which}]"
    samplers = anim.get("samplers")
    channels = anim.get("channels")
    if not isinstance(samplers, list) or not isinstance(channels, list):
        raise g.fail(f"{where}: 'samplers' and 'channels' must be arrays")
    parent, _, order = _node_tree(g)
    n_nodes = parent.size
    keyed: list[tuple[int, str, np.ndarray, np.ndarray, str]] = []
    for c, ch in enumerate(channels):
        target = ch.get("target") if isinstance(ch, dict) else None
        if not isinstance(target, dict):
            raise g.fail(f"{where}.channels[{c}]: missing 'target'")
        path_name = target.get("path")
        if path_name == "weights":
            continue
        if path_name not in ("translation", "rotation", "scale"):
            raise g.fail(f"{where}.channels[{c}]: unknown target path {path_name!r}")
        node = target.get("node")
        if not isinstance(node, int) or isinstance(node, bool) or not 0 <= node < n_nodes:
            raise g.fail(f"{where}.channels[{c}]: node {node!r} does not exist")
        s = ch.get("sampler")
        if not isinstance(s, int) or isinstance(s, bool) or not 0 <= s < len(samplers):
            raise g.fail(f"{where}.channels[{c}]: sampler {s!r} does not exist")
        smp = samplers[s]
        interp = smp.get("interpolation", "LINEAR")
        if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
            raise g.fail(f"{where}.samplers[{s}]: unknown interpolation {interp!r}")
        t_in = g.accessor(smp.get("input"), what=f"{where}.samplers[{s}].input").reshape(-1)
        if t_in.size > 1 and not (np.diff(t_in) > 0).all():
            raise g.fail(f"{where}.samplers[{s}]: key times must increase strictly")
        values = g.accessor(smp.get("output"), what=f"{where}.samplers[{s}].output")
        width = 4 if path_name == "rotation" else 3
        per_key = 3 if interp == "CUBICSPLINE" else 1
        if values.shape != (t_in.size * per_key, width):
            raise g.fail(
                f"{where}.samplers[{s}]: {values.shape[0]} outputs of width {values.shape[1]} "
                f"for {t_in.size} keys of {path_name}"
            )
        keyed.append((node, path_name, t_in, values.astype(np.float64), interp))
    if not keyed:
        return None
    all_times = np.unique(np.concatenate([k[2] for k in keyed]))
    start, end = float(all_times[0]), float(all_times[-1])
    if rate is None:
        step = float(np.median(np.diff(all_times))) if all_times.size > 1 else 1.0 / 30.0
        rate = min(240.0, 1.0 / step) if step > 0 else 30.0
        if abs(rate - round(rate)) < 1e-3 * rate:  # float32 key times: 120.0018 -> 120
            rate = float(round(rate))
    if not (np.isfinite(rate) and rate > 0):
        raise FormatError(p, f"sampling rate must be positive, got {rate!r}")
    n = int(np.floor((end - start) * rate + 1e-6)) + 1
    times = start + np.arange(n) / rate

    # rest TRS of every node, then overwrite the animated parts per frame
    rest_t = np.zeros((n_nodes, 3))
    rest_r = np.tile([0.0, 0.0, 0.0, 1.0], (n_nodes, 1))
    rest_s = np.ones((n_nodes, 3))
    rest_matrix: dict[int, np.ndarray] = {}
    for i in range(n_nodes):
        node = g.item("nodes", i)
        if "matrix" in node:
            rest_matrix[i] = _local_matrix(g, i, node)
            continue
        rest_t[i], rest_r[i], rest_s[i] = _node_trs(g, i, node)
    trs = {
        "translation": np.broadcast_to(rest_t, (n, n_nodes, 3)).copy(),
        "rotation": np.broadcast_to(rest_r, (n, n_nodes, 4)).copy(),
        "scale": np.broadcast_to(rest_s, (n, n_nodes, 3)).copy(),
    }
    animated = np.zeros(n_nodes, dtype=bool)
    for node, path_name, t_in, values, interp in keyed:
        trs[path_name][:, node] = _sample_channel(t_in, values, interp, times, path_name)
        animated[node] = True
    local = np.zeros((n, n_nodes, 4, 4))
    rot = Rotation.from_quat(trs["rotation"].reshape(-1, 4)).as_matrix().reshape(n, n_nodes, 3, 3)
    local[..., :3, :3] = rot * trs["scale"][..., None, :]
    local[..., :3, 3] = trs["translation"]
    local[..., 3, 3] = 1.0
    for i, m in rest_matrix.items():
        if not animated[i]:  # a node with a 'matrix' may not be animated (glTF spec)
            local[:, i] = m
    world = np.empty_like(local)
    for i in order:  # parents first; each step is vectorised over frames
        world[:, i] = local[:, i] if parent[i] < 0 else world[:, parent[i]] @ local[:, i]
    name = anim.get("name")
    return GltfAnimation(times, float(rate), world, str(name) if name else f"animation{which}")


def _sample_channel(
    t_in: np.ndarray, values: np.ndarray, interp: str, times: np.ndarray, path_name: str
) -> np.ndarray:
    """(T, width) channel values at ``times`` (clamped to the key range)."""
    if interp == "CUBICSPLINE":
        in_tan, vals, out_tan = values[0::3], values[1::3], values[2::3]
    else:
        vals = values
    if t_in.size == 1:
        return np.broadcast_to(vals[0], (times.size, vals.shape[1])).copy()
    tc = np.clip(times, t_in[0], t_in[-1])
    k = np.clip(np.searchsorted(t_in, tc, side="right") - 1, 0, t_in.size - 2)
    dt = t_in[k + 1] - t_in[k]
    u = ((tc - t_in[k]) / dt)[:, None]
    if interp == "STEP":
        out = np.where(u >= 1.0, vals[k + 1], vals[k])
    elif interp == "CUBICSPLINE":
        u2, u3 = u * u, u * u * u
        out = (
            (2 * u3 - 3 * u2 + 1) * vals[k]
            + (u3 - 2 * u2 + u) * dt[:, None] * out_tan[k]
            + (-2 * u3 + 3 * u2) * vals[k + 1]
            + (u3 - u2) * dt[:, None] * in_tan[k + 1]
        )
    elif path_name == "rotation":
        out = _slerp(vals[k], vals[k + 1], u[:, 0])
    else:
        out = (1.0 - u) * vals[k] + u * vals[k + 1]
    if path_name == "rotation":
        norm = np.linalg.norm(out, axis=1, keepdims=True)
        out = out / np.where(norm > 0, norm, 1.0)
    return out


def _slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Shortest-path spherical interpolation of (T, 4) unit quaternions at (T,) u."""
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    dot = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-9
    safe = np.where(small, 1.0, sin_t)
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(small, u, np.sin(u * theta) / safe)
    return w0[:, None] * q0 + w1[:, None] * q1
