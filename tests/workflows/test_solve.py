"""evaluate_solve names the --real capture an error comes from."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.io.trc import write_trc
from skincap.types import MarkerSet
from skincap.workflows.solve import evaluate_solve


def test_error_in_a_real_take_names_that_take(tmp_path):
    # three frames are too few to calibrate; the message must say which file
    short = tmp_path / "short_take.trc"
    positions = np.random.default_rng(0).normal(size=(3, 2, 3))
    write_trc(MarkerSet(positions=positions, labels=["LASI", "RASI"], rate=100.0), short)
    with pytest.raises(ValidationError, match=r"^.*short_take\.trc: the take has 3 frames"):
        evaluate_solve(tmp_path / "out", real=[short])
    assert not (tmp_path / "out").exists()
