#include "session/session.h"

#include <sys/resource.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iomanip>
#include <limits>
#include <map>
#include <numbers>
#include <set>
#include <sstream>
#include <tuple>

#include "core/error.h"
#include "core/fs.h"
#include "core/json_depth.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "core/parallel.h"
#include "session/raw_frame.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;
constexpr int kMaxImageSide = 65536;  // px; keeps width * height * channels well inside size_t
// world_from_device rotations are accepted within this of orthonormal (files written with ~6
// decimals), then replaced by the nearest rotation so that Inverse() (a transpose) stays exact.
constexpr double kRigidTolerance = 1e-5;
// Two sine phases (radians) closer than this are the same phase.
constexpr double kSamePhase = 1e-6;
// Phase tuples agreeing to this fraction of a cycle for every period count as equal (0.36 deg,
// far below any decoder's phase noise, so integer periods give their exact LCM).
constexpr double kSameCycleFraction = 1e-3;

// Numbers in messages: enough digits to tell 2 from 2.0000001, no trailing noise.
std::string Num(double v) {
  std::ostringstream oss;
  oss << std::setprecision(10) << v;
  return oss.str();
}

std::string Quote(const std::string& s) {
  std::string t = s.size() > 60 ? s.substr(0, 57) + "..." : s;
  for (char& c : t)
    if (c == '\n' || c == '\r' || c == '\t') c = ' ';
  return "\"" + t + "\"";
}

// ", got <value>" for scalars; arrays and objects are named, not dumped.
std::string Got(const Json& v) {
  if (v.is_number()) return ", got " + Num(v.get<double>());
  if (v.is_string()) return ", got " + Quote(v.get<std::string>());
  if (v.is_boolean()) return v.get<bool>() ? ", got true" : ", got false";
  if (v.is_null()) return ", got null";
  if (v.is_array()) return ", got an array";
  return ", got an object";
}

std::string Join(const std::string& parent, const std::string& name) {
  return parent.empty() ? name : parent + "." + name;
}

std::string Index(const std::string& parent, size_t i) {
  return parent + "[" + std::to_string(i) + "]";
}

// Reads one session.json document; every failure is one line "<file>: <key>: <expected>".
class Parser {
 public:
  explicit Parser(std::string file) : file_(std::move(file)) {}

  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Key(file_, key), what);
  }
  [[noreturn]] void Expected(const std::string& key, const std::string& expected,
                             const Json& got) const {
    Fail(key, "expected " + expected + Got(got));
  }

  // obj[name], or nullptr if absent (obj is an object).
  static const Json* Find(const Json& obj, const char* name) {
    auto it = obj.find(name);
    return it == obj.end() ? nullptr : &*it;
  }
  const Json& Require(const Json& obj, const std::string& parent, const char* name,
                      const std::string& expected) const {
    const Json* v = Find(obj, name);
    if (!v) Fail(Join(parent, name), "missing, expected " + expected);
    return *v;
  }
  const Json& RequireObject(const Json& obj, const std::string& parent, const char* name,
                            const std::string& expected) const {
    const Json& v = Require(obj, parent, name, expected);
    if (!v.is_object()) Expected(Join(parent, name), expected, v);
    return v;
  }

  double Number(const Json& v, const std::string& key, const std::string& expected) const {
    if (!v.is_number()) Expected(key, expected, v);
    const double d = v.get<double>();
    if (!std::isfinite(d)) Expected(key, expected, v);
    return d;
  }
  // An integer (an integral float like 3.0 is accepted) in [lo, hi].
  int64_t Integer(const Json& v, const std::string& key, int64_t lo, int64_t hi,
                  const std::string& expected) const {
    if (!v.is_number()) Expected(key, expected, v);
    if (v.is_number_integer()) {
      if (v.is_number_unsigned()) {
        const uint64_t u = v.get<uint64_t>();
        // Lower bound too: a positive lo (e.g. width >= 1) must refuse an unsigned 0.
        if (u > static_cast<uint64_t>(hi) || static_cast<int64_t>(u) < lo)
          Expected(key, expected, v);
        return static_cast<int64_t>(u);
      }
      const int64_t i = v.get<int64_t>();
      if (i < lo || i > hi) Expected(key, expected, v);
      return i;
    }
    const double d = v.get<double>();
    if (!std::isfinite(d) || d != std::floor(d) || d < static_cast<double>(lo) ||
        d > static_cast<double>(hi))
      Expected(key, expected, v);
    return static_cast<int64_t>(d);
  }
  std::string String(const Json& v, const std::string& key, const std::string& expected) const {
    if (!v.is_string()) Expected(key, expected, v);
    return v.get<std::string>();
  }
  char Axis(const Json& obj, const std::string& parent) const {
    const std::string key = Join(parent, "axis");
    const std::string a =
        String(Require(obj, parent, "axis", "\"x\" or \"y\""), key, "\"x\" or \"y\"");
    if (a != "x" && a != "y") Expected(key, "\"x\" or \"y\"", obj["axis"]);
    return a[0];
  }
  // rows x cols nested array of finite numbers.
  Eigen::MatrixXd Matrix(const Json& v, const std::string& key, int rows, int cols) const {
    const std::string expected =
        "a " + std::to_string(rows) + "x" + std::to_string(cols) + " array of finite numbers";
    Eigen::MatrixXd m(rows, cols);
    if (!v.is_array() || static_cast<int>(v.size()) != rows) Fail(key, "expected " + expected);
    for (int r = 0; r < rows; ++r) {
      const Json& row = v[r];
      if (!row.is_array() || static_cast<int>(row.size()) != cols)
        Fail(key, "expected " + expected);
      for (int c = 0; c < cols; ++c) {
        if (!row[c].is_number() || !std::isfinite(row[c].get<double>()))
          Fail(key, "expected " + expected);
        m(r, c) = row[c].get<double>();
      }
    }
    return m;
  }

  // A relative path that stays inside the session folder.
  std::string RelativePath(const Json& obj, const std::string& parent, const char* name,
                           const std::string& what) const {
    const std::string key = Join(parent, name);
    const std::string expected = "a relative path to " + what;
    const std::string p = String(Require(obj, parent, name, expected), key, expected);
    if (p.empty()) Expected(key, expected, obj[name]);
    const fs::path path(p);
    if (path.is_absolute() || path.has_root_path() || p[0] == '/' || p[0] == '\\')
      Fail(key, Quote(p) + " is absolute, expected a path relative to the session folder");
    for (const auto& part : path)
      if (part == "..")
        Fail(key, Quote(p) + " leaves the session folder, expected a path inside it (no \"..\")");
    return p;
  }

  // *uncalibrated (if given) is set when K, distortion or world_from_device is absent (a
  // calibration session, spec "Calibration sessions"); without it all three are required.
  PinholeCamera Device(const Json& obj, const std::string& parent,
                       bool* uncalibrated = nullptr) const {
    PinholeCamera cam;
    if (uncalibrated &&
        (!Find(obj, "K") || !Find(obj, "distortion") || !Find(obj, "world_from_device"))) {
      *uncalibrated = true;
      // Whatever is present is an initial guess: validated, then kept.
      const std::string side = "an integer in [1, " + std::to_string(kMaxImageSide) + "]";
      cam.width = static_cast<int>(Integer(Require(obj, parent, "width", side),
                                           Join(parent, "width"), 1, kMaxImageSide, side));
      cam.height = static_cast<int>(Integer(Require(obj, parent, "height", side),
                                            Join(parent, "height"), 1, kMaxImageSide, side));
      Json full = obj;
      if (!Find(obj, "K"))
        full["K"] = {
            {1.0, 0.0, 0.5 * (cam.width - 1)}, {0.0, 1.0, 0.5 * (cam.height - 1)}, {0.0, 0.0, 1.0}};
      if (!Find(obj, "distortion")) full["distortion"] = {0, 0, 0, 0, 0};
      if (!Find(obj, "world_from_device"))
        full["world_from_device"] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
      return Device(full, parent);
    }
    const std::string side = "an integer in [1, " + std::to_string(kMaxImageSide) + "]";
    cam.width = static_cast<int>(Integer(Require(obj, parent, "width", side), Join(parent, "width"),
                                         1, kMaxImageSide, side));
    cam.height = static_cast<int>(Integer(Require(obj, parent, "height", side),
                                          Join(parent, "height"), 1, kMaxImageSide, side));
    // K: finite, upper triangular with fx, fy > 0 and last row [0 0 1] (the model ignores the
    // rest, so anything else would be silently wrong).
    const std::string k_key = Join(parent, "K");
    const Json& kj = Require(obj, parent, "K", "a 3x3 array of finite numbers");
    cam.K = Matrix(kj, k_key, 3, 3);
    const Mat3d& K = cam.K;
    if (!(K(0, 0) > 0) || !(K(1, 1) > 0) || K(1, 0) != 0 || K(2, 0) != 0 || K(2, 1) != 0 ||
        K(2, 2) != 1)
      Fail(k_key,
           "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx > 0 and fy > 0 (a non-singular "
           "pinhole matrix)");
    const std::string d_key = Join(parent, "distortion");
    const std::string d_expected = "5 finite numbers [k1, k2, p1, p2, k3]";
    const Json& dj = Require(obj, parent, "distortion", d_expected);
    if (!dj.is_array() || dj.size() != 5) Fail(d_key, "expected " + d_expected);
    for (int i = 0; i < 5; ++i) {
      if (!dj[i].is_number() || !std::isfinite(dj[i].get<double>()))
        Fail(d_key, "expected " + d_expected);
      cam.distortion[i] = dj[i].get<double>();
    }
    const std::string p_key = Join(parent, "world_from_device");
    const Mat4d m = Matrix(
        Require(obj, parent, "world_from_device", "a 4x4 array of finite numbers"), p_key, 4, 4);
    if (!IsRigid(m, kRigidTolerance))
      Fail(p_key,
           "expected a rigid transform (orthonormal rotation with det +1, last row [0, 0, 0, 1])");
    cam.world_from_device = Rigid3d::FromMatrix(m);
    // A rounded rotation is replaced by the nearest rotation (polar decomposition) so the
    // inverse by transpose downstream is exact; an exact one is kept bit for bit (round trips).
    Mat3d& r = cam.world_from_device.rotation;
    if (!IsRigid(m, 1e-12)) {
      Eigen::JacobiSVD<Mat3d> svd(r, Eigen::ComputeFullU | Eigen::ComputeFullV);
      r = svd.matrixU() * svd.matrixV().transpose();
    }
    return cam;
  }

  Response ReadResponse(const Json& obj, const std::string& parent, bool allow_srgb) const {
    Response r;
    const Json* v = Find(obj, "response");
    if (!v) return r;
    const std::string key = Join(parent, "response");
    const std::string expected = allow_srgb
                                     ? "\"linear\", \"srgb\" or {\"gamma\": g} with finite g > 0"
                                     : "\"linear\" or {\"gamma\": g} with finite g > 0";
    if (v->is_string()) {
      const std::string s = v->get<std::string>();
      if (s == "linear") return r;
      if (s == "srgb" && allow_srgb) {
        r.kind = Response::Kind::kSrgb;
        return r;
      }
      Expected(key, expected, *v);
    }
    if (!v->is_object()) Expected(key, expected, *v);
    const Json* g = Find(*v, "gamma");
    if (!g || !g->is_number() || !std::isfinite(g->get<double>()) || !(g->get<double>() > 0))
      Fail(key, "expected " + expected);
    r.kind = Response::Kind::kGamma;
    r.gamma = g->get<double>();
    return r;
  }

 private:
  std::string file_;
};

bool IsSupportedFormat(const std::string& f) {
  const std::string base = kSessionFormat;  // "mesoscan-session/1"
  if (f == base) return true;
  if (f.size() <= base.size() + 1 || f.compare(0, base.size() + 1, base + ".") != 0) return false;
  return std::all_of(f.begin() + base.size() + 1, f.end(),
                     [](char c) { return c >= '0' && c <= '9'; });
}

double NormalizePhase(double phase) {
  double p = std::fmod(phase, kTwoPi);
  if (p < 0) p += kTwoPi;
  if (p >= kTwoPi - kSamePhase) p = 0.0;  // 2*pi - eps is the same phase as 0
  return p;
}

// Line and column (1-based) of byte offset `byte` (nlohmann reports the byte after the error).
std::pair<size_t, size_t> LineColumn(const std::string& text, size_t byte) {
  size_t line = 1, col = 1;
  for (size_t i = 0; i + 1 < byte && i < text.size(); ++i) {
    if (text[i] == '\n') {
      ++line;
      col = 1;
    } else {
      ++col;
    }
  }
  return {line, col};
}

Json DeviceToJson(const PinholeCamera& c) {
  Json j;
  j["width"] = c.width;
  j["height"] = c.height;
  j["K"] = MatrixToJson(c.K);
  j["distortion"] = Json(std::vector<double>(c.distortion.begin(), c.distortion.end()));
  j["world_from_device"] = MatrixToJson(c.world_from_device.Matrix());
  return j;
}

Json ResponseToJson(const Response& r) {
  switch (r.kind) {
    case Response::Kind::kSrgb:
      return "srgb";
    case Response::Kind::kGamma:
      return Json{{"gamma", r.gamma}};
    case Response::Kind::kLinear:
      break;
  }
  return "linear";
}

bool IsRawExtension(const fs::path& p) { return IsCameraRawPath(p); }

// ReadImageLayout with the message's absolute path replaced by the path as written in the session.
// Also refuses a file that resolves (through symlinks) outside the session folder `root`, and
// a symlink loop, naming the key.
ImageInfo ReadInfoLabelled(const fs::path& path, const std::string& label, const std::string& key,
                           const fs::path& root) {
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(path, ec);
  if (ec)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                          "cannot resolve the path (" << ec.message() << ") (" << key << ")");
  const fs::path real_root = fs::weakly_canonical(fs::absolute(root), ec);
  if (!ec && !PathIsWithin(real, real_root))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                          "resolves to " << real.string()
                                         << ", outside the session folder (a symlink leaving it) ("
                                         << key << ")");
  if (!fs::exists(path))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "file not found (" << key << ")");
  try {
    return ReadImageLayout(path);
  } catch (const Error& e) {  // the image's error, located at the session's name for the file
    // Out of file descriptors is the process's limit, not the frame's fault.
    if (e.Detail().find(std::strerror(EMFILE)) != std::string::npos) {
      rlimit rl{};
      getrlimit(RLIMIT_NOFILE, &rl);
      MESOSCAN_THROW(e.kind(), "too many open files: the process may open "
                                   << rl.rlim_cur << " (ulimit -n); raise the limit (while reading "
                                   << label << ")");
    }
    MESOSCAN_THROW_AT(
        e.kind() == ErrorKind::kInternal ? ErrorKind::kInternal : ErrorKind::kBadInput,
        ErrorSite::File(label), e.Detail() << " (" << key << ")");
  }
}

}  // namespace

double Pattern::Value(double u, double v) const {
  const double x = axis == 'y' ? v : u;
  switch (type) {
    case PatternType::kSine:
      return 0.5 + 0.5 * std::cos(kTwoPi * x / period_px + phase);
    case PatternType::kStripes: {
      const double pixel = std::floor(x + 0.5);  // the pixel whose footprint contains x
      const double bar = std::floor(pixel / (0.5 * period_px));
      return std::fmod(bar, 2.0) == 0.0 ? 1.0 : 0.0;
    }
    case PatternType::kWhite:
      return 1.0;
    case PatternType::kBlack:
      return 0.0;
    case PatternType::kGrayCode: {
      const double pixel = std::floor(x + 0.5);  // the pixel whose footprint contains x
      const int64_t block =
          std::max<int64_t>(0, static_cast<int64_t>(std::floor(pixel / block_px)));
      const int64_t gray = block ^ (block >> 1);
      const bool set = (gray >> (bits - 1 - bit)) & 1;
      return set != inverted ? 1.0 : 0.0;
    }
  }
  return 0.0;
}

double Response::ToLinear(double v) const {
  switch (kind) {
    case Kind::kLinear:
      return v;
    case Kind::kSrgb: {
      // IEC 61966-2-1 EOTF, odd-symmetric so that noise around black stays unbiased.
      const double a = std::abs(v);
      const double l = a <= 0.04045 ? a / 12.92 : std::pow((a + 0.055) / 1.055, 2.4);
      return std::copysign(l, v);
    }
    case Kind::kGamma:
      return std::copysign(std::pow(std::abs(v), gamma), v);
  }
  return v;
}

std::vector<double> FramePlan::Periods(char axis) const {
  std::vector<double> p;
  for (const SineSet& s : sine)
    if (s.axis == axis) p.push_back(s.period_px);
  return p;
}

FramePlan MakeFramePlan(const std::vector<Frame>& frames) {
  FramePlan plan;
  std::set<int> shifts;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Pattern& p = frames[i].pattern;
    switch (p.type) {
      case PatternType::kSine: {
        auto it =
            std::find_if(plan.sine.begin(), plan.sine.end(), [&](const FramePlan::SineSet& s) {
              return s.axis == p.axis && std::abs(s.period_px - p.period_px) <= 1e-9 * p.period_px;
            });
        if (it == plan.sine.end()) {
          plan.sine.push_back({p.axis, p.period_px, {}, {}});
          it = plan.sine.end() - 1;
        }
        it->frames.push_back(i);
        const double ph = NormalizePhase(p.phase);
        if (std::none_of(it->phases.begin(), it->phases.end(),
                         [&](double q) { return std::abs(q - ph) <= kSamePhase; }))
          it->phases.push_back(ph);
        break;
      }
      case PatternType::kStripes:
        plan.lens_shift.push_back(i);
        shifts.insert(frames[i].shift_steps);
        break;
      case PatternType::kWhite:
        plan.white.push_back(i);
        break;
      case PatternType::kBlack:
        plan.black.push_back(i);
        break;
      case PatternType::kGrayCode:
        plan.graycode.push_back(i);
        break;
    }
  }
  for (auto& s : plan.sine) std::sort(s.phases.begin(), s.phases.end());
  std::sort(plan.sine.begin(), plan.sine.end(), [](const auto& a, const auto& b) {
    return a.axis != b.axis ? a.axis < b.axis : a.period_px < b.period_px;
  });
  plan.distinct_shift_steps = static_cast<int>(shifts.size());
  if (!shifts.empty()) {
    plan.min_shift_steps = *shifts.begin();
    plan.max_shift_steps = *shifts.rbegin();
  }
  return plan;
}

double UnambiguousRangePx(const std::vector<double>& periods_px, double search_limit_px) {
  if (periods_px.empty()) return 0.0;
  const double p_max = *std::max_element(periods_px.begin(), periods_px.end());
  if (!(p_max > 0)) return 0.0;
  // Candidates are the multiples of the longest period; the first one that is also (to
  // kSameCycleFraction of a cycle) a multiple of every other period is where the tuple repeats.
  for (int64_t k = 1;; ++k) {
    const double length = static_cast<double>(k) * p_max;
    if (length >= search_limit_px) return search_limit_px;
    bool repeats = true;
    for (double p : periods_px) {
      const double cycles = length / p;
      if (std::abs(cycles - std::round(cycles)) > kSameCycleFraction) {
        repeats = false;
        break;
      }
    }
    if (repeats) return length;
  }
}

std::string FramePlan::Describe(const Rig& rig) const {
  std::ostringstream out;
  for (char axis : {'x', 'y'}) {
    const std::vector<double> periods = Periods(axis);
    if (periods.empty()) continue;
    // "periods 7,11,13 x 3 phases" when every period has the same phase count, else
    // "periods 7 x 3,11 x 4 phases".
    std::vector<size_t> counts;
    for (const auto& s : sine)
      if (s.axis == axis) counts.push_back(s.phases.size());
    const bool same_count =
        std::all_of(counts.begin(), counts.end(), [&](size_t c) { return c == counts.front(); });
    out << "phase shift (axis " << axis << "): period" << (periods.size() > 1 ? "s " : " ");
    for (size_t i = 0; i < periods.size(); ++i) {
      out << (i ? "," : "") << Num(periods[i]);
      if (!same_count) out << " x " << counts[i];
    }
    if (same_count) out << " x " << counts.front();
    out << " phases";
    const double extent = axis == 'x' ? rig.projector.width : rig.projector.height;
    const double range = UnambiguousRangePx(periods, 1e6);
    out << "; unambiguous over " << (range >= 1e6 ? ">= 1e6" : Num(range)) << " px (projector "
        << (axis == 'x' ? "width " : "height ") << Num(extent) << " px)\n";
  }
  if (sine.empty())
    out << "phase shift: none" << (graycode.empty() ? " (projector columns cannot be decoded)" : "")
        << "\n";
  if (!graycode.empty()) out << "gray code: " << graycode.size() << " frames\n";
  if (lens_shift.empty()) {
    out << "lens shift: none\n";
  } else {
    out << "lens shift: " << lens_shift.size() << " frames at " << distinct_shift_steps
        << " positions over " << min_shift_steps << ".." << max_shift_steps << " steps";
    if (rig.lens_shifter) {
      out << " (" << Num(min_shift_steps / rig.lens_shifter->steps_per_px) << ".."
          << Num(max_shift_steps / rig.lens_shifter->steps_per_px) << " px, axis "
          << rig.lens_shifter->axis << ")";
    }
    out << "\n";
  }
  out << "white: " << (white.empty() ? "no (optional: albedo texture)" : "yes")
      << "; black: " << (black.empty() ? "no (optional: modulation bounds)" : "yes") << "\n";
  return out.str();
}

namespace {

// What the numbers of a calibrated rig can be at all (a typo or a damaged file, not a rig the
// reconstruction could use): a pinhole skew beyond fx, distortion terms beyond 100 (k1 of real
// lenses is well below 1), a response gamma outside [0.05, 20], a device at or below the mount
// plane (world z = 0, +z towards the rig), camera and projector within 0.5 mm of each other (no
// triangulation), a lens shifter whose range spans more than the projector's width.
void CheckRigGeometry(const Parser& p, const Rig& rig) {
  const auto device = [&](const PinholeCamera& d, const std::string& key) {
    if (!(std::abs(d.K(0, 1)) <= d.K(0, 0)))
      p.Fail(key + ".K",
             "skew " + Num(d.K(0, 1)) + ", expected |skew| <= fx (" + Num(d.K(0, 0)) + ")");
    for (int i = 0; i < 5; ++i)
      if (!(std::abs(d.distortion[i]) <= 100))
        p.Fail(key + ".distortion", "term " + std::to_string(i) + " is " + Num(d.distortion[i]) +
                                        ", expected |value| <= 100");
    if (rig.uncalibrated) return;
    const double z = d.world_from_device.translation.z();
    if (!(z > 0))
      p.Fail(key + ".world_from_device",
             "the device is at z = " + Num(z) +
                 " m, expected above the mount plane (z > 0, +z towards the rig)");
  };
  device(rig.camera, "rig.camera");
  device(rig.projector, "rig.projector");
  for (const auto& [r, key] : {std::pair{&rig.camera_response, "rig.camera.response"},
                               std::pair{&rig.projector_response, "rig.projector.response"}})
    if (r->kind == Response::Kind::kGamma && !(r->gamma >= 0.05 && r->gamma <= 20))
      p.Fail(key, "gamma " + Num(r->gamma) + ", expected a value in [0.05, 20]");
  if (!rig.uncalibrated) {
    const double baseline =
        (rig.projector.world_from_device.translation - rig.camera.world_from_device.translation)
            .norm();
    if (!(baseline >= 0.5e-3))
      p.Fail("rig.projector.world_from_device",
             "the projector is " + Num(baseline * 1e3) +
                 " mm from the camera, expected a baseline of at least 0.5 mm to triangulate");
  }
  if (rig.lens_shifter) {
    const LensShifter& ls = *rig.lens_shifter;
    const int extent = ls.axis == 'y' ? rig.projector.height : rig.projector.width;
    const double span =
        (static_cast<double>(ls.range_steps[1]) - ls.range_steps[0]) / ls.steps_per_px;
    if (!(span <= extent))
      p.Fail("rig.lens_shifter", "range_steps / steps_per_px spans " + Num(span) +
                                     " projector px, expected at most the projector's " +
                                     (ls.axis == 'y' ? "height (" : "width (") +
                                     std::to_string(extent) +
                                     " px): steps_per_px too small or range_steps too wide?");
  }
}

}  // namespace

Session ParseSession(const Json& j, const fs::path& root, const std::string& file_label) {
  const Parser p(file_label);
  if (!j.is_object())
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(file_label), "expected a JSON object at the top level");
  Session s;
  s.root = root;

  // format: mesoscan-session/1 or a 1.x minor version.
  const std::string format_expected = "\"" + std::string(kSessionFormat) + "\" (or a 1.x minor)";
  const std::string format =
      p.String(p.Require(j, "", "format", format_expected), "format", format_expected);
  if (!IsSupportedFormat(format)) p.Expected("format", format_expected, j["format"]);
  if (const Json* v = Parser::Find(j, "created")) s.created = p.String(*v, "created", "a string");
  if (const Json* v = Parser::Find(j, "object")) s.object = p.String(*v, "object", "a string");

  // rig
  const Json& rig = p.RequireObject(j, "", "rig", "an object with camera and projector");
  const Json& cam = p.RequireObject(rig, "rig", "camera", "an object");
  s.rig.camera = p.Device(cam, "rig.camera", &s.rig.uncalibrated);
  s.rig.camera_response = p.ReadResponse(cam, "rig.camera", /*allow_srgb=*/true);
  if (const Json* v = Parser::Find(cam, "black_level")) {
    const std::string expected = "a finite number in [0, 1)";
    s.rig.black_level = p.Number(*v, "rig.camera.black_level", expected);
    if (s.rig.black_level < 0 || s.rig.black_level >= 1)
      p.Expected("rig.camera.black_level", expected, *v);
  }
  const Json& proj = p.RequireObject(rig, "rig", "projector", "an object");
  s.rig.projector = p.Device(proj, "rig.projector", &s.rig.uncalibrated);
  s.rig.projector_response = p.ReadResponse(proj, "rig.projector", /*allow_srgb=*/false);
  if (const Json* v = Parser::Find(proj, "falloff")) {
    const std::string expected = "an object {\"radial\": f} with f a number in [0, 0.5)";
    if (!v->is_object()) p.Expected("rig.projector.falloff", expected, *v);
    s.rig.projector_falloff = p.Number(p.Require(*v, "rig.projector.falloff", "radial", expected),
                                       "rig.projector.falloff.radial", expected);
    if (!(s.rig.projector_falloff >= 0 && s.rig.projector_falloff < 0.5))
      p.Expected("rig.projector.falloff.radial", expected, (*v)["radial"]);
  }
  if (const Json* ls = Parser::Find(rig, "lens_shifter")) {
    const std::string ls_expected = "an object with axis, steps_per_px and range_steps";
    if (!ls->is_object()) p.Expected("rig.lens_shifter", ls_expected, *ls);
    LensShifter shifter;
    shifter.axis = p.Axis(*ls, "rig.lens_shifter");
    const std::string spp = "a finite number > 0";
    shifter.steps_per_px = p.Number(p.Require(*ls, "rig.lens_shifter", "steps_per_px", spp),
                                    "rig.lens_shifter.steps_per_px", spp);
    if (!(shifter.steps_per_px > 0))
      p.Expected("rig.lens_shifter.steps_per_px", spp, (*ls)["steps_per_px"]);
    const std::string range_expected = "[min, max], two integers with min < max";
    const Json& range = p.Require(*ls, "rig.lens_shifter", "range_steps", range_expected);
    if (!range.is_array() || range.size() != 2)
      p.Fail("rig.lens_shifter.range_steps", "expected " + range_expected);
    for (int i = 0; i < 2; ++i)
      shifter.range_steps[i] = static_cast<int>(
          p.Integer(range[i], "rig.lens_shifter.range_steps", std::numeric_limits<int>::min(),
                    std::numeric_limits<int>::max(), range_expected));
    if (shifter.range_steps[0] >= shifter.range_steps[1])
      p.Fail("rig.lens_shifter.range_steps", "expected " + range_expected);
    s.rig.lens_shifter = shifter;
  }
  CheckRigGeometry(p, s.rig);

  // frames
  const std::string frames_expected = "a non-empty array of frames";
  const Json& frames = p.Require(j, "", "frames", frames_expected);
  if (!frames.is_array() || frames.empty()) p.Expected("frames", frames_expected, frames);
  std::map<fs::path, size_t> seen;  // normalised path -> first frame index
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string key = Index("frames", i);
    const Json& fj = frames[i];
    if (!fj.is_object()) p.Expected(key, "an object with file, pattern and shift_steps", fj);
    Frame f;
    f.file = p.RelativePath(fj, key, "file", "the frame image");
    const fs::path norm = fs::path(f.file).lexically_normal();
    auto [it, inserted] = seen.emplace(norm, i);
    if (!inserted)
      p.Fail(Join(key, "file"), Quote(f.file) + " is also " + Index("frames", it->second) +
                                    ".file, expected each frame file once");

    const std::string pkey = Join(key, "pattern");
    const Json& pj = p.RequireObject(fj, key, "pattern", "an object with type");
    const std::string types = "\"sine\", \"stripes\", \"graycode\", \"white\" or \"black\"";
    const std::string type =
        p.String(p.Require(pj, pkey, "type", types), Join(pkey, "type"), types);
    if (type == "sine") {
      f.pattern.type = PatternType::kSine;
    } else if (type == "stripes") {
      f.pattern.type = PatternType::kStripes;
    } else if (type == "white") {
      f.pattern.type = PatternType::kWhite;
    } else if (type == "black") {
      f.pattern.type = PatternType::kBlack;
    } else if (type == "graycode") {
      f.pattern.type = PatternType::kGrayCode;
      f.pattern.axis = p.Axis(pj, pkey);
      const std::string bits_expected = "an integer in [1, 30]";
      f.pattern.bits = static_cast<int>(p.Integer(p.Require(pj, pkey, "bits", bits_expected),
                                                  Join(pkey, "bits"), 1, 30, bits_expected));
      const std::string bit_expected = "an integer in [0, bits - 1]";
      f.pattern.bit =
          static_cast<int>(p.Integer(p.Require(pj, pkey, "bit", bit_expected), Join(pkey, "bit"), 0,
                                     f.pattern.bits - 1, bit_expected));
      const std::string block_expected = "a finite number >= 1 (projector px)";
      const Json& bv = p.Require(pj, pkey, "block_px", block_expected);
      f.pattern.block_px = p.Number(bv, Join(pkey, "block_px"), block_expected);
      if (!(f.pattern.block_px >= 1)) p.Expected(Join(pkey, "block_px"), block_expected, bv);
      if (const Json* inv = Parser::Find(pj, "inverted")) {
        if (!inv->is_boolean()) p.Expected(Join(pkey, "inverted"), "true or false", *inv);
        f.pattern.inverted = inv->get<bool>();
      }
    } else {
      p.Expected(Join(pkey, "type"), types, pj["type"]);
    }
    if (type == "sine" || type == "stripes") {
      f.pattern.axis = p.Axis(pj, pkey);
      const std::string period_expected = type == "sine" ? "a finite number > 2 (projector px)"
                                                         : "a finite number >= 2 (projector px)";
      const Json& pv = p.Require(pj, pkey, "period_px", period_expected);
      f.pattern.period_px = p.Number(pv, Join(pkey, "period_px"), period_expected);
      if (type == "sine" ? !(f.pattern.period_px > 2) : !(f.pattern.period_px >= 2))
        p.Expected(Join(pkey, "period_px"), period_expected, pv);
    }
    if (type == "sine") {
      const std::string phase_expected = "a finite number (radians)";
      f.pattern.phase = p.Number(p.Require(pj, pkey, "phase", phase_expected), Join(pkey, "phase"),
                                 phase_expected);
    }

    const std::string skey = Join(key, "shift_steps");
    const std::string int_expected = "an integer (lens-shifter steps)";
    f.shift_steps = static_cast<int>(p.Integer(p.Require(fj, key, "shift_steps", int_expected),
                                               skey, std::numeric_limits<int>::min(),
                                               std::numeric_limits<int>::max(), int_expected));
    if (s.rig.lens_shifter) {
      const auto& r = s.rig.lens_shifter->range_steps;
      if (f.shift_steps < r[0] || f.shift_steps > r[1])
        p.Expected(skey,
                   "a value within rig.lens_shifter.range_steps [" + std::to_string(r[0]) + ", " +
                       std::to_string(r[1]) + "]",
                   fj["shift_steps"]);
    } else if (f.pattern.IsLensShift()) {
      p.Fail("rig.lens_shifter",
             "missing, expected it because " + key + " is a lens-shift (stripes) frame");
    } else if (f.shift_steps != 0) {
      p.Expected(skey, "0 without a rig.lens_shifter", fj["shift_steps"]);
    }
    if (f.pattern.IsLensShift() && f.pattern.axis != s.rig.lens_shifter->axis)
      p.Expected(Join(pkey, "axis"),
                 "\"" + std::string(1, s.rig.lens_shifter->axis) +
                     "\" (rig.lens_shifter.axis) for a lens-shift frame",
                 pj["axis"]);
    s.frames.push_back(f);
  }

  // Can the frames decode? Phase shift: >= 3 distinct phases per period (offset, amplitude and
  // phase are unknown) and a period set whose phase tuple is unique across the projector.
  const FramePlan plan = MakeFramePlan(s.frames);
  for (const auto& set : plan.sine) {
    if (set.phases.size() < 3)
      p.Fail("frames", "sine period " + Num(set.period_px) + " px (axis " + set.axis + ") has " +
                           std::to_string(set.phases.size()) +
                           " distinct phases, expected at least 3");
  }
  // Gray code: each set (axis, bits, block_px) covers the projector and has every bit; a set along
  // an axis gives the order of that axis' sine period (one period: e.g. sine + complementary
  // Gray code).
  bool graycode_along[2] = {false, false};
  {
    std::map<std::tuple<char, int, double>, std::vector<int>> sets;  // -> frames per bit
    for (size_t i : plan.graycode) {
      const Pattern& gp = s.frames[i].pattern;
      auto& bits = sets[{gp.axis, gp.bits, gp.block_px}];
      bits.resize(gp.bits, 0);
      ++bits[gp.bit];
    }
    for (const auto& [key, bits] : sets) {
      const auto& [axis, nbits, block] = key;
      const int extent = axis == 'x' ? s.rig.projector.width : s.rig.projector.height;
      const std::string what = "Gray code along " + std::string(1, axis) + " (" +
                               std::to_string(nbits) + " bits, block_px " + Num(block) + ")";
      if (block * std::ldexp(1.0, nbits) < extent)
        p.Fail("frames", what + " covers " + Num(block * std::ldexp(1.0, nbits)) +
                             " px, expected block_px * 2^bits >= the projector's " +
                             std::to_string(extent) + " px");
      for (int k = 0; k < nbits; ++k)
        if (bits[k] == 0)
          p.Fail("frames", what + " has no frame of bit " + std::to_string(k) +
                               ", expected every bit (alone or with its inverse)");
      graycode_along[axis == 'x' ? 0 : 1] = true;
    }
  }
  for (char axis : {'x', 'y'}) {
    const std::vector<double> periods = plan.Periods(axis);
    if (periods.empty()) continue;
    const int extent = axis == 'x' ? s.rig.projector.width : s.rig.projector.height;
    const double range = UnambiguousRangePx(periods, extent);
    if (range < extent && periods.size() == 1 && graycode_along[axis == 'x' ? 0 : 1]) continue;
    if (range < extent) {
      std::string list;
      for (double q : periods) list += (list.empty() ? "" : ", ") + Num(q);
      p.Fail("frames", "sine periods " + list + " px (axis " + axis + ") repeat after " +
                           Num(range) +
                           " px, expected an unambiguous range covering the projector " +
                           (axis == 'x' ? "width " : "height ") + std::to_string(extent) +
                           " px (e.g. coprime periods with LCM >= " + std::to_string(extent) +
                           ", or a period >= " + std::to_string(extent) + ")");
    }
  }
  // Lens shift (Ritz et al. 2012): offset, amplitude, phase and frequency of each pixel's
  // sinusoid over the shift are fitted, so at least 4 frames at 4 distinct positions.
  if (!plan.lens_shift.empty() && plan.lens_shift.size() < 4)
    p.Fail("frames", std::to_string(plan.lens_shift.size()) +
                         " lens-shift (stripes) frames, expected none or at least 4");
  if (!plan.lens_shift.empty() && plan.distinct_shift_steps < 4)
    p.Fail("frames", "lens-shift frames at " + std::to_string(plan.distinct_shift_steps) +
                         " distinct shift_steps, expected at least 4");

  // ground_truth (simulated sessions)
  if (const Json* gt = Parser::Find(j, "ground_truth")) {
    const std::string gt_expected = "an object with \"points\" and/or \"height\" paths";
    if (!gt->is_object() || (!Parser::Find(*gt, "points") && !Parser::Find(*gt, "height")))
      p.Expected("ground_truth", gt_expected, *gt);
    GroundTruth g;
    if (Parser::Find(*gt, "points"))
      g.points = p.RelativePath(*gt, "ground_truth", "points", "an EXR with channels X, Y, Z");
    if (Parser::Find(*gt, "height"))
      g.height = p.RelativePath(*gt, "ground_truth", "height", "a height EXR");
    s.ground_truth = g;
  }

  // Unknown top-level keys are kept so that a rewrite loses nothing.
  static const std::set<std::string> kKnown = {"format", "created", "object",
                                               "rig",    "frames",  "ground_truth"};
  for (auto it = j.begin(); it != j.end(); ++it)
    if (!kKnown.count(it.key())) s.extra[it.key()] = it.value();
  return s;
}

std::vector<ImageInfo> CheckSessionFiles(const Session& s) {
  const int w = s.rig.camera.width, h = s.rig.camera.height;
  const size_t n = s.frames.size();
  std::vector<ImageInfo> infos(n);
  std::vector<std::string> errors(n);
  // Headers only, in parallel; the first failing frame in session order is reported so the
  // message does not depend on thread timing.
  ParallelFor(static_cast<int64_t>(n), [&](int64_t i) {
    const Frame& f = s.frames[i];
    try {
      ImageInfo info =
          ReadInfoLabelled(s.FramePath(i), f.file, Index("frames", i) + ".file", s.root);
      const bool raw = IsRawExtension(f.file);
      const bool ok = raw ? (info.width / 2 == w && info.height / 2 == h)
                          : (info.width == w && info.height == h);
      if (!ok)
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(f.file),
                              "size " << info.width << "x" << info.height << ", expected "
                                      << (raw ? 2 * w : w) << "x" << (raw ? 2 * h : h)
                                      << " (rig.camera.width/height" << (raw ? ", raw: twice" : "")
                                      << ")");
      infos[i] = std::move(info);
    } catch (const Error& e) {
      errors[i] = e.what();
    }
  });
  for (const std::string& e : errors)
    if (!e.empty()) throw Error(e, ErrorKind::kBadInput);

  size_t eight_bit = 0, first_eight_bit = 0;
  for (size_t i = 0; i < n; ++i)
    if (!infos[i].is_float && infos[i].bits_per_sample <= 8 && eight_bit++ == 0)
      first_eight_bit = i;
  if (eight_bit > 0)
    MESOSCAN_LOG(kWarning) << s.frames[first_eight_bit].file << ": " << eight_bit << " of " << n
                           << " frames are 8-bit; 16-bit or float frames keep phase precision";

  if (s.ground_truth) {
    const auto check_gt = [&](const std::string& rel, const char* key,
                              const std::vector<std::string>& channels, bool camera_grid) {
      if (rel.empty()) return;
      const std::string k = std::string("ground_truth.") + key;
      const ImageInfo info = ReadInfoLabelled(s.root / rel, rel, k, s.root);
      for (const std::string& c : channels)
        if (std::find(info.channel_names.begin(), info.channel_names.end(), c) ==
            info.channel_names.end())
          MESOSCAN_BAD_INPUT_AT(ErrorSite::File(rel),
                                "missing channel '" << c << "' (" << k << ")");
      if (camera_grid && (info.width != w || info.height != h))
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(rel), "size " << info.width << "x" << info.height
                                                            << ", expected " << w << "x" << h
                                                            << " (rig.camera.width/height)");
    };
    check_gt(s.ground_truth->points, "points", {"X", "Y", "Z"}, true);
    check_gt(s.ground_truth->height, "height", {"Z"}, false);
  }
  return infos;
}

std::string SessionTimeNow() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

Rig LoadRigFile(const fs::path& path) {
  const Json j = ReadJsonFile(path);
  if (!j.is_object() || !j.contains("rig") || !j["rig"].is_object())
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "rig: expected an object (the session format's rig)");
  // Parse through the session parser so the rig is validated exactly as in a session.
  Json wrapper = {{"format", kSessionFormat},
                  {"rig", j["rig"]},
                  {"frames", Json::array({{{"file", "frames/white.png"},
                                           {"pattern", {{"type", "white"}}},
                                           {"shift_steps", 0}}})}};
  return ParseSession(wrapper, path.parent_path(), path.string()).rig;
}

Session ReadSession(const fs::path& dir, bool check_frames) {
  RestoreInterruptedReplacement(dir);
  fs::path root = dir;
  std::error_code ec;
  if (fs::is_regular_file(dir, ec) && dir.extension() == ".json") root = dir.parent_path();
  const fs::path manifest = fs::is_regular_file(dir, ec) ? dir : dir / "session.json";
  if (!fs::exists(manifest, ec)) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(manifest), "file not found");
  const std::string label = manifest.filename().string();

  if (fs::is_directory(manifest, ec))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "cannot read (a folder)");
  if (!fs::is_regular_file(manifest, ec))  // a FIFO or a device would block or never end
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "cannot read (not a regular file)");
  std::string text;
  {
    errno = 0;
    std::ifstream in(manifest, std::ios::binary);
    if (!in)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label),
                            "cannot read (" << (errno ? std::strerror(errno) : "unknown") << ")");
    std::ostringstream ss;
    ss << in.rdbuf();
    text = ss.str();
  }
  CheckJsonDepth(text, label);
  Json j;
  try {
    j = Json::parse(text);
  } catch (const Json::parse_error& e) {
    const auto [line, col] = LineColumn(text, e.byte);
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "not valid JSON (syntax error at line "
                                                      << line << ", column " << col << ")");
  } catch (const Json::exception& e) {  // e.g. a number beyond double range (K = 1e999)
    std::string what = e.what();
    if (const size_t close = what.find("] "); close != std::string::npos)
      what = what.substr(close + 2);
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "not valid JSON (" << what << ")");
  }
  Session s =
      ParseSession(j, fs::absolute(root.empty() ? fs::path(".") : root).lexically_normal(), label);
  if (check_frames) CheckSessionFiles(s);
  return s;
}

double ProjectorFalloff(const Rig& rig, double u, double v) {
  if (rig.projector_falloff == 0) return 1.0;
  const PinholeCamera& p = rig.projector;
  const double un = (u - p.K(0, 2)) / (0.5 * p.width), vn = (v - p.K(1, 2)) / (0.5 * p.height);
  return 1.0 - rig.projector_falloff * (un * un + vn * vn);
}

Json SessionToJson(const Session& s) {
  Json j;
  j["format"] = kSessionFormat;
  if (!s.created.empty()) j["created"] = s.created;
  if (!s.object.empty()) j["object"] = s.object;
  Json cam = DeviceToJson(s.rig.camera);
  cam["response"] = ResponseToJson(s.rig.camera_response);
  cam["black_level"] = s.rig.black_level;
  Json proj = DeviceToJson(s.rig.projector);
  if (s.rig.uncalibrated)  // a calibration session: the devices' sizes only
    for (Json* d : {&cam, &proj})
      for (const char* k : {"K", "distortion", "world_from_device"}) d->erase(k);
  proj["response"] = ResponseToJson(s.rig.projector_response);
  if (s.rig.projector_falloff != 0) proj["falloff"] = {{"radial", s.rig.projector_falloff}};
  j["rig"] = {{"camera", cam}, {"projector", proj}};
  if (s.rig.lens_shifter) {
    const LensShifter& ls = *s.rig.lens_shifter;
    j["rig"]["lens_shifter"] = {{"axis", std::string(1, ls.axis)},
                                {"steps_per_px", ls.steps_per_px},
                                {"range_steps", {ls.range_steps[0], ls.range_steps[1]}}};
  }
  Json frames = Json::array();
  for (const Frame& f : s.frames) {
    Json pattern;
    switch (f.pattern.type) {
      case PatternType::kSine:
        pattern = {{"type", "sine"},
                   {"axis", std::string(1, f.pattern.axis)},
                   {"period_px", f.pattern.period_px},
                   {"phase", f.pattern.phase}};
        break;
      case PatternType::kStripes:
        pattern = {{"type", "stripes"},
                   {"axis", std::string(1, f.pattern.axis)},
                   {"period_px", f.pattern.period_px}};
        break;
      case PatternType::kWhite:
        pattern = {{"type", "white"}};
        break;
      case PatternType::kBlack:
        pattern = {{"type", "black"}};
        break;
      case PatternType::kGrayCode:
        pattern = {{"type", "graycode"},
                   {"axis", std::string(1, f.pattern.axis)},
                   {"bits", f.pattern.bits},
                   {"bit", f.pattern.bit},
                   {"block_px", f.pattern.block_px},
                   {"inverted", f.pattern.inverted}};
        break;
    }
    frames.push_back(Json{{"file", f.file}, {"pattern", pattern}, {"shift_steps", f.shift_steps}});
  }
  j["frames"] = frames;
  if (s.ground_truth) {
    Json gt = Json::object();
    if (!s.ground_truth->points.empty()) gt["points"] = s.ground_truth->points;
    if (!s.ground_truth->height.empty()) gt["height"] = s.ground_truth->height;
    j["ground_truth"] = gt;
  }
  if (s.extra.is_object())
    for (auto it = s.extra.begin(); it != s.extra.end(); ++it)
      if (!j.contains(it.key())) j[it.key()] = it.value();
  return j;
}

void WriteSessionJson(const Session& s) {
  const Json j = SessionToJson(s);
  // A writer must never produce a session its own reader refuses: validate first.
  ParseSession(j, s.root, (s.root / "session.json").string());
  WriteJsonFile(s.root / "session.json", j);
}

}  // namespace mesoscan
