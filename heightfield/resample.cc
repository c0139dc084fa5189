#include "heightfield/resample.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#include <vector>

#include "core/budget.h"
#include "core/error.h"

namespace mesoscan {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// std::ceil / std::floor to int for values in int's range (the casts below need that anyway):
// baseline x86-64 has no rounding instruction, and these ran four times per triangle.
inline int CeilToInt(double v) {
  const int t = static_cast<int>(v);  // rounds towards zero
  return t + (t < v);
}
inline int FloorToInt(double v) {
  const int t = static_cast<int>(v);
  return t - (t > v);
}

struct GridVertex {
  double i = 0, j = 0, z = 0, c = 0;
  Vec3d p = Vec3d::Zero();
};

}  // namespace

void ResampleOptions::Check() const {
  if (!(pixel_size >= 0.0) || !std::isfinite(pixel_size))
    MESOSCAN_BAD_INPUT("resample: pixel_size: expected a finite value >= 0, got " << pixel_size);
  if (!(max_edge_footprints > 1.0))
    MESOSCAN_BAD_INPUT("resample: max_edge_footprints: expected > 1, got " << max_edge_footprints);
}

float MedianOfNonNegative(const std::vector<std::vector<float>>& parts) {
  // The value nth_element puts at position n / 2 of the parts joined, selected on the pool: the
  // IEEE patterns of non-negative floats order like the values, so a histogram of their top 16
  // bits (per part, then summed) finds the bucket holding that rank, and nth_element runs on
  // that bucket's values alone.
  size_t n = 0;
  for (const std::vector<float>& p : parts) n += p.size();
  if (n == 0) return 0.0f;
  const size_t rank = n / 2;
  auto bucket = [](float v) {
    uint32_t b;
    std::memcpy(&b, &v, sizeof b);
    return b >> 16;
  };
  constexpr size_t kBuckets = 1 << 16;
  const int64_t chunks = std::min<int64_t>(8, static_cast<int64_t>(parts.size()));
  std::vector<std::vector<uint32_t>> hist(chunks, std::vector<uint32_t>(kBuckets, 0));
  auto chunk_parts = [&](int64_t c) {
    return std::pair<size_t, size_t>(parts.size() * c / chunks, parts.size() * (c + 1) / chunks);
  };
  tbb::parallel_for<int64_t>(0, chunks, [&](int64_t c) {
    const auto [p0, p1] = chunk_parts(c);
    for (size_t p = p0; p < p1; ++p)
      for (float v : parts[p]) ++hist[c][bucket(v)];
  });
  size_t below = 0;
  uint32_t target = 0;
  for (size_t b = 0; b < kBuckets; ++b) {
    size_t count = 0;
    for (int64_t c = 0; c < chunks; ++c) count += hist[c][b];
    if (below + count > rank) {
      target = static_cast<uint32_t>(b);
      break;
    }
    below += count;
  }
  std::vector<std::vector<float>> in_bucket(chunks);
  tbb::parallel_for<int64_t>(0, chunks, [&](int64_t c) {
    const auto [p0, p1] = chunk_parts(c);
    for (size_t p = p0; p < p1; ++p)
      for (float v : parts[p])
        if (bucket(v) == target) in_bucket[c].push_back(v);
  });
  std::vector<float> values;
  for (const std::vector<float>& v : in_bucket) values.insert(values.end(), v.begin(), v.end());
  std::nth_element(values.begin(), values.begin() + (rank - below), values.end());
  return values[rank - below];
}

double CameraFootprint(const ImageF& xyz) {
  const int w = xyz.width(), h = xyz.height();
  const int stride = std::max(1, h / 256);  // a few hundred rows are plenty for a median
  // The sampled rows' distances in parallel, then joined (the median does not depend on the
  // order).
  const int rows = (h + stride - 1) / stride;
  std::vector<std::vector<float>> per_row(std::max(rows, 0));
  tbb::parallel_for(tbb::blocked_range<int>(0, rows, 8), [&](const auto& range) {
    const int r0 = range.begin(), r1 = range.end();
    for (int r = r0; r < r1; ++r) {
      const int y = r * stride;
      for (int x = 0; x + 1 < w; ++x) {
        const float dx = xyz(x + 1, y, 0) - xyz(x, y, 0);
        const float dy = xyz(x + 1, y, 1) - xyz(x, y, 1);
        if (std::isfinite(dx) && std::isfinite(dy) && std::isfinite(xyz(x, y, 2)) &&
            std::isfinite(xyz(x + 1, y, 2)))
          per_row[r].push_back(std::sqrt(dx * dx + dy * dy));
      }
    }
  });
  return MedianOfNonNegative(per_row);
}

HeightField ResampleToGrid(const ImageF& xyz, const ImageF& confidence,
                           const ResampleOptions& options) {
  options.Check();
  MESOSCAN_CHECK_EQ(xyz.channels(), 3);
  const int w = xyz.width(), h = xyz.height();
  HeightField hf;
  // The points' bounds, per row in parallel (min and max do not depend on the order).
  std::vector<std::array<double, 4>> row_bounds(std::max(h, 0));
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y) {
      double b[4] = {
          std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
          std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
      for (int x = 0; x < w; ++x) {
        if (!std::isfinite(xyz(x, y, 2))) continue;
        b[0] = std::min<double>(b[0], xyz(x, y, 0));
        b[1] = std::max<double>(b[1], xyz(x, y, 0));
        b[2] = std::min<double>(b[2], xyz(x, y, 1));
        b[3] = std::max<double>(b[3], xyz(x, y, 1));
      }
      row_bounds[y] = {b[0], b[1], b[2], b[3]};
    }
  });
  double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin, ymax = -xmin;
  for (const auto& b : row_bounds) {
    xmin = std::min(xmin, b[0]);
    xmax = std::max(xmax, b[1]);
    ymin = std::min(ymin, b[2]);
    ymax = std::max(ymax, b[3]);
  }
  const double footprint = CameraFootprint(xyz);
  if (!std::isfinite(xmin) || !(footprint > 0)) {
    hf.z = ImageF(0, 0);
    hf.confidence = ImageF(0, 0);
    return hf;
  }
  hf.pixel_size = options.pixel_size > 0 ? options.pixel_size : footprint;
  // Grid aligned to multiples of the pixel size, covering the points.
  hf.x0 = std::ceil(xmin / hf.pixel_size) * hf.pixel_size;
  hf.y0 = std::floor(ymax / hf.pixel_size) * hf.pixel_size;
  // Budget before allocation (and before the int casts): z, confidence, normals and the EXR
  // writers' interleaved copies, ~48 bytes per grid pixel.
  const double gw_d = std::floor((xmax - hf.x0) / hf.pixel_size) + 1;
  const double gh_d = std::floor((hf.y0 - ymin) / hf.pixel_size) + 1;
  {
    std::ostringstream what;
    what << "resample: a " << gw_d << "x" << gh_d << " height grid at pixel size "
         << hf.pixel_size * 1e6 << " um";
    if (!(gw_d < 1 << 30 && gh_d < 1 << 30)) CheckMemoryBudget(what.str(), 1e300);
    CheckMemoryBudget(what.str(), gw_d * gh_d * 48.0);
  }
  if (!(gw_d >= 1 && gh_d >= 1)) {  // the points lie between two grid lines (a 1-pixel ROI strip)
    hf.z = ImageF(0, 0);
    hf.confidence = ImageF(0, 0);
    return hf;
  }
  const int gw = static_cast<int>(gw_d);
  const int gh = static_cast<int>(gh_d);
  tbb::parallel_for<int64_t>(0, 2,
                             [&](int64_t a) {  // one array per task (their page faults and fills)
                               if (a == 0)
                                 hf.z = ImageF(gw, gh, 1, kNaN);
                               else
                                 hf.confidence = ImageF(gw, gh, 1, 0.0f);
                             });
  const double max_edge2 = std::pow(options.max_edge_footprints * footprint, 2);

  auto vertex = [&](int x, int y, GridVertex* v) {
    const float z = xyz(x, y, 2);
    if (!std::isfinite(z)) return false;
    v->p = Vec3d(xyz(x, y, 0), xyz(x, y, 1), z);
    v->i = hf.I(v->p.x());
    v->j = hf.J(v->p.y());
    v->z = z;
    v->c = confidence.empty() ? 1.0 : confidence(x, y);
    return true;
  };
  // Rasterises triangle abc into grid rows [band_j0, band_j1] only.
  auto raster = [&](const GridVertex& a, const GridVertex& b, const GridVertex& c, int band_j0,
                    int band_j1) {
    if ((a.p - b.p).squaredNorm() > max_edge2 || (b.p - c.p).squaredNorm() > max_edge2 ||
        (c.p - a.p).squaredNorm() > max_edge2)
      return;  // spans a depth discontinuity
    const double area = (b.i - a.i) * (c.j - a.j) - (c.i - a.i) * (b.j - a.j);
    if (std::abs(area) < 1e-12) return;
    const int i0 = std::max(0, CeilToInt(std::min({a.i, b.i, c.i}) - 1e-9));
    const int i1 = std::min(gw - 1, FloorToInt(std::max({a.i, b.i, c.i}) + 1e-9));
    const int j0 = std::max(band_j0, CeilToInt(std::min({a.j, b.j, c.j}) - 1e-9));
    const int j1 = std::min(band_j1, FloorToInt(std::max({a.j, b.j, c.j}) + 1e-9));
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const double wa = ((b.i - i) * (c.j - j) - (c.i - i) * (b.j - j)) / area;
        const double wb = ((c.i - i) * (a.j - j) - (a.i - i) * (c.j - j)) / area;
        const double wc = 1.0 - wa - wb;
        constexpr double eps = -1e-9;
        if (wa < eps || wb < eps || wc < eps) continue;
        const float z = static_cast<float>(wa * a.z + wb * b.z + wc * c.z);
        float& gz = hf.z(i, j);
        if (std::isfinite(gz) && gz >= z) continue;
        gz = z;
        hf.confidence(i, j) = static_cast<float>(wa * a.c + wb * b.c + wc * c.c);
      }
  };
  // Grid rows [j_lo, j_hi] that the quads of camera row pair (y, y + 1) can touch.
  // Per camera row the extreme J of its points, rounded once (ceil and floor are monotone: the
  // same as rounding every point's J), then per row pair. J(y) = (y0 - y) / pixel_size is
  // monotone in y (a correctly rounded subtraction and division), so the extremes are J of the
  // row's extreme y, which the bounds above hold (of the same points: finite z).
  std::vector<int> row_lo(std::max(h, 0), std::numeric_limits<int>::max()),
      row_hi(std::max(h, 0), std::numeric_limits<int>::min());
  for (int y = 0; y < h; ++y) {
    const double lo = hf.J(row_bounds[y][3]), hi = hf.J(row_bounds[y][2]);
    if (lo <= hi) {
      row_lo[y] = CeilToInt(lo - 1e-9);
      row_hi[y] = FloorToInt(hi + 1e-9);
    }
  }
  std::vector<int> j_lo(std::max(h - 1, 0)), j_hi(std::max(h - 1, 0));
  for (int y = 0; y + 1 < h; ++y) {
    j_lo[y] = std::min(row_lo[y], row_lo[y + 1]);
    j_hi[y] = std::max(row_hi[y], row_hi[y + 1]);
  }
  // Parallel over bands of grid rows: each band rasterises, in the serial order (camera rows,
  // then columns), the parts of the triangles that fall into it. A grid cell belongs to one
  // band, so it sees the same writes in the same order as a serial pass: identical output.
  constexpr int kBandRows = 32;
  tbb::parallel_for<int64_t>(0, (gh + kBandRows - 1) / kBandRows, [&](int64_t band) {
    const int band_j0 = static_cast<int>(band) * kBandRows;
    const int band_j1 = std::min(gh - 1, band_j0 + kBandRows - 1);
    GridVertex v00, v10, v01, v11;
    for (int y = 0; y + 1 < h; ++y) {
      if (j_hi[y] < band_j0 || j_lo[y] > band_j1) continue;
      // The right corners of a quad are the left corners of the next: computed once.
      bool b10 = w > 0 && vertex(0, y, &v10), b11 = w > 0 && vertex(0, y + 1, &v11);
      for (int x = 0; x + 1 < w; ++x) {
        const bool b00 = b10, b01 = b11;
        v00 = v10;
        v01 = v11;
        b10 = vertex(x + 1, y, &v10);
        b11 = vertex(x + 1, y + 1, &v11);
        // Two triangles per quad; with one corner missing, the triangle of the other three.
        if (b00 && b10 && b11) raster(v00, v10, v11, band_j0, band_j1);
        if (b00 && b11 && b01) raster(v00, v11, v01, band_j0, band_j1);
        if (!b11 && b00 && b10 && b01) raster(v00, v10, v01, band_j0, band_j1);
        if (!b00 && b10 && b11 && b01) raster(v10, v11, v01, band_j0, band_j1);
      }
    }
  });
  return hf;
}

}  // namespace mesoscan
