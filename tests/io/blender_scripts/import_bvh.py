"""Run inside Blender: import a BVH with Blender's own importer, report joint positions.

Usage::

    blender -b --factory-startup --python-exit-code 1 --python import_bvh.py -- \
        IN.bvh OUT.npz FRAME [FRAME ...]

The importer runs with its defaults (scale 1, forward -Z, up Y, frame start 1), so
BVH frame k is scene frame k + 1 and a BVH point (x, y, z) lands at (x, -z, y).

Writes ``OUT.npz`` with ``names`` (J,) bone names, ``frame_range`` (2,) the action's
frame range, and ``heads`` (n, J, 3) world positions of the pose bones' heads at the
requested BVH frames.
"""

import builtins
import sys

import bpy
import io_anim_bvh.import_bvh as _bvh_addon
import numpy as np

# Debian's Blender 3.4 runs on Python 3.11, where open(..., "rU") is gone, but its BVH
# add-on still asks for it; give the add-on an open() that drops the "U".


def _open_without_u(file, mode="r", *args, **kwargs):
    return builtins.open(file, mode.replace("U", ""), *args, **kwargs)


_bvh_addon.open = _open_without_u

args = sys.argv[sys.argv.index("--") + 1 :]
src, out, frames = args[0], args[1], [int(f) for f in args[2:]]
bpy.ops.import_anim.bvh(filepath=src)
arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
names = [b.name for b in arm.pose.bones]
action = arm.animation_data.action
heads = []
for k in frames:
    bpy.context.scene.frame_set(k + 1)
    mw = arm.matrix_world
    heads.append([tuple(mw @ pb.head) for pb in arm.pose.bones])
np.savez(
    out,
    names=np.array(names),
    frame_range=np.array(tuple(action.frame_range)),
    heads=np.array(heads),
)
