#include "heightfield/stage_combine.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <optional>

#include "core/error.h"
#include "core/numbers.h"

namespace mesoscan {

void CombineOptions::Check() const {
  if (!(max_combination_residual_px > 0 && max_combination_residual_px < 1))
    MESOSCAN_BAD_INPUT("max_combination_residual_px: expected a value in (0, 1), got "
                       << max_combination_residual_px);
  if (!(confidence_t > 0)) MESOSCAN_BAD_INPUT("confidence_t: expected > 0, got " << confidence_t);
  if (!(min_confidence >= 0 && min_confidence < 1))
    MESOSCAN_BAD_INPUT("min_confidence: expected a value in [0, 1), got " << min_confidence);
  if (!(phase_shift_fallback_confidence > 0 && phase_shift_fallback_confidence <= 1))
    MESOSCAN_BAD_INPUT("phase_shift_fallback_confidence: expected a value in (0, 1], got "
                       << phase_shift_fallback_confidence);
  if (isolated_max_region_px < 0)
    MESOSCAN_BAD_INPUT("isolated_max_region_px: expected >= 0, got " << isolated_max_region_px);
}

// std::lround for |v| < 2^31 without the libm call (3 M calls per full-resolution scan): v - its
// truncation is exact there, so the half-way test is too.
long RoundHalfAway(double v) {
  const long t = static_cast<long>(v);  // rounds towards zero
  const double frac = v - static_cast<double>(t);
  return frac >= 0.5 ? t + 1 : frac <= -0.5 ? t - 1 : t;
}

double RoundHalfAwayD(double v) {
  if (!(std::abs(v) < 4503599627370496.0)) return std::round(v);  // 2^52: already an integer
  const double t = static_cast<double>(static_cast<int64_t>(v));  // truncated, exact
  const double frac = v - t;                                      // exact
  const double r = frac >= 0.5 ? t + 1 : frac <= -0.5 ? t - 1 : t;
  return r == 0 ? std::copysign(0.0, v) : r;  // std::round keeps the sign of a zero
}

CombinedPixels CombineCodecs(const Codec& absolute, const Codec* refinement,
                             const std::vector<float>& level, const CombineOptions& options,
                             PixelStates* state_out) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  PixelStates& state = *state_out;
  const size_t np = state.size();
  const bool use_ls = refinement != nullptr;
  const double period = use_ls ? refinement->PeriodPx() : 0.0;

  CombinedPixels out;
  const bool reference_positions =
      use_ls && options.reference_positions_to_phase_shift && refinement->OffsetUnknown();
  const bool coarse = options.keep_coarse || reference_positions;
  // One array per task (12.5 MB each at 3 Mpx: their page faults and fills were ~65 MB on
  // one core while the other waited).
  tbb::parallel_for<int64_t>(0, 6, [&](int64_t a) {
    switch (a) {
      case 0:
        out.u.assign(np, kNaN);
        break;
      case 1:
        if (coarse) out.u_coarse.assign(np, kNaN);
        break;
      case 2:
        if (coarse) out.unwrap_residual.assign(np, kNaN);
        break;
      case 3:
        out.confidence.assign(np, 0.0f);
        break;
      case 4:
        out.sigma_u.assign(np, kNaN);
        break;
      default:
        out.source.assign(np, use_ls ? 0 : 1);
        break;
    }
  });
  const bool fallback = use_ls && options.phase_shift_fallback;
  // Rows of the ROI do not matter here: blocks of 4096 pixels.
  constexpr int kBlock = 4096;
  const int blocks = static_cast<int>((np + kBlock - 1) / kBlock);
  tbb::parallel_for(tbb::blocked_range<int>(0, blocks, 8), [&](const auto& range) {
    const int b0 = range.begin(), b1 = range.end();
    // Per block: the active pixels' per-sample noise, then each codec's record of all of them at
    // once (one call per codec), then the combination per pixel; the absolute codec's own sigma
    // and confidence where it decides alone.
    std::vector<double> noise;
    std::vector<size_t> active;
    std::vector<uint32_t> alone;  // entries the absolute codec decides alone
    CodecRecord abs_rec, fine_rec;
    for (int b = b0; b < b1; ++b) {
      const size_t i_begin = static_cast<size_t>(b) * kBlock;
      const size_t i_end = std::min(np, i_begin + kBlock);
      active.clear(), alone.clear();
      for (size_t i = i_begin; i < i_end; ++i) {
        // Graceful defocus: a failed lens-shift fit falls back to the absolute codec.
        if (fallback && state[i] == PixelState::kFitFailed) state[i] = PixelState::kActive;
        if (state[i] == PixelState::kActive) active.push_back(i);
      }
      const size_t n = active.size();
      // Per-sample noise: from the refinement's fits (many samples) where they have it, else the
      // absolute codec's; a floor of 1e-4 of the white level.
      noise.assign(n, -1.0);
      if (use_ls) refinement->SampleNoise(active.data(), n, noise.data());
      absolute.SampleNoise(active.data(), n, noise.data());
      for (size_t a = 0; a < n; ++a) noise[a] = std::max(noise[a], 1e-4 * level[active[a]]);
      absolute.Decode(active.data(), n, noise.data(), &abs_rec);
      if (use_ls) refinement->Decode(active.data(), n, noise.data(), &fine_rec);
      // The confidence's last factors, the checks and the outputs of entry a.
      auto finish = [&](size_t a, double u, double c) {
        const size_t i = active[a];
        c *= abs_rec.consistency[a];
        c = std::clamp(c, 0.0, 1.0);
        if (!(c >= options.min_confidence) || c <= 0) {
          state[i] = PixelState::kLowConfidence;
          return;
        }
        out.u[i] = static_cast<float>(u);
        out.confidence[i] = static_cast<float>(c);
      };
      for (size_t a = 0; a < n; ++a) {
        const size_t i = active[a];
        const double u_abs = abs_rec.value[a];
        if (coarse) {
          out.u_coarse[i] = static_cast<float>(u_abs);
          out.unwrap_residual[i] = static_cast<float>(abs_rec.residual[a]);
        }
        if (!abs_rec.valid[a]) {
          state[i] = PixelState::kUnwrapFailed;
          continue;
        }
        if (!use_ls || !fine_rec.valid[a]) {
          alone.push_back(static_cast<uint32_t>(a));
          continue;
        }
        out.sigma_u[i] = static_cast<float>(fine_rec.sigma_px[a]);
        // Eq. 2: alpha = lambda (round(omega w / lambda - phi) + phi), lambda the period, phi the
        // fine phase in cycles.
        const double phi = fine_rec.value[a];
        const double u = period * (RoundHalfAwayD(u_abs / period - phi) + phi);
        const double comb = u_abs - u;
        double c = fine_rec.confidence[a];
        if (fallback && !(c >= options.min_confidence && c > 0)) {
          alone.push_back(static_cast<uint32_t>(a));  // the stripes have lost their contrast
        } else if (std::abs(comb) > options.max_combination_residual_px) {
          // Good stripes that disagree with the coarse column by a period: neither is trusted.
          state[i] = PixelState::kCombination;
        } else {
          c *= 1.0 - std::pow(comb / options.max_combination_residual_px, 2);
          finish(a, u, c);
        }
      }
      absolute.Describe(active.data(), noise.data(), alone.data(), alone.size(), use_ls, &abs_rec);
      for (const uint32_t a : alone) {
        const size_t i = active[a];
        out.source[i] = 1;
        out.sigma_u[i] = static_cast<float>(abs_rec.sigma_px[a]);
        double c = abs_rec.confidence[a];
        if (use_ls) c *= options.phase_shift_fallback_confidence;
        finish(a, abs_rec.value[a], c);
      }
    }
  });
  if (reference_positions) {
    // The differences gathered in parallel (counted per block, then written at the blocks'
    // offsets); their median does not depend on the order.
    auto use = [&](size_t i) {
      return out.source[i] == 0 && std::isfinite(out.u[i]) && std::isfinite(out.u_coarse[i]);
    };
    std::vector<size_t> count(static_cast<size_t>(blocks) + 1, 0);
    tbb::parallel_for<int64_t>(0, blocks, [&](int64_t b) {
      const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
      size_t n = 0;
      for (size_t i = static_cast<size_t>(b) * kBlock; i < i_end; ++i) n += use(i);
      count[static_cast<size_t>(b) + 1] = n;
    });
    for (int b = 0; b < blocks; ++b) count[b + 1] += count[b];
    std::vector<float> d(count[blocks]);
    tbb::parallel_for<int64_t>(0, blocks, [&](int64_t b) {
      const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
      size_t k = count[b];
      for (size_t i = static_cast<size_t>(b) * kBlock; i < i_end; ++i)
        if (use(i)) d[k++] = out.u_coarse[i] - out.u[i];
    });
    if (d.size() >= 1000) {
      std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
      out.ls_offset_px = d[d.size() / 2];
      tbb::parallel_for(tbb::blocked_range<int>(0, blocks, 8), [&](const auto& range) {
        const int b0 = range.begin(), b1 = range.end();
        const size_t i_end = std::min(np, static_cast<size_t>(b1) * kBlock);
        for (size_t i = static_cast<size_t>(b0) * kBlock; i < i_end; ++i)
          if (out.source[i] == 0 && std::isfinite(out.u[i]))
            out.u[i] = static_cast<float>(out.u[i] + out.ls_offset_px);
      });
    }
  }
  return out;
}

CombinedPixels CombinePhases(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const LensShiftPixels& ls, const CombineOptions& options,
                             PixelStates* state, const PhaseShiftStageOptions& phase_shift) {
  // The absolute coordinate: the sine periods where they unwrap, else the first planned absolute
  // codec, which then fixes the order of the one sine period (OrderedCodec) if there is one.
  std::optional<PhaseShiftCodec> sine;
  if (!plan.periods.empty()) sine.emplace(plan, ps, phase_shift, options.confidence_t);
  const Codec* absolute = sine && sine->Kind() == CodecKind::kAbsolute ? &*sine : nullptr;
  for (const auto& c : plan.codecs)
    if (!absolute && c->Kind() == CodecKind::kAbsolute) absolute = c.get();
  if (!absolute)
    MESOSCAN_BAD_INPUT(plan.label << "/session.json: frames: nothing gives the absolute "
                                     "projector coordinate");
  std::optional<OrderedCodec> ordered;
  if (sine && sine->Kind() == CodecKind::kPeriodic) absolute = &ordered.emplace(*absolute, *sine);
  if (ls.empty()) return CombineCodecs(*absolute, nullptr, ps.level, options, state);
  const LensShiftCodec fine(plan, ls, options.confidence_t);
  return CombineCodecs(*absolute, &fine, ps.level, options, state);
}

void RejectIsolatedColumns(const RoiGrid& grid, const CombineOptions& options,
                           CombinedPixels* combined, PixelStates* state) {
  if (options.isolated_max_region_px <= 0 || grid.pixels() == 0) return;
  std::vector<float>& u = combined->u;
  // filterSpeckles takes 16-bit signed values: u in fixed point, as many fractional bits as the
  // projector's range allows (16ths of a pixel up to 2000 px).
  std::vector<float> row_max(grid.height, 0.0f);
  tbb::parallel_for(tbb::blocked_range<int>(0, grid.height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y) {
      float m = 0.0f;
      const float* row = u.data() + static_cast<size_t>(y) * grid.width;
      for (int x = 0; x < grid.width; ++x)
        if (std::isfinite(row[x])) m = std::max(m, std::abs(row[x]));
      row_max[y] = m;
    }
  });
  const float u_max = row_max.empty() ? 0.0f : *std::max_element(row_max.begin(), row_max.end());
  const double scale = std::min(16.0, 32000.0 / std::max(1.0f, u_max));
  constexpr int16_t kNone = std::numeric_limits<int16_t>::min();
  cv::Mat fixed(grid.height, grid.width, CV_16SC1);
  tbb::parallel_for(tbb::blocked_range<int>(0, grid.height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y) {
      int16_t* row = fixed.ptr<int16_t>(y);
      for (int x = 0; x < grid.width; ++x) {
        const float v = u[static_cast<size_t>(y) * grid.width + x];
        row[x] = std::isfinite(v) ? static_cast<int16_t>(RoundHalfAway(v * scale)) : kNone;
      }
    }
  });
  // filterSpeckles (serial) on bands of rows in parallel, each with `margin` rows of its
  // neighbours on either side, keeping its own rows' verdicts: the same as one call on the whole
  // image. A region of at most S pixels spans at most S rows, so a band sees all of it; a larger
  // region that leaves the band reaches any pixel of the band's own rows by a path of more than
  // `margin` >= S pixels inside the band, so the band sees more than S of its pixels too.
  const int max_region = options.isolated_max_region_px;
  const int margin = max_region + 1;
  const int band_rows = std::max(256, 8 * margin);
  const int bands = (grid.height + band_rows - 1) / band_rows;
  tbb::parallel_for<int64_t>(0, bands, [&](int64_t band) {
    const int y0 = static_cast<int>(band) * band_rows;
    const int y1 = std::min(grid.height, y0 + band_rows);
    const int m0 = std::max(0, y0 - margin), m1 = std::min(grid.height, y1 + margin);
    cv::Mat part = fixed.rowRange(m0, m1).clone();
    cv::filterSpeckles(part, kNone, max_region,
                       std::max(1.0, options.isolated_max_step_px * scale));
    for (int y = y0; y < y1; ++y) {
      const int16_t* row = part.ptr<int16_t>(y - m0);
      for (int x = 0; x < grid.width; ++x) {
        const size_t i = static_cast<size_t>(y) * grid.width + x;
        if (row[x] != kNone || !std::isfinite(u[i])) continue;
        (*state)[i] = PixelState::kIsolated;
        u[i] = std::numeric_limits<float>::quiet_NaN();
        combined->confidence[i] = 0.0f;
      }
    }
  });
}

}  // namespace mesoscan
