#pragma once
// The capture session of docs/formats.md: the rig, every frame, and which pattern
// each frame shows. `capture` and `simulate` write it through WriteSession; `reconstruct` reads
// it through ReadSession, which validates everything the spec lists and refuses anything else
// with one line naming the file, the key and what was expected.

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/camera.h"
#include "core/image_io.h"
#include "core/json.h"

namespace mesoscan {

inline constexpr const char* kSessionFormat = "mesoscan-session/1";

enum class PatternType { kSine, kStripes, kWhite, kBlack, kGrayCode };

struct Pattern {
  PatternType type = PatternType::kWhite;
  char axis = 'x';         // 'x' (varies along projector u) or 'y' (along v)
  double period_px = 0.0;  // sine: any real > 2; stripes: >= 2 (2 for the lens-shift pattern)
  double phase = 0.0;      // sine only, radians
  // graycode only: bit `bit` (0 = the most significant) of the `bits`-bit reflected binary Gray
  // code of floor(u / block_px); `inverted` shows its complement.
  int bits = 0, bit = 0;
  double block_px = 1.0;
  bool inverted = false;

  // Displayed value in [0, 1] at projector pixel (u, v) (spec "Patterns"), before the
  // projector's response. u, v may be fractional (the lens shifter moves the image): sine is
  // then the continuous cosine (the band-limited ideal the phase decoder assumes); stripes take
  // the value of the projector pixel whose footprint [u - 0.5, u + 0.5) contains u (pixel centres
  // are at integers, spec "Conventions"), so a stripe edge lies half-way between two pixels.
  double Value(double u, double v) const;
  bool IsLensShift() const { return type == PatternType::kStripes; }
  // A pattern that a planned codec decodes (heightfield/codecs.h): graycode.
  bool IsCoded() const { return type == PatternType::kGrayCode; }
};

struct Frame {
  std::string file;  // relative to the session folder, as written in session.json
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
  double steps_per_px = 2048;  // > 0
  std::array<int, 2> range_steps{-2048, 2048};
};

struct Rig {
  PinholeCamera camera;
  Response camera_response;
  double black_level = 0.0;  // in the frame's units normalised to [0, 1]
  PinholeCamera projector;
  Response projector_response;  // kLinear or kGamma only
  // Optional `projector.falloff` {"radial": f}: the projector's relative irradiance at pixel
  // (u, v) (at shift 0) is 1 - f * (un^2 + vn^2), un = (u - cx) / (W/2), vn = (v - cy) / (H/2),
  // on top of cos(incidence) / r^2; 0 (the default) = none. f in [0, 0.5).
  double projector_falloff = 0.0;
  std::optional<LensShifter> lens_shifter;
  // A calibration session's rig (spec "Calibration sessions"): a device lacks K, distortion or
  // world_from_device; camera and projector then hold the sizes (and any initial guess) only.
  // `check` says so; `reconstruct` refuses it.
  bool uncalibrated = false;
};

// The relative irradiance of rig.projector_falloff at projector pixel (u, v).
double ProjectorFalloff(const Rig& rig, double u, double v);

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

// The frames of a session grouped by what they encode: for validation, `mesoscan check` and the
// decoders. Indices refer to Session::frames.
struct FramePlan {
  struct SineSet {
    char axis = 'x';
    double period_px = 0.0;
    std::vector<double> phases;  // distinct phases, radians in [0, 2*pi), ascending
    std::vector<size_t> frames;  // every frame of this (axis, period), in session order
  };
  std::vector<SineSet> sine;                     // ascending by axis, then period
  std::vector<size_t> lens_shift;                // stripes frames, in session order
  int distinct_shift_steps = 0;                  // distinct shift_steps among lens_shift frames
  int min_shift_steps = 0, max_shift_steps = 0;  // over lens_shift frames (0 if none)
  std::vector<size_t> white, black;
  std::vector<size_t> graycode;  // graycode frames, in session order

  // Sine periods of one axis ('x' or 'y'), ascending.
  std::vector<double> Periods(char axis) const;
  // Multi-line human summary, e.g. "phase shift: periods 7,11,13 x 3 phases (axis x), ...".
  std::string Describe(const Rig& rig) const;
};

FramePlan MakeFramePlan(const std::vector<Frame>& frames);

// The length (projector px) over which the tuple of phases of sine patterns with these periods is
// unique, i.e. the smallest L > 0 that is (to 1e-3 of a cycle) a multiple of every period: the
// LCM for integer periods, the longest period when one period is a multiple of all others
// (hierarchical cue + fine period). Returns `search_limit_px` if L >= search_limit_px.
double UnambiguousRangePx(const std::vector<double>& periods_px, double search_limit_px);

// Reads and validates <dir>/session.json and checks every frame file's header (size, readable).
// `dir` may also name the session.json file itself.
// Throws Error(kBadInput) with one line on the first problem:
//   "session.json: <key>: <what was expected>"        (document errors; key like rig.camera.K)
//   "<frame file>: <what is wrong>"                   (frame errors; the path as in session.json)
//   "<dir>/session.json: file not found"              (no manifest)
// `check_frames` false skips opening the frame images (for fast inspection).
Session ReadSession(const std::filesystem::path& dir, bool check_frames = true);

// The current UTC time as session.json's "created" holds it: "YYYY-MM-DDTHH:MM:SSZ".
std::string SessionTimeNow();

// Opens every frame's and ground-truth file's header (in parallel, no decode) and checks it is
// readable and camera.width x camera.height (camera raw files: twice that, see the spec).
// Returns one ImageInfo per frame. Warns once if frames are 8-bit. Throws as ReadSession.
std::vector<ImageInfo> CheckSessionFiles(const Session& s);

// Parses and validates a session.json document already in memory (no frame files are opened).
// `file_label` is the name used in error messages.
Session ParseSession(const Json& j, const std::filesystem::path& root,
                     const std::string& file_label = "session.json");

// A rig from a JSON file holding a "rig" object in the session format (validated by the session
// parser; errors name the file and the key): `mesoscan capture --rig` and `simulate --rig`.
Rig LoadRigFile(const std::filesystem::path& path);

Json SessionToJson(const Session& s);

// Writes session.json atomically into s.root (frames must already be there).
void WriteSessionJson(const Session& s);

}  // namespace mesoscan
