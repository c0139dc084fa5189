# Blender 3.4 check that a coloured map set keeps its colour through the mesoscan add-on
# (tools/blender_addon), run by tests/materials_cli_test.cc:
#   BLENDER_USER_SCRIPTS=TMP blender -b --factory-startup --python-exit-code 1 \
#     -P blender_colour_checks.py -- config.json
# Installs the add-on from its zip, imports the map set onto a plane, follows the material's link
# into the Principled BSDF's Base Color back to the albedo image, and renders the plane from above
# (Cycles, a few samples, a white sun straight down): the albedo image's mean R, G, B and the
# render's are written to the config's "out" JSON; the C++ test asserts.
import json
import math
import sys

import bpy
import numpy

cfg = json.load(open(sys.argv[sys.argv.index("--") + 1]))
out = {"blender_version": bpy.app.version_string}

bpy.ops.preferences.addon_install(filepath=cfg["addon_zip"], overwrite=True)
bpy.ops.preferences.addon_enable(module="mesoscan_maps")
for o in list(bpy.data.objects):
    bpy.data.objects.remove(o, do_unlink=True)
bpy.ops.import_scene.mesoscan_maps(filepath=cfg["manifest"], target="PLANE", repeat=1)
obj = [o for o in bpy.context.scene.objects if o.type == "MESH"][0]
nt = obj.active_material.node_tree
bsdf = [n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"][0]


def upstream_images(socket):
    """Image texture nodes feeding `socket`, through any chain of nodes."""
    found, todo = [], [l.from_node for l in socket.links]
    while todo:
        n = todo.pop()
        if n.type == "TEX_IMAGE":
            found.append(n)
        for s in n.inputs:
            todo.extend(l.from_node for l in s.links)
    return found


images = upstream_images(bsdf.inputs["Base Color"])
out["base_color_images"] = sorted(n.name for n in images)
albedo = [n for n in images if n.name == "albedo"]
if albedo:
    img = albedo[0].image
    w, h = img.size
    px = numpy.array(img.pixels[:], dtype=numpy.float64).reshape(h, w, img.channels)
    out["albedo_image"] = {"file": img.filepath, "colorspace": img.colorspace_settings.name,
                           "channels": img.channels,
                           "mean_rgb": [float(px[:, :, c].mean()) for c in range(3)]}

scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 4
scene.cycles.seed = 1
scene.cycles.use_denoising = False
scene.cycles.max_bounces = 1
scene.render.resolution_x = scene.render.resolution_y = cfg.get("render_px", 48)
scene.render.resolution_percentage = 100
scene.render.image_settings.file_format = "OPEN_EXR"
scene.view_settings.view_transform = "Standard"
world = bpy.data.worlds.new("w")
world.use_nodes = True
world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
scene.world = world
size = max(obj.dimensions[0], obj.dimensions[1])
cam_data = bpy.data.cameras.new("cam")
cam_data.type = "ORTHO"
cam_data.ortho_scale = size
cam_data.clip_start = 1e-4
cam = bpy.data.objects.new("cam", cam_data)
cam.location = (0.0, 0.0, 0.5)
scene.collection.objects.link(cam)
scene.camera = cam
sun_data = bpy.data.lights.new("sun", "SUN")
sun_data.energy = 3.0
sun_data.color = (1.0, 1.0, 1.0)
sun = bpy.data.objects.new("sun", sun_data)
sun.rotation_euler = (0.0, math.radians(10.0), 0.0)
scene.collection.objects.link(sun)
path = cfg["tmp"] + "/colour.exr"
scene.render.filepath = path
bpy.ops.render.render(write_still=True)
r = bpy.data.images.load(path, check_existing=False)
w, h = r.size
px = numpy.array(r.pixels[:], dtype=numpy.float64).reshape(h, w, 4)
out["render_mean_rgb"] = [float(px[:, :, c].mean()) for c in range(3)]
json.dump(out, open(cfg["out"], "w"), indent=1)
