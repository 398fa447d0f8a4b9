"""track_file: points file in, rope C3D + body points + rope curve + report out."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincap.errors import FormatError, OutputExistsError, ValidationError
from skincap.io.c3d import read_c3d
from skincap.io.csv import read_points_csv, write_points_csv
from skincap.io.rope_curve import read_rope_curve
from skincap.synth.scenes import jump_rope_scene
from skincap.workflows.track_file import OUTPUT_NAMES, track_file

ROPE = 10


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    cloud, rope, _ = jump_rope_scene(frames=150, points_per_frame=50, rope_markers=ROPE, seed=2)
    path = tmp_path_factory.mktemp("track_file") / "points.csv"
    write_points_csv(cloud, path)
    return path, cloud, rope


def test_track_file_writes_the_four_outputs_from_a_points_file(scene, tmp_path):
    path, cloud, rope = scene
    ids = cloud.ids[cloud.offsets[0] : cloud.offsets[1]]
    rope_rows = np.flatnonzero((ids >= 0) & (ids < ROPE))
    calls = []
    report = track_file(
        path,
        tmp_path / "out",
        markers=rope_rows.tolist(),
        progress=lambda d, n: calls.append((d, n)),
    )
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(OUTPUT_NAMES)
    assert report == json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["frames"] == cloud.n_frames and len(report["rope_markers"]) == ROPE
    # every point goes to the rope or to the body, none twice
    body = read_points_csv(tmp_path / "out" / "body_points.csv")
    assert body.points.shape[0] + report["rope_points"] == cloud.points.shape[0]
    tracked = read_c3d(tmp_path / "out" / "rope.c3d")
    assert tracked.positions.shape == (cloud.n_frames, ROPE, 3)
    # the tracked rope follows the true rope (either end first) within 2 cm, median
    err = np.nanmedian(np.linalg.norm(tracked.positions - rope, axis=-1))
    err_flipped = np.nanmedian(np.linalg.norm(tracked.positions - rope[:, ::-1], axis=-1))
    assert min(err, err_flipped) < 0.02
    curves, rate = read_rope_curve(tmp_path / "out" / "rope_curve.csv")
    assert curves.shape == (cloud.n_frames, 50, 3) and rate == cloud.rate
    # the resampled curve starts and ends on the tracked end markers
    ends = np.isfinite(tracked.positions[:, [0, -1]]).all(axis=(1, 2))
    np.testing.assert_allclose(
        curves[ends][:, [0, -1]], tracked.positions[ends][:, [0, -1]], atol=1e-6
    )
    done = [d for d, _ in calls]
    assert calls[0] == (0.0, cloud.n_frames) and done == sorted(done)
    assert done[-1] == pytest.approx(cloud.n_frames)


def test_track_file_refuses_before_reading(scene, tmp_path):
    path, _, _ = scene
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "report.json").write_text("{}")
    with pytest.raises(OutputExistsError):
        track_file(path, tmp_path / "out", auto=True)
    with pytest.raises(ValidationError, match="exactly one"):
        track_file(path, tmp_path / "new", auto=True, markers=[0, 1, 2])
    labelled = tmp_path / "labelled.c3d"
    labelled.write_bytes((path.parent / "points.csv").read_bytes())
    with pytest.raises(FormatError):
        track_file(labelled, tmp_path / "new", auto=True)
