"""C3D camera masks: which cameras saw each measured sample goes out as it came in.

Checked with ezc3d on the real files in tests/data whose samples carry camera bits.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from skincap.errors import UnitWarning
from skincap.io.c3d import read_c3d, write_c3d
from skincap.io.c3d.scan import INVENTED_MASK
from skincap.types import MarkerSet

DATA = Path(__file__).resolve().parents[1] / "data"
MASKED_FILES = [
    DATA / "c3dorg_sample01_Eb015pr.c3d",  # c3d.org sample01, PC float: 52 distinct masks
    DATA / "external" / "c3dorg_sample02_pc_int.c3d",  # integer file, mask 127 on invalid samples
]


def _read(path: Path) -> MarkerSet:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        return read_c3d(path)


def _ezc3d_masks(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N, T) int camera bits and (N, T) bool valid samples, as ezc3d reads ``path``."""
    c = ezc3d.c3d(str(path))
    masks = c["data"]["meta_points"]["camera_masks"]  # (7, N, T) bool
    bits = (masks.astype(np.int64) << np.arange(7)[:, None, None]).sum(0)
    pts = c["data"]["points"][:3]
    valid = ~np.isnan(pts).any(axis=0) & ~(pts == 0).all(axis=0)
    return bits, valid


@pytest.mark.parametrize("src", MASKED_FILES, ids=lambda p: p.name)
def test_convert_keeps_the_camera_mask_of_every_measured_sample(src, tmp_path):
    bits, valid = _ezc3d_masks(src)
    assert (bits[valid] > 0).mean() > 0.5  # the file does carry camera bits
    markers = _read(src)
    assert markers.camera_masks is not None
    out = tmp_path / "out.c3d"
    write_c3d(markers, out)
    out_bits, out_valid = _ezc3d_masks(out)
    np.testing.assert_array_equal(out_valid, valid)
    np.testing.assert_array_equal(out_bits[valid], bits[valid])
    again = _read(out)
    np.testing.assert_array_equal(again.camera_masks, markers.camera_masks)


def test_select_keeps_the_masks_of_its_columns():
    markers = _read(MASKED_FILES[0])
    part = markers.select([3, 1])
    np.testing.assert_array_equal(part.camera_masks, markers.camera_masks[:, [3, 1]])


def test_a_measured_sample_seen_by_all_seven_cameras_does_not_read_back_invented(tmp_path):
    markers = _read(MASKED_FILES[0])
    masks = markers.camera_masks.copy()
    present = ~markers.missing
    t0, n0 = np.argwhere(present)[0]
    masks[t0, n0] = INVENTED_MASK  # seen by every camera the format records
    invented = np.zeros_like(present)
    t1, n1 = np.argwhere(present)[-1]
    invented[t1, n1] = True
    markers = MarkerSet(
        positions=markers.positions,
        labels=markers.labels,
        rate=markers.rate,
        residuals=markers.residuals,
        invented=invented,
        meta=markers.meta,
        camera_masks=masks,
    )
    out = tmp_path / "out.c3d"
    write_c3d(markers, out)
    again = _read(out)
    np.testing.assert_array_equal(again.invented, invented)
    assert again.camera_masks[t0, n0] == INVENTED_MASK
    np.testing.assert_array_equal(again.camera_masks[~invented], masks[~invented])


def test_masks_outside_seven_bits_are_refused():
    with pytest.raises(Exception, match="camera_masks"):
        MarkerSet(
            positions=np.zeros((2, 1, 3)),
            labels=["A"],
            rate=100.0,
            camera_masks=np.full((2, 1), 200),
        )
