#pragma once
// Phase-shift decoding and temporal unwrapping.
//
// Convention (docs/formats.md, "Patterns"): the projector shows
//   0.5 + 0.5 cos(2 pi u / period + delta)
// so a camera pixel seeing projector column u records I_k = A + B cos(theta + delta_k) with
// theta = 2 pi u / period (mod 2 pi). WrappedPhaseSolver recovers theta per period;
// TemporalUnwrapper combines the wrapped phases of several periods into the absolute u.

#include <cstddef>
#include <vector>

namespace mesoscan {

// Least-squares wrapped phase for any set of >= 3 distinct phase offsets delta_k (unequal steps
// allowed): [A, B cos theta, B sin theta] = pinv([1, cos delta_k, -sin delta_k]) I, the
// pseudo-inverse precomputed once. Solve() is const, thread-safe and allocation-free.
class WrappedPhaseSolver {
 public:
  struct Result {
    float theta = 0.0f;         // wrapped phase in [0, 2 pi)
    float modulation = 0.0f;    // B >= 0, frame units
    float offset = 0.0f;        // A, frame units
    float residual_rms = 0.0f;  // sqrt(sum of squared residuals / K) (0 for K = 3)
    bool valid = false;         // all samples finite (otherwise every other field is 0)
  };

  // deltas: the phase offsets delta_k (radians) of the K frames, in the order Solve() receives
  // the samples. Throws mesoscan::Error (bad input) if K < 3, a delta is not finite, or the
  // offsets do not determine theta (fewer than 3 distinct values mod 2 pi).
  explicit WrappedPhaseSolver(std::vector<double> deltas);

  // samples[k * stride], k in [0, K).
  Result Solve(const float* samples, int stride = 1) const;
  // Solve for n pixels at once: pixel j's samples are samples[k * stride + j] (a frame-major
  // tile), its result out[j]. The same results as Solve, bit for bit: four pixels in the lanes
  // of one vector do Solve's operations in Solve's order (no FMA; core/simd_clones.h), and a
  // lane outside the common case (a non-finite sample or sum, an atan2 within 1e-13 of a float
  // rounding boundary) is redone by Solve. The phase-shift stage decodes every pixel through it.
  void SolveMany(const float* samples, size_t stride, int n, Result* out) const;

  // var(theta) (rad^2) for white noise sigma per sample and modulation B, at a given theta
  // (unequal steps make it depend on theta) and averaged over theta. Equal steps: 2 sigma^2 /
  // (K B^2) for every theta.
  double ThetaVarianceAt(double sigma, double modulation, double theta) const;
  double ThetaVariance(double sigma, double modulation) const {
    // The theta average of sin^2 and cos^2 is 1/2, of sin cos 0.
    return sigma * sigma * 0.5 * (cov_cc_ + cov_ss_) / (modulation * modulation);
  }

  int num_samples() const { return static_cast<int>(deltas_.size()); }
  const std::vector<double>& deltas() const { return deltas_; }

 private:
  std::vector<double> deltas_;
  std::vector<double> pinv_;       // 3 x K row-major: rows A, B cos theta, B sin theta
  std::vector<double> cos_, sin_;  // cos delta_k, sin delta_k (the residual's model)
  double cov_cc_ = 0, cov_ss_ = 0, cov_cs_ = 0;  // (M^T M)^-1 block of (B cos, B sin)
};

struct UnwrapResult {
  double u = 0.0;  // absolute projector coordinate (px), in [-0.5, range - 0.5) up to noise
  // Consistency of the periods, in sigma units: sqrt(chi^2 / (periods - 1)) with chi^2 the
  // weighted squared circular residuals at u; ~1 for consistent data, 0 for a single period.
  double residual = 0.0;
  bool valid = false;  // inputs finite, weights > 0 and residual <= the unwrapper's limit
  // u fell in an ambiguous edge band (TemporalUnwrapper::edge_margin_px()): valid is false.
  bool ambiguous_edge = false;
};

// Temporal unwrapping (one API for both cases):
//  - several periods (e.g. coprime 7/11/13 px covering 1001 px): every candidate fringe order of
//    the coarsest period is scored by the weighted circular residual of the others; the best two
//    candidates are refined (fringe orders of every period, u = weighted mean of the per-period
//    estimates) and the one with the smaller chi^2 wins. Where a period ratio is a fraction with
//    a small denominator q (13/11: 11), that period's residuals repeat every q orders and are
//    computed once per pixel (a table of q); with three periods the best two usually come from
//    the few smallest entries of the two tables, which is checked against a bound, else every
//    candidate is scored. Same results as scoring every candidate, to the last bit;
//  - hierarchical: a cue period >= range (one candidate) plus shorter periods refining it (the
//    same search: the coarsest period then has a single candidate).
// Unwrap() is const, thread-safe and allocation-free.
class TemporalUnwrapper {
 public:
  // periods: > 0 projector px, any order, at least 1; range_px: projector width (px) > 0.
  // max_residual: Unwrap() marks results with residual above it invalid (sigma units).
  // Throws mesoscan::Error (bad input) if the periods cannot tell apart two columns of
  // [0, range): separation_cycles() < kMinSeparationCycles, unless the separation is small only
  // for columns near opposite edges (a one-period cue equal to the width, e.g. 16 periods + cue):
  // then the columns within edge_margin_px() of either edge are marked invalid by Unwrap().
  TemporalUnwrapper(std::vector<double> periods, double range_px, double max_residual = 4.0);

  // theta[i]: wrapped phase of period i in [0, 2 pi) (any real is accepted and wrapped);
  // weight[i]: 1 / var(theta[i]) (rad^-2), > 0. A non-finite theta or weight <= 0 gives
  // valid == false.
  UnwrapResult Unwrap(const double* theta, const double* weight) const;
  // Unwrap() of n pixels: theta[p * m + i], weight[p * m + i] for pixel p and period i (m =
  // periods().size()), result[p]. The same results to the last bit as n calls; pixels are taken
  // four at a time through the common case (three periods with residual tables whose smallest
  // entries decide) in lanes, each lane the same operations in the same order as Unwrap(); a
  // lane that leaves the common case (non-finite input, the full scan, a fringe order within
  // 1e-9 cycles of a half-integer) is redone by Unwrap().
  void UnwrapMany(const double* theta, const double* weight, int n, UnwrapResult* result) const;
  // Unwrap()'s last pass alone: each period's fringe order at u_hint (e.g. Unwrap()'s u for the
  // same phases with other weights), then the weighted mean of the per-period estimates and its
  // residual with these weights, and the same checks. Where Unwrap() with these weights picks
  // the orders that u_hint lies on (u_hint within a fraction of a cycle of its u in every period),
  // the same result to the last bit, at a fraction of the cost (no candidate search).
  UnwrapResult UnwrapAt(const double* theta, const double* weight, double u_hint) const;
  // UnwrapAt() of n pixels (theta, weight as UnwrapMany(), u_hint[p]): the same results to the
  // last bit; three periods four pixels at a time in lanes.
  void UnwrapAtMany(const double* theta, const double* weight, const double* u_hint, int n,
                    UnwrapResult* result) const;

  // The smallest code distance between two columns at least half the finest period apart:
  // min over such pairs of max over periods of the circular distance in cycles. Phase errors
  // below about half of it (in cycles, per period) cannot cause a wrong fringe order.
  double separation_cycles() const { return separation_cycles_; }
  static constexpr double kMinSeparationCycles = 0.02;
  // Width (px) of the band at each edge whose columns the code cannot tell from the other edge's;
  // 0 when every column is unambiguous. At most kMaxEdgeFraction of the width.
  double edge_margin_px() const { return edge_margin_px_; }
  static constexpr double kMaxEdgeFraction = 0.02;

  const std::vector<double>& periods() const { return periods_; }
  double range_px() const { return range_px_; }

 private:
  std::vector<double> periods_;
  double range_px_;
  double max_residual_;
  std::vector<int> order_;          // period indices, coarsest first
  int anchor_ = 0;                  // index of the coarsest period
  double separation_cycles_ = 0.0;  // over the column distances that are not edge pairs
  double edge_margin_px_ = 0.0;
  std::vector<double> inv_periods_;  // 1 / period
  std::vector<double> phase_rate_;   // d theta / d u = 2 pi / period
  // Per period: the number q of the anchor's fringe orders after which its residual repeats
  // (anchor / period = p / q in lowest terms, e.g. 13 / 11: q = 11), if small enough for a
  // per-pixel table of q residuals to beat scoring every candidate; 0 otherwise.
  std::vector<int> cycle_;
  // The tables are used where every other period has one and the candidates of a pixel are at
  // most the combined cycle (lcm of the q): no two candidates then share all their residuals.
  int table_candidates_ = 0;
  // Three periods with tables: the other two (pair_) and the candidate offset r in [0, lcm) of
  // each pair of table entries, crt_[(r mod q_a) * q_b + r mod q_b] = r.
  std::vector<int> pair_;
  std::vector<int> crt_;
  // UnwrapMany's four pixels; false where a lane leaves the common case. Its steps: FourPixels.
  class FourPixels;
  void UnwrapFour(const double* theta, const double* weight, UnwrapResult* result,
                  bool* done) const;
  // The result at u with chi^2 `chi2`: residual, validity and the edge bands (every path).
  UnwrapResult ResultAt(double u, double chi2) const;
  // Unwrap()'s last pass: with period i's fringe order order(i), the weighted mean of the
  // per-period estimates (t: phases in cycles, w_px: weights in px^-2), its total weight and chi^2.
  template <class Order>
  double LastPass(const double* t, const double* w_px, Order&& order, double* sw_out,
                  double* chi2_out) const;
  // UnwrapAtMany's four pixels (three periods); false where a lane needs UnwrapAt() itself.
  void UnwrapAtFour(const double* theta, const double* weight, const double* u_hint,
                    UnwrapResult* result, bool* done) const;
};

}  // namespace mesoscan
