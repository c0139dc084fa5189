#include "maps/maps.h"

#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/parallel.h"
#include "core/stage_timer.h"
#include "maps/export.h"
#include "session/session.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr const char* kMapsFormat = "mesoscan-maps/1";
// Above this share of filled pixels, or under this share on the sample, the tile is doubtful.
constexpr double kTileFilledWarnFraction = 0.20;
constexpr double kTileOnSampleWarnFraction = 0.80;
constexpr float kNan = std::numeric_limits<float>::quiet_NaN();

// Value of the q-quantile of the finite values of channel 0..nc-1 (mean over channels).
double Quantile(const ImageF& im, double q) {
  std::vector<float> v;
  v.reserve(im.pixels());
  for (size_t p = 0; p < im.pixels(); ++p) {
    double s = 0;
    for (int k = 0; k < im.channels(); ++k) s += im.channel(k)[p];
    if (std::isfinite(s)) v.push_back(static_cast<float>(s / im.channels()));
  }
  if (v.empty()) return 0.0;
  const size_t i = static_cast<size_t>(q * (v.size() - 1));
  std::nth_element(v.begin(), v.begin() + i, v.end());
  return v[i];
}

// ---- contact sheet ------------------------------------------------------------------------

struct Panel {
  std::string label;
  cv::Mat rgb;  // CV_8UC3, any size (scaled to the cell)
};

cv::Mat GreyPanel(const ImageF& im, double lo, double hi) {
  cv::Mat m(im.height(), im.width(), CV_8UC3);
  const double s = hi > lo ? 255.0 / (hi - lo) : 0.0;
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x) {
      const float v = im(x, y);
      const uint8_t g =
          std::isfinite(v) ? static_cast<uint8_t>(std::clamp((v - lo) * s, 0.0, 255.0)) : 0;
      m.at<cv::Vec3b>(y, x) = std::isfinite(v) ? cv::Vec3b(g, g, g) : cv::Vec3b(80, 0, 80);
    }
  return m;
}

cv::Mat RgbPanel(const ImageF& im, bool srgb) {
  cv::Mat m(im.height(), im.width(), CV_8UC3);
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x) {
      cv::Vec3b px;
      for (int c = 0; c < 3; ++c) {
        double v = im(x, y, im.channels() == 1 ? 0 : c);
        if (!std::isfinite(v)) v = 0;
        v = std::clamp(v, 0.0, 1.0);
        if (srgb) v = v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1 / 2.4) - 0.055;
        px[2 - c] = static_cast<uint8_t>(std::lround(v * 255));  // OpenCV is BGR
      }
      m.at<cv::Vec3b>(y, x) = px;
    }
  return m;
}

// Hill shade of a height field lit from the upper left at 30 degrees elevation.
cv::Mat ShadePanel(const ImageF& normals) {
  ImageF s(normals.width(), normals.height(), 1);
  const double l[3] = {-0.61, 0.61, 0.5};
  for (int y = 0; y < s.height(); ++y)
    for (int x = 0; x < s.width(); ++x)
      s(x, y) = static_cast<float>(std::max(
          0.0, l[0] * normals(x, y, 0) + l[1] * normals(x, y, 1) + l[2] * normals(x, y, 2)));
  return GreyPanel(s, 0.0, 1.0);
}

// Cells of `cell` px, 4 per row, a label above each and a scale bar on each map panel.
ImageU8 ContactSheet(const std::vector<Panel>& panels, const std::vector<double>& panel_width_m) {
  const int cell = 320, label_h = 26, cols = std::min<int>(4, static_cast<int>(panels.size()));
  const int rows = (static_cast<int>(panels.size()) + cols - 1) / cols;
  cv::Mat sheet(rows * (cell + label_h + 8) + 8, cols * (cell + 8) + 8, CV_8UC3,
                cv::Scalar(40, 40, 40));
  for (size_t k = 0; k < panels.size(); ++k) {
    const int cx = 8 + static_cast<int>(k % cols) * (cell + 8);
    const int cy = 8 + static_cast<int>(k / cols) * (cell + label_h + 8);
    const cv::Mat& p = panels[k].rgb;
    const double s = static_cast<double>(cell) / std::max(p.cols, p.rows);
    const int pw = std::max(1, static_cast<int>(p.cols * s)),
              ph = std::max(1, static_cast<int>(p.rows * s));
    cv::Mat scaled;
    cv::resize(p, scaled, cv::Size(pw, ph), 0, 0, s < 1 ? cv::INTER_AREA : cv::INTER_NEAREST);
    scaled.copyTo(sheet(cv::Rect(cx, cy + label_h, pw, ph)));
    cv::putText(sheet, panels[k].label, cv::Point(cx, cy + 18), cv::FONT_HERSHEY_SIMPLEX, 0.5,
                cv::Scalar(235, 235, 235), 1, cv::LINE_AA);
    // Scale bar: the largest 1-2-5 x 10^k mm under 40% of the panel's width.
    const double width_m = panel_width_m[k];
    if (width_m > 0) {
      const double max_mm = 0.4 * width_m * 1e3;
      double bar_mm = std::pow(10.0, std::floor(std::log10(max_mm)));
      for (double f : {5.0, 2.0})
        if (bar_mm * f <= max_mm) {
          bar_mm *= f;
          break;
        }
      const int bar_px = static_cast<int>(std::lround(bar_mm / (width_m * 1e3) * pw));
      const int bx = cx + 8, by = cy + label_h + ph - 12;
      cv::rectangle(sheet, cv::Rect(bx - 2, by - 16, bar_px + 4, 22), cv::Scalar(0, 0, 0),
                    cv::FILLED);
      cv::rectangle(sheet, cv::Rect(bx, by, bar_px, 4), cv::Scalar(255, 255, 255), cv::FILLED);
      std::ostringstream t;
      t << bar_mm << " mm";
      cv::putText(sheet, t.str(), cv::Point(bx, by - 3), cv::FONT_HERSHEY_SIMPLEX, 0.4,
                  cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
    }
  }
  ImageU8 out(sheet.cols, sheet.rows, 3);
  for (int y = 0; y < sheet.rows; ++y)
    for (int x = 0; x < sheet.cols; ++x)
      for (int c = 0; c < 3; ++c) out(x, y, c) = sheet.at<cv::Vec3b>(y, x)[2 - c];
  return out;
}

}  // namespace

void MapsOptions::Check() const {
  fill.Check();
  flatten.Check();
  if (tile) tile_options.Check();
  ao.Check();
  if (!(curvature_sigma_px >= 0))
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "maps: curvature sigma " << curvature_sigma_px << ": expected >= 0");
  if (!(roughness <= 1.0) || (roughness < 0 && roughness != -1.0))
    MESOSCAN_BAD_OPTION("MapsOptions.roughness", roughness << ": expected a roughness in [0, 1]");
  if (size_px != 0 && (size_px < 8 || size_px > 16384 || (size_px & (size_px - 1)) != 0))
    MESOSCAN_BAD_OPTION("MapsOptions.size_px",
                        size_px << ": expected a power of two from 8 to 16384 (or 0: unchanged)");
  if (name.empty() || name.find_first_of("/\\") != std::string::npos)
    MESOSCAN_BAD_OPTION("MapsOptions.name", "'" << name << "': expected a file name prefix");
  if (!maps.height && !maps.normal && !maps.albedo && !maps.confidence && !maps.ao &&
      !maps.curvature)
    MESOSCAN_BAD_OPTION("MapsOptions.maps", "expected at least one map");
}

void ParseMapSelection(const std::string& list, MapsOptions* o) {
  o->maps = MapSelection{false, false, false, false, false, false};
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item == "height")
      o->maps.height = true;
    else if (item == "normal")
      o->maps.normal = true;
    else if (item == "albedo")
      o->maps.albedo = true;
    else if (item == "confidence")
      o->maps.confidence = true;
    else if (item == "ao")
      o->maps.ao = true;
    else if (item == "curvature")
      o->maps.curvature = true;
    else
      MESOSCAN_BAD_OPTION("MapsOptions.maps", "'" << item
                                                  << "': expected height, normal, albedo, "
                                                     "confidence, ao or curvature");
  }
}

std::string MapsSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(3);
  s << "maps: " << files.size() << " files in " << seconds << " s; " << fill.BriefReport()
    << "; flatten " << flatten;
  if (!tile.empty()) s << "; " << tile;
  return s.str();
}

namespace {

// ---- the steps of BuildMapSet --------------------------------------------------------------

// The map region of the scan's height grid, with at least one valid sample.
HeightField CropForMaps(const HeightField& height, const PixelRect& crop) {
  if (height.width() < 2 || height.height() < 2)
    MESOSCAN_BAD_INPUT("height.exr: the height grid is " << height.width() << "x" << height.height()
                                                         << ", too small for maps");
  HeightField cropped = CropAndResample(height, crop, 0.0);
  int64_t valid = 0;
  for (float v : cropped.z.data()) valid += std::isfinite(v);
  if (valid == 0) MESOSCAN_BAD_INPUT("height.exr: no valid height sample in the map region");
  return cropped;
}

// Where the flatten is fit: the measured pixels (filled ones are left out) of the sample, those
// standing more than `clearance_m` off the mount plane, when the scan shows both the sample and
// the bare mount (each at least 1% of the measured pixels): the sample's shape is removed, not
// the mount's plane. Otherwise every measured pixel. `region` says which.
ImageU8 FlattenFitMask(const FillResult& fill, double clearance_m, std::string* region) {
  const ImageF& z = fill.field.z;
  ImageU8 mask(z.width(), z.height(), 1, 0);
  int64_t measured = 0, on = 0;
  for (size_t p = 0; p < mask.pixels(); ++p) {
    const float v = z.data()[p];
    if (fill.filled.data()[p] || !std::isfinite(v)) continue;
    ++measured;
    on += v > clearance_m;
  }
  const bool sample_only = on >= measured / 100 && measured - on >= measured / 100 && on > 0;
  for (size_t p = 0; p < mask.pixels(); ++p)
    mask.data()[p] = !fill.filled.data()[p] && (!sample_only || z.data()[p] > clearance_m);
  *region = sample_only ? "the sample's measured pixels (" + std::to_string(on) +
                              " px standing off the mount plane)"
                        : "every measured pixel";
  return mask;
}

// The albedo on the cropped grid and where it came from.
struct MapAlbedo {
  ImageF image;  // empty: no albedo
  std::string source = "none";
  bool reflectance = false;  // scaled by a reference of known reflectance (else relative)
  Json info = nullptr;       // the manifest's "albedo": units, reference, figures
};

// The rig's projector falloff (rig.projector.falloff) at each height sample's projector pixel;
// empty if the rig has none. NaN where the sample does not project.
ImageF ProjectorFalloffOnGrid(const HeightField& hf, const Rig& rig) {
  if (rig.projector_falloff == 0) return ImageF();
  ImageF f(hf.width(), hf.height(), 1, kNan);
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      const double z = hf.z(i, j);
      Vec2d uv;
      if (std::isfinite(z) && rig.projector.Project(Vec3d(hf.X(i), hf.Y(j), z), &uv))
        f(i, j) = static_cast<float>(ProjectorFalloff(rig, uv.x(), uv.y()));
    }
  return f;
}

// The session's albedo divided by the projector's absolute irradiance (cos(i) (r0/r)^2 times the
// rig's falloff) and scaled per channel so that the grey card has its stated reflectance.
void ScaleToReflectance(const Session& s, const HeightField& field, const FillResult& fill,
                        const GreyCard& card_ref, MapAlbedo* a) {
  const ImageF texture = SessionTexture(s);
  const CardLevel card = MeasureGreyCard(s, texture, card_ref);
  // The irradiance over each measured sample's footprint on the measured surface (its facets to
  // measured neighbours; the fill's interpolated heights would flatten the steep flanks around
  // the holes it fills).
  ImageU8 measured(field.width(), field.height(), 1, 0);
  for (size_t p = 0; p < measured.pixels(); ++p)
    measured.data()[p] = !fill.filled.data()[p] && std::isfinite(field.z.data()[p]);
  const int nc = a->image.channels();
  MESOSCAN_CHECK(static_cast<int>(card.level.size()) >= nc);
  ParallelForRows(field.height(), [&](int r0, int r1) {
    for (int j = r0; j < r1; ++j)
      for (int i = 0; i < field.width(); ++i) {
        const size_t p = static_cast<size_t>(j) * field.width() + i;
        const double e = ProjectorIrradianceOverFacets(s.rig, field, measured, i, j);
        for (int c = 0; c < nc; ++c) {
          float& v = a->image.channel(c)[p];
          // Grazing light (irradiance below 5% of the reference) is too uncertain: left to the
          // fill, as in the relative map.
          v = e > 0.05 ? static_cast<float>(v / e / card.level[c] * card_ref.reflectance) : kNan;
        }
      }
  });
  const PixelRect& r = card_ref.camera_px;
  std::ostringstream ref;
  ref << "grey card at camera pixels " << r.x << "," << r.y << "," << r.w << "," << r.h
      << " of reflectance " << card_ref.reflectance;
  a->reflectance = true;
  a->info = {
      {"units", "reflectance in [0, 1] per channel"},
      {"reference", ref.str()},
      {"card_pixels", card.pixels},
      {"card_spread", card.spread},
      {"card_level", card.level},
      {"falloff", s.rig.projector_falloff != 0
                      ? "cos(i) (r0/r)^2 and rig.projector.falloff divided out"
                      : "cos(i) (r0/r)^2 divided out (no rig.projector.falloff)"},
      {"irradiance", "mean over each measured sample's four facets to its measured neighbours"}};
  if (card.spread > 0.10)
    MESOSCAN_LOG(kWarning) << "maps: the grey card's light varies by "
                           << std::lround(100 * card.spread)
                           << "% (p10..p90) after the falloff model: is the rectangle wholly on "
                              "the card, and the falloff calibrated? The reflectance is doubtful";
}

// The given albedo, or the session's white frame with the projector's falloff divided out.
MapAlbedo ReadAlbedo(const Scan& scan, const MapsOptions& o, const FillResult& fill) {
  MapAlbedo a;
  if (!o.albedo.empty()) {
    if (o.albedo.width() != scan.height.width() || o.albedo.height() != scan.height.height())
      MESOSCAN_BAD_INPUT("maps: albedo: expected the " << scan.height.width() << "x"
                                                       << scan.height.height() << " height grid");
    a.image = CropAndResampleImage(o.albedo, scan.height, o.crop, 0.0);
    a.source = "given on the height grid (no falloff correction)";
  } else if (o.albedo_from_session) {
    const HeightField& filled_field = fill.field;
    const std::string session = SessionPathFromReport(scan.report);
    if (!session.empty() && fs::is_directory(session)) {
      Session s;
      try {
        s = ReadSession(session, /*check_frames=*/false);
        a.image = AlbedoFromSession(filled_field, session);
      } catch (const Error& e) {
        MESOSCAN_LOG(kWarning) << "maps: no albedo (" << e.what() << ")";
        a.image = ImageF();
      }
      if (!a.image.empty() && o.grey_card.given()) {
        ScaleToReflectance(s, filled_field, fill, o.grey_card, &a);  // a bad card is an error
        a.source = "white frame of session " + session +
                   " divided by the projector's irradiance, scaled by the grey card";
      } else if (!a.image.empty()) {
        const ImageF e = ProjectorIrradiance(filled_field, NormalsOf(filled_field, false),
                                             s.rig.projector.CentreInWorld());
        const ImageF f = ProjectorFalloffOnGrid(filled_field, s.rig);  // empty: none
        for (int c = 0; c < a.image.channels(); ++c)
          for (size_t p = 0; p < a.image.pixels(); ++p) {
            float& v = a.image.channel(c)[p];
            const float ep = f.empty() ? e.data()[p] : e.data()[p] * f.data()[p];
            v = fill.filled.data()[p] || !(ep > 0.05f) ? kNan : v / ep;
          }
        a.source = "white frame of session " + session +
                   (f.empty() ? " divided by the projector's falloff cos(i)/r^2 (median 1)"
                              : " divided by the projector's falloff cos(i)/r^2 (median 1) and "
                                "rig.projector.falloff");
        a.info = {{"units", "relative (99th percentile = 1)"},
                  {"reference",
                   "none: no reference of known reflectance (maps --grey-card X,Y,W,H:R), so "
                   "the albedo is relative brightness, not reflectance"}};
      }
    }
  }
  return a;
}

// The albedo wherever the height is known (measured or filled: FillImageWhere), then scaled
// so that its 99th percentile is 1.
void FillAndNormalizeAlbedo(const MapsOptions& o, const HeightField& cropped,
                            const FillResult& fill, MapAlbedo* map_albedo) {
  ImageF* albedo = &map_albedo->image;
  ImageU8 want(cropped.width(), cropped.height(), 1, 0);
  for (size_t p = 0; p < want.pixels(); ++p)
    want.data()[p] = std::isfinite(cropped.z.data()[p]) || fill.filled.data()[p] != 0;
  *albedo = FillImageWhere(*albedo, want, cropped.pixel_size, o.fill);
  for (int c = 0; c < albedo->channels(); ++c)
    for (size_t p = 0; p < want.pixels(); ++p)
      if (!want.data()[p]) albedo->channel(c)[p] = kNan;
  if (map_albedo->reflectance) {
    // Reflectance: kept as measured, clipped to [0, 1]; the clipped fraction is said.
    int64_t n = 0, above = 0;
    for (float& v : albedo->data()) {
      if (!std::isfinite(v)) continue;
      ++n;
      above += v > 1.0f;
      v = std::clamp(v, 0.0f, 1.0f);
    }
    const double frac = n > 0 ? static_cast<double>(above) / n : 0.0;
    map_albedo->info["clipped_above_1"] = frac;
    if (frac > 0.01)
      MESOSCAN_LOG(kWarning) << "maps: " << std::lround(100 * frac)
                             << "% of the albedo samples exceed reflectance 1 (clipped): "
                                "specular highlights, or a wrong grey card";
    return;
  }
  const double q99 = Quantile(*albedo, 0.99);
  const float scale = q99 > 0 ? static_cast<float>(1.0 / q99) : 1.0f;
  for (float& v : albedo->data()) v = std::isfinite(v) ? std::max(0.0f, v * scale) : kNan;
}

// What the maps are made of: the flattened field (tiled or not), its albedo and filled pixels.
struct FinalSurface {
  HeightField field;
  ImageF albedo;
  ImageU8 filled;
  std::optional<TileResult> tile;  // set for a tile
};

// The tile's square is chosen on the sample: the filled but unflattened height says where the
// sample stands off the mount plane.
FinalSurface TileOrKeep(const MapsOptions& o, const FlattenResult& flat, const ImageF& albedo,
                        const FillResult& fill) {
  FinalSurface f;
  if (o.tile) {
    TileOptions to = o.tile_options;
    if (!o.crop.whole()) to.origin_px = {o.crop.x, o.crop.y};
    f.tile = MakeTile(flat.field, albedo, fill.filled, to, fill.field.z);
    f.field = f.tile->field;
    f.albedo = f.tile->albedo;
    f.filled = f.tile->filled;
  } else {
    f.field = flat.field;
    f.albedo = albedo;
    f.filled = fill.filled;
  }
  return f;
}

// A square periodic image resampled to n_out x n_out on its period: its Fourier series cut (or
// zero-padded) to the frequencies both grids hold, so the result stays exactly periodic and its
// mean is kept. Non-finite samples count as the channel's mean.
ImageF FourierResample(const ImageF& im, int n_out) {
  const int n = im.width();
  MESOSCAN_CHECK(im.height() == n && n_out > 0);
  const int half = (std::min(n, n_out) - 1) / 2;  // frequencies -half..half (no Nyquist term)
  const float scale = static_cast<float>(static_cast<double>(n_out) * n_out / (n * n));
  ImageF out(n_out, n_out, im.channels());
  for (int c = 0; c < im.channels(); ++c) {
    cv::Mat src(n, n, CV_32F);
    double sum = 0;
    int64_t finite = 0;
    for (size_t p = 0; p < im.pixels(); ++p)
      if (std::isfinite(im.channel(c)[p])) sum += im.channel(c)[p], ++finite;
    const float mean = finite ? static_cast<float>(sum / finite) : 0.0f;
    for (size_t p = 0; p < im.pixels(); ++p) {
      const float v = im.channel(c)[p];
      src.ptr<float>()[p] = std::isfinite(v) ? v : mean;
    }
    cv::Mat spec, dst = cv::Mat::zeros(n_out, n_out, CV_32FC2), res;
    cv::dft(src, spec, cv::DFT_COMPLEX_OUTPUT);
    for (int ky = -half; ky <= half; ++ky)
      for (int kx = -half; kx <= half; ++kx)
        dst.at<cv::Vec2f>((ky + n_out) % n_out, (kx + n_out) % n_out) =
            spec.at<cv::Vec2f>((ky + n) % n, (kx + n) % n);
    cv::idft(dst, res, cv::DFT_REAL_OUTPUT | cv::DFT_SCALE);
    for (size_t p = 0; p < out.pixels(); ++p) out.channel(c)[p] = res.ptr<float>()[p] * scale;
  }
  return out;
}

// --size: the final surface resampled to N (MapsOptions::size_px).
void ResampleSurface(int n, FinalSurface* f) {
  HeightField& hf = f->field;
  const double p = hf.pixel_size;
  if (f->tile) {
    // Periodic: band-limited on the period; the physical size n_src * p kept.
    const int m = hf.width();
    const double p2 = m * p / n;
    HeightField r;
    r.pixel_size = p2;
    r.x0 = hf.x0 - 0.5 * p + 0.5 * p2;  // the square's corner stays where it was
    r.y0 = hf.y0 + 0.5 * p - 0.5 * p2;
    r.z = FourierResample(hf.z, n);
    if (!hf.confidence.empty()) {
      r.confidence = FourierResample(hf.confidence, n);
      for (float& v : r.confidence.data()) v = std::clamp(v, 0.0f, 1.0f);
    }
    if (!f->albedo.empty()) {
      f->albedo = FourierResample(f->albedo, n);
      for (float& v : f->albedo.data()) v = std::max(v, 0.0f);
    }
    if (!f->filled.empty()) {
      ImageU8 fl(n, n, 1, 0);
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x)
          fl(x, y) = f->filled(std::min(m - 1, static_cast<int>((x + 0.5) * m / n)),
                               std::min(m - 1, static_cast<int>((y + 0.5) * m / n)));
      f->filled = std::move(fl);
    }
    hf = std::move(r);
    return;
  }
  // Not periodic: the longest side N, the span of the pixel centres kept (export's resampling).
  const int longest = std::max(hf.width(), hf.height());
  const double p2 = (longest - 1) * p / (n - 1);
  const HeightField src = hf;
  hf = CropAndResample(src, PixelRect{}, p2);
  if (!f->albedo.empty()) f->albedo = CropAndResampleImage(f->albedo, src, PixelRect{}, p2);
  if (!f->filled.empty()) {
    ImageF fl(src.width(), src.height(), 1);
    for (size_t i = 0; i < fl.pixels(); ++i) fl.data()[i] = f->filled.data()[i];
    const ImageF r = CropAndResampleImage(fl, src, PixelRect{}, p2);
    f->filled = ImageU8(r.width(), r.height(), 1, 0);
    for (size_t i = 0; i < r.pixels(); ++i) f->filled.data()[i] = r.data()[i] > 0.5f;
  }
}

// Loud when the tile is doubtful: much of it invented by the fill, or off the sample.
void WarnAboutTile(const TileResult& t) {
  const int x = t.origin_x + t.src_x, y = t.origin_y + t.src_y;
  if (t.filled_fraction > kTileFilledWarnFraction)
    MESOSCAN_LOG(kWarning) << "maps: " << std::lround(100 * t.filled_fraction)
                           << "% of the tile's square at (" << x << ", " << y
                           << ") is filled (interpolated), above "
                           << std::lround(100 * kTileFilledWarnFraction)
                           << "%: its texture is partly invented; try a smaller tile, another "
                              "square or a finer fill";
  if (t.on_sample_fraction < kTileOnSampleWarnFraction)
    MESOSCAN_LOG(kWarning) << "maps: only " << std::lround(100 * t.on_sample_fraction)
                           << "% of the tile's square at (" << x << ", " << y
                           << ") stands off the mount: the tile shows bare mount; try a smaller "
                              "tile or another square";
}

// The height as written: holes (large, or outside the sample) at kHoleValue; the mask 255
// measured, 128 filled, 0 hole; the range and its 16-bit PNG encoding.
constexpr float kHoleValue = 0.0f;
struct HeightOut {
  ImageF z;
  ImageU8 mask;
  double zmin = 1e30, zmax = -1e30, span = 0, midlevel = 0;
};

HeightOut HeightAndMask(const FinalSurface& f) {
  HeightOut out;
  out.z = f.field.z;
  out.mask = ImageU8(f.field.width(), f.field.height(), 1, 255);
  for (size_t p = 0; p < out.z.pixels(); ++p) {
    if (!std::isfinite(out.z.data()[p]))
      out.z.data()[p] = kHoleValue, out.mask.data()[p] = 0;
    else if (f.filled.data()[p])
      out.mask.data()[p] = 128;
  }
  for (float v : out.z.data())
    out.zmin = std::min<double>(out.zmin, v), out.zmax = std::max<double>(out.zmax, v);
  out.span = std::max(out.zmax - out.zmin, 1e-9);
  out.midlevel = -out.zmin / out.span;
  return out;
}

// Normals, ambient occlusion and curvature of the final height (periodic for a tile).
struct DerivedMaps {
  ImageF normals, ao, curvature;
  ImageF nmap;              // the encoded normal map in the chosen convention
  double cavity_scale = 0;  // curvature of the 1st/99th percentile: the cavity map's scale
};

DerivedMaps Derive(const MapsOptions& o, const HeightField& field, bool periodic) {
  DerivedMaps d;
  tbb::task_group g;
  g.run([&] { d.normals = NormalsOf(field, periodic); });
  if (o.maps.ao) g.run([&] { d.ao = AmbientOcclusion(field, o.ao, periodic); });
  if (o.maps.curvature)
    g.run([&] { d.curvature = MeanCurvature(field, o.curvature_sigma_px, periodic); });
  g.wait();
  d.nmap = EncodeNormalMap(d.normals, o.normals);
  if (o.maps.curvature)
    d.cavity_scale =
        std::max(std::abs(Quantile(d.curvature, 0.01)), std::abs(Quantile(d.curvature, 0.99)));
  return d;
}

// Everything the files are written from; lives until the folder is written.
struct MapSet {
  MapSet(const MapsOptions& o, const HeightField& cropped, const FlattenResult& flat,
         const FinalSurface& surface, const HeightOut& height, const DerivedMaps& derived,
         std::string albedo_source, bool albedo_reflectance)
      : o(o),
        cropped(cropped),
        flat(flat),
        surface(surface),
        height(height),
        derived(derived),
        albedo_source(std::move(albedo_source)),
        albedo_reflectance(albedo_reflectance),
        periodic(o.tile),
        conv(o.normals == NormalConvention::kOpenGl ? "gl" : "dx"),
        grid_attrs({{kAttrX0, surface.field.x0},
                    {kAttrY0, surface.field.y0},
                    {kAttrPixelSize, surface.field.pixel_size}}),
        w(surface.field.width()),
        h(surface.field.height()),
        pixel_size(surface.field.pixel_size) {}
  const MapsOptions& o;
  const HeightField& cropped;  // the grid before tiling (the removed shape's)
  const FlattenResult& flat;
  const FinalSurface& surface;
  const HeightOut& height;
  const DerivedMaps& derived;
  std::string albedo_source;
  bool albedo_reflectance;
  bool periodic;     // a tile
  std::string conv;  // "gl" or "dx"
  std::map<std::string, double> grid_attrs;
  int w, h;
  double pixel_size;
};

// The files of the set: manifest entries, names and writers (run in parallel), in order.
struct MapFiles {
  Json entries = Json::array();
  std::vector<std::string> names;
  std::vector<std::function<void(const fs::path&)>> writers;
  void Add(const std::string& file, Json entry) {
    entry["file"] = file;
    entries.push_back(std::move(entry));
    names.push_back(file);
  }
};

void AddHeightFiles(const MapSet& m, MapFiles* files) {
  const std::string n = m.o.name;
  const HeightOut& ho = m.height;
  files->Add(n + "_height.exr",
             {{"role", "height"},
              {"format", "exr"},
              {"channels", {"Y"}},
              {"units", "m"},
              {"colour_space", "Non-Color"},
              {"midlevel", 0.0},
              {"scale", 1.0},
              {"meaning", m.o.flatten.method == FlattenMethod::kNone
                              ? "metres above the mount plane"
                              : "metres relative to the removed shape (NAME_height_removed.exr)"}});
  files->writers.push_back([&m, f = n + "_height.exr"](const fs::path& d) {
    auto attrs = m.grid_attrs;
    attrs["mesoscan:midlevel"] = 0.0, attrs["mesoscan:scale"] = 1.0,
    attrs["mesoscan:hole_value"] = kHoleValue;
    WriteExr(d / f, m.height.z, {"Y"}, attrs, {{"mesoscan:units", "m"}});
  });
  files->Add(n + "_height.png", {{"role", "height"},
                                 {"format", "png"},
                                 {"pixel_type", "uint16"},
                                 {"units", "m"},
                                 {"colour_space", "Non-Color"},
                                 {"midlevel", ho.midlevel},
                                 {"scale", ho.span},
                                 {"meaning", "metres = (value / 65535 - midlevel) * scale"}});
  files->writers.push_back([&m, f = n + "_height.png", fj = n + "_height.json"](const fs::path& d) {
    const HeightOut& ho = m.height;
    ImageU16 q(m.w, m.h, 1);
    for (size_t i = 0; i < q.pixels(); ++i)
      q.data()[i] = static_cast<uint16_t>(
          std::lround(std::clamp((ho.z.data()[i] - ho.zmin) / ho.span, 0.0, 1.0) * 65535));
    WritePng16(d / f, q, 1);
    WriteJsonFile(d / fj, {{"file", f},
                           {"units", "m"},
                           {"min_m", ho.zmin},
                           {"max_m", ho.zmax},
                           {"midlevel", ho.midlevel},
                           {"scale", ho.span},
                           {"decode", "metres = (value / 65535 - midlevel) * scale"}});
  });
  files->Add(n + "_height.json", {{"role", "height sidecar"}, {"format", "json"}});
  if (m.o.flatten.method == FlattenMethod::kNone) return;
  files->Add(n + "_height_removed.exr", {{"role", "height removed"},
                                         {"format", "exr"},
                                         {"channels", {"Y"}},
                                         {"units", "m"},
                                         {"meaning",
                                          "the low-frequency part flatten removed, on the source "
                                          "grid: height = flattened + removed"},
                                         {"grid",
                                          {{"width_px", m.flat.removed.width()},
                                           {"height_px", m.flat.removed.height()},
                                           {"x0_m", m.cropped.x0},
                                           {"y0_m", m.cropped.y0},
                                           {"pixel_size_m", m.cropped.pixel_size}}}});
  files->writers.push_back([&m, f = n + "_height_removed.exr"](const fs::path& d) {
    WriteExr(
        d / f, m.flat.removed, {"Y"},
        {{kAttrX0, m.cropped.x0}, {kAttrY0, m.cropped.y0}, {kAttrPixelSize, m.cropped.pixel_size}},
        {{"mesoscan:units", "m"}, {"mesoscan:flatten", FlattenName(m.o.flatten)}},
        // Uncompressed: the whole source grid (3 M samples at full resolution), where
        // ZIP costs ~1 s of CPU for a smooth map.
        "none");
  });
}

void AddNormalFiles(const MapSet& m, MapFiles* files) {
  const std::string n = m.o.name, conv = m.conv;
  const std::string conv_text = conv == "gl" ? "OpenGL (+Y up)" : "DirectX (-Y)";
  files->Add(n + "_normal_" + conv + ".png", {{"role", "normal"},
                                              {"format", "png"},
                                              {"pixel_type", "uint16"},
                                              {"convention", conv_text},
                                              {"colour_space", "Non-Color"},
                                              {"encoding", "rgb = 0.5 + 0.5 * n"}});
  files->writers.push_back([&m, f = n + "_normal_" + conv + ".png"](const fs::path& d) {
    WritePng16(d / f, QuantizeU16(m.derived.nmap), 1);
  });
  files->Add(n + "_normal_" + conv + ".exr", {{"role", "normal"},
                                              {"format", "exr"},
                                              {"convention", conv_text},
                                              {"colour_space", "Non-Color"},
                                              {"encoding", "rgb = 0.5 + 0.5 * n"}});
  files->writers.push_back([&m, f = n + "_normal_" + conv + ".exr"](const fs::path& d) {
    WriteExr(d / f, m.derived.nmap, {"R", "G", "B"}, m.grid_attrs);
  });
}

void AddAlbedoFile(const MapSet& m, MapFiles* files) {
  const std::string n = m.o.name;
  files->Add(n + "_albedo.png",
             {{"role", "albedo"},
              {"format", "png"},
              {"colour_space", "sRGB"},
              {"source", m.albedo_source},
              {"channels", m.surface.albedo.channels() == 3 ? "RGB" : "grey"},
              {"meaning", m.albedo_reflectance ? "reflectance per channel in [0, 1]"
                                               : "relative albedo, 99th percentile = 1"}});
  files->writers.push_back([&m, f = n + "_albedo.png"](const fs::path& d) {
    ImageF a = m.surface.albedo;
    for (float& v : a.data()) v = std::isfinite(v) ? v : 0.0f;
    WritePng8(d / f, QuantizeU8(a, true));
  });
  // The same values linear in float (the reflectance itself, not 8-bit sRGB).
  const bool rgb = m.surface.albedo.channels() == 3;
  files->Add(n + "_albedo.exr",
             {{"role", "albedo_linear"},
              {"format", "exr"},
              {"colour_space", "linear"},
              {"channels", rgb ? "R, G, B" : "Y"},
              {"meaning", m.albedo_reflectance ? "reflectance per channel in [0, 1]"
                                               : "relative albedo, 99th percentile = 1"}});
  files->writers.push_back([&m, rgb, f = n + "_albedo.exr"](const fs::path& d) {
    WriteExr(d / f, m.surface.albedo,
             rgb ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"Y"},
             m.grid_attrs);
  });
}

void AddConfidenceFiles(const MapSet& m, MapFiles* files) {
  const std::string n = m.o.name;
  files->Add(n + "_confidence.png",
             {{"role", "confidence"},
              {"format", "png"},
              {"colour_space", "Non-Color"},
              {"meaning", "confidence in [0, 1]; 0 at filled pixels and holes"}});
  files->writers.push_back([&m, f = n + "_confidence.png"](const fs::path& d) {
    const HeightField& field = m.surface.field;
    ImageF c = field.confidence.empty() ? ImageF(m.w, m.h, 1, 1.0f) : field.confidence;
    for (size_t i = 0; i < c.pixels(); ++i)
      if (m.height.mask.data()[i] != 255) c.data()[i] = 0.0f;
    WritePng8(d / f, QuantizeU8(c));
  });
  files->Add(n + "_mask.png",
             {{"role", "mask"},
              {"format", "png"},
              {"colour_space", "Non-Color"},
              {"meaning", "255 measured, 128 filled, 0 hole (height = hole_value_m)"}});
  files->writers.push_back(
      [&m, f = n + "_mask.png"](const fs::path& d) { WritePng8(d / f, m.height.mask); });
}

void AddAoFile(const MapSet& m, MapFiles* files) {
  const std::string n = m.o.name;
  files->Add(n + "_ao.png",
             {{"role", "ao"},
              {"format", "png"},
              {"colour_space", "Non-Color"},
              {"meaning", "ambient occlusion, 1 = unoccluded (horizon-based, radius " +
                              std::to_string(m.o.ao.radius_m * 1e3) + " mm)"}});
  files->writers.push_back([&m, f = n + "_ao.png"](const fs::path& d) {
    ImageF a = m.derived.ao;
    for (float& v : a.data()) v = std::isfinite(v) ? v : 1.0f;
    WritePng8(d / f, QuantizeU8(a));
  });
}

void AddCurvatureFiles(const MapSet& m, MapFiles* files) {
  const std::string n = m.o.name;
  files->Add(n + "_curvature.exr", {{"role", "curvature"},
                                    {"format", "exr"},
                                    {"units", "1/m"},
                                    {"meaning", "mean curvature, positive on bumps"}});
  files->writers.push_back([&m, f = n + "_curvature.exr"](const fs::path& d) {
    WriteExr(d / f, m.derived.curvature, {"Y"}, m.grid_attrs);
  });
  files->Add(n + "_cavity.png", {{"role", "cavity"},
                                 {"format", "png"},
                                 {"colour_space", "Non-Color"},
                                 {"meaning", "0.5 + 0.5 * curvature / scale_per_m, clamped"},
                                 {"scale_per_m", m.derived.cavity_scale}});
  files->writers.push_back([&m, f = n + "_cavity.png"](const fs::path& d) {
    const double cavity_scale = m.derived.cavity_scale;
    ImageF c(m.w, m.h, 1);
    for (size_t i = 0; i < c.pixels(); ++i) {
      const float k = m.derived.curvature.data()[i];
      c.data()[i] = std::isfinite(k) && cavity_scale > 0
                        ? static_cast<float>(0.5 + 0.5 * k / cavity_scale)
                        : 0.5f;
    }
    WritePng8(d / f, QuantizeU8(c));
  });
}

void AddRoughnessFile(const MapSet& m, MapFiles* files) {
  const std::string f = m.o.name + "_roughness.png";
  files->Add(f, {{"role", "roughness"},
                 {"format", "png"},
                 {"colour_space", "Non-Color"},
                 {"value", m.o.roughness},
                 {"meaning", "Principled BSDF roughness in [0, 1], uniform (as given)"}});
  files->writers.push_back([&m, f](const fs::path& d) {
    WritePng8(d / f, QuantizeU8(ImageF(m.w, m.h, 1, static_cast<float>(m.o.roughness))));
  });
}

// Every map side by side, with its label and its physical width.
ImageU8 MakeContactSheet(const MapSet& m) {
  std::vector<Panel> panels;
  std::vector<double> widths;
  const DerivedMaps& dm = m.derived;
  const double wm = m.w * m.pixel_size;
  auto range = [](const ImageF& im) {
    return std::make_pair(Quantile(im, 0.005), Quantile(im, 0.995));
  };
  if (m.periodic) {
    // Where the tile came from: the (unflattened) scan with the source square drawn in red.
    const TileResult& t = *m.surface.tile;
    const auto [sl, sh] = range(m.cropped.z);
    cv::Mat src = GreyPanel(m.cropped.z, sl, sh);
    const int thick =
        std::max(1, static_cast<int>(std::lround(1.5 * std::max(src.cols, src.rows) / 320.0)));
    cv::rectangle(src, cv::Rect(t.src_x, t.src_y, t.src_size, t.src_size), cv::Scalar(0, 0, 255),
                  thick);
    panels.push_back({"tile: " + std::to_string(std::lround(100 * t.on_sample_fraction)) +
                          "% on sample, " + std::to_string(std::lround(100 * t.filled_fraction)) +
                          "% filled",
                      src});
    widths.push_back(m.cropped.width() * m.cropped.pixel_size);
  }
  const auto [hl, hh] = range(m.surface.field.z);
  panels.push_back(
      {"height " + std::to_string(static_cast<int>(std::lround((hh - hl) * 1e6))) + " um p-p",
       GreyPanel(m.surface.field.z, hl, hh)});
  widths.push_back(wm);
  panels.push_back({"normal (" + m.conv + ")", RgbPanel(dm.nmap, false)});
  widths.push_back(wm);
  panels.push_back({"shaded", ShadePanel(dm.normals)});
  widths.push_back(wm);
  if (!m.surface.albedo.empty())
    panels.push_back({"albedo", RgbPanel(m.surface.albedo, true)}), widths.push_back(wm);
  if (m.o.maps.ao)
    panels.push_back({"ambient occlusion", GreyPanel(dm.ao, 0.0, 1.0)}), widths.push_back(wm);
  if (m.o.maps.curvature) {
    ImageF c = dm.curvature;
    panels.push_back({"curvature", GreyPanel(c, -dm.cavity_scale, dm.cavity_scale)});
    widths.push_back(wm);
  }
  {
    ImageF mask(m.w, m.h, 1);
    for (size_t i = 0; i < mask.pixels(); ++i) mask.data()[i] = m.height.mask.data()[i] / 255.0f;
    panels.push_back({"mask: measured/filled/hole", GreyPanel(mask, 0, 1)});
    widths.push_back(wm);
  }
  if (m.o.flatten.method != FlattenMethod::kNone) {
    const auto [rl, rh] = range(m.flat.removed);
    panels.push_back(
        {"removed " + std::to_string(static_cast<int>(std::lround((rh - rl) * 1e6))) + " um p-p",
         GreyPanel(m.flat.removed, rl, rh)});
    widths.push_back(m.flat.removed.width() * m.cropped.pixel_size);
  }
  if (m.periodic) {
    // 2 x 2 repeats of the shaded tile: a seam would show as a cross through the centre.
    cv::Mat s = ShadePanel(dm.normals), big;
    cv::repeat(s, 2, 2, big);
    panels.push_back({"shaded, tiled 2 x 2", big});
    widths.push_back(2 * wm);
  }
  return ContactSheet(panels, widths);
}

void AddContactSheet(const MapSet& m, MapFiles* files) {
  const std::string f = m.o.name + "_contact_sheet.png";
  files->Add(f, {{"role", "contact sheet"}, {"format", "png"}, {"colour_space", "sRGB"}});
  files->writers.push_back([&m, f](const fs::path& d) { WritePng8(d / f, MakeContactSheet(m)); });
}

// The tile's figures for the manifest, or null when the set is not a tile.
Json TileJson(const MapSet& m) {
  if (!m.periodic) return Json(nullptr);
  const TileResult& t = *m.surface.tile;
  return Json{
      {"size_m", m.w * m.pixel_size},
      {"requested_size_m", m.o.tile_options.size_m},
      {"method", TileMethodName(m.o.tile_options.method)},
      {"source_square_px", {t.src_x, t.src_y, t.src_size}},
      {"source_square_height_grid_px", {t.origin_x + t.src_x, t.origin_y + t.src_y, t.src_size}},
      {"source_chosen", t.chosen ? "on the sample" : "given"},
      {"mount_clearance_m", m.o.tile_options.mount_clearance_m},
      {"on_sample_fraction", t.on_sample_fraction},
      {"measured_on_sample_fraction", t.measured_on_sample_fraction},
      {"filled_fraction", t.filled_fraction},
      {"texture_rms_step_m", t.texture_rms_m},
      {"blend_shift_px", {t.shift_x, t.shift_y}},
      {"seam_gradient_ratio", {t.seams_after.ratio_x(), t.seams_after.ratio_y()}},
      {"seam_gradient_ratio_pooled", t.seams_after.pooled_ratio()},
      {"interior_column_row_spread", {t.seams_after.column_spread_x, t.seams_after.row_spread_y}},
      {"seam_gradient_ratio_untiled", {t.seams_before.ratio_x(), t.seams_before.ratio_y()}},
      {"seam_rms_m", {t.seams_after.seam_rms_x, t.seams_after.seam_rms_y}},
      {"interior_rms_m", {t.seams_after.interior_rms_x, t.seams_after.interior_rms_y}}};
}

Json MapsManifest(const Scan& scan, const MapSet& m, const FillResult& fill, Json files) {
  const MapsOptions& o = m.o;
  const std::string& n = o.name;
  const double p = m.pixel_size;
  const HeightField& field = m.surface.field;
  return {
      {"format", kMapsFormat},
      {"name", n},
      {"units", "m"},
      {"grid",
       {{"width_px", m.w},
        {"height_px", m.h},
        {"pixel_size_m", p},
        {"x0_m", field.x0},
        {"y0_m", field.y0},
        {"physical_size_m", {m.w * p, m.h * p}}}},
      {"tileable", m.periodic},
      {"tile", TileJson(m)},
      {"fill",
       {{"method", FillMethodName(o.fill.method)},
        {"max_hole_radius_m", o.fill.max_hole_radius_m},
        {"holes_filled", fill.holes_filled},
        {"pixels_filled", fill.filled_pixels},
        {"holes_left", fill.holes_left},
        {"pixels_left", fill.pixels_left}}},
      {"flatten",
       {{"method", FlattenName(o.flatten)},
        {"description", m.flat.description},
        {"coefficients", m.flat.coefficients}}},
      {"height",
       {{"min_m", m.height.zmin},
        {"max_m", m.height.zmax},
        {"hole_value_m", kHoleValue},
        {"blender", {{"midlevel", 0.0}, {"scale", 1.0}, {"file", n + "_height.exr"}}},
        {"png16", {{"midlevel", m.height.midlevel}, {"scale", m.height.span}}}}},
      {"normal_convention", m.conv},
      {"albedo", m.albedo_source},
      {"source_grid",
       {{"width_px", scan.height.width()},
        {"height_px", scan.height.height()},
        {"pixel_size_m", scan.height.pixel_size}}},
      {"crop_px", o.crop.whole() ? Json(nullptr) : Json{o.crop.x, o.crop.y, o.crop.w, o.crop.h}},
      {"files", std::move(files)}};
}

// The writers in parallel into a temporary folder, then the manifest; the folder replaces `dir`
// only if every file was written (the first error is thrown).
void WriteMapFolder(const fs::path& dir, const MapFiles& files, const Json& manifest) {
  WriteFolderAtomically(dir, [&](const fs::path& tmp) {
    tbb::task_group g;
    std::mutex err_mutex;
    std::optional<Error> err;
    for (auto& fn : files.writers)
      g.run([&, fn] {
        try {
          fn(tmp);
        } catch (const Error& e) {
          std::lock_guard<std::mutex> lock(err_mutex);
          if (!err) err = e;
        }
      });
    g.wait();
    if (err) throw *err;
    WriteJsonFile(tmp / "manifest.json", manifest);
  });
}

}  // namespace

MapsSummary BuildMapSet(const Scan& scan, const MapsOptions& o, const fs::path& dir) {
  o.Check();
  MapsSummary summary;
  StageTimer timer(&summary.seconds_per_stage);
  // 1. Crop.
  timer.Skip();
  const HeightField cropped = CropForMaps(scan.height, o.crop);
  timer.Stage("crop");
  // 2. Fill the holes bounded by surface.
  timer.Skip();
  FillResult fill = FillHoles(cropped, o.fill);
  timer.Stage("fill");
  // 3. Albedo with the projector's falloff divided out, filled like the height.
  timer.Skip();
  MapAlbedo albedo;
  if (o.maps.albedo) {
    albedo = ReadAlbedo(scan, o, fill);
    if (!albedo.image.empty()) FillAndNormalizeAlbedo(o, cropped, fill, &albedo);
  }
  timer.Stage("albedo");
  // 4. Flatten (filled pixels are left out of the fit).
  timer.Skip();
  std::string fit_region;
  const FlattenResult flat = Flatten(
      fill.field, FlattenFitMask(fill, o.tile_options.mount_clearance_m, &fit_region), o.flatten);
  summary.flatten = flat.description;
  timer.Stage("flatten");
  // 5. Tile.
  timer.Skip();
  FinalSurface surface = TileOrKeep(o, flat, albedo.image, fill);
  if (surface.tile) {
    summary.tile = surface.tile->BriefReport();
    summary.seams = surface.tile->seams_after;
    WarnAboutTile(*surface.tile);
  }
  timer.Stage("tile");
  const int native_w = surface.field.width(), native_h = surface.field.height();
  if (o.size_px > 0) {
    timer.Skip();
    ResampleSurface(o.size_px, &surface);
    timer.Stage("size");
  }
  const HeightOut height = HeightAndMask(surface);
  // 6. Derived maps on the final height (holes excluded, periodic for a tile).
  timer.Skip();
  const DerivedMaps derived = Derive(o, surface.field, o.tile);
  timer.Stage("derived");
  // 7. Files, in parallel, into a temporary folder; the manifest last.
  timer.Skip();
  const MapSet set(o, cropped, flat, surface, height, derived, albedo.source, albedo.reflectance);
  MapFiles files;
  if (o.maps.height) AddHeightFiles(set, &files);
  if (o.maps.normal) AddNormalFiles(set, &files);
  if (o.maps.albedo && !surface.albedo.empty()) AddAlbedoFile(set, &files);
  if (o.maps.confidence) AddConfidenceFiles(set, &files);
  if (o.maps.ao) AddAoFile(set, &files);
  if (o.roughness >= 0) AddRoughnessFile(set, &files);
  if (o.maps.curvature) AddCurvatureFiles(set, &files);
  if (o.contact_sheet) AddContactSheet(set, &files);
  Json manifest = MapsManifest(scan, set, fill, files.entries);
  if (!surface.albedo.empty()) manifest["albedo"] = albedo.info;
  if (o.flatten.method != FlattenMethod::kNone) manifest["flatten"]["fit_region"] = fit_region;
  manifest["size"] = o.size_px > 0
                         ? Json{{"size_px", o.size_px},
                                {"from_px", {native_w, native_h}},
                                {"method", surface.tile ? "Fourier series on the tile's period"
                                                        : "area average / bilinear"}}
                         : Json(nullptr);
  WriteMapFolder(dir, files, manifest);
  timer.Stage("write");
  for (const auto& f : files.names) summary.files.push_back(dir / f);
  summary.files.push_back(dir / "manifest.json");
  fill.field = HeightField();
  fill.filled = ImageU8();
  summary.fill = std::move(fill);
  summary.seconds = timer.Total();
  manifest["seconds"] = summary.seconds;
  summary.manifest = std::move(manifest);
  return summary;
}

}  // namespace mesoscan
