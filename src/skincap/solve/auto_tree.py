"""The tree of ``--template auto``: which marker group hangs from which, grown root first.

Kirk, O'Brien & Forsyth (2005) join two marker groups by the point that keeps a constant
distance to every marker of both; the cost of the joint is how badly that holds, and the
skeleton is the minimum spanning tree of those costs. Here the joint of a candidate
edge (parent ``a``, child ``b``) is the common sphere centre of ``b``'s markers in
``a``'s technical frame (:func:`~skincap.solve.joint_centres.sphere_centre`: a point
fixed in ``a`` whose distance to each marker of ``b`` stays constant) and the cost is
the RMS change of those distances over the take (metres). One cost for every edge,
whatever the child's marker count, so the costs compare.

A group needs a frame to carry children, and a group of two markers has none of its
own (two points give no rotation about the line through them). Once it is joined, its
joint centre is a third point fixed in it, so the two markers and the centre frame it
(Kirk's remedy of fitting joints without per-segment frames, done root first): the
tree is grown from the root like Prim's minimum spanning tree, each step adding the
cheapest edge from a group in the tree that has a frame, and a two-marker group that
joins becomes a carrier. Groups of one marker never carry and join last, as leaves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincap.errors import ValidationError
from skincap.solve import joint_centres as jc
from skincap.solve.segments import cluster_frames, to_local, to_world

__all__ = ["AutoTree", "grow_tree", "joint_cost", "MIN_FRAMES", "MIN_TRIANGLE_HEIGHT_M"]

#: Fewest frames in which a candidate parent's frame and a child marker are both known
#: for the edge to be fitted.
MIN_FRAMES = 10

#: A joint lies where its two segments meet: a fitted centre farther than this
#: (metres, median over the take) from every marker of the child is implausible, and
#: such an edge is taken only when the child has no other (a fit of two distances
#: can keep them nearly constant about a far point by chance, e.g. a chest pair
#: about a point half a metre beyond a thigh in a breakdance).
MAX_JOINT_REACH_M = 0.35

#: A two-marker group is framed by its markers and its joint centre only when the
#: centre lies at least this far (metres, median over the take) from the line through
#: the two markers: nearer, the frame's turn about that line is noise.
MIN_TRIANGLE_HEIGHT_M = 0.02


@dataclass(eq=False)
class AutoTree:
    """The tree :func:`grow_tree` found.

    Attributes
    ----------
    groups : list of (K,) int arrays
        The marker columns of each group: the groups given, less any loose marker,
        which ends as a group of its own at the end (:data:`LOOSE_MARKER_GAIN`).
    order : list of int
        Group indices, parents before children (the root first).
    parents : dict int -> int
        Each group's parent group (-1 for the root); groups the tree could not join are
        absent.
    cost_m : dict int -> float
        The joint cost of the edge to the parent, metres (0 for the root).
    how : dict int -> str
        How each group is framed and joined: ``"own frame"`` (three or more markers),
        ``"frame from its joint"`` (two markers and the joint centre),
        ``"leaf, no frame"`` (one marker, or two in line with their joint).
    centres_parent : dict int -> (3,) float64
        The fitted joint centre in the parent's technical frame, metres.
    frames : dict int -> ((T, 3, 3), (T, 3))
        The technical frame of every group that has one, on the frames given.
    spread_deg : dict int -> (3,) float64
        Each joint's RMS range of motion along its principal axes, degrees, largest
        first (:func:`~skincap.solve.joint_centres.motion_spread`; for a child without
        a frame the spread of its markers' directions, third value 0).
    """

    groups: list[np.ndarray]
    order: list[int]
    parents: dict[int, int]
    cost_m: dict[int, float]
    how: dict[int, str]
    centres_parent: dict[int, np.ndarray]
    frames: dict[int, tuple[np.ndarray, np.ndarray]]
    spread_deg: dict[int, np.ndarray]


def joint_cost(
    rot: np.ndarray,
    trans: np.ndarray,
    child: np.ndarray,
    child_frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """Kirk's joint cost of child markers about the best point fixed in a parent frame.

    Parameters
    ----------
    rot : (T, 3, 3) float
        The parent's technical rotations (NaN where unknown).
    trans : (T, 3) float, metres
        The parent's technical origins.
    child : (T, K, 3) float, metres
        The child's markers, NaN where missing.
    child_frame : ((T, 3, 3), (T, 3)), optional
        The child's own technical frame, when it has one: the centre is then SCoRE's
        (:func:`~skincap.solve.joint_centres.score_centre`, a point fixed in both
        frames, so the child must turn about it too, not only keep its distances),
        and the cost is still the change of the markers' distances to it.

    Returns
    -------
    cost : float, metres
        RMS over markers and frames of the change of each marker's distance to the
        centre (its distance minus that marker's mean distance); ``inf`` when fewer
        than :data:`MIN_FRAMES` frames see the parent and a child marker.
    centre : (3,) float64 or None
        The centre in the parent's frame (a least-squares choice along the axis when
        the joint turns about one axis only), None with ``inf``.
    axis : (3,) float64 or None
        The unit hinge axis in the parent's frame when the child's markers turn about
        one axis only (their directions from the centre spread less than
        :data:`~skincap.solve.joint_centres.MIN_SPREAD_DEG` about the second), else None.
    """
    y = to_local(rot, trans, child)  # (T, K, 3)
    seen = np.isfinite(y).all(axis=2)  # (T, K)
    if seen.any(axis=1).sum() < MIN_FRAMES:
        return np.inf, None, None
    y = np.where(seen[..., None], y, np.nan)
    axis = None
    try:
        if child_frame is not None:
            centre, _, _ = jc.score_centre(rot, trans, *child_frame)
        else:
            centre, _ = jc.sphere_centre(y)
            if jc.direction_spread(y, centre)[1] < jc.MIN_SPREAD_DEG:
                _, axis = jc.sphere_centre(y, hinge=True)
    except ValidationError:
        return np.inf, None, None
    dist = np.linalg.norm(y - centre, axis=2)  # (T, K), NaN where unseen
    count = seen.sum(axis=0)
    mean = np.where(seen, dist, 0.0).sum(axis=0) / np.maximum(count, 1)
    dev = np.where(seen, dist - mean, 0.0)
    return float(np.sqrt((dev**2).sum() / seen.sum())), centre, axis


#: Distance (metres) along a hinge axis of the second point a two-marker child takes
#: from it.
AXIS_POINT_M = 0.1


def _frame_from_joint(
    markers: np.ndarray, fixed: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """Technical frame of two markers ``(T, 2, 3)`` and the points of their joint fixed
    in them ``(T, P, 3)`` (the centre; on a hinge also a second point of its axis), or
    None when those points lie in line with the markers (see
    :data:`MIN_TRIANGLE_HEIGHT_M`)."""
    a, b = markers[:, 0], markers[:, 1]
    ab = b - a
    with np.errstate(invalid="ignore", divide="ignore"):
        height = (
            np.linalg.norm(np.cross(ab[:, None], fixed - a[:, None]), axis=2)
            / np.linalg.norm(ab, axis=1)[:, None]
        )  # (T, P)
    height = np.nanmax(np.where(np.isfinite(height), height, -np.inf), axis=1)
    ok = np.isfinite(height)
    if ok.sum() < MIN_FRAMES or float(np.median(height[ok])) < MIN_TRIANGLE_HEIGHT_M:
        return None
    _, rot, trans = cluster_frames(np.concatenate([markers, fixed], axis=1))
    return rot, trans


def _own_group_frames(
    positions: np.ndarray, groups: list[np.ndarray]
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Each group's own frame (rotations (T, 3, 3), translations (T, 3)) where it has one."""
    frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for k, g in enumerate(groups):
        if g.size >= 3:
            try:
                _, rot, trans = cluster_frames(positions[:, g])
            except ValidationError:
                continue
            if np.isfinite(rot).all(axis=(1, 2)).sum() >= MIN_FRAMES:
                frames[k] = (rot, trans)
    return frames


def _regroup(
    groups: list[np.ndarray],
    b: int,
    better: tuple[np.ndarray, np.ndarray, int | None],
    singles: list[int],
) -> int:
    """Apply :func:`_better_members`' change to group ``b`` in place; the moved group's index."""
    members, out, taken = better
    groups[b] = members
    if taken is None:
        groups.append(out)
        return len(groups) - 1
    moved = singles[taken]
    groups[moved] = out
    return moved


def _groups_state(
    groups: list[np.ndarray],
    b: int | None = None,
    better: tuple[np.ndarray, np.ndarray, int | None] | None = None,
    singles: list[int] | None = None,
) -> tuple[tuple[int, ...], ...]:
    """The marker groups as a hashable value, after :func:`_regroup` when ``better`` is given."""
    trial = list(groups)
    if better is not None:
        assert b is not None and singles is not None
        _regroup(trial, b, better, singles)
    return tuple(tuple(int(m) for m in g) for g in trial)


def _frame_pair_at_joint(
    pair: np.ndarray,
    parent_frame: tuple[np.ndarray, np.ndarray],
    centre: np.ndarray,
    axis: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Frame of a two-marker group ``(T, 2, 3)`` from its joint with the parent, or None."""
    rot, trans = parent_frame
    framed = _frame_from_joint(pair, to_world(rot, trans, centre[None]))
    if framed is None and axis is not None:
        # a hinge whose fitted centre fell in line with the markers: any
        # point of its axis is fixed in both segments, so take a second one
        fixed = np.stack([centre, centre + AXIS_POINT_M * axis])
        framed = _frame_from_joint(pair, to_world(rot, trans, fixed))
    return framed


def grow_tree(positions: np.ndarray, groups: list[np.ndarray], root: int) -> AutoTree:
    """Grow the skeleton's tree from ``root`` over the marker groups.

    Parameters
    ----------
    positions : (T, N, 3) float, metres
        The markers (NaN where missing); ``T`` may be a subsample of the take.
    groups : list of (K,) int arrays
        Marker columns of each group.
    root : int
        The group the tree starts from; it must have three or more markers.

    Returns
    -------
    AutoTree

    Raises
    ------
    ValidationError
        The root group cannot be framed (fewer than three markers seen together).
    """
    groups = [np.asarray(g) for g in groups]  # a loose marker may leave its group
    frames = _own_group_frames(positions, groups)
    if root not in frames:
        raise ValidationError("auto template: the root group has no frame (three markers seen)")
    own = set(frames)
    own_frames = dict(frames)
    parents = {root: -1}
    cost_m = {root: 0.0}
    how = {root: "own frame"}
    spread_deg: dict[int, np.ndarray] = {}
    centres: dict[int, np.ndarray] = {}
    order = [root]
    # candidate edges: (parent, child) -> (cost, centre in the parent's frame)
    edges: dict[tuple[int, int], tuple[float, np.ndarray | None, np.ndarray | None]] = {}
    far: set[tuple[int, int]] = set()  # edges whose centre lies beyond MAX_JOINT_REACH_M

    def add_edge(a: int, b: int) -> None:
        rot, trans = frames[a]
        child = positions[:, groups[b]]
        edges[(a, b)] = joint_cost(rot, trans, child, own_frames.get(b))
        centre = edges[(a, b)][1]
        far.discard((a, b))
        if centre is not None and _reach(rot, trans, centre, child) > MAX_JOINT_REACH_M:
            far.add((a, b))

    def add_edges_from(a: int) -> None:
        for b in range(len(groups)):
            if b not in parents:
                add_edge(a, b)

    add_edges_from(root)
    tried: set[tuple[tuple[int, ...], ...]] = {_groups_state(groups)}
    # groups that can carry children (two or more markers) first, then the single markers
    for least in (2, 1):
        while True:
            open_edges = [
                ((a, b) in far, c, a, b) for (a, b), (c, _, _) in edges.items()
                if b not in parents and groups[b].size >= least and np.isfinite(c)
            ]  # fmt: skip
            if not open_edges:
                break
            _, c, a, b = min(open_edges)
            # the parents worth trying: those the whole group is not far from
            carriers = [
                frames[t] for t in order
                if t in frames and edges.get((t, b), (np.inf,))[0] <= CARRIER_FACTOR * c
            ]  # fmt: skip
            singles = [k for k, g in enumerate(groups) if g.size == 1 and k not in parents]
            better = (
                _better_members(
                    carriers, positions, groups[b], [groups[k] for k in singles], c,
                    far_ok=(a, b) in far,
                )
                if b in own
                else None
            )  # fmt: skip
            if better is not None:
                # a change back to groups already tried would loop for ever
                state = _groups_state(groups, b, better, singles)
                if state in tried:
                    better = None
                else:
                    tried.add(state)
            if better is not None:
                # the group's frame turns with a marker that does not ride it (a hand
                # marker near the wrist): it leaves as a group of its own, or changes
                # places with a single marker that rides the segment
                members = better[0]
                moved = _regroup(groups, b, better, singles)
                _, rot_b, trans_b = cluster_frames(positions[:, members])
                frames[b] = own_frames[b] = (rot_b, trans_b)
                for t in order:
                    if t in frames:
                        add_edge(t, b)
                        add_edge(t, moved)
                continue
            _, centre, axis = edges[(a, b)]
            assert centre is not None  # finite cost comes with a centre
            parents[b], cost_m[b], centres[b] = a, float(c), centre
            order.append(b)
            if b in own:
                how[b] = "own frame"
            elif groups[b].size == 2:
                framed = _frame_pair_at_joint(positions[:, groups[b]], frames[a], centre, axis)
                if framed is not None:
                    frames[b] = framed
                    how[b] = "frame from its joint"
                else:
                    how[b] = "leaf, no frame"
            else:
                how[b] = "leaf, no frame"
            spread_deg[b] = _spread(frames[a], frames.get(b), positions[:, groups[b]], centre)
            if b in frames:
                add_edges_from(b)
    return AutoTree(
        groups=groups,
        order=order,
        parents=parents,
        cost_m=cost_m,
        how=how,
        centres_parent=centres,
        frames=frames,
        spread_deg=spread_deg,
    )


#: A group of four or more markers loses the marker without which its joint with its
#: parent costs less than this share of the cost with it (:func:`joint_cost`): that
#: marker turns the group's frame without riding it. Leaving out a marker of a rigid
#: cluster changes the cost by about 30 % at most (the synthetic walk's thorax, the
#: real AML plates); leaving the finger marker out of the walk's forearm divides it by
#: eight.
LOOSE_MARKER_GAIN = 0.5

#: ... and by at least this much (metres): a rigid group's cost is noise.
LOOSE_MARKER_MIN_DROP_M = 0.002


#: The carriers :func:`_better_members` tries for a group: those whose joint with the
#: whole group costs at most this many times the cheapest.
CARRIER_FACTOR = 3.0

#: A single marker may change places with a marker of a group only when its distance
#: to the group's markers varies (standard deviation, metres, averaged) by less than this.
SWAP_MAX_SPREAD_M = 0.016


def _better_members(
    carriers: list[tuple[np.ndarray, np.ndarray]],
    positions: np.ndarray,
    group: np.ndarray,
    singles: list[np.ndarray],
    cost: float,
    *,
    far_ok: bool = False,
) -> tuple[np.ndarray, np.ndarray, int | None] | None:
    """A change of a framed group's markers that makes its joint far cheaper.

    Tried: leaving one marker out (groups of four or more), and changing one marker
    for one of the ``singles`` (single-marker groups not yet joined) whose distances to
    the group hardly vary (:data:`SWAP_MAX_SPREAD_M`). Each variant is scored by its
    cheapest joint with any of the ``carriers`` (frames of the groups in the tree:
    the whole group's frame may have drawn it to the wrong one); the best is taken
    when under :data:`LOOSE_MARKER_GAIN` times ``cost`` (the cheapest joint with the
    group as it is) and :data:`LOOSE_MARKER_MIN_DROP_M` below it. Unless ``far_ok``
    (the group's cheapest joint is itself a far one), a joint whose centre lies beyond
    :data:`MAX_JOINT_REACH_M` of the variant's markers does not count, as
    :func:`grow_tree` ranks such edges after all others: a far joint that is cheap
    whatever the markers (a pair of distances kept about a distant point) would
    otherwise make every variant look better than the group, whose edge it never takes.

    Returns
    -------
    (members, out, taken) or None
        The group's new marker columns, the column(s) that leave it (a new single
        group), and the index in ``singles`` of the single it took (None: none).
    """
    if group.size < 3 or not np.isfinite(cost):
        return None
    variants: list[tuple[np.ndarray, np.ndarray, int | None]] = []
    for k in range(group.size):
        rest = np.delete(group, k)
        if rest.size >= 3:
            variants.append((rest, group[k : k + 1], None))
    for j, single in enumerate(singles):
        d = np.linalg.norm(positions[:, group] - positions[:, single], axis=2)  # (T, K)
        if np.isfinite(d).sum(axis=0).min() < MIN_FRAMES:
            continue
        if float(np.mean(np.nanstd(d, axis=0))) >= SWAP_MAX_SPREAD_M:
            continue
        for k in range(group.size):
            variants.append((np.append(np.delete(group, k), single), group[k : k + 1], j))
    best, best_cost = None, min(LOOSE_MARKER_GAIN * cost, cost - LOOSE_MARKER_MIN_DROP_M)
    for members, out, taken in variants:
        try:  # one round of the cluster fit is enough to rank the variants
            _, rot, trans = cluster_frames(positions[:, members], iterations=1)
        except ValidationError:
            continue
        child = positions[:, members]
        for parent in carriers:
            c, centre, _ = joint_cost(*parent, child, (rot, trans))
            if c >= best_cost or centre is None:
                continue
            if far_ok or _reach(*parent, centre, child) <= MAX_JOINT_REACH_M:
                best, best_cost = (members, out, taken), c
    return best


def _reach(rot: np.ndarray, trans: np.ndarray, centre: np.ndarray, child: np.ndarray) -> float:
    """Median over frames (metres) of the distance from a centre fixed in a parent's
    frame to the nearest of the child's markers ``(T, K, 3)``."""
    world = to_world(rot, trans, centre[None])  # (T, 1, 3)
    d = np.linalg.norm(child - world, axis=2)  # (T, K), NaN where unseen
    nearest = np.min(np.where(np.isfinite(d), d, np.inf), axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if nearest.size else np.inf


def _spread(
    parent: tuple[np.ndarray, np.ndarray],
    child: tuple[np.ndarray, np.ndarray] | None,
    markers: np.ndarray,
    centre: np.ndarray,
) -> np.ndarray:
    """(3,) RMS range of motion (degrees) of a joint along its principal axes, largest
    first: of the relative rotation of two frames, or for a child without a frame of
    its markers' directions from the centre (third value 0)."""
    if child is not None:
        return jc.motion_spread(parent[0], child[0])
    y = to_local(parent[0], parent[1], markers)
    return np.append(jc.direction_spread(y, centre), 0.0)
