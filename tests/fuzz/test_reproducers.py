"""#13 items 2 and 3: each reproducer through the real CLI in a child with limits.

Items 2 (segfaults inside ezc3d) and 3 (allocations sized by a declared count) must end
in exit 0 with a correct output or exit 2 with one line naming the file, within the
harness's memory (1 GiB) and time limits. A crash here is seen as a signal in a child,
not as a dead test run. The last tests check the harness itself.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cli_fuzz_cases import bvh_deep_chain  # noqa: E402
from cli_fuzz_harness import Outcome, judge, run_cli, run_skincap_process  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"

# (name, file, {byte offset: new value}, words the one-line error must contain)
C3D_REPRODUCERS = [
    ("cmu_point_rate_as_char", "cmu_85_02.c3d", {4926: 0xFF}, ["'RATE'", "CHAR with no dimensions"]),
    ("cmu_data_start_as_char", "cmu_85_02.c3d", {4897: 0xFF}, ["'DATA_START'", "CHAR"]),
    ("kt_byte_568", "kt_optitrack_walking.c3d", {568: 0xFF}, ["'DATA_START'", "CHAR"]),
    ("kt_point_used_as_char", "kt_optitrack_walking.c3d", {534: 0xFF}, ["'USED'", "CHAR"]),
    ("pyomeca_event_contexts_0_dims", "pyomeca_markers_analogs.c3d", {14005: 0}, ["'CONTEXTS'"]),
]  # fmt: skip


def _c3d(tmp_path: Path, name: str, source: str, edits: dict[int, int]) -> Path:
    data = bytearray((DATA / source).read_bytes())
    for at, value in edits.items():
        data[at] = value
    p = tmp_path / f"{name}.c3d"
    p.write_bytes(bytes(data))
    return p


def _analog_rate(tmp_path: Path, rate: float) -> Path:
    data = bytearray((DATA / "pyomeca_markers_analogs.c3d").read_bytes())
    assert struct.unpack_from("<f", data, 7863)[0] == 2000.0  # ANALOG:RATE
    data[7863:7867] = struct.pack("<f", rate)
    p = tmp_path / f"analog_rate_{rate:g}.c3d"
    p.write_bytes(bytes(data))
    return p


def _refused(outcome: Outcome, path: Path, words: list[str]) -> None:
    verdict = judge(outcome, inputs=[path])
    assert verdict.violations == [], verdict.violations
    assert verdict.outcome == "refused"
    (line,) = outcome.stderr_lines
    assert line.startswith(f"skincap: error: {path}: ")
    for w in words:
        assert w in line


@pytest.mark.parametrize("name, source, edits, words", C3D_REPRODUCERS)
def test_c3d_ezc3d_segfault_reproducers_give_one_line(tmp_path, name, source, edits, words):
    p = _c3d(tmp_path, name, source, edits)
    _refused(run_cli(["info", str(p)]), p, words)
    out = tmp_path / "out.trc"
    outcome = run_cli(["convert", str(p), str(out)])
    assert judge(outcome, inputs=[p], output=out).outcome == "refused"


@pytest.mark.parametrize(
    "rate, words",
    [
        (1e9, ["ANALOG:RATE is 1e+09", "not a rate in 0..1e+07 Hz"]),
        # in range, but 10,000 analog subframes a frame: the data section cannot hold them
        (1e6, ["frames of", "need", "the file has 2250816"]),
        (float("nan"), ["ANALOG:RATE is nan"]),
    ],
)
def test_c3d_analog_rate_sized_allocation_is_refused(tmp_path, rate, words):
    """#13: ANALOG:RATE = 1e9 ran 35 s and 6.8 GB in ezc3d before being refused."""
    p = _analog_rate(tmp_path, rate)
    _refused(run_cli(["info", str(p)]), p, words)


def test_c3d_checks_are_what_keeps_ezc3d_from_crashing(tmp_path, monkeypatch):
    """Without the checks the first reproducer kills the CLI (ezc3d 1.7.2): the harness
    sees the signal, and the checks are what prevents it."""
    import skincap.io.c3d.reader

    p = _c3d(tmp_path, *C3D_REPRODUCERS[0][:3])
    monkeypatch.setattr(skincap.io.c3d.reader, "check_before_ezc3d", lambda path, data: None)
    outcome = run_cli(["info", str(p)])  # the child inherits the patched module
    verdict = judge(outcome, inputs=[p])
    assert verdict.outcome == "signal", (verdict, outcome.stderr[-500:])
    assert "SIGSEGV at skincap/io/c3d/reader.py:" in verdict.violations[0]  # the call into ezc3d


def test_mhw_vertex_index_2_pow_31_and_5e7(tmp_path):
    """#13: 2**31 asked for 2.17 TiB (5e7: 51.8 GiB) and died with a traceback."""
    weights = json.loads((DATA / "makehuman_default_weights.mhw").read_text())
    bone = next(iter(weights["weights"]))
    weights["weights"][bone][0][0] = 2**31
    big = tmp_path / "w31.mhw"
    big.write_text(json.dumps(weights))
    _refused(run_cli(["info", str(big)]), big, ["vertex index 2147483648"])
    weights["weights"][bone][0][0] = 50_000_000
    far = tmp_path / "w5e7.mhw"
    far.write_text(json.dumps(weights))
    outcome = run_cli(["info", "--json", str(far)])
    assert judge(outcome, inputs=[far]).violations == []
    assert json.loads(outcome.stdout)["max_vertex"] == 50_000_000


@pytest.mark.slow
def test_bvh_100000_deep_chain_converts(tmp_path):
    """#13: written with one tab per level the output grew as N² (~20 GB, MemoryError)."""
    src = tmp_path / "deep.bvh"
    src.write_bytes(bvh_deep_chain(100_000))
    out = tmp_path / "out" / "deep_out.bvh"
    out.parent.mkdir()
    outcome = run_cli(
        ["convert", str(src), str(out), "--units", "m"], memory_bytes=2 << 30, timeout_s=300
    )
    verdict = judge(
        outcome, inputs=[src], output=out, read_back=False, out_dir=out.parent, files_before=set()
    )
    assert verdict.violations == [] and verdict.outcome == "ok"
    assert out.stat().st_size < 8 * src.stat().st_size  # linear in the depth
    lines = out.read_text().splitlines()
    assert sum(ln.lstrip().startswith("JOINT") for ln in lines) == 99_999


@pytest.mark.slow
def test_reproducers_in_a_fresh_skincap_process(tmp_path):
    """The same refusals from the installed console script, not a fork."""
    cases = [
        (_c3d(tmp_path, *C3D_REPRODUCERS[0][:3]), "CHAR with no dimensions"),
        (_analog_rate(tmp_path, 1e9), "ANALOG:RATE"),
    ]
    for path, word in cases:
        outcome = run_skincap_process(["info", str(path)])
        verdict = judge(outcome, inputs=[path])
        assert verdict.violations == [] and verdict.outcome == "refused", outcome.stderr
        assert word in outcome.stderr_lines[0]


# ------------------------------------------------------------------- the harness
def test_harness_kills_a_hang_at_its_time_limit(tmp_path, monkeypatch):
    """A reader that never returns: the child is killed at the limit."""
    import time

    import skincap.io

    p = tmp_path / "x.c3d"
    p.write_bytes(b"\0" * 600)
    monkeypatch.setattr(skincap.io, "read", lambda path, **options: time.sleep(600))
    outcome = run_cli(["info", str(p)], timeout_s=2.0)
    assert outcome.timed_out and outcome.exit_code is None
    verdict = judge(outcome, inputs=[p])
    assert verdict.outcome == "timeout"
    # the stack faulthandler wrote before the kill names where it hung
    assert "at skincap/cli.py:" in verdict.violations[0]


def test_harness_enforces_its_memory_limit(tmp_path, monkeypatch):
    """A child asking for more than its limit gets MemoryError, which the judge reports."""
    import skincap.io

    def greedy(path, **options):
        return bytearray(2 << 30)

    p = tmp_path / "x.c3d"
    p.write_bytes(b"\0" * 600)
    monkeypatch.setattr(skincap.io, "read", greedy)
    outcome = run_cli(["info", str(p)], memory_bytes=256 << 20)
    assert judge(outcome, inputs=[p]).outcome == "memory", outcome.stderr[-300:]


@pytest.mark.parametrize(
    "code, stderr, kind",
    [
        (2, "skincap: error: a.c3d: bad\n", "refused"),
        (2, "skincap: error: a.c3d: bad\nskincap: error: a.c3d: again\n", "message"),
        (2, "skincap: error: something is wrong\n", "message"),
        (2, "x\nskincap: error: a.c3d: bad\n", "message"),
        (1, "Traceback (most recent call last):\n  ...\nValueError: x\n", "traceback"),
        (0, "skincap: warning: a.c3d: guessed mm\n", "ok"),
        (0, "/x/y.py:3: RuntimeWarning: overflow\n  a = b * c\n", "message"),
        (3, "", "exit"),
    ],
)
def test_judge_holds_the_contract(code, stderr, kind):
    outcome = Outcome(["info", "a.c3d"], code, None, False, 0.1, "", stderr)
    assert judge(outcome, inputs=[Path("a.c3d")]).outcome == kind


def test_judge_sees_partial_outputs(tmp_path):
    out = tmp_path / "o.trc"
    out.write_text("half")
    outcome = Outcome(["convert"], 2, None, False, 0.1, "", "skincap: error: a.c3d: bad\n")
    verdict = judge(outcome, inputs=[Path("a.c3d")], output=out)
    assert verdict.outcome == "partial"
    (tmp_path / ".o.trc.x1.part").write_text("")
    out.unlink()
    verdict = judge(
        outcome, inputs=[Path("a.c3d")], output=out, out_dir=tmp_path, files_before=set()
    )
    assert verdict.outcome == "partial"
