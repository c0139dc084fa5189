#pragma once
// The GLB writer (the only file that includes tinygltf, per the architecture).
//
// Geometry in metres. glTF is +Y up; the scan's world is +Z up, so a world point (x, y, z)
// is written as (x, z, -y) (a proper rotation: winding and handedness are kept). UV of the
// sample at grid pixel (i, j): ((i + 0.5) / W, (j + 0.5) / H), the texel centre of the maps
// (glTF UV origin is the top-left of the image, row 0). Tangents point along world +x (+u),
// w = +1, so the bitangent is world +y (image up): the glTF (OpenGL) normal-map convention.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "core/height_field.h"
#include "core/image.h"
#include "core/json.h"
#include "maps/export_mesh.h"

namespace mesoscan {

struct GlbContent {
  std::string name;                   // mesh, node and material name
  const HeightField* grid = nullptr;  // the export grid
  const ImageF* normals = nullptr;    // world unit normals on the grid (3 channels)
  const GridMesh* mesh = nullptr;     // triangles over the grid
  // Optional (may be null): 1 where the grid's height was filled, not measured; written as the
  // vertex attribute _FILLED (float 0 or 1).
  const ImageU8* filled = nullptr;
  std::vector<uint8_t> normal_png;      // encoded PNG of the OpenGL normal map (required)
  std::vector<uint8_t> base_color_png;  // encoded sRGB PNG of the albedo (may be empty)
  // Encoded linear 8-bit PNG of the ambient occlusion (occlusionTexture, read from R; may be
  // empty).
  std::vector<uint8_t> occlusion_png;
  double roughness = 0.6;        // pbrMetallicRoughness.roughnessFactor, in [0, 1]
  Json extras = Json::object();  // node extras (Blender: object custom properties)
};

// Writes the GLB atomically. Throws Error naming the file on failure.
void WriteGlb(const std::filesystem::path& path, const GlbContent& content);

}  // namespace mesoscan
