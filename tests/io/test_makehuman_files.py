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


def test_mhw_vertex_index_of_2_pow_31_is_refused_without_allocating(tmp_path):
    """#13: an index of 2**31 made the summary allocate a dense (2**31, J) table (2.17 TiB)."""
    p = tmp_path / "big.mhw"
    p.write_text(json.dumps({"weights": {"a": [[2**31, 0.5], [0, 1.0]], "b": [[1, 1.0]]}}))
    with pytest.raises(
        FormatError, match="vertex index 2147483648 is not an integer in 0..2147483647"
    ):
        read_mhw(p)


def test_mhw_summary_is_sparse_in_the_vertex_index(tmp_path):
    """An index of 5e7 (51.8 GiB dense before) is summarised from its rows alone."""
    import tracemalloc

    p = tmp_path / "far.mhw"
    p.write_text(
        json.dumps({"weights": {"a": [[50_000_000, 0.25], [3, 1.0]], "b": [[50_000_000, 0.5]]}})
    )
    tracemalloc.start()
    s = read_mhw(p)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert s == {
        "kind": "weights",
        "bones": 2,
        "vertices": 2,
        "max_vertex": 50_000_000,
        "weight_sum_min": 0.75,
        "weight_sum_max": 1.0,
    }
    assert peak < 1 << 20


@pytest.mark.parametrize(
    "pairs, message",
    [
        ([[1.5, 1.0]], "vertex index 1.5 is not an integer"),
        ([[-1, 1.0]], "vertex index -1 is not an integer"),
        ([[0, 1e400]], "non-finite"),
        ([[0, 1.0], [2]], r"expected \[\[vertex, weight\]"),
        ("x", r"expected \[\[vertex, weight\]"),
    ],
)
def test_bad_mhw_rows(tmp_path, pairs, message):
    p = tmp_path / "bad.mhw"
    p.write_text(json.dumps({"weights": {"a": pairs}}).replace("Infinity", "1e400"))
    with pytest.raises(FormatError, match=message):
        read_mhw(p)
