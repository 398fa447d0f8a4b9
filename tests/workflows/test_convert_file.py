"""convert_file called from Python (a notebook, a batch runner): str paths, counts, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from skincap import io
from skincap.errors import FormatError, OutputExistsError, SkincapWarning
from skincap.workflows.convert_file import convert_file


def test_convert_c3d_to_trc_from_str_paths(tmp_path, data_dir):
    src = data_dir / "c3dorg_sample01_Eb015pr.c3d"
    dst = tmp_path / "sample.trc"
    with pytest.warns(SkincapWarning, match="16 analog channels"):  # TRC holds markers only
        counts = convert_file(str(src), str(dst))
    before, after = io.read(src), io.read(dst)
    assert counts == {"frames": before.n_frames}
    assert after.labels == before.labels
    np.testing.assert_allclose(after.positions, before.positions, atol=1e-5, equal_nan=True)
    with pytest.raises(OutputExistsError):
        convert_file(str(src), str(dst))


def test_convert_bvh_counts_joints_and_refuses_other_outputs(tmp_path, data_dir):
    src = data_dir / "bvhtoolbox_test_mocapbank.bvh"
    motion = io.read(src, units="cm")
    counts = convert_file(src, tmp_path / "copy.bvh", units="cm")
    assert counts == {"frames": motion.n_frames, "joints": motion.skeleton.n_joints}
    with pytest.raises(FormatError, match="a BVH converts to .bvh or .csv"):
        convert_file(src, tmp_path / "copy.trc", units="cm")
    with pytest.raises(FormatError, match="cannot write '.xyz'"):
        convert_file(src, tmp_path / "copy.xyz", units="cm")
    assert not (tmp_path / "copy.trc").exists() and not (tmp_path / "copy.xyz").exists()
