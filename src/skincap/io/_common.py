"""Shared plumbing of the readers and writers: atomic output, units, axes, input checks."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from skincap.errors import FormatError, ValidationError

if TYPE_CHECKING:
    from skincap.types import MeshAnimation

__all__ = [
    "UNIT_TO_METRES",
    "unit_scale",
    "atomic_output",
    "check_readable",
    "to_y_up",
    "from_y_up",
    "UP_AXES",
    "up_rotation",
    "finite_frame_chunks",
    "read_file_bytes",
    "read_utf8_text",
]

#: Length units skincap reads and writes, as metres per unit. ``cmu`` is the length
#: unit of the Carnegie Mellon ASF/BVH exports (1/0.45 inch), common in the wild.
UNIT_TO_METRES: dict[str, float] = {
    "m": 1.0,
    "dm": 0.1,
    "cm": 0.01,
    "mm": 0.001,
    "in": 0.0254,
    "cmu": 0.0254 / 0.45,
}

#: Up axes a source file may use; skincap is Y-up inside.
UP_AXES = ("y", "z")


def unit_scale(unit: str, *, argument: str = "units", format_name: str = "") -> float:
    """Metres per ``unit`` (a key of :data:`UNIT_TO_METRES`, any case and spacing).

    An unknown unit (or not a string) raises ValidationError naming ``argument``, and
    the format when ``format_name`` is given (``"unknown BVH length unit 'furlong'"``).
    """
    if not isinstance(unit, str) or unit.strip().lower() not in UNIT_TO_METRES:
        kind = f"{format_name} " if format_name else ""
        raise ValidationError(
            f"{argument}: unknown {kind}length unit {unit!r}, "
            f"expected one of {sorted(UNIT_TO_METRES)}"
        )
    return UNIT_TO_METRES[unit.strip().lower()]


# A Z-up right-handed frame becomes Y-up by a -90 degree turn about X:
# (x, y, z) -> (x, z, -y). Its inverse is (x, y, z) -> (x, -z, y).
_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _check_up(up: str) -> str:
    key = up.strip().lower().lstrip("+")
    if key not in UP_AXES:
        raise ValidationError(f"up: expected one of {UP_AXES}, got {up!r}")
    return key


def up_rotation(up: str) -> np.ndarray:
    """(3, 3) rotation taking coordinates with ``up`` as up axis to skincap's Y-up."""
    return _Z_UP_TO_Y_UP.copy() if _check_up(up) == "z" else np.eye(3)


def to_y_up(points: np.ndarray, up: str) -> np.ndarray:
    """(..., 3) points in a frame with ``up`` as up axis -> Y-up (NaN preserved)."""
    if _check_up(up) == "y":
        return np.array(points, dtype=np.float64, copy=True)
    p = np.asarray(points, dtype=np.float64)
    return np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)


def from_y_up(points: np.ndarray, up: str) -> np.ndarray:
    """(..., 3) Y-up points -> a frame with ``up`` as up axis (inverse of :func:`to_y_up`)."""
    if _check_up(up) == "y":
        return np.array(points, dtype=np.float64, copy=True)
    p = np.asarray(points, dtype=np.float64)
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def check_readable(path: str | os.PathLike[str]) -> Path:
    """Return ``path`` as a Path after checking it is an existing, non-empty file."""
    p = Path(path)
    if not p.exists():
        raise FormatError(p, "no such file")
    if p.is_dir():
        raise FormatError(p, "is a directory, expected a file")
    if p.stat().st_size == 0:
        raise FormatError(p, "file is empty")
    return p


def read_file_bytes(path: Path, *, what: str = "") -> bytes:
    """The bytes of ``path``; an OS error becomes the house one-line format error.

    Parameters
    ----------
    path : Path
        Checked by the caller (e.g. :func:`check_readable`) where that matters.
    what : str
        Names the file in the message: ``cannot read the name map: ...`` for
        ``what="the name map"``; empty: ``cannot read: ...``.

    Raises
    ------
    FormatError
        The file cannot be read (permissions, a folder, an I/O error), with the
        operating system's reason.
    """
    try:
        return path.read_bytes()
    except OSError as exc:
        label = f"cannot read {what}" if what else "cannot read"
        raise FormatError(path, f"{label}: {exc.strerror or exc}") from None


def read_utf8_text(path: Path) -> str:
    """The text of the UTF-8 file ``path`` (universal newlines, as ``Path.read_text``).

    Raises
    ------
    FormatError
        The bytes are not UTF-8, naming the byte offset of the first bad byte. An
        OSError (permissions, a folder) passes through for the CLI to report.
    """
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not UTF-8 text (byte {exc.start})", offset=exc.start) from None


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], *, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is left untouched,
    so a failed write never leaves a partial or corrupted output.

    The target is checked by :func:`skincap.io.output_safety.check_output` first:
    it must not be an input of the running command (registered with
    :func:`~skincap.io.output_safety.protect_inputs`; symbolic and hard links
    included), a dangling symbolic link or a folder.

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``force`` is False.
    FormatError
        The target folder does not exist; the target is a protected input, a dangling
        link or a folder.
    """
    from skincap.io.output_safety import check_output

    target = check_output(path, force=force)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise FormatError(target, f"cannot write: folder {str(folder)!r} does not exist")
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.name}.", suffix=".part" + target.suffix, dir=folder
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give the output the permissions a
        # plain open() would (0666 less the umask).
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def finite_frame_chunks(
    animation: MeshAnimation, chunk: int, *, missing_note: str = ""
) -> Iterator[tuple[int, np.ndarray]]:
    """The animation's frames in chunks, each checked before a writer stores it.

    A writer of vertex caches (PC2, USD, OBJ sequences) states ``n_frames`` up front
    and cannot store a missing point, so a chunk that runs past ``n_frames`` or holds
    a NaN or infinite coordinate stops the write.

    Parameters
    ----------
    animation : MeshAnimation
        Its ``n_frames`` (0 when None) is the count the file promises.
    chunk : int
        Frames per chunk (:meth:`MeshAnimation.iter_chunks`).
    missing_note : str
        Appended to the message about a non-finite frame (e.g. why the format
        cannot store it).

    Yields
    ------
    first : int
        Frame number of the chunk's first frame.
    block : (t, V, 3) float
        The chunk's vertex positions, all finite.

    Raises
    ------
    ValidationError
        The animation yields more frames than ``n_frames``, or a frame has a NaN or
        infinite coordinate (named by its frame number).
    """
    n_frames = int(animation.n_frames or 0)
    done = 0
    for block in animation.iter_chunks(int(chunk)):
        if done + block.shape[0] > n_frames:
            raise ValidationError(
                f"frames: the animation yields more than its n_frames={n_frames} frames"
            )
        if not np.isfinite(block).all():
            bad = int(np.nonzero(~np.isfinite(block).all(axis=(1, 2)))[0][0])
            raise ValidationError(
                f"frames: frame {done + bad} has NaN or infinite positions{missing_note}"
            )
        yield done, block
        done += block.shape[0]
