"""The rest-pose check of a bare mesh: winding numbers and the misfit, against exact cases."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skincap.deform.skeletal.rest_pose import (
    MISFIT_FRACTION,
    RestPoseWarning,
    rest_pose_misfit,
    warn_if_rest_pose_differs,
    winding_numbers,
)
from skincap.types import Mesh, Skeleton


def _box(lo, hi) -> Mesh:  # type: ignore[no-untyped-def]
    """A closed box, triangles counter-clockwise seen from outside."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    v = lo + corners * (hi - lo)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return Mesh(v, faces)


BOX = _box([-0.2, 0.0, -0.2], [0.2, 1.0, 0.2])  # 1 m tall


def test_winding_number_is_one_inside_and_zero_outside():
    inside = np.array([[0.0, 0.5, 0.0], [0.19, 0.01, -0.19], [-0.1, 0.9, 0.1]])
    outside = np.array([[0.3, 0.5, 0.0], [0.0, 1.2, 0.0], [5.0, -3.0, 2.0]])
    w = winding_numbers(BOX.vertices, BOX.faces, np.vstack([inside, outside]), block=7)
    np.testing.assert_allclose(w, [1, 1, 1, 0, 0, 0], atol=1e-12)
    flipped = winding_numbers(BOX.vertices, BOX.faces[:, ::-1], inside)
    np.testing.assert_allclose(flipped, -1.0, atol=1e-12)  # inward faces: -1


def _arm_skeleton(elbow_x: float) -> Skeleton:
    # root in the box, an elbow at elbow_x, a hand end site further out
    names = ["root", "elbow", "hand_end"]
    offsets = np.array([[0.0, 0.5, 0.0], [elbow_x, 0.0, 0.0], [0.3, 0.0, 0.0]])
    return Skeleton(names, np.array([-1, 0, 1]), offsets)


def test_misfit_is_the_distance_of_the_worst_inner_joint_outside():
    misfit = rest_pose_misfit(BOX, _arm_skeleton(0.31))  # 11 cm beyond the x = 0.2 face
    assert misfit["worst_joint"] == "elbow" and misfit["joints_outside"] == ["elbow"]
    assert misfit["worst_distance_m"] == pytest.approx(0.11, abs=1e-12)
    assert misfit["height_m"] == pytest.approx(1.0) and misfit["misfit"]


def test_end_sites_and_joints_inside_do_not_count():
    misfit = rest_pose_misfit(BOX, _arm_skeleton(0.15))  # the hand end site is outside
    assert misfit["joints_outside"] == [] and misfit["worst_distance_m"] == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", RestPoseWarning)
        warn_if_rest_pose_differs(BOX, _arm_skeleton(0.15))
    just_under = 0.2 + 0.99 * MISFIT_FRACTION
    assert not rest_pose_misfit(BOX, _arm_skeleton(just_under))["misfit"]


def test_warning_says_which_joint_and_how_far():
    with pytest.warns(RestPoseWarning, match=r"joint 'elbow' is 11\.0 cm outside the body"):
        warn_if_rest_pose_differs(BOX, _arm_skeleton(0.31))


def test_procedural_body_in_its_own_pose_is_no_misfit():
    from skincap.deform.skeletal.bind import fit_skeleton_to_mesh, transform_skeleton
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=5000)
    skeleton = build_motion(body, "tpose", frames=2).skeleton
    scale, shift = fit_skeleton_to_mesh(skeleton, body)
    misfit = rest_pose_misfit(body, transform_skeleton(skeleton, scale, shift))
    assert not misfit["misfit"], misfit


def test_a_joint_beyond_any_coordinate_is_refused_by_name():
    """A stray BVH OFFSET (found by the CLI fuzz test: -1e308) must not overflow the
    distance query into a SciPy traceback."""
    from skincap.errors import ValidationError

    with pytest.raises(ValidationError, match="joint 'elbow' lies at"):
        rest_pose_misfit(BOX, _arm_skeleton(-1e300))
