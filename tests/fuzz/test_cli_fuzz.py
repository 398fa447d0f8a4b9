"""The CLI fuzz test (#13): mutated inputs of every format through the real CLI.

Each case runs ``skincap`` in a forked child with a memory limit (RLIMIT_AS, 1 GiB
above the test process) and a wall-clock limit, and must end in exit 0 with an output
``skincap info`` reads back, or exit 2 with one line naming the file, nothing written,
the input untouched: never a signal, a timeout, a traceback, a MemoryError or a
partial file. The budget is fixed and derandomised (seed 0, the same cases on every
run; ``SKINCAP_FUZZ_CASES=N`` changes the count); ``tests/fuzz/cli_fuzz_run.py --long``
runs thousands for a developer.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cli_fuzz_cases import FORMATS  # noqa: E402
from cli_fuzz_run import (  # noqa: E402
    CI_CASES,
    CI_DEFAULT_CASES,
    FormatReport,
    prepare,
    run_formats,
)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fuzz_reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, FormatReport]:
    """Every format's fixed budget, run once in two worker processes (two cores)."""
    work = tmp_path_factory.mktemp("cli_fuzz")
    fixtures = prepare(work)
    n = int(os.environ.get("SKINCAP_FUZZ_CASES", "0"))
    budget = {f: n or CI_CASES.get(f, CI_DEFAULT_CASES) for f in FORMATS}
    return run_formats(budget, 0, fixtures, work, workers=2)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_cli_holds_its_contract_on_mutated_inputs(
    fuzz_reports: dict[str, FormatReport], fmt: str
) -> None:
    report = fuzz_reports[fmt]
    n = int(os.environ.get("SKINCAP_FUZZ_CASES", "0")) or CI_CASES.get(fmt, CI_DEFAULT_CASES)
    assert not report.findings, f"{len(report.findings)} broken:\n" + "\n".join(report.findings)
    assert report.cases == n
    # the mutations must reach past the first check: some cases read, some are refused
    assert report.outcomes["refused"] > 0
    if fmt not in ("mhw", "mhskel", "clean", "skin"):
        assert report.outcomes["ok"] > 0
