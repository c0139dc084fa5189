// mesoscan capture: the resumable acquisition sequencer (capture/sequencer.h) on the real rig:
// the projector window on an X display, the lens shifter on a serial port, a libgphoto2 camera.
// Interrupting it (Ctrl-C, a device error) leaves a journal; the same command continues from the
// first missing frame.

#include <atomic>
#include <cmath>
#include <csignal>
#include <iostream>
#include <memory>

#include "app/commands.h"
#include "app/rehearsal.h"
#include "capture/lens_shifter.h"
#include "capture/projector_window.h"
#include "capture/sequencer.h"
#include "core/error.h"
#include "core/log.h"
#include "session/patterns.h"
#include "session/session.h"

namespace mesoscan {
namespace {

std::atomic<bool> g_interrupt{false};
extern "C" void OnSigint(int) { g_interrupt.store(true); }

struct Args {
  std::string out, rig, camera = "gphoto2", camera_ext = "nef", shifter, display, object;
  std::string plan = "scan", periods = "7,11,13", periods_y, patterns = "sine";
  int phases = 3, ls_frames = 50, projector_x = 0, projector_y = 0, baud = 115200;
  bool no_white = false, no_black = false, rehearse = false;
  bool periods_given = false, periods_y_given = false, ls_frames_given = false;
  SequencerOptions seq;
};

// The frames to capture (session/patterns.h, the generator `simulate` uses too): a scan (sines
// along the shifter's axis, lens shift over its range, white, black) or a calibration plan (sines
// along both projector axes, white, black; no lens shift). --patterns graycode | sine+graycode
// turns the sines of each axis into a Gray code (each bit and its inverse) or one period ordered
// by a complementary Gray code (ApplyPatternSet); --patterns heterodyne makes the sines of each
// axis the three-frequency set (HeterodynePeriods, --phases steps each) unless --periods
// (--periods-y) names them. A scan then takes lens-shift frames only if --ls-frames asks for them
// (as `simulate --patterns`).
FramePlanOptions CapturePlan(const Args& a, const Rig& rig) {
  if (a.phases < 3) MESOSCAN_THROW(ErrorKind::kUsage, "--phases: expected >= 3, got " << a.phases);
  FramePlanOptions plan;
  const bool heterodyne = a.patterns == "heterodyne";
  if (a.plan == "calibration") {
    if (a.ls_frames_given && a.ls_frames != 0)
      MESOSCAN_THROW(ErrorKind::kUsage,
                     "--ls-frames: a calibration plan has no lens-shift frames (omit --ls-frames)");
    plan = CalibrationPlan(rig.projector.width, rig.projector.height);
    if (a.periods_given)
      plan.periods_px = ParsePeriodList(a.periods, "FramePlanOptions.periods_px");
    if (a.periods_y_given)
      plan.cross_periods_px = ParsePeriodList(a.periods_y, "FramePlanOptions.cross_periods_px");
    if (heterodyne && !a.periods_given) plan.periods_px = HeterodynePeriods();
    if (heterodyne && !a.periods_y_given) plan.cross_periods_px = HeterodynePeriods();
    if (plan.periods_px.empty() || plan.cross_periods_px.empty())
      MESOSCAN_THROW(ErrorKind::kUsage,
                     "--plan calibration: expected sine periods along both "
                     "axes (--periods, --periods-y)");
  } else if (a.plan == "scan") {
    if (a.periods_y_given)
      MESOSCAN_THROW(ErrorKind::kUsage, "--periods-y: only with --plan calibration");
    plan.periods_px = heterodyne && !a.periods_given
                          ? HeterodynePeriods()
                          : ParsePeriodList(a.periods, "FramePlanOptions.periods_px");
    plan.lens_shift_frames = rig.lens_shifter ? a.ls_frames : 0;
    if (rig.lens_shifter) {
      plan.axis = rig.lens_shifter->axis;
      plan.range_steps = rig.lens_shifter->range_steps;
    }
    const int64_t positions = int64_t{plan.range_steps[1]} - plan.range_steps[0] + 1;
    if (plan.lens_shift_frames != 0 &&
        (plan.lens_shift_frames < 4 || plan.lens_shift_frames > positions))
      MESOSCAN_THROW(ErrorKind::kUsage, "--ls-frames: expected 0 or 4.."
                                            << positions << " (the shifter's positions), got "
                                            << a.ls_frames);
  } else {
    MESOSCAN_THROW(ErrorKind::kUsage, "--plan: '" << a.plan << "': expected scan or calibration");
  }
  ApplyPatternSet(a.patterns, rig.projector.width, rig.projector.height, &plan,
                  "FramePlanOptions.patterns");
  if (a.patterns != "sine" && !a.ls_frames_given) plan.lens_shift_frames = 0;
  plan.phases = a.phases;
  plan.white = !a.no_white;
  plan.black = !a.no_black;
  return plan;
}

void RunCapture(const Args& a) {
  const Rig rig = LoadRigFile(a.rig);
  const FramePlanOptions plan = CapturePlan(a, rig);
  Session s;
  s.root = a.out;
  s.object = a.object;
  if (a.rehearse && s.object.empty())
    s.object = "capture rehearsal: the screen camera's frames are the projector's own image";
  s.rig = rig;
  s.frames = MakeStandardFrames(plan);

  // --rehearse: a private Xvfb, the screen camera and a simulated shifter on a pty.
  std::unique_ptr<Rehearsal> rehearsal;
  std::string shifter_port = a.shifter;
  std::string camera_name = a.camera;
  if (a.rehearse) {
    rehearsal = std::make_unique<Rehearsal>(
        a.display, a.projector_x + rig.projector.width, a.projector_y + rig.projector.height,
        rig.lens_shifter.has_value() && a.shifter.empty(),
        rig.lens_shifter ? rig.lens_shifter->range_steps[0] : 0,
        rig.lens_shifter ? rig.lens_shifter->range_steps[1] : 0);
    if (shifter_port.empty()) shifter_port = rehearsal->shifter_port();
    if (camera_name != "screen-dng") camera_name = "screen";
  }

  // The devices: projector first (the camera may read it back), then shifter and camera.
  ProjectorWindowOptions po;
  po.display = rehearsal ? rehearsal->display() : a.display;
  po.x = a.projector_x;
  po.y = a.projector_y;
  po.width = rig.projector.width;
  po.height = rig.projector.height;
  std::unique_ptr<ProjectorDevice> projector = MakeWindowProjector(po);
  std::unique_ptr<ShifterDevice> shifter;
  if (!shifter_port.empty() && shifter_port != "none") {
    LensShifterOptions so;
    so.port = shifter_port;
    so.baud = a.baud;
    if (rig.lens_shifter) so.range_steps = rig.lens_shifter->range_steps;
    so.Check();
    shifter = MakeSerialShifter(so);
  }
  std::unique_ptr<CameraDevice> camera;
  std::string ext = a.camera_ext;
  if (!ext.empty() && ext[0] != '.') ext = "." + ext;
  if (camera_name == "screen" || camera_name == "screen-dng")
    camera = MakeScreenCamera(*projector, rig.camera.width, rig.camera.height,
                              camera_name == "screen-dng");
  else if (camera_name == "gphoto2" || camera_name.rfind("gphoto2:", 0) == 0)
    camera = MakeGphoto2Camera(camera_name.size() > 8 ? camera_name.substr(8) : "", ext);
  else
    MESOSCAN_THROW(ErrorKind::kUsage, "--camera: '" << a.camera
                                                    << "': expected gphoto2, gphoto2:MODEL, "
                                                       "gphoto2:PORT, screen or screen-dng");

  // Ctrl-C stops between frames with the journal intact.
  SequencerOptions so = a.seq;
  g_interrupt.store(false);
  so.interrupt = &g_interrupt;
  auto* previous = std::signal(SIGINT, OnSigint);
  SequencerSummary summary;
  try {
    summary = RunAcquisition(s, *camera, *projector, shifter.get(), so);
  } catch (...) {
    std::signal(SIGINT, previous);
    throw;
  }
  std::signal(SIGINT, previous);
  std::cout << a.out << ": " << summary.BriefReport() << "\n";
  if (rehearsal && camera_name != "gphoto2" && camera_name.rfind("gphoto2:", 0) != 0)
    std::cout << a.out
              << ": a rehearsal of the capture chain: the screen camera sees the projector's own "
                 "image, not a scene (its white is saturated), so `check --quick` accepts the "
                 "session and `check` and `reconstruct` refuse it\n";
  std::cout << std::flush;
}

}  // namespace

void AddCaptureCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "capture",
      "Acquire a session on the rig: show each pattern, move the lens shifter, trigger the camera; "
      "resumable (re-run the same command after an interruption)");
  auto args = std::make_shared<Args>();
  Args& a = *args;
  cmd->add_option("--out", a.out, "Session folder (created; frames/ and session.json)")->required();
  cmd->add_option("--rig", a.rig, "RIG.json: a file with a \"rig\" object (session format)")
      ->required();
  cmd->add_option("--camera", a.camera,
                  "gphoto2 | gphoto2:MODEL | gphoto2:PORT (libgphoto2), or screen | screen-dng (a "
                  "rehearsal camera reading the projector window back)")
      ->capture_default_str();
  cmd->add_option("--camera-ext", a.camera_ext,
                  "File type the gphoto2 camera is set to deliver (nef, cr2, dng, jpg ...)")
      ->capture_default_str();
  cmd->add_option("--shifter", a.shifter,
                  "Serial port of the lens-shifter controller (e.g. /dev/ttyUSB0); needed for "
                  "lens-shift frames");
  cmd->add_option("--baud", a.baud, "Serial baud rate")->capture_default_str();
  cmd->add_option("--display", a.display, "X display of the projector (default: $DISPLAY)");
  cmd->add_option("--projector-x", a.projector_x,
                  "Left of the projector's output on the X screen, px")
      ->capture_default_str();
  cmd->add_option("--projector-y", a.projector_y,
                  "Top of the projector's output on the X screen, px")
      ->capture_default_str();
  cmd->add_option("--plan", a.plan,
                  "scan (sines, lens shift, white, black) | calibration (sines along projector x "
                  "and y, white, black: a board for `mesoscan calibrate`)")
      ->capture_default_str();
  cmd->add_option("--patterns", a.patterns,
                  "sine (the --periods sets) | graycode (a Gray code of the projector's columns, "
                  "and rows for a calibration plan, each bit with its inverse; no sines) | "
                  "sine+graycode (one --periods period, and one --periods-y period for a "
                  "calibration plan, each ordered by a complementary Gray code of half its width) "
                  "| heterodyne (sines of periods 42, 45, 48 px unless --periods / --periods-y "
                  "name others, --phases steps each, decoded by temporal unwrapping; no lens "
                  "shift unless --ls-frames)")
      ->capture_default_str();
  cmd->add_option("--periods", a.periods,
                  "Sine periods, projector px, comma-separated, or 'none' (calibration plan: "
                  "along x; default the projector width and 1/16 of it)")
      ->capture_default_str();
  cmd->add_option("--periods-y", a.periods_y,
                  "Calibration plan: sine periods along projector y (default the projector "
                  "height and 1/16 of it)");
  cmd->add_option("--phases", a.phases, "Phases per sine period (>= 3)")->capture_default_str();
  cmd->add_option("--ls-frames", a.ls_frames,
                  "Lens-shift frames over the rig's shifter range (0 or >= 4; 0 without a shifter)")
      ->capture_default_str();
  cmd->add_flag("--rehearse", a.rehearse,
                "Rehearse without hardware: a private Xvfb (unless --display), the screen camera "
                "and a simulated lens shifter on a pseudo-terminal");
  cmd->add_flag("--no-white", a.no_white, "No white frame");
  cmd->add_flag("--no-black", a.no_black, "No black frame");
  cmd->add_option("--object", a.object, "The session's \"object\" text");
  cmd->add_option("--settle", a.seq.settle_s,
                  "Wait after showing and moving, before the trigger, seconds")
      ->capture_default_str();
  cmd->add_flag("--force", a.seq.force,
                "Capture again over a completed session or a journal of another plan");
  cmd->add_option("--max-frames", a.seq.max_new_frames,
                  "Capture at most this many new frames, then stop (resume later); -1: all")
      ->capture_default_str();
  cmd->callback([args, cmd] {
    args->periods_given = cmd->count("--periods") > 0;
    args->periods_y_given = cmd->count("--periods-y") > 0;
    args->ls_frames_given = cmd->count("--ls-frames") > 0;
    RunCapture(*args);
  });
}

}  // namespace mesoscan
