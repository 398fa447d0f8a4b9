"""Many takes through one workflow each, on a Dask scheduler.

:func:`run_batch` expands the inputs (files, folders, globs), names every take after
its input, skips the takes whose outputs all exist (resume; ``force`` redoes them),
and runs the others as one task each: on local worker processes (the default), on an
existing cluster (``scheduler="tcp://host:port"``) or one after another in this
process (``scheduler="synchronous"``). A task gets only the input's path, the
verb's name and the options, reads its own file in the worker and hands back one row
(status, seconds, outputs, the one-line error, the key figures), so no array passes
through the scheduler. A take that fails is a row with its error; the others go on.
The rows are written to ``OUT/batch.json`` and ``OUT/batch.csv``.
"""

from __future__ import annotations

import contextlib
import csv
import glob
import io
import json
import os
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skincap.batch.verbs import BatchVerb, batch_verb
from skincap.errors import (
    FormatError,
    MissingDependencyError,
    SkincapError,
    SkincapWarning,
    ValidationError,
    one_line,
)

__all__ = [
    "SUMMARY_NAMES",
    "BatchResult",
    "Take",
    "collect_inputs",
    "name_takes",
    "plan_takes",
    "run_batch",
    "run_take",
]

#: The batch's own files in the output folder (rewritten by every run: the last run's rows).
SUMMARY_NAMES = ("batch.json", "batch.csv")

#: ``progress(takes_finished, takes_total, row)``: called once before the first take
#: (``row`` None) and once per finished take.
BatchProgress = Callable[[int, int, "dict[str, Any] | None"], None]

_GLOB_CHARS = frozenset("*?[")


@dataclass(frozen=True)
class Take:
    """One input file of a batch and where its outputs go.

    Attributes
    ----------
    input : Path
        The input file, as found.
    name : str
        Its name under the output folder (a relative POSIX path without the suffix).
    outputs : tuple of Path
        Every file the take writes.
    """

    input: Path
    name: str
    outputs: tuple[Path, ...]

    def done(self) -> bool:
        """True when every output exists (a previous run finished this take)."""
        return all(p.exists() for p in self.outputs)


@dataclass
class BatchResult:
    """What :func:`run_batch` did: one row per take, in input order.

    Attributes
    ----------
    rows : list of dict
        ``input``, ``name``, ``status`` (``done``, ``skipped``: done by an earlier run,
        ``failed``: a bad input or option, ``crashed``: an unexpected error,
        ``cancelled``), ``seconds`` (wall) and ``cpu_seconds`` of the task,
        ``outputs``, ``error`` (the one-line error), ``warnings``, ``figures``.
    summary_files : list of Path
        ``batch.json`` and ``batch.csv``.
    """

    verb: str
    rows: list[dict[str, Any]]
    summary_files: list[Path] = field(default_factory=list)

    def count(self, status: str) -> int:
        """Takes with ``status``."""
        return sum(row["status"] == status for row in self.rows)

    @property
    def exit_status(self) -> int:
        """0 when every take succeeded (or was done already), 2 when an input was bad, 1 when a
        take crashed on an unexpected error (a bug worth reporting)."""
        if self.count("crashed"):
            return 1
        return 2 if self.count("failed") or self.count("cancelled") else 0


# ------------------------------------------------------------------ the inputs
def collect_inputs(
    inputs: Iterable[str | os.PathLike[str]],
    suffixes: Sequence[str],
    *,
    exclude: str | os.PathLike[str] | None = None,
) -> list[Path]:
    """The input files a batch runs: files as given, a folder's files, a glob's matches.

    Parameters
    ----------
    inputs : iterable of path-like
        Files (any extension: the workflow judges them), folders (their files with one
        of ``suffixes``, not recursive) and glob patterns (``**`` recursive).
    suffixes : sequence of str
        Lower-case extensions taken from folders and globs.
    exclude : path-like, optional
        A folder whose files a folder or a glob never yields (the batch's output
        folder, so a re-run does not take its own outputs as inputs).

    Returns
    -------
    list of Path
        In the order given (a folder's and a glob's files sorted), each file once.

    Raises
    ------
    FormatError
        An input that is not a file, a folder or a pattern with matches; a folder or a
        pattern without takes.
    """
    wanted = {s.lower() for s in suffixes}
    skip = None if exclude is None else Path(os.path.realpath(exclude))
    found: list[Path] = []
    seen: set[str] = set()
    skipped = 0

    def keep(path: Path, explicit: bool) -> None:
        nonlocal skipped
        real = os.path.realpath(path)
        if not explicit and skip is not None and Path(real).is_relative_to(skip):
            skipped += 1
            return
        if real not in seen:
            seen.add(real)
            found.append(path)

    for item in inputs:
        path = Path(item)
        if path.is_file():
            keep(path, True)
        elif path.is_dir():
            files = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in wanted)
            if not files:
                raise FormatError(path, f"folder holds no takes ({', '.join(sorted(wanted))})")
            for p in files:
                keep(p, False)
        elif _GLOB_CHARS & set(str(item)):
            matches = sorted(
                Path(m)
                for m in glob.glob(os.fspath(item), recursive=True)
                if os.path.isfile(m) and Path(m).suffix.lower() in wanted
            )
            if not matches:
                raise FormatError(path, "no takes match this pattern")
            for p in matches:
                keep(p, False)
        elif os.path.lexists(path):
            raise FormatError(path, "not a file or a folder")
        else:
            raise FormatError(path, "no such file or folder")
    if not found:
        why = (
            f": all {skipped} lie in the output folder {exclude}, whose files are never inputs"
            if skipped
            else ""
        )
        raise ValidationError(f"inputs: no takes to run{why}")
    return found


def name_takes(paths: Sequence[Path]) -> list[str]:
    """A name per input for its outputs: its path below the inputs' common folder,
    without the suffix (``a/take.c3d``, ``b/take.c3d`` -> ``a/take``, ``b/take``).

    Two inputs that differ only by suffix keep it, as ``_<ext>`` (``take_c3d``,
    ``take_trc``), so no two takes write the same file.
    """
    real = [Path(os.path.realpath(p)) for p in paths]
    common = Path(os.path.commonpath([p.parent for p in real]))
    names = [p.relative_to(common).with_suffix("").as_posix() for p in real]
    counts: dict[str, int] = {}
    for n in names:
        counts[n] = counts.get(n, 0) + 1
    return [
        f"{n}_{p.suffix.lstrip('.').lower()}" if counts[n] > 1 and p.suffix else n
        for n, p in zip(names, real, strict=True)
    ]


def plan_takes(
    verb: BatchVerb, inputs: Sequence[Path], out_dir: Path, options: Mapping[str, Any]
) -> list[Take]:
    """The :class:`Take` of every input: its name and outputs under ``out_dir``.

    Raises
    ------
    FormatError
        Two takes would write one file, or a take would write the batch's own summary
        files or one of the inputs (inputs are never modified).
    """
    from skincap.io.output_safety import file_identity, is_protected_input, protect_inputs

    takes = [
        Take(src, name, tuple(verb.plan(out_dir, name, options).outputs))
        for src, name in zip(inputs, name_takes(inputs), strict=True)
    ]
    reserved = {file_identity(out_dir / n).resolved for n in SUMMARY_NAMES}
    owner: dict[Path, Path] = {}
    with protect_inputs(inputs):
        for take in takes:
            for out in take.outputs:
                resolved = file_identity(out).resolved
                if resolved in reserved:
                    raise FormatError(
                        take.input, f"its output {str(out)!r} is the batch's own summary; rename it"
                    )
                if resolved in owner:
                    raise FormatError(
                        take.input, f"writes {str(out)!r}, as {str(owner[resolved])!r} does"
                    )
                if is_protected_input(out):
                    raise FormatError(
                        out, f"output of {str(take.input)!r} is an input; inputs are never modified"
                    )
                owner[resolved] = take.input
    return takes


# ------------------------------------------------------------------- one take
def _error_line(exc: BaseException, src: str) -> str:
    """The CLI's one-line error for ``exc``: ``<file>: <what is wrong>``."""
    if isinstance(exc, OSError):
        name = exc.filename if exc.filename is not None else exc.filename2
        what = exc.strerror or str(exc)
        return one_line(f"{os.fsdecode(name) if name is not None else src}: {what}")
    if isinstance(exc, MemoryError):
        return one_line(f"{src}: not enough memory: {exc or 'an allocation failed'}")
    text = str(exc)
    if getattr(exc, "path", None) is None and not isinstance(exc, MissingDependencyError):
        if not text.startswith(f"{src}:"):
            text = f"{src}: {text}"
    return one_line(text)


def run_take(
    verb_name: str,
    src: str,
    name: str,
    out_dir: str,
    options: Mapping[str, Any],
    force: bool,
) -> dict[str, Any]:
    """Run one take in this process (a Dask task); return its row, never raise for bad input.

    Parameters
    ----------
    verb_name : str
        A key of :data:`skincap.batch.verbs.BATCH_VERBS`.
    src : str
        The input file (read here, in the worker).
    name : str
        The take's name under ``out_dir``.
    out_dir : str
        The batch's output folder.
    options : mapping
        The workflow's keyword options (and the verb's batch options).
    force : bool
        Replace existing outputs.

    Returns
    -------
    dict
        The row: ``input``, ``name``, ``status`` (``done``, ``failed`` on a skincap,
        OS or memory error, ``crashed`` on any other exception, with its
        ``traceback``), ``seconds`` (wall),
        ``cpu_seconds``, ``outputs``, ``error`` (one line or None), ``warnings`` (each
        distinct one once), ``figures``, ``worker`` (host and process id).
    """
    import socket

    verb = batch_verb(verb_name)
    row: dict[str, Any] = {"input": src, "name": name, "status": "done", "error": None}
    wall, cpu = time.perf_counter(), time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SkincapWarning)
        try:
            plan = verb.plan(Path(out_dir), name, options)
            args, kwargs = plan.call(options, Path(src))
            summary = verb.workflow_function()(*args, force=force, **kwargs)
            row["outputs"] = [str(p) for p in plan.outputs if p.exists()]
            row["figures"] = verb.figures(summary)
        except (SkincapError, OSError, MemoryError) as exc:
            row.update(status="failed", error=_error_line(exc, src))
        except Exception as exc:  # noqa: BLE001 - a bug in one take must not stop the batch
            import traceback

            row.update(
                status="crashed",
                error=one_line(f"{src}: {type(exc).__name__}: {exc}"),
                traceback=traceback.format_exc(),  # for a bug report (batch.json only)
            )
    shown: list[str] = []
    for w in caught:
        text = one_line(str(w.message))
        if issubclass(w.category, SkincapWarning) and text not in shown:
            shown.append(text)
    row.update(
        seconds=round(time.perf_counter() - wall, 3),
        cpu_seconds=round(time.process_time() - cpu, 3),
        warnings=shown,
        worker=f"{socket.gethostname()}:{os.getpid()}",
    )
    row.setdefault("outputs", [])
    row.setdefault("figures", {})
    return row


# ----------------------------------------------------------------- schedulers
def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise MissingDependencyError("dask[distributed]", "batch", "skincap batch") from None
    return distributed


@contextlib.contextmanager
def _client(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A distributed Client: a new local cluster of ``workers`` processes (one thread each)
    or the existing scheduler at ``scheduler``."""
    distributed = _import_distributed()
    import logging

    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise FormatError(
                scheduler, f"cannot reach the Dask scheduler: {one_line(str(exc))}"
            ) from None
        with client:
            yield client
        return
    # one thread per worker: the workflows are CPU-bound NumPy/numba and the nanny pins
    # each worker's BLAS to one thread, so N workers use N cores
    # numba's parallel kernels (skinning, dense) share the cores among the workers too
    threads = max(1, (os.cpu_count() or 1) // max(1, workers or 1))
    import dask

    with warnings.catch_warnings(), dask.config.set(_QUIET_WORKERS):
        # no dashboard; the scheduler's small HTTP server moves to a free port, say nothing
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        cluster = distributed.LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
            env={"NUMBA_NUM_THREADS": str(threads)},
        )
    with cluster, distributed.Client(cluster) as client:
        yield client


#: Dask settings of the local cluster's workers: no statistical profiler (it samples the
#: task's stack every 10 ms) and slower memory and system monitors, so a worker's own
#: threads take little CPU from the takes on a machine with as many workers as cores.
_QUIET_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.tick.interval": "200ms",
}


def _check_scheduler(scheduler: str | None) -> None:
    if scheduler in (None, "local", "synchronous"):
        return
    if "://" not in str(scheduler):
        raise FormatError(
            "--scheduler",
            f"expected tcp://host:port of a Dask scheduler or 'synchronous', got {scheduler!r}",
        )


def _check_workers(workers: int | None, scheduler: str | None) -> int | None:
    if workers is not None and scheduler not in (None, "synchronous", "local"):
        raise FormatError("--workers", "the cluster at --scheduler has its own workers")
    if workers is not None and not 1 <= workers <= 1024:
        raise FormatError("--workers", f"expected 1..1024, got {workers}")
    if workers is None and scheduler in (None, "local"):
        return os.cpu_count() or 1
    return workers


# --------------------------------------------------------------------- summary
def _json_safe(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, float) and value != value:  # NaN: not JSON
        return None
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return str(value)


def _previous_summary(out_dir: Path) -> dict[str, Any] | None:
    """The earlier run's ``batch.json``: None when there is none, ``{}`` when it is
    there but unreadable or not a run's summary (its options cannot be told)."""
    path = out_dir / SUMMARY_NAMES[0]
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) and "verb" in data and "options" in data else {}


def _write_summary(
    out_dir: Path, verb: str, options: Mapping[str, Any], scheduler: str, rows: list[dict[str, Any]]
) -> list[Path]:
    from skincap.io._common import atomic_output

    figure_names: list[str] = []
    for row in rows:
        figure_names += [k for k in row.get("figures", {}) if k not in figure_names]
    totals = {
        s: sum(r["status"] == s for r in rows)
        for s in ("done", "skipped", "failed", "crashed", "cancelled")
    }
    data = {
        "verb": verb,
        "options": _json_safe(dict(options)),
        "scheduler": scheduler,
        "takes": len(rows),
        "totals": totals,
        "rows": _json_safe(rows),
    }
    json_path, csv_path = (out_dir / n for n in SUMMARY_NAMES)
    # the batch's own log: each run replaces it with its rows (the takes' outputs are
    # what --force guards)
    with atomic_output(json_path, force=True) as tmp:
        tmp.write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(
        ["input", "name", "status", "seconds", "cpu_seconds", "outputs", "error", *figure_names]
    )
    for row in rows:
        figures = row.get("figures", {})
        writer.writerow(
            [
                row["input"],
                row["name"],
                row["status"],
                row.get("seconds", ""),
                row.get("cpu_seconds", ""),
                ";".join(row.get("outputs", [])),
                row.get("error") or "",
                *(_json_safe(figures.get(k, "")) for k in figure_names),
            ]
        )
    with atomic_output(csv_path, force=True) as tmp:
        tmp.write_text(buffer.getvalue(), encoding="utf-8")
    return [json_path, csv_path]


def _remove_partial_outputs(takes: Iterable[Take]) -> None:
    """Remove the temporary ``.part`` files of takes a cancelled worker left behind."""
    for take in takes:
        for out in take.outputs:
            for part in glob.glob(
                os.path.join(
                    glob.escape(os.fspath(out.parent)), f".{glob.escape(out.name)}.*.part*"
                )
            ):
                with contextlib.suppress(OSError):
                    os.unlink(part)


# ------------------------------------------------------------------------ run
def run_batch(
    verb: str,
    inputs: Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    options: Mapping[str, Any] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    progress: BatchProgress | None = None,
) -> BatchResult:
    """Run every take of ``inputs`` through ``verb``'s workflow on Dask; write the summary.

    Parameters
    ----------
    verb : str
        ``clean``, ``track``, ``solve``, ``convert``, ``skin`` or ``animate``
        (:data:`skincap.batch.verbs.BATCH_VERBS`).
    inputs : iterable of path-like
        Files, folders and glob patterns (:func:`collect_inputs`).
    out_dir : path-like
        Every take's outputs go under it, named after its input (:func:`name_takes`),
        with ``batch.json`` and ``batch.csv``. Created if missing.
    options : mapping, optional
        The workflow's keyword options, as its own function takes them (e.g.
        ``{"method": "rigid"}`` for :func:`~skincap.workflows.clean_file.clean_file`),
        plus the verb's batch options (``to``: the output extension of ``convert``,
        ``skin`` and ``animate``; ``mesh``: the body mesh of ``skin`` and ``animate``).
    workers : int, optional
        Worker processes of the local cluster (default: the core count; never more
        than the takes to run).
    scheduler : str, optional
        None or ``"local"``: a local cluster of ``workers`` processes;
        ``"synchronous"``: one take after another in this process;
        ``"tcp://host:port"``: an existing Dask cluster (its workers must import
        skincap and see the input and output paths).
    force : bool
        Redo every take, replacing its outputs; without it a take whose outputs all
        exist is skipped (resume), and one with only some of them fails (output exists).
    progress : callable(finished, total, row), optional

    Returns
    -------
    BatchResult
        One row per take, in input order (``exit_status``: 0, 2 on a bad input).

    Raises
    ------
    FormatError, ValidationError
        A bad input list, output folder or option, before any take runs.
    MissingDependencyError
        ``dask[distributed]`` is not installed (any scheduler but ``synchronous``).
    KeyboardInterrupt
        After cancelling the pending takes and writing the summary of the finished ones.
    """
    from skincap.io.output_safety import check_output_folder, protect_inputs

    spec = batch_verb(verb)
    options = dict(options or {})
    if "force" in options or "progress" in options:
        raise ValidationError("options: pass force to run_batch itself; progress is the batch's")
    _check_scheduler(scheduler)
    workers = _check_workers(workers, scheduler)
    out = Path(out_dir)
    found = collect_inputs(inputs, spec.suffixes, exclude=out)
    with protect_inputs(found):
        check_output_folder(out)
    takes = plan_takes(spec, found, out, options)
    _check_options(spec, options)
    if spec.check is not None:
        spec.check(out, options)
    previous = _previous_summary(out)
    pending = [i for i, t in enumerate(takes) if force or not t.done()]
    if not force and previous is not None and len(pending) < len(takes):
        same = previous.get("verb") == verb and previous.get("options") == _json_safe(options)
        if not previous:  # a damaged summary: the outputs' options cannot be checked
            raise FormatError(
                out / SUMMARY_NAMES[0],
                "not a batch summary skincap can read, so the options that made the outputs "
                "beside it are unknown; pass --force to redo every take, or use another folder",
            )
        if not same:
            raise FormatError(
                out / SUMMARY_NAMES[0],
                f"these outputs were made by 'batch {previous.get('verb')}' with other options "
                f"({previous.get('options')}); pass --force to redo every take, or use another folder",
            )
    if scheduler != "synchronous":
        _import_distributed()  # the one-line MissingDependencyError before anything is made
    with contextlib.ExitStack() as stack:
        # the cluster first: a scheduler that cannot be reached leaves nothing behind
        client = None
        local = scheduler in (None, "local")
        # never more worker processes than takes to run: each costs a start and imports
        started = min(workers, len(pending)) if local and workers is not None else workers
        if pending and scheduler != "synchronous":
            client = stack.enter_context(_client(None if local else scheduler, started))
        return _run_planned(
            spec,
            takes,
            pending,
            out,
            options,
            force,
            previous,
            client,
            scheduler,
            started,
            progress,
        )


def _run_planned(
    spec: BatchVerb,
    takes: list[Take],
    pending: list[int],
    out: Path,
    options: Mapping[str, Any],
    force: bool,
    previous: Mapping[str, Any] | None,
    client: Any,
    scheduler: str | None,
    workers: int | None,
    progress: BatchProgress | None,
) -> BatchResult:
    """Make the output folders, run the ``pending`` takes, write the summary (see :func:`run_batch`)."""
    verb = spec.name
    out.mkdir(parents=True, exist_ok=True)
    for i in pending:  # a take's workflow writes into an existing folder only
        for path in takes[i].outputs:
            path.parent.mkdir(parents=True, exist_ok=True)
    if pending and spec.kernels:
        from skincap.backends import start_pending_compiles

        # once per machine and numba cache (a lock beside the cache), not once per take:
        # here, and on the workers of a cluster elsewhere, which have caches of their own
        start_pending_compiles(spec.kernels)
        if client is not None and scheduler not in (None, "local"):
            with contextlib.suppress(Exception):  # a worker that cannot compile runs NumPy
                client.run(start_pending_compiles, spec.kernels)
    old_rows = {r.get("input"): r for r in (previous or {}).get("rows", []) if isinstance(r, dict)}
    rows: dict[int, dict[str, Any]] = {}
    for i in sorted(set(range(len(takes))) - set(pending)):
        take, old = takes[i], old_rows.get(str(takes[i].input), {})
        rows[i] = {
            "input": str(take.input),
            "name": take.name,
            "status": "skipped",
            "error": None,
            "outputs": [str(p) for p in take.outputs],
            "figures": old.get("figures", {}) if old.get("status") in ("done", "skipped") else {},
            "warnings": [],
        }
    finished = len(rows)
    if progress is not None:
        progress(finished, len(takes), None)

    def record(i: int, row: dict[str, Any]) -> None:
        nonlocal finished
        rows[i] = row
        finished += 1
        if progress is not None:
            progress(finished, len(takes), row)

    scheduler_name = scheduler or f"local:{workers}"
    try:
        if client is None:
            _run_synchronous(spec, takes, pending, out, options, force, record)
        else:
            _run_distributed(spec, takes, pending, out, options, force, record, client)
    except BaseException:  # Ctrl-C, SIGTERM: keep the finished takes' rows
        for i in pending:
            rows.setdefault(
                i,
                {"input": str(takes[i].input), "name": takes[i].name, "status": "cancelled",
                 "error": None, "outputs": [], "figures": {}, "warnings": []},
            )  # fmt: skip
        _remove_partial_outputs(takes[i] for i in pending if rows[i]["status"] == "cancelled")
        with contextlib.suppress(Exception):
            _write_summary(out, verb, options, scheduler_name, [rows[i] for i in range(len(takes))])
        raise
    ordered = [rows[i] for i in range(len(takes))]
    files = _write_summary(out, verb, options, scheduler_name, ordered)
    return BatchResult(verb, ordered, files)


def _check_options(spec: BatchVerb, options: Mapping[str, Any]) -> None:
    """Refuse an option the workflow does not take, before any take runs."""
    import inspect

    params = inspect.signature(spec.workflow_function()).parameters
    taken = {n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    unknown = sorted(set(options) - taken - set(spec.batch_options))
    placed = {"report", "force", "progress", "notify"}
    if unknown or set(options) & placed:
        bad = unknown or sorted(set(options) & placed)
        choices = sorted((taken - placed) | set(spec.batch_options))
        raise ValidationError(
            f"options: batch {spec.name} does not take {', '.join(bad)}; it takes {', '.join(choices)}"
        )


def _task_args(
    spec: BatchVerb, take: Take, out: Path, options: Mapping[str, Any], force: bool
) -> tuple[str, str, str, str, dict[str, Any], bool]:
    """:func:`run_take`'s arguments for one take, as plain values a worker can unpickle."""
    return (spec.name, str(take.input), take.name, str(out), dict(options), force)


def _run_synchronous(
    spec: BatchVerb,
    takes: list[Take],
    pending: list[int],
    out: Path,
    options: Mapping[str, Any],
    force: bool,
    record: Callable[[int, dict[str, Any]], None],
) -> None:
    """Each take through dask's synchronous scheduler, in this process, in order."""
    dask: Any
    try:
        import dask
    except ImportError:  # the synchronous path needs no cluster: plain calls do the same
        dask = None
    for i in pending:
        args = _task_args(spec, takes[i], out, options, force)
        if dask is None:
            row = run_take(*args)
        else:
            row = dask.delayed(run_take, pure=False)(*args).compute(scheduler="synchronous")
        record(i, row)


def _run_distributed(
    spec: BatchVerb,
    takes: list[Take],
    pending: list[int],
    out: Path,
    options: Mapping[str, Any],
    force: bool,
    record: Callable[[int, dict[str, Any]], None],
    client: Any,
) -> None:
    """One task per take on a distributed cluster; rows recorded as tasks finish."""
    distributed = _import_distributed()
    futures = {}
    for i in pending:
        future = client.submit(
            run_take,
            *_task_args(spec, takes[i], out, options, force),
            key=f"skincap-{spec.name}-{i}-{os.getpid()}-{time.time_ns()}",
            pure=False,
        )
        futures[future] = i
    try:
        for future in distributed.as_completed(futures):
            i = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # noqa: BLE001 - the worker died (killed, out of memory)
                row = {
                    "input": str(takes[i].input), "name": takes[i].name, "status": "crashed",
                    "error": one_line(f"{takes[i].input}: the worker running it died "
                                      f"({type(exc).__name__}: {exc})"),
                    "outputs": [], "figures": {}, "warnings": [],
                }  # fmt: skip
            record(i, row)
    except BaseException:
        client.cancel(list(futures), force=True)
        raise
