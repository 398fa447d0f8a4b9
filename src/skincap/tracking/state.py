"""The rope tracker's state and parameters, shared by its two step backends.

:class:`TrackState` is one NamedTuple of arrays (numba compiles functions that take
it) holding the take, the results written frame by frame, and the frame being
matched; :class:`StepParams` is one NamedTuple of floats and ints, built once from
:class:`~skincap.tracking.settings.TrackSettings`, the initialisation and the rate.
The steps in :mod:`skincap.tracking._steps_numpy` and
:mod:`skincap.tracking._steps_numba` take ``(state, t, …, params)`` and change the
arrays in place; the tuples themselves are never rebuilt during a run.
"""

from __future__ import annotations

from dataclasses import fields
from typing import NamedTuple, get_type_hints

import numpy as np

from skincap.tracking.curve import fill_interior_on_curve, rest_arclength
from skincap.tracking.init import RopeInit
from skincap.tracking.settings import TrackSettings
from skincap.types import PointCloud

__all__ = ["HAND_ANCHORS", "StepParams", "TrackState", "leave_one_out_weights", "start_tracking"]


#: Points beside a held end followed as its hand while it is hidden (the nearest ones).
HAND_ANCHORS = 8


class TrackState(NamedTuple):
    """Everything the per-frame steps read and write (M rope markers, P points, T frames).

    The take (read only)::

        points       (P, 3) float64, metres   the cloud's points, C-contiguous
        offsets      (T + 1,) int64           frame t is points[offsets[t]:offsets[t + 1]]
        arclength    (M,) float64, metres     rest arc length s_j of each marker
        spacing      (M - 1,) float64, metres rest spacings l_j
        leave_one_out (M, M) float64          W[j] @ x is the curve through every marker
                                              but j, at s_j (the NumPy steps use it)

    Results, row t written when frame t is done::

        positions    (T, M, 3) float64, metres  never NaN (invented where unseen)
        invented     (T, M) bool
        point_index  (T, M) int64             global index of the point taken, -1 if none
        lost_frames  (T, M) bool              more than maxTempMarkers temporary markers, unpinned

    Carried from frame to frame::

        velocity     (M, 3) float64, metres per frame  last displacement (v Δt, eq. 3.2)
        temp_count   (M,) int64               consecutive temporary markers; 0 = steady
        body         (P,) bool                body points (continuing frame 0's non-rope points)
        body_vel     (P, 3) float64, metres per frame  their last displacement

    The frame being matched (reset at its start)::

        cur          (M, 3) float64, metres   the markers found so far (zero elsewhere)
        known        (M,) bool                measured this frame
        taken        (M,) int64               the point each trace took, -1 if none

    The compiled steps' index of each frame's points (:mod:`skincap.tracking._numba_grid`),
    built when a frame is first searched (the NumPy steps do not use it)::

        grid_info    (T, 4) float64           axis (-1: not built yet), lowest coordinate
                                              along it (metres), 1 / cell width (1/metres),
                                              number of cells
        grid_starts  (P + 2 T,) int64         frame t's cell starts, from offsets[t] + 2 t
        grid_order   (P,) int64               frame t's points cell by cell, at
                                              offsets[t]:offsets[t + 1]

    A held end's hand (:mod:`skincap.tracking._hand_numpy`; row 0 for trace 0, row 1
    for trace M - 1, K = :data:`HAND_ANCHORS`)::

        hand_index   (2, K) int64             global index, in the last frame tracked, of
                                              each anchor beside the end; -1 none
        hand_then    (2, K, 3) float64, metres the anchors where the end was last measured
        hand_vel     (2, K, 3) float64, metres per frame  their last displacement

    Learnt while tracking::

        link_rest    (M - 1,) float64, metres  each link's rest length as the rope has
                                              shown it: the longest chord accepted
                                              between its two measured markers, at most
                                              ``stretch`` times ``spacing`` (the still
                                              window's chord is slack, shorter than the
                                              rope between the markers), or times the
                                              median spacing for a link measured at
                                              both ends in two frames running
    """

    points: np.ndarray
    offsets: np.ndarray
    arclength: np.ndarray
    spacing: np.ndarray
    leave_one_out: np.ndarray
    positions: np.ndarray
    invented: np.ndarray
    point_index: np.ndarray
    lost_frames: np.ndarray
    velocity: np.ndarray
    temp_count: np.ndarray
    body: np.ndarray
    body_vel: np.ndarray
    cur: np.ndarray
    known: np.ndarray
    taken: np.ndarray
    grid_info: np.ndarray
    grid_starts: np.ndarray
    grid_order: np.ndarray
    hand_index: np.ndarray
    hand_then: np.ndarray
    hand_vel: np.ndarray
    link_rest: np.ndarray


class StepParams(NamedTuple):
    """The constants of one run, as plain numbers (lengths in metres).

    ``gamma`` and ``max_temp_markers`` come from the initialisation, ``median_spacing``
    is the median rest spacing, ``rigid_window`` the rigidity window in frames; the
    other fields are those of :class:`~skincap.tracking.settings.TrackSettings`.
    """

    gamma: float
    max_temp_markers: int
    candidates: int
    retry_rounds: int
    wide_gate: float
    stretch: float
    adjacent_stretch: float
    body_chain_gate: float
    rigid_window: int
    rigid_move: float
    rigid_radius: float
    rigid_range: float
    rigid_partners: int
    zipper_rounds: int
    swing_gate: float
    lone_after: int
    settle: float
    carry_tolerance: float
    median_spacing: float


def leave_one_out_weights(s: np.ndarray) -> np.ndarray:
    """(M, M) W: ``W[j] @ x`` is the curve through every marker but ``j``, at ``s_j``.

    :func:`~skincap.tracking.curve.fill_interior_on_curve` is linear in the
    positions, so it is evaluated once on unit positions. Row ``j`` is valid when
    markers ``j - 2 … j + 2`` (those that exist) are all measured; rows 0 and M - 1
    are zero (an end has no curve on both sides).
    """
    m = s.size
    basis = np.zeros((m, m, m, 3))
    basis[:, np.arange(m), np.arange(m), 0] = 1.0  # [j, k]: marker k at unit x
    known = np.ones((m, m, m), dtype=bool)
    known[np.arange(m), :, np.arange(m)] = False
    filled, _ = fill_interior_on_curve(basis, known, s)
    w = filled[np.arange(m), :, np.arange(m), 0]  # (j, k)
    w[[0, m - 1]] = 0.0
    return np.ascontiguousarray(w)


def step_params(cloud_rate: float, init: RopeInit, settings: TrackSettings) -> StepParams:
    """The run's :class:`StepParams` from the take's rate (Hz), the init and the settings."""
    # the fields TrackSettings shares by name, as plain numbers of the field's type
    kinds = get_type_hints(StepParams)  # name -> int or float
    shared = {
        f.name: kinds[f.name](getattr(settings, f.name))
        for f in fields(settings)
        if f.name in StepParams._fields
    }
    return StepParams(
        gamma=float(init.gamma),
        max_temp_markers=int(init.max_temp_markers),
        rigid_window=int(round(settings.rigid_window_s * cloud_rate)),
        median_spacing=float(np.median(init.spacing)),
        **shared,
    )


def start_tracking(
    cloud: PointCloud, init: RopeInit, settings: TrackSettings
) -> tuple[TrackState, StepParams]:
    """The state after frame 0 and the run's parameters.

    Frame 0 is the initialisation: each trace at its selected point (or invented
    where the init added it), zero velocity; every other point of frame 0 is a body
    point (the user selected the rope there).
    """
    t_frames, m = cloud.n_frames, init.n_markers
    points = np.ascontiguousarray(cloud.points, dtype=np.float64)
    offsets = np.ascontiguousarray(cloud.offsets, dtype=np.int64)
    spacing = np.ascontiguousarray(init.spacing, dtype=np.float64)
    s = rest_arclength(spacing)
    positions = np.zeros((t_frames, m, 3))
    invented = np.zeros((t_frames, m), dtype=bool)
    point_index = np.full((t_frames, m), -1, dtype=np.int64)
    seen0 = init.indices >= 0
    positions[0] = init.positions
    positions[0, seen0] = points[offsets[0] + init.indices[seen0]]
    point_index[0, seen0] = init.indices[seen0]
    invented[0] = ~seen0
    body = np.zeros(points.shape[0], dtype=bool)
    body[offsets[0] : offsets[1]] = True
    body[offsets[0] + init.indices[seen0]] = False
    state = TrackState(
        points=points,
        offsets=offsets,
        arclength=s,
        spacing=spacing,
        leave_one_out=leave_one_out_weights(s),
        positions=positions,
        invented=invented,
        point_index=point_index,
        lost_frames=np.zeros((t_frames, m), dtype=bool),
        velocity=np.zeros((m, 3)),
        temp_count=(~seen0).astype(np.int64),
        body=body,
        body_vel=np.zeros((points.shape[0], 3)),
        cur=np.zeros((m, 3)),
        known=np.zeros(m, dtype=bool),
        taken=np.full(m, -1, dtype=np.int64),
        grid_info=np.full((t_frames, 4), -1.0),
        grid_starts=np.zeros(points.shape[0] + 2 * t_frames, dtype=np.int64),
        grid_order=np.zeros(points.shape[0], dtype=np.int64),
        hand_index=np.full((2, HAND_ANCHORS), -1, dtype=np.int64),
        hand_then=np.zeros((2, HAND_ANCHORS, 3)),
        hand_vel=np.zeros((2, HAND_ANCHORS, 3)),
        link_rest=spacing.copy(),
    )
    return state, step_params(cloud.rate, init, settings)
