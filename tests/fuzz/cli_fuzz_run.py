"""Run the CLI fuzz cases and report per format; also a script for long runs.

    python tests/fuzz/cli_fuzz_run.py --long                 # thousands of cases
    python tests/fuzz/cli_fuzz_run.py --format c3d --cases 500 --seed 7
    python tests/fuzz/cli_fuzz_run.py --format c3d --case 123 --keep /tmp/found

Every case that breaks the contract is kept (input, commands, outputs) under
``--keep`` with a ``README.txt`` that says how to reproduce it. Exit status 1 when any
case broke it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cli_fuzz_cases import (  # noqa: E402
    EXTENSION,
    FORMATS,
    Case,
    build_fixtures,
    make_case,
    warm_up_commands,
)  # noqa: E402
from cli_fuzz_harness import DEFAULT_MEMORY_BYTES, judge, preload, run_cli, warm_up  # noqa: E402

#: Cases per format in CI (HYPOTHESIS-like fixed budget), and in ``--long``.
CI_CASES = {"clean": 12, "skin": 8}
CI_DEFAULT_CASES = 60
LONG_CASES = {"clean": 150, "skin": 100}
LONG_DEFAULT_CASES = 1500
#: Wall-clock limit per command: the heavy verbs get longer.
TIMEOUT_S = {"clean": 90.0, "skin": 90.0}
DEFAULT_TIMEOUT_S = 20.0


@dataclass
class FormatReport:
    fmt: str
    cases: int = 0
    runs: int = 0
    outcomes: Counter = field(default_factory=Counter)
    findings: list[str] = field(default_factory=list)
    seconds: float = 0.0


def prepare(folder: Path) -> dict[str, list[Path]]:
    """Fixtures under ``folder``, and this process made ready to fork cheap children."""
    preload()
    fixtures = build_fixtures(folder / "fixtures")
    warm_up(warm_up_commands(fixtures, folder / "warm"))
    shutil.rmtree(folder / "warm", ignore_errors=True)
    return fixtures


def run_case(
    case: Case, work: Path, *, memory_bytes: int = DEFAULT_MEMORY_BYTES
) -> tuple[list[str], list[str]]:
    """Run every command of ``case`` in a fresh folder: (outcome per command, violations).

    The folder is deleted when the case held, kept for a look when it did not."""
    folder = work / f"{case.fmt}_{case.index}"
    if folder.exists():
        shutil.rmtree(folder)
    (folder / "out").mkdir(parents=True)
    src = folder / f"case.{EXTENSION[case.fmt]}"
    src.write_bytes(case.data)
    for name, data in case.companions.items():
        (folder / name).write_bytes(data)
    found, outcomes = [], []
    for k, template in enumerate(case.commands):
        output = None
        argv = []
        for a in template:
            if a == "IN":
                argv.append(str(src))
            elif a == "MESH":
                argv.append(str(folder / "small.obj"))
            elif a.startswith("OUT."):
                output = folder / "out" / f"out{k}{a[3:]}"
                argv.append(str(output))
            else:
                argv.append(a)
        before = set(p.name for p in (folder / "out").iterdir())
        outcome = run_cli(
            argv,
            cwd=folder,
            memory_bytes=memory_bytes,
            timeout_s=TIMEOUT_S.get(case.fmt, DEFAULT_TIMEOUT_S),
        )
        verdict = judge(
            outcome,
            inputs=[src],
            output=output,
            out_dir=folder / "out",
            files_before=before,
            memory_bytes=memory_bytes,
        )
        if src.read_bytes() != case.data:
            verdict.add("input", "the input file was modified")
        outcomes.append(verdict.outcome)
        for v in verdict.violations:
            found.append(f"{' '.join(['skincap', *template])}: {v}")
    if not found:
        shutil.rmtree(folder)
    return outcomes, found


def run_format(
    fmt: str,
    n_cases: int,
    seed: int,
    fixtures: dict[str, list[Path]],
    work: Path,
    *,
    first: int = 0,
    progress: bool = False,
) -> FormatReport:
    """Run cases ``first .. first + n_cases - 1`` of ``fmt``."""
    report = FormatReport(fmt)
    t0 = time.monotonic()
    for index in range(first, first + n_cases):
        case = make_case(fmt, index, seed, fixtures)
        outcomes, found = run_case(case, work)
        report.cases += 1
        report.runs += len(outcomes)
        report.outcomes.update(outcomes)
        for f in found:
            report.findings.append(
                f"[{fmt} case {index}, seed {seed}] {case.description} -> {f} "
                f"(kept in {work / f'{fmt}_{index}'})"
            )
        if progress and index % 50 == 49:
            print(
                f"  {fmt}: {index + 1 - first} cases, {len(report.findings)} findings", flush=True
            )
    report.seconds = time.monotonic() - t0
    return report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--long", action="store_true", help="thousands of cases per format")
    ap.add_argument("--cases", type=int, help="cases per format (overrides the budget)")
    ap.add_argument("--case", type=int, help="run only this case index")
    ap.add_argument("--format", action="append", choices=sorted(FORMATS), help="only these formats")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, help="folder for the cases that break the contract")
    args = ap.parse_args(argv)
    keep = args.keep or Path(tempfile.mkdtemp(prefix="skincap-fuzz-"))
    fixtures = prepare(keep)
    total_findings = 0
    print(f"fixtures and findings in {keep}")
    print(
        f"{'format':8} {'cases':>6} {'runs':>6} {'ok':>6} {'refused':>8} {'findings':>9} {'s':>7}"
    )
    for fmt in args.format or list(FORMATS):
        if args.case is not None:
            first, n = args.case, 1
        else:
            first = 0
            budget = LONG_CASES if args.long else CI_CASES
            n = args.cases or budget.get(fmt, LONG_DEFAULT_CASES if args.long else CI_DEFAULT_CASES)
        rep = run_format(fmt, n, args.seed, fixtures, keep, first=first, progress=args.long)
        total_findings += len(rep.findings)
        print(
            f"{fmt:8} {rep.cases:6d} {rep.runs:6d} {rep.outcomes['ok']:6d} "
            f"{rep.outcomes['refused']:8d} {len(rep.findings):9d} {rep.seconds:7.1f}",
            flush=True,
        )
        for f in rep.findings:
            print("   ", f, flush=True)
    return 1 if total_findings else 0


if __name__ == "__main__":
    sys.exit(main())
