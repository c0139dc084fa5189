#include "heightfield/stage_lens_shift.h"

#include <sys/resource.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <utility>

#include "core/numbers.h"
#include "core/progress.h"
#include "core/robust_stats.h"
#include "core/stage_timer.h"

namespace mesoscan {
namespace {

// The steps' wall times under their names and the process CPU times (all threads) under
// name + "_cpu", if `out` is set (LensShiftStageOptions::step_timings).
class StepClock {
 public:
  explicit StepClock(StageTimings* out) : out_(out), cpu_(out ? ProcessCpuSeconds() : 0.0) {}
  void Stage(const char* name) {
    if (!out_) return;
    const double cpu = ProcessCpuSeconds();
    out_->emplace_back(name, wall_.Restart());
    out_->emplace_back(std::string(name) + "_cpu", cpu - cpu_);
    cpu_ = cpu;
  }

 private:
  StageTimings* out_;
  Stopwatch wall_;
  double cpu_;
};

}  // namespace

void QuadraticMap::Terms(size_t px, size_t py, double* t) const {
  const double sx = 2.0 / std::max(1, width), sy = 2.0 / std::max(1, height);
  const double x = (static_cast<double>(px) + 0.5) * sx - 1.0;
  const double y = (static_cast<double>(py) + 0.5) * sy - 1.0;
  t[0] = 1;
  t[1] = x;
  t[2] = y;
  t[3] = x * x;
  t[4] = x * y;
  t[5] = y * y;
}

void QuadraticMap::Row(int y, int x0, int n, float* out) const {
  // Terms and the sum over them in their order, v = 0 + 1 c0 + x c1 + y c2 + x^2 c3 + x y c4 +
  // y^2 c5, with what does not depend on x taken out of the loop (the same operations: the
  // same floats as evaluating Terms per pixel).
  const double sx = 2.0 / std::max(1, width), sy = 2.0 / std::max(1, height);
  const double yv = (static_cast<double>(static_cast<size_t>(y)) + 0.5) * sy - 1.0;
  const double v0 = 0.0 + 1.0 * c[0], yc2 = yv * c[2], yyc5 = (yv * yv) * c[5];
  for (int j = 0; j < n; ++j) {
    const double x = (static_cast<double>(static_cast<size_t>(x0 + j)) + 0.5) * sx - 1.0;
    double v = v0 + x * c[1];
    v += yc2;
    v += (x * x) * c[3];
    v += (x * yv) * c[4];
    v += yyc5;
    out[j] = static_cast<float>(v);
  }
}

float QuadraticMap::At(size_t i) const {
  float v;
  const size_t w = static_cast<size_t>(std::max(1, width));
  Row(static_cast<int>(i / w), static_cast<int>(i % w), 1, &v);
  return v;
}

std::vector<float> QuadraticMap::Evaluate() const {
  std::vector<float> out(static_cast<size_t>(width) * height);
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y) Row(y, 0, width, out.data() + static_cast<size_t>(y) * width);
  });
  return out;
}

std::vector<float> SmoothFrequencyMap(const std::vector<float>& f, int w, int h) {
  QuadraticMap map;
  if (!FitSmoothFrequencyMap(f, w, h, 1, w, h, &map)) return {};
  return map.Evaluate();
}

bool FitSmoothFrequencyMap(const std::vector<float>& f, int w, int h, int stride, int out_w,
                           int out_h, QuadraticMap* map) {
  if (stride <= 1) stride = 1, out_w = w, out_h = h;
  map->width = out_w;
  map->height = out_h;
  std::vector<size_t> idx;
  for (size_t i = 0; i < f.size(); ++i)
    if (std::isfinite(f[i])) idx.push_back(i);
  if (idx.size() < 50) return false;
  const size_t step = std::max<size_t>(1, idx.size() / 50000);
  std::vector<size_t> sample;
  for (size_t k = 0; k < idx.size(); k += step) sample.push_back(idx[k]);
  // The terms once per sample (6 doubles each); the normal equations' lower triangle in sample
  // order (the products and sums of A += t t^T there, which LDLT reads alone), the residuals on
  // the pool.
  const size_t ns = sample.size();
  std::vector<double> terms(ns * 6);
  tbb::parallel_for(tbb::blocked_range<int>(0, static_cast<int>(ns), 4096), [&](const auto& range) {
    const int k0 = range.begin(), k1 = range.end();
    for (int k = k0; k < k1; ++k)
      map->Terms(sample[k] % w * stride, sample[k] / w * stride, terms.data() + 6 * k);
  });
  std::vector<uint8_t> use(ns, 1);
  std::vector<double> r(ns);
  Eigen::Matrix<double, 6, 1> c = Eigen::Matrix<double, 6, 1>::Zero();
  for (int round = 0; round < 3; ++round) {
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    for (size_t k = 0; k < ns; ++k) {
      if (!use[k]) continue;
      const double* t = terms.data() + 6 * k;
      const double fk = static_cast<double>(f[sample[k]]);
      for (int q = 0; q < 6; ++q) {
        for (int p = q; p < 6; ++p) A(p, q) += t[p] * t[q];
        b(q) += t[q] * fk;
      }
    }
    c = A.ldlt().solve(b);
    if (!c.allFinite()) return false;
    tbb::parallel_for(
        tbb::blocked_range<int>(0, static_cast<int>(ns), 4096), [&](const auto& range) {
          const int k0 = range.begin(), k1 = range.end();
          for (int k = k0; k < k1; ++k) {
            const Eigen::Map<const Eigen::Matrix<double, 6, 1>> t(terms.data() + 6 * k);
            r[k] = std::abs(f[sample[k]] - t.dot(c));
          }
        });
    std::vector<double> sorted = r;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double mad = kMadToSigma * sorted[sorted.size() / 2];
    for (size_t k = 0; k < ns; ++k) use[k] = r[k] <= 4 * mad + 1e-12;
  }
  for (int q = 0; q < 6; ++q) map->c[q] = c(q);
  return true;
}

namespace {

constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();

// What every fitting pass reads: the lens-shift frames, their gains, the pixels' states (a pass
// marks its failures there) and the profile's sampling.
struct LensShiftData {
  const FrameStack& stack;
  const std::vector<int>& ls_stack;
  const std::vector<float>& inv_gain;  // refined by the frame corrections
  PixelStates& state;
  int w, h;
  int nls;   // lens-shift frames
  int nx;    // samples of a profile (fewer than nls with the box filter)
  bool box;  // 5-sample moving average
  double centre;
  size_t np;  // ROI pixels
};

// The output arrays of n entries, NaN; offset and frequency only if `all`.
void Allocate(LensShiftPixels& o, size_t n, bool all) {
  for (auto* v : {&o.phase0, &o.amplitude, &o.residual_rms, &o.samples}) v->assign(n, kNaNf);
  if (all)
    for (auto* v : {&o.frequency, &o.offset}) v->assign(n, kNaNf);
}

// The shifts of the profile's samples from the centre; with the box filter, the 5-sample moving
// average ("valid" part only, so no sample is shifted).
std::vector<double> ProfileShifts(const std::vector<double>& ls_shift_px, double centre, bool box) {
  const int nls = static_cast<int>(ls_shift_px.size());
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
  return x;
}

// Pixels of a fitting pass: every `stride`-th pixel of every `stride`-th row, or (complement)
// all the others.
struct PixelSubset {
  int stride = 1;
  bool complement = false;
  bool Row(int y) const { return complement || y % stride == 0; }
  bool Has(int x, int y) const { return (x % stride == 0 && y % stride == 0) != complement; }
};

// Where a pass stores: ROI pixel (x, y) at entry (y / stride) * width + x / stride of `px`
// (stride 1: the ROI grid; the frequency pass: its sparse subsample's own grid).
struct Target {
  LensShiftPixels* px;
  int stride, width;
  size_t At(size_t x, int y) const {
    return static_cast<size_t>(y / stride) * width + x / static_cast<size_t>(stride);
  }
};

// The outputs of pixel i (entry di of o) from its fit.
void StoreFit(const LensShiftData& d, LensShiftPixels& o, size_t di, size_t i,
              const LensShiftFit& fit) {
  if (!fit.valid) {
    d.state[i] = PixelState::kFitFailed;
    if (std::isfinite(fit.residual_rms) && fit.samples_used > 4) {  // noise estimate
      o.residual_rms[di] = static_cast<float>(fit.residual_rms);
      o.samples[di] = static_cast<float>(fit.samples_used);
    }
    return;
  }
  // Phase at shift 0 with the pixel's own frequency (the model holds at shift 0).
  o.phase0[di] = static_cast<float>(fit.phase - 2 * kPi * fit.frequency * d.centre);
  o.amplitude[di] = static_cast<float>(fit.amplitude);
  if (!o.frequency.empty()) o.frequency[di] = static_cast<float>(fit.frequency);
  if (!o.offset.empty()) o.offset[di] = static_cast<float>(fit.offset);
  o.residual_rms[di] = static_cast<float>(fit.residual_rms);
  o.samples[di] = static_cast<float>(fit.samples_used);
}

// One pass over the active pixels of `subset`; f_map (if given) is the per-pixel frequency
// held fixed. Rows without a pixel of the subset are not even gathered.
void FitPass(const LensShiftData& d, const LensShiftBatchFitter& fitter,
             const std::vector<float>* f_map, const PixelSubset& subset, const char* label,
             const Target& to) {
  const FrameStack& stack = d.stack;
  const std::vector<int>& ls_stack = d.ls_stack;
  const std::vector<float>& inv_gain = d.inv_gain;
  const PixelStates& state = d.state;
  const int w = d.w, h = d.h, nls = d.nls, nx = d.nx;
  const bool box = d.box;
  Progress progress(label, h);
  // Without the box filter and a fixed frequency, the row's pixels of the subset are fitted
  // together (FitMany: four profiles per vector, Fit's results to rounding).
  const bool many = !box && !f_map;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    const size_t n = static_cast<size_t>(w);
    // (Sized where first needed: the sparse pass with FitMany reads no full rows, and these
    // were ~80 MB of zero fills over the pass's tasks.)
    std::vector<float> buf, prof(static_cast<size_t>(nx)), packed;
    if (!many) buf.resize(static_cast<size_t>(nls) * n);
    std::vector<uint32_t> cols;
    std::vector<LensShiftFit> fits;
    for (int y = y0; y < y1; ++y) {
      if (!subset.Row(y)) continue;
      const size_t i0 = static_cast<size_t>(y) * w;
      if (many) {
        // The subset's active pixels of the row, their profiles packed frame-major
        // (packed[k * m + p]: profile p's sample k).
        cols.clear();
        for (size_t j = 0; j < n; ++j)
          if (state[i0 + j] == PixelState::kActive && subset.Has(static_cast<int>(j), y))
            cols.push_back(static_cast<uint32_t>(j));
        const size_t m = cols.size();
        if (m == 0) continue;
        const size_t need = static_cast<size_t>(nls) * m;
        if (packed.size() < need) packed.resize(need);
        if (subset.stride > 1 && !subset.complement) {
          for (int k = 0; k < nls; ++k) {
            const float g = inv_gain[ls_stack[k]];
            float* dst = packed.data() + k * m;
            for (size_t p = 0; p < m; ++p) dst[p] = stack.Value(ls_stack[k], i0 + cols[p]) * g;
          }
        } else {
          if (buf.empty()) buf.resize(static_cast<size_t>(nls) * n);
          for (int k = 0; k < nls; ++k) {
            stack.Gather(ls_stack[k], i0, n, buf.data() + k * n);
            const float g = inv_gain[ls_stack[k]];
            const float* from = buf.data() + k * n;
            float* dst = packed.data() + k * m;
            for (size_t p = 0; p < m; ++p) dst[p] = from[cols[p]] * g;
          }
        }
        fits.resize(m);
        fitter.FitMany(packed.data(), 1, static_cast<int>(m), static_cast<int>(m), fits.data());
        for (size_t p = 0; p < m; ++p) {
          const size_t j = cols[p];
          StoreFit(d, *to.px, to.stride == 1 ? i0 + j : to.At(j, y), i0 + j, fits[p]);
        }
        continue;
      }
      if (subset.stride > 1 && !subset.complement) {
        // A sparse subset (the frequency pass: 1 pixel in stride^2): only its samples.
        for (int k = 0; k < nls; ++k) {
          const float g = inv_gain[ls_stack[k]];
          for (size_t j = 0; j < n; j += subset.stride)
            buf[k * n + j] = stack.Value(ls_stack[k], i0 + j) * g;
        }
      } else {
        for (int k = 0; k < nls; ++k) {
          stack.Gather(ls_stack[k], i0, n, buf.data() + k * n);
          const float g = inv_gain[ls_stack[k]];
          for (size_t j = 0; j < n; ++j) buf[k * n + j] *= g;
        }
      }
      for (size_t j = 0; j < n; ++j) {
        const size_t i = i0 + j;
        if (state[i] != PixelState::kActive || !subset.Has(static_cast<int>(j), y)) continue;
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
        StoreFit(d, *to.px, to.stride == 1 ? i : to.At(j, y), i,
                 f_map ? fitter.Fit(b, stride, (*f_map)[i]) : fitter.Fit(b, stride));
      }
    }
    progress.Advance(y1 - y0);
  });
}

// The fixed-frequency pass of every active pixel with the row kernel (LensShiftRowFitter):
// tiles of a row gathered frame-major, the gains applied inside the kernel.
void FitPassRows(const LensShiftData& d, const LensShiftRowFitter& fitter,
                 const QuadraticMap& f_map, LensShiftPixels* out) {
  const int w = d.w, h = d.h, nls = d.nls;
  std::vector<float> gain(static_cast<size_t>(nls));
  for (int k = 0; k < nls; ++k) gain[k] = d.inv_gain[d.ls_stack[k]];
  Progress progress("fit lens shift", h);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    constexpr int kTile = 512;
    std::vector<float> buf(static_cast<size_t>(nls) * kTile);
    std::vector<uint8_t> use(kTile);
    std::vector<LensShiftFit> fits(kTile);
    std::vector<float> f(kTile);  // the map's frequencies of the tile
    for (int y = y0; y < y1; ++y) {
      for (int x0 = 0; x0 < w; x0 += kTile) {
        const int cnt = std::min(kTile, w - x0);
        const size_t i0 = static_cast<size_t>(y) * w + x0;
        bool any = false;
        for (int j = 0; j < cnt; ++j) {
          use[j] = d.state[i0 + j] == PixelState::kActive;
          any = any || use[j];
        }
        if (!any) continue;
        const size_t stride = static_cast<size_t>(cnt);
        for (int k = 0; k < nls; ++k)
          d.stack.Gather(d.ls_stack[k], i0, stride, buf.data() + k * stride);
        f_map.Row(y, x0, cnt, f.data());
        fitter.FitRow(buf.data(), stride, cnt, gain.data(), f.data(), use.data(), fits.data());
        for (int j = 0; j < cnt; ++j)
          if (use[j]) StoreFit(d, *out, i0 + j, i0 + j, fits[j]);
      }
    }
    progress.Advance(y1 - y0);
  });
}

// The stride of the frequency pass's regular subsample: the quadratic is fitted to ~50000
// frequencies (SmoothFrequencyMap), so the 4-parameter fit runs on about twice that many pixels
// only (all pixels of crops below that).
int FrequencySubsampleStride(const PixelStates& state, size_t np) {
  constexpr size_t kFrequencySamples = 100000;
  size_t n_active = 0;
  for (size_t i = 0; i < np; ++i) n_active += state[i] == PixelState::kActive;
  return std::max(1, static_cast<int>(std::sqrt(n_active / kFrequencySamples)));
}

// The subsample's fits (on its grid of width cw) with a frequency, as the frame corrections
// take them.
FirstPassFits FirstPassFitsOf(const LensShiftPixels& first, int w, int h, int sub, int cw) {
  FirstPassFits fits;
  for (int y = 0; y < h; y += sub)
    for (int x = 0; x < w; x += sub) {
      const size_t q = static_cast<size_t>(y / sub) * cw + x / sub;
      if (!std::isfinite(first.frequency[q])) continue;
      fits.pixels.push_back(static_cast<uint32_t>(static_cast<size_t>(y) * w + x));
      fits.amplitude.push_back(first.amplitude[q]);
      fits.phase.push_back(first.phase0[q]);
      fits.offset.push_back(first.offset[q]);
    }
  return fits;
}

// Joint frame gains and shifter positions from the frequency pass's fits: refines *x and
// gains->inv_gain, mirrors the gains into gains->session_gain; returns the report's entry.
Json CorrectFrames(const LensShiftData& d, const ReconstructPlan& plan,
                   const LensShiftStageOptions& options, const LensShiftPixels& first, int sub,
                   int cw, const QuadraticMap& f_map, std::vector<double>* x, FrameGains* gains) {
  FrameCorrectionOptions fco;
  fco.method = options.frame_gain_method;
  fco.estimate_positions = options.correct_positions;
  const FrameCorrections fc = CorrectLensShiftFrames(
      d.stack, d.ls_stack, FirstPassFitsOf(first, d.w, d.h, sub, cw),
      [&](uint32_t i) { return f_map.At(i); }, x, &gains->inv_gain, fco, &gains->phase_reference);
  for (int k = 0; k < d.nls; ++k) {
    const size_t f = static_cast<size_t>(plan.frames[d.ls_stack[k]]);
    if (f < gains->session_gain.size())
      gains->session_gain[f] = 1.0 / gains->inv_gain[d.ls_stack[k]];
  }
  return fc.ToJson();
}

// The full grid's arrays with the subsample's fits in place (the fixed-frequency pass overwrites
// them, except where it fails); offset and frequency only if `all`. *first is released. One
// array per task (each is 12.5 MB at 3 Mpx, filled right after the last frame: in turn they were
// tens of ms of page faults and fills on one core).
void SpreadToFullGrid(LensShiftPixels* first, int w, int h, size_t np, int sub, int cw, bool all,
                      LensShiftPixels* out) {
  std::vector<std::pair<std::vector<float>*, std::vector<float>*>> arrays = {
      {&first->phase0, &out->phase0},
      {&first->amplitude, &out->amplitude},
      {&first->residual_rms, &out->residual_rms},
      {&first->samples, &out->samples}};
  if (all) {
    arrays.emplace_back(&first->frequency, &out->frequency);
    arrays.emplace_back(&first->offset, &out->offset);
  }
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>(arrays.size()), [&](int64_t a) {
    const std::vector<float>& from = *arrays[a].first;
    std::vector<float>& to = *arrays[a].second;
    to.assign(np, kNaNf);
    for (int y = 0; y < h; y += sub)
      for (int x = 0; x < w; x += sub)
        to[static_cast<size_t>(y) * w + x] = from[static_cast<size_t>(y / sub) * cw + x / sub];
  });
  *first = LensShiftPixels();
}

// The shifter's gain varies smoothly over the image: a robust quadratic of the frequencies
// fitted on a subsample, then the phase of every pixel with f held there (3 parameters: lower
// variance). Between the two, the frame corrections (without the box filter).
void FitWithSmoothFrequency(const LensShiftData& d, const ReconstructPlan& plan,
                            const LensShiftStageOptions& options, const LensShiftFitOptions& fo,
                            const LensShiftBatchFitter& fitter, std::vector<double>* x,
                            FrameGains* gains, StepClock* step, LensShiftPixels* out) {
  const int w = d.w, h = d.h;
  PixelSubset subset;
  subset.stride = FrequencySubsampleStride(d.state, d.np);
  // The 4-parameter fits of the subsample on its own grid (cw x ch): the full-size arrays
  // are made only for the fixed-frequency pass, after the frame corrections (they
  // are 75 MB at 3 Mpx, and the frame corrections are the stage's peak).
  const int sub = subset.stride, cw = (w + sub - 1) / sub, ch = (h + sub - 1) / sub;
  LensShiftPixels first;
  Allocate(first, static_cast<size_t>(cw) * ch, true);
  FitPass(d, fitter, nullptr, subset, "fit lens shift frequency", {&first, sub, cw});
  step->Stage("frequency_fit");
  // Evaluated per row tile where it is used (12.5 MB less at 3 Mpx in the fixed pass).
  QuadraticMap f_map;
  const bool have_map = FitSmoothFrequencyMap(first.frequency, cw, ch, sub, w, h, &f_map);
  step->Stage("frequency_map");
  if (!have_map) {
    SpreadToFullGrid(&first, w, h, d.np, sub, cw, true, out);
    if (subset.stride > 1) {
      // No frequency map: the 4-parameter fit everywhere else too.
      subset.complement = true;
      FitPass(d, fitter, nullptr, subset, "fit lens shift", {out, 1, w});
    }
    return;
  }
  LensShiftFitOptions fo2 = fo;
  fo2.fit_frequency = false;
  if (!d.box) {
    out->frame_corrections = CorrectFrames(d, plan, options, first, sub, cw, f_map, x, gains);
    step->Stage("frame_corrections");
  }
  SpreadToFullGrid(&first, w, h, d.np, sub, cw, options.keep_offset_frequency, out);
  if (options.row_kernel && !d.box && fo2.fitter == LensShiftFitter::kFast) {
    FitPassRows(d, LensShiftRowFitter(*x, 0.5, fo2), f_map, out);
  } else {
    const std::vector<float> f_all = f_map.Evaluate();
    FitPass(d, LensShiftBatchFitter(*x, 0.5, fo2), &f_all, PixelSubset(), "fit lens shift",
            {out, 1, w});
  }
  step->Stage("fixed_frequency_fit");
}

int64_t PixelsFitted(const PixelStates& state, size_t np) {
  int64_t n = 0;
  for (size_t i = 0; i < np; ++i)
    n += state[i] == PixelState::kActive || state[i] == PixelState::kFitFailed;
  return n;
}

}  // namespace

LensShiftPixels FitLensShift(const FrameStack& stack, const ReconstructPlan& plan,
                             FrameGains* gains, const LensShiftStageOptions& options,
                             PixelStates* state_out) {
  LensShiftPixels out;
  if (!plan.use_lens_shift()) return out;
  out.fit_parameters = options.fit_frequency && !options.smooth_frequency ? 4 : 3;
  StepClock step(options.step_timings);
  const RoiGrid grid = RoiGrid::Of(stack);
  const int nls = static_cast<int>(plan.ls_stack.size());
  const double centre = plan.LensShiftCentre();
  const bool box = options.box_filter && nls >= 9;
  std::vector<double> x = ProfileShifts(plan.ls_shift_px, centre, box);
  const LensShiftData d{stack,
                        plan.ls_stack,
                        gains->inv_gain,
                        *state_out,
                        grid.width,
                        grid.height,
                        nls,
                        static_cast<int>(x.size()),
                        box,
                        centre,
                        grid.pixels()};
  LensShiftFitOptions fo;
  fo.fitter = options.fitter;
  fo.fit_frequency = options.fit_frequency;
  const LensShiftBatchFitter fitter(x, 0.5, fo);
  if (options.fit_frequency && options.smooth_frequency) {
    FitWithSmoothFrequency(d, plan, options, fo, fitter, &x, gains, &step, &out);
  } else {
    Allocate(out, grid.pixels(), true);
    FitPass(d, fitter, nullptr, PixelSubset(), "fit lens shift", {&out, 1, grid.width});
  }
  out.pixels_fitted += PixelsFitted(*state_out, grid.pixels());
  return out;
}

namespace {

double Wrap2Pi(double a) {
  // fmod is exact: within one period either way it returns a itself (the libm call is skipped).
  if (std::abs(a) < 2 * kPi) return a < 0 ? a + 2 * kPi : a;
  a = std::fmod(a, 2 * kPi);
  return a < 0 ? a + 2 * kPi : a;
}

}  // namespace

LensShiftCodec::LensShiftCodec(const ReconstructPlan& plan, const LensShiftPixels& ls,
                               double confidence_t)
    : plan_(plan), ls_(ls), confidence_t_(confidence_t) {}

void LensShiftCodec::SampleNoise(const size_t* pixels, size_t n, double* sigma) const {
  for (size_t a = 0; a < n; ++a) {
    const size_t i = pixels[a];
    if (sigma[a] < 0 && ls_.samples[i] > 4)
      sigma[a] =
          ls_.residual_rms[i] * std::sqrt(ls_.samples[i] / (ls_.samples[i] - ls_.fit_parameters));
  }
}

void LensShiftCodec::Decode(const size_t* pixels, size_t n, const double* noise,
                            CodecRecord* out) const {
  out->Resize(n);
  for (size_t a = 0; a < n; ++a) {
    const size_t i = pixels[a];
    out->valid[a] = std::isfinite(ls_.phase0[i]);
    if (!out->valid[a]) continue;
    const double sigma = noise[a];
    out->sigma_px[a] =
        std::sqrt(2.0 * sigma * sigma / (ls_.samples[i] * ls_.amplitude[i] * ls_.amplitude[i])) /
        kPi;
    // Eq. 2's fine phase in cycles: u_fine = 1/2 - phase0 / pi (mod 2).
    out->value[a] = Wrap2Pi(kPi / 2 - ls_.phase0[i]) / (2 * kPi);
    const double e = std::pow(ls_.residual_rms[i] / ls_.amplitude[i], 2);  // Eq. 4's E
    out->confidence[a] = 1.0 - std::sqrt(e * confidence_t_);
  }
}

bool LensShiftCodec::OffsetUnknown() const {
  const Json& fc = ls_.frame_corrections;
  if (!fc.is_object() || !fc.contains("model") || !fc["model"].is_string()) return false;
  if (fc.contains("valid") && fc["valid"].is_boolean() && !fc["valid"].get<bool>()) return false;
  return fc["model"].get<std::string>().find("positions") != std::string::npos;
}

}  // namespace mesoscan
