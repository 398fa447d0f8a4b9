"""A rope added to a real capture: real human motion with a rope whose truth is known.

The synthetic takes are kind to the rope tracker: a smooth synthetic hand and a rope
simulated with the model the tracker's predictions assume. Here the body is a real
labelled capture (its markers as recorded, with the take's own gaps), the rope is held
by the performer's real hand(s), found by marker name, and simulated with plain
position-based dynamics (:mod:`skincap.synth.rope_pbd`); dropouts, ghosts and noise
are added as a capture system makes them. The result is a
:class:`~skincap.synth.generate.SynthCapture` (no skin and no motion), so
:func:`skincap.workflows.synth_folder.write_synth_outputs` writes the same
``capture_points.csv`` and ``truth/`` files as for every synthetic take.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from skincap._arrays import Progress
from skincap.errors import SkincapWarning, ValidationError
from skincap.synth.generate import SynthCapture
from skincap.synth.reconstruction import (
    Fragments,
    Samples,
    fragment_columns,
    shuffled_point_cloud,
)
from skincap.synth.rope import RopeResult
from skincap.synth.rope_pbd import simulate_rope_pbd
from skincap.types import MarkerSet, PointCloud

__all__ = ["HAND_MARKER_NAMES", "find_hand_markers", "hand_path", "real_capture_with_rope"]

#: Marker names that sit on or next to each hand, best first, in the common sets:
#: CMU and Plug-in Gait (finger, two wrist bars), skincap's sparse synthetic set (the
#: same names), the 62-marker AML set (hand, radius, ulna), and generic names.
HAND_MARKER_NAMES = {
    "left": ("LFIN", "LWRA", "LWRB", "LHAND", "LRAD", "LULN", "LHND", "LWRI", "LWR", "LeftHand"),
    "right": ("RFIN", "RWRA", "RWRB", "RHAND", "RRAD", "RULN", "RHND", "RWRI", "RWR", "RightHand"),
    # one-arm sets (e.g. an upper-limb protocol) name the hand without a side
    "either": ("FIN", "INDEX", "WRIST", "WRA", "WRB", "HAND", "STYLU", "STYLR"),
}


def _bare(label: str) -> str:
    """A marker name without its subject prefix (``Male:LFIN`` -> ``LFIN``)."""
    return label.rsplit(":", 1)[-1].strip()


def find_hand_markers(labels: Sequence[str], side: Literal["left", "right", "either"]) -> list[int]:
    """Columns of the markers on one hand, found by name (subject prefixes ignored).

    Returns every column whose bare name (case-insensitive) is one of
    ``HAND_MARKER_NAMES[side]``; empty when the set has none.
    """
    wanted = {name.upper() for name in HAND_MARKER_NAMES[side]}
    return [i for i, label in enumerate(labels) if _bare(label).upper() in wanted]


def columns_named(labels: Sequence[str], names: Sequence[str]) -> list[int]:
    """Columns of ``names`` (full labels or bare names, case-insensitive), in that order."""
    full = {label.upper(): i for i, label in enumerate(labels)}
    bare: dict[str, list[int]] = {}
    for i, label in enumerate(labels):
        bare.setdefault(_bare(label).upper(), []).append(i)
    found = []
    for name in names:
        key = name.strip().upper()
        if key in full:
            found.append(full[key])
        elif len(bare.get(key, [])) == 1:
            found.append(bare[key][0])
        else:
            raise ValidationError(
                f"hands: no single marker named {name!r} (labels: {', '.join(labels[:12])}…)"
            )
    return found


def hand_path(markers: MarkerSet, columns: Sequence[int]) -> np.ndarray:
    """(T, 3) float64, metres: the centre of the hand's markers per frame, gaps bridged.

    The centre is the mean of the markers; in a frame where some are hidden it is the
    mean of the seen markers each moved by its median offset from the centre (so the
    hand does not jump when one of its markers drops out). Frames where none is seen
    are interpolated linearly in time (held at the ends); a hand never seen is a
    :class:`ValidationError`.
    """
    pos = markers.positions[:, list(columns)]  # (T, K, 3)
    seen = np.isfinite(pos).all(axis=2)  # (T, K)
    count = seen.sum(axis=1)  # (T,)
    if not count.any():
        names = ", ".join(markers.labels[c] for c in columns)
        raise ValidationError(f"hands: the hand markers ({names}) are never seen")
    whole = seen.all(axis=1)
    offset = np.zeros((pos.shape[1], 3))  # (K, 3) each marker's place around the centre
    if whole.any():
        offset = np.median(pos[whole] - pos[whole].mean(axis=1, keepdims=True), axis=0)
    total = np.where(seen[:, :, None], pos - offset, 0.0).sum(axis=1)  # (T, 3)
    frames = np.flatnonzero(count)
    mean = total[frames] / count[frames, None]
    t = np.arange(markers.n_frames)
    return np.stack([np.interp(t, frames, mean[:, a]) for a in range(3)], axis=1)


def _dropout_runs(
    rng: np.random.Generator, shape: tuple[int, int], fraction: float, mean_frames: float
) -> np.ndarray:
    """(T, N) bool: ``True`` where a sample is dropped, in runs of ~``mean_frames``."""
    t_n, n = shape
    if fraction <= 0 or t_n == 0 or n == 0:
        return np.zeros(shape, dtype=bool)
    starts = rng.random(shape) < fraction / mean_frames
    st, sn = np.nonzero(starts)
    lengths = np.minimum(rng.geometric(1.0 / mean_frames, st.size), t_n - st)
    run = np.repeat(np.arange(st.size), lengths)
    step = np.arange(run.size) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    dropped = np.zeros(shape, dtype=bool)
    dropped[st[run] + step, sn[run]] = True
    return dropped


def _warn_if_rope_doubled(doubled: int, n_rope: int) -> None:
    """Warn (:class:`~skincap.errors.SkincapWarning`, reported at the caller of
    :func:`real_capture_with_rope`) when more than a quarter of the ``n_rope`` rope
    markers are ``doubled`` (:func:`_doubled_markers`) in the first frame."""
    if 4 * doubled > n_rope:
        warnings.warn(
            f"rope: {doubled} of {n_rope} rope markers lie within half a "
            "spacing of another part of the rope in the first frame (the rope lies "
            "doubled, its held ends too low or too close: are the hands hand markers?); "
            "rope tracking cannot tell such markers apart",
            SkincapWarning,
            stacklevel=3,
        )


def _capture_summary(
    markers: MarkerSet,
    groups: list[list[int]],
    n_still: int,
    rope: str,
    rope_sim: RopeResult,
    length: float,
    floor: float | None,
    doubled: int,
    fragments: Fragments,
    n_ghosts: int,
    seen: np.ndarray,
    samples: Samples,
    *,
    dropout: float,
    noise_mm: float,
    seed: int,
) -> dict[str, Any]:
    """The ``summary`` of :func:`real_capture_with_rope`'s take: counts, the rope's
    length and floor height (metres), the hands' marker names (``groups``: each hand's
    column indices, left then right, as :func:`_hand_columns` returns them), the
    ``n_still`` held frames, the missing fraction of the N body markers in the
    (T, N + R) bool ``seen``, and the options that made it.
    """
    t_n, n_body = markers.n_frames, markers.n_markers
    return {
        "frames": int(t_n),
        "rate": float(markers.rate),
        "markers": int(n_body),
        "marker_set": "real",
        "source": str(markers.meta.get("path", markers.meta.get("source", ""))),
        "hands": [[markers.labels[c] for c in g] for g in groups[::-1]],
        "still_frames": n_still,
        "rope_markers": len(rope_sim.labels),
        "rope": rope,
        "rope_simulator": "pbd",
        "rope_length_m": float(length),
        "rope_max_length_error": float(rope_sim.meta["max_length_error"]),
        "rope_doubled_markers": int(doubled),
        "fragments": int(fragments.n_columns - n_ghosts),
        "labelled_fragments": int(fragments.labelled.sum()),
        "missing_fraction": int((~seen[:, :n_body]).sum()) / max(t_n * n_body, 1),
        "ghosts": int(n_ghosts),
        "points": int(samples.frame.size),
        "dropout": float(dropout),
        "noise_mm": float(noise_mm),
        "floor_m": floor,
        "seed": int(seed),
    }


def real_capture_with_rope(
    markers: MarkerSet,
    *,
    rope: Literal["whip", "jump"] = "whip",
    hands: Sequence[Sequence[str]] | None = None,
    rope_length: float | None = None,
    rope_markers: int | None = None,
    dropout: float = 0.03,
    ghosts_per_frame: float = 0.2,
    noise_mm: float = 0.5,
    hang_seconds: float = 0.5,
    seed: int = 0,
    progress: Progress | None = None,
) -> SynthCapture:
    """The real markers of a labelled capture with a simulated rope in the performer's hands.

    Parameters
    ----------
    markers : MarkerSet
        A labelled capture (T, N, 3), metres, Y up; NaN where it has gaps. Columns
        named ``*N`` (unlabelled fragments) are kept as body points named
        ``unlabelled_N``.
    rope : {"whip", "jump"}
        A rope held at one end by the right hand (``whip``; 1.1 m, 12 markers by
        default) or held by both hands (``jump``; 2.8 m, 22 markers).
    hands : list of one or two lists of str, optional
        Marker names of the left then the right hand; ``whip`` holds the rope in the
        last one given. By default they are found by name
        (:data:`HAND_MARKER_NAMES`).
    rope_length, rope_markers : optional
        Rope length (metres) and number of tape markers; a jump rope is made at least
        1.15 times the largest distance between the hands.
    dropout : float
        Fraction of rope and body samples additionally dropped, in runs of ~3 frames
        (never a rope marker in the first ``hang_seconds``).
    ghosts_per_frame : float
        Mean number of ghost tracks starting per frame, 1-5 cm from a body marker.
    noise_mm : float
        Gaussian noise of the rope's points, mm (the body's points are left as recorded).
    hang_seconds : float
        The opening window in which the rope hangs still and is kept whole (the tracker's
        initialisation, Porter §3.4): the performer holds the take's first pose this
        long before the take plays (frames prepended, the first frame's markers
        repeated), as a performer starts from a still pose.
    seed : int
        Every random choice derives from it.
    progress : callable(fraction, label), optional

    Returns
    -------
    SynthCapture
        ``skin`` and ``motion`` are None, ``marker_surface`` None. ``truth`` holds the
        body markers as recorded (NaN in their own gaps) then ``rope_00``…; frame
        ``summary["still_frames"]`` is the take's first frame.
    """
    _check_options(markers, rope, dropout, ghosts_per_frame, noise_mm, hang_seconds)
    n_still = int(round(hang_seconds * markers.rate))
    markers, body_labels = _first_pose_held(markers, n_still)
    t_n, n_body = markers.n_frames, markers.n_markers
    rng = np.random.default_rng(seed)

    def step(fraction: float, label: str) -> None:
        if progress is not None:
            progress(fraction, label)

    step(0.0, "hands")
    groups = _hand_columns(markers.labels, rope, hands)
    held = np.stack([hand_path(markers, g) for g in groups[::-1]], axis=1)  # (T, H, 3)
    step(0.1, "rope (PBD)")
    rope_sim, length, floor = _rope_in_hands(markers, held, rope, rope_length, rope_markers)
    doubled = _doubled_markers(rope_sim.markers[0], rope_sim.marker_param)
    _warn_if_rope_doubled(doubled, len(rope_sim.labels))
    step(0.8, "dropouts and ghosts")
    every = np.concatenate([markers.positions, rope_sim.markers], axis=1)  # (T, N + R, 3)
    seen, noisy = _what_cameras_see(
        rng, every, n_body, markers.rate, dropout, hang_seconds, noise_mm
    )
    samples, n_ghosts = _samples(rng, markers.positions, seen, noisy, ghosts_per_frame)
    meta = {"source": "skincap.synth.real_capture", "seed": seed, "up": "Y", "source_units": "m"}
    truth_labels = body_labels + rope_sim.labels
    capture, fragments, fragment_truth, points, point_truth = _delivered(
        rng, samples, n_ghosts, t_n, markers.rate, truth_labels, n_body, meta
    )
    truth = MarkerSet(every, truth_labels, markers.rate, meta=dict(meta))
    summary = _capture_summary(
        markers,
        groups,
        n_still,
        rope,
        rope_sim,
        length,
        floor,
        doubled,
        fragments,
        n_ghosts,
        seen,
        samples,
        dropout=dropout,
        noise_mm=noise_mm,
        seed=seed,
    )
    step(1.0, "done")
    return SynthCapture(
        capture=capture,
        points=points,
        point_truth=point_truth,
        fragment_truth=fragment_truth,
        truth=truth,
        marker_surface=None,
        skin=None,
        motion=None,
        rope=rope_sim,
        summary=summary,
    )


def _check_options(
    markers: MarkerSet,
    rope: str,
    dropout: float,
    ghosts_per_frame: float,
    noise_mm: float,
    hang_seconds: float,
) -> None:
    """Refuse the options and takes :func:`real_capture_with_rope` cannot work with."""
    if rope not in ("whip", "jump"):
        raise ValidationError(f"rope: expected 'whip' or 'jump', got {rope!r}")
    if not 0 <= dropout < 0.5 or ghosts_per_frame < 0 or noise_mm < 0 or hang_seconds < 0:
        raise ValidationError(
            "dropout must be in [0, 0.5), ghosts_per_frame, noise_mm and hang_seconds >= 0"
        )
    if markers.n_frames < 2 or markers.n_markers < 1:
        raise ValidationError(
            f"markers: need at least 2 frames and 1 marker, got {markers.positions.shape[:2]}"
        )


def _first_pose_held(markers: MarkerSet, n_still: int) -> tuple[MarkerSet, list[str]]:
    """The take with its first frame repeated ``n_still`` times before it, and the body
    labels of the truth (``*N`` fragments become ``unlabelled_N``)."""
    body_xyz = np.concatenate(
        [np.repeat(markers.positions[:1], n_still, axis=0), markers.positions], axis=0
    )  # (T, N, 3): the first pose held, then the take
    markers = MarkerSet(body_xyz, markers.labels, markers.rate, meta=markers.meta)
    body_labels = [
        f"unlabelled_{label[1:]}" if label.startswith("*") else label for label in markers.labels
    ]
    clash = [lab for lab in body_labels if lab.startswith("rope_") or lab == "ghost"]
    if clash:
        raise ValidationError(f"markers: label {clash[0]!r} is reserved for the rope truth")
    return markers, body_labels


def _hand_columns(
    labels: Sequence[str], rope: str, hands: Sequence[Sequence[str]] | None
) -> list[list[int]]:
    """The marker columns of the holding hands: left then right for a jump rope, the
    one hand for a whip; from ``hands`` (names) or found by name."""
    if hands is None:
        groups = [find_hand_markers(labels, s) for s in ("left", "right")]
        if rope == "whip":
            groups = [groups[1] or groups[0] or find_hand_markers(labels, "either")]
        if not all(groups):
            side = "a" if rope == "whip" else "the left and the right"
            raise ValidationError(
                f"hands: found no marker of {side} hand by name (looked for "
                f"{', '.join(HAND_MARKER_NAMES['right'])} and the L… names); give --hands"
            )
        return groups
    groups = [columns_named(labels, names) for names in hands]
    if rope == "whip":
        return groups[-1:]
    if len(groups) != 2:
        raise ValidationError("hands: a jump rope needs the left and the right hand")
    return groups


def _rope_in_hands(
    markers: MarkerSet,
    held: np.ndarray,
    rope: Literal["whip", "jump"],
    rope_length: float | None,
    rope_markers: int | None,
) -> tuple[RopeResult, float, float | None]:
    """The PBD rope held at ``held`` (T, H, 3) metres, its length (m) and the floor
    height (m; None for a take without a seen marker)."""
    if rope == "whip":
        length = 1.1 if rope_length is None else float(rope_length)
        n_rope = 12 if rope_markers is None else int(rope_markers)
    else:
        span = float(np.linalg.norm(held[:, 0] - held[:, 1], axis=1).max())
        length = max(2.8, 1.15 * span) if rope_length is None else float(rope_length)
        n_rope = 22 if rope_markers is None else int(rope_markers)
    body_y = markers.positions[..., 1]
    floor = float(np.nanmin(body_y)) - 0.02 if np.isfinite(body_y).any() else None
    # what does not hang free at the start lies on the floor, away from the body
    centre = (
        np.nanmean(markers.positions[0], axis=0)
        if np.isfinite(markers.positions[0]).any()
        else held[0].mean(axis=0)
    )
    away = held[0].mean(axis=0) - centre
    if rope == "jump":
        axis = held[0, 1] - held[0, 0]
        away -= axis * (away @ axis) / max(float(axis @ axis), 1e-12)
    rope_sim = simulate_rope_pbd(
        held,
        markers.rate,
        mode=rope,
        length=length,
        n_markers=n_rope,
        floor=floor,
        lay_direction=away,
    )
    return rope_sim, length, floor


def _doubled_markers(first: np.ndarray, param: np.ndarray) -> int:
    """How many rope markers (``first`` (R, 3) metres, at arc lengths ``param`` (R,))
    lie within half a spacing of a marker three or more places along the rope: a rope
    lying doubled on itself, whose arms no tracker can tell apart."""
    spacing = float(np.median(np.diff(param)))
    d = np.linalg.norm(first[:, None] - first[None], axis=2)  # (R, R)
    index = np.arange(first.shape[0])
    far = np.abs(index[:, None] - index[None]) >= 3
    return int(np.count_nonzero(np.where(far, d, np.inf).min(axis=1) < 0.5 * spacing))


def _what_cameras_see(
    rng: np.random.Generator,
    every: np.ndarray,
    n_body: int,
    rate: float,
    dropout: float,
    hang_seconds: float,
    noise_mm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(T, N + R) bool seen samples (runs dropped; the rope whole while it hangs) and
    the (T, N + R, 3) positions with the rope's noise added (the body's as recorded)."""
    t_n, n_all = every.shape[:2]
    seen = np.isfinite(every).all(axis=2) & ~_dropout_runs(rng, (t_n, n_all), dropout, 3.0)
    hang = np.arange(t_n) / rate < hang_seconds
    seen[np.ix_(hang, np.arange(n_body, n_all))] = True
    noisy = every.copy()
    noisy[:, n_body:] += rng.normal(scale=noise_mm / 1000.0, size=noisy[:, n_body:].shape)
    return seen, noisy


def _samples(
    rng: np.random.Generator,
    body: np.ndarray,
    seen: np.ndarray,
    noisy: np.ndarray,
    ghosts_per_frame: float,
) -> tuple[Samples, int]:
    """Every delivered point: one per seen sample, grouped in runs of seen frames per
    marker, then ghost tracks 1-5 cm from a body marker ``body`` (T, N, 3) metres.
    Returns the samples and the number of ghost tracks that have a point."""
    t_n, n_all = seen.shape
    n_body = body.shape[1]
    n_ghost = int(rng.poisson(ghosts_per_frame * t_n))
    g_start = rng.integers(0, t_n, n_ghost)
    g_len = np.minimum(rng.geometric(0.5, n_ghost), t_n - g_start)
    g_anchor = rng.integers(0, n_body, n_ghost)
    g_dir = rng.normal(size=(n_ghost, 3))
    g_dir *= rng.uniform(0.01, 0.05, (n_ghost, 1)) / np.linalg.norm(g_dir, axis=1, keepdims=True)
    starts = seen & ~np.vstack([np.zeros((1, n_all), dtype=bool), seen[:-1]])
    run_of = (np.cumsum(starts.T.ravel()).reshape(n_all, t_n) - 1).T  # (T, N + R)
    st, sn = np.nonzero(seen)
    n_runs = int(starts.sum())
    gk = np.repeat(np.arange(n_ghost), g_len)
    gt = g_start[gk] + np.arange(gk.size) - np.repeat(np.cumsum(g_len) - g_len, g_len)
    g_xyz = body[gt, g_anchor[gk]] + g_dir[gk]
    g_ok = np.isfinite(g_xyz).all(axis=1)  # a ghost beside a marker that is not there: none
    gk, gt, g_xyz = gk[g_ok], gt[g_ok], g_xyz[g_ok]
    # group ids: the runs, then the ghost tracks that kept a point, numbered densely
    _, group = np.unique(np.concatenate([run_of[st, sn], n_runs + gk]), return_inverse=True)
    frame = np.concatenate([st, gt])
    truth = np.concatenate([sn, np.full(gt.size, -1)])
    xyz = np.concatenate([noisy[st, sn], g_xyz])
    return Samples(frame, truth, group.reshape(-1), xyz, n_runs), int(np.unique(gk).size)


def _delivered(
    rng: np.random.Generator,
    samples: Samples,
    n_ghosts: int,
    n_frames: int,
    rate: float,
    truth_labels: list[str],
    n_body: int,
    meta: dict[str, Any],
) -> tuple[MarkerSet, Fragments, dict[str, str], PointCloud, np.ndarray]:
    """The samples as the capture's fragment columns and as the shuffled un-indexed
    cloud, each with its truth (labels ``truth_labels`` of the body then the rope).

    Returns the capture, its fragments, the true label per fragment column, the cloud
    and the (M,) str true label per point (``ghost`` for ghosts).
    """
    fragments = fragment_columns(
        samples, n_ghosts, n_frames, len(truth_labels), truth_labels[:n_body]
    )
    s_col = fragments.column[samples.group]
    capture_xyz = np.full((n_frames, fragments.n_columns, 3), np.nan)
    capture_xyz[samples.frame, s_col] = samples.noisy
    capture = MarkerSet(capture_xyz, fragments.labels, rate, meta=dict(meta))
    names = np.array(truth_labels + ["ghost"], dtype=object)
    fragment_truth = {
        label: str(names[truth])
        for label, truth in zip(fragments.labels, fragments.majority, strict=True)
    }
    points, truth_index = shuffled_point_cloud(
        samples, s_col, fragments.labels, n_frames, rate, rng
    )
    return capture, fragments, fragment_truth, points, names[truth_index].astype(str)
