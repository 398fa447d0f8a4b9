"""Fixtures and mutations for the CLI fuzz test: every input format, byte and structured.

:func:`build_fixtures` writes one folder of small valid inputs, most cut from the real
captures in ``tests/data`` (a few hundred frames or vertices, so a case runs in tens
of milliseconds), plus hand-built glTF files. :func:`make_case` turns (format, index,
seed) into one deterministic case: a mutated input, the CLI commands to run on it and
a description that says how it was made. Half the cases flip, insert, delete or cut
bytes (weighted towards the headers, where the declared sizes live); the other half
are structured: a declared size, type, count or number replaced with an extreme value
(``1e308``, ``nan``, ``2**31``, ``-1``, ``0``…), deep nesting, duplicated or dropped
lines, hostile glTF buffer uris.
"""

from __future__ import annotations

import base64
import json
import random
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1] / "data"

#: Numbers a hostile file puts where a size, count, index or coordinate goes.
EXTREME_NUMBERS = [
    "0", "-1", "1", "-0", "2", "255", "256", "32767", "32768", "65535", "65536",
    "2147483647", "2147483648", "-2147483649", "4294967296", "9223372036854775808",
    "99999999999999999999999", "50000000", "1e308", "-1e308", "1e39", "-1e39", "1e-320",
    "nan", "NaN", "inf", "-inf", "1e300", "0.0", "3.4e38", "-4e307", "1.5", "-0.5",
]  # fmt: skip
#: Binary values for C3D fields: (struct format, value).
_C3D_WORDS = [0, 1, 2, 255, 0x7FFF, 0x8000, 0xFFFF, 0xFFFE]
_C3D_FLOATS = [0.0, -1.0, 1e9, -1e9, 1e38, float("nan"), float("inf"), -float("inf"), 1e-30, 1e6]
_C3D_BYTES = [0, 1, 2, 4, 7, 127, 128, 255, 0xFE, 0x7F]
_NUMBER_RE = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")

#: Formats and the commands run on them (IN: the mutated input, OUT: an output path).
FORMATS: dict[str, list[list[str]]] = {
    "c3d": [["info", "IN"], ["convert", "IN", "OUT.trc"]],
    "trc": [["info", "IN"], ["convert", "IN", "OUT.c3d"]],
    "csv": [["info", "IN"], ["convert", "IN", "OUT.c3d"]],
    "bvh": [["info", "IN"], ["convert", "IN", "OUT.bvh"]],
    "obj": [["info", "IN"], ["convert", "IN", "OUT.ply"]],
    "ply": [["info", "IN"], ["convert", "IN", "OUT.obj"]],
    "gltf": [["info", "IN"], ["convert", "IN", "OUT.obj"]],
    "glb": [["info", "IN"], ["convert", "IN", "OUT.ply"]],
    "mhskel": [["info", "IN"]],
    "mhw": [["info", "IN"]],
    # the heavier verbs, on small inputs
    "clean": [["clean", "IN", "-o", "OUT.c3d"]],
    "skin": [["skin", "MESH", "IN", "-o", "OUT.glb"]],
}
#: The input's file extension for each format group.
EXTENSION = {f: f for f in FORMATS} | {"clean": "c3d", "skin": "bvh"}


@dataclass
class Case:
    """One fuzz case: an input (and companions), the commands, and how it was made."""

    fmt: str
    index: int
    description: str
    data: bytes
    companions: dict[str, bytes] = field(default_factory=dict)  # other files beside it
    commands: list[list[str]] = field(default_factory=list)
    timeout_s: float | None = None  # None: the format's limit


# --------------------------------------------------------------------------- fixtures
def _cut_bvh(text: str, frames: int) -> str:
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    rows = [ln for ln in lines[2:] if ln.strip()][:frames]
    return f"{head}MOTION\nFrames: {len(rows)}\n{lines[1].strip()}\n" + "\n".join(rows) + "\n"


def _small_obj(text: str, n: int) -> str:
    """The first ``n`` vertices and texture vertices of an OBJ and the faces using only them."""
    out, nv, nt = [], 0, 0
    for ln in text.splitlines():
        if ln.startswith("v "):
            nv += 1
            if nv <= n:
                out.append(ln)
        elif ln.startswith("vt "):
            nt += 1
            if nt <= n:
                out.append(ln)
        elif ln.startswith("f "):
            refs = [int(x) for c in ln.split()[1:] for x in c.split("/") if x]
            if refs and max(refs) <= n and min(refs) > 0:
                out.append(ln)
        elif not ln.startswith(("vn ", "#")):
            out.append(ln)
    return "\n".join(out) + "\n"


def _gltf_parts() -> tuple[dict, bytes]:
    """A skinned quad (two triangles, two joints): glTF JSON without buffer uri, and its buffer."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype="<f4")
    idx = np.array([0, 1, 2, 0, 2, 3], dtype="<u2")
    joints = np.array([[0, 1, 0, 0]] * 4, dtype="<u2")
    weights = np.array([[0.7, 0.3, 0, 0], [0.5, 0.5, 0, 0], [0.2, 0.8, 0, 0], [1, 0, 0, 0]], "<f4")
    ibm = np.stack([np.eye(4), np.eye(4)]).astype("<f4")
    ibm[1, 3, 1] = -1.0  # column-major: translation of the second joint
    chunks = [
        pos.tobytes(),
        idx.tobytes() + b"\0\0",
        joints.tobytes(),
        weights.tobytes(),
        ibm.tobytes(),
    ]
    views, offset = [], 0
    for c in chunks:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(c)})
        offset += len(c)
    views[1]["byteLength"] = idx.nbytes
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
         "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
        {"bufferView": 2, "componentType": 5123, "count": 4, "type": "VEC4"},
        {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC4"},
        {"bufferView": 4, "componentType": 5126, "count": 2, "type": "MAT4"},
    ]  # fmt: skip
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "quad", "mesh": 0, "skin": 0},
            {"name": "hips", "children": [2]},
            {"name": "spine", "translation": [0, 1, 0]},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3},
                                    "indices": 1}]}],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": 4}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": offset}],
    }  # fmt: skip
    return doc, b"".join(chunks)


def _glb(doc: dict, blob: bytes) -> bytes:
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = (
        struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(blob), b"BIN\0") + blob
    )
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def build_fixtures(folder: Path) -> dict[str, list[Path]]:
    """Write the small valid inputs of every format into ``folder``; format -> files."""
    from skincap.io.c3d import read_c3d, write_c3d
    from skincap.io.mesh import read_obj, write_ply
    from skincap.io.trc import write_trc
    from skincap.types import MarkerSet, PointCloud

    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, list[Path]] = {f: [] for f in FORMATS}

    def put(fmt: str, name: str, data: bytes | str) -> Path:
        p = folder / name
        p.write_bytes(data.encode() if isinstance(data, str) else data)
        out[fmt].append(p)
        return p

    # C3D: the four real files under 600 kB as they are (headers and parameter sections
    # of four writers), the pyomeca file (analogs, events), and a 120-frame cut
    for name in ("c3dorg_sample01_Eb015pr.c3d", "kt_optitrack_walking.c3d", "cmu_85_02.c3d",
                 "pyomeca_markers_analogs.c3d"):  # fmt: skip
        put("c3d", name, (DATA / name).read_bytes())
    m = read_c3d(DATA / "kt_optitrack_walking.c3d")
    short = MarkerSet(
        positions=m.positions[:120], labels=list(m.labels), rate=m.rate,
        residuals=None if m.residuals is None else m.residuals[:120], meta=dict(m.meta),
    )  # fmt: skip
    short.meta["model_outputs"] = {}
    write_c3d(short, folder / "short.c3d", force=True)
    out["c3d"].append(folder / "short.c3d")
    out["clean"].append(folder / "short.c3d")
    write_trc(short, folder / "short.trc", force=True)
    out["trc"].append(folder / "short.trc")
    csv_lines = (DATA / "pyomeca_vicon_nexus_trajectories.csv").read_text().splitlines()
    put("csv", "vicon_short.csv", "\n".join(csv_lines[:105]) + "\n")
    from skincap.io.csv import write_points_csv

    write_points_csv(PointCloud.from_markerset(short), folder / "points_short.csv", force=True)
    out["csv"].append(folder / "points_short.csv")

    # BVH: the MakeHuman T-pose as it is; the two others cut to 40 frames
    put("bvh", "tpose.bvh", (DATA / "makehuman_tpose.bvh").read_bytes())
    for name in ("bvhtoolbox_test_mocapbank.bvh", "cmu_131_01_bvh11.bvh"):
        put("bvh", "short_" + name, _cut_bvh((DATA / name).read_text(), 40))
    out["skin"] = [out["bvh"][0]]

    # meshes: 600 vertices of the MakeHuman base mesh, as OBJ and PLY (binary, ASCII)
    obj = put("obj", "small.obj", _small_obj((DATA / "makehuman_base.obj").read_text(), 600))
    mesh = read_obj(obj)
    write_ply(mesh, folder / "small_bin.ply", force=True)
    write_ply(mesh, folder / "small_ascii.ply", force=True, binary=False)
    out["ply"] += [folder / "small_bin.ply", folder / "small_ascii.ply"]

    doc, blob = _gltf_parts()
    inline = json.loads(json.dumps(doc))
    inline["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    )
    put("gltf", "quad_inline.gltf", json.dumps(inline, indent=1))
    external = json.loads(json.dumps(doc))
    external["buffers"][0]["uri"] = "quad.bin"
    (folder / "quad.bin").write_bytes(blob)
    put("gltf", "quad_external.gltf", json.dumps(external, indent=1))
    put("glb", "quad.glb", _glb(doc, blob))

    put("mhskel", "default.mhskel", (DATA / "makehuman_default.mhskel").read_bytes())
    put("mhw", "default_weights.mhw", (DATA / "makehuman_default_weights.mhw").read_bytes())
    return out


# -------------------------------------------------------------------------- mutations
def byte_mutation(data: bytes, rng: random.Random, head: int) -> tuple[bytes, str]:
    """1-6 byte edits (flip, set, insert, delete) or a cut, most inside the first ``head`` bytes."""
    b = bytearray(data)
    what = []
    for _ in range(rng.randint(1, 6)):
        if not b:
            break
        span = min(len(b), head) if rng.random() < 0.7 else len(b)
        i = rng.randrange(span)
        kind = rng.choice(
            ["flip", "set", "insert", "delete", "cut"]
            if rng.random() < 0.1
            else ["flip", "set", "insert", "delete"]
        )
        if kind == "flip":
            bit = rng.randrange(8)
            b[i] ^= 1 << bit
            what.append(f"flip bit {bit} of byte {i}")
        elif kind == "set":
            v = rng.choice([0, 0xFF, 0x7F, 0x80, rng.randrange(256)])
            b[i] = v
            what.append(f"byte {i} = 0x{v:02x}")
        elif kind == "insert":
            v = rng.randrange(256)
            b.insert(i, v)
            what.append(f"insert 0x{v:02x} at {i}")
        elif kind == "delete":
            del b[i]
            what.append(f"delete byte {i}")
        else:
            del b[i:]
            what.append(f"cut at {i}")
    return bytes(b), "; ".join(what)


def c3d_records(data: bytes) -> list[dict]:
    """Parameter records of a valid Intel/DEC C3D: where each field of each record is."""
    start = (data[0] - 1) * 512
    pos, out, groups = start + 4, [], {}
    while pos + 2 < len(data):
        nchars = data[pos] - 256 if data[pos] > 127 else data[pos]
        if nchars == 0:
            break
        gid = data[pos + 1] - 256 if data[pos + 1] > 127 else data[pos + 1]
        name_end = pos + 2 + abs(nchars)
        name = data[pos + 2 : name_end].decode("latin-1")
        nxt = int.from_bytes(data[name_end : name_end + 2], "little")
        body = name_end + 2
        rec = {"name": name, "gid": gid, "at": pos, "next_at": name_end, "body": body}
        if gid < 0:
            groups[-gid] = name
            rec["desc_at"] = body
        else:
            kind = data[body] - 256 if data[body] > 127 else data[body]
            nd = data[body + 1]
            dims = list(data[body + 2 : body + 2 + nd])
            rec.update(
                kind=kind, ndims_at=body + 1, dims_at=body + 2, dims=dims, values_at=body + 2 + nd
            )
            count = int(np.prod(dims)) if nd else 1
            rec["desc_at"] = rec["values_at"] + count * abs(kind)
            rec["count"] = count
        out.append(rec)
        if nxt == 0:
            break
        pos = name_end + nxt
    for rec in out:
        rec["group"] = groups.get(abs(rec["gid"]), "?")
    return out


def c3d_structured(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Set one header word or one field of one parameter record to an extreme value."""
    b = bytearray(data)
    if rng.random() < 0.3:  # header: counts, frames, scale, data start, analog ratio, rate
        field_at, kind = rng.choice(
            [
                (2, "w"),
                (4, "w"),
                (6, "w"),
                (8, "w"),
                (12, "f"),
                (16, "w"),
                (18, "w"),
                (20, "f"),
                (0, "b"),
            ]
        )
        if kind == "w":
            v = rng.choice(_C3D_WORDS)
            b[field_at : field_at + 2] = struct.pack("<H", v)
        elif kind == "f":
            v = rng.choice(_C3D_FLOATS)
            b[field_at : field_at + 4] = struct.pack("<f", v)
        else:
            v = rng.choice(_C3D_BYTES)
            b[field_at] = v
        return bytes(b), f"header byte {field_at} = {v!r}"
    recs = [r for r in c3d_records(data) if r["gid"] > 0]
    # the parameters ezc3d and skincap read count double
    key = {
        "USED",
        "RATE",
        "SCALE",
        "FRAMES",
        "DATA_START",
        "OFFSET",
        "GEN_SCALE",
        "LABELS",
        "UNITS",
    }
    weighted = recs + [r for r in recs if r["name"] in key] * 3
    r = rng.choice(weighted)
    where = f"{r['group']}:{r['name']}"
    choice = rng.choice(["kind", "ndims", "dim", "value", "desc", "next", "gid"])
    if choice == "kind":
        v = rng.choice([-1, 1, 2, 4, 0, 3, -2])
        b[r["body"]] = v & 0xFF
    elif choice == "ndims":
        v = rng.choice([0, 1, 2, 3, 7, 8, 0x7F, 0x80, 0xFF])
        b[r["ndims_at"]] = v
    elif choice == "dim" and r["dims"]:
        k = rng.randrange(len(r["dims"]))
        v = rng.choice([0, 1, 255, r["dims"][k] + 1])
        b[r["dims_at"] + k] = v & 0xFF
        choice = f"dim {k}"
    elif choice == "value" and r["kind"] in (1, 2, 4) and r["count"] > 0:
        k = rng.randrange(r["count"])
        at = r["values_at"] + k * abs(r["kind"])
        if r["kind"] == 4:
            v = rng.choice(_C3D_FLOATS)
            b[at : at + 4] = struct.pack("<f", v)
        elif r["kind"] == 2:
            v = rng.choice(_C3D_WORDS)
            b[at : at + 2] = struct.pack("<H", v)
        else:
            v = rng.choice(_C3D_BYTES)
            b[at] = v
        choice = f"value {k}"
    elif choice == "desc":
        v = rng.choice([0, 0x7F, 0x80, 0xFF])
        b[r["desc_at"]] = v
    elif choice == "next":
        v = rng.choice([0, 1, 2, 0x7FFF, 0xFFFF])
        b[r["next_at"] : r["next_at"] + 2] = struct.pack("<H", v)
    else:
        v = rng.choice([0, 1, -1, 127, -128, 50])
        b[r["at"] + 1] = v & 0xFF
        choice = "group id"
    return bytes(b), f"{where} {choice} = {v!r}"


def text_structured(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Replace numbers with extreme ones, or duplicate, drop or cut lines."""
    r = rng.random()
    lines = data.split(b"\n")
    if r < 0.6:
        spans = [m.span() for m in _NUMBER_RE.finditer(data)]
        if not spans:
            return data, "unchanged"
        head = [s for s in spans if s[0] < 4096]  # headers declare the sizes
        what, b = [], bytearray(data)
        picks = sorted(
            {
                rng.choice(head if head and rng.random() < 0.6 else spans)
                for _ in range(rng.randint(1, 3))
            },
            reverse=True,
        )
        for s, e in picks:
            v = rng.choice(EXTREME_NUMBERS).encode()
            what.append(
                f"number at byte {s} {bytes(b[s:e]).decode(errors='replace')!r} -> {v.decode()!r}"
            )
            b[s:e] = v
        return bytes(b), "; ".join(what)
    i = rng.randrange(len(lines))
    if r < 0.75:
        k = rng.choice([1, 2, 1000])
        return b"\n".join(
            lines[:i] + [lines[i]] * (k + 1) + lines[i + 1 :]
        ), f"line {i + 1} repeated {k} times"
    if r < 0.9:
        return b"\n".join(lines[:i] + lines[i + 1 :]), f"line {i + 1} dropped"
    return b"\n".join(lines[:i]) + b"\n", f"cut after line {i}"


def bvh_deep_chain(depth: int) -> bytes:
    """A BVH whose skeleton is one chain ``depth`` joints deep, one frame."""
    parts = [
        "HIERARCHY\nROOT j0\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
    ]
    for k in range(1, depth):
        parts.append(f"JOINT j{k}\n{{\nOFFSET 0 0.01 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n")
    parts.append("End Site\n{\nOFFSET 0 0.01 0\n}\n" + "}\n" * depth)
    parts.append(
        "MOTION\nFrames: 1\nFrame Time: 0.0333333\n" + " ".join(["0"] * (3 + 3 * depth)) + "\n"
    )
    return "".join(parts).encode()


def _json_paths(node: object, path: tuple = ()) -> list[tuple]:
    out = [path]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _json_paths(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node[:50]):
            out += _json_paths(v, path + (i,))
    return out


_HOSTILE_URIS = [
    "/dev/zero", "/dev/urandom", "/etc/passwd", "../../../../../../etc/passwd", "file:///etc/passwd",
    "data:application/octet-stream;base64,!!!!", "data:,", "quad.bin/../quad.bin", "missing.bin",
    "http://127.0.0.1:9/x.bin", "%2e%2e/%2e%2e/etc/passwd", "", "quad.bin\0.png",
]  # fmt: skip
_JSON_VALUES = [
    0, -1, 1, 2**31, 2**53 + 1, 50_000_000, -(2**31), 1e308, -1e308, 0.5, "x", None, True, [], {},
    [[0, 1.0]] * 3, [2**31, 1.0], "NaN",
]  # fmt: skip


def json_structured(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Replace one value of a JSON document, nest it deeply, or point a glTF uri elsewhere."""
    is_glb = data[:4] == b"glTF"
    if is_glb:
        n = struct.unpack_from("<I", data, 12)[0]
        text = data[20 : 20 + n]
    else:
        text = data
    doc = json.loads(text)
    r = rng.random()
    if r < 0.1:
        depth = rng.choice([100, 5000, 200000])
        doc = {"nest": json.loads("[" * min(depth, 900) + "]" * min(depth, 900))} | doc
        raw = json.dumps(doc).encode()
        if depth > 900:  # deeper than json.dumps allows: splice the text in
            raw = raw.replace(b'"nest": ', b'"nest": ' + b"[" * depth + b"]" * depth, 1)
        what = f"nested {depth} deep"
    else:
        paths = [p for p in _json_paths(doc) if p]
        uris = [p for p in paths if p[-1] == "uri"]
        if uris and r < 0.35:
            p, v = rng.choice(uris), rng.choice(_HOSTILE_URIS)
        else:
            p, v = rng.choice(paths), rng.choice(_JSON_VALUES)
        node = doc
        for k in p[:-1]:
            node = node[k]
        node[p[-1]] = v
        raw = json.dumps(doc).encode()
        what = f"{'/'.join(map(str, p))} = {v!r}"[:200]
    if is_glb:
        raw += b" " * (-len(raw) % 4)
        body = struct.pack("<I4s", len(raw), b"JSON") + raw + data[20 + len(text) :]
        return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body, what
    return raw, what


def ply_structured(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Change the PLY header's counts, types or format line."""
    end = data.find(b"end_header")
    head, body = data[:end], data[end:]
    lines = head.split(b"\n")
    i = rng.randrange(len(lines))
    choices = [
        b"element vertex " + rng.choice(EXTREME_NUMBERS).encode(),
        b"element face " + rng.choice(EXTREME_NUMBERS).encode(),
        b"property list uint int vertex_indices",
        b"property list uchar uint vertex_indices",
        b"property list int int vertex_indices",
        b"property float x",
        b"property double nan",
        b"format binary_big_endian 1.0",
        b"format ascii 1.0",
        b"format binary_little_endian 1.0",
    ]
    v = rng.choice(choices)
    lines[i] = v
    return b"\n".join(lines) + body, f"header line {i + 1} = {v.decode()!r}"


def make_case(fmt: str, index: int, seed: int, fixtures: dict[str, list[Path]]) -> Case:
    """The ``index``-th case of ``fmt`` for ``seed``: the same arguments give the same bytes."""
    rng = random.Random(f"{seed}:{fmt}:{index}")
    source = rng.choice(fixtures[fmt])
    data = source.read_bytes()
    companions = {}
    if source.name == "quad_external.gltf":
        companions["quad.bin"] = (source.parent / "quad.bin").read_bytes()
    ext = EXTENSION[fmt]
    structured = index % 2 == 1
    if fmt == "bvh" and structured and index % 50 == 25:
        frames = rng.choice(["100000000000", "4294967296", "-1", "1e9", "3"])
        text = "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 0\nEnd Site\n{\nOFFSET 0 1 0\n}\n}\n"
        text += f"MOTION\nFrames: {frames}\nFrame Time: 0.01\n\n\n\n"
        return Case(fmt, index, f"no channels, Frames: {frames}", text.encode(), {}, FORMATS[fmt])
    if fmt == "bvh" and structured and index % 50 == 1:
        # a deep chain is legal, only slow: the limit grows with the depth
        depth = [1000, 5000, 20000, 100000][(index // 50) % 4]
        return Case(
            fmt,
            index,
            f"deep chain of {depth} joints",
            bvh_deep_chain(depth),
            {},
            FORMATS[fmt],
            timeout_s=20 + depth / 200,
        )
    if not structured:
        head = {"c3d": 512 * 12, "clean": 512 * 12, "glb": 2048, "ply": 1024}.get(fmt, 4096)
        mutated, what = byte_mutation(data, rng, head)
    elif ext == "c3d":
        mutated, what = c3d_structured(data, rng)
    elif ext in ("gltf", "glb", "mhskel", "mhw"):
        mutated, what = json_structured(data, rng)
    elif ext == "ply":
        mutated, what = ply_structured(data, rng)
    else:
        mutated, what = text_structured(data, rng)
    desc = f"{source.name}: {'structured' if structured else 'bytes'}: {what}"
    if fmt == "skin":
        companions["small.obj"] = (source.parent / "small.obj").read_bytes()
    return Case(fmt, index, desc, mutated, companions, FORMATS[fmt])


def warm_up_commands(fixtures: dict[str, list[Path]], out: Path) -> list[list[str]]:
    """Each format's commands on its first valid fixture (outputs under ``out``)."""
    out.mkdir(parents=True, exist_ok=True)
    cmds = []
    for fmt, templates in FORMATS.items():
        src = fixtures[fmt][0]
        for k, template in enumerate(templates):
            argv = []
            for a in template:
                if a == "IN":
                    argv.append(str(src))
                elif a == "MESH":
                    argv.append(str(src.parent / "small.obj"))
                elif a.startswith("OUT."):
                    argv.append(str(out / f"{fmt}{k}{a[3:]}"))
                else:
                    argv.append(a)
            cmds.append(argv + (["--force"] if any(a.startswith("OUT.") for a in template) else []))
    return cmds
