#include "maps/maps_fill.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <opencv2/photo.hpp>
#include <random>
#include <vector>

#include "core/numbers.h"

namespace mesoscan {
namespace {

// A smooth synthetic surface (metres) on a 240 x 200 grid of 20 um: a tilt, a bend and two
// waves of 2.4 and 3.1 mm, up to ~150 um of relief.
HeightField Surface() {
  HeightField hf;
  hf.pixel_size = 20e-6;
  hf.z = ImageF(240, 200, 1);
  for (int y = 0; y < 200; ++y)
    for (int x = 0; x < 240; ++x) {
      const double u = x * hf.pixel_size, v = y * hf.pixel_size;
      hf.z(x, y) = static_cast<float>(1e-3 + 0.02 * u - 0.01 * v + 3.0 * (u - 2e-3) * (u - 2e-3) +
                                      40e-6 * std::sin(2 * kPi * u / 2.4e-3 + 0.3) *
                                          std::cos(2 * kPi * v / 3.1e-3) +
                                      20e-6 * std::sin(2 * kPi * (u + v) / 1.7e-3));
    }
  return hf;
}

struct Disc {
  int cx, cy, r;
};
const std::vector<Disc> kDiscs = {{40, 40, 6}, {120, 60, 12}, {190, 140, 18}, {70, 150, 9}};

HeightField WithHoles(const HeightField& truth, std::vector<int>* disc_of) {
  HeightField hf = truth;
  disc_of->assign(hf.z.pixels(), -1);
  for (size_t k = 0; k < kDiscs.size(); ++k)
    for (int y = 0; y < hf.height(); ++y)
      for (int x = 0; x < hf.width(); ++x) {
        const int dx = x - kDiscs[k].cx, dy = y - kDiscs[k].cy;
        if (dx * dx + dy * dy <= kDiscs[k].r * kDiscs[k].r) {
          hf.z(x, y) = std::numeric_limits<float>::quiet_NaN();
          (*disc_of)[y * hf.width() + x] = static_cast<int>(k);
        }
      }
  return hf;
}

double Lap(const ImageF& z, int x, int y) {
  return static_cast<double>(z(x + 1, y)) + z(x - 1, y) + z(x, y + 1) + z(x, y - 1) - 4.0 * z(x, y);
}

// Discrete maximum principle: e = truth - fill solves lap e = lap truth in the hole, e = 0 on
// its border, so |e| <= M/4 (Rb^2 - |x - c|^2) with M = max |lap truth| over the hole and Rb
// the largest distance from c to a border pixel (a comparison function: lap of |x|^2 is 4).
TEST(MapsFill, HarmonicFillWithinTheMaximumPrincipleBound) {
  const HeightField truth = Surface();
  std::vector<int> disc_of;
  const HeightField holes = WithHoles(truth, &disc_of);
  const FillResult r = FillHoles(holes, FillOptions{});
  EXPECT_EQ(r.holes_filled, static_cast<int64_t>(kDiscs.size()));
  EXPECT_EQ(r.holes_left, 0);
  std::vector<double> lap_max(kDiscs.size(), 0.0), rb2(kDiscs.size(), 0.0);
  const int w = truth.width();
  for (int y = 1; y + 1 < truth.height(); ++y)
    for (int x = 1; x + 1 < w; ++x) {
      const int k = disc_of[y * w + x];
      if (k >= 0) lap_max[k] = std::max(lap_max[k], std::abs(Lap(truth.z, x, y)));
      for (int d = 0; d < static_cast<int>(kDiscs.size()) && k < 0; ++d) {
        // Border pixels: measured, with a hole neighbour.
        bool border = false;
        for (auto [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}})
          border = border || disc_of[(y + dy) * w + x + dx] == d;
        if (border) {
          const double ex = x - kDiscs[d].cx, ey = y - kDiscs[d].cy;
          rb2[d] = std::max(rb2[d], ex * ex + ey * ey);
        }
      }
    }
  double err2 = 0, bound2 = 0;
  int64_t n = 0;
  // OpenCV's inpainting takes 8-bit or 16-bit images (its Telea path mishandles float): the
  // heights are quantised to 16 bits over their range (steps of ~3 nm).
  double zlo = 1e9, zhi = -1e9;
  for (float v : truth.z.data()) zlo = std::min<double>(zlo, v), zhi = std::max<double>(zhi, v);
  const double q = (zhi - zlo) / 65535.0;
  cv::Mat src(truth.height(), w, CV_16U), mask(truth.height(), w, CV_8U);
  for (int y = 0; y < truth.height(); ++y)
    for (int x = 0; x < w; ++x) {
      const int k = disc_of[y * w + x];
      src.at<uint16_t>(y, x) =
          k >= 0 ? 0 : static_cast<uint16_t>(std::lround((truth.z(x, y) - zlo) / q));
      mask.at<uint8_t>(y, x) = k >= 0 ? 255 : 0;
      if (k < 0) {
        EXPECT_EQ(r.field.z(x, y), truth.z(x, y));
        EXPECT_EQ(r.filled(x, y), 0);
        continue;
      }
      EXPECT_EQ(r.filled(x, y), 1);
      EXPECT_EQ(r.field.confidence(x, y), 0.0f);
      const double ex = x - kDiscs[k].cx, ey = y - kDiscs[k].cy;
      const double bound = lap_max[k] / 4 * (rb2[k] - ex * ex - ey * ey) + 1e-9;  // + float32
      const double e = r.field.z(x, y) - truth.z(x, y);
      EXPECT_LE(std::abs(e), bound) << x << "," << y;
      err2 += e * e, bound2 += bound * bound, ++n;
    }
  const double rms = std::sqrt(err2 / n), rms_bound = std::sqrt(bound2 / n);
  // The plain baseline: OpenCV's inpainting (Telea; Navier-Stokes), radius 3.
  double telea2 = 0, ns2 = 0;
  cv::Mat telea, ns;
  cv::inpaint(src, mask, telea, 3, cv::INPAINT_TELEA);
  cv::inpaint(src, mask, ns, 3, cv::INPAINT_NS);
  for (int y = 0; y < truth.height(); ++y)
    for (int x = 0; x < w; ++x)
      if (disc_of[y * w + x] >= 0) {
        telea2 += std::pow(zlo + q * telea.at<uint16_t>(y, x) - truth.z(x, y), 2);
        ns2 += std::pow(zlo + q * ns.at<uint16_t>(y, x) - truth.z(x, y), 2);
      }
  std::cout << "hole RMS error: harmonic " << rms * 1e6 << " um (bound RMS " << rms_bound * 1e6
            << " um); OpenCV inpaint Telea " << std::sqrt(telea2 / n) * 1e6 << " um, NS "
            << std::sqrt(ns2 / n) * 1e6 << " um\n";
  EXPECT_LE(rms, rms_bound);
  EXPECT_LT(rms, std::sqrt(telea2 / n));
  EXPECT_LT(rms, std::sqrt(ns2 / n));
}

// No step at a hole's border: the height steps between filled pixels and their measured
// neighbours are no larger than the true surface's steps on the same pairs (RMS, 1.5x), where
// the old "lowest height" fill made steps of the whole relief.
TEST(MapsFill, NoStepAtTheBorder) {
  const HeightField truth = Surface();
  std::vector<int> disc_of;
  const HeightField holes = WithHoles(truth, &disc_of);
  for (FillMethod m : {FillMethod::kHarmonic, FillMethod::kBiharmonic}) {
    FillOptions o;
    o.method = m;
    const FillResult r = FillHoles(holes, o);
    double fill2 = 0, true2 = 0;
    int64_t n = 0;
    const int w = truth.width();
    for (int y = 1; y + 1 < truth.height(); ++y)
      for (int x = 1; x + 1 < w; ++x) {
        if (disc_of[y * w + x] < 0) continue;
        for (auto [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
          if (disc_of[(y + dy) * w + x + dx] >= 0) continue;
          fill2 += std::pow(r.field.z(x, y) - r.field.z(x + dx, y + dy), 2);
          true2 += std::pow(truth.z(x, y) - truth.z(x + dx, y + dy), 2);
          ++n;
        }
      }
    EXPECT_GT(n, 100);
    EXPECT_LE(std::sqrt(fill2 / n), 1.5 * std::sqrt(true2 / n)) << FillMethodName(m);
  }
}

TEST(MapsFill, BiharmonicBeatsHarmonicOnASmoothSurface) {
  const HeightField truth = Surface();
  std::vector<int> disc_of;
  const HeightField holes = WithHoles(truth, &disc_of);
  double e[2] = {0, 0};
  for (int k = 0; k < 2; ++k) {
    FillOptions o;
    o.method = k == 0 ? FillMethod::kHarmonic : FillMethod::kBiharmonic;
    const FillResult r = FillHoles(holes, o);
    for (size_t p = 0; p < disc_of.size(); ++p)
      if (disc_of[p] >= 0) e[k] += std::pow(r.field.z.data()[p] - truth.z.data()[p], 2);
  }
  std::cout << "hole RMS: harmonic " << std::sqrt(e[0]) << ", biharmonic " << std::sqrt(e[1])
            << " (sum)\n";
  EXPECT_LT(e[1], e[0]);
}

TEST(MapsFill, LargeHolesAndTheOutsideStayHoles) {
  HeightField hf = Surface();
  // A hole touching the left border and a disc of radius 30 px (0.6 mm).
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < hf.width(); ++x) {
      if (x < 5 && y > 50 && y < 80) hf.z(x, y) = NAN;
      if ((x - 150) * (x - 150) + (y - 100) * (y - 100) <= 30 * 30) hf.z(x, y) = NAN;
      if ((x - 40) * (x - 40) + (y - 160) * (y - 160) <= 4 * 4) hf.z(x, y) = NAN;
    }
  FillOptions o;
  o.max_hole_radius_m = 0.4e-3;  // 20 px
  o.fill_border_holes = false;
  const FillResult r = FillHoles(hf, o);
  EXPECT_EQ(r.holes_filled, 1);
  EXPECT_EQ(r.holes_left, 2);
  EXPECT_TRUE(std::isnan(r.field.z(2, 60)));
  EXPECT_TRUE(std::isnan(r.field.z(150, 100)));
  EXPECT_TRUE(std::isfinite(r.field.z(40, 160)));
  // By default a narrow hole at the border (5 px wide) is filled, a wide one is not.
  o.fill_border_holes = true;
  const FillResult rb = FillHoles(hf, o);
  EXPECT_EQ(rb.holes_filled, 2);
  EXPECT_TRUE(std::isfinite(rb.field.z(2, 60)));
  EXPECT_TRUE(std::isnan(rb.field.z(150, 100)));
  o.method = FillMethod::kNone;
  EXPECT_EQ(FillHoles(hf, o).filled_pixels, 0);
  o.method = FillMethod::kHarmonic;
  o.fill_border_holes = true;
  o.max_hole_radius_m = 1.0;
  const FillResult all = FillHoles(hf, o);
  EXPECT_EQ(all.holes_left, 0);
  for (float v : all.field.z.data()) EXPECT_TRUE(std::isfinite(v));
}

TEST(MapsFill, DegenerateInputs) {
  HeightField empty;
  EXPECT_EQ(FillHoles(empty, FillOptions{}).filled_pixels, 0);
  HeightField nan;
  nan.z = ImageF(8, 8, 1, NAN);
  FillOptions o;
  o.fill_border_holes = true;
  const FillResult r = FillHoles(nan, o);
  EXPECT_EQ(r.filled_pixels, 0);
  EXPECT_EQ(r.holes_left, 1);
  EXPECT_THROW(ParseFillMethod("cubic"), Error);
  o.max_hole_radius_m = -1;
  EXPECT_THROW(o.Check(), Error);
}

}  // namespace
}  // namespace mesoscan
