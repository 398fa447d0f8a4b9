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


@pytest.fixture(params=["numpy", "numba"])
def steps(request):  # type: ignore[no-untyped-def]
    """The step module of each backend: the step tests run on both."""
    if request.param == "numpy":
        from skincap.tracking import _steps_numpy

        return _steps_numpy
    pytest.importorskip("numba")
    from skincap.tracking import _steps_numba

    return _steps_numba


def blank_state(cloud, spacing, *, gamma: float = 0.03, **settings):  # type: ignore[no-untyped-def]
    """(TrackState, StepParams) for hand-made step tests: M = len(spacing) + 1 traces,
    every result and carried array zero (positions), -1 (indices) or False, all traces
    steady; ``settings`` are TrackSettings fields."""
    from skincap.tracking.init import RopeInit
    from skincap.tracking.settings import TrackSettings
    from skincap.tracking.state import start_tracking

    spacing = np.asarray(spacing, dtype=np.float64)
    m = spacing.size + 1
    init = RopeInit(np.full(m, -1), np.zeros((m, 3)), spacing, gamma, 10)
    state, params = start_tracking(cloud, init, TrackSettings(**settings))
    state.body[:] = False
    state.temp_count[:] = 0
    state.invented[:] = False
    return state, params
