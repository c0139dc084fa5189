# Set-up shared by the Blender 3.4 background checks of map sets (blender_maps_checks.py,
# blender_seam_checks.py): the config, the add-on's installation, and a top-down orthographic
# render of a plane under a sun, read back as a grey image.
import json
import math
import sys

import bpy
import numpy


def read_config():
    """The JSON config named after "--" on Blender's command line."""
    with open(sys.argv[sys.argv.index("--") + 1]) as f:
        return json.load(f)


def install_addon(zip_path):
    bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
    bpy.ops.preferences.addon_enable(module="mesoscan_maps")


def clear_scene():
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o, do_unlink=True)


def setup_render(size_m, res, engine="CYCLES", samples=8, world_strength=0.0, sun_tilt_deg=70.0,
                 box_filter=False):
    """Camera looking down -z at a size_m square (res x res pixels), a sun tilted sun_tilt_deg
    from the zenith towards the (+x, +y) diagonal (raking light: seams along both axes are lit
    across), a uniform world of world_strength. box_filter: Cycles' pixel filter a 1-pixel box
    and Eevee's filter 0.5 pixel, so each pixel sees about one texel at one pixel per texel."""
    scene = bpy.context.scene
    scene.render.engine = engine
    if engine == "CYCLES":
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.seed = 1
        scene.cycles.use_denoising = False
        scene.cycles.max_bounces = 1
        if box_filter:
            scene.cycles.pixel_filter_type = "BOX"
    else:
        scene.eevee.taa_render_samples = samples
        scene.eevee.use_gtao = False
        scene.eevee.use_ssr = False
        scene.eevee.use_soft_shadows = False
        scene.eevee.shadow_cascade_size = "1024"
    if box_filter:
        scene.render.filter_size = 0.5 if engine == "BLENDER_EEVEE" else 1.0
    scene.render.resolution_x = res
    scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("w")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = world_strength
    scene.world = world
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = size_m
    cam_data.clip_start = 1e-4
    cam_data.clip_end = 10.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (0.0, 0.0, 0.5)
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy = 3.0
    sun_data.angle = 0.0
    sun = bpy.data.objects.new("sun", sun_data)
    sun.rotation_euler = (0.0, math.radians(sun_tilt_deg), math.radians(45.0))
    scene.collection.objects.link(sun)


def render(path):
    """Renders the scene to path (EXR) and returns its grey (mean of R, G, B), row 0 at the top."""
    bpy.context.scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path, check_existing=False)
    w, h = img.size
    px = numpy.array(img.pixels[:], dtype=numpy.float64).reshape(h, w, 4)[:, :, :3].mean(axis=2)
    bpy.data.images.remove(img)
    return px[::-1]
