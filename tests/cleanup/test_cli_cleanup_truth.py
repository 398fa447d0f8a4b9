"""``skincap clean --fragment-truth`` (wrong-merge counts from a CLI run) and ``skincap bench clean``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cleanup_takes import dense_jumprope_take
from typer.testing import CliRunner

from skincap.cli import app
from skincap.io import write


def run(*args: object):  # noqa: ANN201
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def take_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, str]]:
    take = dense_jumprope_take()
    root = tmp_path_factory.mktemp("clean_truth")
    path = root / "capture.c3d"
    write(take.capture, path)
    truth = root / "fragments.csv"
    rows = "".join(f"{k},{v}\n" for k, v in take.fragment_truth.items())
    truth.write_text("fragment,truth\n" + rows, encoding="utf-8")
    return path, truth, take.fragment_truth


def test_clean_counts_wrong_merges_against_the_truth(take_files, tmp_path: Path) -> None:  # noqa: ANN001
    src, truth, mapping = take_files
    report = tmp_path / "r.json"
    res = run("clean", src, "-o", tmp_path / "c.c3d", "--report", report, "--fragment-truth", truth)
    assert res.exit_code == 0, res.output
    data = json.loads(report.read_text())
    merge = data["merge"]
    assert merge["wrongly_merged"] is not None and merge["wrong_rate"] <= 0.01
    assert "wrongly merged" in " ".join(res.output.split())
    # a recovered hidden marker U<n> stands for its first fragment's true marker
    truth = dict(mapping)
    truth.update({new: mapping[frags[0]] for new, frags in data["hidden"]["markers"].items()})
    assert data["hidden"]["wrong_markers"] == 0
    wrong = [f for f, lab in merge["assignments"].items() if mapping[f.split("[")[0]] != truth[lab]]
    assert len(wrong) == merge["wrongly_merged"]


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("", "empty"),
        ("fragment,truth\n", "no fragment rows"),
        ("fragment,truth\n*1\n", "line 2"),
        (b"\xff\xfe", "UTF-8"),
    ],
)
def test_bad_fragment_truth_files(take_files, tmp_path: Path, text, what: str) -> None:  # noqa: ANN001
    src, _, _ = take_files
    bad = tmp_path / "bad.csv"
    if isinstance(text, bytes):
        bad.write_bytes(text)
    else:
        bad.write_text(text, encoding="utf-8")
    res = run("clean", src, "-o", tmp_path / "c.c3d", "--fragment-truth", bad)
    assert res.exit_code == 2
    assert what in res.output and not (tmp_path / "c.c3d").exists()


def test_bench_clean_small() -> None:
    res = run("bench", "clean", "--markers", "30", "--frames", "40,80", "--json")
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)["rows"]
    assert [r["frames"] for r in rows] == [40, 80] and all(r["clean_s"] > 0 for r in rows)
    assert run("bench", "clean", "--methods", "nope").exit_code == 2


def test_clean_and_eval_fill_take_a_rigid_blend(take_files, tmp_path: Path) -> None:  # noqa: ANN001
    src, _, _ = take_files
    report = tmp_path / "r.json"
    res = run("clean", src, "-o", tmp_path / "c.c3d", "--report", report, "--rigid-blend", 0)
    assert res.exit_code == 0, res.output
    assert json.loads(report.read_text())["fill"]["rigid_blend"] == 0.0
    bad = run("clean", src, "-o", tmp_path / "d.c3d", "--rigid-blend", 2)
    assert bad.exit_code == 2 and "--rigid-blend" in bad.output
    res = run(
        "eval", "fill", src, "-o", tmp_path / "ev", "--methods", "local_pca", "--gaps", 1,
        "--gap-lengths", 20, "--rigid-blend", 0.5,
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "ev" / "fill_eval.json").read_text())["rigid_blend"] == 0.5
