"""``write_bvh``: a :class:`~skincap.types.Motion` back to BVH, channel for channel.

The file's conventions are described in :mod:`skincap.io.bvh`.
"""

from __future__ import annotations

import math
import os
from typing import Literal

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.rotations import (
    matrix_to_quat,
    quat_angle,
    quat_apply,
    quat_conjugate,
    quat_multiply,
    quat_to_euler,
)
from skincap.io._common import (
    atomic_output,
    from_y_up,
    unit_scale,
    up_rotation,
)
from skincap.io.bvh.parse import _AXIS, _BAD_NAME_RE, MAX_FRAME_TIME_S, MIN_FRAME_TIME_S
from skincap.io.bvh.units import _skeleton_height
from skincap.types import Motion, Skeleton

__all__ = ["write_bvh"]


# ------------------------------------------------------------------------- writer
def _dfs_order(parents: np.ndarray) -> list[int]:
    children: list[list[int]] = [[] for _ in range(parents.size)]
    roots: list[int] = []
    for k, p in enumerate(parents):
        (roots if p < 0 else children[p]).append(k)
    order: list[int] = []
    stack = roots[::-1]
    while stack:
        k = stack.pop()
        order.append(k)
        stack.extend(children[k][::-1])
    return order


def write_bvh(
    motion: Motion,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    units: str | None = None,
    up: Literal["y", "z"] | None = None,
    precision: int | None = None,
    position_channels: Literal["replace", "add"] | None = None,
) -> None:
    """Write ``motion`` as a BVH file, channel for channel.

    Every joint keeps its channel layout (``motion.channels``, same order); rotation
    channels get intrinsic Euler angles in the joint's own order (scipy
    ``Rotation.as_euler``; gimbal lock is handled by scipy and the rotation is still
    exact), position channels the local translation. Non-root leaves without channels
    are written as ``End Site`` blocks. Joints are written depth-first (children in
    index order), which is the input order for skeletons read by :func:`read_bvh`.

    Parameters
    ----------
    motion : Motion
        ``rotations`` (T, J, 4) and ``translations`` (T, J, 3) metres, Y up.
    path : str or PathLike
    force : bool
        Replace an existing file.
    units : {"m", "dm", "cm", "mm", "in", "cmu"}, optional
        Unit to write in; default ``motion.meta["source_units"]``, else ``"cm"``.
    up : {"y", "z"}, optional
        Up axis of the file; default ``motion.meta["up"]``, else ``"y"``.
    precision : int, optional
        Decimals of every number. Default: 6 for angles (degrees) and, for lengths,
        enough that the last digit is at most 1e-7 of the skeleton's height (at least 6).
    position_channels : {"replace", "add"}, optional
        Write position channels as the translation (``"replace"``) or as its
        displacement from the offset (``"add"``); default
        ``motion.meta["position_channels"]``, else ``"replace"``.

    Raises
    ------
    ValidationError
        The motion cannot be written faithfully: a joint's translation differs from its
        offset along an axis without a position channel, or its rotation has a part its
        rotation channels cannot express (end sites' rotations are not stored by BVH and
        are dropped); a joint name with tabs, newlines, braces or leading/trailing
        spaces; an unknown ``units``/``up``; a negative ``precision``.
    OutputExistsError
        ``path`` exists and ``force`` is False.

    Notes
    -----
    The frame time written is ``motion.meta["frame_time_text"]`` when it still matches
    ``motion.rate`` (so a file read and written keeps e.g. ``.0083333``), else the
    shortest repr of ``1 / rate``.
    """
    if not isinstance(motion, Motion):
        raise ValidationError(f"motion: expected a Motion, got {type(motion).__name__}")
    # the reader's bounds: 'solve' of a C3D at 1e-4 Hz wrote 'Frame Time: 10000.0', a
    # BVH that 'skincap info' then refused
    if not MIN_FRAME_TIME_S <= 1.0 / motion.rate <= MAX_FRAME_TIME_S:
        raise ValidationError(
            f"motion.rate: {motion.rate:g} Hz is a Frame Time of {1.0 / motion.rate:g} s, "
            f"outside the {MIN_FRAME_TIME_S:g}..{MAX_FRAME_TIME_S:g} s a BVH holds"
        )
    scale, up_key, mode = _write_options(motion, units, up, position_channels, precision)
    sk = motion.skeleton
    names = sk.names
    _check_names(names)
    parents = sk.parents
    # Motion fills in a default layout when none was given
    channels: list[tuple[str, ...]] = list(motion.channels or [])
    j = sk.n_joints
    has_child = ~sk.is_leaf
    is_end = [parents[k] >= 0 and not has_child[k] and not channels[k] for k in range(j)]

    # back to the file's frame and unit
    offsets = from_y_up(sk.offsets, up_key) / scale  # (J, 3)
    translations = from_y_up(motion.translations, up_key) / scale  # (T, J, 3)
    rotations = motion.rotations
    if up_key != "y":
        turn = matrix_to_quat(up_rotation(up_key))  # Y-up -> file frame
        rotations = quat_multiply(quat_multiply(quat_conjugate(turn), rotations), turn)
    t = motion.n_frames

    height = _skeleton_height(parents, offsets)
    if precision is None:
        len_dec = 6 if height <= 0 else max(6, math.ceil(-math.log10(1e-7 * height)))
        ang_dec = 6
    else:
        len_dec = ang_dec = int(precision)

    # channel columns, joints in depth-first order
    order = _dfs_order(parents)
    data, decimals, rot_groups = _position_columns(
        motion,
        translations,
        offsets,
        rotations,
        channels,
        order,
        is_end,
        mode,
        scale,
        height,
        len_dec,
        ang_dec,
    )
    _fill_rotation_columns(data, rot_groups, rotations, names, channels)
    time_text = _frame_time_text(motion)

    out: list[str] = ["HIERARCHY"]
    _write_hierarchy(out, sk, channels, offsets, is_end, len_dec)
    out.append("MOTION")
    out.append(f"Frames: {t}")
    out.append(f"Frame Time: {time_text}")
    if data.shape[1]:
        data += 0.0  # no "-0.000000" for exact negative zeros
        row = " ".join(f"%.{d}f" for d in decimals)
        out.extend(row % tuple(values) for values in data.tolist())
    elif t:
        out.extend([""] * t)
    text = "\n".join(out) + "\n"
    with atomic_output(path, force=force) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)


def _write_options(
    motion: Motion,
    units: str | None,
    up: str | None,
    position_channels: str | None,
    precision: int | None,
) -> tuple[float, str, str]:
    """(metres per file unit, up axis, position-channel mode) of the file, the
    arguments' defaults taken from ``motion.meta``; ValidationError for a bad one."""
    unit = units if units is not None else str(motion.meta.get("source_units", "cm"))
    scale = unit_scale(
        unit,
        argument="units" if units is not None else "motion.meta['source_units']",
        format_name="BVH",
    )
    up_key = str(up if up is not None else motion.meta.get("up", "y")).strip().lower().lstrip("+")
    if up_key not in ("auto", "y", "z"):
        raise ValidationError(f"up: expected 'auto', 'y' or 'z', got {up!r}")
    mode = (
        position_channels
        if position_channels is not None
        else motion.meta.get("position_channels", "replace")
    )
    if mode not in ("replace", "add"):
        raise ValidationError(f"position_channels: expected 'replace' or 'add', got {mode!r}")
    if precision is not None and (
        not isinstance(precision, (int, np.integer)) or precision < 0 or precision > 15
    ):
        raise ValidationError(
            f"precision: expected a number of decimals from 0 to 15, got {precision!r}"
        )

    return scale, up_key, mode


def _check_names(names: list[str]) -> None:
    """ValidationError for a joint name BVH cannot hold (empty, tabs, newlines, braces…)."""
    for name in names:
        if not name or _BAD_NAME_RE.search(name):
            raise ValidationError(
                f"skeleton.names: {name!r} cannot be written to BVH (no tabs, newlines, braces, "
                "leading/trailing or double spaces)"
            )


def _position_columns(
    motion: Motion,
    translations: np.ndarray,
    offsets: np.ndarray,
    rotations: np.ndarray,
    channels: list[tuple[str, ...]],
    order: list[int],
    is_end: list[bool],
    mode: str,
    scale: float,
    height: float,
    len_dec: int,
    ang_dec: int,
) -> tuple[np.ndarray, np.ndarray, dict[str, tuple[list[int], list[list[int]]]]]:
    """The channel table (T, C) with its position columns filled, in file units.

    ``translations`` (T, J, 3) and ``offsets`` (J, 3) are in the file's frame and unit
    (``scale`` metres each), ``rotations`` (T, J, 4) in its frame; joints go in
    ``order``. Returns the table, the decimals of each column (C,) and the rotation
    columns to fill, grouped by Euler sequence: {seq: (joints, their columns)}.
    ValidationError for a translation off an axis without a position channel or a
    rotation of a joint without rotation channels.
    """
    names = motion.skeleton.names
    t = motion.n_frames
    n_cols = sum(len(channels[k]) for k in order)
    data = np.zeros((t, n_cols))
    decimals = np.zeros(n_cols, dtype=np.int64)
    rot_groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    col = 0
    for k in order:
        seq, cols = "", []
        present = np.zeros(3, dtype=bool)
        for c in channels[k]:
            if c.endswith("position"):
                axis = _AXIS[c[0]]
                present[axis] = True
                data[:, col] = translations[:, k, axis] - (
                    offsets[k, axis] if mode == "add" else 0.0
                )
                decimals[col] = len_dec
            else:
                seq += c[0]
                cols.append(col)
                decimals[col] = ang_dec
            col += 1
        fixed = ~present
        if t and fixed.any():
            dev = np.abs(translations[:, k, fixed] - offsets[k, fixed])
            tol = 1e-9 * (1.0 + np.abs(offsets[k, fixed]) + height)
            if (dev > tol).any():
                raise ValidationError(
                    f"translations: joint {names[k]!r} moves away from its offset by up to "
                    f"{dev.max() * scale:.3g} m along an axis without a position channel "
                    f"(channels {channels[k]}); BVH cannot store that"
                )
        if seq:
            group = rot_groups.setdefault(seq, ([], []))
            group[0].append(k)
            group[1].append(cols)
        elif t and not is_end[k]:
            angle = quat_angle(rotations[:, k], np.array([0.0, 0.0, 0.0, 1.0]))
            if angle.max() > 1e-8:
                raise ValidationError(
                    f"rotations: joint {names[k]!r} rotates by up to {math.degrees(angle.max()):.3g} degrees "
                    "but has no rotation channels; BVH cannot store that"
                )
    return data, decimals, rot_groups


def _fill_rotation_columns(
    data: np.ndarray,
    rot_groups: dict[str, tuple[list[int], list[list[int]]]],
    rotations: np.ndarray,
    names: list[str],
    channels: list[tuple[str, ...]],
) -> None:
    """Write the Euler angles (degrees) of ``rotations`` (T, J, 4) into ``data`` (T, C).

    ``rot_groups`` from :func:`_position_columns`; one vectorised conversion per Euler
    sequence. ValidationError when a joint with fewer than three rotation channels
    rotates about an axis it has no channel for.
    """
    t = data.shape[0]
    for seq, (ks, group_cols) in rot_groups.items():
        q = rotations[:, ks]  # (T, k, 4)
        if len(seq) == 3:
            angles = quat_to_euler(q, seq, degrees=True)  # (T, k, 3)
        else:
            angles, residual = _partial_euler(q, seq)  # (T, k, n), (T, k) radians
            if t and residual.max() > 1e-8:
                bad = ks[int(np.argmax(residual.max(axis=0)))]
                raise ValidationError(
                    f"rotations: joint {names[bad]!r} rotates by up to {math.degrees(residual.max()):.3g} degrees "
                    f"about an axis it has no channel for (channels {channels[bad]}); BVH cannot store that"
                )
        data[:, np.asarray(group_cols)] = angles


def _frame_time_text(motion: Motion) -> str:
    """The Frame Time line's number: ``meta["frame_time_text"]`` when it still matches
    ``motion.rate``, else the shortest repr of the frame time in seconds."""
    frame_time = float(motion.meta.get("frame_time", 1.0 / motion.rate))
    if (
        not (math.isfinite(frame_time) and frame_time > 0)
        or abs(frame_time * motion.rate - 1.0) > 1e-9
    ):
        frame_time = 1.0 / motion.rate
    time_text = motion.meta.get("frame_time_text")
    if not isinstance(time_text, str) or _float_or_none(time_text) != frame_time:
        time_text = repr(frame_time)
    return time_text


_UNIT_AXES = np.eye(3)


def _axis_quat(axis: int, angle: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions turning ``angle`` radians about coordinate axis ``axis``."""
    q = np.zeros(angle.shape + (4,))
    q[..., axis] = np.sin(angle / 2)
    q[..., 3] = np.cos(angle / 2)
    return q


def _partial_euler(q: np.ndarray, seq: str) -> tuple[np.ndarray, np.ndarray]:
    """Angles (..., n) degrees of ``q`` as ``seq`` (1 or 2 intrinsic axes) and the residual.

    The residual (...,) is the angle in radians of the part of ``q`` the axes cannot
    express (0 for a rotation that really is ``R_A(a) @ R_B(b)``).
    """
    first = _AXIS[seq[0]]
    if len(seq) == 1:
        a = 2.0 * np.arctan2(q[..., first], q[..., 3])
        rest = quat_multiply(quat_conjugate(_axis_quat(first, a)), q)
        angles = a[..., None]
    else:
        second = _AXIS[seq[1]]
        # R_A(a) R_B(b) e_B = R_A(a) e_B = cos(a) e_B + sin(a) (e_A x e_B)
        e_b = _UNIT_AXES[second]
        v = quat_apply(q, e_b)
        a = np.arctan2(v @ np.cross(_UNIT_AXES[first], e_b), v @ e_b)
        rest_b = quat_multiply(quat_conjugate(_axis_quat(first, a)), q)
        b = 2.0 * np.arctan2(rest_b[..., second], rest_b[..., 3])
        rest = quat_multiply(quat_conjugate(_axis_quat(second, b)), rest_b)
        angles = np.stack([a, b], axis=-1)
    residual = quat_angle(rest, np.array([0.0, 0.0, 0.0, 1.0]))
    # wrap to (-180, 180]
    deg = np.degrees(angles)
    deg = np.where(deg > 180.0, deg - 360.0, np.where(deg <= -180.0, deg + 360.0, deg))
    return deg, residual


def _float_or_none(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


#: Deepest indentation the writer uses, in tabs. Real skeletons are under 30 joints
#: deep; a chain of N joints indented one tab per level would make the file grow as N²
#: (a 100,000-deep chain: ~20 GB), so deeper levels stay at this indentation.
_MAX_INDENT = 64


def _write_hierarchy(
    out: list[str],
    sk: Skeleton,
    channels: list[tuple[str, ...]],
    offsets: np.ndarray,
    is_end: list[bool],
    decimals: int,
) -> None:
    children: list[list[int]] = [[] for _ in range(sk.n_joints)]
    roots: list[int] = []
    for k, p in enumerate(sk.parents):
        (roots if p < 0 else children[p]).append(k)

    def offset_line(k: int, depth: int) -> str:
        x, y, z = (float(v) + 0.0 for v in offsets[k])
        tab = chr(9) * min(depth, _MAX_INDENT)
        return f"{tab}OFFSET {x:.{decimals}f} {y:.{decimals}f} {z:.{decimals}f}"

    # explicit stack of (joint, depth, closing?) instead of recursion: any depth works
    stack: list[tuple[int, int, bool]] = [(r, 0, False) for r in roots[::-1]]
    while stack:
        k, depth, closing = stack.pop()
        tab = "\t" * min(depth, _MAX_INDENT)
        if closing:
            out.append(f"{tab}}}")
            continue
        if is_end[k]:
            out.append(f"{tab}End Site")
            out.append(f"{tab}{{")
            out.append(offset_line(k, depth + 1))
            out.append(f"{tab}}}")
            continue
        out.append(f"{tab}{'ROOT' if sk.parents[k] < 0 else 'JOINT'} {sk.names[k]}")
        out.append(f"{tab}{{")
        out.append(offset_line(k, depth + 1))
        out.append(f"{tab}\tCHANNELS {len(channels[k])}" + "".join(f" {c}" for c in channels[k]))
        stack.append((k, depth, True))
        stack.extend((c, depth + 1, False) for c in children[k][::-1])
