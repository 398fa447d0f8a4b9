from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap import io
from skincap.cleanup.fill import (
    FILL_METHODS,
    as_csr,
    fill_gaps,
    mean_neighbour_distance,
    motion_neighbours,
)
from skincap.errors import SkincapWarning, ValidationError
from skincap.evaluate.bench.cleanup import synthetic_dense_take
from skincap.evaluate.cleanup import evaluate_fill
from skincap.types import MarkerSet


@pytest.fixture(scope="module")
def take():
    markers, truth = synthetic_dense_take(150, 150, seed=3, missing=0.03)
    return markers, truth


def _rigid_cluster(frames=120, n=8, seed=0):
    rng = np.random.default_rng(seed)
    local = rng.normal(0, 0.1, (n, 3))
    t = np.arange(frames) / 100.0
    rot = Rotation.from_rotvec(np.stack([np.sin(t), 0.5 * t, np.cos(2 * t) - 1], 1)).as_matrix()
    pos = np.einsum("tij,nj->tni", rot, local) + np.stack([t, np.sin(3 * t), 0 * t], 1)[:, None]
    return pos


@pytest.mark.parametrize("method", FILL_METHODS)
def test_measured_samples_unchanged_and_invented_exact(take, method):
    markers, _ = take
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        out, invented = fill_gaps(markers, method=method)
    measured = ~markers.missing
    np.testing.assert_array_equal(out[measured], markers.positions[measured])
    np.testing.assert_array_equal(invented, markers.missing & ~np.isnan(out[..., 0]))
    assert invented.sum() > 0.5 * markers.missing.sum()


def test_interpolators_exact_on_straight_lines():
    t = np.arange(50, dtype=float)
    pos = np.stack([0.01 * t, 0.02 * t + 1, -0.005 * t], 1)[:, None, :].repeat(2, 1)
    pos[10:30, 0] = np.nan
    m = MarkerSet(pos, ["a", "b"], 100.0)
    for method in ("linear", "pchip", "spline"):
        out, inv = fill_gaps(m, method=method)
        np.testing.assert_allclose(out[:, 0], pos[:, 1], atol=1e-12)
        assert inv[10:30, 0].all() and inv.sum() == 20


def test_rigid_fill_exact_on_rigid_motion():
    pos = _rigid_cluster()
    gappy = pos.copy()
    gappy[40:90, 2] = np.nan
    gappy[0:15, 5] = np.nan  # an edge run: filled from one side
    m = MarkerSet(gappy, [f"m{i}" for i in range(8)], 100.0)
    out, inv = fill_gaps(m, method="rigid")
    np.testing.assert_allclose(out, pos, atol=1e-9)
    assert inv.sum() == 65


def test_local_pca_exact_on_rigid_motion():
    pos = _rigid_cluster()
    gappy = pos.copy()
    gappy[40:90, 2] = np.nan
    m = MarkerSet(gappy, [f"m{i}" for i in range(8)], 100.0)
    for method in ("local_pca", "local_pca_weighted", "local_pca_missing"):
        out, _ = fill_gaps(m, method=method)
        np.testing.assert_allclose(out, pos, atol=1e-6)


def test_local_pca_accuracy_on_deforming_take(take):
    markers, truth = take
    miss = markers.missing
    errs = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        csr = motion_neighbours(markers.positions)
        for method in ("local_pca", "local_pca_weighted", "local_pca_missing", "linear", "rigid"):
            out, _ = fill_gaps(markers, method=method, neighbours=csr)
            e = np.linalg.norm(out - truth, axis=-1)[miss]
            errs[method] = float(np.sqrt(np.nanmean(e**2)))
    # measured: local PCA 1.07-1.19 mm (noise 0.5 mm), linear 50 mm, rigid 1.19 mm
    for method in ("local_pca", "local_pca_weighted", "local_pca_missing"):
        assert errs[method] < 0.0018, errs
        assert errs[method] < 0.1 * errs["linear"], errs


def test_max_gap_leaves_long_runs_unfilled():
    pos = _rigid_cluster()
    pos[10:20, 0] = np.nan
    pos[40:100, 1] = np.nan
    m = MarkerSet(pos, [f"m{i}" for i in range(8)], 100.0)
    for method in ("linear", "rigid", "local_pca"):
        with warnings.catch_warnings():
            warnings.simplefilter("error", SkincapWarning)  # skipped runs are not failures
            out, inv = fill_gaps(m, method=method, max_gap=30)
        assert inv[10:20, 0].all() and not inv[:, 1].any()
        assert np.isnan(out[40:100, 1]).all()


def test_warns_when_samples_cannot_be_filled():
    pos = _rigid_cluster(n=4)
    pos[10:20, :3] = np.nan  # marker 0 has one present neighbour: no rigid frame
    m = MarkerSet(pos, ["a", "b", "c", "d"], 100.0)
    with pytest.warns(SkincapWarning, match="unfilled"):
        out, inv = fill_gaps(m, method="rigid")
    assert not inv[10:20].any() and np.isnan(out[10:20, :3]).all()


def test_validation():
    m = MarkerSet(_rigid_cluster(), [f"m{i}" for i in range(8)], 100.0)
    with pytest.raises(ValidationError, match="method"):
        fill_gaps(m, method="cubic")
    with pytest.raises(ValidationError, match="max_gap"):
        fill_gaps(m, max_gap=0)
    with pytest.raises(ValidationError, match="offsets"):
        as_csr((np.array([0, 1]), np.array([1])), 8)
    with pytest.raises(ValidationError, match="own neighbour"):
        as_csr((np.array([0, 1, 1, 1, 1, 1, 1, 1, 1]), np.array([0])), 8)
    with pytest.raises(ValidationError):
        fill_gaps(np.zeros((3, 2, 3)))  # type: ignore[arg-type]


def test_no_gaps_is_a_copy():
    pos = _rigid_cluster()
    m = MarkerSet(pos, [f"m{i}" for i in range(8)], 100.0)
    out, inv = fill_gaps(m, method="local_pca")
    np.testing.assert_array_equal(out, pos)
    assert not inv.any() and out is not m.positions


def test_neighbours_and_distances():
    pos = _rigid_cluster(n=6)
    off, idx = motion_neighbours(pos, k=3)
    assert off.tolist() == [0, 3, 6, 9, 12, 15, 18]
    assert np.all(idx != np.repeat(np.arange(6), 3))
    d = mean_neighbour_distance(pos, (off, idx))
    owner = np.repeat(np.arange(6), 3)
    expect = np.bincount(owner, np.linalg.norm(pos[0, owner] - pos[0, idx], axis=1)) / 3
    np.testing.assert_allclose(d, expect, rtol=1e-9)


def test_real_take_beats_spline_and_rigid(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        markers = io.read(data_dir / "cmu_85_02.c3d")
    r = evaluate_fill(
        markers,
        methods=["local_pca_weighted", "spline", "rigid"],
        gap_lengths=(60, 120),
        gaps=3,
        seed=1,
    )
    rmse = {m: r["results"][m]["all"]["mm"]["rmse"] for m in r["methods"]}
    # measured (seed 1): local_pca_weighted well under half the spline's RMSE and below rigid
    assert rmse["local_pca_weighted"] < 0.5 * rmse["spline"], rmse
    assert rmse["local_pca_weighted"] < rmse["rigid"], rmse
    assert rmse["local_pca_weighted"] < 40.0, rmse


def _drifting_cluster(frames=200, n=8, seed=1):
    """A turning, moving cluster whose marker 0 also slides 30 mm along the cluster's
    own x axis over the take (skin sliding: no neighbour explains it)."""
    rng = np.random.default_rng(seed)
    local = rng.normal(0, 0.1, (n, 3))
    t = np.arange(frames) / 100.0
    rot = Rotation.from_rotvec(np.stack([0.6 * np.sin(t), 0.8 * t, 0.3 * t], 1)).as_matrix()
    slide = np.zeros((frames, n, 3))
    slide[:, 0, 0] = 0.03 * (np.arange(frames) / (frames - 1)) ** 2
    move = np.stack([t, np.sin(3 * t), 0 * t], 1)[:, None]
    return np.einsum("tij,tnj->tni", rot, local[None] + slide) + move


@pytest.mark.parametrize("method", ["local_pca", "local_pca_weighted", "local_pca_missing"])
def test_anchored_fill_joins_the_gap_ends(method):
    truth = _drifting_cluster()
    pos = truth.copy()
    s, e = 120, 170
    pos[s:e, 0] = np.nan
    m = MarkerSet(pos, [f"m{i}" for i in range(8)], 100.0)
    nb = (np.arange(9) * 7, np.array([j for i in range(8) for j in range(8) if j != i]))
    anchored, inv = fill_gaps(m, method=method, neighbours=nb)
    free, _ = fill_gaps(m, method=method, neighbours=nb, anchor_ends=False)
    assert inv[s:e, 0].all() and inv.sum() == e - s
    err_a = np.linalg.norm(anchored[s:e, 0] - truth[s:e, 0], axis=1)
    err_f = np.linalg.norm(free[s:e, 0] - truth[s:e, 0], axis=1)
    # continuity: the first and last filled frames sit within one frame's slide
    # (at most 0.3 mm) of the truth, and the whole gap follows the drift
    slide_step = 0.03 * 2 * (e / 199) / 199
    assert err_a[0] < slide_step and err_a[-1] < slide_step
    assert err_a.max() < 0.002
    # without the anchoring the drift the neighbourhood cannot explain stays
    assert err_f[0] > 5 * err_a[0] and err_f[-1] > 5 * err_a[-1]
    assert err_f.max() > 3 * err_a.max()


def test_anchored_fill_one_sided_gap_takes_the_end_offset():
    truth = _drifting_cluster()
    pos = truth.copy()
    pos[170:, 0] = np.nan  # a run to the end of the take: anchored from its start only
    m = MarkerSet(pos, [f"m{i}" for i in range(8)], 100.0)
    nb = (np.arange(9) * 7, np.array([j for i in range(8) for j in range(8) if j != i]))
    anchored, _ = fill_gaps(m, method="local_pca", neighbours=nb)
    free, _ = fill_gaps(m, method="local_pca", neighbours=nb, anchor_ends=False)
    err_a = np.linalg.norm(anchored[170:, 0] - truth[170:, 0], axis=1)
    err_f = np.linalg.norm(free[170:, 0] - truth[170:, 0], axis=1)
    assert err_a[0] < 0.001 and err_a[0] < 0.2 * err_f[0]
    assert err_a.max() < err_f.max()


def test_rigid_weights_follow_each_gaps_spreads():
    from skincap.cleanup.fill import _rigid_weights

    missing = np.zeros((10, 3), dtype=bool)
    missing[2:5, 0] = True
    missing[3:8, 1] = True
    missing[1:3, 2] = True
    sp = np.full((10, 3), np.nan)
    sr = np.full((10, 3), np.nan)
    sp[2:5, 0], sr[2:5, 0] = 0.0, 0.01  # the PCA fill agrees with itself: PCA alone
    sp[3:8, 1] = [0.001, 0.002, 0.003, 0.004, 0.005]  # mean 0.003 over the gap
    sr[3:8, 1] = 0.004  # weight of rigid 0.003² / (0.003² + 0.004²) = 0.36
    # marker 2 has no spreads (a one-sided gap): half and half
    w = _rigid_weights(missing, missing, sp, sr, None)
    _, nn = np.nonzero(missing)
    np.testing.assert_allclose(w, np.select([nn == 0, nn == 1], [0.0, 0.36], 0.5))
    np.testing.assert_allclose(_rigid_weights(missing, missing, sp, sr, 0.25), 0.25)


def test_spreads_measure_what_one_side_cannot_explain():
    from skincap.cleanup.fill import fill_local_pca, fill_rigid

    nb = (np.arange(9) * 7, np.array([j for i in range(8) for j in range(8) if j != i]))
    s, e = 120, 170
    for truth, lo, hi in ((_rigid_cluster(200), 0.0, 1e-9), (_drifting_cluster(), 0.008, 0.014)):
        pos = truth.copy()
        pos[s:e, 0] = np.nan
        target = np.isnan(pos[..., 0])
        for fill in (fill_rigid, fill_local_pca):
            spread = np.full(target.shape, np.nan)
            fill(pos, target, nb, spread=spread)
            assert np.isfinite(spread[target]).all() and np.isnan(spread[~target]).all()
            # the drifting marker slides 11 mm along the cluster between the gap's ends
            assert lo <= spread[target].mean() <= hi, (fill.__name__, spread[target].mean())


def test_rigid_blend_extremes_and_validation(take):
    markers, truth = take
    nb = motion_neighbours(markers.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        pure, _ = fill_gaps(markers, method="local_pca", neighbours=nb, rigid_blend=0.0)
        rigid, _ = fill_gaps(markers, method="rigid_weighted", neighbours=nb)
        plain, _ = fill_gaps(markers, method="rigid", neighbours=nb)
        ones, _ = fill_gaps(markers, method="local_pca", neighbours=nb, rigid_blend=1.0)
        ones_plain, _ = fill_gaps(
            markers, method="local_pca", neighbours=nb, rigid_blend=1.0, rigid_weighted=False
        )
        auto, _ = fill_gaps(markers, method="local_pca", neighbours=nb)
        # blending also weighs the local frames by rigidity: the PCA end of the blend
        # is the fill with a vanishing rigid weight, not the paper's rigid_blend=0
        pca_end, _ = fill_gaps(markers, method="local_pca", neighbours=nb, rigid_blend=1e-12)
    miss = markers.missing & ~np.isnan(rigid[..., 0]) & ~np.isnan(pure[..., 0])
    # the blend's rigid fill weighs its donors; rigid_weighted=False is the Vicon-style one
    np.testing.assert_allclose(ones[miss], rigid[miss])
    np.testing.assert_allclose(ones_plain[miss], plain[miss])
    # the adaptive fill lies on the segment between the two fills
    a, b, c = pca_end[miss], auto[miss], rigid[miss]
    np.testing.assert_allclose(
        np.linalg.norm(b - a, axis=1) + np.linalg.norm(c - b, axis=1),
        np.linalg.norm(c - a, axis=1),
        atol=1e-9,
    )
    with pytest.raises(ValidationError):
        fill_gaps(markers, method="local_pca", rigid_blend=1.5)


def test_whole_body_pca_is_not_swamped_by_the_body_travelling():
    """The same swinging limbs, standing or travelling 5 m: the travel is taken out
    first, so the fill of a 40-frame gap is (nearly) the same in both takes."""
    from skincap.cleanup.fill import fill_pca

    rng = np.random.default_rng(3)
    t = np.arange(400) / 100.0
    base = rng.normal(scale=0.2, size=(12, 3))
    swing = np.sin(2 * np.pi * 1.1 * t)[:, None, None] * rng.normal(scale=0.05, size=(12, 3))
    swing += np.sin(2 * np.pi * 0.7 * t + 1.0)[:, None, None] * rng.normal(scale=0.03, size=(12, 3))
    travel = np.stack([1.25 * t, 0.02 * np.sin(7 * t), 0.3 * t**0.5], axis=1)[:, None, :]
    standing = base[None] + swing
    gappy = standing.copy()
    gappy[150:190, 4] = np.nan
    target = np.isnan(gappy[..., 0])
    still = fill_pca(gappy, target)
    moving = fill_pca(gappy + travel, target) - travel
    np.testing.assert_allclose(moving[150:190, 4], still[150:190, 4], atol=0.005)
    np.testing.assert_allclose(moving[~target], gappy[~target], atol=1e-12)


@pytest.mark.parametrize("method", ["local_pca", "rigid_weighted", "linear"])
def test_only_fills_the_masked_samples(take, method):
    markers, truth = take
    missing = markers.missing
    only = np.zeros_like(missing)
    cols = np.flatnonzero(missing.any(axis=0))[:5]
    only[:, cols] = missing[:, cols]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        out, invented = fill_gaps(markers, method=method, only=only)
    assert invented.any() and not (invented & ~only).any()
    assert np.isnan(out[missing & ~only]).all()
    err = np.linalg.norm(out[invented] - truth[invented], axis=-1)
    # spatial fills within 1 cm of the truth; linear interpolation is only checked for
    # filling the same samples it fills without the mask
    limit = {"local_pca": 0.01, "rigid_weighted": 0.01, "linear": np.inf}[method]
    assert np.median(err) < limit
    if method == "linear":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkincapWarning)
            whole, _ = fill_gaps(markers, method=method)
        np.testing.assert_array_equal(out[invented], whole[invented])
    with pytest.raises(ValidationError, match="only"):
        fill_gaps(markers, method=method, only=only[:-1])


def test_evaluate_fill_can_leave_the_takes_own_gaps_open(take):
    markers, _ = take
    kw = dict(methods=["local_pca", "linear"], gap_lengths=(20,), gaps=2, seed=1)
    full = evaluate_fill(markers, **kw)
    punched_only = evaluate_fill(markers, fill_own_gaps=False, **kw)
    assert punched_only["fill_own_gaps"] is False and full["fill_own_gaps"] is True
    for method in kw["methods"]:
        a, b = full["results"][method]["all"], punched_only["results"][method]["all"]
        assert a["samples"] == b["samples"] > 0  # the same punched samples are scored
    # linear interpolation does not look at neighbours: the same fill either way
    assert full["results"]["linear"]["all"]["mm"] == punched_only["results"]["linear"]["all"]["mm"]
