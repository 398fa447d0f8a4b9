"""Skeleton solving measured against ground truth (issue #17's targets).

* **Synthetic takes** (``skincap synth --markers sparse|dense``, solved with the
  synth-sparse or synth-dense template their labels match): the capture's fragments are
  labelled with their true labels (:func:`labelled_from_fragments`: perfect labelling,
  but the occlusion, noise and soft tissue of the capture stay), solved, and compared
  with ``truth/motion.bvh``: the joint-position error per joint (hips, knees, ankles,
  shoulders, elbows, wrists; the synthetic skeleton's joints of those names are the
  true joint centres), the joint-angle error (knee and elbow flexion: the angle between
  the two bones meeting at the joint, free of any choice of anatomical axes), and the
  marker residual.
* **Real captures**: the marker residual, overall and its distribution per marker.
* **``--template auto``** on a synthetic take: the share of markers whose group's
  majority true segment is their own, and for each listed joint the error of the
  nearest joint found and of the found joint between the same two segments (with the
  method that placed it).

Nothing here reads files; :mod:`skincap.workflows.solve` does.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.kinematics import joint_positions
from skincap.solve import load_template, solve_markers
from skincap.solve.auto import auto_template, calibrate_auto
from skincap.solve.ik import ik_backend, solve_poses
from skincap.solve.templates import BUILTIN_TEMPLATES, Template, detect_template, strip_prefix
from skincap.types import MarkerSet, Motion

__all__ = [
    "TARGETS",
    "EVAL_JOINTS",
    "labelled_from_fragments",
    "joint_errors",
    "flexion_errors_deg",
    "residual_distribution",
    "evaluate_synthetic",
    "evaluate_real",
    "evaluate_auto",
    "matched_joint_errors",
    "group_accuracy",
    "ik_frames_per_second",
    "targets_table",
    "DENSE_SEGMENT_WEIGHT",
    "synth_dense_template",
    "synth_dense_body_check",
    "SYNTH_DENSE_MIN_AGREEMENT",
    "template_json_text",
]

#: The joints the issue lists, by their names in the synthetic (CMU bvh11) skeleton
#: and in the solved (Biovision) one -- the same names.
EVAL_JOINTS: tuple[str, ...] = (
    "LeftHip", "RightHip", "LeftKnee", "RightKnee", "LeftAnkle", "RightAnkle",
    "LeftShoulder", "RightShoulder", "LeftElbow", "RightElbow", "LeftWrist", "RightWrist",
)  # fmt: skip

#: (proximal, joint, distal) triples whose included angle is the flexion angle.
FLEXION: tuple[tuple[str, str, str], ...] = (
    ("LeftHip", "LeftKnee", "LeftAnkle"),
    ("RightHip", "RightKnee", "RightAnkle"),
    ("LeftShoulder", "LeftElbow", "LeftWrist"),
    ("RightShoulder", "RightElbow", "RightWrist"),
)

#: Issue #17's targets.
TARGETS: dict[str, float] = {
    "real_rms_m": 0.012,
    "real_max_m": 0.04,
    "joint_mean_m": 0.010,
    "joint_worst_m": 0.020,
    "angle_median_deg": 3.0,
    "auto_share": 0.95,
    "auto_joint_m": 0.020,
    "ik_frames_per_second": 2000.0,
}


def labelled_from_fragments(capture: MarkerSet, fragment_truth: dict[str, str]) -> MarkerSet:
    """The capture with every fragment moved to its true marker's column.

    Parameters
    ----------
    capture : MarkerSet
        Labelled first-frame columns plus ``*N`` fragments (``skincap synth``'s
        ``capture.c3d``), metres.
    fragment_truth : dict
        Column label -> true marker label or ``ghost`` (``truth/fragments.csv``).

    Returns
    -------
    MarkerSet
        One column per true marker (sorted labels); NaN where no fragment saw it.
    """
    labels = sorted({v for v in fragment_truth.values() if v != "ghost"})
    index = {s: k for k, s in enumerate(labels)}
    pos = np.full((capture.n_frames, len(labels), 3), np.nan)
    for k, label in enumerate(capture.labels):
        true = fragment_truth.get(label)
        if true not in index:
            continue
        col = capture.positions[:, k]
        seen = np.isfinite(col).all(axis=1)
        pos[seen, index[true]] = col[seen]
    return MarkerSet(pos, labels, capture.rate, meta=dict(capture.meta))


def joint_errors(
    truth: Motion, solved: Motion, joints: tuple[str, ...] = EVAL_JOINTS
) -> dict[str, dict[str, float]]:
    """Per joint: mean and max distance (metres) between solved and true joint positions."""
    tj = joint_positions(truth)
    sj = joint_positions(solved)
    n = min(tj.shape[0], sj.shape[0])
    out = {}
    for name in joints:
        if name in truth.skeleton.names and name in solved.skeleton.names:
            d = np.linalg.norm(
                tj[:n, truth.skeleton.index(name)] - sj[:n, solved.skeleton.index(name)], axis=1
            )
            out[name] = {"mean_m": float(d.mean()), "max_m": float(d.max())}
    return out


def _included_angle(pos: np.ndarray, names: list[str], triple: tuple[str, str, str]) -> np.ndarray:
    a, b, c = (pos[:, names.index(n)] for n in triple)
    u, v = b - a, c - b
    cos = np.einsum("ti,ti->t", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def flexion_errors_deg(truth: Motion, solved: Motion) -> dict[str, dict[str, float]]:
    """Per knee and elbow: median and max absolute flexion-angle error (degrees)."""
    tj, sj = joint_positions(truth), joint_positions(solved)
    n = min(tj.shape[0], sj.shape[0])
    out = {}
    for triple in FLEXION:
        if all(x in truth.skeleton.names for x in triple) and all(
            x in solved.skeleton.names for x in triple
        ):
            e = np.abs(
                _included_angle(tj[:n], truth.skeleton.names, triple)
                - _included_angle(sj[:n], solved.skeleton.names, triple)
            )
            out[triple[1]] = {"median_deg": float(np.median(e)), "max_deg": float(e.max())}
    return out


def residual_distribution(residuals: np.ndarray, labels: list[str]) -> dict[str, Any]:
    """Overall RMS/max and per-marker RMS, median, 95th percentile and max (metres)."""
    r = residuals
    seen = np.isfinite(r)
    per = {}
    for k, label in enumerate(labels):
        v = r[seen[:, k], k]
        if v.size:
            per[label] = {
                "rms_m": float(np.sqrt(np.mean(v**2))),
                "median_m": float(np.median(v)),
                "p95_m": float(np.percentile(v, 95)),
                "max_m": float(v.max()),
            }
    allv = r[seen]
    return {
        "rms_m": float(np.sqrt(np.mean(allv**2))) if allv.size else None,
        "max_m": float(allv.max()) if allv.size else None,
        "p95_m": float(np.percentile(allv, 95)) if allv.size else None,
        "per_marker": per,
    }


def ik_frames_per_second(result: Any, markers: MarkerSet, repeat: int = 3) -> dict[str, Any]:
    """Frames per second of the inverse kinematics of ``result``'s solve on ``markers``.

    Times :func:`~skincap.solve.ik.solve_poses` over all the take's frames with the
    options the solve used (its model, link springs, loss, joint limits; the default
    backend, as ``skincap solve`` runs it), best of ``repeat``: one pass from the
    calibration's poses (the figure to hold against a per-frame IK), and the
    solve's passes in turn (``1 + refine_offsets``, each from the last one's poses,
    as :func:`~skincap.solve.pipeline.solve_markers` runs them; the offsets' refit
    between them is not IK and not timed, nor is the re-solve of frames with a
    rejected jump, which has none on a clean take).

    Returns
    -------
    dict
        ``wall`` and ``cpu``: one pass's frames per second of elapsed and of this
        process's CPU time (a machine loaded by other work distorts CPU time far
        less; the solver is single-threaded with ``OPENBLAS_NUM_THREADS=1``);
        ``passes``, and ``solve_wall`` / ``solve_cpu``: the take's frames over the
        time of all the passes; ``backend``: ``"numba"`` or ``"numpy"``.
    """
    model = result.model
    measured = markers.positions[:, model.marker_columns]
    ik = getattr(result, "ik", {}) or {}
    options: dict[str, Any] = {
        "link_stiffness": model.link_stiffness,
        "loss": ik.get("loss", "squared"),
        "loss_scale": ik.get("loss_scale_m", 0.02),
    }
    if ik.get("joint_limits"):
        options.update(joint_limits=model.joint_limits, bone_axes=model.bone_axes)
    passes = 1 + int(ik.get("refine_offsets", 1))
    backend = ik_backend()

    def solve(rot: np.ndarray, root: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return solve_poses(
            model.segment_parents, model.joint_offsets, model.marker_segments,
            model.marker_offsets, measured, rot, root, backend=backend, **options,
        )  # fmt: skip

    best = {"wall": np.inf, "cpu": np.inf, "solve_wall": np.inf, "solve_cpu": np.inf}
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        rot, root = solve(model.init_rotations, model.init_origins)
        w1, c1 = time.perf_counter(), time.process_time()
        for _ in range(passes - 1):
            rot, root = solve(rot, root)
        w2, c2 = time.perf_counter(), time.process_time()
        spans = {"wall": w1 - w0, "cpu": c1 - c0, "solve_wall": w2 - w0, "solve_cpu": c2 - c0}
        best = {k: min(best[k], spans[k]) for k in best}
    frames = markers.n_frames
    out: dict[str, Any] = {k: float(frames / max(v, 1e-9)) for k, v in best.items()}
    out.update(passes=passes, backend=backend)
    return out


def _template_of(markers: MarkerSet, template: str | None) -> str:
    """``template``, or the built-in one the take's labels fill (synth-sparse, synth-dense)."""
    if template is not None:
        return template
    found = detect_template(markers.labels, candidates=("synth-sparse", "synth-dense"))
    if found is None:
        raise ValidationError(
            "synthetic take: its labels match no built-in template (give one explicitly)"
        )
    return found


def evaluate_synthetic(
    markers: MarkerSet, truth: Motion, template: str | None = None
) -> dict[str, Any]:
    """Solve a labelled synthetic take and compare it with its true motion.

    ``template`` None: the built-in template its labels match (:func:`detect_template`).
    """
    template = _template_of(markers, template)
    result = solve_markers(markers, template)
    joints = joint_errors(truth, result.motion)
    means = [v["mean_m"] for v in joints.values()]
    angles = flexion_errors_deg(truth, result.motion)
    tj, sj = joint_positions(truth), joint_positions(result.motion)
    all_angles = []
    for triple in FLEXION:
        if all(x in truth.skeleton.names for x in triple) and all(
            x in result.motion.skeleton.names for x in triple
        ):
            all_angles.append(
                np.abs(
                    _included_angle(tj, truth.skeleton.names, triple)
                    - _included_angle(sj, result.motion.skeleton.names, triple)
                )
            )
    residual = residual_distribution(result.residuals, result.model.marker_labels)
    return {
        "frames": markers.n_frames,
        "template": template,
        "joint_errors": joints,
        "joint_mean_m": float(np.mean(means)) if means else None,
        "joint_worst": max(joints, key=lambda k: joints[k]["mean_m"]) if joints else None,
        "joint_worst_m": float(max(means)) if means else None,
        "flexion_errors": angles,
        "angle_median_deg": float(np.median(np.concatenate(all_angles))) if all_angles else None,
        "residual": residual,
        "methods": {
            result.model.template.segment(s).joint: m for s, m in result.model.methods.items()
        },
        # how well the take determines each functionally fitted centre (radians RMS)
        "fit_singular_values": {
            result.model.template.segment(s).joint: v
            for s, v in result.model.fit_singular_values.items()
        },
        "ik_frames_per_second": ik_frames_per_second(result, markers),
        "markers": len(result.model.marker_labels),
    }


def evaluate_real(markers: MarkerSet, template: str = "cmu41") -> dict[str, Any]:
    """Solve a real labelled capture: the marker residual and its distribution per marker."""
    result = solve_markers(markers, template)
    return {
        "frames": markers.n_frames,
        "template": template,
        "residual": residual_distribution(result.residuals, result.model.marker_labels),
        "methods": {
            result.model.template.segment(s).joint: m for s, m in result.model.methods.items()
        },
        # how well the take determines each functionally fitted centre (radians RMS)
        "fit_singular_values": {
            result.model.template.segment(s).joint: v
            for s, v in result.model.fit_singular_values.items()
        },
        "ik_frames_per_second": ik_frames_per_second(result, markers),
        "markers": len(result.model.marker_labels),
    }


def group_accuracy(
    groups: list[list[str]], true_segment: dict[str, str]
) -> tuple[float | None, dict[str, dict[str, int]], dict[str, str]]:
    """How well marker groups found automatically match the true segments.

    Each group stands for the true segment most of its known markers ride (its
    majority); a marker is right when its own true segment is its group's.

    Parameters
    ----------
    groups : list of lists of str
        Marker labels per found group (``Subject:`` prefixes are stripped).
    true_segment : dict
        Marker label -> its true segment; markers not in it are not counted.

    Returns
    -------
    share : float or None
        Right markers over counted markers (None when none is counted).
    per_segment : dict
        True segment -> ``{"markers": n, "right": k}``.
    misplaced : dict
        Wrong marker -> the segment its group stands for.
    """
    per: dict[str, dict[str, int]] = {}
    misplaced: dict[str, str] = {}
    for group in groups:
        labels = [strip_prefix(m) for m in group]
        known = [m for m in labels if m in true_segment]
        if not known:
            continue
        segs = [true_segment[m] for m in known]
        majority = max(sorted(set(segs)), key=segs.count)
        for m, seg in zip(known, segs, strict=True):
            entry = per.setdefault(seg, {"markers": 0, "right": 0})
            entry["markers"] += 1
            if seg == majority:
                entry["right"] += 1
            else:
                misplaced[m] = majority
    total = sum(v["markers"] for v in per.values())
    right = sum(v["right"] for v in per.values())
    return (right / total if total else None), per, misplaced


def matched_joint_errors(
    groups: list[list[str]],
    parents: np.ndarray,
    template: Template,
    truth: Motion,
    solved: Motion,
) -> dict[str, dict[str, Any]]:
    """Each true joint's error at the auto joint that joins the same two segments.

    A found group stands for the true segment most of its markers ride
    (:func:`group_accuracy`'s majority); the true joint between segments ``P`` and
    ``C`` (``C``'s ``joint`` in ``template``) is matched to the found joint whose child
    group stands for ``C`` and whose parent group stands for ``P`` (past a ``link``
    parent, which no group stands for: its own parent). Stricter than the
    nearest joint: a joint the tree put between the wrong segments is not found.

    Parameters
    ----------
    groups : list of lists of str
        Marker labels per found segment, in the found template's order.
    parents : (S,) int
        Each found segment's parent (-1: root).
    template : Template
        The true segments (the take's named template).
    truth, solved : Motion
        The true motion and the one solved with the found template (its joints are
        ``joint_<segment index>``).

    Returns
    -------
    dict
        True joint name -> ``{"auto_joint", "auto_segment", "mean_m", "max_m"}`` (metres),
        or ``{"auto_joint": None}`` where no found joint joins those segments; only the
        joints of :data:`EVAL_JOINTS` the true skeleton has.
    """
    true_segment = {m: s.name for s in template.segments for m in s.markers}
    stands_for = []
    for group in groups:
        segs = [true_segment[m] for m in (strip_prefix(x) for x in group) if m in true_segment]
        stands_for.append(max(sorted(set(segs)), key=segs.count) if segs else None)
    tj, sj = joint_positions(truth), joint_positions(solved)
    n = min(tj.shape[0], sj.shape[0])
    out: dict[str, dict[str, Any]] = {}
    for spec in template.segments[1:]:
        if spec.joint not in EVAL_JOINTS or spec.joint not in truth.skeleton.names:
            continue
        # a link (a bend of its parent with no markers of its own, e.g. an upper
        # thorax) is no group: the joint hangs from the segment the link hangs from
        true_parent = spec.parent
        while true_parent is not None and template.segment(true_parent).link:
            true_parent = template.segment(true_parent).parent
        hits = [
            c for c, p in enumerate(parents)
            if p >= 0 and stands_for[c] == spec.name and stands_for[p] == true_parent
        ]  # fmt: skip
        name = f"joint_{hits[0]}" if hits else None
        if name is None or name not in solved.skeleton.names:
            out[spec.joint] = {"auto_joint": None}
            continue
        d = np.linalg.norm(
            sj[:n, solved.skeleton.index(name)] - tj[:n, truth.skeleton.index(spec.joint)], axis=1
        )
        out[spec.joint] = {
            "auto_joint": name,
            "auto_segment": f"segment_{hits[0]}",
            "mean_m": float(d.mean()),
            "max_m": float(d.max()),
        }
    return out


def evaluate_auto(markers: MarkerSet, truth: Motion, template: str | None = None) -> dict[str, Any]:
    """``--template auto`` on a labelled synthetic take against the true segments and joints.

    The true segments are ``template``'s (None: the built-in one the labels match).
    Returns the groups found (``groups``; ``unjoined``: groups no joint joined, counted
    in the share too), the share of markers in their true segment
    (:func:`group_accuracy`), each listed joint's error at the nearest solved joint
    (``nearest_joint_error_m``, ``joint_mean_m``) and at the auto joint between the same
    two segments with how it was found (``matched_joints``: the calibration's method and
    how the tree framed the child; :func:`matched_joint_errors`), and the residual.
    """
    tpl = load_template(_template_of(markers, template))
    true_segment = {m: s.name for s in tpl.segments for m in s.markers}
    found = auto_template(markers)
    share, per_segment, misplaced = group_accuracy(found.groups + found.unjoined, true_segment)
    out: dict[str, Any] = {
        "groups": found.groups,
        "unjoined": found.unjoined,
        "template": tpl.name,
        # a link (no markers of its own: a bend of its parent) is no segment to find
        "true_segments": sum(not s.link for s in tpl.segments),
        "share_in_true_segment": share,
        "per_segment": per_segment,
        "misplaced": misplaced,
    }
    try:
        result = solve_markers(markers, calibrate_auto(markers, found))
    except Exception as exc:  # noqa: BLE001 - the evaluation reports any failure as data
        out["error"] = str(exc)
        return out
    tj, sj = joint_positions(truth), joint_positions(result.motion)
    n = min(tj.shape[0], sj.shape[0])
    per = {}
    for name in EVAL_JOINTS:
        if name in truth.skeleton.names:
            d = np.linalg.norm(sj[:n] - tj[:n, truth.skeleton.index(name)][:, None], axis=2).mean(
                axis=0
            )
            per[name] = float(d.min())
    out["nearest_joint_error_m"] = per
    out["joint_mean_m"] = float(np.mean(list(per.values()))) if per else None
    matched = matched_joint_errors(found.groups, found.parents, tpl, truth, result.motion)
    for entry in matched.values():
        seg = entry.get("auto_segment")
        if seg is not None:
            entry["method"] = result.model.methods.get(seg)
            entry["tree"] = found.joint_how[int(seg.rsplit("_", 1)[1])]
    out["matched_joints"] = matched
    found_errors = [v["mean_m"] for v in matched.values() if v.get("mean_m") is not None]
    out["matched_joint_mean_m"] = float(np.mean(found_errors)) if found_errors else None
    out["matched_joints_found"] = len(found_errors)
    out["residual_rms_m"] = residual_distribution(result.residuals, result.model.marker_labels)[
        "rms_m"
    ]
    return out


def _fmt(value: float | None, scale: float, unit: str, digits: int = 2) -> str:
    return "not measured" if value is None else f"{value * scale:.{digits}f} {unit}"


def targets_table(
    synthetic: dict[str, Any] | None,
    real: dict[str, dict[str, Any]],
    auto: dict[str, Any] | None,
) -> list[dict[str, str]]:
    """The issue's targets table: one row per measure with the figure measured."""
    rows = []
    for name, r in real.items():
        res = r["residual"]
        rows.append({
            "measure": f"marker RMS residual, real ({name})",
            "measured": f"{_fmt(res['rms_m'], 100, 'cm')} RMS, {_fmt(res['max_m'], 100, 'cm')} max",
            "target": "<= 1.2 cm RMS, <= 4 cm max",
            "met": str(res["rms_m"] <= TARGETS["real_rms_m"] and res["max_m"] <= TARGETS["real_max_m"]).lower(),
        })  # fmt: skip
    if not real:
        rows.append({"measure": "marker RMS residual, real captures", "measured": "not measured (give --real)",
                     "target": "<= 1.2 cm RMS, <= 4 cm max", "met": "n/a"})  # fmt: skip
    if synthetic is not None:
        mean, worst = synthetic["joint_mean_m"], synthetic["joint_worst_m"]
        rows.append({
            "measure": "joint-centre error, synthetic",
            "measured": f"{_fmt(mean, 1000, 'mm', 1)} mean, {_fmt(worst, 1000, 'mm', 1)} worst ({synthetic['joint_worst']})",
            "target": "<= 10 mm mean, <= 20 mm worst joint",
            "met": str(mean is not None and mean <= TARGETS["joint_mean_m"] and worst <= TARGETS["joint_worst_m"]).lower(),
        })  # fmt: skip
        ang = synthetic["angle_median_deg"]
        rows.append({
            "measure": "joint-angle error (knee/elbow flexion), synthetic",
            "measured": _fmt(ang, 1, "deg", 2) + " median",
            "target": "<= 3 deg median",
            "met": str(ang is not None and ang <= TARGETS["angle_median_deg"]).lower(),
        })  # fmt: skip
    if auto is not None:
        share = auto.get("share_in_true_segment")
        jm = auto.get("joint_mean_m")
        mm = auto.get("matched_joint_mean_m")
        matched = auto.get("matched_joints", {})
        worst = max(
            (k for k, v in matched.items() if v.get("mean_m") is not None),
            key=lambda k: matched[k]["mean_m"], default=None,
        )  # fmt: skip
        rows.append({
            "measure": f"--template auto, synthetic ({auto.get('template', 'synth-sparse')})",
            "measured": f"{'n/a' if share is None else f'{100 * share:.0f} %'} in true segment "
            f"({len(auto['groups'])} groups for {auto['true_segments']} segments"
            + (f"; misplaced: {', '.join(f'{m} with {s}' for m, s in auto['misplaced'].items())}" if auto.get("misplaced") else "")
            + f"), joints {_fmt(jm, 1000, 'mm', 1)} (nearest)"
            + (f", {_fmt(mm, 1000, 'mm', 1)} between the same segments ({auto['matched_joints_found']} of {len(matched)} found"
               + (f"; worst {worst} {1000 * matched[worst]['mean_m']:.1f} mm" if worst else "") + ")"
               if "matched_joints" in auto else "")
            + (f"; solve failed: {auto['error']}" if "error" in auto else ""),
            "target": ">= 95 % of markers, joint error <= 20 mm",
            "met": str(share is not None and share >= TARGETS["auto_share"] and jm is not None
                       and jm <= TARGETS["auto_joint_m"]
                       and (mm is None or mm <= TARGETS["auto_joint_m"])).lower(),
        })  # fmt: skip
    speed = [r for r in ([synthetic] if synthetic else []) + list(real.values())]
    if speed:
        first = speed[0]
        speed_of = first["ik_frames_per_second"]
        rows.append({
            "measure": f"IK speed, {first['markers']} markers, {first['frames']} frames",
            "measured": f"{speed_of['cpu']:,.0f} frames/s of CPU time per pass "
            f"({speed_of['wall']:,.0f} wall, {speed_of.get('backend', 'numpy')}); the solve's "
            f"{speed_of.get('passes', 1)} passes {speed_of.get('solve_cpu', speed_of['cpu']):,.0f} frames/s",
            "target": ">= 2,000 frames/s",
            "met": str(first["ik_frames_per_second"]["cpu"] >= TARGETS["ik_frames_per_second"]).lower(),
        })  # fmt: skip
    return rows


# ------------------------------------------------------------ the synth-dense template
#: A dense marker joins a segment only when at least this share of its skin weight
#: comes from that segment's bones; below it the marker straddles a joint (its skin
#: blends two segments) and rides neither rigidly, so the template leaves it out.
DENSE_SEGMENT_WEIGHT = 0.8

#: Park & Hodgins part (:data:`skincap.synth.marker_parts.PART_NAMES`) -> segment of
#: the synth-sparse template. The abdomen (skin over the lumbar spine, which bends
#: between pelvis and thorax) rides no rigid segment.
_SEGMENT_OF_PART: dict[str, str | None] = {
    "pelvis": "pelvis", "abdomen": None, "chest": "thorax", "upper_chest": "thorax",
    "head": "head",
    **{f"{p}_{s}": f"{q}_{s}" for s in "lr" for p, q in (
        ("upperarm", "upperarm"), ("forearm", "forearm"), ("hand", "hand"),
        ("thigh", "thigh"), ("shin", "shank"), ("foot", "foot"))},
}  # fmt: skip


def _relabel(value: Any, groups: dict[str, list[str]]) -> Any:
    """``value`` (a template field) with every sparse marker label in a list of POINTS
    replaced by its group of dense markers (``groups``)."""
    if isinstance(value, list):
        out: list[Any] = []
        for v in value:
            if isinstance(v, str) and v in groups:
                out.extend(g for g in groups[v] if g not in out)
            else:
                out.append(_relabel(v, groups))
        return out
    if isinstance(value, dict):
        return {k: _relabel(v, groups) for k, v in value.items()}
    return value


#: A sparse landmark becomes the group of up to this many dense markers (of its
#: segment, among the nearest :data:`_LANDMARK_CANDIDATES`) whose centroid is nearest it.
_LANDMARK_GROUP = 4
_LANDMARK_CANDIDATES = 12


def _landmark_group(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Indices into ``points (K, 3)`` whose mean is nearest ``target (3,)``; 1 mm per
    extra marker breaks near-ties towards fewer markers."""
    from itertools import combinations

    near = np.argsort(np.linalg.norm(points - target, axis=1))[:_LANDMARK_CANDIDATES]
    best, best_cost = near[:1], np.inf
    for size in range(1, min(_LANDMARK_GROUP, near.size) + 1):
        for combo in combinations(near.tolist(), size):
            cost = float(np.linalg.norm(points[list(combo)].mean(axis=0) - target)) + 1e-3 * size
            if cost < best_cost:
                best, best_cost = np.array(combo), cost
    return best


def synth_dense_template(
    *, vertices: int = 20_000, seed: int = 0, threshold: float = DENSE_SEGMENT_WEIGHT
) -> dict[str, Any]:
    """The ``synth-dense`` solve template, made from ``skincap synth --markers dense``'s layout.

    The body and the dense layout are the ones ``skincap synth --markers dense
    --vertices VERTICES --seed SEED`` makes (the procedural body; the layout seeded as
    :func:`skincap.synth.generate.generate_capture` seeds it), so the labels
    ``D000``... name the same skin points as in such a take. Each dense marker's skin
    weights are summed per segment of the synth-sparse template
    (:data:`_SEGMENT_OF_PART`); a marker rides the segment holding at least
    ``threshold`` of its weight and is left out otherwise. The segments, joints,
    frames, limits and joint-centre methods are synth-sparse's; every sparse landmark
    its axes and end sites name is replaced by the group of up to four dense markers
    riding the same segment whose centroid (in the bind pose) is nearest it. The
    dense set has no markers on the landmarks synth-sparse's regressions start from
    (iliac spines, the elbow and ankle over the joint), so each joint's regression
    prior -- used where the take hardly turns the joint, and to place a centre on a
    hinge axis -- is the centroid of the up to four markers of the segment and its
    parent whose centroid is nearest the body's joint in the bind pose: a regression
    fitted on this very body, as a real set's regressions are fitted on measured ones.

    ``skincap/data/solve_template_synth_dense.json`` is this function's output
    (``json.dumps`` one segment per line); ``tests/solve`` regenerates and compares it.

    Returns
    -------
    dict
        The template as JSON data (``name``, ``description``, ``layout``, ``segments``).
    """
    import json

    from skincap.data import path as data_path
    from skincap.synth.inputs import build_body
    from skincap.synth.marker_parts import PART_NAMES, _joint_parts
    from skincap.synth.markers import dense_marker_layout, place_markers, sparse_marker_layout

    body = build_body("procedural", n_vertices=vertices, seed=seed)
    if body.skin is None:
        raise ValidationError("synth-dense: the procedural body came without a skin")
    layout_seed = int(np.random.default_rng(seed).integers(0, 2**31 - 1, size=6)[1])
    dense = dense_marker_layout(body, seed=layout_seed)
    sparse = sparse_marker_layout(body, body.skin)
    sparse_tpl = json.loads(data_path(BUILTIN_TEMPLATES["synth-sparse"]).read_text("utf-8"))
    seg_names = [s["name"] for s in sparse_tpl["segments"]]

    # skin weight of every vertex per segment (V, S); the abdomen counts for none
    skin = body.skin
    joint_part = _joint_parts(list(skin.skeleton.names), skin.skeleton.parents)
    segment_of = [_SEGMENT_OF_PART[p] for p in PART_NAMES]
    part_segment = np.array([-1 if s is None else seg_names.index(s) for s in segment_of])
    joint_segment = np.where(joint_part >= 0, part_segment[joint_part], -1)
    infl = joint_segment[skin.joint_indices]  # (V, K)
    counted = infl >= 0
    n_v, k = skin.joint_weights.shape
    vertex_segment = np.zeros((n_v, len(seg_names)))
    np.add.at(
        vertex_segment,
        (np.repeat(np.arange(n_v), k)[counted.ravel()], infl[counted]),
        skin.joint_weights[counted],
    )
    corners = body.faces[dense.face]  # (N, 3)
    share = np.einsum("nc,ncs->ns", dense.bary, vertex_segment[corners])  # (N, S)
    total = np.einsum("nc,nc->n", dense.bary, skin.joint_weights.sum(axis=1)[corners])
    share /= np.maximum(total, 1e-12)[:, None]  # of all the marker's weight, abdomen included
    best = np.argmax(share, axis=1)
    kept = share[np.arange(best.size), best] >= threshold

    dense_pos, _ = place_markers(dense, body.vertices, body.faces)
    sparse_pos, _ = place_markers(sparse, body.vertices, body.faces)
    sparse_segment = {m: s["name"] for s in sparse_tpl["segments"] for m in s["markers"]}
    groups: dict[str, list[str]] = {}
    for i, label in enumerate(sparse.labels):
        on = np.flatnonzero(kept & (best == seg_names.index(sparse_segment[label])))
        if on.size == 0:
            raise ValidationError(f"synth-dense: no dense marker rides {sparse_segment[label]}")
        group = on[_landmark_group(dense_pos[on], sparse_pos[i])]
        groups[label] = [dense.labels[int(g)] for g in sorted(group)]
    joint_at = dict(zip(skin.skeleton.names, skin.bind_matrices[:, :3, 3], strict=True))
    segments, misses = [], {}
    for s, seg in enumerate(sparse_tpl["segments"]):
        new = dict(seg)
        new["markers"] = [dense.labels[int(i)] for i in np.flatnonzero(kept & (best == s))]
        if seg.get("centre") is not None:
            # the regression: the centroid of the few markers of this segment and its
            # parent around the joint, fitted on the bind pose (the skeleton's joint);
            # past a link parent (no markers: a bend of its own parent) to that parent
            parent = seg_names.index(seg["parent"])
            while sparse_tpl["segments"][parent].get("link"):
                parent = seg_names.index(sparse_tpl["segments"][parent]["parent"])
            pool = np.flatnonzero(kept & np.isin(best, [s, parent]))
            joint = joint_at[seg["joint"]]
            group = pool[_landmark_group(dense_pos[pool], joint)]
            misses[seg["joint"]] = float(np.linalg.norm(dense_pos[group].mean(axis=0) - joint))
            start = [dense.labels[int(g)] for g in sorted(group)]
            prior: dict[str, Any] = {"from": start}  # a link without markers: the centroid
            if new["markers"]:
                prior |= {"towards": new["markers"], "distance": 0.0}
            new["centre"] = {**seg["centre"], "prior": prior}
        segments.append(_relabel(new, groups))
    worst = max(misses, key=misses.__getitem__)
    return {
        "name": "synth-dense",
        "description": (
            f"skincap's synthetic dense set (`skincap synth --markers dense`, default body "
            f"--vertices {vertices} --seed {seed}): {int(kept.sum())} of {dense.n_markers} "
            f"markers, each on the segment carrying >= {threshold:g} of its skin weight "
            f"(the other {int((~kept).sum())} straddle a joint); synth-sparse's segments, "
            "each of its landmarks replaced by the few dense markers on the same segment "
            "whose centroid is nearest it; each joint's regression prior is the centroid "
            "of the few markers of the two segments around it nearest the joint in the "
            f"bind pose (within {1000 * misses[worst]:.0f} mm there, {worst}). "
            "Generated by skincap.evaluate.solve.synth_dense_template; do not edit."
        ),
        "layout": {"body": "procedural", "vertices": vertices, "seed": seed,
                   "threshold": threshold, "markers": dense.n_markers},
        "segments": segments,
    }  # fmt: skip


#: Least share of synth-dense's markers that must ride their template segment on a
#: take's body (by its ``truth/marker_parts.csv``). On the default body all 289 do; on
#: another seed or vertex count the labels name other skin points (9 % on seed 1,
#: 12,000 vertices), so a check between the two cannot misjudge.
SYNTH_DENSE_MIN_AGREEMENT = 0.9


def synth_dense_body_check(marker_parts: dict[str, str]) -> tuple[int, int]:
    """How many of synth-dense's markers ride their template segment on a given body.

    Parameters
    ----------
    marker_parts : dict
        Marker label -> true near-rigid part (``truth/marker_parts.csv`` of a
        ``skincap synth --markers dense`` folder; part names of
        :data:`skincap.synth.marker_parts.PART_NAMES`).

    Returns
    -------
    (agreeing, total) : (int, int)
        Template markers whose part belongs to their segment, and all template markers.
    """
    tpl = load_template("synth-dense")
    pairs = [(m, s.name) for s in tpl.segments for m in s.markers]
    agree = sum(1 for m, seg in pairs if _SEGMENT_OF_PART.get(marker_parts.get(m, "")) == seg)
    return agree, len(pairs)


def template_json_text(template: dict[str, Any]) -> str:
    """A template's JSON text as the built-in files lay it out: one segment per line."""
    import json

    head = {k: v for k, v in template.items() if k != "segments"}
    lines = [f"  {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
    segs = ",\n".join(f"    {json.dumps(s)}" for s in template["segments"])
    return "{\n" + "\n".join(lines) + '\n  "segments": [\n' + segs + "\n  ]\n}\n"
