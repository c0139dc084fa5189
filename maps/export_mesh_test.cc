#include "maps/export_mesh.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <random>
#include <set>

namespace mesoscan {
namespace {

HeightField MakeGrid(int w, int h, const std::function<double(int, int)>& z) {
  HeightField hf;
  hf.z = ImageF(w, h, 1);
  hf.pixel_size = 1e-4;
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) hf.z(i, j) = static_cast<float>(z(i, j));
  return hf;
}

// Independent check of a mesh against its grid: rasterises every triangle in double
// (barycentric with a small epsilon), returns the max |z - mesh| over the samples inside and
// counts samples inside a triangle that are holes.
struct Raster {
  double max_error = 0;
  int64_t holes_inside = 0;
  int64_t covered = 0;
};
Raster Rasterise(const HeightField& hf, const GridMesh& m) {
  Raster r;
  const int w = hf.width();
  std::vector<uint8_t> cov(hf.z.pixels(), 0);
  for (int64_t t = 0; t < m.triangles(); ++t) {
    double x[3], y[3], z[3];
    for (int k = 0; k < 3; ++k) {
      const int p = m.vertex_pixel[m.indices[3 * t + k]];
      x[k] = p % w, y[k] = p / w, z[k] = hf.z(p % w, p / w);
    }
    const double det = (y[1] - y[2]) * (x[0] - x[2]) + (x[2] - x[1]) * (y[0] - y[2]);
    for (int yy = static_cast<int>(std::min({y[0], y[1], y[2]}));
         yy <= static_cast<int>(std::max({y[0], y[1], y[2]})); ++yy) {
      for (int xx = static_cast<int>(std::min({x[0], x[1], x[2]}));
           xx <= static_cast<int>(std::max({x[0], x[1], x[2]})); ++xx) {
        const double l0 = ((y[1] - y[2]) * (xx - x[2]) + (x[2] - x[1]) * (yy - y[2])) / det;
        const double l1 = ((y[2] - y[0]) * (xx - x[2]) + (x[0] - x[2]) * (yy - y[2])) / det;
        const double l2 = 1 - l0 - l1;
        if (l0 < -1e-12 || l1 < -1e-12 || l2 < -1e-12) continue;
        const double zs = hf.z(xx, yy);
        if (!std::isfinite(zs)) {
          ++r.holes_inside;
          continue;
        }
        r.max_error = std::max(r.max_error, std::abs(zs - (l0 * z[0] + l1 * z[1] + l2 * z[2])));
        cov[static_cast<size_t>(yy) * w + xx] = 1;
      }
    }
  }
  for (uint8_t c : cov) r.covered += c;
  return r;
}

// Crack-free: no mesh vertex lies strictly inside another triangle's edge (a T-junction).
int64_t CountTJunctions(const HeightField& hf, const GridMesh& m) {
  const int w = hf.width();
  std::set<int32_t> verts(m.vertex_pixel.begin(), m.vertex_pixel.end());
  int64_t n = 0;
  for (int64_t t = 0; t < m.triangles(); ++t) {
    for (int e = 0; e < 3; ++e) {
      const int p = m.vertex_pixel[m.indices[3 * t + e]],
                q = m.vertex_pixel[m.indices[3 * t + (e + 1) % 3]];
      const int px = p % w, py = p / w, qx = q % w, qy = q / w;
      const int sx = (qx > px) - (qx < px), sy = (qy > py) - (qy < py);
      // RTIN edges are axis-aligned or diagonal: step one grid point at a time.
      for (int x = px + sx, y = py + sy; x != qx || y != qy; x += sx, y += sy)
        n += verts.count(y * w + x);
    }
  }
  return n;
}

TEST(ExportMesh, LosslessBudgetGivesTheFullGridMesh) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1e-3);
  const HeightField hf = MakeGrid(37, 23, [&](int, int) { return u(rng); });
  GridMeshOptions o;
  o.max_triangles = 1 << 30;
  const GridMesh m = TriangulateHeightField(hf, o);
  EXPECT_EQ(m.triangles(), 2 * 36 * 22);
  EXPECT_EQ(m.lossless_triangles, 2 * 36 * 22);
  EXPECT_EQ(m.vertices(), 37 * 23);
  EXPECT_EQ(m.max_height_error_m, 0.0);
  EXPECT_EQ(m.uncovered_samples, 0);
  EXPECT_TRUE(m.budget_met);
  const Raster r = Rasterise(hf, m);
  EXPECT_LT(r.max_error, 1e-12);
  EXPECT_EQ(r.covered, 37 * 23);
}

TEST(ExportMesh, TriangleWindingIsCounterClockwiseSeenFromAbove) {
  const HeightField hf = MakeGrid(9, 9, [](int i, int j) { return 1e-5 * (i * i + j); });
  const GridMesh m = TriangulateHeightField(hf, {});
  for (int64_t t = 0; t < m.triangles(); ++t) {
    double x[3], y[3];
    for (int k = 0; k < 3; ++k) {
      const int p = m.vertex_pixel[m.indices[3 * t + k]];
      x[k] = hf.X(p % 9), y[k] = hf.Y(p / 9);
    }
    const double cross = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    ASSERT_GT(cross, 0) << "triangle " << t;
  }
}

TEST(ExportMesh, PlaneCollapsesToTheRootTriangles) {
  // A tilted plane (float heights: the tolerance covers float rounding, 1e-9 m >> 6e-8 * 1e-4).
  const HeightField hf = MakeGrid(65, 65, [](int i, int j) { return 1e-5 * i + 2e-6 * j + 1e-4; });
  GridMeshOptions o;
  o.tolerance_m = 1e-9;
  const GridMesh m = TriangulateHeightField(hf, o);
  EXPECT_EQ(m.triangles(), 2);
  EXPECT_EQ(m.vertices(), 4);
  EXPECT_LT(m.max_height_error_m, 1e-9);
  EXPECT_EQ(m.uncovered_samples, 0);
}

TEST(ExportMesh, BudgetIsMetAndTheStatedErrorIsTheTrueError) {
  // 257 x 129: blocks of 128 tile it exactly (no padding, whose edges would be forced).
  const int w = 257, h = 129;
  const HeightField hf = MakeGrid(w, h, [](int i, int j) {
    const double x = i - 128.0, y = j - 64.0;
    return 5e-4 * std::exp(-(x * x + y * y) / (2 * 40.0 * 40.0)) +
           2e-5 * std::sin(0.3 * i) * std::cos(0.2 * j);
  });
  double previous_error = std::numeric_limits<double>::infinity();
  for (int64_t budget : {500, 4000, 30000}) {
    GridMeshOptions o;
    o.max_triangles = budget;
    const GridMesh m = TriangulateHeightField(hf, o);
    EXPECT_LE(m.triangles(), budget);
    // RTIN splits in pairs of diamonds: the budget is used up to a small fraction.
    EXPECT_GE(m.triangles(), budget * 0.75) << budget;
    EXPECT_TRUE(m.budget_met);
    const Raster r = Rasterise(hf, m);
    EXPECT_NEAR(r.max_error, m.max_height_error_m, 1e-12) << budget;
    EXPECT_EQ(r.covered, static_cast<int64_t>(w) * h);
    EXPECT_LT(m.max_height_error_m, previous_error);
    previous_error = m.max_height_error_m;
    EXPECT_EQ(CountTJunctions(hf, m), 0) << budget;
  }
}

TEST(ExportMesh, NoTriangleAcrossHolesAndNoCracks) {
  const int w = 130, h = 97;
  const HeightField hf = MakeGrid(w, h, [](int i, int j) {
    const double dx = i - 60.0, dy = j - 40.0;
    if (dx * dx + dy * dy < 15.0 * 15.0) return std::nan("");  // a shadow
    if (i == 100 && j == 80) return std::nan("");              // a single dropped sample
    return 3e-4 * std::sin(0.05 * i) + 1e-4 * std::cos(0.07 * j);
  });
  for (int64_t budget : {3000, 1 << 30}) {
    GridMeshOptions o;
    o.max_triangles = budget;
    const GridMesh m = TriangulateHeightField(hf, o);
    for (int32_t p : m.vertex_pixel) ASSERT_TRUE(std::isfinite(hf.z.data()[p]));
    const Raster r = Rasterise(hf, m);
    EXPECT_EQ(r.holes_inside, 0) << budget;
    EXPECT_NEAR(r.max_error, m.max_height_error_m, 1e-12);
    EXPECT_EQ(CountTJunctions(hf, m), 0) << budget;
    EXPECT_EQ(r.covered + m.uncovered_samples, m.valid_samples);
    if (m.budget_met) {
      EXPECT_LE(m.triangles(), budget);
    }
  }
}

TEST(ExportMesh, RejectsABadBudget) {
  GridMeshOptions o;
  o.max_triangles = 0;
  EXPECT_THROW(o.Check(), Error);
}

}  // namespace
}  // namespace mesoscan
