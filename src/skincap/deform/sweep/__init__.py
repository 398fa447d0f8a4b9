"""Sweep-based deformation (Hyun, Yoon, Chang, Seong, Kim & Jüttler 2005).

A skinned mesh's arms and legs are approximated by sweeps of moving ellipses
(:mod:`skincap.geometry.sweep`), fitted automatically to the mesh (:mod:`.fit`).
"""

from skincap.deform.sweep.chains import LimbChain, limb_chains
from skincap.deform.sweep.fit import LimbSweep, fit_limb

__all__ = ["LimbChain", "LimbSweep", "fit_limb", "limb_chains"]
