"""rope_curve.csv: write -> read round trip, the rate from report.json, bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincap.errors import FormatError, OutputExistsError, ValidationError
from skincap.io.rope_curve import (
    DEFAULT_CURVE_RATE,
    ROPE_CURVE_HEADER,
    is_rope_curve_csv,
    read_rope_curve,
    write_rope_curve,
)


def _curve(frames: int = 4, samples: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(frames, samples, 3))
    steps = np.linalg.norm(np.diff(points, axis=1), axis=-1)
    s = np.concatenate([np.zeros((frames, 1)), np.cumsum(steps, axis=1)], axis=1)
    return s, points


def test_round_trip_to_nine_digits_with_nan(tmp_path):
    s, points = _curve()
    points[2, 3] = np.nan
    path = tmp_path / "rope_curve.csv"
    write_rope_curve(path, s, points)
    assert path.read_text().splitlines()[0] == ROPE_CURVE_HEADER
    assert is_rope_curve_csv(path)
    curves, rate = read_rope_curve(path)
    assert curves.shape == points.shape
    assert rate == DEFAULT_CURVE_RATE
    np.testing.assert_allclose(curves, points, rtol=1e-8, atol=0)  # %.9g
    assert np.isnan(curves[2, 3]).all() and np.isfinite(np.delete(curves, 3, axis=1)).all()


def test_rate_comes_from_the_report_beside_it(tmp_path):
    s, points = _curve()
    write_rope_curve(tmp_path / "rope_curve.csv", s, points)
    (tmp_path / "report.json").write_text(json.dumps({"rate": 240.0}))
    assert read_rope_curve(tmp_path / "rope_curve.csv")[1] == 240.0
    (tmp_path / "report.json").write_text("{not json")
    assert read_rope_curve(tmp_path / "rope_curve.csv")[1] == DEFAULT_CURVE_RATE


def test_existing_output_and_bad_shapes_are_refused(tmp_path):
    s, points = _curve()
    path = tmp_path / "rope_curve.csv"
    write_rope_curve(path, s, points)
    with pytest.raises(OutputExistsError):
        write_rope_curve(path, s, points)
    write_rope_curve(path, s[:2], points[:2], force=True)
    assert read_rope_curve(path)[0].shape == (2, 5, 3)
    with pytest.raises(ValidationError, match=r"\(T, K, 3\)"):
        write_rope_curve(tmp_path / "other.csv", s, points[:, :4])


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("frame,s,x,y,z\n", "no rows"),
        ("frame,s,x,y,z\n0,0,1,2\n", "5 columns"),
        ("frame,s,x,y,z\n1,0,0,0,0\n0,0,0,0,0\n", "not decrease"),
        ("frame,s,x,y,z\n0,0,0,0,0\n0,1,0,0,0\n1,0,0,0,0\n", "same number"),
        ("frame,s,x,y,z\n0,a,0,0,0\n", "rope curve table"),
    ],
)
def test_bad_files_name_what_is_wrong(tmp_path, text, what):
    path = tmp_path / "rope_curve.csv"
    path.write_text(text)
    with pytest.raises(FormatError, match=what):
        read_rope_curve(path)


def test_other_csv_is_not_a_rope_curve(tmp_path):
    path = tmp_path / "points.csv"
    path.write_text("frame,time,x,y,z,id\n")
    assert not is_rope_curve_csv(path)
