"""Donor-weighted rigid fill (``rigid_weighted``, and the rigid fill the local methods
blend with): tested against exact ground truth and on a real take."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap import io
from skincap.cleanup.fill import fill_gaps, fill_rigid
from skincap.errors import SkincapWarning
from skincap.evaluate.cleanup import evaluate_fill
from skincap.types import MarkerSet

DATA = Path(__file__).resolve().parents[1] / "data"


def _limb_take(frames: int = 300, seed: int = 0) -> tuple[np.ndarray, tuple]:
    """Markers 0-5 on one rigid segment; markers 6-7 on a second segment hinged to it
    and swinging through 60 degrees. Marker 0's neighbours: 1, 2, 6, 7, 3 (the two
    swinging ones rank among its first donors, as proximity alone would pick them).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / 100.0
    body = rng.normal(0.0, 0.06, (6, 3))
    limb = np.array([[0.15, 0.0, 0.0], [0.2, 0.05, 0.0]])
    rot = Rotation.from_rotvec(
        np.stack([0.4 * np.sin(t), 0.3 * t, 0.2 * np.cos(1.5 * t) - 0.2], 1)
    ).as_matrix()
    hinge = Rotation.from_rotvec(
        np.stack([0 * t, 0 * t, (np.pi / 3) * np.sin(2.3 * t)], 1)
    ).as_matrix()
    move = np.stack([0.5 * t, 0.1 * np.sin(2 * t), 0 * t], 1)[:, None]
    seg = np.einsum("tij,nj->tni", rot, body) + move
    swing = np.einsum("tij,tjk,nk->tni", rot, hinge, limb) + move
    pos = np.concatenate([seg, swing], axis=1)
    nb = {0: [1, 2, 6, 7, 3], 1: [0, 2, 3, 4], 2: [0, 1, 3, 5], 3: [0, 1, 2, 4]}
    nb.update({4: [1, 3, 5, 0], 5: [2, 4, 3, 0], 6: [7, 0, 1, 2], 7: [6, 0, 1, 2]})
    counts = [len(nb[i]) for i in range(8)]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    indices = np.concatenate([nb[i] for i in range(8)]).astype(np.int64)
    return pos, (offsets, indices)


def test_weighted_donors_ignore_a_swinging_neighbour():
    truth, nb = _limb_take()
    gappy = truth.copy()
    gappy[100:180, 0] = np.nan
    target = np.isnan(gappy[..., 0])
    plain = fill_rigid(gappy, target, nb)
    weighted = fill_rigid(gappy, target, nb, weighted=True)
    e_plain = np.linalg.norm(plain[target] - truth[target], axis=1).max()
    e_weighted = np.linalg.norm(weighted[target] - truth[target], axis=1).max()
    # the three rigid donors carry the marker; the swinging ones drag the plain fill off
    # by 22 mm and the weighted one by 0.17 mm (their weight is a thousandth)
    assert e_plain > 0.01, e_plain
    assert e_weighted < 0.02 * e_plain, (e_weighted, e_plain)
    np.testing.assert_array_equal(weighted[~target], gappy[~target])


def test_weighted_rigid_is_exact_on_rigid_motion_and_noise_tolerant():
    truth, nb = _limb_take()
    rigid_only = truth[:, :6]
    off, ind = nb
    keep = [(i, [j for j in ind[off[i] : off[i + 1]] if j < 6]) for i in range(6)]
    offsets = np.concatenate([[0], np.cumsum([len(v) for _, v in keep])]).astype(np.int64)
    indices = np.concatenate([v for _, v in keep]).astype(np.int64)
    gappy = rigid_only.copy()
    gappy[40:160, 0] = np.nan
    gappy[0:20, 4] = np.nan  # an edge run: one side only
    m = MarkerSet(gappy, [f"m{i}" for i in range(6)], 100.0)
    out, inv = fill_gaps(m, method="rigid_weighted", neighbours=(offsets, indices))
    np.testing.assert_allclose(out, rigid_only, atol=1e-9)
    assert inv.sum() == 140
    # 0.5 mm noise on equally rigid donors: the noise floor keeps the weights near
    # equal, so the fill is as good as the equal-weight one (measured 1.600 vs 1.596 mm)
    rng = np.random.default_rng(1)
    noisy = MarkerSet(gappy + rng.normal(0.0, 0.0005, gappy.shape), m.labels, 100.0)
    err = {}
    for method in ("rigid", "rigid_weighted"):
        out, _ = fill_gaps(noisy, method=method, neighbours=(offsets, indices))
        err[method] = np.linalg.norm(out[40:160, 0] - rigid_only[40:160, 0], axis=1).mean()
    assert err["rigid_weighted"] < 1.1 * err["rigid"] and err["rigid"] < 0.003, err


def test_local_pca_blend_uses_the_weighted_donors():
    truth, nb = _limb_take()
    gappy = truth.copy()
    gappy[100:180, 0] = np.nan
    m = MarkerSet(gappy, [f"m{i}" for i in range(8)], 100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        new, _ = fill_gaps(m, method="local_pca", neighbours=nb, rigid_blend=1.0)
        old, _ = fill_gaps(
            m, method="local_pca", neighbours=nb, rigid_blend=1.0, rigid_weighted=False
        )
    e_new = np.linalg.norm(new[100:180, 0] - truth[100:180, 0], axis=1).max()
    e_old = np.linalg.norm(old[100:180, 0] - truth[100:180, 0], axis=1).max()
    assert e_new < 0.0005 and e_old > 0.01, (e_new, e_old)


def test_weighted_rigid_beats_plain_rigid_on_real_walking():
    path = DATA / "kt_optitrack_walking.c3d"
    if not path.exists():
        pytest.skip("real take missing")
    markers = io.read(path)
    markers = markers.select(~markers.unlabelled)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        r = evaluate_fill(
            markers,
            methods=["rigid", "rigid_weighted", "local_pca"],
            gap_lengths=(30, 60, 90, 120),
            gaps=4,
            seed=0,
        )
    rmse = {m: r["results"][m]["all"]["mm"]["rmse"] for m in r["methods"]}
    # measured (seed 0, 4 gaps per length): rigid 4.04 mm, weighted 3.15, local PCA 2.20
    assert rmse["rigid_weighted"] < 0.9 * rmse["rigid"], rmse
    assert rmse["local_pca"] < 0.75 * rmse["rigid"], rmse


def test_frame_donors_use_a_neighbour_missing_for_part_of_the_gap():
    """Marker 0's only rigid donors besides two are missing for half its gap: the
    fixed-set fill is left with too few (NaN or a poor fit); per-frame donors use them
    where they are seen and stay exact on rigid motion."""
    truth, _ = _limb_take()
    rigid_only = truth[:, :6]
    offsets = np.arange(7, dtype=np.int64) * 5
    indices = np.array([[j for j in range(6) if j != i] for i in range(6)]).reshape(-1)
    gappy = rigid_only.copy()
    gappy[50:150, 0] = np.nan
    gappy[60:100, 1] = np.nan  # donors 1 and 2 each miss part of the gap
    gappy[110:140, 2] = np.nan
    target = np.zeros(gappy.shape[:2], dtype=bool)
    target[50:150, 0] = True
    fixed = fill_rigid(gappy, target, (offsets, indices))
    per_frame = fill_rigid(gappy, target, (offsets, indices), frame_donors=True)
    weighted = fill_rigid(gappy, target, (offsets, indices), weighted=True, frame_donors=True)
    np.testing.assert_allclose(per_frame[50:150, 0], rigid_only[50:150, 0], atol=1e-9)
    np.testing.assert_allclose(weighted[50:150, 0], rigid_only[50:150, 0], atol=1e-9)
    np.testing.assert_allclose(fixed[50:150, 0], rigid_only[50:150, 0], atol=1e-9)
    # with only two donors seen throughout, the fixed set cannot fill at all
    gappy[80:90, 3] = np.nan
    fixed = fill_rigid(gappy, target, (offsets, indices))
    per_frame = fill_rigid(gappy, target, (offsets, indices), frame_donors=True)
    assert np.isnan(fixed[50:150, 0]).all()
    np.testing.assert_allclose(per_frame[50:150, 0], rigid_only[50:150, 0], atol=1e-9)
