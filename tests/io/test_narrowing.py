"""Writers that store float32 refuse values beyond its range (issue #13 item 6)."""

from __future__ import annotations

import pytest

from skincap.errors import FormatError
from skincap.io.gltf.writer import write_glb
from skincap.io.pc2 import write_pc2
from skincap.types import MeshAnimation, Motion


def test_pc2_refuses_a_position_beyond_float32(tmp_path, cylinder, cylinder_animation):
    frames = cylinder_animation.frames.copy()
    frames[4, 7, 2] = 1e39
    out = tmp_path / "big.pc2"
    with pytest.raises(FormatError, match=r"frame 4, vertex 7, z: 1e\+39 m does not fit"):
        write_pc2(MeshAnimation(cylinder, frames, 24.0), out)
    assert list(tmp_path.iterdir()) == []
    # in range it writes: 3e38 is a float32
    frames[4, 7, 2] = 3e38
    write_pc2(MeshAnimation(cylinder, frames, 24.0), out)
    assert out.exists()


def test_glb_refuses_a_key_beyond_float32(tmp_path, cylinder, bend):
    translations = bend.translations.copy()
    translations[2, 0, 0] = -5e38
    moved = Motion(bend.skeleton, bend.rotations, translations, bend.rate, bend.channels)
    out = tmp_path / "big.glb"
    with pytest.raises(FormatError, match=r"-5e\+38 does not fit the file's float32"):
        write_glb(cylinder, moved, out)
    assert list(tmp_path.iterdir()) == []
