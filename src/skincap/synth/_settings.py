"""Settings objects with the keyword API kept: ``f(..., noise_mm=0.2)`` beside ``settings=``."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from skincap.errors import ValidationError

__all__ = ["settings_with"]

S = TypeVar("S")


def settings_with(cls: type[S], settings: S | None, options: dict[str, Any], *, caller: str) -> S:
    """``settings`` (default ``cls()``) with the keyword ``options`` replaced.

    A name that is no field of ``cls`` is the ``TypeError`` Python gives for an
    unexpected keyword argument; the new object is checked by ``cls`` itself.
    """
    fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(options) - fields)
    if unknown:
        raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}")
    if settings is None:
        return cls(**options)
    if not isinstance(settings, cls):
        raise ValidationError(f"settings: expected a {cls.__name__}, got {type(settings).__name__}")
    return dataclasses.replace(settings, **options) if options else settings  # type: ignore[type-var]
