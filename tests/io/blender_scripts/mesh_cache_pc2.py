"""Run inside Blender: import an OBJ, play a PC2 on it with a Mesh Cache modifier.

Usage::

    blender -b --factory-startup --python-exit-code 1 --python mesh_cache_pc2.py -- \
        IN.obj IN.pc2 OUT.npz IMPORTER FORWARD UP FRAME_START FRAME [FRAME ...]

- ``IMPORTER``: ``new`` = ``bpy.ops.wm.obj_import`` (Blender's C++ OBJ importer, the
  default in File > Import since 3.2) or ``legacy`` = ``bpy.ops.import_scene.obj``
  (the Python add-on), both with their default axis settings (forward -Z, up Y);
  ``new_zup`` = the C++ importer told the file is already Z up (forward Y, up Z: no
  conversion, the file's coordinates become Blender's).
- ``FORWARD``, ``UP``: the modifier's forward/up axis (``POS_Y``, ``NEG_Z``...);
  ``POS_Y`` / ``POS_Z`` is the modifier's default (no conversion).
- ``FRAME_START``: the modifier's frame start (time mode Frame, scale 1).

Writes ``OUT.npz`` with ``vertex_counts`` (n_meshes,), ``frames`` (n,), ``positions``
(n, V, 3) world coordinates of the evaluated mesh (Blender, Z up) and
``rest_positions`` (V, 3) world coordinates without the modifier.
"""

import sys

import bpy
import numpy as np


def world_coords(obj, depsgraph):
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    mw = np.array(ev.matrix_world)
    return co.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3]


def main(argv):
    obj_path, pc2_path, out, importer, forward, up, frame_start = argv[:7]
    frames = [int(f) for f in argv[7:]]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    if importer == "new":
        bpy.ops.wm.obj_import(filepath=obj_path)
    elif importer == "new_zup":
        bpy.ops.wm.obj_import(filepath=obj_path, forward_axis="Y", up_axis="Z")
    elif importer == "legacy":
        bpy.ops.import_scene.obj(filepath=obj_path)
    else:
        raise ValueError(f"IMPORTER must be 'new', 'new_zup' or 'legacy', got {importer!r}")
    meshes = [o for o in scene.objects if o.type == "MESH"]
    if len(meshes) != 1:
        raise RuntimeError(f"expected one mesh object, got {[o.name for o in meshes]}")
    obj = meshes[0]
    scene.frame_set(0)
    rest = world_coords(obj, bpy.context.evaluated_depsgraph_get())
    mod = obj.modifiers.new("skincap_cache", "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = pc2_path
    mod.forward_axis = forward
    mod.up_axis = up
    mod.frame_start = float(frame_start)
    positions = []
    for f in frames:
        scene.frame_set(f)
        positions.append(world_coords(obj, bpy.context.evaluated_depsgraph_get()))
    np.savez(
        out,
        vertex_counts=np.array([len(o.data.vertices) for o in meshes]),
        frames=np.array(frames, dtype=float),
        positions=np.array(positions),
        rest_positions=rest,
    )


main(sys.argv[sys.argv.index("--") + 1 :])
