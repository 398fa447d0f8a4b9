"""``skincap track`` end to end on a small analytic take (a swinging rope and a body blob)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skincap.cli import app
from skincap.io.c3d import read_c3d, write_c3d
from skincap.io.csv import read_points_csv, write_points_csv
from skincap.types import MarkerSet, PointCloud

T, M_ROPE, N_BODY, RATE = 150, 15, 80, 120.0


def run(*args):  # type: ignore[no-untyped-def]
    return CliRunner().invoke(app, [str(a) for a in args])


def _scene() -> tuple[PointCloud, np.ndarray]:
    """Rope (a chain of 12 cm links) hanging from (0, 2, 0), still for 0.5 s, then
    swinging and curling; a blob of body points beside it; rope marker 7 unseen in
    frames 90-99. Returns the cloud and the (M,) truth label per point (rope index or
    -1 for the body)."""
    t = np.arange(T)
    u = np.clip((t - 60) / 30.0, 0, 1)
    ramp = u * u * (3 - 2 * u)  # smooth start of the swing
    theta = 0.5 * ramp * np.sin(2 * np.pi * (t - 60) / RATE)  # (T,)
    s = 0.12 * np.arange(M_ROPE)
    bend = 0.3 * ramp[:, None] * (s[None] / s[-1]) ** 2  # a curl growing along the rope
    ang = theta[:, None] + bend
    # an inextensible chain: each 12 cm link at the angle of its far marker
    link = 0.12 * np.stack([np.sin(ang[:, 1:]), -np.cos(ang[:, 1:])], axis=2)  # (T, M-1, 2)
    xy = np.concatenate([np.zeros((T, 1, 2)), np.cumsum(link, axis=1)], axis=1)
    rope = np.stack([xy[..., 0], 2.0 + xy[..., 1], np.zeros_like(ang)], axis=2)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(N_BODY, 3))
    body0 = np.array([1.2, 1.0, 0.0]) + 0.3 * d / np.linalg.norm(d, axis=1, keepdims=True)
    body = body0[None] + (0.2 * np.sin(t / 40.0) * ramp)[:, None, None] * np.array([0, 0, 1.0])
    pos = np.concatenate([rope, body], axis=1)  # (T, M_ROPE + N_BODY, 3)
    pos = pos + rng.normal(scale=0.0005, size=pos.shape)
    truth = np.concatenate([np.arange(M_ROPE), np.full(N_BODY, -1)])
    present = np.ones(pos.shape[:2], dtype=bool)
    present[90:100, 7] = False
    # shuffle the point order in every frame: an un-indexed cloud
    order = np.argsort(rng.random(pos.shape[:2]), axis=1)
    pos = np.take_along_axis(pos, order[..., None], axis=1)
    present = np.take_along_axis(present, order, axis=1)
    lab = truth[order]
    ti, ni = np.nonzero(present)
    offsets = np.concatenate([[0], np.cumsum(present.sum(axis=1))])
    return PointCloud(pos[ti, ni], offsets, RATE), lab[ti, ni]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):  # type: ignore[no-untyped-def]
    cloud, truth = _scene()
    folder = tmp_path_factory.mktemp("track")
    write_points_csv(cloud, folder / "points.csv")
    return folder, cloud, truth


def _check_outputs(folder, cloud: PointCloud, truth: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    rope = read_c3d(folder / "rope.c3d")
    assert rope.labels == [f"rope_{j:02d}" for j in range(M_ROPE)]
    assert rope.n_frames == T and not rope.missing.any()
    assert rope.invented is not None and rope.invented[90:100].sum(axis=0).max() == 10
    body = read_points_csv(folder / "body_points.csv")
    assert body.n_frames == T
    assert body.points.shape[0] == int((truth < 0).sum())  # every body point, no rope
    curve = np.loadtxt(folder / "rope_curve.csv", delimiter=",", skiprows=1)
    assert curve.shape == (T * 50, 5)
    length = curve[curve[:, 0] == 120, 1].max()
    chord = np.linalg.norm(np.diff(rope.positions[120], axis=0), axis=1).sum()
    assert chord <= length <= 1.01 * chord  # the smooth curve is a little longer
    np.testing.assert_allclose(
        curve[curve[:, 0] == 120][[0, -1], 2:], rope.positions[120, [0, -1]], atol=1e-6
    )
    report = json.loads((folder / "report.json").read_text())
    assert report["frames"] == T and len(report["rope_markers"]) == M_ROPE
    assert report["invented_samples"] == 10 and report["lost_traces"] == []
    assert report["rope_points"] + report["body_points"] == cloud.points.shape[0]


def test_track_auto(scene, tmp_path) -> None:  # type: ignore[no-untyped-def]
    folder, cloud, truth = scene
    out = tmp_path / "auto"
    result = run("track", folder / "points.csv", "--rope", "auto", "-o", out)
    assert result.exit_code == 0, result.output
    assert f"{M_ROPE} rope markers" in " ".join(result.output.split())
    _check_outputs(out, cloud, truth)
    # existing outputs are refused, then replaced with --force
    again = run("track", folder / "points.csv", "--rope", "auto", "-o", out)
    assert again.exit_code == 2 and "exists" in again.output
    forced = run("track", folder / "points.csv", "--rope", "auto", "-o", out, "--force")
    assert forced.exit_code == 0, forced.output


def test_track_markers_and_box(scene, tmp_path) -> None:  # type: ignore[no-untyped-def]
    folder, cloud, truth = scene
    idx = np.nonzero(truth[: cloud.offsets[1]] >= 0)[0]
    out = tmp_path / "markers"
    result = run(
        "track", folder / "points.csv", "--rope-markers", ",".join(map(str, idx)), "-o", out
    )
    assert result.exit_code == 0, result.output
    _check_outputs(out, cloud, truth)
    out = tmp_path / "box"
    result = run(
        "track", folder / "points.csv", "--rope-box", "-0.1,0.2,-0.1,0.1,2.1,0.1", "-o", out,
        "--json",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    _check_outputs(out, cloud, truth)
    # --json: the summary line's counts, as the report has them, and the files written
    summary = json.loads(result.stdout)
    report = json.loads((out / "report.json").read_text())
    assert summary == {
        "input": str(folder / "points.csv"),
        "outputs": [str(out / n) for n in ("rope.c3d", "body_points.csv", "rope_curve.csv",
                                           "report.json")],
        "frames": T,
        "rope_markers": M_ROPE,
        "rope_points": report["rope_points"],
        "invented_samples": 10,
        "lost_traces": 0,
        "lost": [],
    }  # fmt: skip


def test_track_c3d_of_unlabelled_points(scene, tmp_path) -> None:  # type: ignore[no-untyped-def]
    _, cloud, truth = scene
    # one column per point slot: a C3D of '*N' fragments
    n = int(cloud.counts.max())
    pos = np.full((T, n, 3), np.nan)
    col = np.arange(cloud.points.shape[0]) - np.repeat(cloud.offsets[:-1], cloud.counts)
    pos[cloud.frame_index, col] = cloud.points
    write_c3d(MarkerSet(pos, [f"*{i}" for i in range(n)], RATE), tmp_path / "in.c3d")
    result = run("track", tmp_path / "in.c3d", "--rope", "auto", "-o", tmp_path / "out")
    assert result.exit_code == 0, result.output
    rope = read_c3d(tmp_path / "out" / "rope.c3d")
    assert rope.n_markers == M_ROPE
    labelled = MarkerSet(pos, [f"M{i}" for i in range(n)], RATE)
    write_c3d(labelled, tmp_path / "labelled.c3d")
    bad = run("track", tmp_path / "labelled.c3d", "--rope", "auto", "-o", tmp_path / "o2")
    assert bad.exit_code == 2 and "labelled" in bad.output


def test_track_usage_errors(scene, tmp_path) -> None:  # type: ignore[no-untyped-def]
    folder, _, _ = scene
    src = folder / "points.csv"
    cases = [
        (["-o", tmp_path / "a"], "exactly one"),
        (["--rope", "auto", "--rope-markers", "1,2,3", "-o", tmp_path / "b"], "exactly one"),
        (["--rope", "magic", "-o", tmp_path / "c"], "auto"),
        (["--rope-box", "1,2,3", "-o", tmp_path / "d"], "6 numbers"),
        (["--rope-markers", "1,x", "-o", tmp_path / "e"], "comma-separated"),
        (["--rope-markers", "0,1,99999", "-o", tmp_path / "f"], "out of range"),
    ]
    for args, message in cases:
        result = run("track", src, *args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output, (args, result.output)
    garbage = tmp_path / "garbage.csv"
    garbage.write_bytes(b"\\x00\\xff not a csv\\n")
    result = run("track", garbage, "--rope", "auto", "-o", tmp_path / "g")
    assert result.exit_code == 2 and "skincap: error:" in result.output


@pytest.mark.parametrize("window", ["-1", "nan", "inf", "0"])
@pytest.mark.parametrize("rope", [["--rope", "auto"], []])  # checked before the rope choice too
def test_track_refuses_a_bad_window_naming_the_option(scene, tmp_path, window, rope) -> None:  # type: ignore[no-untyped-def]
    folder, _, _ = scene
    out = tmp_path / "out"
    result = run("track", folder / "points.csv", *rope, f"--window={window}", "-o", out)
    assert result.exit_code == 2, result.output
    errors = [ln for ln in result.output.splitlines() if ln.startswith("skincap: error:")]
    assert len(errors) == 1 and "--window: expected seconds > 0" in errors[0], result.output
    assert "Traceback" not in result.output and not out.exists()


def test_track_help_has_example() -> None:
    result = run("track", "--help")
    assert result.exit_code == 0 and "Example: skincap track" in result.output
