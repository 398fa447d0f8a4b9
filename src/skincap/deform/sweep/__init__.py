"""Sweep-based deformation (Hyun, Yoon, Chang, Seong, Kim & Jüttler 2005).

A skinned mesh's arms and legs are approximated by sweeps of moving ellipses
(:mod:`skincap.geometry.sweep`), fitted automatically to the mesh (:mod:`.fit`); every
vertex of a limb is bound to the ellipse whose plane contains it (:mod:`.bind`); per
frame the key ellipses follow the joints, each limb's swept volume is held at its rest
value (:mod:`.volume`), the vertices are rebuilt from their bindings and blended with
skeletal skinning where the limbs meet the body (:mod:`.deformer`).
"""

from skincap.deform.sweep.chains import LimbChain, limb_chains
from skincap.deform.sweep.deformer import SweepDeformer, sweep_motion
from skincap.deform.sweep.fit import LimbSweep, fit_limb

__all__ = ["LimbChain", "LimbSweep", "SweepDeformer", "fit_limb", "limb_chains", "sweep_motion"]
