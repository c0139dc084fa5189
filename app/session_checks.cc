#include "app/session_checks.h"

#include <cmath>

#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/progress.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

// True if the message already starts with a file or key the user can act on.
bool NamesAFile(const std::string& msg, const Session& s) {
  return msg.rfind(s.root.string(), 0) == 0 || msg.rfind("session.json", 0) == 0 ||
         msg.rfind("frames", 0) == 0 || msg.find(".png") != std::string::npos ||
         msg.find(".exr") != std::string::npos || msg.find(".json") != std::string::npos ||
         msg.rfind("roi", 0) == 0 || msg.rfind("--", 0) == 0 ||
         msg.find(": --") != std::string::npos;
}

}  // namespace

Scan ReconstructOrExplain(const Session& session, const ReconstructOptions& options,
                          ReconstructSummary* summary) {
  const std::string manifest = (session.root / "session.json").string();
  Scan scan;
  try {
    scan = Reconstruct(session, options, summary);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kBadInput || NamesAFile(e.what(), session)) throw;
    throw Error(manifest + ": " + e.what(), e.kind());
  }
  size_t points = 0;
  const ImageF& xyz = scan.points.xyz;
  if (xyz.channels() == 3)
    for (size_t i = 0; i < xyz.pixels(); ++i) points += std::isfinite(xyz.channel(2)[i]);
  if (points == 0)
    MESOSCAN_BAD_INPUT(manifest << ": no pixel could be decoded (" << xyz.width() << "x"
                                << xyz.height()
                                << " pixels tried): are the frames identical, unlit or NaN?");
  return scan;
}

void CheckSessionLikeReconstruct(const Session& session) {
  // Every frame decoded whole: a truncated or corrupt body fails here.
  for (size_t i = 0; i < session.frames.size(); ++i) {
    const ImageF im = ReadImage(session.FramePath(i));
    bool finite = false;
    for (const float v : im.data())
      if (std::isfinite(v)) {
        finite = true;
        break;
      }
    if (!finite)
      MESOSCAN_BAD_INPUT(session.frames[i].file << ": no finite sample (frames[" << i << "])");
  }
  // A calibration session has no calibrated rig to reconstruct with: its frames are checked
  // above, its decoding is calibrate's.
  if (session.rig.uncalibrated) return;
  // The reconstruction's own tests (periods, phases, unwrapping, projector size), on a 32x32
  // window at the image centre.
  ReconstructOptions o;
  const int w = session.rig.camera.width, h = session.rig.camera.height;
  o.load.roi = {std::max(0, w / 2 - 16), std::max(0, h / 2 - 16), std::min(32, w), std::min(32, h)};
  o.num_threads = 0;
  Progress::SetEnabled(false);  // check prints its summary, not the window's progress bars
  const LogLevel level = GetLogLevel();
  SetLogLevel(LogLevel::kError);  // the window's own statistics are not the user's business
  try {
    ReconstructSummary summary;
    Scan scan;
    try {
      scan = Reconstruct(session, o, &summary);
    } catch (const Error& e) {
      if (e.kind() != ErrorKind::kBadInput || NamesAFile(e.what(), session)) throw;
      throw Error((session.root / "session.json").string() + ": " + e.what(), e.kind());
    }
  } catch (...) {
    SetLogLevel(level);
    throw;
  }
  SetLogLevel(level);
}

void CheckScanUsable(const Scan& scan, const fs::path& dir) {
  const HeightField& hf = scan.height;
  const std::string file = (dir / "height.exr").string();
  if (hf.width() < 2 || hf.height() < 2)
    MESOSCAN_BAD_INPUT(file << ": a " << hf.width() << "x" << hf.height()
                            << " height grid, expected at least 2x2 samples");
  for (const float z : hf.z.data())
    if (std::isfinite(z)) return;
  MESOSCAN_BAD_INPUT(file << ": no valid (finite) height sample");
}

}  // namespace mesoscan
