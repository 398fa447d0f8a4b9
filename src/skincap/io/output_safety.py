"""Output-path safety: no command may overwrite, replace or delete one of its own inputs.

One mechanism serves every verb and every file it writes (main output and every
sidecar):

* :func:`guard_outputs` registers the inputs of the running command and checks every
  output it is about to write *before anything is written*, so a refusal leaves
  nothing behind (``skin -o x.pc2`` checks ``x.pc2`` and ``x.obj`` together);
* :func:`~skincap.io._common.atomic_output`, through which every writer goes, checks
  its target again against the registered inputs at the moment it writes — a sidecar
  a verb forgot to list is still refused.

An output is refused when it is an input (same resolved path, through symbolic
links), a hard link to an input (same ``(st_dev, st_ino)``), another output of the
same command, a folder where a file is written, or a dangling symbolic link (it is
refused rather than silently replaced: the user meant the link to point somewhere).
An existing output is replaced only with ``force``.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import shutil
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from skincap.errors import FormatError, OutputExistsError

__all__ = [
    "FileIdentity",
    "file_identity",
    "guard_outputs",
    "protect_inputs",
    "protected_inputs",
    "check_output",
    "check_outputs",
    "check_output_folder",
    "is_protected_input",
]


@dataclass(frozen=True)
class FileIdentity:
    """What makes two paths the same file: the resolved path and, if it exists, the inode."""

    given: Path
    resolved: Path
    inode: tuple[int, int] | None  # (st_dev, st_ino), None when nothing is there

    def same_file(self, other: FileIdentity) -> bool:
        """True when both name one file: same resolved path or same device and inode."""
        if self.resolved == other.resolved:
            return True
        return self.inode is not None and self.inode == other.inode


def file_identity(path: str | os.PathLike[str]) -> FileIdentity:
    """The :class:`FileIdentity` of ``path`` (symbolic links followed; the path may not exist)."""
    p = Path(path)
    resolved = Path(os.path.realpath(os.path.abspath(p)))
    try:
        st = os.stat(p)  # follows links: a link to an input has the input's inode
    except OSError:
        inode = None
    else:
        inode = (st.st_dev, st.st_ino)
    return FileIdentity(p, resolved, inode)


_INPUTS: contextvars.ContextVar[tuple[FileIdentity, ...]] = contextvars.ContextVar(
    "skincap_protected_inputs", default=()
)


def protected_inputs() -> tuple[FileIdentity, ...]:
    """The inputs registered by the enclosing :func:`protect_inputs` blocks."""
    return _INPUTS.get()


@contextlib.contextmanager
def protect_inputs(inputs: Iterable[str | os.PathLike[str] | None]) -> Iterator[None]:
    """Register ``inputs`` (None entries skipped) as files no write may touch in this block.

    Blocks nest: the inputs of an outer block stay protected inside an inner one. A
    folder input protects every file under it (a new file may still be written into
    it: that modifies no input).
    """
    added: list[FileIdentity] = []
    for path in inputs:
        if path is None:
            continue
        added.append(file_identity(path))
        if os.path.isdir(path):
            for root, _, names in os.walk(path):
                added.extend(file_identity(os.path.join(root, name)) for name in names)
    token = _INPUTS.set(_INPUTS.get() + tuple(added))
    try:
        yield
    finally:
        _INPUTS.reset(token)


def _input_holding(target: FileIdentity) -> FileIdentity | None:
    """The registered input that ``target`` is (through any link), if any."""
    return next((source for source in _INPUTS.get() if source.same_file(target)), None)


def is_protected_input(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is an input registered with :func:`protect_inputs` (or a link to one)."""
    return _input_holding(file_identity(path)) is not None


def check_output(path: str | os.PathLike[str], *, force: bool = False) -> Path:
    """Refuse ``path`` as a file output unless writing it is safe; return it as a Path.

    Raises
    ------
    FormatError
        ``path`` is a registered input (also through a symbolic or hard link), a
        dangling symbolic link, or a folder.
    OutputExistsError
        ``path`` exists and ``force`` is False.
    """
    target = Path(path)
    identity = file_identity(target)
    source = _input_holding(identity)
    if source is not None:
        how = "is" if source.resolved == identity.resolved else "is a hard link to"
        if target.is_symlink() or source.given.is_symlink():
            how = "is a symbolic link to" if target.is_symlink() else "is, through a link,"
        raise FormatError(
            target, f"output {how} the input {str(source.given)!r}; inputs are never modified"
        )
    _refuse_dangling_link(target, "file")
    if target.is_dir():
        raise FormatError(target, "output is a folder, expected a file")
    if target.exists() and not force:
        raise OutputExistsError(target)
    return target


def _refuse_dangling_link(path: Path, kind: str) -> None:
    """FormatError when ``path`` is a symbolic link to nothing (replacing it would hide that)."""
    if path.is_symlink() and not path.exists():
        raise FormatError(
            path,
            f"output is a symbolic link to a missing {kind} ({os.readlink(path)!r}); "
            "remove the link or choose another output",
        )


def check_outputs(paths: Iterable[str | os.PathLike[str]], *, force: bool = False) -> list[Path]:
    """:func:`check_output` on every path, and refuse two outputs that are one file."""
    checked: list[Path] = []
    seen: list[FileIdentity] = []
    for path in paths:
        target = check_output(path, force=force)
        identity = file_identity(target)
        for other in seen:
            if other.same_file(identity):
                raise FormatError(
                    target, f"is also the output {str(other.given)!r}; give two different files"
                )
        seen.append(identity)
        checked.append(target)
    return checked


def check_output_folder(path: str | os.PathLike[str]) -> Path:
    """Refuse ``path`` as an output folder when it is an input file, a file or a dangling link."""
    folder = Path(path)
    identity = file_identity(folder)
    source = next((s for s in _INPUTS.get() if s.same_file(identity)), None)
    if source is not None and not folder.is_dir():
        raise FormatError(
            folder, f"output folder is the input {str(source.given)!r}; inputs are never modified"
        )
    _refuse_dangling_link(folder, "folder")
    if folder.exists() and not folder.is_dir():
        raise FormatError(folder, "exists and is not a folder")
    return folder


@contextlib.contextmanager
def guard_outputs(
    inputs: Iterable[str | os.PathLike[str] | None],
    outputs: Iterable[str | os.PathLike[str]] = (),
    *,
    folders: Iterable[str | os.PathLike[str]] = (),
    force: bool = False,
) -> Iterator[None]:
    """Protect ``inputs`` for the block; check ``outputs`` and ``folders`` before it runs.

    Every file the block writes through :func:`~skincap.io._common.atomic_output` is
    checked again when written, so no input is replaced even by an output the caller
    did not list. A folder of ``folders`` that did not exist before the block and
    the block made is removed again, with what it holds, when the block fails: a
    command that stops half-way leaves nothing behind.

    Example
    -------
    >>> with guard_outputs([mesh_path, motion_path], [out_pc2, out_pc2.with_suffix(".obj")],
    ...                    force=False):   # doctest: +SKIP
    ...     write_everything()
    """
    with protect_inputs(inputs):
        made = [Path(folder) for folder in folders]
        for folder in made:
            check_output_folder(folder)
        for target in check_outputs(outputs, force=force):
            _refuse_missing_parent(target, made)
        new = [folder for folder in made if not os.path.lexists(folder)]
        try:
            yield
        except BaseException:  # Ctrl-C too: no half-written folder stays
            for folder in new:
                if folder.is_dir() and not folder.is_symlink():
                    shutil.rmtree(folder, ignore_errors=True)
            raise


def _refuse_missing_parent(target: Path, made: list[Path]) -> None:
    """FormatError when ``target``'s folder does not exist and the block will not make it.

    Checked before the block runs, so a verb with several outputs never writes the
    first ones and then fails on a later one whose folder is missing.
    """
    parent = target.parent
    if parent.is_dir():
        return
    if any(parent.absolute().is_relative_to(folder.absolute()) for folder in made):
        return
    raise FormatError(target, f"cannot write: folder {str(parent)!r} does not exist")
