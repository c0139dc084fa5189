# Blender 3.4 seam checks of a tileable map set through the mesoscan add-on (tools/blender_addon),
# run by tests/maps_cli_test.cc (the demo fabric's tile):
#   BLENDER_USER_SCRIPTS=TMP blender -b --factory-startup --python-exit-code 1 \
#     -P blender_seam_checks.py -- config.json
# The add-on imports the set on a new plane repeated 3 x 3 (as an artist would); the plane is
# rendered top-down (orthographic, about one pixel per texel) under raking light from the (+x, +y)
# diagonal by each engine in the config ("BLENDER_EEVEE", "CYCLES"). Per image column (row): the
# mean absolute change to the next column (row) over the rows (columns). The seams are the
# columns (rows) where one repeat meets the next (2 per axis, each spanning the 3 repeats) and
# the lines inside the tile where the blend's shifted copies met (the manifest's blend shift s:
# at N - s); the interior is every other column (row) of the same parity, away from the image
# border and within 2 pixels of no seam. Reported per seam: its value, the interior's mean and
# standard deviation (its own scatter) and the z-score; the C++ test asserts.
import json
import os
import sys
import time

import bpy
import numpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blender_scene import clear_scene, install_addon, read_config, render, setup_render  # noqa: E402

cfg = read_config()
out = {"blender_version": bpy.app.version_string}
with open(cfg["manifest"]) as f:
    manifest = json.load(f)
REPEAT = 3


def seams(img, n_px):
    """Per axis: the mean |change| per column (row); the seams' values against the interior."""
    tile = img.shape[0] / REPEAT  # pixels per repeat
    shift = manifest.get("tile", {}).get("blend_shift_px", [0, 0])
    # The shift counts in the tile's own pixels, before any resampling to the set's size.
    n_tile = manifest.get("resampled", {}).get("from_px", [n_px, n_px])
    res = {}
    for axis, name in ((1, "x"), (0, "y")):
        d = numpy.abs(numpy.diff(img, axis=axis)).mean(axis=1 - axis)  # d[i]: between i and i+1
        n = len(d)
        # The change across a line at position p (pixels) is d[round(p) - 1].
        lines = {"repeat": [k * tile for k in range(1, REPEAT)]}
        s, nt = shift[0 if name == "x" else 1], n_tile[0 if name == "x" else 1]
        if s:
            lines["blend"] = [(k + (nt - s) / nt) * tile for k in range(REPEAT)]
        idx = {kind: [int(round(p)) - 1 for p in ps] for kind, ps in lines.items()}
        near = set()
        for ps in idx.values():
            for i in ps:
                near.update(range(i - 2, i + 3))
        # Each seam against the interior columns (rows) of its own parity: Eevee's bump takes its
        # derivatives per 2 x 2 pixel quad, so the change within a quad and across quads differ
        # everywhere (a scatter of its own that is no seam).
        for kind, ps in idx.items():
            vals, zs, means, stds = [], [], [], []
            for i in ps:
                if not 0 <= i < n:
                    continue
                interior = numpy.array([d[k] for k in range(3, n - 3) if k not in near and k % 2 == i % 2])
                mean, std = float(interior.mean()), float(interior.std())
                vals.append(float(d[i]))
                zs.append((float(d[i]) - mean) / std)
                means.append(mean)
                stds.append(std)
            res["%s_%s" % (name, kind)] = {
                "values": vals, "interior_mean": float(numpy.mean(means)),
                "interior_std": float(numpy.mean(stds)), "z": zs}
    return res


install_addon(cfg["addon_zip"])
n_px = int(manifest["grid"]["width_px"])
for engine in cfg.get("engines", ["BLENDER_EEVEE", "CYCLES"]):
    t0 = time.time()
    clear_scene()
    bpy.ops.import_scene.mesoscan_maps(filepath=cfg["manifest"], target="PLANE", repeat=REPEAT)
    obj = [o for o in bpy.context.scene.objects if o.type == "MESH"][0]
    size = max(obj.dimensions[0], obj.dimensions[1])
    res = cfg.get("render_px", REPEAT * n_px)
    samples = cfg.get("cycles_samples", 4) if engine == "CYCLES" else cfg.get("eevee_samples", 4)
    setup_render(size, res, engine=engine, samples=samples, world_strength=0.05, sun_tilt_deg=60.0,
                 box_filter=True)
    try:
        img = render(os.path.join(cfg["tmp"], "seam_%s.exr" % engine.lower()))
    except RuntimeError as e:  # Eevee without an OpenGL context (no EGL/X display)
        out[engine] = {"error": str(e)}
        continue
    r = seams(img, n_px)
    r["seconds"] = time.time() - t0
    r["mean"] = float(img.mean())
    r["links"] = sorted("%s.%s->%s.%s" % (l.from_node.name, l.from_socket.name, l.to_node.name,
                                          l.to_socket.name) for l in obj.active_material.node_tree.links)
    out[engine] = r

# The selected-object import on a sphere: box projection by default (each image projected along
# the object's axes at the tile's size), the normal map left unlinked, displacement and bump.
clear_scene()
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.01)
sphere = bpy.context.active_object
bpy.ops.import_scene.mesoscan_maps(filepath=cfg["manifest"], target="SELECTED")
snt = sphere.active_material.node_tree
out["sphere"] = {
    "projections": sorted({n.projection for n in snt.nodes if n.type == "TEX_IMAGE"}),
    "mapping_scale": list(snt.nodes["mesoscan mapping"].inputs["Scale"].default_value),
    "displacement_method": sphere.active_material.cycles.displacement_method,
    "normal_linked": any(l.from_node.name == "mesoscan normal map" for l in snt.links),
    "coords": [l.from_socket.name for l in snt.links if l.to_node.name == "mesoscan mapping"]}

with open(cfg["out"], "w") as f:
    json.dump(out, f, indent=1)
