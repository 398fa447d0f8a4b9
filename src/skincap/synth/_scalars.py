"""Checked scalar arguments with the house messages (``name: expected ..., got ...``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = ["check_positive", "check_nonnegative", "check_finite", "check_count"]


def check_positive(name: str, value: Any, *, allow_inf: bool = False) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a positive number, got {value!r}") from None
    if math.isnan(val) or val <= 0.0 or (math.isinf(val) and not allow_inf):
        raise ValidationError(f"{name}: expected a positive finite number, got {value!r}")
    return val


def check_nonnegative(name: str, value: Any, *, allow_inf: bool = False) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a number >= 0, got {value!r}") from None
    if math.isnan(val) or val < 0.0 or (math.isinf(val) and not allow_inf):
        raise ValidationError(f"{name}: expected a finite number >= 0, got {value!r}")
    return val


def check_finite(name: str, value: Any) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"{name}: expected a finite number, got {value!r}") from None
    if not math.isfinite(val):
        raise ValidationError(f"{name}: expected a finite number, got {value!r}")
    return val


def check_count(name: str, value: Any, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValidationError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValidationError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)
