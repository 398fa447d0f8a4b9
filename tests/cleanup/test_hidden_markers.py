"""Markers hidden in the reference frame get a label; a rope's markers do not."""

from __future__ import annotations

import warnings

import numpy as np
from cleanup_takes import dense_jumprope_take
from scipy.spatial.transform import Rotation

from skincap.cleanup.hidden import find_hidden_markers
from skincap.cleanup.merge import merge_fragments
from skincap.cleanup.pipeline import clean_markers
from skincap.cleanup.settings import CleanSettings, FillSettings, HiddenSettings, SmoothSettings
from skincap.cleanup.surface import build_marker_surface
from skincap.errors import SkincapWarning
from skincap.types import MarkerSet


def _sheet(chain: bool) -> tuple[MarkerSet, int]:
    """A 7x7 sheet bending and turning; marker 24 (the centre) is hidden in frames
    0-9 and comes back as fragment *1. With ``chain``, three points 12 cm apart in a
    row ride with the sheet 6 cm off its edge (a rope held still beside the body)."""
    g = np.stack(np.meshgrid(np.arange(7), np.arange(7), indexing="ij"), -1).reshape(-1, 2)
    rest = np.column_stack([g * 0.05, np.zeros(49)])
    frames = 80
    rot = Rotation.from_rotvec(np.outer(np.linspace(0, 1.2, frames), [0.2, 1, 0.3])).as_matrix()
    move = np.outer(np.linspace(0, 0.8, frames), [1, 0, 0.5])[:, None]
    pos = np.einsum("tij,kj->tki", rot, rest) + move
    rng = np.random.default_rng(0)
    pos += rng.normal(0, 3e-4, pos.shape)
    hidden = 24
    frag = np.full((frames, 1, 3), np.nan)
    frag[10:, 0] = pos[10:, hidden]
    cols = [np.delete(pos, hidden, axis=1), frag]
    labels = [f"M{i:02d}" for i in range(49) if i != hidden] + ["*1"]
    if chain:
        row = np.array([[0.03, -0.06, 0.02], [0.15, -0.06, 0.02], [0.27, -0.06, 0.02]])
        rope = np.einsum("tij,kj->tki", rot, row) + move
        rope[:5] = np.nan  # not in the reference frame either
        cols.append(rope)
        labels += ["*2", "*3", "*4"]
    return MarkerSet(positions=np.concatenate(cols, axis=1), labels=labels, rate=100.0), 48


def test_a_marker_hidden_in_the_reference_frame_is_found() -> None:
    markers, n = _sheet(chain=False)
    surface = build_marker_surface(markers.positions[:, :n], reference_frame=0)
    merged, report = merge_fragments(markers, surface)
    assert report.merged == 0  # no labelled marker owns it
    assert find_hidden_markers(merged, surface) == [[n]]
    # too short a fragment is not enough evidence
    assert find_hidden_markers(merged, surface, settings=HiddenSettings(min_frames=80)) == []


def test_a_chain_riding_with_the_skin_is_not_skin() -> None:
    markers, n = _sheet(chain=True)
    surface = build_marker_surface(markers.positions[:, :n], reference_frame=0)
    merged, _ = merge_fragments(markers, surface)
    groups = find_hidden_markers(merged, surface)
    found = {str(merged.labels[c]) for grp in groups for c in grp}
    assert "*1" in found and not found & {"*2", "*3", "*4"}


def test_clean_labels_hidden_markers_against_the_truth() -> None:
    take = dense_jumprope_take()
    truth = take.fragment_truth
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        cleaned, report = clean_markers(
            take.capture,
            settings=CleanSettings(
                fill=FillSettings(method="linear"), smooth=SmoothSettings(enabled=False)
            ),
            fragment_truth=truth,
        )
        _, off = clean_markers(
            take.capture,
            settings=CleanSettings(
                recover_hidden=False,
                fill=FillSettings(method="linear"),
                smooth=SmoothSettings(enabled=False),
            ),
        )
    hidden = report.hidden
    known = {truth.get(lab, lab) for lab in take.capture.labels if not lab.startswith("*")}
    assert hidden.new_markers >= 2 and off.hidden.new_markers == 0
    for new, frags in hidden.markers.items():
        true = {truth[f] for f in frags}
        # one true body marker per new label, one hidden in the reference frame
        assert len(true) == 1
        (label,) = true
        assert label not in known and label != "ghost" and not label.startswith("rope_")
        assert new in cleaned.labels[: report.surface.markers]
    assert hidden.recovered == hidden.new_markers and hidden.wrong_markers == 0
    # the new columns follow the true trajectory where measured
    names = list(take.truth.labels)
    for new, frags in hidden.markers.items():
        col = list(cleaned.labels).index(new)
        err = np.linalg.norm(
            cleaned.positions[:, col] - take.truth.positions[:, names.index(truth[frags[0]])],
            axis=1,
        )
        measured = ~cleaned.invented[:, col] & np.isfinite(err)
        assert measured.sum() >= 10 and np.max(err[measured]) < 5e-3
