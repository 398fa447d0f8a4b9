"""``clean`` gives the same output after the speed work as before it.

The expectation (``data/clean_expected.npz``) was computed by the cleanup as it stood
before the no-harm pipeline was sped up (commit f4f062b); this test holds every later
change to the same positions (to 1e-9 m), flags and report counts. Regenerate only
when a change of results is intended: ``python tests/cleanup/test_clean_unchanged.py --write``.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skincap.cleanup.pipeline import clean_markers
from skincap.errors import SkincapWarning
from skincap.evaluate.bench.cleanup import synthetic_dense_take
from skincap.io import read
from skincap.synth.corrupt import add_rigid_prop, inject_label_swaps, inject_spikes
from skincap.types import MarkerSet

HERE = Path(__file__).parent
EXPECTED = HERE / "data" / "clean_expected.npz"
REAL = HERE.parent / "data" / "kt_optitrack_walking.c3d"


def _synthetic() -> MarkerSet:
    """80 markers, 240 frames, 3 % missing, 4 spikes, one label swap and a rigid prop."""
    markers, truth = synthetic_dense_take(80, 240, missing=0.03, seed=5)
    markers, _ = inject_spikes(markers, 4, seed=1)
    p0 = truth[0]
    d = np.linalg.norm(p0[:, None] - p0[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    i = int(np.argmin(d.min(axis=1)))
    markers, _ = inject_label_swaps(markers, [(i, int(np.argmin(d[i])))], seed=4)
    markers, _ = add_rigid_prop(markers, seed=2)
    return markers


def _clean(markers: MarkerSet) -> dict[str, Any]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        cleaned, report = clean_markers(markers)
    return {
        "positions": cleaned.positions,
        "invented": np.asarray(cleaned.invented, dtype=bool),
        "labels": np.array([str(lab) for lab in cleaned.labels]),
        "report": np.array(json.dumps(report, sort_keys=True, default=str)),
    }


def _cases() -> dict[str, MarkerSet]:
    return {"synthetic": _synthetic(), "real": read(REAL)}


def _write() -> None:
    arrays = {}
    for name, markers in _cases().items():
        for key, value in _clean(markers).items():
            arrays[f"{name}/{key}"] = value
    EXPECTED.parent.mkdir(exist_ok=True)
    np.savez_compressed(EXPECTED, **arrays)


def _close_reports(got: Any, want: Any, path: str = "report") -> None:
    """Equal JSON trees, floats to 1e-9 relative (they come from 1e-9 m positions)."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and sorted(got) == sorted(want), path
        for k in want:
            _close_reports(got[k], want[k], f"{path}.{k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), path
        for k, (g, w) in enumerate(zip(got, want, strict=True)):
            _close_reports(g, w, f"{path}[{k}]")
    elif isinstance(want, float):
        assert got == pytest.approx(want, rel=1e-6, abs=1e-6), path
    else:
        assert got == want, path


@pytest.mark.slow
@pytest.mark.parametrize("name", ["synthetic", "real"])
def test_clean_output_is_unchanged(name: str) -> None:
    want = np.load(EXPECTED)
    markers = _synthetic() if name == "synthetic" else read(REAL)
    got = _clean(markers)
    assert list(got["labels"]) == list(want[f"{name}/labels"])
    np.testing.assert_array_equal(got["invented"], want[f"{name}/invented"])
    np.testing.assert_array_equal(np.isnan(got["positions"]), np.isnan(want[f"{name}/positions"]))
    np.testing.assert_allclose(
        got["positions"], want[f"{name}/positions"], rtol=0, atol=1e-9, equal_nan=True
    )
    _close_reports(json.loads(str(got["report"])), json.loads(str(want[f"{name}/report"])))


if __name__ == "__main__" and "--write" in sys.argv:
    _write()
