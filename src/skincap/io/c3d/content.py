"""What a C3D carries besides its marker trajectories, kept to be written back unchanged.

:func:`skincap.io.c3d.read_c3d` puts one :class:`C3dContent` in ``meta["c3d"]``:
every parameter group with every parameter (type, dimensions, values, description,
lock flag, file order), the analog samples as stored (before ``SCALE``, ``OFFSET`` and
``GEN_SCALE``), and the header's event block. :func:`skincap.io.c3d.write_c3d`
writes all of it back; the POINT parameters that describe the points (labels, units,
scale, rate, frames) are rewritten from the MarkerSet.

The object is immutable (its arrays are read-only), so a MarkerSet whose ``meta`` is
copied along a pipeline (``clean``) carries the same content; it stays valid as long
as the frame count is unchanged (the analog samples are aligned with the point
frames, ``analog_ratio`` samples per frame).

Text rule (both ways): parameter strings are written as UTF-8; on reading, each
string is decoded as UTF-8 when it is valid UTF-8, else as Latin-1 (old files). The
carried parameters keep their bytes, so text skincap does not change goes out
byte for byte.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincap.errors import SkincapWarning

__all__ = [
    "C3dContent",
    "C3dGroup",
    "C3dParameter",
    "HeaderEvents",
    "decode_text",
    "warn_dropped_c3d_content",
]

#: C3D parameter data types: CHAR, BYTE, INT, FLOAT -> bytes per value.
TYPE_SIZES = {-1: 1, 1: 1, 2: 2, 4: 4}
_INTEL_DTYPES = {1: "<i1", 2: "<i2", 4: "<f4"}


def decode_text(raw: bytes) -> str:
    """C3D text -> str: UTF-8 when valid, else Latin-1; cut at the first NUL, trailing
    blanks removed."""
    # writers in C end a fixed-width string with a NUL and may leave whatever was in
    # memory after it; those bytes are not text (kept, a NUL reached the TRC and CSV
    # writers, whose own readers then refused the file as binary)
    raw = raw.split(b"\x00", 1)[0].rstrip(b" ")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class C3dParameter:
    """One parameter record, values in Intel byte order.

    Attributes
    ----------
    name : str
        ASCII, as written in the file (readers match names in any case).
    type : int
        -1 CHAR, 1 BYTE, 2 INT (int16), 4 FLOAT (float32).
    dims : tuple of int
        The record's dimensions (each 0..255); ``()`` for a scalar. For CHAR the first
        is the string width in bytes.
    raw : bytes
        ``prod(dims) * size`` bytes: CHAR bytes as in the file, numbers little-endian.
    description : bytes
    locked : bool
    """

    name: str
    type: int
    dims: tuple[int, ...]
    raw: bytes
    description: bytes = b""
    locked: bool = False

    def value_equals(self, other: C3dParameter) -> bool:
        """Same decoded values (strings compared without trailing blanks; dims may differ)."""
        a, b = self.value, other.value
        if isinstance(a, list) or isinstance(b, list):
            return a == b
        return bool(np.array_equal(np.ravel(a), np.ravel(b)))

    @property
    def value(self) -> list[str] | np.ndarray:
        """Decoded values: a list of str for CHAR, else an (F-ordered) float64/int64 array."""
        if self.type == -1:
            if not self.dims:
                return [decode_text(self.raw)]
            width = self.dims[0]
            count = int(np.prod(self.dims[1:])) if len(self.dims) > 1 else 1
            return [decode_text(self.raw[i * width : (i + 1) * width]) for i in range(count)]
        a = np.frombuffer(self.raw, dtype=_INTEL_DTYPES[self.type])
        a = a.astype(np.float64 if self.type == 4 else np.int64)
        return a.reshape(self.dims, order="F") if self.dims else a


@dataclass(frozen=True)
class C3dGroup:
    """A parameter group: name, description, lock flag and parameters in file order."""

    name: str
    description: bytes = b""
    locked: bool = False
    parameters: tuple[C3dParameter, ...] = ()

    def get(self, name: str) -> C3dParameter | None:
        """The parameter called ``name`` (any case), or None."""
        name = name.upper()
        for p in self.parameters:
            if p.name.upper() == name:
                return p
        return None


@dataclass(frozen=True)
class HeaderEvents:
    """The header's event block (up to 18 time events), as stored.

    Attributes
    ----------
    count : int
        Number of events in use (0..18).
    times : (18,) float64, seconds
    display : bytes
        18 display flags (0 on, 1 off).
    labels : bytes
        18 four-character labels, 72 bytes.
    label_range_present : int
        The header's key word for a label/range section (12345 when present).
    label_range_block : int
        First block of that section.
    """

    count: int
    times: np.ndarray
    display: bytes
    labels: bytes
    label_range_present: int = 0
    label_range_block: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "times", _frozen(np.asarray(self.times, dtype=np.float64)))

    def label_list(self) -> list[str]:
        return [decode_text(self.labels[4 * i : 4 * i + 4]) for i in range(self.count)]


@dataclass(frozen=True)
class C3dContent:
    """Everything of a C3D that skincap carries through unchanged.

    Attributes
    ----------
    groups : tuple of C3dGroup
        Every parameter group of the file, in file order (POINT included: the writer
        replaces the parameters that describe the points and keeps the others).
    analogs : (C, S) float64
        Analog samples as stored (``S = n_frames * analog_ratio``), before
        ``(value - OFFSET) * SCALE * GEN_SCALE``; C = ``ANALOG:USED``.
    analog_ratio : int
        Analog samples per point frame (0 when there are no analog channels).
    n_frames : int
        Point frames the analogs are aligned with.
    first_frame : int
        The header's first frame number.
    events : HeaderEvents or None
    processor : str
        Of the source file ("intel", "dec" or "mips"); skincap writes Intel.
    """

    groups: tuple[C3dGroup, ...]
    analogs: np.ndarray
    analog_ratio: int
    n_frames: int
    first_frame: int
    events: HeaderEvents | None = None
    processor: str = "intel"
    _index: dict[str, int] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "analogs", _frozen(np.asarray(self.analogs, dtype=np.float64)))
        object.__setattr__(self, "_index", {g.name.upper(): i for i, g in enumerate(self.groups)})

    def group(self, name: str) -> C3dGroup | None:
        """The group called ``name`` (any case), or None."""
        i = self._index.get(name.upper())
        return None if i is None else self.groups[i]

    def parameter(self, group: str, name: str) -> C3dParameter | None:
        g = self.group(group)
        return None if g is None else g.get(name)

    @property
    def n_analog_channels(self) -> int:
        return int(self.analogs.shape[0])

    def analog_labels(self) -> list[str]:
        out: list[str] = []
        k = 1
        while True:
            p = self.parameter("ANALOG", "LABELS" + (str(k) if k > 1 else ""))
            if p is None or p.type != -1:
                break
            out.extend(p.value)
            k += 1
        return out[: self.n_analog_channels]

    def n_force_plates(self) -> int:
        p = self.parameter("FORCE_PLATFORM", "USED")
        if p is None or p.type == -1 or not len(p.raw):
            return 0
        return max(int(np.asarray(p.value).ravel()[0]), 0)

    def n_parameter_events(self) -> int:
        p = self.parameter("EVENT", "USED")
        if p is None or p.type == -1 or not len(p.raw):
            return 0
        return max(int(np.asarray(p.value).ravel()[0]), 0)

    def describe(self) -> str:
        """What this carries beyond the points, in words (empty when nothing)."""
        parts = []
        if self.n_analog_channels:
            parts.append(f"{self.n_analog_channels} analog channels")
        if self.n_force_plates():
            parts.append(f"{self.n_force_plates()} force plates")
        n_ev = self.n_parameter_events() + (self.events.count if self.events else 0)
        if n_ev:
            parts.append(f"{n_ev} events")
        # counted above, or the writers' own signature; a group whose USED is 0 is empty
        skip = ("POINT", "ANALOG", "FORCE_PLATFORM", "EVENT", "EVENT_CONTEXT", "EZC3D", "SKINCAP")
        others = [g.name for g in self.groups if g.name.upper() not in skip and not _unused(g)]
        if others:
            parts.append("parameter groups " + ", ".join(others))
        return "; ".join(parts)


def _unused(group: C3dGroup) -> bool:
    """A group declaring ``USED`` = 0 (ANALYSIS, ROTATION with nothing in them)."""
    p = group.get("USED")
    return p is not None and p.type in (1, 2) and len(p.raw) > 0 and p.value.ravel()[0] == 0  # type: ignore[union-attr]


def warn_dropped_c3d_content(
    meta: dict[str, Any],
    fmt: str,
    path: Any,
    stacklevel: int,
    *,
    camera_masks: np.ndarray | None = None,
    residuals: np.ndarray | None = None,
) -> None:
    """A SkincapWarning naming what a C3D source carried that ``fmt`` cannot hold.

    ``camera_masks`` (T, N) and ``residuals`` (T, N) metres are the MarkerSet's:
    the samples with a camera bit are counted, and a C3D source's residuals are
    named when any is above 0 (a TRC or CSV source has none to lose).
    """
    content = meta.get("c3d") if isinstance(meta, dict) else None
    parts = []
    if camera_masks is not None:
        seen = int(np.count_nonzero(np.asarray(camera_masks)))
        if seen:
            parts.append(f"camera masks of {seen:,} samples")
    if isinstance(content, C3dContent) and residuals is not None:
        r = np.asarray(residuals, dtype=np.float64)
        if bool(np.any(r[np.isfinite(r)] > 0)):
            parts.append("residuals")
    if isinstance(content, C3dContent):
        what = content.describe()
        if what:
            parts.append(what)
    if parts:
        warnings.warn(
            f"{path}: {fmt} holds marker trajectories only; not written: {'; '.join(parts)} "
            "(write a .c3d to keep them)",
            SkincapWarning,
            stacklevel=stacklevel + 1,
        )
