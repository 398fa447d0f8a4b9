"""One short synthetic dense jump-rope take shared by the cleanup tests (built once per session)."""

from __future__ import annotations

from functools import lru_cache
from typing import Any


@lru_cache(maxsize=1)
def dense_jumprope_take() -> Any:
    """150 frames of the dense (Park-Hodgins) marker set, jump rope, seed 0 (~15 s)."""
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=6000)
    motion = build_motion(body, "jumprope", frames=150)
    return generate_capture(body, motion, markers="dense", rope="jump", seed=0)
