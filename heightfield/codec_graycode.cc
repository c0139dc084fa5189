#include "heightfield/codec_graycode.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

#include "core/error.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

void GrayCodeOptions::Check() const {
  // Not command-line options: a bad value is a caller's bug.
  MESOSCAN_CHECK(min_bit_snr > 0);
  MESOSCAN_CHECK(full_bit_snr > min_bit_snr);
  MESOSCAN_CHECK(min_bit_contrast >= 0 && min_bit_contrast < 1);
  MESOSCAN_CHECK(min_noise >= 0 && min_noise < 1);
}

namespace {

class GrayCodeCodec final : public PlannedCodec {
 public:
  GrayCodeCodec(const GrayCodeOptions& options, int bits, double block_px, double extent_px,
                bool has_white)
      : plain_(bits, -1),
        inverse_(bits, -1),
        options_(options),
        bits_(bits),
        block_px_(block_px),
        extent_px_(extent_px),
        has_white_(has_white) {}

  const char* Name() const override { return "graycode"; }
  CodecKind Kind() const override { return CodecKind::kAbsolute; }
  std::vector<int> Frames() const override {
    std::vector<int> frames;
    for (int k = 0; k < bits_; ++k)
      for (int f : {plain_[k], inverse_[k]})
        if (f >= 0) frames.push_back(f);
    return frames;
  }
  void SampleNoise(const size_t*, size_t, double*) const override {}  // no fit: no estimate
  void Decode(const size_t* pixels, size_t n, const double*, CodecRecord* out) const override {
    out->Resize(n);
    for (size_t a = 0; a < n; ++a) {
      const size_t i = pixels[a];
      const float u = u_[i];
      out->value[a] = u;
      // A block edge: a coordinate where a period's phase decides the order, or if asked for.
      out->valid[a] = std::isfinite(u) && (orders_period_ || options_.edge_points || !edge_[i]);
      out->residual[a] = 0.0;
      out->consistency[a] = 1.0;
    }
  }
  void Describe(const size_t* pixels, const double*, const uint32_t* which, size_t m, bool,
                CodecRecord* out) const override {
    const double sigma = block_px_ / std::sqrt(12.0);  // uniform over the block
    for (size_t k = 0; k < m; ++k) {
      out->sigma_px[which[k]] = sigma;
      out->confidence[which[k]] = confidence_[pixels[which[k]]];
    }
  }
  void DecodeFrames(const CodecInputs& in, const PixelStates& state) override;
  void OrdersPeriod() override { orders_period_ = true; }

  // Stack frames of bit k: the plain and the inverted frame (-1: none).
  std::vector<int> plain_, inverse_;

 private:
  GrayCodeOptions options_;
  int bits_;
  double block_px_, extent_px_;
  bool has_white_;
  bool orders_period_ = false;
  // Per ROI pixel: the coordinate (NaN: none), the confidence, 1 where the coordinate is the
  // edge between two neighbouring blocks (one unknown bit).
  std::vector<float> u_, confidence_;
  std::vector<uint8_t> edge_;
};

void GrayCodeCodec::DecodeFrames(const CodecInputs& in, const PixelStates& state) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  const FrameStack& stack = *in.stack;
  const size_t np = state.size();
  u_.assign(np, kNaN);
  confidence_.assign(np, 0.0f);
  edge_.assign(np, 0);
  const int64_t blocks = static_cast<int64_t>(std::ceil(extent_px_ / block_px_));
  bool paired = true;
  for (int k = 0; k < bits_; ++k) paired = paired && plain_[k] >= 0 && inverse_[k] >= 0;
  // The noise of d (below) in units of the per-sample noise: a pair's difference; twice a frame's
  // distance from the middle of the white and black frames (each with its own noise), or from
  // half the phase-shift level (a fit of many frames: its noise left out).
  const double d_noise = paired ? std::sqrt(2.0) : has_white_ ? std::sqrt(6.0) : 2.0;
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>((np + 4095) / 4096), [&](int64_t b) {
    const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * 4096);
    std::vector<double> d(bits_), r(bits_);
    for (size_t i = static_cast<size_t>(b) * 4096; i < i_end; ++i) {
      if (state[i] != PixelState::kActive) continue;
      // The white level and the threshold of a bit without its inverse frame.
      const double level = in.ps->level[i];  // the white level (white frame or sine set)
      if (!(level > 0)) continue;
      const double black = has_white_ ? in.classes->black_value[i] : 0.0;
      const double threshold = black + 0.5 * level;
      // d > 0: the bit is set. The per-sample noise from the frames themselves: a pair's sum is
      // the white level in every bit, blurred edges included (its scatter over the bits); a
      // frame alone is the white or the black level (the median of its squared distances to
      // the nearer, robust to the bits the blur leaves between them).
      double noise2;
      if (paired) {
        double sum = 0, sum2 = 0;
        for (int k = 0; k < bits_; ++k) {
          const double p = stack.Value(plain_[k], i), q = stack.Value(inverse_[k], i);
          d[k] = p - q;
          sum += p + q;
          sum2 += (p + q) * (p + q);
        }
        noise2 = bits_ > 1 ? std::max(0.0, sum2 - sum * sum / bits_) / (bits_ - 1) / 2.0 : 0.0;
      } else {
        for (int k = 0; k < bits_; ++k) {
          const bool inv = plain_[k] < 0;
          const double v = stack.Value(inv ? inverse_[k] : plain_[k], i);
          d[k] = (inv ? -2.0 : 2.0) * (v - threshold);
          r[k] = std::pow(v - (v > threshold ? black + level : black), 2);
        }
        std::nth_element(r.begin(), r.begin() + bits_ / 2, r.end());
        noise2 = r[bits_ / 2] / 0.4549;  // the median of a chi-square of 1 degree of freedom
      }
      const double sigma_d =
          d_noise * std::max(std::sqrt(noise2), options_.min_noise * level) + 1e-30;
      uint32_t gray = 0;
      int unknown = -1, unknowns = 0;
      double weakest = std::numeric_limits<double>::infinity();
      for (int k = 0; k < bits_; ++k) {
        const double snr = std::abs(d[k]) / sigma_d;
        gray = gray << 1 | (d[k] > 0 ? 1u : 0u);
        if (!(snr >= options_.min_bit_snr) ||
            !(std::abs(d[k]) >= options_.min_bit_contrast * level)) {
          unknown = k;
          ++unknowns;
        } else {
          weakest = std::min(weakest, snr);
        }
      }
      if (unknowns > 1) continue;
      auto binary = [](uint32_t g) {  // the reflected Gray code's block index
        uint32_t v = g;
        for (uint32_t s = g >> 1; s; s >>= 1) v ^= s;
        return static_cast<int64_t>(v);
      };
      // The weakest read bit's signal-to-noise over full_bit_snr, capped at 1 (a bit read at
      // min_bit_snr: min_bit_snr / full_bit_snr).
      double c = std::isfinite(weakest) ? std::min(1.0, weakest / options_.full_bit_snr) : 1.0;
      double u;
      if (unknowns == 0) {
        const int64_t block = binary(gray);
        if (block >= blocks) continue;
        u = block * block_px_ + 0.5 * (block_px_ - 1.0);  // the block's columns' mean
      } else {
        // One unknown bit: both readings, kept (for the order of a period only) if they are
        // neighbouring blocks: the pixel sees their common edge.
        const uint32_t mask = 1u << (bits_ - 1 - unknown);
        const int64_t b0 = binary(gray & ~mask), b1 = binary(gray | mask);
        if (std::abs(b0 - b1) != 1 || std::max(b0, b1) >= blocks) continue;
        u = std::max(b0, b1) * block_px_ - 0.5;
        c *= 0.5;
        edge_[i] = 1;
      }
      u_[i] = static_cast<float>(u);
      confidence_[i] = static_cast<float>(c);
    }
  });
}

}  // namespace

std::shared_ptr<PlannedCodec> PlanGrayCode(const Session& session, const GrayCodeOptions& options,
                                           ReconstructPlan* plan) {
  // The sets along the plan's axis at shift 0: (bits, block) -> their frames.
  std::map<std::pair<int, double>, std::vector<size_t>> sets;
  for (size_t f = 0; f < session.frames.size(); ++f) {
    const Frame& frame = session.frames[f];
    const Pattern& p = frame.pattern;
    if (p.type != PatternType::kGrayCode || p.axis != plan->axis || frame.shift_steps != 0)
      continue;
    sets[{p.bits, p.block_px}].push_back(f);
  }
  if (sets.empty()) return nullptr;
  // The set with the most bits (the finest code).
  const auto best = std::max_element(sets.begin(), sets.end(), [](const auto& a, const auto& b) {
    return a.first.first < b.first.first;
  });
  const auto [bits, block_px] = best->first;
  auto codec = std::make_shared<GrayCodeCodec>(options, bits, block_px, plan->projector_width,
                                               plan->has_white());
  for (size_t f : best->second) {
    const Pattern& p = session.frames[f].pattern;
    int& slot = p.inverted ? codec->inverse_[p.bit] : codec->plain_[p.bit];
    if (slot >= 0) continue;  // a repeated frame: the first
    slot = static_cast<int>(plan->frames.size());
    plan->frames.push_back(static_cast<int>(f));
  }
  for (int k = 0; k < bits; ++k)
    if (codec->plain_[k] < 0 && codec->inverse_[k] < 0)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::Key(session.root / "session.json", "frames"),
                            "the Gray code along " << plan->axis << " (" << bits
                                                   << " bits, block_px " << block_px
                                                   << ") has no frame of bit " << k);
  return codec;
}

}  // namespace mesoscan
