#include "maps/export_mesh.h"

#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>

#include "core/error.h"
#include "core/log.h"
#include "core/parallel.h"

namespace mesoscan {

void GridMeshOptions::Check() const {
  if (max_triangles <= 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("GridMeshOptions.max_triangles"),
                          "expected a positive number, got " << max_triangles);
  if (!(tolerance_m >= 0.0) || !std::isfinite(tolerance_m))
    MESOSCAN_BAD_INPUT("export: mesh tolerance: expected a finite number >= 0 (metres)");
}

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
// Largest RTIN block side (samples - 1). Blocks tile the grid; larger blocks allow coarser
// meshes (2 root triangles per block), smaller ones may avoid padding beyond the grid.
constexpr int kMaxBlock = 256;

// The RTIN hierarchy over a grid padded to blocks of side `block_` (a power of two). Grid
// coordinates (x = column, y = row). At size s (2, 4, ..., block_), with h = s / 2:
//  - "axis" triangles have an axis-aligned hypotenuse of length s (midpoints at the edge
//    midpoints of the s-lattice) and their apex at the centre of an adjacent s-square;
//  - "diagonal" triangles have the diagonal of an s-square as hypotenuse (midpoint at the square
//    centre). Square (qi, qj) of the s-lattice has its diagonal along +x+y iff qi + qj is even
//    (the 4-8 mesh pattern, consistent across all sizes).
// The error of a midpoint is the max of its own interpolation error and the errors of the
// midpoints of the (up to 4) children of the (up to 2) triangles sharing it: so a triangle is
// split whenever any descendant would be, which keeps the mesh crack-free (mapbox/martini).
class Rtin {
 public:
  explicit Rtin(const HeightField& hf) : hf_(hf), w_(hf.width()), h_(hf.height()) {
    // Block side: the padding beyond the grid is a hole, so its edge is fully subdivided (about
    // 4 triangles per edge sample), while every block costs 2 root triangles. Pick the side
    // (power of two, 2..kMaxBlock) with the least of these forced triangles; ties: the larger.
    int64_t best = std::numeric_limits<int64_t>::max();
    for (int b = 2; b <= kMaxBlock; b *= 2) {
      const int64_t nbx = std::max(1, (w_ - 1 + b - 1) / b),
                    nby = std::max(1, (h_ - 1 + b - 1) / b);
      const int64_t cost =
          2 * nbx * nby + ((w_ - 1) % b ? 4 * h_ : 0) + ((h_ - 1) % b ? 4 * w_ : 0);
      if (cost <= best) best = cost, block_ = b;
    }
    nbx_ = std::max(1, (w_ - 1 + block_ - 1) / block_);
    nby_ = std::max(1, (h_ - 1 + block_ - 1) / block_);
    pw_ = nbx_ * block_ + 1;
    ph_ = nby_ * block_ + 1;
    err_.assign(static_cast<size_t>(pw_) * ph_, 0.0f);
  }

  void ComputeErrors() {
    for (int s = 2; s <= block_; s *= 2) {
      AxisStep(s);
      DiagonalStep(s);
    }
  }

  // Number of triangles the mesh has at threshold t (a triangle is split iff the error at its
  // hypotenuse midpoint is > t).
  int64_t Emitted(float t) const {
    const int64_t above2 = CountAbove(errs2_, t), above1 = CountAbove(errs1_, t);
    return base_ + 2 * above2 + above1;
  }

  // Splits the midpoint errors into the count tables used by Emitted().
  void BuildCounts() {
    // Leaf (unit) triangles with an unknown corner are always reached and always dropped.
    int64_t dropped = 0;
    for (int cy = 0; cy + 1 < ph_; ++cy) {
      for (int cx = 0; cx + 1 < pw_; ++cx) {
        const bool v00 = Valid(cx, cy), v10 = Valid(cx + 1, cy), v01 = Valid(cx, cy + 1),
                   v11 = Valid(cx + 1, cy + 1);
        if (((cx + cy) & 1) == 0) {  // diagonal (cx,cy)-(cx+1,cy+1)
          dropped += !(v00 && v11 && v10);
          dropped += !(v00 && v11 && v01);
        } else {  // diagonal (cx,cy+1)-(cx+1,cy)
          dropped += !(v01 && v10 && v00);
          dropped += !(v01 && v10 && v11);
        }
      }
    }
    int64_t forced = 0;
    ForEachMidpoint([&](int x, int y, int mult) {
      const float e = Err(x, y);
      if (e == kInf)
        forced += mult;
      else if (mult == 2)
        errs2_.push_back(e);
      else
        errs1_.push_back(e);
    });
    base_ = 2 * static_cast<int64_t>(nbx_) * nby_ + forced - dropped;
    max_finite_ = 0.0f;
    for (float e : errs2_) max_finite_ = std::max(max_finite_, e);
    for (float e : errs1_) max_finite_ = std::max(max_finite_, e);
  }

  int64_t base() const { return base_; }
  float max_finite() const { return max_finite_; }

  // Emits the triangles at threshold t as grid pixel triples, counter-clockwise seen from +z.
  std::vector<std::array<int32_t, 3>> Extract(float t) const {
    std::vector<std::vector<std::array<int32_t, 3>>> per_block(static_cast<size_t>(nbx_) * nby_);
    ParallelFor(static_cast<int64_t>(per_block.size()), [&](int64_t b) {
      const int bx = static_cast<int>(b % nbx_), by = static_cast<int>(b / nbx_);
      const int h = block_ / 2, x = bx * block_ + h, y = by * block_ + h;
      auto& out = per_block[b];
      if (((bx + by) & 1) == 0) {
        Visit(x - h, y - h, x + h, y + h, x + h, y - h, t, &out);
        Visit(x + h, y + h, x - h, y - h, x - h, y + h, t, &out);
      } else {
        Visit(x - h, y + h, x + h, y - h, x - h, y - h, t, &out);
        Visit(x + h, y - h, x - h, y + h, x + h, y + h, t, &out);
      }
    });
    std::vector<std::array<int32_t, 3>> all;
    size_t n = 0;
    for (const auto& v : per_block) n += v.size();
    all.reserve(n);
    for (const auto& v : per_block) all.insert(all.end(), v.begin(), v.end());
    return all;
  }

 private:
  bool Valid(int x, int y) const { return x < w_ && y < h_ && std::isfinite(hf_.z(x, y)); }
  float& Err(int x, int y) { return err_[static_cast<size_t>(y) * pw_ + x]; }
  float Err(int x, int y) const { return err_[static_cast<size_t>(y) * pw_ + x]; }

  // Own error of midpoint m of hypotenuse a-b with apexes c1, c2 (c2 may be absent).
  float Own(int mx, int my, int ax, int ay, int bx, int by, int c1x, int c1y, bool has_c1, int c2x,
            int c2y, bool has_c2) const {
    if (!Valid(mx, my) || !Valid(ax, ay) || !Valid(bx, by) || (has_c1 && !Valid(c1x, c1y)) ||
        (has_c2 && !Valid(c2x, c2y)))
      return kInf;
    const double interp = 0.5 * (static_cast<double>(hf_.z(ax, ay)) + hf_.z(bx, by));
    return static_cast<float>(std::abs(hf_.z(mx, my) - interp));
  }

  void AxisStep(int s) {
    const int h = s / 2, q = h / 2;  // q: child midpoint offset (0: children are leaves)
    // Horizontal edges: x = h (mod s), y = 0 (mod s). Vertical: x = 0 (mod s), y = h (mod s).
    const int rows = (ph_ - 1) / h + 1;  // every row index that is a multiple of h
    ParallelForRows(rows, [&](int r0, int r1) {
      for (int r = r0; r < r1; ++r) {
        const int y = r * h;
        const bool horizontal_row = (y % s) == 0;
        const int x_start = horizontal_row ? h : 0;
        for (int x = x_start; x < pw_; x += s) {
          float e;
          if (horizontal_row) {
            const bool up = y - h >= 0, down = y + h < ph_;
            e = Own(x, y, x - h, y, x + h, y, x, y - h, up, x, y + h, down);
            if (q > 0 && e != kInf) {
              if (up) e = std::max({e, Err(x - q, y - q), Err(x + q, y - q)});
              if (down) e = std::max({e, Err(x - q, y + q), Err(x + q, y + q)});
            }
          } else {
            const bool left = x - h >= 0, right = x + h < pw_;
            e = Own(x, y, x, y - h, x, y + h, x - h, y, left, x + h, y, right);
            if (q > 0 && e != kInf) {
              if (left) e = std::max({e, Err(x - q, y - q), Err(x - q, y + q)});
              if (right) e = std::max({e, Err(x + q, y - q), Err(x + q, y + q)});
            }
          }
          Err(x, y) = e;
        }
      }
    });
  }

  void DiagonalStep(int s) {
    const int h = s / 2;
    const int rows = (ph_ - 1) / s;
    ParallelForRows(rows, [&](int r0, int r1) {
      for (int qj = r0; qj < r1; ++qj) {
        const int y = qj * s + h;
        for (int qi = 0; qi * s + h < pw_; ++qi) {
          const int x = qi * s + h;
          int ax, ay, bx, by, c1x, c1y, c2x, c2y;
          Diagonal(x, y, h, ((qi + qj) & 1) == 0, &ax, &ay, &bx, &by, &c1x, &c1y, &c2x, &c2y);
          float e = Own(x, y, ax, ay, bx, by, c1x, c1y, true, c2x, c2y, true);
          if (e != kInf) {
            // Children of each triangle: midpoints of a-c and c-b (edges of the square).
            e = std::max({e, Err((ax + c1x) / 2, (ay + c1y) / 2),
                          Err((c1x + bx) / 2, (c1y + by) / 2), Err((ax + c2x) / 2, (ay + c2y) / 2),
                          Err((c2x + bx) / 2, (c2y + by) / 2)});
          }
          Err(x, y) = e;
        }
      }
    });
  }

  static void Diagonal(int x, int y, int h, bool main, int* ax, int* ay, int* bx, int* by, int* c1x,
                       int* c1y, int* c2x, int* c2y) {
    if (main) {
      *ax = x - h, *ay = y - h, *bx = x + h, *by = y + h;
      *c1x = x + h, *c1y = y - h, *c2x = x - h, *c2y = y + h;
    } else {
      *ax = x - h, *ay = y + h, *bx = x + h, *by = y - h;
      *c1x = x - h, *c1y = y - h, *c2x = x + h, *c2y = y + h;
    }
  }

  // fn(x, y, mult) for every midpoint of the hierarchy; mult = number of triangles sharing it.
  template <typename Fn>
  void ForEachMidpoint(Fn&& fn) const {
    for (int s = 2; s <= block_; s *= 2) {
      const int h = s / 2;
      for (int y = 0; y < ph_; y += h) {
        const bool horizontal_row = (y % s) == 0;
        for (int x = horizontal_row ? h : 0; x < pw_; x += s) {
          const int mult =
              horizontal_row ? (y - h >= 0) + (y + h < ph_) : (x - h >= 0) + (x + h < pw_);
          fn(x, y, mult);
        }
      }
      for (int y = h; y < ph_; y += s)
        for (int x = h; x < pw_; x += s) fn(x, y, 2);
    }
  }

  static int64_t CountAbove(const std::vector<float>& v, float t) {
    return tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, v.size(), 1 << 16), int64_t{0},
        [&](const tbb::blocked_range<size_t>& r, int64_t acc) {
          for (size_t i = r.begin(); i != r.end(); ++i) acc += v[i] > t;
          return acc;
        },
        std::plus<int64_t>());
  }

  // Triangle with hypotenuse a-b and apex c: split at the hypotenuse midpoint or emit.
  void Visit(int ax, int ay, int bx, int by, int cx, int cy, float t,
             std::vector<std::array<int32_t, 3>>* out) const {
    const bool leaf = std::abs(ax - bx) <= 1 && std::abs(ay - by) <= 1;
    if (!leaf) {
      const int mx = (ax + bx) / 2, my = (ay + by) / 2;
      if (Err(mx, my) > t) {
        Visit(ax, ay, cx, cy, mx, my, t, out);
        Visit(cx, cy, bx, by, mx, my, t, out);
        return;
      }
    }
    if (!Valid(ax, ay) || !Valid(bx, by) || !Valid(cx, cy)) return;
    // Counter-clockwise in world (x = i, y = -j) is clockwise in grid coordinates.
    const int64_t cross =
        static_cast<int64_t>(bx - ax) * (cy - ay) - static_cast<int64_t>(by - ay) * (cx - ax);
    const int32_t pa = ay * w_ + ax, pb = by * w_ + bx, pc = cy * w_ + cx;
    if (cross < 0)
      out->push_back({pa, pb, pc});
    else
      out->push_back({pa, pc, pb});
  }

  const HeightField& hf_;
  int w_, h_;
  int block_, nbx_, nby_, pw_, ph_;
  std::vector<float> err_;
  std::vector<float> errs2_, errs1_;  // finite midpoint errors shared by 2 / 1 triangles
  int64_t base_ = 0;
  float max_finite_ = 0.0f;
};

// Max |z - plane| over the grid samples inside each triangle; marks covered samples.
double MeasureMaxError(const HeightField& hf, const std::vector<std::array<int32_t, 3>>& tris,
                       std::vector<uint8_t>* covered) {
  const int w = hf.width();
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, tris.size(), 4096), 0.0,
      [&](const tbb::blocked_range<size_t>& r, double acc) {
        for (size_t k = r.begin(); k != r.end(); ++k) {
          int px[3], py[3];
          double pz[3];
          for (int v = 0; v < 3; ++v) {
            px[v] = tris[k][v] % w, py[v] = tris[k][v] / w;
            pz[v] = hf.z(px[v], py[v]);
          }
          const int64_t area = static_cast<int64_t>(px[1] - px[0]) * (py[2] - py[0]) -
                               static_cast<int64_t>(py[1] - py[0]) * (px[2] - px[0]);
          const int x0 = std::min({px[0], px[1], px[2]}), x1 = std::max({px[0], px[1], px[2]});
          const int y0 = std::min({py[0], py[1], py[2]}), y1 = std::max({py[0], py[1], py[2]});
          for (int y = y0; y <= y1; ++y) {
            for (int x = x0; x <= x1; ++x) {
              // Edge functions (barycentric weights times the doubled area), inclusive.
              const int64_t l0 = static_cast<int64_t>(px[2] - px[1]) * (y - py[1]) -
                                 static_cast<int64_t>(py[2] - py[1]) * (x - px[1]);
              const int64_t l1 = static_cast<int64_t>(px[0] - px[2]) * (y - py[2]) -
                                 static_cast<int64_t>(py[0] - py[2]) * (x - px[2]);
              const int64_t l2 = area - l0 - l1;
              const bool inside =
                  area < 0 ? (l0 <= 0 && l1 <= 0 && l2 <= 0) : (l0 >= 0 && l1 >= 0 && l2 >= 0);
              if (!inside) continue;
              const double z = hf.z(x, y);
              MESOSCAN_DCHECK(std::isfinite(z));
              const double interp =
                  (static_cast<double>(l0) * pz[0] + static_cast<double>(l1) * pz[1] +
                   static_cast<double>(l2) * pz[2]) /
                  static_cast<double>(area);
              acc = std::max(acc, std::abs(z - interp));
              std::atomic_ref<uint8_t>((*covered)[static_cast<size_t>(y) * w + x])
                  .store(1, std::memory_order_relaxed);
            }
          }
        }
        return acc;
      },
      [](double a, double b) { return std::max(a, b); });
}

}  // namespace

GridMesh TriangulateHeightField(const HeightField& hf, const GridMeshOptions& options) {
  options.Check();
  GridMesh mesh;
  const int w = hf.width(), h = hf.height();
  for (size_t i = 0; i < hf.z.pixels(); ++i) mesh.valid_samples += std::isfinite(hf.z.data()[i]);
  if (w < 2 || h < 2) {
    mesh.uncovered_samples = mesh.valid_samples;
    return mesh;
  }
  // 1. Midpoint errors, finest level first.
  Rtin rtin(hf);
  rtin.ComputeErrors();
  rtin.BuildCounts();
  // 2. The smallest threshold (>= tolerance) that meets the budget: Emitted() is monotone, so
  // bisect over the bit patterns of non-negative floats (ordered like their values).
  const float tol = static_cast<float>(options.tolerance_m);
  // Threshold -1 splits everything: the full grid mesh, every covered sample a vertex.
  mesh.lossless_triangles = rtin.Emitted(-1.0f);
  float t = tol;
  if (tol == 0.0f && mesh.lossless_triangles <= options.max_triangles) {
    t = -1.0f;
  } else if (rtin.Emitted(tol) > options.max_triangles) {
    if (rtin.Emitted(rtin.max_finite()) > options.max_triangles) {
      t = std::max(tol, rtin.max_finite());
      mesh.budget_met = false;
    } else {
      uint32_t lo = std::bit_cast<uint32_t>(tol), hi = std::bit_cast<uint32_t>(rtin.max_finite());
      while (hi - lo > 1) {
        const uint32_t mid = lo + (hi - lo) / 2;
        if (rtin.Emitted(std::bit_cast<float>(mid)) <= options.max_triangles)
          hi = mid;
        else
          lo = mid;
      }
      t = std::bit_cast<float>(hi);
    }
  }
  mesh.threshold_m = std::max(t, 0.0f);
  // 3. Triangles, then vertices in first-use order.
  const auto tris = rtin.Extract(t);
  MESOSCAN_CHECK_EQ(static_cast<int64_t>(tris.size()), rtin.Emitted(t));
  std::vector<int32_t> vertex_of(static_cast<size_t>(w) * h, -1);
  mesh.indices.reserve(tris.size() * 3);
  for (const auto& tri : tris) {
    for (int32_t p : tri) {
      int32_t& v = vertex_of[p];
      if (v < 0) {
        v = static_cast<int32_t>(mesh.vertex_pixel.size());
        mesh.vertex_pixel.push_back(p);
      }
      mesh.indices.push_back(static_cast<uint32_t>(v));
    }
  }
  // 4. The true error bound and the samples no triangle covers.
  std::vector<uint8_t> covered(static_cast<size_t>(w) * h, 0);
  mesh.max_height_error_m = MeasureMaxError(hf, tris, &covered);
  for (size_t i = 0; i < covered.size(); ++i)
    mesh.uncovered_samples += !covered[i] && std::isfinite(hf.z.data()[i]);
  if (!mesh.budget_met)
    MESOSCAN_LOG(kWarning) << "export: the holes alone need " << rtin.base()
                           << " triangles, more than the budget of " << options.max_triangles;
  return mesh;
}

}  // namespace mesoscan
