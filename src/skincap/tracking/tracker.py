"""Rope marker tracking through an un-indexed point cloud (Porter 2012, §3.5).

Every frame, each rope trace looks for the point nearest its predicted position
within γ. The prediction is the marker's own velocity (eqs. 3.1-3.2,
``V = m^{i-1} + v^{i-1} Δt``) while the trace is measured; when that finds nothing,
or while the trace is in a gap, it is ``F = α Ṽ + (1 - α) N`` (eq. 3.6) with ``Ṽ``
from the velocities of the nearest measured neighbours on each side (eq. 3.3, ``β``
weighting the nearer neighbour more), ``N`` by midpoint displacement from the three
nearest traces on the measured side (eqs. 3.4-3.5) and ``α = 1 /`` the number of
consecutive temporary markers. Found nothing, the trace gets a temporary (invented)
marker at its prediction.

Beyond the thesis:

* Conflicts are resolved per frame globally: the traces and the points within γ of
  their predictions are matched one-to-one minimising the summed distance
  (:func:`~skincap.tracking.init.gated_assignment`), so two traces never take one
  point.
* A missing marker with measured markers on both sides is predicted (and, if still
  unseen, invented) on the smooth curve through the measured markers at its rest
  arc length (:mod:`skincap.tracking.curve`); the thesis' ``F`` is kept for runs of
  missing markers at the ends of the rope, and it is projected to the rest spacing
  ``l_j`` from its measured side, so invented markers keep the rope's length.
* A hidden marker between measured markers is also carried from where it was last
  seen by the rigid motion of its nearest measured neighbours, blended with the curve
  by how rigidly they moved (:func:`~skincap.tracking.curve.carry_last_seen`): a bend
  that lies still or travels with the hand keeps its shape, which the curve alone
  cuts. The run at a *free* end of the rope, one with no point but the rope's
  within 20 cm when last seen (:func:`~skincap.tracking.curve.end_is_free`; a whip's
  tip, where F misses the swing by 15-25 cm), is dragged as a loose end instead
  (:func:`~skincap.tracking.curve.drag_free_ends`): it keeps its last measured
  velocity and is pulled onto its rest spacing only by a taut link (carried with its
  neighbours, a tip lying on the floor turns with the rope beside it); a held end
  keeps F (carried beyond its neighbours, an end turning with the hand strays).
* A hidden *held* end is carried by its hand instead of F (:mod:`skincap.tracking._hand_numpy`):
  the points the rope did not take within 20 cm of the end when it was last measured
  are followed frame by frame (unambiguous nearest point within γ at constant
  velocity), and the end moves by their rigid motion (Kabsch; their mean displacement
  when fewer than three are left or they do not move rigidly); it is searched for
  there too, and while it is hidden those anchors are body points, which a trace back
  from a gap does not take (a hand marker beside the held end). A carry that would
  stretch the rope beyond what ``reject_overstretched`` allows from the marker measured
  nearest the end (measured in every frame since the end was) is refused, and F kept:
  a wrist turning under the handle does not swing the end off the rope. An end that
  swings about its grip (a foot stamping) lies off the rigid carry and off its own V:
  in the frame after it was measured it is searched for at the free point nearest the
  carry when that lies within ``wide_gate`` γ of both, within the rope's reach of the
  nearest measured marker, and continues no point of the frame before that the rope
  did not take (a hand marker) nor moves rigidly with body points. An end hidden for
  longer is not: the hand's markers coming back from their dropouts lie beside it.
* After more than ``maxTempMarkers`` consecutive temporary markers a trace is *lost*,
  unless a marker measured within two markers along the rope pins it (a marker hidden
  between seen neighbours is repaired however long its gap: a limit in time would
  drop a well-constrained marker of a 50 Hz take after 50 frames): it goes on being
  predicted the same way internally and flagged in
  :attr:`RopeTrack.lost_frames`, and it keeps looking for a point within γ of that
  prediction; taking one ends the loss. What is reported for a lost trace is NaN, and
  every invented sample reported is bounded by the rope's length
  (:mod:`skincap.tracking.physical`).

* A measured trace not found within γ of V gets a second chance in the same frame:
  V corrected by the prediction errors of the traces found (interpolated along the
  rope), searched within ``2 γ`` but only at its rest spacing ``l_j`` (± γ) from a
  measured neighbour — the fast middle of a turning rope accelerates far beyond γ
  per frame, and the errors of neighbouring markers are alike. The same wider,
  length-constrained gate is used for the curve/F searches.
* A point that continues a point of the previous frame that the rope did not take,
  moving slower than the rope by more than γ, is a body marker beside a fast rope:
  traces coming back from a gap, and inner traces, do not take it.
* A trace coming back from a gap does not take, in the wide gate, a point that lies
  nearer V of a trace measured in the frame before and not found yet (within
  ``wide_gate`` γ of it) than its own prediction: that marker moved a little more than
  γ and its hidden neighbour, predicted on the curve, would otherwise take its point
  and the two swap.
* Body chains: every point of frame 0 the rope does not take is a body point (the user
  selected the rope there); a point that continues a body point of the previous frame
  (the only point within ``γ / 3`` of where that point's velocity takes it, and that
  point the only one near it, and no trace, measured or hidden, predicted near it) is
  a body point too: a hidden trace's prediction keeps a chain from passing onto its
  marker's point when a body marker beside it drops out. A trace coming back from a
  gap (or never seen) does not take a body point. This keeps the traces of markers
  hidden in the initialisation window, invented on the curve beside the legs, off the
  leg markers while the rope hangs still and no motion test can tell the two apart.
* The zipper: a run of two or more invented markers inside the rope (a whip's wave,
  a rope lifting off the floor) is badly bridged by the curve, so the markers at the
  run's ends are also searched where the measured side continues: bent as it bends
  (quadratic extrapolation through three measured markers, else straight on as N),
  at the rest spacing, inward one marker per side and round
  (``zipper_predictions``). A held end hidden since an earlier frame that its hand
  carries is looked for at the carry instead, within γ, in the same one-to-one
  assignment (``zip_with_hand``): a rope bent at the hand leaves the end off the
  straight-on continuation, where a leg marker beside the hand lies within the wide gate.
* Traces that break the rope's length (two measured markers farther apart than the
  rope between them, neighbours more than 0.4 γ beyond their rest spacing) are
  resolved by keeping the largest consistent chain (a trace that slipped onto its
  neighbour's marker is dropped), markers on points that move rigidly with body
  points counting against a chain (a body marker keeps its distance to two or more
  points the rope does not take over the last quarter second, none within γ of the
  prediction of a trace hidden in the previous frame and not found yet: rope markers
  hidden together move together; a rope marker does not): the body-like side of a stretched link goes. A trace coming back from a gap
  does not take such a point either. A trace that sits more than ``2 γ`` off the
  curve through the other measured markers moves to a free point on that curve (it
  had taken a body point while its marker was hidden).

* Re-acquisition (``reacquire_on_shell``): traces still unknown after every search
  above (a hand reversing at 10 cm per frame misses every prediction by more than γ;
  a hanging end swung while hidden) are found as Porter's initialisation finds the
  rope: followed out from the measured markers, marker by marker, each taking the free
  point on the shell at its rest length around its measured neighbour nearest to where
  the previous frame's link puts it (within one rest length: the link turned less
  than 60°), else (a trace back from a gap) the free point within γ of where its link
  lay when both were last measured, however short the chord (a slack end folded on
  the floor beside a still hand, which F puts at the rest spacing, 5-9 cm off); with
  nothing measured the two end traces are seeded first at V. Body
  points, points moving rigidly with body points and points seen beside the trace's
  own marker in the frames before (a hand marker beside the held end) are refused.
  Each pass seats the traces' proposals nearest-first, not in rope order: in a rope
  lying doubled, a point back from a dropout is reached both by its own trace's link
  and, within one rest length, by a hidden neighbour's, and goes to the nearer.
* Bridging (``bridge_hidden_runs``): a run of one or two inner traces hidden since an
  earlier frame, between measured markers that are not the rope's ends, takes the
  chain of free points whose links are at most their rest length (+ ``adjacent_stretch
  γ``) minimising the distance to the predictions plus each link's shortness, when
  the next chain costs γ more and no point of it was, where the trace was last
  measured, a point the rope did not take beside its marker. A rope landing on the
  floor stops dead and folds: the hidden markers lie still a few centimetres from
  their predictions at chords more than γ short, which every search above refuses.
* A trace measured again after temporary markers takes the velocity ṽ of its
  neighbours measured in both frames (eq. 3.3), not its jump from the invented
  position (which would predict it that far on, and miss it, the next frame), when
  its point is confirmed: within γ of its temporary marker moved by ṽ, or repeating
  its link to a measured neighbour as last measured. Otherwise it keeps its jump:
  given ṽ, a wrong point (a body marker beside a slow rope) stays within γ of every
  next prediction and is kept.
* A run of traces matched one marker along the rope (``unshift_chain``: a whip jerked
  lengthwise by about a spacing in a frame keeps its shape, so every trace of the run
  takes its neighbour's marker) moves back one marker when its end trace lies more
  than 2 γ from its own prediction and a free point lies within γ of that prediction
  at the end link's rest length.
* A swinging rope (``match_measured_best``): when some steady trace's last change of
  velocity moves its prediction by more than ``swing_gate γ``, the steady traces are
  matched both at V and at the accelerated prediction ``V + (m^{t-1} - 2 m^{t-2} +
  m^{t-3})`` (``accelerated_prediction``) and the match that finds more traces is kept
  (nearer its predictions on a tie, V on an exact tie); when the two give a trace
  different points, the one whose disputed traces lie nearer their predictions is kept
  (the assignment finds as many traces as it can, and beside a doubled rope's other
  arm the wrong prediction finds more by handing a trace that arm's point). A jump rope's bottom turning
  20-45 cm a frame is missed by V by 2-4 γ, and the traces slip a marker a frame; a
  hand jerking at 50 Hz is missed by the acceleration instead.
* A link's chord may be shorter than its spacing (a slack rope lying folded), never
  longer: a short chord refuses only candidates the wide gate reaches beyond γ.
* An inner trace missing for ``lone_after`` frames or more takes, in the
  re-acquisition, the only free point on its measured neighbour's shell whatever its
  direction (a rope end dragged along the floor while hidden folds its links far
  from the previous frame's).
* Each link's rest length (``link_rest``) is the longest chord accepted between its
  two measured markers, at most ``stretch`` times the spacing of the still window,
  whose hanging rope is slack (8.2 cm chords for 9.2 cm of rope), or times the median
  spacing when the link was measured at both ends in the frame before too: the
  neighbour limit of the stretch rule is measured from it.

The steps are written twice, with the same names and signatures: in NumPy
(:mod:`skincap.tracking._steps_numpy`, the reference) and compiled with numba
(:mod:`skincap.tracking._steps_numba`); both read and write one
:class:`~skincap.tracking.state.TrackState` and take the run's constants as one
:class:`~skincap.tracking.state.StepParams`, built from
:class:`~skincap.tracking.settings.TrackSettings`. :func:`track_rope` runs either.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincap import backends
from skincap.backends import numba_available, resolve_backend
from skincap.errors import SkincapWarning, ValidationError
from skincap.tracking.init import RopeInit
from skincap.tracking.physical import bound_invented
from skincap.tracking.settings import TrackSettings
from skincap.tracking.state import start_tracking
from skincap.types import MarkerSet, MarkerTrajectories, PointCloud

__all__ = ["RopeTrack", "TrackSettings", "track_rope"]


@dataclass(eq=False)
class RopeTrack(MarkerTrajectories):
    """The tracked rope.

    Attributes
    ----------
    positions : (T, M, 3) float64, metres
        Rope markers in order along the rope; invented where unseen, within the
        distance the rope's length allows from the measured markers (10 % stretch,
        :mod:`skincap.tracking.physical`); NaN where the trace is lost.
    invented : (T, M) bool
        True where the sample is a temporary marker rather than a measured point.
    point_index : (T, M) int64
        Index into ``cloud.points`` of the point each trace took; -1 where invented.
        No point appears twice.
    lost_frames : (T, M) bool
        True where the trace had more than ``max_temp_markers`` consecutive
        temporary markers and no measured marker within two markers along the rope
        pinned it, or no place the rope's length allows: ``positions`` is NaN
        there (the tracker goes on predicting it internally, so it can be found again).
    labels : list of M str
        ``rope_00``, ``rope_01``….
    rate : float, Hz
    init : RopeInit
    meta : dict
        The cloud's meta (units, up axis, first frame) for writers.
    """

    positions: np.ndarray
    invented: np.ndarray
    point_index: np.ndarray
    lost_frames: np.ndarray
    labels: list[str]
    rate: float
    init: RopeInit
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def lost(self) -> np.ndarray:
        """(M,) bool: True for traces lost at some frame."""
        return self.lost_frames.any(axis=0)

    def rope_points_mask(self, cloud: PointCloud) -> np.ndarray:
        """(cloud.points.shape[0],) bool: True for the points the rope took."""
        mask = np.zeros(cloud.points.shape[0], dtype=bool)
        taken = self.point_index[self.point_index >= 0]
        if taken.size and taken.max() >= mask.size:
            raise ValidationError("cloud: not the point cloud this rope was tracked in")
        mask[taken] = True
        return mask

    def to_markerset(self) -> MarkerSet:
        """The rope as labelled markers, invented samples flagged, lost samples NaN."""
        return MarkerSet(
            positions=self.positions.copy(),
            labels=list(self.labels),
            rate=self.rate,
            invented=self.invented & np.isfinite(self.positions).all(axis=2),
            meta=dict(self.meta),
        )


def _track_frames_dispatcher() -> Any:
    """The compiled frame loop (numba dispatcher), for :mod:`skincap.backends`."""
    from skincap.tracking._steps_numba import track_frames

    return track_frames


def _resolve_backend(backend: str) -> str:
    # "auto" runs NumPy while the kernel is not compiled yet and compiles it in the
    # background (skincap.backends): a first run never waits for the compiler
    return resolve_backend(
        backend,
        numba_installed=numba_available(),
        feature="the compiled rope tracker",
        kernel=("tracking", _track_frames_dispatcher),
    )


def _check_inputs(cloud: PointCloud, init: RopeInit, settings: TrackSettings | None) -> None:
    if not isinstance(cloud, PointCloud):
        raise ValidationError(f"cloud: expected a PointCloud, got {type(cloud).__name__}")
    if not isinstance(init, RopeInit):
        raise ValidationError(f"init: expected a RopeInit, got {type(init).__name__}")
    if settings is not None and not isinstance(settings, TrackSettings):
        raise ValidationError(f"settings: expected a TrackSettings, got {type(settings).__name__}")
    n0 = int(cloud.counts[0]) if cloud.n_frames else 0
    if cloud.n_frames < 1 or init.indices.max() >= n0 or init.n_markers < 3:
        raise ValidationError(
            f"init: rope index {int(init.indices.max())} is beyond frame 0's {n0} points"
        )


def track_rope(
    cloud: PointCloud,
    init: RopeInit,
    *,
    settings: TrackSettings | None = None,
    progress: Callable[[float], object] | None = None,
    backend: str = "auto",
) -> RopeTrack:
    """Track the rope markers through the whole take.

    Parameters
    ----------
    cloud : PointCloud
        The take (the one ``init`` was made from), metres, Y up.
    init : RopeInit
        From :func:`~skincap.tracking.init.init_rope`: frame-0 indices, spacings
        ``l_j``, γ, maxTempMarkers.
    settings : TrackSettings, optional
        The tracker's tuning constants; default ``TrackSettings()``.
    progress : callable, optional
        Called with the fraction of frames done (0..1), about a hundred times.
    backend : {"auto", "numba", "numpy"}
        ``numba`` runs the per-frame steps compiled (:mod:`skincap.tracking._steps_numba`;
        tens of times faster; compiled on first use if needed), ``numpy`` the NumPy
        reference (:mod:`skincap.tracking._steps_numpy`); ``auto`` picks numba once
        its kernel is compiled, and until then NumPy while the kernel compiles in the
        background (:func:`skincap.backends.resolve_backend`), switching to the kernel
        between chunks of frames once it is cached (checked at most once a second).
        Both take the same points and invent the same markers; invented positions
        agree to rounding.

    Returns
    -------
    RopeTrack
        Positions NaN only where a trace is lost (a SkincapWarning counts them),
        invented samples bounded by the rope's length; ``invented`` where a temporary
        marker was used;
        ``point_index`` the taken points (each at most once); ``lost_frames``.

    Raises
    ------
    ValidationError
        ``init`` does not fit ``cloud`` (an index beyond frame 0's points), a
        ``settings`` that is not a :class:`TrackSettings`, or an unknown ``backend``.
    MissingDependencyError
        ``backend="numba"`` without numba installed.

    Examples
    --------
    >>> track = track_rope(cloud, init_rope(cloud, auto=True))  # doctest: +SKIP
    >>> track.to_markerset().positions.shape  # doctest: +SKIP
    (1200, 24, 3)
    """
    _check_inputs(cloud, init, settings)
    state, params = start_tracking(cloud, init, settings or TrackSettings())
    if _resolve_backend(backend) == "numba":
        from skincap.tracking._steps_numba import track_frames
    else:
        from skincap.tracking._steps_numpy import track_frames
    # "auto" got NumPy because the kernel is compiling in the background: both step
    # backends share the state, so the kernel takes over once it is in the cache
    watch = backends.KernelWatch(
        _track_frames_dispatcher,
        backend == "auto" and track_frames.__module__.endswith("_numpy") and numba_available(),
    )
    # frames in chunks of about a hundredth of the take, reporting after each (or
    # looking for the kernel); with neither, one call (each call unboxes the state)
    t_frames = cloud.n_frames
    every = max(1, t_frames // 100) if progress is not None or watch.waiting else t_frames
    t0 = 1
    while t0 < t_frames:
        t1 = min(t_frames, (t0 - 1) // every * every + every + 1)
        track_frames(state, t0, t1, params)
        if watch.landed():
            track_frames = _track_frames_dispatcher()
        if progress is not None and (t1 - 1) % every == 0:
            progress((t1 - 1) / t_frames)
        t0 = t1
    if progress is not None:
        progress(1.0)
    lost_frames = state.lost_frames.copy()
    positions, moved = _physical_output(
        state.positions, state.invented, lost_frames, init.spacing, init.labels
    )
    return RopeTrack(
        positions=positions,
        invented=state.invented,
        point_index=state.point_index,
        lost_frames=lost_frames,
        labels=init.labels,
        rate=cloud.rate,
        init=init,
        meta={
            **{k: v for k, v in cloud.meta.items() if k != "id_labels"},
            "invented_bounded": int(moved.sum()),
        },
    )


def _physical_output(
    positions: np.ndarray,
    invented: np.ndarray,
    lost_frames: np.ndarray,
    spacing: np.ndarray,
    labels: list[str],
) -> tuple[np.ndarray, np.ndarray]:
    """The tracked positions as reported: invented samples bounded, lost samples NaN.

    Both backends track with their own (unbounded) predictions; what leaves the
    tracker is physical (:func:`skincap.tracking.physical.bound_invented`), and a lost
    trace is NaN with a :class:`~skincap.errors.SkincapWarning` that counts them.
    """
    bounded, moved = bound_invented(positions, invented, spacing)
    unplaced = ~np.isfinite(bounded).all(axis=2)  # (T, M) no position the rope allows
    lost_frames |= unplaced
    bounded[lost_frames] = np.nan
    if lost_frames.any():
        lost = np.flatnonzero(lost_frames.any(axis=0))
        first = [int(np.argmax(lost_frames[:, j])) for j in lost]
        where = ", ".join(f"{labels[j]} from frame {f}" for j, f in zip(lost, first, strict=True))
        warnings.warn(
            f"rope: {lost.size} of {len(labels)} traces lost ({where}); "
            f"{int(lost_frames.sum())} samples are NaN",
            SkincapWarning,
            stacklevel=3,
        )
    return bounded, moved


def warm_up_kernel() -> None:
    """Compile :func:`track_frames` into numba's cache by tracking a tiny analytic take.

    Goes through :func:`~skincap.tracking.tracker.track_rope` so the argument types
    are exactly those of a real call (run by the background compile); the take is
    :func:`warm_up_take`.
    """
    from skincap.tracking.init import init_rope

    cloud, rope_markers = warm_up_take()
    track_rope(cloud, init_rope(cloud, markers=rope_markers), backend="numba")


def warm_up_take() -> tuple[PointCloud, np.ndarray]:
    """The background compile's take: a rope of 8 markers beside 40 still body points.

    The rope hangs still for the 60 frames :func:`~skincap.tracking.init.init_rope`
    needs (it refuses a rope that moves in its still window), then swings its arc
    about x; 90 frames at 120 Hz.

    Returns
    -------
    cloud : PointCloud
        48 points per frame, metres.
    rope_markers : (8,) int
        The rope's points among frame 0's points.
    """
    frames, still, rope_markers, body_markers = 90, 60, 8, 40
    t = np.maximum(np.arange(frames) - still, 0)[:, None] / 120.0  # (T, 1) s, 0 while still
    s = np.linspace(0.0, 1.0, rope_markers)[None, :]
    angle = np.pi + 0.5 * np.sin(2 * np.pi * t)  # (T, 1): the arc swings about x
    rope = np.stack(
        [
            -0.45 + 0.9 * s + 0 * t,
            1.0 + np.sin(np.pi * s) * np.cos(angle),
            np.sin(np.pi * s) * np.sin(angle),
        ],
        axis=-1,
    )
    grid = np.linspace(-0.3, 0.3, body_markers)
    body = np.stack(
        [0.2 * np.cos(7 * grid), 1.0 + 2.0 * grid, 0.5 + 0.1 * np.sin(5 * grid)], axis=-1
    )
    frames_points = np.concatenate([rope, np.broadcast_to(body, (frames, body_markers, 3))], axis=1)
    count = rope_markers + body_markers
    cloud = PointCloud(
        points=frames_points.reshape(-1, 3),
        offsets=np.arange(frames + 1, dtype=np.int64) * count,
        rate=120.0,
    )
    return cloud, np.arange(rope_markers)
