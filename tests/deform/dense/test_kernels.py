"""The dense deformer's numba kernel against its NumPy reference, and the ``auto`` backend."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.backends import numba_available
from skincap.deform.dense import deformer as dense_deformer
from skincap.deform.dense.deformer import METHODS, DenseDeformer, fit_part_motion
from skincap.deform.dense.parts import part_frames
from skincap.errors import MissingDependencyError, ValidationError

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba cannot be imported")


def _random_take(seed: int, n_frames: int = 6) -> dict[str, np.ndarray]:
    """Four parts of 12-25 markers (some shared), non-rigid motion, gaps, one part unseen.

    Vertices belong to one to three parts; vertex 0 only to the unseen part.
    """
    rng = np.random.default_rng(seed)
    sizes = rng.integers(12, 26, size=4)
    centres = np.array([[0, 0, 0], [0.25, 0, 0], [0.5, 0.05, 0], [0.2, 0.3, 0.1]])
    ref = np.concatenate(
        [c + 0.07 * rng.normal(size=(n, 3)) for c, n in zip(centres, sizes, strict=True)]
    )
    owner = np.repeat(np.arange(4), sizes)
    alpha = np.zeros((ref.shape[0], 4))
    alpha[np.arange(ref.shape[0]), owner] = 1.0
    shared = rng.choice(np.flatnonzero(owner < 3), size=6, replace=False)
    alpha[shared, (owner[shared] + 1) % 3] = rng.uniform(0.2, 0.6, size=6)  # not into part 3
    rot = Rotation.random(n_frames, random_state=seed).as_matrix()
    bend = 0.3 * rng.normal(size=(n_frames, 1, 3)) * ref[None, :, :1] ** 2  # quadratic
    wobble = 0.003 * rng.normal(size=(n_frames, ref.shape[0], 3))  # for the RBF
    markers = np.einsum("tab,tnb->tna", rot, ref + bend + wobble) + rng.normal(
        size=(n_frames, 1, 3)
    )
    markers[rng.random(markers.shape[:2]) < 0.1] = np.nan  # gaps
    markers[:, owner == 3] = np.nan  # part 3 is never seen with three members
    vertices = np.concatenate([ref[owner == 3][:1], rng.uniform(-0.1, 0.6, size=(300, 3))])
    beta = rng.random((vertices.shape[0], 4)) * (rng.random((vertices.shape[0], 4)) < 0.5)
    beta[np.arange(1, vertices.shape[0]), rng.integers(0, 3, size=vertices.shape[0] - 1)] += 1.0
    beta[0] = [0, 0, 0, 1.0]
    return {
        "reference": ref,
        "alpha": alpha,
        "markers": markers,
        "vertices": vertices,
        "beta": beta,
    }


@needs_numba
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("method", METHODS)
def test_numba_equals_the_numpy_reference_on_random_parts(seed: int, method: str) -> None:
    take = _random_take(seed)
    parts = part_frames(take["reference"], take["alpha"])
    motion = fit_part_motion(take["markers"], parts, method)  # type: ignore[arg-type]
    assert np.abs(motion.rbf_weights).max() > 0 if method.endswith("_rbf") else True
    numpy_out = DenseDeformer(parts, take["vertices"], take["beta"], backend="numpy").deform_block(
        motion
    )
    numba_out = DenseDeformer(parts, take["vertices"], take["beta"], backend="numba").deform_block(
        motion
    )
    assert numpy_out.shape == numba_out.shape == (6, 301, 3)
    # the same NaN (vertex 0 has only the unseen part) and the same numbers elsewhere
    np.testing.assert_array_equal(np.isnan(numpy_out), np.isnan(numba_out))
    assert np.isnan(numpy_out[:, 0]).all() and np.isfinite(numpy_out[:, 1:]).all()
    np.testing.assert_allclose(numba_out, numpy_out, rtol=0, atol=1e-9)


@needs_numba
@pytest.mark.slow  # a synthetic capture (~5 s of CPU)
def test_numba_equals_the_numpy_reference_on_a_synthetic_take() -> None:
    """A jump-rope take of the procedural body with soft tissue: 17 true parts, the
    true skin's vertices weighted by the parts of their nearest markers."""
    from scipy.spatial import cKDTree

    from skincap.synth.generate import generate_capture
    from skincap.synth.inputs import build_body, build_motion

    body = build_body("procedural", n_vertices=2000)
    capture = generate_capture(body, build_motion(body, "jumprope", frames=8), rope="none")
    markers = capture.truth.positions  # (T, N, 3), soft tissue included
    names = sorted(set(capture.marker_parts))
    part = np.array([names.index(n) for n in capture.marker_parts])
    alpha = np.eye(len(names))[part]
    skin = np.asarray(capture.skin.frames)
    dist, nearest = cKDTree(markers[0]).query(skin[0], k=3)
    beta = np.zeros((skin.shape[1], len(names)))
    np.add.at(beta, (np.arange(skin.shape[1])[:, None], part[nearest]), 1.0 / (dist + 1e-3))
    parts = part_frames(markers[0], alpha)
    markers = markers.copy()
    markers[3, ::7] = np.nan  # gaps
    outputs = {}
    for backend in ("numpy", "numba"):
        deformer = DenseDeformer(parts, skin[0], beta, backend=backend)
        for method in METHODS:
            outputs[backend, method] = np.concatenate(list(deformer.deform(markers, method)))
    for method in METHODS:
        np.testing.assert_allclose(
            outputs["numba", method], outputs["numpy", method], rtol=0, atol=1e-9
        )
    # and the deformation follows the true skin (a broken kernel would not)
    error = np.linalg.norm(outputs["numba", "quadratic_rbf"] - skin, axis=-1)
    assert np.sqrt((error**2).mean()) < 0.02


@needs_numba
def test_auto_runs_numpy_while_the_kernel_compiles_then_takes_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from skincap import backends

    compiled = False
    started: list[str] = []
    monkeypatch.delenv("SKINCAP_COMPILE", raising=False)
    monkeypatch.setattr(backends, "kernel_ready", lambda dispatcher: compiled)
    monkeypatch.setattr(backends, "compile_in_background", lambda n, d: started.append(n) or True)
    monkeypatch.setattr(backends, "RECHECK_SECONDS", 0.0)
    take = _random_take(3)
    parts = part_frames(take["reference"], take["alpha"])
    motion = fit_part_motion(take["markers"], parts)
    d = DenseDeformer(parts, take["vertices"], take["beta"])
    assert d.backend == "numpy" and started == ["dense"]
    first = d.deform_block(motion)
    assert d.backend == "numpy"  # still compiling
    compiled = True
    second = d.deform_block(motion)
    assert d.backend == "numba"
    np.testing.assert_allclose(second, first, rtol=0, atol=1e-9)
    pinned = DenseDeformer(parts, take["vertices"], take["beta"], backend="numpy")
    pinned.deform_block(motion)
    assert pinned.backend == "numpy"


def test_without_numba_the_numpy_reference_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dense_deformer, "numba_available", lambda: False)
    take = _random_take(4)
    parts = part_frames(take["reference"], take["alpha"])
    d = DenseDeformer(parts, take["vertices"], take["beta"])
    assert d.backend == "numpy"
    assert np.isfinite(d.deform_block(fit_part_motion(take["markers"], parts))[:, 1:]).all()
    with pytest.raises(MissingDependencyError):
        DenseDeformer(parts, take["vertices"], take["beta"], backend="numba")
    with pytest.raises(ValidationError, match="backend"):
        DenseDeformer(parts, take["vertices"], take["beta"], backend="cuda")  # type: ignore[arg-type]


@needs_numba
def test_the_background_compile_warm_up_compiles_the_kernel() -> None:
    from skincap.backends import WARM_UPS, kernel_ready
    from skincap.deform.dense._kernel_numba import dense_dispatcher

    assert WARM_UPS["dense"] == "skincap.deform.dense.deformer:warm_up_kernel"
    dense_deformer.warm_up_kernel()
    assert kernel_ready(dense_dispatcher())
    # what the warm-up compiled is what a take runs: no second signature to compile
    take = _random_take(5)
    parts = part_frames(take["reference"], take["alpha"])
    deformer = DenseDeformer(parts, take["vertices"], take["beta"], backend="numba")
    for method in METHODS:
        list(deformer.deform(take["markers"], method, chunk=4))
    assert len(dense_dispatcher().signatures) == 1


def test_the_member_table_pads_whole_steps_with_zero_weights() -> None:
    """The numba kernel sums whole vector steps of members: the table is padded to a
    multiple of the step, every slot past a part's members weighs exactly 0 (also a
    stale weight beyond them), and the counts round up (0, no RBF, stays 0)."""
    from skincap.deform.dense._kernel_numba import MEMBER_LANES, _rbf_table

    rng = np.random.default_rng(0)
    k = 2 * MEMBER_LANES + 3
    centres = rng.normal(size=(2, 3, k, 3))
    weights = rng.normal(size=(2, 3, k, 3))  # nonzero everywhere, padding included
    members = np.array([k, 5, 0])
    scale = np.array([10.0, 20.0, 0.0])
    table, summed = _rbf_table(centres, weights, scale, members)
    assert table.shape == (2, 3, 6, 3 * MEMBER_LANES) and table.flags.c_contiguous
    np.testing.assert_array_equal(summed, [3 * MEMBER_LANES, MEMBER_LANES, 0])
    np.testing.assert_allclose(table[:, 0, :3, :k], np.swapaxes(centres[:, 0] * 10.0, -1, -2))
    np.testing.assert_allclose(table[:, 1, 3:, :5], np.swapaxes(weights[:, 1, :5] / 6.0, -1, -2))
    assert not table[:, 1, 3:, 5:].any() and not table[:, 2, 3:].any()
    assert not table[..., k:].any()
