#include "heightfield/export.h"

#include <tbb/task_group.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <mutex>
#include <sstream>

#include "capture/session.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/parallel.h"
#include "heightfield/export_gltf.h"
#include "heightfield/export_mesh.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr const char* kExportFormat = "mesoscan-export/1";
constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
// zlib level of the 16-bit PNGs: measured noise makes the low bits incompressible, where level 1
// is ~2.5x faster than the default 6 for a few % larger files.
constexpr int kPng16Compression = 1;

// ---- grid helpers ---------------------------------------------------------------------------

ImageF CropImage(const ImageF& im, const GridCrop& c) {
  if (c.whole()) return im;
  ImageF out(c.width, c.height, im.channels());
  for (int k = 0; k < im.channels(); ++k)
    for (int y = 0; y < c.height; ++y)
      std::copy(im.row(c.y + y, k) + c.x, im.row(c.y + y, k) + c.x + c.width, out.row(y, k));
  return out;
}

void CheckCrop(const GridCrop& c, int w, int h) {
  if (c.whole()) return;
  if (c.x < 0 || c.y < 0 || c.width <= 0 || c.height <= 0 || c.x + c.width > w ||
      c.y + c.height > h)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --crop " << c.x << "," << c.y << "," << c.width
                                                        << "," << c.height << ": expected a rectangle inside the "
                                                        << w << "x" << h << " height grid");
}

// Resamples a planar image from pixel size `src_p` to `dst_p` (same origin). Validity is
// channel 0 being finite. Larger pixels: area-weighted average of the valid source pixels under
// the output pixel, a hole if under half its area is valid. Smaller: bilinear, a hole if a
// needed corner is.
ImageF Resample(const ImageF& src, double src_p, double dst_p, int dw, int dh) {
  const int sw = src.width(), sh = src.height(), nc = src.channels();
  ImageF out(dw, dh, nc, kNan);
  const double ratio = dst_p / src_p;
  ParallelForRows(dh, [&](int r0, int r1) {
    std::vector<double> acc(nc);
    for (int j = r0; j < r1; ++j) {
      const double fj = j * ratio;
      for (int i = 0; i < dw; ++i) {
        const double fi = i * ratio;
        if (ratio > 1.0) {
          // Area weights: the overlap of each source pixel [k - 0.5, k + 0.5] with the
          // footprint [f - r, f + r] (symmetric about the output pixel's centre).
          // At the grid's border the footprint shrinks symmetrically (no one-sided bias).
          const double rx = std::min({0.5 * ratio, fi + 0.5, sw - 0.5 - fi});
          const double ry = std::min({0.5 * ratio, fj + 0.5, sh - 0.5 - fj});
          if (rx <= 0 || ry <= 0) continue;
          auto weight = [](int k, double f, double r) {
            return std::max(0.0, std::min(k + 0.5, f + r) - std::max(k - 0.5, f - r));
          };
          const int i0 = std::max(0, static_cast<int>(std::floor(fi - rx + 0.5)));
          const int i1 = std::min(sw - 1, static_cast<int>(std::ceil(fi + rx - 0.5)));
          const int j0 = std::max(0, static_cast<int>(std::floor(fj - ry + 0.5)));
          const int j1 = std::min(sh - 1, static_cast<int>(std::ceil(fj + ry - 0.5)));
          std::fill(acc.begin(), acc.end(), 0.0);
          double total = 0, valid = 0;
          for (int y = j0; y <= j1; ++y) {
            const double wy = weight(y, fj, ry);
            for (int x = i0; x <= i1; ++x) {
              const double wxy = wy * weight(x, fi, rx);
              if (wxy <= 0) continue;
              total += wxy;
              if (!std::isfinite(src(x, y, 0))) continue;
              valid += wxy;
              for (int k = 0; k < nc; ++k) acc[k] += wxy * src(x, y, k);
            }
          }
          if (valid <= 0 || 2 * valid < total) continue;
          for (int k = 0; k < nc; ++k) out(i, j, k) = static_cast<float>(acc[k] / valid);
        } else {
          const int i0 = static_cast<int>(std::floor(fi)), j0 = static_cast<int>(std::floor(fj));
          const double a = fi - i0, b = fj - j0;
          const int i1 = a > 0 ? i0 + 1 : i0, j1 = b > 0 ? j0 + 1 : j0;
          if (i1 >= sw || j1 >= sh) continue;
          for (int k = 0; k < nc; ++k) {
            const double v = (1 - a) * (1 - b) * src(i0, j0, k) + a * (1 - b) * src(i1, j0, k) +
                             (1 - a) * b * src(i0, j1, k) + a * b * src(i1, j1, k);
            out(i, j, k) = static_cast<float>(v);
          }
          if (!std::isfinite(src(i0, j0, 0)) || !std::isfinite(src(i1, j0, 0)) ||
              !std::isfinite(src(i0, j1, 0)) || !std::isfinite(src(i1, j1, 0)))
            for (int k = 0; k < nc; ++k) out(i, j, k) = kNan;
        }
      }
    }
  });
  return out;
}

int ResampledSize(int n, double src_p, double dst_p) {
  return static_cast<int>(std::floor((n - 1) * src_p / dst_p + 1e-9)) + 1;
}

bool Resamples(const HeightField& hf, double pixel_size_m) {
  return pixel_size_m > 0 && std::abs(pixel_size_m - hf.pixel_size) > 1e-9 * hf.pixel_size;
}

// ---- map encoders ---------------------------------------------------------------------------

struct HeightRange {
  double min = 0, max = 0;
  int64_t valid = 0;
};

HeightRange RangeOf(const ImageF& z) {
  HeightRange r{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(), 0};
  for (float v : z.data()) {
    if (!std::isfinite(v)) continue;
    r.min = std::min<double>(r.min, v);
    r.max = std::max<double>(r.max, v);
    ++r.valid;
  }
  if (r.valid == 0) r.min = r.max = 0;
  return r;
}

ImageF FillHoles(const ImageF& z, float fill) {
  ImageF out = z;
  for (float& v : out.data())
    if (!std::isfinite(v)) v = fill;
  return out;
}

std::vector<uint8_t> ReadBytes(const fs::path& path) {
  const std::string s = ReadTextFile(path);
  return std::vector<uint8_t>(s.begin(), s.end());
}

// Encodes an 8-bit PNG in memory (through a temporary file next to `near`).
std::vector<uint8_t> EncodePng8(const ImageU8& im, const fs::path& near) {
  const fs::path tmp = TempSiblingPath(near);
  std::vector<uint8_t> bytes;
  try {
    WritePng8(tmp, im);
    bytes = ReadBytes(tmp);
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
  std::error_code ec;
  fs::remove(tmp, ec);
  return bytes;
}

void WritePly(const fs::path& path, const HeightField& hf, const ImageF& normals) {
  static_assert(std::endian::native == std::endian::little, "PLY writer assumes little endian");
  const int w = hf.width(), h = hf.height();
  std::vector<float> rec;
  rec.reserve(hf.z.pixels() * 7);
  int64_t n = 0;
  for (int j = 0; j < h; ++j) {
    for (int i = 0; i < w; ++i) {
      const float z = hf.z(i, j);
      if (!std::isfinite(z)) continue;
      float nx = normals(i, j, 0), ny = normals(i, j, 1), nz = normals(i, j, 2);
      if (!std::isfinite(nx) || !std::isfinite(ny) || !std::isfinite(nz)) nx = 0, ny = 0, nz = 1;
      const float conf = hf.confidence.empty() ? 1.0f : hf.confidence(i, j);
      rec.insert(rec.end(), {static_cast<float>(hf.X(i)), static_cast<float>(hf.Y(j)), z, nx, ny, nz,
                             std::isfinite(conf) ? conf : 0.0f});
      ++n;
    }
  }
  std::ostringstream header;
  header << "ply\nformat binary_little_endian 1.0\n"
         << "comment mesoscan export: world metres, z up, mount plane z = 0\n"
         << "comment normals: unit, world frame; confidence in [0, 1]\n"
         << "element vertex " << n << "\n"
         << "property float x\nproperty float y\nproperty float z\n"
         << "property float nx\nproperty float ny\nproperty float nz\n"
         << "property float confidence\nend_header\n";
  WriteAtomically(path, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    const std::string hs = header.str();
    out.write(hs.data(), static_cast<std::streamsize>(hs.size()));
    out.write(reinterpret_cast<const char*>(rec.data()),
              static_cast<std::streamsize>(rec.size() * sizeof(float)));
    out.close();
    if (!out) MESOSCAN_BAD_INPUT(path.string() << ": cannot write PLY");
  });
}

// Scales an albedo so its 99th percentile (of the channel mean over valid samples) is 1.
ImageF NormaliseAlbedo(const ImageF& a) {
  std::vector<float> lum;
  lum.reserve(a.pixels());
  for (size_t p = 0; p < a.pixels(); ++p) {
    double s = 0;
    for (int k = 0; k < a.channels(); ++k) s += a.channel(k)[p];
    if (std::isfinite(s)) lum.push_back(static_cast<float>(s / a.channels()));
  }
  ImageF out = a;
  if (lum.empty()) return out;
  const size_t q = static_cast<size_t>(0.99 * (lum.size() - 1));
  std::nth_element(lum.begin(), lum.begin() + q, lum.end());
  const float scale = lum[q] > 0 ? 1.0f / lum[q] : 1.0f;
  for (float& v : out.data()) v = std::isfinite(v) ? std::max(0.0f, v * scale) : 0.0f;
  return out;
}


Json GridJson(const HeightField& hf) {
  return {{"width_px", hf.width()},
          {"height_px", hf.height()},
          {"pixel_size_m", hf.pixel_size},
          {"x0_m", hf.x0},
          {"y0_m", hf.y0},
          {"physical_size_m", {hf.width() * hf.pixel_size, hf.height() * hf.pixel_size}},
          {"pixel_centre", "pixel (i, j) at world (x0 + i*pixel_size, y0 - j*pixel_size); row 0 is "
                           "the +y edge (image up = world +y)"}};
}

}  // namespace

std::string SessionPathFromReport(const Json& report) {
  for (const char* key : {"session", "session_dir", "session_path"}) {
    if (!report.contains(key)) continue;
    const Json& v = report.at(key);
    if (v.is_string()) return v.get<std::string>();
    if (v.is_object())
      for (const char* sub : {"path", "dir", "root"})
        if (v.contains(sub) && v.at(sub).is_string()) return v.at(sub).get<std::string>();
  }
  return {};
}

// ---- public helpers -------------------------------------------------------------------------

void ExportOptions::Check() const {
  if (!exr && !png16 && !glb && !ply)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --format: expected at least one of exr,png16,glb,ply");
  if (!(pixel_size_m >= 0) || !std::isfinite(pixel_size_m))
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --pixel-size: expected a positive number of metres");
  if (max_triangles <= 0)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --max-triangles: expected a positive number");
  if (!(mesh_tolerance_m >= 0) || !std::isfinite(mesh_tolerance_m))
    MESOSCAN_THROW(ErrorKind::kUsage, "export: mesh tolerance: expected a number >= 0 (metres)");
  if (name.empty() || name.find('/') != std::string::npos || name.find('\\') != std::string::npos)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --name '" << name << "': expected a plain file name prefix");
  if (!albedo.empty() && albedo.channels() != 1 && albedo.channels() != 3)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: albedo: expected 1 or 3 channels, got " << albedo.channels());
}

std::string ExportSummary::BriefReport() const {
  std::ostringstream s;
  s << "export: " << files.size() << " files in " << seconds << " s";
  if (triangles > 0)
    s << "; GLB " << triangles << " triangles, " << vertices << " vertices, max height error "
      << max_height_error_m * 1e6 << " um";
  return s.str();
}

void ParseExportFormats(const std::string& list, ExportOptions* o) {
  o->exr = o->png16 = o->glb = o->ply = false;
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item == "exr") o->exr = true;
    else if (item == "png16" || item == "png") o->png16 = true;
    else if (item == "glb" || item == "gltf") o->glb = true;
    else if (item == "ply") o->ply = true;
    else
      MESOSCAN_THROW(ErrorKind::kUsage, "export: --format: unknown format '" << item
                                                                           << "' (expected exr, png16, glb, ply)");
  }
}

GridCrop ParseGridCrop(const std::string& text) {
  GridCrop c;
  char c1 = 0, c2 = 0, c3 = 0;
  std::istringstream in(text);
  if (!(in >> c.x >> c1 >> c.y >> c2 >> c.width >> c3 >> c.height) || c1 != ',' || c2 != ',' ||
      c3 != ',' || !in.eof() || c.x < 0 || c.y < 0 || c.width <= 0 || c.height <= 0)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --crop '" << text
                                                         << "': expected X,Y,W,H in height-grid pixels");
  return c;
}

HeightField CropAndResample(const HeightField& hf, const GridCrop& crop, double pixel_size_m) {
  CheckCrop(crop, hf.width(), hf.height());
  HeightField out;
  out.z = CropImage(hf.z, crop);
  out.confidence = hf.confidence.empty() ? ImageF() : CropImage(hf.confidence, crop);
  out.pixel_size = hf.pixel_size;
  out.x0 = hf.X(crop.x);
  out.y0 = hf.Y(crop.y);
  if (!Resamples(out, pixel_size_m)) return out;
  const int dw = ResampledSize(out.width(), out.pixel_size, pixel_size_m);
  const int dh = ResampledSize(out.height(), out.pixel_size, pixel_size_m);
  HeightField r;
  r.x0 = out.x0;
  r.y0 = out.y0;
  r.pixel_size = pixel_size_m;
  r.z = Resample(out.z, out.pixel_size, pixel_size_m, dw, dh);
  if (!out.confidence.empty()) {
    // Confidence follows the height's validity.
    ImageF zc(out.width(), out.height(), 2);
    std::copy(out.z.channel(0), out.z.channel(0) + out.z.pixels(), zc.channel(0));
    std::copy(out.confidence.channel(0), out.confidence.channel(0) + out.z.pixels(), zc.channel(1));
    const ImageF rc = Resample(zc, out.pixel_size, pixel_size_m, dw, dh);
    r.confidence = ImageF(dw, dh, 1, 0.0f);
    for (size_t p = 0; p < r.confidence.pixels(); ++p) {
      const float c = rc.channel(1)[p];
      r.confidence.data()[p] = std::isfinite(rc.channel(0)[p]) && std::isfinite(c) ? c : 0.0f;
    }
  }
  return r;
}

ImageF CropAndResampleImage(const ImageF& image, const HeightField& hf, const GridCrop& crop,
                            double pixel_size_m) {
  CheckCrop(crop, hf.width(), hf.height());
  MESOSCAN_CHECK(image.width() == hf.width() && image.height() == hf.height());
  ImageF c = CropImage(image, crop);
  if (!Resamples(hf, pixel_size_m)) return c;
  const int w = crop.whole() ? hf.width() : crop.width, h = crop.whole() ? hf.height() : crop.height;
  return Resample(c, hf.pixel_size, pixel_size_m, ResampledSize(w, hf.pixel_size, pixel_size_m),
                  ResampledSize(h, hf.pixel_size, pixel_size_m));
}

namespace {

// The sine set (at shift 0) whose phases are spread most evenly over the circle: its mean is
// black + white/2 at every pixel, the texture of a session without a white frame. -1 if none
// (>= 3 phases whose unit phasors average below 0.05 in length).
int EvenPhaseSet(const Session& s, const FramePlan& plan) {
  int best = -1;
  double best_bias = 0.05;
  for (size_t k = 0; k < plan.sine.size(); ++k) {
    double c = 0, sn = 0;
    int n = 0;
    for (size_t f : plan.sine[k].frames) {
      if (s.frames[f].shift_steps != 0) continue;
      c += std::cos(s.frames[f].pattern.phase);
      sn += std::sin(s.frames[f].pattern.phase);
      ++n;
    }
    if (n < 3) continue;
    const double bias = std::hypot(c, sn) / n;
    if (bias < best_bias) best_bias = bias, best = static_cast<int>(k);
  }
  return best;
}

}  // namespace

ImageF AlbedoFromSession(const HeightField& hf, const fs::path& session_dir,
                         std::string* source) {
  const Session s = ReadSession(session_dir, /*check_frames=*/false);
  int white = -1, black = -1;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    if (s.frames[i].pattern.type == PatternType::kWhite && white < 0) white = static_cast<int>(i);
    if (s.frames[i].pattern.type == PatternType::kBlack && black < 0) black = static_cast<int>(i);
  }
  auto linear = [&](int index) {
    ImageF im = ReadImage(s.FramePath(index));
    for (float& v : im.data())
      v = static_cast<float>(s.rig.camera_response.ToLinear(std::max(0.0, v - s.rig.black_level)));
    return im;
  };
  ImageF wf;
  if (white >= 0) {
    wf = linear(white);
    if (source) *source = "white frame";
  } else {
    // No white frame: twice the mean of an evenly spread phase set (black + white / 2 each).
    const FramePlan plan = MakeFramePlan(s.frames);
    const int set = EvenPhaseSet(s, plan);
    if (set < 0)
      MESOSCAN_BAD_INPUT((session_dir / "session.json").string()
                         << ": frames: no white frame and no sine set with >= 3 evenly spread "
                            "phases for the albedo");
    int n = 0;
    for (size_t f : plan.sine[set].frames) {
      if (s.frames[f].shift_steps != 0) continue;
      const ImageF im = linear(static_cast<int>(f));
      if (wf.empty()) wf = ImageF(im.width(), im.height(), im.channels(), 0.0f);
      if (im.width() != wf.width() || im.height() != wf.height() || im.channels() != wf.channels())
        MESOSCAN_BAD_INPUT(s.FramePath(f).string() << ": size differs from the other sine frames");
      for (size_t i = 0; i < im.data().size(); ++i) wf.data()[i] += im.data()[i];
      ++n;
    }
    for (float& v : wf.data()) v *= 2.0f / n;
    if (source) {
      std::ostringstream os;
      os << "mean of the " << n << " sine frames of period " << plan.sine[set].period_px
         << " px (no white frame)";
      *source = os.str();
    }
  }
  const ImageF bf = black >= 0 ? linear(black) : ImageF();
  if (!bf.empty() && (bf.width() != wf.width() || bf.height() != wf.height()))
    MESOSCAN_BAD_INPUT(s.FramePath(black).string() << ": size differs from the white frame");
  const int nc = wf.channels() >= 3 ? 3 : 1;
  ImageF out(hf.width(), hf.height(), nc, kNan);
  ParallelForRows(hf.height(), [&](int r0, int r1) {
    for (int j = r0; j < r1; ++j) {
      for (int i = 0; i < hf.width(); ++i) {
        const double z = hf.z(i, j);
        if (!std::isfinite(z)) continue;
        Vec2d uv;
        if (!s.rig.camera.Project(Vec3d(hf.X(i), hf.Y(j), z), &uv)) continue;
        // Bilinear at the projected position (pixel centres at integer coordinates).
        const int u0 = static_cast<int>(std::floor(uv.x())), v0 = static_cast<int>(std::floor(uv.y()));
        if (u0 < 0 || v0 < 0 || u0 + 1 >= wf.width() || v0 + 1 >= wf.height()) continue;
        const double a = uv.x() - u0, b = uv.y() - v0;
        for (int k = 0; k < nc; ++k) {
          auto at = [&](const ImageF& im, int x, int y) {
            return static_cast<double>(im(x, y, im.channels() == 1 ? 0 : k));
          };
          auto bil = [&](const ImageF& im) {
            return (1 - a) * (1 - b) * at(im, u0, v0) + a * (1 - b) * at(im, u0 + 1, v0) +
                   (1 - a) * b * at(im, u0, v0 + 1) + a * b * at(im, u0 + 1, v0 + 1);
          };
          double v = bil(wf);
          if (!bf.empty()) v -= (white >= 0 ? 1.0 : 2.0) * bil(bf);  // 2 mean - 2 black
          out(i, j, k) = static_cast<float>(std::max(0.0, v));
        }
      }
    }
  });
  return out;
}

ImageF EncodeNormalMap(const ImageF& n, NormalConvention convention) {
  MESOSCAN_CHECK_EQ(n.channels(), 3);
  ImageF out(n.width(), n.height(), 3);
  const float gsign = convention == NormalConvention::kOpenGl ? 1.0f : -1.0f;
  for (size_t p = 0; p < n.pixels(); ++p) {
    float x = n.channel(0)[p], y = n.channel(1)[p], z = n.channel(2)[p];
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) x = 0, y = 0, z = 1;
    out.channel(0)[p] = 0.5f + 0.5f * x;
    out.channel(1)[p] = 0.5f + 0.5f * gsign * y;
    out.channel(2)[p] = 0.5f + 0.5f * z;
  }
  return out;
}

// ---- the export -----------------------------------------------------------------------------

ExportSummary ExportScan(const Scan& scan, const ExportOptions& o, const fs::path& dir) {
  o.Check();
  const auto t_start = std::chrono::steady_clock::now();
  if (scan.height.width() < 2 || scan.height.height() < 2)
    MESOSCAN_BAD_INPUT("height.exr: the height grid is " << scan.height.width() << "x"
                                                         << scan.height.height() << ", too small to export");
  // 1. The export grid: crop, resample; normals (the scan's own unless resampled) and albedo.
  const HeightField hf = CropAndResample(scan.height, o.crop, o.pixel_size_m);
  const bool resampled = Resamples(scan.height, o.pixel_size_m);
  ImageF normals;
  if (!resampled && scan.normals.width() == scan.height.width() &&
      scan.normals.height() == scan.height.height() && scan.normals.channels() == 3)
    normals = CropImage(scan.normals, o.crop);
  else
    normals = hf.Normals();
  ImageF confidence = hf.confidence;
  if (confidence.empty()) {
    confidence = ImageF(hf.width(), hf.height(), 1, 0.0f);
    for (size_t p = 0; p < confidence.pixels(); ++p)
      confidence.data()[p] = std::isfinite(hf.z.data()[p]) ? 1.0f : 0.0f;
  }
  ImageF albedo;
  std::string albedo_source = "none";
  if (!o.albedo.empty()) {
    if (o.albedo.width() != scan.height.width() || o.albedo.height() != scan.height.height())
      MESOSCAN_BAD_INPUT("export: albedo: expected the " << scan.height.width() << "x"
                                                         << scan.height.height() << " height grid");
    albedo = CropAndResampleImage(o.albedo, scan.height, o.crop, o.pixel_size_m);
    albedo_source = "given on the height grid";
  } else if (o.albedo_from_session && (o.exr || o.png16 || o.glb)) {
    const std::string session = SessionPathFromReport(scan.report);
    if (!session.empty() && fs::is_directory(session)) {
      try {
        std::string from;
        albedo = CropAndResampleImage(AlbedoFromSession(scan.height, session, &from), scan.height,
                                      o.crop, o.pixel_size_m);
        albedo_source = from + " of session " + session;
      } catch (const Error& e) {
        MESOSCAN_LOG(kWarning) << "export: no albedo (" << e.what() << ")";
      }
    }
  }
  if (!albedo.empty()) albedo = NormaliseAlbedo(albedo);

  std::error_code ec;
  fs::create_directories(dir, ec);
  if (!fs::is_directory(dir)) MESOSCAN_BAD_INPUT(dir.string() << ": cannot create the export folder");

  const HeightRange range = RangeOf(hf.z);
  if (range.valid == 0) MESOSCAN_BAD_INPUT("height.exr: no valid height sample in the export region");
  // Holes are filled with the lowest valid height in the DCC maps (the confidence map marks
  // them), so displacement never sees a NaN and the 16-bit range stays [min, max].
  const float hole_value = static_cast<float>(range.min);
  const double span = std::max(range.max - range.min, 1e-9);
  const double midlevel = -range.min / span;
  const std::string conv = o.normals == NormalConvention::kOpenGl ? "gl" : "dx";
  const std::string conv_text = o.normals == NormalConvention::kOpenGl
                                    ? "OpenGL (+Y: green points to image up)"
                                    : "DirectX (-Y: green points to image down)";
  const std::string n = o.name;
  const std::map<std::string, double> grid_attrs = {
      {kAttrX0, hf.x0}, {kAttrY0, hf.y0}, {kAttrPixelSize, hf.pixel_size}};

  // 2. The file list (manifest order) and the writers, run in parallel.
  // Everything the tasks read or write is declared before the task groups, whose destructors
  // wait for running tasks when an exception unwinds this function.
  ExportSummary summary;
  Json files = Json::array();
  Json hints = Json::object();
  const FillResult hole_fill = FillHoles(hf, o.fill);
  const ImageF filled = FillHoles(hole_fill.field.z, hole_value);
  if (hole_fill.filled_pixels > 0) {
    // Normals of the filled pixels and of their measured neighbours from the filled surface.
    const ImageF fn = hole_fill.field.Normals();
    for (int j = 0; j < hf.height(); ++j)
      for (int i = 0; i < hf.width(); ++i) {
        bool near = false;
        for (int dj = -1; dj <= 1 && !near; ++dj)
          for (int di = -1; di <= 1 && !near; ++di) {
            const int x = i + di, y = j + dj;
            near = x >= 0 && y >= 0 && x < hf.width() && y < hf.height() && hole_fill.filled(x, y);
          }
        if (near)
          for (int k = 0; k < 3; ++k) normals(i, j, k) = fn(i, j, k);
      }
  }
  const ImageF nmap = EncodeNormalMap(normals, o.normals);
  GridMesh mesh;
  std::vector<uint8_t> glb_normal_png, glb_albedo_png;
  std::mutex timing_mutex;
  tbb::task_group tasks, texture_tasks;
  // Runs one writer as a task and records its wall time under `file`.
  auto run = [&](const std::string& file, std::function<void()> fn) {
    tasks.run([&, file, fn = std::move(fn)] {
      const auto t0 = std::chrono::steady_clock::now();
      fn();
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      std::lock_guard<std::mutex> lock(timing_mutex);
      summary.seconds_per_file[file] = s;
    });
  };
  auto add = [&](const std::string& file, Json entry, const std::string& hint) {
    entry["file"] = file;
    files.push_back(std::move(entry));
    hints[file] = hint;
    summary.files.push_back(dir / file);
  };
  // The normal map in `format` ("exr" | "png"): its manifest entry and Blender hint.
  auto add_normal_map = [&](const std::string& format, const std::string& pixel_type) {
    const std::string fn = n + "_normal_" + conv + "." + format;
    add(fn, {{"role", "normal"}, {"format", format}, {"pixel_type", pixel_type},
             {"channels", {"R", "G", "B"}}, {"convention", conv_text},
             {"encoding", "rgb = 0.5 + 0.5 * n (tangent space: +X right, +Z out)"},
             {"colour_space", "Non-Color (raw data)"}},
        "Blender: Image Texture '" + fn + "' (Color Space Non-Color) -> Normal Map node (Tangent Space)" +
            (o.normals == NormalConvention::kDirectX ? "; DirectX: invert green first" : ""));
    return fn;
  };
  std::ostringstream disp;
  disp.precision(9);
  if (o.exr) {
    const std::string f = n + "_height.exr";
    add(f, {{"role", "height"}, {"format", "exr"}, {"pixel_type", "float32"}, {"channels", {"Y"}},
            {"units", "m"}, {"colour_space", "Non-Color (raw data)"}, {"midlevel", 0.0}, {"scale", 1.0},
            {"meaning", "metres above the mount plane z = 0"}},
        "Blender: Image Texture '" + f + "' (Color Space Non-Color) -> Displacement node or "
        "Displace modifier (UV), Midlevel 0, Scale 1: metres (the modifier clamps values below 0: "
        "for heights under the mount plane use the node or the 16-bit PNG)");
    run(f, [&, f] {
      WriteExr(dir / f, filled, {"Y"},
               {{kAttrX0, hf.x0}, {kAttrY0, hf.y0}, {kAttrPixelSize, hf.pixel_size},
                {"mesoscan:midlevel", 0.0}, {"mesoscan:scale", 1.0}, {"mesoscan:hole_value", hole_value}},
               {{"mesoscan:units", "m"}, {"mesoscan:content", "height above the mount plane"}});
    });
    const std::string fn = add_normal_map("exr", "float32");
    run(fn, [&, fn] {
      WriteExr(dir / fn, nmap, {"R", "G", "B"}, grid_attrs,
               {{"mesoscan:normal_convention", conv_text},
                {"mesoscan:encoding", "rgb = 0.5 + 0.5 * n"}});
    });
  }
  if (o.png16) {
    const std::string f = n + "_height.png", fs_ = n + "_height.json";
    disp << "Blender: Image Texture '" << f << "' (Color Space Non-Color) -> Displacement Midlevel "
         << midlevel << ", Scale " << span << " (metres; see " << fs_ << ")";
    add(f, {{"role", "height"}, {"format", "png"}, {"pixel_type", "uint16"}, {"channels", {"Y"}},
            {"units", "m"}, {"colour_space", "Non-Color (raw data)"}, {"midlevel", midlevel},
            {"scale", span}, {"sidecar", fs_},
            {"meaning", "metres = (value / 65535 - midlevel) * scale"}},
        disp.str());
    Json sidecar = {{"format", kExportFormat},
                    {"file", f},
                    {"units", "m"},
                    {"meaning", "height above the mount plane z = 0"},
                    {"decode", "metres = (value / 65535 - midlevel) * scale = min + value / 65535 * (max - min)"},
                    {"min_m", range.min},
                    {"max_m", range.max},
                    {"midlevel", midlevel},
                    {"scale", span},
                    {"quantisation_step_m", span / 65535.0},
                    {"blender", {{"midlevel", midlevel}, {"scale", span}, {"color_space", "Non-Color"}}},
                    {"arnold", {{"zero_value", midlevel}, {"height", span}}},
                    {"hole_value_m", hole_value},
                    {"pixel_size_m", hf.pixel_size},
                    {"width_px", hf.width()},
                    {"height_px", hf.height()},
                    {"physical_size_m", {hf.width() * hf.pixel_size, hf.height() * hf.pixel_size}}};
    add(fs_, {{"role", "height sidecar"}, {"format", "json"}}, "the 16-bit height's min, max, midlevel, scale");
    run(f, [&, f, fs_, sidecar] {
      ImageU16 q(hf.width(), hf.height(), 1);
      for (size_t p = 0; p < q.pixels(); ++p) {
        const double v = (filled.data()[p] - range.min) / span;
        q.data()[p] = static_cast<uint16_t>(std::lround(std::clamp(v, 0.0, 1.0) * 65535.0));
      }
      WritePng16(dir / f, q, kPng16Compression);
      WriteJsonFile(dir / fs_, sidecar);
    });
    const std::string fn = add_normal_map("png", "uint16");
    run(fn, [&, fn] { WritePng16(dir / fn, QuantizeU16(nmap), kPng16Compression); });
  }
  if (o.exr || o.png16 || o.glb) {
    const std::string f = n + "_confidence.png";
    add(f, {{"role", "confidence"}, {"format", "png"}, {"pixel_type", "uint8"}, {"channels", {"Y"}},
            {"colour_space", "Non-Color (raw data)"}, {"meaning", "confidence in [0, 1]; 0 in holes"}},
        "Blender: Image Texture '" + f + "' (Color Space Non-Color): a mask, 0 in holes");
    run(f, [&, f] { WritePng8(dir / f, QuantizeU8(confidence)); });
    if (!albedo.empty()) {
      const std::string fa = n + "_albedo.png";
      add(fa, {{"role", "albedo"}, {"format", "png"}, {"pixel_type", "uint8"},
               {"channels", albedo.channels() == 3 ? Json{"R", "G", "B"} : Json{"Y"}},
               {"colour_space", "sRGB"}, {"source", albedo_source},
               {"meaning", "relative albedo: white-frame radiance (or twice a sine set's "
                           "mean) minus black, 99th percentile = 1, "
                           "no shading correction"}},
          "Blender: Image Texture '" + fa + "' (Color Space sRGB) -> Principled BSDF Base Color");
      run(fa, [&, fa] { WritePng8(dir / fa, QuantizeU8(albedo, /*srgb_encode=*/true)); });
    }
  }
  if (o.ply) {
    const std::string f = n + ".ply";
    add(f, {{"role", "points"}, {"format", "ply"}, {"units", "m"}, {"axes", "world: z up"},
            {"properties", {"x", "y", "z", "nx", "ny", "nz", "confidence"}}, {"points", range.valid}},
        "MeshLab / CloudCompare: open '" + f + "' (metres, z up; confidence as a scalar field)");
    run(f, [&, f] { WritePly(dir / f, hf, normals); });
  }
  if (o.glb) {
    const std::string f = n + ".glb";
    // The GLB's textures are encoded while this thread builds the mesh.
    const fs::path tex = dir / (n + "_texture.png");  // temporaries are named after it
    texture_tasks.run([&, tex] {
      glb_normal_png = EncodePng8(QuantizeU8(EncodeNormalMap(normals, NormalConvention::kOpenGl)), tex);
    });
    if (!albedo.empty())
      texture_tasks.run([&, tex] { glb_albedo_png = EncodePng8(QuantizeU8(albedo, true), tex); });
    GridMeshOptions mo;
    mo.max_triangles = o.max_triangles;
    mo.tolerance_m = o.mesh_tolerance_m;
    const auto t_mesh = std::chrono::steady_clock::now();
    mesh = TriangulateHeightField(hf, mo);
    {
      std::lock_guard<std::mutex> lock(timing_mutex);
      summary.seconds_per_file["(mesh)"] =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t_mesh).count();
    }
    if (mesh.triangles() == 0) MESOSCAN_BAD_INPUT("height.exr: no triangle in the export region (all holes?)");
    summary.triangles = mesh.triangles();
    summary.vertices = mesh.vertices();
    summary.max_height_error_m = mesh.max_height_error_m;
    Json extras = {{"units", "m"},
                   {"up_axis", "glTF +Y (world z); world (x, y, z) = glTF (x, -z, y)"},
                   {"height_zero_m", 0.0},
                   {"height_scale", 1.0},
                   {"max_height_error_m", mesh.max_height_error_m},
                   {"pixel_size_m", hf.pixel_size}};
    if (o.exr) extras["height_map"] = n + "_height.exr";
    if (o.png16) {
      extras["height_map_png16"] = n + "_height.png";
      extras["height_png16_midlevel"] = midlevel;
      extras["height_png16_scale"] = span;
    }
    if (!extras.contains("height_map")) extras["height_map"] = o.png16 ? n + "_height.png" : "";
    add(f, {{"role", "mesh"}, {"format", "glb"}, {"units", "m"},
            {"axes", "glTF +Y up: (x, y, z)_gltf = (x, z, -y)_world"},
            {"uv", "sample (i, j) at ((i + 0.5)/W, (j + 0.5)/H), glTF top-left origin"},
            {"triangles", mesh.triangles()}, {"vertices", mesh.vertices()},
            {"max_triangles", o.max_triangles}, {"lossless_triangles", mesh.lossless_triangles},
            {"max_height_error_m", mesh.max_height_error_m}, {"rtin_threshold_m", mesh.threshold_m},
            {"uncovered_samples", mesh.uncovered_samples}, {"budget_met", mesh.budget_met},
            {"textures", albedo.empty() ? Json{"normal (OpenGL, 8-bit)"}
                                        : Json{"normal (OpenGL, 8-bit)", "baseColor (sRGB, 8-bit)"}}},
        "Blender: File > Import > glTF 2.0 '" + f + "' (metres; Z up after import)");
    texture_tasks.wait();
    run(f, [&, f, extras] {
      GlbContent c;
      c.name = n;
      c.grid = &hf;
      c.normals = &normals;
      c.mesh = &mesh;
      c.extras = extras;
      c.normal_png = std::move(glb_normal_png);
      c.base_color_png = std::move(glb_albedo_png);
      WriteGlb(dir / f, c);
    });
  }
  tasks.wait();

  // 3. The manifest, last: it names only files that were written completely.
  Json m = {{"format", kExportFormat},
            {"name", n},
            {"units", "m"},
            {"conventions",
             {{"world", "metres; mount plane z = 0, +z up towards the rig"},
              {"maps", "one grid for every map; row 0 is the +y edge, so image up = world +y"},
              {"height", "metres above the mount plane; holes bounded by surface filled (see fill), the others with hole_value_m (see the confidence map)"},
              {"normal_map", conv_text + "; tangent space +X = world x, +Y = world y on a flat sample"},
              {"glb", "metres, glTF +Y up: (x, y, z)_gltf = (x, z, -y)_world; normal texture OpenGL"},
              {"exr_height_channel",
               "Y: OpenEXR's luminance channel, read as grey (R = G = B) by Blender, OIIO and "
               "Substance"}}},
            {"grid", GridJson(hf)},
            {"source_grid", GridJson(scan.height)},
            {"crop_px", o.crop.whole() ? Json(nullptr) : Json{o.crop.x, o.crop.y, o.crop.width, o.crop.height}},
            {"height_range_m", {range.min, range.max}},
            {"hole_value_m", hole_value},
            {"fill", {{"method", FillMethodName(o.fill.method)},
                      {"max_hole_radius_m", o.fill.max_hole_radius_m},
                      {"pixels_filled", hole_fill.filled_pixels},
                      {"holes_filled", hole_fill.holes_filled},
                      {"pixels_left", hole_fill.pixels_left},
                      {"note", "filled pixels have confidence 0; the rest of the holes hold hole_value_m"}}},
            {"valid_samples", range.valid},
            {"albedo", albedo_source},
            {"files", files},
            {"how_to_load", hints}};
  WriteJsonFile(dir / "manifest.json", m);
  summary.files.push_back(dir / "manifest.json");
  summary.manifest = std::move(m);
  summary.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return summary;
}

}  // namespace mesoscan
