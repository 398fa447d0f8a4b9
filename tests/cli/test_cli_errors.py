"""How the CLI reports trouble (issue 13, items 1, 5 and 7): warnings from NumPy or SciPy
once, as one line, never looping; every error one line naming a file; no NumPy reprs,
temporary names or binary bytes in messages; hostile meshes given to ``skin`` end in a
result or one line, never a traceback."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from skincap.cli import _app as cli
from skincap.errors import FormatError, SkincapWarning, ValidationError, one_line
from skincap.io._common import atomic_output

DATA = Path(__file__).parents[1] / "data"
BVH = DATA / "cmu_131_01_bvh11.bvh"


def skincap(*args: object, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """The real console script in a subprocess, with 2 GB of address space at most."""

    def limit() -> None:  # runs in the child: a loop that allocates dies instead of swapping
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))

    return subprocess.run(
        [sys.executable, "-c", "from skincap.cli import main; main()", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=limit,
        env={**os.environ, "PYTHONWARNINGS": "", "COLUMNS": "80"},
    )


def one_error_line(result: subprocess.CompletedProcess[str], file: object) -> str:
    """The single error line of a refused command, checked for the house format."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr
    errors = [ln for ln in result.stderr.splitlines() if not ln.startswith("skincap: warning:")]
    assert len(errors) == 1, result.stderr
    line = errors[0]
    assert line.startswith(f"skincap: error: {file}"), line
    assert "np." not in line and "\\x" not in line and len(line) < 400, line
    return line


# -------------------------------------------------------------- item 1: warnings
def test_numpy_warnings_print_once_and_never_loop(tmp_path: Path) -> None:
    """The issue's reproducer: 1e308 coordinates overflow in NumPy while summarising."""
    obj = tmp_path / "t.obj"
    obj.write_text("v 0 0 0\nv 1e308 0 0\nv -1e308 1 0\nf 1 2 3\n")
    result = skincap("info", obj, timeout=60)  # hung, growing ~50 MB/s, before the fix
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    assert lines and all(ln.startswith("skincap: warning: RuntimeWarning: ") for ln in lines)
    assert len(set(lines)) == len(lines)  # each distinct warning once
    assert "overflow" in result.stderr and "Traceback" not in result.stderr
    assert "vertices" in result.stdout


_WARNING_SCRIPT = """
import warnings
import numpy as np
import scipy.linalg
from skincap.cli import _app as cli
from skincap.errors import SkincapWarning
with cli._user_errors():
    for _ in range(50):  # one location, many times: shown once
        np.array([1e308]) * 10.0
    for _ in range(3):  # an ill-conditioned solve: SciPy's LinAlgWarning
        scipy.linalg.solve(scipy.linalg.hilbert(14), np.ones(14))
    warnings.warn("first line\\n  second line", UserWarning, stacklevel=1)
    warnings.warn("guessed 'cm'", SkincapWarning, stacklevel=1)
    warnings.warn("guessed 'cm'", SkincapWarning, stacklevel=1)
"""


def test_flush_prints_numpy_and_scipy_warnings_once_as_one_line() -> None:
    # in a subprocess with a time and memory limit: the old flush looped forever
    result = subprocess.run(
        [sys.executable, "-c", _WARNING_SCRIPT],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30)),
        env={**os.environ, "PYTHONWARNINGS": ""},
    )
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stderr.splitlines()
    assert lines == [
        "skincap: warning: RuntimeWarning: overflow encountered in multiply",
        lines[1],
        "skincap: warning: UserWarning: first line second line",
        "skincap: warning: guessed 'cm'",
    ]
    assert lines[1].startswith("skincap: warning: LinAlgWarning: An ill-conditioned matrix")


def test_warnings_come_before_the_error_line(capsys) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(cli.typer.Exit) as exit_info, warnings.catch_warnings():
        warnings.simplefilter("default")
        with cli._user_errors():
            warnings.warn("units guessed", SkincapWarning, stacklevel=1)
            raise FormatError("walk.c3d", "bad\nthing np.int64(12)")
    assert exit_info.value.exit_code == 2
    assert capsys.readouterr().err.splitlines() == [
        "skincap: warning: units guessed",
        "skincap: error: walk.c3d: bad thing 12",
    ]


# ------------------------------------------------------------ item 7: messages
def test_one_line_removes_numpy_reprs_line_breaks_and_terminal_escapes() -> None:
    assert one_line("a: np.int64(12) of np.float64(733.0)") == "a: 12 of 733.0"
    assert one_line("matrix\n[[1. 0.]\n [0. 1.]]") == "matrix [[1. 0.] [0. 1.]]"
    assert one_line("np.str_('LASI') np.bool_(True) np.uint8(3)") == "'LASI' True 3"
    assert one_line("name \x1b[2J\x07") == "name \\x1b[2J\\x07"


def test_temp_output_name_maps_back_to_the_path_given(tmp_path: Path) -> None:
    for target in (tmp_path / "o.trc", tmp_path / "take.v2.c3d", tmp_path / "noext"):
        with atomic_output(target) as tmp:  # the very naming atomic_output uses
            assert cli._path_given(str(tmp)) == str(target)
            tmp.write_text("x")
    assert cli._path_given("/data/.hidden.trc") == "/data/.hidden.trc"
    assert cli._path_given(".o.trc.ki5_i32y.part.trc") == "o.trc"


@pytest.mark.skipif(not os.access("/sys", os.F_OK), reason="needs /sys (read-only)")
def test_read_only_folder_names_the_output_not_the_temp_file(tmp_path: Path) -> None:
    # /sys refuses new files even to root: mkstemp fails on the temporary name
    result = skincap("convert", BVH, "/sys/o.bvh", "--units", "cmu")
    line = one_error_line(result, "/sys/o.bvh")
    assert line == "skincap: error: /sys/o.bvh: permission denied"


def test_errors_without_a_file_get_the_file(tmp_path: Path) -> None:
    # a writer's argument check: the output is named
    obj = tmp_path / "fan.obj"
    ring = " ".join(str(k) for k in range(1, 301))
    obj.write_text(
        "".join(f"v {np.cos(a)} {np.sin(a)} 0\n" for a in np.linspace(0, 6, 300)) + f"f {ring}\n"
    )
    line = one_error_line(skincap("convert", obj, tmp_path / "fan.ply"), tmp_path / "fan.ply")
    assert "polygon has 300 corners" in line
    # a check between reading and writing (points to markers): the input is named
    points = tmp_path / "points.csv"
    points.write_text("frame,time,x,y,z,id\n0,0,0,0,0,12\n0,0,1,1,1,12\n1,0.01,0,0,0,12\n")
    line = one_error_line(skincap("convert", points, tmp_path / "m.c3d"), points)
    assert "id 12 appears 2 times" in line
    # an option's check: the file it was for
    line = one_error_line(skincap("convert", BVH, tmp_path / "o.bvh", "--units", "furlong"), BVH)
    assert "unknown BVH length unit 'furlong'" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fan.obj", "points.csv"]


def test_skincap_error_line_prefixes_the_verbs_input_files() -> None:
    import typer

    seen: list[str] = []
    app = typer.Typer()

    @app.command()
    def verb(mesh: Path, motion: Path, output: Path = typer.Option(...)) -> None:
        seen.append(cli._skincap_error_line(ValidationError("no joints to pair")))

    from typer.testing import CliRunner

    result = CliRunner().invoke(
        app, [str(DATA / "makehuman_base.obj"), str(BVH), "--output", "x.glb"]
    )
    assert result.exit_code == 0, result.output
    assert seen == [f"{DATA / 'makehuman_base.obj'}, {BVH}: no joints to pair"]


def test_binary_motion_is_not_printed(tmp_path: Path) -> None:
    c3d = DATA / "cmu_85_02.c3d"
    result = skincap("skin", DATA / "makehuman_base.obj", c3d, "-o", tmp_path / "o.pc2")
    line = one_error_line(result, c3d)
    assert line.endswith("expected 'HIERARCHY', found binary data")
    assert not any(p.exists() for p in (tmp_path / "o.pc2", tmp_path / "o.obj"))


@pytest.mark.parametrize(
    ("option", "fragment"),
    [
        (["--time", "999"], "--time: the take runs from 0 to"),
        (["--time", "-1"], "--time: the take runs from 0 to"),
        (["--time", "nan"], "got nan"),
        (["--frame", "-5"], "--frame: the scene's frames are 0 to"),
        (["--frame", "100000"], "--frame: the scene's frames are 0 to"),
        # a PNG skipped the --fps check; the viewer's "fps: must be positive" came instead
        (["--fps", "nan"], "--fps: expected a positive number, got nan"),
        (["--fps", "0"], "--fps: expected a positive number, got 0"),
    ],
)
def test_render_refuses_times_outside_the_take(tmp_path: Path, option, fragment) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "r.png"
    line = one_error_line(skincap("render", BVH, "--units", "cmu", "-o", out, *option), BVH)
    assert fragment in line
    assert not out.exists()


@pytest.mark.parametrize(
    ("option", "fragment"),
    [  # NaN/inf angles drew an empty picture (exit 0)
        (["--azimuth", "nan"], "--azimuth: expected a finite angle in degrees, got nan"),
        (["--elevation", "inf"], "--elevation: expected a finite angle in degrees, got inf"),
    ],
)
def test_render_refuses_camera_angles_that_are_not_numbers(
    tmp_path: Path, option, fragment
) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "r.png"
    line = one_error_line(skincap("render", BVH, "--units", "cmu", "-o", out, *option), BVH)
    assert fragment in line
    assert not out.exists()


def test_render_refuses_a_pc2_rate_that_is_not_positive(tmp_path: Path) -> None:
    # was ZeroDivisionError (0) and "cannot convert float NaN to integer" tracebacks
    from skincap.io.pc2 import write_pc2
    from skincap.types import Mesh, MeshAnimation

    mesh = Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]]))
    write_pc2(MeshAnimation(mesh, np.stack([np.eye(3)] * 4), rate=30.0), tmp_path / "t.pc2")
    (tmp_path / "t.obj").write_text("v 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n")
    for rate in ("0", "nan", "-30"):
        out = tmp_path / "r.png"
        result = skincap("render", tmp_path / "t.obj", "-o", out, "--rate", rate)
        line = one_error_line(result, tmp_path / "t.obj")
        assert "--rate: expected a positive frame rate in Hz" in line
        assert not out.exists()


def test_render_refuses_clip_options_that_cannot_hold(tmp_path: Path) -> None:
    for option, fragment in [
        (["-o", tmp_path / "c.gif", "--time", "1"], "pick a PNG's frame"),
        (["-o", tmp_path / "c.gif", "--start", "-2"], "--start: the take runs"),
        (["-o", tmp_path / "c.gif", "--start", "2", "--end", "1"], "must not come before"),
        (["-o", tmp_path / "c.gif", "--fps", "1e9"], "a clip holds at most"),
    ]:
        line = one_error_line(skincap("render", BVH, "--units", "cmu", *option), BVH)
        assert fragment in line
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------- item 5: skin tracebacks
def _body_points(n: int = 400, seed: int = 0) -> list[list[float]]:
    """n (x, y, z) points filling a standing person's box, metres, Y up."""
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.25, 0.0, -0.12], [0.25, 1.75, 0.12], size=(n, 3)).tolist()


def test_skin_mesh_with_vertices_and_no_faces_is_refused(tmp_path: Path) -> None:
    """A point cloud is no skin: bone heat needs a surface (it used to bind each vertex
    to its nearest bone and write the cloud as a skin); one line, nothing written."""
    mesh = tmp_path / "cloud.obj"
    mesh.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in _body_points()))
    out = tmp_path / "o.pc2"
    line = one_error_line(skincap("skin", mesh, BVH, "--units", "cmu", "-o", out), mesh)
    assert "no faces" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cloud.obj"]


def test_skin_ply_with_a_vertex_at_minus_4e307_is_refused(tmp_path: Path) -> None:
    v = _body_points()
    v[0][0] = -4e307
    ply = tmp_path / "far.ply"
    ply.write_text(
        f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty double x\nproperty double y\n"
        "property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in v)
        + "3 1 2 3\n"
    )
    line = one_error_line(
        skincap("skin", ply, BVH, "--units", "cmu", "-o", tmp_path / "o.pc2"), ply
    )
    assert "vertex 0 lies at [-4e+307" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.ply"]


def test_skin_glb_with_an_all_zero_inverse_bind_matrix_is_refused(tmp_path: Path) -> None:
    sys.path.insert(0, str(Path(__file__).parents[1] / "io"))
    try:
        from test_gltf import skinned_cylinder
    finally:
        sys.path.pop(0)
    b, nodes, meshes, skins, _ = skinned_cylinder()
    acc = b.accessors[skins[0]["inverseBindMatrices"]]
    start = b.views[acc["bufferView"]]["byteOffset"]
    b.blob[start : start + 64] = bytes(64)
    glb = b.write_glb(tmp_path / "leg.glb", nodes, meshes, skins)
    line = one_error_line(
        skincap("skin", glb, BVH, "--units", "cmu", "-o", tmp_path / "o.pc2"), glb
    )
    assert "inverseBindMatrices[0]" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["leg.glb"]


# ------------------------------------------------------- session 11: options named
def test_solve_unknown_units_names_the_option_not_the_output(tmp_path: Path) -> None:
    """'--units furlong' was reported against OUT.bvh, after the whole solve."""
    result = skincap(
        "solve", DATA / "cmu_85_02.c3d", "-o", tmp_path / "s.bvh", "--units", "furlong"
    )
    line = one_error_line(result, "--units")
    assert "'furlong'" in line and "'cm'" in line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("count", ["1000000000", "0", "-3"])
def test_skin_max_influences_out_of_bounds_names_the_option(tmp_path: Path, count: str) -> None:
    """1e9 was accepted; 0 and -3 were reported against the mesh and the BVH."""
    mesh = DATA / "makehuman_base.obj"
    result = skincap("skin", mesh, BVH, "-o", tmp_path / "o.pc2", "--max-influences", count)
    assert f"got {count}" in one_error_line(result, "--max-influences: expected 1..64")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "args, message",
    [
        # a newcomer's first tries: typer printed a usage line, a hint and a boxed panel
        (["animate", "body.obj", "take.c3d"], "Missing option '-o' / '--output'. (see 'skincap animate --help')"),
        (["demo", "--frames", "abc"], "Invalid value for '--frames': "),
        (["track", "x.csv", "--bogus"], "No such option: --bogus (see 'skincap track --help')"),
        (["nosuchverb"], "No such command 'nosuchverb'. (see 'skincap --help')"),
        (["view"], "Missing argument 'paths'. (see 'skincap view --help')"),
    ],
)  # fmt: skip
def test_a_command_line_that_does_not_parse_is_one_line(tmp_path: Path, args, message) -> None:  # type: ignore[no-untyped-def]
    result = skincap(*args)
    assert result.returncode == 2, result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith("skincap: error: ") and message in line, line
    assert result.stdout == ""


def test_help_and_no_arguments_still_print_the_help() -> None:
    for args, code in (([], 2), (["--help"], 0), (["bench"], 2)):
        result = skincap(*args)
        assert result.returncode == code, result.stderr
        assert "Commands" in result.stdout + result.stderr, args
