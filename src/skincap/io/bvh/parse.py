"""The BVH text parsers: the ``HIERARCHY`` block into joints, the ``MOTION`` rows into an array."""

from __future__ import annotations

import io
import math
import os
import re
from typing import Any

import numpy as np

from skincap.errors import FormatError, quote_excerpt
from skincap.types import POSITION_CHANNELS, ROTATION_CHANNELS

_CHANNEL_NAMES = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}
_AXIS = {"X": 0, "Y": 1, "Z": 2}
_FRAMES_RE = re.compile(r"^\s*Frames\s*:\s*(\S+)\s*$")
_FRAME_TIME_RE = re.compile(r"^\s*Frame\s+Time\s*:\s*(\S+)\s*$")
_MOTION_RE = re.compile(r"^[ \t]*MOTION[ \t\r]*$", re.MULTILINE)
#: Frame Time bounds (s): 1e-7 s is the 10 MHz ceiling the C3D reader allows for a rate;
#: a frame longer than an hour is no motion capture (and 1e-300 would make the rate 1e300).
MIN_FRAME_TIME_S = 1e-7
MAX_FRAME_TIME_S = 3600.0
#: The largest magnitude of an OFFSET or channel value: 1e9 is 1000 km in millimetres or
#: 2.8 million turns in degrees; past it a value is corruption, and 1e308 overflows to
#: inf once scaled to metres or posed (the error would then name an output, not the BVH).
MAX_BVH_VALUE = 1e9
_BAD_NAME_RE = re.compile(r"(^\s|\s$|[\t\r\n\v\f{}]|\s\s)")


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
        if abs(value) > MAX_BVH_VALUE:
            raise self.error(
                f"{what}: {tok[:40]!r} is beyond +-{MAX_BVH_VALUE:g}, not a plausible value", line
            )
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
            next_word = tok.peek()
            if next_word is None:
                raise tok.error(
                    f"file ends inside joint {joints[stack[-1]].name!r} (opened on line {joints[stack[-1]].line}); missing '}}' or MOTION"
                )
            word = next_word
    if not joints:
        first = tok.peek()
        raise tok.error(
            "expected ROOT after HIERARCHY" + (f", found {quote_excerpt(first)}" if first else "")
        )
    if tok.peek() is not None:
        raise tok.error(f"unexpected {tok.peek()!r} after the hierarchy; expected ROOT or MOTION")
    # End sites: "<parent>_end", made unique against every joint name.
    # Each base resumes its search after its last suffix: searching from 1 every time
    # took O(n^2) steps for n end sites of one joint (200,000: over 10 minutes). Same
    # names as that search, as the suffixes of one base are handed out in order.
    taken = {j.name for j in joints if not j.is_end}
    next_k: dict[str, int] = {}
    for j in joints:
        if j.is_end:
            base = f"{j.name}_end"
            k = next_k.get(base, 1)
            name = base if k == 1 else f"{base}_{k}"
            while name in taken:
                k += 1
                name = f"{base}_{k}"
            next_k[base] = k + 1
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

    def header_number(
        regex: re.Pattern[str], what: str, kind: type[int] | type[float], expected: str
    ) -> tuple[Any, str, int]:
        """The header line's number as ``kind``, its text and its line number."""
        token, number = header_line(regex, what)
        try:
            return kind(token), token, number
        except ValueError:
            name = what.split(":")[0]
            raise FormatError(
                path, f"{name}: expected {expected}, found {token!r}", line=number
            ) from None

    n_frames, _, frames_line = header_number(_FRAMES_RE, "Frames: <count>", int, "a whole number")
    if n_frames < 0:
        raise FormatError(path, f"Frames: must not be negative, found {n_frames}", line=frames_line)
    frame_time, time_tok, time_line = header_number(
        _FRAME_TIME_RE, "Frame Time: <seconds>", float, "seconds"
    )
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise FormatError(
            path,
            f"Frame Time: must be a positive number of seconds, found {time_tok!r}",
            line=time_line,
        )
    if not MIN_FRAME_TIME_S <= frame_time <= MAX_FRAME_TIME_S:
        raise FormatError(
            path,
            f"Frame Time: {time_tok[:40]!r} s is outside {MIN_FRAME_TIME_S:g}..{MAX_FRAME_TIME_S:g} s",
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
        plain = _parse_plain_decimals(body, n_channels)
        if plain is not None:
            data = plain
        else:  # exponents, nan, odd spacing...: the general parser
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
    huge = np.abs(data) > MAX_BVH_VALUE
    if huge.any():
        row, col = (int(k) for k in np.argwhere(huge)[0])
        row_lines = [first_line + i for i, ln in enumerate(rest) if ln.split()]
        raise FormatError(
            path,
            f"motion row {row + 1}, value {col + 1}: {data[row, col]:.6g} is beyond "
            f"+-{MAX_BVH_VALUE:g}, not a plausible channel value",
            line=row_lines[row],
        )
    return data, frame_time, time_tok
