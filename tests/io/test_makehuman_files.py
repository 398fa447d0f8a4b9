from __future__ import annotations

import json

import pytest

from skincap.errors import FormatError
from skincap.io.makehuman import read_mhskel, read_mhw


def test_mhskel_summary_matches_file(data_dir):
    s = read_mhskel(data_dir / "makehuman_default.mhskel")
    raw = json.loads((data_dir / "makehuman_default.mhskel").read_text())
    assert (s["kind"], s["bones"], s["joints"], s["root"]) == (
        "rig",
        len(raw["bones"]),
        len(raw["joints"]),
        "root",
    )


def test_mhw_summary_matches_manifest(data_dir):
    s = read_mhw(data_dir / "makehuman_default_weights.mhw")
    assert (s["kind"], s["bones"], s["vertices"]) == ("weights", 139, 19158)
    assert s["weight_sum_min"] == pytest.approx(0.32, abs=0.005)
    assert s["weight_sum_max"] == pytest.approx(1.67, abs=0.005)


@pytest.mark.parametrize(
    "content, message",
    [
        ("[1, 2]", "JSON object"),
        ('{"bones": {}, "joints": {}}', "bones"),
        ('{"bones": {"a": {"head": "x", "tail": "y"}}, "joints": {"x": [0]}}', "tail"),
        ('{"bones"', "invalid JSON"),
    ],
)
def test_bad_mhskel(tmp_path, content, message):
    p = tmp_path / "bad.mhskel"
    p.write_text(content)
    with pytest.raises(FormatError, match=message):
        read_mhskel(p)


def test_bad_mhw(tmp_path):
    p = tmp_path / "bad.mhw"
    p.write_text('{"weights": {"a": [[0, -1]]}}')
    with pytest.raises(FormatError, match="negative weight"):
        read_mhw(p)
    p.write_text('{"weights": {"a": [[0, 1, 2]]}}')
    with pytest.raises(FormatError):
        read_mhw(p)
