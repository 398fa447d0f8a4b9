"""Volume preservation of the sweeps (Hyun et al. §4.4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sweep_limbs import CYLINDER_CHAIN, elliptic_limb

from skincap.deform.skeletal.artefacts import capped_volume, joint_pose_matrices
from skincap.deform.skeletal.deformers import make_deformer
from skincap.deform.sweep import SweepDeformer
from skincap.deform.sweep.volume import MIN_SCALE
from skincap.geometry.sweep import Sweep


def _bends(limb, degrees) -> np.ndarray:
    """(T, 3, 4, 4) skinning matrices bending the limb's joint about z."""
    return np.stack(
        [
            joint_pose_matrices(
                limb.skin, 1, Rotation.from_rotvec([0, 0, np.radians(a)]).as_matrix()
            )
            for a in degrees
        ]
    )


@pytest.fixture(scope="module")
def limb():
    return elliptic_limb(0.04, 0.04)


def test_rest_volume_is_the_sweep_integral(limb, body) -> None:
    for mesh, chains in ((limb, CYLINDER_CHAIN), (body, None)):
        d = SweepDeformer(mesh, chains=chains)
        for lv, sweep_limb in zip(d.volumes, d.limbs, strict=True):
            exact = Sweep(sweep_limb.keys, orientation="nlerp").volume(n=2048)
            assert lv.rest == pytest.approx(exact, rel=1e-4)  # 32 against 2048 intervals
    # the straight cylinder's sweep: pi r^2 L to the fit's accuracy
    (lv,) = SweepDeformer(limb, chains=CYLINDER_CHAIN).volumes
    assert lv.rest == pytest.approx(np.pi * 0.04**2 * 0.5, rel=0.03)


def test_swept_volume_is_restored_in_every_frame(limb) -> None:
    d = SweepDeformer(limb, chains=CYLINDER_CHAIN)
    (lv,) = d.volumes
    m = _bends(limb, [0.0, 30.0, 60.0, 90.0, 120.0, 140.0])
    centres, quats = d.key_poses(0, m)
    before = lv.volume(centres, quats)
    beta = lv.scales(centres, quats)
    c = lv._integrand(centres, quats)
    after = np.sum(c * (1.0 + beta @ lv.basis.hat.T) ** 2, axis=1)
    np.testing.assert_allclose(after, lv.rest, rtol=2e-3)
    assert np.abs(before / lv.rest - 1).max() > 0.01  # bending did change it
    assert beta[0] == pytest.approx(np.zeros_like(beta[0]), abs=1e-12)  # rest: untouched
    assert (1.0 + beta >= MIN_SCALE - 1e-12).all()


def test_bent_limb_keeps_its_mesh_volume_where_lbs_loses_it(limb) -> None:
    """The joint region's enclosed volume (the artefact measure) at a 120-degree bend."""
    x = limb.vertices[:, 0]
    region = np.abs(x - 0.25) <= 0.08 + 1e-12
    rest = capped_volume(limb.vertices, limb.faces, region)
    m = _bends(limb, [120.0])[0]

    def change(d) -> float:
        return float(capped_volume(d.deform(m), limb.faces, region) / rest - 1.0)

    kept = change(SweepDeformer(limb, chains=CYLINDER_CHAIN, volume=True))
    free = change(SweepDeformer(limb, chains=CYLINDER_CHAIN, volume=False))
    lbs = change(make_deformer("lbs", limb))
    assert abs(kept) < 0.05  # stated tolerance: 5 % of the region's volume
    assert lbs < -0.08
    assert kept != free  # the option does something


def test_volume_off_changes_nothing_in_a_twist(limb) -> None:
    twist = joint_pose_matrices(limb.skin, 1, Rotation.from_rotvec([2.0, 0, 0]).as_matrix())
    on = SweepDeformer(limb, chains=CYLINDER_CHAIN, volume=True).deform(twist)
    off = SweepDeformer(limb, chains=CYLINDER_CHAIN, volume=False).deform(twist)
    np.testing.assert_allclose(on, off, atol=1e-9)
