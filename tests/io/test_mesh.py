"""OBJ and PLY readers and writers: real MakeHuman mesh, round trips, trimesh, bad input."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from byte_mutations import mutate as _mutate
from byte_mutations import mutation_ops
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import FormatError, OutputExistsError, SkincapError
from skincap.io.mesh import read_obj, read_ply, triangulate_polygons, write_obj, write_ply
from skincap.types import Mesh

MUTATIONS = mutation_ops(max_size=6)

DATA = Path(__file__).resolve().parents[1] / "data"
BASE_OBJ = DATA / "makehuman_base.obj"

SMALL_OBJ = """\
# a small mixed file
mtllib scene.mtl
o thing
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 2 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 0.5 0.5
vn 0 0 1
g left both
usemtl red
f 1/1/1 2/2/1 3/3/1 4/4/1
g right both
f -4//-1 5//1 -3//1
usemtl blue
f 2/2 5/5 3/3
g
f 1 2 3 4 5
"""


def _write(tmp_path: Path, name: str, text: str | bytes) -> Path:
    p = tmp_path / name
    if isinstance(text, str):
        p.write_text(text)
    else:
        p.write_bytes(text)
    return p


@pytest.fixture(scope="module")
def base_mesh() -> Mesh:
    return read_obj(BASE_OBJ, units="dm")


# ---------------------------------------------------------------------------- OBJ real
def test_makehuman_base_obj_counts(base_mesh: Mesh) -> None:
    m = base_mesh
    assert m.n_vertices == 19158
    assert m.n_polygons == 18486
    assert np.all(np.diff(m.polygon_offsets) == 4)  # all quads, kept as quads
    assert m.n_faces == 2 * 18486
    assert m.face_polygon is not None and np.array_equal(
        m.face_polygon, np.repeat(np.arange(18486), 2)
    )
    assert len(m.groups) == 139 and "body" in m.groups
    assert sum(g.size for g in m.groups.values()) == 18486  # each polygon in exactly one group
    # MakeHuman's UV layout has seams: 21,334 vt for 19,158 vertices -> per-corner UVs
    assert m.uv is None
    assert m.meta["uv_table"].shape == (21334, 2)
    assert m.meta["corner_uv"].shape == (4 * 18486,)
    assert m.meta["source_units"] == "dm" and m.meta["up"] == "y"
    # decimetres -> metres: the whole mesh (with helpers) is 1.69 m tall
    height = m.bounds[1, 1] - m.bounds[0, 1]
    assert height == pytest.approx(0.84967 + 0.84488, abs=1e-9)
    assert m.vertices[0] == pytest.approx([-0.03492, 0.73299, 0.14076])


def test_obj_read_speed_is_a_bench_io_row_not_a_timed_assertion() -> None:
    # the speed is measured as a ratio in `skincap bench io` (house rule: no timed tests)
    from skincap.evaluate.bench.common import _obj_read_row

    results: dict = {}
    lines: list[str] = []
    _obj_read_row(results, lines, repeat=1)
    row = results["obj_read"]
    assert row["file"] == BASE_OBJ.name and row["skincap_s"] > 0 and row["trimesh_s"] > 0
    assert row["speedup_vs_trimesh"] == pytest.approx(row["trimesh_s"] / row["skincap_s"])
    assert len(lines) == 1 and lines[0].startswith("OBJ read  makehuman_base.obj")


def test_makehuman_base_obj_matches_trimesh(base_mesh: Mesh) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tm = trimesh.load(
            BASE_OBJ, process=False, maintain_order=True, skip_materials=True, force="mesh"
        )
    assert tm.vertices.shape == base_mesh.vertices.shape
    np.testing.assert_allclose(base_mesh.vertices, tm.vertices * 0.1, atol=1e-12)
    # trimesh lists all first triangles of the quads, then all second ones: same set
    np.testing.assert_array_equal(_canonical(base_mesh.faces), _canonical(tm.faces))


def _canonical(faces: np.ndarray) -> np.ndarray:
    """Triangles rotated to start at their smallest index (orientation kept), sorted."""
    f = np.asarray(faces)
    shift = np.argmin(f, axis=1)
    rolled = np.stack([f[np.arange(len(f)), (shift + k) % 3] for k in range(3)], axis=1)
    return rolled[np.lexsort(rolled.T[::-1])]


def test_makehuman_obj_round_trip_keeps_everything(base_mesh: Mesh, tmp_path: Path) -> None:
    out = tmp_path / "base.obj"
    write_obj(base_mesh, out)
    # decimetres restored: the file's own text comes back
    lines = out.read_text().splitlines()
    assert "v -0.3492 7.3299 1.4076" in lines[:5]
    assert sum(ln.startswith("f ") and ln.count(" ") == 4 for ln in lines) == 18486
    m2 = read_obj(out, units="dm")
    np.testing.assert_allclose(m2.vertices, base_mesh.vertices, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(m2.polygon_indices, base_mesh.polygon_indices)
    np.testing.assert_array_equal(m2.polygon_offsets, base_mesh.polygon_offsets)
    np.testing.assert_array_equal(m2.faces, base_mesh.faces)
    assert m2.groups.keys() == base_mesh.groups.keys()
    for k, g in base_mesh.groups.items():
        np.testing.assert_array_equal(m2.groups[k], g)
    np.testing.assert_array_equal(m2.meta["corner_uv"], base_mesh.meta["corner_uv"])
    np.testing.assert_array_equal(m2.meta["uv_table"], base_mesh.meta["uv_table"])


# --------------------------------------------------------------------------- OBJ small
def test_small_obj_corner_forms_groups_and_meta(tmp_path: Path) -> None:
    m = read_obj(_write(tmp_path, "s.obj", SMALL_OBJ))
    assert m.n_vertices == 5
    np.testing.assert_array_equal(m.polygon_offsets, [0, 4, 7, 10, 15])
    # negative indices: -4 is vertex 1 (0-based), -3 vertex 2 at that point of the file
    np.testing.assert_array_equal(m.polygon_indices[4:7], [1, 4, 2])
    np.testing.assert_array_equal(m.faces[:2], [[0, 1, 2], [0, 2, 3]])
    assert m.n_faces == 2 + 1 + 1 + 3
    np.testing.assert_array_equal(m.face_polygon, [0, 0, 1, 2, 3, 3, 3])
    np.testing.assert_array_equal(m.groups["left"], [0])
    np.testing.assert_array_equal(m.groups["right"], [1, 2])
    np.testing.assert_array_equal(m.groups["both"], [0, 1, 2])
    np.testing.assert_array_equal(m.meta["materials"]["red"], [0, 1])
    np.testing.assert_array_equal(m.meta["materials"]["blue"], [2, 3])
    np.testing.assert_array_equal(m.meta["objects"]["thing"], [0, 1, 2, 3])
    assert m.meta["mtllib"] == ["scene.mtl"]
    np.testing.assert_array_equal(m.meta["corner_uv"][:7], [0, 1, 2, 3, -1, -1, -1])
    np.testing.assert_array_equal(m.meta["corner_normal"], [0] * 7 + [-1] * 8)
    assert m.uv is None  # the last polygon has corners without UV
    # round trip keeps all of it
    out = tmp_path / "s2.obj"
    write_obj(m, out)
    m2 = read_obj(out)
    np.testing.assert_array_equal(m2.vertices, m.vertices)
    np.testing.assert_array_equal(m2.polygon_indices, m.polygon_indices)
    for key in ("corner_uv", "corner_normal", "uv_table", "normal_table"):
        np.testing.assert_array_equal(m2.meta[key], m.meta[key])
    for key in ("objects", "materials"):
        assert m2.meta[key].keys() == m.meta[key].keys()
        for name in m.meta[key]:
            np.testing.assert_array_equal(m2.meta[key][name], m.meta[key][name])
    assert m2.groups.keys() == m.groups.keys()
    for name in m.groups:
        np.testing.assert_array_equal(m2.groups[name], m.groups[name])


def test_obj_per_vertex_uv_when_consistent(tmp_path: Path) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    m = read_obj(_write(tmp_path, "uv.obj", text))
    np.testing.assert_array_equal(m.uv, [[0, 0], [1, 0], [1, 1], [0, 1]])
    # a mesh with only per-vertex uv (no per-corner tables) writes v/vt corners
    bare = Mesh(vertices=m.vertices, faces=m.faces, uv=m.uv)
    write_obj(bare, tmp_path / "bare.obj")
    m2 = read_obj(tmp_path / "bare.obj")
    np.testing.assert_array_equal(m2.uv, m.uv)
    np.testing.assert_array_equal(m2.faces, m.faces)


def test_obj_units_and_up_round_trip(tmp_path: Path) -> None:
    text = "v 10 20 30\nv 0 0 0\nv 10 0 0\nf 1 2 3\n"
    m = read_obj(_write(tmp_path, "z.obj", text), units="cm", up="z")
    # Z-up (x, y, z) -> Y-up (x, z, -y), centimetres -> metres
    np.testing.assert_allclose(m.vertices[0], [0.1, 0.3, -0.2])
    assert m.meta["source_units"] == "cm" and m.meta["up"] == "z"
    write_obj(m, tmp_path / "z2.obj")
    assert "v 10 20 30" in (tmp_path / "z2.obj").read_text().splitlines()
    m2 = read_obj(tmp_path / "z2.obj", units="cm", up="z")
    np.testing.assert_allclose(m2.vertices, m.vertices, atol=1e-15)
    # explicit override writes metres, Y up
    write_obj(m, tmp_path / "m.obj", units="m", up="y")
    np.testing.assert_array_equal(read_obj(tmp_path / "m.obj").vertices, m.vertices)


def test_obj_writer_refuses_existing_output(tmp_path: Path) -> None:
    m = Mesh(vertices=np.eye(3), faces=[[0, 1, 2]])
    out = tmp_path / "t.obj"
    out.write_text("keep")
    with pytest.raises(OutputExistsError):
        write_obj(m, out)
    assert out.read_text() == "keep"
    write_obj(m, out, force=True)
    np.testing.assert_array_equal(read_obj(out).vertices, np.eye(3))


def test_triangulate_polygons_fan() -> None:
    faces, owner = triangulate_polygons(np.array([0, 1, 2, 3, 4, 5, 6, 7]), np.array([0, 3, 8]))
    np.testing.assert_array_equal(faces, [[0, 1, 2], [3, 4, 5], [3, 5, 6], [3, 6, 7]])
    np.testing.assert_array_equal(owner, [0, 1, 1, 1])


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "index 4 out of range (file has 3 vertices)"),
        ("v 0 0 0\nf 1 1 2\n", 2, "index 2 out of range (file has 1 vertex)"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//2\n", 5, "(file has 1 normal)"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nf 1/1 2/2 3/3\n",
            6,
            "has 2 texture coordinates)",
        ),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", 4, "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", 4, "index 0"),
        ("v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n", 2, "'zero' is not a number"),
        ("v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n", 3, "non-finite"),
        ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", 2, "expected 3 coordinates"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4, "at least 3 corners"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/5\n", 5, "texture coordinate index 5"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/a 2 3\n", 4, "bad texture index"),
        # past int64: was "face: bad vertex index" with no line
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 " + "1" + "0" * 23 + "\n", 5, "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -" + "9" * 30 + "\n", 4, "vertex index -999"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/" + "9" * 20 + "\n", 5, "texture"),
        ("# only a comment\n", 1, "no vertices"),
    ],
)
def test_obj_bad_input_names_line(tmp_path: Path, text: str, line: int, fragment: str) -> None:
    p = _write(tmp_path, "bad.obj", text)
    with pytest.raises(FormatError) as err:
        read_obj(p)
    assert err.value.line == line
    assert fragment in str(err.value)
    assert str(p) in str(err.value)


def test_obj_empty_and_binary_garbage(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="empty"):
        read_obj(_write(tmp_path, "e.obj", b""))
    with pytest.raises(FormatError, match="UTF-8") as err:
        read_obj(_write(tmp_path, "g.obj", b"v 0 0 0\n\xff\xfe\x00garbage"))
    assert err.value.offset == 8


SEED_OBJ = SMALL_OBJ.encode()


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(ops=MUTATIONS)
def test_obj_fuzz(tmp_path: Path, ops: list[tuple[int, int, int]]) -> None:
    p = tmp_path / "fuzz.obj"
    p.write_bytes(_mutate(SEED_OBJ, ops))
    try:
        m = read_obj(p)
    except SkincapError:
        return
    assert isinstance(m, Mesh)


# -------------------------------------------------------------------------------- PLY
def _mixed_mesh() -> Mesh:
    verts = (
        np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0.5, 0.25]], dtype=float) * 0.37
    )
    idx = np.array([0, 1, 2, 3, 1, 4, 2])
    off = np.array([0, 4, 7])
    faces, owner = triangulate_polygons(idx, off)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.125]])
    return Mesh(
        vertices=verts,
        faces=faces,
        polygon_indices=idx,
        polygon_offsets=off,
        face_polygon=owner,
        uv=uv,
    )


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip_mixed_polygons(tmp_path: Path, binary: bool) -> None:
    m = _mixed_mesh()
    out = tmp_path / "m.ply"
    write_ply(m, out, binary=binary)
    m2 = read_ply(out)
    np.testing.assert_array_equal(m2.vertices, m.vertices)
    np.testing.assert_array_equal(m2.polygon_indices, m.polygon_indices)
    np.testing.assert_array_equal(m2.polygon_offsets, m.polygon_offsets)
    np.testing.assert_array_equal(m2.faces, m.faces)
    np.testing.assert_array_equal(m2.uv, m.uv)
    assert m2.meta["ply_format"] == ("binary_little_endian" if binary else "ascii")


@pytest.mark.parametrize("binary", [True, False])
def test_ply_makehuman_round_trip_and_trimesh(
    base_mesh: Mesh, tmp_path: Path, binary: bool
) -> None:
    out = tmp_path / "base.ply"
    write_ply(base_mesh, out, binary=binary)
    m2 = read_ply(out, units="dm")
    np.testing.assert_allclose(m2.vertices, base_mesh.vertices, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(m2.polygon_indices, base_mesh.polygon_indices)
    np.testing.assert_array_equal(m2.faces, base_mesh.faces)
    tm = trimesh.load(out, process=False)
    np.testing.assert_allclose(tm.vertices * 0.1, base_mesh.vertices, atol=1e-12)
    np.testing.assert_array_equal(_canonical(tm.faces), _canonical(base_mesh.faces))


def test_ply_reads_trimesh_output_and_big_endian(tmp_path: Path) -> None:
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    for enc in ("binary", "ascii"):
        p = tmp_path / f"box_{enc}.ply"
        p.write_bytes(box.export(file_type="ply", encoding=enc))
        m = read_ply(p)
        np.testing.assert_allclose(m.vertices, box.vertices, atol=1e-6)
        np.testing.assert_array_equal(m.faces, box.faces)
    # a hand-written big-endian file with float vertices and a uint8 count / uint32 index list
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=">f4")
    tris = np.array([[0, 1, 2], [0, 1, 3]], dtype=">u4")
    rec = np.zeros(2, dtype=[("n", "u1"), ("i", ">u4", (3,))])
    rec["n"], rec["i"] = 3, tris
    head = (
        b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 2\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    p = _write(tmp_path, "be.ply", head + verts.tobytes() + rec.tobytes())
    m = read_ply(p)
    np.testing.assert_array_equal(m.vertices, verts.astype(float))
    np.testing.assert_array_equal(m.faces, tris)


def test_ply_units_up_and_force(tmp_path: Path) -> None:
    m = _mixed_mesh()
    out = tmp_path / "u.ply"
    write_ply(m, out, units="mm", up="z")
    m2 = read_ply(out, units="mm", up="z")
    np.testing.assert_allclose(m2.vertices, m.vertices, atol=1e-15)
    raw = read_ply(out)  # as if metres and Y up: millimetre numbers, Z-up axes
    np.testing.assert_allclose(raw.vertices[4], np.array([2, -0.25, 0.5]) * 0.37 * 1000, atol=1e-9)
    with pytest.raises(OutputExistsError):
        write_ply(m, out)


def _valid_ply_bytes(binary: bool) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "v.ply"
        write_ply(_mixed_mesh(), p, binary=binary)
        return p.read_bytes()


@pytest.mark.parametrize(
    ("mutate", "fragment"),
    [
        (lambda b: b[:-5], "truncated"),
        (lambda b: b.replace(b"ply\n", b"plx\n", 1), "magic"),
        (lambda b: b.replace(b"end_header", b"end_headxx"), "end_header"),
        (lambda b: b.replace(b"property double z", b"property quad z"), "bad property"),
        (lambda b: b[:-4] + (99).to_bytes(4, "little"), "out of range"),
        (lambda b: b.replace(b"element vertex 5", b"element vertex 2"), "truncated list"),
    ],
)
def test_ply_bad_binary(tmp_path: Path, mutate, fragment: str) -> None:
    p = _write(tmp_path, "bad.ply", mutate(_valid_ply_bytes(True)))
    with pytest.raises(FormatError, match=fragment):
        read_ply(p)


def test_ply_list_count_past_the_end_names_its_byte(tmp_path: Path) -> None:
    """A uint list count of 4e9 was NumPy's 'dimension does not fit into a C int'."""
    head = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
        b"property float y\nproperty float z\nelement face 1\n"
        b"property list uint int vertex_indices\nend_header\n"
    )
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()
    for count in (4_000_000_000, 4):  # past any buffer; one past this file's end
        p = _write(tmp_path, "lie.ply", head + verts + np.array([count, 0, 1, 2], "<u4").tobytes())
        with pytest.raises(
            FormatError, match=rf"lie\.ply: byte {len(head) + 36}: .*list of {count}"
        ):
            read_ply(p)


def test_ply_bad_ascii(tmp_path: Path) -> None:
    good = _valid_ply_bytes(False)
    with pytest.raises(FormatError, match="non-numeric"):
        read_ply(_write(tmp_path, "a.ply", good.replace(b"0.37 0.0 0.0", b"0.37 x 0.0")))
    with pytest.raises(FormatError, match="truncated"):
        read_ply(_write(tmp_path, "b.ply", good[:-8]))
    with pytest.raises(FormatError, match="non-finite"):
        read_ply(_write(tmp_path, "c.ply", good.replace(b"0.37 0.0 0.0", b"0.37 nan 0.0")))


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(ops=MUTATIONS, binary=st.booleans())
def test_ply_fuzz(tmp_path: Path, ops: list[tuple[int, int, int]], binary: bool) -> None:
    p = tmp_path / "fuzz.ply"
    p.write_bytes(_mutate(_PLY_SEEDS[binary], ops))
    try:
        m = read_ply(p)
    except SkincapError:
        return
    assert isinstance(m, Mesh)


_PLY_SEEDS = {True: _valid_ply_bytes(True), False: _valid_ply_bytes(False)}
