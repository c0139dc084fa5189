#pragma once
// A rig file as `mesoscan calibrate --out` writes it, used by `reconstruct --rig` and
// `check --rig` in place of the rig in session.json: {"rig": the session format's rig,
// "calibration": the models, the held-out validation, the calibrated regions, the warnings}
// (docs/calibration.md). A rig file from elsewhere (only "rig") is accepted too.

#include <filesystem>
#include <optional>
#include <string>

#include "calibration/calibrate_coverage.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "session/session.h"

namespace mesoscan {

struct RigFile {
  std::filesystem::path path;  // absolute
  std::string sha256;          // of the file's bytes
  Rig rig;
  Json calibration;  // the "calibration" object, null if the file has none
  // Where each device saw the calibration board's corners (absent: not known).
  std::optional<CalibratedRegion> camera_region, projector_region;
  bool camera_distorted = false, projector_distorted = false;  // a distortion term is fitted
  Json ToJson() const;  // {"file", "sha256"} for a scan's report
};

// Reads and validates the file. Errors name the file and the key (exit 3).
RigFile ReadRigFile(const std::filesystem::path& path);

// The session's rig replaced by the file's devices, their poses and lens shifter; the session
// keeps its responses and black level (they describe its frames). The device sizes must agree
// with the session's (an error naming both files otherwise). A calibration session's frames
// are still refused by reconstruct: only the rig is taken from the file.
void UseRigFile(const RigFile& rig_file, Session* session);

// Points whose camera pixel or projector pixel lies outside the calibration's corners (where
// the lens model is extrapolated): counted for the scan's report.
struct CalibratedRegionCheck {
  bool known = false;  // the rig file has both regions
  long points = 0, outside = 0;
  double OutsideFraction() const { return points ? static_cast<double>(outside) / points : 0.0; }
  Json ToJson() const;
};
CalibratedRegionCheck CheckCalibratedRegion(const RigFile& rig_file, const ScanPoints& points);

}  // namespace mesoscan
