"""Names of the hole-filling methods, importable without numpy (the CLI's help uses them)."""

from __future__ import annotations

from typing import Literal, get_args

FillMethod = Literal[
    "local_pca",
    "local_pca_weighted",
    "local_pca_missing",
    "local_pca_window",
    "linear",
    "pchip",
    "spline",
    "rigid",
    "rigid_weighted",
    "pca",
]
#: Every method :func:`skincap.cleanup.fill.fill_gaps` accepts.
FILL_METHODS: tuple[str, ...] = get_args(FillMethod)
