"""Real-world corruption of a labelled capture: spikes, label swaps and a rigid prop.

The camera model (:mod:`skincap.synth.cameras`) gives Gaussian noise, occlusion and
fragments; real takes also have samples that jump a few centimetres for a frame or
three, neighbouring markers that exchange labels for a while, and rigid props (a
wheelchair, a bat) whose markers move with no body around them. These functions put
them into any labelled :class:`~skincap.types.MarkerSet` and say exactly where, so a
cleanup can be scored on what it flagged, repaired and left alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skincap.errors import ValidationError
from skincap.types import MarkerSet

__all__ = [
    "CorruptionTruth",
    "add_rigid_prop",
    "corrupt_capture",
    "inject_label_swaps",
    "inject_spikes",
    "neighbour_pairs",
]


@dataclass
class CorruptionTruth:
    """Where the corruption went.

    Attributes
    ----------
    spikes : (T, N) bool
        Samples displaced by a spike.
    swaps : list of (i, j, start, end)
        Columns ``i`` and ``j`` exchanged over frames ``[start, end)``.
    prop : list of int
        Columns of the rigid prop's markers.
    """

    spikes: np.ndarray
    swaps: list[tuple[int, int, int, int]] = field(default_factory=list)
    prop: list[int] = field(default_factory=list)

    @property
    def swapped(self) -> np.ndarray:
        """(T, N) bool: samples that carry the other marker's label."""
        out = np.zeros_like(self.spikes)
        for i, j, s, e in self.swaps:
            out[s:e, i] = out[s:e, j] = True
        return out


def _rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def inject_spikes(
    markers: MarkerSet,
    count: int,
    *,
    size: tuple[float, float] = (0.04, 0.06),
    frames: tuple[int, int] = (1, 3),
    seed: int | np.random.Generator | None = 0,
) -> tuple[MarkerSet, np.ndarray]:
    """Make ``count`` markers jump ``size`` metres for 1-3 frames (real-world spikes).

    Each spike moves one marker's present samples over ``frames`` consecutive frames
    by one random direction of length uniform in ``size``. Spikes are at least 10
    frames apart on a marker and never at the take's first or last 5 frames.

    Parameters
    ----------
    markers : MarkerSet, positions (T, N, 3) metres
    count : int >= 0
    size : (low, high) metres
    frames : (shortest, longest) run length in frames
    seed : int or Generator

    Returns
    -------
    markers : MarkerSet
        A copy with the spikes.
    spikes : (T, N) bool
        The displaced samples.
    """
    if count < 0:
        raise ValidationError(f"count: expected >= 0, got {count!r}")
    rng = _rng(seed)
    p = markers.positions.copy()
    t, n, _ = p.shape
    if t < 20 and count:
        raise ValidationError(f"a take of {t} frames is too short for spikes (needs 20)")
    spikes = np.zeros((t, n), dtype=bool)
    placed, tries = 0, 0
    while placed < count and tries < 100 * max(count, 1):
        tries += 1
        c = int(rng.integers(n))
        length = int(rng.integers(frames[0], frames[1] + 1))
        s = int(rng.integers(5, t - 5 - length))
        near = spikes[max(s - 10, 0) : s + length + 10, c]
        if near.any() or np.isnan(p[s : s + length, c, 0]).any():
            continue
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        p[s : s + length, c] += direction * rng.uniform(*size)
        spikes[s : s + length, c] = True
        placed += 1
    if placed < count:
        raise ValidationError(f"room for only {placed} of {count} spikes")
    out = MarkerSet(
        p,
        list(markers.labels),
        markers.rate,
        meta=dict(markers.meta),
        residuals=markers.residuals,
        invented=markers.invented,
    )
    return out, spikes


def inject_label_swaps(
    markers: MarkerSet,
    pairs: list[tuple[int, int]],
    *,
    length: tuple[int, int] = (5, 40),
    seed: int | np.random.Generator | None = 0,
) -> tuple[MarkerSet, list[tuple[int, int, int, int]]]:
    """Exchange the labels of each marker pair over a random run of frames.

    Parameters
    ----------
    markers : MarkerSet
    pairs : list of (i, j)
        Columns to swap (real swaps happen between markers a few centimetres apart).
    length : (shortest, longest) frames
    seed : int or Generator

    Returns
    -------
    markers : MarkerSet
        A copy with the swaps (positions and residuals exchanged).
    swaps : list of (i, j, start, end)
    """
    rng = _rng(seed)
    p = markers.positions.copy()
    res = None if markers.residuals is None else markers.residuals.copy()
    t = p.shape[0]
    swaps = []
    for i, j in pairs:
        n_frames = int(rng.integers(length[0], length[1] + 1))
        if t < n_frames + 10:
            raise ValidationError(f"a take of {t} frames is too short for a {n_frames}-frame swap")
        s = int(rng.integers(5, t - 5 - n_frames))
        e = s + n_frames
        p[s:e, [i, j]] = p[s:e, [j, i]]
        if res is not None:
            res[s:e, [i, j]] = res[s:e, [j, i]]
        swaps.append((int(i), int(j), s, e))
    out = MarkerSet(
        p,
        list(markers.labels),
        markers.rate,
        meta=dict(markers.meta),
        residuals=res,
        invented=markers.invented,
    )
    return out, swaps


def add_rigid_prop(
    markers: MarkerSet,
    *,
    n_markers: int = 4,
    size: float = 0.25,
    offset: float = 1.0,
    gaps: int = 2,
    gap_length: int = 20,
    seed: int | np.random.Generator | None = 0,
) -> tuple[MarkerSet, list[int]]:
    """Append the markers of a rigid prop that moves on its own, away from the body.

    The prop is ``n_markers`` points within a ``size``-metre box, its centre
    ``offset`` metres beside the body's mean position, turning and gliding smoothly
    on its own (no body marker moves with it). ``gaps`` runs of ``gap_length`` frames
    are removed from random prop markers.

    Returns
    -------
    markers : MarkerSet
        The body's columns then the prop's, labelled ``Prop:Marker<k>``.
    prop : list of int
        The prop's columns.
    """
    from scipy.spatial.transform import Rotation

    rng = _rng(seed)
    p = markers.positions
    t, n, _ = p.shape
    shape = rng.uniform(-size / 2, size / 2, (n_markers, 3))
    time = np.arange(t) / markers.rate
    angle = np.stack(
        [0.8 * np.sin(2 * np.pi * 0.4 * time), 0.3 * np.sin(2 * np.pi * 0.7 * time), 0.5 * time],
        axis=1,
    )
    rot = Rotation.from_rotvec(angle).as_matrix()  # (T, 3, 3)
    centre = np.nanmean(p, axis=(0, 1)) + np.array([offset, 0.0, 0.0])
    path = centre + np.stack(
        [0.3 * np.sin(2 * np.pi * 0.2 * time), 0 * time, 0.4 * np.sin(2 * np.pi * 0.25 * time)],
        axis=1,
    )
    prop = np.einsum("tij,kj->tki", rot, shape) + path[:, None, :]
    prop = prop + rng.normal(0.0, 0.0005, prop.shape)
    for _ in range(gaps):
        k = int(rng.integers(n_markers))
        s = int(rng.integers(5, max(6, t - 5 - gap_length)))
        prop[s : s + gap_length, k] = np.nan
    labels = list(markers.labels) + [f"Prop:Marker{k + 1}" for k in range(n_markers)]
    res = None
    if markers.residuals is not None:
        res = np.concatenate(
            [markers.residuals, np.where(np.isnan(prop[..., 0]), np.nan, 0.0)], axis=1
        )
    inv = None
    if markers.invented is not None:
        inv = np.concatenate([markers.invented, np.zeros((t, n_markers), dtype=bool)], axis=1)
    out = MarkerSet(
        np.concatenate([p, prop], axis=1),
        labels,
        markers.rate,
        meta=dict(markers.meta),
        residuals=res,
        invented=inv,
    )
    return out, list(range(n, n + n_markers))


def neighbour_pairs(
    markers: MarkerSet, count: int, *, max_distance: float = 0.12
) -> list[tuple[int, int]]:
    """Up to ``count`` disjoint pairs of labelled markers that stand close together.

    Real label swaps happen between markers a few centimetres apart, so pairs are
    taken closest first among labelled columns (not ``*N`` fragments) whose median
    distance over the frames where both are seen is at most ``max_distance`` metres.

    Returns
    -------
    list of (i, j) column indices, i < j, no column twice.
    """
    labelled = [k for k, label in enumerate(markers.labels) if not label.startswith("*")]
    if count <= 0 or len(labelled) < 2:
        return []
    p = markers.positions[:, labelled]  # (T, L, 3)
    d = np.linalg.norm(p[:, :, None] - p[:, None, :], axis=-1)  # (T, L, L)
    seen = ~np.isnan(d)
    both = seen.sum(axis=0)
    med = np.full(both.shape, np.inf)
    ok = both >= max(10, p.shape[0] // 4)
    if ok.any():
        with np.errstate(all="ignore"):
            med_all = np.nanmedian(np.where(seen, d, np.nan)[:, ok], axis=0)
        med[ok] = med_all
    np.fill_diagonal(med, np.inf)
    order = np.argsort(med, axis=None)
    pairs: list[tuple[int, int]] = []
    used: set[int] = set()
    for flat in order:
        a, b = np.unravel_index(flat, med.shape)
        if med[a, b] > max_distance or len(pairs) == count:
            break
        if a < b and a not in used and b not in used:
            pairs.append((labelled[a], labelled[b]))
            used.update((int(a), int(b)))
    return pairs


def corrupt_capture(
    markers: MarkerSet,
    *,
    spikes: int = 0,
    swaps: int = 0,
    prop: bool = False,
    seed: int | np.random.Generator | None = 0,
) -> tuple[MarkerSet, CorruptionTruth]:
    """Put real-world corruption into a capture: spikes, label swaps, a rigid prop.

    Swaps go first (between :func:`neighbour_pairs`), then the prop's columns are
    appended, then ``spikes`` spikes of 4-6 cm for 1-3 frames land on random
    columns (the prop's included).

    Raises
    ------
    ValidationError
        When the take has no room for what is asked (too short, too few close pairs).
    """
    if swaps < 0:
        raise ValidationError(f"swaps: expected >= 0, got {swaps!r}")
    rng = _rng(seed)
    out = markers
    swap_runs: list[tuple[int, int, int, int]] = []
    if swaps:
        pairs = neighbour_pairs(out, swaps)
        if len(pairs) < swaps:
            raise ValidationError(
                f"swaps: only {len(pairs)} pairs of labelled markers stand within 12 cm, "
                f"{swaps} asked"
            )
        out, swap_runs = inject_label_swaps(out, pairs, seed=rng)
    prop_columns: list[int] = []
    if prop:
        out, prop_columns = add_rigid_prop(out, seed=rng)
    spiked = np.zeros(out.positions.shape[:2], dtype=bool)
    if spikes:
        out, spiked = inject_spikes(out, spikes, seed=rng)
    return out, CorruptionTruth(spiked, swap_runs, prop_columns)
