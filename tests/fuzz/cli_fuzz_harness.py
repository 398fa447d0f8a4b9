"""Run the real ``skincap`` CLI on one input in a child process with limits, and judge it.

A fresh ``skincap`` process spends about a second importing; hundreds of cases per
format would take too long that way. :func:`run_cli` therefore forks the test process,
which has imported ``skincap.cli`` once: the child sets its own memory and core-dump
limits, points stdout and stderr at files, restores Python's default warning filters
(the test run turns RuntimeWarning into errors; the CLI must not see that) and runs
``skincap.cli.main()`` with the given argv; the parent waits with a wall-clock limit and
kills the child on expiry. It is the real CLI code in a separate process, so a segfault,
a runaway allocation or a hang is observed, not suffered. :func:`run_skincap_process`
runs the installed console script for a few end-to-end cases.

:func:`judge` states the contract for bad input: exit 0 with a readable output, or
exit 2 with one line ``skincap: error: <file>: <what is wrong>`` and nothing written;
never a signal, a timeout, a traceback, an allocation above the limit or a partial file.
"""

from __future__ import annotations

import faulthandler
import io
import os
import re
import resource
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

#: Memory a case may allocate above what the test process already maps (RLIMIT_AS).
DEFAULT_MEMORY_BYTES = 1 << 30
#: Largest file a case may write (RLIMIT_FSIZE; its stdout and stderr included).
MAX_FILE_BYTES = 1 << 30
#: Wall-clock limit per CLI run.
DEFAULT_TIMEOUT_S = 20.0

_ERROR_PREFIX = "skincap: error: "
_WARNING_PREFIX = "skincap: warning: "


@dataclass
class Outcome:
    """What one CLI run did."""

    argv: list[str]
    exit_code: int | None  # None when killed by a signal or the timeout
    signal: int | None
    timed_out: bool
    seconds: float
    stdout: str
    stderr: str

    @property
    def stderr_lines(self) -> list[str]:
        return [ln for ln in self.stderr.splitlines() if ln.strip()]


@dataclass
class Verdict:
    """The violations of the bad-input contract found in one case (empty: it held)."""

    violations: list[str] = field(default_factory=list)
    outcome: str = ""  # "ok", "refused" or the first violation's kind

    def add(self, kind: str, detail: str) -> None:
        if not self.violations:
            self.outcome = kind
        self.violations.append(f"{kind}: {detail}")


def _vm_size_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def _head_and_tail(f: BinaryIO, keep: int = 1 << 20) -> str:
    """A child's output, at most ``keep`` bytes of its start and of its end (a looping
    child can write gigabytes; the judge needs the first and last lines)."""
    size = f.seek(0, os.SEEK_END)
    f.seek(0)
    if size <= 2 * keep:
        return f.read().decode("utf-8", "replace")
    head = f.read(keep)
    f.seek(size - keep)
    skipped = f"\n[... {size - 2 * keep} bytes ...]\n".encode()
    return (head + skipped + f.read(keep)).decode("utf-8", "replace")


def _rss_bytes(pid: int) -> int:
    """Resident memory of a process (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * resource.getpagesize()
    except (OSError, ValueError, IndexError):
        return 0


def _child(
    argv: list[str],
    cwd: str,
    memory_bytes: int,
    out_fd: int,
    err_fd: int,
    interruptible: bool = False,
) -> int:
    """Body of the forked child: limits, clean stdio and warning filters, then the CLI.

    ``interruptible``: SIGINT raises KeyboardInterrupt, as Ctrl-C in a shell does (a
    serving verb such as ``view`` stops on it); otherwise it kills the child at once."""
    os.chdir(cwd)
    limit = _vm_size_bytes() + memory_bytes
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    # no file it writes may outgrow this: a runaway output is a SIGXFSZ, not a full disk
    resource.setrlimit(resource.RLIMIT_FSIZE, (MAX_FILE_BYTES, MAX_FILE_BYTES))
    global _RESERVE
    _RESERVE = bytearray(16 << 20)
    signal.signal(signal.SIGINT, signal.default_int_handler if interruptible else signal.SIG_DFL)
    os.dup2(out_fd, 1)
    os.dup2(err_fd, 2)
    sys.stdout = io.TextIOWrapper(open(1, "wb", closefd=False), write_through=True)
    sys.stderr = io.TextIOWrapper(open(2, "wb", closefd=False), write_through=True)
    # on a timeout the parent asks for the stack before it kills: the judge names the hang
    faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=False)
    faulthandler.enable(file=sys.stderr, all_threads=False)  # a crash's stack, to the file
    # Python's own default filters, as a user's shell would run skincap
    warnings.resetwarnings()
    warnings.simplefilter("default", DeprecationWarning, append=False)
    for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.filterwarnings("ignore", category=category, append=True)
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
    sys.argv = ["skincap", *argv]
    try:
        _cli_command()(args=argv, prog_name="skincap")
        code = 0
    except SystemExit as exc:
        if exc.code is None:
            code = 0
        elif isinstance(exc.code, int):
            code = exc.code
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except MemoryError as exc:
        # say where first, in a few bytes: printing the whole traceback may fail too
        _write_innermost_frame(exc)
        traceback.print_exc()
        code = 1
    except BaseException:  # noqa: BLE001 - the harness reports it as a traceback
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    return code


_COMMAND = None
#: Memory the child keeps in reserve and frees to report a MemoryError.
_RESERVE: bytearray | None = None


def _write_innermost_frame(exc: BaseException) -> None:
    """Write the innermost skincap frame of ``exc``'s traceback to fd 2, as a traceback
    line, with as little allocation as possible (it runs out of memory)."""
    global _RESERVE
    _RESERVE = None  # give back the headroom kept for this moment
    try:
        tb, last = exc.__traceback__, None
        while tb is not None:
            if "/skincap/" in tb.tb_frame.f_code.co_filename:
                last = tb
            tb = tb.tb_next
        if last is not None:
            code = last.tb_frame.f_code
            line = f'  File "{code.co_filename}", line {last.tb_lineno}, in {code.co_name}\n'
            os.write(2, line.encode())
    except BaseException:  # noqa: BLE001, S110 - best effort while out of memory
        pass


def _cli_command():
    """``skincap.cli.app`` as the click command typer builds on every call to ``app()``.

    Building it takes ~0.4 s (typer inspects every verb's signature); the parent builds
    it once and each child runs it, which is what ``skincap.cli.main`` does.
    """
    global _COMMAND
    if _COMMAND is None:
        import typer.main

        import skincap.cli

        _COMMAND = typer.main.get_command(skincap.cli.app)
    return _COMMAND


def preload() -> None:
    """Import, in the parent, what the verbs import lazily, so no child pays for it."""
    import importlib
    import pkgutil

    import skincap

    _cli_command()
    skip = ("viz", "viewer", "render", "batch", "evaluate", "cli_view", "cli_render", "bench")
    for mod in pkgutil.walk_packages(skincap.__path__, "skincap."):
        if not any(part in mod.name for part in skip):
            importlib.import_module(mod.name)


def warm_up(commands: list[list[str]]) -> None:
    """Run valid commands once in this process, output discarded.

    A verb's first call in a process costs 5-20 times its later calls (lazy imports,
    rich's first render, compiled regexes); forked children inherit the warm state.
    Only for trusted inputs: this runs in the test process itself.
    """
    import contextlib

    command = _cli_command()
    sink = io.StringIO()
    for argv in commands:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    command(args=argv, prog_name="skincap")
                except SystemExit:
                    pass


def run_cli(
    argv: list[str],
    *,
    cwd: str | os.PathLike[str] = ".",
    memory_bytes: int = DEFAULT_MEMORY_BYTES,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    interrupt_on: str | None = None,
) -> Outcome:
    """Run ``skincap <argv>`` in a forked child with memory and wall-clock limits.

    ``interrupt_on``: once the child's stdout holds this text, it gets SIGINT (Ctrl-C)
    and is waited for as usual: how a serving verb (``view``) is stopped."""
    _cli_command()  # built once here, inherited by every child

    with tempfile.TemporaryFile() as out_f, tempfile.TemporaryFile() as err_f:
        sys.stdout.flush()
        sys.stderr.flush()
        t0 = time.monotonic()
        pid = os.fork()
        if pid == 0:  # child: never return into the test process
            code = 70
            try:
                code = _child(
                    list(argv),
                    os.fspath(cwd),
                    memory_bytes,
                    out_f.fileno(),
                    err_f.fileno(),
                    interruptible=interrupt_on is not None,
                )
            except MemoryError as exc:  # even printing its traceback ran out of memory
                os.write(2, b"\nharness: MemoryError escaped the CLI\n")
                _write_innermost_frame(exc.__context__ or exc)
            except BaseException as exc:  # noqa: BLE001
                os.write(2, f"\nharness: {type(exc).__name__} escaped the CLI\n".encode())
            finally:
                os._exit(code)
        timed_out = False
        pause = 0.002
        # a child growing towards its limit is asked once for its stack (faulthandler),
        # so a MemoryError is reported with the place that kept allocating
        rss_alarm = _rss_bytes(os.getpid()) + 0.75 * memory_bytes
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if interrupt_on is not None and interrupt_on.encode() in os.pread(
                out_f.fileno(), 1 << 16, 0
            ):
                os.kill(pid, signal.SIGINT)
                interrupt_on = None
            if rss_alarm and _rss_bytes(pid) > rss_alarm:
                os.kill(pid, signal.SIGUSR1)
                rss_alarm = 0
            if time.monotonic() - t0 > timeout_s:
                os.kill(pid, signal.SIGUSR1)  # faulthandler writes the stack to stderr
                time.sleep(0.5)
                os.kill(pid, signal.SIGKILL)
                _, status = os.waitpid(pid, 0)
                timed_out = True
                break
            time.sleep(pause)
            pause = min(pause * 1.5, 0.05)
        seconds = time.monotonic() - t0
        stdout = _head_and_tail(out_f)
        stderr = _head_and_tail(err_f)
    sig = os.WTERMSIG(status) if os.WIFSIGNALED(status) and not timed_out else None
    code = os.WEXITSTATUS(status) if os.WIFEXITED(status) else None
    return Outcome(list(argv), code, sig, timed_out, seconds, stdout, stderr)


def run_skincap_process(
    argv: list[str],
    *,
    cwd: str | os.PathLike[str] = ".",
    memory_bytes: int = DEFAULT_MEMORY_BYTES,
    timeout_s: float = 60.0,
) -> Outcome:
    """Run the installed ``skincap`` console script (a fresh interpreter) with limits."""

    def limits() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes + (1 << 30),) * 2)
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))

    exe = Path(sys.executable).parent / "skincap"
    cmd = [str(exe), *argv] if exe.exists() else [sys.executable, "-m", "skincap", *argv]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(
            cmd, cwd=cwd, capture_output=True, timeout=timeout_s, preexec_fn=limits, check=False
        )
    except subprocess.TimeoutExpired as exc:
        return Outcome(
            list(argv), None, None, True, time.monotonic() - t0,
            (exc.stdout or b"").decode("utf-8", "replace"),
            (exc.stderr or b"").decode("utf-8", "replace"),
        )  # fmt: skip
    sig = -proc.returncode if proc.returncode < 0 else None
    return Outcome(
        list(argv),
        None if sig else proc.returncode,
        sig,
        False,
        time.monotonic() - t0,
        proc.stdout.decode("utf-8", "replace"),
        proc.stderr.decode("utf-8", "replace"),
    )


def judge(
    outcome: Outcome,
    *,
    inputs: list[Path],
    output: Path | None = None,
    out_dir: Path | None = None,
    files_before: set[str] | None = None,
    read_back: bool = True,
    memory_bytes: int = DEFAULT_MEMORY_BYTES,
) -> Verdict:
    """Hold one run to the bad-input contract.

    ``output`` is the file the command was asked to write (None for ``info``);
    ``out_dir`` with ``files_before`` lets the judge see stray temporary files.
    A successful output is read back with ``skincap info`` in another child.
    """
    v = Verdict()
    err = outcome.stderr
    if outcome.timed_out:
        v.add("timeout", f"no exit within {outcome.seconds:.1f} s{_where(err)}")
    if outcome.signal is not None:
        v.add("signal", f"{signal.Signals(outcome.signal).name}{_where(err)}")
    # the CLI reports a MemoryError as one line ("not enough memory: ..."), which is right
    # for a user but still a defect on a small hostile file: the judge counts it as memory
    memory_signs = ("MemoryError", "std::bad_alloc", "Cannot allocate memory", "not enough memory:")
    if any(sign in err for sign in memory_signs):
        v.add("memory", f"allocation above the limit: {_last_line(err)}{_where(err)}")
    if "Traceback (most recent call last)" in err:
        v.add("traceback", f"{_last_line(err)}{_where(err)}")
    if v.violations:
        return v
    lines = outcome.stderr_lines
    errors = [ln for ln in lines if ln.startswith(_ERROR_PREFIX)]
    stray = [ln for ln in lines if not ln.startswith((_ERROR_PREFIX, _WARNING_PREFIX))]
    if outcome.exit_code == 0:
        if errors:
            v.add("message", f"exit 0 with an error line: {errors[0]!r}")
        if stray:
            v.add("message", f"stderr line that is neither a warning nor an error: {stray[0]!r}")
        if output is not None:
            if not output.is_file():
                v.add("output", f"exit 0 but {output.name} was not written")
            elif read_back:
                back = run_cli(["info", str(output)], memory_bytes=memory_bytes)
                if back.exit_code != 0:
                    v.add(
                        "unreadable",
                        f"exit 0 but 'skincap info {output.name}' says {_last_line(back.stderr)!r}",
                    )
        v.outcome = v.outcome or "ok"
    elif outcome.exit_code == 2:
        if len(errors) != 1 or (lines and lines[-1] != errors[0]) or stray:
            v.add("message", f"exit 2 without exactly one error line: {lines[-3:]!r}")
        else:
            line = errors[0]
            names = {p.name for p in inputs} | ({output.name} if output is not None else set())
            if not any(n in line for n in names):
                v.add("message", f"the error line names no file of the command: {line!r}")
        if output is not None and output.exists():
            v.add("partial", f"exit 2 but {output.name} exists")
        v.outcome = v.outcome or "refused"
    else:
        v.add("exit", f"exit status {outcome.exit_code}: {_last_line(err)!r}")
    if out_dir is not None and files_before is not None:
        extra = sorted(
            set(os.listdir(out_dir)) - files_before - ({output.name} if output else set())
        )
        if extra:
            v.add("partial", f"stray files left behind: {extra[:3]}")
    return v


_FRAME_RE = re.compile(r'File "[^"]*/(skincap/[^"]+)", line (\d+),? in (\w+)')


def _where(stderr: str) -> str:
    """`` at skincap/<module>:<line> <function>``: the innermost skincap frame of the
    traceback or faulthandler stack in ``stderr`` (empty when there is none)."""
    lines = stderr.splitlines()
    if any(
        ln.startswith(("Thread 0x", "Current thread 0x", "Stack (most recent call first)"))
        for ln in lines
    ):
        frames = [m for ln in lines if (m := _FRAME_RE.search(ln))]  # most recent first
    else:
        frames = [m for ln in reversed(lines) if (m := _FRAME_RE.search(ln))]
    return f" at {frames[0][1]}:{frames[0][2]} {frames[0][3]}" if frames else ""


def _last_line(text: str) -> str:
    lines = [ln for ln in text.splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""
