#include "session/patterns.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <sstream>

#include "core/error.h"
#include "core/numbers.h"
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
  for (const auto* list : {&periods_px, &cross_periods_px})
    for (double p : *list) MESOSCAN_CHECK(std::isfinite(p) && p > 2);
  if (!periods_px.empty() || !cross_periods_px.empty()) MESOSCAN_CHECK_GE(phases, 3);
  MESOSCAN_CHECK(axis == 'x' || axis == 'y');
  MESOSCAN_CHECK(lens_shift_frames == 0 || lens_shift_frames >= 4);
  MESOSCAN_CHECK(graycode_bits >= 0 && graycode_bits <= 30 && graycode_block_px >= 1);
  MESOSCAN_CHECK(cross_graycode_bits >= 0 && cross_graycode_bits <= 30 &&
                 cross_graycode_block_px >= 1);
  MESOSCAN_CHECK_LT(range_steps[0], range_steps[1]);
  // Distinct positions: at most one frame per step.
  MESOSCAN_CHECK(lens_shift_frames <= int64_t{range_steps[1]} - range_steps[0] + 1);
}

FramePlanOptions CalibrationPlan(int projector_width, int projector_height) {
  MESOSCAN_CHECK(projector_width > 2 && projector_height > 2);
  FramePlanOptions o;
  o.axis = 'x';
  o.periods_px = {double(projector_width), projector_width / 16.0};
  o.cross_periods_px = {double(projector_height), projector_height / 16.0};
  o.lens_shift_frames = 0;
  return o;
}

std::vector<double> HeterodynePeriods() { return {42, 45, 48}; }

void ApplyPatternSet(const std::string& patterns, int width, int height, FramePlanOptions* plan,
                     const std::string& option) {
  if (patterns == "sine" || patterns == "heterodyne") return;
  if (patterns != "graycode" && patterns != "sine+graycode")
    MESOSCAN_BAD_OPTION(
        option, "'" << patterns << "': expected sine, heterodyne, graycode or sine+graycode");
  const char cross = plan->axis == 'x' ? 'y' : 'x';
  for (const char axis : {plan->axis, cross}) {
    std::vector<double>& periods = axis == plan->axis ? plan->periods_px : plan->cross_periods_px;
    if (axis != plan->axis && periods.empty()) continue;  // nothing along the other axis
    int& bits = axis == plan->axis ? plan->graycode_bits : plan->cross_graycode_bits;
    double& block = axis == plan->axis ? plan->graycode_block_px : plan->cross_graycode_block_px;
    if (patterns == "graycode") {
      periods.clear();
      block = 1.0;
    } else {
      if (periods.size() != 1)
        MESOSCAN_BAD_OPTION(option, "sine+graycode: expected one sine period along "
                                        << axis << ", got " << periods.size());
      block = 0.5 * periods[0];
      if (!(block >= 1))
        MESOSCAN_BAD_OPTION(option,
                            "sine+graycode: the period along " << axis << " must be >= 2 px");
    }
    const int extent = axis == 'x' ? width : height;
    bits = std::max(1, static_cast<int>(std::ceil(std::log2(extent / block) - 1e-9)));
  }
}

std::string PeriodName(double period) {
  std::ostringstream os;
  if (period == std::round(period)) {
    os << std::setw(2) << std::setfill('0') << static_cast<int>(period);
  } else {
    os << period;
  }
  return os.str();
}

std::vector<double> ParsePeriodList(const std::string& text, const std::string& option) {
  std::vector<double> periods;
  if (text.empty() || text == "none") return periods;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    size_t used = 0;
    double p = 0;
    try {
      p = std::stod(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != item.size() || !(p > 2) || !std::isfinite(p))
      MESOSCAN_BAD_OPTION(option, "'" << text
                                      << "': expected comma-separated periods > 2 px, "
                                         "e.g. 7,11,13, or 'none'");
    periods.push_back(p);
  }
  if (!text.empty() && text.back() == ',')
    MESOSCAN_BAD_OPTION(option, "'" << text << "': a period is missing after ','");
  return periods;
}

std::vector<Frame> MakeStandardFrames(const FramePlanOptions& o) {
  o.Check();
  std::vector<Frame> frames;
  const std::string dir = o.frame_dir.empty() ? "" : o.frame_dir + "/";
  const char cross = o.axis == 'x' ? 'y' : 'x';
  for (const char axis : {o.axis, cross})
    for (double period : axis == o.axis ? o.periods_px : o.cross_periods_px)
      for (int k = 0; k < o.phases; ++k) {
        Frame f;
        f.file = dir + "ps" + (axis == 'y' ? "y" : "") + PeriodName(period) + "_" +
                 std::to_string(k) + o.extension;
        f.pattern.type = PatternType::kSine;
        f.pattern.axis = axis;
        f.pattern.period_px = period;
        f.pattern.phase = 2 * kPi * k / o.phases;
        frames.push_back(f);
      }
  for (const char axis : {o.axis, cross}) {
    const int bits = axis == o.axis ? o.graycode_bits : o.cross_graycode_bits;
    for (int k = 0; k < bits; ++k)
      for (bool inverted : {false, true}) {
        if (inverted && !o.graycode_inverse) continue;
        Frame f;
        f.file = dir + (inverted ? "gci" : "gc") + (axis == 'y' ? "y" : "") + std::to_string(k) +
                 o.extension;
        f.pattern.type = PatternType::kGrayCode;
        f.pattern.axis = axis;
        f.pattern.bits = bits;
        f.pattern.bit = k;
        f.pattern.block_px = axis == o.axis ? o.graycode_block_px : o.cross_graycode_block_px;
        f.pattern.inverted = inverted;
        frames.push_back(f);
      }
  }
  const auto& r = o.range_steps;
  for (int i = 0; i < o.lens_shift_frames; ++i) {
    Frame f;
    char name[32];
    std::snprintf(name, sizeof(name), "ls_%03d", i);
    f.file = dir + name + o.extension;
    f.pattern.type = PatternType::kStripes;
    f.pattern.axis = o.axis;
    f.pattern.period_px = 2;
    f.shift_steps = static_cast<int>(
        std::lround(r[0] + static_cast<double>(i) * (r[1] - r[0]) / (o.lens_shift_frames - 1)));
    frames.push_back(f);
  }
  if (o.white) frames.push_back({dir + "white" + o.extension, {PatternType::kWhite}, 0});
  if (o.black) frames.push_back({dir + "black" + o.extension, {PatternType::kBlack}, 0});
  return frames;
}

}  // namespace mesoscan
