"""Ordering the rope's markers along the rope (initialisation, issue #15).

A jump rope held by both hands sags into a U whose bottom lies doubled on the floor:
its arms pass closer than the tape spacing and one link is folded. The order must
still follow the rope, a hidden marker must become one inserted trace, and a ghost
beside a marker must not become a trace.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.tracking.chain_order import chain_length, off_chain_points, shortest_open_path
from skincap.tracking.init import init_rope
from skincap.types import PointCloud

SPACING = 0.12
RATE = 120.0
WINDOW = 60  # init_rope's still window at 120 Hz


def _u_rope(arm_gap: float = 0.07, seed: int = 0, *, fold: bool = False) -> np.ndarray:
    """(N, 3) markers every 12 cm of rope along a U held at both ends: down from the
    left hand, out along the floor, round a hairpin whose arms run ``arm_gap`` apart for
    40 cm, back along the floor and up to the right hand; turned about Y and moved at
    random. With ``fold`` the arms close to 2 cm at the hairpin and two markers lie
    either side of it, 6 cm of rope from its apex: the rope lies doubled between them."""
    tip = 0.01 if fold else arm_gap / 2  # hairpin radius
    mid = -0.1 + arm_gap / 2
    turn = np.linspace(np.pi, 0.0, 40)
    hairpin = [mid, 0.0, 0.7] + tip * np.stack([np.cos(turn), 0 * turn, np.sin(turn)], axis=1)
    right = -0.1 + arm_gap
    corners = [
        np.array([[-0.3, 0.72, 0.0], [-0.3, 0.0, 0.0], [-0.1, 0.0, 0.2], [-0.1, 0.0, 0.6],
                  [mid - tip, 0.0, 0.7]]),
        hairpin,
        np.array([[mid + tip, 0.0, 0.7], [right, 0.0, 0.6], [right, 0.0, 0.2], [0.17, 0.0, 0.0],
                  [0.17, 0.72, 0.0]]),
    ]  # fmt: skip
    dense = np.concatenate(
        [np.linspace(a, b, 200) for piece in corners for a, b in itertools.pairwise(piece)]
    )
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    apex = s[np.argmax(dense[:, 2])]
    first = (apex - SPACING / 2) % SPACING if fold else 0.0
    at = np.arange(first, s[-1], SPACING)
    rope = np.stack([np.interp(at, s, dense[:, c]) for c in range(3)], axis=1)
    rng = np.random.default_rng(seed)
    turn_y = Rotation.from_euler("y", rng.uniform(0, 360), degrees=True)  # keep Y up
    return turn_y.apply(rope) + rng.uniform(-1, 1, 3) * [1.0, 0.0, 1.0]


def _still_cloud(
    rope: np.ndarray, extra: np.ndarray | None = None, extra_frames: int = WINDOW, seed: int = 0
) -> tuple[PointCloud, int]:
    """The rope (rows 0..N-1 of every frame), 30 body points 2 m beside it, then the
    points ``extra`` (K, 3) seen in the first ``extra_frames`` frames, all standing
    still (0.5 mm noise). Returns the cloud and the number of frame 0's points."""
    rng = np.random.default_rng(seed)
    body = np.column_stack([rng.uniform(3.0, 3.4, 30), rng.uniform(0.0, 1.7, 30), np.zeros(30)])
    frames = []
    for t in range(WINDOW + 20):
        pts = [rope, body] + ([extra] if extra is not None and t < extra_frames else [])
        frame = np.concatenate(pts) + rng.normal(scale=5e-4, size=(sum(p.shape[0] for p in pts), 3))
        frames.append(frame)
    offsets = np.concatenate([[0], np.cumsum([f.shape[0] for f in frames])])
    return PointCloud(np.concatenate(frames), offsets, RATE), frames[0].shape[0]


def _is_rope_order(order: np.ndarray, n: int) -> bool:
    return order.tolist() in (list(range(n)), list(range(n))[::-1])


@pytest.mark.parametrize(("seed", "fold"), [(0, False), (1, False), (2, True), (3, True)])
def test_u_rope_whose_arms_pass_within_a_spacing_is_ordered_along_the_rope(
    seed: int, fold: bool
) -> None:
    rope = _u_rope(seed=seed, fold=fold)
    n = rope.shape[0]
    far = np.linalg.norm(rope[:, None] - rope[None], axis=2)[np.triu_indices(n, 2)]
    assert far.min() < SPACING  # the arms (or the fold) come within one spacing
    shuffle = np.random.default_rng(seed).permutation(n)
    order = shortest_open_path(rope[shuffle])
    assert _is_rope_order(shuffle[order], n)


def test_init_orders_the_u_rope_and_gives_the_fold_the_tape_spacing() -> None:
    rope = _u_rope(fold=True)
    n = rope.shape[0]
    cloud, _ = _still_cloud(rope)
    shuffled = np.random.default_rng(3).permutation(n)  # the user's selection, any order
    init = init_rope(cloud, markers=shuffled)
    # the rope is rows 0..n-1 of every frame before shuffling: indices are rope numbers
    assert init.n_markers == n and init.meta["inserted"] == 0
    assert _is_rope_order(init.indices, n)
    # the folded link's rest spacing is the tape's, not its 4 cm chord; the others
    # are their chords, or the rope a bend between their markers holds: the tape's
    chords = np.linalg.norm(np.diff(rope[init.indices], axis=0), axis=1)
    folded = chords < 0.5 * SPACING
    assert folded.sum() == 1 == init.meta["folded"]
    np.testing.assert_allclose(init.spacing[folded], SPACING, atol=0.002)
    assert np.all(init.spacing[~folded] >= chords[~folded] - 0.002)
    np.testing.assert_allclose(init.spacing[~folded], SPACING, rtol=0.03)


def test_init_inserts_one_trace_for_a_hidden_marker_and_none_elsewhere() -> None:
    rope = _u_rope()
    n = rope.shape[0]
    hidden = 3  # on the left arm, unseen through the whole window
    cloud, _ = _still_cloud(np.delete(rope, hidden, axis=0))
    init = init_rope(cloud, markers=np.arange(n - 1))
    assert init.n_markers == n and init.meta["inserted"] == 1
    seen_numbers = np.where(np.arange(n - 1) >= hidden, np.arange(n - 1) + 1, np.arange(n - 1))
    got = np.where(init.indices >= 0, seen_numbers[np.maximum(init.indices, 0)], -1)
    expected = np.where(np.arange(n) == hidden, -1, np.arange(n))
    assert got.tolist() in (expected.tolist(), expected[::-1].tolist())
    where = int(np.flatnonzero(init.indices < 0)[0])
    assert np.linalg.norm(init.positions[where] - rope[hidden]) < 0.01


@pytest.mark.parametrize("lasting", [False, True])
def test_a_ghost_selected_with_the_rope_gets_no_trace(lasting: bool) -> None:
    # selected with the rope (as a box would): a ghost 2 cm beside marker 12 seen for
    # 3 frames (the window discards it), or a stray point between markers 5 and 6 seen
    # throughout (it is off the rope's chain: both its links are short)
    rope = _u_rope()
    n = rope.shape[0]
    ghost = (rope[5] + rope[6]) / 2 + [0.0, 0.0, 0.01] if lasting else rope[12] + [0, 0.02, 0]
    cloud, n0 = _still_cloud(rope, ghost[None], extra_frames=WINDOW + 20 if lasting else 3)
    init = init_rope(cloud, markers=np.append(np.arange(n), n0 - 1))  # the rope and the ghost
    assert init.n_markers == n and init.meta["inserted"] == 0
    assert _is_rope_order(init.indices, n)
    assert init.meta["off_chain"] == int(lasting) and init.meta["discarded"] == int(not lasting)


def test_shortest_open_path_small_cases_and_errors() -> None:
    assert shortest_open_path(np.zeros((0, 3))).size == 0
    assert shortest_open_path(np.ones((1, 3))).tolist() == [0]
    line = np.array([[0.0, 0, 0], [0.3, 0, 0], [0.1, 0, 0], [0.2, 0, 0]])
    assert shortest_open_path(line).tolist() in ([0, 2, 3, 1], [1, 3, 2, 0])
    with pytest.raises(ValidationError, match="points"):
        shortest_open_path(np.array([[0.0, np.nan, 0.0], [1, 1, 1], [2, 2, 2]]))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 7))
def test_shortest_open_path_is_the_shortest(seed: int, n: int) -> None:
    points = np.random.default_rng(seed).normal(size=(n, 3))
    order = shortest_open_path(points)
    assert sorted(order.tolist()) == list(range(n))
    best = min(chain_length(points, np.array(p)) for p in itertools.permutations(range(n)))
    assert chain_length(points, order) <= best + 1e-9


def test_off_chain_points() -> None:
    line = np.arange(8)[:, None] * np.array([[SPACING, 0.0, 0.0]])
    ghost = (line[4] + line[5]) / 2 + [0.0, 0.01, 0.0]
    chain = np.insert(line, 5, ghost, axis=0)  # ... 3, 4, ghost, 5, ...
    np.testing.assert_array_equal(np.flatnonzero(off_chain_points(chain, SPACING)), [5])
    # a fold has one short link between two markers: nobody is off the chain
    fold = np.array(
        [[0, 0.36, 0], [0, 0.24, 0], [0, 0.12, 0], [0, 0, 0], [0.03, 0, 0], [0.03, 0.12, 0]]
    )
    assert not off_chain_points(fold, SPACING).any()


def _bunched_chain() -> np.ndarray:
    """A chain whose chords shrink gradually to a third and grow back (markers bunched
    where a rope curves, as in the synthetic jump scene's frame 0)."""
    chords = SPACING * np.concatenate([np.linspace(1.0, 0.3, 12), np.linspace(0.3, 1.0, 12)])
    return np.column_stack([np.concatenate([[0.0], np.cumsum(chords)]), np.zeros(25), np.zeros(25)])


def test_a_bunched_chain_keeps_every_point() -> None:
    chain = _bunched_chain()
    assert not off_chain_points(chain, float(np.median(np.diff(chain[:, 0])))).any()
    # a hidden marker's double link does not make its neighbours look like ghosts
    line = np.delete(np.arange(10)[:, None] * np.array([[SPACING, 0.0, 0.0]]), 7, axis=0)
    assert not off_chain_points(line, SPACING).any()


def test_init_keeps_a_bunched_rope_s_chords_as_its_rest_spacing() -> None:
    chain = _bunched_chain()
    cloud, _ = _still_cloud(chain)
    init = init_rope(cloud, markers=np.arange(chain.shape[0]))
    assert init.n_markers == chain.shape[0]
    assert init.meta["off_chain"] == 0 and init.meta["folded"] == 0 and init.meta["inserted"] == 0
    np.testing.assert_allclose(init.spacing, np.abs(np.diff(chain[init.indices, 0])), atol=0.002)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_init_gives_a_link_bent_onto_the_floor_the_rope_its_corner_holds(seed: int) -> None:
    # the arms of a U turn 90° onto the floor (and the floor arms 45° twice) between
    # two markers: the chord across a corner is shorter than the 12 cm of rope
    rope = _u_rope(arm_gap=0.3, seed=seed)
    chords = np.linalg.norm(np.diff(rope, axis=0), axis=1)
    assert chords.min() < 0.93 * SPACING  # the scene has sharply bent links
    cloud, _ = _still_cloud(rope)
    init = init_rope(cloud, markers=np.arange(rope.shape[0]))
    assert init.n_markers == rope.shape[0] and init.meta["inserted"] == 0
    # every link at the tape spacing: within 3 % (the corner model's equal legs)
    np.testing.assert_allclose(init.spacing, SPACING, rtol=0.03)
