// The Gray-code codec (heightfield/codec_graycode.h) on frames held in memory: the column of every
// pixel whose bits are read; where one bit is unknown, no coordinate alone and the edge between
// two neighbouring columns for a code that orders a period; with and without the inverse frames.

#include "heightfield/codec_graycode.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "heightfield/stage_classify.h"
#include "heightfield/stage_phase_shift.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {
namespace {

constexpr int kBits = 3, kColumns = 8;

int GrayBit(int column, int k) { return ((column ^ (column >> 1)) >> (kBits - 1 - k)) & 1; }

// Camera pixels 0..7 see projector columns 0..7; pixel 8 sees half of column 5 and half of 6
// (their codes differ in bit 1 only); pixel 9 has no contrast; pixel 10 sees column 0 with its
// most significant bit at half level (its two readings, 0 and 7, are no neighbours).
double PixelLevel(int pixel, int k, bool inverted) {
  double v;
  if (pixel < kColumns)
    v = GrayBit(pixel, k);
  else if (pixel == 8)
    v = 0.5 * (GrayBit(5, k) + GrayBit(6, k));
  else if (pixel == 9)
    v = 0.5;
  else
    v = k == 0 ? 0.5 : GrayBit(0, k);
  return inverted ? 1.0 - v : v;
}

struct Decoded {
  std::vector<double> u, sigma, confidence;
  std::vector<uint8_t> valid;
};

Decoded DecodeSession(bool with_inverse, bool orders_period, bool edge_points) {
  constexpr int kPixels = 11;
  Session s;
  s.rig.camera.width = kPixels;
  s.rig.camera.height = 1;
  s.rig.projector.width = kColumns;
  s.rig.projector.height = 4;
  for (int k = 0; k < kBits; ++k)
    for (bool inverted : {false, true}) {
      if (inverted && !with_inverse) continue;
      Frame f;
      f.pattern.type = PatternType::kGrayCode;
      f.pattern.axis = 'x';
      f.pattern.bits = kBits;
      f.pattern.bit = k;
      f.pattern.inverted = inverted;
      s.frames.push_back(f);
    }
  Frame white, black;
  white.pattern.type = PatternType::kWhite;
  black.pattern.type = PatternType::kBlack;
  s.frames.push_back(white);
  s.frames.push_back(black);
  const ReconstructPlan plan = MakeReconstructPlan(s, {});
  EXPECT_EQ(plan.unwrapping, "graycode");
  EXPECT_EQ(plan.codecs.size(), 1u);
  // The stack in the plan's order.
  std::vector<std::vector<float>> frames;
  for (int f : plan.frames) {
    const Pattern& p = s.frames[f].pattern;
    std::vector<float> v(kPixels);
    for (int i = 0; i < kPixels; ++i)
      v[i] = p.type == PatternType::kWhite   ? 1.0f
             : p.type == PatternType::kBlack ? 0.0f
                                             : static_cast<float>(PixelLevel(i, p.bit, p.inverted));
    frames.push_back(v);
  }
  const FrameStack stack = FrameStack::FromLinear(kPixels, 1, frames);
  PixelClasses classes = ClassifyPixels(stack, plan, kPixels, 1, {});
  const PhaseShiftPixels ps =
      DecodePhaseShift(stack, plan, UnitGains(plan, s.frames.size()), classes, {}, &classes.state);
  PlanOptions options;
  options.codecs.graycode.edge_points = false;
  const ReconstructPlan plan_strict = MakeReconstructPlan(s, options);
  PlannedCodec& codec = *(edge_points ? plan : plan_strict).codecs[0];
  if (orders_period) codec.OrdersPeriod();
  codec.DecodeFrames({&stack, &classes, &ps}, classes.state);
  std::vector<size_t> pixels(kPixels);
  for (int i = 0; i < kPixels; ++i) pixels[i] = i;
  std::vector<uint32_t> all(kPixels);
  for (int i = 0; i < kPixels; ++i) all[i] = i;
  const std::vector<double> noise(kPixels, 0.01);
  CodecRecord r;
  codec.Decode(pixels.data(), kPixels, noise.data(), &r);
  codec.Describe(pixels.data(), noise.data(), all.data(), kPixels, false, &r);
  return {r.value, r.sigma_px, r.confidence, r.valid};
}

TEST(GrayCodeCodec, ColumnsEdgesAndUnknownBits) {
  for (bool with_inverse : {true, false})
    for (bool orders_period : {false, true})
      for (bool edge_points : {false, true}) {
        const Decoded d = DecodeSession(with_inverse, orders_period, edge_points);
        for (int j = 0; j < kColumns; ++j) {
          ASSERT_TRUE(d.valid[j]) << j;
          EXPECT_EQ(d.u[j], j) << j;
          EXPECT_NEAR(d.sigma[j], 1 / std::sqrt(12.0), 1e-6);
          EXPECT_EQ(d.confidence[j], 1.0f);
        }
        // The edge between columns 5 and 6 (bit 1 unknown): neither column guessed; the edge's
        // coordinate (GrayCodeOptions::edge_points, or where the code orders a period), else none.
        EXPECT_EQ(d.valid[8], orders_period || edge_points);
        if (d.valid[8]) {
          EXPECT_EQ(d.u[8], 5.5);
          EXPECT_EQ(d.confidence[8], 0.5f);
        }
        EXPECT_FALSE(d.valid[9]);   // no contrast in any bit
        EXPECT_FALSE(d.valid[10]);  // an unknown bit whose readings are not neighbours
      }
}

}  // namespace
}  // namespace mesoscan
