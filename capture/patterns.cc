#include "capture/patterns.h"

#include <cmath>
#include <cstdio>
#include <numbers>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {

ImageF RenderPattern(const Pattern& pattern, int width, int height, const Response& response) {
  MESOSCAN_CHECK(width > 0 && height > 0);
  ImageF image(width, height, 1);
  // The pattern varies along one axis only: evaluate one line, then copy it.
  const bool along_x = pattern.axis != 'y';
  std::vector<float> line(along_x ? width : height);
  for (size_t i = 0; i < line.size(); ++i) {
    const double t = static_cast<double>(i);
    line[i] =
        static_cast<float>(response.ToLinear(along_x ? pattern.Value(t, 0) : pattern.Value(0, t)));
  }
  ParallelForRows(height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      float* row = image.row(y);
      if (along_x) {
        std::copy(line.begin(), line.end(), row);
      } else {
        std::fill(row, row + width, line[y]);
      }
    }
  });
  return image;
}

double ValueAtShift(const Pattern& pattern, double x, double y, double shift_px, char shift_axis) {
  return shift_axis == 'y' ? pattern.Value(x, y - shift_px) : pattern.Value(x - shift_px, y);
}

double ShiftPx(const Frame& frame, const Rig& rig) {
  if (!rig.lens_shifter) return 0.0;
  return frame.shift_steps / rig.lens_shifter->steps_per_px;
}

void FramePlanOptions::Check() const {
  for (double p : periods_px) MESOSCAN_CHECK(std::isfinite(p) && p > 2);
  MESOSCAN_CHECK_GE(phases, 3);
  MESOSCAN_CHECK(axis == 'x' || axis == 'y');
  MESOSCAN_CHECK(lens_shift_frames == 0 || lens_shift_frames >= 4);
  MESOSCAN_CHECK_LT(range_steps[0], range_steps[1]);
  MESOSCAN_CHECK(lens_shift_frames <= range_steps[1] - range_steps[0]);
}

std::vector<Frame> MakeStandardFrames(const FramePlanOptions& o) {
  o.Check();
  std::vector<Frame> frames;
  char name[64];
  for (double period : o.periods_px) {
    for (int k = 0; k < o.phases; ++k) {
      Frame f;
      std::snprintf(name, sizeof(name), "ps%g_%d.png", period, k);
      f.file = o.frame_dir + "/" + name;
      f.pattern.type = PatternType::kSine;
      f.pattern.axis = o.axis;
      f.pattern.period_px = period;
      f.pattern.phase = 2.0 * std::numbers::pi * k / o.phases;
      frames.push_back(f);
    }
  }
  const long span = static_cast<long>(o.range_steps[1]) - o.range_steps[0];
  for (int i = 0; i < o.lens_shift_frames; ++i) {
    Frame f;
    std::snprintf(name, sizeof(name), "ls_%03d.png", i);
    f.file = o.frame_dir + "/" + name;
    f.pattern.type = PatternType::kStripes;
    f.pattern.axis = o.axis;
    f.pattern.period_px = 2;
    f.shift_steps = static_cast<int>(
        std::lround(o.range_steps[0] + static_cast<double>(span) * i / o.lens_shift_frames));
    frames.push_back(f);
  }
  if (o.white) frames.push_back({o.frame_dir + "/white.png", {PatternType::kWhite}, 0});
  if (o.black) frames.push_back({o.frame_dir + "/black.png", {PatternType::kBlack}, 0});
  return frames;
}

}  // namespace mesoscan
