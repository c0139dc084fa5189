#include "session/session.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <limits>
#include <random>

#include "core/fs.h"
#include "core/image_io.h"
#include "session/patterns.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

constexpr int kCamW = 8, kCamH = 6;

// A small valid session: camera 8x6, projector 60x40, periods 7 and 11 (LCM 77 >= 60) x 3
// phases, 4 lens-shift frames, white, black.
Session SmallSession(const fs::path& root) {
  Session s;
  s.root = root;
  s.created = "2026-11-21T12:00:00Z";
  s.object = "test";
  s.rig.camera.width = kCamW;
  s.rig.camera.height = kCamH;
  s.rig.camera.K << 100, 0, 3.5, 0, 100, 2.5, 0, 0, 1;
  s.rig.camera.world_from_device.rotation = Eigen::Vector3d(1, -1, -1).asDiagonal();
  s.rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  s.rig.projector.width = 60;
  s.rig.projector.height = 40;
  s.rig.projector.K << 200, 0, 29.5, 0, 200, 19.5, 0, 0, 1;
  s.rig.projector.world_from_device = s.rig.camera.world_from_device;
  s.rig.projector.world_from_device.translation = Vec3d(0.05, 0, 0.25);
  s.rig.lens_shifter = LensShifter{'x', 2048, {-2048, 2048}};
  FramePlanOptions plan;
  plan.periods_px = {7, 11};
  plan.lens_shift_frames = 4;
  s.frames = MakeStandardFrames(plan);
  return s;
}

std::string ErrorOf(const std::function<void()>& fn) {
  try {
    fn();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput) << e.what();
    return e.what();
  }
  return "(no error)";
}

class SessionTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() /
                        ("mesoscan_session_test_" + std::to_string(getpid())));
    fs::remove_all(*dir_);
    fs::create_directories(*dir_ / "frames");
    const Session s = SmallSession(*dir_);
    const ImageU16 frame(kCamW, kCamH, 1, 30000);
    for (const Frame& f : s.frames) WritePng16(*dir_ / f.file, frame);
    WriteSessionJson(s);
    valid_ = new Json(SessionToJson(s));
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
    delete valid_;
  }

  // Parses a mutated copy of the valid document (no files opened).
  static std::string ParseError(const std::function<void(Json&)>& mutate) {
    Json j = *valid_;
    mutate(j);
    return ErrorOf([&] { ParseSession(j, *dir_); });
  }

  // A fresh copy of the session folder for tests that change files.
  static fs::path CopySession(const std::string& name) {
    const fs::path copy =
        *dir_ / ".." / ("mesoscan_session_copy_" + std::to_string(getpid()) + name);
    fs::remove_all(copy);
    fs::copy(*dir_, copy, fs::copy_options::recursive);
    return copy;
  }

  static fs::path* dir_;
  static Json* valid_;
};
fs::path* SessionTest::dir_ = nullptr;
Json* SessionTest::valid_ = nullptr;

TEST_F(SessionTest, ValidSessionReadsWithFramesChecked) {
  const Session s = ReadSession(*dir_);
  EXPECT_EQ(s.frames.size(), 12u);
  EXPECT_EQ(s.root, fs::absolute(*dir_).lexically_normal());
  EXPECT_EQ(s.rig.camera.width, kCamW);
  ASSERT_TRUE(s.rig.lens_shifter.has_value());
  EXPECT_EQ(s.rig.lens_shifter->steps_per_px, 2048);
  const std::vector<ImageInfo> infos = CheckSessionFiles(s);
  ASSERT_EQ(infos.size(), 12u);
  EXPECT_EQ(infos[0].bits_per_sample, 16);
  // The session.json path itself is accepted too.
  EXPECT_EQ(ReadSession(*dir_ / "session.json").frames.size(), 12u);
}

TEST_F(SessionTest, RoundTripWriteRead) {
  Session s = SmallSession(*dir_);
  s.rig.camera.distortion = {0.01, -0.002, 0.0003, -0.0004, 0.00005};
  s.rig.camera_response.kind = Response::Kind::kSrgb;
  s.rig.black_level = 0.0123456789;
  s.rig.projector_response = {Response::Kind::kGamma, 2.2};
  s.rig.camera.world_from_device =
      Rigid3d::LookAt(Vec3d(0.01, 0.02, 0.25), Vec3d(0, 0, 0), Vec3d(0, 1, 0));
  s.frames[0].pattern.phase = 0.1234567890123;
  s.ground_truth = GroundTruth{"gt_points.exr", ""};
  s.extra["vendor"] = {{"exposure_s", 0.01}};
  const Json j = SessionToJson(s);
  const Session r = ParseSession(j, s.root);
  EXPECT_EQ(SessionToJson(r), j);  // nothing lost, doubles exact
  EXPECT_EQ(r.rig.camera.distortion, s.rig.camera.distortion);
  EXPECT_EQ(r.rig.camera_response.kind, Response::Kind::kSrgb);
  EXPECT_EQ(r.rig.projector_response.gamma, 2.2);
  EXPECT_EQ(r.frames[0].pattern.phase, 0.1234567890123);
  EXPECT_TRUE(r.rig.camera.world_from_device.rotation.isApprox(
      s.rig.camera.world_from_device.rotation, 1e-15));
  EXPECT_EQ(r.extra["vendor"]["exposure_s"], 0.01);
  EXPECT_EQ(r.ground_truth->points, "gt_points.exr");

  // Through the file: WriteSessionJson then ReadSession.
  const fs::path copy = CopySession("roundtrip");
  s.root = copy;
  s.ground_truth.reset();
  WriteSessionJson(s);
  const Session f = ReadSession(copy);
  Json expected = SessionToJson(s);
  EXPECT_EQ(SessionToJson(f), expected);
  fs::remove_all(copy);
}

TEST_F(SessionTest, WriterRefusesInvalidSession) {
  Session s = SmallSession(*dir_ / "nowhere");
  s.frames.resize(2);  // one sine period with 2 phases
  EXPECT_THROW(WriteSessionJson(s), Error);
  EXPECT_FALSE(fs::exists(*dir_ / "nowhere" / "session.json"));
}

TEST_F(SessionTest, UnknownKeysAcceptedAndKept) {
  Json j = *valid_;
  j["vendor_notes"] = "hello";
  j["rig"]["camera"]["serial"] = 1234;
  j["frames"][0]["exposure_s"] = 0.1;
  const Session s = ParseSession(j, *dir_);
  EXPECT_EQ(s.extra["vendor_notes"], "hello");
  EXPECT_EQ(SessionToJson(s)["vendor_notes"], "hello");
}

TEST_F(SessionTest, ConformanceCoinEdgeExample) {
  const fs::path example = fs::path(MESOSCAN_SHARED_DIR) / "spec/examples/coin-edge";
  if (!fs::exists(example / "session.json")) GTEST_SKIP() << "no example at " << example;
  const Session s = ReadSession(example);
  EXPECT_EQ(s.frames.size(), 61u);
  EXPECT_EQ(s.rig.camera.width, 192);
  EXPECT_EQ(s.rig.projector.width, 800);
  ASSERT_TRUE(s.ground_truth.has_value());
  const FramePlan plan = MakeFramePlan(s.frames);
  EXPECT_EQ(plan.Periods('x'), (std::vector<double>{7, 11, 13}));
  for (const auto& set : plan.sine) EXPECT_EQ(set.phases.size(), 3u);
  EXPECT_EQ(plan.lens_shift.size(), 50u);
  EXPECT_EQ(plan.distinct_shift_steps, 50);
  EXPECT_EQ(plan.min_shift_steps, -2048);
  EXPECT_EQ(plan.max_shift_steps, 1966);
  EXPECT_EQ(plan.white.size(), 1u);
  EXPECT_EQ(plan.black.size(), 1u);
  // Our standard plan is the same acquisition: the same patterns in the same order, 50
  // lens-shift positions from -2048. The example spaces them (max - min) / 50 apart (last 1966);
  // the one generator (capture and simulate) spans the shifter's whole range, both ends
  // included, (max - min) / 49 apart (last 2048), as the simulator always has.
  const std::vector<Frame> standard = MakeStandardFrames(FramePlanOptions());
  ASSERT_EQ(standard.size(), s.frames.size());
  for (size_t i = 0; i < standard.size(); ++i) {
    EXPECT_EQ(standard[i].pattern.type, s.frames[i].pattern.type) << i;
    EXPECT_EQ(standard[i].pattern.period_px, s.frames[i].pattern.period_px) << i;
    EXPECT_NEAR(standard[i].pattern.phase, s.frames[i].pattern.phase, 1e-15) << i;
  }
  const FramePlan ours = MakeFramePlan(standard);
  EXPECT_EQ(ours.distinct_shift_steps, plan.distinct_shift_steps);
  EXPECT_EQ(ours.min_shift_steps, plan.min_shift_steps);
  EXPECT_EQ(ours.max_shift_steps, 2048);
}

TEST_F(SessionTest, DescribeFramePlan) {
  Session s = ParseSession(*valid_, *dir_);
  EXPECT_EQ(MakeFramePlan(s.frames).Describe(s.rig),
            "phase shift (axis x): periods 7,11 x 3 phases; unambiguous over 77 px (projector "
            "width 60 px)\n"
            "lens shift: 4 frames at 4 positions over -2048..2048 steps (-1..1 px, axis x)\n"
            "white: yes; black: yes\n");
  Frame extra = s.frames[3];
  extra.file = "frames/ps11_3.png";
  extra.pattern.phase = 1.0;
  s.frames.push_back(extra);
  s.frames.erase(s.frames.end() - 3);  // white
  const std::string d = MakeFramePlan(s.frames).Describe(s.rig);
  EXPECT_NE(d.find("periods 7 x 3,11 x 4 phases"), std::string::npos) << d;
  EXPECT_NE(d.find("white: no (optional: albedo texture); black: yes"), std::string::npos) << d;
}

// ---- One test per reader error, asserting the exact one-line message. ----

TEST_F(SessionTest, ErrorMissingSessionJson) {
  const fs::path nowhere = *dir_ / "no_such_session";
  EXPECT_EQ(ErrorOf([&] { ReadSession(nowhere); }),
            (nowhere / "session.json").string() + ": file not found");
}

TEST_F(SessionTest, ErrorInvalidJson) {
  const fs::path copy = CopySession("badjson");
  WriteTextFile(copy / "session.json", "{\n  \"format\": \"mesoscan-session/1\",\n  \"rig\": }\n");
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "session.json: not valid JSON (syntax error at line 3, column 10)");
  WriteTextFile(copy / "session.json", "");
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "session.json: not valid JSON (syntax error at line 1, column 1)");
  WriteTextFile(copy / "session.json", "[1, 2]");
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "session.json: expected a JSON object at the top level");
  fs::remove_all(copy);
}

TEST_F(SessionTest, ErrorFormatVersion) {
  EXPECT_EQ(ParseError([](Json& j) { j["format"] = "mesoscan-session/2"; }),
            "session.json: format: expected \"mesoscan-session/1\" (or a 1.x minor), got "
            "\"mesoscan-session/2\"");
  EXPECT_EQ(ParseError([](Json& j) { j["format"] = "mesoscan-session/10"; }),
            "session.json: format: expected \"mesoscan-session/1\" (or a 1.x minor), got "
            "\"mesoscan-session/10\"");
  EXPECT_EQ(ParseError([](Json& j) { j.erase("format"); }),
            "session.json: format: missing, expected \"mesoscan-session/1\" (or a 1.x minor)");
  EXPECT_EQ(ParseError([](Json& j) { j["format"] = 1; }),
            "session.json: format: expected \"mesoscan-session/1\" (or a 1.x minor), got 1");
  EXPECT_EQ(ParseError([](Json& j) { j["format"] = "mesoscan-session/1.7"; }), "(no error)");
}

TEST_F(SessionTest, ErrorNonFiniteOrMalformedK) {
  const std::string msg = "session.json: rig.camera.K: expected a 3x3 array of finite numbers";
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"]["K"][0][0] = std::numeric_limits<double>::quiet_NaN();
            }),
            msg);
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"]["K"][1][2] = std::numeric_limits<double>::infinity();
            }),
            msg);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["K"][2].erase(2); }), msg);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["K"] = "eye"; }), msg);
}

// A rig whose devices lack K, distortion or world_from_device is a calibration session (spec
// "Calibration sessions"): accepted, flagged, written back with the devices' sizes only; what is
// present is still validated.
TEST_F(SessionTest, CalibrationSession) {
  Json j = *valid_;
  for (const char* d : {"camera", "projector"})
    for (const char* k : {"K", "distortion", "world_from_device"}) j["rig"][d].erase(k);
  const Session s = ParseSession(j, *dir_);
  EXPECT_TRUE(s.rig.uncalibrated);
  EXPECT_EQ(s.rig.camera.width, (*valid_)["rig"]["camera"]["width"].get<int>());
  const Json back = SessionToJson(s);
  EXPECT_FALSE(back["rig"]["camera"].contains("K"));
  EXPECT_FALSE(back["rig"]["projector"].contains("world_from_device"));
  EXPECT_TRUE(ParseSession(back, *dir_).rig.uncalibrated);
  EXPECT_FALSE(ParseSession(*valid_, *dir_).rig.uncalibrated);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"].erase("K"); }), "(no error)");
  // An initial guess present but malformed is still refused.
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"].erase("world_from_device");
              j["rig"]["camera"]["K"] = "eye";
            }),
            "session.json: rig.camera.K: expected a 3x3 array of finite numbers");
}

TEST_F(SessionTest, ErrorSingularK) {
  const std::string msg =
      "session.json: rig.projector.K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx > 0 "
      "and fy > 0 (a non-singular pinhole matrix)";
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["projector"]["K"][1][1] = 0; }), msg);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["projector"]["K"][2][2] = 0; }), msg);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["projector"]["K"][0][0] = -100; }), msg);
}

TEST_F(SessionTest, ErrorPose) {
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"]["world_from_device"][0][3] =
                  std::numeric_limits<double>::quiet_NaN();
            }),
            "session.json: rig.camera.world_from_device: expected a 4x4 array of finite numbers");
  const std::string rigid =
      "session.json: rig.camera.world_from_device: expected a rigid transform (orthonormal "
      "rotation with det +1, last row [0, 0, 0, 1])";
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["world_from_device"][0][0] = 2.0; }),
            rigid);
  EXPECT_EQ(ParseError([](Json& j) {  // a reflection: det -1
              j["rig"]["camera"]["world_from_device"][0][0] = -1.0;
            }),
            rigid);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["world_from_device"][3][0] = 0.5; }),
            rigid);
  // 6-decimal rotations are accepted and made exactly orthonormal.
  Json j = *valid_;
  const double c = std::cos(0.3), s = std::sin(0.3);
  const double c6 = std::round(c * 1e6) / 1e6, s6 = std::round(s * 1e6) / 1e6;
  j["rig"]["camera"]["world_from_device"] = {
      {c6, 0, s6, 0}, {0, 1, 0, 0}, {-s6, 0, c6, 0.25}, {0, 0, 0, 1}};
  const Mat3d r = ParseSession(j, *dir_).rig.camera.world_from_device.rotation;
  EXPECT_LT((r * r.transpose() - Mat3d::Identity()).cwiseAbs().maxCoeff(), 1e-14);
}

TEST_F(SessionTest, ErrorDistortion) {
  const std::string msg =
      "session.json: rig.camera.distortion: expected 5 finite numbers [k1, k2, p1, p2, k3]";
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["distortion"] = {0, 0, 0, 0}; }), msg);
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"]["distortion"][4] = std::numeric_limits<double>::infinity();
            }),
            msg);
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["distortion"][1] = "0"; }), msg);
}

TEST_F(SessionTest, ErrorResponse) {
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["response"] = "log"; }),
            "session.json: rig.camera.response: expected \"linear\", \"srgb\" or {\"gamma\": g} "
            "with finite g > 0, got \"log\"");
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"]["response"] = {{"gamma", -1}};
            }),
            "session.json: rig.camera.response: expected \"linear\", \"srgb\" or {\"gamma\": g} "
            "with finite g > 0");
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["projector"]["response"] = "srgb"; }),
            "session.json: rig.projector.response: expected \"linear\" or {\"gamma\": g} with "
            "finite g > 0, got \"srgb\"");
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["black_level"] = 1.5; }),
            "session.json: rig.camera.black_level: expected a finite number in [0, 1), got 1.5");
  // Optional keys may be absent.
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["camera"].erase("response");
              j["rig"]["camera"].erase("black_level");
              j["rig"]["projector"].erase("response");
            }),
            "(no error)");
}

TEST_F(SessionTest, ErrorImageSize) {
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["camera"]["width"] = 0; }),
            "session.json: rig.camera.width: expected an integer in [1, 65536], got 0");
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["projector"]["height"] = 40.5; }),
            "session.json: rig.projector.height: expected an integer in [1, 65536], got 40.5");
}

TEST_F(SessionTest, ErrorTooFewPhases) {
  EXPECT_EQ(ParseError([](Json& j) { j["frames"].erase(1); }),
            "session.json: frames: sine period 7 px (axis x) has 2 distinct phases, expected at "
            "least 3");
  // A repeated phase does not count twice.
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][1]["pattern"]["phase"] = 2 * M_PI; }),
            "session.json: frames: sine period 7 px (axis x) has 2 distinct phases, expected at "
            "least 3");
}

TEST_F(SessionTest, ErrorPeriodsDoNotCoverProjector) {
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["projector"]["width"] = 100; }),
            "session.json: frames: sine periods 7, 11 px (axis x) repeat after 77 px, expected an "
            "unambiguous range covering the projector width 100 px (e.g. coprime periods with "
            "LCM >= 100, or a period >= 100)");
  // 8 and 12 share a factor: LCM 24.
  EXPECT_EQ(ParseError([](Json& j) {
              for (int i = 0; i < 3; ++i) j["frames"][i]["pattern"]["period_px"] = 8;
              for (int i = 3; i < 6; ++i) j["frames"][i]["pattern"]["period_px"] = 12;
            }),
            "session.json: frames: sine periods 8, 12 px (axis x) repeat after 24 px, expected an "
            "unambiguous range covering the projector width 60 px (e.g. coprime periods with LCM "
            ">= 60, or a period >= 60)");
  // Hierarchical: a cue period >= width plus a fine period decodes.
  EXPECT_EQ(ParseError([](Json& j) {
              for (int i = 0; i < 3; ++i) j["frames"][i]["pattern"]["period_px"] = 64;
              for (int i = 3; i < 6; ++i) j["frames"][i]["pattern"]["period_px"] = 4.5;
            }),
            "(no error)");
  // A single period >= width decodes.
  EXPECT_EQ(ParseError([](Json& j) {
              j["frames"].erase(5);
              j["frames"].erase(4);
              j["frames"].erase(3);
              for (int i = 0; i < 3; ++i) j["frames"][i]["pattern"]["period_px"] = 60;
            }),
            "(no error)");
}

TEST_F(SessionTest, ErrorLensShiftCount) {
  EXPECT_EQ(ParseError([](Json& j) { j["frames"].erase(6); }),
            "session.json: frames: 3 lens-shift (stripes) frames, expected none or at least 4");
  EXPECT_EQ(
      ParseError([](Json& j) { j["frames"][7]["shift_steps"] = -2048; }),
      "session.json: frames: lens-shift frames at 3 distinct shift_steps, expected at least 4");
  EXPECT_EQ(ParseError([](Json& j) {
              for (int i = 0; i < 4; ++i) j["frames"].erase(6);
            }),
            "(no error)");
}

TEST_F(SessionTest, ErrorLensShiftWithoutShifter) {
  EXPECT_EQ(ParseError([](Json& j) { j["rig"].erase("lens_shifter"); }),
            "session.json: rig.lens_shifter: missing, expected it because frames[6] is a "
            "lens-shift (stripes) frame");
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"].erase("lens_shifter");
              for (int i = 0; i < 4; ++i) j["frames"].erase(6);
              j["frames"][0]["shift_steps"] = 10;
            }),
            "session.json: frames[0].shift_steps: expected 0 without a rig.lens_shifter, got 10");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][6]["shift_steps"] = 4096; }),
            "session.json: frames[6].shift_steps: expected a value within "
            "rig.lens_shifter.range_steps [-2048, 2048], got 4096");
  EXPECT_EQ(
      ParseError([](Json& j) { j["frames"][6]["shift_steps"] = 0.5; }),
      "session.json: frames[6].shift_steps: expected an integer (lens-shifter steps), got 0.5");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][7]["pattern"]["axis"] = "y"; }),
            "session.json: frames[7].pattern.axis: expected \"x\" (rig.lens_shifter.axis) for a "
            "lens-shift frame, got \"y\"");
  EXPECT_EQ(ParseError([](Json& j) {
              j["rig"]["lens_shifter"]["range_steps"] = {5, 5};
            }),
            "session.json: rig.lens_shifter.range_steps: expected [min, max], two integers with "
            "min < max");
  EXPECT_EQ(ParseError([](Json& j) { j["rig"]["lens_shifter"]["steps_per_px"] = 0; }),
            "session.json: rig.lens_shifter.steps_per_px: expected a finite number > 0, got 0");
}

TEST_F(SessionTest, ErrorPatternParameters) {
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][0]["pattern"]["period_px"] = 2; }),
            "session.json: frames[0].pattern.period_px: expected a finite number > 2 (projector "
            "px), got 2");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][6]["pattern"]["period_px"] = 1; }),
            "session.json: frames[6].pattern.period_px: expected a finite number >= 2 (projector "
            "px), got 1");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][2]["pattern"]["type"] = "checker"; }),
            "session.json: frames[2].pattern.type: expected \"sine\", \"stripes\", \"graycode\", "
            "\"white\" or \"black\", got \"checker\"");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][2]["pattern"]["axis"] = "z"; }),
            "session.json: frames[2].pattern.axis: expected \"x\" or \"y\", got \"z\"");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][2]["pattern"].erase("phase"); }),
            "session.json: frames[2].pattern.phase: missing, expected a finite number (radians)");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"] = Json::array(); }),
            "session.json: frames: expected a non-empty array of frames, got an array");
  EXPECT_EQ(
      ParseError([](Json& j) { j["frames"][3] = 5; }),
      "session.json: frames[3]: expected an object with file, pattern and shift_steps, got 5");
}

// Gray-code frames (the spec's "Patterns"): parsed, written back the same, and validated: every bit
// of a set present, the set covering the projector (60 px here), and one sine period along the
// same axis accepted (the code fixes its order) where alone it would repeat.
TEST_F(SessionTest, GrayCodeFrames) {
  auto graycode = [](int bits, int bit, double block, bool inverted) {
    return Json{{"file", "frames/gc" + std::to_string(bit) + (inverted ? "i" : "") + ".png"},
                {"pattern",
                 {{"type", "graycode"},
                  {"axis", "x"},
                  {"bits", bits},
                  {"bit", bit},
                  {"block_px", block},
                  {"inverted", inverted}}},
                {"shift_steps", 0}};
  };
  auto sine = [](double period, double phase) {
    return Json{
        {"file", "frames/s" + std::to_string(phase) + ".png"},
        {"pattern", {{"type", "sine"}, {"axis", "x"}, {"period_px", period}, {"phase", phase}}},
        {"shift_steps", 0}};
  };
  auto with_frames = [&](const std::vector<Json>& frames) {
    Json j = *valid_;
    j["frames"] = frames;
    return j;
  };
  // One 12-px sine period (repeats 5 times over 60 px) and a complementary code of 6-px blocks.
  std::vector<Json> frames = {sine(12, 0), sine(12, 2.1), sine(12, 4.2)};
  for (int k = 0; k < 4; ++k) frames.push_back(graycode(4, k, 6, k == 3));
  const Session s = ParseSession(with_frames(frames), *dir_);
  ASSERT_EQ(s.frames.size(), 7u);
  const Pattern& p = s.frames[6].pattern;
  EXPECT_EQ(p.type, PatternType::kGrayCode);
  EXPECT_EQ(p.bits, 4);
  EXPECT_EQ(p.bit, 3);
  EXPECT_EQ(p.block_px, 6.0);
  EXPECT_TRUE(p.inverted);
  EXPECT_EQ(MakeFramePlan(s.frames).graycode.size(), 4u);
  EXPECT_EQ(SessionToJson(s)["frames"][6]["pattern"], frames[6]["pattern"]);
  // Pattern values: bit 0 of Gray(floor(u / 6)) over the 10 blocks, and its complement.
  EXPECT_EQ(s.frames[3].pattern.Value(5, 0), 0.0);   // block 0: Gray 0000
  EXPECT_EQ(s.frames[3].pattern.Value(48, 0), 1.0);  // block 8: Gray 1100
  EXPECT_EQ(s.frames[6].pattern.Value(6, 0), 0.0);   // block 1: Gray 0001, inverted
  EXPECT_EQ(s.frames[6].pattern.Value(12, 0), 0.0);  // block 2: Gray 0011, inverted
  EXPECT_EQ(s.frames[6].pattern.Value(0, 0), 1.0);   // block 0, inverted
  // A missing bit; too few bits for the projector; the sine period alone.
  std::vector<Json> missing = frames;
  missing.erase(missing.begin() + 4);
  EXPECT_EQ(ErrorOf([&] { ParseSession(with_frames(missing), *dir_); }),
            "session.json: frames: Gray code along x (4 bits, block_px 6) has no frame of bit 1, "
            "expected every bit (alone or with its inverse)");
  std::vector<Json> short_code = {sine(12, 0), sine(12, 2.1), sine(12, 4.2)};
  for (int k = 0; k < 3; ++k) short_code.push_back(graycode(3, k, 6, false));
  EXPECT_EQ(ErrorOf([&] { ParseSession(with_frames(short_code), *dir_); }),
            "session.json: frames: Gray code along x (3 bits, block_px 6) covers 48 px, expected "
            "block_px * 2^bits >= the projector's 60 px");
  EXPECT_NE(ErrorOf([&] {
              ParseSession(with_frames({sine(12, 0), sine(12, 2.1), sine(12, 4.2)}), *dir_);
            }).find("repeat after 12 px"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              std::vector<Json> f = frames;
              f[4]["pattern"]["bit"] = 4;
              ParseSession(with_frames(f), *dir_);
            }).find("frames[4].pattern.bit"),
            std::string::npos);
}

TEST_F(SessionTest, ErrorFramePaths) {
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][1]["file"] = "/etc/passwd"; }),
            "session.json: frames[1].file: \"/etc/passwd\" is absolute, expected a path relative "
            "to the session folder");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][1]["file"] = "frames/../../x.png"; }),
            "session.json: frames[1].file: \"frames/../../x.png\" leaves the session folder, "
            "expected a path inside it (no \"..\")");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][1].erase("file"); }),
            "session.json: frames[1].file: missing, expected a relative path to the frame image");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][1]["file"] = ""; }),
            "session.json: frames[1].file: expected a relative path to the frame image, got \"\"");
  EXPECT_EQ(ParseError([](Json& j) { j["frames"][4]["file"] = "frames/./ps07_0.png"; }),
            "session.json: frames[4].file: \"frames/./ps07_0.png\" is also frames[0].file, "
            "expected each frame file once");
  EXPECT_EQ(ParseError([](Json& j) {
              j["ground_truth"] = {{"points", "../gt.exr"}};
            }),
            "session.json: ground_truth.points: \"../gt.exr\" leaves the session folder, expected "
            "a path inside it (no \"..\")");
  EXPECT_EQ(ParseError([](Json& j) { j["ground_truth"] = Json::object(); }),
            "session.json: ground_truth: expected an object with \"points\" and/or \"height\" "
            "paths, got an object");
}

TEST_F(SessionTest, ErrorFrameFiles) {
  const fs::path copy = CopySession("files");
  fs::remove(copy / "frames/ls_001.png");
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "frames/ls_001.png: file not found (frames[7].file)");
  // check_frames = false does not open them.
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy, false); }), "(no error)");

  WriteTextFile(copy / "frames/ls_001.png", "not a png at all");
  const std::string unreadable = ErrorOf([&] { ReadSession(copy); });
  EXPECT_EQ(unreadable.rfind("frames/ls_001.png: cannot read image (", 0), 0u) << unreadable;
  EXPECT_NE(unreadable.find(" (frames[7].file)"), std::string::npos) << unreadable;
  EXPECT_EQ(unreadable.find('\n'), std::string::npos);

  // One frame of another size than the others and the camera.
  WritePng16(copy / "frames/ls_001.png", ImageU16(kCamW, kCamH));
  WritePng16(copy / "frames/ls_003.png", ImageU16(10, 6));
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "frames/ls_003.png: size 10x6, expected 8x6 (rig.camera.width/height)");
  fs::remove_all(copy);
}

TEST_F(SessionTest, ErrorGroundTruthFiles) {
  const fs::path copy = CopySession("gt");
  Session s = ReadSession(copy);
  s.ground_truth = GroundTruth{"gt_points.exr", ""};
  WriteSessionJson(s);
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "gt_points.exr: file not found (ground_truth.points)");
  WriteExr(copy / "gt_points.exr", ImageF(kCamW, kCamH, 2), {"X", "Y"});
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }),
            "gt_points.exr: missing channel 'Z' (ground_truth.points)");
  WriteExr(copy / "gt_points.exr", ImageF(kCamW, kCamH, 3), {"X", "Y", "Z"});
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }), "(no error)");
  fs::remove_all(copy);
}

TEST_F(SessionTest, EightBitFramesAcceptedWithWarning) {
  const fs::path copy = CopySession("8bit");
  WritePng8(copy / "frames/white.png", ImageU8(kCamW, kCamH, 1, 250));
  testing::internal::CaptureStderr();
  EXPECT_EQ(ErrorOf([&] { ReadSession(copy); }), "(no error)");
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("warning: frames/white.png: 1 of 12 frames are 8-bit"), std::string::npos)
      << err;
  fs::remove_all(copy);
}

TEST(PatternTest, ResponseToLinear) {
  Response r;
  EXPECT_EQ(r.ToLinear(0.3), 0.3);
  r.kind = Response::Kind::kSrgb;
  EXPECT_NEAR(r.ToLinear(0.04045), 0.04045 / 12.92, 1e-15);
  EXPECT_NEAR(r.ToLinear(0.5), 0.214041140482232, 1e-12);  // sRGB 128/255-ish reference
  EXPECT_NEAR(r.ToLinear(1.0), 1.0, 1e-15);
  EXPECT_NEAR(r.ToLinear(-0.5), -0.214041140482232, 1e-12);
  r = {Response::Kind::kGamma, 2.2};
  EXPECT_NEAR(r.ToLinear(0.5), std::pow(0.5, 2.2), 1e-15);
}

TEST(PatternTest, UnambiguousRange) {
  EXPECT_EQ(UnambiguousRangePx({7, 11, 13}, 1e6), 1001);
  EXPECT_EQ(UnambiguousRangePx({8, 12}, 1e6), 24);
  EXPECT_EQ(UnambiguousRangePx({7.5, 11}, 1e6), 165);
  EXPECT_EQ(UnambiguousRangePx({64, 4.5}, 1e6), 576);  // LCM of 64 and 9/2
  EXPECT_EQ(UnambiguousRangePx({1000, 8}, 800), 800);  // capped at the limit
  EXPECT_EQ(UnambiguousRangePx({9}, 1e6), 9);
}

// ---- Fuzz: the reader accepts or throws mesoscan::Error(kBadInput), nothing else. ----

void CollectPointers(const Json& j, const Json::json_pointer& at,
                     std::vector<Json::json_pointer>* out) {
  out->push_back(at);
  if (j.is_object()) {
    for (auto it = j.begin(); it != j.end(); ++it) CollectPointers(it.value(), at / it.key(), out);
  } else if (j.is_array()) {
    for (size_t i = 0; i < j.size(); ++i) CollectPointers(j[i], at / i, out);
  }
}

void Mutate(Json& j, std::mt19937& rng) {
  std::vector<Json::json_pointer> ptrs;
  CollectPointers(j, Json::json_pointer(), &ptrs);
  const Json::json_pointer at =
      ptrs[std::uniform_int_distribution<size_t>(0, ptrs.size() - 1)(rng)];
  if (at.empty()) return;
  Json& v = j[at];
  const double kNaN = std::numeric_limits<double>::quiet_NaN();
  switch (std::uniform_int_distribution<int>(0, 11)(rng)) {
    case 0: {  // delete the key or element
      Json& parent = j[at.parent_pointer()];
      if (parent.is_object())
        parent.erase(at.back());
      else
        parent.erase(std::stoul(at.back()));
      break;
    }
    case 1:
      v = "x";
      break;
    case 2:
      v = kNaN;
      break;
    case 3:
      v = std::numeric_limits<double>::infinity();
      break;
    case 4:
      v = 1e308;
      break;
    case 5:
      v = -4294967296.0;
      break;
    case 6:
      v = nullptr;
      break;
    case 7:
      v = Json::array({1, 2});
      break;
    case 8:
      v = Json::object({{"type", "sine"}});
      break;
    case 9:
      v = std::numeric_limits<int64_t>::min();
      break;
    case 10: {  // swap with another node of the document (arrays included)
      const Json other = j[ptrs[std::uniform_int_distribution<size_t>(0, ptrs.size() - 1)(rng)]];
      v = other;
      break;
    }
    default:
      v = std::uniform_int_distribution<int>(-3, 3)(rng);
      break;
  }
}

TEST_F(SessionTest, FuzzMutatedSessionsNeverCrash) {
  const fs::path copy = CopySession("fuzz");
  std::mt19937 rng(20261121);
  int accepted = 0, refused = 0;
  for (int iter = 0; iter < 1000; ++iter) {
    Json j = *valid_;
    const int n = std::uniform_int_distribution<int>(1, 3)(rng);
    for (int k = 0; k < n; ++k) Mutate(j, rng);
    try {
      if (iter % 2 == 0) {
        ParseSession(j, copy);  // in memory: keeps NaN and infinities
      } else {
        std::string text = j.dump();
        if (iter % 3 == 0)  // truncate
          text.resize(std::uniform_int_distribution<size_t>(0, text.size())(rng));
        if (iter % 5 == 0 && !text.empty())  // flip a byte
          text[std::uniform_int_distribution<size_t>(0, text.size() - 1)(rng)] ^=
              static_cast<char>(1 << std::uniform_int_distribution<int>(0, 6)(rng));
        WriteTextFile(copy / "session.json", text);
        ReadSession(copy, /*check_frames=*/iter % 10 == 1);
      }
      ++accepted;
    } catch (const Error& e) {
      ASSERT_EQ(e.kind(), ErrorKind::kBadInput) << e.what();
      ASSERT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
      ++refused;
    }
    // Any other exception or a crash fails the test.
  }
  EXPECT_GT(refused, 300);
  EXPECT_GT(accepted, 10);
  fs::remove_all(copy);
}

}  // namespace
}  // namespace mesoscan
