"""``--template auto``: segments and tree found from the markers' motion (Kirk et al. 2005)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincap.errors import SkincapWarning, ValidationError
from skincap.io import read
from skincap.solve import solve_markers
from skincap.solve.auto import auto_template, distance_spread
from skincap.types import MarkerSet


def test_distance_spread_is_zero_within_a_rigid_body_and_not_across():
    rng = np.random.default_rng(0)
    rot = Rotation.from_rotvec(rng.normal(size=(50, 3))).as_matrix()
    body = rng.normal(scale=0.1, size=(3, 3))
    a = np.einsum("tij,kj->tki", rot, body)
    b = rng.normal(size=(50, 1, 3))
    spread = distance_spread(np.concatenate([a, b], axis=1))
    assert np.abs(spread[:3, :3]).max() < 1e-12
    assert (spread[:3, 3] > 0.1).all()


def _chain_take(seed=1, n=400):
    """Three rigid 4-marker bodies in a chain with ball joints, moving widely."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    rots = [
        Rotation.from_rotvec(
            0.6 * np.sin(np.outer(t, rng.uniform(1, 3, 3)) + rng.uniform(0, 6, 3))
        ).as_matrix()
        for _ in range(3)
    ]
    world = [rots[0], rots[0] @ rots[1], rots[0] @ rots[1] @ rots[2]]
    origin = [np.zeros((n, 3))]
    joint = np.array([0.0, -0.4, 0.0])
    origin.append(origin[0] + world[0] @ joint)
    origin.append(origin[1] + world[1] @ joint)
    pos = []
    for k in range(3):
        local = rng.normal(scale=0.06, size=(4, 3)) + [0.0, -0.2, 0.0]
        pos.append(origin[k][:, None] + np.einsum("tij,kj->tki", world[k], local))
    labels = [f"{s}{i}" for s in "ABC" for i in range(4)]
    order = rng.permutation(12)
    positions = np.concatenate(pos, axis=1)[:, order]
    return MarkerSet(positions, [labels[i] for i in order], 100.0), origin


def test_auto_finds_the_segments_and_the_chain():
    take, origin = _chain_take()
    found = auto_template(take)
    groups = sorted(sorted(g) for g in found.groups)
    assert groups == [[f"{s}{i}" for i in range(4)] for s in "ABC"]
    # the tree is the chain: the middle body is the root (nearest the centroid) or an end
    names = [g[0][0] for g in found.groups]
    edges = {tuple(sorted((names[c], names[p]))) for c, p in enumerate(found.parents) if p >= 0}
    assert edges == {("A", "B"), ("B", "C")}
    assert found.fit_residual_m.max() < 1e-6
    result = solve_markers(take, found.template)
    assert np.nanmax(result.residuals) < 1e-5


@pytest.mark.slow
def test_auto_on_the_real_62_marker_capture(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        take = read(data_dir / "aml_PronetoRun01_labeled.c3d")
        found = auto_template(take)
        result = solve_markers(take, found.template)
    groups = {frozenset(g) for g in found.groups}
    # every four-marker plate is found as one segment
    for plate in ("LTH", "RTH", "LSH", "RSH", "LUA", "RUA", "LFA", "RFA"):
        members = {f"{plate}{pos}" for pos in ("PA", "PP", "DP", "DA")}
        assert any(members <= g for g in groups), plate
    assert len(found.groups) == 17  # 15 body segments + the two acromion markers
    # both thighs hang from the pelvis plate, each shank from its thigh
    index = {m: k for k, g in enumerate(found.groups) for m in g}
    for side in "LR":
        thigh, shank = index[f"{side}THPA"], index[f"{side}SHPA"]
        assert found.parents[thigh] == index["PVUL"]
        assert found.parents[shank] == thigh
    assert result.report()["overall"]["rms_m"] < 0.01


def test_too_few_markers():
    take = MarkerSet(np.zeros((20, 2, 3)), ["a", "b"], 100.0)
    with pytest.raises(ValidationError, match="at least three"):
        auto_template(take)


def test_auto_on_cmu_85_02_finds_the_tree_it_found_before(data_dir):
    """The breakdance's tree as session 17's code found it (loose finger markers and a
    far chest pair included): the member-change rules of session 18 leave it unchanged."""
    from dataclasses import replace

    from skincap.solve.outliers import off_body_samples

    take = read(data_dir / "cmu_85_02.c3d")
    off = off_body_samples(take.positions)
    take = replace(take, positions=np.where(off[..., None], np.nan, take.positions))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        found = auto_template(take)
    assert found.groups == [
        ["LFWT", "RFWT", "LBWT", "RBWT"], ["LTHI", "LKNE"], ["CLAV", "C7"],
        ["LFHD", "RFHD", "LBHD", "RBHD"], ["STRN", "T10", "LSHO"], ["LUPA", "LELB"],
        ["RBAC", "RSHO"], ["LFRM", "LWRA", "LWRB"], ["RELB", "RFRM", "RWRA", "RWRB"],
        ["RKNE", "RSHN"], ["RANK", "RHEE", "RMT5", "RTOE"], ["LANK", "LHEE", "LMT5", "LTOE"],
        ["RFIN"], ["LSHN"], ["LFIN"], ["RUPA"], ["RTHI"],
    ]  # fmt: skip
    assert found.parents.tolist() == [-1, 0, 0, 2, 2, 4, 4, 5, 6, 0, 9, 1, 8, 11, 7, 6, 9]
    np.testing.assert_allclose(
        found.fit_residual_m,
        [0.0, 0.00957, 0.01131, 0.00674, 0.00802, 0.00336, 0.00686, 0.00796, 0.03857,
         0.02086, 0.01898, 0.03246, 0.00214, 0.00219, 0.00224, 0.0028, 0.0066],
        atol=1e-5,
    )  # fmt: skip
