// mesoscan check PATH: validates a session folder (session-format.md) or a scan folder
// (scan-outputs.md) and prints a short summary. Bad input: the reader's one line, exit 3.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>

#include "app/commands.h"
#include "app/session_checks.h"
#include "calibration/rig_file.h"
#include "core/error.h"
#include "core/output_dir.h"
#include "core/scan_folder.h"
#include "session/session.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

std::string ResponseName(const Response& r) {
  switch (r.kind) {
    case Response::Kind::kSrgb:
      return "srgb";
    case Response::Kind::kGamma: {
      std::ostringstream oss;
      oss << "gamma " << r.gamma;
      return oss.str();
    }
    case Response::Kind::kLinear:
      break;
  }
  return "linear";
}

std::string SampleFormat(const ImageInfo& info) {
  std::ostringstream oss;
  if (info.is_float)
    oss << "float" << info.bits_per_sample;
  else
    oss << info.bits_per_sample << "-bit";
  oss << (info.channels == 1 ? " grey" : " " + std::to_string(info.channels) + " channels");
  return oss.str();
}

void CheckSession(const fs::path& path, bool quick, const std::string& rig_path) {
  Session s = ReadSession(path, /*check_frames=*/false);
  std::optional<RigFile> rig_file;
  if (!rig_path.empty()) {
    rig_file = ReadRigFile(rig_path);
    UseRigFile(*rig_file, &s);
  }
  const std::vector<ImageInfo> infos = CheckSessionFiles(s);
  if (!quick) CheckSessionLikeReconstruct(s);  // what reconstruct would refuse
  const Rig& rig = s.rig;
  std::ostringstream out;
  out << std::setprecision(6);
  out << "session: " << s.root.string() << "\n";
  if (!s.object.empty()) out << "object: " << s.object << "\n";
  if (!s.created.empty()) out << "created: " << s.created << "\n";
  if (rig_file) {
    out << "rig: " << rig_file->path.string() << " (sha256 " << rig_file->sha256.substr(0, 16)
        << "...)";
    if (rig_file->calibration.contains("warnings") && !rig_file->calibration["warnings"].empty())
      out << ", made with " << rig_file->calibration["warnings"].size()
          << " calibration warning(s)";
    out << "\n";
  }
  if (rig.uncalibrated)
    out << "calibration session: the rig holds device sizes only (input of `mesoscan calibrate`; "
           "reconstruct needs a calibrated rig)\n";
  out << "camera: " << rig.camera.width << "x" << rig.camera.height << ", fx " << rig.camera.K(0, 0)
      << " px, response " << ResponseName(rig.camera_response) << ", black level "
      << rig.black_level << (rig.camera.HasDistortion() ? ", distortion" : "") << "\n";
  out << "projector: " << rig.projector.width << "x" << rig.projector.height << ", fx "
      << rig.projector.K(0, 0) << " px, response " << ResponseName(rig.projector_response)
      << (rig.projector.HasDistortion() ? ", distortion" : "") << "\n";
  const Vec3d baseline =
      rig.projector.world_from_device.translation - rig.camera.world_from_device.translation;
  out << "baseline: " << baseline.norm() * 1000 << " mm\n";
  if (rig.lens_shifter)
    out << "lens shifter: axis " << rig.lens_shifter->axis << ", " << rig.lens_shifter->steps_per_px
        << " steps/px, range " << rig.lens_shifter->range_steps[0] << ".."
        << rig.lens_shifter->range_steps[1] << " steps\n";
  else
    out << "lens shifter: none\n";
  // Frame formats (all share the camera size; the reader checked it).
  std::string formats;
  for (const ImageInfo& info : infos) {
    const std::string f = SampleFormat(info);
    if (formats.find(f) == std::string::npos) formats += (formats.empty() ? "" : ", ") + f;
  }
  out << "frames: " << s.frames.size() << ", " << rig.camera.width << "x" << rig.camera.height
      << ", " << formats << "\n";
  out << MakeFramePlan(s.frames).Describe(rig);
  if (s.ground_truth) {
    out << "ground truth: yes (";
    if (!s.ground_truth->points.empty()) out << "points " << s.ground_truth->points;
    if (!s.ground_truth->points.empty() && !s.ground_truth->height.empty()) out << ", ";
    if (!s.ground_truth->height.empty()) out << "height " << s.ground_truth->height;
    out << ")\n";
  } else {
    out << "ground truth: no (optional: simulated sessions only)\n";
  }
  if (!s.extra.empty()) {
    out << "extra keys:";
    for (auto it = s.extra.begin(); it != s.extra.end(); ++it) out << " " << it.key();
    out << "\n";
  }
  out << "ok\n";
  std::cout << out.str() << std::flush;
}

// Count of finite values in a channel, and its range.
struct ChannelStats {
  size_t finite = 0;
  float lo = 0, hi = 0;
};
ChannelStats Stats(const ImageF& im, int c) {
  ChannelStats st;
  const float* p = im.channel(c);
  for (size_t i = 0; i < im.pixels(); ++i) {
    if (!std::isfinite(p[i])) continue;
    st.lo = st.finite ? std::min(st.lo, p[i]) : p[i];
    st.hi = st.finite ? std::max(st.hi, p[i]) : p[i];
    ++st.finite;
  }
  return st;
}

void CheckScan(const fs::path& dir, bool quick) {
  const Scan scan = ReadScanFolder(dir);
  if (!quick) CheckScanUsable(scan, dir);
  std::ostringstream out;
  out << std::setprecision(6);
  out << "scan: " << fs::absolute(dir).lexically_normal().string() << "\n";
  const ImageF& xyz = scan.points.xyz;
  const ChannelStats pz = Stats(xyz, 2);
  out << "points.exr: " << xyz.width() << "x" << xyz.height() << ", " << pz.finite << " of "
      << xyz.pixels() << " pixels reconstructed ("
      << (xyz.pixels() ? 100.0 * pz.finite / xyz.pixels() : 0.0) << "%)\n";
  const HeightField& hf = scan.height;
  const ChannelStats hz = Stats(hf.z, 0);
  out << "height.exr: " << hf.width() << "x" << hf.height() << ", pixel " << hf.pixel_size * 1e6
      << " um, x0 " << hf.x0 << " m, y0 " << hf.y0 << " m, " << hz.finite << " of " << hf.z.pixels()
      << " known";
  if (hz.finite) out << ", z " << hz.lo * 1e3 << ".." << hz.hi * 1e3 << " mm";
  out << "\n";
  out << "normal.exr: " << scan.normals.width() << "x" << scan.normals.height();
  if (scan.normals.width() != hf.width() || scan.normals.height() != hf.height())
    MESOSCAN_BAD_INPUT((dir / "normal.exr").string()
                       << ": size " << scan.normals.width() << "x" << scan.normals.height()
                       << ", expected " << hf.width() << "x" << hf.height() << " (height.exr)");
  out << "\n";
  if (fs::exists(dir / "report.json")) {
    out << "report.json:";
    for (auto it = scan.report.begin(); it != scan.report.end(); ++it) out << " " << it.key();
    out << "\n";
  } else {
    out << "report.json: missing\n";
  }
  std::string exports;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (name == "points.exr" || name == "height.exr" || name == "normal.exr" ||
        name == "report.json")
      continue;
    exports += (exports.empty() ? "" : ", ") + name;
  }
  out << "other files: " << (exports.empty() ? "none (exports are optional)" : exports) << "\n";
  out << "ok\n";
  std::cout << out.str() << std::flush;
}

}  // namespace

void AddCheckCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "check", "Validate a session folder (session.json) or a scan folder (points.exr ...)");
  auto path = std::make_shared<std::string>();
  auto quick = std::make_shared<bool>(false);
  auto rig = std::make_shared<std::string>();
  cmd->add_option("path", *path, "Session folder, its session.json, or a scan folder")->required();
  cmd->add_option("--rig", *rig,
                  "Rig file (`mesoscan calibrate --out`) to check the session with, as "
                  "`reconstruct --rig` would use it");
  cmd->add_flag("--quick", *quick,
                "Headers only (no frame decoding, no reconstruction test on a small window)");
  cmd->callback([path, quick, rig] {
    const fs::path p(*path);
    RestoreInterruptedReplacement(p);  // core/output_dir.h: a replacement killed half-way
    std::error_code ec;
    if (fs::is_regular_file(p, ec) || fs::exists(p / "session.json", ec)) {
      CheckSession(p, *quick, *rig);
    } else if (fs::exists(p / "points.exr", ec) || fs::exists(p / "height.exr", ec)) {
      if (!rig->empty())
        MESOSCAN_THROW(ErrorKind::kUsage, "--rig applies to a session, not to a scan folder");
      CheckScan(p, *quick);
    } else if (!fs::exists(p, ec)) {
      MESOSCAN_BAD_INPUT(p.string() << ": not found, expected a session or scan folder");
    } else {
      MESOSCAN_BAD_INPUT(p.string() << ": expected a session folder (session.json) or a scan "
                                       "folder (points.exr, height.exr)");
    }
  });
}

}  // namespace mesoscan
