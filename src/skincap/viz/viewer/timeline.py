"""The viewer's clock: which scene frame to show at a wall-clock time.

Pure logic, no viser: the server's playback thread asks :class:`PlaybackClock` for
the frame due now and draws it only when it changed, so playback runs in real time at
the capture's rate (frames are skipped, never slowed down, when the capture rate is
above the display rate).
"""

from __future__ import annotations

import math

from skincap.errors import ValidationError

__all__ = ["SPEEDS", "speed_label", "parse_speed", "PlaybackClock"]

#: Playback speeds offered in the GUI (multiples of real time).
SPEEDS = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0)


def speed_label(speed: float) -> str:
    """The dropdown text of a speed: ``0.25x``, ``1x``."""
    return f"{speed:g}x"


def parse_speed(label: str) -> float:
    """The speed of a dropdown text (inverse of :func:`speed_label`)."""
    try:
        value = float(label.rstrip("x"))
    except ValueError:
        raise ValidationError(f"speed: expected a text such as '1x', got {label!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise ValidationError(f"speed: expected a positive multiple of real time, got {label!r}")
    return value


class PlaybackClock:
    """Maps wall-clock seconds to a frame of a looping timeline.

    Parameters
    ----------
    rate : float, Hz
        Frames per second of the timeline (the scene's highest layer rate).
    n_frames : int
        Number of frames; playback wraps from the last to the first.
    speed : float, optional
        Multiple of real time (1 = the capture's own pace).

    Notes
    -----
    The clock is anchored at a (frame, wall time) pair; :meth:`anchor` re-anchors it
    when the user scrubs or the speed changes, so playback continues from there.
    """

    def __init__(self, rate: float, n_frames: int, *, speed: float = 1.0) -> None:
        rate = float(rate)
        if not math.isfinite(rate) or rate <= 0:
            raise ValidationError(f"rate: expected a positive frame rate in Hz, got {rate!r}")
        if int(n_frames) < 1:
            raise ValidationError(f"n_frames: expected at least 1 frame, got {n_frames!r}")
        self.rate = rate
        self.n_frames = int(n_frames)
        self.speed = float(speed)
        self._frame0 = 0
        self._wall0 = 0.0

    def anchor(self, frame: int, wall: float) -> None:
        """Frame ``frame`` is the one shown at wall-clock time ``wall`` (seconds)."""
        self._frame0 = int(frame) % self.n_frames
        self._wall0 = float(wall)

    def set_speed(self, speed: float, wall: float) -> None:
        """Change the speed at ``wall`` without jumping: re-anchor at the current frame."""
        self.anchor(self.frame_at(wall), wall)
        self.speed = float(speed)

    def frame_at(self, wall: float) -> int:
        """The frame due at wall-clock time ``wall`` seconds (wraps around)."""
        advanced = math.floor((wall - self._wall0) * self.speed * self.rate + 1e-9)
        return (self._frame0 + max(advanced, 0)) % self.n_frames

    def seconds_until_next(self, wall: float) -> float:
        """Wall-clock seconds from ``wall`` until the next frame is due (> 0)."""
        step = 1.0 / (self.rate * self.speed)
        elapsed = (wall - self._wall0) % step
        return max(step - elapsed, 1e-4)
