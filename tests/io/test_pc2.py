"""PC2 writer and reader: layout, round trips, streaming, axes, bad input, fuzz."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincap.errors import FormatError, OutputExistsError, SkincapError, ValidationError
from skincap.io.pc2 import PC2Cache, read_pc2, write_pc2
from skincap.types import MeshAnimation


def _independent_read(path):
    """Header fields and (T, V, 3) float32 points by a structured numpy read."""
    raw = path.read_bytes()
    sig, ver, n_pts, start, rate, n_smp = struct.unpack_from("<12siiffi", raw, 0)
    pts = np.frombuffer(raw, dtype="<f4", offset=32).reshape(n_smp, n_pts, 3)
    return sig, ver, n_pts, start, rate, n_smp, pts


def test_layout_and_round_trip(tmp_path, cylinder_animation):
    out = tmp_path / "c.pc2"
    write_pc2(cylinder_animation, out)
    frames = cylinder_animation.frames
    sig, ver, n_pts, start, rate, n_smp, pts = _independent_read(out)
    assert (sig, ver, n_pts, start, rate, n_smp) == (b"POINTCACHE2\0", 1, 108, 0.0, 1.0, 25)
    assert out.stat().st_size == 32 + 25 * 108 * 12
    np.testing.assert_array_equal(pts, frames.astype(np.float32))
    back = read_pc2(out)
    assert isinstance(back, PC2Cache)
    f, sample_rate, start_frame = back
    assert (sample_rate, start_frame) == (1.0, 0.0)
    np.testing.assert_allclose(f, frames, atol=3e-8)
    assert f.dtype == np.float64


def test_header_options_and_meta_first_frame(tmp_path, cylinder, cylinder_animation):
    anim = MeshAnimation(cylinder, cylinder_animation.frames, 24.0, meta={"first_frame": 101})
    out = tmp_path / "a.pc2"
    write_pc2(anim, out)
    assert read_pc2(out).start_frame == 101.0
    write_pc2(anim, out, force=True, start_frame=-3.5, sample_rate=0.5)
    back = read_pc2(out)
    assert (back.start_frame, back.sample_rate) == (-3.5, 0.5)


def test_axes_and_units(tmp_path, cylinder_animation):
    frames = cylinder_animation.frames
    out = tmp_path / "z.pc2"
    write_pc2(cylinder_animation, out, up="z", units="cm")
    pts = _independent_read(out)[-1]
    # Blender-native Z up: (x, y, z) -> (x, -z, y), in centimetres
    expect = np.stack([frames[..., 0], -frames[..., 2], frames[..., 1]], axis=-1) * 100.0
    np.testing.assert_allclose(pts, expect, rtol=1e-6, atol=1e-6)
    back = read_pc2(out, up="z", units="cm")
    np.testing.assert_allclose(back.frames, frames, atol=1e-7)
    with pytest.raises(ValidationError, match="up"):
        write_pc2(cylinder_animation, tmp_path / "bad.pc2", up="x")
    with pytest.raises(ValidationError, match="unit"):
        write_pc2(cylinder_animation, tmp_path / "bad.pc2", units="furlong")
    assert not (tmp_path / "bad.pc2").exists()


def test_streams_chunks(tmp_path, cylinder, cylinder_animation):
    frames = cylinder_animation.frames
    pulled = []

    def chunks():
        for s in range(0, frames.shape[0], 7):
            pulled.append(s)
            yield frames[s : s + 7]

    anim = MeshAnimation(cylinder, chunks(), 24.0, n_frames=frames.shape[0])
    out = tmp_path / "s.pc2"
    write_pc2(anim, out)
    assert pulled == [0, 7, 14, 21]
    np.testing.assert_allclose(read_pc2(out).frames, frames, atol=3e-8)


@pytest.mark.parametrize("n_frames", [20, 30])
def test_stream_with_wrong_length_leaves_nothing(tmp_path, cylinder, cylinder_animation, n_frames):
    frames = cylinder_animation.frames  # 25 frames
    anim = MeshAnimation(cylinder, iter([frames[:10], frames[10:]]), 24.0, n_frames=n_frames)
    out = tmp_path / "w.pc2"
    with pytest.raises(ValidationError, match="frames"):
        write_pc2(anim, out)
    assert list(tmp_path.iterdir()) == []


def test_refuses_nan_and_existing(tmp_path, cylinder, cylinder_animation):
    frames = cylinder_animation.frames.copy()
    frames[3, 5, 1] = np.nan
    with pytest.raises(ValidationError, match="frame 3"):
        write_pc2(MeshAnimation(cylinder, frames, 24.0), tmp_path / "n.pc2")
    out = tmp_path / "e.pc2"
    write_pc2(cylinder_animation, out)
    with pytest.raises(OutputExistsError):
        write_pc2(cylinder_animation, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.pc2"]


def test_empty_animation(tmp_path, cylinder):
    out = tmp_path / "empty.pc2"
    write_pc2(MeshAnimation(cylinder, np.zeros((0, cylinder.n_vertices, 3)), 24.0), out)
    back = read_pc2(out)
    assert back.frames.shape == (0, cylinder.n_vertices, 3)


def _valid_bytes(n_pts=4, n_smp=3):
    pts = np.arange(n_smp * n_pts * 3, dtype="<f4")
    return struct.pack("<12siiffi", b"POINTCACHE2\0", 1, n_pts, 0.0, 1.0, n_smp) + pts.tobytes()


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda b: b[:20], "truncated header"),
        (lambda b: b"POINTCACHE3\0" + b[12:], "signature"),
        (lambda b: b[:12] + struct.pack("<i", 2) + b[16:], "version"),
        (lambda b: b[:16] + struct.pack("<i", -1) + b[20:], "negative point count"),
        (lambda b: b[:20] + struct.pack("<f", np.inf) + b[24:], "startFrame"),
        (lambda b: b[:24] + struct.pack("<f", 0.0) + b[28:], "sampleRate"),
        (lambda b: b[:28] + struct.pack("<i", -2) + b[32:], "negative sample count"),
        (lambda b: b[:-4], "truncated"),
        (lambda b: b + b"\0\0\0\0", "trailing bytes"),
        (lambda b: b[:40] + struct.pack("<f", np.nan) + b[44:], "non-finite"),
    ],
)
def test_bad_files(tmp_path, mutate, match):
    bad = tmp_path / "bad.pc2"
    bad.write_bytes(mutate(_valid_bytes()))
    with pytest.raises(FormatError, match=match) as err:
        read_pc2(bad)
    assert str(bad) in str(err.value)


def test_nan_offset_and_missing_file(tmp_path):
    data = bytearray(_valid_bytes())
    data[40:44] = struct.pack("<f", np.nan)
    bad = tmp_path / "nan.pc2"
    bad.write_bytes(bytes(data))
    with pytest.raises(FormatError) as err:
        read_pc2(bad)
    assert err.value.offset == 40
    with pytest.raises(FormatError, match="no such file"):
        read_pc2(tmp_path / "missing.pc2")
    (tmp_path / "empty.pc2").write_bytes(b"")
    with pytest.raises(FormatError, match="empty"):
        read_pc2(tmp_path / "empty.pc2")


@settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    op=st.sampled_from(["flip", "insert", "delete", "truncate"]),
    pos=st.integers(min_value=0, max_value=200),
    byte=st.integers(min_value=0, max_value=255),
)
def test_fuzz_mutated_bytes(tmp_path, op, pos, byte):
    data = bytearray(_valid_bytes())
    pos = pos % len(data)
    if op == "flip":
        data[pos] ^= byte or 1
    elif op == "insert":
        data.insert(pos, byte)
    elif op == "delete":
        del data[pos]
    else:
        data = data[:pos]
    f = tmp_path / "fuzz.pc2"
    f.write_bytes(bytes(data))
    try:
        out = read_pc2(f)
    except SkincapError:
        return
    assert isinstance(out, PC2Cache)
    assert np.isfinite(out.frames).all()


def test_mesh_animation_pair_fails_whole(tmp_path, cylinder, cylinder_animation):
    """A .pc2 output is the cache and its rest OBJ: a failure in either leaves neither."""
    from skincap.io.mesh_animation_files import write_mesh_animation

    frames = cylinder_animation.frames.copy()
    frames[4, 0, 0] = np.nan  # the cache fails midway
    with pytest.raises(ValidationError, match="frame 4"):
        write_mesh_animation(MeshAnimation(cylinder, frames, 24.0), tmp_path / "a.pc2", force=False)
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "b.obj").write_text("# someone else's mesh\n")  # the OBJ fails after the cache
    with pytest.raises(OutputExistsError):
        write_mesh_animation(cylinder_animation, tmp_path / "b.pc2", force=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.obj"]
    assert (tmp_path / "b.obj").read_text() == "# someone else's mesh\n"
