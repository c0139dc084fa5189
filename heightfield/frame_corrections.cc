#include "heightfield/frame_corrections.h"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "core/numbers.h"
#include "core/robust_stats.h"
#include "heightfield/frames.h"

namespace mesoscan {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Projects delta off span{1, x} (the affine gauge).
void ProjectAffine(std::vector<double>* delta, const std::vector<double>& x) {
  const int nk = static_cast<int>(x.size());
  Eigen::MatrixXd B(nk, 2);
  Eigen::VectorXd d(nk);
  for (int k = 0; k < nk; ++k) {
    B(k, 0) = 1.0;
    B(k, 1) = x[k];
    d(k) = (*delta)[k];
  }
  const Eigen::Vector2d c = (B.transpose() * B).ldlt().solve(B.transpose() * d);
  d -= B * c;
  for (int k = 0; k < nk; ++k) (*delta)[k] = d(k);
}

struct Problem {
  const std::vector<float>& s;
  int nk;
  const std::vector<double>& freq;
  const std::vector<double>& x;
  std::vector<int> pix;  // pixels in use
  // cos / sin at delta = 0 (the positions of every gains-only pass), pixel j's at
  // trig0[2 nk j ..]: cos then sin; empty until filled.
  std::vector<float> trig0;
};

bool AllZero(const std::vector<double>& v) {
  return std::all_of(v.begin(), v.end(), [](double e) { return e == 0.0; });
}

// cos / sin of theta_k = 2 pi f_j (x_k + delta_k) of pixel j, into ct[0..nk), st[0..nk);
// delta_zero: delta is all 0 (the table is used if filled).
void PixelTrig(const Problem& p, int j, const std::vector<double>& delta, double* ct, double* st,
               bool delta_zero = false) {
  if (delta_zero && !p.trig0.empty()) {
    const float* t = p.trig0.data() + static_cast<size_t>(j) * 2 * p.nk;
    for (int k = 0; k < p.nk; ++k) {
      ct[k] = t[k];
      st[k] = t[p.nk + k];
    }
    return;
  }
  const double w = 2 * kPi * p.freq[j];
  for (int k = 0; k < p.nk; ++k) {
    const double th = w * (p.x[k] + delta[k]);
    ct[k] = std::cos(th);
    st[k] = std::sin(th);
  }
}

// Per-pixel coefficients c = (d, alpha, beta) for frame parameters (g, delta) with the pixel's
// cos / sin from PixelTrig; the unweighted SSR in *ssr.
bool SolvePixel(const Problem& p, int j, const std::vector<double>& g, const double* ct,
                const double* st, Eigen::Vector3d* c, double* ssr,
                Eigen::LLT<Eigen::Matrix3d>* llt_out = nullptr) {
  // A = sum D D^T, b = sum D I with D = g (1, cos, sin): the six distinct entries of A summed
  // in scalars (the same products and sums as the Eigen expressions A += D D^T, b += D I; the
  // 3x3 temporaries cost more than the sums), mirrored for the solve.
  double a00 = 0, a10 = 0, a20 = 0, a11 = 0, a21 = 0, a22 = 0, b0 = 0, b1 = 0, b2 = 0;
  const float* I = p.s.data() + static_cast<size_t>(j) * p.nk;
  for (int k = 0; k < p.nk; ++k) {
    const double d0 = g[k], d1 = g[k] * ct[k], d2 = g[k] * st[k];
    const double v = static_cast<double>(I[k]);
    a00 += d0 * d0;
    a10 += d1 * d0;
    a20 += d2 * d0;
    a11 += d1 * d1;
    a21 += d2 * d1;
    a22 += d2 * d2;
    b0 += d0 * v;
    b1 += d1 * v;
    b2 += d2 * v;
  }
  Eigen::Matrix3d A;
  A << a00, a10, a20, a10, a11, a21, a20, a21, a22;
  const Eigen::Vector3d b(b0, b1, b2);
  Eigen::LLT<Eigen::Matrix3d> llt(A);
  if (llt.info() != Eigen::Success) return false;
  // Conditioning (cheaper than an rcond estimate): the Cholesky pivots' spread, squared.
  const Eigen::Vector3d piv = llt.matrixLLT().diagonal();
  if (!(piv.minCoeff() * piv.minCoeff() > 1e-10 * piv.maxCoeff() * piv.maxCoeff())) return false;
  *c = llt.solve(b);
  double r2 = 0;
  for (int k = 0; k < p.nk; ++k) {
    const double m = (*c)(0) + (*c)(1) * ct[k] + (*c)(2) * st[k];
    const double r = I[k] - g[k] * m;
    r2 += r * r;
  }
  *ssr = r2;
  if (llt_out) *llt_out = llt;
  return c->allFinite() && std::isfinite(r2);
}

// The pixels of a problem are processed in fixed blocks (in parallel), whose partial sums are
// added in block order: the result does not depend on the number of threads.
constexpr int kBlockPixels = 256;

}  // namespace

const char* FrameGainMethodName(FrameGainMethod m) {
  switch (m) {
    case FrameGainMethod::kJoint:
      return "joint";
    case FrameGainMethod::kAlternating:
      return "als";
    case FrameGainMethod::kFrameMeans:
      return "means";
  }
  return "?";
}

Json FrameCorrections::ToJson() const {
  if (gains.empty()) return nullptr;
  return {{"gains", gains},
          {"positions_px", positions_px},
          {"position_rms_px", position_rms_px},
          {"pixels_used", pixels_used},
          {"iterations", iterations},
          {"model", model},
          {"view_residual_stripe", view_residual_stripe},
          {"position_chi2_gain", position_chi2_gain},
          {"position_model_stopped", position_model_stopped},
          {"in_band_pixels", in_band_pixels},
          {"in_band_correction", {in_band_correction[0], in_band_correction[1]}},
          {"in_band_sigma", in_band_sigma},
          {"in_band_shrink", in_band_shrink},
          {"valid", valid}};
}

namespace {

// The pixels of one estimate, with their weights: the data every step below reads.
struct Fit {
  const Problem& p;
  const std::vector<double>& wts;  // 1 / sigma_j^2 per p.pix entry
  int n_pix;
  int n_blocks;
  double f_mid;  // the median frequency of the pixels in use
};

// The inputs EstimateFrameCorrections can work with (sizes agree, enough frames, gains > 0).
bool UsableInputs(const std::vector<float>& samples, int nk, const std::vector<double>& freq,
                  const std::vector<double>& x, const std::vector<double>& initial_gains) {
  if (nk < 8 || static_cast<int>(x.size()) != nk || static_cast<int>(initial_gains.size()) != nk ||
      freq.empty() || samples.size() != freq.size() * static_cast<size_t>(nk))
    return false;
  return true;
}

bool PositiveFinite(const std::vector<double>& v) {
  for (double e : v)
    if (!(e > 0) || !std::isfinite(e)) return false;
  return true;
}

// A regular subsample of at most ~max_pixels pixels with a frequency and finite samples.
std::vector<int> SubsamplePixels(const std::vector<float>& samples, int nk,
                                 const std::vector<double>& freq, int max_pixels) {
  std::vector<int> pix;
  const int n_all = static_cast<int>(freq.size());
  const int stride = std::max(1, n_all / std::max(16, max_pixels));
  for (int j = 0; j < n_all; j += stride) {
    if (!std::isfinite(freq[j]) || freq[j] == 0) continue;
    bool ok = true;
    for (int k = 0; k < nk && ok; ++k) ok = std::isfinite(samples[static_cast<size_t>(j) * nk + k]);
    if (ok) pix.push_back(j);
  }
  return pix;
}

// The delta = 0 table of cos / sin (floats: 4.8 MB for 12000 pixels of 50 frames).
std::vector<float> ZeroPositionTrig(const Problem& p) {
  const int nk = p.nk;
  std::vector<float> trig0(p.freq.size() * 2 * nk, 0.0f);
  const std::vector<double> zero(nk, 0.0);
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>(p.pix.size()), [&](int64_t q) {
    const int j = p.pix[q];
    std::vector<double> ct(nk), st(nk);
    PixelTrig(p, j, zero, ct.data(), st.data());
    float* t = trig0.data() + static_cast<size_t>(j) * 2 * nk;
    for (int k = 0; k < nk; ++k) {
      t[k] = static_cast<float>(ct[k]);
      t[nk + k] = static_cast<float>(st[k]);
    }
  });
  return trig0;
}

std::vector<double> MeanOne(std::vector<double> g) {
  const double mean = std::accumulate(g.begin(), g.end(), 0.0) / static_cast<int>(g.size());
  for (double& v : g) v /= mean;
  return g;
}

// Weights 1 / sigma_j^2 from a first solve at g_start (fixed afterwards: one objective
// throughout) and robust selection on the relative residual sigma_j / amplitude_j: p->pix keeps
// the selected pixels, *wts their weights. False: fewer than 16 pixels left.
bool WeighPixelsByFirstFit(Problem* p, const std::vector<double>& g_start,
                           std::vector<double>* wts) {
  const int nk = p->nk;
  std::vector<int> keep;
  std::vector<double> rel, sig2;
  const std::vector<double> zero(nk, 0.0);
  // Per pixel on the pool (NaN: not kept), then collected in pixel order.
  const int n_cand = static_cast<int>(p->pix.size());
  std::vector<double> rel_of(n_cand, kNaN), s2_of(n_cand, kNaN);
  tbb::parallel_for<int64_t>(0, (n_cand + kBlockPixels - 1) / kBlockPixels, [&](int64_t blk) {
    std::vector<double> ct(nk), st(nk);
    const int q_end = std::min(n_cand, static_cast<int>(blk + 1) * kBlockPixels);
    for (int q = static_cast<int>(blk) * kBlockPixels; q < q_end; ++q) {
      const int j = p->pix[q];
      Eigen::Vector3d c;
      double ssr;
      PixelTrig(*p, j, zero, ct.data(), st.data(), true);
      if (!SolvePixel(*p, j, g_start, ct.data(), st.data(), &c, &ssr)) continue;
      const double amp = std::hypot(c(1), c(2));
      const double s2 = ssr / (nk - 3);
      // Only profiles whose sinusoid stands out of the noise carry the frame parameters.
      if (!(amp > 1e-5 * std::abs(c(0))) || !(amp > 2.0 * std::sqrt(s2 * 2.0 / nk))) continue;
      rel_of[q] = std::sqrt(s2) / amp;
      s2_of[q] = s2;
    }
  });
  for (int q = 0; q < n_cand; ++q) {
    if (std::isnan(s2_of[q])) continue;
    keep.push_back(p->pix[q]);
    rel.push_back(rel_of[q]);
    sig2.push_back(s2_of[q]);
  }
  if (keep.size() < 16) return false;
  const double med = Median(rel);
  std::vector<double> dev(rel.size());
  for (size_t q = 0; q < rel.size(); ++q) dev[q] = std::abs(rel[q] - med);
  const double mad = kMadToSigma * Median(dev);
  const double s2_floor = 1e-3 * Median(sig2) + 1e-30;
  p->pix.clear();
  for (size_t q = 0; q < keep.size(); ++q)
    if (rel[q] <= med + 4 * mad) {
      p->pix.push_back(keep[q]);
      wts->push_back(1.0 / std::max(sig2[q], s2_floor));
    }
  return p->pix.size() >= 16;
}

double MedianFrequency(const Problem& p) {
  std::vector<double> fs;
  for (int j : p.pix) fs.push_back(p.freq[j]);
  return Median(fs);
}

// The weighted objective sum_j w_j SSR_j at (g, delta) (infinite where a pixel cannot be solved).
double Objective(const Fit& fit, const std::vector<double>& gg, const std::vector<double>& dd) {
  const Problem& p = fit.p;
  const int nk = p.nk;
  const bool dz = AllZero(dd);
  std::vector<double> partial(fit.n_blocks, 0.0);
  tbb::parallel_for<int64_t>(0, fit.n_blocks, [&](int64_t blk) {
    std::vector<double> ct(nk), st(nk);
    double total = 0;
    const int q_end = std::min(fit.n_pix, static_cast<int>(blk + 1) * kBlockPixels);
    for (int q = static_cast<int>(blk) * kBlockPixels; q < q_end; ++q) {
      Eigen::Vector3d c;
      double ssr;
      PixelTrig(p, p.pix[q], dd, ct.data(), st.data(), dz);
      if (!SolvePixel(p, p.pix[q], gg, ct.data(), st.data(), &c, &ssr)) {
        total = std::numeric_limits<double>::infinity();
        break;
      }
      total += fit.wts[q] * ssr;
    }
    partial[blk] = total;
  });
  double total = 0;
  for (double v : partial) total += v;
  return total;
}

// Which parameter blocks a Gauss-Newton run frees; freeze_in_band keeps the gains' components
// along cos / sin(2 pi f x) (weighted by g) where they are.
struct FreeParameters {
  bool gains;
  bool positions;
  bool freeze_in_band;
  int ng() const { return gains ? static_cast<int>(nk) : 0; }
  int nd() const { return positions ? static_cast<int>(nk) : 0; }
  int nk;
};

// The reduced normal equations S step = rhs of the frame parameters at (g, delta): the per-pixel
// coefficients eliminated by their Schur complements (the lower triangle summed per block of
// pixels, in block order, then mirrored).
void ReducedNormalEquations(const Fit& fit, const FreeParameters& free,
                            const std::vector<double>& g, const std::vector<double>& delta,
                            Eigen::MatrixXd* S_out, Eigen::VectorXd* rhs_out) {
  const Problem& p = fit.p;
  const int nk = p.nk, ng = free.ng(), P = ng + free.nd();
  const bool est_gain = free.gains, est_pos = free.positions;
  // Per block of pixels: the diagonal-block part of S and rhs, and the pixels' Schur
  // complement terms sqrt(w) L^-1 F^T stacked (3 rows per pixel) for one product per block.
  struct Partial {
    Eigen::MatrixXd S;
    Eigen::VectorXd rhs;
  };
  std::vector<Partial> partials(fit.n_blocks);
  const bool dz = AllZero(delta);
  tbb::parallel_for<int64_t>(0, fit.n_blocks, [&](int64_t blk) {
    Partial& part = partials[blk];
    part.S.setZero(P, P);
    part.rhs.setZero(P);
    const int q0 = static_cast<int>(blk) * kBlockPixels;
    const int q_end = std::min(fit.n_pix, q0 + kBlockPixels);
    Eigen::MatrixXd G(3 * (q_end - q0), P);
    G.setZero();
    Eigen::MatrixXd F(P, 3);
    std::vector<double> ct(nk), st(nk);
    for (int q = q0; q < q_end; ++q) {
      const int j = p.pix[q];
      Eigen::Vector3d c;
      double ssr;
      PixelTrig(p, j, delta, ct.data(), st.data(), dz);
      // Hcc, the pixel's block (sum D D^T): SolvePixel's normal matrix, factored there.
      Eigen::LLT<Eigen::Matrix3d> llt;
      if (!SolvePixel(p, j, g, ct.data(), st.data(), &c, &ssr, &llt)) continue;
      const double wq = fit.wts[q], om = 2 * kPi * p.freq[j];
      const float* I = p.s.data() + static_cast<size_t>(j) * nk;
      F.setZero();
      for (int k = 0; k < nk; ++k) {
        const Eigen::Vector3d D(g[k], g[k] * ct[k], g[k] * st[k]);
        const double m = c(0) + c(1) * ct[k] + c(2) * st[k];
        const double r = I[k] - g[k] * m;
        const double Jd = g[k] * om * (-c(1) * st[k] + c(2) * ct[k]);
        if (est_gain) {
          part.S(k, k) += wq * m * m;
          part.rhs(k) += wq * m * r;
          F.row(k) = m * D.transpose();
        }
        if (est_pos) {
          part.S(ng + k, ng + k) += wq * Jd * Jd;
          part.rhs(ng + k) += wq * Jd * r;
          F.row(ng + k) = Jd * D.transpose();
        }
        if (est_gain && est_pos) {
          part.S(ng + k, k) += wq * m * Jd;
          part.S(k, ng + k) += wq * m * Jd;
        }
      }
      // Schur complement of the pixel's block: S -= w F Hcc^-1 F^T = (sqrt(w) L^-1 F^T)^T (..).
      G.middleRows(3 * (q - q0), 3) = std::sqrt(wq) * llt.matrixL().solve(F.transpose());  // 3 x P
    }
    // Lower triangle only (S is symmetric; the sparse terms above fill both halves).
    part.S.selfadjointView<Eigen::Lower>().rankUpdate(G.transpose(), -1.0);
  });
  Eigen::MatrixXd& S = *S_out;
  Eigen::VectorXd& rhs = *rhs_out;
  S.setZero(P, P);
  rhs.setZero(P);
  for (const Partial& part : partials) {
    S += part.S;
    rhs += part.rhs;
  }
  S.triangularView<Eigen::StrictlyUpper>() = S.transpose();
}

void AddPenalty(Eigen::MatrixXd* S, Eigen::VectorXd u, double weight) {
  if (u.norm() > 0) u.normalize();
  *S += weight * u * u.transpose();
}

// The gauges (mean gain, positions along {1, x}) and the frozen in-band gain directions as
// penalties on S, scaled by its mean diagonal; then a relative ridge of 1e-9.
void PenaliseGauges(const Fit& fit, const FreeParameters& free, const std::vector<double>& g,
                    Eigen::MatrixXd* S) {
  const int nk = fit.p.nk, ng = free.ng(), P = ng + free.nd();
  const std::vector<double>& x = fit.p.x;
  const double lam = S->diagonal().cwiseAbs().mean() + 1e-300;
  if (free.gains) {
    Eigen::VectorXd u = Eigen::VectorXd::Zero(P);
    for (int k = 0; k < nk; ++k) u(k) = g[k];
    AddPenalty(S, u, 1.0 * lam);
    if (free.freeze_in_band) {
      Eigen::VectorXd uc = Eigen::VectorXd::Zero(P), us = Eigen::VectorXd::Zero(P);
      for (int k = 0; k < nk; ++k) {
        uc(k) = g[k] * std::cos(2 * kPi * fit.f_mid * x[k]);
        us(k) = g[k] * std::sin(2 * kPi * fit.f_mid * x[k]);
      }
      AddPenalty(S, uc, 1e6 * lam);
      AddPenalty(S, us, 1e6 * lam);
    }
  }
  if (free.positions) {
    Eigen::VectorXd u0 = Eigen::VectorXd::Zero(P), u1 = Eigen::VectorXd::Zero(P);
    for (int k = 0; k < nk; ++k) {
      u0(ng + k) = 1.0;
      u1(ng + k) = x[k];
    }
    AddPenalty(S, u0, 1.0 * lam);
    AddPenalty(S, u1, 1.0 * lam);
  }
  S->diagonal() *= 1.0 + 1e-9;
}

// Steps (g, delta) along `step`, halving it until the objective does not increase (at most 6
// tries). Returns false where no try was accepted; otherwise updates (g, delta, *current) and
// *converged.
bool LineSearch(const Fit& fit, const FreeParameters& free, const Eigen::VectorXd& step,
                double drop, std::vector<double>* g, std::vector<double>* delta, double* current,
                bool* converged) {
  const int nk = fit.p.nk, ng = free.ng(), nd = free.nd();
  double t = 1.0;
  for (int tries = 0; tries < 6; ++tries, t *= 0.5) {
    std::vector<double> g2 = *g, d2 = *delta;
    for (int k = 0; k < ng; ++k) g2[k] += t * step(k);
    for (int k = 0; k < nd; ++k) d2[k] += t * step(ng + k);
    if (free.gains) {
      const double mean = std::accumulate(g2.begin(), g2.end(), 0.0) / nk;
      if (!(mean > 0)) continue;
      for (double& v : g2) v /= mean;
    }
    if (free.positions) ProjectAffine(&d2, fit.p.x);
    const double c2 = Objective(fit, g2, d2);
    if (c2 <= *current) {
      const double rel_change = (*current - c2) / std::max(*current, 1e-300);
      // The objective is a chi^2 (weights 1 / sigma_j^2): a drop below 0.5 is no
      // information, and Gauss-Newton crawls from there (measured: 0.4-0.6 per iteration
      // after the first on the coin and the tilted bar). A full step whose drop the
      // quadratic model predicted to within 0.5 leaves less than that to the next (on the
      // coin: 4993.80 against 4993.51 predicted, then 1e-4 predicted for the next).
      *converged = rel_change < 1e-9 || *current - c2 < 0.5 ||
                   (tries == 0 && std::abs(*current - c2 - drop) < 0.5);
      *g = std::move(g2);
      *delta = std::move(d2);
      *current = c2;
      return true;
    }
  }
  return false;
}

// Gauss-Newton from (g, delta) with the given parameter blocks free. Returns the objective;
// *iters += the iterations spent. `start`: the objective at (g, delta) if known (NaN: computed).
// A first step after which the objective is predicted to stay above stop_above (even with 1.25
// times the predicted drop, plus 1) is not taken: (g, delta) stay, and *predicted receives the
// objective predicted after it.
double GaussNewton(const Fit& fit, const FreeParameters& free, int max_iterations,
                   std::vector<double>* g, std::vector<double>* delta, int* iters,
                   double start = kNaN, double stop_above = kNaN, double* predicted = nullptr) {
  double current = std::isnan(start) ? Objective(fit, *g, *delta) : start;
  if (!std::isfinite(current)) return current;
  Eigen::MatrixXd S;
  Eigen::VectorXd rhs;
  int it = 0;
  bool converged = false;
  for (; it < std::max(1, max_iterations) && !converged; ++it) {
    ReducedNormalEquations(fit, free, *g, *delta, &S, &rhs);
    PenaliseGauges(fit, free, *g, &S);
    const Eigen::VectorXd step = S.ldlt().solve(rhs);
    if (!step.allFinite()) break;
    // The quadratic model's drop, rhs . S^-1 rhs (the objective is a weighted sum of squares:
    // S = J^T W J with the gauge penalties, rhs = J^T W r).
    const double drop = step.dot(rhs);
    if (it == 0 && current - (1.25 * drop + 1.0) > stop_above) {
      if (predicted) *predicted = current - drop;
      ++it;
      break;
    }
    if (!LineSearch(fit, free, step, drop, g, delta, &current, &converged)) break;
  }
  *iters += it;
  return current;
}

// The phase-shift reference per p.pix entry (phase NaN / variance 0: none), and the nuisance
// columns it brings.
struct Reference {
  const PhaseConstraint* constraint = nullptr;
  std::vector<double> phase, var;
  int n_valid = 0;
  int n_nuisance = 0;
};

constexpr int kMinReferencePixels = 200;

Reference ReferenceAtPixels(const PhaseConstraint* reference, bool estimate_gains,
                            const Problem& p) {
  Reference ref;
  ref.constraint = reference;
  const size_t n = p.freq.size();
  if (reference && estimate_gains && reference->phase.size() == n && reference->sigma.size() == n) {
    for (size_t q = 0; q < p.pix.size(); ++q) {
      const double ph = reference->phase[p.pix[q]], sg = reference->sigma[p.pix[q]];
      const bool ok = std::isfinite(ph) && std::isfinite(sg) && sg > 0;
      ref.phase.push_back(ok ? ph : std::numeric_limits<double>::quiet_NaN());
      ref.var.push_back(ok ? sg * sg : 0.0);
      ref.n_valid += ok;
    }
  }
  ref.n_nuisance = (reference && reference->nuisance_per_pixel > 0 &&
                    reference->nuisance.size() == n * reference->nuisance_per_pixel)
                       ? reference->nuisance_per_pixel
                       : 0;
  return ref;
}

bool ReferenceUsable(const Reference& ref) {
  return ref.n_valid >= kMinReferencePixels + 10 * ref.n_nuisance;
}

// The in-band figures of FrameCorrections.
struct InBand {
  int pixels = 0;
  double correction[2] = {0.0, 0.0};
  double sigma = 0.0;
  double shrink = 0.0;
};

InBand InBandOf(const FrameCorrections& fc) {
  InBand b;
  b.pixels = fc.in_band_pixels;
  b.correction[0] = fc.in_band_correction[0];
  b.correction[1] = fc.in_band_correction[1];
  b.sigma = fc.in_band_sigma;
  b.shrink = fc.in_band_shrink;
  return b;
}

void SetInBand(const InBand& b, FrameCorrections* fc) {
  fc->in_band_pixels = b.pixels;
  fc->in_band_correction[0] = b.correction[0];
  fc->in_band_correction[1] = b.correction[1];
  fc->in_band_sigma = b.sigma;
  fc->in_band_shrink = b.shrink;
}

// Per pixel: r = phi - ref (wrapped), J = d phi / d eps, weight 1 / (var_ls + var_ref).
struct ReferenceRow {
  double r, j1, j2, w;
};

// The rows of the in-band fit at (gg, dd): the phases' derivatives by refitting with the gains
// multiplied by 1 + h b1 and 1 + h b2 (g1, g2). NaN r: no row.
std::vector<ReferenceRow> ReferenceRows(const Fit& fit, const Reference& ref,
                                        const std::vector<double>& gg,
                                        const std::vector<double>& g1,
                                        const std::vector<double>& g2,
                                        const std::vector<double>& dd, double h) {
  const Problem& p = fit.p;
  const int nk = p.nk;
  std::vector<ReferenceRow> rows(fit.n_pix,
                                 ReferenceRow{std::numeric_limits<double>::quiet_NaN(), 0, 0, 0});
  const bool dz = AllZero(dd);
  tbb::parallel_for<int64_t>(0, fit.n_blocks, [&](int64_t blk) {
    std::vector<double> ct(nk), st(nk);
    const int q_end = std::min(fit.n_pix, static_cast<int>(blk + 1) * kBlockPixels);
    for (int q = static_cast<int>(blk) * kBlockPixels; q < q_end; ++q) {
      if (!std::isfinite(ref.phase[q])) continue;
      const int j = p.pix[q];
      PixelTrig(p, j, dd, ct.data(), st.data(), dz);
      Eigen::Vector3d c0, c1, c2;
      double ssr, ssr1, ssr2;
      if (!SolvePixel(p, j, gg, ct.data(), st.data(), &c0, &ssr) ||
          !SolvePixel(p, j, g1, ct.data(), st.data(), &c1, &ssr1) ||
          !SolvePixel(p, j, g2, ct.data(), st.data(), &c2, &ssr2))
        continue;
      const double a = std::hypot(c0(1), c0(2));
      if (!(a > 0)) continue;
      // I = d + alpha cos + beta sin = d + a sin(phi + theta): phi = atan2(alpha, beta).
      const double ph0 = std::atan2(c0(1), c0(2));
      const double var_ls = 2.0 * ssr / (nk - 3) / (nk * a * a);
      rows[q] = {std::remainder(ph0 - ref.phase[q], 2 * kPi),
                 std::remainder(std::atan2(c1(1), c1(2)) - ph0, 2 * kPi) / h,
                 std::remainder(std::atan2(c2(1), c2(2)) - ph0, 2 * kPi) / h,
                 1.0 / (var_ls + ref.var[q])};
    }
  });
  return rows;
}

// The constant between the two cues: the circular mean of the residuals, removed from them.
// Returns the standardised residuals |r| sqrt(w) (empty where the mean is undefined).
std::vector<double> RemoveConstantOffset(std::vector<ReferenceRow>* rows, bool* ok) {
  double sr = 0, si = 0;
  for (const ReferenceRow& row : *rows)
    if (std::isfinite(row.r)) {
      sr += row.w * std::cos(row.r);
      si += row.w * std::sin(row.r);
    }
  std::vector<double> z;
  *ok = std::hypot(sr, si) > 0;
  if (!*ok) return z;
  const double c0 = std::atan2(si, sr);
  for (ReferenceRow& row : *rows)
    if (std::isfinite(row.r)) {
      row.r = std::remainder(row.r - c0, 2 * kPi);
      z.push_back(std::abs(row.r) * std::sqrt(row.w));
    }
  return z;
}

// The weighted least-squares solution of (c, eps_c, eps_s, nuisance) over the rows within
// `limit`, with its inverse information matrix and the residuals' scatter.
struct InBandSolution {
  Eigen::VectorXd sol;
  Eigen::MatrixXd info_inv;
  double scatter = 0.0;
  int used = 0;
};

bool SolveInBand(const Fit& fit, const Reference& ref, const std::vector<ReferenceRow>& rows,
                 double limit, InBandSolution* out) {
  const int n_nuis = ref.n_nuisance;
  // Normal equations of (c, eps_c, eps_s) and the phase-shift gain nuisance.
  const int nv = 3 + n_nuis;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(nv, nv);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(nv);
  Eigen::VectorXd J(nv);
  int used = 0;
  double r2 = 0;  // weighted sum of squares before the fit
  for (int q = 0; q < fit.n_pix; ++q) {
    const ReferenceRow& row = rows[q];
    if (!std::isfinite(row.r) || std::abs(row.r) * std::sqrt(row.w) > limit) continue;
    J(0) = 1.0;
    J(1) = row.j1;
    J(2) = row.j2;
    const float* nu = ref.constraint->nuisance.data() + static_cast<size_t>(fit.p.pix[q]) * n_nuis;
    for (int m = 0; m < n_nuis; ++m) J(3 + m) = nu[m];
    A.selfadjointView<Eigen::Lower>().rankUpdate(J, row.w);
    rhs -= row.w * row.r * J;
    r2 += row.w * row.r * row.r;
    ++used;
  }
  if (used < kMinReferencePixels + 10 * n_nuis) return false;
  A.triangularView<Eigen::StrictlyUpper>() = A.transpose();
  A.diagonal() *= 1.0 + 1e-12;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(A);
  const Eigen::VectorXd sol = ldlt.solve(rhs);
  if (ldlt.info() != Eigen::Success || !sol.allFinite()) return false;
  // Standard error of the gain components, with the residuals' own scale (chi^2 after the
  // fit = before - sol . rhs).
  const double chi2 = std::max(0.0, r2 - sol.dot(rhs));
  out->scatter = chi2 / std::max(1, used - nv);  // ~1 where the weights are right
  out->info_inv = ldlt.solve(Eigen::MatrixXd::Identity(nv, nv));
  out->sol = sol;
  out->used = used;
  return true;
}

// Shrinkage towards the start. Where the start's in-band gains are right the estimate is
// noise alone, and applying it adds that noise to every pixel's phase (times d / a): on a
// 24x18 view of the tilted bar without jitter 1.39-1.44 um against 1.02-1.08 um with the
// start kept. The posterior mean under a normal prior of variance tau^2 per component is
// k eps with k = tau^2 / (tau^2 + sigma^2), tau^2 the larger of two estimates:
//  - white jitter: the start gains' spread s^2 (out of band, where the start is an estimate)
//    predicts s^2 / sum_k b_k^2 per in-band component;
//  - from the estimate itself (a drift that is not white): z2 = eps^T C^-1 eps is chi^2 with
//    2 degrees of freedom where eps = 0, so (z2 - 2) / 2 sigma^2 estimates tau^2 by moments,
//    k = 1 - 2 / z2 (0 below z2 = 2).
double InBandShrinkage(const InBandSolution& s, const std::vector<double>& gg,
                       const std::vector<double>& b1, const std::vector<double>& b2) {
  const int nk = static_cast<int>(gg.size());
  // The estimate's noise from the residuals' own scatter, also where it is below what the
  // weights assume (they take 1% of the level per sample: noise-free data would otherwise
  // shrink an accurate estimate).
  const Eigen::Matrix2d C = s.info_inv.block<2, 2>(1, 1) * s.scatter;
  const Eigen::Vector2d e(s.sol(1), s.sol(2));
  const Eigen::LDLT<Eigen::Matrix2d> cl(C);
  const double z2 = cl.info() == Eigen::Success ? e.dot(cl.solve(e)) : 0.0;
  const double k_moments = std::isfinite(z2) && z2 > 2.0 ? 1.0 - 2.0 / z2 : 0.0;
  double s2 = 0, bb = 0;
  for (int k = 0; k < nk; ++k) {
    s2 += (gg[k] - 1) * (gg[k] - 1);
    bb += 0.5 * (b1[k] * b1[k] + b2[k] * b2[k]);
  }
  s2 /= std::max(1, nk - 3);  // mean gauge and the two in-band components
  const double tau2 = s2 / std::max(bb, 1e-300), sig2 = 0.5 * C.trace();
  const double k_white = tau2 > 0 && sig2 >= 0 ? tau2 / (tau2 + sig2) : 0.0;
  return std::max(k_moments, std::isfinite(k_white) ? k_white : 0.0);
}

// The in-band gain components from the phase-shift reference: with the per-pixel fits at the
// current (g, delta), the lens-shift phase of pixel j is phi_j = ref_j + c + noise where the
// gains are right (c: the constant between the two cues, e.g. the shifter's zero). An in-band
// gain error moves phi_j by (d_j / a_j) times a sinusoid of phi_j, which no constant
// absorbs: weighted least squares for (c, eps_c, eps_s) with the gains multiplied by
// 1 + eps_c cos(2 pi f_mid x) + eps_s sin(2 pi f_mid x), the phases' derivatives taken per
// pixel by refitting (exact for any frequency and sampling). Frame means are biased by the
// stripes left in the view's average, this is not. Corrects *g_io and fills *in_band; returns
// false where it cannot run.
bool InBandGainsFromReference(const Fit& fit, const Reference& ref, bool shrink_in_band_gains,
                              const std::vector<double>& dd, std::vector<double>* g_io,
                              InBand* in_band) {
  std::vector<double>& gg = *g_io;
  const int nk = fit.p.nk;
  const std::vector<double>& x = fit.p.x;
  constexpr double h = 1e-3;
  std::vector<double> b1(nk), b2(nk);
  for (int k = 0; k < nk; ++k) {
    b1[k] = std::cos(2 * kPi * fit.f_mid * x[k]);
    b2[k] = std::sin(2 * kPi * fit.f_mid * x[k]);
  }
  std::vector<double> g1(nk), g2(nk);
  for (int k = 0; k < nk; ++k) {
    g1[k] = gg[k] * (1 + h * b1[k]);
    g2[k] = gg[k] * (1 + h * b2[k]);
  }
  std::vector<ReferenceRow> rows = ReferenceRows(fit, ref, gg, g1, g2, dd, h);
  bool has_offset = false;
  const std::vector<double> z = RemoveConstantOffset(&rows, &has_offset);
  if (!has_offset) return false;
  if (static_cast<int>(z.size()) < kMinReferencePixels) return false;
  const double limit = 4.0 * kMadToSigma * Median(z);
  InBandSolution s;
  if (!SolveInBand(fit, ref, rows, limit, &s)) return false;
  const Eigen::MatrixXd cov = s.info_inv * std::max(1.0, s.scatter);
  const double shrink = shrink_in_band_gains ? InBandShrinkage(s, gg, b1, b2) : 1.0;
  for (int k = 0; k < nk; ++k) gg[k] *= 1 + shrink * (s.sol(1) * b1[k] + s.sol(2) * b2[k]);
  const double mean = std::accumulate(gg.begin(), gg.end(), 0.0) / nk;
  for (double& v : gg) v /= mean;
  in_band->pixels = s.used;
  in_band->correction[0] = shrink * s.sol(1);
  in_band->correction[1] = shrink * s.sol(2);
  in_band->shrink = shrink;
  in_band->sigma = std::sqrt(0.5 * (cov(1, 1) + cov(2, 2)));
  return true;
}

double Rms(const std::vector<double>& v) {
  double s2 = 0;
  for (double e : v) s2 += e * e;
  return std::sqrt(s2 / static_cast<int>(v.size()));
}

// Model B (positions added to model A's gains) against model A at objective c_a. From A's
// solution (with a reference) B's first Gauss-Newton step predicts the drop it can reach (a
// score test): the model is linear in the gains and nearly so in positions of a few mpx
// (measured on the coin: 56.159 predicted, 56.165 after two iterations). Where even 1.25 times
// that drop leaves B short of `needed`, B would be rejected: it stops there (about half the
// estimate's time on a capture without position errors). Without a reference B starts from
// g_start, and its drop mixes the gains' with the positions'. Where B is chosen, (g, delta)
// become its solution; out receives the model's figures.
void ChoosePositionModel(const Fit& fit, const FrameCorrectionOptions& options, bool use_reference,
                         const std::vector<double>& g_start, double c_a, std::vector<double>* g,
                         std::vector<double>* delta, int* it, FrameCorrections* out) {
  const int nk = fit.p.nk;
  const bool est_g = options.estimate_gains;
  const InBand after_a = InBandOf(*out);  // the in-band figures of model A
  std::vector<double> gb = use_reference ? *g : g_start, db(nk, 0.0);
  const double dof = std::max(1, nk - 4);
  const double needed = dof + 6 * std::sqrt(2 * dof);  // the drop that makes B the model
  double predicted = kNaN;
  const bool stop = use_reference && options.stop_position_model_early;
  const double c_b =
      GaussNewton(fit, FreeParameters{est_g, true, est_g, nk}, options.iterations, &gb, &db, it,
                  use_reference ? c_a : kNaN, stop ? c_a - needed : kNaN, &predicted);
  const bool stopped = !std::isnan(predicted);
  out->position_model_stopped = stopped;
  out->position_chi2_gain = stopped ? c_a - predicted : std::isfinite(c_b) ? c_a - c_b : 0.0;
  const bool relevant = Rms(db) >= options.min_position_rms_px;
  if (!stopped && std::isfinite(c_b) && relevant && (!est_g || c_a - c_b > needed)) {
    *g = std::move(gb);
    *delta = std::move(db);
    out->model =
        est_g ? (use_reference ? "gains+reference+positions" : "gains+positions") : "positions";
  } else {
    SetInBand(after_a, out);
  }
}

bool WithinLimits(const std::vector<double>& g, const std::vector<double>& delta,
                  const FrameCorrectionOptions& options) {
  for (size_t k = 0; k < g.size(); ++k) {
    if (!std::isfinite(g[k]) || std::abs(g[k] - 1.0) > options.max_gain_deviation ||
        !std::isfinite(delta[k]) || std::abs(delta[k]) > options.max_position_error_px)
      return false;
  }
  return true;
}

}  // namespace

// In-band gain jitter and in-band position errors put the same 2 f signature into the profiles
// (a sin(phi + th) * E cos(th + psi) and a cos(phi + th) * E sin(th + psi) differ by a per-pixel
// constant only), so they cannot be told apart from the data. Model A: gains only (all
// components; unbiased when the shifter is exact), their in-band components from the
// phase-shift reference where there is one. Model B: positions, with the in-band gains kept at
// their start. B is chosen when it explains significantly more than A (the out-of-band position
// errors, which nothing else mimics, make the difference).
FrameCorrections EstimateFrameCorrections(const std::vector<float>& samples, int nk,
                                          const std::vector<double>& freq,
                                          const std::vector<double>& x,
                                          const std::vector<double>& initial_gains,
                                          const FrameCorrectionOptions& options,
                                          const PhaseConstraint* reference) {
  FrameCorrections out;
  out.gains = initial_gains;
  out.positions_px.assign(std::max(nk, 0), 0.0);
  if (!UsableInputs(samples, nk, freq, x, initial_gains)) return out;
  const bool est_g = options.estimate_gains, est_d = options.estimate_positions;
  if (!est_g && !est_d) return out;
  if (!PositiveFinite(initial_gains)) return out;

  Problem p{samples, nk, freq, x, SubsamplePixels(samples, nk, freq, options.max_pixels), {}};
  if (p.pix.size() < 16) return out;
  p.trig0 = ZeroPositionTrig(p);
  const std::vector<double> g_start = MeanOne(initial_gains);
  std::vector<double> wts;
  if (!WeighPixelsByFirstFit(&p, g_start, &wts)) return out;
  const int n_pix = static_cast<int>(p.pix.size());
  const Fit fit{p, wts, n_pix, (n_pix + kBlockPixels - 1) / kBlockPixels, MedianFrequency(p)};
  const Reference ref = ReferenceAtPixels(reference, est_g, p);
  const bool use_reference = ReferenceUsable(ref);

  // Model A: the gains.
  int it = 0;
  std::vector<double> g = g_start, delta(nk, 0.0);
  double c_a = Objective(fit, g, delta);
  if (est_g) {
    InBand in_band;
    if (use_reference) {
      if (!InBandGainsFromReference(fit, ref, options.shrink_in_band_gains, delta, &g, &in_band))
        return out;
      SetInBand(in_band, &out);
    }
    const FreeParameters gains_only{true, false, use_reference || options.freeze_in_band_gains, nk};
    c_a = GaussNewton(fit, gains_only, options.iterations, &g, &delta, &it);
  }
  if (!std::isfinite(c_a)) return out;
  out.model = use_reference ? "gains+reference" : "gains";
  // Model B: the positions, where they explain significantly more.
  if (est_d) ChoosePositionModel(fit, options, use_reference, g_start, c_a, &g, &delta, &it, &out);

  if (!WithinLimits(g, delta, options)) return out;
  out.gains = g;
  out.positions_px = delta;
  out.position_rms_px = Rms(delta);
  out.pixels_used = n_pix;
  out.iterations = it;
  out.valid = true;
  return out;
}

FrameCorrections EstimateFrameCorrections(const FrameStack& stack, const std::vector<int>& frames,
                                          const std::vector<uint32_t>& pixels,
                                          const FrequencyAt& f_map, const std::vector<double>& x,
                                          const std::vector<double>& initial_gains,
                                          const FrameCorrectionOptions& options,
                                          const PhaseConstraint* reference,
                                          const GatheredSamples* gathered) {
  const int nk = static_cast<int>(frames.size());
  const size_t stride = std::max<size_t>(1, pixels.size() / std::max(16, options.max_pixels));
  if (gathered && (stack.is_float() || gathered->pixels != pixels || !gathered->Complete(frames)))
    gathered = nullptr;
  PhaseConstraint sub;
  const bool with_ref =
      reference && reference->phase.size() == pixels.size() &&
      reference->sigma.size() == pixels.size() &&
      reference->nuisance.size() == pixels.size() * std::max(0, reference->nuisance_per_pixel);
  if (with_ref) sub.nuisance_per_pixel = reference->nuisance_per_pixel;
  std::vector<uint32_t> used;  // the pixels taken
  std::vector<size_t> from;    // and their entries in `pixels`
  std::vector<double> freq;
  for (size_t q = 0; q < pixels.size(); q += stride) {
    const uint32_t i = pixels[q];
    used.push_back(i);
    from.push_back(q);
    freq.push_back(f_map(i));
    if (with_ref) {
      sub.phase.push_back(reference->phase[q]);
      sub.sigma.push_back(reference->sigma[q]);
      const int m = reference->nuisance_per_pixel;
      if (m > 0)
        sub.nuisance.insert(sub.nuisance.end(), reference->nuisance.begin() + q * m,
                            reference->nuisance.begin() + (q + 1) * m);
    }
  }
  // The samples, pixel-major: gathered frame by frame (in parallel; one frame's samples at
  // increasing pixels, not one cache miss per sample), then transposed.
  const size_t n = used.size();
  std::vector<float> by_frame(n * static_cast<size_t>(nk));
  tbb::parallel_for<int64_t>(0, nk, [&](int64_t k) {
    float* dst = by_frame.data() + static_cast<size_t>(k) * n;
    if (gathered) {
      const std::vector<uint16_t>& codes = gathered->codes[frames[k]];
      for (size_t q = 0; q < n; ++q) dst[q] = stack.Linear(codes[from[q]]);
    } else {
      for (size_t q = 0; q < n; ++q) dst[q] = stack.Value(frames[k], used[q]);
    }
  });
  std::vector<float> samples(n * static_cast<size_t>(nk));
  for (size_t q = 0; q < n; ++q)
    for (int k = 0; k < nk; ++k) samples[q * nk + k] = by_frame[static_cast<size_t>(k) * n + q];
  return EstimateFrameCorrections(samples, nk, freq, x, initial_gains, options,
                                  with_ref ? &sub : nullptr);
}

}  // namespace mesoscan

namespace mesoscan {

std::vector<double> FrameMeanGains(const FrameStack& stack, const std::vector<int>& frames,
                                   const std::vector<uint32_t>& pixels) {
  std::vector<double> g;
  double total = 0;
  for (int k : frames) {
    double m = 0;
    for (uint32_t i : pixels) m += stack.Value(k, i);
    g.push_back(m);
    total += m;
  }
  bool ok = total > 0 && std::isfinite(total);
  for (double& v : g) {
    v *= static_cast<double>(frames.size()) / total;
    ok = ok && v > 0 && std::isfinite(v);
  }
  if (!ok) g.clear();
  return g;
}

FrameCorrections CorrectLensShiftFrames(const FrameStack& stack, const std::vector<int>& frames,
                                        const FirstPassFits& first, const FrequencyAt& f_map,
                                        std::vector<double>* x, std::vector<float>* inv_gain,
                                        const FrameCorrectionOptions& options,
                                        const PhaseReference* reference) {
  if (reference && !reference->empty() && options.method == FrameGainMethod::kJoint &&
      options.estimate_gains) {
    // The phase-shift reference makes every gain component identifiable: no frame means (and
    // their gate) needed. Its pixels, where the frequency map is defined.
    std::vector<uint32_t> pixels;
    PhaseConstraint pc;
    const double centre = reference->ls_centre_px;
    for (size_t q = 0; q < reference->pixels.size(); ++q) {
      const uint32_t i = reference->pixels[q];
      if (i >= stack.pixels()) continue;
      const float fi = f_map(i);
      if (!std::isfinite(fi)) continue;
      pixels.push_back(i);
      // Shift 0: pi/2 - pi u (stage_combine.cc); the fit's x = 0 is the range's centre.
      pc.phase.push_back(kPi / 2 - kPi * reference->u_px[q] + 2 * kPi * fi * centre);
      pc.sigma.push_back(kPi * reference->sigma_u_px[q]);
      const int m = reference->nuisance_per_pixel;
      if (m > 0 && reference->nuisance.size() == reference->pixels.size() * m)
        pc.nuisance.insert(pc.nuisance.end(), reference->nuisance.begin() + q * m,
                           reference->nuisance.begin() + (q + 1) * m);
    }
    pc.nuisance_per_pixel =
        pc.nuisance.size() == pc.phase.size() * reference->nuisance_per_pixel && !pc.phase.empty()
            ? reference->nuisance_per_pixel
            : 0;
    if (pc.nuisance_per_pixel == 0) pc.nuisance.clear();
    std::vector<double> g0;
    for (int k : frames) g0.push_back(1.0 / (*inv_gain)[k]);
    // The samples the stream stage gathered, where every reference pixel is taken.
    const GatheredSamples* gathered =
        pixels.size() == reference->pixels.size() ? &reference->samples : nullptr;
    FrameCorrections fc =
        EstimateFrameCorrections(stack, frames, pixels, f_map, *x, g0, options, &pc, gathered);
    if (fc.in_band_pixels > 0) {  // else (too few reference pixels): as without a reference
      if (fc.valid) {
        for (size_t k = 0; k < frames.size(); ++k) {
          (*inv_gain)[frames[k]] = static_cast<float>(1.0 / fc.gains[k]);
          (*x)[k] += fc.positions_px[k];
        }
      }
      return fc;
    }
  }
  std::vector<uint32_t> pixels, entries;  // and their entries in `first`
  for (size_t q = 0; q < first.pixels.size(); ++q)
    if (first.pixels[q] < stack.pixels() && std::isfinite(f_map(first.pixels[q]))) {
      pixels.push_back(first.pixels[q]);
      entries.push_back(static_cast<uint32_t>(q));
    }
  std::vector<double> g0;
  for (int k : frames) g0.push_back(1.0 / (*inv_gain)[k]);
  if (options.method == FrameGainMethod::kAlternating) return {};
  // Frame means are unbiased only where the view's stripes average out: the residual sinusoid
  // of the view relative to its mean level, |sum a e^{i phi}| / sum d over the first-pass fits.
  double residual_stripe = 0.0;
  if (!first.amplitude.empty()) {
    double re = 0, im = 0, dsum = 0;
    for (uint32_t q : entries) {
      const double a = first.amplitude[q], ph = first.phase[q], d = first.offset[q];
      if (!std::isfinite(a) || !std::isfinite(ph) || !std::isfinite(d)) continue;
      re += a * std::cos(ph);
      im += a * std::sin(ph);
      dsum += d;
    }
    residual_stripe = dsum > 0 ? std::hypot(re, im) / dsum : 1.0;
  }
  // Frame means over the fitted pixels, normalised to a mean gain of 1.
  const std::vector<double> mean_gains = FrameMeanGains(stack, frames, pixels);
  const bool means_valid = !mean_gains.empty();
  double spread2 = 0;  // the jitter the frame means see
  for (double g : mean_gains) spread2 += (g - 1) * (g - 1);
  const double spread = means_valid ? std::sqrt(spread2 / mean_gains.size()) : 0.0;
  // The means' bias is bounded by the residual stripe: they are worth starting from only where
  // that bias is small both absolutely and against the jitter they correct (a small view of a
  // steady lamp keeps the given gains: its stripes do not average out to below its jitter).
  const bool means_ok = means_valid && residual_stripe <= options.max_residual_stripe &&
                        residual_stripe <= options.max_stripe_to_jitter * spread;
  if (options.method == FrameGainMethod::kFrameMeans ||
      (options.method == FrameGainMethod::kJoint && options.start_from_frame_means && means_ok)) {
    if (!means_valid) return {};
    FrameCorrections fc;
    fc.positions_px.assign(frames.size(), 0.0);
    fc.gains = mean_gains;
    fc.pixels_used = static_cast<int>(pixels.size());
    fc.valid = true;
    fc.model = "means";
    if (options.method == FrameGainMethod::kFrameMeans) {
      for (size_t k = 0; k < frames.size(); ++k)
        (*inv_gain)[frames[k]] = static_cast<float>(1.0 / fc.gains[k]);
      return fc;
    }
    g0 = fc.gains;
  }
  FrameCorrectionOptions o = options;
  FrameCorrections fc = EstimateFrameCorrections(stack, frames, pixels, f_map, *x, g0, o);
  fc.view_residual_stripe = residual_stripe;
  if (!means_ok && fc.model == "gains") {
    // Neither a frame-mean start nor positions: the given (alternating least squares) gains
    // stay; the out-of-band refinement alone was measured to gain nothing (and it shrinks the
    // residuals of noise-free data below the model errors the mixed-pixel test must tolerate).
    FrameCorrections kept;
    kept.gains = g0;
    kept.positions_px.assign(frames.size(), 0.0);
    kept.model = "kept";
    kept.view_residual_stripe = residual_stripe;
    kept.position_chi2_gain = fc.position_chi2_gain;
    return kept;
  }
  if (fc.valid) {
    for (size_t k = 0; k < frames.size(); ++k) {
      (*inv_gain)[frames[k]] = static_cast<float>(1.0 / fc.gains[k]);
      (*x)[k] += fc.positions_px[k];
    }
  }
  return fc;
}

}  // namespace mesoscan
