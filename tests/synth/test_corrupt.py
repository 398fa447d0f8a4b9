"""Real-world corruption of a labelled capture: spikes, label swaps, a rigid prop."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.synth.corrupt import (
    add_rigid_prop,
    corrupt_capture,
    inject_label_swaps,
    inject_spikes,
    neighbour_pairs,
)
from skincap.types import MarkerSet


def _take(frames: int = 120, markers: int = 8) -> MarkerSet:
    t = np.arange(frames)[:, None, None] / 100.0
    pos = np.linspace(0, 1, markers)[None, :, None] + np.concatenate([t, 0 * t, 0 * t], axis=2)
    return MarkerSet(pos, [f"M{i}" for i in range(markers)], 100.0, meta={"k": 1})


def test_spikes_have_the_asked_size_length_and_seed() -> None:
    take = _take()
    a, spikes = inject_spikes(take, 5, seed=3)
    b, again = inject_spikes(take, 5, seed=3)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(spikes, again)
    jump = np.linalg.norm(a.positions - take.positions, axis=-1)
    assert np.all((jump[spikes] >= 0.04) & (jump[spikes] <= 0.06))
    assert np.all(jump[~spikes] == 0)
    # 5 runs of 1-3 frames
    runs = np.diff(np.vstack([np.zeros((1, 8), int), spikes.astype(int)]), axis=0) == 1
    assert runs.sum() == 5 and 5 <= spikes.sum() <= 15
    assert a.meta == take.meta
    with pytest.raises(ValidationError):
        inject_spikes(_take(frames=10), 1)


def test_swaps_exchange_two_columns_over_one_run() -> None:
    take = _take()
    out, swaps = inject_label_swaps(take, [(1, 2)], seed=0)
    ((i, j, s, e),) = swaps
    assert (i, j) == (1, 2) and 5 <= e - s <= 40
    np.testing.assert_array_equal(out.positions[s:e, 1], take.positions[s:e, 2])
    np.testing.assert_array_equal(out.positions[:s], take.positions[:s])


def test_rigid_prop_keeps_its_shape() -> None:
    take = _take()
    out, prop = add_rigid_prop(take, n_markers=4, gaps=1, seed=1)
    assert prop == [8, 9, 10, 11] and out.labels[8] == "Prop:Marker1"
    pts = out.positions[:, prop]
    d = np.linalg.norm(pts[:, :, None] - pts[:, None], axis=-1)
    spread = np.nanmax(d, axis=0) - np.nanmin(d, axis=0)
    assert np.nanmax(spread) < 0.005  # rigid up to the 0.5 mm noise
    assert np.isnan(pts[..., 0]).sum() == 20


def test_neighbour_pairs_closest_first_disjoint_and_labelled_only() -> None:
    pos = np.zeros((40, 5, 3))
    pos[:, :, 0] = [0.0, 0.05, 0.5, 0.52, 0.53]  # pairs (0,1) at 5 cm, (3,4) at 1 cm
    take = MarkerSet(pos, ["A", "B", "C", "D", "*7"], 100.0)
    assert neighbour_pairs(take, 3) == [(2, 3), (0, 1)]  # *7 is a fragment, D is taken
    assert neighbour_pairs(take, 1) == [(2, 3)]
    assert neighbour_pairs(take, 2, max_distance=0.03) == [(2, 3)]


def test_corrupt_capture_combines_and_records() -> None:
    take = _take(frames=200, markers=6)
    take.positions[:] = np.array([0.0, 0.05, 0.4, 0.45, 0.8, 0.85])[:, None]
    out, truth = corrupt_capture(take, spikes=3, swaps=2, prop=True, seed=1)
    assert out.positions.shape == (200, 10, 3) and truth.prop == [6, 7, 8, 9]
    assert len(truth.swaps) == 2 and truth.spikes.shape == (200, 10)
    assert 3 <= truth.spikes.sum() <= 9
    with pytest.raises(ValidationError):
        corrupt_capture(take, swaps=4)
