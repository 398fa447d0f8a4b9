"""Hypothesis strategy for unit quaternions near the hard cases (shared by geometry tests)."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

SQ = np.sqrt(0.5)
# identity, 180 degrees about each axis and a diagonal (w = 0), tiny angles, their negatives
SPECIAL = np.array(
    [
        [0, 0, 0, 1],
        [1, 0, 0, 0],
        [0, 1, 0, 0],
        [0, 0, 1, 0],
        [SQ, SQ, 0, 0],
        [0, 0, SQ, SQ],
        [1e-9, 0, 0, 1],
        [0, 1e-12, 1, 0],
        [0, 0, 0, -1],
        [-1, 0, 0, 0],
    ],
    dtype=float,
)
SPECIAL = SPECIAL / np.linalg.norm(SPECIAL, axis=1, keepdims=True)


@st.composite
def unit_quats(draw: st.DrawFn) -> np.ndarray:
    """Unit quaternions (x, y, z, w): random, special, or special perturbed by 1e-7; maybe negated."""
    kind = draw(st.sampled_from(["random", "special", "near"]))
    if kind == "special":
        q = SPECIAL[draw(st.integers(0, len(SPECIAL) - 1))].copy()
    else:
        raw = draw(arrays(np.float64, 4, elements=st.floats(-1, 1, allow_nan=False)))
        if np.linalg.norm(raw) < 1e-3:
            raw = np.array([0.0, 0.0, 0.0, 1.0])
        q = raw
        if kind == "near":
            q = SPECIAL[draw(st.integers(0, len(SPECIAL) - 1))] + 1e-7 * raw
    q = q / np.linalg.norm(q)
    return -q if draw(st.booleans()) else q
