#include "maps/maps_fill.h"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>
#include <sstream>
#include <vector>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {

constexpr int kDx[4] = {1, -1, 0, 0};
constexpr int kDy[4] = {0, 0, 1, -1};

struct Component {
  std::vector<int> pixels;  // flat indices y * w + x
  bool touches_border = false;
  float radius_px = 0.0f;  // largest distance from a hole pixel to a measured pixel
};

// 4-connected components of the NaN pixels.
std::vector<Component> HoleComponents(const ImageF& z, std::vector<int>* label) {
  const int w = z.width(), h = z.height();
  label->assign(static_cast<size_t>(w) * h, -1);
  std::vector<Component> comps;
  std::vector<int> stack;
  const float* zp = z.channel(0);
  for (int start = 0; start < w * h; ++start) {
    if (std::isfinite(zp[start]) || (*label)[start] >= 0) continue;
    Component c;
    const int id = static_cast<int>(comps.size());
    stack.assign(1, start);
    (*label)[start] = id;
    while (!stack.empty()) {
      const int p = stack.back();
      stack.pop_back();
      c.pixels.push_back(p);
      const int x = p % w, y = p / w;
      if (x == 0 || y == 0 || x == w - 1 || y == h - 1) c.touches_border = true;
      for (int k = 0; k < 4; ++k) {
        const int nx = x + kDx[k], ny = y + kDy[k];
        if (nx < 0 || ny < 0 || nx >= w || ny >= h) continue;
        const int q = ny * w + nx;
        if (std::isfinite(zp[q]) || (*label)[q] >= 0) continue;
        (*label)[q] = id;
        stack.push_back(q);
      }
    }
    comps.push_back(std::move(c));
  }
  return comps;
}

// Solves one hole. Unknowns are the component's pixels; `z` (the input grid) holds the measured
// values around it; the solution is written into `out` (the component's pixels only).
void SolveHole(const Component& c, FillMethod method, int w, int h, const float* z, float* out) {
  const int n = static_cast<int>(c.pixels.size());
  // Local index of each unknown: a small hash-free map through a sorted vector.
  std::vector<int> sorted = c.pixels;
  std::sort(sorted.begin(), sorted.end());
  auto index_of = [&](int p) {
    auto it = std::lower_bound(sorted.begin(), sorted.end(), p);
    return it != sorted.end() && *it == p ? static_cast<int>(it - sorted.begin()) : -1;
  };
  // Heights relative to the border's mean (conditioning).
  double offset = 0.0;
  int64_t nb = 0;
  for (int p : sorted) {
    const int x = p % w, y = p / w;
    for (int k = 0; k < 4; ++k) {
      const int nx = x + kDx[k], ny = y + kDy[k];
      if (nx < 0 || ny < 0 || nx >= w || ny >= h) continue;
      const float v = z[ny * w + nx];
      if (std::isfinite(v)) offset += v, ++nb;
    }
  }
  offset = nb > 0 ? offset / nb : 0.0;

  std::vector<Eigen::Triplet<double>> trip;
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
  if (method == FillMethod::kHarmonic) {
    // deg * z_p - sum of in-grid neighbours = 0 (5-point Laplacian; Neumann at the grid border).
    trip.reserve(static_cast<size_t>(n) * 5);
    for (int i = 0; i < n; ++i) {
      const int p = sorted[i], x = p % w, y = p / w;
      int deg = 0;
      for (int k = 0; k < 4; ++k) {
        const int nx = x + kDx[k], ny = y + kDy[k];
        if (nx < 0 || ny < 0 || nx >= w || ny >= h) continue;
        ++deg;
        const int q = ny * w + nx;
        const float v = z[q];
        if (std::isfinite(v))
          rhs[i] += v - offset;
        else
          trip.emplace_back(i, index_of(q), -1.0);
      }
      trip.emplace_back(i, i, static_cast<double>(deg));
    }
  } else {
    // Least squares over the 5-point Laplacian at every hole pixel and at every measured pixel
    // of the 1-ring whose stencil is complete: min sum (lap z)^2, the discrete thin plate.
    std::vector<int> rows = sorted;
    for (int p : sorted) {
      const int x = p % w, y = p / w;
      for (int k = 0; k < 4; ++k) {
        const int nx = x + kDx[k], ny = y + kDy[k];
        if (nx < 0 || ny < 0 || nx >= w || ny >= h) continue;
        if (std::isfinite(z[ny * w + nx])) rows.push_back(ny * w + nx);
      }
    }
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    std::vector<Eigen::Triplet<double>> lt;
    std::vector<double> lb;
    int m = 0;
    for (int p : rows) {
      const int x = p % w, y = p / w;
      bool ok = true;
      double b = 0.0;
      int cols[5], ncols = 0;
      double vals[5];
      for (int k = -1; k < 4; ++k) {
        const int nx = k < 0 ? x : x + kDx[k], ny = k < 0 ? y : y + kDy[k];
        if (nx < 0 || ny < 0 || nx >= w || ny >= h) {
          ok = false;
          break;
        }
        const int q = ny * w + nx;
        const double coef = k < 0 ? -4.0 : 1.0;
        const int j = index_of(q);
        if (j >= 0) {
          cols[ncols] = j, vals[ncols] = coef, ++ncols;
        } else if (std::isfinite(z[q])) {
          b -= coef * (z[q] - offset);
        } else {
          ok = false;  // another hole's pixel: no equation here
          break;
        }
      }
      if (!ok || ncols == 0) continue;
      for (int t = 0; t < ncols; ++t) lt.emplace_back(m, cols[t], vals[t]);
      lb.push_back(b);
      ++m;
    }
    Eigen::SparseMatrix<double> L(m, n);
    L.setFromTriplets(lt.begin(), lt.end());
    const Eigen::Map<const Eigen::VectorXd> bl(lb.data(), m);
    Eigen::SparseMatrix<double> A = (L.transpose() * L).pruned();
    // A tiny harmonic term keeps the system definite where the Laplacian rows do not pin a
    // pixel (e.g. a hole a single pixel wide along the grid's border).
    Eigen::SparseMatrix<double> reg(n, n);
    reg.setIdentity();
    A += 1e-9 * reg;
    rhs = L.transpose() * bl;
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(A);
    if (solver.info() == Eigen::Success) {
      const Eigen::VectorXd x = solver.solve(rhs);
      if (solver.info() == Eigen::Success && x.allFinite()) {
        for (int i = 0; i < n; ++i) out[sorted[i]] = static_cast<float>(x[i] + offset);
        return;
      }
    }
    // Not definite (a stencil-less hole): fall back to the harmonic fill.
    SolveHole(c, FillMethod::kHarmonic, w, h, z, out);
    return;
  }
  Eigen::SparseMatrix<double> A(n, n);
  A.setFromTriplets(trip.begin(), trip.end());
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(A);
  Eigen::VectorXd x;
  if (solver.info() == Eigen::Success) x = solver.solve(rhs);
  if (solver.info() != Eigen::Success || !x.allFinite() || nb == 0) return;  // stays NaN
  for (int i = 0; i < n; ++i) out[sorted[i]] = static_cast<float>(x[i] + offset);
}

}  // namespace

void FillOptions::Check() const {
  if (!(max_hole_radius_m > 0) || !std::isfinite(max_hole_radius_m))
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "fill: max hole radius " << max_hole_radius_m << " m: expected > 0");
}

ImageF FillImageWhere(const ImageF& image, const ImageU8& want, double pixel_size_m,
                      const FillOptions& options) {
  MESOSCAN_CHECK(want.width() == image.width() && want.height() == image.height());
  FillOptions fo = options;
  if (fo.method == FillMethod::kNone) fo.method = FillMethod::kHarmonic;
  const size_t n = image.pixels();
  ImageF out(image.width(), image.height(), image.channels());
  for (int c = 0; c < image.channels(); ++c) {
    HeightField f;
    f.pixel_size = pixel_size_m;
    f.z = ImageF(image.width(), image.height(), 1);
    std::copy(image.channel(c), image.channel(c) + n, f.z.channel(0));
    const FillResult fr = FillHoles(f, fo);
    cv::Mat a(image.height(), image.width(), CV_32FC1), unknown(a.size(), CV_8UC1);
    float* av = a.ptr<float>();  // both continuous: pixel p at [p]
    uint8_t* uv = unknown.ptr<uint8_t>();
    bool any_known = false, any_left = false;
    for (size_t p = 0; p < n; ++p) {
      const float v = fr.field.z.data()[p];
      const bool known = std::isfinite(v);
      av[p] = known ? v : 0.0f;
      uv[p] = known ? 0 : 255;
      any_known |= known;
      any_left |= !known && want.data()[p] != 0;
    }
    if (!any_known) {
      std::copy(image.channel(c), image.channel(c) + n, out.channel(c));
      continue;
    }
    if (any_left) {
      cv::Mat painted;
      cv::inpaint(a, unknown, painted, 3.0, cv::INPAINT_TELEA);
      a = painted;
      av = a.ptr<float>();
    }
    constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
    for (size_t p = 0; p < n; ++p) {
      const float v = image.channel(c)[p];
      out.channel(c)[p] = std::isfinite(v) ? v : want.data()[p] ? av[p] : kNan;
    }
  }
  return out;
}

FillMethod ParseFillMethod(const std::string& t) {
  if (t == "harmonic") return FillMethod::kHarmonic;
  if (t == "biharmonic") return FillMethod::kBiharmonic;
  if (t == "none") return FillMethod::kNone;
  MESOSCAN_BAD_OPTION("FillOptions.method", "'" << t << "': expected harmonic, biharmonic or none");
}

const char* FillMethodName(FillMethod m) {
  switch (m) {
    case FillMethod::kHarmonic:
      return "harmonic";
    case FillMethod::kBiharmonic:
      return "biharmonic";
    case FillMethod::kNone:
      return "none";
  }
  return "?";
}

std::string FillResult::BriefReport() const {
  std::ostringstream s;
  s << "fill: " << holes_filled << " holes (" << filled_pixels << " px) filled, " << holes_left
    << " left as holes (" << pixels_left << " px), " << seconds << " s";
  return s.str();
}

FillResult FillHoles(const HeightField& hf, const FillOptions& o) {
  o.Check();
  const auto t0 = std::chrono::steady_clock::now();
  FillResult r;
  r.field = hf;
  const int w = hf.width(), h = hf.height();
  r.filled = ImageU8(w, h, 1, 0);
  if (r.field.confidence.empty() && w > 0) {
    r.field.confidence = ImageF(w, h, 1, 0.0f);
    for (size_t p = 0; p < r.field.z.pixels(); ++p)
      r.field.confidence.data()[p] = std::isfinite(hf.z.data()[p]) ? 1.0f : 0.0f;
  }
  if (w == 0 || h == 0) return r;
  std::vector<int> label;
  std::vector<Component> comps = HoleComponents(hf.z, &label);
  if (comps.empty()) return r;
  // Inscribed radius of each hole: the distance transform of the hole mask.
  cv::Mat holes(h, w, CV_8U);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) holes.at<uint8_t>(y, x) = std::isfinite(hf.z(x, y)) ? 0 : 255;
  cv::Mat dist;
  cv::distanceTransform(holes, dist, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  const double max_radius_px = o.max_hole_radius_m / hf.pixel_size;
  std::vector<int> todo;
  for (size_t i = 0; i < comps.size(); ++i) {
    Component& c = comps[i];
    for (int p : c.pixels) c.radius_px = std::max(c.radius_px, dist.at<float>(p / w, p % w));
    const bool fill = o.method != FillMethod::kNone && c.radius_px <= max_radius_px &&
                      (o.fill_border_holes || !c.touches_border);
    // A hole with no measured pixel at all (the whole grid) cannot be filled.
    if (fill && static_cast<int64_t>(c.pixels.size()) < static_cast<int64_t>(w) * h)
      todo.push_back(static_cast<int>(i));
    else
      ++r.holes_left, r.pixels_left += static_cast<int64_t>(c.pixels.size());
  }
  // Largest holes first so the parallel loop does not end on one big solve.
  std::sort(todo.begin(), todo.end(),
            [&](int a, int b) { return comps[a].pixels.size() > comps[b].pixels.size(); });
  float* z = r.field.z.channel(0);
  // Holes are disjoint and a solve reads only measured pixels (never another hole's), so the
  // solves may run in parallel and write in place.
  ParallelFor(static_cast<int64_t>(todo.size()),
              [&](int64_t k) { SolveHole(comps[todo[k]], o.method, w, h, hf.z.channel(0), z); });
  for (int i : todo) {
    const Component& c = comps[i];
    bool ok = true;
    for (int p : c.pixels) ok = ok && std::isfinite(z[p]);
    if (!ok) {
      for (int p : c.pixels) z[p] = std::numeric_limits<float>::quiet_NaN();
      ++r.holes_left, r.pixels_left += static_cast<int64_t>(c.pixels.size());
      continue;
    }
    ++r.holes_filled;
    r.filled_pixels += static_cast<int64_t>(c.pixels.size());
    for (int p : c.pixels) {
      r.filled.data()[p] = 1;
      r.field.confidence.data()[p] = 0.0f;
    }
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace mesoscan
