"""The IK's numba kernels against the NumPy reference: normal equations, damped solve, poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import ValidationError
from skincap.solve._ik_numba import ancestor_blocks, damped_solve, lm_steps, normal_equations
from skincap.solve.ik import _Paths, _Springs, model_markers, solve_poses

# a branching tree (a pelvis with a spine and two legs) and markers on every segment
PARENTS = np.array([-1, 0, 1, 0, 3, 0, 5])
OFFSETS = np.random.default_rng(0).normal(scale=0.3, size=(PARENTS.size, 3))
SEG = np.repeat(np.arange(PARENTS.size), 3)
LOCAL = np.random.default_rng(1).normal(scale=0.08, size=(SEG.size, 3))
N_PAR = 3 + 3 * PARENTS.size
DATA = Path(__file__).parents[1] / "data"


def _dense_jacobian(v: np.ndarray, sw: np.ndarray, paths: _Paths) -> np.ndarray:
    """(T, 3 M, P) float64 Jacobian written out entry by entry (the reference's layout)."""
    t, m = sw.shape
    jac = np.zeros((t, 3 * m, N_PAR))
    for q, (mk, s) in enumerate(zip(paths.marker, paths.segment, strict=True)):
        a = v[:, q]
        minus_skew = np.zeros((t, 3, 3))  # -[a]x
        minus_skew[:, 0, 1], minus_skew[:, 0, 2] = a[:, 2], -a[:, 1]
        minus_skew[:, 1, 0], minus_skew[:, 1, 2] = -a[:, 2], a[:, 0]
        minus_skew[:, 2, 0], minus_skew[:, 2, 1] = a[:, 1], -a[:, 0]
        jac[:, 3 * mk : 3 * mk + 3, 3 + 3 * s : 6 + 3 * s] = minus_skew
    for mk in range(m):
        jac[:, 3 * mk : 3 * mk + 3, :3] = sw[:, mk, None, None] * np.eye(3)
    return jac


def _frames(t: int, seed: int):
    """Rotations (T, S, 3, 3), weights (T, M) with misses, residuals (T, M, 3), the
    weighted pair vectors (T, Q, 3) and the pairs."""
    rng = np.random.default_rng(seed)
    paths = _Paths(PARENTS, OFFSETS, SEG, LOCAL)
    rot = Rotation.random(t * PARENTS.size, random_state=seed).as_matrix()
    rot = rot.reshape(t, PARENTS.size, 3, 3)
    sw = rng.uniform(0.2, 1.0, size=(t, SEG.size)) * (rng.random((t, SEG.size)) > 0.3)
    v = np.einsum("tqij,qj->tqi", rot[:, paths.segment], paths.local) * sw[:, paths.marker, None]
    resid = rng.normal(scale=0.01, size=(t, SEG.size, 3)) * sw[..., None]
    return rot, sw, resid, v, paths


def _normal_equations(rot, sw, resid, paths, normal):
    return normal_equations(rot, paths.local, paths.segment, paths.start, sw, resid, normal)


def test_normal_equations_equal_the_dense_jacobian_products():
    rot, sw, resid, v, paths = _frames(20, seed=2)
    normal = np.zeros((N_PAR, N_PAR))
    normal[3:6, 6:9] = normal[6:9, 3:6] = -0.5 * np.eye(3)  # a spring's coupling, kept as is
    h, g = _normal_equations(rot, sw, resid, paths, normal)
    jac = _dense_jacobian(v, sw, paths)
    want_h = np.einsum("tri,trj->tij", jac, jac) + normal
    want_g = np.einsum("tri,tr->ti", jac, resid.reshape(20, -1))
    upper = np.triu(np.ones((N_PAR, N_PAR), dtype=bool))  # what the solve reads
    np.testing.assert_allclose(h[:, upper], want_h[:, upper], rtol=0, atol=1e-13)
    np.testing.assert_allclose(g, want_g, rtol=0, atol=1e-15)
    # a frame with no marker seen keeps the constant matrix and a zero gradient
    h0, g0 = _normal_equations(rot[:1], sw[:1] * 0, resid[:1] * 0, paths, normal)
    np.testing.assert_array_equal(h0[0][upper], normal[upper])
    assert not g0.any()


def _chain_columns(s: int) -> list[int]:
    """The parameters a row on segment ``s`` may reach: the root origin and its chain."""
    cols = [0, 1, 2]
    while s >= 0:
        cols += [3 + 3 * s, 4 + 3 * s, 5 + 3 * s]
        s = PARENTS[s]
    return cols


@pytest.mark.parametrize("source", ["markers", "any rows"])
def test_damped_solve_matches_numpy_solve(source):
    rng = np.random.default_rng(3)
    if source == "markers":  # the IK's own normal equations
        rot, sw, resid, _, paths = _frames(30, seed=4)
        h, g = _normal_equations(rot, sw, resid, paths, np.zeros((N_PAR, N_PAR)))
        h = np.triu(h) + np.triu(h, 1).transpose(0, 2, 1)  # the symmetric matrix it stands for
    else:  # any rows that reach a chain to the root (springs, limits): dense blocks
        jac = np.zeros((30, 80, N_PAR))
        for r, seg in enumerate(rng.integers(0, PARENTS.size, size=80)):
            cols = _chain_columns(seg)
            jac[:, r, cols] = rng.normal(size=(30, len(cols)))
        h, g = np.einsum("tri,trj->tij", jac, jac), rng.normal(size=(30, N_PAR))
    damping = 10.0 ** rng.uniform(-9, 3, size=30)
    damped = h.copy()
    idx = np.arange(N_PAR)
    damped[:, idx, idx] += damping[:, None] * damped[:, idx, idx] + 1e-6
    want = -np.linalg.solve(damped, g[..., None])[..., 0]
    got = damped_solve(h.copy(), g, damping, 1e-6, PARENTS)
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-10 * np.abs(want).max())
    # the fused kernel (normal equations, then the solve, per frame) steps alike
    if source == "markers":
        fused = lm_steps(rot, paths.local, paths.segment, paths.start, sw, resid,
                         np.zeros((N_PAR, N_PAR)), np.zeros((30, N_PAR)), np.zeros(0, np.int64),
                         np.zeros(0, np.int64), np.zeros((30, 0, 3)), damping, 1e-6,
                         ancestor_blocks(PARENTS))  # fmt: skip
        np.testing.assert_allclose(fused, want, rtol=1e-8, atol=1e-10 * np.abs(want).max())


def test_ancestor_blocks_list_each_chain_and_refuse_a_child_before_its_parent():
    start, block = ancestor_blocks(PARENTS)
    assert [sorted(block[start[k] : start[k + 1]]) for k in range(PARENTS.size + 1)] == [
        [], [0], [0, 1], [0, 1, 2], [0, 1], [0, 1, 4], [0, 1], [0, 1, 6]
    ]  # fmt: skip
    with pytest.raises(ValidationError, match="parents first"):
        ancestor_blocks(np.array([-1, 2, 0]))


def _solve(y, rot, root, backend, **options):
    return solve_poses(PARENTS, OFFSETS, SEG, LOCAL, y, rot, root, backend=backend, **options)


LIMITS = np.full((PARENTS.size, 3, 2), np.nan)
LIMITS[2, 0] = [-0.2, 0.2]  # radians about the parent's x axis: the random poses pass them
LIMITS[4, 2] = [-0.3, 0.1]


def test_a_step_with_springs_and_joint_limits_equals_the_dense_float64_step():
    rot, sw, resid, v, paths = _frames(25, seed=8)
    springs = _Springs(PARENTS, np.array([0, 0, 0.5, 0, 0, 0, 0.0]), N_PAR, LIMITS, 2.0)
    r = springs.residuals(rot)
    assert (r[:, springs.segment.size :, 0] != 0).sum() > 20  # limits pushing back
    jac = _dense_jacobian(v, sw, paths)
    h = np.einsum("tri,trj->tij", jac, jac) + springs.normal
    g = np.einsum("tri,tr->ti", jac, resid.reshape(25, -1))
    springs.add_gradient(g, r)
    springs.add_limits(h, g, rot, r)
    damping = np.full(25, 1e-3)
    idx = np.arange(N_PAR)
    h[:, idx, idx] += damping[:, None] * h[:, idx, idx] + 1e-6
    want = -np.linalg.solve(h, g[..., None])[..., 0]
    rest = np.zeros((25, N_PAR))
    springs.add_gradient(rest, r)
    u, res = springs.limit_rows(rot, r)
    springs.add_limit_gradient(rest, u, res)
    got = lm_steps(rot, paths.local, paths.segment, paths.start, sw, resid, springs.normal, rest,
                   springs.lim_segment, springs.lim_parent, u, damping, 1e-6,
                   ancestor_blocks(PARENTS))  # fmt: skip
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("options", [{}, {"loss": "huber", "loss_scale": 0.01}])
def test_both_backends_reach_the_same_poses(options):
    rng = np.random.default_rng(5)
    t = 60
    rot = Rotation.from_rotvec(rng.normal(scale=0.6, size=(t * PARENTS.size, 3))).as_matrix()
    rot = rot.reshape(t, PARENTS.size, 3, 3)
    root = rng.normal(size=(t, 3))
    y = model_markers(PARENTS, OFFSETS, SEG, LOCAL, rot, root)
    y += rng.normal(scale=0.003, size=y.shape)
    y[rng.random(y.shape[:2]) < 0.1] = np.nan
    kick = Rotation.from_rotvec(rng.normal(scale=0.1, size=(t * PARENTS.size, 3))).as_matrix()
    start = kick.reshape(rot.shape) @ rot
    # to convergence: the stopping rule would stop either where its last gain happens to fall
    tight = dict(options, tolerance=1e-14, relative_tolerance=0.0, iterations=40)
    ref_rot, ref_root = _solve(y, start, root + 0.02, "numpy", **tight)
    got_rot, got_root = _solve(y, start, root + 0.02, "numba", **tight)
    # a segment down to one marker turns freely about it: only its fit is determined
    seen = np.isfinite(y).all(axis=2).reshape(t, PARENTS.size, 3).all(axis=2)
    np.testing.assert_allclose(got_rot[seen], ref_rot[seen], atol=1e-6)
    np.testing.assert_allclose(got_root, ref_root, atol=1e-7)
    fits = [model_markers(PARENTS, OFFSETS, SEG, LOCAL, r, o) for r, o in
            ((ref_rot, ref_root), (got_rot, got_root))]  # fmt: skip
    np.testing.assert_allclose(fits[1], fits[0], atol=1e-5)  # metres


def test_both_backends_fit_a_real_capture_alike():
    from skincap.io import read
    from skincap.solve.calibrate import calibrate
    from skincap.solve.templates import load_template

    markers = read(DATA / "cmu_85_02.c3d")
    model = calibrate(markers, load_template("cmu41"))
    y = markers.positions[:200, model.marker_columns]
    rms = {}
    for backend in ("numpy", "numba"):
        rot, root = solve_poses(
            model.segment_parents, model.joint_offsets, model.marker_segments,
            model.marker_offsets, y, model.init_rotations[:200], model.init_origins[:200],
            link_stiffness=model.link_stiffness, backend=backend,
        )  # fmt: skip
        fit = model_markers(model.segment_parents, model.joint_offsets, model.marker_segments,
                            model.marker_offsets, rot, root)  # fmt: skip
        rms[backend] = np.sqrt(np.nanmean(np.sum((fit - y) ** 2, axis=2)))
    assert 0.003 < rms["numba"] < 0.012  # metres: a fit, not a failure
    assert abs(rms["numba"] - rms["numpy"]) < 1e-7


def test_an_unknown_backend_is_refused():
    y = model_markers(
        PARENTS, OFFSETS, SEG, LOCAL, np.tile(np.eye(3), (2, 7, 1, 1)), np.zeros((2, 3))
    )
    with pytest.raises(ValidationError, match="backend"):
        _solve(y, np.tile(np.eye(3), (2, 7, 1, 1)), np.zeros((2, 3)), "fortran")


def test_ik_backend_names_what_solve_poses_runs():
    from skincap.solve.ik import ik_backend

    assert ik_backend("numpy") == "numpy"
    assert ik_backend("numba") == "numba"  # numba is a core dependency
    with pytest.raises(ValidationError, match="backend"):
        ik_backend("fortran")


def test_rotated_turns_as_the_reference_exp_including_tiny_and_zero_steps():
    from skincap.solve._ik_numba import rotated
    from skincap.solve.ik import _exp

    rng = np.random.default_rng(9)
    step = rng.normal(scale=0.8, size=(40, 7, 3))
    step[0, 0], step[0, 1] = 0.0, 1e-10  # the series branch below 1e-8 rad
    rot = Rotation.random(280, random_state=2).as_matrix().reshape(40, 7, 3, 3)
    np.testing.assert_allclose(rotated(step, rot), _exp(step) @ rot, rtol=0, atol=1e-14)
