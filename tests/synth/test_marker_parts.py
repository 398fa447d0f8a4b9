"""The true near-rigid part of every synthetic marker (truth/marker_parts.csv)."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.synth.inputs import build_body
from skincap.synth.marker_parts import PART_NAMES, PART_OF_LANDMARK, true_marker_parts
from skincap.synth.markers import sparse_marker_layout
from skincap.types import Mesh


@pytest.fixture(scope="module")
def body():
    return build_body("procedural", n_vertices=6000)


def test_seventeen_parts_cover_every_landmark():
    from skincap.deform.skeletal.name_maps import LANDMARKS

    assert len(PART_NAMES) == 17
    assert set(PART_OF_LANDMARK) == set(LANDMARKS)


def test_a_marker_on_a_vertex_takes_that_vertex_dominant_part(body):
    """A marker on a vertex bound only to the left knee joint is on the left shin."""
    skin = body.skin
    knee = skin.skeleton.names.index("LeftKnee")
    only_knee = np.flatnonzero(
        (skin.joint_weights.max(axis=1) > 0.999)
        & (
            skin.joint_indices[np.arange(skin.joint_indices.shape[0]), skin.joint_weights.argmax(1)]
            == knee
        )
    )
    assert only_knee.size
    vertex = int(only_knee[0])
    face = int(np.flatnonzero((body.faces == vertex).any(axis=1))[0])
    bary = (body.faces[face] == vertex).astype(float)[None]
    assert true_marker_parts(body, np.array([face]), bary) == ["shin_l"]


def test_makehuman_and_sparse_markers_get_parts():
    body = build_body("makehuman")
    layout = sparse_marker_layout(body, body.skin)
    parts = dict(zip(layout.labels, true_marker_parts(body, layout.face, layout.bary), strict=True))
    assert parts["LKNE"] in ("thigh_l", "shin_l")
    assert parts["RFHD"] == "head" and parts["LANK"] in ("shin_l", "foot_l")
    assert parts["LWRA"] in ("forearm_l", "hand_l")


def test_unknown_skeleton_or_no_skin_is_refused(body):
    bare = Mesh(body.vertices, body.faces)
    with pytest.raises(ValidationError, match="skin"):
        true_marker_parts(bare, np.array([0]), np.array([[1.0, 0, 0]]))
    with pytest.raises(ValidationError, match="bary"):
        true_marker_parts(body, np.array([0, 1]), np.ones((1, 3)) / 3)
