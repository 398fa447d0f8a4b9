"""clean keeps the camera masks of the measured samples it keeps, merged fragments too."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from skincap.cleanup.pipeline import clean_markers
from skincap.errors import UnitWarning
from skincap.io.c3d import read_c3d
from skincap.types import MarkerSet

EB015 = Path(__file__).resolve().parents[1] / "data" / "c3dorg_sample01_Eb015pr.c3d"


def _broken_take() -> tuple[MarkerSet, MarkerSet, int, slice]:
    """The real take with one marker's frames 150-299 moved into a fragment ``*99``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        take = read_c3d(EB015)
    col = take.labels.index("LSK2")
    run = slice(150, 300)
    pos = take.positions.copy()
    frag = np.full((take.n_frames, 1, 3), np.nan)
    frag[run, 0] = pos[run, col]
    pos[run, col] = np.nan
    cam = take.camera_masks.copy()
    frag_cam = np.zeros((take.n_frames, 1), dtype=np.uint8)
    frag_cam[run, 0] = cam[run, col]
    cam[run, col] = 0
    broken = MarkerSet(
        positions=np.concatenate([pos, frag], axis=1),
        labels=[*take.labels, "*99"],
        rate=take.rate,
        residuals=np.concatenate([take.residuals, np.full((take.n_frames, 1), np.nan)], 1),
        meta=take.meta,
        camera_masks=np.concatenate([cam, frag_cam], axis=1),
    )
    return take, broken, col, run


def test_clean_keeps_the_cameras_of_measured_and_merged_samples():
    take, broken, col, run = _broken_take()
    assert (take.camera_masks[run, col] > 0).mean() > 0.9
    cleaned, report = clean_markers(broken)
    assert report.merge.merged >= 1
    out = cleaned.labels.index("LSK2")
    kept = ~cleaned.missing[:, out] & ~cleaned.invented[:, out]
    assert kept[run].mean() > 0.9  # the fragment came back as measured samples
    np.testing.assert_array_equal(cleaned.camera_masks[kept, out], take.camera_masks[kept, col])
    # every other measured sample keeps its cameras; invented ones have none
    src = [take.labels.index(lab) for lab in cleaned.labels if lab in take.labels]
    dst = [cleaned.labels.index(lab) for lab in cleaned.labels if lab in take.labels]
    meas = ~cleaned.missing[:, dst] & ~cleaned.invented[:, dst]
    ref = take.camera_masks[:, src].copy()
    ref[run, src.index(col)] = take.camera_masks[run, col]
    np.testing.assert_array_equal(cleaned.camera_masks[:, dst][meas], ref[meas])
    assert (cleaned.camera_masks[cleaned.invented] == 0).all()
