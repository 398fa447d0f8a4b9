"""The progress callback of the frame-by-frame workflows (skin, track)."""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["FrameProgress"]

#: ``progress(frames_done, frames_total)``: frames done so far (fractional while a
#: batch of frames is under way) out of the take's frames, known only once the inputs
#: are read. The CLI draws it as a frame-counting bar; ``None`` means no reporting.
FrameProgress = Callable[[float, int], None]
