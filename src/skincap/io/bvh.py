"""Biovision Hierarchy (BVH) skeleton motion: reader and writer.

A BVH file has a ``HIERARCHY`` of joints (``ROOT``/``JOINT`` blocks with an ``OFFSET``
and ``CHANNELS``, leaves closed by ``End Site`` blocks) and a ``MOTION`` section with
``Frames:``, ``Frame Time:`` and one row of channel values per frame, joints in the
order the hierarchy lists them.

Conventions used here
---------------------
Rotations
    Each joint's rotation channels, read left to right, are *intrinsic* Euler angles in
    degrees: ``Zrotation Xrotation Yrotation`` means ``R = Rz @ Rx @ Ry``
    (``Rotation.from_euler("ZXY", ..., degrees=True)``). Orders may differ between
    joints; joints with one or two rotation channels are supported.
Positions
    A joint's local transform is ``T(t) @ R`` with ``t`` its translation. Position
    channels *replace* the matching component of the joint's ``OFFSET`` (for the root
    and for non-root joints alike; this is what Biovision, MotionBuilder, Blender and
    bvhio do); components without a channel keep the offset. ``Motion.translations``
    therefore always holds the effective local translation and equals the offset for
    joints without position channels.
End sites
    Become joints named ``<parent>_end`` (``<parent>_end_2``... if that name is taken)
    with no channels. The writer turns every non-root leaf without channels back into
    an ``End Site`` (its name is not stored by BVH).
Units
    BVH has none. Pass ``units``; when it is None the reader infers it from the height
    of the rest-pose skeleton (see :func:`guess_bvh_units`) and warns with a
    :class:`~skincap.errors.UnitWarning`. Besides the general units (``m``, ``dm``,
    ``cm``, ``mm``, ``in``) BVH has ``"cmu"``: the Carnegie Mellon ASF length unit,
    1/0.45 inch = 0.05644 m, kept by the widely used cgspeed conversions of the CMU
    database (a CMU skeleton is about 24 such units tall: in centimetres or inches it
    would be a doll, in decimetres a giant).
Axes
    ``up="y"`` (default, the BVH norm) or ``"z"``; Z-up data is turned to skincap's
    Y-up (``(x, y, z) -> (x, z, -y)``, rotations conjugated to match) and back on write.

``meta`` of a read Motion: ``source_units``, ``units_guessed``, ``up``,
``frame_time`` (float seconds), ``frame_time_text`` (the file's own spelling, written
back unchanged), ``first_frame`` (0: BVH has no frame numbers).
"""

from __future__ import annotations

import io
import math
import os
import re
import warnings
from typing import Literal

import numpy as np

from skincap.errors import FormatError, UnitWarning, ValidationError, quote_excerpt
from skincap.geometry.rotations import (
    euler_to_quat,
    matrix_to_quat,
    quat_angle,
    quat_apply,
    quat_conjugate,
    quat_multiply,
    quat_to_euler,
)
from skincap.io._common import (
    UNIT_TO_METRES,
    atomic_output,
    check_readable,
    from_y_up,
    to_y_up,
    up_rotation,
)
from skincap.types import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

__all__ = ["read_bvh", "write_bvh", "guess_bvh_units", "guess_bvh_up", "BVH_UNITS"]

#: Length units of BVH files, metres per unit: the general units plus ``"cmu"``,
#: the CMU ASF unit (1/0.45 inch) of the cgspeed CMU conversions.
BVH_UNITS: dict[str, float] = dict(UNIT_TO_METRES)

#: The units :func:`guess_bvh_units` chooses from.
_GUESSABLE = ("m", "dm", "cm", "mm", "in", "cmu")
#: Typical standing height of the humans BVH files hold, metres.
_HUMAN_HEIGHT = 1.7
_PLAUSIBLE_HEIGHT = (1.0, 2.5)

_CHANNEL_NAMES = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}
_AXIS = {"X": 0, "Y": 1, "Z": 2}
_FRAMES_RE = re.compile(r"^\s*Frames\s*:\s*(\S+)\s*$")
_FRAME_TIME_RE = re.compile(r"^\s*Frame\s+Time\s*:\s*(\S+)\s*$")
_MOTION_RE = re.compile(r"^[ \t]*MOTION[ \t\r]*$", re.MULTILINE)
_BAD_NAME_RE = re.compile(r"(^\s|\s$|[\t\r\n\v\f{}]|\s\s)")


# ------------------------------------------------------------------------- units
def _bvh_unit_scale(unit: str, argument: str = "units") -> float:
    if not isinstance(unit, str) or unit.strip().lower() not in BVH_UNITS:
        raise ValidationError(
            f"{argument}: unknown BVH length unit {unit!r}, expected one of {sorted(BVH_UNITS)}"
        )
    return BVH_UNITS[unit.strip().lower()]


def guess_bvh_units(height: float) -> str:
    """The unit that makes a skeleton ``height`` units tall a plausible human.

    Picks, among ``m``, ``dm``, ``cm``, ``mm``, ``in`` and ``cmu`` (the CMU ASF unit,
    1/0.45 inch), the one whose height in metres is closest to 1.7 m on a log scale
    (so 1.2-2.2 units -> m, 12-22 -> dm, 120-220 -> cm, 1200-2200 -> mm, 45-60 -> in,
    about 24-38 -> cmu).

    Parameters
    ----------
    height : float
        Largest extent of the rest-pose joint positions, in file units. A skeleton of
        zero (or non-finite) height gives ``"m"``.

    Returns
    -------
    str
        A key of :data:`BVH_UNITS`.
    """
    h = float(height)
    if not math.isfinite(h) or h <= 0:
        return "m"
    return min(_GUESSABLE, key=lambda u: abs(math.log(h * BVH_UNITS[u] / _HUMAN_HEIGHT)))


def _rest_extent(parents: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(3,) extent along the file's x, y, z of the rest-pose joint positions, offsets' unit."""
    pos = np.zeros_like(offsets)
    for k in range(parents.size):
        pos[k] = offsets[k] if parents[k] < 0 else pos[parents[k]] + offsets[k]
    return pos.max(axis=0) - pos.min(axis=0) if pos.size else np.zeros(3)


def _skeleton_height(parents: np.ndarray, offsets: np.ndarray) -> float:
    """Largest extent (over x, y, z) of the rest-pose joint positions, offsets' unit."""
    return float(_rest_extent(parents, offsets).max())


def guess_bvh_up(extent: np.ndarray) -> str:
    """ "y" or "z": the up axis of a BVH file from its rest pose's extent (3,) along x, y, z.

    A BVH's rest pose stands (T- or A-pose). Read with the wrong up axis a standing
    body lies down: its extent along the supposed up axis is its depth, a fraction of
    its height. "z" only when the body is clearly standing along z (z extent at least
    twice the y extent and the largest of the two); otherwise "y", the BVH norm.
    """
    y, z = float(extent[1]), float(extent[2])
    return "z" if z > 0 and z >= 2.0 * y else "y"


# ---------------------------------------------------------------------- hierarchy
class _Tokens:
    """Whitespace-separated tokens of the hierarchy with their 1-based line numbers."""

    def __init__(self, path: os.PathLike[str] | str, lines: list[str]) -> None:
        self.path = path
        self.items: list[tuple[str, int]] = []
        for n, line in enumerate(lines, start=1):
            self.items.extend((tok, n) for tok in line.split())
        self.pos = 0
        self.last_line = max(len("\n".join(lines).rstrip().split("\n")), 1)

    def error(self, what: str, line: int | None = None) -> FormatError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.last_line
        return FormatError(self.path, what, line=line)

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def next(self, expected: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"file ends inside the HIERARCHY; expected {expected}")
        item = self.items[self.pos]
        self.pos += 1
        return item

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok != word:
            raise self.error(f"expected {word!r}, found {quote_excerpt(tok)}", line)
        return line

    def rest_of_line(self, line: int) -> list[str]:
        out = []
        while (
            self.pos < len(self.items)
            and self.items[self.pos][1] == line
            and self.items[self.pos][0] != "{"
        ):
            out.append(self.items[self.pos][0])
            self.pos += 1
        return out

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"{what}: expected a number, found {tok!r}", line) from None
        if not math.isfinite(value):
            raise self.error(f"{what}: must be finite, found {tok!r}", line)
        return value


class _Joint:
    __slots__ = ("name", "parent", "offset", "channels", "is_end", "line")

    def __init__(self, name: str, parent: int, line: int, is_end: bool = False) -> None:
        self.name = name
        self.parent = parent
        self.line = line
        self.is_end = is_end
        self.offset: tuple[float, float, float] | None = None
        self.channels: tuple[str, ...] = ()


def _parse_joint_body(tok: _Tokens, joint: _Joint) -> None:
    """OFFSET and CHANNELS (either order, CHANNELS optional) after a joint's '{'."""
    while tok.peek() in ("OFFSET", "CHANNELS"):
        word, line = tok.next("OFFSET or CHANNELS")
        if word == "OFFSET":
            if joint.offset is not None:
                raise tok.error(f"joint {joint.name!r} has two OFFSET lines", line)
            joint.offset = (tok.number("OFFSET x"), tok.number("OFFSET y"), tok.number("OFFSET z"))
            continue
        if joint.is_end:
            raise tok.error("an End Site has no CHANNELS", line)
        if joint.channels:
            raise tok.error(f"joint {joint.name!r} has two CHANNELS lines", line)
        count_tok, count_line = tok.next("the number of channels")
        try:
            count = int(count_tok)
        except ValueError:
            raise tok.error(
                f"CHANNELS: expected a channel count, found {count_tok!r}", count_line
            ) from None
        if count < 0 or count > 6:
            raise tok.error(f"CHANNELS: a joint has 0 to 6 channels, found {count}", count_line)
        names = []
        for _ in range(count):
            name_tok, name_line = tok.next(f"{count} channel names")
            canonical = _CHANNEL_NAMES.get(name_tok.lower())
            if canonical is None:
                raise tok.error(
                    f"unknown channel {name_tok!r}; expected one of {', '.join(POSITION_CHANNELS + ROTATION_CHANNELS)}",
                    name_line,
                )
            if canonical in names:
                raise tok.error(
                    f"channel {canonical} listed twice for joint {joint.name!r}", name_line
                )
            names.append(canonical)
        joint.channels = tuple(names)
    if joint.offset is None:
        raise tok.error(
            f"{'End Site of ' if joint.is_end else 'joint '}{joint.name!r}: expected OFFSET"
        )


def _parse_hierarchy(tok: _Tokens) -> list[_Joint]:
    """Joints in file (depth-first) order; end sites carry ``is_end`` and their parent's name."""
    tok.expect("HIERARCHY")
    joints: list[_Joint] = []
    seen: dict[str, int] = {}
    while tok.peek() == "ROOT":
        stack: list[int] = []
        word = "ROOT"
        while True:
            if word in ("ROOT", "JOINT"):
                _, line = tok.next(word)
                name = " ".join(tok.rest_of_line(line))
                if not name:
                    raise tok.error(f"{word} without a name", line)
                if name in seen:
                    raise tok.error(
                        f"joint name {name!r} used twice (first on line {seen[name]})", line
                    )
                seen[name] = line
                joint = _Joint(name, stack[-1] if stack else -1, line)
                tok.expect("{")
                _parse_joint_body(tok, joint)
                joints.append(joint)
                stack.append(len(joints) - 1)
            elif word == "End":
                _, line = tok.next("End Site")
                tok.expect("Site")
                end = _Joint(joints[stack[-1]].name, stack[-1], line, is_end=True)
                tok.expect("{")
                _parse_joint_body(tok, end)
                tok.expect("}")
                joints.append(end)
            elif word == "}":
                tok.next("'}'")
                stack.pop()
                if not stack:
                    break
            else:
                found, line = tok.next("JOINT, End Site or '}'")
                raise tok.error(
                    f"expected JOINT, End Site or '}}' in joint {joints[stack[-1]].name!r}, found {found!r}",
                    line,
                )
            word = tok.peek()
            if word is None:
                raise tok.error(
                    f"file ends inside joint {joints[stack[-1]].name!r} (opened on line {joints[stack[-1]].line}); missing '}}' or MOTION"
                )
    if not joints:
        found = tok.peek()
        raise tok.error(
            "expected ROOT after HIERARCHY" + (f", found {quote_excerpt(found)}" if found else "")
        )
    if tok.peek() is not None:
        raise tok.error(f"unexpected {tok.peek()!r} after the hierarchy; expected ROOT or MOTION")
    # End sites: "<parent>_end", made unique against every joint name.
    taken = {j.name for j in joints if not j.is_end}
    for j in joints:
        if j.is_end:
            base = f"{j.name}_end"
            name, k = base, 1
            while name in taken:
                k += 1
                name = f"{base}_{k}"
            j.name = name
            taken.add(name)
    return joints


# ------------------------------------------------------------------------- motion
def _diagnose_rows(
    path: os.PathLike[str] | str, lines: list[str], first_line: int, n_frames: int, n_channels: int
) -> FormatError:
    """Find the first bad motion row (slow path, only run when the bulk parse failed)."""
    rows = 0
    last = first_line
    for i, line in enumerate(lines):
        values = line.split()
        if not values:
            continue
        number = first_line + i
        last = number
        rows += 1
        if rows > n_frames:
            return FormatError(
                path, f"more motion rows than 'Frames: {n_frames}' declares", line=number
            )
        if len(values) != n_channels:
            return FormatError(
                path,
                f"motion row {rows} has {len(values)} values, the hierarchy has {n_channels} channels",
                line=number,
            )
        for col, v in enumerate(values):
            try:
                x = float(v)
            except ValueError:
                return FormatError(
                    path,
                    f"motion row {rows}, value {col + 1}: not a number: {v[:40]!r}",
                    line=number,
                )
            if not math.isfinite(x):
                return FormatError(
                    path,
                    f"motion row {rows}, value {col + 1}: must be finite, found {v!r}",
                    line=number,
                )
    if rows < n_frames:
        return FormatError(
            path,
            f"'Frames: {n_frames}' declared but the file has {rows} motion rows (truncated?)",
            line=last,
        )
    return FormatError(path, "could not parse the motion rows as numbers", line=first_line)


_WHITESPACE = np.zeros(256, dtype=bool)
_WHITESPACE[[9, 10, 11, 12, 13, 32]] = True
_PLAIN = _WHITESPACE.copy()
_PLAIN[[43, 45, 46]] = True  # + - .
_PLAIN[48:58] = True  # digits


def _parse_plain_decimals(body: str, n_columns: int) -> np.ndarray | None:
    """(rows, n_columns) float64 of a block of plain decimals, vectorised; None if unsure.

    Handles the tokens BVH writers produce (``-12.3456``, ``7``, ``.5``, ``+1.``) with
    at most 15 significant digits, every non-blank line holding ``n_columns`` of them.
    Each value is ``integer mantissa / 10**decimals``: two exact numbers and one
    correctly rounded division, so the result equals ``float(token)``. Anything else
    (exponents, nan, ragged rows, stray characters) returns None and the caller falls
    back to the general parser, which reports errors with their line.
    """
    try:
        raw = body.encode("ascii")
    except UnicodeEncodeError:
        return None
    b = np.frombuffer(raw, dtype=np.uint8)
    if b.size == 0 or not _PLAIN[b].all():
        return None
    solid = np.concatenate([[False], ~_WHITESPACE[b], [False]])
    edges = np.flatnonzero(solid[1:] != solid[:-1])
    starts, ends = edges[0::2], edges[1::2]  # token i is b[starts[i]:ends[i]]
    n_tok = starts.size
    if n_tok == 0 or n_tok % n_columns:
        return None
    # tokens per line must all be n_columns
    line_of = np.searchsorted(np.flatnonzero(b == 10), starts)
    per_line = np.bincount(line_of)
    if (per_line[per_line > 0] != n_columns).any():
        return None
    lengths = ends - starts
    width = int(lengths.max())
    if width > 17:
        return None
    mant = np.zeros(n_tok, dtype=np.int64)
    n_digits = np.zeros(n_tok, dtype=np.int64)
    decimals = np.zeros(n_tok, dtype=np.int64)
    seen_dot = np.zeros(n_tok, dtype=bool)
    negative = np.zeros(n_tok, dtype=bool)
    ok = True
    for col in range(width):  # loop over character positions, vectorised over tokens
        inside = lengths > col
        c = np.where(inside, b[np.minimum(starts + col, b.size - 1)], 32)
        digit = (c >= 48) & (c <= 57)
        dot = c == 46
        sign = (c == 45) | (c == 43)
        if col == 0:
            negative = c == 45
        else:
            ok &= not sign.any()
        ok &= not (dot & seen_dot).any()
        mant = np.where(digit, mant * 10 + (c.astype(np.int64) - 48), mant)
        n_digits += digit
        decimals += digit & seen_dot
        seen_dot |= dot
    if not ok or (n_digits == 0).any() or n_digits.max() > 15:
        return None
    values = mant / (10.0**decimals)
    values[negative] *= -1.0
    return values.reshape(-1, n_columns)


def _parse_motion(
    path: os.PathLike[str] | str, lines: list[str], motion_line: int, n_channels: int
) -> tuple[np.ndarray, float, str]:
    """(T, C) channel values, frame time and its text from the lines after MOTION."""
    i = 0

    def header_line(regex: re.Pattern[str], what: str) -> tuple[str, int]:
        nonlocal i
        while i < len(lines) and not lines[i].strip():
            i += 1
        number = motion_line + 1 + i
        if i >= len(lines):
            raise FormatError(path, f"file ends after MOTION; expected {what!r}", line=number - 1)
        m = regex.match(lines[i])
        if m is None:
            raise FormatError(
                path, f"expected {what!r}, found {lines[i].strip()[:60]!r}", line=number
            )
        i += 1
        return m.group(1), number

    frames_tok, frames_line = header_line(_FRAMES_RE, "Frames: <count>")
    try:
        n_frames = int(frames_tok)
    except ValueError:
        raise FormatError(
            path, f"Frames: expected a whole number, found {frames_tok!r}", line=frames_line
        ) from None
    if n_frames < 0:
        raise FormatError(path, f"Frames: must not be negative, found {n_frames}", line=frames_line)
    time_tok, time_line = header_line(_FRAME_TIME_RE, "Frame Time: <seconds>")
    try:
        frame_time = float(time_tok)
    except ValueError:
        raise FormatError(
            path, f"Frame Time: expected seconds, found {time_tok!r}", line=time_line
        ) from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise FormatError(
            path,
            f"Frame Time: must be a positive number of seconds, found {time_tok!r}",
            line=time_line,
        )
    rest = lines[i:]
    first_line = motion_line + 1 + i
    body = "\n".join(rest)
    if not body.strip():
        data = np.zeros((0, n_channels))
    elif n_channels == 0:
        raise FormatError(
            path, "motion rows given but the hierarchy has no channels", line=first_line
        )
    else:
        data = _parse_plain_decimals(body, n_channels)
        if data is None:  # exponents, nan, odd spacing...: the general parser
            try:
                data = np.loadtxt(io.StringIO(body), dtype=np.float64, comments=None, ndmin=2)
            except (ValueError, TypeError, OverflowError):
                raise _diagnose_rows(path, rest, first_line, n_frames, n_channels) from None
    if n_channels == 0:
        # frames without channels are empty lines (as write_bvh writes them): the count
        # is held to the lines the file has, never trusted to size arrays on its own
        if n_frames > len(rest):
            raise FormatError(
                path,
                f"'Frames: {n_frames}' declared but the hierarchy has no channels and only "
                f"{len(rest)} lines follow",
                line=frames_line,
            )
        data = np.zeros((n_frames, 0))
    if data.shape != (n_frames, n_channels) or not np.isfinite(data).all():
        raise _diagnose_rows(path, rest, first_line, n_frames, n_channels)
    return data, frame_time, time_tok


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
    scale = None if units is None else _bvh_unit_scale(units)
    if position_channels not in ("auto", "replace", "add"):
        raise ValidationError(
            f"position_channels: expected 'auto', 'replace' or 'add', got {position_channels!r}"
        )
    up_key = str(up).strip().lower().lstrip("+")
    if up_key not in ("auto", "y", "z"):
        raise ValidationError(f"up: expected 'auto', 'y' or 'z', got {up!r}")
    p = check_readable(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise FormatError(p, f"cannot read: {exc.strerror or exc}") from None
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

    # column bookkeeping: (joint, axis, column) of position channels; per rotation
    # sequence the joints and their columns
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

    if position_mode == "auto":
        position_mode = _position_mode(parents, offsets, pos_joint, pos_axis, data[:, pos_col])
    translations = np.repeat(offsets[None], t, axis=0)  # (T, J, 3) file units
    if pos_col and position_mode == "add":
        translations[:, pos_joint, pos_axis] += data[:, pos_col]
    elif pos_col:
        translations[:, pos_joint, pos_axis] = data[:, pos_col]
    rotations = np.zeros((t, len(joints), 4))
    rotations[..., 3] = 1.0
    for seq, (ks, cols) in rot_groups.items():
        angles = data[:, np.asarray(cols)]  # (T, k, len(seq)) degrees
        rotations[:, ks] = euler_to_quat(angles, seq, degrees=True)

    if up == "auto":
        up = guess_bvh_up(_rest_extent(parents, offsets))
        if up == "z":
            warnings.warn(
                f"{os.fspath(p)}: up axis not given; the rest pose stands along z, read as "
                "Z-up (pass up='y' to override)",
                UnitWarning,
                stacklevel=3,
            )
    guessed = scale is None
    if units is not None and scale is not None:
        unit_name = units.strip().lower()
    else:
        height = _skeleton_height(parents, offsets)
        unit_name = guess_bvh_units(height)
        scale = BVH_UNITS[unit_name]
        metres = height * scale
        note = ""
        if not _PLAUSIBLE_HEIGHT[0] <= metres <= _PLAUSIBLE_HEIGHT[1]:
            note = "; no unit gives a plausible human height, pass units= to be sure"
        warnings.warn(
            f"{os.fspath(p)}: units not given; guessed {unit_name!r} from a skeleton {height:.4g} units tall "
            f"({metres:.3g} m){note}",
            UnitWarning,
            stacklevel=3,
        )
    offsets = to_y_up(offsets * scale, up)
    translations *= scale
    translations = to_y_up(translations, up)
    if up != "y":
        c = matrix_to_quat(up_rotation(up))  # file frame -> Y-up
        rotations = quat_multiply(quat_multiply(c, rotations), quat_conjugate(c))
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
        },
    )


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


# ------------------------------------------------------------------------- writer
def _dfs_order(parents: np.ndarray) -> list[int]:
    children: list[list[int]] = [[] for _ in range(parents.size)]
    roots = []
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
    unit = units if units is not None else str(motion.meta.get("source_units", "cm"))
    scale = _bvh_unit_scale(unit, "units" if units is not None else "motion.meta['source_units']")
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

    sk = motion.skeleton
    names = sk.names
    for name in names:
        if not name or _BAD_NAME_RE.search(name):
            raise ValidationError(
                f"skeleton.names: {name!r} cannot be written to BVH (no tabs, newlines, braces, "
                "leading/trailing or double spaces)"
            )
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
        c = matrix_to_quat(up_rotation(up_key))
        rotations = quat_multiply(quat_multiply(quat_conjugate(c), rotations), c)
    t = motion.n_frames

    height = _skeleton_height(parents, offsets)
    if precision is None:
        len_dec = 6 if height <= 0 else max(6, math.ceil(-math.log10(1e-7 * height)))
        ang_dec = 6
    else:
        len_dec = ang_dec = int(precision)

    # channel columns, joints in depth-first order
    order = _dfs_order(parents)
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
    for seq, (ks, cols) in rot_groups.items():
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
        data[:, np.asarray(cols)] = angles

    frame_time = float(motion.meta.get("frame_time", 1.0 / motion.rate))
    if (
        not (math.isfinite(frame_time) and frame_time > 0)
        or abs(frame_time * motion.rate - 1.0) > 1e-9
    ):
        frame_time = 1.0 / motion.rate
    time_text = motion.meta.get("frame_time_text")
    if not isinstance(time_text, str) or _float_or_none(time_text) != frame_time:
        time_text = repr(frame_time)

    out: list[str] = ["HIERARCHY"]
    _write_hierarchy(out, sk, channels, offsets, is_end, len_dec)
    out.append("MOTION")
    out.append(f"Frames: {t}")
    out.append(f"Frame Time: {time_text}")
    if n_cols:
        data += 0.0  # no "-0.000000" for exact negative zeros
        row = " ".join(f"%.{d}f" for d in decimals)
        out.extend(row % tuple(values) for values in data.tolist())
    elif t:
        out.extend([""] * t)
    text = "\n".join(out) + "\n"
    with atomic_output(path, force=force) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)


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
    roots = []
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
