"""Fixtures of the export tests (the cylinder itself is in skinned_cylinder.py)."""

from __future__ import annotations

import pytest
from skinned_cylinder import bend_motion, cylinder_mesh, lbs_reference

from skincap.types import Mesh, MeshAnimation, Motion


@pytest.fixture
def cylinder() -> Mesh:
    return cylinder_mesh()


@pytest.fixture
def bend(cylinder: Mesh) -> Motion:
    return bend_motion(cylinder)


@pytest.fixture
def cylinder_animation(cylinder: Mesh, bend: Motion) -> MeshAnimation:
    return MeshAnimation(rest=cylinder, frames=lbs_reference(cylinder, bend), rate=bend.rate)
