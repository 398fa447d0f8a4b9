from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from skincap._arrays import as_finite_array, broadcast_leading
from skincap._arrays import interior_runs as find_gaps
from skincap.errors import ValidationError
from skincap.evaluate.summary import summarize
from skincap.types import MarkerSet


def _gaps_reference(missing):
    """Per-column scan: the plain version find_gaps must agree with."""
    out = []
    t, n = missing.shape
    for c in range(n):
        f = 0
        while f < t:
            if missing[f, c]:
                s = f
                while f < t and missing[f, c]:
                    f += 1
                if s > 0 and f < t:
                    out.append((c, s, f - s))
            else:
                f += 1
    return sorted(out)


@settings(max_examples=200, deadline=None)
@given(arrays(bool, st.tuples(st.integers(0, 30), st.integers(0, 5))))
def test_find_gaps_matches_scan(missing):
    m, s, length = find_gaps(missing)
    assert sorted(zip(m.tolist(), s.tolist(), length.tolist(), strict=True)) == _gaps_reference(
        missing
    )


def test_marker_summary_counts():
    p = np.zeros((10, 3, 3))
    p[2:5, 0] = np.nan  # interior gap of 3
    p[0:2, 1] = np.nan  # leading run: not a gap
    p[7, 2] = np.nan  # interior gap of 1
    s = summarize(MarkerSet(p, ["a", "*1", "c"], 100.0))
    assert s["kind"] == "markers"
    assert (s["markers"], s["labelled"], s["unlabelled"]) == (3, 2, 1)
    assert (s["gaps"], s["longest_gap"]) == (2, 3)
    assert s["missing_fraction"] == 6 / 30
    assert s["duration"] == 0.1


def test_as_finite_array_checks_shape_and_finiteness_and_copies_on_request():
    source = np.arange(6.0).reshape(2, 3)
    same = as_finite_array(source, "points", (None, 3))
    assert same.dtype == np.float64 and np.shares_memory(same, source)
    copied = as_finite_array(source, "points", (2, 3), copy=True)
    assert np.array_equal(copied, source) and not np.shares_memory(copied, source)
    assert as_finite_array([1, 2], "pair", (2,)).dtype == np.float64
    with pytest.raises(ValidationError, match=r"points: expected shape \(\*, 3\), got \(3, 2\)"):
        as_finite_array(source.T, "points", (None, 3))
    with pytest.raises(ValidationError, match=r"fov: expected shape \(\), got \(2,\)"):
        as_finite_array([1.0, 2.0], "fov", ())
    with pytest.raises(ValidationError, match="points: must be finite"):
        as_finite_array([[0.0, np.nan, 1.0]], "points", (None, 3))
    with pytest.raises(ValidationError, match="ragged: expected a float array of shape"):
        as_finite_array([[1.0], [1.0, 2.0]], "ragged", (None, None))


def test_broadcast_leading_gives_the_common_shape_or_the_callers_message():
    assert broadcast_leading((4, 1), (3,), (), error="unused") == (4, 3)
    assert broadcast_leading((), error="unused") == ()
    with pytest.raises(ValidationError, match=r"^a \(2,\) and b \(3,\): no broadcast$") as info:
        broadcast_leading((2,), (3,), error="a (2,) and b (3,): no broadcast")
    assert info.value.__cause__ is None  # the house message alone, not numpy's


def test_marker_summary_names_what_a_c3d_carries_besides_points(data_dir):
    # `info` on an EMG or force-plate take said nothing of its analog channels
    import ezc3d

    from skincap import io

    path = data_dir / "external" / "c3dorg_sample02_pc_int.c3d"
    c = ezc3d.c3d(str(path))
    s = summarize(io.read(path))
    assert s["analog_channels"] == c["header"]["analogs"]["size"] == 16
    assert s["analog_rate"] == c["header"]["analogs"]["frame_rate"] == 200.0
    assert s["force_plates"] == 2 and s["events"] == 9
    trc = summarize(io.read(data_dir / "external" / "btk_motionanalysis_gait.trc"))
    assert "analog_channels" not in trc  # only a C3D carries them
