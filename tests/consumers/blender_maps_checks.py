# Blender 3.4 checks of the mesoscan map-set add-on (tools/blender_addon), run by
# tests/maps_cli_test.cc:
#   BLENDER_USER_SCRIPTS=TMP blender -b --factory-startup --python-exit-code 1 \
#     -P blender_maps_checks.py -- config.json
# 1. installs the add-on from its zip and imports a map set through its operator: the plane's
#    size, the node tree, the Displacement node's Midlevel/Scale/space and the images' settings
#    are measured;
# 2. renders the imported plane (Cycles, true displacement from the height EXR) and the same
#    plane whose vertices were moved by the EXR's heights in Python (the reference), and a flat
#    plane (to show what the comparison can see);
# 3. renders a tileable set repeated 2 x 2 under raking light and measures the column-to-column
#    change of the image at the seam against its neighbours (also for an untiled crop forced to
#    Repeat, which has a seam).
# Measurements go to the config's "out" JSON; the C++ test asserts.
import json
import os
import sys

import bpy
import numpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blender_scene import clear_scene, install_addon, read_config, render, setup_render  # noqa: E402

cfg = read_config()
out = {"blender_version": bpy.app.version_string}


def image_array(img):
    w, h = img.size
    return numpy.array(img.pixels[:], dtype=numpy.float64).reshape(h, w, img.channels)[:, :, 0]


# 1. Install the zip and import.
install_addon(cfg["addon_zip"])
clear_scene()
res = bpy.ops.import_scene.mesoscan_maps(filepath=cfg["manifest"], target="PLANE", repeat=1)
out["import_result"] = list(res)
obj = [o for o in bpy.context.scene.objects if o.type == "MESH"][0]
mat = obj.active_material
nt = mat.node_tree
disp = nt.nodes["mesoscan displacement"]
out["dimensions"] = list(obj.dimensions)
out["vertices"] = len(obj.data.vertices)
out["displacement"] = {"midlevel": disp.inputs["Midlevel"].default_value,
                       "scale": disp.inputs["Scale"].default_value, "space": disp.space}
out["displacement_method"] = mat.cycles.displacement_method
out["links"] = sorted({"%s.%s->%s.%s" % (l.from_node.name, l.from_socket.name, l.to_node.name, l.to_socket.name)
                       for l in nt.links})
out["images"] = {n.name: {"file": os.path.basename(n.image.filepath), "colorspace": n.image.colorspace_settings.name,
                          "extension": n.extension} for n in nt.nodes if n.type == "TEX_IMAGE"}

# 2. Render the add-on's displacement against the EXR-displaced reference and a flat plane.
size = max(obj.dimensions[0], obj.dimensions[1])
setup_render(size, cfg.get("render_px", 160), samples=cfg.get("samples", 8))
tmp = cfg["tmp"]
a = render(os.path.join(tmp, "addon.exr"))
# The reference: the same mesh, vertices moved by the EXR (bilinear at each vertex's UV, as
# Cycles samples it; Repeat wraps, Extend clamps), and the material's displacement unlinked.
height_img = nt.nodes["height"].image
H = image_array(height_img)  # rows bottom to top, as UV v
hh, hw = H.shape
wrap = nt.nodes["height"].extension == "REPEAT"
me = obj.data
uv = me.uv_layers.active.data
vert_uv = numpy.zeros((len(me.vertices), 2))
for li, loop in enumerate(me.loops):
    vert_uv[loop.vertex_index] = uv[li].uv
fx = vert_uv[:, 0] * hw - 0.5
fy = vert_uv[:, 1] * hh - 0.5
x0 = numpy.floor(fx).astype(int)
y0 = numpy.floor(fy).astype(int)
ax = fx - x0
ay = fy - y0


def tex(x, y):
    if wrap:
        return H[y % hh, x % hw]
    return H[numpy.clip(y, 0, hh - 1), numpy.clip(x, 0, hw - 1)]


z = ((1 - ax) * (1 - ay) * tex(x0, y0) + ax * (1 - ay) * tex(x0 + 1, y0) +
     (1 - ax) * ay * tex(x0, y0 + 1) + ax * ay * tex(x0 + 1, y0 + 1))
midlevel, scale = disp.inputs["Midlevel"].default_value, disp.inputs["Scale"].default_value
co = numpy.zeros(3 * len(me.vertices))
me.vertices.foreach_get("co", co)
co = co.reshape(-1, 3)
flat_co = co.copy()
co[:, 2] = (z - midlevel) * scale
out_link = [l for l in nt.links if l.to_node.type == "OUTPUT_MATERIAL" and l.to_socket.name == "Displacement"][0]
nt.links.remove(out_link)
me.vertices.foreach_set("co", co.ravel())
me.update()
b = render(os.path.join(tmp, "reference.exr"))
me.vertices.foreach_set("co", flat_co.ravel())
me.update()
c = render(os.path.join(tmp, "flat.exr"))
out["render"] = {"mean": float(a.mean()), "addon_vs_reference_mean_abs": float(numpy.abs(a - b).mean()),
                 "addon_vs_flat_mean_abs": float(numpy.abs(a - c).mean()),
                 "reference_height_range_m": [float(z.min()), float(z.max())]}


# 3. Seams: 2 x 2 repeats under raking light across the seam.
def seam_score(manifest, force_repeat):
    clear_scene()
    bpy.ops.import_scene.mesoscan_maps(filepath=manifest, target="PLANE", repeat=2)
    o = [o for o in bpy.context.scene.objects if o.type == "MESH"][0]
    for n in o.active_material.node_tree.nodes:
        if n.type == "TEX_IMAGE" and force_repeat:
            n.extension = "REPEAT"
    w_px = int(json.load(open(manifest))["grid"]["width_px"]) * 2
    setup_render(max(o.dimensions[0], o.dimensions[1]), w_px, samples=cfg.get("samples", 8))
    img = render(os.path.join(tmp, "seam_%d.exr" % force_repeat))
    # Column-to-column (x) and row-to-row (y) mean change; the seam lies between columns
    # (rows) s and s + 1. It is compared with every other interior column (row): its ratio to
    # their mean and its z-score in their distribution.
    s = w_px // 2 - 1
    res = {"extension": [n.extension for n in o.active_material.node_tree.nodes if n.type == "TEX_IMAGE"]}
    for axis, name in ((1, "x"), (0, "y")):
        d = numpy.abs(numpy.diff(img, axis=axis)).mean(axis=1 - axis)
        others = numpy.delete(d, [s])[2:-2]
        res[name + "_seam"] = float(d[s])
        res[name + "_ratio"] = float(d[s] / others.mean())
        res[name + "_z"] = float((d[s] - others.mean()) / others.std())
    return res


out["seam_tiled"] = seam_score(cfg["manifest"], False)
if cfg.get("manifest_untiled"):
    out["seam_untiled"] = seam_score(cfg["manifest_untiled"], True)

with open(cfg["out"], "w") as f:
    json.dump(out, f, indent=1)
