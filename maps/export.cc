#include "maps/export.h"

#include <tbb/task_group.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <mutex>
#include <sstream>

#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/oiio_module.h"
#include "core/parallel.h"
#include "core/stage_timer.h"
#include "maps/export_gltf.h"
#include "maps/export_mesh.h"
#include "session/raw_frame.h"
#include "session/session.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr const char* kExportFormat = "mesoscan-export/1";
constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
// zlib level of the 16-bit PNGs: measured noise makes the low bits incompressible, where level 1
// is ~2.5x faster than the default 6 for a few % larger files.
constexpr int kPng16Compression = 1;

// ---- grid helpers ---------------------------------------------------------------------------

ImageF CropImage(const ImageF& im, const PixelRect& c) {
  if (c.whole()) return im;
  ImageF out(c.w, c.h, im.channels());
  for (int k = 0; k < im.channels(); ++k)
    for (int y = 0; y < c.h; ++y)
      std::copy(im.row(c.y + y, k) + c.x, im.row(c.y + y, k) + c.x + c.w, out.row(y, k));
  return out;
}

void CheckCrop(const PixelRect& c, int w, int h) {
  if (c.whole()) return;
  if (c.x < 0 || c.y < 0 || c.w <= 0 || c.h <= 0 || c.x + c.w > w || c.y + c.h > h)
    MESOSCAN_BAD_OPTION("ExportOptions.crop", c.x << "," << c.y << "," << c.w << "," << c.h
                                                  << ": expected a rectangle inside the " << w
                                                  << "x" << h << " height grid");
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
  HeightRange r{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                0};
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

// Encodes an 8-bit PNG in memory (`near`: the file it is for, named in errors).
std::vector<uint8_t> EncodePng8(const ImageU8& im, const fs::path& near) {
  ImageToWrite w(im.width(), im.height(), im.channels(), PixelType::kUInt8);
  std::vector<uint8_t> inter(im.pixels() * im.channels());
  for (int c = 0; c < im.channels(); ++c)
    for (size_t i = 0; i < im.pixels(); ++i) inter[i * im.channels() + c] = im.channel(c)[i];
  w.data = inter.data();
  std::vector<unsigned char> bytes;
  std::string err;
  bool no_memory_writer = false;
  if (!Oiio().Encode("png", {w}, &bytes, &err, &no_memory_writer))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(near), "cannot encode PNG texture (" << err << ")");
  return std::vector<uint8_t>(bytes.begin(), bytes.end());
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
      rec.insert(rec.end(), {static_cast<float>(hf.X(i)), static_cast<float>(hf.Y(j)), z, nx, ny,
                             nz, std::isfinite(conf) ? conf : 0.0f});
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
  WriteFileChecked(path, [&](CheckedFile& out) {
    out.Write(header.str());
    out.Write(rec.data(), rec.size() * sizeof(float));
  });
}

// Scales an albedo so its 99th percentile (of the channel mean over valid samples) is 1; NaN
// stays NaN (FillExportHeights fills it where the height is known).
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
  for (float& v : out.data()) v = std::isfinite(v) ? std::max(0.0f, v * scale) : v;
  return out;
}

Json GridJson(const HeightField& hf) {
  return {{"width_px", hf.width()},
          {"height_px", hf.height()},
          {"pixel_size_m", hf.pixel_size},
          {"x0_m", hf.x0},
          {"y0_m", hf.y0},
          {"physical_size_m", {hf.width() * hf.pixel_size, hf.height() * hf.pixel_size}},
          {"pixel_centre",
           "pixel (i, j) at world (x0 + i*pixel_size, y0 - j*pixel_size); row 0 is "
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

namespace {

// The formats, in the order of the full list: the name, another spelling, the flag that asks
// for it. The writers are ExportScan's steps.
struct ExportFormat {
  const char* name;
  const char* alias;
  bool ExportOptions::*flag;
};
constexpr ExportFormat kExportFormats[] = {{"exr", "", &ExportOptions::exr},
                                           {"png16", "png", &ExportOptions::png16},
                                           {"glb", "gltf", &ExportOptions::glb},
                                           {"ply", "", &ExportOptions::ply}};

}  // namespace

std::string ExportFormatList() {
  std::string list;
  for (const ExportFormat& f : kExportFormats) {
    if (!list.empty()) list += ',';
    list += f.name;
  }
  return list;
}

void ExportOptions::Check() const {
  bool any = false;
  for (const ExportFormat& f : kExportFormats) any = any || this->*f.flag;
  if (!any)
    MESOSCAN_BAD_OPTION("ExportOptions.formats", "expected at least one of " << ExportFormatList());
  if (!(pixel_size_m >= 0) || !std::isfinite(pixel_size_m))
    MESOSCAN_BAD_OPTION("ExportOptions.pixel_size_m", "expected a positive number of metres");
  if (max_triangles <= 0)
    MESOSCAN_BAD_OPTION("ExportOptions.max_triangles", "expected a positive number");
  if (!(mesh_tolerance_m >= 0) || !std::isfinite(mesh_tolerance_m))
    MESOSCAN_THROW(ErrorKind::kUsage, "export: mesh tolerance: expected a number >= 0 (metres)");
  if (name.empty() || name.find('/') != std::string::npos || name.find('\\') != std::string::npos)
    MESOSCAN_BAD_OPTION("ExportOptions.name",
                        "'" << name << "': expected a plain file name prefix");
  if (!albedo.empty() && albedo.channels() != 1 && albedo.channels() != 3)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "export: albedo: expected 1 or 3 channels, got " << albedo.channels());
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
  for (const ExportFormat& f : kExportFormats) o->*f.flag = false;
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    const ExportFormat* format = nullptr;
    for (const ExportFormat& f : kExportFormats)
      if (item == f.name || (*f.alias && item == f.alias)) format = &f;
    if (!format)
      MESOSCAN_BAD_OPTION("ExportOptions.formats", "unknown format '" << item << "' (expected "
                                                                      << ExportFormatList() << ")");
    o->*format->flag = true;
  }
}

HeightField CropAndResample(const HeightField& hf, const PixelRect& crop, double pixel_size_m) {
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

ImageF CropAndResampleImage(const ImageF& image, const HeightField& hf, const PixelRect& crop,
                            double pixel_size_m) {
  CheckCrop(crop, hf.width(), hf.height());
  MESOSCAN_CHECK(image.width() == hf.width() && image.height() == hf.height());
  ImageF c = CropImage(image, crop);
  if (!Resamples(hf, pixel_size_m)) return c;
  const int w = crop.whole() ? hf.width() : crop.w, h = crop.whole() ? hf.height() : crop.h;
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

ImageF SessionTexture(const Session& s, std::string* source) {
  int white = -1, black = -1;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    if (s.frames[i].pattern.type == PatternType::kWhite && white < 0) white = static_cast<int>(i);
    if (s.frames[i].pattern.type == PatternType::kBlack && black < 0) black = static_cast<int>(i);
  }
  // A frame in linear radiance, all its colour channels; a camera raw frame on the half-size grid
  // reconstruction sees, its cells' R, G, B (session/raw_frame.h).
  auto linear = [&](int index) {
    const fs::path path = s.FramePath(index);
    ImageF im = IsCameraRawPath(path) ? ReadRawColour(path) : ReadImage(path);
    if (im.channels() == 2 || im.channels() == 4) {  // an alpha channel: dropped
      ImageF c(im.width(), im.height(), im.channels() - 1);
      std::copy(im.data().begin(), im.data().begin() + c.data().size(), c.data().begin());
      im = std::move(c);
    }
    for (float& v : im.data())
      v = static_cast<float>(s.rig.camera_response.ToLinear(std::max(0.0, v - s.rig.black_level)));
    return im;
  };
  ImageF wf;
  const fs::path manifest = s.root / "session.json";
  if (white >= 0) {
    wf = linear(white);
    if (source) *source = "white frame";
  } else {
    // No white frame: twice the mean of an evenly spread phase set (black + white / 2 each).
    const FramePlan plan = MakeFramePlan(s.frames);
    const int set = EvenPhaseSet(s, plan);
    if (set < 0)
      MESOSCAN_BAD_INPUT(manifest.string()
                         << ": frames: no white frame and no sine set with >= 3 evenly spread "
                            "phases for the albedo");
    int n = 0;
    for (size_t f : plan.sine[set].frames) {
      if (s.frames[f].shift_steps != 0) continue;
      const ImageF im = linear(static_cast<int>(f));
      if (wf.empty()) wf = ImageF(im.width(), im.height(), im.channels(), 0.0f);
      if (im.width() != wf.width() || im.height() != wf.height() || im.channels() != wf.channels())
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(s.FramePath(f)),
                              "size differs from the other sine frames");
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
  if (black >= 0) {
    const ImageF bf = linear(black);
    if (bf.width() != wf.width() || bf.height() != wf.height())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(s.FramePath(black)),
                            "size differs from the white frame");
    const float k = white >= 0 ? 1.0f : 2.0f;  // 2 mean - 2 black
    const int nc = wf.channels();
    for (int c = 0; c < nc; ++c) {
      const float* b = bf.channel(bf.channels() == 1 ? 0 : std::min(c, bf.channels() - 1));
      float* w = wf.channel(c);
      for (size_t i = 0; i < wf.pixels(); ++i) w[i] = std::max(0.0f, w[i] - k * b[i]);
    }
  } else {
    for (float& v : wf.data()) v = std::max(0.0f, v);
  }
  if (wf.channels() > 3) {  // keep R, G, B
    ImageF c(wf.width(), wf.height(), 3);
    std::copy(wf.data().begin(), wf.data().begin() + c.data().size(), c.data().begin());
    wf = std::move(c);
  }
  return wf;
}

ImageF AlbedoFromSession(const HeightField& hf, const fs::path& session_dir, std::string* source) {
  const Session s = ReadSession(session_dir, /*check_frames=*/false);
  const ImageF wf = SessionTexture(s, source);
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
        const int u0 = static_cast<int>(std::floor(uv.x())),
                  v0 = static_cast<int>(std::floor(uv.y()));
        if (u0 < 0 || v0 < 0 || u0 + 1 >= wf.width() || v0 + 1 >= wf.height()) continue;
        const double a = uv.x() - u0, b = uv.y() - v0;
        for (int k = 0; k < nc; ++k) {
          auto at = [&](int x, int y) { return static_cast<double>(wf(x, y, k)); };
          const double v = (1 - a) * (1 - b) * at(u0, v0) + a * (1 - b) * at(u0 + 1, v0) +
                           (1 - a) * b * at(u0, v0 + 1) + a * b * at(u0 + 1, v0 + 1);
          out(i, j, k) = static_cast<float>(std::max(0.0, v));
        }
      }
    }
  });
  return out;
}

double ProjectorIrradianceAt(const Rig& rig, const Vec3d& p, const Vec3d& n) {
  const Vec3d c = rig.projector.CentreInWorld();
  const Vec3d d = c - p;
  const double r = d.norm(), r0 = c.norm();
  const double cosi = n.dot(d) / (r * n.norm());
  if (!(cosi > 1e-3)) return kNan;
  Vec2d uv;
  if (!rig.projector.Project(p, &uv)) return kNan;
  const double f = ProjectorFalloff(rig, uv.x(), uv.y());
  if (!(f > 0)) return kNan;
  return cosi * (r0 / r) * (r0 / r) * f;
}

double ProjectorIrradianceOverFacets(const Rig& rig, const HeightField& hf, const ImageU8& usable,
                                     int i, int j) {
  const int w = hf.width(), h = hf.height();
  if (i < 0 || j < 0 || i >= w || j >= h || !usable(i, j)) return kNan;
  const Vec3d p(hf.X(i), hf.Y(j), hf.z(i, j));
  const Vec3d c = rig.projector.CentreInWorld();
  const Vec3d d = c - p;
  const double r = d.norm(), r0 = c.norm();
  Vec2d uv;
  if (!rig.projector.Project(p, &uv)) return kNan;
  const double f = ProjectorFalloff(rig, uv.x(), uv.y());
  if (!(f > 0)) return kNan;
  double sum = 0;
  int facets = 0;
  for (int sx : {-1, 1})
    for (int sy : {-1, 1}) {
      const int ii = i + sx, jj = j + sy;
      if (ii < 0 || jj < 0 || ii >= w || jj >= h || !usable(ii, j) || !usable(i, jj)) continue;
      // World x = column, world y = -row.
      const double gx = (hf.z(ii, j) - p.z()) / (sx * hf.pixel_size);
      const double gy = (hf.z(i, jj) - p.z()) / (-sy * hf.pixel_size);
      const double cosi =
          (d.z() - gx * d.x() - gy * d.y()) / (r * std::sqrt(1 + gx * gx + gy * gy));
      sum += std::max(0.0, cosi);
      ++facets;
    }
  if (facets == 0) return kNan;
  return sum / facets * (r0 / r) * (r0 / r) * f;
}

GreyCard ParseGreyCard(const std::string& text, const std::string& option) {
  GreyCard card;
  const size_t colon = text.find(':');
  bool ok = colon != std::string::npos;
  if (ok) {
    try {
      card.camera_px = ParsePixelRect(text.substr(0, colon), option);
      size_t used = 0;
      const std::string r = text.substr(colon + 1);
      card.reflectance = std::stod(r, &used);
      ok = used == r.size();
    } catch (const std::exception&) {
      ok = false;
    }
  }
  if (!ok || !(card.reflectance > 0 && card.reflectance <= 1) || card.camera_px.w <= 0 ||
      card.camera_px.h <= 0)
    MESOSCAN_THROW_AT(ErrorKind::kUsage, ErrorSite::Option(option),
                      "expected X,Y,W,H:REFLECTANCE (camera pixels of a neutral card on the "
                      "mount, its reflectance in (0, 1]), got '"
                          << text << "'");
  return card;
}

CardLevel MeasureGreyCard(const Session& s, const ImageF& texture, const GreyCard& card) {
  const PixelRect& r = card.camera_px;
  if (r.x < 0 || r.y < 0 || r.x + r.w > texture.width() || r.y + r.h > texture.height())
    MESOSCAN_BAD_INPUT("grey card " << r.x << "," << r.y << "," << r.w << "," << r.h
                                    << ": outside the " << texture.width() << "x"
                                    << texture.height() << " white frame of "
                                    << (s.root / "session.json").string());
  CardLevel level;
  const Vec3d centre = s.rig.camera.CentreInWorld(), up(0, 0, 1);
  const int nc = texture.channels();
  std::vector<std::vector<double>> ratios(nc);
  for (int y = r.y; y < r.y + r.h; ++y)
    for (int x = r.x; x < r.x + r.w; ++x) {
      // The card lies on the mount plane z = 0.
      const Vec3d d = s.rig.camera.RayDirectionInWorld(Vec2d(x, y));
      if (!(d.z() < 0)) continue;
      const Vec3d p = centre + (-centre.z() / d.z()) * d;
      const double e = ProjectorIrradianceAt(s.rig, p, up);
      if (!(e > 0)) continue;
      for (int c = 0; c < nc; ++c) ratios[c].push_back(texture(x, y, c) / e);
    }
  for (int c = 0; c < nc; ++c) {
    std::vector<double>& v = ratios[c];
    if (v.size() < 16)
      MESOSCAN_BAD_INPUT("grey card " << r.x << "," << r.y << "," << r.w << "," << r.h
                                      << ": fewer than 16 pixels lit by the projector");
    auto q = [&](double f) {
      std::vector<double> w = v;
      const size_t k = std::min(w.size() - 1, static_cast<size_t>(f * (w.size() - 1) + 0.5));
      std::nth_element(w.begin(), w.begin() + k, w.end());
      return w[k];
    };
    const double med = q(0.5);
    if (!(med > 0))
      MESOSCAN_BAD_INPUT("grey card " << r.x << "," << r.y << "," << r.w << "," << r.h
                                      << ": no light in the white frame");
    level.level.push_back(med);
    level.spread = std::max(level.spread, (q(0.9) - q(0.1)) / med);
  }
  level.pixels = static_cast<int>(ratios[0].size());
  return level;
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

// ---- the export's steps -----------------------------------------------------------------------

namespace {

// Step 1 output: the export grid and the maps on it, before hole filling.
struct ExportGrid {
  HeightField hf;     // the scan's height field, cropped and resampled
  ImageF normals;     // world normals on hf's grid (3 channels, NaN in holes)
  ImageF confidence;  // [0, 1] on hf's grid (the scan's, else 1 where valid)
  ImageF albedo;      // relative albedo (99th percentile 1), empty if none
  std::string albedo_source = "none";
};

ExportGrid MakeExportGrid(const Scan& scan, const ExportOptions& o) {
  ExportGrid g;
  g.hf = CropAndResample(scan.height, o.crop, o.pixel_size_m);
  const HeightField& hf = g.hf;
  // Normals: the scan's own unless resampled.
  if (!Resamples(scan.height, o.pixel_size_m) && scan.normals.width() == scan.height.width() &&
      scan.normals.height() == scan.height.height() && scan.normals.channels() == 3)
    g.normals = CropImage(scan.normals, o.crop);
  else
    g.normals = hf.Normals();
  g.confidence = hf.confidence;
  if (g.confidence.empty()) {
    g.confidence = ImageF(hf.width(), hf.height(), 1, 0.0f);
    for (size_t p = 0; p < g.confidence.pixels(); ++p)
      g.confidence.data()[p] = std::isfinite(hf.z.data()[p]) ? 1.0f : 0.0f;
  }
  // Albedo: given on the scan's grid, or the white frame of the session report.json names.
  if (!o.albedo.empty()) {
    if (o.albedo.width() != scan.height.width() || o.albedo.height() != scan.height.height())
      MESOSCAN_BAD_INPUT("export: albedo: expected the " << scan.height.width() << "x"
                                                         << scan.height.height() << " height grid");
    g.albedo = CropAndResampleImage(o.albedo, scan.height, o.crop, o.pixel_size_m);
    g.albedo_source = "given on the height grid";
  } else if (o.albedo_from_session && (o.exr || o.png16 || o.glb)) {
    const std::string session = SessionPathFromReport(scan.report);
    if (!session.empty() && fs::is_directory(session)) {
      try {
        std::string from;
        g.albedo = CropAndResampleImage(AlbedoFromSession(scan.height, session, &from), scan.height,
                                        o.crop, o.pixel_size_m);
        g.albedo_source = from + " of session " + session;
      } catch (const Error& e) {
        MESOSCAN_LOG(kWarning) << "export: no albedo (" << e.what() << ")";
      }
    }
  }
  if (!g.albedo.empty()) g.albedo = NormaliseAlbedo(g.albedo);
  return g;
}

// Step 2 output: the heights the DCC maps hold. Holes bounded by surface are filled (o.fill);
// the rest hold the lowest valid height (the confidence map marks them), so displacement never
// sees a NaN and the 16-bit range stays [min, max].
struct ExportHeights {
  HeightRange range;
  float hole_value = 0;  // lowest valid height, m
  double span = 0;       // max - min (>= 1e-9), m: the 16-bit PNG's scale
  double midlevel = 0;   // -min / span: the 16-bit PNG's value of height 0
  FillResult hole_fill;  // the filled field and which pixels were filled
  ImageF filled;         // hole_fill's heights, remaining holes at hole_value
};

// Fills the holes; the normals of filled pixels and of their measured neighbours are taken
// from the filled surface (grid->normals is updated).
ExportHeights FillExportHeights(const FillOptions& fill, ExportGrid* grid) {
  const HeightField& hf = grid->hf;
  ExportHeights h;
  h.range = RangeOf(hf.z);
  if (h.range.valid == 0)
    MESOSCAN_BAD_INPUT("height.exr: no valid height sample in the export region");
  h.hole_value = static_cast<float>(h.range.min);
  h.span = std::max(h.range.max - h.range.min, 1e-9);
  h.midlevel = -h.range.min / h.span;
  h.hole_fill = FillHoles(hf, fill);
  h.filled = FillHoles(h.hole_fill.field.z, h.hole_value);
  // The albedo wherever the height is now known (no black outline around a filled hole); 0 in
  // the holes left.
  if (!grid->albedo.empty()) {
    ImageU8 want(hf.width(), hf.height(), 1, 0);
    for (size_t p = 0; p < want.pixels(); ++p)
      want.data()[p] = std::isfinite(h.hole_fill.field.z.data()[p]);
    grid->albedo = FillImageWhere(grid->albedo, want, hf.pixel_size, fill);
    for (float& v : grid->albedo.data()) v = std::isfinite(v) ? std::max(0.0f, v) : 0.0f;
  }
  if (h.hole_fill.filled_pixels > 0) {
    const ImageF fn = h.hole_fill.field.Normals();
    for (int j = 0; j < hf.height(); ++j)
      for (int i = 0; i < hf.width(); ++i) {
        bool near = false;
        for (int dj = -1; dj <= 1 && !near; ++dj)
          for (int di = -1; di <= 1 && !near; ++di) {
            const int x = i + di, y = j + dj;
            near =
                x >= 0 && y >= 0 && x < hf.width() && y < hf.height() && h.hole_fill.filled(x, y);
          }
        if (near)
          for (int k = 0; k < 3; ++k) grid->normals(i, j, k) = fn(i, j, k);
      }
  }
  return h;
}

// Step 3: the files. Each Add* lists its files (manifest entry and Blender hint, in manifest
// order) and runs their writers as tasks; everything a task reads lives in the caller's
// ExportGrid / ExportHeights / ExportMaps, declared before the writer, whose task group waits
// for running tasks when an exception unwinds ExportScan.
class ExportWriter {
 public:
  ExportWriter(const fs::path& dir, ExportSummary* summary) : dir_(dir), summary_(summary) {}
  // On an exception the other writers are waited for (their own errors dropped: the first one
  // is reported).
  ~ExportWriter() {
    try {
      tasks_.wait();
    } catch (...) {
    }
  }
  const fs::path& dir() const { return dir_; }
  // A file of the export: its manifest entry and how to load it.
  void Add(const std::string& file, Json entry, const std::string& hint) {
    entry["file"] = file;
    files_.push_back(std::move(entry));
    hints_[file] = hint;
    summary_->files.push_back(dir_ / file);
  }
  // Runs one writer as a task and records its wall time under `file`.
  void Run(const std::string& file, std::function<void()> fn) {
    tasks_.run([this, file, fn = std::move(fn)] {
      const Stopwatch watch;
      fn();
      Record(file, watch.Seconds());
    });
  }
  void Record(const std::string& name, double seconds) {
    std::lock_guard<std::mutex> lock(mutex_);
    summary_->seconds_per_file[name] = seconds;
  }
  void Wait() { tasks_.wait(); }
  const Json& files() const { return files_; }
  const Json& hints() const { return hints_; }

 private:
  fs::path dir_;
  ExportSummary* summary_;
  Json files_ = Json::array(), hints_ = Json::object();
  std::mutex mutex_;
  tbb::task_group tasks_;
};

// What the writers of one export share: the grid, the heights and the encoded normal map.
struct ExportMaps {
  const ExportOptions& o;
  const ExportGrid& grid;
  const ExportHeights& heights;
  ImageF nmap;            // the normal map in o.normals' convention
  std::string conv;       // "gl" | "dx"
  std::string conv_text;  // the convention, spelled out
};

// <name>_normal_<conv>.<format>: its manifest entry; returns the file name.
std::string AddNormalMap(const ExportMaps& m, const std::string& format,
                         const std::string& pixel_type, ExportWriter* w) {
  const std::string fn = m.o.name + "_normal_" + m.conv + "." + format;
  w->Add(fn,
         {{"role", "normal"},
          {"format", format},
          {"pixel_type", pixel_type},
          {"channels", {"R", "G", "B"}},
          {"convention", m.conv_text},
          {"encoding", "rgb = 0.5 + 0.5 * n (tangent space: +X right, +Z out)"},
          {"colour_space", "Non-Color (raw data)"}},
         "Blender: Image Texture '" + fn +
             "' (Color Space Non-Color) -> Normal Map node (Tangent Space)" +
             (m.o.normals == NormalConvention::kDirectX ? "; DirectX: invert green first" : ""));
  return fn;
}

// <name>_height.exr (metres) and <name>_normal_<conv>.exr.
void AddExrMaps(const ExportMaps& m, ExportWriter* w) {
  const HeightField& hf = m.grid.hf;
  const std::string f = m.o.name + "_height.exr";
  w->Add(f,
         {{"role", "height"},
          {"format", "exr"},
          {"pixel_type", "float32"},
          {"channels", {"Y"}},
          {"units", "m"},
          {"colour_space", "Non-Color (raw data)"},
          {"midlevel", 0.0},
          {"scale", 1.0},
          {"meaning", "metres above the mount plane z = 0"}},
         "Blender: Image Texture '" + f +
             "' (Color Space Non-Color) -> Displacement node or "
             "Displace modifier (UV), Midlevel 0, Scale 1: metres (the modifier clamps values "
             "below 0: "
             "for heights under the mount plane use the node or the 16-bit PNG)");
  w->Run(f, [&m, &hf, f, dir = w->dir()] {
    WriteExr(dir / f, m.heights.filled, {"Y"},
             {{kAttrX0, hf.x0},
              {kAttrY0, hf.y0},
              {kAttrPixelSize, hf.pixel_size},
              {"mesoscan:midlevel", 0.0},
              {"mesoscan:scale", 1.0},
              {"mesoscan:hole_value", m.heights.hole_value}},
             {{"mesoscan:units", "m"}, {"mesoscan:content", "height above the mount plane"}});
  });
  const std::string fn = AddNormalMap(m, "exr", "float32", w);
  w->Run(fn, [&m, &hf, fn, dir = w->dir()] {
    WriteExr(dir / fn, m.nmap, {"R", "G", "B"},
             {{kAttrX0, hf.x0}, {kAttrY0, hf.y0}, {kAttrPixelSize, hf.pixel_size}},
             {{"mesoscan:normal_convention", m.conv_text},
              {"mesoscan:encoding", "rgb = 0.5 + 0.5 * n"}});
  });
}

// <name>_height.png (16 bit, min..max) with its <name>_height.json sidecar, and
// <name>_normal_<conv>.png.
void AddPng16Maps(const ExportMaps& m, ExportWriter* w) {
  const HeightField& hf = m.grid.hf;
  const ExportHeights& h = m.heights;
  const std::string f = m.o.name + "_height.png", fs_ = m.o.name + "_height.json";
  std::ostringstream disp;
  disp.precision(9);
  disp << "Blender: Image Texture '" << f << "' (Color Space Non-Color) -> Displacement Midlevel "
       << h.midlevel << ", Scale " << h.span << " (metres; see " << fs_ << ")";
  w->Add(f,
         {{"role", "height"},
          {"format", "png"},
          {"pixel_type", "uint16"},
          {"channels", {"Y"}},
          {"units", "m"},
          {"colour_space", "Non-Color (raw data)"},
          {"midlevel", h.midlevel},
          {"scale", h.span},
          {"sidecar", fs_},
          {"meaning", "metres = (value / 65535 - midlevel) * scale"}},
         disp.str());
  Json sidecar = {
      {"format", kExportFormat},
      {"file", f},
      {"units", "m"},
      {"meaning", "height above the mount plane z = 0"},
      {"decode", "metres = (value / 65535 - midlevel) * scale = min + value / 65535 * (max - min)"},
      {"min_m", h.range.min},
      {"max_m", h.range.max},
      {"midlevel", h.midlevel},
      {"scale", h.span},
      {"quantisation_step_m", h.span / 65535.0},
      {"blender", {{"midlevel", h.midlevel}, {"scale", h.span}, {"color_space", "Non-Color"}}},
      {"arnold", {{"zero_value", h.midlevel}, {"height", h.span}}},
      {"hole_value_m", h.hole_value},
      {"pixel_size_m", hf.pixel_size},
      {"width_px", hf.width()},
      {"height_px", hf.height()},
      {"physical_size_m", {hf.width() * hf.pixel_size, hf.height() * hf.pixel_size}}};
  w->Add(fs_, {{"role", "height sidecar"}, {"format", "json"}},
         "the 16-bit height's min, max, midlevel, scale");
  w->Run(f, [&h, &hf, f, fs_, sidecar, dir = w->dir()] {
    ImageU16 q(hf.width(), hf.height(), 1);
    for (size_t p = 0; p < q.pixels(); ++p) {
      const double v = (h.filled.data()[p] - h.range.min) / h.span;
      q.data()[p] = static_cast<uint16_t>(std::lround(std::clamp(v, 0.0, 1.0) * 65535.0));
    }
    WritePng16(dir / f, q, kPng16Compression);
    WriteJsonFile(dir / fs_, sidecar);
  });
  const std::string fn = AddNormalMap(m, "png", "uint16", w);
  w->Run(fn, [&m, fn, dir = w->dir()] {
    WritePng16(dir / fn, QuantizeU16(m.nmap), kPng16Compression);
  });
}

// <name>_confidence.png and, with an albedo, <name>_albedo.png (sRGB).
void AddMaskAndAlbedo(const ExportMaps& m, ExportWriter* w) {
  const ExportGrid& g = m.grid;
  const std::string f = m.o.name + "_confidence.png";
  w->Add(f,
         {{"role", "confidence"},
          {"format", "png"},
          {"pixel_type", "uint8"},
          {"channels", {"Y"}},
          {"colour_space", "Non-Color (raw data)"},
          {"meaning", "confidence in [0, 1]; 0 in holes"}},
         "Blender: Image Texture '" + f + "' (Color Space Non-Color): a mask, 0 in holes");
  w->Run(f, [&g, f, dir = w->dir()] { WritePng8(dir / f, QuantizeU8(g.confidence)); });
  if (g.albedo.empty()) return;
  const std::string fa = m.o.name + "_albedo.png";
  w->Add(fa,
         {{"role", "albedo"},
          {"format", "png"},
          {"pixel_type", "uint8"},
          {"channels", g.albedo.channels() == 3 ? Json{"R", "G", "B"} : Json{"Y"}},
          {"colour_space", "sRGB"},
          {"source", g.albedo_source},
          {"meaning",
           "relative albedo: white-frame radiance (or twice a sine set's "
           "mean) minus black, 99th percentile = 1, "
           "no shading correction"}},
         "Blender: Image Texture '" + fa + "' (Color Space sRGB) -> Principled BSDF Base Color");
  w->Run(fa, [&g, fa, dir = w->dir()] {
    WritePng8(dir / fa, QuantizeU8(g.albedo, /*srgb_encode=*/true));
  });
}

// <name>.ply: the valid samples as points with normals and confidence.
void AddPly(const ExportMaps& m, ExportWriter* w) {
  const std::string f = m.o.name + ".ply";
  w->Add(f,
         {{"role", "points"},
          {"format", "ply"},
          {"units", "m"},
          {"axes", "world: z up"},
          {"properties", {"x", "y", "z", "nx", "ny", "nz", "confidence"}},
          {"points", m.heights.range.valid}},
         "MeshLab / CloudCompare: open '" + f + "' (metres, z up; confidence as a scalar field)");
  w->Run(f, [&m, f, dir = w->dir()] { WritePly(dir / f, m.grid.hf, m.grid.normals); });
}

// What the GLB writer reads; owned by ExportScan so that it outlives the task.
struct GlbParts {
  GridMesh mesh;
  std::vector<uint8_t> normal_png, albedo_png, occlusion_png;
};

// The GLB's extras: units, axes, the height maps beside it and the mesh's error.
Json GlbExtras(const ExportMaps& m, const GridMesh& mesh) {
  const ExportOptions& o = m.o;
  const std::string& n = o.name;
  Json extras = {{"units", "m"},
                 {"up_axis", "glTF +Y (world z); world (x, y, z) = glTF (x, -z, y)"},
                 {"height_zero_m", 0.0},
                 {"height_scale", 1.0},
                 {"max_height_error_m", mesh.max_height_error_m},
                 {"pixel_size_m", m.grid.hf.pixel_size}};
  if (o.exr) extras["height_map"] = n + "_height.exr";
  if (o.png16) {
    extras["height_map_png16"] = n + "_height.png";
    extras["height_png16_midlevel"] = m.heights.midlevel;
    extras["height_png16_scale"] = m.heights.span;
  }
  if (!extras.contains("height_map")) extras["height_map"] = o.png16 ? n + "_height.png" : "";
  return extras;
}

// The GLB's manifest entry.
// Vertices of `mesh` on samples the hole filling made.
int64_t FilledVertices(const ExportMaps& m, const GridMesh& mesh) {
  const ImageU8& filled = m.heights.hole_fill.filled;
  if (filled.empty()) return 0;
  int64_t n = 0;
  for (const int32_t p : mesh.vertex_pixel) n += filled.data()[p] != 0;
  return n;
}

Json GlbTextures(const ExportMaps& m) {
  Json t = Json::array({"normal (OpenGL, 8-bit)"});
  if (!m.grid.albedo.empty()) t.push_back("baseColor (sRGB, 8-bit)");
  if (m.o.glb_occlusion) t.push_back("occlusion (ambient occlusion, linear 8-bit, R)");
  return t;
}

Json GlbEntry(const ExportMaps& m, const GridMesh& mesh) {
  return {{"role", "mesh"},
          {"format", "glb"},
          {"units", "m"},
          {"axes", "glTF +Y up: (x, y, z)_gltf = (x, z, -y)_world"},
          {"uv", "sample (i, j) at ((i + 0.5)/W, (j + 0.5)/H), glTF top-left origin"},
          {"triangles", mesh.triangles()},
          {"vertices", mesh.vertices()},
          {"max_triangles", m.o.max_triangles},
          {"lossless_triangles", mesh.lossless_triangles},
          {"max_height_error_m", mesh.max_height_error_m},
          {"rtin_threshold_m", mesh.threshold_m},
          {"uncovered_samples", mesh.uncovered_samples},
          {"filled_vertices", FilledVertices(m, mesh)},
          {"filled_attribute", "_FILLED: 1 at vertices on filled (not measured) samples"},
          {"budget_met", mesh.budget_met},
          {"textures", GlbTextures(m)},
          {"roughness", m.o.glb_roughness >= 0 ? m.o.glb_roughness : 0.6}};
}

// <name>.glb: the mesh (built on this thread while its textures are encoded) with its
// normal (OpenGL) and base-colour textures.
void AddGlb(const ExportMaps& m, GlbParts* parts, ExportSummary* summary, ExportWriter* w) {
  const ExportGrid& g = m.grid;
  const std::string n = m.o.name, f = n + ".glb";
  // Textures encoded in parallel with the mesh.
  const fs::path tex = w->dir() / (n + "_texture.png");  // temporaries are named after it
  tbb::task_group texture_tasks;
  texture_tasks.run([&g, parts, tex] {
    parts->normal_png =
        EncodePng8(QuantizeU8(EncodeNormalMap(g.normals, NormalConvention::kOpenGl)), tex);
  });
  if (!g.albedo.empty())
    texture_tasks.run(
        [&g, parts, tex] { parts->albedo_png = EncodePng8(QuantizeU8(g.albedo, true), tex); });
  if (m.o.glb_occlusion)
    texture_tasks.run([&m, parts, tex] {
      parts->occlusion_png = EncodePng8(
          QuantizeU8(AmbientOcclusion(m.heights.hole_fill.field, m.o.glb_ao, false)), tex);
    });
  // The mesh (RTIN within the triangle budget) over the hole-filled field, so that viewers show
  // no gap where the scan has a hole; its filled vertices are flagged (_FILLED).
  const HeightField& surface = m.heights.hole_fill.field;
  GridMeshOptions mo;
  mo.max_triangles = m.o.max_triangles;
  mo.tolerance_m = m.o.mesh_tolerance_m;
  const Stopwatch mesh_watch;
  try {
    parts->mesh = TriangulateHeightField(surface, mo);
  } catch (...) {
    texture_tasks.wait();
    throw;
  }
  w->Record("(mesh)", mesh_watch.Seconds());
  const GridMesh& mesh = parts->mesh;
  if (mesh.triangles() == 0) {
    texture_tasks.wait();
    MESOSCAN_BAD_INPUT("height.exr: no triangle in the export region (all holes?)");
  }
  summary->triangles = mesh.triangles();
  summary->vertices = mesh.vertices();
  summary->max_height_error_m = mesh.max_height_error_m;
  // The file: listed, then written once its textures are ready.
  w->Add(f, GlbEntry(m, mesh),
         "Blender: File > Import > glTF 2.0 '" + f +
             "' with Shading: Smooth in the importer's options (Debian's Blender needs it; "
             "Python: bpy.ops.import_scene.gltf(filepath='" +
             f + "', import_shading='SMOOTH')) (metres; Z up after import)");
  texture_tasks.wait();
  w->Run(f, [&g, &surface, &m, parts, n, f, extras = GlbExtras(m, mesh), dir = w->dir()] {
    GlbContent c;
    c.name = n;
    c.grid = &surface;
    c.normals = &g.normals;
    c.mesh = &parts->mesh;
    if (!m.heights.hole_fill.filled.empty()) c.filled = &m.heights.hole_fill.filled;
    c.extras = extras;
    c.normal_png = std::move(parts->normal_png);
    c.base_color_png = std::move(parts->albedo_png);
    c.occlusion_png = std::move(parts->occlusion_png);
    if (m.o.glb_roughness >= 0) c.roughness = m.o.glb_roughness;
    WriteGlb(dir / f, c);
  });
}

// manifest.json: units, conventions, grids, fill, and the files written (in `w`'s order).
Json ExportManifest(const Scan& scan, const ExportMaps& m, const ExportWriter& w) {
  const ExportOptions& o = m.o;
  const ExportHeights& h = m.heights;
  return {
      {"format", kExportFormat},
      {"name", o.name},
      {"units", "m"},
      {"conventions",
       {{"world", "metres; mount plane z = 0, +z up towards the rig"},
        {"maps", "one grid for every map; row 0 is the +y edge, so image up = world +y"},
        {"height",
         "metres above the mount plane; holes bounded by surface filled (see fill), the others "
         "with hole_value_m (see the confidence map)"},
        {"normal_map", m.conv_text + "; tangent space +X = world x, +Y = world y on a flat sample"},
        {"glb", "metres, glTF +Y up: (x, y, z)_gltf = (x, z, -y)_world; normal texture OpenGL"},
        {"exr_height_channel",
         "Y: OpenEXR's luminance channel, read as grey (R = G = B) by Blender, OIIO and "
         "Substance"}}},
      {"grid", GridJson(m.grid.hf)},
      {"source_grid", GridJson(scan.height)},
      {"crop_px", o.crop.whole() ? Json(nullptr) : Json{o.crop.x, o.crop.y, o.crop.w, o.crop.h}},
      {"height_range_m", {h.range.min, h.range.max}},
      {"hole_value_m", h.hole_value},
      {"fill",
       {{"method", FillMethodName(o.fill.method)},
        {"max_hole_radius_m", o.fill.max_hole_radius_m},
        {"pixels_filled", h.hole_fill.filled_pixels},
        {"holes_filled", h.hole_fill.holes_filled},
        {"pixels_left", h.hole_fill.pixels_left},
        {"note", "filled pixels have confidence 0; the rest of the holes hold hole_value_m"}}},
      {"valid_samples", h.range.valid},
      {"albedo", m.grid.albedo_source},
      {"files", w.files()},
      {"how_to_load", w.hints()}};
}

}  // namespace

// ---- the export -----------------------------------------------------------------------------

ExportSummary ExportScan(const Scan& scan, const ExportOptions& o, const fs::path& dir) {
  o.Check();
  const Stopwatch total;
  if (scan.height.width() < 2 || scan.height.height() < 2)
    MESOSCAN_BAD_INPUT("height.exr: the height grid is " << scan.height.width() << "x"
                                                         << scan.height.height()
                                                         << ", too small to export");
  // 1. The export grid: crop, resample; normals, confidence and albedo on it.
  ExportGrid grid = MakeExportGrid(scan, o);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (!fs::is_directory(dir))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(dir), "cannot create the export folder");
  // 2. Holes filled for the DCC maps; the normal map encoded.
  const ExportHeights heights = FillExportHeights(o.fill, &grid);
  const bool gl = o.normals == NormalConvention::kOpenGl;
  const ExportMaps maps{
      o,
      grid,
      heights,
      EncodeNormalMap(grid.normals, o.normals),
      gl ? "gl" : "dx",
      gl ? "OpenGL (+Y: green points to image up)" : "DirectX (-Y: green points to image down)"};
  // 3. The files, written in parallel (the writer waits for its tasks, also on an exception).
  ExportSummary summary;
  GlbParts glb;
  {
    ExportWriter writer(dir, &summary);
    if (o.exr) AddExrMaps(maps, &writer);
    if (o.png16) AddPng16Maps(maps, &writer);
    if (o.exr || o.png16 || o.glb) AddMaskAndAlbedo(maps, &writer);
    if (o.ply) AddPly(maps, &writer);
    if (o.glb) AddGlb(maps, &glb, &summary, &writer);
    writer.Wait();
    // 4. The manifest, last: it names only files that were written completely.
    summary.manifest = ExportManifest(scan, maps, writer);
  }
  WriteJsonFile(dir / "manifest.json", summary.manifest);
  summary.files.push_back(dir / "manifest.json");
  summary.seconds = total.Seconds();
  return summary;
}

}  // namespace mesoscan
