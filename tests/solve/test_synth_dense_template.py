"""The synth-dense template: generated from the synthetic dense layout, and it solves dense takes."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from skincap.data import path as data_path
from skincap.errors import SkincapWarning
from skincap.evaluate.solve import (
    DENSE_SEGMENT_WEIGHT,
    evaluate_synthetic,
    labelled_from_fragments,
    synth_dense_template,
    template_json_text,
)
from skincap.solve import load_template
from skincap.solve.templates import BUILTIN_TEMPLATES, detect_template


def test_synth_dense_has_synth_sparse_skeleton_and_only_dense_markers():
    dense, sparse = load_template("synth-dense"), load_template("synth-sparse")
    assert [(s.name, s.joint, s.parent) for s in dense.segments] == [
        (s.name, s.joint, s.parent) for s in sparse.segments
    ]
    for d, s in zip(dense.segments, sparse.segments, strict=True):
        assert d.limits_deg == s.limits_deg
        assert (d.centre or {}).get("kind") == (s.centre or {}).get("kind")
        # a hand or foot may be sparse; a link (the upper thorax) has no markers of its own
        assert len(d.markers) >= 3 or d.end is not None or d.link, d.name
    labels = dense.markers
    assert all(re.fullmatch(r"D\d{3}", m) for m in labels)
    assert len(labels) == len(set(labels)) > 250  # most of the ~350 markers ride a segment
    # every label a prior or an axis names is a dense marker of the template
    text = data_path(BUILTIN_TEMPLATES["synth-dense"]).read_text("utf-8")
    named = set(re.findall(r'"([A-Z][A-Z0-9]{1,4})"', text))
    assert named <= set(labels), sorted(named - set(labels))


def test_detect_template_picks_the_set_the_labels_fill():
    dense = load_template("synth-dense").markers
    assert detect_template(dense) == "synth-dense"
    sparse = [f"Sub:{m}" for m in load_template("synth-sparse").markers]
    assert detect_template(sparse, candidates=("synth-sparse", "synth-dense")) == "synth-sparse"
    assert detect_template(sparse + dense) == "synth-dense"  # the set the labels fill more
    assert detect_template(load_template("cmu41").markers) == "cmu41"
    assert detect_template(dense[:50]) is None  # too few of any set's markers
    assert detect_template(["foo", "bar"]) is None


@pytest.mark.slow
def test_the_checked_in_template_is_what_the_generator_makes():
    """Regenerated from the synthetic body and dense layout: the shipped file cannot drift."""
    made = synth_dense_template()
    assert made["layout"]["threshold"] == DENSE_SEGMENT_WEIGHT
    shipped = data_path(BUILTIN_TEMPLATES["synth-dense"]).read_text("utf-8")
    assert template_json_text(made) == shipped


#: A 120-frame dense squat (seed 0) measured 8.9 mm mean, 36.4 mm worst joint (the right
#: ankle, from its regression), 1.4 deg median flexion error, 1.1 mm RMS residual.
FRAMES = 120
JOINT_MEAN_BOUND_M = 0.015
JOINT_WORST_BOUND_M = 0.055
ANGLE_BOUND_DEG = 3.0
RMS_BOUND_M = 0.003


@pytest.mark.slow
def test_a_short_dense_take_is_solved_near_its_true_joints():
    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=20_000, seed=0)  # skincap synth's defaults
    clip = build_motion(body, "squat", frames=FRAMES, seed=0)
    take = generate_capture(body, clip, markers="dense", seed=0)
    markers = labelled_from_fragments(take.capture, take.fragment_truth)
    # the template's segments agree with the true part of every marker it uses
    part = dict(zip(take.truth.labels, take.marker_parts, strict=False))
    for seg in load_template("synth-dense").segments:
        want = {"thorax": {"chest", "upper_chest"}}.get(
            seg.name, {seg.name.replace("shank", "shin")}
        )
        assert {part[m] for m in seg.markers} <= want, seg.name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        result = evaluate_synthetic(markers, take.motion)  # template detected from the labels
    assert result["template"] == "synth-dense"
    assert result["joint_mean_m"] < JOINT_MEAN_BOUND_M
    assert result["joint_worst_m"] < JOINT_WORST_BOUND_M
    assert result["angle_median_deg"] < ANGLE_BOUND_DEG
    assert result["residual"]["rms_m"] < RMS_BOUND_M
    assert np.isfinite(result["residual"]["max_m"])


def _parts_file(folder, parts):
    (folder / "truth").mkdir(parents=True)
    rows = "".join(f"{m},{p}\n" for m, p in parts.items())
    (folder / "truth" / "marker_parts.csv").write_text("marker,part\n" + rows, encoding="utf-8")


def _true_parts(share_right):
    """Marker -> part as on a body where ``share_right`` of synth-dense's markers ride
    their template segment (the rest put on the head, or the pelvis for head markers)."""
    from skincap.evaluate.solve import _SEGMENT_OF_PART

    part_of = {seg: part for part, seg in _SEGMENT_OF_PART.items() if seg is not None}
    pairs = [(m, s.name) for s in load_template("synth-dense").segments for m in s.markers]
    n_right = int(round(share_right * len(pairs)))
    return {
        m: part_of[seg] if k < n_right else ("pelvis" if seg == "head" else "head")
        for k, (m, seg) in enumerate(pairs)
    }


def test_synth_dense_is_checked_against_the_take_body(tmp_path):
    from skincap.errors import FormatError
    from skincap.evaluate.solve import SYNTH_DENSE_MIN_AGREEMENT, synth_dense_body_check
    from skincap.workflows.solve import check_synth_dense_body

    total = len(load_template("synth-dense").markers)
    assert synth_dense_body_check(_true_parts(1.0)) == (total, total)
    assert synth_dense_body_check(_true_parts(0.5))[0] == round(0.5 * total)
    assert synth_dense_body_check({}) == (0, total)
    good, other = tmp_path / "default_body", tmp_path / "seed_1"
    _parts_file(good, _true_parts(1.0))
    _parts_file(other, _true_parts(SYNTH_DENSE_MIN_AGREEMENT - 0.05))
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkincapWarning)
        check_synth_dense_body(good)  # the folder, its capture or its truth markers
        check_synth_dense_body(good / "capture.c3d")
        check_synth_dense_body(good / "truth" / "markers.c3d")
    for where in (other, other / "capture.c3d", other / "truth" / "markers.c3d"):
        with pytest.raises(FormatError, match=r"fits only the body of .*--seed 0.* of its"):
            check_synth_dense_body(where)
    with pytest.warns(SkincapWarning, match="cannot be checked"):
        check_synth_dense_body(tmp_path / "loose.c3d")
