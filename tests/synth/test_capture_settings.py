"""CaptureSettings: today's defaults, checked values, the keyword API kept."""

from __future__ import annotations

import dataclasses

import pytest

from skincap.errors import ValidationError
from skincap.synth._settings import settings_with
from skincap.synth.capture_settings import CaptureSettings


def test_defaults_are_the_studio_of_the_papers() -> None:
    s = CaptureSettings()
    assert (s.markers, s.rope, s.n_cameras, s.n_cameras_up, s.min_cameras) == (
        "dense", "none", 12, 2, 2,
    )  # fmt: skip
    assert (s.noise_mm, s.marginal_dropout, s.confusion_distance) == (0.5, 0.1, 0.025)
    assert (s.confusion_share, s.swap_rate, s.ghost_rate, s.ghost_frames) == (0.5, 0.05, 0.1, 3.0)
    assert (s.bulge, s.jiggle, s.breathing) == (1.0, 1.0, 1.0)
    assert (s.rope_length, s.rope_marker_spacing, s.extra_radius, s.facing_limit_deg) == (
        2.8, 0.12, 0.01, 80.0,
    )  # fmt: skip


def test_every_field_has_a_docstring() -> None:
    import ast
    import inspect

    import skincap.synth.capture_settings as module

    tree = ast.parse(inspect.getsource(module))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "CaptureSettings")
    documented = {
        prev.target.id
        for prev, nxt in zip(cls.body, cls.body[1:], strict=False)
        if isinstance(prev, ast.AnnAssign)
        and isinstance(nxt, ast.Expr)
        and isinstance(nxt.value, ast.Constant)
        and isinstance(nxt.value.value, str)
    }
    assert documented == {f.name for f in dataclasses.fields(CaptureSettings)}


def test_settings_are_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        CaptureSettings().noise_mm = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "bad",
    [
        {"markers": "medium"},
        {"rope": "lasso"},
        {"noise_mm": -0.1},
        {"marginal_dropout": 1.5},
        {"confusion_share": 2.0},
        {"swap_rate": -0.01},
        {"ghost_rate": -1.0},
        {"ghost_frames": 0.5},
        {"min_cameras": 0},
        {"facing_limit_deg": 0.0},
    ],
)
def test_bad_values_are_refused_by_name(bad: dict) -> None:
    (name,) = bad
    with pytest.raises(ValidationError, match=name):
        CaptureSettings(**bad)


def test_keywords_replace_fields_of_the_given_settings() -> None:
    base = CaptureSettings(rope="jump", noise_mm=0.0)
    s = settings_with(CaptureSettings, base, {"swap_rate": 0.2}, caller="f")
    assert (s.rope, s.noise_mm, s.swap_rate) == ("jump", 0.0, 0.2)
    assert settings_with(CaptureSettings, base, {}, caller="f") is base
    assert settings_with(CaptureSettings, None, {}, caller="f") == CaptureSettings()
    with pytest.raises(TypeError, match="f\\(\\) got an unexpected keyword argument 'noise'"):
        settings_with(CaptureSettings, None, {"noise": 1.0}, caller="f")
    with pytest.raises(ValidationError, match="settings"):
        settings_with(CaptureSettings, {"noise_mm": 1.0}, {}, caller="f")  # type: ignore[arg-type]
