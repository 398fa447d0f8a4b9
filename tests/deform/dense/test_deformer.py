"""The dense-marker deformer (Park & Hodgins eqs. 6-9) against analytic motions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.backends import numba_available
from skincap.deform.dense.deformer import (
    METHODS,
    RBF_RIDGE,
    DenseDeformer,
    choose_quadratic_parts,
    fit_part_motion,
    held_frames,
    rbf_kernel_scales,
)
from skincap.deform.dense.parts import part_frames
from skincap.deform.dense.weights import seam_vertex_weights
from skincap.errors import ValidationError
from skincap.geometry.quadratic import QUADRATIC_TERMS, apply_quadratic
from skincap.geometry.rbf import evaluate_rbf

#: Every analytic test runs on the numba kernel and on its NumPy reference.
BACKENDS = ["numpy"] + (["numba"] if numba_available() else [])


def _blob(rng: np.random.Generator, n: int, centre: tuple[float, float, float]) -> np.ndarray:
    return np.asarray(centre) + 0.08 * rng.normal(size=(n, 3))


def _three_parts(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Reference markers of three parts (20 each) and hard weights α, 3 boundary markers shared."""
    ref = np.concatenate(
        [_blob(rng, 20, (0, 0, 0)), _blob(rng, 20, (0.3, 0, 0)), _blob(rng, 20, (0.6, 0, 0))]
    )
    alpha = np.zeros((60, 3))
    alpha[np.arange(60), np.arange(60) // 20] = 1.0
    alpha[[19, 39, 5]] = [[0.6, 0.4, 0.0], [0.0, 0.7, 0.3], [0.8, 0.0, 0.2]]
    return ref, alpha


def _rigid(rng: np.random.Generator, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    return Rotation.random(
        n_frames, random_state=int(rng.integers(1 << 30))
    ).as_matrix(), rng.normal(size=(n_frames, 3))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_rigid_motion_is_reproduced_exactly_by_every_variant(method: str, backend: str) -> None:
    rng = np.random.default_rng(0)
    ref, alpha = _three_parts(rng)
    rot, trans = _rigid(rng, 7)
    markers = np.einsum("tab,nb->tna", rot, ref) + trans[:, None]
    markers[2, [0, 1, 25]] = np.nan  # missing markers change nothing under a rigid motion
    vertices = _blob(rng, 200, (0.3, 0.0, 0.0))
    beta = rng.random((200, 3))
    deformer = DenseDeformer(part_frames(ref, alpha), vertices, beta, backend=backend)
    out = np.concatenate(list(deformer.deform(markers, method, chunk=3)))
    expected = np.einsum("tab,nb->tna", rot, vertices) + trans[:, None]
    np.testing.assert_allclose(out, expected, atol=1e-9)


@pytest.mark.parametrize("method", ["quadratic", "quadratic_rbf"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_pure_quadratic_field_is_reproduced_exactly(method: str, backend: str) -> None:
    rng = np.random.default_rng(1)
    ref = _blob(rng, 30, (0, 0, 0))
    parts = part_frames(ref, np.ones((30, 1)))
    a = np.zeros((3, QUADRATIC_TERMS))
    a[:, :3] = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    a[:, 3:9] = 0.5 * rng.normal(size=(3, 6))

    def field(points: np.ndarray) -> np.ndarray:  # the field acts in the part's frame
        local = parts.to_local(points, np.zeros(len(points), dtype=int))
        return apply_quadratic(a, local) @ parts.axes[0] + parts.origin[0]

    rot, trans = _rigid(rng, 4)
    markers = np.einsum("tab,nb->tna", rot, field(ref)) + trans[:, None]
    vertices = _blob(rng, 100, (0, 0, 0))
    expected = np.einsum("tab,nb->tna", rot, field(vertices)) + trans[:, None]
    deformer = DenseDeformer(parts, vertices, np.ones((100, 1)), backend=backend)
    out = np.concatenate(list(deformer.deform(markers, method, quadratic_regularisation=0.0)))
    np.testing.assert_allclose(out, expected, atol=1e-9)
    rigid = np.concatenate(list(deformer.deform(markers, "rigid")))
    assert np.abs(rigid - expected).max() > 1e-3  # the field is far from rigid


@pytest.mark.parametrize("method", ["rigid_rbf", "quadratic_rbf"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_rbf_variants_pass_through_every_marker(method: str, backend: str) -> None:
    """Unregularised (the paper's eq. 7), the RBF reproduces every marker exactly."""
    rng = np.random.default_rng(2)
    ref = np.stack(np.meshgrid(np.arange(5), np.arange(4), np.arange(2), indexing="ij"), -1)
    ref = 0.05 * ref.reshape(-1, 3).astype(float) + 0.004 * rng.normal(size=(40, 3))
    parts = part_frames(ref, np.ones((40, 1)))
    rot, trans = _rigid(rng, 5)
    wobble = ref + 0.004 * rng.normal(size=(5, 40, 3))  # non-rigid, non-quadratic
    markers = np.einsum("tab,tnb->tna", rot, wobble) + trans[:, None]
    deformer = DenseDeformer(
        parts, ref, np.ones((40, 1)), backend=backend, precision="float64"
    )  # the markers as vertices (float64 sums: "mixed" agrees to 1e-6 m, test_kernels)
    out = np.concatenate(list(deformer.deform(markers, method, rbf_regularisation=0.0)))
    np.testing.assert_allclose(out, markers, atol=1e-9)
    rigid = np.concatenate(list(deformer.deform(markers, "rigid")))
    assert np.abs(rigid - markers).max() > 1e-3


@pytest.mark.parametrize("method", ["rigid_rbf", "quadratic_rbf"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_regularised_rbf_follows_a_smooth_bulge_closely(method: str, backend: str) -> None:
    """The default (a small ridge) and a ridge chosen by cross-validation pass near
    every marker of a smooth soft-tissue bulge: far closer than the rigid fit."""
    rng = np.random.default_rng(2)
    ref = np.stack(np.meshgrid(np.arange(5), np.arange(4), np.arange(2), indexing="ij"), -1)
    ref = 0.05 * ref.reshape(-1, 3).astype(float) + 0.004 * rng.normal(size=(40, 3))
    parts = part_frames(ref, np.ones((40, 1)))
    rot, trans = _rigid(rng, 5)
    amplitude = 0.01 * np.sin(np.arange(5))[:, None, None]  # breathes over the frames
    bump = np.exp(-((ref - ref.mean(0)) ** 2).sum(1) / 0.01)[None, :, None] * [0.0, 0.0, 1.0]
    markers = np.einsum("tab,tnb->tna", rot, ref + amplitude * bump) + trans[:, None]
    deformer = DenseDeformer(parts, ref, np.ones((40, 1)), backend=backend)
    rigid = np.concatenate(list(deformer.deform(markers, "rigid")))
    rigid_off = np.abs(rigid - markers).max()
    out = np.concatenate(list(deformer.deform(markers, method)))
    assert np.abs(out - markers).max() < 0.002 * rigid_off  # measured: 6e-6, 3e-6
    gcv = np.concatenate(list(deformer.deform(markers, method, rbf_regularisation="gcv")))
    assert np.abs(gcv - markers).max() < 0.1 * rigid_off  # measured: 0.005, 3e-12


def _wide_kernel_part(rng: np.random.Generator) -> tuple[np.ndarray, object]:
    """A 6 x 5 x 3 marker lattice as one part whose σ sits where its kernel matrix's
    smallest eigenvalue crosses zero: an irregular part's wide σ, made exact."""
    from dataclasses import replace

    from scipy.optimize import brentq

    from skincap.geometry.rbf import evaluate_rbf

    g = np.stack(np.meshgrid(np.arange(6), np.arange(5), np.arange(3), indexing="ij"), -1)
    ref = 0.04 * g.reshape(-1, 3).astype(float) + 0.006 * rng.normal(size=(90, 3))
    parts = part_frames(ref, np.ones((90, 1)))
    local = parts.local_reference[0]

    def smallest(sigma: float) -> float:
        return float(np.linalg.eigvalsh(evaluate_rbf(local, np.eye(90), sigma, local))[0])

    grid = np.linspace(0.08, 0.3, 45)
    values = [smallest(x) for x in grid]
    i = next(i for i in range(len(grid) - 1) if values[i] > 0 > values[i + 1])
    sigma = brentq(smallest, grid[i], grid[i + 1]) * (1 + 1e-3)  # |λ| ~6e-6 of the largest
    return ref, replace(parts, sigma=np.array([sigma]))


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_near_singular_part_kernel_no_longer_throws_vertices(backend: str) -> None:
    """The defect of the demo's 12-frame rig in miniature: exact interpolation of a 2 cm
    bulge through a near-singular kernel throws vertices between the markers tens of
    cm; the regularised fits (the default ridge, and GCV's) keep every vertex closer
    than the rigid fit (10.8 mm)."""
    rng = np.random.default_rng(40)
    ref, parts = _wide_kernel_part(rng)
    rot, trans = _rigid(rng, 4)
    bump = np.exp(-((ref - ref.mean(0)) ** 2).sum(1) / 0.01)[:, None] * [0.0, 0.0, 0.02]
    amplitude = np.array([0.0, 1.0, -0.7, 0.4])[:, None, None]
    noise = 0.001 * rng.normal(size=(4, 90, 3))  # soft tissue is not a perfect bump
    markers = np.einsum("tab,tnb->tna", rot, ref + amplitude * bump + noise) + trans[:, None]
    vertices = ref.min(0) + (ref.max(0) - ref.min(0)) * rng.random((2000, 3))
    vbump = np.exp(-((vertices - ref.mean(0)) ** 2).sum(1) / 0.01)[:, None] * [0.0, 0.0, 0.02]
    truth = np.einsum("tab,tnb->tna", rot, vertices + amplitude * vbump) + trans[:, None]
    deformer = DenseDeformer(parts, vertices, np.ones((2000, 1)), backend=backend)
    for method in ("rigid_rbf", "quadratic_rbf"):
        exact = np.concatenate(list(deformer.deform(markers, method, rbf_regularisation=0.0)))
        assert np.linalg.norm(exact - truth, axis=-1).max() > 0.1  # measured: 0.14-0.34 m
        for regularisation in (RBF_RIDGE, "gcv"):
            out = np.concatenate(
                list(deformer.deform(markers, method, rbf_regularisation=regularisation))
            )
            assert np.linalg.norm(out - truth, axis=-1).max() < 0.008  # measured: 3.8-5.9 mm


def test_the_ridge_is_chosen_once_per_take_not_per_chunk() -> None:
    """With "gcv", deform() chooses each part's ridge over the whole take: chunking
    changes nothing, and fit_part_motion reports the ridges it used (none when exact)."""
    rng = np.random.default_rng(41)
    ref, alpha = _three_parts(rng)
    rot, trans = _rigid(rng, 9)
    markers = np.einsum("tab,tnb->tna", rot, ref + 0.004 * rng.normal(size=(9, 60, 3)))
    markers += trans[:, None]
    vertices = _blob(rng, 50, (0.3, 0.0, 0.0))
    deformer = DenseDeformer(part_frames(ref, alpha), vertices, rng.random((50, 3)))
    for method in ("rigid_rbf", "quadratic_rbf"):
        whole = np.concatenate(
            list(deformer.deform(markers, method, chunk=100, rbf_regularisation="gcv"))
        )
        chunked = np.concatenate(
            list(deformer.deform(markers, method, chunk=2, rbf_regularisation="gcv"))
        )
        np.testing.assert_allclose(chunked, whole, atol=1e-12)
        motion = fit_part_motion(markers, deformer.parts, method, rbf_regularisation="gcv")
        assert motion.rbf_ridge is not None and motion.rbf_ridge.shape == (2, 3)
        assert (
            fit_part_motion(markers, deformer.parts, method, rbf_regularisation=0).rbf_ridge is None
        )
        given = fit_part_motion(
            markers, deformer.parts, method, rbf_regularisation=motion.rbf_ridge
        )
        np.testing.assert_allclose(given.rbf_weights, motion.rbf_weights, atol=1e-15)
    with pytest.raises(ValidationError, match="rbf_regularisation"):
        fit_part_motion(markers, deformer.parts, "rigid_rbf", rbf_regularisation="loo")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="rbf_regularisation"):
        fit_part_motion(markers, deformer.parts, "rigid_rbf", rbf_regularisation=np.ones(4))
    with pytest.raises(ValidationError, match="rbf_regularisation"):
        fit_part_motion(markers, deformer.parts, "rigid_rbf", rbf_regularisation=-1.0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_part_without_three_markers_is_held_and_never_nan(backend: str) -> None:
    rng = np.random.default_rng(3)
    ref, alpha = _three_parts(rng)
    rot, trans = _rigid(rng, 6)
    markers = np.einsum("tab,nb->tna", rot, ref) + trans[:, None]
    markers[3:5, 40:60] = np.nan  # part 2 unseen in frames 3-4 (its boundary marker 5 too)
    markers[3:5, 5] = np.nan
    present = np.isfinite(markers[:, part_frames(ref, alpha).members]).all(-1)
    src = held_frames(present & part_frames(ref, alpha).valid)
    np.testing.assert_array_equal(src[:, 2], [0, 1, 2, 2, 2, 5])
    vertices = _blob(rng, 50, (0.6, 0.0, 0.0))
    beta = np.zeros((50, 3))
    beta[:, 2] = 1.0
    deformer = DenseDeformer(part_frames(ref, alpha), vertices, beta, backend=backend)
    out = np.concatenate(list(deformer.deform(markers, "quadratic_rbf", chunk=2)))
    assert np.isfinite(out).all()
    held = np.einsum("ab,nb->na", rot[2], vertices) + trans[2]
    np.testing.assert_allclose(out[3], held, atol=1e-9)
    np.testing.assert_allclose(out[4], held, atol=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_part_never_seen_gives_nan_only_where_it_alone_rules(backend: str) -> None:
    rng = np.random.default_rng(4)
    ref, alpha = _three_parts(rng)
    markers = np.repeat(ref[None], 3, axis=0)
    markers[:, 40:60] = np.nan
    markers[:, 5] = np.nan
    beta = np.array([[0, 0, 1.0], [0, 0.5, 0.5]])
    deformer = DenseDeformer(part_frames(ref, alpha), ref[[50, 30]], beta, backend=backend)
    out = np.concatenate(list(deformer.deform(markers)))
    assert np.isnan(out[:, 0]).all()
    np.testing.assert_allclose(out[:, 1], np.repeat(ref[None, 30], 3, axis=0), atol=1e-9)


def test_bad_inputs_are_refused() -> None:
    rng = np.random.default_rng(5)
    ref, alpha = _three_parts(rng)
    parts = part_frames(ref, alpha)
    with pytest.raises(ValidationError, match="method"):
        fit_part_motion(ref[None], parts, "cubic")
    with pytest.raises(ValidationError, match="positions"):
        fit_part_motion(ref, parts)
    with pytest.raises(ValidationError, match="vertex_weights"):
        DenseDeformer(parts, ref, np.ones((60, 2)))
    with pytest.raises(ValidationError, match="no part"):
        DenseDeformer(parts, ref, np.zeros((60, 3)))
    with pytest.raises(ValidationError, match="no member"):
        part_frames(ref, np.concatenate([alpha, np.zeros((60, 1))], axis=1))


def _two_part_strip(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 8x4 marker grid strip (x, z), split at x = 3.5 into two parts, and its triangles."""
    i, j = np.meshgrid(np.arange(8), np.arange(4), indexing="ij")
    ref = 0.05 * np.stack([i, 0.2 * rng.random(i.shape), j], -1).reshape(-1, 3).astype(float)
    alpha = np.zeros((32, 2))
    alpha[np.arange(32), (i.ravel() >= 4).astype(int)] = 1.0
    quad = (i[:-1, :-1] * 4 + j[:-1, :-1]).ravel()
    faces = np.concatenate(
        [np.stack([quad, quad + 4, quad + 1], 1), np.stack([quad + 1, quad + 4, quad + 5], 1)]
    )
    return ref, alpha, faces


def test_seam_centres_are_rbf_centres_only() -> None:
    rng = np.random.default_rng(6)
    ref, alpha, faces = _two_part_strip(rng)
    plain = part_frames(ref, alpha)
    seam = part_frames(ref, alpha, surface_faces=faces)
    for p, other_column in ((0, 4), (1, 3)):
        fitted = seam.members[p, seam.fitted[p]]
        extra = seam.members[p, seam.valid[p] & ~seam.fitted[p]]
        np.testing.assert_array_equal(fitted, plain.members[p, plain.valid[p]])
        # the seam centres are the other part's column next to the seam
        np.testing.assert_array_equal(np.sort(extra), other_column * 4 + np.arange(4))
        assert seam.valid[p, : fitted.size + extra.size].all()  # members, then seam centres
    np.testing.assert_allclose(seam.sigma, plain.sigma)
    np.testing.assert_allclose(seam.origin, plain.origin)
    # a bend at the seam: the fits of a part do not see the other side's markers
    markers = np.repeat(ref[None], 3, axis=0)
    markers[1:, 16:, 1] += 0.03 * (ref[16:, 0] - 0.175)[None] / 0.2
    for method in ("rigid", "quadratic"):
        a, b = fit_part_motion(markers, plain, method), fit_part_motion(markers, seam, method)
        np.testing.assert_allclose(b.rotation, a.rotation, atol=1e-12)
        np.testing.assert_allclose(b.quadratic, a.quadratic, atol=1e-12)


@pytest.mark.parametrize("method", ["rigid_rbf", "quadratic_rbf"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_part_field_passes_through_its_seam_centres(method: str, backend: str) -> None:
    """Each part alone reproduces the markers across its seam; a seam vertex blended
    half-half lands on the measured surface, which it misses without seam centres."""
    rng = np.random.default_rng(7)
    ref, alpha, faces = _two_part_strip(rng)
    rot, trans = _rigid(rng, 4)
    bent = ref + 0.02 * np.maximum(ref[:, 0] - 0.15, 0.0)[:, None] / 0.2 * [0.0, 1.0, 0.0]
    bent = bent + 0.002 * rng.normal(size=(4, 32, 3))
    markers = np.einsum("tab,tnb->tna", rot, bent) + trans[:, None]
    seam_columns = np.r_[12:20]  # the two columns either side of the seam
    for p in (0, 1):  # the markers as vertices of one part only
        beta = np.zeros((8, 2))
        beta[:, p] = 1.0
        parts = part_frames(ref, alpha, surface_faces=faces)
        out = DenseDeformer(parts, ref[seam_columns], beta, backend=backend, precision="float64")
        got = np.concatenate(list(out.deform(markers, method, rbf_regularisation=0.0)))
        np.testing.assert_allclose(got, markers[:, seam_columns], atol=1e-9)
    # a point on the seam, halfway between the columns, with half weight for each part
    mid = 0.5 * (ref[12:16] + ref[16:20])
    half = np.full((4, 2), 0.5)
    truth = 0.5 * (markers[:, 12:16] + markers[:, 16:20])
    errors = {}
    for name, extra in (("seam", faces), ("plain", None)):
        deformer = DenseDeformer(
            part_frames(ref, alpha, surface_faces=extra), mid, half, backend=backend
        )
        got = np.concatenate(list(deformer.deform(markers, method, rbf_regularisation=0.0)))
        errors[name] = np.abs(got - truth).max()
    # measured: 0.56 (quadratic_rbf) and less (rigid_rbf) of the error without them
    assert errors["seam"] < 0.75 * errors["plain"]


def test_seam_weights_are_one_at_the_seam_and_zero_inside() -> None:
    rng = np.random.default_rng(8)
    ref, alpha, faces = _two_part_strip(rng)
    # vertices at triangle centroids: the seam is between columns 3 and 4
    centroids = ref[faces].mean(axis=1)
    seam = seam_vertex_weights(centroids, ref, faces, alpha > 0)
    column = np.floor(centroids[:, 0] / 0.05 + 1e-9).astype(int)  # left column of the triangle
    np.testing.assert_allclose(seam[column == 3], 1.0)  # triangles across the seam
    np.testing.assert_allclose(seam[column <= 1], 0.0)  # inside either part
    np.testing.assert_allclose(seam[column >= 5], 0.0)
    assert ((seam[column == 2] > 0) & (seam[column == 2] < 1)).any()  # continuous between


@pytest.mark.parametrize("backend", BACKENDS)
def test_seam_weights_choose_between_the_two_fields(backend: str) -> None:
    """Seam weight 0 is the members-only deformer, 1 the deformer through the seam
    centres, and the numba kernel and its NumPy reference agree on both halves."""
    rng = np.random.default_rng(9)
    ref, alpha, faces = _two_part_strip(rng)
    rot, trans = _rigid(rng, 3)
    wobble = ref + 0.01 * np.maximum(ref[:, 0] - 0.15, 0.0)[:, None] * rng.normal(size=(3, 32, 3))
    markers = np.einsum("tab,tnb->tna", rot, wobble) + trans[:, None]
    vertices = ref + 0.01 * rng.normal(size=ref.shape)
    beta = rng.random((32, 2))
    plain = part_frames(ref, alpha)
    seam = part_frames(ref, alpha, surface_faces=faces)
    for method in ("rigid_rbf", "quadratic_rbf"):
        runs = {
            name: np.concatenate(list(DenseDeformer(parts, vertices, beta, **kw, backend=backend).deform(markers, method)))
            for name, parts, kw in (
                ("plain", plain, {}),
                ("zero", seam, {"seam_weights": np.zeros((32, 2))}),
                ("one", seam, {"seam_weights": np.ones((32, 2))}),
                ("default", seam, {}),
            )
        }  # fmt: skip
        np.testing.assert_allclose(runs["zero"], runs["plain"], atol=1e-9)
        np.testing.assert_allclose(runs["default"], runs["one"], atol=1e-12)
        assert np.abs(runs["one"] - runs["plain"]).max() > 1e-4
        half = np.full((32, 2), 0.5)
        both = [
            np.concatenate(
                list(DenseDeformer(seam, vertices, beta, seam_weights=half, backend=b).deform(markers, method))
            )
            for b in (backend, "numpy")
        ]  # fmt: skip
        np.testing.assert_allclose(both[0], both[1], atol=1e-9)
    with pytest.raises(ValidationError, match="seam_weights"):
        DenseDeformer(seam, vertices, beta, seam_weights=np.full((32, 2), 2.0))


def test_rigid_rbf_fits_with_fixed_centres_equal_the_plain_fit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """rigid_rbf's RBF centres are the rest positions at every frame, so both of its
    exact fits (members, seam centres) downdate one inverse per part: the weights equal
    fit_rbf's, with markers missing at random frames."""
    import skincap.deform.dense.deformer as deformer_module
    from skincap.geometry.rbf import fit_rbf

    rng = np.random.default_rng(21)
    ref, alpha, faces = _two_part_strip(rng)
    parts = part_frames(ref, alpha, surface_faces=faces)
    rot, trans = _rigid(rng, 12)
    bent = ref + 0.004 * rng.normal(size=(12, 32, 3))
    markers = np.einsum("tab,tnb->tna", rot, bent) + trans[:, None]
    markers[rng.random((12, 32)) < 0.06] = np.nan
    got = fit_part_motion(markers, parts, "rigid_rbf", rbf_regularisation=0.0)

    def plain(centres, values, sigma, mask):  # type: ignore[no-untyped-def]
        return fit_rbf(centres[None], values, sigma[None], mask)

    monkeypatch.setattr(deformer_module, "fit_rbf_fixed_centres", plain)
    want = fit_part_motion(markers, parts, "rigid_rbf", rbf_regularisation=0.0)
    assert got.member_rbf_weights is not None and want.member_rbf_weights is not None
    assert np.abs(want.rbf_weights).max() > 1e-4  # the fields are not trivial
    scale = np.abs(want.rbf_weights).max()
    np.testing.assert_allclose(got.rbf_weights, want.rbf_weights, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(
        got.member_rbf_weights, want.member_rbf_weights, rtol=0, atol=1e-9 * scale
    )


@pytest.mark.parametrize("method", ["rigid_rbf", "quadratic_rbf"])
def test_the_ridge_fits_solve_their_normal_equations_with_the_rest_scale(method: str) -> None:
    """Each part's RBF weights at each frame minimise ||Φ w - r||² + μ ||w||² with
    μ = ρ max|λ(Φ at rest)|² (rbf_kernel_scales): (Φ² + μ I) w = Φ r over the
    present centres, with markers missing at random, for both fields of a part."""
    rng = np.random.default_rng(22)
    ref, alpha, faces = _two_part_strip(rng)
    parts = part_frames(ref, alpha, surface_faces=faces)
    rot, trans = _rigid(rng, 6)
    bent = ref + 0.004 * rng.normal(size=(6, 32, 3))
    markers = np.einsum("tab,tnb->tna", rot, bent) + trans[:, None]
    markers[rng.random((6, 32)) < 0.1] = np.nan
    rho = 1e-3  # strong enough that a wrong μ shows
    motion = fit_part_motion(markers, parts, method, rbf_regularisation=rho)
    scales = rbf_kernel_scales(parts)
    assert scales.shape == (2, 2) and (scales > 0).all()
    assert motion.member_rbf_weights is not None
    for t in range(6):
        for p in range(2):
            cols = parts.members[p]
            local = markers[t, cols] @ motion.rotation[t, p].T + motion.translation[t, p]
            for field, weights, use in (
                (0, motion.rbf_weights, parts.valid[p]),
                (1, motion.member_rbf_weights, parts.fitted[p]),
            ):
                present = use & np.isfinite(local).all(-1)
                c = motion.centres[t, p, present]
                r = local[present] - c
                w = weights[t, p, present]
                phi = evaluate_rbf(c, np.eye(len(c)), parts.sigma[p], c)
                mu = rho * scales[field, p] ** 2
                lhs = phi @ (phi @ w) + mu * w
                np.testing.assert_allclose(lhs, phi @ r, rtol=0, atol=1e-10 * np.abs(r).max())
                assert (weights[t, p, ~present] == 0).all()
    with pytest.raises(ValidationError, match="rbf_kernel_scale"):
        fit_part_motion(markers, parts, method, rbf_kernel_scale=np.ones((2, 3)))


def _bent_and_noisy_parts(rng: np.random.Generator, n_frames: int) -> tuple[np.ndarray, ...]:
    """Part 0: 40 markers on a 0.4 m bar bent by a growing quadratic field; part 1: 10
    markers of a small rigid block measured with 1 mm noise. Returns ref, alpha, markers."""
    bar = np.column_stack(
        [rng.uniform(-0.2, 0.2, 40), rng.uniform(-0.04, 0.04, 40), rng.uniform(-0.04, 0.04, 40)]
    )
    block = np.array([0.6, 0.0, 0.0]) + rng.uniform(-0.03, 0.03, (10, 3)) * [2.0, 1.0, 1.0]
    ref = np.concatenate([bar, block])
    alpha = np.zeros((50, 2))
    alpha[:40, 0] = alpha[40:, 1] = 1.0
    bend = np.linspace(0.0, 2.0, n_frames)[:, None, None]  # curvature 1/m, growing
    bent = np.repeat(ref[None], n_frames, axis=0)
    bent[:, :40, 1] += (bend[..., 0] * ref[None, :40, 0] ** 2) / 2.0
    noisy = bent + np.concatenate([np.zeros((40, 3)), 0.001 * rng.normal(size=(10, 3))])
    noisy[:, 40:] += 0.001 * rng.normal(size=(n_frames, 10, 3))
    rot, trans = _rigid(rng, n_frames)
    return ref, alpha, np.einsum("tab,tnb->tna", rot, noisy) + trans[:, None]


def test_the_model_choice_keeps_a_bend_quadratic_and_a_small_noisy_part_rigid() -> None:
    rng = np.random.default_rng(11)
    ref, alpha, markers = _bent_and_noisy_parts(rng, 12)
    markers[3, [2, 45]] = np.nan  # missing members are left out of the test
    parts = part_frames(ref, alpha)
    np.testing.assert_array_equal(choose_quadratic_parts(markers, parts), [True, False])
    # a part with fewer than five fitted members is never tested: rigid
    few = part_frames(ref[:4], np.ones((4, 1)))
    np.testing.assert_array_equal(choose_quadratic_parts(markers[:, :4], few), [False])
    with pytest.raises(ValidationError):
        choose_quadratic_parts(markers[:, :30], parts)


def test_a_large_part_is_tested_in_interleaved_groups_each_member_left_out_once() -> None:
    """A part of more members than MODEL_CHOICE_MAX_FOLDS (a still take's few big parts)
    leaves them out in that many groups spread along its long axis, plus the six ends;
    a smaller part still leaves each member out alone."""
    from skincap.deform.dense.deformer import MODEL_CHOICE_MAX_FOLDS, _held_out_folds

    rng = np.random.default_rng(3)
    ref = rng.uniform(-1.0, 1.0, size=(150, 3)) * [0.2, 0.05, 0.02]
    folds = _held_out_folds(ref, 0.2)
    assert folds.shape == (MODEL_CHOICE_MAX_FOLDS + 6, 150)
    groups = folds[:MODEL_CHOICE_MAX_FOLDS]
    np.testing.assert_array_equal(groups.sum(axis=0), np.ones(150))  # each member once
    assert set(groups.sum(axis=1).tolist()) <= {4, 5}  # 150 / 32, evenly
    # spread along the long axis: every group spans most of it
    span = [np.ptp(ref[g, 0]) for g in groups]
    assert min(span) > 0.5 * np.ptp(ref[:, 0])
    small = _held_out_folds(ref[:20], 0.2)
    np.testing.assert_array_equal(small[:20], np.eye(20, dtype=bool))


def test_the_model_choice_on_large_parts_keeps_a_bend_quadratic_and_a_noisy_block_rigid() -> None:
    rng = np.random.default_rng(5)
    n = 120
    bar = np.column_stack(
        [rng.uniform(-0.2, 0.2, n), rng.uniform(-0.04, 0.04, n), rng.uniform(-0.04, 0.04, n)]
    )
    block = np.array([0.8, 0.0, 0.0]) + rng.uniform(-0.1, 0.1, (n, 3))
    ref = np.concatenate([bar, block])
    alpha = np.zeros((2 * n, 2))
    alpha[:n, 0] = alpha[n:, 1] = 1.0
    frames = 8
    moved = np.repeat(ref[None], frames, axis=0)
    moved[:, :n, 1] += np.linspace(0.0, 2.0, frames)[:, None] * ref[None, :n, 0] ** 2 / 2.0
    moved[:, n:] += 0.001 * rng.normal(size=(frames, n, 3))
    rot, trans = _rigid(rng, frames)
    markers = np.einsum("tab,tnb->tna", rot, moved) + trans[:, None]
    parts = part_frames(ref, alpha)
    np.testing.assert_array_equal(choose_quadratic_parts(markers, parts), [True, False])


@pytest.mark.parametrize("backend", BACKENDS)
def test_quadratic_rbf_with_no_quadratic_part_is_rigid_rbf(backend: str) -> None:
    rng = np.random.default_rng(12)
    ref, alpha, markers = _bent_and_noisy_parts(rng, 5)
    parts = part_frames(ref, alpha)
    vertices = ref + 0.01 * rng.normal(size=ref.shape)
    beta = rng.random((50, 2))
    chosen = DenseDeformer(parts, vertices, beta, quadratic_parts=[False, False], backend=backend)
    plain = DenseDeformer(parts, vertices, beta, backend=backend)
    got = np.concatenate(list(chosen.deform(markers, "quadratic_rbf")))
    np.testing.assert_allclose(
        got, np.concatenate(list(plain.deform(markers, "rigid_rbf"))), atol=1e-9
    )
    # the markers are still interpolated exactly (the exact RBF; the default ridge is
    # within ~1e-6 m), and "quadratic" keeps every part quadratic
    at_markers = DenseDeformer(parts, ref, alpha, quadratic_parts=[True, False], backend=backend)
    exact = at_markers.deform(markers, "quadratic_rbf", rbf_regularisation=0)
    np.testing.assert_allclose(np.concatenate(list(exact)), markers, atol=1e-9)
    np.testing.assert_allclose(
        np.concatenate(list(chosen.deform(markers, "quadratic"))),
        np.concatenate(list(plain.deform(markers, "quadratic"))),
        atol=1e-12,
    )
    with pytest.raises(ValidationError):
        DenseDeformer(parts, vertices, beta, quadratic_parts=[True])


def test_a_rig_carries_its_model_choice_to_its_deformer() -> None:
    from skincap.deform.dense.rig import DenseRig

    rng = np.random.default_rng(13)
    ref, alpha, _ = _bent_and_noisy_parts(rng, 2)
    arrays = {
        "vertices": ref[:10],
        "faces": np.array([[0, 1, 2]]),
        "reference": ref,
        "surface_faces": np.array([[0, 1, 2], [40, 41, 42]]),
        "marker_parts": alpha.argmax(axis=1),
        "marker_weights": alpha,
        "vertex_weights": alpha[:10],
    }
    labels = [f"M{i}" for i in range(50)]
    assert DenseRig.from_arrays(arrays, labels, {}).deformer().quadratic_parts is None  # old rigs
    rig = DenseRig.from_arrays(arrays, labels, {"quadratic_parts": [True, False]})
    np.testing.assert_array_equal(rig.deformer().quadratic_parts, [True, False])
    with pytest.raises(ValidationError):
        DenseRig.from_arrays(arrays, labels, {"quadratic_parts": [True]}).deformer()


def test_held_out_errors_do_not_depend_on_the_fold_chunks(monkeypatch) -> None:
    """The model choice's folds run in chunks (bounded memory): any chunk size gives the
    same squared errors, bit for bit, as all the folds at once."""
    from skincap.deform.dense import deformer

    rng = np.random.default_rng(3)
    reference = rng.normal(scale=0.1, size=(40, 3))
    turn = Rotation.from_rotvec(rng.normal(scale=0.3, size=(5, 3))).as_matrix()  # (S, 3, 3)
    bulge = 0.2 * reference[:, :1] ** 2  # a quadratic field along x
    markers = np.einsum("sij,kj->ski", turn, reference + bulge) + rng.normal(size=(5, 1, 3))
    markers[1, 7] = np.nan  # a missing member
    weights = np.linspace(0.5, 1.0, 40)
    whole = deformer._held_out_member_errors(markers, reference, weights, 0.2, 1e-6)
    monkeypatch.setattr(deformer, "_HELD_OUT_CHUNK_ELEMENTS", 5 * 40 * 40 * 3)  # 3 folds a chunk
    chunked = deformer._held_out_member_errors(markers, reference, weights, 0.2, 1e-6)
    assert whole[0].size == chunked[0].size > 40
    for a, b in zip(whole, chunked, strict=True):
        np.testing.assert_array_equal(a, b)
