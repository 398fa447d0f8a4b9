"""Wavefront OBJ and Stanford PLY mesh readers and writers.

Both formats carry no length unit and no up axis, so the readers take them as
arguments (metres and Y up by default), convert to skincap's metres / Y-up and record
the choice in ``meta["source_units"]`` and ``meta["up"]``; the writers restore them.

:mod:`skincap.io.mesh.obj` reads and writes OBJ, :mod:`skincap.io.mesh.ply` PLY;
:mod:`skincap.io.mesh.common` holds what they share.
"""

from skincap.io.mesh.common import triangulate_polygons
from skincap.io.mesh.obj import read_obj, write_obj
from skincap.io.mesh.ply import read_ply, write_ply

__all__ = ["read_obj", "write_obj", "read_ply", "write_ply", "triangulate_polygons"]
