#pragma once
// The resumable acquisition sequencer: for every frame of a session's plan it shows the pattern
// in the projector, moves the lens shifter, waits for the rig to settle, triggers the camera and
// stores the frame under the name the plan gives it; session.json is written (atomically) only
// when every frame is there.
//
// Resuming: a progress journal (<session>/capture_journal.jsonl, one JSON object a line, flushed
// and fsync'ed after every frame) records the plan and, per stored frame, its size and FNV-1a
// hash. A re-run after an interruption (Ctrl-C, a device error, a crash) verifies the journaled
// frames in plan order and continues from the first one that is missing or differs; a journal
// written for another plan or rig is refused. The journal is removed once session.json is
// written, so a completed session folder holds exactly what the spec describes. A completed
// session (session.json present) is not touched unless `force`.
//
// The devices are interfaces so that tests (and rehearsals) can drive the real projector window
// and serial driver with a simulated camera.

#include <atomic>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>

#include "core/image.h"
#include "session/session.h"

namespace mesoscan {

// Every method throws Error(kDevice) whose message starts with the device's name.
class CameraDevice {
 public:
  virtual ~CameraDevice() = default;
  virtual std::string Name() const = 0;  // e.g. "camera 'Nikon DSC D800E' on usb:001,004"
  // Extension of the files it stores, with the dot (".nef", ".png"): frame files get it.
  virtual std::string FrameExtension() const = 0;
  // One exposure, stored at `path` atomically (temp + rename).
  virtual void CaptureToFile(const std::filesystem::path& path) = 0;
};

class ProjectorDevice {
 public:
  virtual ~ProjectorDevice() = default;
  virtual std::string Name() const = 0;
  virtual int width() const = 0;  // px
  virtual int height() const = 0;
  // Shows a grey image of the projector's size (values in [0, 1]); returns once it is displayed.
  virtual void Show(const ImageF& image) = 0;
  // What the projector shows now (R, G, B, 8 bits), if it can be read back; throws
  // Error(kDevice) otherwise.
  virtual ImageU8 Screenshot() const;
};

class ShifterDevice {
 public:
  virtual ~ShifterDevice() = default;
  virtual std::string Name() const = 0;
  // Absolute move in motor steps; returns once the motor has stopped, with the position reached.
  virtual int MoveTo(int steps) = 0;
};

struct SequencerOptions {
  // Wait after the pattern is shown and the shifter has stopped, before the trigger, seconds
  // (>= 0): projector latency and mechanical settling.
  double settle_s = 0.3;
  // Overwrite a completed session (session.json present) or a journal of another plan.
  bool force = false;
  // Capture at most this many new frames in this run, then stop as an interrupted run would
  // (-1: no limit). For capturing in parts, rehearsals and tests.
  int max_new_frames = -1;
  // Polled between steps; when it becomes true the run stops (journal intact) with
  // Error(kDevice) "capture: interrupted ...". May be null.
  const std::atomic<bool>* interrupt = nullptr;
  void Check() const;
};

struct SequencerSummary {
  int frames = 0;         // frames in the plan
  int reused = 0;         // verified frames of an earlier run
  int captured = 0;       // frames captured in this run
  bool complete = false;  // session.json written
  double seconds = 0.0;
  // One line, e.g. "capture: 59 frames (12 reused, 47 captured) in 31.2 s; session.json written".
  std::string BriefReport() const;
};

inline constexpr const char* kCaptureJournal = "capture_journal.jsonl";

// Captures `plan` (root, rig and frames; frame file names keep their stem and take the camera's
// extension) into plan.root. `shifter` may be null when no frame has shift_steps != 0.
// Throws Error(kDevice) naming the device on a device failure, Error(kBadInput) on a journal of
// another plan (without `force`), Error(kUsage) for a completed session without `force`.
SequencerSummary RunAcquisition(const Session& plan, CameraDevice& camera,
                                ProjectorDevice& projector, ShifterDevice* shifter,
                                const SequencerOptions& options);

// The plan with the camera's extension applied to every frame file (what RunAcquisition writes).
Session PlanForCamera(const Session& plan, const CameraDevice& camera);

// FNV-1a 64-bit hash of a file's bytes (journal verification). Throws Error naming the file.
uint64_t HashFile(const std::filesystem::path& path, uint64_t* size = nullptr);

// ---- the real devices ----
struct ProjectorWindowOptions;
struct LensShifterOptions;
// The projector window on an X display (capture/projector_window.h).
std::unique_ptr<ProjectorDevice> MakeWindowProjector(const ProjectorWindowOptions& options);
// The lens-shifter controller on a serial port (capture/lens_shifter.h).
std::unique_ptr<ShifterDevice> MakeSerialShifter(const LensShifterOptions& options);
// A libgphoto2 camera: `which` is empty (the first detected), a port ("usb:001,004") or a model
// name as libgphoto2 reports it. `extension` is the file type the camera is set to deliver.
std::unique_ptr<CameraDevice> MakeGphoto2Camera(const std::string& which,
                                                const std::string& extension);

// A rehearsal camera that looks straight at the projector: it reads the projector window back
// (Screenshot) and box-resamples it to camera.width x camera.height, stored as a 16-bit grey PNG
// (v * 65535) or, with raw = true, as a DNG mosaic of twice the size whose 2x2 cells all hold
// that value (black 0, white 65535), so the raw decoder gives the PNG's values back.
std::unique_ptr<CameraDevice> MakeScreenCamera(const ProjectorDevice& projector, int width,
                                               int height, bool raw);

}  // namespace mesoscan
