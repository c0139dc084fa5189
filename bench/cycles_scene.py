# Blender (3.4) script: the preview renderer's scene in Cycles, for bench_render.
#   blender -b --factory-startup -noaudio --python bench/cycles_scene.py -- SCENE.json
# SCENE.json (written by bench_render) names a raw float32 height grid (row-major, NaN = hole),
# its grid (x0, y0, pixel_size), the mount plane, the camera, the environment and the material,
# the Cycles settings and the output EXR. Everything is scaled by 1000 (metres -> millimetres):
# radiance is scale-invariant and Cycles' float geometry is better conditioned at mm scale.
# Prints "CYCLES_RENDER_SECONDS <s>" (bpy.ops.render.render wall time: scene sync, BVH build
# and sampling, no Blender start-up or mesh creation).
import array
import json
import math
import sys
import time

import bpy
from mathutils import Vector

S = 1000.0  # metres -> millimetres

cfg = json.load(open(sys.argv[sys.argv.index("--") + 1]))
w, h = cfg["grid_width"], cfg["grid_height"]
z = array.array("f")
with open(cfg["height_raw"], "rb") as f:
    z.fromfile(f, w * h)
x0, y0, px = cfg["x0"], cfg["y0"], cfg["pixel_size"]

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene

# Height field: one vertex per finite sample, one quad per cell with four finite corners (as
# the Embree grid leaves out every cell touching a hole).
index = [-1] * (w * h)
verts = []
for j in range(h):
    for i in range(w):
        v = z[j * w + i]
        if v == v:  # not NaN
            index[j * w + i] = len(verts)
            verts.append(((x0 + i * px) * S, (y0 - j * px) * S, v * S))
faces = []
for j in range(h - 1):
    for i in range(w - 1):
        a, b = index[j * w + i], index[j * w + i + 1]
        c, d = index[(j + 1) * w + i + 1], index[(j + 1) * w + i]
        if a >= 0 and b >= 0 and c >= 0 and d >= 0:
            faces.append((a, d, c, b))  # counter-clockwise seen from +z (rows go towards -y)
mesh = bpy.data.meshes.new("heightfield")
mesh.from_pydata(verts, [], faces)
mesh.update()
obj = bpy.data.objects.new("heightfield", mesh)
scene.collection.objects.link(obj)


def diffuse_material(name, rgb):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (rgb[0], rgb[1], rgb[2], 1.0)
    bsdf.inputs["Roughness"].default_value = 0.0  # Lambert
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return m


obj.data.materials.append(diffuse_material("sample", cfg["albedo"]))

# Mount plane.
pz, ps = cfg["plane_z"] * S, cfg["plane_half_size"] * S
pm = bpy.data.meshes.new("mount")
pm.from_pydata([(-ps, -ps, pz), (ps, -ps, pz), (ps, ps, pz), (-ps, ps, pz)], [], [(0, 1, 2, 3)])
pm.update()
po = bpy.data.objects.new("mount", pm)
po.data.materials.append(diffuse_material("mount", cfg["mount_albedo"]))
scene.collection.objects.link(po)

# Camera: pinhole, vertical field of view, looking from eye to target with +z up.
cam_data = bpy.data.cameras.new("camera")
cam_data.sensor_fit = "VERTICAL"
cam_data.angle = math.radians(cfg["fov_deg"])
cam_data.clip_start = 1e-3
cam_data.clip_end = 1e5
cam = bpy.data.objects.new("camera", cam_data)
eye, target = Vector(cfg["eye"]) * S, Vector(cfg["target"]) * S
cam.location = eye
cam.rotation_euler = (target - eye).to_track_quat("-Z", "Y").to_euler()
scene.collection.objects.link(cam)
scene.camera = cam

# World: lat-long environment (Blender's convention, which mesoscan's env map follows), turned
# about +z like EnvironmentMap::SetRotation; or a constant colour.
world = bpy.data.worlds.new("world")
scene.world = world
world.use_nodes = True
nt = world.node_tree
nt.nodes.clear()
bg = nt.nodes.new("ShaderNodeBackground")
wout = nt.nodes.new("ShaderNodeOutputWorld")
nt.links.new(bg.outputs["Background"], wout.inputs["Surface"])
if cfg.get("env_exr"):
    tex = nt.nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(cfg["env_exr"])
    tex.image.colorspace_settings.name = "Linear"
    tex.interpolation = "Closest"  # mesoscan looks texels up without filtering
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value[2] = -math.radians(cfg.get("env_rotation_deg", 0.0))
    nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = cfg.get("env_scale", 1.0)
else:
    c = cfg["env_constant"]
    bg.inputs["Color"].default_value = (c[0], c[1], c[2], 1.0)
    bg.inputs["Strength"].default_value = 1.0

# Cycles: the comparison's settings (box filter, no denoising or clamping, fixed samples).
scene.render.engine = "CYCLES"
cy = scene.cycles
cy.device = "CPU"
cy.samples = cfg["spp"]
cy.use_adaptive_sampling = False
cy.use_denoising = False
cy.seed = cfg.get("seed", 0)
cy.pixel_filter_type = "BOX"
cy.filter_width = 1.0
depth = cfg["max_depth"]  # mesoscan: surface vertices; Cycles: bounces after the first hit
cy.max_bounces = depth - 1
cy.diffuse_bounces = depth - 1
cy.glossy_bounces = depth - 1
cy.transmission_bounces = 0
cy.transparent_max_bounces = 0
cy.volume_bounces = 0
cy.sample_clamp_direct = 0.0
cy.sample_clamp_indirect = 0.0
cy.blur_glossy = 0.0
cy.light_sampling_threshold = 0.0
world.cycles.sampling_method = "MANUAL" if cfg.get("env_exr") else "NONE"
if cfg.get("env_exr"):
    world.cycles.sample_map_resolution = max(tex.image.size[0], 64)
scene.render.threads_mode = "FIXED"
scene.render.threads = cfg.get("threads", 2)
scene.render.resolution_x = cfg["width"]
scene.render.resolution_y = cfg["height"]
scene.render.resolution_percentage = 100
scene.render.film_transparent = False
scene.view_settings.view_transform = "Standard"
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.image_settings.color_depth = "32"
scene.render.image_settings.color_mode = "RGB"
scene.render.image_settings.exr_codec = "NONE"
scene.render.filepath = cfg["out_exr"]

t0 = time.time()
bpy.ops.render.render(write_still=True)
print("CYCLES_RENDER_SECONDS %.4f" % (time.time() - t0), flush=True)
