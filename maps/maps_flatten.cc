#include "maps/maps_flatten.h"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "core/robust_stats.h"

namespace mesoscan {
namespace {

// Monomials u^a v^b with a + b <= degree, u and v the pixel coordinates mapped to [-1, 1].
int Terms(int degree) { return (degree + 1) * (degree + 2) / 2; }
void Basis(double u, double v, int degree, double* out) {
  double pu[7] = {1}, pv[7] = {1};
  for (int d = 1; d <= degree; ++d) pu[d] = pu[d - 1] * u, pv[d] = pv[d - 1] * v;
  int k = 0;
  for (int d = 0; d <= degree; ++d)
    for (int b = 0; b <= d; ++b) out[k++] = pu[d - b] * pv[b];
}

struct PolyFit {
  int degree = 1;
  Eigen::VectorXd c;
  double su = 1, sv = 1, cu = 0, cv = 0;  // u = (x - cu) / su
  double Eval(int x, int y) const {
    double b[28];
    Basis((x - cu) / su, (y - cv) / sv, degree, b);
    double s = 0;
    for (int k = 0; k < c.size(); ++k) s += c[k] * b[k];
    return s;
  }
};

// Robust (Huber IRLS) least-squares polynomial of total degree `degree` on the finite pixels
// of z, subsampled to at most ~250k points.
PolyFit FitPolynomial(const ImageF& z, const ImageU8& mask, int degree, const FlattenOptions& o) {
  const int w = z.width(), h = z.height();
  PolyFit f;
  f.degree = degree;
  f.cu = 0.5 * (w - 1), f.cv = 0.5 * (h - 1);
  f.su = std::max(1.0, 0.5 * (w - 1)), f.sv = std::max(1.0, 0.5 * (h - 1));
  const int stride = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(w) * h / 250e3)));
  const int nt = Terms(degree);
  std::vector<double> rows, values;
  for (int y = 0; y < h; y += stride)
    for (int x = 0; x < w; x += stride) {
      const float v = z(x, y);
      if (!std::isfinite(v) || (!mask.empty() && mask(x, y) == 0)) continue;
      double b[28];
      Basis((x - f.cu) / f.su, (y - f.cv) / f.sv, degree, b);
      rows.insert(rows.end(), b, b + nt);
      values.push_back(v);
    }
  const int m = static_cast<int>(values.size());
  if (m < 2 * nt)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Key("height.exr", "Z"),
                          m << " valid samples, too few to fit a degree-" << degree
                            << " polynomial for " << OptionRef{"FlattenOptions.method"});
  const Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> A(
      rows.data(), m, nt);
  const Eigen::Map<const Eigen::VectorXd> b(values.data(), m);
  Eigen::VectorXd wgt = Eigen::VectorXd::Ones(m);
  for (int it = 0; it < o.irls_iterations; ++it) {
    const Eigen::MatrixXd AtWA = A.transpose() * wgt.asDiagonal() * A;
    const Eigen::VectorXd AtWb = A.transpose() * wgt.cwiseProduct(b);
    f.c = AtWA.ldlt().solve(AtWb);
    // Huber weights, scale from the median absolute residual.
    Eigen::VectorXd r = (b - A * f.c).cwiseAbs();
    std::vector<double> rs(r.data(), r.data() + m);
    std::nth_element(rs.begin(), rs.begin() + m / 2, rs.end());
    const double sigma = std::max(kMadToSigma * rs[m / 2], 1e-12);
    const double t = o.huber_k * sigma;
    for (int i = 0; i < m; ++i) wgt[i] = r[i] <= t ? 1.0 : t / r[i];
  }
  return f;
}

}  // namespace

void FlattenOptions::Check() const {
  if (poly_degree < 1 || poly_degree > 6)
    MESOSCAN_BAD_OPTION("FlattenOptions.poly_degree",
                        "poly:" << poly_degree << ": expected a degree 1..6");
  if (!(highpass_wavelength_m > 0) || !std::isfinite(highpass_wavelength_m))
    MESOSCAN_BAD_OPTION("FlattenOptions.highpass_wavelength_m", "highpass: wavelength "
                                                                    << highpass_wavelength_m * 1e3
                                                                    << " mm: expected > 0");
  if (irls_iterations < 1 || !(huber_k > 0))
    MESOSCAN_THROW(ErrorKind::kUsage, "flatten: irls_iterations >= 1 and huber_k > 0 expected");
}

FlattenOptions ParseFlatten(const std::string& t) {
  FlattenOptions o;
  auto number = [&](const std::string& s) {
    try {
      size_t used = 0;
      const double v = std::stod(s, &used);
      if (used == s.size()) return v;
    } catch (...) {
    }
    MESOSCAN_BAD_OPTION("FlattenOptions.method",
                        "'" << t << "': expected none, plane, poly:N or highpass:MM");
  };
  if (t == "none")
    o.method = FlattenMethod::kNone;
  else if (t == "plane")
    o.method = FlattenMethod::kPlane;
  else if (t.rfind("poly:", 0) == 0) {
    o.method = FlattenMethod::kPoly;
    const double d = number(t.substr(5));
    if (d != std::floor(d)) number("x");
    o.poly_degree = static_cast<int>(d);
  } else if (t.rfind("highpass:", 0) == 0) {
    o.method = FlattenMethod::kHighpass;
    o.highpass_wavelength_m = number(t.substr(9)) * 1e-3;
  } else {
    number("x");
  }
  o.Check();
  return o;
}

std::string FlattenName(const FlattenOptions& o) {
  std::ostringstream s;
  switch (o.method) {
    case FlattenMethod::kNone:
      return "none";
    case FlattenMethod::kPlane:
      return "plane";
    case FlattenMethod::kPoly:
      s << "poly:" << o.poly_degree;
      return s.str();
    case FlattenMethod::kHighpass:
      s << "highpass:" << o.highpass_wavelength_m * 1e3;
      return s.str();
  }
  return "?";
}

ImageF NormalisedGaussianBlur(const ImageF& z, double sigma_px, bool periodic) {
  const int w = z.width(), h = z.height();
  // Downsample first when sigma is large: a Gaussian of sigma s at 1/f resolution is one of
  // sigma s*f at full, and the box downsampling adds only f^2/12 of variance.
  int f = 1;
  while (sigma_px / (2 * f) >= 4.0 && w / (2 * f) >= 16 && h / (2 * f) >= 16) f *= 2;
  const int sw = (w + f - 1) / f, sh = (h + f - 1) / f;
  cv::Mat num(sh, sw, CV_32F, cv::Scalar(0)), den(sh, sw, CV_32F, cv::Scalar(0));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float v = z(x, y);
      if (!std::isfinite(v)) continue;
      num.at<float>(y / f, x / f) += v;
      den.at<float>(y / f, x / f) += 1.0f;
    }
  const double s = std::sqrt(std::max(0.25, sigma_px * sigma_px - (f * f - 1) / 12.0)) / f;
  const int k = 2 * static_cast<int>(std::ceil(3.5 * s)) + 1;
  if (periodic) {
    // Wrap by padding with the opposite side, blurring, and cutting the centre.
    const int pad = std::min(k / 2, std::min(sw, sh));
    cv::Mat pn, pd;
    cv::copyMakeBorder(num, pn, pad, pad, pad, pad, cv::BORDER_WRAP);
    cv::copyMakeBorder(den, pd, pad, pad, pad, pad, cv::BORDER_WRAP);
    cv::GaussianBlur(pn, pn, cv::Size(k, k), s, s, cv::BORDER_REFLECT);
    cv::GaussianBlur(pd, pd, cv::Size(k, k), s, s, cv::BORDER_REFLECT);
    num = pn(cv::Rect(pad, pad, sw, sh)).clone();
    den = pd(cv::Rect(pad, pad, sw, sh)).clone();
  } else {
    cv::GaussianBlur(num, num, cv::Size(k, k), s, s, cv::BORDER_REFLECT);
    cv::GaussianBlur(den, den, cv::Size(k, k), s, s, cv::BORDER_REFLECT);
  }
  cv::Mat low(sh, sw, CV_32F);
  for (int y = 0; y < sh; ++y)
    for (int x = 0; x < sw; ++x) {
      const float d = den.at<float>(y, x);
      low.at<float>(y, x) =
          d > 1e-6f ? num.at<float>(y, x) / d : std::numeric_limits<float>::quiet_NaN();
    }
  ImageF out(w, h, 1);
  if (f == 1) {
    for (int y = 0; y < h; ++y) std::copy(low.ptr<float>(y), low.ptr<float>(y) + w, out.row(y));
    return out;
  }
  // Bilinear upsampling: low-res pixel (X, Y) is centred at full-res ((X + 0.5) f - 0.5).
  ParallelForRows(h, [&](int r0, int r1) {
    for (int y = r0; y < r1; ++y) {
      const double fy = std::clamp((y + 0.5) / f - 0.5, 0.0, sh - 1.0);
      const int y0 = std::min(static_cast<int>(fy), sh - 1), y1 = std::min(y0 + 1, sh - 1);
      const double b = fy - y0;
      for (int x = 0; x < w; ++x) {
        const double fx = std::clamp((x + 0.5) / f - 0.5, 0.0, sw - 1.0);
        const int x0 = std::min(static_cast<int>(fx), sw - 1), x1 = std::min(x0 + 1, sw - 1);
        const double a = fx - x0;
        out(x, y) = static_cast<float>(
            (1 - a) * (1 - b) * low.at<float>(y0, x0) + a * (1 - b) * low.at<float>(y0, x1) +
            (1 - a) * b * low.at<float>(y1, x0) + a * b * low.at<float>(y1, x1));
      }
    }
  });
  return out;
}

FlattenResult Flatten(const HeightField& hf, const ImageU8& mask, const FlattenOptions& o) {
  o.Check();
  const auto t0 = std::chrono::steady_clock::now();
  const int w = hf.width(), h = hf.height();
  FlattenResult r;
  r.field = hf;
  r.removed = ImageF(w, h, 1, 0.0f);
  if (o.method == FlattenMethod::kNone) {
    r.description = "none";
    return r;
  }
  // 1. The robust plane or polynomial.
  // The high-pass first removes a quadratic: the normalised Gaussian is biased at the grid's
  // border by the local slope times sigma, so what it filters must be nearly flat there.
  const int degree = o.method == FlattenMethod::kPoly       ? o.poly_degree
                     : o.method == FlattenMethod::kHighpass ? 2
                                                            : 1;
  const PolyFit fit = FitPolynomial(hf.z, mask, degree, o);
  r.coefficients.assign(fit.c.data(), fit.c.data() + fit.c.size());
  ParallelForRows(h, [&](int r0, int r1) {
    for (int y = r0; y < r1; ++y)
      for (int x = 0; x < w; ++x) r.removed(x, y) = static_cast<float>(fit.Eval(x, y));
  });
  std::ostringstream d;
  // Tilt of the fitted plane (degree-1 terms: dz/du, dz/dv per normalised unit).
  const double gx = fit.c[1] / (fit.su * hf.pixel_size), gy = -fit.c[2] / (fit.sv * hf.pixel_size);
  d << FlattenName(o) << ": plane tilt " << std::atan(std::hypot(gx, gy)) * 180 / kPi << " deg";
  // 2. High-pass: the low-pass of what the plane left.
  if (o.method == FlattenMethod::kHighpass) {
    ImageF resid(w, h, 1);
    for (size_t p = 0; p < resid.pixels(); ++p) {
      const bool use = mask.empty() || mask.data()[p] != 0;
      resid.data()[p] =
          use ? hf.z.data()[p] - r.removed.data()[p] : std::numeric_limits<float>::quiet_NaN();
    }
    const double sigma_px =
        o.highpass_wavelength_m * std::sqrt(std::log(2.0) / 2.0) / kPi / hf.pixel_size;
    const ImageF low = NormalisedGaussianBlur(resid, sigma_px);
    for (size_t p = 0; p < low.pixels(); ++p)
      if (std::isfinite(low.data()[p])) r.removed.data()[p] += low.data()[p];
    d << ", low-pass sigma " << sigma_px * hf.pixel_size * 1e3 << " mm";
  }
  for (size_t p = 0; p < r.removed.pixels(); ++p) r.field.z.data()[p] -= r.removed.data()[p];
  r.description = d.str();
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace mesoscan
