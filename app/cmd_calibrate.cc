// mesoscan calibrate SESSION... --board checker:COLSxROWS:SQUARE_MM | charuco:COLSxROWS:SQUARE_MM:
// MARKER_MM:DICT --out RIG.json: the rig from calibration sessions of a printed board
// (calibration/calibrate.h).

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "app/commands.h"
#include "calibration/calibrate.h"
#include "calibration/calibrate_mount.h"
#include "calibration/calibrate_shifter.h"
#include "core/error.h"
#include "core/json.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "session/session.h"

namespace fs = std::filesystem;

namespace mesoscan {
namespace {

struct CalibrateArgs {
  std::vector<std::string> sessions;
  std::string board, out, mount, shifter, report, fix, model = "auto";
  int window = 20;
  bool force = false, fix_principal_point = false, strict = false;
};

Json RigJson(const Rig& rig) {
  Session s;
  s.rig = rig;
  return SessionToJson(s)["rig"];
}

// An earlier output of `mesoscan calibrate --out`: a JSON object whose only key is "rig".
bool IsRigFile(const fs::path& path) {
  try {
    const Json j = ReadJsonFile(path);
    return j.is_object() && j.size() == 1 && j.contains("rig") && j["rig"].is_object();
  } catch (const Error&) {
    return false;
  }
}

// The report folder's files (an earlier report written before the output marker existed).
const std::vector<std::string> kReportFiles = {"report.json", "residuals_camera.png",
                                               "coverage_camera.png"};

// --out and --report checked as every command's outputs (core/output_dir.h) before any work:
// neither may be, contain or lie in an input session; an existing --out is replaced only if it
// is an earlier rig file, an existing --report folder only if it is an earlier report (or
// --force); and neither may lie inside the other.
struct CalibrateOutputs {
  OutputSpec rig, report;
};

CalibrateOutputs CheckCalibrateOutputs(const CalibrateArgs& a) {
  std::vector<fs::path> inputs(a.sessions.begin(), a.sessions.end());
  inputs.push_back(a.mount);
  inputs.push_back(a.shifter);
  CalibrateOutputs o;
  o.rig = {"calibrate", "--out", a.out, inputs, a.force, {}};
  o.report = {"calibrate", "--report", a.report, inputs, a.force, kReportFiles};
  const fs::path rig = CheckOutputFile(o.rig, IsRigFile);
  if (!a.report.empty()) {
    const fs::path report = CheckOutputFolder(o.report);
    if (PathIsWithin(rig, report))  // the report folder is replaced as a whole
      MESOSCAN_THROW(ErrorKind::kUsage, "calibrate: --out " << a.out << ": lies inside --report "
                                                            << a.report
                                                            << "; choose a file outside it");
  }
  return o;
}

void Run(const CalibrateArgs& a) {
  CalibrateOptions opt;
  opt.board = CalibrationBoard::Parse(a.board, "CalibrateOptions.board");
  opt.ParseFix(a.fix);
  opt.ParseModel(a.model);
  opt.fix_principal_point = a.fix_principal_point;
  opt.homography_half_window_px = a.window;
  opt.Check();
  if (a.sessions.size() < 3)
    MESOSCAN_THROW(ErrorKind::kUsage, "calibrate: " << a.sessions.size()
                                                    << " sessions given, expected at least 3 "
                                                       "board poses (8 or more recommended)");
  const CalibrateOutputs outputs = CheckCalibrateOutputs(a);
  std::vector<CalibrationView> views;
  std::optional<Rig> size_rig;
  for (size_t i = 0; i < a.sessions.size(); ++i) {
    const Session s = ReadSession(a.sessions[i]);
    if (size_rig && (s.rig.camera.width != size_rig->camera.width ||
                     s.rig.camera.height != size_rig->camera.height ||
                     s.rig.projector.width != size_rig->projector.width ||
                     s.rig.projector.height != size_rig->projector.height))
      MESOSCAN_BAD_INPUT(a.sessions[i] << "/session.json: rig: device sizes differ from "
                                       << a.sessions[0] << "'s, expected one rig");
    if (!size_rig) size_rig = s.rig;
    CalibrationView v = DetectView(s, opt);
    if (!v.found) MESOSCAN_LOG(kWarning) << a.sessions[i] << ": skipped: " << v.problem;
    MESOSCAN_LOG(kInfo) << "view " << i + 1 << "/" << a.sessions.size() << " " << a.sessions[i]
                        << (v.found ? ": board found" : ": no board") << " (" << v.decode_seconds
                        << " s)";
    views.push_back(std::move(v));
  }
  // --mount: a board lying on the mount (its board defines the world, in the adjustment) or the
  // empty mount (a plane fitted to its points once the rig is calibrated). Which one: a session
  // with sines along both axes is searched for the board first.
  std::optional<CalibrationView> mount;
  std::optional<Session> mount_session;
  if (!a.mount.empty()) {
    mount_session = ReadSession(a.mount);
    if (HasBoardPatterns(*mount_session)) {
      CalibrationView v = DetectView(*mount_session, opt);
      if (v.found) {
        MESOSCAN_LOG(kInfo) << "mount " << a.mount << ": a board on the mount";
        mount = std::move(v);
      }
    }
    if (!mount)
      MESOSCAN_LOG(kInfo) << "mount " << a.mount
                          << ": no board: the empty mount (a plane through its points)";
  }
  CalibrationResult result = Calibrate(std::move(views), *size_rig, mount, opt);
  Json extra{{"board", opt.board.ToString()}, {"rig_file", a.out}};
  std::vector<std::string> lines;
  // The empty mount: scanned with the calibrated rig (world: the first board), plane fitted.
  std::optional<FlatTargetScan> mount_scan;
  Rig mount_scan_rig;
  if (mount_session && !mount) {
    mount_scan_rig = result.rig;
    mount_scan = ScanFlatTarget(*mount_session, mount_scan_rig);
    MountPlane plane = FitMountPlane(*mount_scan, mount_scan_rig, MountPlaneOptions());
    plane.session = a.mount;
    result.rig = RigOnMount(result.rig, plane);
    result.world = "empty mount " + a.mount;
    Json mj = plane.ToJson();
    mj["kind"] = "empty mount";
    // The plane in the first board's world: how the mount lies relative to that board.
    mj["tilt_from_first_board_deg"] =
        std::acos(std::clamp(plane.normal.z(), -1.0, 1.0)) * 180.0 / 3.14159265358979323846;
    extra["mount"] = mj;
    std::ostringstream o;
    o << "mount plane: " << plane.inliers << " of " << plane.points << " points, RMS "
      << plane.rms_m * 1e6 << " um, tilt +- "
      << plane.normal_sigma_rad * 180 / 3.14159265358979323846 << " deg, offset +- "
      << plane.offset_sigma_m * 1e6 << " um (" << mount_scan->seconds + plane.seconds << " s)";
    lines.push_back(o.str());
    const std::string warning = MountFlatnessWarning(plane);
    if (!warning.empty()) result.warnings.push_back(warning);
  } else if (mount) {
    extra["mount"] = {{"kind", "board on the mount"}, {"session", a.mount}};
  }
  // The lens shifter: from --shifter, else from the mount session's lens-shift frames.
  std::optional<ShifterCalibration> shifter_cal;
  std::string shifter_path = a.shifter;
  if (shifter_path.empty() && mount_session && mount_session->rig.lens_shifter &&
      !MakeFramePlan(mount_session->frames).lens_shift.empty())
    shifter_path = a.mount;
  if (!shifter_path.empty()) {
    const Session s =
        shifter_path == a.mount && mount_session ? *mount_session : ReadSession(shifter_path);
    const bool reuse = shifter_path == a.mount && mount_scan.has_value();
    const Rig scan_rig = reuse ? mount_scan_rig : result.rig;
    const FlatTargetScan scan = reuse ? *mount_scan : ScanFlatTarget(s, scan_rig);
    const ShifterCalibration cal = CalibrateShifter(s, scan, scan_rig, ShifterCalibrationOptions());
    result.rig.lens_shifter = cal.calibrated;
    extra["lens_shifter"] = cal.ToJson();
    lines.push_back(cal.BriefReport());
    shifter_cal = cal;
  } else {
    extra["lens_shifter"] = "not calibrated (no --shifter, and no lens-shift frames in --mount)";
  }
  for (const auto& w : result.warnings) MESOSCAN_LOG(kWarning) << w;
  if (a.strict && !result.warnings.empty())
    MESOSCAN_BAD_INPUT("calibrate --strict: " << result.warnings.size()
                                              << " warning(s) above; no rig written");
  // The report is staged in a temporary folder; the rig file is written (atomically) once the
  // report is complete, then the report folder is swapped into place: a failed write leaves
  // neither a new rig nor a partial report.
  const Json rig_json{{"rig", RigJson(result.rig)}, {"calibration", result.RigFileJson()}};
  if (a.report.empty()) {
    WriteJsonFile(a.out, rig_json);
  } else {
    WriteOutputFolder(outputs.report, [&](const fs::path& tmp) {
      if (shifter_cal) WriteShifterMapPng(*shifter_cal, tmp / "lens_shifter_steps.png");
      WriteCalibrationReport(result, tmp, extra);
      WriteJsonFile(a.out, rig_json);
    });
  }
  std::cout << a.out << ": " << result.BriefReport() << "\n";
  for (const auto& l : result.ReportLines()) std::cout << "  " << l << "\n";
  for (const auto& l : lines) std::cout << "  " << l << "\n";
  std::cout << std::flush;
}

}  // namespace

void AddCalibrateCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "calibrate",
      "Calibrate camera, projector and their pose from sessions of a printed checkerboard or "
      "ChArUco board at different poses (calibration sessions), write RIG.json");
  auto args = std::make_shared<CalibrateArgs>();
  cmd->add_option("sessions", args->sessions, "Calibration sessions, one board pose each (>= 3)")
      ->required();
  cmd->add_option("--board", args->board,
                  "checker:COLSxROWS:SQUARE_MM (inner corners, e.g. checker:13x9:10) or "
                  "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares, e.g. "
                  "charuco:11x8:12:9:DICT_5X5_100; may be partly out of view)")
      ->required();
  cmd->add_option("--out", args->out, "Output rig file ({\"rig\": ...}, written atomically)")
      ->required();
  cmd->add_option("--mount", args->mount,
                  "Session of the mount, either a board lying on it or the empty mount (sines "
                  "and/or lens-shift frames; a plane is fitted to its points): world z = 0 "
                  "there, +z towards the rig (default: the first board's plane)");
  cmd->add_option("--shifter", args->shifter,
                  "Session with lens-shift frames of a flat target for the lens shifter's "
                  "steps_per_px (default: the --mount session if it has lens-shift frames)");
  cmd->add_option("--report", args->report, "Folder for report.json and residual / coverage PNGs");
  cmd->add_option("--model", args->model,
                  "Distortion model of both devices: auto (each device's chosen by leave-one-view-"
                  "out cross-validation from none, k1, k1 k2, + tangential, + k3, the principal "
                  "point free or at the centre, fx = fy or not), none, k1, k1k2 or full")
      ->capture_default_str();
  cmd->add_option("--fix", args->fix, "Distortion terms held at 0: k2,k3,tangential");
  cmd->add_flag("--fix-principal-point", args->fix_principal_point,
                "Hold both principal points at the image centre");
  cmd->add_flag("--strict", args->strict,
                "Any warning (poor coverage, a mount that does not come out flat, held-out views "
                "off beyond their noise, an undetermined term) is an error: exit 3, no rig");
  cmd->add_flag("--force", args->force,
                "Replace an existing --out or --report that is not an earlier output of "
                "`mesoscan calibrate`");
  cmd->add_option("--window", args->window,
                  "Local homography half window, camera px (Moreno & Taubin)")
      ->capture_default_str();
  cmd->callback([args] { Run(*args); });
}

}  // namespace mesoscan
