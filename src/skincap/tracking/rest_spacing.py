"""Rest spacings of the rope's links from the initialisation window (beyond the thesis).

The mean chord between neighbouring traces over the window is each link's rest
spacing ``l_j``, corrected where the window shows the rope folded between two markers
(a short isolated chord: its rest spacing is the median chord) or bending a corner
inside a link (the chord lengthened by the rope its corner holds). Moved out of
:mod:`skincap.tracking.init`, which uses :func:`_rest_spacing`.
"""

from __future__ import annotations

import numpy as np

#: A window chord shorter than this many median chords is a folded link.
_FOLDED = 0.75


def _turn_angles(mean: np.ndarray) -> np.ndarray:
    """(M,) radians: the turn of the chain at each marker of ``mean`` (M, 3) metres,
    the angle between its incoming and outgoing links (0 at the two ends)."""
    d = np.diff(mean, axis=0)  # (M - 1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", d[:-1], d[1:]).clip(-1.0, 1.0)
    return np.concatenate([[0.0], np.arccos(cos), [0.0]])


def _bent_link_length(chord: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """(M - 1,) metres: each window chord lengthened by the bend inside its link.

    A rope that bends sharply between two markers (a jump rope's arm meeting the
    floor) joins them with a chord shorter than the rope between them. The turn the
    link itself makes is the chain's turn at its two markers less the turns at the
    markers beyond them (a smooth curve turns alike at every marker: no excess; a
    corner inside the link turns only at its own two markers); a corner of turn θ
    between two straight legs is at most ``chord / cos(θ / 2)`` of rope (equal legs).
    The result is at most the median chord (a link does not hold more rope than a
    typical one) and never shorter than its chord.
    """
    turn = _turn_angles(mean)  # (M,)
    outer = np.concatenate([[0.0], turn[:-2]]) + np.concatenate([turn[2:], [0.0]])
    own = np.clip(turn[:-1] + turn[1:] - outer, 0.0, np.radians(170.0))  # (M - 1,)
    return np.clip(chord / np.cos(own / 2.0), chord, np.maximum(chord, np.median(chord)))


def _rest_spacing(
    chord: np.ndarray, mean: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rest spacings ``l_j`` (M - 1,) metres from the mean chords of the window, and
    the (M - 1,) bool mask of the folded links.

    A chord shorter than ``_FOLDED`` times the median chord, and than ``_FOLDED`` times
    the shorter of its neighbouring chords, is a rope folded between its two markers
    (the bottom of a jump rope lying doubled on the floor), not a short piece of rope:
    its rest spacing is the median chord, so the link may open to the tape spacing once
    the rope lifts. A run of gradually shorter chords (markers bunched where the rope
    curves) keeps its chords. (Raising every chord below the median to
    it, for the bends onto the floor too, was measured worse on the whole CMU take:
    F1 0.990 -> 0.975.) With the markers' mean positions ``mean`` (M, 3), a link the
    rope turns a corner in (an arm bending onto the floor) gets the rope its corner
    holds (:func:`_bent_link_length`), at most the median chord.
    """
    typical = float(np.median(chord))
    # a fold is one short link between ordinary ones; a run of short chords is a rope
    # bunched or curving smoothly (its markers' spacing changes gradually), kept as is
    before = np.concatenate([[np.nan], chord[:-1]])
    after = np.concatenate([chord[1:], [np.nan]])
    beside = np.fmin(before, after)
    isolated = ~(chord >= _FOLDED * beside)  # True also with no neighbour (NaN)
    folded = (chord < _FOLDED * typical) & isolated
    base = chord if mean is None else _bent_link_length(chord, mean)
    return np.where(folded, typical, base), folded
