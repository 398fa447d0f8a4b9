"""Own-group local PCA trained around each gap (``local_pca_window``): its contract
on an exact synthetic body and its gain on punched gaps of a real take."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap import io
from skincap.cleanup.fill import fill_gaps
from skincap.cleanup.fill_local import fill_local_pca, fill_local_window
from skincap.cleanup.settings import FillSettings
from skincap.errors import SkincapWarning, UnitWarning
from skincap.evaluate.cleanup import evaluate_fill
from skincap.types import MarkerSet

DATA = Path(__file__).resolve().parents[1] / "data"


def _sliding_take(frames: int = 600, coupling: float = 0.0) -> np.ndarray:
    """Six markers on a moving, turning body: markers 2-5 rigid with it, marker 1
    sliding 20 mm along the body's x axis, marker 0 sliding ``coupling`` times as far
    along y in step with it. Returns (T, 6, 3) metres."""
    t = np.arange(frames) / 100.0
    body = np.array(
        [
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.0, 0.1, 0.0],
            [0.0, 0.0, 0.1],
            [0.1, 0.1, 0.0],
            [0.05, 0.0, 0.1],
        ]
    )
    a = 0.02 * np.sin(2.0 * np.pi * 0.7 * t)
    local = np.broadcast_to(body, (frames, 6, 3)).copy()
    local[:, 1, 0] += a
    local[:, 0, 1] += coupling * a
    rot = Rotation.from_rotvec(
        np.stack([0.5 * np.sin(t), 0.4 * t, 0.3 * np.cos(1.3 * t)], 1)
    ).as_matrix()
    move = np.stack([0.6 * t, 0.05 * np.sin(3 * t), 0.02 * t], 1)[:, None]
    return np.einsum("tij,tnj->tni", rot, local) + move


def _csr() -> tuple[np.ndarray, np.ndarray]:
    nb = [[j for j in range(6) if j != i] for i in range(6)]
    return np.arange(7, dtype=np.int64) * 5, np.array(nb, dtype=np.int64).ravel()


def test_window_fill_contract_and_ends() -> None:
    truth = _sliding_take(coupling=0.25)
    pos = truth.copy()
    pos[420:480, 0] = np.nan  # interior: anchored at both ends
    pos[:20, 2] = np.nan  # at the start of the take: anchored at its end only
    target = np.isnan(pos[..., 0])
    spread = np.full(target.shape, np.nan)
    out = fill_local_window(pos, target, _csr(), spread=spread)
    assert np.array_equal(out[~target], pos[~target])  # measured samples untouched
    assert np.isfinite(out[target]).all()
    # joined to the measured samples: the first and last filled samples sit within
    # one frame's travel of their measured neighbours
    step = np.linalg.norm(np.diff(truth[:, 0], axis=0), axis=1).max()
    assert np.linalg.norm(out[420, 0] - pos[419, 0]) < 2 * step
    assert np.linalg.norm(out[479, 0] - pos[480, 0]) < 2 * step
    assert np.linalg.norm(out[19, 2] - pos[20, 2]) < 2 * step
    # the spread is written on the two-sided run only
    assert np.isfinite(spread[420:480, 0]).all() and np.isnan(spread[:20, 2]).all()
    err = np.linalg.norm(out[target] - truth[target], axis=1)
    assert err.max() < 0.02  # within the 20 mm slide the body undergoes
    # only the targeted samples are filled
    only = target.copy()
    only[:20, 2] = False
    part = fill_local_window(pos, only, _csr())
    assert np.isnan(part[:20, 2]).all() and np.array_equal(part[420:480, 0], out[420:480, 0])


def test_rigidity_weighted_frame_ignores_a_sliding_neighbour() -> None:
    """Marker 0 is rigid with the body; neighbour 1 slides 20 mm over it. With equal
    weights the sliding member drags the local frame and the estimate errs by
    millimetres (as the take-wide local PCA does); weighted by rigidity the frame
    follows the rigid members and the estimate is exact to a fraction of a mm."""
    truth = _sliding_take(coupling=0.0)
    pos = truth.copy()
    pos[420:480, 0] = np.nan
    target = np.isnan(pos[..., 0])

    def err(out: np.ndarray) -> float:
        return float(np.linalg.norm(out[420:480, 0] - truth[420:480, 0], axis=1).max())

    equal = err(fill_local_window(pos, target, _csr(), rigid_frame=False))
    sharp = err(fill_local_window(pos, target, _csr(), rigidity_floor=0.001))
    default = err(fill_local_window(pos, target, _csr()))
    assert equal > 3e-3
    assert sharp < 5e-4
    assert sharp < default < equal


def test_window_fill_through_fill_gaps() -> None:
    truth = _sliding_take(coupling=0.25)
    pos = truth.copy()
    pos[100:160, 0] = np.nan
    pos[:20, 2] = np.nan
    markers = MarkerSet(pos, [f"m{i}" for i in range(6)], 100.0)
    for blend in (0.0, None):
        out, invented = fill_gaps(
            markers,
            settings=FillSettings(method="local_pca_window", rigid_blend=blend),
            neighbours=_csr(),
        )
        assert np.array_equal(invented, np.isnan(pos[..., 0]))
        assert np.array_equal(out[~invented], pos[~invented])
        assert np.linalg.norm(out[invented] - truth[invented], axis=1).max() < 0.02


def test_window_fill_beats_the_take_wide_model_on_cmu() -> None:
    """Punched gaps in a real take are scored against the measured samples: on
    cmu_85_02 (41 markers, 120 Hz, pelvis and shoulder clusters deforming by up to
    40 mm) the own-group model trained around each gap beats the paper's averaged
    take-wide model and the rigid fill, blended with the rigid fill alike."""
    markers = io.read(DATA / "cmu_85_02.c3d")
    markers = markers.select(~markers.unlabelled)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        r = evaluate_fill(
            markers,
            methods=["local_pca_window", "local_pca_missing", "rigid_weighted"],
            seed=0,
        )
    rmse = {m: r["results"][m]["all"]["mm"]["rmse"] for m in r["methods"]}
    assert rmse["local_pca_window"] < 0.8 * rmse["local_pca_missing"]
    assert rmse["local_pca_window"] < 0.7 * rmse["rigid_weighted"]


@pytest.fixture(scope="module")
def aml_rmse() -> dict[str, float]:
    """aml_PronetoRun01's labelled markers, the same seeded gaps (the plan depends on the
    take and the seed only, not on the methods) filled by every method the two AML tests
    compare, once: RMSE in mm per method, and ``paper`` for local_pca with
    ``rigid_blend=0``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        markers = io.read(DATA / "aml_PronetoRun01_labeled.c3d")
    markers = markers.select(~markers.unlabelled)
    methods = ["local_pca_window", "local_pca_missing", "rigid_weighted", "rigid", "local_pca"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        r = evaluate_fill(markers, methods=methods, seed=0)
        paper = evaluate_fill(markers, methods=["local_pca"], seed=0, rigid_blend=0.0)
    rmse = {m: r["results"][m]["all"]["mm"]["rmse"] for m in r["methods"]}
    rmse["paper"] = paper["results"]["local_pca"]["all"]["mm"]["rmse"]
    return rmse


@pytest.mark.slow  # the two AML tests with their fixture: 45 s of CPU
def test_window_fill_on_aml(aml_rmse: dict[str, float]) -> None:
    """aml_PronetoRun01 (hand and knee markers among forearm and shank clusters):
    local_pca_window, its frame weighted by rigidity, beats the take-wide
    missing-data model and the donor-weighted rigid fill, at most half the rigid
    fill's RMSE."""
    rmse = aml_rmse
    assert rmse["local_pca_window"] < 0.95 * min(rmse["local_pca_missing"], rmse["rigid_weighted"])
    assert rmse["local_pca_window"] < 0.5 * rmse["rigid"]


def test_take_wide_local_pca_with_rigidity_weighted_frames() -> None:
    """fill_local_pca(rigid_frame=): the same sliding neighbour drags the paper's
    equal-weight frame (1-6 mm error on the rigid marker); weighted by rigidity the
    estimate is exact to a fraction of a mm."""
    truth = _sliding_take(coupling=0.0)
    pos = truth.copy()
    pos[420:480, 0] = np.nan
    target = np.isnan(pos[..., 0])

    def err(out: np.ndarray) -> float:
        return float(np.linalg.norm(out[420:480, 0] - truth[420:480, 0], axis=1).max())

    for kw in ({}, {"weighted": True, "missing_data": True}):
        equal = err(fill_local_pca(pos, target, _csr(), **kw))
        sharp = err(fill_local_pca(pos, target, _csr(), rigid_frame=0.001, **kw))
        default = err(fill_local_pca(pos, target, _csr(), rigid_frame=0.05, **kw))
        assert equal > 1e-3
        assert sharp < 2.5e-4
        assert sharp < default < 0.7 * equal


@pytest.mark.slow
def test_adaptive_local_pca_halves_the_rigid_fill_on_aml(aml_rmse: dict[str, float]) -> None:
    """The default local_pca (blended, rigidity-weighted frames) on aml_PronetoRun01:
    at most half the rigid fill's RMSE, ahead of the paper's estimate alone."""
    rmse = aml_rmse
    assert rmse["local_pca"] < 0.5 * rmse["rigid"]
    assert rmse["local_pca"] < 0.7 * rmse["paper"]
