"""``animate --method skeleton_rbf`` on the analytic arm: the skeleton solved from the
take's own markers (``--template auto``), skinned, plus the markers' residuals, against
the true skin; and its refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from dense_arm import ELBOW, arm_take
from typer.testing import CliRunner

from skincap.cli import app
from skincap.io.pc2 import read_pc2
from skincap.workflows.animate_file import animate_file


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> tuple[Path, Path, np.ndarray, np.ndarray]:
    return arm_take(tmp_path_factory.mktemp("arm_skel"))


def run(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_skeleton_rbf_follows_the_true_skin_of_the_arm(arm, tmp_path) -> None:
    mesh_path, take_path, truth, x = arm
    out = tmp_path / "arm.pc2"
    summary = animate_file(
        mesh_path, take_path, out, method="skeleton_rbf", reference_frame=0,
        report=tmp_path / "r.json",
    )  # fmt: skip
    got = np.asarray(read_pc2(out).frames)
    assert got.shape == truth.shape and np.isfinite(got).all()
    err = np.linalg.norm(got - truth, axis=-1)
    far = np.abs(x - ELBOW) > 0.15
    # two rigid tubes: the solved skeleton's skinning plus the residual is within a
    # millimetre away from the elbow (the automatic weights blend over ~10 cm), and
    # within millimetres at the tubes' hard fold (2.9 mm RMS when written)
    assert err[:, far].max() < 1e-3
    assert np.sqrt(np.mean(err**2)) < 4e-3
    assert summary["method"] == "skeleton_rbf" and summary["parts"] is None
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["rig"]["skeleton"]["joints"] >= 2
    assert len(report["deformation_ms_per_frame"]["frames"]) == truth.shape[0]
    # calibrated on a range-of-motion take (here a copy of the take, markers reversed):
    # the model's markers are matched by label, so the skeleton and the skin are the same
    from skincap import io
    from skincap.types import MarkerSet

    take = io.read(take_path)
    rom = tmp_path / "rom.c3d"
    order = np.arange(take.n_markers)[::-1]
    io.write(MarkerSet(positions=take.positions[:, order], labels=[take.labels[i] for i in order],
                       rate=take.rate), rom)  # fmt: skip
    animate_file(mesh_path, take_path, tmp_path / "rom.pc2", method="skeleton_rbf",
                 reference_frame=0, rom=rom)  # fmt: skip
    again = np.asarray(read_pc2(tmp_path / "rom.pc2").frames)
    assert np.abs(again - got).max() < 1e-6


def test_cli_skeleton_rbf_says_one_line_and_refuses_a_rig(arm, tmp_path) -> None:
    mesh_path, take_path, _, _ = arm
    res = run("animate", mesh_path, take_path, "--method", "skeleton_rbf", "--reference-frame",
              "0", "-o", tmp_path / "a.pc2")  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "joints, skeleton_rbf" in res.output
    for extra, what in (
        (("--save-rig", tmp_path / "r.npz"), "--method skeleton_rbf: --rig/--save-rig"),
        (("--rig", tmp_path / "r.npz"), "--method skeleton_rbf: --rig/--save-rig"),
        (("--skeleton-template", tmp_path / "nope.json"), "nope.json"),
    ):
        before = set(tmp_path.iterdir())
        res = run("animate", mesh_path, take_path, "--method", "skeleton_rbf", *extra,
                  "-o", tmp_path / "b.pc2")  # fmt: skip
        assert res.exit_code == 2, res.output
        lines = [s for s in res.output.splitlines() if s.startswith("skincap: error:")]
        assert len(lines) == 1 and what in lines[0], res.output
        assert set(tmp_path.iterdir()) == before
