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

// A single-channel image as a HeightField on the grid of `g` (for FillHoles on other maps).
HeightField AsField(const ImageF& im, int c, const HeightField& g) {
  HeightField f;
  f.z = ImageF(im.width(), im.height(), 1);
  std::copy(im.channel(c), im.channel(c) + im.pixels(), f.z.channel(0));
  f.x0 = g.x0, f.y0 = g.y0, f.pixel_size = g.pixel_size;
  return f;
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

MapsSummary BuildMapSet(const Scan& scan, const MapsOptions& o, const fs::path& dir) {
  o.Check();
  MapsSummary summary;
  StageTimer timer(&summary.seconds_per_stage);
  if (scan.height.width() < 2 || scan.height.height() < 2)
    MESOSCAN_BAD_INPUT("height.exr: the height grid is " << scan.height.width() << "x"
                                                         << scan.height.height()
                                                         << ", too small for maps");
  // 1. Crop.
  timer.Skip();
  const HeightField cropped = CropAndResample(scan.height, o.crop, 0.0);
  {
    int64_t valid = 0;
    for (float v : cropped.z.data()) valid += std::isfinite(v);
    if (valid == 0) MESOSCAN_BAD_INPUT("height.exr: no valid height sample in the map region");
  }
  timer.Stage("crop");
  // 2. Fill.
  timer.Skip();
  FillResult fill = FillHoles(cropped, o.fill);
  timer.Stage("fill");
  const HeightField& filled_field = fill.field;
  // 3. Albedo with the projector's falloff divided out.
  timer.Skip();
  ImageF albedo;
  std::string albedo_source = "none";
  if (o.maps.albedo) {
    if (!o.albedo.empty()) {
      if (o.albedo.width() != scan.height.width() || o.albedo.height() != scan.height.height())
        MESOSCAN_BAD_INPUT("maps: albedo: expected the " << scan.height.width() << "x"
                                                         << scan.height.height() << " height grid");
      albedo = CropAndResampleImage(o.albedo, scan.height, o.crop, 0.0);
      albedo_source = "given on the height grid (no falloff correction)";
    } else if (o.albedo_from_session) {
      const std::string session = SessionPathFromReport(scan.report);
      if (!session.empty() && fs::is_directory(session)) {
        try {
          const Session s = ReadSession(session, /*check_frames=*/false);
          albedo = AlbedoFromSession(filled_field, session);
          const ImageF e = ProjectorIrradiance(filled_field, NormalsOf(filled_field, false),
                                               s.rig.projector.CentreInWorld());
          for (int c = 0; c < albedo.channels(); ++c)
            for (size_t p = 0; p < albedo.pixels(); ++p) {
              float& a = albedo.channel(c)[p];
              a = fill.filled.data()[p] || !(e.data()[p] > 0.05f) ? kNan : a / e.data()[p];
            }
          albedo_source = "white frame of session " + session +
                          " divided by the projector's falloff cos(i)/r^2 (median 1)";
        } catch (const Error& e) {
          MESOSCAN_LOG(kWarning) << "maps: no albedo (" << e.what() << ")";
          albedo = ImageF();
        }
      }
    }
    if (!albedo.empty()) {
      // Filled pixels get the albedo filled the same way (harmonic from the border).
      FillOptions fo = o.fill;
      if (fo.method == FillMethod::kNone) fo.method = FillMethod::kHarmonic;
      for (int c = 0; c < albedo.channels(); ++c) {
        HeightField f = AsField(albedo, c, filled_field);
        for (size_t p = 0; p < f.z.pixels(); ++p)
          if (!fill.filled.data()[p] && !std::isfinite(cropped.z.data()[p])) f.z.data()[p] = 0.0f;
        const FillResult fr = FillHoles(f, fo);
        for (size_t p = 0; p < f.z.pixels(); ++p)
          albedo.channel(c)[p] = std::isfinite(cropped.z.data()[p]) || fill.filled.data()[p]
                                     ? fr.field.z.data()[p]
                                     : kNan;
      }
      const double q99 = Quantile(albedo, 0.99);
      const float scale = q99 > 0 ? static_cast<float>(1.0 / q99) : 1.0f;
      for (float& v : albedo.data()) v = std::isfinite(v) ? std::max(0.0f, v * scale) : kNan;
    }
  }
  timer.Stage("albedo");
  // 4. Flatten (filled pixels are left out of the fit).
  timer.Skip();
  ImageU8 fit_mask(fill.filled.width(), fill.filled.height(), 1, 1);
  for (size_t p = 0; p < fit_mask.pixels(); ++p) fit_mask.data()[p] = fill.filled.data()[p] ? 0 : 1;
  FlattenResult flat = Flatten(filled_field, fit_mask, o.flatten);
  summary.flatten = flat.description;
  timer.Stage("flatten");
  // 5. Tile.
  timer.Skip();
  HeightField final_field;
  ImageF final_albedo;
  ImageU8 final_filled;
  std::optional<TileResult> tile;
  if (o.tile) {
    tile = MakeTile(flat.field, albedo, fill.filled, o.tile_options);
    final_field = tile->field;
    final_albedo = tile->albedo;
    final_filled = tile->filled;
    summary.tile = tile->BriefReport();
    summary.seams = tile->seams_after;
  } else {
    final_field = flat.field;
    final_albedo = albedo;
    final_filled = fill.filled;
  }
  timer.Stage("tile");
  const bool periodic = o.tile;
  const int w = final_field.width(), h = final_field.height();
  // Holes left (large, or outside the sample): hole_value in the maps, 0 in the mask.
  const float hole_value = 0.0f;
  ImageF zout = final_field.z;
  ImageU8 mask(w, h, 1, 255);
  for (size_t p = 0; p < zout.pixels(); ++p) {
    if (!std::isfinite(zout.data()[p]))
      zout.data()[p] = hole_value, mask.data()[p] = 0;
    else if (final_filled.data()[p])
      mask.data()[p] = 128;
  }
  // 6. Derived maps on the final height (holes excluded, periodic for a tile).
  timer.Skip();
  ImageF normals, ao, curvature;
  {
    tbb::task_group g;
    g.run([&] { normals = NormalsOf(final_field, periodic); });
    if (o.maps.ao) g.run([&] { ao = AmbientOcclusion(final_field, o.ao, periodic); });
    if (o.maps.curvature)
      g.run([&] { curvature = MeanCurvature(final_field, o.curvature_sigma_px, periodic); });
    g.wait();
  }
  timer.Stage("derived");

  // 7. Files, in parallel, into a temporary folder.
  timer.Skip();
  const std::string n = o.name;
  const std::string conv = o.normals == NormalConvention::kOpenGl ? "gl" : "dx";
  const double p = final_field.pixel_size;
  const std::map<std::string, double> grid_attrs = {
      {kAttrX0, final_field.x0}, {kAttrY0, final_field.y0}, {kAttrPixelSize, p}};
  double zmin = 1e30, zmax = -1e30;
  for (float v : zout.data()) zmin = std::min<double>(zmin, v), zmax = std::max<double>(zmax, v);
  const double span = std::max(zmax - zmin, 1e-9), midlevel = -zmin / span;
  Json files = Json::array();
  std::vector<std::string> names;
  auto add = [&](const std::string& file, Json entry) {
    entry["file"] = file;
    files.push_back(std::move(entry));
    names.push_back(file);
  };
  const ImageF nmap = EncodeNormalMap(normals, o.normals);
  double cavity_scale = 0;
  if (o.maps.curvature)
    cavity_scale =
        std::max(std::abs(Quantile(curvature, 0.01)), std::abs(Quantile(curvature, 0.99)));
  std::vector<std::function<void(const fs::path&)>> writers;
  if (o.maps.height) {
    add(n + "_height.exr",
        {{"role", "height"},
         {"format", "exr"},
         {"channels", {"Y"}},
         {"units", "m"},
         {"colour_space", "Non-Color"},
         {"midlevel", 0.0},
         {"scale", 1.0},
         {"meaning", o.flatten.method == FlattenMethod::kNone
                         ? "metres above the mount plane"
                         : "metres relative to the removed shape (NAME_height_removed.exr)"}});
    writers.push_back([&, f = n + "_height.exr"](const fs::path& d) {
      auto attrs = grid_attrs;
      attrs["mesoscan:midlevel"] = 0.0, attrs["mesoscan:scale"] = 1.0,
      attrs["mesoscan:hole_value"] = hole_value;
      WriteExr(d / f, zout, {"Y"}, attrs, {{"mesoscan:units", "m"}});
    });
    add(n + "_height.png", {{"role", "height"},
                            {"format", "png"},
                            {"pixel_type", "uint16"},
                            {"units", "m"},
                            {"colour_space", "Non-Color"},
                            {"midlevel", midlevel},
                            {"scale", span},
                            {"meaning", "metres = (value / 65535 - midlevel) * scale"}});
    writers.push_back([&, f = n + "_height.png", fj = n + "_height.json"](const fs::path& d) {
      ImageU16 q(w, h, 1);
      for (size_t i = 0; i < q.pixels(); ++i)
        q.data()[i] = static_cast<uint16_t>(
            std::lround(std::clamp((zout.data()[i] - zmin) / span, 0.0, 1.0) * 65535));
      WritePng16(d / f, q, 1);
      WriteJsonFile(d / fj, {{"file", f},
                             {"units", "m"},
                             {"min_m", zmin},
                             {"max_m", zmax},
                             {"midlevel", midlevel},
                             {"scale", span},
                             {"decode", "metres = (value / 65535 - midlevel) * scale"}});
    });
    add(n + "_height.json", {{"role", "height sidecar"}, {"format", "json"}});
    if (o.flatten.method != FlattenMethod::kNone) {
      add(n + "_height_removed.exr", {{"role", "height removed"},
                                      {"format", "exr"},
                                      {"channels", {"Y"}},
                                      {"units", "m"},
                                      {"meaning",
                                       "the low-frequency part flatten removed, on the source "
                                       "grid: height = flattened + removed"},
                                      {"grid",
                                       {{"width_px", flat.removed.width()},
                                        {"height_px", flat.removed.height()},
                                        {"x0_m", cropped.x0},
                                        {"y0_m", cropped.y0},
                                        {"pixel_size_m", cropped.pixel_size}}}});
      writers.push_back([&, f = n + "_height_removed.exr"](const fs::path& d) {
        WriteExr(
            d / f, flat.removed, {"Y"},
            {{kAttrX0, cropped.x0}, {kAttrY0, cropped.y0}, {kAttrPixelSize, cropped.pixel_size}},
            {{"mesoscan:units", "m"}, {"mesoscan:flatten", FlattenName(o.flatten)}},
            // Uncompressed: the whole source grid (3 M samples at full resolution), where
            // ZIP costs ~1 s of CPU for a smooth map.
            "none");
      });
    }
  }
  if (o.maps.normal) {
    const std::string conv_text = conv == "gl" ? "OpenGL (+Y up)" : "DirectX (-Y)";
    add(n + "_normal_" + conv + ".png", {{"role", "normal"},
                                         {"format", "png"},
                                         {"pixel_type", "uint16"},
                                         {"convention", conv_text},
                                         {"colour_space", "Non-Color"},
                                         {"encoding", "rgb = 0.5 + 0.5 * n"}});
    writers.push_back([&, f = n + "_normal_" + conv + ".png"](const fs::path& d) {
      WritePng16(d / f, QuantizeU16(nmap), 1);
    });
    add(n + "_normal_" + conv + ".exr", {{"role", "normal"},
                                         {"format", "exr"},
                                         {"convention", conv_text},
                                         {"colour_space", "Non-Color"},
                                         {"encoding", "rgb = 0.5 + 0.5 * n"}});
    writers.push_back([&, f = n + "_normal_" + conv + ".exr"](const fs::path& d) {
      WriteExr(d / f, nmap, {"R", "G", "B"}, grid_attrs);
    });
  }
  if (o.maps.albedo && !final_albedo.empty()) {
    add(n + "_albedo.png", {{"role", "albedo"},
                            {"format", "png"},
                            {"colour_space", "sRGB"},
                            {"source", albedo_source},
                            {"meaning", "relative albedo, 99th percentile = 1"}});
    writers.push_back([&, f = n + "_albedo.png"](const fs::path& d) {
      ImageF a = final_albedo;
      for (float& v : a.data()) v = std::isfinite(v) ? v : 0.0f;
      WritePng8(d / f, QuantizeU8(a, true));
    });
  }
  if (o.maps.confidence) {
    add(n + "_confidence.png", {{"role", "confidence"},
                                {"format", "png"},
                                {"colour_space", "Non-Color"},
                                {"meaning", "confidence in [0, 1]; 0 at filled pixels and holes"}});
    writers.push_back([&, f = n + "_confidence.png"](const fs::path& d) {
      ImageF c = final_field.confidence.empty() ? ImageF(w, h, 1, 1.0f) : final_field.confidence;
      for (size_t i = 0; i < c.pixels(); ++i)
        if (mask.data()[i] != 255) c.data()[i] = 0.0f;
      WritePng8(d / f, QuantizeU8(c));
    });
    add(n + "_mask.png", {{"role", "mask"},
                          {"format", "png"},
                          {"colour_space", "Non-Color"},
                          {"meaning", "255 measured, 128 filled, 0 hole (height = hole_value_m)"}});
    writers.push_back([&, f = n + "_mask.png"](const fs::path& d) { WritePng8(d / f, mask); });
  }
  if (o.maps.ao) {
    add(n + "_ao.png", {{"role", "ao"},
                        {"format", "png"},
                        {"colour_space", "Non-Color"},
                        {"meaning", "ambient occlusion, 1 = unoccluded (horizon-based, radius " +
                                        std::to_string(o.ao.radius_m * 1e3) + " mm)"}});
    writers.push_back([&, f = n + "_ao.png"](const fs::path& d) {
      ImageF a = ao;
      for (float& v : a.data()) v = std::isfinite(v) ? v : 1.0f;
      WritePng8(d / f, QuantizeU8(a));
    });
  }
  if (o.maps.curvature) {
    add(n + "_curvature.exr", {{"role", "curvature"},
                               {"format", "exr"},
                               {"units", "1/m"},
                               {"meaning", "mean curvature, positive on bumps"}});
    writers.push_back([&, f = n + "_curvature.exr"](const fs::path& d) {
      WriteExr(d / f, curvature, {"Y"}, grid_attrs);
    });
    add(n + "_cavity.png", {{"role", "cavity"},
                            {"format", "png"},
                            {"colour_space", "Non-Color"},
                            {"meaning", "0.5 + 0.5 * curvature / scale_per_m, clamped"},
                            {"scale_per_m", cavity_scale}});
    writers.push_back([&, f = n + "_cavity.png"](const fs::path& d) {
      ImageF c(w, h, 1);
      for (size_t i = 0; i < c.pixels(); ++i) {
        const float k = curvature.data()[i];
        c.data()[i] = std::isfinite(k) && cavity_scale > 0
                          ? static_cast<float>(0.5 + 0.5 * k / cavity_scale)
                          : 0.5f;
      }
      WritePng8(d / f, QuantizeU8(c));
    });
  }
  // The contact sheet.
  if (o.contact_sheet) {
    add(n + "_contact_sheet.png",
        {{"role", "contact sheet"}, {"format", "png"}, {"colour_space", "sRGB"}});
    writers.push_back([&, f = n + "_contact_sheet.png"](const fs::path& d) {
      std::vector<Panel> panels;
      std::vector<double> widths;
      const double wm = w * p;
      auto range = [](const ImageF& im) {
        return std::make_pair(Quantile(im, 0.005), Quantile(im, 0.995));
      };
      const auto [hl, hh] = range(final_field.z);
      panels.push_back(
          {"height " + std::to_string(static_cast<int>(std::lround((hh - hl) * 1e6))) + " um p-p",
           GreyPanel(final_field.z, hl, hh)});
      widths.push_back(wm);
      panels.push_back({"normal (" + conv + ")", RgbPanel(nmap, false)});
      widths.push_back(wm);
      panels.push_back({"shaded", ShadePanel(normals)});
      widths.push_back(wm);
      if (!final_albedo.empty())
        panels.push_back({"albedo", RgbPanel(final_albedo, true)}), widths.push_back(wm);
      if (o.maps.ao)
        panels.push_back({"ambient occlusion", GreyPanel(ao, 0.0, 1.0)}), widths.push_back(wm);
      if (o.maps.curvature) {
        ImageF c = curvature;
        panels.push_back({"curvature", GreyPanel(c, -cavity_scale, cavity_scale)});
        widths.push_back(wm);
      }
      {
        ImageF m(w, h, 1);
        for (size_t i = 0; i < m.pixels(); ++i) m.data()[i] = mask.data()[i] / 255.0f;
        panels.push_back({"mask: measured/filled/hole", GreyPanel(m, 0, 1)});
        widths.push_back(wm);
      }
      if (o.flatten.method != FlattenMethod::kNone) {
        const auto [rl, rh] = range(flat.removed);
        panels.push_back({"removed " +
                              std::to_string(static_cast<int>(std::lround((rh - rl) * 1e6))) +
                              " um p-p",
                          GreyPanel(flat.removed, rl, rh)});
        widths.push_back(flat.removed.width() * cropped.pixel_size);
      }
      if (periodic) {
        // 2 x 2 repeats of the shaded tile: a seam would show as a cross through the centre.
        cv::Mat s = ShadePanel(normals), big;
        cv::repeat(s, 2, 2, big);
        panels.push_back({"shaded, tiled 2 x 2", big});
        widths.push_back(2 * wm);
      }
      WritePng8(d / f, ContactSheet(panels, widths));
    });
  }
  // The manifest.
  Json manifest = {
      {"format", kMapsFormat},
      {"name", n},
      {"units", "m"},
      {"grid",
       {{"width_px", w},
        {"height_px", h},
        {"pixel_size_m", p},
        {"x0_m", final_field.x0},
        {"y0_m", final_field.y0},
        {"physical_size_m", {w * p, h * p}}}},
      {"tileable", periodic},
      {"tile",
       periodic ? Json{{"size_m", w * p},
                       {"requested_size_m", o.tile_options.size_m},
                       {"method", TileMethodName(o.tile_options.method)},
                       {"source_square_px", {tile->src_x, tile->src_y, tile->src_size}},
                       {"blend_shift_px", {tile->shift_x, tile->shift_y}},
                       {"seam_gradient_ratio",
                        {tile->seams_after.ratio_x(), tile->seams_after.ratio_y()}},
                       {"seam_gradient_ratio_pooled", tile->seams_after.pooled_ratio()},
                       {"interior_column_row_spread",
                        {tile->seams_after.column_spread_x, tile->seams_after.row_spread_y}},
                       {"seam_gradient_ratio_untiled",
                        {tile->seams_before.ratio_x(), tile->seams_before.ratio_y()}},
                       {"seam_rms_m", {tile->seams_after.seam_rms_x, tile->seams_after.seam_rms_y}},
                       {"interior_rms_m",
                        {tile->seams_after.interior_rms_x, tile->seams_after.interior_rms_y}}}
                : Json(nullptr)},
      {"fill",
       {{"method", FillMethodName(o.fill.method)},
        {"max_hole_radius_m", o.fill.max_hole_radius_m},
        {"holes_filled", fill.holes_filled},
        {"pixels_filled", fill.filled_pixels},
        {"holes_left", fill.holes_left},
        {"pixels_left", fill.pixels_left}}},
      {"flatten",
       {{"method", FlattenName(o.flatten)},
        {"description", flat.description},
        {"coefficients", flat.coefficients}}},
      {"height",
       {{"min_m", zmin},
        {"max_m", zmax},
        {"hole_value_m", hole_value},
        {"blender", {{"midlevel", 0.0}, {"scale", 1.0}, {"file", n + "_height.exr"}}},
        {"png16", {{"midlevel", midlevel}, {"scale", span}}}}},
      {"normal_convention", conv},
      {"albedo", albedo_source},
      {"source_grid",
       {{"width_px", scan.height.width()},
        {"height_px", scan.height.height()},
        {"pixel_size_m", scan.height.pixel_size}}},
      {"crop_px", o.crop.whole() ? Json(nullptr) : Json{o.crop.x, o.crop.y, o.crop.w, o.crop.h}},
      {"files", files}};
  WriteFolderAtomically(dir, [&](const fs::path& tmp) {
    tbb::task_group g;
    std::mutex err_mutex;
    std::optional<Error> err;
    for (auto& fn : writers)
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
  timer.Stage("write");
  for (const auto& f : names) summary.files.push_back(dir / f);
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
