"""Biovision Hierarchy (BVH) skeleton motion: reader and writer.

A BVH file has a ``HIERARCHY`` of joints (``ROOT``/``JOINT`` blocks with an ``OFFSET``
and ``CHANNELS``, leaves closed by ``End Site`` blocks) and a ``MOTION`` section with
``Frames:``, ``Frame Time:`` and one row of channel values per frame, joints in the
order the hierarchy lists them.

Conventions used here
---------------------
Rotations
    Each joint's rotation channels, read left to right, are *intrinsic* Euler angles in
    degrees: ``Zrotation Xrotation Yrotation`` means ``R = Rz @ Rx @ Ry``
    (``Rotation.from_euler("ZXY", ..., degrees=True)``). Orders may differ between
    joints; joints with one or two rotation channels are supported.
Positions
    A joint's local transform is ``T(t) @ R`` with ``t`` its translation. Position
    channels *replace* the matching component of the joint's ``OFFSET`` (for the root
    and for non-root joints alike; this is what Biovision, MotionBuilder, Blender and
    bvhio do); components without a channel keep the offset. ``Motion.translations``
    therefore always holds the effective local translation and equals the offset for
    joints without position channels.
End sites
    Become joints named ``<parent>_end`` (``<parent>_end_2``... if that name is taken)
    with no channels. The writer turns every non-root leaf without channels back into
    an ``End Site`` (its name is not stored by BVH).
Units
    BVH has none. Pass ``units``; when it is None the reader infers it from the height
    of the rest-pose skeleton (see :func:`guess_bvh_units`) and warns with a
    :class:`~skincap.errors.UnitWarning`. Besides the general units (``m``, ``dm``,
    ``cm``, ``mm``, ``in``) BVH has ``"cmu"``: the Carnegie Mellon ASF length unit,
    1/0.45 inch = 0.05644 m, kept by the widely used cgspeed conversions of the CMU
    database (a CMU skeleton is about 24 such units tall: in centimetres or inches it
    would be a doll, in decimetres a giant).
Axes
    ``up="y"`` (default, the BVH norm) or ``"z"``; Z-up data is turned to skincap's
    Y-up (``(x, y, z) -> (x, z, -y)``, rotations conjugated to match) and back on write.

``meta`` of a read Motion: ``source_units``, ``units_guessed``, ``up``,
``frame_time`` (float seconds), ``frame_time_text`` (the file's own spelling, written
back unchanged), ``first_frame`` (0: BVH has no frame numbers).
"""

from skincap.io.bvh.reader import read_bvh
from skincap.io.bvh.units import BVH_UNITS, guess_bvh_units, guess_bvh_up
from skincap.io.bvh.writer import write_bvh

__all__ = ["read_bvh", "write_bvh", "guess_bvh_units", "guess_bvh_up", "BVH_UNITS"]
