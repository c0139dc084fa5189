// Camera raw sessions through `mesoscan check` and the reconstruction's frame decoder, and the
// acquisition sequencer through `mesoscan capture`.

#include <gtest/gtest.h>

#include <random>

#include "capture/patterns.h"
#include "capture/raw_frame.h"
#include "capture/session.h"
#include "core/image_io.h"
#include "heightfield/frames.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// A small phase-shift session (camera 12 x 11: sensor 24 x 22, LibRaw's minimum is 22 x 22)
// whose frames are DNG mosaics with black level 256 and white level 4095 (12-bit sensor).
Session RawSession(const fs::path& root) {
  Session s;
  s.root = root;
  s.created = "2026-11-21T12:00:00Z";
  s.object = "raw session";
  s.rig.camera.width = 12;
  s.rig.camera.height = 11;
  s.rig.camera.K << 100, 0, 5.5, 0, 100, 5, 0, 0, 1;
  s.rig.camera.world_from_device.rotation = Eigen::Vector3d(1, -1, -1).asDiagonal();
  s.rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  s.rig.projector.width = 60;
  s.rig.projector.height = 40;
  s.rig.projector.K << 200, 0, 29.5, 0, 200, 19.5, 0, 0, 1;
  s.rig.projector.world_from_device = s.rig.camera.world_from_device;
  s.rig.projector.world_from_device.translation = Vec3d(0.05, 0, 0.25);
  FramePlanOptions plan;
  plan.periods_px = {7, 11};
  plan.lens_shift_frames = 0;
  s.frames = MakeStandardFrames(plan);
  for (Frame& f : s.frames) f.file = fs::path(f.file).replace_extension(".dng").string();
  return s;
}

TEST(CaptureCli, DngSessionPassesCheckAndDecodesToBinnedBlackSubtractedFrames) {
  const fs::path dir = CliTempDir("capture_cli", "dng");
  fs::remove_all(dir);
  fs::create_directories(dir / "frames");
  Session s = RawSession(dir);
  RawLevels levels;
  levels.black = {256, 256, 256, 256};
  levels.white = 4095;
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> code(256, 4095);
  std::vector<ImageU16> mosaics;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    ImageU16 m(24, 22);
    for (uint16_t& v : m.data()) v = static_cast<uint16_t>(code(rng));
    WriteCfaDng(s.FramePath(i), m, levels);
    mosaics.push_back(std::move(m));
  }
  WriteSessionJson(s);

  const CliResult check = RunMesoscan("check " + dir.string());
  EXPECT_EQ(check.code, 0) << check.output;

  // The decoder of `reconstruct` sees 12 x 11 frames: (mean of each cell - 256) * 65535 / 3839,
  // then the session's black level (0) and linear response through a 65536-entry table.
  const Session r = ReadSession(dir);
  std::vector<int> all(r.frames.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
  const FrameStack stack = LoadFrames(r, all, FrameLoadOptions());
  ASSERT_EQ(stack.width(), 12);
  ASSERT_EQ(stack.height(), 11);
  double max_err_codes = 0.0;
  for (int k = 0; k < stack.num_frames(); ++k)
    for (int y = 0; y < 11; ++y)
      for (int x = 0; x < 12; ++x) {
        const ImageU16& m = mosaics[k];
        const double mean = (double(m(2 * x, 2 * y)) + m(2 * x + 1, 2 * y) + m(2 * x, 2 * y + 1) +
                             m(2 * x + 1, 2 * y + 1)) /
                            4.0;
        const double expected = (mean - 256.0) / (4095.0 - 256.0);  // in [0, 1]
        max_err_codes = std::max(
            max_err_codes,
            std::abs(stack.Value(k, static_cast<size_t>(y) * 12 + x) - expected) * 65535.0);
      }
  EXPECT_LE(max_err_codes, 0.5 + 1e-3);  // one rounding to 16 bits
  fs::remove_all(dir);
}

}  // namespace
}  // namespace mesoscan
