// mesoscan capture: the resumable acquisition sequencer (capture/sequencer.h) on the real rig:
// the projector window on an X display, the lens shifter on a serial port, a libgphoto2 camera.
// Interrupting it (Ctrl-C, a device error) leaves a journal; the same command continues from the
// first missing frame.

#include <atomic>
#include <cmath>
#include <csignal>
#include <iostream>
#include <memory>
#include <sstream>

#include "app/commands.h"
#include "app/rehearsal.h"
#include "capture/lens_shifter.h"
#include "capture/patterns.h"
#include "capture/projector_window.h"
#include "capture/sequencer.h"
#include "capture/session.h"
#include "core/error.h"
#include "core/log.h"

namespace mesoscan {
namespace {

std::atomic<bool> g_interrupt{false};
extern "C" void OnSigint(int) { g_interrupt.store(true); }

std::vector<double> ParsePeriodList(const std::string& text) {
  std::vector<double> periods;
  if (text == "none") return periods;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    size_t used = 0;
    double p = 0;
    try {
      p = std::stod(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != item.size() || !(p > 2) || !std::isfinite(p))
      MESOSCAN_THROW(ErrorKind::kUsage, "--periods: '" << text
                                                       << "': expected comma-separated periods "
                                                          "> 2 px, e.g. 7,11,13, or 'none'");
    periods.push_back(p);
  }
  return periods;
}

struct Args {
  std::string out, rig, camera = "gphoto2", camera_ext = "nef", shifter, display, object;
  std::string periods = "7,11,13";
  int phases = 3, ls_frames = 50, projector_x = 0, projector_y = 0, baud = 115200;
  bool no_white = false, no_black = false, rehearse = false;
  SequencerOptions seq;
};

void RunCapture(const Args& a) {
  // The plan: the rig's devices and the standard frames (phase shift + lens shift + white/black).
  const Rig rig = LoadRigFile(a.rig);
  FramePlanOptions plan;
  plan.periods_px = ParsePeriodList(a.periods);
  if (a.phases < 3) MESOSCAN_THROW(ErrorKind::kUsage, "--phases: expected >= 3, got " << a.phases);
  plan.phases = a.phases;
  plan.lens_shift_frames = rig.lens_shifter ? a.ls_frames : 0;
  if (rig.lens_shifter) {
    plan.axis = rig.lens_shifter->axis;
    plan.range_steps = rig.lens_shifter->range_steps;
  }
  if (plan.lens_shift_frames != 0 &&
      (plan.lens_shift_frames < 4 ||
       plan.lens_shift_frames > plan.range_steps[1] - plan.range_steps[0]))
    MESOSCAN_THROW(ErrorKind::kUsage, "--ls-frames: expected 0 or 4.."
                                          << plan.range_steps[1] - plan.range_steps[0]
                                          << " (the shifter's range in steps), got "
                                          << a.ls_frames);
  plan.white = !a.no_white;
  plan.black = !a.no_black;
  Session s;
  s.root = a.out;
  s.object = a.object;
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
  std::cout << a.out << ": " << summary.BriefReport() << "\n" << std::flush;
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
  cmd->add_option("--periods", a.periods, "Sine periods, projector px, comma-separated, or 'none'")
      ->capture_default_str();
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
  cmd->callback([args] { RunCapture(*args); });
}

}  // namespace mesoscan
