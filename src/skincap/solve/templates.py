"""Marker-set templates: which markers ride which segment, and how joints and axes are found.

A template is a small JSON file (the built-in ones are ``skincap/data/solve_template_*.json``;
a user writes one for their own set in the same form)::

    {"name": "cmu41", "description": "...",
     "segments": [                               # parents before children
       {"name": "pelvis", "joint": "Hips", "parent": null,
        "markers": ["LFWT", "RFWT", "LBWT", "RBWT"],
        "origin": ["@thigh_l", "@thigh_r"],      # root only: where its joint sits
        "axes": [["y", FROM, TO], ["x", FROM, TO]]},
       {"name": "thigh_l", "joint": "LeftHip", "parent": "pelvis",
        "markers": ["LTHI", "LKNE"],
        "centre": {"kind": "ball", "prior": PRIOR},
        "axes": [["y", ["@shank_l"], ["@thigh_l"]], ["x", "hinge:shank_l"]]}, ...]}

* ``markers``: labels riding the segment (matched with a ``Subject:`` prefix stripped;
  a template marker absent from the capture is simply not used).
* ``joint``: the output BVH joint whose rotation moves the segment; ``parent_joint``
  (default: the parent segment's joint) and ``via`` (zero-length fixed joints in
  between, e.g. collars) shape the hierarchy; ``fixed_joints`` ``[{"name", "at"}]``
  put rotation-less joints inside the segment at fraction ``at`` of its primary axis.
* ``centre``: the joint between the parent and this segment. ``kind`` ``"ball"``
  (SCoRE, or a common-centre sphere fit when the segment has under three markers) or
  ``"hinge"`` (SARA axis, centre the point of it nearest the prior; ``flexion``
  ``[P, J, D]`` orients the axis along the mean of ``(J - P) x (D - J)``). ``prior``
  is the regression used when the range of motion is too small and to place a centre
  on a hinge axis: ``{"harrington": "left"|"right", "asis": [L, R], "psis": [L, R]}``
  or ``{"from": POINTS, "towards": POINTS, "distance": metres | "fraction": f}``
  (``"towards_line": [POINTS, POINTS]`` instead of ``towards``: towards the nearest
  point of that line, e.g. from the elbow marker towards the shoulder-wrist line).
  ``"along": "axis"`` (with ``towards`` and ``distance``): once the joint's functional
  axis is found (a hinge's SARA or sphere-fit axis; a ball joint's principal axis of
  rotation) the prior is ``distance`` from ``from`` along that axis, signed towards
  ``towards``, and the centre takes the prior's place along the axis -- the one
  direction a joint that mostly flexes does not determine. ``"along":
  "hinge:SEGMENT"`` uses that segment's hinge axis instead (an ankle along its knee's
  axis). From a knee marker, the other knee is not straight medial in a walk (the
  legs pass each other), so ``towards`` alone misplaces the centre along the axis.
  ``"axis_point": [POINTS, POINTS]`` (a hinge): once SARA found the axis, the
  centre's place along it is midway between the feet of the perpendiculars from the
  two points (the proximal and the distal joint centre, e.g. ``[["@upperarm_l"],
  ["LWRA", "LWRB"]]``): where the two bones' long axes cross the flexion axis; their
  carrying angles tilt the bones about equally either way, so the mean cancels them.
  The prior still gives the centre when the joint hardly moves.
  ``"parent_points": [POINTS, ...]`` (a ball joint, three or more entries): SCoRE in
  a parent frame made of these points rather than of all the parent's markers -- the
  markers that ride the part of the parent the joint sits on, a centroid of markers,
  and ``@SIBLING`` for a sibling joint's centre (same parent, ``parent_points`` of its
  own; the siblings' centres are solved together, each in a frame holding the
  others'). For a parent that bends (a thorax whose upper part carries the
  shoulders while CLAV, STRN and T10 ride the part below): the frame follows the
  part the joint rides.
* ``axes``: the anatomical frame. The first entry's axis is exact (``FROM`` -> ``TO``),
  the second is orthogonalised; the third follows (right-handed). A second entry may
  be ``"hinge:SEGMENT"`` (that segment's joint axis, ``"-hinge:..."`` reversed) or
  ``"parent"`` (the parent's axis of that name). The frames are chosen so that all
  identity rotations give a T-pose facing +Z with Y up and the body's left on +X.
* POINTS: a list of marker labels and ``@segment`` (that segment's joint centre), averaged.
* ``end``: POINTS of a leaf segment's end site.
* ``link``: ``true`` for a segment the set has (almost) no markers for but the body
  bends at -- the neck between thorax and head, a clavicle between thorax and upper
  arm. Its proximal joint comes from the ``prior`` alone (no range-of-motion test),
  its frame starts as its parent's, and inverse kinematics rotates it against a
  spring ``stiffness`` (metres per radian, default :data:`LINK_STIFFNESS_M_PER_RAD`)
  pulling it back to its parent's orientation, so the head or shoulder can translate
  relative to the trunk without absorbing every residual. ``markers`` may list markers
  riding it (an acromion marker on a clavicle) or be empty. ``axes`` is not needed.
* ``limits``: optional joint limits, ``{"x": [LOW, HIGH], ...}`` in degrees (``null``
  for an open end): bounds on the component along the parent's anatomical axis of
  the rotation vector of the segment's frame in its parent's (for a knee, flexion
  about x; with the frames above a straight joint is 0). Inverse kinematics enforces
  them only when asked (``solve --joint-limits``), as a stiff penalty beyond the range.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skincap.data import path as data_path
from skincap.errors import FormatError, ValidationError
from skincap.io.json_file import parse_json, read_json

__all__ = [
    "BUILTIN_TEMPLATES",
    "LINK_STIFFNESS_M_PER_RAD",
    "SegmentSpec",
    "Template",
    "detect_template",
    "load_template",
    "strip_prefix",
]

#: Built-in template names -> their file among the shipped data (``skincap/data/``).
BUILTIN_TEMPLATES: dict[str, str] = {
    "pig": "solve_template_pig.json",
    "cmu41": "solve_template_cmu41.json",
    "synth-sparse": "solve_template_synth_sparse.json",
    "synth-dense": "solve_template_synth_dense.json",
    "aml62": "solve_template_aml62.json",
}

_AXES = ("x", "y", "z")

#: Default spring of a ``link`` segment: a 0.1 rad (5.7 deg) turn away from its parent
#: costs as much as a 3 mm marker residual.
LINK_STIFFNESS_M_PER_RAD = 0.03


@dataclass
class SegmentSpec:
    """One segment of a template (see the module docstring for the fields)."""

    name: str
    joint: str
    parent: str | None
    markers: list[str]
    axes: list[Any]
    centre: dict[str, Any] | None = None
    origin: list[str] | None = None
    parent_joint: str | None = None
    via: list[str] = field(default_factory=list)
    fixed_joints: list[dict[str, Any]] = field(default_factory=list)
    end: list[str] | None = None
    link: bool = False
    stiffness: float = LINK_STIFFNESS_M_PER_RAD
    limits_deg: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)


def _parse_limits(bad: Any, name: str, raw: Any) -> dict[str, tuple[float | None, float | None]]:
    """``{"x": [low, high]}`` (degrees, ``null`` for none) -> validated dict."""
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise bad(f"segment {name!r}: 'limits' must be an object such as {{\"x\": [-5, 150]}}")
    out: dict[str, tuple[float | None, float | None]] = {}
    for axis, pair in raw.items():
        ok = (
            axis in _AXES
            and isinstance(pair, list)
            and len(pair) == 2
            and all(v is None or (isinstance(v, (int, float)) and abs(v) <= 180) for v in pair)
        )
        if not ok:
            raise bad(
                f"segment {name!r}: limits[{axis!r}] must be [low, high] in degrees "
                "(-180..180 or null) on an axis x, y or z"
            )
        lo, hi = (None if v is None else float(v) for v in pair)
        if lo is not None and hi is not None and lo > hi:
            raise bad(f"segment {name!r}: limits[{axis!r}] low {lo:g} is above high {hi:g}")
        out[axis] = (lo, hi)
    return out


@dataclass
class Template:
    """A validated marker-set template: ``segments`` parents first."""

    name: str
    description: str
    segments: list[SegmentSpec]

    @property
    def markers(self) -> list[str]:
        return [m for s in self.segments for m in s.markers]

    def segment(self, name: str) -> SegmentSpec:
        for s in self.segments:
            if s.name == name:
                return s
        raise ValidationError(f"template {self.name}: no segment {name!r}")


def strip_prefix(label: str) -> str:
    """``'Subject:LKNE'`` -> ``'LKNE'`` (the part after the last colon), stripped."""
    return label.rsplit(":", 1)[-1].strip()


def _points(where: str, value: Any, bad: Any = ValidationError) -> list[str]:
    """POINTS (one label or a non-empty list of labels and ``@segment`` names) as a list;
    ``bad`` builds the error (the parser's names the template file)."""
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise bad(f"{where}: expected a list of marker labels or '@segment' names")
    return list(value)


def _is_number(value: Any) -> bool:
    """A finite JSON number (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_prior(bad: Any, name: str, centre: dict[str, Any]) -> None:
    """Validate a centre's ``prior`` and a hinge's ``flexion`` (module docstring)."""
    prior = centre["prior"]
    where = f"segment {name!r} prior"
    if "harrington" in prior:
        if prior["harrington"] not in ("left", "right"):
            raise bad(f"{where}: 'harrington' must be 'left' or 'right'")
        for key in ("asis", "psis"):
            pair = prior.get(key)
            if not (
                isinstance(pair, list) and len(pair) == 2 and all(isinstance(m, str) for m in pair)
            ):
                raise bad(f"{where}: 'harrington' needs {key!r}: [LEFT, RIGHT] marker labels")
    else:
        _points(f"{where} 'from'", prior["from"], bad)
        if "towards" in prior:
            _points(f"{where} 'towards'", prior["towards"], bad)
        if "towards_line" in prior:
            line = prior["towards_line"]
            if not (isinstance(line, list) and len(line) == 2):
                raise bad(f"{where}: 'towards_line' must be [POINTS, POINTS]")
            for end in line:
                _points(f"{where} 'towards_line'", end, bad)
        for key in ("distance", "fraction"):
            if key in prior and not _is_number(prior[key]):
                raise bad(f"{where}: {key!r} must be a finite number")
    if centre["kind"] == "hinge":
        for point in centre["flexion"]:
            _points(f"segment {name!r} flexion", point, bad)


def _check_axes(bad: Any, name: str, parent: str | None, axes: Any) -> None:
    """Validate a segment's ``axes`` (see the module docstring); ``bad`` builds the error."""
    if not isinstance(axes, list) or len(axes) != 2:
        raise bad(f"segment {name!r}: 'axes' needs two entries")
    first, second = axes
    if not (isinstance(first, list) and len(first) == 3 and first[0] in _AXES):
        raise bad(f"segment {name!r}: first axis must be [axis, FROM, TO]")
    _points(f"segment {name!r} axis", first[1], bad)
    _points(f"segment {name!r} axis", first[2], bad)
    if not (isinstance(second, list) and second and second[0] in _AXES and second[0] != first[0]):
        raise bad(f"segment {name!r}: second axis must name another of x, y, z")
    if len(second) == 2:
        ref = second[1]
        if not (isinstance(ref, str) and (ref == "parent" or ref.lstrip("-").startswith("hinge:"))):
            raise bad(
                f"segment {name!r}: second axis reference must be 'parent' or '[-]hinge:SEGMENT'"
            )
        if ref == "parent" and parent is None:
            raise bad(f"segment {name!r}: the root cannot take its axis from a parent")
    elif len(second) != 3:
        raise bad(f"segment {name!r}: second axis must be [axis, FROM, TO] or [axis, REFERENCE]")


def _check_centre(bad: Any, name: str, names: set[str], centre: Any) -> None:
    """Validate a non-root segment's ``centre`` against the earlier segment ``names``."""
    if not isinstance(centre, dict) or centre.get("kind") not in ("ball", "hinge"):
        raise bad(f"segment {name!r}: 'centre' needs kind 'ball' or 'hinge'")
    prior = centre.get("prior")
    if not isinstance(prior, dict) or not ("harrington" in prior or "from" in prior):
        raise bad(f"segment {name!r}: centre 'prior' needs 'harrington' or 'from'")
    along = prior.get("along")
    if along is not None and not (
        along == "axis"
        or (isinstance(along, str) and along.removeprefix("hinge:") in names)
        and along.startswith("hinge:")
    ):
        raise bad(
            f"segment {name!r}: prior 'along' must be 'axis' or 'hinge:SEGMENT' "
            f"(an earlier segment), got {along!r}"
        )
    if along is not None and not (
        ("towards" in prior or "towards_line" in prior) and "distance" in prior
    ):
        raise bad(f"segment {name!r}: prior 'along' needs 'towards' and a 'distance'")
    flexion = centre.get("flexion", [])
    if centre["kind"] == "hinge" and not (isinstance(flexion, list) and len(flexion) == 3):
        raise bad(f"segment {name!r}: a hinge needs 'flexion': [P, J, D]")
    axis_point = centre.get("axis_point")
    if axis_point is not None:
        if centre["kind"] != "hinge" or not (isinstance(axis_point, list) and len(axis_point) == 2):
            raise bad(f"segment {name!r}: 'axis_point' is a hinge's [POINTS, POINTS]")
        for end in axis_point:
            _points(f"segment {name!r} axis_point", end, bad)
    parent_points = centre.get("parent_points")
    if parent_points is not None:
        if centre["kind"] != "ball" or not (
            isinstance(parent_points, list) and len(parent_points) >= 3
        ):
            raise bad(
                f"segment {name!r}: 'parent_points' is a ball joint's list of 3 or more POINTS"
            )
        for entry in parent_points:
            entry = _points(f"segment {name!r} parent_points", entry, bad)
            if any(n.startswith("@") for n in entry) and len(entry) > 1:
                raise bad(f"segment {name!r}: a parent_points '@segment' entry stands alone")
    _check_prior(bad, name, centre)


def _check_parent_points(bad: Any, segments: list[SegmentSpec]) -> None:
    """Each ``@segment`` of a ``parent_points`` names a sibling (same parent) that has
    ``parent_points`` too: their centres are solved together."""
    by_name = {s.name: s for s in segments}
    for spec in segments:
        for entry in (spec.centre or {}).get("parent_points", []):
            entry = [entry] if isinstance(entry, str) else entry
            for n in entry:
                other = by_name.get(n[1:]) if n.startswith("@") else None
                if n.startswith("@") and (
                    other is None
                    or other.name == spec.name
                    or other.parent != spec.parent
                    or "parent_points" not in (other.centre or {})
                ):
                    raise bad(
                        f"segment {spec.name!r}: parent_points {n!r} must be a sibling "
                        "segment (same parent) with parent_points of its own"
                    )


def _parse(data: Any, source: str) -> Template:
    def bad(what: str) -> FormatError:
        return FormatError(source, f"template: {what}")

    if not isinstance(data, dict) or not isinstance(data.get("segments"), list):
        raise bad("expected an object with a 'segments' list")
    if not data["segments"]:
        raise bad("'segments' is empty")
    segments: list[SegmentSpec] = []
    names: set[str] = set()
    joints: set[str] = set()
    seen_markers: set[str] = set()
    for k, raw in enumerate(data["segments"]):
        if not isinstance(raw, dict):
            raise bad(f"segment {k}: expected an object")
        try:
            name = str(raw["name"])
            joint = str(raw["joint"])
            markers = raw.get("markers", [])
            link = raw.get("link", False)
            axes = raw.get("axes", []) if link else raw["axes"]
        except KeyError as exc:
            raise bad(f"segment {k}: missing field {exc.args[0]!r}") from None
        parent = raw.get("parent")
        if not (isinstance(markers, list) and all(isinstance(m, str) for m in markers)):
            raise bad(f"segment {name!r}: 'markers' must be a list of marker labels")
        via = raw.get("via", [])
        if not (isinstance(via, list) and all(isinstance(v, str) for v in via)):
            raise bad(f"segment {name!r}: 'via' must be a list of joint names")
        fixed_joints = raw.get("fixed_joints", [])
        if not (
            isinstance(fixed_joints, list)
            and all(
                isinstance(f, dict) and isinstance(f.get("name"), str) and _is_number(f.get("at"))
                for f in fixed_joints
            )
        ):
            raise bad(f'segment {name!r}: \'fixed_joints\' must be a list of {{"name", "at"}}')
        if not isinstance(link, bool):
            raise bad(f"segment {name!r}: 'link' must be true or false")
        stiffness = raw.get("stiffness", LINK_STIFFNESS_M_PER_RAD)
        if link and parent is None:
            raise bad(f"segment {name!r}: the root cannot be a link")
        if not _is_number(stiffness) or not stiffness > 0:
            raise bad(
                f"segment {name!r}: 'stiffness' must be a positive number (metres per radian)"
            )
        if name in names:
            raise bad(f"segment {name!r} appears twice")
        if parent is not None and parent not in names:
            raise bad(f"segment {name!r}: parent {parent!r} must be an earlier segment")
        if (parent is None) != (k == 0):
            raise bad(
                f"segment {name!r}: the first segment, and only it, is the root (parent null)"
            )
        if joint in joints:
            raise bad(f"segment {name!r}: joint {joint!r} used twice")
        dup = seen_markers.intersection(markers)
        if dup or len(set(markers)) != len(markers):
            raise bad(f"segment {name!r}: marker(s) {sorted(dup) or markers} on two segments")
        seen_markers.update(markers)
        if not link:
            _check_axes(bad, name, parent, axes)
        centre = raw.get("centre")
        if parent is not None:
            _check_centre(bad, name, names, centre)
        limits = _parse_limits(bad, name, raw.get("limits"))
        if limits and parent is None:
            raise bad(f"segment {name!r}: the root has no joint to limit")
        origin = raw.get("origin")
        if parent is None and origin is None:
            raise bad(f"segment {name!r}: the root needs an 'origin'")
        segments.append(
            SegmentSpec(
                name=name,
                joint=joint,
                parent=parent,
                markers=markers,
                axes=axes,
                centre=centre,
                origin=None if origin is None else _points(f"segment {name!r} origin", origin, bad),
                parent_joint=raw.get("parent_joint"),
                via=list(via),
                fixed_joints=list(fixed_joints),
                end=None
                if raw.get("end") is None
                else _points(f"segment {name!r} end", raw["end"], bad),
                link=link,
                stiffness=float(stiffness),
                limits_deg=limits,
            )
        )
        names.add(name)
        joints.update([joint, *segments[-1].via, *(f["name"] for f in segments[-1].fixed_joints)])
    if not seen_markers:  # nothing to match a capture's labels against, nothing to fit
        raise bad("no segment lists any 'markers'; a template needs at least one marker label")
    _check_parent_points(bad, segments)
    return Template(
        name=str(data.get("name", Path(source).stem)),
        description=str(data.get("description", "")),
        segments=segments,
    )


def load_template(template: str | os.PathLike[str]) -> Template:
    """A built-in template by name (:data:`BUILTIN_TEMPLATES`) or a JSON file.

    Raises
    ------
    FormatError
        The file is not valid JSON or not a valid template (names the file and the field).
    ValidationError
        Neither a built-in name nor an existing file.
    """
    key = os.fspath(template)
    if key in BUILTIN_TEMPLATES:
        source = f"template {key}"
        data = parse_json(source, data_path(BUILTIN_TEMPLATES[key]).read_text("utf-8"))
    else:
        path = Path(key)
        if not path.is_file():
            names = f"{', '.join(BUILTIN_TEMPLATES)} or auto"
            if path.suffix.lower() == ".json" or len(path.parts) > 1 or path.exists():
                # a path: the error names the template file, not the take
                what = "is a folder" if path.is_dir() else "no such file"
                raise FormatError(path, f"template: {what} (a template is a JSON file or {names})")
            raise ValidationError(f"template: {key!r} is neither a file nor one of {names}")
        source = key
        data = read_json(path, what="template JSON")
    return _parse(data, source)


def detect_template(
    labels: list[str], *, candidates: tuple[str, ...] | None = None, min_share: float = 0.5
) -> str | None:
    """The built-in template a capture's labels match best, or None.

    Each built-in template (or each of ``candidates``) is scored by the overlap of its
    markers with ``labels`` (``Subject:`` prefixes stripped) over their union, so a set
    that shares most labels with a larger one goes to the template it fills; the best
    is returned when at least ``min_share`` of its own markers are present. Sets with
    the same labels (synth-sparse and pig) tie, and the first in ``candidates`` (else
    :data:`BUILTIN_TEMPLATES` order) wins.
    """
    present = {strip_prefix(x) for x in labels}
    best, best_score = None, 0.0
    for name in candidates or tuple(BUILTIN_TEMPLATES):
        wanted = set(load_template(name).markers)
        common = len(wanted & present)
        score = common / len(wanted | present) if wanted else 0.0
        if score > best_score and common >= min_share * len(wanted):
            best, best_score = name, score
    return best
