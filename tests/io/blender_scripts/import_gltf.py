"""Run inside Blender: import a .glb and report what Blender made of it.

Usage::

    blender -b --factory-startup --python-exit-code 1 --python import_gltf.py -- \
        IN.glb OUT.npz FPS FRAME [FRAME ...]

Sets the scene frame rate to ``FPS`` (frames per second, an integer) before the
import, imports ``IN.glb`` with Blender's own glTF importer (default options but
``import_shading='SMOOTH'``, the option the README documents), and
writes ``OUT.npz`` with:

- ``vertex_counts`` (n_meshes,) int: vertices of each imported mesh object.
- ``frame_range`` (2,) float: the scene's frame_start and frame_end after import.
- ``action_ranges`` (n_actions, 2) float: each action's frame_range.
- ``key_counts`` (n_actions,) int: keyframes of the action's busiest F-curve.
- ``frames`` (n,) float: the frames evaluated.
- ``positions`` (n, V, 3) float: world positions of the skinned mesh's vertices at
  each frame, from the evaluated (armature-deformed) mesh, Blender coordinates (Z up).
- ``fps`` (1,) float: the scene frame rate used.
"""

import sys

import bpy
import numpy as np

# No patch of NumPy here: the import is what a user runs. Blender 3.4's glTF importer
# calls ``np.bool`` (gone from NumPy 1.24, Debian 12's python3-numpy) in its default
# "Shading: Use Normal Data" mode, whatever the file holds; "Shading: Smooth" skips
# that code. The README gives users exactly this option, so this script uses it.
IMPORT_OPTIONS = {"import_shading": "SMOOTH"}


def main(argv):
    glb, out, fps = argv[0], argv[1], int(argv[2])
    frames = [float(f) for f in argv[3:]]
    bpy.ops.wm.read_factory_settings(use_empty=True)  # no default cube, camera, light
    scene = bpy.context.scene
    scene.render.fps = fps
    scene.render.fps_base = 1.0
    bpy.ops.import_scene.gltf(filepath=glb, **IMPORT_OPTIONS)
    meshes = [o for o in scene.objects if o.type == "MESH"]
    if len(meshes) != 1:
        raise RuntimeError(f"expected one mesh object, got {[o.name for o in meshes]}")
    obj = meshes[0]
    actions = list(bpy.data.actions)
    action_ranges = np.array([tuple(a.frame_range) for a in actions], dtype=float).reshape(-1, 2)
    key_counts = np.array(
        [max((len(fc.keyframe_points) for fc in a.fcurves), default=0) for a in actions],
        dtype=int,
    )
    positions = []
    for f in frames:
        whole = int(np.floor(f))
        scene.frame_set(whole, subframe=f - whole)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        ev = obj.evaluated_get(depsgraph)
        me = ev.to_mesh()
        co = np.empty(len(me.vertices) * 3)
        me.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3)
        mw = np.array(ev.matrix_world)
        positions.append(co @ mw[:3, :3].T + mw[:3, 3])
        ev.to_mesh_clear()
    np.savez(
        out,
        vertex_counts=np.array([len(o.data.vertices) for o in meshes]),
        frame_range=np.array([scene.frame_start, scene.frame_end], dtype=float),
        action_ranges=action_ranges,
        key_counts=key_counts,
        frames=np.array(frames),
        positions=np.array(positions),
        fps=np.array([float(fps)]),
    )


main(sys.argv[sys.argv.index("--") + 1 :])
