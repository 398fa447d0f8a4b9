"""``skincap batch``: real captures through ``clean`` on Dask equal ``clean`` alone, a hostile
file among them is recorded without stopping the rest, resume, ``--force``, the CLI."""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from skincap.batch import run_batch
from skincap.batch.runner import collect_inputs, name_takes
from skincap.cli import app
from skincap.errors import FormatError, MissingDependencyError, ValidationError
from skincap.workflows.clean_file import clean_file

DATA = Path(__file__).resolve().parents[1] / "data"
#: Quick real captures (Vicon/BTK/c3d.org C3D); the slow test runs every capture in tests/data.
QUICK = ("cmu_85_02.c3d", "btk_pig_calibration_hole_unlabeled_fragments.c3d")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _takes(folder: Path, names: tuple[str, ...] = QUICK) -> list[Path]:
    """Copies of real captures plus two hostile files: a truncated C3D and text named .trc."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        shutil.copyfile(DATA / name, folder / name)
    (folder / "truncated.c3d").write_bytes((DATA / "cmu_85_02.c3d").read_bytes()[:700])
    (folder / "notes.trc").write_text("this is not a TRC file\n", encoding="utf-8")
    return sorted(folder.iterdir())


def _alone(src: Path, folder: Path) -> tuple[Path, dict]:
    """``clean`` on one take, as the verb runs it (default options)."""
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{src.stem}.c3d"
    report = clean_file(src, out, report=folder / f"{src.stem}.report.json")
    return out, report


def _report_without_paths(path: Path) -> dict:
    data = json.loads(path.read_text(encoding="utf-8"))
    data.pop("input"), data.pop("output")
    return data


def _check_batch_equals_alone(inputs: list[Path], out: Path, alone: Path, rows: list[dict]) -> None:
    by_input = {Path(r["input"]).name: r for r in rows}
    for src in inputs:
        row = by_input[src.name]
        if src.name in ("truncated.c3d", "notes.trc"):
            assert row["status"] == "failed"
            assert row["error"].startswith(f"{src}:"), row["error"]
            assert "\n" not in row["error"]
            assert not list(out.glob(f"{src.stem}.*"))  # nothing written for it
            continue
        assert row["status"] == "done", row
        mine, report = _alone(src, alone)
        assert _digest(out / f"{src.stem}.c3d") == _digest(mine)  # bit-identical
        assert _report_without_paths(out / f"{src.stem}.report.json") == _report_without_paths(
            alone / f"{src.stem}.report.json"
        )
        assert row["figures"]["frames"] == report["frames"]
        assert row["figures"]["filled_samples"] == report["guard"]["filled_samples"]
        assert row["outputs"] == [
            str(out / f"{src.stem}.c3d"),
            str(out / f"{src.stem}.report.json"),
        ]


def test_synchronous_batch_equals_clean_alone_and_survives_hostile_files(tmp_path: Path) -> None:
    inputs = _takes(tmp_path / "in")
    before = {p: _digest(p) for p in inputs}
    seen: list[tuple[int, int]] = []
    result = run_batch(
        "clean",
        [tmp_path / "in"],
        tmp_path / "out",
        scheduler="synchronous",
        progress=lambda done, total, row: seen.append((done, total)),
    )
    assert result.exit_status == 2  # a bad input among them
    assert [r["status"] for r in result.rows].count("done") == len(QUICK)
    assert seen[0] == (0, 4) and seen[-1] == (4, 4) and len(seen) == 5
    _check_batch_equals_alone(inputs, tmp_path / "out", tmp_path / "alone", result.rows)
    assert {p: _digest(p) for p in inputs} == before  # inputs never modified
    # the summary files agree with the rows
    data = json.loads((tmp_path / "out" / "batch.json").read_text(encoding="utf-8"))
    assert data["verb"] == "clean" and data["totals"]["done"] == 2 and data["totals"]["failed"] == 2
    with open(tmp_path / "out" / "batch.csv", newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table] == [r["status"] for r in result.rows]
    assert all(float(r["seconds"]) >= 0 for r in table)
    failed = [r for r in table if r["status"] == "failed"]
    assert all(r["error"].startswith(r["input"]) for r in failed)


def test_resume_skips_done_takes_and_force_redoes_them(tmp_path: Path) -> None:
    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))
    first = run_batch("clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
    out = tmp_path / "out" / "cmu_85_02.c3d"
    stamp = out.stat().st_mtime_ns, out.stat().st_ino
    again = run_batch("clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
    status = {r["name"]: r["status"] for r in again.rows}
    assert status == {"cmu_85_02": "skipped", "notes": "failed", "truncated": "failed"}
    assert (out.stat().st_mtime_ns, out.stat().st_ino) == stamp  # not touched
    skipped = next(r for r in again.rows if r["name"] == "cmu_85_02")
    done = next(r for r in first.rows if r["name"] == "cmu_85_02")
    assert skipped["figures"] == done["figures"]  # carried from the earlier run's rows
    # other options on a resumed folder: refused rather than mixing two settings
    with pytest.raises(FormatError, match="other options"):
        run_batch(
            "clean",
            [tmp_path / "in"],
            tmp_path / "out",
            scheduler="synchronous",
            options={"method": "rigid"},
        )
    # a damaged summary cannot vouch for the outputs' options (it was taken as none)
    summary = tmp_path / "out" / "batch.json"
    kept = summary.read_bytes()
    for damaged in (kept[:300], b"[]", b'{"verb": "clean", "rows": 5}'):
        summary.write_bytes(damaged)
        with pytest.raises(FormatError, match="not a batch summary skincap can read"):
            run_batch("clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
        assert (out.stat().st_mtime_ns, out.stat().st_ino) == stamp
    forced = run_batch(
        "clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous", force=True
    )
    assert {r["name"]: r["status"] for r in forced.rows}["cmu_85_02"] == "done"
    assert out.stat().st_ino != stamp[1]  # replaced (atomically: a new file)
    # a take with only some of its outputs is not done: without --force it is refused
    (tmp_path / "out" / "cmu_85_02.report.json").unlink()
    partial = run_batch("clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
    row = next(r for r in partial.rows if r["name"] == "cmu_85_02")
    assert row["status"] == "failed" and "--force" in row["error"]


def test_bad_option_refused_before_any_take(tmp_path: Path) -> None:
    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))
    with pytest.raises(ValidationError, match="--method"):
        run_batch(
            "clean", [tmp_path / "in"], tmp_path / "out", options={"method": "nope"}, workers=2
        )
    with pytest.raises(ValidationError, match="does not take report"):
        run_batch("clean", [tmp_path / "in"], tmp_path / "out", options={"report": "x.json"})
    with pytest.raises(ValidationError, match="--to"):
        run_batch("convert", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
    assert not (tmp_path / "out").exists()  # nothing written


def test_outputs_never_replace_inputs(tmp_path: Path) -> None:
    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))
    before = _digest(tmp_path / "in" / "cmu_85_02.c3d")
    with pytest.raises(FormatError, match="inputs are never modified"):
        run_batch(
            "convert",
            [tmp_path / "in" / "cmu_85_02.c3d"],
            tmp_path / "in",
            options={"to": ".c3d"},
            scheduler="synchronous",
            force=True,
        )
    assert _digest(tmp_path / "in" / "cmu_85_02.c3d") == before


def test_inputs_names_and_globs(tmp_path: Path) -> None:
    for sub in ("s1", "s2"):
        (tmp_path / sub).mkdir()
        shutil.copyfile(DATA / "cmu_85_02.c3d", tmp_path / sub / "walk.c3d")
    shutil.copyfile(DATA / "cmu_85_02.c3d", tmp_path / "s1" / "run.trc")
    shutil.copyfile(DATA / "cmu_85_02.c3d", tmp_path / "s1" / "run.c3d")
    found = collect_inputs([str(tmp_path / "**" / "*.c3d")], (".c3d",))
    assert [p.relative_to(tmp_path).as_posix() for p in found] == [
        "s1/run.c3d",
        "s1/walk.c3d",
        "s2/walk.c3d",
    ]
    # the same file twice (as a file and through its folder) is one take
    again = collect_inputs([tmp_path / "s1" / "run.c3d", tmp_path / "s1"], (".c3d", ".trc"))
    assert [p.name for p in again] == ["run.c3d", "run.trc", "walk.c3d"]
    assert name_takes(again) == ["run_c3d", "run_trc", "walk"]
    assert name_takes(found) == ["s1/run", "s1/walk", "s2/walk"]
    # the output folder's files are never taken as inputs by a folder or a glob
    out = tmp_path / "s1" / "out"
    out.mkdir()
    shutil.copyfile(DATA / "cmu_85_02.c3d", out / "walk.c3d")
    assert len(collect_inputs([str(tmp_path / "**" / "*.c3d")], (".c3d",), exclude=out)) == 3
    # an output folder that is the input folder leaves nothing, and the error says why
    with pytest.raises(ValidationError, match=r"no takes to run: all 2 lie in the output folder"):
        collect_inputs([tmp_path / "s1"], (".c3d",), exclude=tmp_path / "s1")
    with pytest.raises(FormatError, match="no such file"):
        collect_inputs([tmp_path / "missing.c3d"], (".c3d",))
    with pytest.raises(FormatError, match="no takes match"):
        collect_inputs([str(tmp_path / "*.bvh")], (".bvh",))


def test_missing_dask_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(MissingDependencyError, match=r"skincap\[batch\]"):
        run_batch("clean", [tmp_path / "in"], tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_interrupt_keeps_finished_rows_and_cancels_the_rest(tmp_path: Path) -> None:
    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))

    def interrupt(done: int, total: int, row: dict | None) -> None:
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(
            "clean",
            [tmp_path / "in"],
            tmp_path / "out",
            scheduler="synchronous",
            progress=interrupt,
        )
    data = json.loads((tmp_path / "out" / "batch.json").read_text(encoding="utf-8"))
    assert [r["status"] for r in data["rows"]] == ["done", "cancelled", "cancelled"]
    assert not list((tmp_path / "out").glob(".*part*"))


def test_cli_batch_clean(tmp_path: Path) -> None:
    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))
    args = ["batch", "clean", str(tmp_path / "in"), "-o", str(tmp_path / "out")]
    result = CliRunner().invoke(app, [*args, "--scheduler", "synchronous", "--no-smooth"])
    assert result.exit_code == 2, result.output  # the two hostile files
    assert "1 done, 2 failed" in result.output
    truncated = tmp_path / "in" / "truncated.c3d"
    assert f"skincap: error: {truncated}: " in result.output  # each failed take's line, whole
    data = json.loads((tmp_path / "out" / "batch.json").read_text(encoding="utf-8"))
    assert data["options"]["smooth"] is False  # the verb's --no-smooth, translated as clean does
    # a bad option: one line, exit 2, before any take
    bad = CliRunner().invoke(app, [*args, "--iterations", "0", "--force"])
    assert bad.exit_code == 2
    assert "skincap: error: --iterations: expected 1..1000, got 0" in bad.output
    help_text = CliRunner().invoke(app, ["batch", "clean", "--help"]).output
    assert "--workers" in help_text and "--method" in help_text and "Exit status" in help_text


@pytest.mark.slow
def test_two_process_local_cluster_equals_synchronous(tmp_path: Path) -> None:
    inputs = _takes(tmp_path / "in")
    result = run_batch("clean", [tmp_path / "in"], tmp_path / "out", workers=2)
    assert result.exit_status == 2
    _check_batch_equals_alone(inputs, tmp_path / "out", tmp_path / "alone", result.rows)
    assert len({r["worker"] for r in result.rows}) == 2  # both worker processes took takes
    data = json.loads((tmp_path / "out" / "batch.json").read_text(encoding="utf-8"))
    assert data["scheduler"] == "local:2"
    # one take to run: one worker process is started, not two
    (tmp_path / "one").mkdir()
    shutil.copyfile(DATA / "cmu_85_02.c3d", tmp_path / "one" / "cmu_85_02.c3d")
    single = run_batch("clean", [tmp_path / "one"], tmp_path / "o2", workers=2)
    assert [r["status"] for r in single.rows] == ["done"]
    data = json.loads((tmp_path / "o2" / "batch.json").read_text(encoding="utf-8"))
    assert data["scheduler"] == "local:1"


@pytest.mark.slow
def test_real_captures_through_clean_equal_clean_alone(tmp_path: Path) -> None:
    """The real captures the quick tests do not batch (analog channels, a Plug-in Gait
    take): the batch adds nothing capture-specific, and clean's own tests run every one."""
    names = ("c3dorg_sample01_Eb015pr.c3d", "pyomeca_markers_analogs.c3d")
    inputs = _takes(tmp_path / "in", names=names)
    result = run_batch("clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
    assert result.count("done") == len(names)
    _check_batch_equals_alone(inputs, tmp_path / "out", tmp_path / "alone", result.rows)


@pytest.mark.slow
def test_other_verbs_take_their_own_options(tmp_path: Path) -> None:
    """convert, solve and skin through the batch: the verb's outputs per take, its figures."""
    from skincap.io import read

    runner = CliRunner()
    inputs = [DATA / "cmu_85_02.c3d", DATA / "c3dorg_sample01_Eb015pr.c3d"]
    converted = runner.invoke(
        app,
        ["batch", "convert", *map(str, inputs), "--to", "trc", "-o", str(tmp_path / "trc")],
        catch_exceptions=False,
    )
    assert converted.exit_code == 0, converted.output
    for src in inputs:
        back = read(tmp_path / "trc" / f"{src.stem}.trc")
        assert back.n_frames == read(src).n_frames
    # solve: the verb's --loss-scale-cm reaches the workflow in metres, as `solve` passes it
    solved = run_batch(
        "solve",
        [DATA / "cmu_85_02.c3d"],
        tmp_path / "bvh",
        options={"template": "cmu41", "loss": "huber", "loss_scale_m": 0.03},
        scheduler="synchronous",
    )
    row = solved.rows[0]
    assert row["status"] == "done", row
    assert row["figures"]["joints"] > 10 and 0 < row["figures"]["rms_m"] < 0.05
    report = json.loads((tmp_path / "bvh" / "cmu_85_02.report.json").read_text(encoding="utf-8"))
    assert report["frames"] == row["figures"]["frames"] == 810
    bad = runner.invoke(
        app,
        [
            "batch",
            "solve",
            str(DATA / "cmu_85_02.c3d"),
            "-o",
            str(tmp_path / "b2"),
            "--units",
            "furlong",
        ],
    )
    assert bad.exit_code == 2 and "skincap: error: --units: unknown BVH length unit" in bad.output
    # skin: one body, many motions; a capture among the motions fails alone
    skinned = run_batch(
        "skin",
        [DATA / "makehuman_tpose.bvh", DATA / "cmu_85_02.c3d"],
        tmp_path / "skin",
        options={"mesh": DATA / "makehuman_base.obj", "to": ".pc2"},
        scheduler="synchronous",
    )
    status = {r["name"]: r["status"] for r in skinned.rows}
    assert status == {"makehuman_tpose": "done", "cmu_85_02": "failed"}
    assert (tmp_path / "skin" / "makehuman_tpose.pc2").is_file()
    assert (tmp_path / "skin" / "makehuman_tpose.obj").is_file()
    # track's rope selection is checked as track checks it, before any take
    no_rope = runner.invoke(
        app, ["batch", "track", str(DATA / "cmu_85_02.c3d"), "-o", str(tmp_path / "t")]
    )
    assert no_rope.exit_code == 2
    assert "give exactly one of --rope-box, --rope-markers or --rope auto" in no_rope.output
    assert not (tmp_path / "t").exists()


@pytest.mark.slow
def test_existing_scheduler_address(tmp_path: Path) -> None:
    """--scheduler tcp://...: the takes run on a cluster the batch did not start, which stays up."""
    import logging

    from distributed import Client, LocalCluster

    _takes(tmp_path / "in", names=("cmu_85_02.c3d",))
    with LocalCluster(
        n_workers=1, threads_per_worker=1, dashboard_address=None, silence_logs=logging.ERROR
    ) as cluster:
        result = run_batch(
            "clean", [tmp_path / "in"], tmp_path / "out", scheduler=cluster.scheduler_address
        )
        with Client(cluster.scheduler_address) as client:  # the cluster is still there
            assert len(client.scheduler_info()["workers"]) == 1
    assert {r["name"]: r["status"] for r in result.rows} == {
        "cmu_85_02": "done",
        "notes": "failed",
        "truncated": "failed",
    }
    mine, _ = _alone(tmp_path / "in" / "cmu_85_02.c3d", tmp_path / "alone")
    assert _digest(tmp_path / "out" / "cmu_85_02.c3d") == _digest(mine)
    with pytest.raises(FormatError, match="--workers"):
        run_batch("clean", [tmp_path / "in"], tmp_path / "o2", scheduler="tcp://x:1", workers=2)


def test_a_crash_in_one_take_is_recorded_with_its_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An unexpected exception (a bug) in one take: status crashed, exit status 1, the rest run."""
    import skincap.workflows.clean_file as clean_module

    real = clean_module.clean_file

    def flaky(src, output, **kwargs):  # noqa: ANN001, ANN202
        if Path(src).name == "cmu_85_02.c3d":
            raise ZeroDivisionError("a bug")
        return real(src, output, **kwargs)

    monkeypatch.setattr(clean_module, "clean_file", flaky)
    _takes(tmp_path / "in", names=("cmu_85_02.c3d", "c3dorg_sample01_Eb015pr.c3d"))
    result = run_batch("clean", [tmp_path / "in"], tmp_path / "out", scheduler="synchronous")
    rows = {r["name"]: r for r in result.rows}
    assert rows["cmu_85_02"]["status"] == "crashed"
    assert rows["cmu_85_02"]["error"].endswith("ZeroDivisionError: a bug")
    assert "ZeroDivisionError" in rows["cmu_85_02"]["traceback"]
    assert rows["c3dorg_sample01_Eb015pr"]["status"] == "done"
    assert result.exit_status == 1
