"""Opens a `facesim export` in Blender (Debian's 3.4) as an artist would and checks it:
the PC2 topology OBJ (vertex order kept) with the cache on a Mesh Cache modifier, and the glTF
file. Both must come in with the rig's UV layer and one material per part, and play.

Usage: blender --background --factory-startup --python-exit-code 1 --python check_export.py -- NAME.obj NAME.pc2 NAME.glb FRAMES
Prints "ok" or exits 1.
"""

import sys

import bpy
import numpy

# Blender 3.4's glTF importer still says `numpy.bool`, which numpy 1.24 removed.
if not hasattr(numpy, "bool"):
    numpy.bool = bool


def need(cond, message):
    if not cond:
        print(f"blender check failed: {message}")
        sys.exit(1)


def main(obj_path, pc2_path, glb_path, frames):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.obj_import(filepath=obj_path, forward_axis="NEGATIVE_Z", up_axis="Y")
    (face,) = bpy.context.selected_objects
    mesh = face.data
    need(len(mesh.uv_layers) == 1, f"{len(mesh.uv_layers)} UV layers in the OBJ")
    names = sorted(m.name for m in mesh.materials)
    need("M_Face" in names and "M_EyeLashes" in names, f"OBJ materials {names}")
    rest = [v.co.copy() for v in mesh.vertices]
    cache = face.modifiers.new("cache", "MESH_CACHE")
    cache.cache_format = "PC2"
    cache.filepath = pc2_path
    # The importer keeps the file's coordinates and turns the object (Y up to Blender's Z
    # up), so the cache is read as it is: the modifier's default axes.

    def moved(frame):
        bpy.context.scene.frame_set(frame)
        evaluated = face.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        need(len(evaluated.vertices) == len(rest), "the cache's points are the OBJ's vertices")
        return max((v.co - r).length for v, r in zip(evaluated.vertices, rest))

    first, last = moved(0), moved(frames - 1)
    need(first < 1e-4, f"frame 0 is the OBJ's rest pose ({first} cm off)")
    need(0.1 < last < 5.0, f"the cache moves the face ({last:.3f} cm at the last frame)")

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb_path)
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    need(len(meshes) == 1, f"{len(meshes)} glTF meshes")
    mesh = meshes[0].data
    need(len(mesh.uv_layers) == 1, f"{len(mesh.uv_layers)} UV layers in the glTF")
    need(len(mesh.materials) >= 12, f"{len(mesh.materials)} glTF materials")
    keys = mesh.shape_keys.key_blocks if mesh.shape_keys else []
    need(len(keys) == frames + 1, f"{len(keys)} shape keys (basis + one per frame)")
    print(f"ok: OBJ + PC2 with {len(rest)} vertices moving up to {last:.2f} cm, "
          f"1 UV layer, {len(names)} materials; glTF with {len(keys) - 1} frame targets")


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1 :]
    main(args[0], args[1], args[2], int(args[3]))
