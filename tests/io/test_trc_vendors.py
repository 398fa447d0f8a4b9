"""TRC files of Motion Analysis (Cortex/EVaRT, from BTKData, BSD-3): unnamed markers
follow the named ones in each row, as many as that frame saw."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skincap.io.c3d import read_c3d, write_c3d
from skincap.io.trc import read_trc, write_trc

EXTERNAL = Path(__file__).resolve().parents[1] / "data" / "external"
GAIT = EXTERNAL / "btk_motionanalysis_gait.trc"  # 33 named, NumMarkers 66, rows up to 105
UNNAMED = EXTERNAL / "btk_motionanalysis_unnamed.trc"  # NumMarkers 0, no names


def _triplets(path: Path) -> tuple[int, dict[tuple[int, int], tuple[float, float, float]]]:
    """Independent parse: (rows, {(row, marker): xyz in file units}) of every complete
    non-empty triplet of the data rows."""
    lines = [ln.rstrip("\r") for ln in path.read_text().split("\n")[5:] if ln.strip()]
    seen = {}
    for r, line in enumerate(lines):
        fields = line.split("\t")[2:]
        for k in range(len(fields) // 3):
            xyz = fields[3 * k : 3 * k + 3]
            if all(f.strip() for f in xyz):
                seen[(r, k)] = tuple(float(f) for f in xyz)
    return len(lines), seen


@pytest.mark.parametrize(("path", "named"), [(GAIT, 33), (UNNAMED, 0)], ids=["gait", "unnamed"])
def test_unnamed_markers_are_unlabelled_columns(path, named):
    m = read_trc(path)
    rows, seen = _triplets(path)
    assert m.n_frames == rows
    assert all(not lab.startswith("*") for lab in m.labels[:named])
    assert m.labels[named:] == [f"*{k}" for k in range(named + 1, m.n_markers + 1)]
    assert m.n_markers == max(k for _, k in seen) + 1  # as many columns as the rows hold
    # every sample the file holds, and nothing else, in metres
    present = {(r, k) for r, k in zip(*np.nonzero(~m.missing), strict=True)}
    assert present == set(seen)
    got = np.array([m.positions[r, k] for r, k in sorted(seen)])
    np.testing.assert_allclose(got, 0.001 * np.array([seen[i] for i in sorted(seen)]), atol=1e-12)


def test_gait_header_counts():
    m = read_trc(GAIT)
    assert (m.n_frames, m.rate, m.n_markers) == (487, 100.0, 105)
    assert m.labels[:3] == ["R.Shoulder", "R.Offset", "R.Elbow"]


@pytest.mark.parametrize("suffix", [".c3d", ".trc"])
def test_unnamed_markers_round_trip(tmp_path, suffix):
    m = read_trc(GAIT)
    out = tmp_path / f"gait{suffix}"
    (write_c3d if suffix == ".c3d" else write_trc)(m, out)
    back = (read_c3d if suffix == ".c3d" else read_trc)(out)
    assert back.labels == m.labels
    np.testing.assert_array_equal(back.missing, m.missing)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6, equal_nan=True)
