"""USD export: reopened with usd-core; the missing-dependency error without it."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from skincap.errors import MissingDependencyError, OutputExistsError, ValidationError
from skincap.io.usd import write_usd
from skincap.types import MeshAnimation


def _open(path):
    usd = pytest.importorskip("pxr.Usd", reason="usd-core (pxr) is not installed")
    from pxr import UsdGeom

    stage = usd.Stage.Open(str(path))
    return stage, UsdGeom


@pytest.mark.parametrize("suffix", [".usd", ".usda", ".usdc"])
def test_time_sampled_points(tmp_path, cylinder, cylinder_animation, suffix):
    pytest.importorskip("pxr", reason="usd-core (pxr) is not installed")
    out = tmp_path / f"bend{suffix}"
    write_usd(cylinder_animation, out)
    stage, UsdGeom = _open(out)
    assert stage.GetTimeCodesPerSecond() == 24.0
    assert stage.GetFramesPerSecond() == 24.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0.0, 24.0)
    assert UsdGeom.GetStageUpAxis(stage) == "Y"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/Root"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/cylinder"))
    assert mesh
    points = mesh.GetPointsAttr()
    assert points.GetTimeSamples() == [float(k) for k in range(25)]
    frames = cylinder_animation.frames
    for k in (0, 11, 24):
        np.testing.assert_allclose(np.array(points.Get(k)), frames[k], atol=3e-8)
        ext = np.array(mesh.GetExtentAttr().Get(k))
        np.testing.assert_allclose(ext, [frames[k].min(0), frames[k].max(0)], atol=3e-8)
    np.testing.assert_allclose(np.array(points.Get()), cylinder.vertices, atol=3e-8)
    # quads kept, no subdivision, UVs as a per-vertex primvar
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4] * cylinder.n_polygons
    np.testing.assert_array_equal(
        np.array(mesh.GetFaceVertexIndicesAttr().Get()), cylinder.polygon_indices
    )
    assert mesh.GetSubdivisionSchemeAttr().Get() == "none"
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == "vertex"
    np.testing.assert_allclose(np.array(st.Get()), cylinder.uv, atol=1e-7)
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]


def test_streamed_triangles_only(tmp_path, cylinder_animation):
    pytest.importorskip("pxr", reason="usd-core (pxr) is not installed")
    tri = type(cylinder_animation.rest)(
        vertices=cylinder_animation.rest.vertices,
        faces=cylinder_animation.rest.faces,
        meta={"name": "7 tri-mesh"},
    )
    frames = cylinder_animation.frames
    anim = MeshAnimation(tri, (frames[s : s + 8] for s in range(0, 25, 8)), 30.0, n_frames=25)
    calls = []
    out = tmp_path / "tri.usda"
    write_usd(anim, out, chunk=8, progress=lambda d, n: calls.append(d))
    assert calls == [8, 16, 24, 25]
    stage, UsdGeom = _open(out)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/_7_tri_mesh"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * tri.n_faces
    assert stage.GetTimeCodesPerSecond() == 30.0
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get(17)), frames[17], atol=3e-8)


def test_validation_and_existing(tmp_path, cylinder, cylinder_animation):
    pytest.importorskip("pxr", reason="usd-core (pxr) is not installed")
    with pytest.raises(ValidationError, match="usd"):
        write_usd(cylinder_animation, tmp_path / "x.abc")
    bad = cylinder_animation.frames.copy()
    bad[6] = np.nan
    with pytest.raises(ValidationError, match="frame 6"):
        write_usd(MeshAnimation(cylinder, bad, 24.0), tmp_path / "nan.usd")
    assert list(tmp_path.iterdir()) == []
    out = tmp_path / "a.usd"
    write_usd(cylinder_animation, out)
    with pytest.raises(OutputExistsError):
        write_usd(cylinder_animation, out)
    write_usd(cylinder_animation, out, force=True)


def test_missing_usd_core(tmp_path, cylinder_animation, monkeypatch):
    # a None entry in sys.modules makes "from pxr import ..." raise ImportError
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(MissingDependencyError, match=r"usd-core.*skincap\[usd\]"):
        write_usd(cylinder_animation, tmp_path / "a.usd")
    assert list(tmp_path.iterdir()) == []
