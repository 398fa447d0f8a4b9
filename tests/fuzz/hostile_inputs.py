"""Hostile variants of every input the newer verbs take, made from small valid fixtures.

:func:`build_fixtures` writes the valid inputs: a dense analytic "arm" take (60 labelled
markers, 24 frames) with its mesh as OBJ, PLY and GLB, its marker surface, a subject rig
(``rig.npz`` + ``rig.json``, saved by ``skincap animate``) and a landmarks JSON; an
un-indexed point cloud with a hanging rope for ``track``; a 60-frame cut of the CMU walk
(41 labelled markers) for ``solve`` and ``synth --real-markers``; a small BVH.

Each ``*_variants`` function returns ``(name, bytes)`` pairs for one input kind, all
derived deterministically from a fixture: truncations at several offsets, an empty file,
header counts that lie, NaN and inf, all-NaN markers, one frame, duplicated and
non-UTF-8 labels, meshes with no, degenerate or out-of-range faces, rig arrays of the
wrong shape or dtype, landmarks out of range. :data:`DIRECTORY` in place of bytes asks
for a folder where a file is expected.
"""

from __future__ import annotations

import io
import json
import re
import struct
import sys
import zipfile
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1] / "data"
#: Stands for "a directory where the file should be" in a variant list.
DIRECTORY = b"<directory>"


def truncations(name: str, data: bytes, fractions=(0.0, 0.02, 0.3, 0.7, 0.999)) -> list:
    """``data`` cut at each fraction of its length (0.0: the empty file)."""
    out = []
    for f in fractions:
        n = int(len(data) * f)
        if f > 0 and n == 0:
            n = 1
        out.append((f"{name}_cut{n}", data[:n]))
    return out


# ------------------------------------------------------------------ valid fixtures
def _rope_cloud(n_frames: int = 90, n_rope: int = 12, n_body: int = 40):
    """A rope hanging still from (0, 2, 0) for 0.5 s then swinging, beside a blob of
    body points, shuffled in every frame: a small un-indexed take for ``track``."""
    from skincap.types import PointCloud

    rate = 120.0
    t = np.arange(n_frames)
    swing = 0.4 * np.clip((t - 60) / 30.0, 0, 1) * np.sin(2 * np.pi * (t - 60) / rate)
    s = 0.12 * np.arange(n_rope)
    rope = np.stack(
        [s[None] * np.sin(swing)[:, None], 2.0 - s[None] * np.cos(swing)[:, None],
         np.zeros((n_frames, n_rope))], axis=2,
    )  # fmt: skip
    rng = np.random.default_rng(5)
    d = rng.normal(size=(n_body, 3))
    body = np.array([1.2, 1.0, 0.0]) + 0.3 * d / np.linalg.norm(d, axis=1, keepdims=True)
    pos = np.concatenate([rope, np.broadcast_to(body, (n_frames, n_body, 3))], axis=1)
    pos = pos + rng.normal(scale=5e-4, size=pos.shape)
    order = np.argsort(rng.random(pos.shape[:2]), axis=1)
    pos = np.take_along_axis(pos, order[..., None], axis=1)
    m = pos.shape[1]
    return PointCloud(pos.reshape(-1, 3), np.arange(n_frames + 1) * m, rate)


def build_fixtures(folder: Path) -> dict[str, Path]:
    """Write the valid inputs into ``folder``; kind -> path."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflows"))
    from dense_arm import arm_take

    from skincap import io as skio
    from skincap.io.c3d import read_c3d
    from skincap.io.csv import write_points_csv
    from skincap.io.mesh import read_obj, write_ply
    from skincap.types import MarkerSet

    folder.mkdir(parents=True, exist_ok=True)
    mesh, take, _, _ = arm_take(folder, n_frames=24)
    arm = skio.read(take)
    skio.write(arm, folder / "arm.trc")
    write_ply(read_obj(mesh), folder / "arm.ply")
    (folder / "landmarks.json").write_text(json.dumps({"M00": 0, "M10": 100, "M30": 300}))
    cloud = _rope_cloud()
    write_points_csv(cloud, folder / "points.csv")
    walk = read_c3d(DATA / "cmu_85_02.c3d")
    cut = MarkerSet(positions=walk.positions[:60], labels=list(walk.labels), rate=walk.rate)
    skio.write(cut, folder / "walk.c3d")
    skio.write(cut, folder / "walk.trc")
    text = (DATA / "cmu_131_01_bvh11.bvh").read_text()
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    rows = [ln for ln in lines[2:] if ln.strip()][:10]
    (folder / "walk.bvh").write_text(
        f"{head}MOTION\nFrames: {len(rows)}\n{lines[1].strip()}\n" + "\n".join(rows) + "\n"
    )
    return {
        "mesh": mesh,
        "mesh_ply": folder / "arm.ply",
        "take": take,
        "take_trc": folder / "arm.trc",
        "surface": folder / "arm_surface.ply",
        "landmarks": folder / "landmarks.json",
        "rig": folder / "rig.npz",  # written by the test's warm-up (skincap animate --save-rig)
        "points": folder / "points.csv",
        "walk": folder / "walk.c3d",
        "walk_trc": folder / "walk.trc",
        "bvh": folder / "walk.bvh",
    }


# ------------------------------------------------------------------ marker files
def _c3d_bytes(positions: np.ndarray, labels: list[str], rate: float = 100.0) -> bytes:
    import tempfile

    from skincap import io as skio
    from skincap.types import MarkerSet

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.c3d"
        skio.write(MarkerSet(positions=positions, labels=labels, rate=rate), p)
        return p.read_bytes()


def _patch_floats(data: bytes, sentinels: list[float], values: list[float]) -> bytes:
    """``data`` with each float32 sentinel (stored in metres or millimetres) replaced."""
    b = bytes(data)
    for s, v in zip(sentinels, values, strict=True):
        for scale in (1000.0, 1.0, -1000.0, -1.0):  # the writer may flip an axis
            key = struct.pack("<f", s * scale)
            if key in b:
                b = b.replace(key, struct.pack("<f", v), 1)
                break
        else:
            raise ValueError(f"sentinel {s} not found in the C3D data")
    return b


def _replace_label(data: bytes, old: str, new: bytes) -> bytes:
    """Swap one label's bytes for ``new`` (same length) wherever the file stores it."""
    assert len(new) == len(old)
    return data.replace(old.encode(), new)


def c3d_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile C3D files made from the labelled take at ``path``."""
    from skincap.io.c3d import read_c3d

    m = read_c3d(path)
    data = path.read_bytes()
    pos, labels = m.positions, list(m.labels)
    out = truncations("c3d", data, (0.0, 0.01, 0.3, 0.5, 0.999))
    nan_all = np.full_like(pos, np.nan)
    one_dead = pos.copy()
    one_dead[:, 0] = np.nan
    # the writer refuses inf (a MarkerSet holds NaN for missing): write sentinels and
    # put inf, -inf and float32's largest values in their place in the file
    marked = pos.copy()
    marked[3, 2] = [7.125, 7.25, 7.375]
    raw = _c3d_bytes(marked, labels, m.rate)
    inf = _patch_floats(raw, [7.125, 7.25, 7.375], [np.inf, 0.0, -np.inf])
    huge = _patch_floats(raw, [7.125, 7.25, 7.375], [3e38, -3e38, 1e-45])
    out += [("c3d_inf", inf), ("c3d_huge", huge)]
    out += [
        ("c3d_all_nan", _c3d_bytes(nan_all, labels, m.rate)),
        ("c3d_all_nan_marker", _c3d_bytes(one_dead, labels, m.rate)),
        ("c3d_one_frame", _c3d_bytes(pos[:1], labels, m.rate)),
        ("c3d_dup_label", _replace_label(data, labels[1], labels[0].encode())),
        ("c3d_non_utf8_label", _replace_label(data, labels[2], b"\xff\xfe" + b"\x80" * (len(labels[2]) - 2))),
    ]  # fmt: skip
    # header words that lie: points, last frame, data start (they are checked against
    # the parameter section), and the parameters' own POINT:USED / POINT:FRAMES
    for at, value, what in [(2, 0xFFFF, "points"), (2, 0, "points0"), (8, 0xFFFF, "last")]:
        b = bytearray(data)
        b[at : at + 2] = struct.pack("<H", value)
        out.append((f"c3d_header_{what}", bytes(b)))
    for name, value in [("USED", 0x7FFF), ("USED", 0), ("FRAMES", 0xFFFF), ("FRAMES", 0)]:
        b = _set_point_param(data, name, value)
        if b is not None:
            out.append((f"c3d_point_{name.lower()}_{value}", b))
    return out


def _set_point_param(data: bytes, name: str, value: int) -> bytes | None:
    """``data`` with the first int16 parameter ``name`` of the POINT group set to ``value``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from cli_fuzz_cases import c3d_records

    for r in c3d_records(data):
        if r["group"] == "POINT" and r["name"] == name and r.get("kind") == 2:
            b = bytearray(data)
            b[r["values_at"] : r["values_at"] + 2] = struct.pack("<H", value)
            return bytes(b)
    return None


def trc_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile TRC files: truncations, header counts that lie, NaN/inf, bad labels."""
    data = path.read_bytes()
    text = data.decode()
    lines = text.split("\n")
    out = truncations("trc", data, (0.0, 0.05, 0.5, 0.999))
    # line 3 holds the values of DataRate CameraRate NumFrames NumMarkers Units ...
    vals = lines[2].split("\t")
    for k, v, tag in [(2, "999999999999", "frames_huge"), (2, "-1", "frames_neg"),
                      (2, "0", "frames0"), (3, "100000000", "markers_huge"), (3, "-5", "markers_neg"),
                      (0, "0", "rate0"), (0, "nan", "rate_nan"), (0, "1e308", "rate_huge")]:  # fmt: skip
        w = list(vals)
        w[k] = v
        out.append((f"trc_{tag}", "\n".join(lines[:2] + ["\t".join(w)] + lines[3:]).encode()))
    body = lines[5:]
    nan_body = [re.sub(r"-?\d+\.\d+(e-?\d+)?", "nan", ln) if ln.strip() else ln for ln in body]
    out.append(("trc_all_nan", "\n".join(lines[:5] + _keep_time(body, nan_body)).encode()))
    inf_body = list(body)
    cells = inf_body[1].split("\t")
    cells[2:5] = ["inf", "-inf", "1e400"]
    inf_body[1] = "\t".join(cells)
    out.append(("trc_inf", "\n".join(lines[:5] + inf_body).encode()))
    names = lines[3].split("\t")
    dup = list(names)
    dup[5] = dup[2]
    out.append(("trc_dup_label", "\n".join(lines[:3] + ["\t".join(dup)] + lines[4:]).encode()))
    raw = bytearray(data)
    at = data.index(names[2].encode(), len("\n".join(lines[:3])))
    raw[at : at + 2] = b"\xff\xfe"
    out.append(("trc_non_utf8_label", bytes(raw)))
    out.append(("trc_one_frame", "\n".join(lines[:6]).encode() + b"\n"))
    return out


def _keep_time(body: list[str], nan_body: list[str]) -> list[str]:
    """Rows of ``nan_body`` with frame number and time put back from ``body``."""
    rows = []
    for ln, nl in zip(body, nan_body, strict=True):
        if not ln.strip():
            rows.append(ln)
            continue
        a, b = ln.split("\t"), nl.split("\t")
        rows.append("\t".join(a[:2] + b[2:]))
    return rows


# ------------------------------------------------------------------ point clouds
def points_csv_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile long points CSVs (``# rate=``/``# frames=`` comments, then frame,time,x,y,z)."""
    data = path.read_bytes()
    lines = data.decode().split("\n")
    out = truncations("points", data, (0.0, 0.01, 0.4, 0.999))
    n_head = next(i for i, ln in enumerate(lines) if not ln.startswith("#")) + 1
    head, rows = lines[:n_head], [ln for ln in lines[n_head:] if ln.strip()]
    cols = head[-1].split(",")
    xcol = cols.index("x")

    def rebuild(new_rows: list[str], new_head: list[str] | None = None) -> bytes:
        return ("\n".join([*(new_head or head), *new_rows]) + "\n").encode()

    def edit(col: int, value: str) -> list[str]:
        res = []
        for ln in rows:
            c = ln.split(",")
            c[col] = value
            res.append(",".join(c))
        return res

    def comment(key: str, value: str) -> list[str]:
        return [f"# {key}={value}" if ln.startswith(f"# {key}=") else ln for ln in head]

    first = rows[0].split(",")[0]
    out += [
        ("points_all_nan", rebuild(edit(xcol, "nan"))),
        ("points_inf", rebuild(edit(xcol + 1, "inf"))),
        ("points_huge", rebuild(edit(xcol, "1e308"))),
        ("points_frame_huge", rebuild(rows[:-1] + [",".join(["99999999999"] + rows[-1].split(",")[1:])])),
        ("points_frame_neg", rebuild([",".join(["-3"] + rows[0].split(",")[1:])] + rows[1:])),
        ("points_header_frames_huge", rebuild(rows, comment("frames", "99999999999"))),
        ("points_header_frames_neg", rebuild(rows, comment("frames", "-1"))),
        ("points_header_frames_0", rebuild(rows, comment("frames", "0"))),
        ("points_header_rate_0", rebuild(rows, comment("rate", "0"))),
        ("points_header_rate_nan", rebuild(rows, comment("rate", "nan"))),
        ("points_one_frame", rebuild([r for r in rows if r.split(",")[0] == first])),
        ("points_one_point", rebuild(rows[:1])),
        ("points_header_only", rebuild([])),
        ("points_non_utf8", data.replace(b",", b"\xff", 1)),
    ]  # fmt: skip
    return out


# ------------------------------------------------------------------ meshes
def obj_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile OBJ meshes: no faces, degenerate faces, faces past the vertices, NaN."""
    data = path.read_bytes()
    lines = data.decode().split("\n")
    verts = [ln for ln in lines if ln.startswith("v ")]
    faces = [ln for ln in lines if ln.startswith("f ")]
    others = [ln for ln in lines if not ln.startswith(("v ", "f "))]
    nv = len(verts)

    def mk(v: list[str], f: list[str]) -> bytes:
        return ("\n".join(others + v + f) + "\n").encode()

    nan_v = list(verts)
    nan_v[3] = "v nan 0 inf"
    return truncations("obj", data, (0.0, 0.02, 0.5, 0.999)) + [
        ("obj_no_faces", mk(verts, [])),
        ("obj_degenerate", mk(verts, ["f 1 1 1"] * len(faces))),
        ("obj_face_past", mk(verts, faces + [f"f 1 2 {nv + 1}"])),
        ("obj_face_far", mk(verts, faces + ["f 1 2 2147483648"])),
        ("obj_face_neg", mk(verts, faces + [f"f -1 -2 -{nv + 5}"])),
        ("obj_face_zero", mk(verts, faces + ["f 0 1 2"])),
        ("obj_nan_vertex", mk(nan_v, faces)),
        ("obj_one_vertex", mk(verts[:1], ["f 1 1 1"])),
    ]


def ply_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile PLY meshes: counts that lie, no faces, faces past the vertices."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode()
    nv = int(re.search(r"element vertex (\d+)", head).group(1))
    nf = int(re.search(r"element face (\d+)", head).group(1))
    out = truncations("ply", data, (0.0, 0.05, 0.5, 0.999))
    for tag, a, b in [
        ("vertex_huge", f"element vertex {nv}", "element vertex 99999999999"),
        ("vertex_neg", f"element vertex {nv}", "element vertex -1"),
        ("vertex0", f"element vertex {nv}", "element vertex 0"),
        ("face_huge", f"element face {nf}", "element face 4000000000"),
        ("face0", f"element face {nf}", "element face 0"),
    ]:
        out.append((f"ply_{tag}", head.replace(a, b).encode() + data[end:]))
    out.append(("ply_dir", DIRECTORY))
    # binary little-endian body: vertices as 3 float32 (maybe more), then faces as
    # uchar count + 3 int32: point the first face past the vertices
    vprops = head.split("element vertex")[1].split("element face")[0].count("property")
    face_at = end + nv * 4 * vprops
    if b"binary_little_endian" in data[:end] and len(data) > face_at + 13:
        b = bytearray(data)
        b[face_at + 1 : face_at + 13] = struct.pack("<3i", 0, 1, nv + 7)
        out.append(("ply_face_past", bytes(b)))
        b = bytearray(data)
        b[face_at + 1 : face_at + 13] = struct.pack("<3i", 0, -2, 5)
        out.append(("ply_face_neg", bytes(b)))
        b = bytearray(data)
        b[end : end + 12] = struct.pack("<3f", np.nan, np.inf, 0.0)
        out.append(("ply_nan_vertex", bytes(b)))
    return out


def glb_from_obj(path: Path) -> bytes:
    """The OBJ at ``path`` as a minimal GLB (one primitive, uint32 indices)."""
    from skincap.io.mesh import read_obj

    mesh = read_obj(path)
    return _glb(mesh.vertices.astype("<f4"), mesh.faces.astype("<u4"))


def _glb(
    v: np.ndarray, f: np.ndarray, count_v: int | None = None, count_f: int | None = None
) -> bytes:
    blob = v.tobytes() + f.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": count_v or len(v), "type": "VEC3",
             "min": np.nan_to_num(v.min(0)).tolist(), "max": np.nan_to_num(v.max(0)).tolist()},
            {"bufferView": 1, "componentType": 5125, "count": count_f or f.size, "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": v.nbytes},
            {"buffer": 0, "byteOffset": v.nbytes, "byteLength": f.nbytes},
        ],
        "buffers": [{"byteLength": len(blob)}],
    }  # fmt: skip
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = (
        struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(blob), b"BIN\0") + blob
    )
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def glb_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile GLB meshes made from the OBJ at ``path``."""
    from skincap.io.mesh import read_obj

    mesh = read_obj(path)
    v, f = mesh.vertices.astype("<f4"), mesh.faces.astype("<u4")
    good = _glb(v, f)
    past = f.copy()
    past[0, 2] = len(v) + 3
    degenerate = np.zeros_like(f)
    return truncations("glb", good, (0.01, 0.5, 0.999)) + [
        ("glb_face_past", _glb(v, past)),
        ("glb_degenerate", _glb(v, degenerate)),
        ("glb_count_lies", _glb(v, f, count_v=2**31 - 1)),
        ("glb_index_count_lies", _glb(v, f, count_f=3 * 10**9)),
        ("glb_nan_vertex", _glb(np.where(np.arange(len(v))[:, None] == 4, np.nan, v).astype("<f4"), f)),
    ]  # fmt: skip


# ------------------------------------------------------------------ rig, landmarks
def _npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def rig_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile subject rigs (``.npz``; the ``.json`` beside it is kept as it was)."""
    data = path.read_bytes()
    good = dict(np.load(path, allow_pickle=False))
    out = truncations("rig", data, (0.0, 0.01, 0.5, 0.999))
    keys = sorted(good)
    big = max(keys, key=lambda k: good[k].size)
    for k in keys:
        a = good[k]
        if a.ndim >= 1 and a.shape[0] > 1:
            out.append((f"rig_{k}_short", _npz({**good, k: a[:-1]})))
        if a.ndim >= 1:
            out.append((f"rig_{k}_flat", _npz({**good, k: a.reshape(-1)[:1]})))
    out += [
        ("rig_missing_array", _npz({k: v for k, v in good.items() if k != big})),
        ("rig_strings", _npz({**good, big: np.array(["x"] * good[big].size).reshape(good[big].shape)})),
        ("rig_objects", _npz_pickled({**good, big: np.array([None, 1], dtype=object)})),
        ("rig_complex", _npz({**good, big: good[big].astype(np.complex128)})),
        ("rig_nan", _npz({**good, big: np.full(good[big].shape, np.nan)})),
        ("rig_scalar", _npz({**good, big: np.float64(1.0)})),
        ("rig_not_zip", b"PK\x03\x04" + b"\0" * 100),
        ("rig_zip_bomb_header", _zip_lying_size(data)),
    ]  # fmt: skip
    return out


def _npz_pickled(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # object arrays are pickled: the reader must refuse to load them
    return buf.getvalue()


def _zip_lying_size(data: bytes) -> bytes:
    """The npz with every .npy's header claiming a shape of 2**40 elements."""
    src = zipfile.ZipFile(io.BytesIO(data))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as dst:
        for info in src.infolist():
            raw = src.read(info)
            raw = re.sub(rb"'shape': \([^)]*\)", b"'shape': (1099511627776, 3)", raw, count=1)
            dst.writestr(info.filename, raw)
    return buf.getvalue()


def landmarks_variants(path: Path, n_vertices: int) -> list[tuple[str, bytes]]:
    """Hostile landmark JSONs {marker label: vertex index}."""
    good = json.loads(path.read_text())
    label = next(iter(good))
    out = truncations("landmarks", path.read_bytes(), (0.0, 0.5))
    for tag, value in [("past", n_vertices), ("far", 2**63), ("neg", -1), ("negfar", -n_vertices - 1),
                       ("float", 1.5), ("nan", float("nan")), ("str", "12"), ("null", None),
                       ("list", [1, 2]), ("bool", True)]:  # fmt: skip
        out.append((f"landmarks_{tag}", json.dumps({**good, label: value}).encode()))
    out += [
        ("landmarks_unknown_label", json.dumps({**good, "NOT_A_MARKER": 3}).encode()),
        ("landmarks_list", b"[1, 2, 3]"),
        ("landmarks_empty", b"{}"),
        ("landmarks_non_utf8", b'{"\xff\xfe": 3}'),
        ("landmarks_deep", b"[" * 100000 + b"]" * 100000),
        ("landmarks_dup_vertex", json.dumps(dict.fromkeys(good, 0)).encode()),
        ("landmarks_dir", DIRECTORY),
    ]
    return out


# ------------------------------------------------------------------ BVH
def bvh_variants(path: Path) -> list[tuple[str, bytes]]:
    """Hostile BVH motions: truncations, frame counts that lie, NaN, an absurd hierarchy."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from cli_fuzz_cases import bvh_deep_chain

    data = path.read_bytes()
    text = data.decode()
    out = truncations("bvh", data, (0.0, 0.05, 0.5, 0.999))
    frames = re.search(r"Frames:\s*(\d+)", text).group(0)
    for tag, v in [("huge", "99999999999"), ("neg", "-1"), ("zero", "0"), ("nan", "nan")]:
        out.append((f"bvh_frames_{tag}", text.replace(frames, f"Frames: {v}").encode()))
    ftime = re.search(r"Frame Time:\s*\S+", text).group(0)
    for tag, v in [("0", "0"), ("neg", "-0.01"), ("nan", "nan"), ("inf", "inf")]:
        out.append((f"bvh_frametime_{tag}", text.replace(ftime, f"Frame Time: {v}").encode()))
    head, motion = text.split("MOTION", 1)
    mlines = motion.strip().split("\n")
    rows = [re.sub(r"-?\d+\.\d+", "nan", r) for r in mlines[2:]]
    out.append(("bvh_all_nan", (head + "MOTION\n" + "\n".join(mlines[:2] + rows) + "\n").encode()))
    out.append(("bvh_deep_1000", bvh_deep_chain(1000)))
    return out
