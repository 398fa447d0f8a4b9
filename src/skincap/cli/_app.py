"""The ``skincap`` application: consoles, error handling, progress bars and ``main``.

Errors the user can fix (bad input, an existing output) print one line,
``skincap: error: <file>: <what is wrong>``, and exit with status 2. Warnings
(a guessed unit) print ``skincap: warning: …`` and the command goes on.
"""

from __future__ import annotations

import contextlib
import inspect
import json
import os
import re
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
import typer.core
from rich.console import Console

from skincap.errors import (
    MissingDependencyError,
    SkincapError,
    SkincapWarning,
    ValidationError,
    one_line,
)


class _OneLineUsageErrors(typer.core.TyperGroup):
    """The root command: a command line click cannot parse (a missing ``-o``, a word
    where a number goes, an unknown option) is one line, ``skincap: error: <what>
    (see '<verb> --help')``, exit 2, as every other error; not a usage text and a box."""

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:  # a typer that vendors click
            from typer._click import exceptions as click
        except ImportError:  # pragma: no cover - a typer built on click
            import click  # type: ignore[no-redef]

        try:
            code = super().main(*args, standalone_mode=False, **kwargs)
        except click.UsageError as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":  # 'skincap' alone: the help
                from typer import rich_utils

                rich_utils.rich_format_error(exc)
                sys.exit(exc.exit_code)
            ctx = exc.ctx
            hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
            err.print(
                f"skincap: error: {one_line(exc.format_message())}{hint}",
                markup=False,
                soft_wrap=True,
            )
            sys.exit(2)
        except click.ClickException as exc:
            err.print(f"skincap: error: {one_line(exc.format_message())}", markup=False)
            sys.exit(exc.exit_code)
        except typer.Abort:  # the vendored click raises typer's
            err.print("skincap: aborted", markup=False)
            sys.exit(1)
        # standalone_mode=False returns an Exit's code (130 after Ctrl-C) instead of exiting
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    name="skincap",
    help="Optical motion capture to moving human skin. Run 'skincap demo' to see it work.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    cls=_OneLineUsageErrors,
)
bench_app = typer.Typer(
    help="Benchmarks that print speed ratios against a peer measured in the same run.",
    no_args_is_help=True,
)
app.add_typer(bench_app, name="bench")
eval_app = typer.Typer(
    help="Evaluations against ground truth, as JSON and PNG plots.", no_args_is_help=True
)
app.add_typer(eval_app, name="eval")

out = Console(highlight=False)
err = Console(stderr=True, highlight=False)


def skincap_version() -> str:
    """The installed distribution's version (``skincap.__version__`` when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("skincap")
    except PackageNotFoundError:
        from skincap import __version__

        return __version__


def _print_version(value: bool) -> None:
    if value:
        print(f"skincap {skincap_version()}")
        raise typer.Exit()


@app.callback()
def _global_options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Optical motion capture to moving human skin. Run 'skincap demo' to see it work."""


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn skincap errors into one line and status 2; show each warning once, one line each.

    Warnings are collected while the verb runs and printed when it ends (before the
    error line, if any), each distinct message once.
    """
    error_line = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SkincapWarning)
        try:
            yield
        except SkincapError as exc:
            error_line = _skincap_error_line(exc)
        except OSError as exc:
            error_line = _os_error_line(exc)
        except MemoryError as exc:  # a request too large for this machine, e.g. --frames 1e8
            error_line = _memory_error_line(exc)
        finally:
            _flush_warnings(caught)
    if error_line is not None:
        _print_line(f"skincap: error: {error_line}")
        raise typer.Exit(2)


def check_seed(seed: int) -> int:
    """``--seed`` as NumPy's generators take it: a non-negative integer (else one line, exit 2)."""
    if seed < 0:
        raise ValidationError(f"--seed: expected a non-negative integer, got {seed}")
    return seed


def _print_line(text: str) -> None:
    """One line on stderr, exactly as given: no markup, emoji codes or highlighting."""
    err.print(text, markup=False, emoji=False, highlight=False, soft_wrap=True)


def _flush_warnings(caught: list[warnings.WarningMessage]) -> None:
    """Print the recorded warnings, each distinct one once, and forget them.

    Warnings from NumPy, SciPy or Python itself are printed here too, with their
    category, rather than handed back to ``warnings.showwarning``: inside
    ``catch_warnings(record=True)`` that appends to the very list being printed.
    """
    shown: set[str] = set()
    for w in caught:
        if issubclass(w.category, SkincapWarning):
            text = one_line(str(w.message))
        else:
            text = one_line(f"{w.category.__name__}: {w.message}")
        if text not in shown:
            shown.add(text)
            _print_line(f"skincap: warning: {text}")
    caught.clear()


def _skincap_error_line(exc: SkincapError) -> str:
    """``<file>: <what is wrong>`` for a skincap error, on one line.

    An error that names no file (an argument check deep in an algorithm) is prefixed
    with the input files the verb was given.
    """
    text = str(exc)
    if getattr(exc, "path", None) is None and not isinstance(exc, MissingDependencyError):
        inputs = _verb_input_files()
        if inputs and not any(text.startswith(f"{p}:") for p in inputs):
            text = f"{', '.join(inputs)}: {text}"
    return one_line(text)


def _memory_error_line(exc: MemoryError) -> str:
    """``<inputs>: not enough memory: <what NumPy could not allocate>`` on one line."""
    inputs = _verb_input_files()
    what = str(exc) or "an allocation failed"
    text = f"not enough memory: {what}"
    return one_line(f"{', '.join(inputs)}: {text}" if inputs else text)


def _os_error_line(exc: OSError) -> str:
    """``<file>: <system message>`` for an OSError, naming the path the user gave."""
    name = exc.filename if exc.filename is not None else exc.filename2
    what = exc.strerror or str(exc)
    if name is None:
        inputs = _verb_input_files()
        return one_line(f"{', '.join(inputs)}: {what}" if inputs else what)
    return one_line(f"{_path_given(os.fsdecode(name))}: {what.lower()}")


# atomic_output (skincap.io._common) writes ``<folder>/.<name>.<8 random>.part<suffix>``
# and renames it onto ``<folder>/<name>``; an error on that file is about ``<name>``.
_TEMP_OUTPUT = re.compile(r"^\.(?P<name>.+)\.[A-Za-z0-9_]{8}\.part(?P<suffix>\.[^./]*)?$")


def _path_given(filename: str) -> str:
    """The output path the user gave, when ``filename`` is atomic_output's temporary file."""
    folder, base = os.path.split(filename)
    match = _TEMP_OUTPUT.match(base)
    if match is None or not match["name"].endswith(match["suffix"] or ""):
        return filename
    return match["name"] if folder in ("", ".") else os.path.join(folder, match["name"])


def _verb_input_files() -> list[str]:
    """The existing files among the running verb's positional arguments, as given."""
    try:
        from typer._click.globals import get_current_context  # a typer that vendors click
    except ImportError:  # pragma: no cover - a typer built on click
        from click import get_current_context

    ctx = get_current_context(silent=True)
    if ctx is None:
        return []
    found: list[str] = []
    for param in ctx.command.params:
        if param.param_type_name != "argument":
            continue
        value = ctx.params.get(param.name or "")
        for item in value if isinstance(value, list | tuple) else [value]:
            if isinstance(item, Path) and item.is_file():
                found.append(str(item))
    return found


def frame_progress() -> Any:
    """A transient rich progress bar on stderr counting frames (hidden off a terminal)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} frames"),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    )


@contextlib.contextmanager
def frame_bar(description: str) -> Iterator[Callable[[float, int], None]]:
    """A :func:`frame_progress` bar fed by a workflow's ``progress(frames_done, frames)``.

    The bar appears on the first call, once the workflow knows the take's frames.
    """
    with frame_progress() as bar:
        task: Any = None

        def advance(done: float, total: int) -> None:
            nonlocal task
            if task is None:
                task = bar.add_task(description, total=total)
            bar.update(task, completed=done)

        yield advance


@contextlib.contextmanager
def stage_progress(description: str) -> Iterator[Callable[[float, str], None]]:
    """A transient bar on stderr fed by ``progress(fraction, stage label)`` (hidden off a
    terminal); it appears on the first call."""
    from rich.progress import Progress

    with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
        task: Any = None

        def progress(fraction: float, label: str) -> None:
            nonlocal task
            if task is None:
                task = bar.add_task(description, total=1.0)
            bar.update(task, completed=fraction, description=label)

        yield progress


def print_json(data: Any) -> None:
    """Print ``data`` as JSON on stdout: the machine-readable form of a verb's summary line."""
    print(json.dumps(data, indent=2, allow_nan=False, default=str))


def print_bench_results(results: dict[str, Any], json_output: bool) -> None:
    """Print a benchmark's ``lines``, or its measurements as JSON (without the lines)."""
    if json_output:
        print(json.dumps({k: v for k, v in results.items() if k != "lines"}, indent=2, default=str))
        return
    for line in results["lines"]:
        out.print(line, markup=False, soft_wrap=True)


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds like Ctrl-C so every ``.part`` file is removed."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated(signum)


def install_termination_handlers() -> None:
    """Make SIGTERM and SIGHUP raise :class:`Terminated` (a BaseException).

    Without this Python dies on them at once and a write in progress leaves its
    temporary ``.part`` file; raised as an exception, the signal unwinds through
    :func:`skincap.io._common.atomic_output`, which removes it, as SIGINT does.
    """
    import signal

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), _raise_terminated)


def _reflowed(doc: str) -> str:
    """``doc`` with each paragraph's lines joined into one.

    typer keeps a docstring's single line breaks, so text wrapped at 88 columns in the
    source broke into orphan words on an 80-column terminal. A paragraph whose later
    lines start with a space, ``- ``, ``* `` or ``| `` (a list, a table, an example block)
    keeps its breaks; so does anything after a ``\\f`` line (click's cut mark).
    """
    text, cut, rest = inspect.cleandoc(doc).partition("\f")
    paragraphs = []
    for paragraph in text.split("\n\n"):
        lines = paragraph.split("\n")
        if paragraph.startswith("\b") or any(
            line.startswith((" ", "- ", "* ", "| ")) for line in lines[1:]
        ):
            paragraphs.append(paragraph)
        else:
            paragraphs.append(" ".join(line.strip() for line in lines if line.strip()))
    return "\n\n".join(paragraphs) + cut + rest


def reflow_help(application: typer.Typer) -> None:
    """Reflow every verb's help paragraphs (:func:`_reflowed`), sub-apps included."""
    for command in application.registered_commands:
        doc = command.help or (command.callback.__doc__ if command.callback else None)
        if doc:
            command.help = _reflowed(doc)
    for group in application.registered_groups:
        if group.typer_instance is not None:
            reflow_help(group.typer_instance)


def main() -> None:
    """Console-script entry point."""
    # numba's parallel kernels pick TBB first when a system libtbb is installed (Blender's
    # packages bring one), and TBB's shutdown has spun for minutes at exit on a loaded
    # machine: OpenMP, then numba's own workqueue, first (read when numba loads, later)
    os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp workqueue tbb")
    install_termination_handlers()
    try:
        app(prog_name="skincap")  # also under 'python -m skincap' (the hints name the verb)
    except KeyboardInterrupt:
        err.print("skincap: interrupted")
        sys.exit(130)
    except Terminated as exc:
        import signal

        err.print(f"skincap: terminated by {signal.Signals(exc.signum).name}")
        sys.exit(128 + exc.signum)
