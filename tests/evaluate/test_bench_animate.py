"""``bench animate``: the scene is a true rigid chain and every figure is reported."""

from __future__ import annotations

import numpy as np
import pytest

from skincap.deform.dense._kernel_numpy import F32_TOLERANCE
from skincap.deform.dense.deformer import METHODS, DenseDeformer
from skincap.deform.dense.parts import part_frames
from skincap.evaluate.bench.animate import chain_scene, default_parts, run_animate_benchmark


def test_the_chain_scene_moves_each_part_rigidly_and_the_deformer_follows() -> None:
    scene = chain_scene(n_vertices=400, n_parts=4, n_markers=120, n_frames=5)
    assert scene["markers"].shape == (5, 120, 3)
    np.testing.assert_allclose(scene["alpha"].sum(1), 1.0)
    np.testing.assert_allclose(scene["beta"].sum(1), 1.0)
    deformer = DenseDeformer(
        part_frames(scene["reference"], scene["alpha"]), scene["vertices"], scene["beta"]
    )
    got = np.concatenate(list(deformer.deform(scene["markers"], "rigid")))
    # vertices wholly inside one part move with that part's transform
    inside = scene["beta"].max(1) == 1.0
    part = np.argmax(scene["beta"], 1)
    world = scene["transforms"][:, part]
    expected = np.einsum("tvab,vb->tva", world[..., :3, :3], scene["vertices"]) + world[..., :3, 3]
    np.testing.assert_allclose(got[:, inside], expected[:, inside], atol=1e-3)


def test_the_benchmark_deforms_with_seam_centres_and_seam_weights_as_a_rig_does() -> None:
    """The default path: every part has seam centres, seam weights are 1 at the joints
    and 0 inside a part, and the rig-style deformer still follows the rigid chain."""
    scene = chain_scene(n_vertices=600, n_parts=4, n_markers=120, n_frames=4)
    parts, seam = default_parts(scene)
    assert parts.has_seam_centres
    assert (parts.valid & ~parts.fitted).any(axis=1).all()  # every part has some
    assert seam.shape == scene["beta"].shape
    assert seam.min() == 0.0 and seam.max() == 1.0
    deformer = DenseDeformer(parts, scene["vertices"], scene["beta"], seam_weights=seam)
    inside = scene["beta"].max(1) == 1.0
    part = np.argmax(scene["beta"], 1)
    world = scene["transforms"][:, part]
    expected = np.einsum("tvab,vb->tva", world[..., :3, :3], scene["vertices"]) + world[..., :3, 3]
    rigid = np.concatenate(list(deformer.deform(scene["markers"], "rigid")))
    np.testing.assert_allclose(rigid[:, inside], expected[:, inside], atol=1e-3)
    # the quadratic and RBF fields of this coarse chain (a part's markers near a joint
    # move with the next part) bend the inside by ~4 mm RMS, 2.3 cm at worst, as
    # much as without seam centres (3.9 mm, 2.4 cm): bounded, never NaN
    full = np.concatenate(list(deformer.deform(scene["markers"], "quadratic_rbf")))
    assert np.isfinite(full).all()
    err = np.linalg.norm(full[:, inside] - expected[:, inside], axis=-1)
    assert np.sqrt((err**2).mean()) < 6e-3 and err.max() < 3e-2


@pytest.mark.slow  # numba compiles the LBS baseline and the dense kernel
def test_bench_reports_every_variant_on_both_backends_and_the_lbs_ratio() -> None:
    res = run_animate_benchmark(
        n_vertices=500,
        n_parts=3,
        n_markers=60,
        n_frames=4,
        repeat=1,
        rom_frames=20,
        first_call=False,
        registration=False,
    )
    for method in METHODS:
        for backend in ("numpy", "numba"):
            assert res["ms_per_frame"][f"{method}_{backend}"] > 0
            assert res["cpu_ms_per_frame"][f"{method}_{backend}"] > 0
            assert res["ratios"][f"{method}_{backend} / lbs_{backend}"] > 0
        # the benchmark's own agreement check between the kernels: each within
        # F32_TOLERANCE of the float64 reference (float32 RBF sums), to rounding without
        tolerance = 2 * F32_TOLERANCE if method.endswith("_rbf") else 1e-9
        assert res["max_abs_diff"][f"{method}_numba vs {method}_numpy"] < tolerance
    # the fits alone are part of every dense frame
    assert 0 < res["cpu_ms_per_frame"]["fits_quadratic_rbf"]
    assert res["ratios"]["fits_quadratic_rbf / quadratic_rbf_numpy"] > 0
    # and so is the vertex pass, timed alone on each backend
    for backend in ("numpy", "numba"):
        assert res["cpu_ms_per_frame"][f"vertices_quadratic_rbf_{backend}"] > 0
        share = res["ratios"][f"vertices_quadratic_rbf_{backend} / quadratic_rbf_{backend}"]
        assert share > 0
    assert res["first_call"] is None and res["seconds"]["registration"] is None
    assert res["seconds"]["segmentation"] > 0
    assert res["config"]["default_backend"] in ("numba", "numpy")
    assert any("ms/frame" in line for line in res["lines"])
