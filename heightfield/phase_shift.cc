#include "heightfield/phase_shift.h"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <numeric>

#include "core/error.h"
#include "core/fast_atan.h"
#include "core/simd_clones.h"

namespace mesoscan {
namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;
// Longest residual cycle (in fringe orders of the anchor period) kept as a per-pixel table.
constexpr int kMaxCycle = 64;

// Signed distance of t to the nearest integer, in [-0.5, 0.5].
// Round to nearest, ties to even: the same as std::nearbyint in the default rounding mode for
// |t| < 2^51, without its library call (x86-64 has no inline rounding before SSE4.1).
inline double RoundNearest(double t) {
  constexpr double kMagic = 6755399441055744.0;  // 1.5 * 2^52
  return std::abs(t) < 2251799813685248.0 ? (t + kMagic) - kMagic : std::nearbyint(t);
}

inline double WrapCycles(double t) { return t - RoundNearest(t); }

// WrapCycles for |t| < 2^51 (branch-free, vectorisable).
inline double WrapCyclesSmall(double t) {
  constexpr double kMagic = 6755399441055744.0;  // 1.5 * 2^52
  return t - ((t + kMagic) - kMagic);
}

// Indices of the kK smallest of v[0..n) by (value, index), in that order; n >= kK.
template <int kK>
std::array<int, kK> Smallest(const double* v, int n) {
  std::array<int, kK> idx;
  for (int j = 0; j < kK; ++j) {  // insertion sort of the first kK
    int p = j;
    while (p > 0 && v[j] < v[idx[p - 1]]) {
      idx[p] = idx[p - 1];
      --p;
    }
    idx[p] = j;
  }
  double last = v[idx[kK - 1]];
  for (int j = kK; j < n; ++j) {
    if (!(v[j] < last)) continue;  // a later index ranks first only if strictly smaller
    int p = kK - 1;
    while (p > 0 && v[j] < v[idx[p - 1]]) {
      idx[p] = idx[p - 1];
      --p;
    }
    idx[p] = j;
    last = v[idx[kK - 1]];
  }
  return idx;
}

// Smallest<4> without its branches (which mispredict on noisy residuals: ~80% of its time):
// four sorted slots in one vector of GCC's vector extensions (one AVX2 register in Unwrap's AVX2
// clone, two SSE2 halves otherwise); each value goes to the first slot it is smaller than, the
// slots after it shift up; slots not yet filled take any value. The same indices as Smallest<4>
// for values without NaN (a later index ranks after an equal value: strict <), which is checked
// (with a NaN, Smallest<4> decides).
// (GCC's __builtin_shuffle and vector conditionals; other compilers use Smallest<4>.)
#if defined(__GNUC__) && !defined(__clang__)
typedef double V4d __attribute__((vector_size(32)));
typedef long long V4l __attribute__((vector_size(32)));
// One value v[j] into the four sorted slots (s, id).
__attribute__((always_inline)) inline void SmallestFourInsert(double v, int j, V4d* s_io,
                                                              V4l* id_io) {
  const V4l lane = {0, 1, 2, 3};
  const V4l shift = {0, 0, 1, 2};
  const V4l not_first = {0, -1, -1, -1};
  const V4d s = *s_io;
  const V4l id = *id_io;
  const V4d x = {v, v, v, v};
  const V4l jv = {j, j, j, j};
  const V4l m = (x < s) | (lane >= jv);  // slots x goes before (or that are still empty)
  const V4l m_prev = __builtin_shuffle(m, shift) & not_first;
  const V4d s_prev = __builtin_shuffle(s, shift);
  const V4l id_prev = __builtin_shuffle(id, shift);
  *s_io = m_prev ? s_prev : (m ? x : s);
  *id_io = m_prev ? id_prev : (m ? jv : id);
}

inline std::array<int, 4> FourIndices(const V4l& id) {
  return {static_cast<int>(id[0]), static_cast<int>(id[1]), static_cast<int>(id[2]),
          static_cast<int>(id[3])};
}

__attribute__((always_inline)) inline std::array<int, 4> SmallestFour(const double* v, int n) {
  bool nan = false;
  for (int j = 0; j < n; ++j) nan |= std::isnan(v[j]);
  if (nan || n < 4) return Smallest<4>(v, n);
  V4d s = {0, 0, 0, 0};
  V4l id = {0, 0, 0, 0};
  for (int j = 0; j < n; ++j) SmallestFourInsert(v[j], j, &s, &id);
  return FourIndices(id);
}

// SmallestFour of two arrays at once: each insertion depends on the one before, so the two
// chains interleaved keep the vector units busy (the same indices as two calls).
__attribute__((always_inline)) inline void SmallestFourPair(const double* a, int na,
                                                            const double* b, int nb,
                                                            std::array<int, 4>* sa,
                                                            std::array<int, 4>* sb) {
  bool nan = false;
  for (int j = 0; j < na; ++j) nan |= std::isnan(a[j]);
  for (int j = 0; j < nb; ++j) nan |= std::isnan(b[j]);
  if (nan || na < 4 || nb < 4) {
    *sa = SmallestFour(a, na);
    *sb = SmallestFour(b, nb);
    return;
  }
  V4d s_a = {0, 0, 0, 0}, s_b = {0, 0, 0, 0};
  V4l id_a = {0, 0, 0, 0}, id_b = {0, 0, 0, 0};
  int j = 0;
  for (; j < na && j < nb; ++j) {
    SmallestFourInsert(a[j], j, &s_a, &id_a);
    SmallestFourInsert(b[j], j, &s_b, &id_b);
  }
  for (int k = j; k < na; ++k) SmallestFourInsert(a[k], k, &s_a, &id_a);
  for (int k = j; k < nb; ++k) SmallestFourInsert(b[k], k, &s_b, &id_b);
  *sa = FourIndices(id_a);
  *sb = FourIndices(id_b);
}
#else
inline std::array<int, 4> SmallestFour(const double* v, int n) { return Smallest<4>(v, n); }
inline void SmallestFourPair(const double* a, int na, const double* b, int nb,
                             std::array<int, 4>* sa, std::array<int, 4>* sb) {
  *sa = Smallest<4>(a, na);
  *sb = Smallest<4>(b, nb);
}
#endif

}  // namespace

// ---------------------------------------------------------------------------------------------
// WrappedPhaseSolver

WrappedPhaseSolver::WrappedPhaseSolver(std::vector<double> deltas) : deltas_(std::move(deltas)) {
  const int k = static_cast<int>(deltas_.size());
  if (k < 3)
    MESOSCAN_BAD_INPUT("phase shifting: " << k << " phase offsets given, at least 3 are needed");
  for (double d : deltas_)
    if (!std::isfinite(d)) MESOSCAN_BAD_INPUT("phase shifting: a phase offset is not finite");
  // Design matrix of I_k = A + (B cos theta) cos delta_k + (B sin theta) (-sin delta_k).
  Eigen::MatrixXd m(k, 3);
  for (int i = 0; i < k; ++i) m.row(i) << 1.0, std::cos(deltas_[i]), -std::sin(deltas_[i]);
  const Eigen::Matrix3d mtm = m.transpose() * m;
  // Fewer than 3 distinct offsets mod 2 pi make M^T M singular; the smallest eigenvalue of a
  // well-posed set is O(K) (equal steps: K/2), so a relative threshold tells them apart.
  const double min_eig = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(mtm).eigenvalues()(0);
  if (!(min_eig > 1e-6 * k))
    MESOSCAN_BAD_INPUT("phase shifting: the " << k
                                              << " phase offsets do not determine the phase (fewer "
                                                 "than 3 distinct values modulo 2 pi)");
  const Eigen::Matrix3d inv = mtm.inverse();
  const Eigen::MatrixXd pinv = inv * m.transpose();  // 3 x K
  for (double d : deltas_) {
    cos_.push_back(std::cos(d));
    sin_.push_back(std::sin(d));
  }
  pinv_.resize(3 * k);
  for (int r = 0; r < 3; ++r)
    for (int i = 0; i < k; ++i) pinv_[r * k + i] = pinv(r, i);
  cov_cc_ = inv(1, 1);
  cov_ss_ = inv(2, 2);
  cov_cs_ = inv(1, 2);
}

namespace {

// Solve's result from its sums: A = a, (B cos theta, B sin theta) = (c, s), the sum of squared
// residuals ssr and fast = FastAtan2(s, c) (one code for Solve and SolveMany's lanes).
WrappedPhaseSolver::Result FinishSolve(double a, double c, double s, double ssr, double fast,
                                       int k) {
  WrappedPhaseSolver::Result result;
  // theta is stored as a float: FastAtan2 (~2 ulp) gives the float std::atan2 (correctly
  // rounded) would, unless theta lies within 1e-13 rad of a float rounding boundary or of 0
  // (where the sign picks the branch); there std::atan2 decides. Same floats, 3-4x faster.
  auto to_0_2pi = [](double theta) {
    if (theta < 0.0) theta += kTwoPi;
    return theta;
  };
  double theta = to_0_2pi(fast);
  if (!(std::abs(fast) > 1e-13) ||
      static_cast<float>(theta - 1e-13) != static_cast<float>(theta + 1e-13))
    theta = to_0_2pi(std::atan2(s, c));
  float theta_f = static_cast<float>(theta);
  if (theta_f >= static_cast<float>(kTwoPi)) theta_f = 0.0f;  // float rounding of 2 pi - tiny
  result.theta = theta_f;
  // sqrt instead of std::hypot (a library call): c and s are frame values, far from overflow.
  result.modulation = static_cast<float>(std::sqrt(c * c + s * s));
  result.offset = static_cast<float>(a);
  result.residual_rms = static_cast<float>(std::sqrt(ssr / k));
  result.valid = true;
  return result;
}

}  // namespace

WrappedPhaseSolver::Result WrappedPhaseSolver::Solve(const float* samples, int stride) const {
  const int k = num_samples();
  double a = 0.0, c = 0.0, s = 0.0;
  for (int i = 0; i < k; ++i) {
    const double v = samples[static_cast<std::ptrdiff_t>(i) * stride];
    if (!std::isfinite(v)) return Result();  // valid == false, all fields 0
    a += pinv_[i] * v;
    c += pinv_[k + i] * v;
    s += pinv_[2 * k + i] * v;
  }
  double ssr = 0.0;
  for (int i = 0; i < k; ++i) {
    const double v = samples[static_cast<std::ptrdiff_t>(i) * stride];
    const double r = v - (a + c * cos_[i] - s * sin_[i]);
    ssr += r * r;
  }
  return FinishSolve(a, c, s, ssr, FastAtan2(s, c), k);
}

namespace {

// SolveMany's pixels per call of its vector kernel.
constexpr int kSolveChunk = 64;

// The sums of Solve (a, c, s, ssr) and FastAtan2(s, c) of n pixels (a multiple of 4, at most
// kSolveChunk), four per vector, each lane with Solve's operations in Solve's order; out[q * n
// + j] for q = a, c, s, ssr, fast. ssr is NaN where a sample is not finite (Solve then decides).
#if defined(__GNUC__) && !defined(__clang__)
typedef float V4f __attribute__((vector_size(16)));
// Four floats as doubles, element by element: one vcvtps2pd in the AVX2 clone, where GCC lowers
// __builtin_convertvector to two halves through the stack (as lens_shift_fit.cc's Widen).
// (Through a pointer: a function returning a 32-byte vector has another ABI with AVX.)
inline void Widen(V4f v, V4d* out) { *out = V4d{v[0], v[1], v[2], v[3]}; }
MESOSCAN_SIMD_CLONES
void SolveLanes(const double* pinv, const double* cosd, const double* sind, int k,
                const float* samples, size_t stride, int n, double* out) {
  const V4d zero = {0.0, 0.0, 0.0, 0.0};
  const V4l sign = {INT64_MIN, INT64_MIN, INT64_MIN, INT64_MIN};
  for (int j = 0; j < n; j += 4) {
    V4d a = zero, c = zero, s = zero, finite = zero;
    for (int i = 0; i < k; ++i) {
      V4f vf;
      std::memcpy(&vf, samples + static_cast<size_t>(i) * stride + j, sizeof vf);
      V4d v;
      Widen(vf, &v);
      finite += v - v;  // NaN where a sample is NaN or infinite
      a += pinv[i] * v;
      c += pinv[k + i] * v;
      s += pinv[2 * k + i] * v;
    }
    V4d ssr = zero;
    for (int i = 0; i < k; ++i) {
      V4f vf;
      std::memcpy(&vf, samples + static_cast<size_t>(i) * stride + j, sizeof vf);
      V4d v;
      Widen(vf, &v);
      const V4d r = v - (a + c * cosd[i] - s * sind[i]);
      ssr += r * r;
    }
    ssr += finite;
    // FastAtan2(s, c), step by step (fast_atan.h); |.| by the sign bit as std::abs.
    const V4d ay = reinterpret_cast<V4d>(reinterpret_cast<V4l>(s) & ~sign);
    const V4d ax = reinterpret_cast<V4d>(reinterpret_cast<V4l>(c) & ~sign);
    const V4d hi = ay < ax ? ax : ay;  // std::max(ay, ax)
    const V4d lo = ax < ay ? ax : ay;  // std::min(ay, ax)
    const V4d t = hi > 0.0 ? lo / hi : zero;
    V4d at;
    AtanOfRatio(t, ay, ax, &at);
    at = c < 0.0 ? kPi - at : at;
    at = s < 0.0 ? -at : at;
    std::memcpy(out + j, &a, sizeof a);
    std::memcpy(out + n + j, &c, sizeof c);
    std::memcpy(out + 2 * n + j, &s, sizeof s);
    std::memcpy(out + 3 * n + j, &ssr, sizeof ssr);
    std::memcpy(out + 4 * n + j, &at, sizeof at);
  }
}
#endif

}  // namespace

void WrappedPhaseSolver::SolveMany(const float* samples, size_t stride, int n, Result* out) const {
  const int k = num_samples();
  int j0 = 0;
#if defined(__GNUC__) && !defined(__clang__)
  double sums[5 * kSolveChunk];
  for (; j0 + 4 <= n; j0 += kSolveChunk) {
    const int m = std::min(kSolveChunk, (n - j0) / 4 * 4);
    SolveLanes(pinv_.data(), cos_.data(), sin_.data(), k, samples + j0, stride, m, sums);
    for (int j = 0; j < m; ++j) {
      const double a = sums[j], c = sums[m + j], s = sums[2 * m + j], ssr = sums[3 * m + j];
      out[j0 + j] = std::isfinite(ssr) && std::isfinite(c) && std::isfinite(s)
                        ? FinishSolve(a, c, s, ssr, sums[4 * m + j], k)
                        : Solve(samples + j0 + j, static_cast<int>(stride));
    }
    if (m < kSolveChunk) {
      j0 += m;
      break;
    }
  }
#endif
  for (; j0 < n; ++j0) out[j0] = Solve(samples + j0, static_cast<int>(stride));
}

double WrappedPhaseSolver::ThetaVarianceAt(double sigma, double modulation, double theta) const {
  // theta = atan2(S, C) with (C, S) = B (cos theta, sin theta) and Cov(C, S) = sigma^2 (M^T M)^-1:
  // var(theta) = g^T Cov g with g = (-sin theta, cos theta) / B (first-order propagation).
  const double sn = std::sin(theta), cs = std::cos(theta);
  const double q = sn * sn * cov_cc_ - 2.0 * sn * cs * cov_cs_ + cs * cs * cov_ss_;
  return sigma * sigma * q / (modulation * modulation);
}

// ---------------------------------------------------------------------------------------------
// TemporalUnwrapper

TemporalUnwrapper::TemporalUnwrapper(std::vector<double> periods, double range_px,
                                     double max_residual)
    : periods_(std::move(periods)), range_px_(range_px), max_residual_(max_residual) {
  if (periods_.empty()) MESOSCAN_BAD_INPUT("unwrapping: no phase-shift period given");
  for (double p : periods_)
    if (!(std::isfinite(p) && p > 0.0))
      MESOSCAN_BAD_INPUT("unwrapping: period " << p << " px is not a positive number");
  if (!(std::isfinite(range_px_) && range_px_ > 0.0))
    MESOSCAN_BAD_INPUT("unwrapping: projector width " << range_px_ << " px is not positive");
  if (!(max_residual_ > 0.0))
    MESOSCAN_BAD_INPUT("unwrapping: max_residual " << max_residual_ << " must be > 0");
  order_.resize(periods_.size());
  for (size_t i = 0; i < order_.size(); ++i) order_[i] = static_cast<int>(i);
  std::stable_sort(order_.begin(), order_.end(),
                   [&](int i, int j) { return periods_[i] > periods_[j]; });
  anchor_ = order_[0];
  inv_periods_.resize(periods_.size());
  phase_rate_.resize(periods_.size());
  for (size_t i = 0; i < periods_.size(); ++i) {
    inv_periods_[i] = 1.0 / periods_[i];
    phase_rate_[i] = kTwoPi / periods_[i];
  }
  // Residual tables (Unwrap): the residual of period i at the anchor's fringe order k is
  // wrap(k pa / p_i + c_i), which repeats every q orders if pa / p_i = p / q. The q * pa / p_i
  // that should be an integer may be off by rounding only (the error, added up over the
  // candidates, stays < 1e-12 cycles).
  {
    const double pa = periods_[anchor_];
    const double candidates = range_px_ / pa + 2.0;
    cycle_.assign(periods_.size(), 0);
    int64_t lcm = 1;
    for (size_t i = 0; i < periods_.size(); ++i) {
      if (static_cast<int>(i) == anchor_) continue;
      const double ratio = pa / periods_[i];
      for (int q = 1; q <= kMaxCycle && q < candidates; ++q) {
        if (std::abs(WrapCycles(q * ratio)) * (candidates / q) <= 1e-12) {
          cycle_[i] = q;
          lcm = std::min<int64_t>(std::lcm(lcm, q), 1 << 20);
          break;
        }
      }
      if (cycle_[i] == 0) lcm = 0;
    }
    table_candidates_ = periods_.size() > 1 ? static_cast<int>(lcm) : 0;
    if (periods_.size() == 3 && lcm > 0) {
      for (int i = 0; i < 3; ++i)
        if (i != anchor_) pair_.push_back(i);
      const int qa = cycle_[pair_[0]], qb = cycle_[pair_[1]];
      crt_.assign(static_cast<size_t>(qa) * qb, std::numeric_limits<int>::max());  // no such r
      for (int r = static_cast<int>(lcm) - 1; r >= 0; --r) crt_[(r % qa) * qb + r % qb] = r;
    }
  }

  // Separation: min over column distances D in [p_min / 2, R - 1] of the max over periods of the
  // circular distance of D / p in cycles. The max is piecewise linear in D with slopes <= 1 /
  // p_min, so sampling D every 0.002 p_min finds the minimum within 0.001 cycles.
  const double p_min = *std::min_element(periods_.begin(), periods_.end());
  const double step = 0.002 * p_min;
  const double d_end = range_px_ - 1.0;
  separation_cycles_ = 0.5;
  // The first column distance whose code separation falls below the minimum (or none).
  double d_bad = std::numeric_limits<double>::infinity();
  double separation_below_bad = 0.5;  // min separation over distances < d_bad
  if (d_end > 0.5 * p_min) {
    const double n_steps = std::ceil((d_end - 0.5 * p_min) / step);
    if (n_steps > 5e7)
      MESOSCAN_BAD_INPUT("unwrapping: projector width " << range_px_ << " px is too large for the "
                                                        << "finest period " << p_min << " px");
    for (int64_t i = 0; i <= static_cast<int64_t>(n_steps); ++i) {
      const double d = std::min(0.5 * p_min + static_cast<double>(i) * step, d_end);
      double worst = 0.0;
      for (double p : periods_) worst = std::max(worst, std::abs(WrapCycles(d / p)));
      separation_cycles_ = std::min(separation_cycles_, worst);
      if (worst < kMinSeparationCycles && !std::isfinite(d_bad)) d_bad = d;
      if (!std::isfinite(d_bad)) separation_below_bad = std::min(separation_below_bad, worst);
    }
  }
  // Small separation only at distances close to the width (a cue period equal to the width, or
  // a period set that almost repeats at the width): only pairs of columns within
  // edge_margin_px_ of opposite edges can be confused (any column farther in is at most
  // R - 1 - E from every other column), so those columns are marked invalid by Unwrap() instead
  // of refusing the set. Allowed if the band is at most kMaxEdgeFraction of the width.
  if (separation_cycles_ < kMinSeparationCycles) {
    // Columns live in [-0.5, R - 0.5): an interior column is at most R - E from any other one,
    // which must stay below d_bad (one pixel of slack for the sampling and the noise).
    const double margin = std::ceil(range_px_ - d_bad) + 1.0;
    if (std::isfinite(d_bad) && margin <= kMaxEdgeFraction * range_px_) {
      edge_margin_px_ = margin;
      separation_cycles_ = separation_below_bad;
    }
  }
  if (separation_cycles_ < kMinSeparationCycles) {
    std::ostringstream list;
    for (size_t i = 0; i < periods_.size(); ++i) list << (i ? "/" : "") << periods_[i];
    MESOSCAN_BAD_INPUT("unwrapping: periods "
                       << list.str() << " px do not tell apart the columns "
                       << "of a " << range_px_ << " px wide projector (code separation "
                       << separation_cycles_ << " cycles < " << kMinSeparationCycles << ")");
  }
}

template <class Order>
double TemporalUnwrapper::LastPass(const double* t, const double* w_px, Order&& order,
                                   double* sw_out, double* chi2_out) const {
  const int m = static_cast<int>(periods_.size());
  double sw = 0.0, swu = 0.0;
  for (int i = 0; i < m; ++i) {
    const double n_i = order(i);
    sw += w_px[i];
    swu += w_px[i] * periods_[i] * (t[i] + n_i);
  }
  const double u = swu / sw;
  double chi2 = 0.0;
  for (int i = 0; i < m; ++i) {
    const double r_px = WrapCycles(u / periods_[i] - t[i]) * periods_[i];
    chi2 += w_px[i] * r_px * r_px;
  }
  *sw_out = sw;
  *chi2_out = chi2;
  return u;
}

UnwrapResult TemporalUnwrapper::ResultAt(double u, double chi2) const {
  const int m = static_cast<int>(periods_.size());
  UnwrapResult result;
  result.u = u;
  result.residual = m > 1 ? std::sqrt(chi2 / (m - 1)) : 0.0;
  result.valid = std::isfinite(result.u) && result.residual <= max_residual_ && result.u >= -1.0 &&
                 result.u < range_px_;
  // Columns in the ambiguous edge bands (see edge_margin_px()): the other edge's code is as close.
  if (edge_margin_px_ > 0.0 &&
      (u < edge_margin_px_ - 0.5 || u > range_px_ - 0.5 - edge_margin_px_)) {
    result.valid = false;
    result.ambiguous_edge = true;
  }
  return result;
}

// Runtime dispatch (core/simd_clones.h): the AVX2 clone has SSE4.1's inline floor and 4-lane
// loops. GCC cannot see that anchor_ < m (the constructor's invariant) and would warn that the
// per-period arrays, filled for i < m only, may be read uninitialised.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
MESOSCAN_SIMD_CLONES
UnwrapResult TemporalUnwrapper::Unwrap(const double* theta, const double* weight) const {
  UnwrapResult result;
  const int m = static_cast<int>(periods_.size());
  constexpr int kMaxPeriods = 16;
  if (m > kMaxPeriods) return result;  // not a pattern set anyone projects
  // The per-period arrays are left uninitialised: only their first m entries are read (zeroing
  // all 16 cost a `rep stos` each per pixel, ~6% of the unwrapper's time at full resolution).
  std::array<double, kMaxPeriods> t;     // wrapped phase in cycles [0, 1)
  std::array<double, kMaxPeriods> w_px;  // weight of the per-period estimate of u (px^-2)
  for (int i = 0; i < m; ++i) {
    if (!std::isfinite(theta[i]) || !(weight[i] > 0.0) || !std::isfinite(weight[i])) return result;
    const double c = theta[i] / kTwoPi;
    t[i] = c - std::floor(c);
    const double g = phase_rate_[i];  // d theta / d u
    w_px[i] = weight[i] * g * g;
  }
  const int a = anchor_;
  const double pa = periods_[a], ta = t[a];

  // 1. Score every fringe order k of the anchor: u_k = pa (t_a + k). The residual of period i at
  //    u_k, in cycles, carries its own noise and the anchor's scaled by pa / p_i.
  std::array<double, kMaxPeriods> inv_var;  // 1 / var of the residual of period i (cycles^-2)
  const double var_a_px = 1.0 / w_px[a];
  for (int i = 0; i < m; ++i) {
    if (i == a) continue;
    const double var_i_px = 1.0 / w_px[i];
    inv_var[i] = periods_[i] * periods_[i] / (var_i_px + var_a_px);
  }
  // Candidates may leave the domain [-0.5, R - 0.5) by the anchor's own noise (a long cue
  // period turns a small phase error into pixels). u grows with k: trim both ends.
  const double margin = 0.5 + 6.0 * std::sqrt(var_a_px);
  // An anchor whose noise spans more than the whole range (a weight near 0) tells nothing, and
  // its candidate orders would not fit in an int: invalid.
  if (!(margin <= range_px_)) return result;
  auto inside = [&](int k) {
    const double u = pa * (ta + k);
    return !(u < -0.5 - margin || u >= range_px_ - 0.5 + margin);
  };
  int k_first = static_cast<int>(std::floor((-0.5 - margin) / pa));
  int k_last = static_cast<int>(std::floor((range_px_ - 0.5 + margin) / pa));
  while (k_first <= k_last && !inside(k_first)) ++k_first;
  while (k_last >= k_first && !inside(k_last)) --k_last;
  if (k_first > k_last) return result;
  double best_score[2] = {std::numeric_limits<double>::infinity(),
                          std::numeric_limits<double>::infinity()};
  int best_k[2] = {k_first, k_first};
  // Periods whose residual repeats every q orders: the q weighted squared residuals of the
  // first q candidates, reused for the rest (table[i][(k - k_first) mod q]).
  const bool tables = k_last - k_first < table_candidates_;
  std::array<std::array<double, kMaxCycle>, kMaxPeriods> table;
  if (tables) {
    for (int i = 0; i < m; ++i) {
      if (i == a) continue;
      const double ip = inv_periods_[i], ti = t[i], wi = inv_var[i];
      for (int j = 0; j < cycle_[i]; ++j) {
        const double r = WrapCyclesSmall(pa * (ta + (k_first + j)) * ip - ti);
        table[i][j] = r * r * wi;
      }
    }
  }
  // Two other periods with tables (e.g. 13 with 7 and 11): the score of candidate r = k -
  // k_first is A[r mod qa] + B[r mod qb]. The best two usually pair small entries of each table:
  // among the pairs of the kPairRank smallest of A and of B (those that are candidates), if the
  // second best is below every sum outside them (>= min(A_K + B_1, A_1 + B_K)), these are the
  // two the full scan finds; otherwise scan.
  bool scanned = false;
  if (tables && pair_.size() == 2) {
    constexpr int kPairRank = 4;
    const int ia = pair_[0], ib = pair_[1];
    const int qa = cycle_[ia], qb = cycle_[ib];
    const int nk = k_last - k_first + 1;
    if (qa >= kPairRank && qb >= kPairRank) {
      const double* ta_v = table[ia].data();
      const double* tb_v = table[ib].data();
      static_assert(kPairRank == 4, "SmallestFour");
      std::array<int, 4> sa, sb;
      SmallestFourPair(ta_v, qa, tb_v, qb, &sa, &sb);
      // (score, offset) of the best two, compared lexicographically (the scan keeps the first
      // of equal scores). The score adds the periods in index order, as the scan does.
      double s0 = std::numeric_limits<double>::infinity(), s1 = s0;
      int r0 = -1, r1 = -1;
      for (int x = 0; x < kPairRank; ++x)
        for (int y = 0; y < kPairRank; ++y) {
          const int r = crt_[sa[x] * qb + sb[y]];
          if (r >= nk) continue;
          const double sc = (0.0 + ta_v[sa[x]]) + tb_v[sb[y]];
          if (sc < s0 || (sc == s0 && r < r0)) {
            s1 = s0, r1 = r0, s0 = sc, r0 = r;
          } else if (sc < s1 || (sc == s1 && r < r1)) {
            s1 = sc, r1 = r;
          }
        }
      const double bound =
          std::min(ta_v[sa[kPairRank - 1]] + tb_v[sb[0]], ta_v[sa[0]] + tb_v[sb[kPairRank - 1]]);
      if (r1 >= 0 && s1 < bound) {
        best_score[0] = s0, best_k[0] = k_first + r0;
        best_score[1] = s1, best_k[1] = k_first + r1;
        scanned = true;
      }
    }
  }
  // Scores of a chunk of candidates at a time: branch-free loops the compiler vectorises (this
  // is the hot loop of the pipeline's unwrapping), then the best two of the chunk.
  constexpr int kChunk = 64;
  std::array<double, kChunk> score;
  for (int kb = k_first; !scanned && kb <= k_last; kb += kChunk) {
    const int nk = std::min(kChunk, k_last - kb + 1);
    std::fill(score.begin(), score.begin() + nk, 0.0);
    for (int i = 0; i < m; ++i) {
      if (i == a) continue;
      if (tables) {
        const int q = cycle_[i];
        const double* tab = table[i].data();
        for (int j = 0, c = (kb - k_first) % q; j < nk; j += q - c, c = 0) {
          const int len = std::min(q - c, nk - j);
          for (int l = 0; l < len; ++l) score[j + l] += tab[c + l];
        }
        continue;
      }
      const double ip = inv_periods_[i], ti = t[i], wi = inv_var[i];
      for (int j = 0; j < nk; ++j) {
        const double u = pa * (ta + (kb + j));  // |u| <= range + margin: far below 2^51
        const double r = WrapCyclesSmall(u * ip - ti);
        score[j] += r * r * wi;
      }
    }
    for (int j = 0; j < nk; ++j) {
      if (score[j] < best_score[0]) {
        best_score[1] = best_score[0];
        best_k[1] = best_k[0];
        best_score[0] = score[j];
        best_k[0] = kb + j;
      } else if (score[j] < best_score[1]) {
        best_score[1] = score[j];
        best_k[1] = kb + j;
      }
    }
  }
  if (!std::isfinite(best_score[0])) return result;

  // 2. Refine the best two: coarse to fine, each period's fringe order from the running
  //    estimate, which then becomes the weighted mean of the per-period estimates so far
  //    (hierarchical sets need the chain); a last pass re-derives every order at the final u.
  //    Keep the candidate with the smaller chi^2.
  // Both candidates advance together (two independent chains the CPU overlaps). The fringe
  // orders need u / p_i only up to rounding: u * (1 / p_i) with the running mean's u = swu *
  // (1 / sw) (the prefix sums of the weights are the same for both candidates) gives the same
  // integer unless u / p_i - t_i lies within 1e-9 cycles of a half-integer (the products are off
  // by a few ulps, ~1e-13 cycles), where the exact quotient decides. Same results to the last bit
  // as dividing throughout, without the chain of dependent divisions.
  std::array<double, kMaxPeriods> inv_prefix_w;
  {
    double sw = 0.0;
    for (int o = 0; o < m; ++o) {
      sw += w_px[order_[o]];
      inv_prefix_w[o] = 1.0 / sw;
    }
  }
  auto fringe_order = [&](double u_approx, int i, double u_exact_num, double u_exact_den) {
    const double x = u_approx * inv_periods_[i] - t[i];
    const double n = RoundNearest(x);
    if (std::abs(std::abs(x - n) - 0.5) > 1e-9 * (1.0 + std::abs(x))) return n;
    return RoundNearest((u_exact_num / u_exact_den) / periods_[i] - t[i]);
  };
  const int nc = std::isfinite(best_score[1]) ? 2 : 1;
  double u_c[2], swu_c[2] = {0.0, 0.0}, sw_prev = 1.0;
  for (int c = 0; c < 2; ++c) u_c[c] = pa * (ta + best_k[c]);
  double num_c[2] = {u_c[0], u_c[1]};  // u = num / den exactly (den 1 for the start)
  double sw = 0.0;
  for (int o = 0; o < m; ++o) {
    const int i = order_[o];
    sw += w_px[i];
    for (int c = 0; c < 2; ++c) {
      const double n_i = fringe_order(u_c[c], i, num_c[c], sw_prev);
      swu_c[c] += w_px[i] * periods_[i] * (t[i] + n_i);
      u_c[c] = swu_c[c] * inv_prefix_w[o];
      num_c[c] = swu_c[c];
    }
    sw_prev = sw;
  }
  double best_score_refined = std::numeric_limits<double>::infinity();
  double best_chi2 = 0.0, best_u = 0.0;
  for (int c = 0; c < nc; ++c) {
    double sw_f, chi2;
    const double u = LastPass(
        t.data(), w_px.data(), [&](int i) { return fringe_order(u_c[c], i, num_c[c], sw_prev); },
        &sw_f, &chi2);
    // Where the code repeats exactly at the projector width (e.g. 7/11/13 on 1001 px) the two
    // ends alias: prefer the estimate inside the domain, by its distance outside in sigma_u.
    const double out = std::max({0.0, -0.5 - u, u - (range_px_ - 0.5)});
    const double score = chi2 + out * out * sw_f;
    if (score < best_score_refined) {
      best_score_refined = score;
      best_chi2 = chi2;
      best_u = u;
    }
  }
  return ResultAt(best_u, best_chi2);
}

MESOSCAN_SIMD_CLONES
UnwrapResult TemporalUnwrapper::UnwrapAt(const double* theta, const double* weight,
                                         double u_hint) const {
  // Unwrap()'s steps and checks in its order, without the candidates: the inputs, the anchor's
  // margin, the orders at u_hint (Unwrap() takes them at its refined estimate, which differs
  // from u_hint by noise, far from a half-cycle), then its last pass.
  UnwrapResult result;
  const int m = static_cast<int>(periods_.size());
  constexpr int kMaxPeriods = 16;
  if (m > kMaxPeriods || !std::isfinite(u_hint)) return result;
  std::array<double, kMaxPeriods> t;
  std::array<double, kMaxPeriods> w_px;
  for (int i = 0; i < m; ++i) {
    if (!std::isfinite(theta[i]) || !(weight[i] > 0.0) || !std::isfinite(weight[i])) return result;
    const double c = theta[i] / kTwoPi;
    t[i] = c - std::floor(c);
    const double g = phase_rate_[i];
    w_px[i] = weight[i] * g * g;
  }
  const double margin = 0.5 + 6.0 * std::sqrt(1.0 / w_px[anchor_]);
  if (!(margin <= range_px_)) return result;
  double sw_f, chi2;
  const double u = LastPass(
      t.data(), w_px.data(), [&](int i) { return RoundNearest(u_hint / periods_[i] - t[i]); },
      &sw_f, &chi2);
  return ResultAt(u, chi2);
}

#if defined(__GNUC__) && !defined(__clang__)  // GCC's vector extensions (V4d, V4l)
// UnwrapMany's lanes: Unwrap()'s steps for the common case (three periods, residual tables, the
// best two among the smallest table entries), every step a loop over four pixels (the compiler
// makes them vector operations), per lane the same operations in the same order as Unwrap().
// ok[l] turns false where lane l leaves the common case (Unwrap() then decides). The steps are
// inlined into UnwrapFour's clones (always_inline: each clone compiles them for its own ISA).
class TemporalUnwrapper::FourPixels {
 public:
  static constexpr int kL = 4;
  static constexpr int kM = 3;
  static constexpr double kMagic = 6755399441055744.0;  // RoundNearest's
  static constexpr double kRoundLimit = 2251799813685248.0;

  explicit FourPixels(const TemporalUnwrapper& u) : u_(u) {}

  // Unwrap()'s input checks, wrapped phases in cycles and weights in px^-2.
  __attribute__((always_inline)) void Load(const double* theta, const double* weight) {
    for (int l = 0; l < kL; ++l) {
      bool good = true;
      for (int i = 0; i < kM; ++i) {
        const double th = theta[l * kM + i], w = weight[l * kM + i];
        good &= std::isfinite(th) & (w > 0.0) & std::isfinite(w);
      }
      ok_[l] = good;
    }
    for (int i = 0; i < kM; ++i) {
      const double g = u_.phase_rate_[i];
      for (int l = 0; l < kL; ++l) {
        const double c = theta[l * kM + i] / kTwoPi;
        t_[i][l] = c - std::floor(c);
        w_px_[i][l] = weight[l * kM + i] * g * g;
      }
    }
  }

  // Unwrap() step 1's variances and the anchor's candidate orders [k_first, k_first + nk).
  __attribute__((always_inline)) void CandidateOrders() {
    const int a = u_.anchor_;
    const double pa = u_.periods_[a];
    for (int l = 0; l < kL; ++l) var_a_px_[l] = 1.0 / w_px_[a][l];
    for (int i = 0; i < kM; ++i) {
      if (i == a) continue;
      for (int l = 0; l < kL; ++l) {
        const double var_i_px = 1.0 / w_px_[i][l];
        inv_var_[i][l] = u_.periods_[i] * u_.periods_[i] / (var_i_px + var_a_px_[l]);
      }
    }
    for (int l = 0; l < kL; ++l) {
      k_first_[l] = 0, nk_[l] = 0;
      if (!ok_[l]) continue;
      const double ta = t_[a][l];
      const double margin = 0.5 + 6.0 * std::sqrt(var_a_px_[l]);
      if (!(margin <= u_.range_px_)) {  // Unwrap() returns it invalid
        ok_[l] = false;
        continue;
      }
      auto inside = [&](int k) {
        const double u = pa * (ta + k);
        return !(u < -0.5 - margin || u >= u_.range_px_ - 0.5 + margin);
      };
      int kf = static_cast<int>(std::floor((-0.5 - margin) / pa));
      int kl = static_cast<int>(std::floor((u_.range_px_ - 0.5 + margin) / pa));
      while (kf <= kl && !inside(kf)) ++kf;
      while (kl >= kf && !inside(kl)) --kl;
      ok_[l] = kf <= kl && kl - kf < u_.table_candidates_;
      if (ok_[l]) k_first_[l] = kf, nk_[l] = kl - kf + 1;
    }
  }

  // The residual tables of the two other periods; a NaN entry in either: Unwrap() decides.
  __attribute__((always_inline)) void ResidualTables() {
    const int a = u_.anchor_;
    const double pa = u_.periods_[a];
    for (int i = 0; i < kM; ++i) {
      if (i == a) continue;
      const double ip = u_.inv_periods_[i];
      for (int j = 0; j < u_.cycle_[i]; ++j)
        for (int l = 0; l < kL; ++l) {
          const double r = WrapCyclesSmall(pa * (t_[a][l] + (k_first_[l] + j)) * ip - t_[i][l]);
          table_[i][j][l] = r * r * inv_var_[i][l];
        }
    }
    // (lanes in one vector: v != v)
    V4l nan = {0, 0, 0, 0};
    for (int i : {u_.pair_[0], u_.pair_[1]})
      for (int j = 0; j < u_.cycle_[i]; ++j) {
        V4d v;
        __builtin_memcpy(&v, table_[i][j], sizeof(v));
        nan |= v != v;
      }
    for (int l = 0; l < kL; ++l) ok_[l] &= nan[l] == 0;
  }

  // The best two candidate orders per lane: the four smallest entries of each table, then
  // Unwrap()'s comparisons over their 16 pairs as selects; a lane whose second best is not below
  // every sum outside them leaves the common case.
  __attribute__((always_inline)) void BestTwoOrders() {
    const int ia = u_.pair_[0], ib = u_.pair_[1];
    const int qa = u_.cycle_[ia], qb = u_.cycle_[ib];
    // SmallestFourInsert per lane: slot k takes x if x < slot k (or the slot is still empty, k >=
    // j), after shifting up when slot k - 1 took it. Four sorted slots per lane, in GCC vectors
    // across the lanes (V4d from SmallestFour).
    auto insert = [&](const double* xp, int j, V4d* sv, V4l* id) {
      V4d x;
      __builtin_memcpy(&x, xp, sizeof(x));
      const V4l jv = {j, j, j, j};
      V4l m[4];
      for (int k = 0; k < 4; ++k) m[k] = (x < sv[k]) | (k >= j ? V4l{-1, -1, -1, -1} : V4l{});
      for (int k = 3; k >= 1; --k) {
        sv[k] = m[k - 1] ? sv[k - 1] : (m[k] ? x : sv[k]);
        id[k] = m[k - 1] ? id[k - 1] : (m[k] ? jv : id[k]);
      }
      sv[0] = m[0] ? x : sv[0];
      id[0] = m[0] ? jv : id[0];
    };
    // The slots' starting contents never reach a result (slot k takes x at every j <= k, and
    // both tables have >= 4 entries): +inf and index 1, which the compiler writes with vector
    // stores (zeros became two `rep stos`, ~4 % of this function's time).
    const double inf_slot = std::numeric_limits<double>::infinity();
    const V4d e = {inf_slot, inf_slot, inf_slot, inf_slot};
    const V4l e_id = {1, 1, 1, 1};
    V4d sva[4] = {e, e, e, e}, svb[4] = {e, e, e, e};
    V4l ida[4] = {e_id, e_id, e_id, e_id}, idb[4] = {e_id, e_id, e_id, e_id};
    for (int j = 0; j < qa || j < qb; ++j) {
      if (j < qa) insert(table_[ia][j], j, sva, ida);
      if (j < qb) insert(table_[ib][j], j, svb, idb);
    }
    // The best two of the 16 pairs of slots per lane (a slot's value is the table entry at its
    // index, so the score is the sum of the two slots).
    const V4l nk_v = {nk_[0], nk_[1], nk_[2], nk_[3]};
    const double inf = std::numeric_limits<double>::infinity();
    V4d s0 = {inf, inf, inf, inf}, s1 = s0;
    V4l r0 = {-1, -1, -1, -1}, r1 = r0;
    const int* crt = u_.crt_.data();
    for (int x = 0; x < 4; ++x)
      for (int y = 0; y < 4; ++y) {
        const V4l r = {crt[ida[x][0] * qb + idb[y][0]], crt[ida[x][1] * qb + idb[y][1]],
                       crt[ida[x][2] * qb + idb[y][2]], crt[ida[x][3] * qb + idb[y][3]]};
        const V4d sc = (0.0 + sva[x]) + svb[y];
        const V4l in = r < nk_v;
        const V4l first = in & ((sc < s0) | ((sc == s0) & (r < r0)));
        const V4l second = in & ~first & ((sc < s1) | ((sc == s1) & (r < r1)));
        s1 = first ? s0 : (second ? sc : s1);
        r1 = first ? r0 : (second ? r : r1);
        s0 = first ? sc : s0;
        r0 = first ? r : r0;
      }
    const V4d bound_a = sva[3] + svb[0], bound_b = sva[0] + svb[3];
    const V4d bound = bound_b < bound_a ? bound_b : bound_a;  // std::min(bound_a, bound_b)
    const V4l pair_ok = (r1 >= 0) & (s1 < bound);
    for (int l = 0; l < kL; ++l) {
      ok_[l] &= pair_ok[l] != 0;
      best_k_[0][l] = k_first_[l] + static_cast<int>(r0[l]);
      best_k_[1][l] = k_first_[l] + static_cast<int>(r1[l]);
    }
    for (int l = 0; l < kL; ++l)
      if (!ok_[l]) best_k_[0][l] = best_k_[1][l] = 0;
  }

  // Unwrap() step 2 for both candidates together (fringe_order's fast path; a lane where the
  // exact quotient would decide leaves the common case), then its last pass: u_f_, chi2_f_.
  __attribute__((always_inline)) void Refine() {
    double inv_prefix_w[kM][kL];
    {
      double sw[kL] = {};
      for (int o = 0; o < kM; ++o)
        for (int l = 0; l < kL; ++l) {
          sw[l] += w_px_[u_.order_[o]][l];
          inv_prefix_w[o][l] = 1.0 / sw[l];
        }
    }
    // The lanes in GCC vectors (the same operations per lane; |.| by clearing the sign bit).
    // (Results through pointers: a lambda returning a 32-byte vector has another ABI in the
    // baseline clone.)
    auto load = [](const double* p, V4d* v) { __builtin_memcpy(v, p, sizeof(*v)); };
    auto vabs = [](const V4d& v, V4d* out) {
      V4l b;
      __builtin_memcpy(&b, &v, sizeof(b));
      b &= V4l{0x7fffffffffffffffLL, 0x7fffffffffffffffLL, 0x7fffffffffffffffLL,
               0x7fffffffffffffffLL};
      __builtin_memcpy(out, &b, sizeof(*out));
    };
    const std::vector<double>& periods = u_.periods_;
    const std::vector<double>& inv_periods = u_.inv_periods_;
    V4d tv[kM], wv[kM];
    for (int i = 0; i < kM; ++i) load(t_[i], &tv[i]), load(w_px_[i], &wv[i]);
    V4l exact = {-1, -1, -1, -1};
    auto fringe_order = [&](const V4d& u_approx, int i, V4d* n) {
      const V4d x = u_approx * inv_periods[i] - tv[i];
      *n = (x + kMagic) - kMagic;
      V4d ax, ad;
      vabs(x, &ax);
      vabs(x - *n, &ad);
      vabs(ad - 0.5, &ad);
      exact &= (ax < kRoundLimit) & (ad > 1e-9 * (1.0 + ax));
    };
    const int a = u_.anchor_;
    const double pa = periods[a];
    V4d u_c[2], swu_c[2];
    for (int c = 0; c < 2; ++c) {
      for (int l = 0; l < kL; ++l) u_c[c][l] = pa * (t_[a][l] + best_k_[c][l]);
      swu_c[c] = V4d{0.0, 0.0, 0.0, 0.0};
    }
    for (int o = 0; o < kM; ++o) {
      const int i = u_.order_[o];
      V4d inv_w;
      load(inv_prefix_w[o], &inv_w);
      for (int c = 0; c < 2; ++c) {
        V4d n_i;
        fringe_order(u_c[c], i, &n_i);
        swu_c[c] += wv[i] * periods[i] * (tv[i] + n_i);
        u_c[c] = swu_c[c] * inv_w;
      }
    }
    V4d sw_f = {0.0, 0.0, 0.0, 0.0}, swu_f[2] = {sw_f, sw_f};
    for (int i = 0; i < kM; ++i) {
      sw_f += wv[i];
      for (int c = 0; c < 2; ++c) {
        V4d n_i;
        fringe_order(u_c[c], i, &n_i);
        swu_f[c] += wv[i] * periods[i] * (tv[i] + n_i);
      }
    }
    V4d u_fv[2], chi2_fv[2] = {V4d{0.0, 0.0, 0.0, 0.0}, V4d{0.0, 0.0, 0.0, 0.0}};
    for (int c = 0; c < 2; ++c) u_fv[c] = swu_f[c] / sw_f;
    for (int i = 0; i < kM; ++i)
      for (int c = 0; c < 2; ++c) {
        const V4d x = u_fv[c] / periods[i] - tv[i];
        V4d ax;
        vabs(x, &ax);
        exact &= ax < kRoundLimit;
        const V4d r_px = (x - ((x + kMagic) - kMagic)) * periods[i];
        chi2_fv[c] += wv[i] * r_px * r_px;
      }
    for (int l = 0; l < kL; ++l) {
      for (int c = 0; c < 2; ++c) u_f_[c][l] = u_fv[c][l], chi2_f_[c][l] = chi2_fv[c][l];
      sw_f_[l] = sw_f[l];
      ok_[l] &= exact[l] != 0;
    }
  }

  // Per lane, the candidate Unwrap() keeps (the smaller chi^2, out-of-domain estimates penalised)
  // and its result; done[l] is false where the lane left the common case.
  __attribute__((always_inline)) void Results(UnwrapResult* result, bool* done) const {
    for (int l = 0; l < kL; ++l) {
      done[l] = ok_[l];
      if (!done[l]) continue;
      double best_score_refined = std::numeric_limits<double>::infinity();
      double best_chi2 = 0.0, best_u = 0.0;
      for (int c = 0; c < 2; ++c) {
        const double u = u_f_[c][l], chi2 = chi2_f_[c][l];
        const double out = std::max({0.0, -0.5 - u, u - (u_.range_px_ - 0.5)});
        const double score = chi2 + out * out * sw_f_[l];
        if (score < best_score_refined) {
          best_score_refined = score;
          best_chi2 = chi2;
          best_u = u;
        }
      }
      result[l] = u_.ResultAt(best_u, best_chi2);
    }
  }

 private:
  const TemporalUnwrapper& u_;
  bool ok_[kL];
  double t_[kM][kL], w_px_[kM][kL];  // phases in cycles, weights in px^-2
  double var_a_px_[kL], inv_var_[kM][kL];
  int k_first_[kL], nk_[kL];
  double table_[kM][kMaxCycle][kL];
  int best_k_[2][kL];
  double u_f_[2][kL], chi2_f_[2][kL], sw_f_[kL];
};

MESOSCAN_SIMD_CLONES
void TemporalUnwrapper::UnwrapFour(const double* theta, const double* weight, UnwrapResult* result,
                                   bool* done) const {
  FourPixels lanes(*this);
  lanes.Load(theta, weight);
  lanes.CandidateOrders();
  lanes.ResidualTables();
  lanes.BestTwoOrders();
  lanes.Refine();
  lanes.Results(result, done);
}

// UnwrapAt()'s steps for three periods on four pixels in vector lanes (V4d), per lane the same
// operations in the same order, but for the fringe orders: the hint times 1 / period rounds to
// the same integer as the quotient unless within 1e-9 cycles of a half-integer (that lane is
// left to UnwrapAt()). done[l] is false there and where lane l's inputs are not finite, its
// anchor margin fails or a value leaves the fast rounding's range.
MESOSCAN_SIMD_CLONES
void TemporalUnwrapper::UnwrapAtFour(const double* theta, const double* weight,
                                     const double* u_hint, UnwrapResult* result, bool* done) const {
  constexpr int kM = 3;
  constexpr double kMagic = 6755399441055744.0;  // RoundNearest's
  constexpr double kRoundLimit = 2251799813685248.0;
  const V4d magic = {kMagic, kMagic, kMagic, kMagic};
  const V4d limit = {kRoundLimit, kRoundLimit, kRoundLimit, kRoundLimit};
  const V4d zero = {0.0, 0.0, 0.0, 0.0};
  const V4l sign = {INT64_MIN, INT64_MIN, INT64_MIN, INT64_MIN};
  // |v| and "finite" (v - v is 0 for finite v, NaN otherwise) written out below: a lambda
  // returning a V4d changes the ABI of the baseline clone (-Wpsabi).
#define MESOSCAN_ABS4(v) reinterpret_cast<V4d>(reinterpret_cast<V4l>(v) & ~sign)
#define MESOSCAN_FINITE4(v) (((v) - (v)) == zero)
  const V4d hint = {u_hint[0], u_hint[1], u_hint[2], u_hint[3]};
  auto ok = MESOSCAN_FINITE4(hint) & (MESOSCAN_ABS4(hint) < limit);
  V4d t[kM], w_px[kM];
  for (int i = 0; i < kM; ++i) {
    const V4d th = {theta[i], theta[kM + i], theta[2 * kM + i], theta[3 * kM + i]};
    const V4d w = {weight[i], weight[kM + i], weight[2 * kM + i], weight[3 * kM + i]};
    ok &= MESOSCAN_FINITE4(th) & (w > zero) & MESOSCAN_FINITE4(w);
    const V4d c = th / kTwoPi;
    ok &= MESOSCAN_ABS4(c) < limit;
    const V4d r = (c + magic) - magic;
    t[i] = c - (r > c ? r - 1.0 : r);  // c - std::floor(c)
    const double g = phase_rate_[i];
    w_px[i] = w * g * g;
  }
  V4d sw_f = zero, swu = zero;
  for (int i = 0; i < kM; ++i) {
    const double p = periods_[i];
    const V4d x = hint * inv_periods_[i] - t[i];
    const V4d n_i = (x + magic) - magic;
    ok &= MESOSCAN_ABS4(MESOSCAN_ABS4(x - n_i) - 0.5) > 1e-9 * (1.0 + MESOSCAN_ABS4(x));
    sw_f += w_px[i];
    swu += w_px[i] * p * (t[i] + n_i);
  }
  const V4d u = swu / sw_f;
  V4d chi2 = zero;
  for (int i = 0; i < kM; ++i) {
    const double p = periods_[i];
    const V4d y = u / p - t[i];
    ok &= MESOSCAN_ABS4(y) < limit;
    const V4d r_px = (y - ((y + magic) - magic)) * p;
    chi2 += w_px[i] * r_px * r_px;
  }
#undef MESOSCAN_ABS4
#undef MESOSCAN_FINITE4
  for (int l = 0; l < 4; ++l) {
    done[l] = ok[l] != 0 && 0.5 + 6.0 * std::sqrt(1.0 / w_px[anchor_][l]) <= range_px_;
    if (!done[l]) continue;
    result[l] = ResultAt(u[l], chi2[l]);
  }
}
#endif
#pragma GCC diagnostic pop

void TemporalUnwrapper::UnwrapAtMany(const double* theta, const double* weight,
                                     const double* u_hint, int n, UnwrapResult* result) const {
  const int m = static_cast<int>(periods_.size());
  int p = 0;
#if defined(__GNUC__) && !defined(__clang__)
  if (m == 3) {
    bool done[4];
    for (; p + 4 <= n; p += 4) {
      UnwrapAtFour(theta + p * m, weight + p * m, u_hint + p, result + p, done);
      for (int l = 0; l < 4; ++l)
        if (!done[l])
          result[p + l] = UnwrapAt(theta + (p + l) * m, weight + (p + l) * m, u_hint[p + l]);
    }
  }
#endif
  for (; p < n; ++p) result[p] = UnwrapAt(theta + p * m, weight + p * m, u_hint[p]);
}

void TemporalUnwrapper::UnwrapMany(const double* theta, const double* weight, int n,
                                   UnwrapResult* result) const {
  const int m = static_cast<int>(periods_.size());
  int p = 0;
#if defined(__GNUC__) && !defined(__clang__)
  if (m == 3 && pair_.size() == 2 && cycle_[pair_[0]] >= 4 && cycle_[pair_[1]] >= 4) {
    bool done[4];
    for (; p + 4 <= n; p += 4) {
      UnwrapFour(theta + p * m, weight + p * m, result + p, done);
      for (int l = 0; l < 4; ++l)
        if (!done[l]) result[p + l] = Unwrap(theta + (p + l) * m, weight + (p + l) * m);
    }
  }
#endif
  for (; p < n; ++p) result[p] = Unwrap(theta + p * m, weight + p * m);
}

}  // namespace mesoscan
