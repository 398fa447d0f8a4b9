"""Key ellipses fitted to the mesh automatically (Hyun et al. §3.2)."""

from __future__ import annotations

import numpy as np
import pytest
from sweep_limbs import CYLINDER_CHAIN, elliptic_limb, limb_beside_another

from skincap.deform.sweep.chains import limb_chains
from skincap.deform.sweep.fit import fit_limb, key_layout
from skincap.errors import ValidationError
from skincap.types import Mesh


def _fit(mesh: Mesh, **kw):
    (chain,) = limb_chains(mesh.skin.skeleton, CYLINDER_CHAIN)
    return fit_limb(mesh, chain, **kw)


def test_key_layout_joints_and_fractions() -> None:
    pivot, frac = key_layout(3, 2)
    np.testing.assert_array_equal(pivot, [0, 0, 0, 1, 1, 1, 2])
    np.testing.assert_allclose(frac, [-1, 1 / 3, 2 / 3, -1, 1 / 3, 2 / 3, -1])


def test_elliptic_limb_recovers_axes_radii_and_centres() -> None:
    limb = _fit(elliptic_limb(0.05, 0.03), n_between=3)
    keys = limb.keys
    assert keys.n_keys == 9
    # ground truth: centres on the x axis, normals along x, half-axes 5 cm along y, 3 cm along z
    np.testing.assert_allclose(keys.centres[:, 1:], 0.0, atol=1e-3)
    frames = keys.frames
    np.testing.assert_allclose(np.abs(frames[:, 0, 2]), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(frames[:, 1, 0]), 1.0, atol=1e-6)  # a along y
    np.testing.assert_allclose(keys.radii[:, 0], 0.05, rtol=0.02)
    np.testing.assert_allclose(keys.radii[:, 1], 0.03, rtol=0.02)
    # frames follow each other: no quarter turn between consecutive keys
    assert (np.einsum("kij,kij->k", frames[1:], frames[:-1]) > 2.9).all()
    assert np.all(np.diff(keys.params) > 0)


def test_section_ignores_a_limb_it_also_cuts() -> None:
    alone = _fit(elliptic_limb())
    beside = _fit(limb_beside_another(gap=0.005))
    np.testing.assert_allclose(beside.keys.radii, alone.keys.radii, rtol=1e-9)
    np.testing.assert_allclose(beside.keys.centres, alone.keys.centres, atol=1e-12)


def test_makehuman_limbs_found_and_fitted(body) -> None:
    chains = limb_chains(body.skin.skeleton)
    assert [c.name for c in chains] == ["arm_l", "arm_r", "leg_l", "leg_r"]
    names = body.skin.skeleton.names
    assert [names[j] for j in chains[1].joints] == ["upperarm01.R", "lowerarm01.R", "wrist.R"]
    for chain in chains:
        limb = fit_limb(body, chain)
        r = limb.keys.radii
        # a human limb: half-axes between 1 and 12 cm, every section inside the body's bounds
        assert (r > 0.01).all() and (r < 0.12).all(), (chain.name, r)
        lo, hi = body.bounds
        assert ((limb.keys.centres > lo) & (limb.keys.centres < hi)).all()
    # the left and right arms are mirror images on the symmetric base mesh
    left, right = (fit_limb(body, c) for c in chains[:2])
    np.testing.assert_allclose(left.keys.radii, right.keys.radii, rtol=1e-3)
    np.testing.assert_allclose(left.keys.centres[:, 0], -right.keys.centres[:, 0], atol=1e-3)


def test_mesh_away_from_the_skeleton_is_refused() -> None:
    mesh = elliptic_limb()
    far = Mesh(vertices=mesh.vertices + np.array([0.0, 5.0, 0.0]), faces=mesh.faces, skin=mesh.skin)
    with pytest.raises(ValidationError, match="cannot fit the limb sweep.*'upper'"):
        _fit(far)


def test_unknown_skeleton_needs_named_chains() -> None:
    mesh = elliptic_limb()
    with pytest.raises(ValidationError, match="no known convention"):
        limb_chains(mesh.skin.skeleton)
    with pytest.raises(ValidationError, match="'nope' is not in the skeleton"):
        limb_chains(mesh.skin.skeleton, {"x": ("upper", "nope", "lower_end")})
    with pytest.raises(ValidationError, match="is not below"):
        limb_chains(mesh.skin.skeleton, {"x": ("lower", "upper", "lower_end")})


def test_mixamo_limbs_are_found_past_the_namespace(data_dir) -> None:
    import warnings

    from skincap.errors import SkincapWarning
    from skincap.io import read

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SkincapWarning)
        skeleton = read(data_dir / "external" / "bvhpython_mixamo_walk.bvh").skeleton
    chains = {c.name: [skeleton.names[j] for j in c.joints] for c in limb_chains(skeleton)}
    assert chains == {
        "arm_l": ["mixamorig:LeftArm", "mixamorig:LeftForeArm", "mixamorig:LeftHand"],
        "arm_r": ["mixamorig:RightArm", "mixamorig:RightForeArm", "mixamorig:RightHand"],
        "leg_l": ["mixamorig:LeftUpLeg", "mixamorig:LeftLeg", "mixamorig:LeftFoot"],
        "leg_r": ["mixamorig:RightUpLeg", "mixamorig:RightLeg", "mixamorig:RightFoot"],
    }
