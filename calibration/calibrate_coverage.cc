#include "calibration/calibrate_coverage.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "core/error.h"

namespace mesoscan {

std::vector<Vec2d> ConvexHull(const std::vector<Vec2d>& points) {
  // Andrew's monotone chain, counter-clockwise in (x, y).
  std::vector<Vec2d> p;
  for (const auto& q : points)
    if (q.allFinite()) p.push_back(q);
  if (p.size() < 3) return {};
  std::sort(p.begin(), p.end(), [](const Vec2d& a, const Vec2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  auto cross = [](const Vec2d& o, const Vec2d& a, const Vec2d& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Vec2d> h(2 * p.size());
  size_t k = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (size_t i = p.size() - 1, t = k + 1; i > 0; --i) {
    while (k >= t && cross(h[k - 2], h[k - 1], p[i - 1]) <= 0) --k;
    h[k++] = p[i - 1];
  }
  h.resize(k - 1);
  if (h.size() < 3) return {};
  return h;
}

bool CalibratedRegion::Contains(const Vec2d& px) const {
  for (const auto& h : hulls) {
    bool inside = h.size() >= 3;
    for (size_t i = 0; i < h.size() && inside; ++i) {
      const Vec2d& a = h[i];
      const Vec2d& b = h[(i + 1) % h.size()];
      inside = (b.x() - a.x()) * (px.y() - a.y()) - (b.y() - a.y()) * (px.x() - a.x()) >= 0;
    }
    if (inside) return true;
  }
  return false;
}

Json CalibratedRegion::ToJson() const {
  Json hs = Json::array();
  for (const auto& h : hulls) {
    Json poly = Json::array();
    for (const auto& p : h)
      poly.push_back({std::round(p.x() * 100) / 100, std::round(p.y() * 100) / 100});
    hs.push_back(poly);
  }
  return {{"width", width}, {"height", height}, {"hulls", hs}};
}

CalibratedRegion CalibratedRegion::FromJson(const Json& j, const std::string& where) {
  CalibratedRegion r;
  try {
    r.width = j.at("width").get<int>();
    r.height = j.at("height").get<int>();
    for (const auto& poly : j.at("hulls")) {
      std::vector<Vec2d> h;
      for (const auto& p : poly) {
        const Vec2d q(p.at(0).get<double>(), p.at(1).get<double>());
        if (!q.allFinite()) throw std::invalid_argument("non-finite vertex");
        h.push_back(q);
      }
      // Stored counter-clockwise; re-hull in case another tool wrote it in any order.
      h = ConvexHull(h);
      if (!h.empty()) r.hulls.push_back(std::move(h));
    }
  } catch (const std::exception& e) {
    MESOSCAN_BAD_INPUT(where << ": expected {\"width\", \"height\", \"hulls\": [[[x, y], ...]]} ("
                             << e.what() << ")");
  }
  if (r.width <= 0 || r.height <= 0)
    MESOSCAN_BAD_INPUT(where << ": expected a positive width and height");
  return r;
}

Json DeviceCoverage::ToJson() const {
  return {{"fraction", fraction},
          {"median_view_fraction", median_view_fraction},
          {"missing", missing},
          {"poor", poor},
          {"advice", advice}};
}

DeviceCoverage MeasureCoverageCells(const std::string& device, const CalibratedRegion& region,
                                    const CoverageCells& c, double poor_below) {
  DeviceCoverage out;
  out.device = device;
  auto centre = [&](int i, int j) {
    return Vec2d((i + 0.5) * c.cell - 0.5, (j + 0.5) * c.cell - 0.5);
  };
  // Per cell: covered by the union; the field's extent for the 3 x 3 blocks.
  int x0 = c.cols, x1 = -1, y0 = c.rows, y1 = -1;
  int64_t n_field = 0, n_cov = 0;
  std::vector<uint8_t> cov(c.field.size(), 0);
  for (int j = 0; j < c.rows; ++j)
    for (int i = 0; i < c.cols; ++i) {
      const size_t n = static_cast<size_t>(j) * c.cols + i;
      if (!c.field[n]) continue;
      x0 = std::min(x0, i), x1 = std::max(x1, i), y0 = std::min(y0, j), y1 = std::max(y1, j);
      ++n_field;
      cov[n] = region.Contains(centre(i, j));
      n_cov += cov[n];
    }
  if (n_field == 0) {
    out.advice = device + ": no field";
    out.poor = true;
    return out;
  }
  out.fraction = static_cast<double>(n_cov) / n_field;
  std::vector<double> per_view;
  for (const auto& h : region.hulls) {
    CalibratedRegion one;
    one.hulls = {h};
    int64_t k = 0;
    for (int j = y0; j <= y1; ++j)
      for (int i = x0; i <= x1; ++i)
        if (c.field[static_cast<size_t>(j) * c.cols + i] && one.Contains(centre(i, j))) ++k;
    per_view.push_back(static_cast<double>(k) / n_field);
  }
  if (!per_view.empty()) {
    std::nth_element(per_view.begin(), per_view.begin() + per_view.size() / 2, per_view.end());
    out.median_view_fraction = per_view[per_view.size() / 2];
  }
  // The 3 x 3 blocks of the field's bounding box: an outer block with field cells less than half
  // covered is missing.
  static const char* kNames[3][3] = {{"top left", "top", "top right"},
                                     {"left", "", "right"},
                                     {"bottom left", "bottom", "bottom right"}};
  bool miss[3][3] = {};
  for (int bj = 0; bj < 3; ++bj)
    for (int bi = 0; bi < 3; ++bi) {
      if (bi == 1 && bj == 1) continue;
      const int ia = x0 + (x1 - x0 + 1) * bi / 3, ib = x0 + (x1 - x0 + 1) * (bi + 1) / 3;
      const int ja = y0 + (y1 - y0 + 1) * bj / 3, jb = y0 + (y1 - y0 + 1) * (bj + 1) / 3;
      int64_t f = 0, k = 0;
      for (int j = ja; j < jb; ++j)
        for (int i = ia; i < ib; ++i) {
          const size_t n = static_cast<size_t>(j) * c.cols + i;
          f += c.field[n];
          k += c.field[n] && cov[n];
        }
      miss[bj][bi] = f > 0 && k < 0.5 * f;
    }
  // Whole sides first ("left edge" for its three blocks), then the remaining corners.
  bool used[3][3] = {};
  auto side = [&](const char* name, int a0, int a1, int b0, int b1) {
    for (int j = b0; j <= b1; ++j)
      for (int i = a0; i <= a1; ++i)
        if (!miss[j][i]) return;
    out.missing.push_back(name);
    for (int j = b0; j <= b1; ++j)
      for (int i = a0; i <= a1; ++i) used[j][i] = true;
  };
  side("left", 0, 0, 0, 2);
  side("right", 2, 2, 0, 2);
  side("top", 0, 2, 0, 0);
  side("bottom", 0, 2, 2, 2);
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i)
      if (miss[j][i] && !used[j][i]) out.missing.push_back(kNames[j][i]);
  out.poor = out.fraction < poor_below || !out.missing.empty();
  std::ostringstream o;
  o << "corners cover " << std::lround(out.fraction * 100) << "% of the " << device << " image";
  if (!out.missing.empty()) {
    // "near the left and bottom edges and the top right corner"
    std::vector<std::string> sides, corners;
    for (const auto& m : out.missing)
      (m.find(' ') == std::string::npos ? sides : corners).push_back(m);
    auto list = [](const std::vector<std::string>& v, const char* one, const char* many) {
      std::string s;
      for (size_t i = 0; i < v.size(); ++i)
        s += (i == 0 ? "" : i + 1 == v.size() ? " and " : ", ") + v[i];
      return s + (v.size() > 1 ? many : one);
    };
    o << "; add views with the board near the ";
    if (!sides.empty()) o << list(sides, " edge", " edges");
    if (!sides.empty() && !corners.empty()) o << " and the ";
    if (!corners.empty()) o << list(corners, " corner", " corners");
  }
  if (out.median_view_fraction > 0 && out.median_view_fraction < 0.15)
    o << "; or use a larger board (one view covers " << std::lround(out.median_view_fraction * 100)
      << "%)";
  out.advice = o.str();
  return out;
}

}  // namespace mesoscan
