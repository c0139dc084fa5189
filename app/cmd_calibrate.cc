// mesoscan calibrate SESSION... --board checker:COLSxROWS:SQUARE_MM | charuco:COLSxROWS:SQUARE_MM:
// MARKER_MM:DICT --out RIG.json: the rig from calibration sessions of a printed board
// (heightfield/calibrate.h).

#include <filesystem>
#include <iostream>

#include "app/commands.h"
#include "capture/session.h"
#include "core/error.h"
#include "core/json.h"
#include "core/log.h"
#include "heightfield/calibrate.h"

namespace fs = std::filesystem;

namespace mesoscan {
namespace {

struct CalibrateArgs {
  std::vector<std::string> sessions;
  std::string board, out, mount, report, fix;
  int window = 20;
};

Json RigJson(const Rig& rig) {
  Session s;
  s.rig = rig;
  return SessionToJson(s)["rig"];
}

void Run(const CalibrateArgs& a) {
  CalibrateOptions opt;
  opt.board = CalibrationBoard::Parse(a.board, "--board");
  opt.ParseFix(a.fix);
  opt.homography_half_window_px = a.window;
  opt.Check();
  if (a.sessions.size() < 3)
    MESOSCAN_THROW(ErrorKind::kUsage, "calibrate: " << a.sessions.size()
                                                    << " sessions given, expected at least 3 "
                                                       "board poses (8 or more recommended)");
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
                        << (v.found ? ": board found" : ": no board") << " ("
                        << v.decode_seconds << " s)";
    views.push_back(std::move(v));
  }
  std::optional<CalibrationView> mount;
  if (!a.mount.empty()) {
    const Session s = ReadSession(a.mount);
    mount = DetectView(s, opt);
  }
  const CalibrationResult result = Calibrate(std::move(views), *size_rig, mount, opt);
  WriteJsonFile(a.out, Json{{"rig", RigJson(result.rig)}});
  if (!a.report.empty())
    WriteCalibrationReport(result, a.report,
                           Json{{"board", opt.board.ToString()}, {"rig_file", a.out}});
  std::cout << a.out << ": " << result.BriefReport() << "\n" << std::flush;
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
                  "Session of the board lying on the mount: world z = 0 there (default: the "
                  "first board's plane)");
  cmd->add_option("--report", args->report,
                  "Folder for report.json and residual / coverage PNGs");
  cmd->add_option("--fix", args->fix, "Distortion terms held at 0: k2,k3,tangential");
  cmd->add_option("--window", args->window,
                  "Local homography half window, camera px (Moreno & Taubin)")
      ->capture_default_str();
  cmd->callback([args] { Run(*args); });
}

}  // namespace mesoscan
