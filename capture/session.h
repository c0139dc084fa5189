#pragma once
// The capture session of shared/spec/session-format.md: the rig, every frame, and which pattern
// each frame shows. `capture` and `simulate` write it through WriteSession; `reconstruct` reads
// it through ReadSession, which validates everything the spec lists and refuses anything else
// with one line naming the file, the key and what was expected.

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/camera.h"
#include "core/json.h"

namespace mesoscan {

inline constexpr const char* kSessionFormat = "mesoscan-session/1";

enum class PatternType { kSine, kStripes, kWhite, kBlack };

struct Pattern {
  PatternType type = PatternType::kWhite;
  char axis = 'x';         // 'x' (varies along projector u) or 'y' (along v)
  double period_px = 0.0;  // sine: any real > 2; stripes: > 0 (2 for the lens-shift pattern)
  double phase = 0.0;      // sine only, radians

  // Displayed value in [0, 1] at projector pixel (u, v) (spec "Patterns"), before the
  // projector's response. u, v may be fractional (the lens shifter moves the image).
  double Value(double u, double v) const;
  bool IsLensShift() const { return type == PatternType::kStripes; }
};

struct Frame {
  std::string file;     // relative to the session folder, as written in session.json
  Pattern pattern;
  int shift_steps = 0;  // lens-shifter position when the frame was taken
};

// Camera response: how frame values map to scene radiance.
struct Response {
  enum class Kind { kLinear, kSrgb, kGamma } kind = Kind::kLinear;
  double gamma = 1.0;  // kGamma only, > 0
  // Frame value in [0, 1] -> linear radiance (camera) or displayed value -> light (projector).
  double ToLinear(double v) const;
};

struct LensShifter {
  char axis = 'x';
  double steps_per_px = 2048;                // > 0
  std::array<int, 2> range_steps{-2048, 2048};
};

struct Rig {
  PinholeCamera camera;
  Response camera_response;
  double black_level = 0.0;  // in the frame's units normalised to [0, 1]
  PinholeCamera projector;
  Response projector_response;  // kLinear or kGamma only
  std::optional<LensShifter> lens_shifter;
};

struct GroundTruth {
  std::string points;  // relative path of gt_points.exr (channels X, Y, Z)
  std::string height;  // relative path of gt_height.exr (scan-outputs.md layout)
};

struct Session {
  std::filesystem::path root;  // the session folder (absolute after ReadSession)
  std::string created;
  std::string object;
  Rig rig;
  std::vector<Frame> frames;
  std::optional<GroundTruth> ground_truth;
  Json extra = Json::object();  // unknown top-level keys, kept so a rewrite loses nothing

  std::filesystem::path FramePath(size_t i) const { return root / frames[i].file; }
};

// Reads and validates <dir>/session.json and checks every frame file's header (size, readable).
// Throws Error(kBadInput) with one line "<file>: <key>: <expected ...>" on the first problem.
// `check_frames` false skips opening the frame images (for fast inspection).
Session ReadSession(const std::filesystem::path& dir, bool check_frames = true);

// Parses and validates a session.json document already in memory (no frame files are opened).
// `file_label` is the name used in error messages.
Session ParseSession(const Json& j, const std::filesystem::path& root,
                     const std::string& file_label = "session.json");

Json SessionToJson(const Session& s);

// Writes session.json atomically into s.root (frames must already be there).
void WriteSessionJson(const Session& s);

}  // namespace mesoscan
