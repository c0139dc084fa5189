#include "heightfield/reconstruct.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <Eigen/Dense>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "heightfield/frame_corrections.h"
#include "heightfield/phase_shift.h"
#include "heightfield/triangulate.h"

namespace mesoscan {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

// Why a pixel has no point (for the counts); kOk = reconstructed.
enum PixelState : uint8_t {
  kOutside = 0,    // outside the ROI or masked out
  kSaturated,      // a frame is saturated
  kUnlit,          // white - black below min_lit
  kUnmodulated,    // phase-shift modulation too low
  kFitFailed,      // lens-shift fit invalid
  kUnwrapFailed,   // temporal unwrapping inconsistent
  kCombination,    // coarse and fine disagree (period jump)
  kLowConfidence,  // Eq. 4 confidence below min_confidence
  kNoIntersection, // triangulation failed
  kDiscontinuity,  // a mixed pixel at a depth discontinuity
  kActive,         // still in the running
  kOk,
};

class StageTimer {
 public:
  explicit StageTimer(ReconstructSummary* s) : s_(s), t_(Clock::now()) {}
  void Stage(const std::string& name) {
    const auto now = Clock::now();
    s_->timings_s.emplace_back(name, std::chrono::duration<double>(now - t_).count());
    t_ = now;
  }

 private:
  using Clock = std::chrono::steady_clock;
  ReconstructSummary* s_;
  Clock::time_point t_;
};

double Wrap2Pi(double a) {
  a = std::fmod(a, 2 * kPi);
  return a < 0 ? a + 2 * kPi : a;
}

ImageF NaNImage(int w, int h) { return ImageF(w, h, 1, kNaN); }

// One period of the phase-shift patterns (axis x, shift 0).
struct PeriodSet {
  double period = 0;
  std::vector<int> stack_frames;  // indices into the FrameStack
  std::vector<double> deltas;
};

// A robust quadratic surface f(x, y) through the finite values of `f` (w x h, row-major),
// evaluated everywhere; empty if there are too few values. Two rounds drop values beyond
// 4 MADs of the residual.
std::vector<float> SmoothFrequencyMap(const std::vector<float>& f, int w, int h) {
  std::vector<size_t> idx;
  for (size_t i = 0; i < f.size(); ++i)
    if (std::isfinite(f[i])) idx.push_back(i);
  if (idx.size() < 50) return {};
  const size_t stride = std::max<size_t>(1, idx.size() / 50000);
  std::vector<size_t> sample;
  for (size_t k = 0; k < idx.size(); k += stride) sample.push_back(idx[k]);
  const double sx = 2.0 / std::max(1, w), sy = 2.0 / std::max(1, h);
  auto terms = [&](size_t i, double* t) {
    const double x = (static_cast<double>(i % w) + 0.5) * sx - 1.0;
    const double y = (static_cast<double>(i / w) + 0.5) * sy - 1.0;
    t[0] = 1; t[1] = x; t[2] = y; t[3] = x * x; t[4] = x * y; t[5] = y * y;
  };
  std::vector<uint8_t> use(sample.size(), 1);
  Eigen::Matrix<double, 6, 1> c = Eigen::Matrix<double, 6, 1>::Zero();
  for (int round = 0; round < 3; ++round) {
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    for (size_t k = 0; k < sample.size(); ++k) {
      if (!use[k]) continue;
      Eigen::Matrix<double, 6, 1> t;
      terms(sample[k], t.data());
      A += t * t.transpose();
      b += t * static_cast<double>(f[sample[k]]);
    }
    c = A.ldlt().solve(b);
    if (!c.allFinite()) return {};
    std::vector<double> r(sample.size());
    for (size_t k = 0; k < sample.size(); ++k) {
      Eigen::Matrix<double, 6, 1> t;
      terms(sample[k], t.data());
      r[k] = std::abs(f[sample[k]] - t.dot(c));
    }
    std::vector<double> sorted = r;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double mad = 1.4826 * sorted[sorted.size() / 2];
    for (size_t k = 0; k < sample.size(); ++k) use[k] = r[k] <= 4 * mad + 1e-12;
  }
  std::vector<float> out(f.size());
  for (size_t i = 0; i < f.size(); ++i) {
    double t[6];
    terms(i, t);
    double v = 0;
    for (int q = 0; q < 6; ++q) v += t[q] * c(q);
    out[i] = static_cast<float>(v);
  }
  return out;
}

}  // namespace

void ReconstructOptions::Check() const {
  if (roi.x < 0 || roi.y < 0 || roi.w < 0 || roi.h < 0)
    MESOSCAN_BAD_INPUT("--roi: expected non-negative x,y,w,h");
  if (num_threads < 0) MESOSCAN_BAD_INPUT("--threads: expected >= 0, got " << num_threads);
  if (!(min_lit > 0)) MESOSCAN_BAD_INPUT("min_lit: expected > 0, got " << min_lit);
  if (!(min_modulation > 0 && min_modulation <= 0.5))
    MESOSCAN_BAD_INPUT("min_modulation: expected a value in (0, 0.5], got " << min_modulation);
  if (!(max_unwrap_residual > 0))
    MESOSCAN_BAD_INPUT("max_unwrap_residual: expected > 0, got " << max_unwrap_residual);
  if (!(max_combination_residual_px > 0 && max_combination_residual_px < 1))
    MESOSCAN_BAD_INPUT("max_combination_residual_px: expected a value in (0, 1), got "
                       << max_combination_residual_px);
  if (!(confidence_t > 0)) MESOSCAN_BAD_INPUT("confidence_t: expected > 0, got " << confidence_t);
  if (!(min_confidence >= 0 && min_confidence < 1))
    MESOSCAN_BAD_INPUT("min_confidence: expected a value in [0, 1), got " << min_confidence);
  mixed_pixels.Check();
  if (!(phase_shift_fallback_confidence > 0 && phase_shift_fallback_confidence <= 1))
    MESOSCAN_BAD_INPUT("phase_shift_fallback_confidence: expected a value in (0, 1], got "
                       << phase_shift_fallback_confidence);
  if (!(systematic_phase_noise >= 0))
    MESOSCAN_BAD_INPUT("systematic_phase_noise: expected >= 0, got " << systematic_phase_noise);
  resample.Check();
}

Json ReconstructOptions::ToJson() const {
  Json j;
  j["roi"] = {roi.x, roi.y, roi.w, roi.h};
  j["mask"] = mask_path;
  j["fitter"] = LensShiftFitterName(fitter);
  j["use_lens_shift"] = use_lens_shift;
  j["threads"] = num_threads;
  j["normalize_luminance"] = normalize_luminance;
  j["lens_shift_box_filter"] = lens_shift_box_filter;
  j["fit_frequency"] = fit_frequency;
  j["smooth_frequency"] = smooth_frequency;
  j["phase_shift_fallback"] = phase_shift_fallback;
  j["phase_shift_fallback_confidence"] = phase_shift_fallback_confidence;
  j["frame_gain_method"] = FrameGainMethodName(frame_gain_method);
  j["correct_positions"] = correct_positions;
  j["min_lit"] = min_lit;
  j["min_modulation"] = min_modulation;
  j["max_unwrap_residual"] = max_unwrap_residual;
  j["max_combination_residual_px"] = max_combination_residual_px;
  j["confidence_t"] = confidence_t;
  j["min_confidence"] = min_confidence;
  j["systematic_phase_noise"] = systematic_phase_noise;
  j["reject_mixed_pixels"] = reject_mixed_pixels;
  j["mixed_pixels"] = {{"max_sigmas", mixed_pixels.max_sigmas},
                       {"outlier_footprints", mixed_pixels.outlier_footprints},
                       {"shadow_edge_ratio", mixed_pixels.shadow_edge_ratio},
                       {"dim_ratio", mixed_pixels.dim_ratio},
                       {"dim_sigmas", mixed_pixels.dim_sigmas},
                       {"dim_sharpness", mixed_pixels.dim_sharpness},
                       {"passes", mixed_pixels.passes}};
  j["grid_pixel_size_m"] = resample.pixel_size;
  j["grid_max_edge_footprints"] = resample.max_edge_footprints;
  return j;
}

double ReconstructSummary::Seconds(const std::string& stage) const {
  for (const auto& [name, s] : timings_s)
    if (name == stage) return s;
  return 0.0;
}

std::string ReconstructSummary::BriefReport() const {
  std::ostringstream o;
  o << "reconstruct: " << pixels_valid << " points of " << pixels_roi << " pixels ("
    << pixels_lit << " lit, " << pixels_fitted << " fitted), "
    << (used_lens_shift ? "lens shift + phase shift" : "phase shift only") << " ("
    << unwrapping << " unwrapping), " << total_s << " s";
  return o.str();
}

Json ReconstructSummary::ToJson() const {
  Json j;
  Json t = Json::object();
  for (const auto& [name, s] : timings_s) t[name] = s;
  t["total"] = total_s;
  j["timings_s"] = t;
  j["pixels"] = {{"total", pixels_total},
                 {"roi", pixels_roi},
                 {"lit", pixels_lit},
                 {"fitted", pixels_fitted},
                 {"valid", pixels_valid},
                 {"saturated", pixels_saturated},
                 {"rejected_unwrap", pixels_rejected_unwrap},
                 {"rejected_combination", pixels_rejected_combination},
                 {"rejected_confidence", pixels_rejected_confidence},
                 {"rejected_discontinuity", pixels_rejected_discontinuity}};
  j["frames"] = {{"lens_shift", lens_shift_frames}, {"phase_shift", phase_shift_frames}};
  j["frame_gains"] = frame_gains;
  j["frame_corrections"] = frame_corrections;
  j["unwrapping"] = unwrapping;
  j["used_lens_shift"] = used_lens_shift;
  j["predicted_depth_rms_m"] = predicted_depth_rms_m;
  return j;
}

Scan Reconstruct(const Session& session, const ReconstructOptions& options,
                 ReconstructSummary* summary_out) {
  options.Check();
  ReconstructSummary local_summary;
  ReconstructSummary& sum = summary_out ? *summary_out : local_summary;
  sum = ReconstructSummary();
  const auto t_start = std::chrono::steady_clock::now();
  StageTimer timer(&sum);
  ThreadLimit thread_limit(options.num_threads);
  const Rig& rig = session.rig;
  const int cam_w = rig.camera.width, cam_h = rig.camera.height;
  sum.pixels_total = static_cast<int64_t>(cam_w) * cam_h;

  // ---- Plan: which frames encode what. Only axis-x sine frames at shift 0 decode u.
  const FramePlan plan = MakeFramePlan(session.frames);
  std::vector<int> wanted;  // session frame indices to decode
  std::vector<PeriodSet> periods;
  for (const auto& set : plan.sine) {
    if (set.axis != 'x') {
      MESOSCAN_LOG(kInfo) << "reconstruct: ignoring " << set.frames.size()
                          << " sine frames along the projector's y axis";
      continue;
    }
    PeriodSet p;
    p.period = set.period_px;
    for (size_t f : set.frames) {
      if (session.frames[f].shift_steps != 0) continue;  // the calibrated model holds at 0
      p.stack_frames.push_back(static_cast<int>(wanted.size()));
      p.deltas.push_back(session.frames[f].pattern.phase);
      wanted.push_back(static_cast<int>(f));
    }
    if (p.stack_frames.size() >= 3) periods.push_back(std::move(p));
  }
  if (periods.empty())
    MESOSCAN_BAD_INPUT(session.root.string()
                       << "/session.json: frames: no sine pattern along x with >= 3 phases at "
                          "shift_steps 0; nothing gives the absolute projector column");
  std::vector<double> period_list;
  for (const auto& p : periods) period_list.push_back(p.period);
  const double range_px = rig.projector.width;
  const double longest = *std::max_element(period_list.begin(), period_list.end());
  sum.unwrapping = period_list.size() == 1   ? "single"
                   : longest >= range_px     ? "hierarchical"
                                             : "temporal";
  const TemporalUnwrapper unwrapper(period_list, range_px, options.max_unwrap_residual);
  std::vector<WrappedPhaseSolver> solvers;
  for (const auto& p : periods) solvers.emplace_back(p.deltas);
  for (const auto& p : periods) sum.phase_shift_frames += static_cast<int>(p.stack_frames.size());

  // Lens-shift frames (stripes, period 2, axis x), sorted by shift.
  std::vector<int> ls_stack;  // stack indices
  std::vector<double> ls_shift_px;
  std::vector<std::pair<int, size_t>> by_shift;
  if (options.use_lens_shift && rig.lens_shifter) {
    for (size_t f : plan.lens_shift) {
      const Pattern& pat = session.frames[f].pattern;
      if (pat.axis != 'x' || std::abs(pat.period_px - 2.0) > 1e-9) continue;
      by_shift.emplace_back(session.frames[f].shift_steps, f);
    }
    std::sort(by_shift.begin(), by_shift.end());
  }
  const bool use_ls = by_shift.size() >= 4;
  if (use_ls) {
    for (const auto& [steps, f] : by_shift) {
      ls_stack.push_back(static_cast<int>(wanted.size()));
      ls_shift_px.push_back(steps / rig.lens_shifter->steps_per_px);
      wanted.push_back(static_cast<int>(f));
    }
  }
  sum.used_lens_shift = use_ls;
  sum.lens_shift_frames = static_cast<int>(ls_stack.size());
  int white_k = -1, black_k = -1;
  if (!plan.white.empty()) {
    white_k = static_cast<int>(wanted.size());
    wanted.push_back(static_cast<int>(plan.white.front()));
  }
  if (!plan.black.empty()) {
    black_k = static_cast<int>(wanted.size());
    wanted.push_back(static_cast<int>(plan.black.front()));
  }
  const bool has_white = white_k >= 0;

  // ---- 1. Decode.
  FrameLoadOptions load;
  load.roi = options.roi;
  FrameStack stack = LoadFrames(session, wanted, load);
  const PixelRect roi = stack.roi();
  const int w = stack.width(), h = stack.height();
  const size_t np = stack.pixels();
  timer.Stage("decode");

  // ---- Masks: ROI, user mask, saturation, lit.
  std::vector<uint8_t> state(np, kActive);
  if (!options.mask_path.empty()) {
    ImageInfo info;
    const ImageF mask = ReadImageGrey(options.mask_path, &info);
    if (mask.width() != cam_w || mask.height() != cam_h)
      MESOSCAN_BAD_INPUT(options.mask_path << ": size " << mask.width() << "x" << mask.height()
                                           << ", expected the camera's " << cam_w << "x"
                                           << cam_h);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        if (!(mask(x + roi.x, y + roi.y) > 0)) state[static_cast<size_t>(y) * w + x] = kOutside;
  }
  std::vector<float> white_level(np, kNaN), black_value(np, 0.0f);
  for (size_t i = 0; i < np; ++i) {
    if (state[i] == kOutside) continue;
    ++sum.pixels_roi;
    if (stack.saturated()[i]) {
      state[i] = kSaturated;
      ++sum.pixels_saturated;
      continue;
    }
    if (black_k >= 0) black_value[i] = stack.Value(black_k, i);
    if (has_white) {
      white_level[i] = stack.Value(white_k, i) - black_value[i];
      if (!(white_level[i] >= options.min_lit)) state[i] = kUnlit;
    }
  }

  // ---- 2. Per-frame luminance normalisation on a subsample of lit pixels.
  sum.frame_gains.assign(session.frames.size(), 1.0);
  std::vector<float> inv_gain(wanted.size(), 1.0f);
  if (options.normalize_luminance) {
    std::vector<uint32_t> sample;
    size_t n_active = 0;
    for (size_t i = 0; i < np; ++i) n_active += state[i] == kActive;
    const size_t stride = std::max<size_t>(1, n_active / 20000);
    for (size_t i = 0, c = 0; i < np; ++i)
      if (state[i] == kActive && (c++ % stride) == 0) sample.push_back(static_cast<uint32_t>(i));
    auto apply = [&](const GainModel& m, const std::vector<double>& g) {
      for (size_t k = 0; k < m.frames.size(); ++k) {
        inv_gain[m.frames[k]] = static_cast<float>(1.0 / g[k]);
        sum.frame_gains[wanted[m.frames[k]]] = g[k];
      }
    };
    // Sine frames: a DC shared by every period, a cosine and a sine per period.
    GainModel ps;
    const int nper = static_cast<int>(periods.size());
    for (int p = 0; p < nper; ++p)
      for (size_t k = 0; k < periods[p].stack_frames.size(); ++k) {
        std::vector<double> row(1 + 2 * nper, 0.0);
        row[0] = 1.0;
        row[1 + 2 * p] = std::cos(periods[p].deltas[k]);
        row[2 + 2 * p] = -std::sin(periods[p].deltas[k]);
        ps.frames.push_back(periods[p].stack_frames[k]);
        ps.design.push_back(row);
      }
    apply(ps, EstimateFrameGains(stack, ps, sample));
    if (use_ls) {
      // Lens-shift frames: DC plus the nominal sinusoid and its first two derivatives by
      // frequency (x^m cos, x^m sin; the per-pixel frequency deviates from nominal by several
      // percent, which the gains must not absorb). Note: jitter along the sinusoid itself
      // (the part that biases the phase, ~jitter * sqrt(2/N) * d/a rad) is absorbed by each
      // pixel's fit and cannot be told from the pattern without a spatial assumption; frame
      // averages were tried and are worse unless the view holds hundreds of stripe periods.
      const double centre =
          std::accumulate(ls_shift_px.begin(), ls_shift_px.end(), 0.0) / ls_shift_px.size();
      GainModel ls;
      for (size_t k = 0; k < ls_stack.size(); ++k) {
        const double x = ls_shift_px[k] - centre, ph = kPi * x;
        ls.frames.push_back(ls_stack[k]);
        ls.design.push_back({1.0, std::cos(ph), std::sin(ph), x * std::cos(ph), x * std::sin(ph),
                             x * x * std::cos(ph), x * x * std::sin(ph)});
      }
      apply(ls, EstimateFrameGains(stack, ls, sample));
    }
  }
  timer.Stage("normalize");

  // ---- 3. Phase shifting: wrapped phase, modulation per period.
  const int nper = static_cast<int>(periods.size());
  const double proj_gamma =
      rig.projector_response.kind == Response::Kind::kGamma ? rig.projector_response.gamma : 1.0;
  const bool linearize_gamma = std::abs(proj_gamma - 1.0) > 1e-9 && has_white;
  if (std::abs(proj_gamma - 1.0) > 1e-9 && !has_white)
    MESOSCAN_LOG(kWarning) << session.root.string()
                           << ": projector gamma without white/black frames: sine patterns are "
                              "decoded as if linear (phase bias from harmonics)";
  std::vector<std::vector<float>> theta(nper, std::vector<float>(np, kNaN));
  std::vector<std::vector<float>> modulation(nper, std::vector<float>(np, kNaN));
  std::vector<std::vector<float>> ps_res(nper, std::vector<float>(np, kNaN));
  std::vector<float> level(np, kNaN);
  ParallelForRows(h, [&](int y0, int y1) {
    std::vector<float> buf;
    const size_t i0 = static_cast<size_t>(y0) * w, n = static_cast<size_t>(y1 - y0) * w;
    for (int p = 0; p < nper; ++p) {
      const int K = static_cast<int>(periods[p].stack_frames.size());
      buf.resize(static_cast<size_t>(K) * n);
      for (int k = 0; k < K; ++k) {
        const int sk = periods[p].stack_frames[k];
        stack.Gather(sk, i0, n, buf.data() + k * n);
        const float g = inv_gain[sk];
        for (size_t j = 0; j < n; ++j) buf[k * n + j] *= g;
      }
      for (size_t j = 0; j < n; ++j) {
        const size_t i = i0 + j;
        if (state[i] != kActive) continue;
        if (linearize_gamma) {
          // v^g is what the camera sees (relative to white); undo it per sample.
          const float wl = white_level[i], bl = black_value[i];
          for (int k = 0; k < K; ++k) {
            float& s = buf[k * n + j];
            const double v = std::clamp((s - bl) / wl, 0.0f, 1.0f);
            s = static_cast<float>(std::pow(v, 1.0 / proj_gamma) * wl);
          }
        }
        const auto r = solvers[p].Solve(buf.data() + j, static_cast<int>(n));
        if (!r.valid) continue;
        theta[p][i] = r.theta;
        modulation[p][i] = r.modulation;
        ps_res[p][i] = r.residual_rms;
        if (p == 0 && !has_white) level[i] = 2.0f * r.offset;
      }
    }
    for (size_t j = 0; j < n; ++j) {
      const size_t i = i0 + j;
      if (state[i] != kActive) continue;
      if (has_white) level[i] = white_level[i];
      if (!(level[i] >= options.min_lit)) {
        state[i] = kUnlit;
        continue;
      }
      for (int p = 0; p < nper; ++p)
        if (!(modulation[p][i] >= options.min_modulation * level[i])) state[i] = kUnmodulated;
    }
  });
  for (size_t i = 0; i < np; ++i) sum.pixels_lit += state[i] == kActive;
  timer.Stage("phase_shift");

  // ---- 4. Lens-shift fit, positions referenced to the centre of the shift range.
  const int nls = static_cast<int>(ls_stack.size());
  std::vector<float> ls_phase0(np, kNaN), ls_amp(np, kNaN), ls_freq(np, kNaN), ls_off(np, kNaN),
      ls_rms(np, kNaN), ls_n(np, kNaN);
  if (use_ls) {
    const double centre =
        std::accumulate(ls_shift_px.begin(), ls_shift_px.end(), 0.0) / nls;
    // Box filter: 5-sample moving average ("valid" part only, so no sample is shifted).
    const bool box = options.lens_shift_box_filter && nls >= 9;
    std::vector<double> x;
    if (box) {
      for (int k = 2; k + 2 < nls; ++k) {
        double s = 0;
        for (int q = -2; q <= 2; ++q) s += ls_shift_px[k + q];
        x.push_back(s / 5 - centre);
      }
    } else {
      for (double s : ls_shift_px) x.push_back(s - centre);
    }
    LensShiftFitOptions fo;
    fo.fitter = options.fitter;
    fo.fit_frequency = options.fit_frequency;
    const int nx = static_cast<int>(x.size());
    // Pixels of a fitting pass: every `stride`-th pixel of every `stride`-th row, or (complement)
    // all the others.
    struct PixelSubset {
      int stride = 1;
      bool complement = false;
      bool Row(int y) const { return complement || y % stride == 0; }
      bool Has(int x, int y) const {
        return (x % stride == 0 && y % stride == 0) != complement;
      }
    };
    // One pass over the active pixels of `subset`; f_map (if given) is the per-pixel frequency
    // held fixed. Rows without a pixel of the subset are not even gathered.
    auto fit_pass = [&](const LensShiftBatchFitter& fitter, const std::vector<float>* f_map,
                        const PixelSubset& subset, const char* label) {
      Progress progress(label, h);
      ParallelForRows(h, [&](int y0, int y1) {
        const size_t n = static_cast<size_t>(w);
        std::vector<float> buf(static_cast<size_t>(nls) * n), prof(static_cast<size_t>(nx));
        for (int y = y0; y < y1; ++y) {
          if (!subset.Row(y)) continue;
          const size_t i0 = static_cast<size_t>(y) * w;
          for (int k = 0; k < nls; ++k) {
            stack.Gather(ls_stack[k], i0, n, buf.data() + k * n);
            const float g = inv_gain[ls_stack[k]];
            for (size_t j = 0; j < n; ++j) buf[k * n + j] *= g;
          }
          for (size_t j = 0; j < n; ++j) {
            const size_t i = i0 + j;
            if (state[i] != kActive || !subset.Has(static_cast<int>(j), y)) continue;
            const float* b = buf.data() + j;
            int stride = static_cast<int>(n);
            if (box) {
              for (int k = 0; k < nx; ++k) {
                float sm = 0;
                for (int q = 0; q < 5; ++q) sm += buf[(k + q) * n + j];
                prof[k] = sm / 5;
              }
              b = prof.data();
              stride = 1;
            }
            const LensShiftFit fit =
                f_map ? fitter.Fit(b, stride, (*f_map)[i]) : fitter.Fit(b, stride);
            if (!fit.valid) {
              state[i] = kFitFailed;
              if (std::isfinite(fit.residual_rms) && fit.samples_used > 4) {  // noise estimate
                ls_rms[i] = static_cast<float>(fit.residual_rms);
                ls_n[i] = static_cast<float>(fit.samples_used);
              }
              continue;
            }
            // Phase at shift 0 with the pixel's own frequency (the model holds at shift 0).
            ls_phase0[i] = static_cast<float>(fit.phase - 2 * kPi * fit.frequency * centre);
            ls_amp[i] = static_cast<float>(fit.amplitude);
            ls_freq[i] = static_cast<float>(fit.frequency);
            ls_off[i] = static_cast<float>(fit.offset);
            ls_rms[i] = static_cast<float>(fit.residual_rms);
            ls_n[i] = static_cast<float>(fit.samples_used);
          }
        }
        progress.Advance(y1 - y0);
      });
    };
    const LensShiftBatchFitter fitter(x, 0.5, fo);
    if (options.fit_frequency && options.smooth_frequency) {
      // The shifter's gain varies smoothly over the image: a robust quadratic of the fitted
      // frequencies, then the phase of every pixel with f held there (3 parameters: lower
      // variance). The quadratic is fitted to ~50000 frequencies (SmoothFrequencyMap), so the
      // 4-parameter fit runs on a regular subsample of about twice that many pixels only (all
      // pixels of crops below that).
      constexpr size_t kFrequencySamples = 100000;
      size_t n_active = 0;
      for (size_t i = 0; i < np; ++i) n_active += state[i] == kActive;
      PixelSubset subset;
      subset.stride = std::max(1, static_cast<int>(std::sqrt(n_active / kFrequencySamples)));
      fit_pass(fitter, nullptr, subset, "fit lens shift frequency");
      std::vector<float> f_map = SmoothFrequencyMap(ls_freq, w, h);
      if (!f_map.empty()) {
        LensShiftFitOptions fo2 = fo;
        fo2.fit_frequency = false;
        if (!box) {  // issue 13: joint frame gains and positions
          FrameCorrectionOptions fco;
          fco.method = options.frame_gain_method;
          fco.estimate_positions = options.correct_positions;
          const FrameCorrections fc =
              CorrectLensShiftFrames(stack, ls_stack, ls_freq, f_map, &x, &inv_gain, fco,
                                     &ls_amp, &ls_phase0, &ls_off);
          for (int k = 0; k < nls; ++k) sum.frame_gains[wanted[ls_stack[k]]] = 1.0 / inv_gain[ls_stack[k]];
          sum.frame_corrections = fc.ToJson();
        }
        fit_pass(LensShiftBatchFitter(x, 0.5, fo2), &f_map, PixelSubset(), "fit lens shift");
      } else if (subset.stride > 1) {
        // No frequency map: the 4-parameter fit everywhere else too.
        subset.complement = true;
        fit_pass(fitter, nullptr, subset, "fit lens shift");
      }
    } else {
      fit_pass(fitter, nullptr, PixelSubset(), "fit lens shift");
    }
  }
  for (size_t i = 0; i < np; ++i)
    sum.pixels_fitted += state[i] == kActive || state[i] == kFitFailed;
  timer.Stage("lens_shift");

  // ---- 5./6. Unwrapping, combination (paper Eq. 2), confidence (paper Eq. 4).
  std::vector<float> u_final(np, kNaN), u_coarse(np, kNaN), unwrap_res(np, kNaN),
      conf(np, 0.0f), sigma_u(np, kNaN);
  // Which cue fixed u (points.exr `source`): 0 lens shift, 1 phase shifting alone.
  std::vector<uint8_t> source(np, use_ls ? 0 : 1);
  const bool fallback = use_ls && options.phase_shift_fallback;
  ParallelForRows(h, [&](int y0, int y1) {
    std::vector<double> th(nper), wt(nper);
    for (size_t i = static_cast<size_t>(y0) * w; i < static_cast<size_t>(y1) * w; ++i) {
      // Issue 13, graceful defocus: a failed lens-shift fit falls back to phase shifting.
      if (state[i] == kFitFailed && fallback) state[i] = kActive;
      if (state[i] != kActive) continue;
      // Per-sample noise: from the lens-shift residual (many samples) or the phase-shift
      // residuals (K > 3), else a floor of 1% of the white level; plus a systematic part
      // (model errors: harmonics, defocus, jitter) proportional to the modulation.
      double sigma = 0.01 * level[i];
      if (use_ls && ls_n[i] > 4) {
        const bool four = options.fit_frequency && !options.smooth_frequency;
        sigma = ls_rms[i] * std::sqrt(ls_n[i] / (ls_n[i] - (four ? 4 : 3)));
      } else {
        double s2 = 0;
        int cnt = 0;
        for (int p = 0; p < nper; ++p) {
          const int K = static_cast<int>(periods[p].stack_frames.size());
          if (K > 3) {
            s2 += ps_res[p][i] * ps_res[p][i] * K / (K - 3.0);
            ++cnt;
          }
        }
        if (cnt) sigma = std::sqrt(s2 / cnt);
      }
      sigma = std::max(sigma, 1e-4 * level[i]);
      for (int p = 0; p < nper; ++p) {
        th[p] = theta[p][i];
        const double var = solvers[p].ThetaVariance(sigma, modulation[p][i]) +
                           std::pow(options.systematic_phase_noise, 2);
        wt[p] = 1.0 / var;
      }
      const UnwrapResult ur = unwrapper.Unwrap(th.data(), wt.data());
      u_coarse[i] = static_cast<float>(ur.u);
      unwrap_res[i] = static_cast<float>(ur.residual);
      if (!ur.valid) {
        state[i] = kUnwrapFailed;
        continue;
      }
      double u = ur.u, c = 1.0;
      bool ls_pixel = use_ls && std::isfinite(ls_phase0[i]);
      if (ls_pixel) {
        sigma_u[i] = static_cast<float>(
            std::sqrt(2.0 * sigma * sigma / (ls_n[i] * ls_amp[i] * ls_amp[i])) / kPi);
        // Eq. 2: alpha = lambda (round(omega w / lambda - phi) + phi), lambda = 2 px, phi the
        // fine phase in cycles. u_fine = 1/2 - phase0 / pi (mod 2), see the header.
        const double phi = Wrap2Pi(kPi / 2 - ls_phase0[i]) / (2 * kPi);  // cycles in [0, 1)
        u = 2.0 * (std::round(ur.u / 2.0 - phi) + phi);
        const double comb = ur.u - u;
        const double e = std::pow(ls_rms[i] / ls_amp[i], 2);  // Eq. 4's E, normalised units
        c = 1.0 - std::sqrt(e * options.confidence_t);
        c *= 1.0 - std::pow(comb / options.max_combination_residual_px, 2);
        if (fallback && !(c >= options.min_confidence && c > 0)) {
          ls_pixel = false;  // the stripes have lost their contrast: phase shifting decides
          u = ur.u;
        } else if (std::abs(comb) > options.max_combination_residual_px) {
          state[i] = kCombination;  // the cues disagree: neither is trusted
          continue;
        }
      }
      if (!ls_pixel) {
        source[i] = 1;
        double info = 0.0;  // Fisher information of u from the periods
        // Fallback pixels: the model errors (systematic_phase_noise) count as in the weights.
        const double sys2 = use_ls ? std::pow(options.systematic_phase_noise, 2) : 0.0;
        for (int p = 0; p < nper; ++p)
          info += std::pow(2 * kPi / periods[p].period, 2) /
                  (solvers[p].ThetaVariance(sigma, modulation[p][i]) + sys2);
        sigma_u[i] = static_cast<float>(1.0 / std::sqrt(info));
        double e = 0.0;
        for (int p = 0; p < nper; ++p)
          e = std::max(e, std::pow(ps_res[p][i] / modulation[p][i], 2));
        c = 1.0 - std::sqrt(e * options.confidence_t);
        if (use_ls) c *= options.phase_shift_fallback_confidence;
      }
      if (nper > 1) c *= 1.0 - std::pow(ur.residual / options.max_unwrap_residual, 2);
      c = std::clamp(c, 0.0, 1.0);
      if (!(c >= options.min_confidence) || c <= 0) {
        state[i] = kLowConfidence;
        continue;
      }
      u_final[i] = static_cast<float>(u);
      conf[i] = static_cast<float>(c);
    }
  });
  timer.Stage("unwrap_combine");

  // ---- Triangulation.
  const Triangulator tri(rig.camera, rig.projector);
  Scan scan;
  scan.points.xyz = ImageF(cam_w, cam_h, 3, kNaN);
  scan.points.confidence = ImageF(cam_w, cam_h, 1, 0.0f);
  scan.points.projector_u = NaNImage(cam_w, cam_h);
  scan.points.source = NaNImage(cam_w, cam_h);
  ImageF dz_du;
  if (options.keep_diagnostics) dz_du = NaNImage(cam_w, cam_h);
  std::vector<float> sigma_z(np, kNaN);  // predicted depth sigma: sigma_u |dZ/du|, m
  ParallelForRows(h, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        const int cx = x + roi.x, cy = y + roi.y;
        if (std::isfinite(u_final[i])) scan.points.projector_u(cx, cy) = u_final[i];
        if (state[i] != kActive) continue;
        const Vec3d ray = tri.CameraRay(cx, cy);
        const auto p = tri.Intersect(ray, u_final[i]);
        if (!p) {
          state[i] = kNoIntersection;
          continue;
        }
        for (int c = 0; c < 3; ++c) scan.points.xyz(cx, cy, c) = static_cast<float>((*p)[c]);
        scan.points.confidence(cx, cy) = conf[i];
        scan.points.source(cx, cy) = source[i];
        state[i] = kOk;
        // dZ/du by a forward difference (the map is smooth on this scale).
        const auto b = tri.Intersect(ray, u_final[i] + 0.5);
        if (b) {
          const float d = static_cast<float>(2.0 * (b->z() - p->z()));
          if (options.keep_diagnostics) dz_du(cx, cy) = d;
          sigma_z[i] = sigma_u[i] * std::abs(d);
        }
      }
  });
  // RMS of the predicted depth sigma over the points still accepted (every 4th pixel and row).
  auto predicted_depth_rms = [&] {
    double s2 = 0;
    int64_t n = 0;
    for (int y = 0; y < h; y += 4)
      for (int x = 0; x < w; x += 4) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (state[i] == kOk && std::isfinite(sigma_z[i])) {
          s2 += static_cast<double>(sigma_z[i]) * sigma_z[i];
          ++n;
        }
      }
    return n ? std::sqrt(s2 / n) : 0.0;
  };
  // Mixed pixels at depth steps and shadow edges (heightfield/mixed_pixels.h).
  if (options.reject_mixed_pixels) {
    std::vector<float> z(np, kNaN);
    std::vector<uint8_t> unlit(np, 0);
    for (size_t i = 0; i < np; ++i) {
      const int cx = static_cast<int>(i % w) + roi.x, cy = static_cast<int>(i / w) + roi.y;
      if (state[i] == kOk) z[i] = scan.points.xyz(cx, cy, 2);
      unlit[i] = state[i] == kUnlit || state[i] == kUnmodulated;
    }
    MixedPixelInput in;
    in.width = w;
    in.height = h;
    in.z = z.data();
    in.sigma_z = sigma_z.data();
    in.white = white_level.data();
    in.unlit = unlit.data();
    in.footprint_m = CameraFootprint(scan.points.xyz);
    const std::vector<uint8_t> reject = FindMixedPixels(in, options.mixed_pixels);
    for (size_t i = 0; i < np; ++i) {
      if (!reject[i]) continue;
      state[i] = kDiscontinuity;
      const int cx = static_cast<int>(i % w) + roi.x, cy = static_cast<int>(i / w) + roi.y;
      for (int c = 0; c < 3; ++c) scan.points.xyz(cx, cy, c) = kNaN;
      scan.points.confidence(cx, cy) = 0.0f;
      scan.points.source(cx, cy) = kNaN;
    }
  }
  for (size_t i = 0; i < np; ++i) {
    sum.pixels_rejected_discontinuity += state[i] == kDiscontinuity;
    sum.pixels_valid += state[i] == kOk;
    sum.pixels_rejected_unwrap += state[i] == kUnwrapFailed;
    sum.pixels_rejected_combination += state[i] == kCombination;
    sum.pixels_rejected_confidence += state[i] == kLowConfidence;
  }
  if (!use_ls) sum.pixels_fitted = sum.pixels_lit;
  sum.predicted_depth_rms_m = predicted_depth_rms();
  timer.Stage("triangulate");

  // ---- 7. Height field and normals.
  scan.height = ResampleToGrid(scan.points.xyz, scan.points.confidence, options.resample);
  if (scan.height.z.empty()) {  // nothing reconstructed: a 1x1 unknown grid keeps the layout
    scan.height.z = NaNImage(1, 1);
    scan.height.confidence = ImageF(1, 1, 1, 0.0f);
  }
  scan.normals = scan.height.Normals();
  timer.Stage("height_field");

  if (options.keep_diagnostics) {
    ReconstructDiagnostics& d = sum.diagnostics;
    auto to_cam = [&](const std::vector<float>& v) {
      ImageF im = NaNImage(cam_w, cam_h);
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) im(x + roi.x, y + roi.y) = v[static_cast<size_t>(y) * w + x];
      return im;
    };
    d.u_coarse = to_cam(u_coarse);
    d.unwrap_residual = to_cam(unwrap_res);
    std::vector<float> mod(np, kNaN);
    for (size_t i = 0; i < np; ++i) {
      float m = std::numeric_limits<float>::infinity();
      for (int p = 0; p < nper; ++p) m = std::min(m, modulation[p][i] / level[i]);
      mod[i] = std::isfinite(m) ? m : kNaN;
    }
    d.ps_modulation = to_cam(mod);
    d.white_level = to_cam(level);
    d.ls_amplitude = to_cam(ls_amp);
    d.ls_offset = to_cam(ls_off);
    d.ls_frequency = to_cam(ls_freq);
    d.ls_residual_rms = to_cam(ls_rms);
    d.ls_samples = to_cam(ls_n);
    d.dz_du = std::move(dz_du);
    d.u = to_cam(u_final);
    d.sigma_u = to_cam(sigma_u);
  }
  sum.total_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  scan.report["summary"] = sum.ToJson();
  scan.report["options"] = options.ToJson();
  return scan;
}

// ---------------------------------------------------------------------------------------------

Json GroundTruthErrors::ToJson() const {
  return {{"depth_error", "Z(reconstructed) - Z(gt_points.exr) at the same camera pixel, metres"},
          {"pixels_gt", pixels_gt},
          {"pixels_both", pixels_both},
          {"coverage", coverage},
          {"rms_m", rms_m},
          {"mean_m", mean_m},
          {"median_abs_m", median_abs_m},
          {"p99_abs_m", p99_abs_m},
          {"max_abs_m", max_abs_m},
          {"gross", gross},
          {"gross_fraction", gross_fraction},
          {"gross_threshold_m", gross_threshold_m},
          {"footprint_known", footprint_known},
          {"mixed_relief_m", mixed_relief_m},
          {"pixels_mixed", pixels_mixed},
          {"mixed_kept", mixed_kept},
          {"gross_mixed", gross_mixed},
          {"coverage_single", coverage_single}};
}

double LensShiftDepthCrlbRms(const Session& session, const ReconstructDiagnostics& d,
                             const ImageF& error, const std::function<double(double)>& sigma) {
  if (d.ls_amplitude.empty() || session.frames.empty()) return 0.0;
  const double steps_per_px = session.rig.lens_shifter ? session.rig.lens_shifter->steps_per_px : 1.0;
  std::vector<double> x;
  for (const Frame& f : session.frames)
    if (f.pattern.type == PatternType::kStripes) x.push_back(f.shift_steps / steps_per_px);
  if (x.empty()) return 0.0;
  const double centre = std::accumulate(x.begin(), x.end(), 0.0) / x.size();
  for (double& v : x) v -= centre;
  double s2 = 0;
  int64_t n = 0;
  for (int y = 0; y < d.u.height(); ++y)
    for (int xx = 0; xx < d.u.width(); ++xx) {
      if (!std::isfinite(error(xx, y)) || !std::isfinite(d.dz_du(xx, y))) continue;
      const double var_phi = LensShiftPhaseCrlb(sigma(d.ls_offset(xx, y)), d.ls_amplitude(xx, y),
                                                x, d.ls_frequency(xx, y),
                                                /*fit_frequency=*/false);
      s2 += var_phi / (M_PI * M_PI) * std::pow(d.dz_du(xx, y), 2);
      ++n;
    }
  return n ? std::sqrt(s2 / n) : 0.0;
}

GroundTruthErrors EvaluateAgainstGroundTruth(const Session& session, const ScanPoints& points,
                                             const PixelRect& roi_in, double gross_threshold_m) {
  if (!session.ground_truth)
    MESOSCAN_BAD_INPUT(session.root.string() << "/session.json: ground_truth: not present");
  const auto path = session.root / session.ground_truth->points;
  const ImageInfo info = ReadImageInfo(path);
  const auto& names = info.channel_names;
  auto has = [&](const char* c) { return std::find(names.begin(), names.end(), c) != names.end(); };
  const bool footprint = has("lit_fraction") && has("relief");
  const ImageF gt = footprint ? ReadExrChannels(path, {"X", "Y", "Z", "lit_fraction", "relief"})
                              : ReadExrChannels(path, {"X", "Y", "Z"});
  const int w = points.xyz.width(), h = points.xyz.height();
  if (gt.width() != w || gt.height() != h)
    MESOSCAN_BAD_INPUT(path.string() << ": size " << gt.width() << "x" << gt.height()
                                     << ", expected the camera's " << w << "x" << h);
  PixelRect roi = roi_in;
  if (roi.w <= 0 || roi.h <= 0) roi = {0, 0, w, h};
  GroundTruthErrors e;
  e.error = NaNImage(w, h);
  std::vector<double> errs;
  for (int y = std::max(0, roi.y); y < std::min(h, roi.y + roi.h); ++y)
    for (int x = std::max(0, roi.x); x < std::min(w, roi.x + roi.w); ++x) {
      const float zg = gt(x, y, 2);
      if (!std::isfinite(zg)) continue;
      ++e.pixels_gt;
      const float z = points.xyz(x, y, 2);
      if (!std::isfinite(z)) continue;
      const double d = static_cast<double>(z) - zg;
      e.error(x, y) = static_cast<float>(d);
      errs.push_back(d);
    }
  e.pixels_both = static_cast<int64_t>(errs.size());
  e.coverage = e.pixels_gt ? static_cast<double>(e.pixels_both) / e.pixels_gt : 0.0;
  if (errs.empty()) return e;
  double s = 0, s2 = 0;
  std::vector<double> a;
  for (double d : errs) {
    s += d;
    s2 += d * d;
    a.push_back(std::abs(d));
  }
  e.mean_m = s / errs.size();
  e.rms_m = std::sqrt(s2 / errs.size());
  std::sort(a.begin(), a.end());
  e.median_abs_m = a[a.size() / 2];
  e.p99_abs_m = a[std::min(a.size() - 1, static_cast<size_t>(0.99 * a.size()))];
  e.max_abs_m = a.back();
  if (gross_threshold_m <= 0) {
    double in2 = 0;
    size_t n = 0;
    for (double v : a)
      if (v < 5 * e.median_abs_m) {
        in2 += v * v;
        ++n;
      }
    gross_threshold_m = 10 * std::sqrt(in2 / std::max<size_t>(1, n));
  }
  e.gross_threshold_m = gross_threshold_m;
  for (double v : a) e.gross += v > gross_threshold_m;
  e.gross_fraction = static_cast<double>(e.gross) / errs.size();

  e.footprint_known = footprint;
  e.mixed_relief_m = footprint ? gross_threshold_m / 10 : 0.0;
  int64_t single = 0, single_both = 0;
  for (int y = std::max(0, roi.y); y < std::min(h, roi.y + roi.h); ++y)
    for (int x = std::max(0, roi.x); x < std::min(w, roi.x + roi.w); ++x) {
      if (!std::isfinite(gt(x, y, 2))) continue;
      const bool kept = std::isfinite(e.error(x, y));
      const bool mixed = footprint && (gt(x, y, 3) < 1.0f || gt(x, y, 4) > e.mixed_relief_m);
      if (!mixed) {
        ++single;
        single_both += kept;
        continue;
      }
      ++e.pixels_mixed;
      e.mixed_kept += kept;
      e.gross_mixed += kept && std::abs(e.error(x, y)) > gross_threshold_m;
    }
  e.coverage_single = single ? static_cast<double>(single_both) / single : 0.0;
  return e;
}

void WriteErrorMapPng(const std::filesystem::path& path, const ImageF& error, double max_m) {
  const int w = error.width(), h = error.height();
  if (max_m <= 0) {
    std::vector<float> a;
    for (float v : error.data())
      if (std::isfinite(v)) a.push_back(std::abs(v));
    if (!a.empty()) {
      std::nth_element(a.begin(), a.begin() + static_cast<size_t>(0.99 * (a.size() - 1)), a.end());
      max_m = a[static_cast<size_t>(0.99 * (a.size() - 1))];
    }
    if (!(max_m > 0)) max_m = 1e-6;
  }
  // Image, then a scale bar below it (at least 320 px wide so the labels fit).
  const int bar_h = 48, out_w = std::max(w, 320);
  cv::Mat grey(h, w, CV_8UC1, cv::Scalar(0)), valid(h, w, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float v = error(x, y);
      if (!std::isfinite(v)) continue;
      grey.at<uint8_t>(y, x) = static_cast<uint8_t>(std::clamp(std::abs(v) / max_m, 0.0, 1.0) * 255);
      valid.at<uint8_t>(y, x) = 255;
    }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_VIRIDIS);
  cv::Mat out(h + bar_h, out_w, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::Mat black(h, w, CV_8UC3, cv::Scalar(0, 0, 0));
  colour.copyTo(black, valid);
  black.copyTo(out(cv::Rect(0, 0, w, h)));
  cv::Mat ramp(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i) ramp.at<uint8_t>(0, i) = static_cast<uint8_t>(i);
  cv::Mat ramp_c;
  cv::applyColorMap(ramp, ramp_c, cv::COLORMAP_VIRIDIS);
  const int bar_w = out_w - 20;
  cv::Mat ramp_big;
  cv::resize(ramp_c, ramp_big, cv::Size(bar_w, 14), 0, 0, cv::INTER_NEAREST);
  ramp_big.copyTo(out(cv::Rect(10, h + 6, bar_w, 14)));
  auto label = [&](const std::string& s, int x) {
    cv::putText(out, s, cv::Point(x, h + 40), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  };
  std::ostringstream hi;
  hi.precision(3);
  hi << max_m * 1e6 << " um";
  label("0", 10);
  label("|Z error|", out_w / 2 - 30);
  label(hi.str(), out_w - 80);
  // OpenCV is BGR; the PNG writer takes planar RGB.
  ImageU8 im(out_w, h + bar_h, 3);
  for (int y = 0; y < out.rows; ++y)
    for (int x = 0; x < out.cols; ++x) {
      const cv::Vec3b px = out.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) im(x, y, c) = px[2 - c];
    }
  WritePng8(path, im);
}

}  // namespace mesoscan
