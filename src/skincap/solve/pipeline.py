"""Labelled capture -> calibrated body model -> per-frame poses -> solved Motion.

:func:`solve_markers` is the library entry point of ``skincap solve``: calibration on
the take (:mod:`skincap.solve.calibrate`), batched inverse kinematics
(:mod:`skincap.solve.ik`), the BVH-ready motion (:mod:`skincap.solve.skeleton`), the
model's markers per frame and the residual report.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.errors import SkincapWarning, ValidationError
from skincap.solve.calibrate import BodyModel, calibrate
from skincap.solve.ik import model_markers, refit_marker_offsets, solve_poses
from skincap.solve.outliers import jumped_samples, off_body_samples
from skincap.solve.skeleton import motion_of, skeleton_of
from skincap.solve.smooth import smooth_poses
from skincap.solve.templates import Template, load_template
from skincap.types import MarkerSet, Motion

__all__ = ["SolveResult", "solve_markers", "residual_report"]


@dataclass(eq=False)
class SolveResult:
    """What :func:`solve_markers` returns.

    Attributes
    ----------
    motion : Motion
        The solved skeleton (metres, Y up).
    model : BodyModel
    fitted : MarkerSet
        The model's markers per frame (each rigidly on its segment), same labels.
    rotations : (T, S, 3, 3) float64, world segment frames
    root : (T, 3) float64, metres
    residuals : (T, M) float64, metres
        Distance model -> measured marker; NaN where the marker is missing.
    smooth_hz : float or None
        The temporal smoothing cut-off applied, Hz.
    ik : dict
        The IK's settings: ``loss``, ``loss_scale_m``, ``refine_offsets``.
    rejected : (T, M) bool
        Samples left out as jumps off their segment (:mod:`skincap.solve.outliers`):
        solved as missing, their residual NaN.
    off_body : (T, M) bool or None
        Samples left out before calibration as too far from the rest of the body
        (:func:`skincap.solve.outliers.off_body_samples`); NaN residuals too.
    """

    motion: Motion
    model: BodyModel
    fitted: MarkerSet
    rotations: np.ndarray
    root: np.ndarray
    residuals: np.ndarray
    smooth_hz: float | None = None
    ik: dict[str, Any] = field(default_factory=dict)
    rejected: np.ndarray | None = None
    off_body: np.ndarray | None = None

    def report(self) -> dict[str, Any]:
        return residual_report(self)


def solve_markers(
    markers: MarkerSet,
    template: Template | str | BodyModel = "cmu41",
    *,
    iterations: int = 12,
    smooth_hz: float | None = None,
    loss: str = "squared",
    loss_scale: float = 0.02,
    refine_offsets: int = 1,
    joint_limits: bool = False,
    reject_jumps: bool = True,
    drop_off_body: bool = True,
    progress: Progress | None = None,
) -> SolveResult:
    """Solve a skeleton motion from a labelled marker capture.

    Parameters
    ----------
    markers : MarkerSet
        Labelled capture in metres, Y up; NaN where a marker is missing.
    template : Template, str or BodyModel
        A template, a built-in name (``pig``, ``cmu41``, ``synth-sparse``, ``aml62``)
        or a JSON file; or a body model already calibrated on this take (its
        ``marker_columns`` index ``markers``), solved as it is -- e.g.
        :func:`skincap.solve.auto.calibrate_auto`'s.
    iterations : int
        Most Levenberg-Marquardt steps per frame.
    smooth_hz : float, optional
        Low-pass the solved poses over time at this cut-off (Hz, below half the frame
        rate; :func:`skincap.solve.smooth.smooth_poses`); the residuals are those of
        the smoothed poses. Default: no smoothing.
    loss : {"squared", "huber", "cauchy"}, default "squared"
        The IK's loss of each marker's residual (:func:`~skincap.solve.ik.solve_poses`):
        a robust loss lets a marker that slides or is mislabelled in some frames
        pull its segment less -- the other markers fit better and that marker's own
        residual grows, so the maximum residual is then the outlier's.
    loss_scale : float, default 0.02
        The robust loss's scale, metres.
    refine_offsets : int, default 1
        Rounds of re-fitting every marker's offset on its segment to the solved
        poses (:func:`~skincap.solve.ik.refit_marker_offsets`), each followed by a
        second IK started from the poses: on CMU 85_02 one round takes the RMS
        residual from 0.695 to 0.678 cm and the max from 4.03 to 3.97 cm; 0 keeps
        the calibration's offsets.
    joint_limits : bool, default False
        Hold the joints within the template's ``limits`` (see
        :mod:`skincap.solve.templates`); a template without any is refused.
    reject_jumps : bool, default True
        Leave out the pieces of a marker's track whose residual jumps away from its
        model marker and back (a swapped label, a ghost:
        :func:`skincap.solve.outliers.jumped_samples`) and solve their frames again
        without them; they are listed in the report (``rejected_samples``) and their
        residuals are NaN. On AML PronetoRun01 it leaves out LSHPA in frames
        1248-1251 (swapped onto another track) and the max residual falls from 4.07 to
        3.73 cm; CMU 85_02 and the synthetic walk and squat have no such sample.
    drop_off_body : bool, default True
        Before calibration, leave out (with a warning) the samples too far from the
        rest of the body to be on the performer
        (:func:`skincap.solve.outliers.off_body_samples`); listed in the report
        (``off_body_samples``).
    progress : callable(fraction, label), optional

    Returns
    -------
    SolveResult

    Raises
    ------
    ValidationError
        The capture does not fit the template (see :func:`~skincap.solve.calibrate.calibrate`).
    """
    if progress is not None:
        progress(0.0, "calibration")
    markers, off_body = _without_off_body(markers) if drop_off_body else (markers, None)
    if isinstance(template, BodyModel):
        model = template
        cols = model.marker_columns
        if cols.size and (
            cols.max() >= markers.n_markers
            or [markers.labels[c] for c in cols] != list(model.marker_labels)
        ):
            raise ValidationError("the body model was calibrated on a take with other labels")
    else:
        tpl = template if isinstance(template, Template) else load_template(template)
        model = calibrate(markers, tpl)
    if model.marker_columns.size == 0:
        raise ValidationError("no template marker was seen with its segment")
    if off_body is not None:  # only the markers solved count (a prop's marker may roam)
        off_body = off_body[:, model.marker_columns]
        _warn_off_body(off_body, list(model.marker_labels))

    def ik_progress(f: float, label: str) -> None:
        if progress is not None:
            progress(0.2 + 0.8 * f, label)

    limits = _template_limits(model) if joint_limits else None
    if refine_offsets < 0:
        raise ValidationError(f"refine_offsets: expected a count >= 0, got {refine_offsets}")
    measured = markers.positions[:, model.marker_columns]
    model, rot, root = _solve_rounds(
        model, measured, int(refine_offsets) + 1, iterations, loss, loss_scale, limits,
        joint_limits, ik_progress,
    )  # fmt: skip
    rejected = np.zeros(measured.shape[:2], dtype=bool)
    if reject_jumps:
        measured, rot, root, rejected = _without_jumps(
            model, measured, rot, root, iterations, loss, loss_scale, limits, joint_limits
        )
    if smooth_hz is not None:
        rot, root = smooth_poses(rot, root, markers.rate, float(smooth_hz))
    motion = motion_of(model, rot, root, markers.rate)
    fitted, resid = _fitted_markers(model, markers, measured, rot, root)
    return SolveResult(
        motion=motion,
        model=model,
        fitted=fitted,
        rotations=rot,
        root=root,
        residuals=resid,
        smooth_hz=None if smooth_hz is None else float(smooth_hz),
        ik={
            "loss": loss,
            "loss_scale_m": float(loss_scale),
            "refine_offsets": int(refine_offsets),
            "joint_limits": bool(joint_limits),
            "reject_jumps": bool(reject_jumps),
        },
        rejected=rejected,
        off_body=off_body,
    )


def _without_off_body(markers: MarkerSet) -> tuple[MarkerSet, np.ndarray]:
    """``markers`` with the off-body samples NaN, and their ``(T, M)`` mask."""
    off = off_body_samples(markers.positions)
    if not off.any():
        return markers, off
    return replace(markers, positions=np.where(off[..., None], np.nan, markers.positions)), off


def _warn_off_body(off: np.ndarray, labels: list[str]) -> None:
    """Say how many of the solved markers' samples ``off (T, M)`` were left out."""
    if not off.any():
        return
    t, m = (int(i[0]) for i in np.nonzero(off))
    warnings.warn(
        f"{int(off.sum())} sample(s) lie too far from the rest of the body to be on the "
        f"performer and are left out (first: {labels[m]!r} in frame {t})",
        SkincapWarning,
        stacklevel=3,
    )


def _template_limits(model: BodyModel) -> np.ndarray:
    """The model's joint limits, ``(S, 3, 2)`` radians (NaN: none); raises
    :class:`ValidationError` when its template defines none at all."""
    limits = model.joint_limits
    if not np.isfinite(limits).any():
        raise ValidationError(
            f"joint limits: template {model.template.name} defines none (a segment's 'limits')"
        )
    return limits


def _solve_rounds(
    model: BodyModel,
    measured: np.ndarray,
    rounds: int,
    iterations: int,
    loss: str,
    loss_scale: float,
    limits: np.ndarray | None,
    joint_limits: bool,
    ik_progress: Progress,
) -> tuple[BodyModel, np.ndarray, np.ndarray]:
    """Solve the poses ``rounds`` times from the calibration's, re-fitting the marker
    offsets to the last poses before every round but the first.

    ``measured (T, M, 3)`` metres are the model's markers (NaN: missing), ``limits``
    the ``(S, 3, 2)`` joint limits in radians or None. Returns the model with its
    re-fitted offsets, the ``(T, S, 3, 3)`` world rotations and the ``(T, 3)`` root
    origins, metres; ``ik_progress`` sees the rounds' fractions in turn."""
    rot, root = model.init_rotations, model.init_origins
    for k in range(rounds):
        if k > 0:
            model = replace(
                model,
                marker_offsets=refit_marker_offsets(
                    model.segment_parents, model.joint_offsets, model.marker_segments,
                    measured, rot, root, model.marker_offsets,
                ),
            )  # fmt: skip

        def round_progress(f: float, label: str, _k: int = k) -> None:
            ik_progress((_k + f) / rounds, label)

        rot, root = solve_poses(
            model.segment_parents,
            model.joint_offsets,
            model.marker_segments,
            model.marker_offsets,
            measured,
            rot,
            root,
            iterations=iterations,
            link_stiffness=model.link_stiffness,
            loss=loss,
            loss_scale=loss_scale,
            joint_limits=limits,
            bone_axes=model.bone_axes if joint_limits else None,
            progress=round_progress,
        )
    return model, rot, root


def _without_jumps(
    model: BodyModel,
    measured: np.ndarray,
    rot: np.ndarray,
    root: np.ndarray,
    iterations: int,
    loss: str,
    loss_scale: float,
    limits: np.ndarray | None,
    joint_limits: bool,
    rounds: int = 3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Drop the samples that jumped off their segment and solve their frames again.

    ``measured (T, M, 3)`` metres and the solved ``rot (T, S, 3, 3)`` / ``root (T, 3)``
    in; returns the measured markers with those samples NaN, the poses (the affected
    frames re-solved from their previous solution) and the ``(T, M)`` bool mask.

    One bad marker drags its segment, so its neighbours' residuals jump with it: each
    round tries every flagged marker of a frame, solves the frame without it, and drops
    the one whose absence lets the rest fit best (the least RMS residual of the markers
    left); then it looks again (at most ``rounds`` times)."""
    rejected = np.zeros(measured.shape[:2], dtype=bool)
    rot, root = rot.copy(), root.copy()
    seg = model.marker_segments

    def solve(y: np.ndarray, r0: np.ndarray, o0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return solve_poses(
            model.segment_parents, model.joint_offsets, seg, model.marker_offsets, y, r0, o0,
            iterations=iterations, link_stiffness=model.link_stiffness, warm_start=False,
            loss=loss, loss_scale=loss_scale, joint_limits=limits,
            bone_axes=model.bone_axes if joint_limits else None,
        )  # fmt: skip

    for _ in range(rounds):
        fitted = model_markers(
            model.segment_parents, model.joint_offsets, seg, model.marker_offsets, rot, root
        )
        frame, marker = np.nonzero(jumped_samples(measured, fitted))
        if frame.size == 0:
            break
        # one variant per flagged sample: its frame without that marker
        y = measured[frame].copy()
        y[np.arange(frame.size), marker] = np.nan
        v_rot, v_root = solve(y, rot[frame], root[frame])
        x = model_markers(
            model.segment_parents, model.joint_offsets, seg, model.marker_offsets, v_rot, v_root
        )
        with np.errstate(invalid="ignore"):
            sq = np.nansum((x - y) ** 2, axis=(1, 2)) / np.isfinite(y).all(axis=2).sum(axis=1)
        # the best variant of each frame (the next round sees what it leaves)
        order = np.lexsort((sq, frame))
        first = np.ones(order.size, dtype=bool)
        first[1:] = frame[order][1:] != frame[order][:-1]
        best = order[first]
        rejected[frame[best], marker[best]] = True
        measured = np.where(rejected[..., None], np.nan, measured)
        rot[frame[best]], root[frame[best]] = v_rot[best], v_root[best]
    return measured, rot, root, rejected


def _fitted_markers(
    model: BodyModel,
    markers: MarkerSet,
    measured: np.ndarray,
    rot: np.ndarray,
    root: np.ndarray,
) -> tuple[MarkerSet, np.ndarray]:
    """The model's markers for poses ``rot (T, S, 3, 3)`` / ``root (T, 3)`` metres, as a
    MarkerSet with the model's labels, and their ``(T, M)`` distances (metres, NaN
    where missing) to the ``measured (T, M, 3)`` ones."""
    fitted_pos = model_markers(
        model.segment_parents,
        model.joint_offsets,
        model.marker_segments,
        model.marker_offsets,
        rot,
        root,
    )
    with np.errstate(invalid="ignore"):
        resid = np.linalg.norm(fitted_pos - measured, axis=2)
    fitted = MarkerSet(
        positions=fitted_pos,
        labels=list(model.marker_labels),
        rate=markers.rate,
        meta={k: v for k, v in markers.meta.items() if k in ("source_units", "up", "first_frame")},
    )
    return fitted, resid


def _stats(r: np.ndarray) -> dict[str, float | None]:
    r = r[np.isfinite(r)]
    if r.size == 0:
        return {"rms_m": None, "max_m": None, "samples": 0}
    return {"rms_m": float(np.sqrt(np.mean(r**2))), "max_m": float(r.max()), "samples": int(r.size)}


def residual_report(result: SolveResult) -> dict[str, Any]:
    """JSON-ready report: overall, per-marker and per-frame RMS residuals (metres),
    per joint the centre's method, range of motion (degrees), fit singular values
    (radians RMS) and the parent markers SCoRE left out, bone lengths (metres)."""
    model = result.model
    r = result.residuals
    seen = np.isfinite(r)
    sq = np.where(seen, r, 0.0) ** 2
    n_frame = seen.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_frame = np.where(n_frame > 0, np.sqrt(sq.sum(axis=1) / np.maximum(n_frame, 1)), np.nan)
    skel, seg_joint = skeleton_of(model)
    return {
        "template": model.template.name,
        "frames": int(r.shape[0]),
        "joints": skel.n_joints,
        "markers_used": len(model.marker_labels),
        "smoothing_hz": result.smooth_hz,
        "ik": dict(result.ik),
        "overall": _stats(r),
        "rejected_samples": _frames_of(result.rejected, model.marker_labels),
        "off_body_samples": _frames_of(result.off_body, model.marker_labels),
        "per_marker": {label: _stats(r[:, k]) for k, label in enumerate(model.marker_labels)},
        "per_frame_rms_m": [None if not np.isfinite(v) else round(float(v), 6) for v in per_frame],
        "joint_centres": {
            model.template.segments[s].joint: {
                "segment": model.segment_names[s],
                "method": model.methods.get(model.segment_names[s], "root"),
                "range_of_motion_deg": model.spreads_deg.get(model.segment_names[s], []),
                "fit_singular_values": model.fit_singular_values.get(model.segment_names[s], []),
                "parent_markers_left_out": model.loose_markers.get(model.segment_names[s], []),
            }
            for s in range(1, model.n_segments)
        },
        "bone_lengths_m": {
            model.template.segments[s].joint: round(
                float(np.linalg.norm(model.joint_offsets[s])), 6
            )
            for s in range(1, model.n_segments)
        },
    }


def _frames_of(mask: np.ndarray | None, labels: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """Samples left out (a ``(T, M)`` mask): their count and, per marker, the frames."""
    if mask is None:
        return {"count": 0, "frames": {}}
    return {
        "count": int(mask.sum()),
        "frames": {
            labels[k]: [int(t) for t in np.flatnonzero(mask[:, k])]
            for k in np.flatnonzero(mask.any(axis=0))
        },
    }
