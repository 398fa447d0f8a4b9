"""The frame-progress adapter of the skin and track workflows."""

from __future__ import annotations

from skincap.workflows.progress import frame_fractions


def test_frame_fractions_starts_at_zero_and_reports_frames_done() -> None:
    calls: list[tuple[float, int]] = []
    advance = frame_fractions(lambda done, total: calls.append((done, total)), 240)
    assert calls == [(0.0, 240)]  # announced before the first library call
    advance(0.25)
    advance(1.0)
    assert calls == [(0.0, 240), (60.0, 240), (240.0, 240)]


def test_frame_fractions_without_a_callback_does_nothing() -> None:
    frame_fractions(None, 240)(0.5)  # no error, nothing to report to
