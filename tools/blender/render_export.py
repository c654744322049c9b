"""Renders a frame of a `facesim export` in Blender (Debian's 3.4, Cycles on the CPU), as an
artist would see it: the PC2 topology OBJ with the cache on a Mesh Cache modifier, a UV test
grid on every part through the rig's UVs, the eyes' see-through layers transparent.

    blender --background --factory-startup --python-exit-code 1 --python tools/blender/render_export.py -- NAME.obj NAME.pc2 OUT.png FRAME

The README's export picture: `examples/tracks/smile.json` exported with `--format pc2 --fps 3`,
frame 5 (t = 1.67 s, the smile).
"""

import bpy, sys, math
from mathutils import Vector
obj_path, pc2_path, out_png, frame = sys.argv[sys.argv.index("--") + 1:][:4]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.obj_import(filepath=obj_path)
(face,) = bpy.context.selected_objects
cache = face.modifiers.new("cache", "MESH_CACHE"); cache.cache_format = "PC2"; cache.filepath = pc2_path
scene = bpy.context.scene
scene.frame_set(int(frame))
# UV test texture on every part; the see-through layers transparent.
grid = bpy.data.images.new("grid", 1024, 1024); grid.generated_type = "COLOR_GRID"
for slot in face.material_slots:
    m = slot.material; m.use_nodes = True; nt = m.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    if m.name in ("M_EyeBlend", "M_EyeOcclusion", "M_LacrimalFluid"):
        bsdf.inputs["Alpha"].default_value = 0.0; m.blend_method = "BLEND"; continue
    tex = nt.nodes.new("ShaderNodeTexImage"); tex.image = grid
    nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.6
bpy.context.view_layer.update()
dg = bpy.context.evaluated_depsgraph_get()
ev = face.evaluated_get(dg)
pts = [ev.matrix_world @ v.co for v in ev.data.vertices]
lo = Vector([min(p[i] for p in pts) for i in range(3)]); hi = Vector([max(p[i] for p in pts) for i in range(3)])
c = (lo + hi) / 2
cam_data = bpy.data.cameras.new("cam"); cam_data.lens = 85
cam = bpy.data.objects.new("cam", cam_data); scene.collection.objects.link(cam)
cam.location = (c.x + 25, c.y - 95, c.z + 12)
direction = Vector((c.x, c.y, c.z + 4)) - cam.location
cam.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
scene.camera = cam
for loc, energy in [((60, -80, 60), 60000), ((-80, -40, 20), 25000)]:
    light = bpy.data.lights.new("l", "POINT"); light.energy = energy
    o = bpy.data.objects.new("l", light); o.location = loc; scene.collection.objects.link(o)
world = bpy.data.worlds.new("w"); scene.world = world; world.use_nodes = True
world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.055, 0.065, 1)
scene.render.engine = "CYCLES"; scene.cycles.samples = 24; scene.cycles.device = "CPU"; scene.cycles.use_denoising = False
scene.render.resolution_x = 640; scene.render.resolution_y = 640
scene.render.filepath = out_png
bpy.ops.render.render(write_still=True)
print("rendered", out_png)
