#include "compare/planar_alignment.h"

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/parallel.h"
#include "core/robust_stats.h"

namespace mesoscan {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A field's object pixels: their centroid (world x, y) and largest distance from it.
struct Extent {
  Vec2d centre = Vec2d::Zero();
  double radius = 0;
  int64_t pixels = 0;
};

Extent ObjectExtent(const HeightField& hf, const ImageU8& in) {
  Extent e;
  Vec2d sum = Vec2d::Zero();
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i)
      if (in(i, j) && std::isfinite(hf.z(i, j))) {
        sum += Vec2d(hf.X(i), hf.Y(j));
        ++e.pixels;
      }
  if (e.pixels == 0) return e;
  e.centre = sum / static_cast<double>(e.pixels);
  double r2 = 0;
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i)
      if (in(i, j) && std::isfinite(hf.z(i, j)))
        r2 = std::max(r2, (Vec2d(hf.X(i), hf.Y(j)) - e.centre).squaredNorm());
  e.radius = std::sqrt(r2);
  return e;
}

// The field's relief on an n x n image of pixel s centred on world `c` (image pixel centre
// ((n-1)/2, (n-1)/2) at c; rows towards -y): the object's heights averaged into the image's
// pixels, minus their Gaussian-weighted local mean over the object (the object's outline and
// overall shape leave, the relief that tells rotations apart stays), clipped at 3 robust sigmas;
// 0 off the object.
cv::Mat Relief(const HeightField& hf, const ImageU8& in, const Vec2d& c, double s, int n) {
  cv::Mat sum = cv::Mat::zeros(n, n, CV_32F), count = cv::Mat::zeros(n, n, CV_32F);
  for (int j = 0; j < hf.height(); ++j) {
    const int v = static_cast<int>(std::floor((c.y() - hf.Y(j)) / s + 0.5 * n));
    if (v < 0 || v >= n) continue;
    float* srow = sum.ptr<float>(v);
    float* crow = count.ptr<float>(v);
    for (int i = 0; i < hf.width(); ++i) {
      const float z = hf.z(i, j);
      if (!in(i, j) || !std::isfinite(z)) continue;
      const int u = static_cast<int>(std::floor((hf.X(i) - c.x()) / s + 0.5 * n));
      if (u < 0 || u >= n) continue;
      srow[u] += z;
      crow[u] += 1;
    }
  }
  cv::Mat mask = count > 0;  // 255 where the object is
  cv::Mat m, z;
  mask.convertTo(m, CV_32F, 1.0 / 255);
  cv::divide(sum, cv::max(count, 1.0f), z);
  cv::Mat bz, bm;
  const double sigma = n / 24.0;
  cv::GaussianBlur(z, bz, cv::Size(0, 0), sigma);
  cv::GaussianBlur(m, bm, cv::Size(0, 0), sigma);
  cv::Mat f = z - bz / cv::max(bm, 1e-3f);
  f.setTo(0, ~mask);
  std::vector<double> v;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x)
      if (mask.at<uint8_t>(y, x)) v.push_back(f.at<float>(y, x));
  double med = Median(v);
  for (double& x : v) x = std::abs(x - med);
  const double clip = 3 * kMadToSigma * Median(v);
  if (clip > 0) f = cv::min(cv::max(f, -clip), clip);
  f.setTo(0, ~mask);
  return f;
}

struct Trial {
  double deg = 0, response = -1;
  cv::Point2d shift;
};

// B's relief rotated by `deg` about the image centre (counter-clockwise as seen with y up),
// phase-correlated with A's.
Trial Correlate(const cv::Mat& fa, const cv::Mat& fb, double deg) {
  const int n = fa.rows;
  const cv::Mat rot = cv::getRotationMatrix2D(cv::Point2f(0.5f * (n - 1), 0.5f * (n - 1)), deg, 1);
  cv::Mat fbr;
  cv::warpAffine(fb, fbr, rot, fb.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, 0);
  Trial t;
  t.deg = deg;
  t.shift = cv::phaseCorrelate(fbr, fa, cv::noArray(), &t.response);
  return t;
}

double Wrap(double deg) {
  deg = std::fmod(deg, 360.0);
  if (deg <= -180) deg += 360;
  if (deg > 180) deg -= 360;
  return deg;
}

}  // namespace

void PlanarAlignmentOptions::Check() const {
  // No flag sets these: invariants of the callers.
  MESOSCAN_CHECK(size >= 32 && size <= 4096 && (size & (size - 1)) == 0);
  MESOSCAN_CHECK(step_deg > 0 && step_deg <= 30);
  MESOSCAN_CHECK(candidates >= 1);
}

std::vector<PlanarCandidate> PlanarAlignment(const HeightField& a, const ImageU8& in_a,
                                             const HeightField& b, const ImageU8& in_b,
                                             const PlanarAlignmentOptions& o) {
  o.Check();
  MESOSCAN_CHECK(in_a.width() == a.width() && in_a.height() == a.height());
  MESOSCAN_CHECK(in_b.width() == b.width() && in_b.height() == b.height());
  const Extent ea = ObjectExtent(a, in_a), eb = ObjectExtent(b, in_b);
  if (ea.pixels < 64 || eb.pixels < 64) return {};
  // Both images centred on their object's centroid, large enough for either object turned
  // about it; never finer than the fields.
  const int n = o.size;
  const double s = std::max({2.2 * std::max(ea.radius, eb.radius) / n, a.pixel_size, b.pixel_size});
  const cv::Mat fa = Relief(a, in_a, ea.centre, s, n), fb = Relief(b, in_b, eb.centre, s, n);
  const cv::Mat ha = Relief(a, in_a, ea.centre, 2 * s, n / 2),
                hb = Relief(b, in_b, eb.centre, 2 * s, n / 2);

  // The sweep at half size; its local maxima refined at full size.
  const int steps = static_cast<int>(std::ceil(360.0 / o.step_deg));
  std::vector<Trial> sweep(steps);
  ParallelFor(steps, [&](int64_t k) { sweep[k] = Correlate(ha, hb, k * 360.0 / steps); });
  std::vector<int> peaks;
  for (int k = 0; k < steps; ++k)
    if (sweep[k].response >= sweep[(k + steps - 1) % steps].response &&
        sweep[k].response > sweep[(k + 1) % steps].response)
      peaks.push_back(k);
  std::sort(peaks.begin(), peaks.end(),
            [&](int p, int q) { return sweep[p].response > sweep[q].response; });
  peaks.resize(std::min<size_t>(peaks.size(), 2 * o.candidates));
  const double step = 360.0 / steps;
  std::vector<Trial> best(peaks.size());
  ParallelFor(static_cast<int64_t>(peaks.size()), [&](int64_t p) {
    const double d0 = sweep[peaks[p]].deg;
    Trial t;
    for (int j = -4; j <= 4; ++j) {
      const Trial c = Correlate(fa, fb, d0 + j * step / 4);
      if (c.response > t.response) t = c;
    }
    const Trial lo = Correlate(fa, fb, t.deg - step / 8), hi = Correlate(fa, fb, t.deg + step / 8);
    // A parabola through the three responses gives the angle between them.
    const double den = lo.response - 2 * t.response + hi.response;
    if (den < 0) {
      const double off = 0.5 * (lo.response - hi.response) / den * (step / 8);
      if (std::abs(off) <= step / 8) {
        const Trial c = Correlate(fa, fb, t.deg + off);
        if (c.response >= std::max(lo.response, hi.response)) t = c;
      }
    }
    if (lo.response > t.response) t = lo;
    if (hi.response > t.response) t = hi;
    best[p] = t;
  });
  std::sort(best.begin(), best.end(),
            [](const Trial& p, const Trial& q) { return p.response > q.response; });

  std::vector<PlanarCandidate> out;
  for (const Trial& t : best) {
    if (static_cast<int>(out.size()) >= o.candidates) break;
    const double deg = Wrap(t.deg);
    bool duplicate = false;
    for (const PlanarCandidate& c : out) duplicate |= std::abs(Wrap(c.angle_deg - deg)) < step;
    if (duplicate) continue;
    // Image pixel p_b of B's relief lands on p_a = Rimg (p_b - c) + c + shift in A's; world
    // w = centre + s F (p - c) with F = diag(1, -1) (rows towards -y), so
    // w_a = F Rimg F (w_b - centre_b) + centre_a + s F shift.
    const double rad = deg * kPi / 180;
    Eigen::Matrix2d r;  // F Rimg F: a counter-clockwise rotation by deg in the world
    r << std::cos(rad), -std::sin(rad), std::sin(rad), std::cos(rad);
    const Vec2d shift(s * t.shift.x, -s * t.shift.y);
    PlanarCandidate c;
    c.angle_deg = deg;
    c.response = t.response;
    c.b_to_a.topLeftCorner<2, 2>() = r;
    c.b_to_a.block<2, 1>(0, 3) = ea.centre - r * eb.centre + shift;
    out.push_back(c);
  }
  return out;
}

}  // namespace mesoscan
