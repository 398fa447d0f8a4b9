"""Landmark files (``--landmarks FILE.json``): label -> template vertex index."""

from __future__ import annotations

import pytest

from skincap.errors import FormatError, OutputExistsError
from skincap.io.landmarks_json import read_landmarks, write_landmarks


def test_round_trip_keeps_labels_indices_and_order(tmp_path) -> None:
    landmarks = {"LKNE": 10452, "RKNE": 3711, "C7": 0, "D017": 9}
    path = tmp_path / "lm.json"
    write_landmarks(landmarks, path)
    got = read_landmarks(path)
    assert got == landmarks and list(got) == list(landmarks)
    with pytest.raises(OutputExistsError):
        write_landmarks(landmarks, path)
    write_landmarks({"A": 1}, path, force=True)
    assert read_landmarks(path) == {"A": 1}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[1, 2]", "expected a JSON object"),
        ('{"A": 1.5}', "vertex index"),
        ('{"A": -1}', "vertex index"),
        ('{"A": true}', "vertex index"),
        ('{"A": "7"}', "vertex index"),
        ('{"A": 1, "A": 2}', "appears twice"),
        ('{"": 1}', "empty marker label"),
        ('{"A": 1', "not valid JSON"),
        ("[" * 100000, "JSON"),
    ],
)
def test_malformed_files_are_format_errors(tmp_path, text: str, message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text, encoding="utf-8")
    before = path.read_bytes()
    with pytest.raises(FormatError, match=message) as info:
        read_landmarks(path)
    assert str(path) in str(info.value)
    assert path.read_bytes() == before


def test_missing_empty_and_binary_files(tmp_path) -> None:
    with pytest.raises(FormatError, match="no such file"):
        read_landmarks(tmp_path / "none.json")
    (tmp_path / "empty.json").write_bytes(b"")
    with pytest.raises(FormatError, match="empty"):
        read_landmarks(tmp_path / "empty.json")
    (tmp_path / "bin.json").write_bytes(b'{"A": \xff}')
    with pytest.raises(FormatError, match="UTF-8"):
        read_landmarks(tmp_path / "bin.json")
