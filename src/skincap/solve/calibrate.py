"""Calibration on the take: segment frames, joint centres, anatomical axes, offsets.

From a labelled capture and a :class:`~skincap.solve.templates.Template`:

1. technical frames of every segment with three or more markers
   (:func:`skincap.solve.segments.cluster_frames`);
2. joint centres top-down: SCoRE between two framed segments, SARA for hinges, a
   common-centre sphere fit in the parent's frame for a child with fewer than three
   markers, and the template's regression prior when the range of motion is below
   :data:`~skincap.solve.joint_centres.MIN_SPREAD_DEG` (a :class:`SkincapWarning`
   names the joint) -- a child made of two markers then gets its technical frame from
   them and its joint centre. SCoRE is fitted again without a parent marker that does
   not keep its distance to the centre (:meth:`_Calibrator.score_without_loose`: a
   thorax bends between T10 and the shoulders); a prior marked ``"along"`` is placed
   along the joint's functional axis and gives the centre its place on it (a knee, an
   ankle: :mod:`skincap.solve.templates`);
3. anatomical frames from the template's axes, held constant in the technical frames;
4. the model's constants: each joint's offset in its parent's anatomical frame (bone
   lengths constant over the take) and each marker's offset in its segment's frame
   (medians over the take).

Everything is in metres, Y up; frames are batched over the take.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.errors import SkincapWarning, ValidationError
from skincap.solve import joint_centres as jc
from skincap.solve.segments import cluster_frames, to_local, to_world
from skincap.solve.take_points import (
    TakePoints,
    _as_list,
    _nanmean0,
    _nanmedian0,
    _unit,
    match_markers,
)
from skincap.solve.templates import SegmentSpec, Template
from skincap.types import MarkerSet

__all__ = ["BodyModel", "calibrate", "match_markers", "MIN_CALIBRATION_FRAMES"]

#: Fewest frames with markers a take needs to be calibrated on.
MIN_CALIBRATION_FRAMES = 10

#: A parent marker whose distance to a SCoRE joint centre has an SD over the take
#: above this (metres) and LOOSE_FACTOR times the median of the parent's other markers
#: does not define the parent's frame for that joint (:meth:`_Calibrator.score_without_loose`).
LOOSE_FLOOR_M = 0.003
LOOSE_FACTOR = 1.5
#: A ball joint whose prior lies ``along`` an axis (a template's word that the prior is
#: good there) takes the prior's component along every direction of its SCoRE solution
#: that the take turns it through less than this RMS spread, degrees
#: (:func:`skincap.solve.joint_centres.score_centre`'s ``prior_spread_deg``): the
#: synthetic walk's ankles 11.4 / 14.7 -> 4.5 / 7.8 mm.
ALONG_PRIOR_SPREAD_DEG = 10.0
#: ... while at least this many markers stay: three markers of a trunk (C7, CLAV, STRN)
#: may lie near one line, a frame badly determined about it.
LOOSE_KEEP = 4
#: A hinge's ``axis_point`` feet further apart along SARA's axis than this (metres)
#: do not place its centre (:meth:`_Calibrator.axis_point`): the synthetic walk's
#: elbows 10 mm, a forearm-twisting clip's 144-187 mm, a range-of-motion clip's
#: 395-475 mm (its centre then 35-40 mm off instead of 16-19).
AXIS_POINT_AGREEMENT_M = 0.03
#: Most rounds of solving sibling joints with ``parent_points`` together (each in a
#: frame holding the others' centres, :meth:`_Calibrator.centres_in_parent_points`),
#: which stop once no centre moves by more than PARENT_POINTS_TOLERANCE_M: the
#: synthetic walk's shoulders settle within 3 (SCoRE in them 21 / 5 -> 7.4 / 6.6 mm).
PARENT_POINTS_ROUNDS = 30
PARENT_POINTS_TOLERANCE_M = 1e-8

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


@dataclass(eq=False)
class BodyModel:
    """A calibrated body: rigid segments in a tree, markers fixed on them.

    Attributes
    ----------
    segment_names : list of S str
    segment_parents : (S,) int64, -1 for the root, parents first
    joint_offsets : (S, 3) float64, metres
        Each segment's origin (its proximal joint centre) in its parent's anatomical
        frame; zero for the root.
    marker_labels : list of M str
        The capture's labels (prefix kept) of the markers the model uses.
    marker_columns : (M,) int64
        Their columns in the capture.
    marker_segments : (M,) int64
    marker_offsets : (M, 3) float64, metres, in the segment's anatomical frame
    init_rotations : (T, S, 3, 3) float64
        Anatomical frames measured on the calibration take (NaN where not seen).
    init_origins : (T, 3) float64, metres
        Root origin measured on the take (NaN where not seen).
    ends : dict segment -> (3,) end-site position in the segment's frame
    fixed : dict segment -> list of (joint name, (3,) position in the segment's frame)
    methods : dict segment -> str, how its proximal joint centre was found
    spreads_deg : dict segment -> list of float, range of motion used to decide
    fit_singular_values : dict segment -> list of 6 float
        For a joint between two framed segments, the SCoRE/SARA system's singular
        values over sqrt(T) (:func:`skincap.solve.joint_centres.fit_singular_values`):
        how well the take determines its centre and axis.
    loose_markers : dict segment -> list of str
        The parent markers SCoRE left out of the parent's frame for that segment's
        joint (they did not keep their distance to it), in the order dropped.
    link_stiffness : (S,) float64, metres per radian
        The spring holding each ``link`` segment to its parent's orientation in
        inverse kinematics; 0 for the other segments.
    joint_limits : (S, 3, 2) float64, radians
        The template's joint limits (low, high per parent axis; NaN: none), for
        :func:`skincap.solve.ik.solve_poses`.
    bone_axes : (S,) int64
        Each segment's primary anatomical axis (0, 1, 2: its first ``axes`` entry; y
        for a link), the long axis the joint limits' Euler angles turn about last.
    """

    segment_names: list[str]
    segment_parents: np.ndarray
    joint_offsets: np.ndarray
    marker_labels: list[str]
    marker_columns: np.ndarray
    marker_segments: np.ndarray
    marker_offsets: np.ndarray
    init_rotations: np.ndarray
    init_origins: np.ndarray
    template: Template
    ends: dict[str, np.ndarray] = field(default_factory=dict)
    fixed: dict[str, list[tuple[str, np.ndarray]]] = field(default_factory=dict)
    methods: dict[str, str] = field(default_factory=dict)
    spreads_deg: dict[str, list[float]] = field(default_factory=dict)
    fit_singular_values: dict[str, list[float]] = field(default_factory=dict)
    loose_markers: dict[str, list[str]] = field(default_factory=dict)
    link_stiffness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    joint_limits: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 2)))
    bone_axes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n_segments(self) -> int:
        return len(self.segment_names)

    def bone_lengths(self) -> dict[str, float]:
        """Length (metres) from each non-root segment's parent joint to its joint."""
        return {
            self.segment_names[s]: float(np.linalg.norm(self.joint_offsets[s]))
            for s in range(1, self.n_segments)
        }


def _mean_rotation(r: np.ndarray) -> np.ndarray:
    """Chordal mean (3, 3) of rotations (T, 3, 3), NaN frames skipped."""
    ok = np.isfinite(r).all(axis=(1, 2))
    if not ok.any():
        return np.full((3, 3), np.nan)
    return Rotation.from_matrix(r[ok]).mean().as_matrix()


def _right_handed(first: int, second: int, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """(T, 3, 3) frames with column ``first`` = e1 exactly, ``second`` along e2 orthogonalised."""
    e2 = _unit(e2 - e1 * np.einsum("...i,...i->...", e2, e1)[..., None])
    third = 3 - first - second
    # cyclic order x->y->z: e_{k+1} = e_{k+2} x e_k
    e3 = np.cross(e1, e2) if (second - first) % 3 == 1 else np.cross(e2, e1)
    out = np.empty(e1.shape[:-1] + (3, 3))
    out[..., :, first] = e1
    out[..., :, second] = e2
    out[..., :, third] = e3
    return out


class _Calibrator(TakePoints):
    """The calibration's steps on a take and what they find (technical and
    anatomical frames, joint centres, hinge axes, methods); :func:`calibrate` runs them."""

    def __init__(self, markers: MarkerSet, template: Template, min_spread_deg: float) -> None:
        super().__init__(markers, template)
        self.min_spread = float(min_spread_deg)
        self.score_prior_spread_deg = 0.0
        self.tech: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.axes_local: dict[
            str, tuple[np.ndarray, np.ndarray]
        ] = {}  # hinge axis in parent, child
        self.methods: dict[str, str] = {}
        self.spreads: dict[str, list[float]] = {}
        self.loose: dict[str, list[str]] = {}  # segment -> parent markers SCoRE left out
        self.conditions: dict[str, list[float]] = {}  # segment -> fit_singular_values
        self.anat: dict[str, np.ndarray] = {}
        # segment -> parent_points frame (T, 3, 3), (T, 3) and the centre in it and in
        # the segment's technical frame (centres_in_parent_points)
        self.point_frames: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    def score_without_loose(
        self,
        spec: SegmentSpec,
        rp: np.ndarray,
        tp: np.ndarray,
        rc: np.ndarray,
        tc: np.ndarray,
        cp: np.ndarray,
        cc: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str]]:
        """SCoRE again with the parent's frame built without its markers that do not
        keep their distance to the joint centre.

        A parent cluster that spans a bending part of the body (a thorax from T10 to
        C7: the shoulders ride the upper thorax) is not rigid about the joint, and the
        fit absorbs the bend. Each round drops the parent marker whose distance to the
        centre ``(c_p, c_c)`` varies most over the take when its SD is above
        :data:`LOOSE_FLOOR_M` and :data:`LOOSE_FACTOR` times the median SD of the
        others, rebuilds the parent's technical frame from the rest (at least
        :data:`LOOSE_KEEP`) and fits again. Returns the parent frame used ``(T, 3, 3)``, ``(T, 3)``, the
        centre in both frames and the markers dropped (empty: unchanged).
        """
        assert spec.parent is not None
        # the markers that made the parent's frame: past a link, its framed ancestor's
        names = self.present(self.template.segment(self.framed_ancestor(spec)))
        loose: list[str] = []
        while len(names) - len(loose) > LOOSE_KEEP:
            kept = [n for n in names if n not in loose]
            pts = np.stack([self.marker(n) for n in kept], axis=1)  # (T, K, 3)
            centre = 0.5 * (to_world(rp, tp, cp[None])[:, 0] + to_world(rc, tc, cc[None])[:, 0])
            dist = np.linalg.norm(pts - centre[:, None], axis=2)  # (T, K), NaN where unseen
            ok = np.isfinite(dist)
            if (ok.sum(axis=0) < MIN_CALIBRATION_FRAMES).any():
                break
            sd = np.array([np.std(dist[ok[:, k], k]) for k in range(len(kept))])
            worst = int(np.argmax(sd))
            others = np.delete(sd, worst)
            if sd[worst] <= max(LOOSE_FLOOR_M, LOOSE_FACTOR * float(np.median(others))):
                break
            rest = np.delete(pts, worst, axis=1)
            if (np.isfinite(rest).all(axis=2).sum(axis=1) >= 3).sum() < MIN_CALIBRATION_FRAMES:
                break
            _, rp, tp = cluster_frames(rest)
            cp, cc, _ = jc.score_centre(rp, tp, rc, tc)
            loose.append(kept[worst])
        return rp, tp, cp, cc, loose

    def axis_point(
        self,
        spec: SegmentSpec,
        frames: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
        axis_parent: np.ndarray,
        centre_parent: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The point ``(m_p, m_c)`` (3,) in the parent's and the child's technical
        ``frames`` whose place along a hinge's axis is the mean of its two
        ``axis_point`` POINTS' feet on it, or None: no ``axis_point``, or feet further
        apart than :data:`AXIS_POINT_AGREEMENT_M` (along ``axis_parent`` (3,) unit from
        ``centre_parent`` (3,), SARA's, in the parent's frame) -- an axis the bones do
        not cross near one point, e.g. SARA's axis wandering with a forearm that
        twists, which the points' lever (a bone's length) would magnify.

        The mean over frames, not the median: its along-axis part is the mean of the
        points' (a median of coordinates is not rotation-equivariant)."""
        ends = (spec.centre or {}).get("axis_point")
        if not ends:
            return None
        where = f"joint {spec.joint} (segment {spec.name}) axis_point"
        a, b = (self.point(_as_list(e), where) for e in ends)
        (rp, tp), (rc, tc) = frames
        feet = [
            float(axis_parent @ (_nanmean0(to_local(rp, tp, x[:, None])[:, 0]) - centre_parent))
            for x in (a, b)
        ]
        if not np.isfinite(feet).all() or abs(feet[0] - feet[1]) > AXIS_POINT_AGREEMENT_M:
            return None
        mid = 0.5 * (a + b)
        mp, mc = (_nanmean0(to_local(r, t, mid[:, None])[:, 0]) for r, t in frames)
        if not (np.isfinite(mp).all() and np.isfinite(mc).all()):
            return None
        return mp, mc

    def parent_points_frame(
        self, spec: SegmentSpec, child_centres: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The technical frame ``(T, 3, 3)``, ``(T, 3)`` of a joint's ``parent_points``:
        marker centroids (those the capture has) and siblings' centres
        (``child_centres``: each sibling's centre in its own technical frame); None
        with fewer than three points or frames."""
        assert spec.centre is not None
        pts = []
        for entry in spec.centre["parent_points"]:
            names = _as_list(entry)
            if names[0].startswith("@"):
                sib = names[0][1:]
                if sib in child_centres and sib in self.tech:
                    rs, ts = self.tech[sib]
                    pts.append(to_world(rs, ts, child_centres[sib][None])[:, 0])
                continue
            have = [n for n in names if n in self.columns]
            if have:
                pts.append(self.point(have, f"joint {spec.joint} parent_points"))
        if len(pts) < 3:
            return None
        stack = np.stack(pts, axis=1)  # (T, K, 3)
        if (np.isfinite(stack).all(axis=2).sum(axis=1) >= 3).sum() < MIN_CALIBRATION_FRAMES:
            return None
        _, rot, trans = cluster_frames(stack)
        return rot, trans

    def centres_in_parent_points(self) -> None:
        """SCoRE of the joints with ``parent_points``, each in the frame of those points.

        A parent that bends (a thorax) carries a joint on one part of it; its markers
        on another part turn with the bend, and SCoRE in their frame absorbs it (the
        synthetic walk's shoulders: 22 / 20 mm off). The template names the points
        that ride the joint's part -- markers, a centroid, and the sibling joints'
        centres, which no marker of the parent gives. The siblings start from plain
        SCoRE in the parent's technical frame, then each is fitted in a frame holding
        the others' current centres, round after round until none moves by more than
        :data:`PARENT_POINTS_TOLERANCE_M` (at most :data:`PARENT_POINTS_ROUNDS`): the
        siblings' points are rigid with the part carrying them once their centres are
        right, so the true centres are where the rounds settle. A joint keeps its
        points' frame only where SCoRE's two estimates of its centre (one per frame)
        agree better, RMS, than in the parent's technical frame: the synthetic walk's
        shoulders 22 -> 12-13 mm, a clip that twists the arms 15-16 -> 18-19 mm (kept
        out; its centres 60-80 mm off in the points' frame against 35-43). Results in
        ``self.point_frames``; a joint whose points give no frame, or whose range of
        motion in it is under ``min_spread``, is left to :meth:`centre`.
        """
        specs = [
            s for s in self.template.segments[1:]
            if s.centre is not None and "parent_points" in s.centre
            and s.name in self.tech and self.framed_ancestor(s) in self.tech
        ]  # fmt: skip
        child_centres: dict[str, np.ndarray] = {}
        for spec in specs:
            (rp, tp), (rc, tc) = self.tech[self.framed_ancestor(spec)], self.tech[spec.name]
            if jc.motion_spread(rp, rc)[1] >= self.min_spread:
                child_centres[spec.name] = jc.score_centre(rp, tp, rc, tc)[1]
        for _ in range(PARENT_POINTS_ROUNDS):
            moved = 0.0
            for spec in specs:
                if spec.name not in child_centres:
                    continue
                frame = self.parent_points_frame(spec, child_centres)
                rc, tc = self.tech[spec.name]
                if frame is None or jc.motion_spread(frame[0], rc)[1] < self.min_spread:
                    del child_centres[spec.name]
                    self.point_frames.pop(spec.name, None)
                    continue
                cp, cc, _ = jc.score_centre(frame[0], frame[1], rc, tc)
                moved = max(moved, float(np.linalg.norm(cc - child_centres[spec.name])))
                child_centres[spec.name] = cc
                self.point_frames[spec.name] = (frame[0], frame[1], cp, cc)
            if moved <= PARENT_POINTS_TOLERANCE_M:
                break
        # kept only where the joint is more of a ball joint in the points' frame than
        # in the parent's: SCoRE's two estimates of the centre agree better
        for name, (rp, tp, _, _) in list(self.point_frames.items()):
            spec = self.template.segment(name)
            (rq, tq), (rc, tc) = self.tech[self.framed_ancestor(spec)], self.tech[name]
            if jc.score_centre(rp, tp, rc, tc)[2] >= jc.score_centre(rq, tq, rc, tc)[2]:
                del self.point_frames[name]

    # steps --------------------------------------------------------------------
    def technical(self, spec: SegmentSpec, extra: np.ndarray | None = None) -> None:
        names = self.present(spec)
        pts = [self.marker(m) for m in names]
        if extra is not None:
            pts.append(extra)
        if len(pts) < 3:
            return
        stack = np.stack(pts, axis=1)  # (T, K, 3)
        if (np.isfinite(stack).all(axis=2).sum(axis=1) >= 3).sum() < MIN_CALIBRATION_FRAMES:
            return
        _, rot, trans = cluster_frames(stack)
        self.tech[spec.name] = (rot, trans)

    def centre_from_child_markers(
        self,
        spec: SegmentSpec,
        parent: tuple[np.ndarray, np.ndarray],
        prior_w: np.ndarray,
        child_markers: list[str],
    ) -> tuple[str, list[float], np.ndarray]:
        """Method, spread (deg), centre (T, 3) m: from the child's markers in the parent's frame."""
        assert spec.centre is not None
        kind = spec.centre["kind"]
        along = spec.centre["prior"].get("along")
        method = "regression"
        spread: list[float] = []
        centre_w = prior_w
        rp, tp = parent
        y = to_local(rp, tp, np.stack([self.marker(m) for m in child_markers], axis=1))
        pp = _nanmedian0(to_local(rp, tp, prior_w[:, None])[:, 0])
        c = None
        if (np.isfinite(y).all(axis=2).any(axis=1)).sum() >= MIN_CALIBRATION_FRAMES and np.isfinite(
            pp
        ).all():
            # the range of motion seen from the prior centre: a fitted centre is
            # meaningless when the markers hardly move
            s2 = jc.direction_spread(y, pp)
            c0, _ = jc.sphere_centre(y)
            spread = [round(float(v), 2) for v in s2]
            if kind == "ball" and s2[1] >= self.min_spread:
                c, method = c0, "sphere fit"
            elif s2[0] >= self.min_spread and np.isfinite(pp).all():
                c, axis = jc.sphere_centre(y, pp, hinge=True)
                assert axis is not None  # hinge=True always returns the axis
                if along == "axis":
                    prior_w = self.prior_along(spec, np.einsum("tij,j->ti", rp, axis))
                    pp = _nanmedian0(to_local(rp, tp, prior_w[:, None])[:, 0])
                    if np.isfinite(pp).all():
                        c = jc.closest_on_line(c, axis, pp)
                self.axes_local[spec.name] = (axis, np.full(3, np.nan))
                method = "sphere-fit axis" if kind == "hinge" else "sphere-fit axis + regression"
        if c is not None:
            centre_w = to_world(rp, tp, c[None])[:, 0]
            centre_w = np.where(np.isfinite(centre_w), centre_w, prior_w)
        return method, spread, centre_w

    def centre_between_frames(
        self, spec: SegmentSpec, parent: tuple[np.ndarray, np.ndarray], prior_w: np.ndarray
    ) -> tuple[str, list[float], np.ndarray]:
        """Method, spread (deg), centre (T, 3) m of a joint between two framed segments.

        SCoRE in the joint's ``parent_points`` frame (:meth:`centres_in_parent_points`),
        SCoRE for a ball joint, SARA for a hinge; the prior ``prior_w`` (T, 3) where the
        range of motion in the parent's technical frame ``parent`` is too small.
        """
        assert spec.centre is not None
        kind = spec.centre["kind"]
        along = spec.centre["prior"].get("along")
        method = "regression"
        centre_w = prior_w
        rp, tp = parent
        rc, tc = self.tech[spec.name]
        s = jc.motion_spread(rp, rc)
        spread = [round(float(v), 2) for v in s]
        pp = _nanmedian0(to_local(rp, tp, prior_w[:, None])[:, 0])
        pc = _nanmedian0(to_local(rc, tc, prior_w[:, None])[:, 0])
        fitted: tuple[np.ndarray, np.ndarray] | None = None
        sv = jc.fit_singular_values(rp, tp, rc, tc)
        if spec.name in self.point_frames:
            rp, tp, cp, cc = self.point_frames[spec.name]
            spread = [round(float(v), 2) for v in jc.motion_spread(rp, rc)]
            sv = jc.fit_singular_values(rp, tp, rc, tc)
            fitted = (cp, cc)
            method = "SCoRE in its parent_points frame"
        elif kind == "ball" and s[1] >= self.min_spread:
            usable = np.isfinite(pp).all() and np.isfinite(pc).all()
            cp, cc, _ = jc.score_centre(
                rp, tp, rc, tc,
                prior=(pp, pc) if usable else None,
                prior_spread_deg=self.score_prior_spread_deg,
            )  # fmt: skip
            method = "SCoRE"
            rp, tp, cp, cc, loose = self.score_without_loose(spec, rp, tp, rc, tc, cp, cc)
            if loose:
                self.loose[spec.name] = loose
                method = (
                    f"SCoRE without {', '.join(loose)}"
                    if len(loose) <= 3
                    else f"SCoRE without {len(loose)} parent markers"
                )
                pp = _nanmedian0(to_local(rp, tp, prior_w[:, None])[:, 0])
                sv = jc.fit_singular_values(rp, tp, rc, tc)
            fitted = (cp, cc)
            along_axes = self.along_axis(spec, rp, rc)
            if along_axes is not None:
                ap, ac = along_axes
                prior_w = self.prior_along(spec, np.einsum("tij,j->ti", rp, ap))
                pp, pc = (
                    _nanmedian0(to_local(r, t, prior_w[:, None])[:, 0])
                    for r, t in ((rp, tp), (rc, tc))
                )
                if np.isfinite(pp).all() and np.isfinite(pc).all():
                    # a prior trusted along the axis: it also takes the directions
                    # the take hardly determines (under ALONG_PRIOR_SPREAD_DEG)
                    cp, cc, _ = jc.score_centre(
                        rp, tp, rc, tc, prior=(pp, pc),
                        prior_spread_deg=max(self.score_prior_spread_deg, ALONG_PRIOR_SPREAD_DEG),
                    )  # fmt: skip
                    fitted = jc.slide_along_axis(cp, cc, ap, ac, pp, pc)
                    method = "SCoRE + regression along the axis"
        elif s[0] >= self.min_spread and np.isfinite(pp).all():
            ap, ac, cp, cc = jc.sara_axis(rp, tp, rc, tc, pp, pc)
            # along the axis: where the two bones cross it (templates: axis_point)
            crossing = self.axis_point(spec, ((rp, tp), (rc, tc)), ap, cp)
            if crossing is not None:
                cp, cc = jc.slide_along_axis(cp, cc, ap, ac, *crossing)
            elif along == "axis":
                prior_w = self.prior_along(spec, np.einsum("tij,j->ti", rp, ap))
                pp, pc = (
                    _nanmedian0(to_local(r, t, prior_w[:, None])[:, 0])
                    for r, t in ((rp, tp), (rc, tc))
                )
                if np.isfinite(pp).all() and np.isfinite(pc).all():
                    cp, cc = jc.slide_along_axis(cp, cc, ap, ac, pp, pc)
            fitted = (cp, cc)
            self.axes_local[spec.name] = (ap, ac)
            method = "SARA" if kind == "hinge" else "SARA axis + regression"
            if crossing is not None:
                method += ", centre where the bones cross the axis"
        self.conditions[spec.name] = [round(float(v), 4) for v in sv]
        if fitted is not None:
            cp, cc = fitted
            wp = to_world(rp, tp, cp[None])[:, 0]
            wc = to_world(rc, tc, cc[None])[:, 0]
            centre_w = np.where(np.isfinite(wp), np.where(np.isfinite(wc), 0.5 * (wp + wc), wp), wc)
        return method, spread, centre_w

    def centre(self, spec: SegmentSpec) -> None:
        assert spec.parent is not None and spec.centre is not None
        prior_w = self.prior(spec)
        parent = self.tech.get(spec.parent)
        if spec.link:
            # a link's joint is its prior (no functional fit: nothing rides it alone) and
            # its frame starts as its parent's; inverse kinematics lets it turn
            self.methods[spec.name] = "link (template prior)"
            self.spreads[spec.name] = []
            self.centres[spec.name] = prior_w
            if parent is not None:
                self.tech[spec.name] = parent
            return
        child_markers = self.present(spec)
        method = "regression"
        spread: list[float] = []
        centre_w = prior_w
        if parent is not None and spec.name in self.tech:
            method, spread, centre_w = self.centre_between_frames(spec, parent, prior_w)
        elif parent is not None and child_markers:
            method, spread, centre_w = self.centre_from_child_markers(
                spec, parent, prior_w, child_markers
            )
        if method == "regression":
            why = (
                "its parent segment has no frame"
                if parent is None
                else f"range of motion {', '.join(f'{v:.1f}' for v in spread) or 'unmeasured'} deg "
                f"is under {self.min_spread:g} deg on the axes it needs"
            )
            warnings.warn(
                f"joint {spec.joint}: centre from the template's regression ({why})",
                SkincapWarning,
                stacklevel=4,
            )
        self.methods[spec.name] = method
        self.spreads[spec.name] = spread
        self.centres[spec.name] = centre_w
        if spec.name not in self.tech:
            self.technical(spec, extra=centre_w)
        if spec.name in self.axes_local:
            ap, ac = self.axes_local[spec.name]
            rp, _ = parent  # type: ignore[misc]
            world = np.einsum("tij,j->ti", rp, ap)
            if spec.name in self.tech and not np.isfinite(ac).all():
                rc, _ = self.tech[spec.name]
                ac = _unit(_nanmedian0(np.einsum("tji,tj->ti", rc, world)))
                self.axes_local[spec.name] = (ap, ac)
            self.hinge_world[spec.name] = world

    def orient_hinges(self) -> None:
        """Sign each hinge axis along the mean flexion direction ``(J - P) x (D - J)``."""
        for spec in self.template.segments[1:]:
            if spec.name not in self.hinge_world:
                continue
            flex = (spec.centre or {}).get("flexion")
            if not flex:
                continue
            try:
                p, j, d = (self.point([n] if isinstance(n, str) else n, spec.name) for n in flex)
            except ValidationError:
                continue
            cross = np.cross(j - p, d - j)
            ok = np.isfinite(cross).all(axis=1) & np.isfinite(self.hinge_world[spec.name]).all(
                axis=1
            )
            if ok.any() and np.einsum("ti,ti->", cross[ok], self.hinge_world[spec.name][ok]) < 0:
                self.hinge_world[spec.name] = -self.hinge_world[spec.name]
                ap, ac = self.axes_local[spec.name]
                self.axes_local[spec.name] = (-ap, -ac)

    def anatomical(self, spec: SegmentSpec) -> None:
        if spec.link:
            assert spec.parent is not None  # the template parser refuses a root link
            frames = self.anat[spec.parent]
            origin = self.centres[spec.name]
            if spec.name in self.tech:
                rt, tt = self.tech[spec.name]
                o_loc = _nanmedian0(to_local(rt, tt, origin[:, None])[:, 0])
                if np.isfinite(o_loc).all():
                    origin = to_world(rt, tt, o_loc[None])[:, 0]
            self.anat[spec.name] = frames
            self.origin[spec.name] = origin
            return
        (a1, from1, to1), second = spec.axes[0], spec.axes[1]
        where = f"segment {spec.name} axes"
        e1 = _unit(
            self.point(list(from1) if isinstance(from1, list) else [from1], where) * -1
            + self.point(list(to1) if isinstance(to1, list) else [to1], where)
        )
        a2 = second[0]
        e2 = None
        if len(second) == 3:
            e2 = _unit(
                self.point(_as_list(second[2]), where) - self.point(_as_list(second[1]), where)
            )
        elif second[1].lstrip("-").startswith("hinge:"):
            seg = second[1].lstrip("-")[len("hinge:") :]
            if seg in self.hinge_world:
                e2 = self.hinge_world[seg] * (-1.0 if second[1].startswith("-") else 1.0)
        if e2 is None:  # "parent", or a hinge whose axis could not be found
            if spec.parent is None:
                raise ValidationError(f"{where}: no second axis")
            e2 = self.anat[spec.parent][..., :, _AXIS_INDEX[a2]]
        frames = _right_handed(_AXIS_INDEX[a1], _AXIS_INDEX[a2], e1, e2)  # (T, 3, 3)
        if spec.parent is None:
            origin = self.point(list(spec.origin or []), f"segment {spec.name} origin")
        else:
            origin = self.centres[spec.name]
        if spec.name in self.tech:
            # constant in the technical frame: smoother, and defined wherever the cluster is
            rt, tt = self.tech[spec.name]
            rel = _mean_rotation(np.einsum("tji,tjk->tik", rt, frames))
            o_loc = _nanmedian0(to_local(rt, tt, origin[:, None])[:, 0])
            if np.isfinite(rel).all() and np.isfinite(o_loc).all():
                frames = rt @ rel
                origin = to_world(rt, tt, o_loc[None])[:, 0]
        self.anat[spec.name] = frames
        self.origin[spec.name] = origin


def calibrate(
    markers: MarkerSet,
    template: Template,
    *,
    min_spread_deg: float = jc.MIN_SPREAD_DEG,
    score_prior_spread_deg: float = 0.0,
) -> BodyModel:
    """Calibrate a body model on a labelled take.

    Parameters
    ----------
    markers : MarkerSet
        Labelled capture, metres, Y up (NaN where missing).
    template : Template
    min_spread_deg : float
        Least range of motion for the functional methods (see
        :func:`skincap.solve.joint_centres.motion_spread`).
    score_prior_spread_deg : float, default 0
        SCoRE takes the template's regression estimate along the directions the take
        turns a joint through less than about this RMS spread (degrees;
        :func:`skincap.solve.joint_centres.score_centre`). 10 brings the synthetic
        walk's ankles from 21 / 25 mm to 18 / 15 mm, but raises the max residual of
        CMU 85_02 from 3.97 to 4.00 cm and of AML PronetoRun01 from 4.07 to 4.22 cm,
        hence off by default.

    Returns
    -------
    BodyModel

    Raises
    ------
    ValidationError
        No template marker in the capture; a segment with no marker; a segment that
        cannot get a frame (fewer than three points, markers and joint centre, in
        enough frames); a take with fewer than :data:`MIN_CALIBRATION_FRAMES` frames.

    Warns
    -----
    SkincapWarning
        A joint centre taken from the regression prior, naming the joint and the range
        of motion measured.
    """
    if markers.n_frames < MIN_CALIBRATION_FRAMES:
        raise ValidationError(
            f"the take has {markers.n_frames} frames; calibration needs at least {MIN_CALIBRATION_FRAMES}"
        )
    cal = _Calibrator(markers, template, min_spread_deg)
    cal.score_prior_spread_deg = float(score_prior_spread_deg)
    segs = template.segments
    for spec in segs:
        if not cal.present(spec) and not spec.link:
            raise ValidationError(
                f"segment {spec.name} has none of its template markers "
                f"({', '.join(spec.markers)}) in the capture (or they are never seen)"
            )
        cal.technical(spec)
    root = segs[0]
    if root.name not in cal.tech:
        raise ValidationError(
            f"segment {root.name} needs three markers seen together in {MIN_CALIBRATION_FRAMES} "
            f"frames; the capture has {', '.join(cal.present(root))}"
        )
    with np.errstate(invalid="ignore"):
        cal.centres_in_parent_points()
        for spec in segs[1:]:
            cal.centre(spec)
    cal.orient_hinges()
    # the root's origin needs its children's centres; anatomical frames top-down
    for spec in segs:
        cal.anatomical(spec)
        if not np.isfinite(cal.anat[spec.name]).all(axis=(1, 2)).any():
            raise ValidationError(
                f"segment {spec.name}: fewer than three points (markers "
                f"{', '.join(cal.present(spec))} and its joint centre) in any frame: no frame for it"
            )
    return _model(cal, markers)


def _model(cal: _Calibrator, markers: MarkerSet) -> BodyModel:
    segs = cal.template.segments
    index = {s.name: k for k, s in enumerate(segs)}
    parents = np.array([-1 if s.parent is None else index[s.parent] for s in segs], dtype=np.int64)
    offsets = np.zeros((len(segs), 3))
    for k, spec in enumerate(segs[1:], start=1):
        p = segs[parents[k]].name
        rel = np.einsum("tji,tj->ti", cal.anat[p], cal.origin[spec.name] - cal.origin[p])
        offsets[k] = _nanmedian0(rel)
        if not np.isfinite(offsets[k]).all():
            raise ValidationError(
                f"segment {spec.name}: its joint centre and segment {p}'s frame are never "
                "known in the same frame (their markers are not seen together)"
            )
    labels, columns, seg_of, local = [], [], [], []
    for k, spec in enumerate(segs):
        for m in cal.present(spec):
            loc = _nanmedian0(
                np.einsum("tji,tj->ti", cal.anat[spec.name], cal.marker(m) - cal.origin[spec.name])
            )
            if not np.isfinite(loc).all():
                continue  # never seen together with its segment's frame
            labels.append(markers.labels[cal.columns[m]])
            columns.append(cal.columns[m])
            seg_of.append(k)
            local.append(loc)
    ends: dict[str, np.ndarray] = {}
    fixed: dict[str, list[tuple[str, np.ndarray]]] = {}
    has_child = set(s.parent for s in segs)
    for spec in segs:
        frames, origin = cal.anat[spec.name], cal.origin[spec.name]

        def local_of(names: list[str], _f=frames, _o=origin, _s=spec) -> np.ndarray:
            pt = cal.point(names, f"segment {_s.name}")
            return _nanmedian0(np.einsum("tji,tj->ti", _f, pt - _o))

        if spec.fixed_joints:
            to = local_of(_as_list(spec.axes[0][2]))
            fixed[spec.name] = [(str(f["name"]), float(f["at"]) * to) for f in spec.fixed_joints]
        if spec.name not in has_child:
            ends[spec.name] = local_of(spec.end or _as_list(spec.axes[0][2]))
    init = np.stack([cal.anat[s.name] for s in segs], axis=1)  # (T, S, 3, 3)
    return BodyModel(
        segment_names=[s.name for s in segs],
        segment_parents=parents,
        joint_offsets=offsets,
        marker_labels=labels,
        marker_columns=np.array(columns, dtype=np.int64),
        marker_segments=np.array(seg_of, dtype=np.int64),
        marker_offsets=np.array(local).reshape(-1, 3),
        init_rotations=init,
        init_origins=cal.origin[segs[0].name],
        template=cal.template,
        ends=ends,
        fixed=fixed,
        methods=dict(cal.methods),
        spreads_deg=dict(cal.spreads),
        fit_singular_values=dict(cal.conditions),
        loose_markers=dict(cal.loose),
        link_stiffness=np.array([s.stiffness if s.link else 0.0 for s in segs]),
        joint_limits=_joint_limits(segs),
        bone_axes=np.array(
            [_AXIS_INDEX[s.axes[0][0]] if s.axes else 1 for s in segs], dtype=np.int64
        ),
    )


def _joint_limits(segs: list[SegmentSpec]) -> np.ndarray:
    """(S, 3, 2) radians of the segments' ``limits`` (NaN where none)."""
    out = np.full((len(segs), 3, 2), np.nan)
    for k, spec in enumerate(segs):
        for axis, pair in spec.limits_deg.items():
            out[k, _AXIS_INDEX[axis]] = [np.nan if v is None else np.radians(v) for v in pair]
    return out
