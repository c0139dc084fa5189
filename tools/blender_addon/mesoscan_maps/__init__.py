# mesoscan map set importer for Blender (3.4 and later): File > Import > mesoscan map set.
#
# Reads a map set's manifest.json (written by `mesoscan maps` or `mesoscan export --tile ...`)
# and builds a material with true-scale displacement (the height EXR: Midlevel 0, Scale 1, in
# world metres), the tangent-space normal map, albedo multiplied by ambient occlusion, the
# roughness map (when the set has one) into the Principled BSDF's Roughness, either
#  - on a new plane of the sample's physical size (one vertex per texel, up to a limit, so
#    Cycles' true displacement has the map's resolution; Eevee, which does not displace, gets
#    its own output with the normal map), repeated `repeat` times for a tileable set, or
#  - on the selected object at the tile's physical size (Repeat extension), so a 12 mm tile is
#    12 mm on the object, projected
#      BOX   (default) from the object's coordinates along its X, Y and Z axes, each face taking
#            the axis nearest its normal (blended over a narrow band): no smearing on a curved
#            object (a sphere, a cylinder); the relief comes from the height (Cycles displaces
#            and bumps, Eevee bumps), the tangent-space normal map is not linked (its tangents
#            would not follow the box's faces);
#      UV    through the object's own UV map, `repeat` tiles per UV unit, normal map linked;
#      FLAT  along the object's Z (its X-Y coordinates), as for a flat object.
# Installable as a zip (the build writes build/tools/mesoscan_maps.zip):
#   blender --python-expr "import bpy; bpy.ops.preferences.addon_install(filepath='ZIP');
#     bpy.ops.preferences.addon_enable(module='mesoscan_maps');
#     bpy.ops.import_scene.mesoscan_maps(filepath='DIR/manifest.json')"
import json
import os

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

bl_info = {
    "name": "mesoscan map set",
    "author": "mesoscan",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "File > Import > mesoscan map set (manifest.json)",
    "description": "Material from a mesoscan map set: displacement at true scale, normal, "
                   "albedo, AO, on a plane of the sample's size or the selected object",
    "category": "Import-Export",
}

MAX_GRID = 1024  # vertices per side of the plane (one per texel up to this)


def read_manifest(path):
    with open(path) as f:
        m = json.load(f)
    if not str(m.get("format", "")).startswith("mesoscan-maps/"):
        raise ValueError("%s: format: expected mesoscan-maps/1, got %r" % (path, m.get("format")))
    return m


def pick(m, role, fmt=None):
    for f in m["files"]:
        if f["role"] == role and (fmt is None or f["format"] == fmt):
            return f
    return None


def build_material(m, folder, coords="UV", repeat=1.0, tile_m=None, link_normal_map=True):
    """The node tree. coords: "UV" (the mesh's UVs, `repeat` tiles per unit), "BOX" (box
    projection of the object's coordinates at the tile's size) or "OBJECT" (its X-Y coordinates
    at the tile's size).
    link_normal_map: False when the mesh has a vertex per texel, where Cycles' displaced
    geometry already carries the map's slopes (the normal map on top would tilt them twice);
    Eevee, which does not displace, then gets an output of its own with the normal map."""
    name = m["name"]
    mat = bpy.data.materials.new("mesoscan " + name)
    mat.use_nodes = True
    # Box projection: the relief from the height alone, displaced where the mesh is dense and
    # bumped at the texels' scale.
    mat.cycles.displacement_method = "BOTH" if coords == "BOX" else "DISPLACEMENT"
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.location = (800, 0)
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.location = (500, 100)
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    tc = nt.nodes.new("ShaderNodeTexCoord")
    tc.location = (-900, 0)
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.location = (-700, 0)
    mapping.name = "mesoscan mapping"
    if coords == "UV":
        nt.links.new(tc.outputs["UV"], mapping.inputs["Vector"])
        mapping.inputs["Scale"].default_value = (repeat, repeat, 1.0)
    elif coords == "BOX":
        # One scale on every axis (the box's faces share the tile's size).
        nt.links.new(tc.outputs["Object"], mapping.inputs["Vector"])
        mapping.inputs["Scale"].default_value = (1.0 / tile_m[0], 1.0 / tile_m[1], 1.0 / tile_m[0])
    else:
        nt.links.new(tc.outputs["Object"], mapping.inputs["Vector"])
        mapping.inputs["Scale"].default_value = (1.0 / tile_m[0], 1.0 / tile_m[1], 1.0)
    extension = "REPEAT" if m.get("tileable") else "EXTEND"

    def image_node(entry, colorspace, y, label):
        img = bpy.data.images.load(os.path.join(folder, entry["file"]), check_existing=True)
        img.colorspace_settings.name = colorspace
        node = nt.nodes.new("ShaderNodeTexImage")
        node.image = img
        node.extension = extension
        node.interpolation = "Linear"
        if coords == "BOX":
            node.projection = "BOX"
            node.projection_blend = 0.15
        node.location = (-400, y)
        node.name = node.label = label
        nt.links.new(mapping.outputs["Vector"], node.inputs["Vector"])
        return node

    height = pick(m, "height", "exr")
    if height:
        tex = image_node(height, "Non-Color", 400, "height")
        disp = nt.nodes.new("ShaderNodeDisplacement")
        disp.name = "mesoscan displacement"
        disp.location = (500, -300)
        disp.space = "WORLD"
        disp.inputs["Midlevel"].default_value = float(height.get("midlevel", 0.0))
        disp.inputs["Scale"].default_value = float(height.get("scale", 1.0))
        nt.links.new(tex.outputs["Color"], disp.inputs["Height"])
        nt.links.new(disp.outputs["Displacement"], out.inputs["Displacement"])
    normal = pick(m, "normal", "png") or pick(m, "normal", "exr")
    if normal:
        tex = image_node(normal, "Non-Color", 100, "normal")
        nm = nt.nodes.new("ShaderNodeNormalMap")
        nm.location = (200, -100)
        if "DirectX" in normal.get("convention", ""):
            # Invert green for the DirectX convention.
            sep = nt.nodes.new("ShaderNodeSeparateColor")
            comb = nt.nodes.new("ShaderNodeCombineColor")
            inv = nt.nodes.new("ShaderNodeMath")
            inv.operation = "SUBTRACT"
            inv.inputs[0].default_value = 1.0
            nt.links.new(tex.outputs["Color"], sep.inputs["Color"])
            nt.links.new(sep.outputs[0], comb.inputs[0])
            nt.links.new(sep.outputs[1], inv.inputs[1])
            nt.links.new(inv.outputs[0], comb.inputs[1])
            nt.links.new(sep.outputs[2], comb.inputs[2])
            nt.links.new(comb.outputs["Color"], nm.inputs["Color"])
        else:
            nt.links.new(tex.outputs["Color"], nm.inputs["Color"])
        nm.name = "mesoscan normal map"
        if link_normal_map and coords != "BOX":
            nt.links.new(nm.outputs["Normal"], bsdf.inputs["Normal"])
    albedo = pick(m, "albedo")
    ao = pick(m, "ao")
    base = None
    if albedo:
        base = image_node(albedo, "sRGB", -200, "albedo").outputs["Color"]
    if ao:
        ao_tex = image_node(ao, "Non-Color", -500, "ao")
        mix = nt.nodes.new("ShaderNodeMixRGB")
        mix.blend_type = "MULTIPLY"
        mix.name = "mesoscan albedo x ao"
        mix.inputs["Fac"].default_value = 1.0
        mix.location = (100, 200)
        if base is not None:
            nt.links.new(base, mix.inputs["Color1"])
        else:
            mix.inputs["Color1"].default_value = (0.6, 0.6, 0.6, 1.0)
        nt.links.new(ao_tex.outputs["Color"], mix.inputs["Color2"])
        base = mix.outputs["Color"]
    if base is not None:
        nt.links.new(base, bsdf.inputs["Base Color"])
    roughness = pick(m, "roughness")
    if roughness:
        tex = image_node(roughness, "Non-Color", -800, "roughness")
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Roughness"])
    if normal and coords == "UV" and not link_normal_map:
        # Eevee cannot displace: it would bump the flat mesh with the height's screen-space
        # derivatives, taken per 2 x 2 pixel block (blocky, and different on each repeat of a
        # tile whose size in pixels is odd). It gets an output of its own, the same BSDF with the
        # tangent-space normal map; Cycles keeps the true displacement.
        out.target = "CYCLES"
        eevee = nt.nodes.new("ShaderNodeBsdfPrincipled")
        eevee.name = eevee.label = "mesoscan BSDF (Eevee)"
        eevee.location = (500, -700)
        for i, socket in enumerate(bsdf.inputs):
            for link in socket.links:
                nt.links.new(link.from_socket, eevee.inputs[i])
        nt.links.new(nm.outputs["Normal"], eevee.inputs["Normal"])
        eevee_out = nt.nodes.new("ShaderNodeOutputMaterial")
        eevee_out.name = eevee_out.label = "mesoscan output (Eevee)"
        eevee_out.target = "EEVEE"
        eevee_out.location = (800, -700)
        nt.links.new(eevee.outputs["BSDF"], eevee_out.inputs["Surface"])
    mat["mesoscan_manifest"] = json.dumps({"name": name, "grid": m["grid"], "tileable": m.get("tileable")})
    return mat


def make_plane(m, repeat=1, max_grid=MAX_GRID):
    """A plane of the map's physical size (times `repeat`), centred at the origin, with one
    vertex per texel up to max_grid per side and UVs 0..repeat."""
    g = m["grid"]
    w_m, h_m = g["physical_size_m"]
    nx = max(1, min(int(g["width_px"]) * repeat, max_grid))
    ny = max(1, min(int(g["height_px"]) * repeat, max_grid))
    sx, sy = w_m * repeat, h_m * repeat
    verts = [((i / nx - 0.5) * sx, (0.5 - j / ny) * sy, 0.0) for j in range(ny + 1) for i in range(nx + 1)]
    faces = [(j * (nx + 1) + i, (j + 1) * (nx + 1) + i, (j + 1) * (nx + 1) + i + 1, j * (nx + 1) + i + 1)
             for j in range(ny) for i in range(nx)]
    me = bpy.data.meshes.new("mesoscan " + m["name"])
    me.from_pydata(verts, [], faces)
    uv = me.uv_layers.new(name="UVMap")
    # UV (0, 0) is the image's bottom-left: image row 0 (world +y edge) is at v = 1.
    for poly in me.polygons:
        for li in poly.loop_indices:
            x, y, _ = verts[me.loops[li].vertex_index]
            uv.data[li].uv = (x / sx + 0.5, y / sy + 0.5)  # the Mapping node repeats
    for poly in me.polygons:
        poly.use_smooth = True
    me.update()
    obj = bpy.data.objects.new("mesoscan " + m["name"], me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def load_map_set(manifest_path, target="PLANE", repeat=1, max_grid=MAX_GRID, projection="BOX"):
    """Imports the map set; returns the object carrying its material. projection (target
    SELECTED): "BOX", "UV" or "FLAT" (see the header)."""
    m = read_manifest(manifest_path)
    folder = os.path.dirname(os.path.abspath(manifest_path))
    if target == "SELECTED":
        obj = bpy.context.active_object
        if obj is None or obj.type != "MESH":
            raise ValueError("mesoscan map set: select a mesh object to apply the material to")
        size = m["tile"]["size_m"] if m.get("tile") else m["grid"]["physical_size_m"][0]
        tile_m = (size, size * m["grid"]["height_px"] / m["grid"]["width_px"])
        if projection == "UV":
            if not obj.data.uv_layers:
                raise ValueError("mesoscan map set: %s has no UV map (use the Box projection)" % obj.name)
            mat = build_material(m, folder, coords="UV", repeat=float(repeat))
        elif projection == "FLAT":
            mat = build_material(m, folder, coords="OBJECT", tile_m=tile_m)
        else:
            mat = build_material(m, folder, coords="BOX", tile_m=tile_m)
    else:
        obj = make_plane(m, repeat=repeat, max_grid=max_grid)
        full_res = int(m["grid"]["width_px"]) * repeat <= max_grid and int(m["grid"]["height_px"]) * repeat <= max_grid
        mat = build_material(m, folder, coords="UV", repeat=float(repeat), link_normal_map=not full_res)
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    return obj


class ImportMesoscanMaps(bpy.types.Operator, ImportHelper):
    """Import a mesoscan map set (manifest.json) as a material"""
    bl_idname = "import_scene.mesoscan_maps"
    bl_label = "Import mesoscan map set"
    bl_options = {"REGISTER", "UNDO"}
    filename_ext = ".json"
    filter_glob: StringProperty(default="manifest.json;*.json", options={"HIDDEN"})
    target: EnumProperty(
        name="Apply to",
        items=[("PLANE", "New plane", "A plane of the sample's physical size"),
               ("SELECTED", "Selected object", "The active mesh, maps at the tile's physical size")],
        default="PLANE")
    repeat: IntProperty(name="Repeat", description="Tiles per side on the new plane (per UV unit with "
                        "the UV projection)", default=1, min=1, max=16)
    projection: EnumProperty(
        name="Projection",
        description="How the maps are laid on the selected object",
        items=[("BOX", "Box", "From the object's X, Y and Z at the tile's size: curved objects"),
               ("UV", "UV", "The object's own UV map, Repeat tiles per UV unit"),
               ("FLAT", "Flat (X-Y)", "Along the object's Z at the tile's size: flat objects")],
        default="BOX")

    def execute(self, context):
        try:
            obj = load_map_set(self.filepath, self.target, self.repeat, projection=self.projection)
        except (OSError, ValueError, KeyError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, "mesoscan: material on %s" % obj.name)
        return {"FINISHED"}


def menu_func_import(self, context):
    self.layout.operator(ImportMesoscanMaps.bl_idname, text="mesoscan map set (manifest.json)")


def register():
    bpy.utils.register_class(ImportMesoscanMaps)
    bpy.types.TOPBAR_MT_file_import.append(menu_func_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(menu_func_import)
    bpy.utils.unregister_class(ImportMesoscanMaps)
