"""Session 20's hostile-input sweep: each problem it found, through the real CLI.

Every hostile file is made here from a valid fixture (or from nothing) and run in a
forked child with the harness's memory and time limits (:func:`cli_fuzz_harness.run_cli`);
the contract is the one of ``test_cli_fuzz.py``: exit 0 with a readable output, or exit
2 with one line naming the file and nothing written.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cli_fuzz_cases import c3d_records  # noqa: E402
from cli_fuzz_harness import judge, run_cli  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"


def _one_error_line(outcome, path: Path) -> str:
    verdict = judge(outcome, inputs=[path])
    assert verdict.violations == [] and verdict.outcome == "refused", (verdict, outcome.stderr)
    (line,) = outcome.stderr_lines
    assert line.startswith(f"skincap: error: {path}: ")
    return line


# ------------------------------------------------------------------ C3D labels with NUL
def _c3d_with_first_label(tmp_path: Path, label: bytes) -> Path:
    data = bytearray((DATA / "external" / "c3dorg_sample02_pc_int.c3d").read_bytes())
    (rec,) = [
        r for r in c3d_records(bytes(data)) if r["group"] == "POINT" and r["name"] == "LABELS"
    ]
    width = rec["dims"][0]
    at = rec["values_at"]
    assert len(label) <= width
    data[at : at + width] = label.ljust(width, b" ")
    p = tmp_path / "nul_label.c3d"
    p.write_bytes(bytes(data))
    return p


@pytest.mark.parametrize(
    "label, expected",
    [(b"\0\0\0" + b"1", "point_1"), (b"LA\0\xcd", "LA"), (b"A\0B", "A")],
)
def test_c3d_label_is_cut_at_its_first_nul(tmp_path, label, expected):
    """A NUL inside a C3D label reached the TRC writer; 'skincap info' then refused the
    TRC that 'skincap convert' had written as binary data (exit 0, unreadable output)."""
    from skincap.io.c3d import read_c3d

    p = _c3d_with_first_label(tmp_path, label)
    assert read_c3d(p).labels[0] == expected
    for suffix in (".trc", ".csv"):
        out = tmp_path / f"out{suffix}"
        outcome = run_cli(["convert", str(p), str(out)])
        verdict = judge(outcome, inputs=[p], output=out)  # reads the output back
        assert verdict.violations == [] and verdict.outcome == "ok", verdict
        assert "\0" not in out.read_text()


@pytest.mark.parametrize("fmt", ["trc", "csv"])
def test_text_writers_refuse_a_label_with_nul(tmp_path, fmt):
    from skincap import io as skio
    from skincap.errors import ValidationError
    from skincap.types import MarkerSet

    m = MarkerSet(positions=np.zeros((2, 2, 3)), labels=["A\0B", "C"], rate=100.0)
    out = tmp_path / f"m.{fmt}"
    with pytest.raises(ValidationError, match="NUL"):
        skio.write(m, out)
    assert not out.exists()


# ------------------------------------------------------------------ glTF amplification
def _glb(doc: dict, blob: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(blob), b"BIN\0")
    body += blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _instanced(n_vertices: int, nodes: int, primitives: int) -> bytes:
    """A GLB of one mesh of ``n_vertices`` (unindexed), its primitive repeated
    ``primitives`` times, the mesh on ``nodes`` nodes."""
    pos = np.random.default_rng(0).random((n_vertices, 3)).astype("<f4")
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": list(range(nodes))}],
        "nodes": [{"mesh": 0}] * nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}] * primitives}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": n_vertices,
                       "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes}],
        "buffers": [{"byteLength": pos.nbytes}],
    }  # fmt: skip
    return _glb(doc, pos.tobytes())


@pytest.mark.parametrize("nodes, primitives", [(3000, 1), (1, 3000)])
def test_gltf_instancing_one_mesh_is_refused_before_decoding(tmp_path, nodes, primitives):
    """A 1.8 MB GLB instancing a 9,999-vertex mesh 100,000 times (by nodes or by
    primitives) asked for 24 GB; here 3,000 instances of 9,999 vertices (30 M)."""
    p = tmp_path / "instanced.glb"
    p.write_bytes(_instanced(9999, nodes, primitives))
    line = _one_error_line(run_cli(["info", str(p)], memory_bytes=512 << 20, timeout_s=10), p)
    assert "add up to 29997000 vertices" in line and "at most 16777216" in line


def test_gltf_few_instances_still_read(tmp_path):
    p = tmp_path / "few.glb"
    p.write_bytes(_instanced(999, 3, 2))
    outcome = run_cli(["info", "--json", str(p)])
    assert judge(outcome, inputs=[p]).outcome == "ok", outcome.stderr
    assert json.loads(outcome.stdout)["vertices"] == 999 * 6


def test_gltf_accessor_of_zeros_with_a_huge_count_is_refused(tmp_path):
    """An accessor without a bufferView is zeros the file does not hold: 170 bytes
    declaring 6e7 VEC3 positions took 4.9 GB and 40 s (the scene's vertex count refuses
    that one now); texture coordinates and inverse binds are not in that count."""
    doc = {
        "asset": {"version": "2.0"},
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}]}],
        "accessors": [
            {"componentType": 5126, "count": 3, "type": "VEC3"},
            {"componentType": 5126, "count": 2**25, "type": "VEC2"},
        ],
    }
    p = tmp_path / "zeros.gltf"
    p.write_text(json.dumps(doc))
    line = _one_error_line(run_cli(["info", str(p)], memory_bytes=512 << 20, timeout_s=10), p)
    assert "accessors[1] (TEXCOORD_0): 33554432 VEC2 elements with no bufferView" in line
    # 2**22 MAT4 inverse binds of zeros would be 2 GB as float64
    from skincap.errors import FormatError
    from skincap.io.gltf.document import GltfDocument

    doc["accessors"].append({"componentType": 5126, "count": 2**22, "type": "MAT4"})
    with pytest.raises(FormatError, match="4194304 MAT4 elements with no bufferView"):
        GltfDocument(p, doc, None).accessor(2, what="inverseBindMatrices")
    doc["accessors"][0]["count"] = 60_000_000
    p.write_text(json.dumps(doc))
    line = _one_error_line(run_cli(["info", str(p)], memory_bytes=512 << 20, timeout_s=10), p)
    assert "add up to 60000000 vertices" in line


def test_gltf_many_nodes_read_in_one_batch(tmp_path):
    """Each node's rotation was one scipy call (0.1 ms): 100,000 nodes took 17 s before
    any check; 20,000 transformed nodes now take well under the 10 s limit."""
    import time

    from skincap.io.gltf.reader import read_gltf

    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4")
    n = 20_000
    nodes = [{"mesh": 0, "translation": [0, 0, 0], "rotation": [0, 0, 0.6, 0.8]}]
    nodes += [{"translation": [1, 2, 3], "rotation": [0, 0.6, 0, 0.8]}] * (n - 1)
    doc = {
        "asset": {"version": "2.0"},
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes}],
        "buffers": [{"byteLength": pos.nbytes}],
    }  # fmt: skip
    p = tmp_path / "nodes.glb"
    p.write_bytes(_glb(doc, pos.tobytes()))
    t0 = time.process_time()
    mesh = read_gltf(p)
    assert time.process_time() - t0 < 1.5
    # node 0 turned 73.74 degrees about z: (1, 0, 0) -> (0.28, 0.96, 0)
    np.testing.assert_allclose(mesh.vertices[1], [0.28, 0.96, 0.0], atol=1e-6)


# ------------------------------------------------------------------ BVH end sites
def _bvh_end_sites(n: int, joint: str = "") -> str:
    """A root with ``n`` End Sites (and optionally one channel-less joint ``joint``)."""
    body = "End Site\n{\nOFFSET 0 1 0\n}\n" * n
    if joint:
        body += f"JOINT {joint}\n{{\nOFFSET 0 1 0\nCHANNELS 0\nEnd Site\n{{\nOFFSET 0 1 0\n}}\n}}\n"
    return (
        "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Xposition Yposition Zposition\n"
        + body
        + "}\nMOTION\nFrames: 1\nFrame Time: 0.01\n0 0 0\n"
    )


def test_bvh_many_end_sites_of_one_joint_read_in_linear_time(tmp_path):
    """Naming n end sites of one joint searched the suffixes from 1 each time, O(n^2):
    'skincap convert' wrote the 200,000 channel-less joints of a 8 MB BVH as End Sites
    and 'skincap info' on its own output ran for over 10 minutes (8,000: 7 s)."""
    import time

    from skincap.io.bvh import read_bvh

    p = tmp_path / "ends.bvh"
    p.write_text(_bvh_end_sites(20_000))
    t0 = time.process_time()
    names = read_bvh(p, units="m").skeleton.names
    assert time.process_time() - t0 < 1.5
    assert names[:3] == ["r", "r_end", "r_end_2"] and names[-1] == "r_end_20000"


def test_bvh_end_site_names_stay_unique_beside_a_joint_of_that_name(tmp_path):
    from skincap.io.bvh import read_bvh

    p = tmp_path / "clash.bvh"
    p.write_text(_bvh_end_sites(3, joint="r_end_2"))
    names = read_bvh(p, units="m").skeleton.names
    assert len(set(names)) == len(names)
    assert names == ["r", "r_end", "r_end_3", "r_end_4", "r_end_2", "r_end_2_end"]


# ------------------------------------------------------------------ skin: many joints
def _grid_obj(n: int) -> str:
    """An n x n vertex sheet, 1.6 m tall, as OBJ text."""
    u, v = np.meshgrid(np.linspace(-0.3, 0.3, n), np.linspace(0.0, 1.6, n))
    verts = "".join(f"v {a:.4f} {b:.4f} 0\n" for a, b in zip(u.ravel(), v.ravel(), strict=True))
    k = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel() + 1
    quads = np.stack([k, k + 1, k + n + 1, k + n], axis=1)
    return verts + "".join("f {} {} {} {}\n".format(*q) for q in quads)


def test_skin_with_a_skeleton_too_wide_for_bone_heat_is_refused_before_allocating(tmp_path):
    """The 200,000 channel-less joints of an 8 MB BVH on a 600-vertex mesh asked bone
    heat for (600, 200000, 3) float64 (2.7 GB) and died of MemoryError; here 2,025
    vertices x 20,001 joints (4.1e7 dense entries) are refused in one line."""
    mesh = tmp_path / "sheet.obj"
    mesh.write_text(_grid_obj(45))
    bvh = tmp_path / "wide.bvh"
    bvh.write_text(_bvh_end_sites(20_000).replace("OFFSET 0 1 0", "OFFSET 0 1.6 0"))
    out = tmp_path / "out" / "wide.pc2"
    out.parent.mkdir()
    outcome = run_cli(
        ["skin", str(mesh), str(bvh), "-o", str(out), "--units", "m"],
        memory_bytes=1 << 30,
        timeout_s=30,
    )
    verdict = judge(outcome, inputs=[mesh, bvh], output=out, out_dir=out.parent, files_before=set())
    assert verdict.violations == [] and verdict.outcome == "refused", (verdict, outcome.stderr)
    assert "2025 vertices x 20001 joints" in outcome.stderr_lines[-1]


def test_point_segment_distances_blocks_do_not_change_the_result():
    """Many segments shrink the block of points (its (n, B, 3) temporaries); the
    distances are those of one point at a time."""
    from skincap.deform.skeletal.weights import point_segment_distances

    rng = np.random.default_rng(3)
    p, a, b = rng.normal(size=(700, 3)), rng.normal(size=(9000, 3)), rng.normal(size=(9000, 3))
    d, s = point_segment_distances(p, a, b)
    d1, s1 = point_segment_distances(p[::97], a, b, chunk=1)
    np.testing.assert_array_equal(d[::97], d1)
    np.testing.assert_array_equal(s[::97], s1)


# ------------------------------------------------------------------ far samples
def _trc_with_cell(tmp_path: Path, value: str) -> Path:
    """A 30-frame, 4-marker TRC (mm) with one coordinate replaced by ``value``."""
    from skincap import io as skio
    from skincap.types import MarkerSet

    t = np.arange(30) / 100.0
    pos = np.stack(
        [np.stack([0.1 * k + 0.01 * np.sin(t), 1.0 + 0.1 * k + 0 * t, 0.2 * np.cos(t)], axis=1)
         for k in range(4)], axis=1,
    )  # fmt: skip
    p = tmp_path / "far.trc"
    skio.write(MarkerSet(positions=pos, labels=["A", "B", "C", "D"], rate=100.0), p)
    lines = p.read_text().split("\n")
    row = next(i for i, ln in enumerate(lines) if ln.startswith("3\t"))
    cells = lines[row].split("\t")
    cells[3] = value
    lines[row] = "\t".join(cells)
    p.write_text("\n".join(lines))
    return p


@pytest.mark.parametrize("verb", ["info", "clean", "render"])
def test_a_marker_beyond_reach_is_refused_on_reading(tmp_path, verb):
    """One TRC cell of 1e300 mm: 'clean' died in an SVD that did not converge and
    'render' asked for a floor grid beyond NumPy's largest array (tracebacks)."""
    p = _trc_with_cell(tmp_path, "1e300")
    out = tmp_path / "out" / ("o.png" if verb == "render" else "o.c3d")
    out.parent.mkdir()
    argv = ["info", str(p)] if verb == "info" else [verb, str(p), "-o", str(out)]
    line = _one_error_line(run_cli(argv, timeout_s=20), p)
    assert "marker 'A' in frame 2 lies at" in line and "beyond the ±1e+09 m" in line
    assert not any(out.parent.iterdir())


def test_render_floor_grid_stays_small_for_a_far_outlier():
    """A sample 1e9 m out (within reach) made a 0.5 m floor grid of 6e9 points (44 GB)."""
    from skincap.viz.render import MAX_FLOOR_LINES, _floor_lines

    eye, rows = np.array([0.0, 1.0, -10.0]), np.eye(3)  # looking along +z
    far = _floor_lines(np.array([[-1.0, 0.0, -1.0], [9.9e8, 2.0, 1.0]]), eye, rows, 500.0)
    assert len(far) <= 2 * (MAX_FLOOR_LINES + 3)
    near = _floor_lines(np.array([[-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]]), eye, rows, 500.0)
    assert len(near) == 2 * 7  # 0.5 m lines from -1.5 to 1.5 on both axes, all in view
    assert len(_floor_lines(np.array([[0.0] * 3, [np.inf] * 3]), eye, rows, 500.0)) == 0


def test_render_refuses_a_mesh_beyond_float32(tmp_path):
    """An OBJ vertex at 1e308 m (finite, read) became inf in the float32 scene: exit 0
    with a stray 'RuntimeWarning: overflow encountered in cast' and a blank picture."""
    p = tmp_path / "far.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1e308 0\nf 1 2 3\n")
    out = tmp_path / "out" / "far.png"
    out.parent.mkdir()
    line = _one_error_line(run_cli(["render", str(p), "-o", str(out)], timeout_s=20), p)
    assert "1e+308 m is beyond float32" in line
    assert not out.exists()


# ------------------------------------------------------------------ BVH frame time
def test_solve_of_a_take_slower_than_a_bvh_holds_writes_nothing(tmp_path):
    """A C3D at 1e-4 Hz (its reader takes any rate up to 1e7 Hz): 'solve' wrote
    'Frame Time: 10000.0', a BVH its own reader refuses (outside 1e-7..3600 s)."""
    from skincap import io as skio
    from skincap.types import MarkerSet

    take = skio.read(DATA / "cmu_85_02.c3d")
    src = tmp_path / "slow.c3d"
    skio.write(MarkerSet(positions=take.positions[:60], labels=list(take.labels), rate=1e-4), src)
    out = tmp_path / "out" / "slow.bvh"
    out.parent.mkdir()
    outcome = run_cli(["solve", str(src), "-o", str(out)], timeout_s=60)
    verdict = judge(outcome, inputs=[src], output=out, out_dir=out.parent, files_before=set())
    assert verdict.violations == [] and verdict.outcome == "refused", (verdict, outcome.stderr)
    assert "Frame Time of 10000 s, outside the 1e-07..3600 s" in outcome.stderr_lines[-1]
