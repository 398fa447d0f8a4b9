"""C3D POINT listing: a converted file keeps the source's point order, every point's
description and the unit parameters it does not rewrite (checked with ezc3d)."""

from __future__ import annotations

import warnings
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from skincap.errors import UnitWarning
from skincap.io.c3d import read_c3d, write_c3d

DATA = Path(__file__).resolve().parents[1] / "data"
PIG = DATA / "btk_pig_calibration_hole_unlabeled_fragments.c3d"  # markers, angles, bones
ANALYSIS = DATA / "external" / "btk_vicon_analysis_model_outputs.c3d"  # model outputs only
SHD01 = DATA / "external" / "btk_shd01_units_without_outputs.c3d"  # *_UNITS, no outputs


def _convert(src: Path, tmp_path: Path) -> tuple[dict, dict]:
    """ezc3d's view of ``src`` and of skincap's C3D of it."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        markers = read_c3d(src)
    out = tmp_path / "out.c3d"
    write_c3d(markers, out)
    return ezc3d.c3d(str(src)), ezc3d.c3d(str(out))


@pytest.mark.parametrize("src", [PIG, ANALYSIS], ids=lambda p: p.name)
def test_points_go_out_in_the_source_order_with_their_descriptions(src, tmp_path):
    a, b = _convert(src, tmp_path)
    pa, pb = a["parameters"]["POINT"], b["parameters"]["POINT"]
    assert pb["LABELS"]["value"] == pa["LABELS"]["value"]
    assert pb["DESCRIPTIONS"]["value"] == pa["DESCRIPTIONS"]["value"]
    xa, xb = a["data"]["points"][:3], b["data"]["points"][:3]
    valid = a["data"]["meta_points"]["residuals"][0] >= 0
    valid &= ~(xa == 0).all(axis=0)  # skincap reads exact (0, 0, 0) as missing
    np.testing.assert_allclose(xb[:, valid], xa[:, valid], atol=1e-3)


def test_model_output_descriptions_are_kept(tmp_path):
    a, b = _convert(ANALYSIS, tmp_path)
    described = [d for d in a["parameters"]["POINT"]["DESCRIPTIONS"]["value"] if d.strip()]
    assert len(described) == 24
    assert (
        b["parameters"]["POINT"]["DESCRIPTIONS"]["value"]
        == a["parameters"]["POINT"]["DESCRIPTIONS"]["value"]
    )


def test_unit_parameters_without_outputs_are_kept(tmp_path):
    a, b = _convert(SHD01, tmp_path)
    for name in ("ANGLE_UNITS", "FORCE_UNITS", "MOMENT_UNITS", "POWER_UNITS", "SCALAR_UNITS"):
        assert name in a["parameters"]["POINT"]
        assert b["parameters"]["POINT"][name]["value"] == a["parameters"]["POINT"][name]["value"]
