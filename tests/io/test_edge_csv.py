"""Edge-list CSV of marker labels (``skincap clean --surface edges.csv``)."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import FormatError
from skincap.io.edge_csv import read_edge_csv

LABELS = ["LASI", "RASI", "LPSI", "RPSI"]


def test_pairs_become_index_pairs_header_and_blank_lines_skipped(tmp_path):
    path = tmp_path / "edges.csv"
    path.write_text("a,b\nLASI,RASI\n\n RPSI , LPSI \nLASI,LPSI\n")
    np.testing.assert_array_equal(read_edge_csv(path, LABELS), [[0, 1], [3, 2], [0, 2]])
    assert read_edge_csv(path, LABELS).dtype == np.int64


@pytest.mark.parametrize(
    ("data", "what"),
    [
        (b"LASI,RASI\nLASI,XXXX\n", "line 2: unknown marker label 'XXXX'"),
        (b"LASI,RASI,LPSI\n", "two labels per line"),
        (b"a,b\n", "no edges"),
        (b"LASI,R\xffASI\n", "not UTF-8"),
    ],
)
def test_bad_edge_files_name_the_problem(tmp_path, data, what):
    path = tmp_path / "edges.csv"
    path.write_bytes(data)
    with pytest.raises(FormatError, match=what):
        read_edge_csv(path, LABELS)
