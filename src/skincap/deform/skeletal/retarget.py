"""Retargeting: a motion on one skeleton replayed on another rig.

The method
----------
**A motion on the rig itself.** When every target joint has a source joint of the
same name, with the same-named parent, whose local translations are the rig's
bind-local ones in every frame (a motion skincap wrote on this rig, read back from a
BVH whose joints come in depth-first order rather than the rig's), the local
rotations are the rig's own: they are copied joint for joint *by name* and nothing is
aligned or rescaled. The zero pose of such a motion is not the bind pose (its local
rotations are relative to the bind frames), so the general method below, which takes
the zero pose as the rest pose, would not apply.

**Pairs.** A *name map* pairs source joints with target joints (a source joint may
drive a group of sibling target joints, e.g. one BVH toe driving MakeHuman's five
toes). Built in: both skeletons' naming conventions are detected
(:mod:`skincap.deform.skeletal.name_maps`) and their canonical landmarks paired; joints with
identical names on both sides are paired too (so a rig retargets onto itself joint
for joint). A user map ``{source_joint: target_joint | [target_joints] | null}``
(a dict or a JSON file) overrides: its entries replace automatic pairs that use the
same source or target joints, and ``null`` removes a source joint. Pairs must keep
the hierarchy: the nearest paired ancestor of a source joint must be paired with the
nearest paired ancestor of its target (automatic pairs breaking this are dropped; a
user map breaking it is an error).

**Segments and chains.** A pair's *segment* runs from its joint to the next paired
joints below it (its *ends*; an end at zero distance on either side, such as CMU's
``lowerneck`` at ``Chest2``, is replaced by its own ends). When the target has more
bones than the source for a segment (MakeHuman ``upperarm01.L`` + ``upperarm02.L`` for
CMU ``LeftShoulder``; ``spine05`` + ``spine04`` for ``lowerback``), the unpaired target
bones between the paired ones are *chain bones*: they receive the same world rotation
change as the paired bone, so the chain moves rigidly in its bind shape and its end
lands exactly along the source segment (twist is carried by the whole chain, not
split). Target joints that are neither paired nor in a chain (fingers, face, breasts)
keep their bind relation to their parent. Source joints left unpaired inside a segment
(when the source has more bones) are accounted for: for single-end segments the world
rotation is corrected by the swing that carries the predicted segment direction onto
the actual one, so the target segment follows the source's end exactly.

**Rest-pose alignment.** The source's zero pose (all local rotations identity: BVH
rest, a T-pose or arms-down pose) and the target's bind pose (MakeHuman's A-pose)
differ. Each pair gets a constant world alignment ``A`` computed once, top-down:
``A = S @ A_parent`` where ``S`` is the minimal rotation carrying the target segment
direction (already turned by the parent's alignment) onto the source segment
direction. Because ``S`` is applied after the parent's alignment, each bone's roll is
inherited from its parent (an elbow straightened this way turns about the target's own
elbow hinge). Segments with several ends (the chest: neck and both shoulders) align
the end that continues the chain exactly and fit the roll about it to the others; the
root segment aligns the facing only: a turn about the vertical that brings the
target's left-right hip axis onto the source's (both skeletons stand upright, Y up).
Segments without ends (head, hands, toes) inherit their parent's alignment.
Per frame, with ``R_src(t)`` the world rotation of the source joint (identity at
rest)::

    R_target_world(t) = R_src(t) @ inv(R_src_rest) @ A @ R_target_bind

so every paired target segment points along its source segment in every frame.

**Root motion and scale.** The output lives in the source's world scaled about its
origin by ``s``: the capture floor ``y = 0`` stays the floor, and the walk travels
``s`` times as far. The target's pelvis (the mid-point of the paired thighs, or the
paired root joint) is placed at ``s`` times the source's. ``scale="height"`` takes
``s`` = the ratio of standing hip heights, measured as leg lengths along the bones
(hip to ankle, averaged over both sides; pose independent, so a source whose rest pose
splays the legs is measured correctly). That ratio is what keeps the feet on the
floor. Without paired legs it falls back to the ratio of rest-pose heights (the
vertical extents of the joints; the largest extent for a skeleton lying flat).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from skincap._arrays import check_positive
from skincap.deform.skeletal.name_maps import CONVENTIONS, LANDMARKS, bare_names, detect_convention
from skincap.deform.skeletal.rig import (
    ALL_CHANNELS,
    bind_local_transforms,
    bind_matrices_of,
    motion_from_world,
)
from skincap.errors import FormatError, ValidationError
from skincap.geometry.kinematics import (
    forward_kinematics,
    joint_positions_arrays,
    rest_positions,
)
from skincap.io._common import read_file_bytes
from skincap.io.json_file import parse_json
from skincap.types import Mesh, Motion, Skeleton, Skin

__all__ = ["retarget", "joint_name_map", "load_name_map"]

#: Segments shorter than this (metres) are treated as zero length.
_ZERO_LENGTH = 1e-4
#: A source joint whose local translation is within this (metres, every frame) of the
#: target's bind-local one counts as the rig's own bone (BVH text keeps 1e-7 m).
_SAME_BONE = 5e-5

NameMapLike = Mapping[str, Any] | str | os.PathLike[str] | None


# ------------------------------------------------------------------ name maps
def load_name_map(name_map: NameMapLike) -> dict[str, tuple[str, ...] | None]:
    """Read and validate a user joint-name map.

    Parameters
    ----------
    name_map : dict, str or PathLike, or None
        ``{source_joint: target_joint | [target_joint, ...] | null}``, or the path
        of a JSON file holding that object.

    Returns
    -------
    dict of str to tuple of str or None
        Empty for None.

    Raises
    ------
    FormatError
        The file cannot be read or is not such a JSON object.
    ValidationError
        A dict argument with the wrong value types.
    """
    if name_map is None:
        return {}
    if isinstance(name_map, Mapping):
        data: Any = dict(name_map)
        path = None
    elif isinstance(name_map, (str, os.PathLike)):
        path = Path(name_map)
        raw = read_file_bytes(path, what="the name map")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FormatError(path, f"not UTF-8 text ({exc.reason})", offset=exc.start) from None
        data = parse_json(path, text)
    else:
        raise ValidationError(
            f"name_map: expected None, a dict or a JSON file path, got {type(name_map).__name__}"
        )

    def bad(what: str) -> Exception:
        return FormatError(path, what) if path is not None else ValidationError(f"name_map: {what}")

    if not isinstance(data, dict):
        raise bad("expected an object {source_joint: target_joint}")
    out: dict[str, tuple[str, ...] | None] = {}
    for key, value in data.items():
        if not isinstance(key, str):
            raise bad(f"source joint names must be strings, got {key!r}")
        if value is None:
            out[key] = None
        elif isinstance(value, str):
            out[key] = (value,)
        elif (
            isinstance(value, (list, tuple))
            and value
            and all(isinstance(v, str) for v in value)
            and len(set(value)) == len(value)
        ):
            out[key] = tuple(value)
        else:
            raise bad(
                f"{key!r}: expected a target joint name, a list of distinct names or null, got {value!r}"
            )
    return out


def _paired_ancestor(parents: np.ndarray, owner: np.ndarray, j: int) -> int:
    """Pair index of the nearest strict ancestor of ``j`` owned by a pair, or -1."""
    p = parents[j]
    while p >= 0:
        if owner[p] >= 0:
            return int(owner[p])
        p = parents[p]
    return -1


def _owners(
    src: Skeleton, tgt: Skeleton, pairs: list[tuple[int, tuple[int, ...]]]
) -> tuple[np.ndarray, np.ndarray]:
    """Pair index of every source (Js,) and target (Jt,) joint, -1 where unpaired."""
    s_owner = np.full(src.n_joints, -1)
    t_owner = np.full(tgt.n_joints, -1)
    for i, (s, ts) in enumerate(pairs):
        s_owner[s] = i
        t_owner[list(ts)] = i
    return s_owner, t_owner


def _consistent(
    pairs: list[tuple[int, tuple[int, ...]]], src: Skeleton, tgt: Skeleton
) -> int | None:
    """Index of the first pair that breaks the hierarchy, or None when all keep it."""
    s_owner, t_owner = _owners(src, tgt, pairs)
    for i, (s, ts) in enumerate(pairs):
        a = _paired_ancestor(src.parents, s_owner, s)
        for t in ts:
            if _paired_ancestor(tgt.parents, t_owner, t) != a:
                return i
    return None


def _resolve_pairs(
    src: Skeleton, tgt: Skeleton, name_map: NameMapLike
) -> tuple[list[tuple[int, tuple[int, ...]]], dict[str, int], dict[str, Any]]:
    """Pairs (source index, target indices), landmark -> pair index, and a report."""
    user = load_name_map(name_map)
    src_index = {n: i for i, n in enumerate(src.names)}
    tgt_index = {n: i for i, n in enumerate(tgt.names)}
    for s, ts in user.items():
        if s not in src_index:
            raise ValidationError(f"name_map: source joint {s!r} is not in the source skeleton")
        for t in ts or ():
            if t not in tgt_index:
                raise ValidationError(f"name_map: target joint {t!r} is not in the target skeleton")
    pairs: list[tuple[int, tuple[int, ...]]] = []
    used_s: set[int] = set()
    used_t: set[int] = set()
    for s, ts in user.items():
        if ts is None:
            continue
        idx = tuple(tgt_index[t] for t in ts)
        clash = used_t.intersection(idx)
        if clash:
            raise ValidationError(
                f"name_map: target joint {tgt.names[min(clash)]!r} is driven by two source joints"
            )
        pairs.append((src_index[s], idx))
        used_s.add(src_index[s])
        used_t.update(idx)
    bad = _consistent(pairs, src, tgt)
    if bad is not None:
        s, ts = pairs[bad]
        raise ValidationError(
            f"name_map: {src.names[s]!r} -> {tgt.names[ts[0]]!r} breaks the hierarchy: the "
            "nearest mapped ancestors of the two joints are not mapped to each other"
        )
    removed = {src_index[s] for s, ts in user.items() if ts is None}

    # conventions are matched past a namespace ("mixamorig:Hips" is Mixamo's "Hips")
    src_bare, tgt_bare = bare_names(src.names), bare_names(tgt.names)
    src_conv = detect_convention(list(src_bare))
    tgt_conv = detect_convention(list(tgt_bare))
    candidates: list[tuple[int, tuple[int, ...]]] = []
    if src_conv is not None and tgt_conv is not None:
        for key in LANDMARKS:
            a = CONVENTIONS[src_conv].get(key)
            b = CONVENTIONS[tgt_conv].get(key)
            if a is None or b is None:
                continue
            a_names = [n for n in ((a,) if isinstance(a, str) else a) if n in src_bare]
            b_idx = tuple(tgt_bare[n] for n in ((b,) if isinstance(b, str) else b) if n in tgt_bare)
            if not a_names or not b_idx:
                continue
            # a group on the source side drives through its middle member
            candidates.append((src_bare[a_names[len(a_names) // 2]], b_idx))
    candidates.extend((src_index[n], (tgt_index[n],)) for n in src.names if n in tgt_index)
    for s, ts in candidates:
        if s in used_s or s in removed or used_t.intersection(ts):
            continue
        trial = pairs + [(s, ts)]
        if _consistent(trial, src, tgt) is None:
            pairs = trial
            used_s.add(s)
            used_t.update(ts)
    if not pairs:
        raise ValidationError(
            f"no joints to pair: the source ({src_conv or 'unknown naming'}) and the target "
            f"({tgt_conv or 'unknown naming'}) share no landmarks or names; pass name_map "
            "(skincap skin --map names.json)"
        )
    # landmarks of the pairs, recognised on the target side first
    keys: dict[str, int] = {}
    for conv, skel, side in ((tgt_conv, tgt, 1), (src_conv, src, 0)):
        if conv is None:
            continue
        for key, value in CONVENTIONS[conv].items():
            first = (value,) if isinstance(value, str) else value
            for i, pair in enumerate(pairs):
                members = pair[1] if side else (pair[0],)
                bare = bare_names([skel.names[m] for m in members])
                if key not in keys and any(n in first for n in bare):
                    keys[key] = i
    report = {"source_convention": src_conv, "target_convention": tgt_conv}
    return pairs, keys, report


def joint_name_map(
    source: Skeleton | Motion,
    target: Mesh | Skin | Skeleton,
    name_map: NameMapLike = None,
) -> dict[str, tuple[str, ...]]:
    """The joint pairs :func:`retarget` would use.

    Parameters
    ----------
    source : Skeleton or Motion
    target : Mesh with a skin, Skin or Skeleton
    name_map : dict, JSON path or None
        User overrides, as for :func:`retarget`.

    Returns
    -------
    dict of str to tuple of str
        Source joint name -> the target joint names it drives, source order.
    """
    src = source.skeleton if isinstance(source, Motion) else source
    if not isinstance(src, Skeleton):
        raise ValidationError(f"source: expected a Motion or Skeleton, got {type(source).__name__}")
    tgt, _ = bind_matrices_of(_target_rig(target))
    pairs, _, _ = _resolve_pairs(src, tgt, name_map)
    pairs.sort(key=lambda p: p[0])
    return {src.names[s]: tuple(tgt.names[t] for t in ts) for s, ts in pairs}


# ------------------------------------------------------------------ rotations
def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _axis_angle_matrix(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: (..., 3) unit axes and (...,) angles -> (..., 3, 3)."""
    x, y, z = np.moveaxis(axis, -1, 0)
    c, s = np.cos(angle), np.sin(angle)
    cc = 1.0 - c
    return np.stack(
        [
            np.stack([c + x * x * cc, x * y * cc - z * s, x * z * cc + y * s], -1),
            np.stack([y * x * cc + z * s, c + y * y * cc, y * z * cc - x * s], -1),
            np.stack([z * x * cc - y * s, z * y * cc + x * s, c + z * z * cc], -1),
        ],
        -2,
    )


def _swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Minimal rotations (..., 3, 3) carrying directions ``u`` onto ``v`` (any lengths)."""
    u = _unit(np.asarray(u, dtype=np.float64))
    v = _unit(np.asarray(v, dtype=np.float64))
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=-1)
    c = np.sum(u * v, axis=-1)
    angle = np.arctan2(s, c)
    # antiparallel: any axis perpendicular to u
    helper = np.where(np.abs(u[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    perp = np.cross(u, helper)
    axis = np.where((s > 1e-12)[..., None], axis, perp)
    return _axis_angle_matrix(_unit(axis), angle)


def _twist_to_fit(axis: np.ndarray, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) about unit ``axis`` best turning directions ``us`` onto ``vs`` (k, 3)."""
    up = us - np.outer(us @ axis, axis)
    vp = vs - np.outer(vs @ axis, axis)
    sin = float(np.sum(np.cross(up, vp) @ axis))
    cos = float(np.sum(up * vp))
    angle = np.arctan2(sin, cos) if (abs(sin) + abs(cos)) > 1e-12 else 0.0
    return _axis_angle_matrix(axis, np.asarray(angle))


# ------------------------------------------------------------------ public
def _kept_meta(source: Motion) -> dict[str, Any]:
    """What a retargeted Motion keeps of ``source.meta``: units, axes, frame numbering."""
    return {
        k: source.meta[k]
        for k in ("source_units", "up", "first_frame", "frame_time")
        if k in source.meta
    }


def _target_rig(target: Mesh | Skin | Skeleton) -> Skin | Skeleton:
    if isinstance(target, Mesh):
        if target.skin is None:
            raise ValidationError(
                "target: the mesh has no skin; bind it first (skincap.deform.skeletal.bind.bind_mesh)"
            )
        return target.skin
    if isinstance(target, (Skin, Skeleton)):
        return target
    raise ValidationError(
        f"target: expected a Mesh with a skin, a Skin or a Skeleton, got {type(target).__name__}"
    )


def _on_own_rig(source: Motion, rig: Skin | Skeleton, scale: str | float) -> Motion | None:
    """``source`` reordered onto ``rig`` by joint name when it moves the rig's own bones.

    The source qualifies when every target joint name is in it, each with the
    same-named parent (roots with roots; extra source joints are allowed where they
    do not sit between two target joints) and, for every non-root joint, local
    translations within :data:`_SAME_BONE` of the rig's bind-local ones in every frame.
    Returns None otherwise (the general retargeting applies). ``scale="height"`` is 1
    (the same legs); a number scales the root's path about the origin.
    """
    tgt, _ = bind_matrices_of(rig)
    src = source.skeleton
    src_index = {n: i for i, n in enumerate(src.names)}
    if any(n not in src_index for n in tgt.names):
        return None
    idx = np.array([src_index[n] for n in tgt.names], dtype=np.int64)  # (Jt,) source joints
    src_parent = src.parents[idx]
    want = np.where(tgt.parents >= 0, idx[np.maximum(tgt.parents, 0)], -1)
    if not np.array_equal(src_parent, want):
        return None
    trans = source.translations
    if trans.ndim != 3 or trans.shape[1] != src.n_joints:
        return None  # root-only translations: the bones are the source's offsets
    _, bind_t = bind_local_transforms(rig)  # (Jt, 3) metres
    inner = tgt.parents >= 0
    moved = trans[:, idx[inner]] - bind_t[inner]  # (T, Jt', 3)
    if moved.size and not float(np.abs(moved).max()) <= _SAME_BONE:
        return None
    translations = np.broadcast_to(bind_t, (source.n_frames, tgt.n_joints, 3)).copy()
    s_val = (
        1.0
        if isinstance(scale, str) and scale == "height"
        else _scale(scale, src, tgt, [], {}, np.zeros((0, 3)), np.zeros((0, 3)))
    )
    translations[:, ~inner] = s_val * trans[:, idx[~inner]]  # roots: the source's world path
    meta = _kept_meta(source)
    meta["retarget"] = {
        "source_convention": detect_convention(list(bare_names(src.names))),
        "target_convention": detect_convention(list(bare_names(tgt.names))),
        "name_map": {n: [n] for n in tgt.names},
        "scale": s_val,
        "same_rig": True,
    }
    return Motion(
        skeleton=tgt,
        rotations=source.rotations[:, idx].copy(),
        translations=translations,
        rate=source.rate,
        channels=[ALL_CHANNELS] * tgt.n_joints,
        meta=meta,
    )


def _leg_length(skel_parents: np.ndarray, pos: np.ndarray, top: int, bottom: int) -> float | None:
    """Length along the bones from joint ``top`` down to its descendant ``bottom``."""
    total = 0.0
    j = bottom
    while j != top:
        p = skel_parents[j]
        if p < 0:
            return None
        total += float(np.linalg.norm(pos[j] - pos[p]))
        j = p
    return total


def retarget(
    source: Motion,
    target: Mesh | Skin | Skeleton,
    *,
    name_map: NameMapLike = None,
    scale: str | float = "height",
) -> Motion:
    """Replay ``source`` on the target rig (see the module docstring for the method).

    Parameters
    ----------
    source : Motion
        Any skeleton, metres, Y up; its zero pose (all local rotations identity) is
        its rest pose, and its floor is ``y = 0``.
    target : Mesh with a skin, Skin or Skeleton
        The rig to drive; its bind pose (``skin.bind_matrices``; for a bare skeleton
        identity rotations at the rest positions) is its rest pose.
    name_map : dict, str or PathLike, optional
        User joint-name map ``{source_joint: target_joint | [targets] | null}`` or a
        JSON file with it; overrides the built-in maps (see the module docstring).
    scale : "height" or float
        ``"height"``: target hip height / source hip height (leg lengths along the
        bones). A positive float: that factor. For a motion on the target rig itself
        (see the module docstring) ``"height"`` is 1.

    Returns
    -------
    Motion
        On the target's skeleton (same names and order), ``T`` frames at the
        source's rate. Every joint has six channels; translations are the bind-local
        ones (bone lengths never change) and the root's world position (metres).
        ``forward_kinematics`` gives world frames ``W`` with
        ``W @ skin.inverse_bind`` the skinning matrices (identity where the source
        is in its rest pose and the poses agree). ``meta``: the source's
        ``source_units``, ``up``, ``first_frame`` and ``frame_time``, plus
        ``retarget``: ``{"name_map": {source: [targets]}, "scale": s,
        "source_convention", "target_convention"}``. Never NaN.

    Raises
    ------
    ValidationError
        Wrong argument types, an invalid or inconsistent ``name_map``, no joints to
        pair, an unpaired target root, or a non-positive scale.
    FormatError
        ``name_map`` is a file that cannot be read.
    """
    if not isinstance(source, Motion):
        raise ValidationError(f"source: expected a Motion, got {type(source).__name__}")
    rig = _target_rig(target)
    tgt, bind = bind_matrices_of(rig)
    src = source.skeleton
    if name_map is None:
        own = _on_own_rig(source, rig, scale)
        if own is not None:
            return own
    pairs, keys, report = _resolve_pairs(src, tgt, name_map)
    # parents first (source order) so alignments and ancestors come before use
    order = sorted(range(len(pairs)), key=lambda i: pairs[i][0])
    pairs = [pairs[i] for i in order]
    remap = {old: new for new, old in enumerate(order)}
    keys = {k: remap[v] for k, v in keys.items()}
    s_owner, t_owner = _pair_owners(src, tgt, pairs)
    parent_pair = np.array(
        [_paired_ancestor(src.parents, s_owner, s) for s, _ in pairs], dtype=np.int64
    )
    # rest geometry: source zero pose, target bind pose
    src_rest = rest_positions(src)  # (Js, 3)
    heads = bind[:, :3, 3]  # (Jt, 3)
    u, _, vt = np.linalg.svd(bind[:, :3, :3])
    bind_rot = u @ vt  # (Jt, 3, 3)
    s_start = np.array([src_rest[s] for s, _ in pairs])  # (P, 3)
    t_start = np.array([heads[list(ts)].mean(axis=0) for _, ts in pairs])  # (P, 3)
    ends = _segment_ends(parent_pair, s_start, t_start)
    align = _rest_alignment(parent_pair, ends, s_start, t_start, keys)
    world = forward_kinematics(source)  # (T, Js, 4, 4)
    src_pos = world[:, :, :3, 3]
    drive = _drive(world[:, :, :3, :3], src_pos, src.parents, pairs, ends, align, s_start)
    tgt_world = _target_world(tgt.parents, t_owner, drive, bind_rot)
    n_frames = source.n_frames

    # ---- scale and root translation
    s_val = _scale(scale, src, tgt, pairs, keys, src_rest, heads)
    if "thigh_l" in keys and "thigh_r" in keys:
        landmark = [keys["thigh_l"], keys["thigh_r"]]
    else:
        landmark = [int(t_owner[0])]
    src_land = np.mean([src_pos[:, pairs[k][0]] for k in landmark], axis=0)  # (T, 3)
    placed = motion_from_world(
        rig, tgt_world, np.broadcast_to(heads[0], (n_frames, 3)), rate=source.rate
    )
    fk = joint_positions_arrays(tgt, placed.rotations, placed.translations)  # (T, Jt, 3)
    tgt_land = np.mean([fk[:, list(pairs[k][1])].mean(axis=1) for k in landmark], axis=0)
    root = heads[0] + (s_val * src_land - tgt_land)

    meta = _kept_meta(source)
    meta["retarget"] = {
        **report,
        "name_map": {src.names[s]: [tgt.names[t] for t in ts] for s, ts in pairs},
        "scale": s_val,
    }
    out = Motion(
        skeleton=tgt,
        rotations=placed.rotations,
        translations=placed.translations.copy(),
        rate=source.rate,
        channels=placed.channels,
        meta=meta,
    )
    out.translations[:, 0] = root
    return out


def _pair_owners(
    src: Skeleton, tgt: Skeleton, pairs: list[tuple[int, tuple[int, ...]]]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_owners`, refusing a target root that no source joint drives."""
    s_owner, t_owner = _owners(src, tgt, pairs)
    if t_owner[0] < 0:
        raise ValidationError(
            f"name_map: the target root {tgt.names[0]!r} is not driven by any source joint; "
            f"map the source root {src.names[0]!r} to it"
        )
    return s_owner, t_owner


def _segment_ends(
    parent_pair: np.ndarray, s_start: np.ndarray, t_start: np.ndarray
) -> list[list[int]]:
    """Per pair, the child pairs that end its segment: zero-length children (at the
    same place in either rest pose) are looked through to their own children."""
    n_pairs = parent_pair.size
    children: list[list[int]] = [[] for _ in range(n_pairs)]
    for i in range(n_pairs):
        if parent_pair[i] >= 0:
            children[parent_pair[i]].append(i)

    def ends_of(i: int, origin: int) -> list[int]:
        out: list[int] = []
        for c in children[i]:
            if (
                np.linalg.norm(s_start[c] - s_start[origin]) < _ZERO_LENGTH
                or np.linalg.norm(t_start[c] - t_start[origin]) < _ZERO_LENGTH
            ):
                out.extend(ends_of(c, origin))
            else:
                out.append(c)
        return out

    return [ends_of(i, i) for i in range(n_pairs)]


def _rest_alignment(
    parent_pair: np.ndarray,
    ends: list[list[int]],
    s_start: np.ndarray,
    t_start: np.ndarray,
    keys: dict[str, int],
) -> np.ndarray:
    """Rest alignment A (P, 3, 3) per pair, world, top-down: turns the target's rest
    segments onto the source's; the root turns about the vertical only (the facing,
    from the hips' lateral axis when both thighs are paired)."""
    n_pairs = parent_pair.size
    align = np.zeros((n_pairs, 3, 3))
    lateral = None
    if "thigh_l" in keys and "thigh_r" in keys:
        ls = s_start[keys["thigh_l"]] - s_start[keys["thigh_r"]]
        lt = t_start[keys["thigh_l"]] - t_start[keys["thigh_r"]]
        ls[1] = lt[1] = 0.0
        if np.linalg.norm(ls) > _ZERO_LENGTH and np.linalg.norm(lt) > _ZERO_LENGTH:
            lateral = (lt, ls)
    for i in range(n_pairs):
        par = parent_pair[i]
        a_par = np.eye(3) if par < 0 else align[par]
        e = ends[i]
        if par < 0 and lateral is not None:
            lt, ls = lateral  # a turn about the vertical: the facing only
            yaw = np.arctan2(np.cross(lt, ls)[1], float(lt @ ls))
            align[i] = _axis_angle_matrix(np.array([0.0, 1.0, 0.0]), np.asarray(yaw))
            continue
        if not e:
            align[i] = a_par
            continue
        us = _unit((t_start[e] - t_start[i]) @ a_par.T)  # target dirs after parent's A
        vs = _unit(s_start[e] - s_start[i])
        if len(e) == 1:
            align[i] = _swing(us[0], vs[0]) @ a_par
            continue
        # the end continuing the chain from the parent is aligned exactly
        incoming = s_start[i] - (s_start[par] if par >= 0 else s_start[i])
        if np.linalg.norm(incoming) > _ZERO_LENGTH:
            primary = int(np.argmax(vs @ _unit(incoming)))
        else:
            primary = int(np.argmax(vs[:, 1]))
        sw = _swing(us[primary], vs[primary])
        tw = _twist_to_fit(vs[primary], us @ sw.T, vs)
        align[i] = tw @ sw @ a_par
    return align


def _drive(
    src_rot: np.ndarray,
    src_pos: np.ndarray,
    src_parents: np.ndarray,
    pairs: list[tuple[int, tuple[int, ...]]],
    ends: list[list[int]],
    align: np.ndarray,
    s_start: np.ndarray,
) -> np.ndarray:
    """(P, T, 3, 3) world rotation ``D(t) @ A`` each pair imposes on its target joints.

    ``src_rot`` (T, Js, 3, 3) and ``src_pos`` (T, Js, 3) are the source's world frames;
    a segment with unpaired source joints inside follows its actual end.
    """
    drive = np.zeros((len(pairs), src_rot.shape[0], 3, 3))
    for i, (s, _) in enumerate(pairs):
        d = src_rot[:, s]  # (T, 3, 3); source rest world rotation is the identity
        e = ends[i]
        if len(e) == 1:
            end_joint = pairs[e[0]][0]
            if src_parents[end_joint] != s:
                # unpaired source joints inside the segment: follow its actual end
                rest_dir = s_start[e[0]] - s_start[i]
                predicted = np.einsum("tab,b->ta", d, rest_dir)
                actual = src_pos[:, end_joint] - src_pos[:, s]
                d = _swing(predicted, actual) @ d
        drive[i] = d @ align[i]
    return drive


def _target_world(
    parents: np.ndarray, t_owner: np.ndarray, drive: np.ndarray, bind_rot: np.ndarray
) -> np.ndarray:
    """(T, Jt, 3, 3) target world rotations: paired joints (and the chain bones above
    a paired joint) follow their pair; the rest keep their bind pose under their parent."""
    n_j = parents.size
    has_paired_below = np.zeros(n_j, dtype=bool)
    for j in range(n_j - 1, -1, -1):
        p = parents[j]
        if p >= 0 and (has_paired_below[j] or t_owner[j] >= 0):
            has_paired_below[p] = True
    tgt_world = np.zeros((drive.shape[1], n_j, 3, 3))
    for j in range(n_j):
        p = parents[j]
        i = t_owner[j]
        if i < 0 and has_paired_below[j]:
            i = _paired_ancestor(parents, t_owner, j)  # chain bone
        if i >= 0:
            tgt_world[:, j] = drive[i] @ bind_rot[j]
        elif p >= 0:
            tgt_world[:, j] = tgt_world[:, p] @ (bind_rot[p].T @ bind_rot[j])
        else:
            tgt_world[:, j] = bind_rot[j]
    return tgt_world


def _scale(
    scale: str | float,
    src: Skeleton,
    tgt: Skeleton,
    pairs: list[tuple[int, tuple[int, ...]]],
    keys: dict[str, int],
    src_rest: np.ndarray,
    heads: np.ndarray,
) -> float:
    if isinstance(scale, str):
        if scale != "height":
            raise ValidationError(f"scale: expected 'height' or a positive number, got {scale!r}")
        ratios_s, ratios_t = [], []
        for side in ("l", "r"):
            top, bottom = keys.get(f"thigh_{side}"), keys.get(f"foot_{side}")
            if top is None or bottom is None:
                continue
            ls = _leg_length(src.parents, src_rest, pairs[top][0], pairs[bottom][0])
            lt = _leg_length(tgt.parents, heads, pairs[top][1][0], pairs[bottom][1][0])
            if ls and lt:
                ratios_s.append(ls)
                ratios_t.append(lt)
        if ratios_s:
            return float(np.mean(ratios_t) / np.mean(ratios_s))
        hs = float(np.ptp(src_rest[:, 1]))
        ht = float(np.ptp(heads[:, 1]))
        if hs <= _ZERO_LENGTH or ht <= _ZERO_LENGTH:  # lying flat: the largest extent
            hs = float(np.ptp(src_rest, axis=0).max())
            ht = float(np.ptp(heads, axis=0).max())
        if hs <= _ZERO_LENGTH or ht <= _ZERO_LENGTH:
            raise ValidationError("scale='height': a skeleton has no height; pass a number")
        return ht / hs
    return check_positive(
        "scale",
        scale,
        expected="'height' or a positive number",
        expected_finite="a positive finite factor",
    )
