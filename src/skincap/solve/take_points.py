"""The points a template names on a calibration take, per frame.

A :class:`~skincap.solve.templates.Template` names points by capture marker labels
(``Subject:`` prefixes stripped: :func:`match_markers`), marker centroids, ``@segment``
joint centres found so far, and regression priors built from them (``from`` /
``towards`` / ``towards_line`` / ``fraction`` / ``distance`` / ``harrington``, and
``along`` a joint's functional axis). :class:`TakePoints` resolves them over the take
for :mod:`skincap.solve.calibrate`, which fills in the centres, origins and hinge axes
they refer to as it goes.

Everything is in metres, Y up; points are (T, 3) over the take, NaN where not seen.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.errors import ValidationError
from skincap.solve import joint_centres as jc
from skincap.solve.templates import SegmentSpec, Template, strip_prefix
from skincap.types import MarkerSet

__all__ = ["TakePoints", "match_markers"]


# --------------------------------------------------------------- small helpers


def _nanmedian0(x: np.ndarray) -> np.ndarray:
    """Median over axis 0 ignoring NaN rows; NaN where a column has none (no warning)."""
    ok = np.isfinite(x).all(axis=tuple(range(1, x.ndim)))
    if not ok.any():
        return np.full(x.shape[1:], np.nan)
    return np.median(x[ok], axis=0)


def _nanmean0(x: np.ndarray) -> np.ndarray:
    """Mean over axis 0 of the rows without NaN; NaN where there is none (no warning)."""
    ok = np.isfinite(x).all(axis=tuple(range(1, x.ndim)))
    if not ok.any():
        return np.full(x.shape[1:], np.nan)
    return np.mean(x[ok], axis=0)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 1e-12, v / np.where(n > 0, n, 1.0), np.nan)


def match_markers(labels: list[str], template: Template) -> dict[str, int]:
    """Template label -> capture column, matching with ``Subject:`` prefixes stripped.

    Raises
    ------
    ValidationError
        No template marker is in the capture (the message lists what the template
        expects), or two capture columns strip to the same template label.
    """
    wanted = set(template.markers)
    found: dict[str, int] = {}
    for col, label in enumerate(labels):
        key = strip_prefix(label)
        if key in wanted:
            if key in found:
                raise ValidationError(
                    f"markers {labels[found[key]]!r} and {label!r} both match template marker {key!r}"
                )
            found[key] = col
    if not found:
        raise ValidationError(
            f"no marker matches template {template.name}; it expects "
            f"{', '.join(template.markers[:12])}{'...' if len(template.markers) > 12 else ''}"
        )
    return found


def _as_list(v: Any) -> list[str]:
    return list(v) if isinstance(v, list) else [v]


class TakePoints:
    """A take's markers matched to a template, and the points the template names on it.

    Holds what those points refer to as calibration finds it: ``centres`` (segment ->
    (T, 3) proximal joint centre), ``origin`` (segment -> (T, 3) anatomical origin) and
    ``hinge_world`` (segment -> (T, 3) unit hinge axis).
    """

    def __init__(self, markers: MarkerSet, template: Template) -> None:
        self.template = template
        self.columns = match_markers(markers.labels, template)
        self.labels = markers.labels
        self.positions = markers.positions
        self.seen = np.isfinite(markers.positions).all(axis=2).any(axis=0)  # (N,)
        self.n_frames = markers.n_frames
        self.centres: dict[str, np.ndarray] = {}
        self.origin: dict[str, np.ndarray] = {}
        self.hinge_world: dict[str, np.ndarray] = {}

    # points -------------------------------------------------------------------
    def present(self, spec: SegmentSpec) -> list[str]:
        """The segment's markers in the capture and seen in at least one frame."""
        return [m for m in spec.markers if m in self.columns and self.seen[self.columns[m]]]

    def marker(self, label: str) -> np.ndarray:
        return self.positions[:, self.columns[label]]

    def point(self, names: list[str], where: str) -> np.ndarray:
        """(T, 3) mean of markers and ``@segment`` centres.

        A list of markers averages those the capture has and sees in each frame; a
        list with a joint centre is NaN where any part is missing.
        """
        parts = []
        if len(names) > 1 and not any(n.startswith("@") for n in names):
            # a centroid of markers: one the capture lacks (never seen) drops out of it
            names = [n for n in names if n in self.columns] or names
        for n in names:
            if n.startswith("@"):
                seg = n[1:]
                if seg in self.centres:
                    parts.append(self.centres[seg])
                elif seg == self.template.segments[0].name and seg in self.origin:
                    parts.append(self.origin[seg])
                else:
                    raise ValidationError(f"{where}: joint centre {n} is not known yet")
            elif n in self.columns:
                parts.append(self.marker(n))
            else:
                raise ValidationError(f"{where}: needs marker {n}, which the capture does not have")
        stack = np.stack(parts)  # (P, T, 3)
        seen = np.isfinite(stack).all(axis=2)  # (P, T)
        if len(parts) == 1 or names[0].startswith("@"):
            return np.mean(stack, axis=0)  # joint centres and single markers: exact or NaN
        # a centroid of markers uses those seen in the frame (a hidden one would
        # otherwise blank the frame); with none seen it is NaN
        count = seen.sum(axis=0)
        total = np.where(seen[..., None], stack, 0.0).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count[:, None] > 0, total / count[:, None], np.nan)

    def prior_points(self, pr: dict[str, Any], where: str) -> tuple[np.ndarray, np.ndarray | None]:
        """A ``from``/``towards`` prior's (T, 3) start and target points (target None
        for a prior with neither ``towards`` nor ``towards_line``)."""
        start = self.point(list(pr["from"]), where)
        if "towards_line" in pr:
            # towards the nearest point of a line (e.g. shoulder centre -> mid-wrist):
            # from a marker on a joint's skin, that direction points into the joint
            a = self.point(_as_list(pr["towards_line"][0]), where)
            b = self.point(_as_list(pr["towards_line"][1]), where)
            d = _unit(b - a)
            return start, a + d * np.einsum("ti,ti->t", start - a, d)[:, None]
        if "towards" in pr:
            return start, self.point(_as_list(pr["towards"]), where)
        return start, None

    def prior(self, spec: SegmentSpec) -> np.ndarray:
        assert spec.centre is not None  # checked by the template parser
        pr = spec.centre["prior"]
        where = f"joint {spec.joint} (segment {spec.name})"
        if "harrington" in pr:
            la, ra = (self.point([m], where) for m in pr["asis"])
            lp, rp = (self.point([m], where) for m in pr["psis"])
            left, right = jc.harrington_hip_centres(la, ra, lp, rp)
            return left if pr["harrington"] == "left" else right
        start, towards = self.prior_points(pr, where)
        if towards is None:
            return start
        if "fraction" in pr:
            return start + float(pr["fraction"]) * (towards - start)
        return start + float(pr.get("distance", 0.0)) * _unit(towards - start)

    def along_axis(
        self, spec: SegmentSpec, r_parent: np.ndarray, r_child: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The axis a ball joint's prior ``along`` names, ``(a_p, a_c)`` (3,) unit in the
        parent's and the child's technical frames, or None (no ``along``, or the named
        hinge axis was not found).

        ``"axis"``: the joint's own principal axis of rotation
        (:func:`~skincap.solve.joint_centres.principal_axis`); ``"hinge:SEGMENT"``: that
        segment's hinge axis (an ankle's along its knee's: in a walk the foot turns most
        about the shank's long axis, so its own principal axis is not the flexion axis).
        """
        assert spec.centre is not None
        along = spec.centre["prior"].get("along")
        if along == "axis":
            return jc.principal_axis(r_parent, r_child)
        if not isinstance(along, str) or along.removeprefix("hinge:") not in self.hinge_world:
            return None
        world = self.hinge_world[along.removeprefix("hinge:")]  # (T, 3)
        ap, ac = (
            _unit(_nanmedian0(np.einsum("tji,tj->ti", r, world))) for r in (r_parent, r_child)
        )
        if not (np.isfinite(ap).all() and np.isfinite(ac).all()):
            return None
        return ap, ac

    def prior_along(self, spec: SegmentSpec, axis_world: np.ndarray) -> np.ndarray:
        """(T, 3) the prior ``from + distance * axis`` for a prior with ``"along": "axis"``.

        ``axis_world (T, 3)``: the joint's functional axis per frame (unit), signed here
        so that it points on average towards the prior's ``towards`` points: from a
        marker on the joint's lateral skin the centre lies along the axis, whatever
        the direction to the other side's marker (in a walk the feet and knees are
        not side by side, so ``towards`` alone points partly forwards or back).
        """
        assert spec.centre is not None
        pr = spec.centre["prior"]
        where = f"joint {spec.joint} (segment {spec.name})"
        start, towards = self.prior_points(pr, where)
        assert towards is not None  # the template parser requires it with "along"
        dots = np.einsum("ti,ti->t", axis_world, towards - start)
        sign = -1.0 if np.nansum(dots) < 0 else 1.0
        return start + float(pr["distance"]) * sign * axis_world

    def framed_ancestor(self, spec: SegmentSpec) -> str:
        """The segment's parent, or past ``link`` parents (their frame starts as their
        parent's) the first ancestor that is not a link."""
        assert spec.parent is not None
        name = spec.parent
        while self.template.segment(name).link and self.template.segment(name).parent:
            name = str(self.template.segment(name).parent)
        return name
