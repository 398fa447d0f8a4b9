"""The dense deformer's numba kernel against its NumPy reference, and the ``auto`` backend."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation

from real_parts import segmented_real_take
from skincap.backends import numba_available
from skincap.deform.dense import deformer as dense_deformer
from skincap.deform.dense._kernel_numpy import F32_TOLERANCE
from skincap.deform.dense.deformer import METHODS, DenseDeformer, PartMotion, fit_part_motion
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
    """Both kernels in float64 agree to rounding; with the float32 RBF sums ("mixed",
    the default) each stays within F32_TOLERANCE of that reference."""
    take = _random_take(seed)
    parts = part_frames(take["reference"], take["alpha"])
    motion = fit_part_motion(take["markers"], parts, method)  # type: ignore[arg-type]
    assert np.abs(motion.rbf_weights).max() > 0 if method.endswith("_rbf") else True
    out = {
        (backend, precision): DenseDeformer(
            parts, take["vertices"], take["beta"], backend=backend, precision=precision
        ).deform_block(motion)
        for backend in ("numpy", "numba")
        for precision in ("float64", "mixed")
    }
    reference = out["numpy", "float64"]
    assert reference.shape == (6, 301, 3)
    # the same NaN (vertex 0 has only the unseen part) and the same numbers elsewhere
    assert np.isnan(reference[:, 0]).all() and np.isfinite(reference[:, 1:]).all()
    for key, got in out.items():
        np.testing.assert_array_equal(np.isnan(got), np.isnan(reference))
        atol = 1e-9 if key[1] == "float64" else F32_TOLERANCE
        np.testing.assert_allclose(got, reference, rtol=0, atol=atol, err_msg=str(key))


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
    for backend, precision in (("numpy", "float64"), ("numba", "float64"), ("numpy", "mixed"),
                               ("numba", "mixed")):  # fmt: skip
        deformer = DenseDeformer(parts, skin[0], beta, backend=backend, precision=precision)
        for method in METHODS:
            outputs[backend, precision, method] = np.concatenate(
                list(deformer.deform(markers, method))
            )
    for method in METHODS:
        want = outputs["numpy", "float64", method]
        np.testing.assert_allclose(outputs["numba", "float64", method], want, rtol=0, atol=1e-9)
        for backend in ("numpy", "numba"):  # the float32 RBF sums, against the reference
            np.testing.assert_allclose(
                outputs[backend, "mixed", method], want, rtol=0, atol=F32_TOLERANCE
            )
    # and the deformation follows the true skin (a broken kernel would not)
    error = np.linalg.norm(outputs["numba", "mixed", "quadratic_rbf"] - skin, axis=-1)
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
    np.testing.assert_allclose(second, first, rtol=0, atol=2 * F32_TOLERANCE)  # both mixed
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
    from skincap.deform.dense._kernel_numba import dense_dispatcher, dense_no_rbf_dispatcher

    assert WARM_UPS["dense"] == "skincap.deform.dense.deformer:warm_up_kernel"
    dense_deformer.warm_up_kernel()
    assert kernel_ready(dense_dispatcher()) and kernel_ready(dense_no_rbf_dispatcher())
    # what the warm-up compiled is what a take runs: no second signature to compile
    take = _random_take(5)
    parts = part_frames(take["reference"], take["alpha"])
    deformer = DenseDeformer(parts, take["vertices"], take["beta"], backend="numba")
    for method in METHODS:
        list(deformer.deform(take["markers"], method, chunk=4))
    assert len(dense_dispatcher().signatures) == 1
    assert len(dense_no_rbf_dispatcher().signatures) == 1


def test_the_centre_table_has_room_for_whole_steps() -> None:
    """The numba kernel copies each tile's centres and pads them to whole vector steps
    with zero weights: the table is K rounded up to a step, the centres scaled by 2/σ,
    both fields' weights / 6, and nothing past K."""
    from skincap.deform.dense._kernel_numba import MEMBER_LANES, _rbf_table

    rng = np.random.default_rng(0)
    k = 2 * MEMBER_LANES + 3
    centres = rng.normal(size=(2, 3, k, 3))
    members, seam = rng.normal(size=(2, 2, 3, k, 3))
    scale = np.array([10.0, 20.0, 0.0])
    table = _rbf_table(centres, members, seam, scale)
    assert table.shape == (2, 3, 9, 3 * MEMBER_LANES) and table.flags.c_contiguous
    np.testing.assert_allclose(table[:, 1, :3, :k], np.swapaxes(centres[:, 1] * 20.0, -1, -2))
    np.testing.assert_allclose(table[:, 1, 3:6, :k], np.swapaxes(members[:, 1] / 6.0, -1, -2))
    np.testing.assert_allclose(table[:, 1, 6:, :k], np.swapaxes(seam[:, 1] / 6.0, -1, -2))
    assert not table[..., k:].any()


def _direct_eqs_8_9(
    deformer: DenseDeformer, rest: np.ndarray, motion: PartMotion, seam_weights: np.ndarray
) -> np.ndarray:
    """Eqs. 8-9 written out per part with :func:`skincap.geometry.rbf.evaluate_rbf` over
    every centre (no tiles, no support test): each vertex's position in each part, the
    members' and the seam field blended by its seam weight, then β."""
    from skincap.geometry.quadratic import apply_quadratic
    from skincap.geometry.rbf import evaluate_rbf

    parts = deformer.parts
    n_t, n_p = motion.quadratic.shape[:2]
    beta = np.zeros((deformer.n_vertices, n_p))
    beta[deformer.pair_vertex, deformer.pair_part] = deformer.pair_weight
    num = np.zeros((n_t, deformer.n_vertices, 3))
    den = np.zeros((n_t, deformer.n_vertices, 1))
    members = motion.rbf_weights if motion.member_rbf_weights is None else motion.member_rbf_weights
    for p in range(n_p):
        rows = np.flatnonzero(beta[:, p] > 0)
        local = parts.to_local(rest[rows], np.full(rows.size, p))
        moved = apply_quadratic(motion.quadratic[:, p], local[None])  # (T, n, 3)
        k = int(parts.valid[p].sum())
        sums = [
            evaluate_rbf(motion.centres[:, p, :k], w[:, p, :k], parts.sigma[p], moved)
            for w in (members, motion.rbf_weights)
        ]
        s = seam_weights[rows, p][None, :, None]
        moved = moved + (1 - s) * sums[0] + s * sums[1]
        world = np.einsum(
            "tnx,txy->tny", moved - motion.translation[:, p, None], motion.rotation[:, p]
        )
        ok = np.isfinite(world).all(-1, keepdims=True)
        num[:, rows] += np.where(ok, beta[rows, p][None, :, None] * world, 0.0)
        den[:, rows] += np.where(ok, beta[rows, p][None, :, None], 0.0)
    with np.errstate(invalid="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


@pytest.mark.parametrize("backend", ["numpy", pytest.param("numba", marks=needs_numba)])
@pytest.mark.parametrize("method", ["rigid_rbf", "quadratic_rbf"])
def test_the_tiled_kernels_equal_eqs_8_9_written_out(backend: str, method: str) -> None:
    """Parts with seam centres, random seam weights, a bent take with gaps and an unseen
    part: the kernels (pairs in tiles, only the centres reaching a tile summed, both
    fields in one pass) give eqs. 8-9 summed over every centre."""
    take = _random_take(6, n_frames=5)
    ref = take["reference"]
    faces = Delaunay(ref[:, :2]).simplices  # a marker surface over the four parts
    parts = part_frames(ref, take["alpha"], surface_faces=faces)
    assert parts.has_seam_centres
    rng = np.random.default_rng(6)
    seam = rng.random(take["beta"].shape) * (rng.random(take["beta"].shape) < 0.7)
    deformer = DenseDeformer(
        parts, take["vertices"], take["beta"], seam_weights=seam, backend=backend,
        precision="float64",
    )  # fmt: skip
    motion = fit_part_motion(take["markers"], parts, method)  # type: ignore[arg-type]
    got = deformer.deform_block(motion)
    want = _direct_eqs_8_9(deformer, take["vertices"], motion, seam)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    assert np.isnan(got[:, 0]).all() and np.isfinite(got[:, 1:]).all()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)
    mixed = DenseDeformer(
        parts, take["vertices"], take["beta"], seam_weights=seam, backend=backend
    ).deform_block(motion)  # float32 RBF sums where the error model allows
    np.testing.assert_array_equal(np.isnan(mixed), np.isnan(want))
    np.testing.assert_allclose(mixed, want, rtol=0, atol=F32_TOLERANCE)
    # the RBF moved the vertices (a kernel that dropped the sums would differ by mm)
    plain = DenseDeformer(parts, take["vertices"], take["beta"], backend=backend)
    rigid = plain.deform_block(fit_part_motion(take["markers"], parts, "rigid"))
    assert np.nanmax(np.abs(got - rigid)) > 1e-3


def test_pair_tiles_cover_every_pair_once_in_compact_tiles_of_one_part() -> None:
    from skincap.deform.dense._pair_tiles import pair_tiles

    take = _random_take(7)
    parts = part_frames(take["reference"], take["alpha"])
    beta = take["beta"] / take["beta"].sum(axis=1, keepdims=True)
    tiles = pair_tiles(parts, take["vertices"], beta, np.zeros_like(beta), tile_pairs=8)
    want = set(zip(*np.nonzero(beta > 1e-6), strict=True))
    assert set(zip(tiles.vertex.tolist(), tiles.part.tolist(), strict=True)) == want
    assert len(want) == tiles.vertex.size
    np.testing.assert_array_equal(tiles.weight, beta[tiles.vertex, tiles.part])
    sizes = np.diff(tiles.tile_start)
    assert (sizes >= 1).all() and (sizes <= 8).all() and tiles.tile_start[-1] == tiles.part.size
    for i, p in enumerate(tiles.tile_part):  # one part a tile, parts in order
        assert (tiles.part[tiles.tile_start[i] : tiles.tile_start[i + 1]] == p).all()
    assert (np.diff(tiles.part) >= 0).all()
    np.testing.assert_array_equal(tiles.part_start, np.searchsorted(tiles.part, np.arange(5)))
    np.testing.assert_allclose(
        tiles.local, parts.to_local(take["vertices"][tiles.vertex], tiles.part)
    )
    # the vertex rows list each vertex's pairs
    for v in (1, 50, 300):
        rows = tiles.by_vertex[tiles.vertex_start[v] : tiles.vertex_start[v + 1]]
        assert (tiles.vertex[rows] == v).all() and rows.size == (beta[v] > 1e-6).sum()
    np.testing.assert_array_equal(tiles.weight_by_vertex, tiles.weight[tiles.by_vertex])
    # k-d leaves are compact: each tile spans less than its part does
    for p in range(4):
        in_part = tiles.local[tiles.part == p]
        span = np.ptp(in_part, axis=0).max()
        ids = np.flatnonzero(tiles.tile_part == p)
        spans = [
            np.ptp(tiles.local[tiles.tile_start[i] : tiles.tile_start[i + 1]], axis=0).max()
            for i in ids
        ]
        assert np.median(spans) < 0.6 * span


@needs_numba
@pytest.mark.parametrize("method", METHODS)
def test_the_kernels_equal_eqs_8_9_written_out_with_an_unseen_part(method: str) -> None:
    """Without an RBF field the numba kernel blends each vertex's pairs in one fused pass
    (no buffer of moved pairs); with one, the tile pass writes a vertex's only pair
    straight to the output and buffers the pairs of the vertices with several. On parts
    with seam centres (as a rig builds them), a take with gaps and an unseen part, both
    give eqs. 8-9 and the NumPy reference (a vertex of the unseen part alone NaN), and a
    vertex of the unseen part and a seen one follows the seen one alone."""
    take = _random_take(7, n_frames=5)
    ref = take["reference"]
    parts = part_frames(ref, take["alpha"], surface_faces=Delaunay(ref[:, :2]).simplices)
    rng = np.random.default_rng(7)
    seam = rng.random(take["beta"].shape) * (rng.random(take["beta"].shape) < 0.7)
    beta = take["beta"].copy()
    beta[1:40, 3] = 0.5  # seen parts and the unseen one
    beta[200:] = np.eye(4)[np.argmax(beta[200:, :3], axis=1)]  # one seen part each
    motion = fit_part_motion(take["markers"], parts, method)  # type: ignore[arg-type]
    assert np.any(motion.rbf_weights) == method.endswith("_rbf")
    assert np.isnan(motion.rotation[:, 3]).all()  # part 3 unseen
    outputs = {
        backend: DenseDeformer(
            parts, take["vertices"], beta, seam_weights=seam, backend=backend,
            precision="float64",
        ).deform_block(motion)
        for backend in ("numba", "numpy")
    }  # fmt: skip
    deformer = DenseDeformer(parts, take["vertices"], beta, seam_weights=seam, backend="numba")
    # vertex 0 has part 3 alone, vertices 1-39 two parts or more, the rest one or more
    assert (deformer.pair_vertex == 0).sum() == 1 and np.isin(
        np.arange(1, 40), deformer.pair_vertex[deformer.pair_part == 3]
    ).all()
    assert (np.bincount(deformer.pair_vertex) == 1).sum() > 100
    want = _direct_eqs_8_9(deformer, take["vertices"], motion, seam)
    for got in outputs.values():
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        assert np.isnan(got[:, 0]).all() and np.isfinite(got[:, 1:]).all()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)
    np.testing.assert_allclose(outputs["numba"], outputs["numpy"], rtol=0, atol=1e-12)
    # the mixed vertices equal the same vertices without the unseen part
    seen_only = beta.copy()
    seen_only[:, 3] = 0.0
    seen_only[0, 0] = 1.0  # vertex 0 needs some part to bind
    alone = DenseDeformer(
        parts, take["vertices"], seen_only, seam_weights=seam, backend="numba",
        precision="float64",
    ).deform_block(motion)  # fmt: skip
    np.testing.assert_allclose(outputs["numba"][:, 1:40], alone[:, 1:40], rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", ["numpy", pytest.param("numba", marks=needs_numba)])
def test_the_float32_sums_agree_with_the_float64_reference_on_a_real_capture(
    data_dir, backend: str
) -> None:
    """A real take (CMU 85_02: noise, gaps) cut into six parts of its marker surface with
    seam centres, skin points scattered off the markers: the default ("mixed") vertex
    pass stays within F32_TOLERANCE of float64 for both RBF variants, and it did take
    the float32 path for some tiles (the answers differ)."""
    from scipy.spatial import cKDTree

    real = segmented_real_take(data_dir / "cmu_85_02.c3d", step=8)
    x, frame, faces, alpha = real["x"], real["frame"], real["faces"], real["alpha"]
    parts = part_frames(x[frame], alpha, surface_faces=faces)
    rng = np.random.default_rng(0)
    skin = x[frame][rng.integers(0, x.shape[1], 1500)] + 0.02 * rng.normal(size=(1500, 3))
    _, nearest = cKDTree(x[frame]).query(skin, k=2)
    beta = alpha[nearest].mean(axis=1)
    markers = x[np.linspace(0, x.shape[0] - 1, 12).round().astype(int)]
    for method in ("rigid_rbf", "quadratic_rbf"):
        motion = fit_part_motion(markers, parts, method)  # type: ignore[arg-type]
        out = {
            precision: DenseDeformer(
                parts,
                skin,
                beta,
                backend=backend,
                precision=precision,  # type: ignore[arg-type]
            ).deform_block(motion)
            for precision in ("float64", "mixed")
        }
        np.testing.assert_array_equal(np.isnan(out["mixed"]), np.isnan(out["float64"]))
        diff = np.nanmax(np.abs(out["mixed"] - out["float64"]))
        assert diff <= F32_TOLERANCE, (method, diff)
        # NumPy sums a rigid base through its float64 rest matrices instead
        assert diff > 0 or (backend, method) == ("numpy", "rigid_rbf")


def test_parts_with_a_rigid_base_sum_through_their_rest_kernels() -> None:
    """A part whose base field is the identity at every frame (rigid_rbf; the parts
    quadratic_rbf keeps rigid) sums its RBF through a sparse matrix made once at rest:
    the same answer as the tiles in float64, for a second block too (the cached
    matrices), and not taken for a quadratic part."""
    from skincap.deform.dense._kernel_numpy import blend_pairs, move_pairs_numpy

    take = _random_take(7, n_frames=6)
    ref = take["reference"]
    parts = part_frames(ref, take["alpha"], surface_faces=Delaunay(ref[:, :2]).simplices)
    chosen = np.array([True, False, True, False])
    rng = np.random.default_rng(7)
    seam = rng.random(take["beta"].shape)
    deformer = DenseDeformer(
        parts, take["vertices"], take["beta"], seam_weights=seam, quadratic_parts=chosen,
        backend="numpy", precision="float64",
    )  # fmt: skip
    tiles = deformer._tiles
    for method, frames in (("rigid_rbf", slice(0, 3)), ("rigid_rbf", slice(3, 6)),
                           ("quadratic_rbf", slice(0, 6))):  # fmt: skip
        motion = fit_part_motion(take["markers"][frames], parts, method, quadratic_parts=chosen)
        got = deformer.deform_block(motion)
        tiled = move_pairs_numpy(
            tiles.basis, tiles.seam, tiles.part_start, tiles.tile_start, motion.quadratic,
            motion.rotation, motion.translation, motion.centres, motion.member_rbf_weights,
            motion.rbf_weights, deformer._rbf_scale,
            np.where(deformer._rbf_scale > 0, deformer._n_centres, 0), precision="float64",
        )  # fmt: skip
        want = blend_pairs(tiled, deformer._blend)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        # every part seen (0-2; part 3 never is) has its matrix after rigid_rbf; a
        # quadratic part summed through it would not equal the tiles above
        assert sorted(tiles.rest_kernels) == [0, 1, 2]


def test_centres_reaching_a_box_are_those_within_the_support_at_some_frame() -> None:
    """The NumPy kernel's centre search (axis by axis) against the distance from each
    centre to each slab's box written out per frame: a centre is kept when it is within
    scaled distance 2 of the box at one frame at least; NaN boxes or centres keep none."""
    from skincap.deform.dense._kernel_numpy import SUPPORT_SLACK, _centres_reaching

    rng = np.random.default_rng(3)
    lo = rng.normal(size=(7, 4, 3))
    hi = lo + rng.uniform(0.0, 1.0, size=lo.shape)
    centres = 2.0 * rng.normal(size=(4, 30, 3))
    lo[2, :, 1] = np.nan  # slab 2 unseen at every frame
    centres[:, 5, 0] = np.nan  # centre 5 missing at every frame
    with np.errstate(invalid="ignore"):
        got = _centres_reaching(lo, hi, centres)
    want = np.zeros((7, 30), dtype=bool)
    for s in range(7):
        for t in range(4):
            for k in range(30):
                nearest = np.clip(centres[t, k], lo[s, t], hi[s, t])
                d2 = float(((centres[t, k] - nearest) ** 2).sum())
                want[s, k] |= d2 < 4.0 + SUPPORT_SLACK  # False for NaN
    np.testing.assert_array_equal(got, want)
    assert got.any() and not got.all() and not got[2].any() and not got[:, 5].any()
