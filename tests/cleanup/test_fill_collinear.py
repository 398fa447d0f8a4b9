"""Gap fills from nearly collinear neighbours: the frame's twist about their line falls
back on temporal continuity (skincap.cleanup.frame_continuity) instead of on noise."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.cleanup.fill import fill_gaps
from skincap.cleanup.fill_local import fill_local_pca
from skincap.cleanup.fill_rigid import fill_rigid
from skincap.cleanup.frame_continuity import (
    WELL_SPREAD,
    fit_rigid_with_prior,
    line_axis,
    twist_prior,
)
from skincap.cleanup.settings import FillSettings
from skincap.geometry.rigid import fit_rigid
from skincap.types import MarkerSet

NOISE = 0.0005  # metres per axis


def _segment_take(seed: int = 1):
    """A rigid segment turning about all three axes for 300 frames: marker 0 sits 40 mm
    off the line of neighbours 1-3 (1.5 mm spread over 100 mm), neighbour 4 off the line
    is missing around marker 0's 90-frame gap. Returns truth, noisy take, gap (s, e)."""
    rng = np.random.default_rng(seed)
    shape = np.array(
        [
            [0.0, 0.04, 0.0],
            [-0.05, 0.0, 0.0],
            [0.0, 0.0015, 0.0],
            [0.05, -0.0005, 0.001],
            [0.0, 0.035, 0.03],
        ]
    )
    t = np.linspace(0.0, 3.0, 300)
    rv = np.stack(
        [0.6 * np.sin(2.1 * t), 0.8 * np.sin(1.3 * t + 0.5), 0.9 * np.sin(1.7 * t + 1.0)], 1
    )
    rot = Rotation.from_rotvec(rv).as_matrix()
    trans = np.stack([0.3 * np.sin(t), 0.1 * t, 0.2 * np.cos(0.7 * t)], 1)
    truth = np.einsum("tij,nj->tni", rot, shape) + trans[:, None]
    noisy = truth + rng.normal(0.0, NOISE, truth.shape)
    s, e = 120, 210
    noisy[s:e, 0] = np.nan
    noisy[s - 10 : e + 10, 4] = np.nan
    return truth, noisy, (s, e)


def _all_neighbours(n: int):
    full = np.arange(n)
    return np.arange(n + 1) * (n - 1), np.concatenate([np.delete(full, i) for i in range(n)])


def _gap_error(filled: np.ndarray, truth: np.ndarray, s: int, e: int) -> float:
    return float(np.linalg.norm(filled[s:e, 0] - truth[s:e, 0], axis=1).mean())


def test_fill_from_nearly_collinear_neighbours_follows_the_truth():
    truth, noisy, (s, e) = _segment_take()
    csr = _all_neighbours(truth.shape[1])
    markers = MarkerSet(noisy, [f"m{i}" for i in range(truth.shape[1])], 100.0)
    target = np.zeros(noisy.shape[:2], dtype=bool)
    target[s:e, 0] = True
    errors = {}
    for method in ("local_pca", "rigid_weighted", "local_pca_window"):
        out, _ = fill_gaps(markers, FillSettings(method=method), neighbours=csr, only=target)
        errors[method] = _gap_error(out, truth, s, e)
    # each frame's fit alone: the noise turns the frame about the line (about 19 mm
    # mean error here); with the continuity prior about 2.7 mm
    alone = {
        "local_pca": fill_local_pca(noisy, target, csr, frame_prior=None),
        "rigid_weighted": fill_rigid(
            noisy, target, csr, weighted=True, frame_donors=True, frame_prior=None
        ),
    }
    for method, out in alone.items():
        before = _gap_error(out, truth, s, e)
        assert errors[method] < 0.25 * before, (method, errors[method], before)
    assert max(errors.values()) < 8 * NOISE, errors


def test_prior_leaves_well_spread_fits_unchanged():
    rng = np.random.default_rng(0)
    src = rng.normal(0.0, 0.05, (20, 6, 3))
    rot = Rotation.random(20, random_state=1).as_matrix()
    dst = np.einsum("sij,skj->ski", rot, src) + rng.normal(0.0, 1e-3, (20, 6, 3))
    w = np.ones((20, 6))
    prior = Rotation.random(20, random_state=2).as_matrix()  # far from the truth
    r0, t0 = fit_rigid(src, dst, weights=w)
    r1, t1 = fit_rigid_with_prior(src, dst, w, prior, noise=1e-3, twist_sd=0.05)
    _, cond = line_axis(src, w)
    wide = cond >= WELL_SPREAD  # spread a fifth of their length off a line: no pull at all
    assert wide.sum() > 10
    np.testing.assert_allclose(r1[wide], r0[wide], atol=1e-12)
    np.testing.assert_allclose(t1[wide], t0[wide], atol=1e-12)


def test_twist_prior_keeps_the_line_and_interpolates_the_twist():
    axis = np.tile([1.0, 0.0, 0.0], (3, 1))
    r_end = Rotation.from_rotvec([0.8, 0.0, 0.0]).as_matrix()  # a pure twist about the line
    fit = Rotation.from_rotvec([0.0, 0.0, 0.3]).as_matrix()  # the line turned in its plane
    q = twist_prior(
        np.stack([fit] * 3),
        axis,
        np.stack([np.eye(3)] * 3),
        np.stack([r_end] * 3),
        np.array([0.0, 0.5, 1.0]),
    )
    # the prior carries the line where the fit does
    np.testing.assert_allclose(q @ axis[0], np.stack([fit @ axis[0]] * 3), atol=1e-12)
    # and twists about it by 0, 0.4 and 0.8 rad
    twist = (Rotation.from_matrix(q) * Rotation.from_matrix(fit).inv()).magnitude()
    np.testing.assert_allclose(twist, [0.0, 0.4, 0.8], atol=1e-9)
