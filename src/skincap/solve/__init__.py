"""Skeleton solving: labelled markers -> joint centres -> inverse kinematics -> a Motion.

``templates`` (which markers ride which segment), ``segments`` (technical frames of a
marker cluster), ``joint_centres`` (SCoRE, SARA, sphere fits, Harrington), ``calibrate``
(the body model of a take), ``ik`` (batched Levenberg-Marquardt over frames),
``skeleton`` (the BVH-ready motion), ``auto`` (segments and tree found from the markers'
own motion, Kirk et al. 2005) and ``pipeline`` (:func:`solve_markers`, the entry point).
"""

from skincap.solve.pipeline import SolveResult, solve_markers
from skincap.solve.templates import BUILTIN_TEMPLATES, Template, load_template

__all__ = ["BUILTIN_TEMPLATES", "SolveResult", "Template", "load_template", "solve_markers"]
