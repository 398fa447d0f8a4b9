"""``--template auto``: segments, joints and the tree from the markers' own motion.

After Kirk, O'Brien & Forsyth (2005), "Skeletal parameter estimation from optical
motion capture data":

1. **Segments by distance constancy.** Markers on one rigid segment keep their mutual
   distances. The cost of a pair is the standard deviation of its distance over the
   frames where both are seen; markers are grouped by average-linkage clustering on
   that cost, cut at ``max_spread`` (metres). Groups of one or two markers are kept.
2. **Joint fits and the tree** (:mod:`skincap.solve.auto_tree`): a joint's cost is
   how much the child's markers' distances to the best point fixed in the parent
   change (Kirk's joint cost; SCoRE's point when the child has a frame); the tree is
   grown from the trunk (the group of three or more markers nearest the markers'
   centroid) one cheapest joint at a time, a two-marker group framed by its joint
   centre once it joins, so it carries the next; a marker that turns its group's
   frame without riding it leaves the group (or changes places with a lone marker).
3. **Hinge or ball**: a joint whose second range of motion is under
   :data:`HINGE_RATIO` of its first is a hinge (SARA); the point on its axis starts at
   the foot of the perpendicular from the parent's joint where the parent's bone runs
   square to the axis, and after calibration (:func:`calibrate_auto`) sits between
   its neighbours' joints (:mod:`skincap.solve.auto_hinges`).

The result is a :class:`~skincap.solve.templates.Template` with generic names
(``segment_0``, ``joint_0``...), which :func:`skincap.solve.solve_markers` solves like
any other (or :func:`calibrate_auto`'s model, with the hinges placed); its anatomical
axes are arbitrary (the bones point along the tree), so the BVH's rest pose is not a
T-pose and retargeting onto a named rig does not apply.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import squareform

from skincap.errors import SkincapWarning, ValidationError
from skincap.solve import joint_centres as jc
from skincap.solve.auto_hinges import centre_hinges_between_neighbours
from skincap.solve.auto_tree import AutoTree, grow_tree
from skincap.solve.calibrate import BodyModel, calibrate
from skincap.solve.segments import to_local, to_world
from skincap.solve.templates import SegmentSpec, Template, strip_prefix
from skincap.types import MarkerSet

__all__ = ["AutoResult", "auto_template", "calibrate_auto", "distance_spread"]

#: Frames used for the pairwise statistics (evenly spaced over the take).
MAX_FRAMES = 400


@dataclass(eq=False)
class AutoResult:
    """What :func:`auto_template` found.

    Attributes
    ----------
    template : Template
    groups : list of lists of str
        Marker labels per segment, in template order.
    parents : (S,) int64, -1 for the root
    fit_residual_m : (S,) float64
        The joint cost (:func:`~skincap.solve.auto_tree.joint_cost`, metres) of the
        joint joining each segment to its parent (0 for the root).
    spread_m : (N, N) float64
        Standard deviation of every pair's distance (NaN where never seen together).
    joint_how : list of S str
        How each segment is framed and joined (:class:`~skincap.solve.auto_tree.AutoTree`'s
        ``how``: ``"own frame"``, ``"frame from its joint"``, ``"leaf, no frame"``).
    unjoined : list of lists of str
        Marker groups no joint could join to the tree (not in the template).
    """

    template: Template
    groups: list[list[str]]
    parents: np.ndarray
    fit_residual_m: np.ndarray
    spread_m: np.ndarray
    joint_how: list[str] = field(default_factory=list)
    unjoined: list[list[str]] = field(default_factory=list)


def distance_spread(positions: np.ndarray, *, chunk: int = 32) -> np.ndarray:
    """(N, N) standard deviation of each pair's distance over the frames both are seen.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    chunk : int
        Frames per step (memory ~ ``chunk * N^2 * 3`` floats; dense sets have N ~ 350).

    Returns
    -------
    (N, N) float64, metres; NaN for pairs seen together in fewer than 3 frames.
    """
    p = np.asarray(positions, dtype=np.float64)
    n_markers = p.shape[1]
    count = np.zeros((n_markers, n_markers))
    total = np.zeros((n_markers, n_markers))
    square = np.zeros((n_markers, n_markers))
    # accumulate sums relative to a first estimate of each pair's distance (no cancellation)
    ref = None
    for start in range(0, p.shape[0], chunk):
        blk = p[start : start + chunk]
        d = np.linalg.norm(
            blk[:, :, None] - blk[:, None, :], axis=3
        )  # (t, N, N), NaN where missing
        seen = np.isfinite(d)
        if ref is None:
            with np.errstate(invalid="ignore"):
                first = np.where(
                    seen.any(axis=0), np.nanmax(np.where(seen, d, -np.inf), axis=0), 0.0
                )
            ref = np.where(np.isfinite(first), first, 0.0)
        dev = np.where(seen, d - ref, 0.0)
        count += seen.sum(axis=0)
        total += dev.sum(axis=0)
        square += (dev**2).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        var = np.maximum(square / count - mean**2, 0.0)
    return np.where(count >= 3, np.sqrt(var), np.nan)


def auto_template(
    markers: MarkerSet, *, max_spread: float = 0.008, min_markers: int = 1
) -> AutoResult:
    """Find segments, joints and the tree of an unknown labelled marker set.

    Parameters
    ----------
    markers : MarkerSet
        Labelled markers, metres (NaN where missing); the labels are only names.
    max_spread : float
        Cut of the clustering: markers whose distances vary (standard deviation, metres)
        more than this on average are not one segment.
    min_markers : int
        Drop groups with fewer markers (their markers are not solved).

    Returns
    -------
    AutoResult

    Raises
    ------
    ValidationError
        Fewer than three markers, or no group of three markers seen together (no
        segment gets a frame, so no joint can be fitted).

    Warns
    -----
    SkincapWarning
        Groups no joint could join to the tree (named; they are left out of the
        template).
    """
    labels = [s for s in markers.labels if not s.startswith("*")]
    cols = [markers.labels.index(s) for s in labels]
    if len(cols) < 3:
        raise ValidationError("auto template: needs at least three labelled markers")
    t = markers.n_frames
    frames = np.unique(np.linspace(0, t - 1, min(t, MAX_FRAMES)).round().astype(int))
    pos_all = markers.positions[:, cols]
    spread = distance_spread(pos_all[frames])
    cost = np.where(np.isfinite(spread), spread, 1.0)  # never seen together: far apart
    np.fill_diagonal(cost, 0.0)
    cost = 0.5 * (cost + cost.T)
    tree = linkage(squareform(cost, checks=False), method="average")
    group_of = fcluster(tree, t=max_spread, criterion="distance")
    groups = [np.nonzero(group_of == g)[0] for g in np.unique(group_of)]
    groups = [g for g in groups if g.size >= min_markers]
    sub = pos_all[frames]
    centroid = np.nanmean(sub.reshape(-1, 3), axis=0)
    # the root: the group of three or more markers nearest the markers' centroid (the trunk)
    big = [k for k, g in enumerate(groups) if g.size >= 3]
    if not big:
        raise ValidationError("auto template: no group of three rigidly moving markers")
    dist = [
        float(np.linalg.norm(np.nanmean(sub[:, groups[k]].reshape(-1, 3), axis=0) - centroid))
        for k in big
    ]
    found = grow_tree(sub, groups, big[int(np.argmin(dist))])
    groups = found.groups
    order = found.order
    new_index = {k: i for i, k in enumerate(order)}
    parents = np.array(
        [-1 if found.parents[k] < 0 else new_index[found.parents[k]] for k in order],
        dtype=np.int64,
    )
    fit = np.array([found.cost_m[k] for k in order])
    names = [[strip_prefix(labels[m]) for m in groups[k]] for k in order]
    template = _as_template(
        names,
        parents,
        [found.spread_deg.get(k) for k in order],
        [k != order[0] and _perpendicular_ok(found, sub, groups, k) for k in order],
    )
    unjoined = [
        [strip_prefix(labels[m]) for m in g] for k, g in enumerate(groups) if k not in found.parents
    ]
    if unjoined:
        warnings.warn(
            "auto template: no joint joins marker(s) "
            f"{', '.join(m for g in unjoined for m in g)} to the rest (seen too seldom with "
            "a segment that has a frame); they are not solved",
            SkincapWarning,
            stacklevel=2,
        )
    return AutoResult(
        template=template,
        groups=names,
        parents=parents,
        fit_residual_m=fit,
        spread_m=spread,
        joint_how=[found.how[k] for k in order],
        unjoined=unjoined,
    )


#: A joint turns as a hinge when its second principal range of motion is under this
#: share of its first (or under :data:`~skincap.solve.joint_centres.MIN_SPREAD_DEG`):
#: SCoRE's centre along the axis then rests on that little turn, mostly skin motion.
HINGE_RATIO = 0.25


def _is_hinge(spread_deg: np.ndarray) -> bool:
    """Whether a joint's ``(3,)`` range of motion (degrees, largest first) is a hinge's."""
    first, second = float(spread_deg[0]), float(spread_deg[1])
    return first >= jc.MIN_SPREAD_DEG and second < max(jc.MIN_SPREAD_DEG, HINGE_RATIO * first)


def _perpendicular_ok(
    tree: AutoTree, positions: np.ndarray, groups: list[np.ndarray], k: int
) -> bool:
    """Whether hinge ``k``'s centre may be the foot of the perpendicular from its
    parent's own joint ``J``.

    That holds for a limb (a thigh runs from the hip square to the knee's axis), not
    for a parent whose own joint lies on or near the child's axis (a pelvis hung from
    one hip, carrying the other). So ``J`` must be known, the direction from ``J`` to
    the midpoint of the two segments' markers (roughly the bone) must make at least
    :data:`PERPENDICULAR_MIN_ANGLE_DEG` with the hinge axis (in the parent's frame), and
    calibration must see the hinge turn from it (first range of motion at least
    :data:`PERPENDICULAR_MIN_FACTOR` times
    :data:`~skincap.solve.joint_centres.MIN_SPREAD_DEG`, measured as
    :func:`~skincap.solve.calibrate.calibrate` measures it) so that it never falls
    back to the prior itself, which would put the joint on the parent's.
    """
    p = tree.parents[k]
    grand = tree.parents.get(p, -1)
    if grand < 0 or p not in tree.frames or grand not in tree.frames:
        return False
    rot, trans = tree.frames[p]
    joint = to_world(*tree.frames[grand], tree.centres_parent[p][None])  # (T, 1, 3)
    seen_from = np.nanmedian(to_local(rot, trans, joint)[:, 0], axis=0)  # J in the parent
    y = to_local(rot, trans, positions[:, groups[k]])  # child markers in the parent
    x = to_local(rot, trans, positions[:, groups[p]])  # parent markers in the parent
    middle = 0.5 * (np.nanmedian(x.reshape(-1, 3), axis=0) + np.nanmedian(y.reshape(-1, 3), axis=0))
    if not (np.isfinite(seen_from).all() and np.isfinite(middle).all()):
        return False
    need = PERPENDICULAR_MIN_FACTOR * jc.MIN_SPREAD_DEG
    try:
        axis: np.ndarray | None
        if k in tree.frames:
            axis, _, cp, _ = jc.sara_axis(rot, trans, *tree.frames[k])
            turns = float(tree.spread_deg[k][0]) >= need
        else:
            cp, axis = jc.sphere_centre(y, hinge=True)
            turns = float(jc.direction_spread(y, seen_from)[0]) >= need
    except ValidationError:
        return False
    if axis is None:  # hinge=True always returns one
        return False
    bone = middle - seen_from
    cos = abs(float(bone @ axis)) / max(float(np.linalg.norm(bone) * np.linalg.norm(axis)), 1e-12)
    return turns and cos <= np.cos(np.radians(PERPENDICULAR_MIN_ANGLE_DEG))


#: See :func:`_perpendicular_ok`.
PERPENDICULAR_MIN_ANGLE_DEG = 60.0
PERPENDICULAR_MIN_FACTOR = 1.5


def _as_template(
    names: list[list[str]],
    parents: np.ndarray,
    spreads: list[np.ndarray | None],
    perpendicular: list[bool],
) -> Template:
    segs: list[SegmentSpec] = []
    children = {i: [c for c in range(len(parents)) if parents[c] == i] for i in range(len(parents))}
    for i, group in enumerate(names):
        p = int(parents[i])
        kids = children[i]
        if p < 0:
            origin = list(group)
            primary = ["y", list(group), [f"@segment_{kids[0]}"] if kids else [group[0]]]
            secondary = ["x", [group[0]], [group[-1]]] if len(group) > 1 else ["x", "parent"]
            centre: dict[str, Any] | None = None
        else:
            origin = None
            end = [f"@segment_{kids[0]}"] if kids else list(group)
            primary = ["y", [f"@segment_{i}"], end]
            secondary = ["x", "parent"]
            parent_markers = names[p]
            centre = {
                "kind": "ball",
                "prior": {"from": list(parent_markers), "towards": list(group), "fraction": 0.5},
            }
            spread = spreads[i]
            if spread is not None and _is_hinge(spread) and centre is not None:
                # SARA's axis; the centre is the point of it nearest the prior
                centre["kind"] = "hinge"
                centre["flexion"] = [list(parent_markers), f"@segment_{i}", list(group)]
                if perpendicular[i]:
                    # a bone runs square to its hinge: the centre is the point of the
                    # axis nearest the parent's own joint
                    centre["prior"] = {"from": [f"@segment_{p}"]}
        segs.append(
            SegmentSpec(
                name=f"segment_{i}",
                joint="Root" if p < 0 else f"joint_{i}",
                parent=None if p < 0 else f"segment_{p}",
                markers=list(group),
                axes=[primary, secondary],
                centre=centre,
                origin=origin,
            )
        )
    # a root with one marker cannot give its own second axis: use its primary's partner
    if segs[0].axes[1] == ["x", "parent"]:
        segs[0].axes[1] = (
            ["x", [segs[0].markers[0]], [f"@segment_{children[0][0]}"]]
            if children[0]
            else ["x", [segs[0].markers[0]], [segs[0].markers[0]]]
        )
    return Template(
        name="auto", description="found from the markers' motion (Kirk et al. 2005)", segments=segs
    )


def calibrate_auto(markers: MarkerSet, found: AutoResult | None = None) -> BodyModel:
    """The body model ``--template auto`` solves: found, calibrated, hinges centred.

    Parameters
    ----------
    markers : MarkerSet
        Labelled markers, metres (NaN where missing).
    found : AutoResult, optional
        :func:`auto_template`'s result on ``markers`` (found again when omitted).

    Returns
    -------
    BodyModel
        :func:`~skincap.solve.calibrate.calibrate` on the found template, each hinge
        then moved along its axis between its neighbours' joints
        (:func:`~skincap.solve.auto_hinges.centre_hinges_between_neighbours`); pass it
        to :func:`~skincap.solve.solve_markers` as the template.
    """
    if found is None:
        found = auto_template(markers)
    return centre_hinges_between_neighbours(calibrate(markers, found.template))
