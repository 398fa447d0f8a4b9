"""Rope tracking on real human motion (issue #15): real captures with a PBD rope in the hands.

The takes are short pieces of the real captures in tests/data (the fast part of each),
built by :func:`skincap.synth.real_capture.real_capture_with_rope`.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skincap.errors import SkincapWarning
from skincap.evaluate.tracking import classify_points, rope_tracker_from_truth
from skincap.io.c3d import read_c3d
from skincap.synth.real_capture import real_capture_with_rope
from skincap.tracking.physical import STRETCH_ALLOWANCE, physics_excess
from skincap.types import MarkerSet

#: (file, first frame, frames, rope, hands): the fastest stretch of each labelled take
SCENES = {
    "cmu_whip": ("cmu_85_02.c3d", 240, 240, "whip", None),
    "aml_whip": ("aml_PronetoRun01_labeled.c3d", 900, 350, "whip", None),
    "pyomeca_whip": ("pyomeca_markers_analogs.c3d", 200, 300, "whip", None),
    "pig_jump": ("btk_pig_calibration_hole_unlabeled_fragments.c3d", 0, 150, "jump", None),
    # a jump rope whose bottom lies doubled on the floor in the still window: its arms
    # pass within a spacing (the ordering of init_rope), bend onto the floor (the rest
    # length of a bent link: F1 0.959 -> 0.999 with the settled rope) and lift
    "cmu_jump": ("cmu_85_02.c3d", 240, 240, "jump", None),
    # the fast swing: the rope's bottom turns 20-29 cm a frame in 35 of 120 frames;
    # constant velocity misses it by 2-4 γ and the traces slip a marker a frame
    # (F1 0.960 before the accelerated prediction, match_measured_best: 0.999)
    "cmu_jump_swing": ("cmu_85_02.c3d", 480, 120, "jump", None),
    "aml_jump": ("aml_PronetoRun01_labeled.c3d", 900, 350, "jump", None),
    # the performer lies prone: the whip's end link lies folded beside the still hand
    # (3.7 cm chords for 9.2 cm of rope) and its markers drop out; F put them back at
    # the rest spacing, 5-9 cm off, and the rope lying still never brought them back
    # (F1 0.954 before the re-acquisition at the last measured link and the returning
    # trace's neighbour velocity: 0.993)
    "aml_whip_prone": ("aml_PronetoRun01_labeled.c3d", 400, 500, "whip", None),
    "c3dorg_jump": ("c3dorg_sample01_Eb015pr.c3d", 0, 200, "jump", [["LFT1"], ["RFT1"]]),
}


def _scene(data_dir, name: str):  # type: ignore[no-untyped-def]
    file, first, frames, rope, hands = SCENES[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the AML file's empty POINT:UNITS
        m = read_c3d(data_dir / file)
    piece = MarkerSet(m.positions[first : first + frames], m.labels, m.rate, meta=dict(m.meta))
    return real_capture_with_rope(piece, rope=rope, hands=hands, seed=1)


def _measured_breach(track) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(T,) metres by which the measured markers of each frame break the rope's length
    (``|x_a - x_b| - (1 + stretch) |s_a - s_b|`` over measured pairs, at least 0)."""
    s = np.concatenate([[0.0], np.cumsum(track.init.spacing)])
    pos = track.positions
    measured = ~track.invented & np.isfinite(pos).all(axis=2)
    reach = (1.0 + STRETCH_ALLOWANCE) * np.abs(s[:, None] - s[None, :])
    gap = np.linalg.norm(pos[:, :, None] - pos[:, None], axis=3) - reach  # (T, M, M)
    pairs = measured[:, :, None] & measured[:, None, :]
    return np.where(pairs, np.nan_to_num(gap, nan=-np.inf), -np.inf).max(axis=(1, 2)).clip(0.0)


@pytest.fixture(scope="module")
def tracked(data_dir):  # type: ignore[no-untyped-def]
    out = {}
    for name in SCENES:
        take = _scene(data_dir, name)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            track = rope_tracker_from_truth(take.points, take.point_truth)(take.points)
        out[name] = (take, track, [w for w in caught if issubclass(w.category, SkincapWarning)])
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENES))
def test_invented_rope_markers_stay_within_the_ropes_reach(tracked, name: str) -> None:  # type: ignore[no-untyped-def]
    take, track, caught = tracked[name]
    excess = physics_excess(
        track.positions, track.invented, track.init.spacing, stretch=STRETCH_ALLOWANCE
    )
    # never beyond the rope's length, unless the measured markers of the frame break it
    # themselves (a jump rope pulled taut opens its links beyond the still window's
    # chords): then by no more than they do (the projections of bound_invented)
    assert np.nanmax(np.nanmax(excess, axis=1) - _measured_breach(track)) <= 1e-3
    # and so never far from the true rope: within the rope's length of it
    rope = [i for i, label in enumerate(take.truth.labels) if label.startswith("rope_")]
    truth = take.truth.positions[:, rope]
    near = np.linalg.norm(track.positions[:, :, None] - truth[:, None], axis=3).min(axis=2)
    length = float(take.summary["rope_length_m"])
    assert np.nanmax(near) <= length
    # a lost trace is NaN, counted in the warning, never an extrapolation
    lost = track.lost_frames
    assert np.isnan(track.positions[lost]).all() and np.isfinite(track.positions[~lost]).all()
    if lost.any():
        assert any(f"{int(track.lost.sum())} of" in str(w.message) for w in caught)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENES))
def test_issue_targets_rope_body_f1_and_no_trace_lost(tracked, name: str) -> None:  # type: ignore[no-untyped-def]
    # issue #15's targets on every scene: F1 >= 0.99 (the fast CMU hand reversing at
    # 9-15 cm per frame included: 0.741 over the whole take before re-acquisition on
    # the rope's spacing shell), no trace lost (the jump ropes: one trace per rope
    # marker, none invented in the still window by a misordered U)
    take, track, _ = tracked[name]
    assert track.n_markers == take.summary["rope_markers"]
    scores = classify_points(track, take.points, take.point_truth)
    assert scores["precision"] >= 0.99  # the rope never takes the body's markers
    assert scores["f1"] >= 0.99
    assert not track.lost.any()


@pytest.fixture(scope="module")
def c3dorg_jump_whole(data_dir):  # type: ignore[no-untyped-def]
    """The whole c3d.org take (seed 0) with a jump rope: its tracked rope and the take."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = read_c3d(data_dir / "c3dorg_sample01_Eb015pr.c3d")
        take = real_capture_with_rope(m, rope="jump", hands=[["LFT1"], ["RFT1"]], seed=0)
        track = rope_tracker_from_truth(take.points, take.point_truth)(take.points)
    return take, track


@pytest.mark.slow
def test_a_doubled_rope_keeps_its_traces_on_their_own_arm(c3dorg_jump_whole) -> None:  # type: ignore[no-untyped-def]
    # a jump rope's bottom lies doubled on the floor, its arms 1.8 cm apart; at frame 406
    # the matching at V found 20 traces by handing two of them the other arm's points
    # (2.6 cm from V), the accelerated prediction 14, all right (within 0.4 cm): more
    # traces won, and the chain slid along the other arm for ten frames (115 samples
    # on another rope marker's point at main). What is left (frames 407-409: traces
    # 7/8 and 11/12 on each other's points) no rule can tell: rope_14 and rope_09, and
    # rope_13 and rope_10, lie 1.4 and 1.9 mm apart there (the simulated rope passes
    # through itself), within the 0.5 mm noise of a prediction's few millimetres
    take, track = c3dorg_jump_whole
    truth = np.asarray(take.point_truth).astype(str)
    own = truth[take.points.offsets[0] + track.init.indices]  # (M,) each trace's marker
    taken = track.point_index >= 0
    elsewhere = taken & (truth[np.maximum(track.point_index, 0)] != own[None, :])
    assert int(elsewhere.sum()) <= 85  # 73 now (115 at main)
    assert int(elsewhere[400:420].sum()) <= 25  # the frames after 406: 17 now (59 at main)
    assert not track.lost.any()


@pytest.mark.slow
def test_a_rope_landing_folded_beside_a_foot_is_found_again(c3dorg_jump_whole) -> None:  # type: ignore[no-untyped-def]
    # frames 418-441: the rope's middle lands on the floor beside the left foot and
    # stops dead, folded (chords 8.8 cm for 12.6 cm of rope); rope_07 and rope_06,
    # hidden as it landed, lie still 3.7 and 14 cm from their predictions, and every
    # search refused them (beyond γ at a short chord): both invented for 22 frames,
    # then a foot marker taken (F1 0.988). Bridged between their measured neighbours
    # (the foot marker LFT3 fits the rope as well, but stood beside rope_06 before)
    take, track = c3dorg_jump_whole
    scores = classify_points(track, take.points, take.point_truth)
    assert scores["f1"] >= 0.99  # 0.9940 (0.9880 before the bridge)
    assert scores["precision"] >= 0.999  # 1.0 (0.9976: the foot markers)
    truth = np.asarray(take.point_truth).astype(str)
    own = truth[take.points.offsets[0] + track.init.indices]
    landed = [int(np.flatnonzero(own == label)[0]) for label in ("rope_07", "rope_06")]
    measured = ~track.invented[425:441][:, landed]
    assert measured.mean() >= 0.9
    assert not track.lost.any()


def test_a_rope_held_at_a_foot_and_a_shin_is_ordered_and_followed(data_dir) -> None:  # type: ignore[no-untyped-def]
    """The OptiTrack walking take has only leg markers: a jump rope held at a foot
    and a shin marker, one above the other, used to start laid doubled on the floor
    (markers 3 mm apart), so init_rope ordered it wrong from frame 0 and the traces
    fell apart once the walk began (issue #15's kt jump). Laid in an open loop it is
    ordered as the truth and followed through the first steps."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = read_c3d(data_dir / "kt_optitrack_walking.c3d")
    piece = MarkerSet(m.positions[:480], m.labels, m.rate, meta=dict(m.meta))
    take = real_capture_with_rope(
        piece, rope="jump", hands=[["Foot_Marker1"], ["Leg_Marker1"]], seed=1
    )
    assert take.summary["rope_doubled_markers"] == 0
    cloud = take.points
    first = take.point_truth[cloud.offsets[0] : cloud.offsets[1]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        track = rope_tracker_from_truth(cloud, take.point_truth)(cloud)
    order = [str(first[i]) for i in track.init.indices]
    truth_order = [f"rope_{j:02d}" for j in range(22)]
    assert order in (truth_order, truth_order[::-1])
    assert not track.lost.any()
    assert classify_points(track, cloud, take.point_truth)["f1"] >= 0.95


@pytest.fixture(scope="module")
def kt_jump_whole(data_dir):  # type: ignore[no-untyped-def]
    """The whole OptiTrack walk (seed 0, as ``skincap synth --rope jump --hands
    Foot_Marker1:Leg_Marker1``): the rope's end lies on the floor beside the knee and
    foot markers, moving with them."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = read_c3d(data_dir / "kt_optitrack_walking.c3d")
        take = real_capture_with_rope(
            m, rope="jump", hands=[["Foot_Marker1"], ["Leg_Marker1"]], seed=0
        )
        track = rope_tracker_from_truth(take.points, take.point_truth)(take.points)
    return take, track


@pytest.mark.slow
def test_rope_points_back_beside_a_hidden_trace_do_not_become_body_points(kt_jump_whole) -> None:  # type: ignore[no-untyped-def]
    # the end of the rope lies on the floor beside the knee and foot markers; a leg
    # marker's body chain passed onto a hidden rope marker's point as it came back
    # (its trace, hidden, did not count against the chain), and the trace, back from
    # its gap, refused it as a body point for as long as the chain went on (about a
    # third of the rope points left untaken were body points): recall 0.9238 ->
    # 0.9303, F1 0.9556 -> 0.9591
    # (issue #15's 0.99 is held by the test below, after the held end's carry search)
    take, track = kt_jump_whole
    scores = classify_points(track, take.points, take.point_truth)
    assert scores["recall"] >= 0.928
    assert scores["f1"] >= 0.958
    assert scores["precision"] >= 0.989


@pytest.mark.slow
def test_a_hidden_held_end_is_not_handed_a_knee_marker(kt_jump_whole) -> None:  # type: ignore[no-untyped-def]
    # the rope is held at the shin (trace 0) and lies bent there; at frame 965 its end,
    # hidden for five frames, was looked for by the zipper straight on from its measured
    # links, 5.4 cm off, and took Knee_Marker4 (its hand's carry lay within 1 cm of the
    # rope's end): trace 0 then rode the knee and trace 1 the foot until ~frame 1500
    # (F1 0.9875, precision 0.9931). Looked for at the carry, within γ
    take, track = kt_jump_whole
    truth = np.asarray(take.point_truth).astype(str)
    on = truth[np.maximum(track.point_index, 0)]  # (T, M) the label of each taken point
    body = (track.point_index >= 0) & ~np.char.startswith(on, "rope_")
    assert int(body[960:1500, :2].sum()) <= 10  # 0 now (348 before, NumPy steps)
    scores = classify_points(track, take.points, take.point_truth)
    assert scores["f1"] >= 0.99
    assert not track.lost.any()
