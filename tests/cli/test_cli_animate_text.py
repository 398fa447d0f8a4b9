"""The held-out line of ``eval animate``: its figures printed to the same precision."""

from __future__ import annotations

from skincap.cli.animate import _worst_held_out_text


def test_worst_held_out_marker_is_not_rounded_below_the_p95():
    # a near-still take printed "p95 0.02 mm, max 0.0 mm": the max looked smaller
    held = {"worst": {"max_m": 4.4e-5, "marker": "D290", "frame": 9, "nearest_kept_m": 0.058}}
    text = _worst_held_out_text(held)
    assert text.startswith(", max 0.04 mm (D290 at frame 9, 58 mm")
    assert _worst_held_out_text({"worst": None}) == ""
