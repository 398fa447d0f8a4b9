"""Batched inverse kinematics on an exact rigid chain."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.solve.ik import _exp, _log, model_markers, solve_poses

PARENTS = np.array([-1, 0, 1, 1])
OFFSETS = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.3, 0.1, 0.0], [-0.3, 0.1, 0.0]])
SEG = np.array([0, 0, 0, 1, 1, 1, 2, 2, 3, 3, 3])
LOCAL = np.random.default_rng(0).normal(scale=0.08, size=(SEG.size, 3))


def _poses(rng, t):
    rot = (
        Rotation.from_rotvec(rng.normal(scale=0.7, size=(t * 4, 3))).as_matrix().reshape(t, 4, 3, 3)
    )
    root = rng.normal(scale=1.0, size=(t, 3))
    return rot, root


def test_recovers_exact_poses_from_a_perturbed_start():
    rng = np.random.default_rng(1)
    rot, root = _poses(rng, 300)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    kick = (
        Rotation.from_rotvec(rng.normal(scale=0.15, size=(300 * 4, 3)))
        .as_matrix()
        .reshape(300, 4, 3, 3)
    )
    got_rot, got_root = solve_poses(
        PARENTS, OFFSETS, SEG, LOCAL, y, kick @ rot, root + 0.03, iterations=30, tolerance=1e-16
    )
    fit = model_markers(PARENTS, OFFSETS, SEG, LOCAL, got_rot, got_root)
    assert np.abs(fit - y).max() < 1e-7
    np.testing.assert_allclose(got_rot, rot, atol=1e-6)
    np.testing.assert_allclose(got_root, root, atol=1e-7)


def test_missing_markers_drop_out_and_poses_never_go_nan():
    rng = np.random.default_rng(2)
    rot, root = _poses(rng, 120)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    y[:, 3] = np.nan  # one marker of segment 1 gone: still determined via the chain
    y[40:60, 8:11] = np.nan  # segment 3 unseen for 20 frames
    init = rot.copy()
    init[40:60, 3] = np.nan  # and no initial pose for it there: warm start fills it
    got_rot, got_root = solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, init, root, tolerance=1e-16)
    assert np.isfinite(got_rot).all() and np.isfinite(got_root).all()
    seen = np.ones(120, dtype=bool)
    seen[40:60] = False
    fit = model_markers(PARENTS, OFFSETS, SEG, LOCAL, got_rot, got_root)
    ok = np.isfinite(y).all(axis=2)
    assert np.abs((fit - y)[ok]).max() < 1e-7
    # the hidden segment keeps the pose of the frame before it vanished
    np.testing.assert_allclose(
        got_rot[40:60, 3], np.repeat(got_rot[39:40, 3], 20, axis=0), atol=1e-6
    )
    # determined segments are exact everywhere
    np.testing.assert_allclose(got_rot[:, :3], rot[:, :3], atol=1e-6)


def test_rotations_stay_orthonormal():
    rng = np.random.default_rng(3)
    rot, root = _poses(rng, 50)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root) + rng.normal(
        scale=0.002, size=(50, SEG.size, 3)
    )
    got_rot, _ = solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root)
    eye = np.einsum("tsji,tsjk->tsik", got_rot, got_rot)
    assert np.abs(eye - np.eye(3)).max() < 1e-9
    assert np.allclose(np.linalg.det(got_rot), 1.0)


# a link (segment 1: no markers of its own) between the root and two marked segments
LINK_PARENTS = np.array([-1, 0, 1, 1])
LINK_OFFSETS = np.array([[0.0, 0.0, 0.0], [0.0, 0.4, 0.0], [0.2, 0.1, 0.0], [-0.2, 0.1, 0.0]])
LINK_SEG = np.array([0, 0, 0, 2, 2, 2, 3, 3, 3])
LINK_LOCAL = np.random.default_rng(5).normal(scale=0.08, size=(LINK_SEG.size, 3))


def _link_take(link_angle_rad, t=80, seed=6):
    rng = np.random.default_rng(seed)
    rot, root = _poses(rng, t)
    # the link turns a fixed angle from its parent about a random axis per frame
    axis = rng.normal(size=(t, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    rot[:, 1] = Rotation.from_rotvec(link_angle_rad * axis).as_matrix() @ rot[:, 0]
    y = model_markers(LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, rot, root)
    init = rot.copy()
    init[:, 1] = rot[:, 0]  # a link starts as its parent
    return rot, root, y, init


def _relative_angle(rot):
    rel = rot[:, 1] @ rot[:, 0].transpose(0, 2, 1)
    return Rotation.from_matrix(rel).magnitude()


def test_a_soft_link_lets_its_children_translate_and_fits_them():
    rot, root, y, init = _link_take(0.3)
    stiff = np.array([0.0, 1e-4, 0.0, 0.0])
    got_rot, got_root = solve_poses(
        LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, y, init, root,
        iterations=40, tolerance=1e-16, link_stiffness=stiff,
    )  # fmt: skip
    fit = model_markers(LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, got_rot, got_root)
    # the spring costs (1e-4 m/rad * 0.3 rad)^2: the markers fit to well under a millimetre
    assert np.abs(fit - y).max() < 1e-4
    # the two directions the children see are recovered: the link's angle is close
    assert np.abs(_relative_angle(got_rot) - 0.3).max() < 0.05
    # without the link's freedom (a stiff spring) the same take cannot be fitted
    stiff_rot, stiff_root = solve_poses(
        LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, y, init, root,
        iterations=40, tolerance=1e-16, link_stiffness=np.array([0.0, 100.0, 0.0, 0.0]),
    )  # fmt: skip
    assert _relative_angle(stiff_rot).max() < 1e-2
    rigid = model_markers(LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, stiff_rot, stiff_root)
    assert np.abs(rigid - y).max() > 0.02


def test_a_resting_link_stays_with_its_parent_and_the_fit_is_exact():
    rot, root, y, init = _link_take(0.0)
    got_rot, got_root = solve_poses(
        LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, y, init, root,
        tolerance=1e-16, link_stiffness=np.array([0.0, 0.03, 0.0, 0.0]),
    )  # fmt: skip
    fit = model_markers(LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, got_rot, got_root)
    assert np.abs(fit - y).max() < 1e-7
    assert _relative_angle(got_rot).max() < 1e-6  # its undetermined twist is held too


def test_link_stiffness_is_validated():
    rot, root, y, init = _link_take(0.0, t=5)
    with pytest.raises(ValidationError, match="link_stiffness"):
        solve_poses(
            LINK_PARENTS, LINK_OFFSETS, LINK_SEG, LINK_LOCAL, y, init, root,
            link_stiffness=np.array([0.0, -1.0, 0.0, 0.0]),
        )  # fmt: skip


def test_log_inverts_exp_up_to_a_half_turn():
    rng = np.random.default_rng(8)
    axis = rng.normal(size=(500, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.concatenate([rng.uniform(0, np.pi - 1e-6, 497), [0.0, 1e-10, np.pi - 1e-9]])
    vec = axis * angle[:, None]
    np.testing.assert_allclose(_log(_exp(vec)), vec, atol=1e-7)
    np.testing.assert_allclose(_log(Rotation.from_rotvec(vec).as_matrix()), vec, atol=1e-7)


def test_the_warm_start_pass_reaches_the_same_poses():
    # a smooth motion: odd frames start from their neighbours' midpoint
    t = 90
    phase = np.linspace(0, 2.0, t)[:, None, None]
    axes = np.random.default_rng(9).normal(scale=0.6, size=(1, 4, 3))
    rot = (
        Rotation.from_rotvec((np.sin(phase) * axes).reshape(-1, 3)).as_matrix().reshape(t, 4, 3, 3)
    )
    root = np.stack([np.sin(phase[:, 0, 0]), np.ones(t), 0.2 * phase[:, 0, 0]], axis=1)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    kick = Rotation.from_rotvec(np.full((t * 4, 3), 0.1)).as_matrix().reshape(t, 4, 3, 3)
    for warm in (True, False):
        got_rot, got_root = solve_poses(
            PARENTS, OFFSETS, SEG, LOCAL, y, kick @ rot, root + 0.02,
            iterations=30, tolerance=1e-16, relative_tolerance=0.0, warm_start=warm,
        )  # fmt: skip
        np.testing.assert_allclose(got_rot, rot, atol=1e-6)
        np.testing.assert_allclose(got_root, root, atol=1e-7)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_a_robust_loss_keeps_one_wandering_marker_from_pulling_its_segment(loss):
    # noise-free poses, then one marker of segment 1 slides 15 cm in a third of the frames
    rng = np.random.default_rng(10)
    rot, root = _poses(rng, 90)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    bad = np.zeros((90, SEG.size), dtype=bool)
    bad[::3, 4] = True
    y[bad] += 0.15 * Rotation.random(30, random_state=11).apply([1.0, 0.0, 0.0])
    fits = {}
    for name in ("squared", loss):
        got_rot, got_root = solve_poses(
            PARENTS, OFFSETS, SEG, LOCAL, y, rot, root,
            iterations=40, tolerance=1e-16, loss=name, loss_scale=0.01,
        )  # fmt: skip
        fit = model_markers(PARENTS, OFFSETS, SEG, LOCAL, got_rot, got_root)
        fits[name] = np.linalg.norm(fit - y, axis=2)[~bad].max(), got_rot
    # squared: the other markers take centimetres of the slide (5 cm here)
    assert fits["squared"][0] > 0.04
    # Huber bounds the slide's pull to about the scale; Cauchy's falls off with distance,
    # so the other markers stay within a millimetre of their true places
    assert fits[loss][0] < (0.015 if loss == "huber" else 1e-3)
    assert np.abs(fits[loss][1] - rot)[~bad[:, 4]].max() < 1e-6  # clean frames exact
    shift = np.abs(fits[loss][1] - rot).max() / np.abs(fits["squared"][1] - rot).max()
    assert shift < (0.6 if loss == "huber" else 0.02)


def test_loss_and_its_scale_are_validated():
    rot, root = _poses(np.random.default_rng(12), 4)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    with pytest.raises(ValidationError, match="loss"):
        solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, loss="l1")
    with pytest.raises(ValidationError, match="loss_scale"):
        solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, loss="huber", loss_scale=0.0)


def test_refitted_offsets_are_exact_on_exact_poses_and_lower_the_cost_of_wrong_ones():
    from skincap.solve.ik import refit_marker_offsets

    rng = np.random.default_rng(13)
    rot, root = _poses(rng, 60)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    y[rng.random((60, SEG.size)) < 0.2] = np.nan  # missing samples drop out
    y[:, 7] = np.nan  # never seen: keeps the fallback
    fallback = LOCAL + 0.01
    got = refit_marker_offsets(PARENTS, OFFSETS, SEG, y, rot, root, fallback)
    seen = np.arange(SEG.size) != 7
    np.testing.assert_allclose(got[seen], LOCAL[seen], atol=1e-12)
    np.testing.assert_array_equal(got[7], fallback[7])
    # from offsets 1 cm off: solve, refit, solve again -- the squared cost only falls
    wrong = LOCAL + rng.normal(scale=0.01, size=LOCAL.shape)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    costs, offs = [], wrong
    r, o = rot, root
    for _ in range(4):
        r, o = solve_poses(PARENTS, OFFSETS, SEG, offs, y, r, o, tolerance=1e-16)
        costs.append(np.sum((model_markers(PARENTS, OFFSETS, SEG, offs, r, o) - y) ** 2))
        offs = refit_marker_offsets(PARENTS, OFFSETS, SEG, y, r, o, offs)
    assert all(b <= a * (1 + 1e-9) for a, b in zip(costs, costs[1:], strict=False))
    assert costs[-1] < 0.5 * costs[0]


def _hinge_take(t, flex_rad, seed=14):
    """Segment 1 bends about its parent's x axis by ``flex_rad (T,)``; the rest random."""
    rng = np.random.default_rng(seed)
    rot, root = _poses(rng, t)
    rot[:, 1] = rot[:, 0] @ Rotation.from_rotvec(flex_rad[:, None] * [1.0, 0.0, 0.0]).as_matrix()
    return rot, root


def _flexion(rot):
    rel = np.einsum("tji,tjk->tik", rot[:, 0], rot[:, 1])
    return Rotation.from_matrix(rel).as_rotvec()[:, 0]


def test_a_joint_limit_holds_and_leaves_poses_inside_it_exact():
    t = 60
    flex = np.linspace(-0.4, 1.2, t)  # -23 to 69 deg
    rot, root = _hinge_take(t, flex)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    limits = np.full((4, 3, 2), np.nan)
    limits[1, 0] = [0.0, 1.0]  # segment 1: 0 to 57 deg about its parent's x
    kw = dict(iterations=40, tolerance=1e-16, relative_tolerance=0.0)
    free_rot, _ = solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, **kw)
    np.testing.assert_allclose(_flexion(free_rot), flex, atol=1e-6)  # no limit: the truth
    got_rot, got_root = solve_poses(
        PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, joint_limits=limits, **kw
    )
    got = _flexion(got_rot)
    inside = (flex >= 0.0) & (flex <= 1.0)
    np.testing.assert_allclose(got[inside], flex[inside], atol=1e-6)
    # beyond the limit the markers pull against it: it gives way by under 0.3 degree
    excess = np.abs(got - np.clip(flex, 0.0, 1.0))[~inside]
    assert excess.max() < np.radians(0.3)
    # a softer limit gives way more
    soft_rot, _ = solve_poses(
        PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, joint_limits=limits, limit_stiffness=1.0, **kw
    )
    soft_excess = np.abs(_flexion(soft_rot) - np.clip(flex, 0.0, 1.0))[~inside]
    assert np.median(soft_excess) > 5 * np.median(excess)
    assert soft_excess.max() < np.radians(3.0)


def test_joint_limits_are_validated():
    rot, root = _poses(np.random.default_rng(15), 4)
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    bad = np.full((4, 3, 2), np.nan)
    bad[1, 0] = [1.0, 0.0]
    with pytest.raises(ValidationError, match="joint_limits"):
        solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, joint_limits=bad)
    with pytest.raises(ValidationError, match="joint_limits"):
        solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, joint_limits=np.zeros((4, 3)))
