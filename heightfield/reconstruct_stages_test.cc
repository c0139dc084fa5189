// One test (or a few) per reconstruction stage (heightfield/reconstruct.h), each on its own
// inputs built here in memory: the plan from a session's frame list, the pixel stages from
// FrameStack::FromLinear, the later stages from hand-made per-pixel records. The whole pipeline is
// tested in reconstruct_test.cc and tests/reconstruct_sim_test.cc.

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <random>
#include <string>

#include "core/error.h"
#include "core/image_io.h"
#include "core/numbers.h"
#include "core/stage_timer.h"
#include "core/test_temp_dir.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/resample.h"
#include "heightfield/stage_classify.h"
#include "heightfield/stage_combine.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_height_field.h"
#include "heightfield/stage_lens_shift.h"
#include "heightfield/stage_mixed_pixels.h"
#include "heightfield/stage_phase_shift.h"
#include "heightfield/stage_plan.h"
#include "heightfield/stage_triangulate.h"
#include "heightfield/triangulate.h"

namespace mesoscan {
namespace {

Frame SineFrame(double period, double phase, int shift = 0) {
  Frame f;
  f.pattern.type = PatternType::kSine;
  f.pattern.period_px = period;
  f.pattern.phase = phase;
  f.shift_steps = shift;
  return f;
}

Frame StripesFrame(int shift) {
  Frame f;
  f.pattern.type = PatternType::kStripes;
  f.pattern.period_px = 2;
  f.shift_steps = shift;
  return f;
}

Frame FlatFrame(PatternType t) {
  Frame f;
  f.pattern.type = t;
  return f;
}

// The streaming front end (stage_stream.h) decodes two complementary halves of the frame list
// and joins them; released frames are what the other half fills in.
TEST(StageStream, ReleaseAndMergeJoinComplementaryStacks) {
  const std::vector<std::vector<float>> frames = {{1, 2}, {3, 4}, {5, 6}};
  FrameStack a = FrameStack::FromLinear(2, 1, frames, {0, 0});
  FrameStack b = FrameStack::FromLinear(2, 1, frames, {0, 1});
  a.Release(1);
  b.Release(0);
  b.Release(2);
  a.Merge(std::move(b));
  ASSERT_EQ(a.num_frames(), 3);
  for (int k = 0; k < 3; ++k)
    for (size_t i = 0; i < 2; ++i) EXPECT_EQ(a.Value(k, i), frames[k][i]);
  EXPECT_EQ(a.saturated(), (std::vector<uint8_t>{0, 1}));  // saturation of both halves
  FrameStack c = FrameStack::FromLinear(1, 2, {{1, 2}, {3, 4}, {5, 6}});
  EXPECT_THROW(a.Merge(std::move(c)), Error);  // another size: refused
}

// Decoding marks a pixel saturated where any of its frames reaches the saturation code; the scan
// screens blocks of 256 samples before looking at single samples, so the marks are placed at and
// around block boundaries, and one sample just below the code must stay unmarked. The samples
// are stored as decoded (the storage is not zero-filled first; every sample is written).
TEST(StageStream, DecodedFramesMarkSaturationAtEverySample) {
  namespace fs = std::filesystem;
  const fs::path dir = TestTempDir("stages_test", "sat");
  fs::create_directories(dir / "frames");
  const int w = 300, h = 5;  // 1500 pixels: six blocks, the last one partial
  Session s;
  s.root = dir;
  s.rig.camera.width = w;
  s.rig.camera.height = h;
  const uint16_t sat = static_cast<uint16_t>(std::floor(0.999 * 65535.0));
  const std::vector<std::vector<size_t>> marks = {{0, 255, 256, 777, 1499}, {511, 1000}};
  std::vector<ImageU16> images;
  for (int k = 0; k < 2; ++k) {
    ImageU16 img(w, h);
    for (int i = 0; i < w * h; ++i) img(i % w, i / w) = static_cast<uint16_t>(1000 + 37 * i + k);
    for (size_t i : marks[k]) img(static_cast<int>(i % w), static_cast<int>(i / w)) = sat;
    img(1 + k, 3) = static_cast<uint16_t>(sat - 1);  // just below: not saturated
    Frame f = StripesFrame(k);
    f.file = "frames/f" + std::to_string(k) + ".png";
    WritePng16(dir / f.file, img);
    s.frames.push_back(f);
    images.push_back(img);
  }
  // The decoding tasks hand each frame's samples to on_decoded once (the stream stage gathers
  // the lens-shift gains' samples from them): the stack's values, gathered at any pixels.
  GatheredSamples gathered;
  gathered.pixels = {0, 7, 256, 1499};
  gathered.codes.resize(2);
  std::atomic<int> calls{0};
  FrameLoadOptions load;
  load.on_decoded = [&](int k, const uint16_t* samples) {
    ++calls;
    gathered.Gather(k, samples);
  };
  EXPECT_FALSE(gathered.Complete({0, 1}));
  const FrameStack stack = LoadFrames(s, {0, 1}, load);
  EXPECT_EQ(calls.load(), 2);
  ASSERT_TRUE(gathered.Complete({0, 1}));
  for (int k = 0; k < 2; ++k)
    for (size_t j = 0; j < gathered.pixels.size(); ++j)
      EXPECT_EQ(stack.Linear(gathered.codes[k][j]), stack.Value(k, gathered.pixels[j]));
  std::vector<uint8_t> expected(static_cast<size_t>(w) * h, 0);
  for (const auto& m : marks)
    for (size_t i : m) expected[i] = 1;
  EXPECT_EQ(stack.saturated(), expected);
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < w * h; ++i)
      ASSERT_FLOAT_EQ(stack.Value(k, static_cast<size_t>(i)), images[k](i % w, i / w) / 65535.0f)
          << "frame " << k << " pixel " << i;
}

TEST(StagePlan, GroupsSineSetsSortsLensShiftAndFindsWhiteBlack) {
  Session s;
  s.rig.projector.width = 800;
  s.rig.lens_shifter = LensShifter();
  s.rig.lens_shifter->steps_per_px = 100;
  for (double ph : {0.0, 2.0, 4.0}) s.frames.push_back(SineFrame(7, ph));
  for (double ph : {0.0, 2.0, 4.0}) s.frames.push_back(SineFrame(11, ph));
  s.frames.push_back(SineFrame(11, 1.0, 50));  // not at shift 0: not decoded
  for (int st : {30, -10, 10, 50}) s.frames.push_back(StripesFrame(st));
  s.frames.push_back(FlatFrame(PatternType::kBlack));
  s.frames.push_back(FlatFrame(PatternType::kWhite));

  const ReconstructPlan p = MakeReconstructPlan(s, {});
  ASSERT_EQ(p.periods.size(), 2u);
  EXPECT_EQ(p.PeriodList(), (std::vector<double>{7, 11}));
  EXPECT_EQ(p.PhaseShiftFrames(), 6);
  EXPECT_EQ(p.unwrapping, "temporal");
  ASSERT_EQ(p.ls_stack.size(), 4u);
  EXPECT_EQ(p.ls_shift_px, (std::vector<double>{-0.1, 0.1, 0.3, 0.5}));
  EXPECT_DOUBLE_EQ(p.LensShiftCentre(), 0.2);
  // Stack order: sine frames, lens-shift frames by shift, white, black.
  EXPECT_EQ(p.frames, (std::vector<int>{0, 1, 2, 3, 4, 5, 8, 9, 7, 10, 12, 11}));
  EXPECT_EQ(p.white, 10);
  EXPECT_EQ(p.black, 11);

  PlanOptions no_ls;
  no_ls.use_lens_shift = false;
  EXPECT_FALSE(MakeReconstructPlan(s, no_ls).use_lens_shift());
  s.rig.lens_shifter.reset();
  EXPECT_FALSE(MakeReconstructPlan(s, {}).use_lens_shift());

  Session none;
  none.frames.push_back(SineFrame(7, 0));
  none.frames.push_back(SineFrame(7, 2));
  EXPECT_THROW(MakeReconstructPlan(none, {}), Error);
}

// Horizontal fringes: the decoded axis is the lens shifter's when a sine set lies
// along it, else x, else y; the unwrapping range is the projector's extent along that axis.
TEST(StagePlan, DecodesOneAxis) {
  auto along = [](Frame f, char axis) {
    f.pattern.axis = axis;
    return f;
  };
  Session s;
  s.rig.projector.width = 800;
  s.rig.projector.height = 600;
  for (char axis : {'x', 'y'})
    for (double ph : {0.0, 2.0, 4.0}) s.frames.push_back(along(SineFrame(7, ph), axis));
  EXPECT_EQ(MakeReconstructPlan(s, {}).axis, 'x');  // no shifter, both axes: x
  s.rig.lens_shifter = LensShifter();
  s.rig.lens_shifter->axis = 'y';
  s.rig.lens_shifter->steps_per_px = 100;
  for (int st : {-20, 0, 10, 20}) s.frames.push_back(along(StripesFrame(st), 'y'));
  const ReconstructPlan p = MakeReconstructPlan(s, {});
  EXPECT_EQ(p.axis, 'y');  // the shifter's axis
  EXPECT_EQ(p.projector_width, 600);
  EXPECT_EQ(p.frames, (std::vector<int>{3, 4, 5, 6, 7, 8, 9}));
  EXPECT_EQ(p.ls_stack.size(), 4u);
  Session y_only;
  y_only.rig.projector.width = 800;
  y_only.rig.projector.height = 600;
  for (double ph : {0.0, 2.0, 4.0}) y_only.frames.push_back(along(SineFrame(7, ph), 'y'));
  EXPECT_EQ(MakeReconstructPlan(y_only, {}).axis, 'y');  // no shifter, only y
}

TEST(StageClassify, SaturatedUnlitAndLit) {
  // Stack frames: white, black. Pixels: saturated, unlit, lit, lit.
  std::vector<std::vector<float>> frames = {{0.9f, 0.03f, 0.5f, 0.8f}, {0.1f, 0.02f, 0.1f, 0.0f}};
  const FrameStack stack = FrameStack::FromLinear(4, 1, frames, {1, 0, 0, 0});
  ReconstructPlan plan;
  plan.frames = {0, 1};
  plan.white = 0;
  plan.black = 1;
  const PixelClasses c = ClassifyPixels(stack, plan, 4, 1, {});
  EXPECT_EQ(c.state, (PixelStates{PixelState::kSaturated, PixelState::kUnlit, PixelState::kActive,
                                  PixelState::kActive}));
  EXPECT_EQ(c.pixels_roi, 4);
  EXPECT_EQ(c.pixels_saturated, 1);
  EXPECT_FLOAT_EQ(c.white_level[2], 0.4f);
  EXPECT_FLOAT_EQ(c.black_value[2], 0.1f);
  ClassifyOptions bad;
  bad.mask_path = "/nonexistent/mask.png";
  EXPECT_THROW(ClassifyPixels(stack, plan, 4, 1, bad), Error);
}

// A sine set of `K` phases per period on random pixels: u uniform over the projector.
struct SineStack {
  ReconstructPlan plan;
  std::vector<std::vector<float>> frames;
  std::vector<double> u, amp, dc;
};

SineStack MakeSineStack(int np, const std::vector<double>& periods, int K,
                        const std::vector<double>& gains, uint32_t seed) {
  SineStack s;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  for (int i = 0; i < np; ++i) {
    s.u.push_back(800 * U(rng));
    s.amp.push_back(0.1 + 0.2 * U(rng));
    s.dc.push_back(0.35 + 0.1 * U(rng));
  }
  s.plan.projector_width = 800;
  for (double period : periods) {
    PhasePeriod p;
    p.period = period;
    for (int k = 0; k < K; ++k) {
      const double delta = 2 * kPi * k / K;
      p.stack_frames.push_back(static_cast<int>(s.frames.size()));
      p.deltas.push_back(delta);
      const double g = gains.empty() ? 1.0 : gains[s.frames.size()];
      std::vector<float> f(np);
      for (int i = 0; i < np; ++i)
        f[i] = static_cast<float>(
            g * (s.dc[i] + s.amp[i] * std::cos(2 * kPi * s.u[i] / period + delta)));
      s.plan.frames.push_back(static_cast<int>(s.frames.size()));
      s.frames.push_back(std::move(f));
    }
    s.plan.periods.push_back(p);
  }
  return s;
}

TEST(StageGains, RecoversAPerFrameGain) {
  // 5 phases per period: with 3, a gain pattern times the sinusoid aliases onto the sinusoid
  // and the per-pixel model absorbs it (heightfield/frames.h).
  const std::vector<double> gains = {1.0, 1.03, 0.98, 1.0, 1.01, 0.99, 1.02, 0.97, 1.0, 1.0};
  SineStack s = MakeSineStack(4000, {7, 11}, 5, gains, 3);
  const FrameStack stack = FrameStack::FromLinear(4000, 1, s.frames);
  const PixelStates state(4000, PixelState::kActive);
  const FrameGains g = EstimateLuminanceGains(stack, s.plan, state, 10, {});
  // Noiseless data: the 3 alternating rounds of EstimateFrameGains remove most of the jitter
  // (what is left is the slow convergence of the alternation, not noise).
  double mean = 0;
  for (double v : gains) mean += v / gains.size();
  double before = 0, after = 0;
  for (int k = 0; k < 10; ++k) {
    before += std::pow(gains[k] / mean - 1, 2);
    after += std::pow(g.session_gain[k] - gains[k] / mean, 2);
    EXPECT_NEAR(g.inv_gain[k], 1.0 / g.session_gain[k], 1e-6);
  }
  EXPECT_LT(std::sqrt(after), 0.5 * std::sqrt(before));  // 0.32 measured
  // The gains from samples gathered beforehand (the stream stage's lens-shift frames) are the
  // same numbers.
  GainModel model;
  for (int k = 0; k < 10; ++k) {
    model.frames.push_back(k);
    model.design.push_back({1.0, std::cos(0.7 * k), std::sin(0.7 * k)});
  }
  const std::vector<uint32_t> sample = GainSample(state);
  std::vector<float> by_frame;
  for (int k = 0; k < 10; ++k)
    for (uint32_t i : sample) by_frame.push_back(stack.Value(k, i));
  EXPECT_EQ(EstimateFrameGains(by_frame, sample.size(), model),
            EstimateFrameGains(stack, model, sample));
  GainOptions off;
  off.normalize_luminance = false;
  for (float v : EstimateLuminanceGains(stack, s.plan, state, 10, off).inv_gain) EXPECT_EQ(v, 1.0f);
}

TEST(StagePhaseShift, WrappedPhaseModulationAndRejections) {
  SineStack s = MakeSineStack(6, {7, 11}, 4, {}, 5);
  // Pixel 4: no modulation in period 11; pixel 5: dark.
  for (int k = 4; k < 8; ++k) s.frames[k][4] = static_cast<float>(s.dc[4]);
  for (int k = 0; k < 8; ++k) s.frames[k][5] = 0.001f;
  const FrameStack stack = FrameStack::FromLinear(6, 1, s.frames);
  PixelClasses classes;
  classes.state.assign(6, PixelState::kActive);
  classes.white_level.assign(6, std::nanf(""));
  classes.black_value.assign(6, 0.0f);
  FrameGains gains;
  gains.inv_gain.assign(8, 1.0f);
  const PhaseShiftPixels ps = DecodePhaseShift(stack, s.plan, gains, classes, {}, &classes.state);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(classes.state[i], PixelState::kActive);
    for (int p = 0; p < 2; ++p) {
      const double period = s.plan.periods[p].period;
      const double d = std::remainder(ps.theta[p][i] - 2 * kPi * s.u[i] / period, 2 * kPi);
      EXPECT_NEAR(d, 0.0, 1e-5);
      EXPECT_NEAR(ps.modulation[p][i], s.amp[i], 1e-5);
    }
    EXPECT_NEAR(ps.level[i], 2 * s.dc[i], 1e-5);  // no white frame: twice the offset
  }
  EXPECT_EQ(classes.state[4], PixelState::kUnmodulated);
  EXPECT_EQ(classes.state[5], PixelState::kUnlit);
  EXPECT_EQ(ps.pixels_lit, 4);
}

TEST(StageLensShift, NoiselessProfilesGiveThePhaseAtShiftZero) {
  const int w = 12, h = 10, n = w * h, N = 24;
  ReconstructPlan plan;
  std::vector<std::vector<float>> frames;
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> U(-kPi, kPi);
  std::vector<double> phase0(n);
  for (double& v : phase0) v = U(rng);
  const double f = 0.5;
  for (int k = 0; k < N; ++k) {
    const double x = -0.7 + 0.13 * k;  // centre 0.795: not 0 on purpose
    plan.ls_stack.push_back(k);
    plan.ls_shift_px.push_back(x);
    plan.frames.push_back(k);
    std::vector<float> fr(n);
    for (int i = 0; i < n; ++i)
      fr[i] = static_cast<float>(0.4 + 0.25 * std::sin(phase0[i] + 2 * kPi * f * x));
    frames.push_back(std::move(fr));
  }
  const FrameStack stack = FrameStack::FromLinear(w, h, frames);
  FrameGains gains;
  gains.inv_gain.assign(N, 1.0f);
  PixelStates state(n, PixelState::kActive);
  state[7] = PixelState::kUnlit;  // never fitted
  const LensShiftPixels ls = FitLensShift(stack, plan, &gains, {}, &state);
  ASSERT_FALSE(ls.empty());
  EXPECT_EQ(ls.pixels_fitted, n - 1);
  EXPECT_TRUE(std::isnan(ls.phase0[7]));
  for (int i = 0; i < n; ++i) {
    if (i == 7) continue;
    ASSERT_EQ(state[i], PixelState::kActive) << i;
    EXPECT_NEAR(std::remainder(ls.phase0[i] - phase0[i], 2 * kPi), 0.0, 1e-4) << i;
    EXPECT_NEAR(ls.amplitude[i], 0.25, 1e-4);
    EXPECT_NEAR(ls.frequency[i], f, 1e-4);
  }
  // No lens-shift frames: nothing fitted, nothing changed.
  ReconstructPlan none;
  PixelStates s2(n, PixelState::kActive);
  EXPECT_TRUE(FitLensShift(stack, none, &gains, {}, &s2).empty());
  EXPECT_EQ(s2, PixelStates(n, PixelState::kActive));
}

TEST(StageLensShift, SmoothFrequencyMapIsARobustQuadratic) {
  const int w = 40, h = 30;
  std::vector<float> f(w * h);
  auto q = [&](int x, int y) {
    const double u = (x + 0.5) * 2.0 / w - 1, v = (y + 0.5) * 2.0 / h - 1;
    return 0.5 + 0.01 * u - 0.02 * v + 0.005 * u * u + 0.003 * u * v - 0.004 * v * v;
  };
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) f[y * w + x] = static_cast<float>(q(x, y));
  for (int i = 0; i < w * h; i += 37) f[i] = 0.9f;           // outliers
  for (int i = 5; i < w * h; i += 41) f[i] = std::nanf("");  // unfitted
  const std::vector<float> m = SmoothFrequencyMap(f, w, h);
  ASSERT_EQ(m.size(), f.size());
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) EXPECT_NEAR(m[y * w + x], q(x, y), 1e-6);
  EXPECT_TRUE(SmoothFrequencyMap(std::vector<float>(49, 0.5f), 7, 7).empty());
}

// Phase-shift records of pixels at columns u (periods 7, 11, 13; 3 phases) and lens-shift
// records whose fine phase says column u_fine.
struct CombineInput {
  ReconstructPlan plan;
  PhaseShiftPixels ps;
  LensShiftPixels ls;
};

CombineInput MakeCombineInput(const std::vector<double>& u_coarse,
                              const std::vector<double>& u_fine) {
  CombineInput in;
  in.plan.projector_width = 800;
  const size_t n = u_coarse.size();
  for (double period : {7.0, 11.0, 13.0}) {
    PhasePeriod p;
    p.period = period;
    for (int k = 0; k < 3; ++k) {
      p.stack_frames.push_back(static_cast<int>(in.plan.frames.size()));
      in.plan.frames.push_back(static_cast<int>(in.plan.frames.size()));
      p.deltas.push_back(2 * kPi * k / 3);
    }
    in.plan.periods.push_back(p);
    std::vector<float> th(n), mod(n, 0.3f), res(n, 0.0f);
    for (size_t i = 0; i < n; ++i)
      th[i] = static_cast<float>(std::fmod(2 * kPi * u_coarse[i] / period, 2 * kPi));
    in.ps.theta.push_back(th);
    in.ps.modulation.push_back(mod);
    in.ps.residual_rms.push_back(res);
  }
  in.ps.level.assign(n, 0.8f);
  if (!u_fine.empty()) {
    for (int k = 0; k < 40; ++k) in.plan.ls_stack.push_back(9 + k);
    for (auto* v : {&in.ls.phase0, &in.ls.amplitude, &in.ls.frequency, &in.ls.offset,
                    &in.ls.residual_rms, &in.ls.samples})
      v->assign(n, 0.0f);
    for (size_t i = 0; i < n; ++i) {
      in.ls.phase0[i] = static_cast<float>(kPi / 2 - kPi * u_fine[i]);  // u = 1/2 - phase0 / pi
      in.ls.amplitude[i] = 0.3f;
      in.ls.frequency[i] = 0.5f;
      in.ls.residual_rms[i] = 0.003f;
      in.ls.samples[i] = 40;
    }
  }
  return in;
}

TEST(StageCombine, RoundHalfAwayIsLround) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> big(-40000.0, 40000.0), small(-3.0, 3.0);
  for (int k = 0; k < 200000; ++k) {
    const double v = k % 2 ? big(rng) : small(rng);
    ASSERT_EQ(RoundHalfAway(v), std::lround(v)) << v;
  }
  for (double v : {0.5, -0.5, 1.5, -1.5, 2.5, -2.5, 0.49999999999999994, -0.49999999999999994, 0.0,
                   -0.0, 31999.5, -31999.5, 4503599627370495.5 / 4096.0})
    EXPECT_EQ(RoundHalfAway(v), std::lround(v)) << v;
  for (double v = -3.0; v <= 3.0; v = std::nextafter(v, 4.0) + 1e-3)
    ASSERT_EQ(RoundHalfAway(v), std::lround(v)) << v;
  EXPECT_EQ(RoundHalfAway(std::nextafter(0.5, 0.0)), 0);
  EXPECT_EQ(RoundHalfAway(std::nextafter(-0.5, 0.0)), 0);
  EXPECT_EQ(RoundHalfAway(std::nextafter(2.5, 3.0)), 3);
}

TEST(StageCombine, RoundHalfAwayDIsStdRoundBitForBit) {
  auto same = [](double v) {
    const double a = RoundHalfAwayD(v), b = std::round(v);
    return std::memcmp(&a, &b, sizeof a) == 0 || (std::isnan(a) && std::isnan(b));
  };
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<double> big(-1e6, 1e6), small(-3.0, 3.0);
  for (int k = 0; k < 200000; ++k) {
    const double v = k % 2 ? big(rng) : small(rng);
    ASSERT_TRUE(same(v)) << v;
  }
  for (double v : {0.0,
                   -0.0,
                   0.3,
                   -0.3,
                   0.5,
                   -0.5,
                   0.49999999999999994,
                   -0.49999999999999994,
                   1.5,
                   -1.5,
                   4503599627370495.5,
                   -4503599627370495.5,
                   4503599627370496.0,
                   1e300,
                   -1e300,
                   std::numeric_limits<double>::infinity(),
                   -std::numeric_limits<double>::infinity(),
                   std::numeric_limits<double>::quiet_NaN(),
                   5e-324,
                   -5e-324})
    EXPECT_TRUE(same(v)) << v;
}

TEST(StageCombine, UnwrapsAndRejectsInconsistentPhases) {
  CombineInput in = MakeCombineInput({123.4, 640.9, 300.0}, {});
  // Pixel 2: period 7 half a fringe off.
  in.ps.theta[0][2] = static_cast<float>(std::fmod(in.ps.theta[0][2] + kPi, 2 * kPi));
  PixelStates state(3, PixelState::kActive);
  const CombinedPixels c = CombinePhases(in.plan, in.ps, in.ls, {}, &state);
  EXPECT_EQ(state,
            (PixelStates{PixelState::kActive, PixelState::kActive, PixelState::kUnwrapFailed}));
  EXPECT_NEAR(c.u[0], 123.4, 1e-3);
  EXPECT_NEAR(c.u[1], 640.9, 1e-3);
  EXPECT_TRUE(std::isnan(c.u[2]));
  EXPECT_EQ(c.confidence[2], 0.0f);
  EXPECT_GT(c.confidence[0], 0.5f);
  EXPECT_GT(c.sigma_u[0], 0.0f);
}

// The combine stage reads the codecs through their records alone (heightfield/codec.h): an
// absolute codec other than phase shifting (a given coordinate with its sigma, as a Gray code
// gives one) refined by the lens shift follows paper Eq. 2, rejects a period jump, fails where
// the absolute coordinate fails, and lets the absolute codec decide alone where the fit failed.
class GivenCoordinateCodec final : public Codec {
 public:
  explicit GivenCoordinateCodec(std::vector<double> u) : u_(std::move(u)) {}
  const char* Name() const override { return "given"; }
  CodecKind Kind() const override { return CodecKind::kAbsolute; }
  std::vector<int> Frames() const override { return {}; }
  void SampleNoise(const size_t*, size_t n, double* sigma) const override {
    for (size_t a = 0; a < n; ++a)
      if (sigma[a] < 0) sigma[a] = 0.01;
  }
  void Decode(const size_t* pixels, size_t n, const double*, CodecRecord* out) const override {
    out->Resize(n);
    for (size_t a = 0; a < n; ++a) {
      out->value[a] = u_[pixels[a]];
      out->valid[a] = std::isfinite(u_[pixels[a]]);
      out->residual[a] = 0.0;
      out->consistency[a] = 1.0;
    }
  }
  void Describe(const size_t*, const double*, const uint32_t* which, size_t m, bool,
                CodecRecord* out) const override {
    for (size_t k = 0; k < m; ++k) {
      out->sigma_px[which[k]] = 0.29;
      out->confidence[which[k]] = 0.9;
    }
  }

 private:
  std::vector<double> u_;
};

TEST(StageCombine, AnyAbsoluteCodecRefinedByTheLensShift) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  CombineInput in = MakeCombineInput({0, 0, 0, 0}, {100.3, 100.3, 400.25, 10.0});
  in.ls.phase0[3] = static_cast<float>(kNaN);  // no fit: the absolute codec alone
  const GivenCoordinateCodec coarse({100.6, 101.1, kNaN, 10.4});
  const LensShiftCodec fine(in.plan, in.ls, 4.0);
  PixelStates state(4, PixelState::kActive);
  const CombinedPixels c = CombineCodecs(coarse, &fine, std::vector<float>(4, 0.8f), {}, &state);
  EXPECT_EQ(state, (PixelStates{PixelState::kActive, PixelState::kCombination,
                                PixelState::kUnwrapFailed, PixelState::kActive}));
  EXPECT_NEAR(c.u[0], 100.3, 1e-4);
  EXPECT_EQ(c.source[0], 0);
  // Eq. 4 (E = (0.003 / 0.3)^2, t = 4) times the combination factor 1 - (0.3 / 0.6)^2.
  EXPECT_NEAR(c.confidence[0], (1 - std::sqrt(4e-4)) * 0.75, 1e-5);  // (float inputs)
  EXPECT_TRUE(std::isnan(c.u[1]));
  EXPECT_TRUE(std::isnan(c.u[2]));
  EXPECT_NEAR(c.u[3], 10.4, 1e-5);
  EXPECT_EQ(c.source[3], 1);
  EXPECT_NEAR(c.confidence[3], 0.9 * 0.5, 1e-6);  // times phase_shift_fallback_confidence
  EXPECT_NEAR(c.sigma_u[3], 0.29, 1e-6);
}

TEST(StageCombine, LensShiftFinePhaseAndPeriodJumps) {
  // Pixel 0: coarse 0.2 px off the fine column (kept, fine wins); pixel 1: 0.8 px off (a period
  // jump of the 2-px fine period: rejected); pixel 2: low confidence (noisy profile).
  CombineInput in = MakeCombineInput({100.5, 101.1, 400.25}, {100.3, 100.3, 400.25});
  in.ls.residual_rms[2] = 0.16f;  // E = (0.16 / 0.3)^2: c = 1 - sqrt(4 E) < 0
  PixelStates state(3, PixelState::kActive);
  CombineOptions no_fallback;
  no_fallback.phase_shift_fallback = false;
  const CombinedPixels c = CombinePhases(in.plan, in.ps, in.ls, no_fallback, &state);
  EXPECT_EQ(state, (PixelStates{PixelState::kActive, PixelState::kCombination,
                                PixelState::kLowConfidence}));
  // With the fallback (the default) the noisy-profile pixel is decided by phase shifting alone,
  // at a lower confidence; the period jump of good stripes is still rejected.
  PixelStates state_fb(3, PixelState::kActive);
  const CombinedPixels fb = CombinePhases(in.plan, in.ps, in.ls, {}, &state_fb);
  EXPECT_EQ(state_fb,
            (PixelStates{PixelState::kActive, PixelState::kCombination, PixelState::kActive}));
  EXPECT_EQ(fb.source[0], 0);
  EXPECT_EQ(fb.source[2], 1);
  EXPECT_NEAR(fb.u[2], fb.u_coarse[2], 1e-6);
  EXPECT_GT(fb.confidence[2], 0.0f);
  EXPECT_LE(fb.confidence[2], 0.5f);
  EXPECT_NEAR(c.u[0], 100.3, 1e-4);
  EXPECT_NEAR(c.u_coarse[0], 100.5, 1e-3);
  // sigma_u = sqrt(2 sigma^2 / (N a^2)) / pi with sigma = rms sqrt(N / (N - 3)).
  const double sigma = 0.003 * std::sqrt(40.0 / 37.0);
  EXPECT_NEAR(c.sigma_u[0], std::sqrt(2 * sigma * sigma / (40 * 0.09)) / kPi, 1e-7);
}

// The combine stage with phase shifting's own fringe orders (UnwrapPhaseShift, made while the
// lens-shift frames decode) gives the same bits as its own search, on noisy phases where the two
// noise estimates differ (the lens-shift residual 0.3-3x the phase-shift floor); a pixel whose
// hint is NaN or on the wrong orders is searched again.
TEST(StageCombine, PhaseShiftFringeOrdersGiveTheSameResult) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> uni(5.0, 790.0), scale(0.3, 3.0);
  std::normal_distribution<double> noise(0.0, 0.02);
  std::vector<double> coarse(4000), fine(4000);
  for (size_t i = 0; i < coarse.size(); ++i) {
    fine[i] = uni(rng);
    coarse[i] = fine[i] + (i % 50 == 0 ? 1.0 : 0.1 * noise(rng) / 0.02);
  }
  CombineInput in = MakeCombineInput(coarse, fine);
  for (auto& th : in.ps.theta)
    for (float& t : th) t = static_cast<float>(std::fmod(t + noise(rng) + 2 * kPi, 2 * kPi));
  for (float& r : in.ls.residual_rms) r = static_cast<float>(0.008 * scale(rng));
  PixelStates state(coarse.size(), PixelState::kActive);
  const CombinedPixels want = CombinePhases(in.plan, in.ps, in.ls, {}, &state);
  PixelStates state_hinted(coarse.size(), PixelState::kActive);
  in.ps.u_unwrapped = UnwrapPhaseShift(in.plan, in.ps, state_hinted, {});
  ASSERT_EQ(in.ps.u_unwrapped.size(), coarse.size());
  in.ps.u_unwrapped.q[1] = ColumnHints::kNone;
  in.ps.u_unwrapped.Set(2, in.ps.u_unwrapped.At(2) + 7.0);  // one fringe of period 7 off
  // The hints are within half a step of the column (they are 16 bits).
  for (size_t i = 3; i < 50; ++i)  // (their phases' noise is ~0.02 px of u)
    EXPECT_NEAR(in.ps.u_unwrapped.At(i), coarse[i], 0.5 / in.ps.u_unwrapped.scale + 0.1) << i;
  const CombinedPixels got = CombinePhases(in.plan, in.ps, in.ls, {}, &state_hinted);
  EXPECT_EQ(state, state_hinted);
  auto same = [](const std::vector<float>& a, const std::vector<float>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
  };
  EXPECT_TRUE(same(want.u, got.u));
  EXPECT_TRUE(same(want.u_coarse, got.u_coarse));
  EXPECT_TRUE(same(want.unwrap_residual, got.unwrap_residual));
  EXPECT_TRUE(same(want.confidence, got.confidence));
  EXPECT_TRUE(same(want.sigma_u, got.sigma_u));
}

// RejectIsolatedColumns runs OpenCV's speckle filter on bands of rows with margins: the same
// verdicts as one call on the whole image (filterSpeckles itself, with the stage's fixed point),
// with small regions, regions that cross the bands' edges and long thin ones that do.
TEST(StageCombine, IsolatedColumnsInBandsAreTheWholeImagesSpeckles) {
  const int w = 97, h = 1100;  // several bands of 256 rows
  RoiGrid grid{{0, 0, w, h}, w, h};
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  CombinedPixels c;
  c.u.assign(grid.pixels(), 0.0f);
  c.confidence.assign(grid.pixels(), 1.0f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      float& u = c.u[static_cast<size_t>(y) * w + x];
      u = static_cast<float>(x * 0.5 + 20.0 * std::floor(y / 40.0));  // 40-row strips
      const double r = uni(rng);
      if (r < 0.3)
        u += static_cast<float>(5.0 + 100.0 * uni(rng));  // speckles of all sizes
      else if (r < 0.35)
        u = std::numeric_limits<float>::quiet_NaN();
      if (x == 50) u = 900.0f + static_cast<float>(y % 300 < 20 ? 0.0 : 500.0);  // thin columns
    }
  CombineOptions options;
  PixelStates state(grid.pixels(), PixelState::kActive);
  // The reference: the stage's fixed point, then one filterSpeckles on the whole image.
  float u_max = 0.0f;
  for (float u : c.u)
    if (std::isfinite(u)) u_max = std::max(u_max, std::abs(u));
  const double scale = std::min(16.0, 32000.0 / std::max(1.0f, u_max));
  constexpr int16_t kNone = std::numeric_limits<int16_t>::min();
  cv::Mat fixed(h, w, CV_16SC1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float v = c.u[static_cast<size_t>(y) * w + x];
      fixed.at<int16_t>(y, x) =
          std::isfinite(v) ? static_cast<int16_t>(RoundHalfAway(v * scale)) : kNone;
    }
  cv::filterSpeckles(fixed, kNone, options.isolated_max_region_px,
                     options.isolated_max_step_px * scale);
  const std::vector<float> u_before = c.u;
  RejectIsolatedColumns(grid, options, &c, &state);
  int isolated = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const bool want = std::isfinite(u_before[i]) && fixed.at<int16_t>(y, x) == kNone;
      ASSERT_EQ(state[i] == PixelState::kIsolated, want) << x << " " << y;
      ASSERT_EQ(std::isnan(c.u[i]), want || std::isnan(u_before[i])) << x << " " << y;
      isolated += want;
    }
  EXPECT_GT(isolated, 1000);
}

Rig SimpleRig(int w, int h) {
  Rig rig;
  rig.camera.width = w;
  rig.camera.height = h;
  rig.camera.K << 4545.45, 0, (w - 1) / 2.0, 0, 4545.45, (h - 1) / 2.0, 0, 0, 1;
  rig.camera.world_from_device.rotation << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  rig.projector.width = 800;
  rig.projector.height = 600;
  rig.projector.K << 1650, 0, 399.5, 0, 1650, 299.5, 0, 0, 1;
  const double a = 20 * kPi / 180;
  rig.projector.world_from_device.rotation << std::cos(a), 0, -std::sin(a), 0, -1, 0, -std::sin(a),
      0, -std::cos(a);
  rig.projector.world_from_device.translation = Vec3d(0.0906, 0, 0.249);
  return rig;
}

TEST(StageTriangulate, PointsProjectBackToTheirPixelAndColumn) {
  const Rig rig = SimpleRig(40, 30);
  RoiGrid grid{{10, 5, 4, 3}, 4, 3};  // a crop: ROI pixel (0, 0) is camera pixel (10, 5)
  CombinedPixels c;
  c.u.assign(12, 0.0f);
  c.confidence.assign(12, 0.7f);
  c.sigma_u.assign(12, 0.01f);
  for (int i = 0; i < 12; ++i) c.u[i] = 390.0f + i;
  PixelStates state(12, PixelState::kActive);
  state[3] = PixelState::kUnwrapFailed;
  c.u[3] = std::nanf("");
  const TriangulatedPoints t = TriangulatePoints(rig, grid, c, {true}, &state);
  EXPECT_EQ(t.points.xyz.width(), 40);
  for (int i = 0; i < 12; ++i) {
    const int cx = 10 + i % 4, cy = 5 + i / 4;
    if (i == 3) {
      EXPECT_EQ(state[i], PixelState::kUnwrapFailed);
      EXPECT_TRUE(std::isnan(t.points.xyz(cx, cy, 2)));
      EXPECT_EQ(t.points.confidence(cx, cy), 0.0f);
      continue;
    }
    ASSERT_EQ(state[i], PixelState::kOk);
    const Vec3d p(t.points.xyz(cx, cy, 0), t.points.xyz(cx, cy, 1), t.points.xyz(cx, cy, 2));
    Vec2d uv, xy;
    ASSERT_TRUE(rig.projector.Project(p, &uv));
    ASSERT_TRUE(rig.camera.Project(p, &xy));
    EXPECT_NEAR(uv.x(), c.u[i], 1e-3);
    EXPECT_NEAR(xy.x(), cx, 1e-3);
    EXPECT_NEAR(xy.y(), cy, 1e-3);
    EXPECT_EQ(t.points.confidence(cx, cy), 0.7f);
    EXPECT_EQ(t.points.projector_u(cx, cy), c.u[i]);
    EXPECT_NEAR(t.sigma_z[i], 0.01 * std::abs(t.dz_du(cx, cy)), 1e-12);
  }
  EXPECT_TRUE(std::isnan(t.points.xyz(0, 0, 2)));  // outside the ROI
}

// The stage computes the pinhole camera's rays and the closed-form column planes inline; every
// point, dZ/du and state must be the bits of the general Triangulator calls, on the inline paths
// and on the general ones (camera or projector distortion, a skewed projector, rows), at the
// image edges and for rays that miss (columns behind the projector).
TEST(StageTriangulate, SameBitsAsTheTriangulatorOnEveryRig) {
  for (int variant = 0; variant < 5; ++variant) {
    Rig rig = SimpleRig(40, 30);
    char axis = 'x';
    if (variant == 1) rig.camera.distortion[0] = -0.2;
    if (variant == 2) rig.projector.distortion[0] = 0.1;
    if (variant == 3) rig.projector.K(0, 1) = 2.0;
    if (variant == 4) axis = 'y';
    if (variant == 0) rig.camera.K(0, 1) = 0.5;  // a skewed camera: x per pixel, not per column
    const int w = 40, h = 30;
    RoiGrid grid{{0, 0, w, h}, w, h};
    CombinedPixels c;
    const size_t np = static_cast<size_t>(w) * h;
    c.u.resize(np);
    c.confidence.assign(np, 0.5f);
    c.sigma_u.assign(np, 0.02f);
    PixelStates state(np, PixelState::kActive);
    // The projector coordinate of each pixel's point on a wavy surface around z = 0.
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const Vec3d ray = rig.camera.RayDirectionInWorld({double(x), double(y)});
        const Vec3d o = rig.camera.CentreInWorld();
        const double z = 1e-4 * std::sin(0.7 * x + 0.3 * y);
        Vec2d uv;
        ASSERT_TRUE(rig.projector.Project(o + ((z - o.z()) / ray.z()) * ray, &uv));
        c.u[static_cast<size_t>(y) * w + x] = static_cast<float>(uv[axis == 'x' ? 0 : 1]);
      }
    c.u[7] = -5e6f;  // far outside: no intersection in front of both devices
    const TriangulatedPoints t = TriangulatePoints(rig, grid, c, {true, axis}, &state);
    const Triangulator tri(rig.camera, rig.projector, axis);
    int ok = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        const Vec3d ray = tri.CameraRay(x, y);
        const auto p = tri.Intersect(ray, c.u[i]);
        ASSERT_EQ(state[i], p ? PixelState::kOk : PixelState::kNoIntersection)
            << variant << " " << i;
        if (!p) {
          EXPECT_TRUE(std::isnan(t.points.xyz(x, y, 2)));
          continue;
        }
        ++ok;
        for (int k = 0; k < 3; ++k)
          EXPECT_EQ(t.points.xyz(x, y, k), static_cast<float>((*p)[k])) << variant << " " << i;
        const auto b = tri.Intersect(ray, c.u[i] + 0.5);
        if (!b) {
          EXPECT_TRUE(std::isnan(t.dz_du(x, y)) && std::isnan(t.sigma_z[i]));
          continue;
        }
        const float d = static_cast<float>(2.0 * (b->z() - p->z()));
        EXPECT_EQ(t.dz_du(x, y), d);
        EXPECT_EQ(t.sigma_z[i], 0.02f * std::abs(d));
      }
    EXPECT_GT(ok, static_cast<int>(np) - 10) << variant;
    EXPECT_EQ(state[7], PixelState::kNoIntersection) << variant;
  }
}

TEST(StageMixedPixels, AStepPointBetweenTheSurfacesIsRemoved) {
  // A row of points on z = 0 (x < 6) and z = 100 um (x > 6); x = 6 half-way.
  const int w = 13, h = 1;
  RoiGrid grid{{0, 0, w, h}, w, h};
  ScanPoints pts;
  pts.xyz = ImageF(w, h, 3, 0.0f);
  pts.confidence = ImageF(w, h, 1, 1.0f);
  for (int x = 0; x < w; ++x) {
    pts.xyz(x, 0, 0) = x * 1e-5f;
    pts.xyz(x, 0, 2) = x < 6 ? 0.0f : x > 6 ? 1e-4f : 5e-5f;
  }
  PixelStates state(w, PixelState::kOk);
  const std::vector<float> white(w, 0.8f), sigma(w, 1e-6f);
  MixedPixelOptions o;
  o.outlier_footprints = 0;
  EXPECT_EQ(RejectMixedPixels(grid, white, sigma, o, &pts, &state), 1);
  EXPECT_EQ(state[6], PixelState::kDiscontinuity);
  EXPECT_TRUE(std::isnan(pts.xyz(6, 0, 2)));
  EXPECT_EQ(pts.confidence(6, 0), 0.0f);
  for (int x = 0; x < w; ++x)
    EXPECT_EQ(state[x], x == 6 ? PixelState::kDiscontinuity : PixelState::kOk) << x;
}

// The camera footprint's median, selected by a histogram of the floats' top bits on the pool:
// the value std::nth_element gives, with ties, zeros, one crowded bucket and empty parts.
TEST(StageHeightField, MedianOfNonNegativeIsNthElement) {
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (int trial = 0; trial < 40; ++trial) {
    std::vector<std::vector<float>> parts(1 + trial % 13);
    for (auto& p : parts) {
      const int n = static_cast<int>(rng() % (trial < 5 ? 3 : 5000));
      for (int k = 0; k < n; ++k) {
        const int kind = static_cast<int>(rng() % 10);
        p.push_back(kind == 0   ? 0.0f
                    : kind < 3  ? 1e-4f * (1.0f + 1e-3f * uni(rng))  // one crowded bucket
                    : kind == 3 ? 0.5f                               // ties
                                : 10.0f * uni(rng));
      }
    }
    std::vector<float> all;
    for (const auto& p : parts) all.insert(all.end(), p.begin(), p.end());
    if (all.empty()) {
      EXPECT_EQ(MedianOfNonNegative(parts), 0.0f);
      continue;
    }
    std::nth_element(all.begin(), all.begin() + all.size() / 2, all.end());
    EXPECT_EQ(MedianOfNonNegative(parts), all[all.size() / 2]) << trial;
  }
}

TEST(StageHeightField, NoPointGivesAOneByOneUnknownGrid) {
  ScanPoints pts;
  pts.xyz = ImageF(8, 6, 3, std::nanf(""));
  pts.confidence = ImageF(8, 6, 1, 0.0f);
  const HeightFieldResult r = MakeHeightField(pts, {});
  EXPECT_EQ(r.height.z.width(), 1);
  EXPECT_TRUE(std::isnan(r.height.z(0, 0)));
  EXPECT_EQ(r.height.confidence(0, 0), 0.0f);
  EXPECT_EQ(r.normals.width(), 1);
}

TEST(StageTimer, RecordsStagesInOrder) {
  StageTimings t;
  StageTimer timer(&t);
  timer.Stage("a");
  timer.Stage("b");
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t[0].first, "a");
  EXPECT_EQ(t[1].first, "b");
  EXPECT_GE(t[0].second, 0.0);
  EXPECT_GE(timer.Total(), t[0].second + t[1].second);
}

}  // namespace
}  // namespace mesoscan
