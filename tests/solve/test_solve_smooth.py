"""Temporal smoothing of solved poses against exact motions."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import SkincapWarning, ValidationError
from skincap.io import read
from skincap.solve import solve_markers
from skincap.solve.smooth import smooth_poses
from skincap.types import MarkerSet

RATE = 120.0


def _smooth_motion(t=480, s=3, turns=1.0):
    """Rotations turning about fixed axes (``turns`` full turns over the take) and a root path."""
    time = np.arange(t) / RATE
    axes = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])[:s]
    angle = 2 * np.pi * turns * time / time[-1]
    rot = Rotation.from_rotvec((angle[:, None, None] * axes).reshape(-1, 3)).as_matrix()
    root = np.stack([np.sin(time), 0.9 + 0.02 * np.cos(2 * time), 0.5 * time], axis=1)
    return rot.reshape(t, s, 3, 3), root


def _angle(a, b):
    rel = np.einsum("...ji,...jk->...ik", a, b)
    return Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude().reshape(a.shape[:-2])


def test_a_slow_motion_passes_through_including_full_turns():
    # a full turn crosses the quaternion sign flip at 180 deg: it must not show
    rot, root = _smooth_motion()
    got_rot, got_root = smooth_poses(rot, root, RATE, 6.0)
    inner = slice(30, -30)  # filtfilt's edges are padded, not exact
    assert _angle(got_rot, rot)[inner].max() < 1e-4
    assert np.abs(got_root - root)[inner].max() < 1e-5
    assert _angle(got_rot, rot).max() < 5e-3  # measured 4.0e-3 rad at the ends


def test_noise_above_the_cut_off_is_removed():
    rot, root = _smooth_motion()
    rng = np.random.default_rng(4)
    jitter = Rotation.from_rotvec(rng.normal(scale=0.02, size=(rot.size // 9, 3))).as_matrix()
    noisy_rot = jitter.reshape(rot.shape) @ rot
    noisy_root = root + rng.normal(scale=0.003, size=root.shape)
    got_rot, got_root = smooth_poses(noisy_rot, noisy_root, RATE, 6.0)
    before = np.sqrt(np.mean(_angle(noisy_rot, rot) ** 2))
    after = np.sqrt(np.mean(_angle(got_rot, rot) ** 2))
    assert after < 0.35 * before  # measured 0.23: 6 of the 60 Hz bandwidth kept
    assert np.sqrt(np.mean((got_root - root) ** 2)) < 0.35 * 0.003
    np.testing.assert_allclose(
        np.einsum("...ji,...jk->...ik", got_rot, got_rot), np.broadcast_to(np.eye(3), rot.shape),
        atol=1e-12,
    )  # fmt: skip


def test_bad_cut_offs_are_refused_and_short_takes_kept():
    rot, root = _smooth_motion(t=40)
    for bad in (0.0, -1.0, 60.0, 100.0):
        with pytest.raises(ValidationError, match="smoothing cut-off"):
            smooth_poses(rot, root, RATE, bad)
    short_rot, short_root = smooth_poses(rot[:10], root[:10], RATE, 6.0)
    np.testing.assert_array_equal(short_rot, rot[:10])
    bad_rot = rot.copy()
    bad_rot[3, 0, 0, 0] = np.nan
    with pytest.raises(ValidationError, match="finite"):
        smooth_poses(bad_rot, root, RATE, 6.0)


def test_smoothing_a_real_solve_keeps_its_residual_and_calms_its_poses(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        cmu = read(data_dir / "cmu_85_02.c3d")
        take = MarkerSet(cmu.positions[:240], cmu.labels, cmu.rate)
        raw = solve_markers(take, "cmu41")
        smooth = solve_markers(take, "cmu41", smooth_hz=6.0)
    assert smooth.report()["smoothing_hz"] == 6.0 and raw.report()["smoothing_hz"] is None

    def rms(r):
        return np.sqrt(np.nanmean(r.residuals**2))

    assert rms(smooth) < rms(raw) + 0.002  # a 6 Hz cut-off keeps the body's motion

    def roughness(r):  # frame-to-frame change of the frame-to-frame rotation
        step = _angle(r.rotations[1:], r.rotations[:-1])
        return np.mean(np.abs(np.diff(step, axis=0)))

    assert roughness(smooth) < 0.7 * roughness(raw)  # measured 0.53
