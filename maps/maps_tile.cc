#include "maps/maps_tile.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {

// Summed-area table of value(x, y) (a 0/1 predicate or a double), (w+1) x (h+1).
template <typename T, typename Value>
std::vector<T> Integral(int w, int h, Value&& value) {
  std::vector<T> s(static_cast<size_t>(w + 1) * (h + 1), T(0));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      s[(y + 1) * (w + 1) + x + 1] = static_cast<T>(value(x, y)) + s[y * (w + 1) + x + 1] +
                                     s[(y + 1) * (w + 1) + x] - s[y * (w + 1) + x];
  return s;
}
template <typename T>
T BoxSum(const std::vector<T>& s, int w, int x, int y, int n) {
  return s[(y + n) * (w + 1) + x + n] - s[y * (w + 1) + x + n] - s[(y + n) * (w + 1) + x] +
         s[y * (w + 1) + x];
}

double Sqr(double v) { return v * v; }

// Mean of the finite values of channel c.
double MeanOf(const ImageF& im, int c) {
  double s = 0;
  int64_t n = 0;
  const float* p = im.channel(c);
  for (size_t i = 0; i < im.pixels(); ++i)
    if (std::isfinite(p[i])) s += p[i], ++n;
  return n ? s / n : 0.0;
}

// Normalised autocorrelation of channel 0 of the square `t` at shift s along x (axis 0) or y
// (axis 1), over the overlap without wrapping.
double Autocorrelation(const ImageF& t, int s, int axis) {
  const int n = t.width();
  const double mu = MeanOf(t, 0);
  double c = 0, v = 0;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      const double a = t(x, y) - mu;
      v += a * a;
      const int x2 = axis == 0 ? x + s : x, y2 = axis == 0 ? y : y + s;
      if (x2 < n && y2 < n) c += a * (t(x2, y2) - mu);
    }
  const double overlap = static_cast<double>(n - s) / n;
  return v > 0 ? c / (v * overlap) : 0.0;
}

// How much the shading changes across each line of a map along one axis: for line i (between
// column i and i + 1 for axis 0, rows for axis 1) the mean over the other axis of the change of
// the central-difference gradient vector, |G(i + 1) - G(i)|, which is what a renderer's normals
// (displaced or bumped) see change from one column to the next under any light. Periodic: the
// map is read cyclically; otherwise the lines within 2 pixels of the border are left NaN.
std::vector<double> ShadingChange(const ImageF& z, int axis, bool periodic) {
  const int n = z.width();
  const auto at = [&](int x, int y) { return z((x + n) % n, (y + n) % n); };
  const auto grad = [&](int x, int y, double* g) {
    g[0] = 0.5 * (at(x + 1, y) - at(x - 1, y)), g[1] = 0.5 * (at(x, y + 1) - at(x, y - 1));
  };
  std::vector<double> c(n, std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < n; ++i) {
    if (!periodic && (i < 2 || i > n - 4)) continue;
    double s = 0;
    int64_t k = 0;
    for (int j = periodic ? 0 : 1; j < (periodic ? n : n - 1); ++j) {
      double a[2], b[2];
      if (axis == 0)
        grad(i, j, a), grad(i + 1, j, b);
      else
        grad(j, i, a), grad(j, i + 1, b);
      const double d = std::hypot(b[0] - a[0], b[1] - a[1]);
      if (std::isfinite(d)) s += d, ++k;
    }
    if (k) c[i] = s / k;
  }
  return c;
}

// Per line i of a map along one axis (as ShadingChange): the RMS over the other axis of the
// height step across it, z(i + 1) - z(i) (the seam statistic of MeasureSeams).
std::vector<double> StepRms(const ImageF& z, int axis, bool periodic) {
  const int n = z.width();
  std::vector<double> g(n, std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < (periodic ? n : n - 1); ++i) {
    double s = 0;
    int64_t k = 0;
    for (int j = 0; j < n; ++j) {
      const double d = axis == 0 ? z((i + 1) % n, j) - z(i, j) : z(j, (i + 1) % n) - z(j, i);
      if (std::isfinite(d)) s += d * d, ++k;
    }
    if (k) g[i] = std::sqrt(s / k);
  }
  return g;
}

// (v - mean) / standard deviation of the finite values of a profile (NaN stays NaN).
std::vector<double> Standardised(std::vector<double> v) {
  double m = 0, m2 = 0;
  int k = 0;
  for (const double x : v)
    if (std::isfinite(x)) m += x, m2 += x * x, ++k;
  m = k ? m / k : 0.0;
  const double sd = k ? std::sqrt(std::max(0.0, m2 / k - m * m)) : 0.0;
  for (double& x : v) x = sd > 0 ? (x - m) / sd : 0.0 * x;
  return v;
}

// How far line i is from the typical line of its map, given the standardised profiles of the
// shading change (ShadingChange) and of the height step (StepRms): the RMS of the shading
// change's deviation on the line and its neighbours either side (a renderer may place the line
// a pixel off, and filters over a pixel) and of the step's deviation on the line. A seam placed
// where this is small lies where both the slope and the shading change as on an average line:
// on a weave, neither on a flank's steepest column nor on a crest, and not on the step to one.
double LineAtypicality(const std::vector<double>& change, const std::vector<double>& step, int i) {
  const int n = static_cast<int>(change.size());
  double e = 0;
  for (int d = -1; d <= 1; ++d) {
    const double v = change[((i + d) % n + n) % n];
    e += std::isfinite(v) ? v * v : 1e6;
  }
  e += std::isfinite(step[i]) ? step[i] * step[i] : 1e6;
  return std::sqrt(e / 4);
}

// The offset of the shifted copies along one axis: half the tile, unless a shift in
// [n/3, 2n/3] correlates clearly better with the square (a periodic texture such as a weave:
// the copies then stay in phase with it instead of cancelling it in the blend). Of the shifts
// within 2 pixels of that one whose correlation is within 0.05 of it (the same phase of a weave
// to a few degrees), the one whose blend line (at n - s: the square's own columns, the copy's
// weight 0 there) lies where the square's shading and slope are most typical (LineAtypicality).
int BestShift(const ImageF& t, int axis) {
  const int n = t.width();
  int best = n / 2;
  double best_c =
      Autocorrelation(t, best, axis) + 0.2;  // the half shift wins unless clearly beaten
  for (int s = n / 3; s <= 2 * n / 3; ++s) {
    const double c = Autocorrelation(t, s, axis);
    if (c > best_c) best_c = c, best = s;
  }
  const double ref = Autocorrelation(t, best, axis);
  const std::vector<double> change = Standardised(ShadingChange(t, axis, false));
  const std::vector<double> step = Standardised(StepRms(t, axis, false));
  int pick = best;
  double pick_e = LineAtypicality(change, step, n - best - 1);
  for (int s = std::max(n / 3, best - 2); s <= std::min(2 * n / 3, best + 2); ++s) {
    if (s == best || Autocorrelation(t, s, axis) < ref - 0.05) continue;
    const double e = LineAtypicality(change, step, n - s - 1);
    if (e < pick_e - 1e-9) pick_e = e, pick = s;
  }
  return pick;
}

// Weight of the square itself along one axis: 0 at the tile's edges (its seam), 1 at c = n - s
// where the copy shifted by s has its own seam; sin^2 ramps in between.
std::vector<double> Window(int n, int shift) {
  const double c = n - shift;
  std::vector<double> w(n);
  constexpr double kHalfPi = kPi / 2;
  for (int i = 0; i < n; ++i) {
    const double t = i + 0.5;
    const double s = t <= c ? std::sin(kHalfPi * t / c) : std::sin(kHalfPi * (n - t) / (n - c));
    w[i] = s * s;
  }
  return w;
}

// Correlation of channel c's gradient (the steps to the right and lower neighbours) with the
// gradient of the copy shifted by s along x (axis 0) or y (axis 1), over their overlap. The
// blend's copies are taken in phase with a periodic texture, so they are correlated: a blend
// normalised as if they were independent inflates the gradients where the copies mix (the
// tile's interior) against the seams, where one copy dominates.
double GradientCorrelation(const ImageF& t, int c, int s, int axis) {
  const int n = t.width();
  double ab = 0, aa = 0, bb = 0;
  for (int y = 0; y + 1 < n; ++y)
    for (int x = 0; x + 1 < n; ++x) {
      const int x2 = axis == 0 ? x + s : x, y2 = axis == 0 ? y : y + s;
      if (x2 + 1 >= n || y2 + 1 >= n) continue;
      const double ax = t(x + 1, y, c) - t(x, y, c), ay = t(x, y + 1, c) - t(x, y, c);
      const double bx = t(x2 + 1, y2, c) - t(x2, y2, c), by = t(x2, y2 + 1, c) - t(x2, y2, c);
      if (!std::isfinite(ax + ay + bx + by)) continue;
      ab += ax * bx + ay * by, aa += ax * ax + ay * ay, bb += bx * bx + by * by;
    }
  const double rho = aa > 0 && bb > 0 ? ab / std::sqrt(aa * bb) : 0.0;
  return std::clamp(rho, -0.5, 0.95);
}

// Offset-and-blend of a square image (all channels) with matched variance (see the header);
// shifts from the height channel (the same for every map of the set). The normalisation is the
// standard deviation of the weighted sum of the copies given their gradient correlation along
// each axis (separable: rho_xy = rho_x rho_y), so that the gradient statistics, not only the
// value's, are the same where the copies mix as at the seams.
ImageF BlendPeriodic(const ImageF& t, bool preserve_variance, int shift_x, int shift_y) {
  const int n = t.width();
  ImageF out(n, n, t.channels());
  const std::vector<double> wxs = Window(n, shift_x), wys = Window(n, shift_y);
  for (int c = 0; c < t.channels(); ++c) {
    const double mu = preserve_variance ? MeanOf(t, c) : 0.0;
    const double rho_x = preserve_variance ? GradientCorrelation(t, c, shift_x, 0) : 0.0;
    const double rho_y = preserve_variance ? GradientCorrelation(t, c, shift_y, 1) : 0.0;
    ParallelForRows(n, [&](int r0, int r1) {
      for (int y = r0; y < r1; ++y) {
        const int ys = (y + shift_y) % n;
        const double wy = wys[y];
        for (int x = 0; x < n; ++x) {
          const int xs = (x + shift_x) % n;
          const double wx = wxs[x];
          const double w[4] = {wx * wy, (1 - wx) * wy, wx * (1 - wy), (1 - wx) * (1 - wy)};
          const double v[4] = {t(x, y, c), t(xs, y, c), t(x, ys, c), t(xs, ys, c)};
          double s = 0;
          for (int k = 0; k < 4; ++k) s += w[k] * (v[k] - mu);
          const double vx = wx * wx + (1 - wx) * (1 - wx) + 2 * wx * (1 - wx) * rho_x;
          const double vy = wy * wy + (1 - wy) * (1 - wy) + 2 * wy * (1 - wy) * rho_y;
          out(x, y, c) = static_cast<float>(mu + (preserve_variance ? s / std::sqrt(vx * vy) : s));
        }
      }
    });
  }
  return out;
}

// The cyclic roll (columns, rows) that puts the wrap-around seam of the periodic height z on
// the line whose slope and shading change are the most typical (LineAtypicality). A periodic
// texture (a weave) has crests (little slope), flanks (much) and the steps between them, where
// the shading changes fast; a seam on any of them stands out in a render as a darker or brighter
// line repeated with the tile. Rolling a periodic tile moves its seam without changing it.
std::array<int, 2> SeamRoll(const ImageF& z) {
  const int n = z.width();
  std::array<int, 2> roll = {0, 0};
  for (int axis = 0; axis < 2; ++axis) {
    const std::vector<double> change = Standardised(ShadingChange(z, axis, true));
    const std::vector<double> step = Standardised(StepRms(z, axis, true));
    // After rolling by r the seam is between the input's columns r - 1 and r.
    double best = std::numeric_limits<double>::max();
    for (int r = 0; r < n; ++r) {
      const double e = LineAtypicality(change, step, (r + n - 1) % n);
      if (e < best - 1e-9) best = e, roll[axis] = r;
    }
  }
  return roll;
}

// out(x, y) = in((x + rx) mod n, (y + ry) mod n), every channel.
template <typename Image>
Image Roll(const Image& in, int rx, int ry) {
  const int n = in.width();
  Image out = in;
  for (int c = 0; c < in.channels(); ++c)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) out(x, y, c) = in((x + rx) % n, (y + ry) % n, c);
  return out;
}

ImageF MirrorPeriodic(const ImageF& t) {
  const int s = t.width(), n = 2 * s;
  ImageF out(n, n, t.channels());
  for (int c = 0; c < t.channels(); ++c)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) out(x, y, c) = t(x < s ? x : n - 1 - x, y < s ? y : n - 1 - y, c);
  return out;
}

ImageF CropSquare(const ImageF& im, int x0, int y0, int n) {
  ImageF out(n, n, im.channels());
  for (int c = 0; c < im.channels(); ++c)
    for (int y = 0; y < n; ++y)
      std::copy(im.row(y0 + y, c) + x0, im.row(y0 + y, c) + x0 + n, out.row(y, c));
  return out;
}

}  // namespace

void TileOptions::Check() const {
  if (!(size_m > 0) || !std::isfinite(size_m))
    MESOSCAN_BAD_OPTION("TileOptions.size_m", size_m * 1e3 << " mm: expected a size > 0");
  // Not a command-line option: a bad value is a caller's bug.
  MESOSCAN_CHECK(mount_clearance_m >= 0 && std::isfinite(mount_clearance_m));
}

TileMethod ParseTileMethod(const std::string& t) {
  if (t == "blend") return TileMethod::kBlend;
  if (t == "mirror") return TileMethod::kMirror;
  MESOSCAN_BAD_OPTION("TileOptions.method", "'" << t << "': expected blend or mirror");
}
const char* TileMethodName(TileMethod m) { return m == TileMethod::kBlend ? "blend" : "mirror"; }

SeamStats MeasureSeams(const ImageF& z) {
  const int w = z.width(), h = z.height();
  SeamStats s;
  double sx = 0, ix = 0, sy = 0, iy = 0;
  int64_t nsx = 0, nix = 0, nsy = 0, niy = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double v = z(x, y);
      const double dx = z((x + 1) % w, y) - v, dy = z(x, (y + 1) % h) - v;
      if (std::isfinite(dx)) {
        if (x == w - 1)
          sx += dx * dx, ++nsx;
        else
          ix += dx * dx, ++nix;
      }
      if (std::isfinite(dy)) {
        if (y == h - 1)
          sy += dy * dy, ++nsy;
        else
          iy += dy * dy, ++niy;
      }
    }
  // Per-column (x) and per-row (y) interior gradient RMS, and their scatter.
  std::vector<double> col2(w, 0.0), row2(h, 0.0);
  std::vector<int64_t> coln(w, 0), rown(h, 0);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double v = z(x, y);
      const double dx = z((x + 1) % w, y) - v, dy = z(x, (y + 1) % h) - v;
      if (std::isfinite(dx)) col2[x] += dx * dx, ++coln[x];
      if (std::isfinite(dy)) row2[y] += dy * dy, ++rown[y];
    }
  auto spread = [](const std::vector<double>& a2, const std::vector<int64_t>& n, double ref) {
    if (ref <= 0) return 0.0;
    double m = 0, m2 = 0;
    int k = 0;
    for (size_t i = 0; i + 1 < a2.size(); ++i) {  // the last one is the seam
      if (n[i] == 0) continue;
      const double r = std::sqrt(a2[i] / n[i]) / ref;
      m += r, m2 += r * r, ++k;
    }
    return k > 1 ? std::sqrt(std::max(0.0, m2 / k - (m / k) * (m / k))) : 0.0;
  };
  s.seam_rms_x = nsx ? std::sqrt(sx / nsx) : 0;
  s.interior_rms_x = nix ? std::sqrt(ix / nix) : 0;
  s.seam_rms_y = nsy ? std::sqrt(sy / nsy) : 0;
  s.interior_rms_y = niy ? std::sqrt(iy / niy) : 0;
  s.column_spread_x = spread(col2, coln, s.interior_rms_x);
  s.row_spread_y = spread(row2, rown, s.interior_rms_y);
  return s;
}

std::string TileResult::BriefReport() const {
  std::ostringstream s;
  s.precision(3);
  s << "tile: " << size_px << " px (" << size_px * field.pixel_size * 1e3 << " mm) from the "
    << src_size << " px square at (" << origin_x + src_x << ", " << origin_y + src_y
    << ") of the height grid (" << (chosen ? "chosen on the sample" : "given") << ": "
    << std::lround(100 * on_sample_fraction) << "% on the sample, "
    << std::lround(100 * measured_on_sample_fraction) << "% measured there, "
    << std::lround(100 * filled_fraction) << "% filled); seam/interior gradient RMS "
    << "x " << seams_after.ratio_x() << ", y " << seams_after.ratio_y() << " (untiled crop: x "
    << seams_before.ratio_x() << ", y " << seams_before.ratio_y() << "); single interior columns "
    << "scatter by " << seams_after.column_spread_x << ", rows by " << seams_after.row_spread_y;
  return s.str();
}

TileResult MakeTile(const HeightField& hf, const ImageF& albedo, const ImageU8& filled,
                    const TileOptions& o, const ImageF& mount_height) {
  o.Check();
  const int w = hf.width(), h = hf.height();
  const int n_target = static_cast<int>(std::lround(o.size_m / hf.pixel_size));
  const int src = o.method == TileMethod::kBlend ? n_target : (n_target + 1) / 2;
  if (n_target < 8)
    MESOSCAN_BAD_OPTION("TileOptions.size_m", o.size_m * 1e3 << " mm: under 8 grid pixels of "
                                                             << hf.pixel_size * 1e6 << " um");
  if (src > w || src > h)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File("height.exr"),
                          "the " << w << "x" << h << " grid (" << w * hf.pixel_size * 1e3 << " x "
                                 << h * hf.pixel_size * 1e3 << " mm) is smaller than the "
                                 << OptionRef{"TileOptions.size_m"} << " square of "
                                 << src * hf.pixel_size * 1e3 << " mm");
  MESOSCAN_CHECK(mount_height.empty() || (mount_height.width() == w && mount_height.height() == h));
  MESOSCAN_CHECK(filled.empty() || (filled.width() == w && filled.height() == h));
  // 1. The square: given, or chosen on the sample (see the header).
  const auto is_filled = [&](int x, int y) { return !filled.empty() && filled(x, y) != 0; };
  const auto on_sample = [&](int x, int y) {
    if (!std::isfinite(hf.z(x, y))) return false;
    return mount_height.empty() || mount_height(x, y) > o.mount_clearance_m;
  };
  const auto measured = [&](int x, int y) { return std::isfinite(hf.z(x, y)) && !is_filled(x, y); };
  const auto holes =
      Integral<int64_t>(w, h, [&](int x, int y) { return !std::isfinite(hf.z(x, y)); });
  const auto fills = Integral<int64_t>(w, h, is_filled);
  const auto on = Integral<int64_t>(w, h, on_sample);
  const auto measured_on =
      Integral<int64_t>(w, h, [&](int x, int y) { return on_sample(x, y) && !is_filled(x, y); });
  // Squared height steps to the right and lower neighbours where both are measured, and how many.
  const auto step2 = Integral<double>(w, h, [&](int x, int y) {
    if (!measured(x, y)) return 0.0;
    double s = 0;
    if (x + 1 < w && measured(x + 1, y)) s += Sqr(hf.z(x + 1, y) - hf.z(x, y));
    if (y + 1 < h && measured(x, y + 1)) s += Sqr(hf.z(x, y + 1) - hf.z(x, y));
    return s;
  });
  const auto steps = Integral<int64_t>(w, h, [&](int x, int y) {
    if (!measured(x, y)) return 0;
    return (x + 1 < w && measured(x + 1, y) ? 1 : 0) + (y + 1 < h && measured(x, y + 1) ? 1 : 0);
  });
  const auto texture2 = [&](int x, int y) {
    const int64_t n = BoxSum(steps, w, x, y, src);
    return n ? BoxSum(step2, w, x, y, src) / static_cast<double>(n) : 0.0;
  };
  int bx = -1, by = -1;
  if (o.at_px) {
    const auto [ax, ay] = *o.at_px;
    bx = ax - o.origin_px[0], by = ay - o.origin_px[1];
    if (bx < 0 || by < 0 || bx + src > w || by + src > h)
      MESOSCAN_BAD_OPTION("TileOptions.at_px", ax << "," << ay << ": the " << src
                                                  << " px square leaves the " << w << "x" << h
                                                  << " map grid at (" << o.origin_px[0] << ", "
                                                  << o.origin_px[1] << ") of the height grid");
    if (const int64_t n = BoxSum(holes, w, bx, by, src); n != 0)
      MESOSCAN_BAD_OPTION("TileOptions.at_px", ax << "," << ay << ": the " << src
                                                  << " px square holds " << n
                                                  << " hole pixels (not filled)");
  } else {
    // The best measured-on-sample count, then the most textured square within the band below it.
    int64_t best_on = -1;
    for (int y = 0; y + src <= h; ++y)
      for (int x = 0; x + src <= w; ++x)
        if (BoxSum(holes, w, x, y, src) == 0)
          best_on = std::max(best_on, BoxSum(measured_on, w, x, y, src));
    const int64_t band = static_cast<int64_t>(kTileBandFraction * src * src);
    const auto in_band = [&](int x, int y) {
      return BoxSum(holes, w, x, y, src) == 0 &&
             BoxSum(measured_on, w, x, y, src) >= best_on - band;
    };
    double best_t2 = 0;
    for (int y = 0; y + src <= h; ++y)
      for (int x = 0; x + src <= w; ++x)
        if (in_band(x, y)) best_t2 = std::max(best_t2, texture2(x, y));
    // Of the textured ones (RMS step within kTileTextureFraction of the best), the most measured
    // on the sample, then the one nearest the sample's centre.
    const double min_t2 = kTileTextureFraction * kTileTextureFraction * best_t2;
    int64_t best_m = -1;
    double best_d = std::numeric_limits<double>::max();
    // The sample's centre: the centroid of its pixels (the grid's centre if it has none).
    double sx = 0, sy = 0, sn = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        if (on_sample(x, y)) sx += x, sy += y, ++sn;
    const double cx = (sn > 0 ? sx / sn : 0.5 * (w - 1)) - 0.5 * (src - 1);
    const double cy = (sn > 0 ? sy / sn : 0.5 * (h - 1)) - 0.5 * (src - 1);
    for (int y = 0; y + src <= h; ++y)
      for (int x = 0; x + src <= w; ++x) {
        if (!in_band(x, y) || texture2(x, y) < min_t2) continue;
        const int64_t m = BoxSum(measured_on, w, x, y, src);
        const double d = (x - cx) * (x - cx) + (y - cy) * (y - cy);
        if (m > best_m || (m == best_m && d < best_d)) best_m = m, best_d = d, bx = x, by = y;
      }
  }
  if (bx < 0)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File("height.exr"),
                          "no hole-free square of "
                              << src * hf.pixel_size * 1e3
                              << " mm in the filled height field; use a smaller "
                              << OptionRef{"TileOptions.size_m"} << " or "
                              << OptionRef{"MapsOptions.crop"});
  TileResult r;
  r.src_x = bx, r.src_y = by, r.src_size = src;
  r.origin_x = o.origin_px[0], r.origin_y = o.origin_px[1];
  r.chosen = !o.at_px.has_value();
  const double area = static_cast<double>(src) * src;
  r.on_sample_fraction = BoxSum(on, w, bx, by, src) / area;
  r.measured_on_sample_fraction = BoxSum(measured_on, w, bx, by, src) / area;
  r.filled_fraction = BoxSum(fills, w, bx, by, src) / area;
  r.texture_rms_m = std::sqrt(texture2(bx, by));
  const ImageF zsq = CropSquare(hf.z, bx, by, src);
  r.seams_before = MeasureSeams(zsq);
  // 2. Periodic height, albedo, confidence and filled mask.
  const bool blend = o.method == TileMethod::kBlend;
  const int shift_x = blend ? BestShift(zsq, 0) : 0, shift_y = blend ? BestShift(zsq, 1) : 0;
  r.shift_x = shift_x, r.shift_y = shift_y;
  auto periodic = [&](const ImageF& sq, bool preserve) {
    return blend ? BlendPeriodic(sq, preserve, shift_x, shift_y) : MirrorPeriodic(sq);
  };
  r.field.z = periodic(zsq, true);
  r.size_px = r.field.z.width();
  r.field.pixel_size = hf.pixel_size;
  r.field.x0 = hf.X(bx);
  r.field.y0 = hf.Y(by);
  if (!hf.confidence.empty())
    r.field.confidence = periodic(CropSquare(hf.confidence, bx, by, src), false);
  if (!albedo.empty()) r.albedo = periodic(CropSquare(albedo, bx, by, src), true);
  if (!filled.empty()) {
    ImageF fsq(src, src, 1);
    for (int y = 0; y < src; ++y)
      for (int x = 0; x < src; ++x) fsq(x, y) = filled(bx + x, by + y) ? 1.0f : 0.0f;
    const ImageF fb = periodic(fsq, false);
    r.filled = ImageU8(r.size_px, r.size_px, 1, 0);
    for (size_t p = 0; p < fb.pixels(); ++p) r.filled.data()[p] = fb.data()[p] > 0.05f ? 1 : 0;
  }
  if (blend) {
    // The wrap seam away from the texture's crests (see SeamRoll); the blend lines, at N - shift
    // in the rolled tile, move with it.
    const auto [rx, ry] = SeamRoll(r.field.z);
    r.field.z = Roll(r.field.z, rx, ry);
    if (!r.field.confidence.empty()) r.field.confidence = Roll(r.field.confidence, rx, ry);
    if (!r.albedo.empty()) r.albedo = Roll(r.albedo, rx, ry);
    if (!r.filled.empty()) r.filled = Roll(r.filled, rx, ry);
    r.shift_x = (shift_x + rx) % r.size_px, r.shift_y = (shift_y + ry) % r.size_px;
  }
  r.seams_after = MeasureSeams(r.field.z);
  return r;
}

ImageU8 OnSampleMask(const HeightField& hf, double clearance_m) {
  ImageU8 mask(hf.width(), hf.height(), 1, 0);
  int64_t finite = 0, on = 0;
  for (const float z : hf.z.data()) {
    finite += std::isfinite(z);
    on += std::isfinite(z) && z > clearance_m;
  }
  const bool split = on >= finite / 100 && finite - on >= finite / 100 && on > 0 && on < finite;
  for (size_t p = 0; p < mask.pixels(); ++p) {
    const float z = hf.z.data()[p];
    mask.data()[p] = std::isfinite(z) && (!split || z > clearance_m) ? 1 : 0;
  }
  return mask;
}

}  // namespace mesoscan
