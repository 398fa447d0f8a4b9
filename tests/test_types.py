from __future__ import annotations

import numpy as np
import pytest

from skincap.errors import ValidationError
from skincap.types import MarkerSet, Mesh, MeshAnimation, Motion, PointCloud, Skeleton, Skin


def _markers(t=5, n=3, seed=0):
    rng = np.random.default_rng(seed)
    return MarkerSet(rng.normal(size=(t, n, 3)), [f"m{i}" for i in range(n)], 100.0)


def test_markerset_shape_error_names_field_and_shapes():
    with pytest.raises(
        ValidationError, match=r"positions: expected shape \(\*, \*, 3\), got \(4, 2\)"
    ):
        MarkerSet(np.zeros((4, 2)), ["a", "b"], 100)


def test_markerset_counts_and_clock():
    ms = _markers(t=5, n=3)  # 100 Hz
    assert (ms.n_frames, ms.n_markers) == (5, 3)
    assert ms.duration == pytest.approx(0.05, abs=1e-15)
    np.testing.assert_allclose(ms.times, [0.0, 0.01, 0.02, 0.03, 0.04], rtol=0, atol=1e-15)


def test_markerset_label_count_and_uniqueness():
    with pytest.raises(ValidationError, match="expected 2 labels"):
        MarkerSet(np.zeros((1, 2, 3)), ["a"], 100)
    with pytest.raises(ValidationError, match="unique"):
        MarkerSet(np.zeros((1, 2, 3)), ["a", "a"], 100)


@pytest.mark.parametrize("rate", [0, -1, float("nan"), float("inf"), "x"])
def test_bad_rate(rate):
    with pytest.raises(ValidationError, match="rate"):
        MarkerSet(np.zeros((1, 1, 3)), ["a"], rate)


def test_rate_kept_exact():
    m = MarkerSet(np.zeros((1, 1, 3)), ["a"], 119.88011988011988)
    assert m.rate == 119.88011988011988


def test_partial_nan_sample_is_missing_as_a_whole_and_inf_rejected():
    p = np.zeros((2, 1, 3))
    p[1, 0, 2] = np.nan
    m = MarkerSet(p, ["a"], 50)
    assert m.missing.tolist() == [[False], [True]]
    assert np.isnan(m.positions[1, 0]).all()
    p[0, 0, 0] = np.inf
    with pytest.raises(ValidationError, match="infinite"):
        MarkerSet(p, ["a"], 50)


def test_residual_and_invented_shapes_checked():
    with pytest.raises(ValidationError, match=r"residuals: expected shape \(5, 3\)"):
        MarkerSet(np.zeros((5, 3, 3)), list("abc"), 10, residuals=np.zeros((5, 2)))
    with pytest.raises(ValidationError, match="invented"):
        MarkerSet(np.zeros((5, 3, 3)), list("abc"), 10, invented=np.zeros((4, 3)))


def test_pointcloud_roundtrip_through_markerset():
    m = _markers(6, 4)
    m.positions[2, 1] = np.nan
    m.positions[0, 3] = np.nan
    cloud = PointCloud.from_markerset(m)
    assert cloud.counts.tolist() == [3, 4, 3, 4, 4, 4]
    back = cloud.to_markerset()
    assert back.labels == m.labels
    np.testing.assert_array_equal(back.positions, m.positions)


def test_pointcloud_validation():
    with pytest.raises(ValidationError, match="last entry"):
        PointCloud(np.zeros((3, 3)), [0, 2], 10)
    with pytest.raises(ValidationError, match="non-decreasing"):
        PointCloud(np.zeros((3, 3)), [0, 2, 1, 3], 10)
    with pytest.raises(ValidationError, match="finite"):
        PointCloud(np.full((1, 3), np.nan), [0, 1], 10)
    with pytest.raises(ValidationError, match="ids"):
        PointCloud(np.zeros((2, 3)), [0, 2], 10).to_markerset()
    dup = PointCloud(np.zeros((2, 3)), [0, 2], 10, ids=[5, 5])
    with pytest.raises(ValidationError, match="appears 2 times in frame 0"):
        dup.to_markerset()


def test_skeleton_topological_order():
    with pytest.raises(ValidationError, match="joint 1 'b' has parent 2"):
        Skeleton(["a", "b", "c"], [-1, 2, 0], np.zeros((3, 3)))
    sk = Skeleton(["a", "b", "c"], [-1, 0, 1], np.zeros((3, 3)))
    assert sk.is_leaf.tolist() == [False, False, True]
    assert sk.children(0).tolist() == [1]


def test_motion_requires_unit_quaternions_and_matching_channels():
    sk = Skeleton(["a", "b"], [-1, 0], np.zeros((2, 3)))
    rot = np.zeros((3, 2, 4))
    rot[..., 3] = 1
    m = Motion(sk, rot, np.zeros((3, 2, 3)), 30.0)
    assert m.channels[1] == ()  # leaf -> end site by default
    rot[0, 0] = [0, 0, 0, 2]
    with pytest.raises(ValidationError, match="unit quaternions"):
        Motion(sk, rot, np.zeros((3, 2, 3)), 30.0)
    rot[0, 0] = [0, 0, 0, 1]
    with pytest.raises(ValidationError, match="invalid channels"):
        Motion(sk, rot, np.zeros((3, 2, 3)), 30.0, channels=[("Wrotation",), ()])


def test_mesh_and_skin_validation():
    v = np.eye(3)
    with pytest.raises(ValidationError, match="vertex indices must be in 0..2"):
        Mesh(v, [[0, 1, 3]])
    sk = Skeleton(["a"], [-1], np.zeros((1, 3)))
    with pytest.raises(ValidationError, match="sum to 1"):
        Skin(sk, np.zeros((3, 1)), np.full((3, 1), 0.5), np.eye(4)[None])
    skin = Skin(sk, np.zeros((3, 1)), np.ones((3, 1)), np.eye(4)[None])
    mesh = Mesh(v, [[0, 1, 2]], skin=skin)
    assert mesh.bounds.tolist() == [[0, 0, 0], [1, 1, 1]]
    with pytest.raises(ValidationError, match="cover 3 vertices"):
        Mesh(np.eye(4, 3), [[0, 1, 2]], skin=skin)


def test_mesh_animation_streams_chunks_and_checks_count():
    mesh = Mesh(np.eye(3), [[0, 1, 2]])
    frames = np.random.default_rng(1).normal(size=(10, 3, 3))
    anim = MeshAnimation(mesh, frames, 30)
    assert sum(c.shape[0] for c in anim.iter_chunks(4)) == 10
    streamed = MeshAnimation(mesh, (frames[i : i + 3] for i in range(0, 10, 3)), 30, n_frames=10)
    np.testing.assert_array_equal(np.concatenate(list(streamed.iter_chunks())), frames)
    short = MeshAnimation(mesh, iter([frames[:4]]), 30, n_frames=10)
    with pytest.raises(ValidationError, match="gave 4 frames"):
        list(short.iter_chunks())
    with pytest.raises(ValidationError, match="n_frames"):
        MeshAnimation(mesh, iter([]), 30)


def test_atomic_output_permissions_and_cleanup(tmp_path):
    import os

    from skincap.errors import OutputExistsError
    from skincap.io._common import atomic_output

    target = tmp_path / "out.txt"
    with atomic_output(target) as tmp:
        tmp.write_text("x")
    umask = os.umask(0)
    os.umask(umask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~umask)
    with pytest.raises(OutputExistsError):
        with atomic_output(target):
            pass
    with pytest.raises(RuntimeError):
        with atomic_output(target, force=True) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert target.read_text() == "x"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]
