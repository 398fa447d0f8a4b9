"""Hostile template files: one FormatError naming the file, never a raw decode error."""

from __future__ import annotations

import json
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


def _cmu41_with(edit) -> dict:  # type: ignore[no-untyped-def]
    """The built-in cmu41 template, as JSON data, with ``edit(segments)`` applied."""
    from skincap.data import path as data_path

    data = json.loads(data_path("solve_template_cmu41.json").read_text("utf-8"))
    edit(data["segments"])
    return data


@pytest.mark.parametrize(
    ("edit", "fragment"),
    [  # each was a TypeError/KeyError traceback, a silent misreading or blamed the take
        (lambda s: s[3].update(markers=5), "'thorax': 'markers' must be a list of marker labels"),
        (lambda s: s[3].update(markers="LKNE"), "'markers' must be a list"),
        (lambda s: s[3].update(via="abc"), "'via' must be a list of joint names"),
        (lambda s: s[3].update(fixed_joints=[1, 2]), "'fixed_joints' must be a list"),
        (lambda s: s[3].update(fixed_joints=[{"name": "X", "at": "1"}]), "'fixed_joints'"),
        (lambda s: s[3]["centre"]["prior"].update({"from": 12}), "prior 'from': expected a list"),
        (lambda s: s[3]["centre"]["prior"].update(towards=[3]), "prior 'towards': expected"),
        (lambda s: s[3]["centre"]["prior"].update(fraction="x"), "'fraction' must be a finite"),
        (lambda s: s[3]["centre"]["prior"].update(harrington="up"), "'left' or 'right'"),
        (lambda s: s[3].update(stiffness=float("inf")), "'stiffness' must be a positive number"),
        (lambda s: s[3].update(end=[[]]), "'thorax' end: expected a list of marker labels"),
        (lambda s: s[0].update(origin=[["LFWT", 1.0]]), "'pelvis' origin: expected a list"),
        (lambda s: s.clear(), "'segments' is empty"),
        # no markers anywhere: the solve said "it expects " followed by nothing
        (
            lambda s: [seg.update(markers=[]) for seg in s],
            "no segment lists any 'markers'",
        ),
    ],
)
def test_template_fields_of_the_wrong_kind_are_a_format_error_naming_the_file(
    tmp_path: Path, edit, fragment: str
) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "mine.json"
    bad.write_text(json.dumps(_cmu41_with(edit)))
    with pytest.raises(FormatError, match=r"mine\.json") as info:
        load_template(bad)
    assert fragment in str(info.value)


def test_a_hinge_flexion_of_numbers_and_a_harrington_prior_without_asis_are_refused(
    tmp_path: Path,
) -> None:
    def hinge(s: list) -> None:  # type: ignore[type-arg]
        knee = next(seg for seg in s if seg.get("centre") and seg["centre"]["kind"] == "hinge")
        knee["centre"]["flexion"] = [1, 2, 3]

    def harrington(s: list) -> None:  # type: ignore[type-arg]
        hip = next(seg for seg in s if seg.get("centre") and "harrington" in seg["centre"]["prior"])
        del hip["centre"]["prior"]["asis"]

    for edit, fragment in ((hinge, "flexion: expected a list"), (harrington, "needs 'asis'")):
        bad = tmp_path / "mine.json"
        bad.write_text(json.dumps(_cmu41_with(edit)))
        with pytest.raises(FormatError, match=fragment):
            load_template(bad)
