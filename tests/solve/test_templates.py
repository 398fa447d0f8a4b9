"""Hostile template files: one FormatError naming the file, never a raw decode error."""

from __future__ import annotations

from pathlib import Path

import pytest

from skincap.errors import FormatError
from skincap.solve import load_template


def test_template_file_not_utf8_is_a_format_error(tmp_path: Path) -> None:
    bad = tmp_path / "t.json"
    bad.write_bytes(b'{"markers": "\xb3\xff"}')
    with pytest.raises(FormatError, match=r"t\.json.*not UTF-8 text \(byte 13\)"):
        load_template(bad)


def test_template_file_nested_too_deeply_is_a_format_error(tmp_path: Path) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000)
    with pytest.raises(FormatError, match=r"deep\.json.*nested too deeply"):
        load_template(deep)
