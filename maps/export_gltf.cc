#include "maps/export_gltf.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>

#include "core/error.h"
#include "core/fs.h"
#include "core/parallel.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

tinygltf::Value ToValue(const Json& j) {
  if (j.is_object()) {
    tinygltf::Value::Object o;
    for (auto it = j.begin(); it != j.end(); ++it) o[it.key()] = ToValue(it.value());
    return tinygltf::Value(std::move(o));
  }
  if (j.is_array()) {
    tinygltf::Value::Array a;
    for (const auto& v : j) a.push_back(ToValue(v));
    return tinygltf::Value(std::move(a));
  }
  if (j.is_boolean()) return tinygltf::Value(j.get<bool>());
  if (j.is_number_integer()) return tinygltf::Value(static_cast<int>(j.get<int64_t>()));
  if (j.is_number()) return tinygltf::Value(j.get<double>());
  if (j.is_string()) return tinygltf::Value(j.get<std::string>());
  return tinygltf::Value();
}

// Appends `bytes` to the single buffer (4-byte aligned) as a new buffer view; returns its index.
int AddView(tinygltf::Model* model, const void* bytes, size_t size, int target) {
  auto& data = model->buffers[0].data;
  while (data.size() % 4) data.push_back(0);
  tinygltf::BufferView view;
  view.buffer = 0;
  view.byteOffset = data.size();
  view.byteLength = size;
  view.target = target;
  const auto* p = static_cast<const unsigned char*>(bytes);
  data.insert(data.end(), p, p + size);
  model->bufferViews.push_back(view);
  return static_cast<int>(model->bufferViews.size() - 1);
}

int AddAccessor(tinygltf::Model* model, int view, int component_type, size_t count, int type,
                std::vector<double> min = {}, std::vector<double> max = {}) {
  tinygltf::Accessor a;
  a.bufferView = view;
  a.byteOffset = 0;
  a.componentType = component_type;
  a.count = count;
  a.type = type;
  a.minValues = std::move(min);
  a.maxValues = std::move(max);
  model->accessors.push_back(a);
  return static_cast<int>(model->accessors.size() - 1);
}

int AddPngTexture(tinygltf::Model* model, const std::vector<uint8_t>& png,
                  const std::string& name) {
  tinygltf::Image image;
  image.name = name;
  image.mimeType = "image/png";
  image.bufferView = AddView(model, png.data(), png.size(), 0);
  model->images.push_back(image);
  tinygltf::Texture texture;
  texture.name = name;
  texture.sampler = 0;
  texture.source = static_cast<int>(model->images.size() - 1);
  model->textures.push_back(texture);
  return static_cast<int>(model->textures.size() - 1);
}

}  // namespace

void WriteGlb(const fs::path& path, const GlbContent& c) {
  MESOSCAN_CHECK(c.grid && c.normals && c.mesh && !c.normal_png.empty());
  const HeightField& hf = *c.grid;
  const GridMesh& mesh = *c.mesh;
  const int w = hf.width(), h = hf.height();
  const size_t nv = mesh.vertex_pixel.size();
  MESOSCAN_CHECK_GT(nv, size_t{0});

  // 1. Vertex attributes in glTF axes: (x, y, z)_gltf = (x, z, -y)_world.
  std::vector<float> pos(nv * 3), nrm(nv * 3), tan(nv * 4), uv(nv * 2);
  ParallelFor(
      static_cast<int64_t>(nv),
      [&](int64_t v) {
        const int p = mesh.vertex_pixel[v], i = p % w, j = p / w;
        const double x = hf.X(i), y = hf.Y(j), z = hf.z(i, j);
        pos[3 * v + 0] = static_cast<float>(x);
        pos[3 * v + 1] = static_cast<float>(z);
        pos[3 * v + 2] = static_cast<float>(-y);
        Vec3d n((*c.normals)(i, j, 0), (*c.normals)(i, j, 1), (*c.normals)(i, j, 2));
        if (!n.allFinite() || n.norm() < 1e-6) n = Vec3d(0, 0, 1);
        n.normalize();
        // Tangent: world +x made orthogonal to the normal (a height-field normal has n_z > 0, so
        // +x is never parallel to it).
        Vec3d t = Vec3d(1, 0, 0) - n * n.x();
        t.normalize();
        nrm[3 * v + 0] = static_cast<float>(n.x());
        nrm[3 * v + 1] = static_cast<float>(n.z());
        nrm[3 * v + 2] = static_cast<float>(-n.y());
        tan[4 * v + 0] = static_cast<float>(t.x());
        tan[4 * v + 1] = static_cast<float>(t.z());
        tan[4 * v + 2] = static_cast<float>(-t.y());
        tan[4 * v + 3] = 1.0f;
        uv[2 * v + 0] = static_cast<float>((i + 0.5) / w);
        uv[2 * v + 1] = static_cast<float>((j + 0.5) / h);
      },
      4096);
  std::vector<double> pmin(3, std::numeric_limits<double>::infinity());
  std::vector<double> pmax(3, -std::numeric_limits<double>::infinity());
  for (size_t v = 0; v < nv; ++v) {
    for (int k = 0; k < 3; ++k) {
      pmin[k] = std::min<double>(pmin[k], pos[3 * v + k]);
      pmax[k] = std::max<double>(pmax[k], pos[3 * v + k]);
    }
  }

  // 2. The model: one buffer, one mesh, one node, one material.
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "mesoscan 0.1.0";
  model.buffers.resize(1);
  constexpr int kArray = TINYGLTF_TARGET_ARRAY_BUFFER,
                kElements = TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER;
  constexpr int kFloat = TINYGLTF_COMPONENT_TYPE_FLOAT;
  tinygltf::Primitive prim;
  prim.mode = TINYGLTF_MODE_TRIANGLES;
  prim.attributes["POSITION"] =
      AddAccessor(&model, AddView(&model, pos.data(), pos.size() * 4, kArray), kFloat, nv,
                  TINYGLTF_TYPE_VEC3, pmin, pmax);
  prim.attributes["NORMAL"] = AddAccessor(
      &model, AddView(&model, nrm.data(), nrm.size() * 4, kArray), kFloat, nv, TINYGLTF_TYPE_VEC3);
  prim.attributes["TANGENT"] = AddAccessor(
      &model, AddView(&model, tan.data(), tan.size() * 4, kArray), kFloat, nv, TINYGLTF_TYPE_VEC4);
  prim.attributes["TEXCOORD_0"] = AddAccessor(
      &model, AddView(&model, uv.data(), uv.size() * 4, kArray), kFloat, nv, TINYGLTF_TYPE_VEC2);
  if (c.filled) {
    std::vector<float> flag(nv);
    for (size_t v = 0; v < nv; ++v) {
      const int p = mesh.vertex_pixel[v];
      flag[v] = (*c.filled)(p % w, p / w) ? 1.0f : 0.0f;
    }
    prim.attributes["_FILLED"] =
        AddAccessor(&model, AddView(&model, flag.data(), flag.size() * 4, kArray), kFloat, nv,
                    TINYGLTF_TYPE_SCALAR);
  }
  prim.indices =
      AddAccessor(&model, AddView(&model, mesh.indices.data(), mesh.indices.size() * 4, kElements),
                  TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT, mesh.indices.size(), TINYGLTF_TYPE_SCALAR);

  tinygltf::Sampler sampler;
  sampler.magFilter = TINYGLTF_TEXTURE_FILTER_LINEAR;
  sampler.minFilter = TINYGLTF_TEXTURE_FILTER_LINEAR_MIPMAP_LINEAR;
  sampler.wrapS = TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
  sampler.wrapT = TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
  model.samplers.push_back(sampler);

  tinygltf::Material material;
  material.name = c.name;
  material.pbrMetallicRoughness.metallicFactor = 0.0;
  material.pbrMetallicRoughness.roughnessFactor = std::clamp(c.roughness, 0.0, 1.0);
  material.normalTexture.index = AddPngTexture(&model, c.normal_png, c.name + "_normal_gl");
  if (!c.base_color_png.empty())
    material.pbrMetallicRoughness.baseColorTexture.index =
        AddPngTexture(&model, c.base_color_png, c.name + "_albedo");
  if (!c.occlusion_png.empty()) {
    material.occlusionTexture.index = AddPngTexture(&model, c.occlusion_png, c.name + "_ao");
    material.occlusionTexture.strength = 1.0;
  }
  model.materials.push_back(material);
  prim.material = 0;

  tinygltf::Mesh gmesh;
  gmesh.name = c.name;
  gmesh.primitives.push_back(prim);
  model.meshes.push_back(gmesh);
  tinygltf::Node node;
  node.name = c.name;
  node.mesh = 0;
  node.extras = ToValue(c.extras);
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.name = c.name;
  scene.nodes.push_back(0);
  model.scenes.push_back(scene);
  model.defaultScene = 0;

  // 3. Serialise to a temporary sibling, then rename.
  WriteFileChecked(path, [&](CheckedFile& out) {
    tinygltf::TinyGLTF writer;
    const bool ok = writer.WriteGltfSceneToStream(&model, out.stream(), false, true);
    out.Close();  // a failed write names the file and the reason
    if (!ok)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot write GLB (tinygltf refused the model)");
  });
}

}  // namespace mesoscan
