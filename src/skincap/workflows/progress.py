"""The progress callback of the frame-by-frame workflows (skin, track)."""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["FrameProgress", "frame_fractions"]

#: ``progress(frames_done, frames_total)``: frames done so far (fractional while a
#: batch of frames is under way) out of the take's frames, known only once the inputs
#: are read. The CLI draws it as a frame-counting bar; ``None`` means no reporting.
FrameProgress = Callable[[float, int], None]


def frame_fractions(progress: FrameProgress | None, frames: int) -> Callable[[float], None]:
    """Report 0 of ``frames`` to ``progress`` now; return the callback a library step takes.

    The library reports the fraction of the take done (0..1); the returned callback
    passes it on as ``progress(fraction * frames, frames)``. With ``progress`` None it
    does nothing.
    """
    if progress is not None:
        progress(0.0, frames)

    def advance(fraction: float) -> None:
        if progress is not None:
            progress(fraction * frames, frames)

    return advance
