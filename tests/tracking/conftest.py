"""Synthetic rope takes shared by the tracking tests (generated once per session)."""

from __future__ import annotations

import numpy as np
import pytest

FRAMES = 200


def _take(rope: str):  # type: ignore[no-untyped-def]
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=3000)
    motion = build_motion(body, "jumprope", frames=FRAMES)
    return generate_capture(body, motion, markers="dense", rope=rope, seed=0)


@pytest.fixture(scope="session")
def jump_take():  # type: ignore[no-untyped-def]
    return _take("jump")


@pytest.fixture(scope="session")
def whip_take():  # type: ignore[no-untyped-def]
    return _take("whip")


def rope_truth_indices(take) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Indices of the rope's points among frame 0's points."""
    cloud = take.points
    labels = take.point_truth[: cloud.offsets[1]].astype(str)
    return np.nonzero(np.char.startswith(labels, "rope_"))[0]
