# Blender 3.4 checks of mesoscan's exports, run by tests/export_consumers_test.cc (synthetic
# scan) and tests/export_coin_test.cc (the demo coin), through tests/export_consumers.h:
#   blender -b --factory-startup --python-exit-code 1 -P blender_checks.py -- config.json
# The config names the files and the sample pixels; every measurement is written to the
# config's "out" JSON, and the C++ test compares it with the scan it exported. The script
# asserts nothing itself (the test does), but any exception exits Blender with code 1.
import json
import sys

import bpy
import numpy
from mathutils import kdtree

# Debian 12's Blender 3.4.1 ships a glTF importer that uses numpy.bool, removed in Debian's
# numpy 1.24: its default import (Shading "Use Normal Data") fails on any mesh with normals,
# whatever the file. Users work around it with Shading "Smooth"; here the alias is restored so
# the importer's default path (the one blender.org builds run) is the one tested.
if not hasattr(numpy, "bool") or numpy.__dict__.get("bool") is None:
    numpy.bool = bool

cfg = json.load(open(sys.argv[sys.argv.index("--") + 1]))
out = {"blender_version": bpy.app.version_string}


def clear_scene():
    bpy.ops.object.select_all(action="SELECT")
    bpy.ops.object.delete()


def load_image(path, colorspace="Non-Color"):
    img = bpy.data.images.load(path, check_existing=False)
    img.colorspace_settings.name = colorspace
    return img


# 1. The GLB: vertex count, bounding box in metres (after Blender's +Y-up -> +Z-up import),
# the node extras and the material's texture wiring.
if cfg.get("glb"):
    clear_scene()
    bpy.ops.import_scene.gltf(filepath=cfg["glb"])
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    # World positions of every vertex (object matrix applied, in float64).
    world = numpy.zeros((0, 3))
    for o in meshes:
        co = numpy.zeros(3 * len(o.data.vertices), dtype=numpy.float32)
        o.data.vertices.foreach_get("co", co)
        mw = numpy.array(o.matrix_world, dtype=numpy.float64)
        world = numpy.vstack([world, co.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3]])
    verts = len(world)
    lo = world.min(axis=0).tolist() if verts else [float("inf")] * 3
    hi = world.max(axis=0).tolist() if verts else [float("-inf")] * 3
    # Heights of the imported mesh at world points (x, y): the vertex nearest in x, y.
    points = []
    if cfg.get("glb_points"):
        tree = kdtree.KDTree(verts)
        for n, p in enumerate(world):
            tree.insert((p[0], p[1], 0.0), n)
        tree.balance()
        for x, y in cfg["glb_points"]:
            _, n, _ = tree.find((x, y, 0.0))
            points.append(world[n].tolist())
    extras = {}
    links = []
    if meshes:
        o = meshes[0]
        for k in o.keys():
            val = o[k]
            extras[k] = val if isinstance(val, (int, float, str)) else str(val)
        mat = o.active_material
        if mat and mat.use_nodes:
            for l in mat.node_tree.links:
                links.append([l.from_node.type, l.to_node.type, l.to_socket.name])
    out["glb"] = {"objects": len(meshes), "vertices": verts, "bbox_min": lo, "bbox_max": hi,
                  "extras": extras, "material_links": links, "points": points}

# 2. Displacement: one tiny triangle per sample pixel, all three corners carrying the UV of
# that pixel's centre (v flipped: Blender's image row 0 is the bottom one), displaced along Z by
# the height map read at its texel (no interpolation), (value - midlevel) * scale; the evaluated
# z of the first corner is the displaced height. Two of Blender's ways:
#  - "modifier": a Displace modifier (texture coordinates UV) with the map as an Image texture.
#    Blender's image texture clamps values below 0 (BRICONTRGB), so heights under the mount
#    plane in a midlevel-0 EXR land on 0 (export.cc's hint says so);
#  - "nodes": a Geometry Nodes modifier, Image Texture node (the sampling of the shader's Image
#    Texture -> Displacement node path) -> Set Position offset, which keeps negative values.
def sample_mesh():
    w, h = cfg["width"], cfg["height"]
    verts, faces, uvs = [], [], []
    for n, (i, j) in enumerate(cfg["samples"]):
        x, y = cfg["x0"] + i * cfg["pixel_size"], cfg["y0"] - j * cfg["pixel_size"]
        d = 0.25 * cfg["pixel_size"]
        verts += [(x, y, 0.0), (x + d, y, 0.0), (x, y + d, 0.0)]
        faces.append((3 * n, 3 * n + 1, 3 * n + 2))
        uvs += [((i + 0.5) / w, 1.0 - (j + 0.5) / h)] * 3
    me = bpy.data.meshes.new("samples")
    me.from_pydata(verts, [], faces)
    uv = me.uv_layers.new(name="UVMap")
    for loop in me.loops:
        uv.data[loop.index].uv = uvs[loop.vertex_index]
    uvpt = me.attributes.new("uv_point", "FLOAT_VECTOR", "POINT")  # the same UV per vertex
    for n, (u, v) in enumerate(uvs):
        uvpt.data[n].vector = (u, v, 0.0)
    obj = bpy.data.objects.new("samples", me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def displace_nodes(obj, image, midlevel, scale):
    ng = bpy.data.node_groups.new("displace", "GeometryNodeTree")
    ng.inputs.new("NodeSocketGeometry", "Geometry")
    ng.outputs.new("NodeSocketGeometry", "Geometry")
    n_in = ng.nodes.new("NodeGroupInput")
    n_out = ng.nodes.new("NodeGroupOutput")
    attr = ng.nodes.new("GeometryNodeInputNamedAttribute")
    attr.data_type = "FLOAT_VECTOR"
    attr.inputs["Name"].default_value = "uv_point"
    tex = ng.nodes.new("GeometryNodeImageTexture")
    tex.interpolation = "Closest"
    tex.extension = "EXTEND"
    tex.inputs["Image"].default_value = image
    sep = ng.nodes.new("ShaderNodeSeparateXYZ")  # colour -> vector: R, G, B as x, y, z
    sub = ng.nodes.new("ShaderNodeMath")
    sub.operation = "SUBTRACT"
    sub.inputs[1].default_value = midlevel
    mul = ng.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = scale
    comb = ng.nodes.new("ShaderNodeCombineXYZ")
    setpos = ng.nodes.new("GeometryNodeSetPosition")
    links = ng.links
    links.new(n_in.outputs[0], setpos.inputs["Geometry"])
    links.new([o for o in attr.outputs if o.enabled][0], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], sep.inputs[0])
    links.new(sep.outputs["X"], sub.inputs[0])
    links.new(sub.outputs[0], mul.inputs[0])
    links.new(mul.outputs[0], comb.inputs["Z"])
    links.new(comb.outputs[0], setpos.inputs["Offset"])
    links.new(setpos.outputs["Geometry"], n_out.inputs[0])
    mod = obj.modifiers.new("displace", "NODES")
    mod.node_group = ng


def displaced_heights(image_path, midlevel, scale, how="modifier"):
    clear_scene()
    obj = sample_mesh()
    image = load_image(image_path)
    if how == "nodes":
        displace_nodes(obj, image, midlevel, scale)
    else:
        tex = bpy.data.textures.new("height", type="IMAGE")
        tex.image = image
        tex.use_interpolation = False
        tex.use_mipmap = False
        tex.extension = "EXTEND"
        mod = obj.modifiers.new("displace", "DISPLACE")
        mod.texture = tex
        mod.texture_coords = "UV"
        mod.uv_layer = "UVMap"
        mod.direction = "Z"
        mod.mid_level = midlevel
        mod.strength = scale
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg).to_mesh()
    z = [ev.vertices[3 * n].co.z for n in range(len(cfg["samples"]))]
    obj.evaluated_get(dg).to_mesh_clear()
    return z, image


if cfg.get("height_exr"):
    z, img = displaced_heights(cfg["height_exr"], 0.0, 1.0)
    out["displace_exr"] = z
    # What Blender decoded from the one-channel EXR at the first sample: R, G, B, A.
    i, j = cfg["samples"][0]
    row = cfg["height"] - 1 - j
    k = 4 * (row * cfg["width"] + i)
    out["exr_first_sample_rgba"] = list(img.pixels[k:k + 4])
    out["exr_channels_seen"] = img.channels
    out["displace_exr_nodes"], _ = displaced_heights(cfg["height_exr"], 0.0, 1.0, "nodes")
if cfg.get("height_png"):
    z, _ = displaced_heights(cfg["height_png"], cfg["png_midlevel"], cfg["png_scale"])
    out["displace_png"] = z

# 3. Normal maps: a 2 x 2 plane (UV 0..1, tangent +X, bitangent +Y) whose material reads the
# map through a Normal Map node (tangent space); the shading normal, mapped to 0.5 + 0.5 n, is
# baked (Cycles, EMIT, 1 sample) into a float image of the map's size, so each baked pixel is
# the texel of the same index. `invert_green` inserts the usual DirectX fix (G -> 1 - G).
def bake_normal_map(path, invert_green):
    clear_scene()
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False  # Debian's Cycles has no OpenImageDenoise: bakes black
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    obj = bpy.context.active_object
    mat = bpy.data.materials.new("normal_check")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = load_image(path)
    tex.interpolation = "Closest"
    nmap = nt.nodes.new("ShaderNodeNormalMap")
    nmap.space = "TANGENT"
    nmap.uv_map = "UVMap"
    if invert_green:
        sep = nt.nodes.new("ShaderNodeSeparateRGB")
        inv = nt.nodes.new("ShaderNodeMath")
        inv.operation = "SUBTRACT"
        inv.inputs[0].default_value = 1.0
        comb = nt.nodes.new("ShaderNodeCombineRGB")
        nt.links.new(tex.outputs["Color"], sep.inputs["Image"])
        nt.links.new(sep.outputs["R"], comb.inputs["R"])
        nt.links.new(sep.outputs["G"], inv.inputs[1])
        nt.links.new(inv.outputs[0], comb.inputs["G"])
        nt.links.new(sep.outputs["B"], comb.inputs["B"])
        nt.links.new(comb.outputs["Image"], nmap.inputs["Color"])
    else:
        nt.links.new(tex.outputs["Color"], nmap.inputs["Color"])
    remap = nt.nodes.new("ShaderNodeVectorMath")
    remap.operation = "MULTIPLY_ADD"
    remap.inputs[1].default_value = (0.5, 0.5, 0.5)
    remap.inputs[2].default_value = (0.5, 0.5, 0.5)
    nt.links.new(nmap.outputs["Normal"], remap.inputs[0])
    emit = nt.nodes.new("ShaderNodeEmission")
    nt.links.new(remap.outputs["Vector"], emit.inputs["Color"])
    outn = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(emit.outputs["Emission"], outn.inputs["Surface"])
    w, h = tex.image.size
    target = bpy.data.images.new("baked", w, h, float_buffer=True)
    tnode = nt.nodes.new("ShaderNodeTexImage")
    tnode.image = target
    nt.nodes.active = tnode
    obj.data.materials.append(mat)
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.bake(type="EMIT", margin=0)
    px = list(target.pixels)
    # Back to rows from the top, world normal n = 2 * baked - 1.
    normals = []
    for j in range(h):
        row = h - 1 - j
        for i in range(w):
            k = 4 * (row * w + i)
            normals.append([2 * px[k] - 1, 2 * px[k + 1] - 1, 2 * px[k + 2] - 1])
    return {"width": w, "height": h, "normals": normals}


if cfg.get("normal_gl"):
    out["bake_gl"] = bake_normal_map(cfg["normal_gl"], False)
if cfg.get("normal_dx"):
    out["bake_dx_as_gl"] = bake_normal_map(cfg["normal_dx"], False)
    out["bake_dx_inverted"] = bake_normal_map(cfg["normal_dx"], True)

json.dump(out, open(cfg["out"], "w"))
