// A stress sweep of the rule "no point with confidence > 0 lies more than 10 predicted sigmas
// (and never more than 100 um) from the truth" on small simulated coin sessions: mislabelled
// frames of each kind, cue-only period sets with and without lens shift, exposure down to 0.02
// in 8 and 16 bits, ambient light up to 20 times the projector's. Prints one table row per case
// (points kept, the worst |error| / predicted sigma, the worst |error|, the largest confidence
// of a point breaking the rule) and fails on any such point. A capture refused with an Error
// keeps no point (and passes).

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "core/image_io.h"
#include "core/json.h"
#include "core/progress.h"
#include "core/test_temp_dir.h"
#include "heightfield/reconstruct.h"
#include "session/session.h"
#include "sim/ground_truth.h"
#include "sim/virtual_rig.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

struct Row {
  std::string name;
  bool refused = false;
  std::string why;
  int64_t kept = 0;
  double max_z = 0, max_abs_um = 0, bad_conf = 0;
  int64_t bad = 0;
};

SimulateOptions Base() {
  SimulateOptions so;
  so.object = "coin";
  so.crop = PixelRect{1000, 700, 128, 96};
  so.seed = 1;
  return so;
}

// Reconstructs `dir` (after `mutate` edits the session folder) and scores it.
Row Score(const std::string& name, const fs::path& dir,
          const std::function<void(const fs::path&)>& mutate = {}) {
  Row row;
  row.name = name;
  if (mutate) mutate(dir);
  try {
    const Session s = ReadSession(dir);
    ReconstructOptions ro;
    ro.keep_diagnostics = true;
    ReconstructSummary sum;
    const Scan scan = Reconstruct(s, ro, &sum);
    const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, scan.points);
    const ReconstructDiagnostics& d = sum.diagnostics;
    for (int y = 0; y < e.error.height(); ++y)
      for (int x = 0; x < e.error.width(); ++x) {
        const float c = scan.points.confidence(x, y);
        if (!(c > 0)) continue;
        ++row.kept;
        const double err = e.error(x, y);
        const double sz = d.sigma_u(x, y) * std::abs(d.dz_du(x, y));
        const double z = std::isfinite(err) && sz > 0 ? std::abs(err) / sz
                                                      : std::numeric_limits<double>::infinity();
        if (!std::isfinite(err)) continue;  // no ground truth at this pixel
        row.max_z = std::max(row.max_z, z);
        row.max_abs_um = std::max(row.max_abs_um, std::abs(err) * 1e6);
        if (z > 10 || std::abs(err) > 100e-6) {
          ++row.bad;
          row.bad_conf = std::max<double>(row.bad_conf, c);
        }
      }
  } catch (const Error& e) {
    row.refused = true;
    row.why = e.what();
  }
  return row;
}

void Print(const Row& r) {
  if (r.refused) {
    std::printf("| %-44s | refused: %.90s\n", r.name.c_str(), r.why.c_str());
    return;
  }
  std::printf("| %-44s | %6lld | %8.2f | %8.2f | %5lld | %4.2f |\n", r.name.c_str(),
              static_cast<long long>(r.kept), r.max_z, r.max_abs_um, static_cast<long long>(r.bad),
              r.bad_conf);
}

class Sweep : public ::testing::Test {
 protected:
  void SetUp() override { Progress::SetEnabled(false); }
  static fs::path Dir(const std::string& name) { return TestTempPath("sweep", name); }
  static void Check(const std::vector<Row>& rows) {
    std::printf(
        "| case                                         | points | max e/sd | max |e| um | bad   "
        "| conf |\n");
    for (const Row& r : rows) {
      Print(r);
      EXPECT_EQ(r.bad, 0) << r.name << ": " << r.bad << " points break the rule, confidence up to "
                          << r.bad_conf;
    }
  }
};

// The sine frames of period `period` (session order).
std::vector<std::string> SineFrames(const fs::path& dir, double period) {
  std::vector<std::string> out;
  const Json session_json = ReadJsonFile(dir / "session.json");
  for (const Json& f : session_json["frames"])
    if (f["pattern"]["type"] == "sine" && f["pattern"]["period_px"].get<double>() == period)
      out.push_back(f["file"]);
  return out;
}

TEST_F(Sweep, MislabelledFrames) {
  const fs::path clean = Dir("clean");
  Simulate(Base(), clean);
  SimulateOptions other = Base();
  other.object = "plane";
  other.ls_frames = 0;
  const fs::path plane = Dir("plane");
  Simulate(other, plane);
  const auto copy = [&](const std::string& n) {
    const fs::path d = Dir(n);
    fs::remove_all(d);
    fs::copy(clean, d, fs::copy_options::recursive);
    return d;
  };
  std::vector<Row> rows;
  rows.push_back(Score("good session", clean));
  for (const double p : {7.0, 11.0, 13.0}) {
    const std::string per = std::to_string(static_cast<int>(p));
    rows.push_back(Score("phase frames 0<->1 swapped, period " + per, copy("swap" + per),
                         [&](const fs::path& d) {
                           const auto f = SineFrames(d, p);
                           fs::rename(d / f[0], d / "t.png");
                           fs::rename(d / f[1], d / f[0]);
                           fs::rename(d / "t.png", d / f[1]);
                         }));
    rows.push_back(
        Score("frame 0 copied over 2, period " + per, copy("copy" + per), [&](const fs::path& d) {
          const auto f = SineFrames(d, p);
          fs::copy_file(d / f[0], d / f[2], fs::copy_options::overwrite_existing);
        }));
    rows.push_back(Score(
        "frame 1 of another object, period " + per, copy("foreign" + per), [&](const fs::path& d) {
          const auto f = SineFrames(d, p);
          fs::copy_file(plane / f[1], d / f[1], fs::copy_options::overwrite_existing);
        }));
    rows.push_back(Score("phases 0 and 2 listed swapped, period " + per, copy("phase" + per),
                         [&](const fs::path& d) {
                           Json j = ReadJsonFile(d / "session.json");
                           std::vector<Json*> fr;
                           for (Json& f : j["frames"])
                             if (f["pattern"]["type"] == "sine" &&
                                 f["pattern"]["period_px"].get<double>() == p)
                               fr.push_back(&f);
                           std::swap((*fr[0])["pattern"]["phase"], (*fr[2])["pattern"]["phase"]);
                           WriteJsonFile(d / "session.json", j);
                         }));
    rows.push_back(Score("float EXR frame in 0..65535, period " + per, copy("units" + per),
                         [&](const fs::path& d) {
                           const auto f = SineFrames(d, p);
                           ImageF im = ReadImage(d / f[1]);
                           for (float& v : im.data()) v *= 65535.0f;
                           const std::string exr = fs::path(f[1]).replace_extension(".exr");
                           WriteExr(d / exr, im, {"Y"});
                           Json j = ReadJsonFile(d / "session.json");
                           for (Json& fr : j["frames"])
                             if (fr["file"] == f[1]) fr["file"] = exr;
                           WriteJsonFile(d / "session.json", j);
                         }));
  }
  for (const auto& [a, b] : {std::pair{7.0, 11.0}, std::pair{11.0, 13.0}, std::pair{7.0, 13.0}})
    rows.push_back(Score(
        "period labels " + std::to_string(int(a)) + " <-> " + std::to_string(int(b)) + " swapped",
        copy("labels"), [&](const fs::path& d) {
          Json j = ReadJsonFile(d / "session.json");
          for (Json& f : j["frames"]) {
            if (f["pattern"]["type"] != "sine") continue;
            const double q = f["pattern"]["period_px"];
            if (q == a) f["pattern"]["period_px"] = b;
            if (q == b) f["pattern"]["period_px"] = a;
          }
          WriteJsonFile(d / "session.json", j);
        }));
  rows.push_back(Score("two lens-shift frames swapped", copy("ls_swap"), [&](const fs::path& d) {
    std::vector<std::string> ls;
    const Json session_json = ReadJsonFile(d / "session.json");
    for (const Json& f : session_json["frames"])
      if (f["pattern"]["type"] == "stripes") ls.push_back(f["file"]);
    fs::rename(d / ls[10], d / "t.png");
    fs::rename(d / ls[30], d / ls[10]);
    fs::rename(d / "t.png", d / ls[30]);
  }));
  Check(rows);
}

TEST_F(Sweep, CueOnlyPeriods) {
  std::vector<Row> rows;
  for (const std::vector<double>& periods :
       {std::vector<double>{800}, std::vector<double>{1000, 1100}, std::vector<double>{800, 50}})
    for (const int ls : {50, 0}) {
      SimulateOptions so = Base();
      so.ps_periods_px = periods;
      so.ls_frames = ls;
      std::string name = "periods";
      for (double p : periods) {
        name += ' ';
        name += std::to_string(static_cast<int>(p));
      }
      name += ls ? ", lens shift" : ", no lens shift";
      const fs::path d = Dir("cue");
      Simulate(so, d);
      rows.push_back(Score(name, d));
    }
  Check(rows);
}

TEST_F(Sweep, DarkAndAmbient) {
  std::vector<Row> rows;
  for (const int bits : {8, 16})
    for (const auto& [exposure, ambient] :
         {std::pair{0.02, 0.03}, std::pair{0.04, 0.03}, std::pair{0.08, 0.03},
          std::pair{0.08, 10.0}, std::pair{0.045, 20.0}}) {
      SimulateOptions so = Base();
      so.adc_bits = bits;
      so.exposure = exposure;
      so.ambient = ambient;
      so.blur_sigma_px = 1.0;
      so.gain_jitter = 0.02;
      char name[96];
      std::snprintf(name, sizeof(name), "%d-bit, exposure %.3f, ambient %g", bits, exposure,
                    ambient);
      const fs::path d = Dir("dark");
      Simulate(so, d);
      rows.push_back(Score(name, d));
    }
  Check(rows);
}

}  // namespace
}  // namespace mesoscan
