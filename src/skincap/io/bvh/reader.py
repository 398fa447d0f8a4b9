"""``read_bvh``: a BVH file into a :class:`~skincap.types.Motion` (metres, Y up).

The file's conventions (Euler orders, position channels, end sites, units, axes) are
described in :mod:`skincap.io.bvh`.
"""

from __future__ import annotations

import os
import warnings
from typing import Literal

import numpy as np

from skincap.errors import FormatError, UnitWarning, ValidationError
from skincap.geometry.kinematics import joint_positions_arrays
from skincap.geometry.rotations import (
    euler_to_quat,
    matrix_to_quat,
    quat_conjugate,
    quat_multiply,
)
from skincap.io._common import (
    check_readable,
    read_file_bytes,
    to_y_up,
    unit_scale,
    up_rotation,
)
from skincap.io.bvh.parse import _AXIS, _MOTION_RE, _parse_hierarchy, _parse_motion, _Tokens
from skincap.io.bvh.units import (
    _PLAUSIBLE_HEIGHT,
    BVH_UNITS,
    _rest_extent,
    guess_bvh_units,
    guess_bvh_up,
    standing_height,
)
from skincap.types import Motion, Skeleton

__all__ = ["read_bvh"]


# ------------------------------------------------------------------------- reader
def read_bvh(
    path: str | os.PathLike[str],
    *,
    units: str | None = None,
    up: Literal["auto", "y", "z"] = "auto",
    position_channels: Literal["auto", "replace", "add"] = "auto",
) -> Motion:
    """Read a BVH file into a :class:`~skincap.types.Motion` (metres, Y up).

    Parameters
    ----------
    path : str or PathLike
    units : {"m", "dm", "cm", "mm", "in", "cmu"}, optional
        Length unit of the file. None: guessed from the skeleton's height with
        :func:`guess_bvh_units`, with a :class:`~skincap.errors.UnitWarning` naming the
        file and the guess.
    up : {"auto", "y", "z"}
        Up axis of the file (BVH is normally Y-up). Z-up files are turned to Y-up.
        ``"auto"`` (default): "y" unless the rest pose clearly stands along z
        (:func:`guess_bvh_up`; e.g. MakeHuman and some Blender exports), with a
        :class:`~skincap.errors.UnitWarning` naming the file when it guesses "z".
        The axis used is recorded in ``meta["up"]``.
    position_channels : {"auto", "replace", "add"}
        How position channel values combine with the joint's ``OFFSET``: ``"replace"``
        (the BVH norm) or ``"add"`` (values are displacements from the rest offset, as
        MakeHuman writes its 6-channel joints). ``"auto"`` (default) reads "replace"
        unless the non-root joints' bones would collapse under it (median bone-length
        change over half the median bone) while keeping their ``OFFSET`` lengths under
        "add" (within a tenth): values near zero beside non-zero offsets are
        displacements. The mode used is recorded in ``meta["position_channels"]``.

    Returns
    -------
    Motion
        ``skeleton``: joints in file order, end sites as ``<parent>_end`` joints;
        ``offsets`` (J, 3) float64 metres. ``rotations`` (T, J, 4) float64 local unit
        quaternions ``(x, y, z, w)``, identity for joints without rotation channels;
        ``translations`` (T, J, 3) float64 metres, local, the offset where there is no
        position channel (channels replace offset components). ``rate`` = 1 /
        frame time, exactly; ``channels`` the file's per-joint channel layout; ``meta``
        as described in the module docstring. Never NaN: BVH has no missing samples,
        and NaN or infinite values are refused.

    Raises
    ------
    FormatError
        Anything wrong with the file (empty, truncated, unbalanced braces, unknown
        channel, rows not matching the channels or ``Frames:``, non-numeric, NaN or
        infinite values, missing or non-positive ``Frame Time``...), with the line.
    ValidationError
        An unknown ``units`` or ``up``.

    Examples
    --------
    >>> motion = read_bvh("walk.bvh", units="cm")  # doctest: +SKIP
    >>> motion.rotations.shape  # (frames, joints incl. end sites, 4)  # doctest: +SKIP
    (994, 38, 4)
    """
    scale = None if units is None else unit_scale(units, format_name="BVH")
    if position_channels not in ("auto", "replace", "add"):
        raise ValidationError(
            f"position_channels: expected 'auto', 'replace' or 'add', got {position_channels!r}"
        )
    up_key = str(up).strip().lower().lstrip("+")
    if up_key not in ("auto", "y", "z"):
        raise ValidationError(f"up: expected 'auto', 'y' or 'z', got {up!r}")
    p = check_readable(path)
    raw = read_file_bytes(p)
    try:
        return _read(p, raw, units, scale, up_key, position_channels)
    except FormatError:
        raise
    except (ValueError, IndexError, KeyError, TypeError, OverflowError, ArithmeticError) as exc:
        # ValidationError from the data model is a ValueError too: the file is inconsistent.
        raise FormatError(p, f"invalid BVH content: {exc}") from None


def _read(
    p: os.PathLike[str],
    raw: bytes,
    units: str | None,
    scale: float | None,
    up: str,
    position_mode: str,
) -> Motion:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    text = text.removeprefix("\ufeff")
    if not text.strip():
        raise FormatError(p, "file is empty (only whitespace)")
    m = _MOTION_RE.search(text)
    head = text if m is None else text[: m.start()]
    head_lines = head.split("\n")
    if m is not None and head_lines and head_lines[-1] == "":
        head_lines.pop()  # the newline ending the line before MOTION
    joints = _parse_hierarchy(_Tokens(p, head_lines))
    if m is None:
        raise FormatError(
            p,
            "no MOTION section after the hierarchy (truncated file?)",
            line=len(text.rstrip().split("\n")),
        )
    motion_line = head.count("\n") + 1
    after = text[m.end() :]
    lines = after.split("\n")[1:] if "\n" in after else []
    n_channels = sum(len(j.channels) for j in joints)
    data, frame_time, time_tok = _parse_motion(p, lines, motion_line, n_channels)
    t = data.shape[0]

    names = [j.name for j in joints]
    parents = np.array([j.parent for j in joints], dtype=np.int64)
    offsets = np.array([j.offset for j in joints], dtype=np.float64).reshape(-1, 3)
    channels = [j.channels for j in joints]

    pos_joint, pos_axis, pos_col, rot_groups = _channel_columns(channels)

    if position_mode == "auto":
        position_mode = _position_mode(parents, offsets, pos_joint, pos_axis, data[:, pos_col])
    translations = np.repeat(offsets[None], t, axis=0)  # (T, J, 3) file units
    if pos_col and position_mode == "add":
        translations[:, pos_joint, pos_axis] += data[:, pos_col]
    elif pos_col:
        translations[:, pos_joint, pos_axis] = data[:, pos_col]
    rotations = np.zeros((t, len(joints), 4))
    rotations[..., 3] = 1.0
    for seq, (ks, group_cols) in rot_groups.items():
        angles = data[:, np.asarray(group_cols)]  # (T, k, len(seq)) degrees
        rotations[:, ks] = euler_to_quat(angles, seq, degrees=True)

    extent, posed = _figure_extent(parents, offsets, rotations, translations)
    if up == "auto":
        up = guess_bvh_up(extent)
        if up == "z":
            warnings.warn(
                f"{os.fspath(p)}: up axis not given; "
                f"{'the first frame' if posed else 'the rest pose'} stands along z, read as "
                "Z-up (pass up='y' to override)",
                UnitWarning,
                stacklevel=3,
            )
    guessed = scale is None
    if units is not None and scale is not None:
        unit_name = units.strip().lower()
    else:
        unit_name, scale = _guessed_units(p, extent, up, posed)
    offsets = to_y_up(offsets * scale, up)
    translations *= scale
    translations = to_y_up(translations, up)
    if up != "y":
        turn = matrix_to_quat(up_rotation(up))  # file frame -> Y-up
        rotations = quat_multiply(quat_multiply(turn, rotations), quat_conjugate(turn))
    skeleton = Skeleton(names=names, parents=parents, offsets=offsets)
    return Motion(
        skeleton=skeleton,
        rotations=rotations,
        translations=translations,
        rate=1.0 / frame_time,
        channels=channels,
        meta={
            "source_units": unit_name,
            "units_guessed": guessed,
            "up": up,
            "position_channels": position_mode,
            "frame_time": frame_time,
            "frame_time_text": time_tok,
            "first_frame": 0,
            # False when the rest pose is no figure and the guesses read the first frame
            "rest_pose_is_figure": not posed,
        },
    )


def _channel_columns(
    channels: list[tuple[str, ...]],
) -> tuple[list[int], list[int], list[int], dict[str, tuple[list[int], list[list[int]]]]]:
    """Column bookkeeping of the motion table: (joint, axis, column) of each position
    channel, and per rotation sequence (``"ZXY"``…) the joints and their columns."""
    pos_joint, pos_axis, pos_col = [], [], []
    rot_groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    col = 0
    for k, ch in enumerate(channels):
        seq, cols = "", []
        for c in ch:
            if c.endswith("position"):
                pos_joint.append(k)
                pos_axis.append(_AXIS[c[0]])
                pos_col.append(col)
            else:
                seq += c[0]
                cols.append(col)
            col += 1
        if seq:
            group = rot_groups.setdefault(seq, ([], []))
            group[0].append(k)
            group[1].append(cols)
    return pos_joint, pos_axis, pos_col, rot_groups


def _plausible_extent(extent: np.ndarray) -> bool:
    """Whether some unit makes a figure of this extent (3,) a plausible human height,
    standing along y or z."""
    for up in ("y", "z"):
        height, _ = standing_height(extent, up)
        metres = height * BVH_UNITS[guess_bvh_units(height)]
        if _PLAUSIBLE_HEIGHT[0] <= metres <= _PLAUSIBLE_HEIGHT[1]:
            return True
    return False


def _figure_extent(
    parents: np.ndarray, offsets: np.ndarray, rotations: np.ndarray, translations: np.ndarray
) -> tuple[np.ndarray, bool]:
    """(3,) extent, file units and axes, of the figure the up and unit guesses read, and
    whether it is the first frame's pose.

    The rest pose's, the BVH norm; when no unit makes it a plausible human (its bones
    laid along their local axes and the hips placed metres from a root joint at the
    origin, as Bandai-Namco's files are) and the file has frames, the first frame's
    posed joints (``rotations`` (T, J, 4), ``translations`` (T, J, 3) file units).
    """
    rest = _rest_extent(parents, offsets)
    if _plausible_extent(rest) or rotations.shape[0] == 0:
        return rest, False
    posed = joint_positions_arrays(parents, rotations[0], translations[0])  # (J, 3)
    if not np.isfinite(posed).all():
        return rest, False
    extent = posed.max(axis=0) - posed.min(axis=0)
    return (extent, True) if _plausible_extent(extent) else (rest, False)


def _guessed_units(
    p: os.PathLike[str], extent: np.ndarray, up: str, posed: bool
) -> tuple[str, float]:
    """The unit (and metres per unit) that makes the figure (its extent (3,) in file
    units, ``up`` its up axis; ``posed``: the first frame's, else the rest pose's) a
    plausible human height (:func:`standing_height`: the height ``info`` reports);
    warns (UnitWarning, at read_bvh's caller)."""
    height, standing = standing_height(extent, up)
    unit_name = guess_bvh_units(height)
    scale = BVH_UNITS[unit_name]
    metres = height * scale
    note = ""
    if not _PLAUSIBLE_HEIGHT[0] <= metres <= _PLAUSIBLE_HEIGHT[1]:
        note = "; no unit gives a plausible human height, pass units= to be sure"
    figure = "the first frame's pose" if posed else "a skeleton"
    warnings.warn(
        f"{os.fspath(p)}: units not given; guessed {unit_name!r} from {figure} {height:.4g} units "
        f"{'tall' if standing else 'across'} "
        f"({metres:.3g} m){note}",
        UnitWarning,
        stacklevel=4,
    )
    return unit_name, scale


def _position_mode(
    parents: np.ndarray,
    offsets: np.ndarray,
    pos_joint: list[int],
    pos_axis: list[int],
    values: np.ndarray,
) -> str:
    """ "replace" or "add": how this file's position channels combine with OFFSET.

    ``values`` (T, C) are the position channel columns, ``pos_joint``/``pos_axis`` (C,)
    their joint and axis. Only non-root joints decide (a root's channels place the
    body in the world either way): under the right reading their bone lengths stay
    near their OFFSET lengths; under the wrong one a file of displacements (near 0)
    collapses its bones, and a file of absolute values doubles them.
    """
    joint = np.asarray(pos_joint, dtype=np.int64)
    axis = np.asarray(pos_axis, dtype=np.int64)
    keep = parents[joint] >= 0
    if not keep.any() or values.shape[0] == 0:
        return "replace"
    joint, axis, values = joint[keep], axis[keep], values[:, keep]
    moved = np.unique(joint)
    replaced = np.repeat(offsets[None, moved], values.shape[0], axis=0)  # (T, M, 3)
    added = replaced.copy()
    slot = np.searchsorted(moved, joint)
    replaced[:, slot, axis] = values
    added[:, slot, axis] += values
    rest = np.linalg.norm(offsets[moved], axis=-1)  # (M,)
    dev_replace = np.median(np.abs(np.linalg.norm(replaced, axis=-1) - rest))
    dev_add = np.median(np.abs(np.linalg.norm(added, axis=-1) - rest))
    # "replace" is the norm: only a clear collapse under it, with the bones intact
    # under "add", reads the file as displacements
    scale = np.median(rest)
    return "add" if dev_add < 0.1 * scale < 0.5 * scale < dev_replace else "replace"
