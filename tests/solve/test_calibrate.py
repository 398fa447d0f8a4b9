"""Calibration's joint centres on exact synthetic takes: a prior placed along the joint's
axis, and SCoRE without a parent marker that does not keep its distance to the joint."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import FormatError, SkincapWarning
from skincap.geometry.kinematics import joint_positions
from skincap.solve import joint_centres as jc
from skincap.solve import load_template, solve_markers
from skincap.solve.calibrate import _Calibrator
from skincap.types import MarkerSet

T = 400


def _sines(rng: np.random.Generator, amp_rad: np.ndarray) -> np.ndarray:
    """(T, 3) smooth rotation vectors, amplitude ``amp_rad`` per axis."""
    t = np.arange(T) / 120.0
    freq = rng.uniform(0.3, 0.8, size=3)
    phase = rng.uniform(0, 2 * np.pi, size=3)
    return amp_rad * np.sin(2 * np.pi * freq * t[:, None] + phase)


def _root_motion(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3, 3) rotations and (T, 3) origins of a parent moving about the room."""
    rot = Rotation.from_rotvec(_sines(rng, np.radians([25.0, 40.0, 25.0]))).as_matrix()
    origin = np.array([0.2, 1.0, -0.3]) + _sines(rng, np.array([0.4, 0.05, 0.4]))
    return rot, origin


def _place(rot: np.ndarray, origin: np.ndarray, local: dict[str, list[float]]) -> dict:
    return {k: np.einsum("tij,j->ti", rot, v) + origin for k, v in local.items()}


def _template(tmp_path, segments: list[dict]) -> object:
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"name": "t", "segments": segments}))
    return load_template(path)


def _markers(points: dict[str, np.ndarray]) -> MarkerSet:
    labels = sorted(points)
    return MarkerSet(np.stack([points[k] for k in labels], axis=1), labels, 120.0)


# a knee-like hinge: the centre at the thigh's origin, the axis along its x; KNE on the
# lateral skin over the axis, OTHER (the other knee) medial but well ahead of it, as in
# mid-stride -- the direction KNE -> OTHER is 53 deg off the axis
_THIGH = {
    "T1": [0.0, 0.4, 0.0], "T2": [0.06, 0.2, 0.04], "T3": [-0.05, 0.25, 0.06],
    "KNE": [0.05, 0.0, 0.0], "OTHER": [-0.1, 0.0, 0.2],
}  # fmt: skip
_SHANK = {"S1": [0.06, -0.2, 0.02], "S2": [-0.02, -0.25, 0.06], "S3": [0.0, -0.4, 0.0]}


def _hinge_take(rng: np.random.Generator) -> tuple[dict, np.ndarray, np.ndarray]:
    """The thigh and shank markers (label -> (T, 3)), the knee centre (T, 3) and the
    shank's world rotations (T, 3, 3) (its origin is the knee centre)."""
    rot, origin = _root_motion(rng)
    flex = np.radians(50.0) * (1 - np.cos(np.linspace(0, 8 * np.pi, T)))  # 0..100 deg
    shank_rot = rot @ Rotation.from_rotvec(-flex[:, None] * [1.0, 0.0, 0.0]).as_matrix()
    points = _place(rot, origin, _THIGH) | _place(shank_rot, origin, _SHANK)
    return points, origin, shank_rot


def _hinge_template(tmp_path, prior: dict) -> object:
    return _template(
        tmp_path,
        [
            {"name": "thigh", "joint": "Hip", "parent": None,
             "markers": ["T1", "T2", "T3", "KNE", "OTHER"], "origin": ["T1"],
             "axes": [["y", ["@shank"], ["T1"]], ["x", "hinge:shank"]]},
            {"name": "shank", "joint": "Knee", "parent": "thigh", "markers": ["S1", "S2", "S3"],
             "centre": {"kind": "hinge", "prior": prior, "flexion": ["T1", "@shank", "S3"]},
             "axes": [["y", ["S3"], ["@shank"]], ["x", "hinge:shank"]]},
        ],
    )  # fmt: skip


def test_a_prior_along_the_hinge_axis_places_the_knee_where_towards_alone_does_not(tmp_path):
    points, centre, _ = _hinge_take(np.random.default_rng(31))
    markers = _markers(points)
    prior = {"from": ["KNE"], "towards": ["OTHER"], "distance": 0.05}
    errors = {}
    for along in (None, "axis"):
        tpl = _hinge_template(tmp_path, prior if along is None else dict(prior, along=along))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkincapWarning)
            result = solve_markers(markers, tpl)
        knee = joint_positions(result.motion)[:, result.motion.skeleton.index("Knee")]
        errors[along] = np.linalg.norm(knee - centre, axis=1).max()
        assert result.model.methods["shank"] == "SARA"
    # towards OTHER: 5 cm from KNE at 53 deg to the axis, 2 cm short along it
    assert errors[None] == pytest.approx(0.02, abs=1e-3)
    assert errors["axis"] < 1e-6  # 5 cm along the axis from KNE: the true centre


def test_a_ball_joint_prior_along_another_segments_hinge_axis(tmp_path):
    """An ankle turning mostly about its shank's long axis takes its prior along the
    knee's axis ("hinge:shank"), not its own principal axis."""
    rng = np.random.default_rng(32)
    pts, knee, shank_rot = _hinge_take(rng)
    # ANK on the lateral skin over the ankle along the knee's axis (x); ANK2 (the other
    # ankle) medial and well ahead
    ankle = np.einsum("tij,j->ti", shank_rot, [0.0, -0.45, 0.0]) + knee
    pts |= _place(shank_rot, knee, {"ANK": [0.04, -0.45, 0.0], "ANK2": [-0.1, -0.45, 0.25]})
    # the foot turns most about the shank's long axis (y), little about the others
    foot_rot = (
        shank_rot @ Rotation.from_rotvec(_sines(rng, np.radians([8.0, 30.0, 6.0]))).as_matrix()
    )
    foot = {"F1": [0.03, -0.05, 0.12], "F2": [-0.04, -0.06, 0.1], "F3": [0.0, -0.07, -0.05]}
    pts |= _place(foot_rot, ankle, foot)
    prior = {"from": ["ANK"], "towards": ["ANK2"], "distance": 0.04}
    centres = {}
    for along in ("hinge:shank", "axis"):
        _hinge_template(tmp_path, {"from": ["KNE"], "towards": ["OTHER"], "distance": 0.05})
        raw = json.loads((tmp_path / "t.json").read_text())
        raw["segments"][1]["markers"] += ["ANK", "ANK2"]
        raw["segments"].append(
            {"name": "foot", "joint": "Ankle", "parent": "shank", "markers": list(foot),
             "centre": {"kind": "ball", "prior": dict(prior, along=along)},
             "axes": [["z", ["F3"], ["F1"]], ["x", "parent"]]}
        )  # fmt: skip
        (tmp_path / "t.json").write_text(json.dumps(raw))
        tpl = load_template(tmp_path / "t.json")
        cal = _Calibrator(_markers(pts), tpl, jc.MIN_SPREAD_DEG)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkincapWarning)
            for spec in tpl.segments:
                cal.technical(spec)
            for spec in tpl.segments[1:]:
                cal.centre(spec)
        assert cal.methods["foot"] == "SCoRE + regression along the axis"
        centres[along] = cal.centres["foot"]
    # exact data: SCoRE is exact, and sliding it along the knee's axis to the prior 4 cm
    # medial of ANK (which sits on that axis, 4 cm lateral of the ankle) keeps it exact
    assert np.abs(centres["hinge:shank"] - ankle).max() < 1e-6
    # the foot's own principal axis is the shank's long axis (30 deg of turn): the
    # prior 4 cm along it from ANK is no ankle, and the centre slides centimetres off
    assert np.linalg.norm(centres["axis"] - ankle, axis=1).mean() > 0.01


def test_score_leaves_out_a_parent_marker_on_a_part_that_bends(tmp_path):
    """A thorax: A-D ride the upper trunk that carries the shoulder, E the lower trunk
    that bends 15 deg against it; the shoulder turns about a point fixed in A-D."""
    rng = np.random.default_rng(33)
    rot, origin = _root_motion(rng)
    upper = {"A": [0.0, 0.2, -0.1], "B": [0.0, 0.15, 0.12], "C": [-0.1, 0.1, -0.1],
             "D": [0.08, 0.05, 0.11]}  # fmt: skip
    bend = Rotation.from_rotvec(_sines(rng, np.radians([15.0, 5.0, 5.0]))).as_matrix()
    lower_rot = rot @ bend
    hinge = np.einsum("tij,j->ti", rot, [0.0, -0.1, 0.0]) + origin  # where the trunk bends
    e_pos = np.einsum("tij,j->ti", lower_rot, [0.0, -0.15, -0.1]) + hinge
    shoulder = np.array([0.18, 0.15, 0.0])
    arm_rot = rot @ Rotation.from_rotvec(_sines(rng, np.radians([40.0, 30.0, 35.0]))).as_matrix()
    arm_origin = np.einsum("tij,j->ti", rot, shoulder) + origin
    arm = {"U1": [0.05, -0.03, 0.03], "U2": [0.15, 0.02, -0.03], "U3": [0.3, -0.02, 0.0]}
    pts = _place(rot, origin, upper) | {"E": e_pos} | _place(arm_rot, arm_origin, arm)
    tpl = _template(
        tmp_path,
        [
            {"name": "trunk", "joint": "Chest", "parent": None,
             "markers": ["A", "B", "C", "D", "E"], "origin": ["A"],
             "axes": [["y", ["C"], ["A"]], ["x", ["C"], ["D"]]]},
            {"name": "arm", "joint": "Shoulder", "parent": "trunk", "markers": list(arm),
             "centre": {"kind": "ball", "prior": {"from": ["U1"]}},
             "axes": [["x", ["@arm"], ["U3"]], ["y", "parent"]]},
        ],
    )  # fmt: skip
    cal = _Calibrator(_markers(pts), tpl, jc.MIN_SPREAD_DEG)
    for spec in tpl.segments:
        cal.technical(spec)
    cal.centre(tpl.segments[1])
    assert cal.methods["arm"] == "SCoRE without E"
    assert cal.loose == {"arm": ["E"]}
    assert np.abs(cal.centres["arm"] - arm_origin).max() < 1e-6
    # what the whole bending cluster gives: centimetres off
    rp, tp = cal.tech["trunk"]
    rc, tc = cal.tech["arm"]
    cp, _, _ = jc.score_centre(rp, tp, rc, tc)
    plain = np.einsum("tij,j->ti", rp, cp) + tp
    assert np.linalg.norm(plain - arm_origin, axis=1).mean() > 0.005


@pytest.mark.parametrize(
    ("along", "message"),
    [
        ("nowhere", "'along' must be 'axis' or 'hinge:SEGMENT'"),
        ("hinge:shin", "'along' must be 'axis' or 'hinge:SEGMENT'"),
        (["axis"], "'along' must be 'axis' or 'hinge:SEGMENT'"),
    ],
)
def test_a_bad_along_is_refused(tmp_path, along, message):
    with pytest.raises(FormatError, match=message):
        _hinge_template(
            tmp_path, {"from": ["KNE"], "towards": ["OTHER"], "distance": 0.05, "along": along}
        )


def test_along_needs_a_direction_and_a_distance(tmp_path):
    with pytest.raises(FormatError, match="'along' needs 'towards' and a 'distance'"):
        _hinge_template(tmp_path, {"from": ["KNE"], "towards": ["OTHER"], "along": "axis"})


def test_a_hinge_centre_where_the_bones_cross_the_axis(tmp_path):
    """``axis_point``: the centre's place along SARA's axis midway between the feet of
    the perpendiculars from a proximal and a distal point; bones tilted either way off
    the flexion axis (a carrying angle) cancel in the mean."""
    points, centre, shank_rot = _hinge_take(np.random.default_rng(34))
    # the thigh's point 1.2 cm lateral along the axis, the shank's 1.2 cm medial
    points |= _place(shank_rot, centre, {"DIST": [-0.012, -0.42, 0.0]})
    rot, _ = _root_motion(np.random.default_rng(34))  # the thigh's frames (same seed)
    points |= _place(rot, centre, {"PROX": [0.012, 0.42, 0.0]})
    # and two whose feet lie 8 cm apart along the axis (over AXIS_POINT_AGREEMENT_M)
    points |= _place(shank_rot, centre, {"DIST2": [-0.04, -0.42, 0.0]})
    points |= _place(rot, centre, {"PROX2": [0.04, 0.42, 0.0]})
    prior = {"from": ["KNE"], "towards": ["OTHER"], "distance": 0.05}
    tpl = _hinge_template(tmp_path, prior)
    raw = json.loads((tmp_path / "t.json").read_text())
    raw["segments"][0]["markers"] += ["PROX", "PROX2"]
    raw["segments"][1]["markers"] += ["DIST", "DIST2"]
    raw["segments"][1]["centre"]["axis_point"] = [["PROX"], ["DIST"]]
    (tmp_path / "t.json").write_text(json.dumps(raw))
    tpl = load_template(tmp_path / "t.json")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        result = solve_markers(_markers(points), tpl)
    assert result.model.methods["shank"] == "SARA, centre where the bones cross the axis"
    knee = joint_positions(result.motion)[:, result.motion.skeleton.index("Knee")]
    assert np.abs(knee - centre).max() < 1e-6
    # feet too far apart: the prior (towards OTHER, 53 deg off the axis) places it, 2 cm off
    raw["segments"][1]["centre"]["axis_point"] = [["PROX2"], ["DIST2"]]
    (tmp_path / "t.json").write_text(json.dumps(raw))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        alone = solve_markers(_markers(points), load_template(tmp_path / "t.json"))
    assert alone.model.methods["shank"] == "SARA"
    knee = joint_positions(alone.motion)[:, alone.motion.skeleton.index("Knee")]
    assert np.linalg.norm(knee - centre, axis=1).mean() > 0.015


def _bending_trunk_take(rng: np.random.Generator) -> tuple[dict, dict, dict]:
    """A trunk whose lower part (L1-L3) bends up to 12 deg against the upper part, which
    carries C7, N and both shoulders; the arms turn about the shoulders. Returns the
    markers, the shoulder centres (T, 3) per side and the template's segments."""
    rot, origin = _root_motion(rng)  # the upper part
    upper = {"C7": [0.0, 0.2, -0.1], "N": [0.0, 0.22, 0.08]}
    bend = Rotation.from_rotvec(_sines(rng, np.radians([12.0, 6.0, 8.0]))).as_matrix()
    waist = np.einsum("tij,j->ti", rot, [0.0, -0.15, 0.0]) + origin
    lower = {"L1": [0.1, -0.05, 0.1], "L2": [-0.1, -0.08, 0.1], "L3": [0.0, -0.1, -0.12]}
    pts = _place(rot, origin, upper) | _place(rot @ bend, waist, lower)
    centres = {}
    for side, x in (("l", 0.18), ("r", -0.18)):
        arm_rot = (
            rot @ Rotation.from_rotvec(_sines(rng, np.radians([35.0, 25.0, 30.0]))).as_matrix()
        )
        centres[side] = np.einsum("tij,j->ti", rot, [x, 0.15, 0.0]) + origin
        arm = {f"{side}A": [0.0, 0.05, 0.03], f"{side}B": [x * 0.6, -0.04, -0.04],
               f"{side}C": [x * 1.5, 0.0, 0.04]}  # fmt: skip
        pts |= _place(arm_rot, centres[side], arm)
    return pts, centres, rot


def _trunk_template(tmp_path, parent_points: bool) -> object:
    segs = [
        {"name": "trunk", "joint": "Chest", "parent": None,
         "markers": ["L1", "L2", "L3", "C7", "N"], "origin": ["C7"],
         "axes": [["y", ["L3"], ["C7"]], ["x", ["L2"], ["L1"]]]},
    ]  # fmt: skip
    for side, other in (("l", "r"), ("r", "l")):
        centre: dict = {"kind": "ball", "prior": {"from": [f"{side}A"]}}
        if parent_points:
            centre["parent_points"] = [["C7"], ["N"], [f"@arm_{other}"]]
        segs.append(
            {"name": f"arm_{side}", "joint": f"Shoulder_{side}", "parent": "trunk",
             "markers": [f"{side}A", f"{side}B", f"{side}C"], "centre": centre,
             "axes": [["x", [f"@arm_{side}"], [f"{side}C"]], ["y", "parent"]]}
        )  # fmt: skip
    return _template(tmp_path, segs)


def test_siblings_solved_together_in_a_frame_of_parent_points(tmp_path):
    """Two shoulders on the upper part of a bending trunk that has only two markers of
    its own: SCoRE in the trunk's frame is centimetres off, in a frame of C7, N and the
    other shoulder's centre (solved together) it is exact."""
    pts, centres, _ = _bending_trunk_take(np.random.default_rng(35))
    markers = _markers(pts)
    for with_points in (False, True):
        cal = _Calibrator(markers, _trunk_template(tmp_path, with_points), jc.MIN_SPREAD_DEG)
        for spec in cal.template.segments:
            cal.technical(spec)
        cal.centres_in_parent_points()
        for spec in cal.template.segments[1:]:
            cal.centre(spec)
        err = {s: np.linalg.norm(cal.centres[f"arm_{s}"] - centres[s], axis=1).max() for s in "lr"}
        if with_points:
            assert cal.methods["arm_l"] == "SCoRE in its parent_points frame"
            assert max(err.values()) < 1e-6
        else:
            assert min(err.values()) > 0.005


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda c: c.update(kind="hinge", flexion=["C7", "@arm_l", "lC"]), "ball joint's list"),
        (lambda c: c.update(parent_points=[["C7"], ["@arm_r"]]), "3 or more POINTS"),
        (lambda c: c.update(parent_points=[["C7"], ["N"], ["@trunk"]]), "must be a sibling"),
        (lambda c: c.update(parent_points=[["C7"], ["N"], ["@arm_r", "N"]]), "stands alone"),
        (lambda c: c.update(axis_point=[["C7"], ["lC"]]), "'axis_point' is a hinge's"),
    ],
)
def test_bad_parent_points_and_axis_points_are_refused(tmp_path, change, message):
    _trunk_template(tmp_path, True)
    raw = json.loads((tmp_path / "t.json").read_text())
    change(raw["segments"][1]["centre"])
    (tmp_path / "t.json").write_text(json.dumps(raw))
    with pytest.raises(FormatError, match=message):
        load_template(tmp_path / "t.json")
