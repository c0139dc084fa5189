#include "brdf/warp2d.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace mesoscan {
namespace {

// Largest i in [0, size-2] with pred(i) true, for a predicate that is true then false (pbrt-v4
// FindInterval).
template <typename Pred>
int FindInterval(int size, const Pred& pred) {
  int first = 1, len = size - 2;
  while (len > 0) {
    const int half = len >> 1, middle = first + half;
    if (pred(middle)) {
      first = middle + 1;
      len -= half + 1;
    } else {
      len = half;
    }
  }
  return std::clamp(first - 1, 0, size - 2);
}

// Inverts the CDF of the linear density a (1 - t) + b t on t in [0, 1] at mass s: a t + (b - a) t^2
// / 2 = s, written in the cancellation-free form 2 s / (a + sqrt(disc)).
double SolveLinearCdf(double a, double b, double s) {
  const double disc = std::max(0.0, a * a + 2 * s * (b - a));
  const double den = a + std::sqrt(disc);
  if (!(den > 0)) return 0.0;
  return std::clamp(2 * s / den, 0.0, 1.0);
}

}  // namespace

Warp2D::Warp2D(int width, int height, std::vector<double> data,
               std::vector<std::vector<double>> param_values, bool sampling, std::string name)
    : width_(width),
      height_(height),
      slice_size_(static_cast<size_t>(width) * height),
      param_values_(std::move(param_values)),
      sampling_(sampling) {
  if (width < 2 || height < 2)
    MESOSCAN_BAD_INPUT(name << ": table is " << width << "x" << height << ", expected >= 2x2");
  if (param_values_.size() > kMaxParams)
    MESOSCAN_BAD_INPUT(name << ": " << param_values_.size() << " parameters, at most "
                            << kMaxParams);
  size_t slices = 1;
  param_strides_.assign(param_values_.size(), 0);
  for (int d = static_cast<int>(param_values_.size()) - 1; d >= 0; --d) {
    const auto& v = param_values_[d];
    if (v.empty()) MESOSCAN_BAD_INPUT(name << ": parameter " << d << " has no values");
    for (size_t i = 0; i + 1 < v.size(); ++i)
      if (!(v[i + 1] > v[i]))
        MESOSCAN_BAD_INPUT(name << ": parameter " << d << " values are not increasing");
    param_strides_[d] = slices;
    slices *= v.size();
  }
  if (data.size() != slices * slice_size_)
    MESOSCAN_BAD_INPUT(name << ": " << data.size() << " values, expected " << slices << "x"
                            << height << "x" << width);
  for (size_t i = 0; i < data.size(); ++i)
    if (!std::isfinite(data[i]) || data[i] < 0)
      MESOSCAN_BAD_INPUT(name << ": entry " << i << " is " << data[i]
                              << ", expected a finite value >= 0");
  if (!sampling) {
    data_ = std::move(data);
    return;
  }

  const size_t w = width, h = height;
  data_.resize(data.size());
  marginal_cdf_.resize(slices * h);
  conditional_cdf_.resize(data.size());
  for (size_t s = 0; s < slices; ++s) {
    const double* in = data.data() + s * slice_size_;
    double* cond = conditional_cdf_.data() + s * slice_size_;
    double* marg = marginal_cdf_.data() + s * h;
    // Conditional CDFs: the integral of each row's linear interpolant, in node units.
    for (size_t y = 0; y < h; ++y) {
      double sum = 0;
      cond[y * w] = 0;
      for (size_t x = 0; x + 1 < w; ++x) {
        sum += 0.5 * (in[y * w + x] + in[y * w + x + 1]);
        cond[y * w + x + 1] = sum;
      }
    }
    // Marginal CDF over rows: the row totals are themselves linear between rows.
    double sum = 0;
    marg[0] = 0;
    for (size_t y = 0; y + 1 < h; ++y) {
      sum += 0.5 * (cond[y * w + w - 1] + cond[(y + 1) * w + w - 1]);
      marg[y + 1] = sum;
    }
    if (!(sum > 0)) MESOSCAN_BAD_INPUT(name << ": slice " << s << " has no mass to sample");
    const double norm = 1.0 / sum;
    for (size_t i = 0; i < slice_size_; ++i) {
      cond[i] *= norm;
      data_[s * slice_size_ + i] = in[i] * norm;
    }
    for (size_t y = 0; y < h; ++y) marg[y] *= norm;
  }
}

Warp2D::Blend Warp2D::Interpolate(const double* params) const {
  Blend b;
  for (size_t d = 0; d < param_values_.size(); ++d) {
    const auto& v = param_values_[d];
    if (v.size() == 1) continue;
    const double x = params[d];
    const int n = static_cast<int>(v.size());
    const int i = FindInterval(n, [&](int k) { return v[k] <= x; });
    const double w1 = std::clamp((x - v[i]) / (v[i + 1] - v[i]), 0.0, 1.0);
    const int stride = static_cast<int>(param_strides_[d]);
    const int m = b.n;
    if (w1 == 0.0) {
      for (int k = 0; k < m; ++k) b.slice[k] += i * stride;
    } else if (w1 == 1.0) {
      for (int k = 0; k < m; ++k) b.slice[k] += (i + 1) * stride;
    } else {
      for (int k = 0; k < m; ++k) {
        b.slice[m + k] = b.slice[k] + (i + 1) * stride;
        b.weight[m + k] = b.weight[k] * w1;
        b.slice[k] += i * stride;
        b.weight[k] *= 1 - w1;
      }
      b.n = 2 * m;
    }
  }
  return b;
}

double Warp2D::Eval(const Eigen::Vector2d& pos, const double* params) const {
  const Blend b = Interpolate(params);
  const double x = std::clamp(pos.x(), 0.0, 1.0) * (width_ - 1);
  const double y = std::clamp(pos.y(), 0.0, 1.0) * (height_ - 1);
  const int ix = std::min(static_cast<int>(x), width_ - 2);
  const int iy = std::min(static_cast<int>(y), height_ - 2);
  const double fx = x - ix, fy = y - iy;
  const size_t i00 = static_cast<size_t>(iy) * width_ + ix;
  const double v00 = Lookup(data_, b, slice_size_, i00);
  const double v10 = Lookup(data_, b, slice_size_, i00 + 1);
  const double v01 = Lookup(data_, b, slice_size_, i00 + width_);
  const double v11 = Lookup(data_, b, slice_size_, i00 + width_ + 1);
  const double v = (1 - fy) * ((1 - fx) * v00 + fx * v10) + fy * ((1 - fx) * v01 + fx * v11);
  return sampling_ ? v * (width_ - 1) * (height_ - 1) : v;
}

std::pair<Eigen::Vector2d, double> Warp2D::Sample(const Eigen::Vector2d& u,
                                                  const double* params) const {
  MESOSCAN_DCHECK(sampling_);
  const Blend b = Interpolate(params);
  const size_t w = width_, h = height_;
  const double ux = std::clamp(u.x(), 0.0, 1.0), uy = std::clamp(u.y(), 0.0, 1.0);
  // Row: invert the marginal CDF, then the linear marginal density within the row interval.
  const int row = FindInterval(height_, [&](int k) { return Lookup(marginal_cdf_, b, h, k) < uy; });
  const double r0 = Lookup(conditional_cdf_, b, slice_size_, row * w + w - 1);
  const double r1 = Lookup(conditional_cdf_, b, slice_size_, (row + 1) * w + w - 1);
  const double ty = SolveLinearCdf(r0, r1, uy - Lookup(marginal_cdf_, b, h, row));
  // Column: the conditional CDF at this fractional row is the blend of its two neighbours.
  const double target = ux * ((1 - ty) * r0 + ty * r1);
  auto cond = [&](int k) {
    return (1 - ty) * Lookup(conditional_cdf_, b, slice_size_, row * w + k) +
           ty * Lookup(conditional_cdf_, b, slice_size_, (row + 1) * w + k);
  };
  const int col = FindInterval(width_, [&](int k) { return cond(k) < target; });
  const size_t i00 = row * w + col;
  const double v00 = Lookup(data_, b, slice_size_, i00);
  const double v10 = Lookup(data_, b, slice_size_, i00 + 1);
  const double v01 = Lookup(data_, b, slice_size_, i00 + w);
  const double v11 = Lookup(data_, b, slice_size_, i00 + w + 1);
  const double c0 = (1 - ty) * v00 + ty * v01, c1 = (1 - ty) * v10 + ty * v11;
  const double tx = SolveLinearCdf(c0, c1, target - cond(col));
  const Eigen::Vector2d pos((col + tx) / (width_ - 1), (row + ty) / (height_ - 1));
  const double pdf = ((1 - tx) * c0 + tx * c1) * (width_ - 1) * (height_ - 1);
  return {pos, pdf};
}

std::pair<Eigen::Vector2d, double> Warp2D::Invert(const Eigen::Vector2d& pos,
                                                  const double* params) const {
  MESOSCAN_DCHECK(sampling_);
  const Blend b = Interpolate(params);
  const size_t w = width_, h = height_;
  const double x = std::clamp(pos.x(), 0.0, 1.0) * (width_ - 1);
  const double y = std::clamp(pos.y(), 0.0, 1.0) * (height_ - 1);
  const int ix = std::min(static_cast<int>(x), width_ - 2);
  const int iy = std::min(static_cast<int>(y), height_ - 2);
  const double fx = x - ix, fy = y - iy;
  const size_t i00 = static_cast<size_t>(iy) * w + ix;
  const double v00 = Lookup(data_, b, slice_size_, i00);
  const double v10 = Lookup(data_, b, slice_size_, i00 + 1);
  const double v01 = Lookup(data_, b, slice_size_, i00 + w);
  const double v11 = Lookup(data_, b, slice_size_, i00 + w + 1);
  const double c0 = (1 - fy) * v00 + fy * v01, c1 = (1 - fy) * v10 + fy * v11;
  const double pdf = ((1 - fx) * c0 + fx * c1) * (width_ - 1) * (height_ - 1);
  // Column: CDF at the patch start plus the integral of the linear conditional inside it.
  double sx = fx * (c0 + 0.5 * fx * (c1 - c0));
  sx += (1 - fy) * Lookup(conditional_cdf_, b, slice_size_, i00) +
        fy * Lookup(conditional_cdf_, b, slice_size_, i00 + w);
  const double r0 = Lookup(conditional_cdf_, b, slice_size_, iy * w + w - 1);
  const double r1 = Lookup(conditional_cdf_, b, slice_size_, (iy + 1) * w + w - 1);
  const double row_total = (1 - fy) * r0 + fy * r1;
  const double ux = row_total > 0 ? sx / row_total : 0.0;
  // Row: marginal CDF at the row start plus the integral of the linear marginal inside it.
  const double uy = fy * (r0 + 0.5 * fy * (r1 - r0)) + Lookup(marginal_cdf_, b, h, iy);
  return {Eigen::Vector2d(ux, uy), pdf};
}

}  // namespace mesoscan
