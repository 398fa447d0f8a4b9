"""``--template auto``'s tree: two-marker segments framed by their joint, grown root first."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.geometry.kinematics import joint_positions
from skincap.solve import solve_markers
from skincap.solve.auto import auto_template
from skincap.solve.auto_tree import _frame_from_joint, joint_cost
from skincap.solve.segments import cluster_frames, to_world
from skincap.types import MarkerSet

#: Marker positions in each segment's frame (origin at its proximal joint), metres.
_PELVIS = [[0.12, 0.05, 0.08], [-0.12, 0.05, 0.08], [0.06, 0.08, -0.1], [-0.06, 0.08, -0.1],
           [0.0, 0.15, -0.12], [0.0, 0.12, 0.1]]  # fmt: skip
_THIGH = [[0.07, -0.2, 0.03], [0.06, -0.38, 0.0]]
_SHANK = [[0.06, -0.15, 0.02], [0.05, -0.38, -0.01]]
_FOOT = [[0.0, -0.05, -0.05], [0.04, -0.06, 0.1], [-0.01, -0.06, 0.15]]
_HIP = np.array([0.1, -0.1, 0.0])  # in the pelvis
_BONE = np.array([0.0, -0.4, 0.0])  # knee in the thigh, ankle in the shank


def _leg_take(n: int = 400, seed: int = 3):
    """A pelvis, a two-marker thigh (ball hip), a two-marker shank (knee: a hinge about
    the thigh's x, square to the bone) and a three-marker foot (ball ankle), exact.

    Returns the take, the true (T, 3) hip, knee and ankle centres, and the labels per
    segment.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0

    def wobble(amplitude_deg):
        w = rng.uniform(1.0, 3.0, 3)
        phase = rng.uniform(0, 6, 3)
        return Rotation.from_rotvec(
            np.radians(amplitude_deg) * np.sin(np.outer(t, w) + phase)
        ).as_matrix()

    r_pelvis = wobble([8.0, 8.0, 8.0])
    o_pelvis = np.stack([0.3 * t, 0.9 + 0.02 * np.sin(3 * t), 0.0 * t], axis=1)
    r_thigh = r_pelvis @ wobble([35.0, 25.0, 25.0])
    knee_flex = np.radians(35.0) * (1 - np.cos(2.3 * t))
    r_shank = r_thigh @ Rotation.from_euler("x", knee_flex[:, None]).as_matrix()
    r_foot = r_shank @ wobble([25.0, 20.0, 15.0])
    hip = o_pelvis + r_pelvis @ _HIP
    knee = hip + r_thigh @ _BONE
    ankle = knee + r_shank @ _BONE

    def ride(rot, origin, local):
        return origin[:, None] + np.einsum("tij,kj->tki", rot, np.asarray(local))

    parts = {
        "P": ride(r_pelvis, o_pelvis, _PELVIS),
        "T": ride(r_thigh, hip, _THIGH),
        "S": ride(r_shank, knee, _SHANK),
        "F": ride(r_foot, ankle, _FOOT),
    }
    labels = [f"{k}{i}" for k, v in parts.items() for i in range(v.shape[1])]
    take = MarkerSet(np.concatenate(list(parts.values()), axis=1), labels, 100.0)
    segments = {k: [f"{k}{i}" for i in range(v.shape[1])] for k, v in parts.items()}
    return take, {"hip": hip, "knee": knee, "ankle": ankle}, segments


def test_two_marker_thigh_and_shank_carry_the_leg_chain():
    take, truth, segments = _leg_take()
    found = auto_template(take)
    assert sorted(sorted(g) for g in found.groups) == sorted(segments.values())
    seg_of = {g[0][0]: k for k, g in enumerate(found.groups)}
    edges = {
        tuple(sorted((found.groups[c][0][0], found.groups[p][0][0])))
        for c, p in enumerate(found.parents)
        if p >= 0
    }
    assert edges == {("P", "T"), ("S", "T"), ("F", "S")}
    assert found.parents[seg_of["P"]] == -1  # the pelvis is nearest the markers' centroid
    assert found.joint_how[seg_of["T"]] == "frame from its joint"
    assert found.joint_how[seg_of["S"]] == "frame from its joint"
    assert found.joint_how[seg_of["F"]] == "own frame"
    assert found.fit_residual_m.max() < 1e-6  # exact data: every joint keeps its distances
    # the knee turns about one axis only: a hinge, centred square to the thigh bone
    knee_spec = found.template.segments[seg_of["S"]]
    assert knee_spec.centre["kind"] == "hinge"
    assert knee_spec.centre["prior"] == {"from": [f"@segment_{seg_of['T']}"]}
    assert found.template.segments[seg_of["T"]].centre["kind"] == "ball"

    result = solve_markers(take, found.template)
    assert np.nanmax(result.residuals) < 1e-4
    pos = joint_positions(result.motion)
    names = result.motion.skeleton.names
    for joint, seg in (("hip", "T"), ("knee", "S"), ("ankle", "F")):
        solved = pos[:, names.index(f"joint_{seg_of[seg]}")]
        err = np.linalg.norm(solved - truth[joint], axis=1)
        assert err.max() < 1e-4, (joint, err.max())


def test_joint_cost_is_zero_at_a_joint_and_large_across_two():
    take, truth, segments = _leg_take()
    cols = {k: [take.labels.index(m) for m in v] for k, v in segments.items()}
    _, rot, trans = cluster_frames(take.positions[:, cols["P"]])
    cost_thigh, centre, axis = joint_cost(rot, trans, take.positions[:, cols["T"]])
    assert cost_thigh < 1e-9
    assert axis is None  # the hip turns about three axes
    hip = to_world(rot, trans, centre[None])[:, 0]
    assert np.abs(hip - truth["hip"]).max() < 1e-9
    cost_shank, _, _ = joint_cost(rot, trans, take.positions[:, cols["S"]])
    assert cost_shank > 0.005  # hip and knee together keep no distance constant


def test_a_two_marker_group_in_line_with_its_joint_gets_no_frame():
    t = 20
    a = np.zeros((t, 3))
    b = np.tile([0.0, -0.3, 0.0], (t, 1))
    markers = np.stack([a, b], axis=1)
    in_line = np.tile([0.0, 0.2, 0.005], (t, 1, 1))  # 5 mm off the line through a and b
    assert _frame_from_joint(markers, in_line) is None
    aside = np.tile([0.05, 0.2, 0.0], (t, 1, 1))
    framed = _frame_from_joint(markers, aside)
    assert framed is not None and np.isfinite(framed[0]).all()


def test_reach_is_the_median_distance_to_the_nearest_child_marker():
    from skincap.solve.auto_tree import _reach

    t = 30
    rot = np.broadcast_to(np.eye(3), (t, 3, 3)).copy()
    trans = np.zeros((t, 3))
    child = np.zeros((t, 2, 3))
    child[:, 0] = [0.5, 0.0, 0.0]
    child[:, 1] = [0.0, 0.2, 0.0]
    child[:10, 1] = np.nan  # hidden: the other marker is the nearest there
    assert _reach(rot, trans, np.zeros(3), child) == 0.2
    assert _reach(rot, trans, np.zeros(3), np.full((t, 1, 3), np.nan)) == np.inf


def test_hinge_centred_between_its_neighbours_moves_no_marker():
    from skincap.solve.auto_hinges import centre_hinges_between_neighbours
    from skincap.solve.calibrate import calibrate
    from skincap.solve.ik import model_markers, segment_origins

    take, truth, _ = _leg_take()
    found = auto_template(take)
    shank = next(k for k, g in enumerate(found.groups) if g[0].startswith("S"))
    spec = found.template.segments[shank]
    thigh = spec.parent
    # a prior off to the side (the shank's lateral markers): the knee lands on its
    # axis but away from the bones
    spec.centre["prior"] = {"from": list(spec.markers)}
    before = calibrate(take, found.template)
    after = centre_hinges_between_neighbours(before)
    assert after.methods[spec.name].endswith("centred between its neighbours' joints")
    assert after.methods[thigh] == before.methods[thigh]  # a ball: untouched

    def knee_error(model):
        args = (model.segment_parents, model.joint_offsets)
        origins = segment_origins(*args, model.init_rotations, model.init_origins)
        return np.nanmax(np.linalg.norm(origins[:, shank] - truth["knee"], axis=1))

    assert knee_error(before) > 0.02
    assert knee_error(after) < 1e-6

    # every marker, and every other joint, stays where it was in the world
    def world(model):
        return model_markers(
            model.segment_parents, model.joint_offsets, model.marker_segments,
            model.marker_offsets, model.init_rotations, model.init_origins,
        )  # fmt: skip

    np.testing.assert_allclose(world(after), world(before), atol=1e-6)
    foot = next(k for k, g in enumerate(found.groups) if g[0].startswith("F"))
    args = (after.init_rotations, after.init_origins)
    np.testing.assert_allclose(
        segment_origins(after.segment_parents, after.joint_offsets, *args)[:, foot],
        segment_origins(before.segment_parents, before.joint_offsets, *args)[:, foot],
        atol=1e-6,
    )
    assert before.joint_offsets is not after.joint_offsets  # the input is not changed


def test_calibrate_auto_solves_the_exact_leg():
    from skincap.solve.auto import calibrate_auto

    take, truth, _ = _leg_take()
    found = auto_template(take)
    result = solve_markers(take, calibrate_auto(take, found))
    assert np.nanmax(result.residuals) < 1e-4
    pos = joint_positions(result.motion)
    shank = next(k for k, g in enumerate(found.groups) if g[0].startswith("S"))
    knee = pos[:, result.motion.skeleton.names.index(f"joint_{shank}")]
    assert np.linalg.norm(knee - truth["knee"], axis=1).max() < 1e-4


def test_solve_template_auto_from_the_command_line(tmp_path):
    import json

    from typer.testing import CliRunner

    from skincap.cli import app
    from skincap.io import write
    from skincap.io.bvh import read_bvh

    take, _, _ = _leg_take()
    write(take, tmp_path / "leg.c3d")
    out, report = tmp_path / "leg.bvh", tmp_path / "leg.json"
    args = ["solve", tmp_path / "leg.c3d", "--template", "auto", "-o", out, "--report", report]
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    rep = json.loads(report.read_text())
    assert rep["template"] == "auto"
    assert rep["overall"]["rms_m"] < 1e-3  # the C3D stores millimetres as float32
    methods = [v["method"] for v in rep["joint_centres"].values()]
    assert sorted(methods) == sorted(
        ["sphere fit", "sphere-fit axis, centred between its neighbours' joints", "SCoRE"]
    )
    assert read_bvh(out, units="cm").skeleton.n_joints == 5  # root, three joints, the foot end


def test_a_marker_that_turns_its_group_leaves_it():
    from skincap.solve.auto_tree import _better_members

    take, truth, segments = _leg_take()
    cols = {k: [take.labels.index(m) for m in v] for k, v in segments.items()}
    pos = take.positions
    parent = cluster_frames(pos[:, cols["P"]])[1:]
    thigh = pos[:, cols["T"]]
    # a rigid four-marker thigh: the two thigh markers and two more on the bone
    rng = np.random.default_rng(5)
    _, rot, trans = cluster_frames(np.concatenate([thigh, truth["hip"][:, None]], axis=1))
    extra = to_world(rot, trans, rng.normal(scale=0.05, size=(2, 3)))
    rigid = np.concatenate([thigh, extra], axis=1)
    # ... and one whose fourth marker sits 4 cm from a point it turns about (a finger
    # beyond a wrist), so its distances to the others hardly change
    t = np.arange(pos.shape[0]) / 100.0
    wrist = extra[:, 1]
    wobble = Rotation.from_rotvec(np.outer(np.sin(3 * t), [0.0, 0.0, 0.5])).as_matrix()
    finger = wrist + np.einsum("tij,tjk,k->ti", rot, wobble, [0.0, -0.04, 0.0])
    loose = np.concatenate([thigh, extra[:, :1], finger[:, None]], axis=1)
    cols_all = np.arange(4)
    frame = cluster_frames(rigid)[1:]
    cost, _, _ = joint_cost(*parent, rigid, frame)
    assert _better_members([parent], rigid, cols_all, [], cost) is None
    frame = cluster_frames(loose)[1:]
    cost, _, _ = joint_cost(*parent, loose, frame)
    members, out, taken = _better_members([parent], loose, cols_all, [], cost)
    assert members.tolist() == [0, 1, 2] and out.tolist() == [3] and taken is None
    # three markers, the finger one of them, and the fourth thigh marker alone: they
    # change places
    both = np.concatenate([loose, extra[:, 1:]], axis=1)  # columns 0-3 as above, 4: thigh
    group = np.array([0, 1, 3])
    cost, _, _ = joint_cost(*parent, both[:, group], cluster_frames(both[:, group])[1:])
    members, out, taken = _better_members([parent], both, group, [np.array([4])], cost)
    assert sorted(members.tolist()) == [0, 1, 4] and out.tolist() == [3] and taken == 0


def test_only_bones_square_to_the_hinge_place_it():
    from skincap.solve.auto_hinges import _square_to

    axis = np.array([1.0, 0.0, 0.0])
    thigh = np.tile([0.02, 0.4, 0.0], (5, 1))  # 87 deg from the axis
    other_hip = np.tile([-0.18, 0.02, 0.03], (5, 1))  # along it (a pelvis)
    assert _square_to(thigh, axis)
    assert not _square_to(other_hip, axis)
    assert not _square_to(np.zeros((5, 3)), axis)


def test_markers_no_joint_can_join_are_named_and_left_out():
    import pytest

    from skincap.errors import SkincapWarning

    take, _, segments = _leg_take()
    pos = take.positions.copy()
    foot = [take.labels.index(m) for m in segments["F"]]
    others = [k for k in range(take.n_markers) if k not in foot]
    half = pos.shape[0] // 2
    pos[:half, foot] = np.nan  # the foot is seen only when the rest is not
    pos[half:, others] = np.nan
    with pytest.warns(SkincapWarning, match="F0, F1, F2"):
        found = auto_template(MarkerSet(pos, take.labels, 100.0))
    assert sorted(found.unjoined) == [["F0", "F1", "F2"]]
    assert all(not g[0].startswith("F") for g in found.groups)


def test_a_model_calibrated_on_another_take_is_refused():
    import pytest

    from skincap.errors import ValidationError
    from skincap.solve.auto import calibrate_auto

    take, _, _ = _leg_take()
    model = calibrate_auto(take)
    renamed = MarkerSet(take.positions, [f"x{k}" for k in range(take.n_markers)], 100.0)
    with pytest.raises(ValidationError, match="other labels"):
        solve_markers(renamed, model)
    with pytest.raises(ValidationError, match="other labels"):
        solve_markers(take.select(list(range(5))), model)


def _far_joint_take(n: int = 200):
    """A still three-marker parent and a rigid four-marker group turning about a point
    1 m beyond its markers: their joint costs nothing, but lies out of reach."""
    t = np.arange(n) / 100.0
    parent = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.05]])
    centre = np.array([0.0, 1.2, 0.0])
    local = np.array([[0.0, -1.0, 0.0], [0.08, -1.0, 0.0], [0.0, -1.05, 0.07], [0.05, -0.95, 0.04]])
    rot = Rotation.from_rotvec(
        np.radians(20.0) * np.sin(np.outer(t, [1.3, 2.1, 1.7]) + [0.0, 1.0, 2.0])
    ).as_matrix()
    group = centre + np.einsum("tij,kj->tki", rot, local)
    return np.concatenate([np.broadcast_to(parent, (n, 3, 3)), group], axis=1)


def test_a_far_joint_does_not_make_a_variant_look_better():
    """The change of members is scored as grow_tree ranks edges: a joint beyond
    MAX_JOINT_REACH_M counts only when the group's own cheapest joint is far too (it made
    the dense ROM take drop marker after marker and then swap two for ever)."""
    from skincap.solve.auto_tree import _better_members, _reach

    pos = _far_joint_take()
    parent = cluster_frames(pos[:, :3])[1:]
    group = np.arange(3, 7)
    whole, centre, _ = joint_cost(*parent, pos[:, group], cluster_frames(pos[:, group])[1:])
    assert whole < 1e-6 and _reach(*parent, centre, pos[:, group]) > 0.9
    # the group's cheapest near joint costs 4 cm: no variant beats it through a far one
    assert _better_members([parent], pos, group, [], 0.04) is None
    assert _better_members([parent], pos, group, [], 0.04, far_ok=True) is not None


def test_member_changes_that_come_back_to_groups_tried_stop(monkeypatch):
    """A change that would return the groups to a state already tried joins the group
    as it is (before: grow_tree swapped the same two markers for ever)."""
    import skincap.solve.auto_tree as auto_tree

    take, _, _ = _leg_take(n=200)
    pos = take.positions
    calls = []

    def swap(carriers, positions, group, singles, cost, **kwargs):
        # trade the group's last marker for the first loose one, again and again
        calls.append(group.copy())
        assert len(calls) < 20, "member changes loop"
        if not singles:
            return None
        return np.append(group[:-1], singles[0]), group[-1:], 0

    monkeypatch.setattr(auto_tree, "_better_members", swap)
    pelvis = np.arange(5)
    groups = [pelvis, np.array([5]), np.array([6, 7]), np.array([8, 9]), np.arange(10, 13)]
    found = auto_tree.grow_tree(pos, groups, 0)
    # the foot takes the loose pelvis marker once; trading it back would restore the
    # groups it started from, so the foot joins as it then is
    assert len(calls) == 2
    assert sorted(found.groups[4].tolist()) == [5, 10, 11]
    assert found.groups[1].tolist() == [12] and found.parents[4] >= 0
