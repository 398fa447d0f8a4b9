"""``clean`` does no harm: measured samples kept, fills continuous, every change flagged and counted.

Ground truth: a synthetic dense take with injected spikes (4-6 cm for 1-3 frames),
label swaps and a rigid prop. Invariants: every real capture in tests/data.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skincap.cleanup.continuity import condition_fills, second_difference
from skincap.cleanup.outliers import (
    find_label_swaps,
    find_spikes,
    measurement_noise,
    running_median,
)
from skincap.cleanup.pipeline import clean_markers
from skincap.cleanup.smooth import smooth_local
from skincap.errors import SkincapWarning
from skincap.evaluate.bench.cleanup import synthetic_dense_take
from skincap.io import read
from skincap.synth.corrupt import add_rigid_prop, inject_label_swaps, inject_spikes
from skincap.types import MarkerSet

REAL = [
    "aml_PronetoRun01_labeled.c3d",
    "aml_S09_KneeltoRun02_unlabeled.c3d",
    "btk_pig_calibration_hole_unlabeled_fragments.c3d",
    "c3dorg_sample01_Eb015pr.c3d",
    "cmu_85_02.c3d",
    "kt_optitrack_walking.c3d",
    "pyomeca_markers_analogs.c3d",
]


def _quiet(fn, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        return fn(*args, **kwargs)


# ------------------------------------------------------------------ building blocks
def test_measurement_noise_recovers_white_noise() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(2000) / 120.0
    motion = np.stack([np.sin(2 * t), np.cos(3 * t), 0.2 * t], axis=1)[:, None, :]  # metres
    noisy = motion + rng.normal(0.0, [[0.0005], [0.002]], (2000, 2, 3))
    noisy[100:103, 0] += 0.05  # spikes do not inflate the robust estimate
    sigma = measurement_noise(noisy)
    np.testing.assert_allclose(sigma, [0.0005, 0.002], rtol=0.08)


def test_running_median_is_exact_on_steady_motion_up_to_a_gap() -> None:
    x = np.linspace(0.0, 1.0, 50)[:, None, None] * np.ones((1, 1, 3))
    x[20:25] = np.nan
    np.testing.assert_allclose(running_median(x, 9), x, atol=1e-12)


@pytest.mark.slow
def test_spike_is_found_among_its_neighbours() -> None:
    markers, _ = synthetic_dense_take(60, 300, missing=0.0, seed=3)
    from skincap.cleanup.neighbours import motion_neighbours

    nb = motion_neighbours(markers.positions, k=6)
    spiky, truth = inject_spikes(markers, 6, seed=1)
    found = find_spikes(spiky.positions, nb)
    assert (found & truth).sum() == truth.sum()
    assert (found & ~truth).sum() <= 2
    assert not find_spikes(markers.positions, nb).any()
    # the bounded smoother moves no sample further than the bound, spikes or not
    bound = 0.0015
    out = smooth_local(spiky.positions, nb, max_move=bound)
    assert np.linalg.norm(out - spiky.positions, axis=-1).max() <= bound + 1e-12


def test_local_frame_ignores_one_spiking_neighbour() -> None:
    from scipy.spatial.transform import Rotation

    from skincap.cleanup.local_frames import fit_frames_robust
    from skincap.geometry.rigid import fit_rigid

    rng = np.random.default_rng(0)
    shape = rng.normal(0.0, 0.05, (1, 6, 3))  # one neighbourhood of six, metres
    rot = Rotation.from_rotvec(np.linspace(0, 1, 60)[:, None] * [0.3, 1.0, 0.2]).as_matrix()
    move = np.linspace(0, 1, 60)[:, None] * [0.5, 0.1, 0.0]
    cur = (np.einsum("tij,kj->tki", rot, shape[0]) + move[:, None])[:, None]  # (T, 1, 6, 3)
    cur = cur + rng.normal(0.0, 0.0005, cur.shape)
    spiky = cur.copy()
    spiky[30:32, 0, 2] += [0.03, -0.04, 0.02]  # a 5 cm spike on one neighbour
    ok = np.ones(cur.shape[:3], dtype=bool)
    r0, t0 = fit_frames_robust(shape, cur, ok)
    r1, t1 = fit_frames_robust(shape, spiky, ok)
    rp, tp = fit_rigid(shape, spiky, mask=ok)
    centre = shape[0].mean(axis=0)
    at = lambda r, t: np.einsum("tnij,j->tni", r, centre) + t  # noqa: E731
    plain = np.linalg.norm(at(rp, tp) - at(r0, t0), axis=-1)[30:32].max()
    robust = np.linalg.norm(at(r1, t1) - at(r0, t0), axis=-1)[30:32].max()
    assert plain > 0.005
    assert robust < 0.001
    # elsewhere the two fits agree
    np.testing.assert_allclose(t1[:28], t0[:28], atol=1e-12)


def test_label_swap_is_found_between_close_markers() -> None:
    markers, truth = synthetic_dense_take(60, 300, missing=0.0, seed=2)
    p0 = truth[0]
    d = np.linalg.norm(p0[:, None] - p0[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    i = int(np.argmin(d.min(axis=1)))
    j = int(np.argmin(d[i]))
    swapped, swaps = inject_label_swaps(markers, [(i, j)], seed=4)
    from skincap.cleanup.neighbours import motion_neighbours

    found = find_label_swaps(swapped.positions, motion_neighbours(swapped.positions))
    ((a, b, s, e),) = swaps
    assert len(found) == 1
    fi, fj, frames = found[0]
    assert {fi, fj} == {a, b}
    np.testing.assert_array_equal(frames, np.arange(s, e))
    assert find_label_swaps(markers.positions, motion_neighbours(markers.positions)) == []


@pytest.mark.parametrize("amplitude", [0.002, 0.3])
def test_condition_fills_never_keeps_a_zig_zag(amplitude: float) -> None:
    t = np.arange(200)
    x = np.stack([0.002 * t, np.sin(t / 12.0) * 0.1, 0 * t], axis=1)[:, None, :].astype(float)
    fill = np.zeros((200, 1), dtype=bool)
    fill[80:130] = True
    zig = x.copy()
    zig[80:130, 0, 1] += amplitude * (-1.0) ** t[80:130]  # two solutions alternating
    zig[80:130, 0, 0] += 0.01  # and a 1 cm step at both ends
    limit = 3 * np.percentile(second_difference(x)[1:-1], 99.9)
    out, dropped = condition_fills(zig, fill, limit=limit)
    kept = fill & ~dropped
    d2 = second_difference(out)
    assert (d2[kept] <= limit).all()
    assert np.isnan(out[dropped]).all()
    np.testing.assert_array_equal(out[~fill[:, 0]], x[~fill[:, 0]])  # measured untouched
    if amplitude < 0.01:
        assert kept.all() == fill.all() and kept[80:130].all()
        # the alternation is gone and the ends join: within 2 mm of the smooth motion
        np.testing.assert_allclose(out[80:130, 0, 1], x[80:130, 0, 1], atol=0.002)
        assert abs(out[80, 0, 0] - x[80, 0, 0]) < 0.002


def test_condition_fills_leaves_an_unfixable_run_unfilled() -> None:
    x = np.zeros((60, 1, 3))
    x[:, 0, 0] = np.linspace(0, 0.1, 60)
    fill = np.zeros((60, 1), dtype=bool)
    fill[20:40] = True
    bad = x.copy()
    bad[30:40, 0, 2] += 1.0  # a metre jump in the middle of the fill
    out, dropped = condition_fills(bad, fill, limit=1e-4)
    assert dropped[30:40].all()  # the part past the jump is not kept
    assert np.isnan(out[dropped]).all()
    assert np.isfinite(out[~fill[:, 0]]).all()


# ------------------------------------------------------------------ synthetic ground truth
@pytest.fixture(scope="module")
def corrupted() -> dict:
    markers, truth = synthetic_dense_take(90, 300, missing=0.01, seed=5)
    spiky, spikes = inject_spikes(markers, 8, seed=6)
    p0 = truth[0]
    d = np.linalg.norm(p0[:, None] - p0[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    order = np.argsort(d.min(axis=1))
    pairs: list[tuple[int, int]] = []
    used: set[int] = set()
    for a in order.tolist():
        b = int(np.argmin(d[a]))
        if a not in used and b not in used and not spikes[:, [a, b]].any():
            pairs.append((a, b))
            used |= {a, b}
        if len(pairs) == 2:
            break
    # swaps away from gaps, so both ends of each swap are seen
    holes = np.isnan(spiky.positions[..., 0])
    for a, b in pairs:
        holes_ab = holes[:, [a, b]].any(axis=1)
        spiky.positions[holes_ab, a] = truth[holes_ab, a]
        spiky.positions[holes_ab, b] = truth[holes_ab, b]
    swapped, swaps = inject_label_swaps(spiky, pairs, seed=7)
    taken, prop = add_rigid_prop(swapped, seed=8)
    cleaned, report = _quiet(clean_markers, taken)
    return {
        "input": taken,
        "truth": truth,
        "spikes": spikes,
        "swaps": swaps,
        "prop": prop,
        "cleaned": cleaned,
        "report": report,
    }


@pytest.mark.slow
def test_spikes_are_flagged_replaced_and_counted(corrupted: dict) -> None:
    spikes, out, report = corrupted["spikes"], corrupted["cleaned"], corrupted["report"]
    n = corrupted["truth"].shape[1]
    inv = out.invented[:, :n]
    assert inv[spikes].all()
    err = np.linalg.norm(out.positions[:, :n] - corrupted["truth"], axis=-1)
    assert np.nanmax(err[spikes]) < 0.006  # a 4-6 cm spike replaced within 6 mm
    assert report.guard.outlier_samples >= spikes.sum()
    assert report.guard.outliers_replaced >= spikes.sum()
    counted = sum(v["outliers"] for k, v in report.markers.items())
    assert counted == report.guard.outlier_samples


@pytest.mark.slow
def test_swaps_are_repaired_flagged_and_counted(corrupted: dict) -> None:
    out, truth, report = corrupted["cleaned"], corrupted["truth"], corrupted["report"]
    n = truth.shape[1]
    assert report.guard.label_swaps_repaired == len(corrupted["swaps"])
    for a, b, s, e in corrupted["swaps"]:
        err = np.linalg.norm(out.positions[s:e, [a, b]] - truth[s:e, [a, b]], axis=-1)
        assert np.nanmax(err) < 0.003
        assert out.invented[s:e, [a, b]].all()
    assert report.guard.relabelled_samples == sum(2 * (e - s) for _, _, s, e in corrupted["swaps"])
    assert out.invented[:, :n].sum() >= report.guard.relabelled_samples


@pytest.mark.slow
def test_measured_samples_stay_and_neighbours_are_unmoved(corrupted: dict) -> None:
    taken, out, report = corrupted["input"], corrupted["cleaned"], corrupted["report"]
    measured = ~np.isnan(taken.positions[..., 0]) & ~out.invented
    moved = np.linalg.norm(out.positions - taken.positions, axis=-1)[measured]
    assert moved.max() <= 0.0015 + 1e-9
    assert report.guard.largest_move_mm == pytest.approx(1000 * moved.max(), abs=1e-6)
    # the take's noise is 0.5 mm: the bound 3 sigma is the 1.5 mm cap here
    assert report.guard.noise_median_mm == pytest.approx(0.5, rel=0.15)


@pytest.mark.slow
def test_rigid_prop_fills_are_continuous_or_left_out(corrupted: dict) -> None:
    taken, out, report = corrupted["input"], corrupted["cleaned"], corrupted["report"]
    prop = corrupted["prop"]
    limit = report.fill.acceleration_limit_mm_per_frame2 / 1000
    d2 = second_difference(out.positions)
    filled = out.invented & np.isfinite(d2)
    assert (d2[filled] <= limit * (1 + 1e-9)).all()
    holes = np.isnan(taken.positions[:, prop, 0])
    assert holes.any()
    # each prop hole is either filled (flagged) or counted unfilled
    got = out.positions[:, prop, 0]
    assert (out.invented[:, prop][holes] | np.isnan(got[holes])).all()
    counted = sum(report.markers[taken.labels[c]]["unfilled"] for c in prop)
    assert counted == int(np.isnan(got).sum())


@pytest.mark.slow
def test_meta_and_frames_pass_through(corrupted: dict) -> None:
    taken = corrupted["input"]
    with_meta = MarkerSet(
        taken.positions,
        list(taken.labels),
        taken.rate,
        meta={"source": "x", "c3d": {"EVENT": {"LABELS": ["a"]}}},
    )
    out, _ = _quiet(clean_markers, with_meta)
    assert out.meta == with_meta.meta
    assert out.n_frames == taken.n_frames


# ------------------------------------------------------------------ real captures
@pytest.mark.slow
@pytest.mark.parametrize("name", REAL)
def test_real_capture_keeps_measured_samples_and_fills_continuous(
    data_dir: Path, name: str
) -> None:
    """The issue-11 targets on every real capture: <= 2 mm moves, fills <= 3x p99.9."""
    markers = _quiet(read, data_dir / name)
    out, report = _quiet(clean_markers, markers)
    labels = [str(lab) for lab in markers.labels]
    got = [str(lab) for lab in out.labels]
    cols = [c for c, lab in enumerate(labels) if not lab.startswith("*") and lab in got]
    raw = markers.positions[:, cols]
    new = out.positions[:, [got.index(labels[c]) for c in cols]]
    inv = out.invented[:, [got.index(labels[c]) for c in cols]]
    measured = ~np.isnan(raw[..., 0]) & ~inv
    kept = measured & ~np.isnan(new[..., 0])
    moved = np.linalg.norm(new - raw, axis=-1)[kept]
    assert moved.size == 0 or moved.max() <= 0.002
    # a measured sample missing from the output is a spike removed and left unfilled
    assert (measured & ~kept).sum() <= report.guard.outlier_samples
    d2 = second_difference(new)
    triple = np.zeros_like(measured)
    triple[1:-1] = kept[:-2] & kept[1:-1] & kept[2:]
    if triple.any() and inv.any():
        ref = np.percentile(d2[triple], 99.9)
        filled = inv & np.isfinite(d2)
        assert not filled.any() or d2[filled].max() <= 3 * ref
    guard = report.guard
    for key in (
        "filled_samples",
        "unfilled_samples",
        "outlier_samples",
        "relabelled_fragments",
        "largest_move_mm",
    ):
        assert key in report.as_dict()["guard"]
    assert guard.unfilled_samples == sum(v["unfilled"] for v in report.markers.values())
    assert out.n_frames == markers.n_frames


@pytest.mark.parametrize("frames", [1, 3, 12])
def test_tiny_and_static_takes_clean_without_error(frames: int) -> None:
    pos = np.zeros((frames, 6, 3))
    pos[:, :, 0] = np.arange(6) * 0.05  # nothing moves: measured second differences are 0
    if frames > 2:
        pos[1, 1] = np.nan
    out, report = _quiet(clean_markers, MarkerSet(pos, [f"M{i}" for i in range(6)], 100.0))
    assert out.n_frames == frames
    filled = out.invented & np.isfinite(out.positions[..., 0])
    expected = np.zeros((int(filled.sum()), 3))
    expected[:, 0] = 0.05
    np.testing.assert_allclose(out.positions[filled], expected, atol=1e-9)
    assert report.guard.largest_move_mm == 0.0


def test_holes_at_the_takes_first_and_last_frames_are_filled(data_dir: Path) -> None:
    """A hole touching frame 0 or the last frame is filled like an interior one (its
    end sample judged by its neighbour's second difference, which includes it): CMU
    85_02 is fully measured, so the measured samples are the truth."""
    markers = _quiet(read, data_dir / "cmu_85_02.c3d")
    assert np.isfinite(markers.positions).all()
    last = markers.n_frames - 1
    holes = [(slice(0, 1), 20), (slice(last - 4, last + 1), 5), (slice(0, 3), 30)]
    pos = markers.positions.copy()
    for frames, column in holes:
        pos[frames, column] = np.nan
    out, report = _quiet(clean_markers, replace(markers, positions=pos))
    assert report.fill.unfilled_samples == 0 and np.isfinite(out.positions).all()
    for frames, column in holes:
        error = np.linalg.norm(
            out.positions[frames, column] - markers.positions[frames, column], axis=-1
        )
        assert error.max() < 0.01  # metres
        assert out.invented[frames, column].all()
