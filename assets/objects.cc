#include "assets/objects.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace {

double SmoothStep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

// An empty grid covering [x_min, x_max] x [y_min, y_max] plus `margin_cells` zero cells.
HeightField MakeGrid(double x_min, double x_max, double y_min, double y_max, double h,
                     int margin_cells) {
  HeightField hf;
  hf.pixel_size = h;
  const int w = static_cast<int>(std::ceil((x_max - x_min) / h)) + 1 + 2 * margin_cells;
  const int ht = static_cast<int>(std::ceil((y_max - y_min) / h)) + 1 + 2 * margin_cells;
  hf.x0 = x_min - margin_cells * h;
  hf.y0 = y_max + margin_cells * h;
  hf.z = ImageF(w, ht, 1, 0.0f);
  return hf;
}

// Fills height and albedo from fn(x, y, &z, &albedo), rows in parallel. Cells within
// `margin_cells` of the border are forced to z = 0 and the mount albedo.
template <typename Fn>
SceneObject Generate(const std::string& name, HeightField hf, int margin_cells, Fn&& fn) {
  SceneObject obj;
  obj.name = name;
  obj.albedo = ImageF(hf.width(), hf.height(), 1, 0.0f);
  ParallelForRows(hf.height(), [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < hf.width(); ++i) {
        const double x = hf.X(i), y = hf.Y(j);
        double z = 0.0, a = MountAlbedo(x, y);
        const bool border = i < margin_cells || j < margin_cells ||
                            i >= hf.width() - margin_cells || j >= hf.height() - margin_cells;
        if (!border) fn(x, y, &z, &a);
        hf.z(i, j) = static_cast<float>(z);
        obj.albedo(i, j) = static_cast<float>(std::clamp(a, 0.0, 1.0));
      }
  });
  obj.height = std::move(hf);
  return obj;
}

// ---- 5x7 bitmap font: 7 rows of 5, top to bottom, '#' = raised ----
const std::map<char, std::array<const char*, 7>>& Font() {
  static const std::map<char, std::array<const char*, 7>> font = {
      {'A', {".###.", "#...#", "#...#", "#####", "#...#", "#...#", "#...#"}},
      {'C', {".####", "#....", "#....", "#....", "#....", "#....", ".####"}},
      {'E', {"#####", "#....", "#....", "####.", "#....", "#....", "#####"}},
      {'F', {"#####", "#....", "#....", "####.", "#....", "#....", "#...."}},
      {'H', {"#...#", "#...#", "#...#", "#####", "#...#", "#...#", "#...#"}},
      {'I', {"#####", "..#..", "..#..", "..#..", "..#..", "..#..", "#####"}},
      {'L', {"#....", "#....", "#....", "#....", "#....", "#....", "#####"}},
      {'M', {"#...#", "##.##", "#.#.#", "#.#.#", "#...#", "#...#", "#...#"}},
      {'N', {"#...#", "##..#", "#.#.#", "#..##", "#...#", "#...#", "#...#"}},
      {'O', {".###.", "#...#", "#...#", "#...#", "#...#", "#...#", ".###."}},
      {'S', {".####", "#....", "#....", ".###.", "....#", "....#", "####."}},
      {'T', {"#####", "..#..", "..#..", "..#..", "..#..", "..#..", "..#.."}},
      {'0', {".###.", "#...#", "#..##", "#.#.#", "##..#", "#...#", ".###."}},
      {'2', {".###.", "#...#", "....#", "...#.", "..#..", ".#...", "#####"}},
      {'6', {"..##.", ".#...", "#....", "####.", "#...#", "#...#", ".###."}},
      {'*', {".....", "#.#.#", ".###.", "#####", ".###.", "#.#.#", "....."}},
  };
  return font;
}

bool GlyphOn(char c, int col, int row) {
  if (col < 0 || col >= 5 || row < 0 || row >= 7) return false;
  auto it = Font().find(c);
  return it != Font().end() && it->second[row][col] == '#';
}

// Lettering around the coin: text on a circle of radius kTextRadius, letters upright (tops
// outwards), reading clockwise from the top. Returns the raised fraction in [0, 1] with edges
// smoothed over kEdge.
constexpr char kCoinText[] = "MESOSCAN * LENS SHIFT * 2026 *";
constexpr double kFontPx = 0.2e-3;     // bitmap pixel size on the coin
constexpr double kCharPitch = 1.2e-3;  // 5 pixels + 1 gap
constexpr double kTextTop = 8.25e-3;   // radius of the letters' top row
constexpr double kEdge = 25e-6;        // width of the letters' rounded edges

double LetteringAt(double x, double y) {
  const double r = std::hypot(x, y);
  if (r > kTextTop + kEdge || r < kTextTop - 7 * kFontPx - kEdge) return 0.0;
  const double text_len = (sizeof(kCoinText) - 1) * kCharPitch;
  const double radius_mid = kTextTop - 3.5 * kFontPx;
  // Arc length clockwise from the top (+y), centred so the text is symmetric about the top.
  double theta = std::atan2(x, y);  // 0 at +y, positive clockwise (towards +x)
  double s = theta * radius_mid + 0.5 * text_len;
  if (s < -kCharPitch || s > text_len + kCharPitch) {
    s = (theta + (theta < 0 ? 2 * kPi : -2 * kPi)) * radius_mid + 0.5 * text_len;
    if (s < -kCharPitch || s > text_len + kCharPitch) return 0.0;
  }
  const double row_f = (kTextTop - r) / kFontPx;  // 0 at the top row's top edge
  const int ci = static_cast<int>(std::floor(s / kCharPitch));
  double best = 0.0;
  // The raised fraction is the max over nearby "on" font pixels of a box that is 1 inside the
  // pixel and falls smoothly to 0 over kEdge outside it.
  for (int char_index = ci - 1; char_index <= ci + 1; ++char_index) {
    if (char_index < 0 || char_index >= static_cast<int>(sizeof(kCoinText) - 1)) continue;
    const char c = kCoinText[char_index];
    const double local_col = (s - char_index * kCharPitch) / kFontPx;
    if (local_col < -1 || local_col > 6) continue;
    const int col0 = static_cast<int>(std::floor(local_col));
    for (int col = col0 - 1; col <= col0 + 1; ++col)
      for (int row = static_cast<int>(std::floor(row_f)) - 1;
           row <= static_cast<int>(std::floor(row_f)) + 1; ++row) {
        if (!GlyphOn(c, col, row)) continue;
        const double du = std::max({0.0, col - local_col, local_col - (col + 1)}) * kFontPx;
        const double dv = std::max({0.0, row - row_f, row_f - (row + 1)}) * kFontPx;
        const double d = std::hypot(du, dv);
        best = std::max(best, 1.0 - SmoothStep(0.0, kEdge, d));
      }
  }
  return best;
}

}  // namespace

double MountAlbedo(double x, double y) {
  return 0.30 + 0.03 * std::sin(2 * kPi * x / 0.023 + 0.4) * std::cos(2 * kPi * y / 0.017) +
         0.01 * std::cos(2 * kPi * (x + y) / 0.031);
}

double SceneObject::Albedo(double x, double y) const {
  const double i = height.I(x), j = height.J(y);
  if (i < 0 || j < 0 || i > height.width() - 1 || j > height.height() - 1) {
    if (card && x >= card->x0 && x <= card->x1 && y >= card->y0 && y <= card->y1)
      return card->reflectance;
    return MountAlbedo(x, y);
  }
  const int i0 = std::min(static_cast<int>(i), height.width() - 2);
  const int j0 = std::min(static_cast<int>(j), height.height() - 2);
  const double a = i - i0, b = j - j0;
  return (1 - a) * (1 - b) * albedo(i0, j0) + a * (1 - b) * albedo(i0 + 1, j0) +
         (1 - a) * b * albedo(i0, j0 + 1) + a * b * albedo(i0 + 1, j0 + 1);
}

std::array<double, 3> SceneObject::ColourAlbedo(double x, double y) const {
  const double i = height.I(x), j = height.J(y);
  const bool inside = !(i < 0 || j < 0 || i > height.width() - 1 || j > height.height() - 1);
  if (!inside || colour.empty()) {
    const double a = Albedo(x, y);
    return {a, a, a};
  }
  const int i0 = std::min(static_cast<int>(i), height.width() - 2);
  const int j0 = std::min(static_cast<int>(j), height.height() - 2);
  const double a = i - i0, b = j - j0;
  std::array<double, 3> rgb{};
  for (int c = 0; c < 3; ++c)
    rgb[c] = (1 - a) * (1 - b) * colour(i0, j0, c) + a * (1 - b) * colour(i0 + 1, j0, c) +
             (1 - a) * b * colour(i0, j0 + 1, c) + a * b * colour(i0 + 1, j0 + 1, c);
  return rgb;
}

double Luminance(const std::array<double, 3>& rgb) {
  return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
}

bool ColourObject(SceneObject* o) {
  const bool fabric = o->name == "fabric", coin = o->name == "coin";
  if (!fabric && !coin) return false;
  const HeightField& hf = o->height;
  o->colour = ImageF(hf.width(), hf.height(), 3);
  ParallelForRows(hf.height(), [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < hf.width(); ++i) {
        const double x = hf.X(i), y = hf.Y(j);
        const double a = o->albedo(i, j);
        std::array<double, 3> rgb{a, a, a};
        if (hf.z(i, j) > 0) {
          // The dye's colour scaled to the grey albedo's luminance, so that the object decodes
          // as before (reconstruction sees luminance) while its texture has colour.
          std::array<double, 3> dye;
          if (fabric) {
            // Madder-dyed threads (a dusty rose red), the dye a little uneven: a slow mottle of
            // +-6 % in green and blue.
            const double mottle =
                1.0 + 0.06 * std::sin(2 * kPi * x / 7.3e-3) * std::cos(2 * kPi * y / 5.9e-3);
            dye = {0.80, 0.45 * mottle, 0.40 * mottle};
          } else {
            // Patinated copper: warm brown, green verdigris where a smooth field is high.
            const double v =
                0.5 + 0.25 * std::sin(2 * kPi * x / 3.1e-3 + 1.3) * std::cos(2 * kPi * y / 2.3e-3) +
                0.25 * std::sin(2 * kPi * (x - 0.6 * y) / 4.7e-3);
            const double g = std::clamp((v - 0.55) / 0.2, 0.0, 1.0);  // verdigris fraction
            const std::array<double, 3> copper{0.80, 0.52, 0.38}, verdigris{0.38, 0.60, 0.50};
            for (int c = 0; c < 3; ++c) dye[c] = (1 - g) * copper[c] + g * verdigris[c];
          }
          const double k = a / Luminance(dye);
          for (int c = 0; c < 3; ++c) rgb[c] = k * dye[c];
        }
        bool clipped = false;
        for (int c = 0; c < 3; ++c) {
          clipped |= rgb[c] > 1.0;
          rgb[c] = std::clamp(rgb[c], 0.0, 1.0);
          o->colour(i, j, c) = static_cast<float>(rgb[c]);
        }
        if (clipped) o->albedo(i, j) = static_cast<float>(Luminance(rgb));
      }
  });
  return true;
}

double SceneObject::SurfaceZ(double x, double y) const {
  const double z = height.Sample(x, y);
  return std::isfinite(z) ? z : 0.0;
}

SceneObject MakeCoin(double h) {
  constexpr double kRadius = 9.5e-3, kField = 1.2e-3, kRim = 1.3e-3, kRimInner = 8.6e-3;
  constexpr int kMargin = 3;
  HeightField grid = MakeGrid(-kRadius, kRadius, -kRadius, kRadius, h, kMargin);
  return Generate("coin", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
    const double r = std::hypot(x, y);
    if (r >= kRadius) return;
    // Body: field, raised rim (inner flank 0.15 mm wide), edge rounded over the last 0.1 mm.
    double zz = kField + (kRim - kField) * SmoothStep(kRimInner - 0.15e-3, kRimInner, r);
    if (r > kRadius - 0.1e-3) {
      const double q = (r - (kRadius - 0.1e-3)) / 0.1e-3;
      zz = (kRim - 0.1e-3) + 0.1e-3 * std::sqrt(std::max(0.0, 1 - q * q));
      zz *= std::sqrt(std::max(0.0, 1 - q * q * q * q));
    }
    // Portrait: a head (smooth elliptical dome, 90 um), a nose and a neck, left of centre.
    auto dome = [](double u, double v, double amp) {
      const double q = u * u + v * v;
      return q < 1 ? amp * (1 - q) * (1 - q) : 0.0;
    };
    zz += dome((x + 0.4e-3) / 3.2e-3, (y - 0.6e-3) / 4.0e-3, 90e-6);
    zz += dome((x - 2.9e-3) / 0.8e-3, (y - 0.3e-3) / 0.6e-3, 35e-6);  // nose
    zz += dome((x + 0.2e-3) / 1.8e-3, (y + 4.0e-3) / 1.6e-3, 50e-6);  // neck
    // Lettering 40 um, and a ring of beads (20 um) inside the rim.
    zz += 40e-6 * LetteringAt(x, y);
    const double bead_r = 8.4e-3, bead_pitch = 0.3e-3;
    if (std::abs(r - bead_r) < 0.15e-3) {
      const double s = std::atan2(y, x) * bead_r;
      const double ds = s - bead_pitch * std::round(s / bead_pitch);
      zz += dome(ds / 0.1e-3, (r - bead_r) / 0.1e-3, 20e-6);
    }
    *z = zz;
    // Bronze with smooth tarnish.
    *a = 0.55 + 0.08 * std::cos(x / 3e-3) * std::sin(y / 4e-3 + 0.3) -
         0.06 * std::exp(-((x - 4e-3) * (x - 4e-3) + (y + 3e-3) * (y + 3e-3)) / (2 * 2e-3 * 2e-3));
  });
}

SceneObject MakePaperRamp(double h) {
  constexpr int kMargin = 3;
  HeightField grid = MakeGrid(kRampX0, kRampX1, -kRampHalfWidthM, kRampHalfWidthM, h, kMargin);
  return Generate("ramp", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
    if (x < kRampX0 || x > kRampX1 || std::abs(y) > kRampHalfWidthM) return;
    const int sheets =
        std::min(kRampSheets, static_cast<int>(std::floor((x - kRampX0) / kRampStepWidthM)) + 1);
    *z = sheets * kRampSheetM;
    *a = 0.80 + 0.04 * std::sin(2 * kPi * x / 7e-3) * std::cos(2 * kPi * y / 5e-3);
  });
}

SceneObject MakeTiltedPlane(double h) {
  constexpr int kMargin = 2;
  HeightField grid = MakeGrid(kBarX0, kBarX1, -kBarHalfWidthM, kBarHalfWidthM, h, kMargin);
  return Generate("plane", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
    if (x < kBarX0 || x > kBarX1 || std::abs(y) > kBarHalfWidthM) return;
    *z = (x - kBarX0) * std::tan(kBarAngleRad);
    *a = 0.45 + 0.05 * std::sin(2 * kPi * x / 13e-3) + 0.03 * std::cos(2 * kPi * y / 6e-3);
  });
}

SceneObject MakeLeaf(double h) {
  constexpr double kHalfLength = 20e-3, kHalfWidth = 9e-3;
  constexpr int kMargin = 3;
  HeightField grid = MakeGrid(-kHalfLength, kHalfLength, -kHalfWidth, kHalfWidth, h, kMargin);
  return Generate("leaf", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
    const double u = (x + kHalfLength) / (2 * kHalfLength);  // 0 at the stem, 1 at the tip
    if (u <= 0 || u >= 1) return;
    const double w = kHalfWidth * std::pow(std::sin(kPi * u), 0.8) * (1.0 - 0.25 * u);
    if (std::abs(y) >= w) return;
    const double yn = y / w;  // -1..1 across the blade
    // Curled blade: 1.0 mm at the margins rising to 1.3 mm along the midrib, sagging at the tip.
    double zz = 1.0e-3 + 0.3e-3 * (1 - yn * yn) - 0.2e-3 * u * u;
    // Midrib: a groove 60 um deep, 0.15 mm sigma.
    zz -= 60e-6 * std::exp(-y * y / (2 * 0.15e-3 * 0.15e-3));
    // Lateral veins leaving the midrib at 50 degrees every 4 mm, 45 um deep, fading outwards.
    const double along = x - std::abs(y) / std::tan(50.0 * kPi / 180.0);
    const double d = (along - 4e-3 * std::round(along / 4e-3)) * std::sin(50.0 * kPi / 180.0);
    zz -= 45e-6 * std::exp(-d * d / (2 * 0.08e-3 * 0.08e-3)) * (1 - 0.6 * std::abs(yn));
    *z = zz;
    *a = 0.28 + 0.05 * std::sin(2 * kPi * x / 11e-3) * std::cos(2 * kPi * y / 9e-3) +
         0.03 * std::exp(-d * d / (2 * 0.1e-3 * 0.1e-3));
  });
}

namespace {

// A deterministic hash of integer coordinates to [0, 1) (jitter of the procedural samples).
double Hash01(int a, int b, int salt) {
  uint32_t h = static_cast<uint32_t>(a) * 73856093u ^ static_cast<uint32_t>(b) * 19349663u ^
               static_cast<uint32_t>(salt) * 83492791u;
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return (h & 0xffffff) / static_cast<double>(0x1000000);
}

// The sample's shape under the material: lying with a slight tilt and a sag, as a cloth or a
// plate does on a mount (the flatten step removes it).
double SampleShape(double x, double y) {
  return 0.010 * x - 0.006 * y - 0.15e-3 * (x * x + y * y) / (kMaterialHalfM * kMaterialHalfM);
}

}  // namespace

SceneObject MakeFabric(double h) {
  constexpr int kMargin = 3;
  HeightField grid =
      MakeGrid(-kMaterialHalfM, kMaterialHalfM, -kMaterialHalfM, kMaterialHalfM, h, kMargin);
  constexpr double pitch = kFabricPitchM, half_w = 0.42 * kFabricPitchM;
  constexpr double base = 0.45e-3, thread = 0.16e-3, wave = 0.07e-3;
  return Generate(
      "fabric", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
        if (std::abs(x) > kMaterialHalfM || std::abs(y) > kMaterialHalfM) return;
        // Plain weave: warp threads run along y (centred at x = i * pitch), weft along x; each
        // passes over and under the crossing threads in turn (a cosine along its length, the sign
        // alternating from one thread to the next), with an elliptical cross-section.
        const int iw = static_cast<int>(std::lround(x / pitch)),
                  jw = static_cast<int>(std::lround(y / pitch));
        const double dx = x - iw * pitch, dy = y - jw * pitch;
        auto section = [&](double d) {
          const double t = d / half_w;
          return t * t < 1 ? thread * std::sqrt(1 - t * t) : -1.0;
        };
        const double warp_c = wave * std::cos(kPi * y / pitch + kPi * iw);
        const double weft_c = -wave * std::cos(kPi * x / pitch + kPi * jw);
        double top = 0.0;
        const double sw = section(dx), sf = section(dy);
        // Fibre twist: fine ridges at 45 degrees along each thread, 6 um.
        if (sw >= 0)
          top = std::max(top, base + warp_c + sw + 6e-6 * std::sin(2 * kPi * (y + dx) / 0.12e-3));
        if (sf >= 0)
          top = std::max(top, base + weft_c + sf + 6e-6 * std::sin(2 * kPi * (x - dy) / 0.12e-3));
        if (top == 0.0) top = base - thread;  // the gap between threads: the cloth's back
        *z = top + SampleShape(x, y);
        // Dyed yarn: warp and weft slightly different, with slub variations along each thread.
        const bool on_warp = sw >= 0 && (sf < 0 || base + warp_c + sw >= base + weft_c + sf);
        *a = (on_warp ? 0.62 : 0.48) +
             0.05 * (Hash01(on_warp ? iw : jw,
                            static_cast<int>(std::floor((on_warp ? y : x) / 2e-3)), 3) -
                     0.5);
      });
}

SceneObject MakeImpasto(double h, double half_x, double half_y) {
  constexpr int kMargin = 3;
  HeightField grid = MakeGrid(-half_x, half_x, -half_y, half_y, h, kMargin);
  constexpr double kCell = 7e-3, kGround = 0.4e-3;
  return Generate(
      "impasto", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
        if (std::abs(x) > half_x || std::abs(y) > half_y) return;
        // Ground: a slow undulation and the canvas weave showing through.
        double height = kGround +
                        20e-6 * std::sin(2 * kPi * x / 47e-3) * std::cos(2 * kPi * y / 61e-3) +
                        20e-6 * std::sin(2 * kPi * (x + 0.6 * y) / 83e-3) +
                        4e-6 * (std::sin(2 * kPi * x / 0.6e-3) + std::sin(2 * kPi * y / 0.6e-3));
        double albedo = 0.78;
        // Strokes: one per cell of a jittered grid and layer; the cells around (x, y) can reach it.
        const int ci = static_cast<int>(std::floor(x / kCell)),
                  cj = static_cast<int>(std::floor(y / kCell));
        for (int layer = 0; layer < 2; ++layer)
          for (int dj = -2; dj <= 2; ++dj)
            for (int di = -2; di <= 2; ++di) {
              const int i = ci + di, j = cj + dj, seed = 11 + 7 * layer;
              const double sx = (i + Hash01(i, j, seed)) * kCell,
                           sy = (j + Hash01(i, j, seed + 1)) * kCell;
              const double angle = kPi * Hash01(i, j, seed + 2);
              const double half_len = 0.5 * (6e-3 + 8e-3 * Hash01(i, j, seed + 3));
              const double half_w = 0.5 * (1.6e-3 + 1.6e-3 * Hash01(i, j, seed + 4));
              const double peak = 80e-6 + 340e-6 * Hash01(i, j, seed + 5);
              const double c = std::cos(angle), s = std::sin(angle);
              const double u = (x - sx) * c + (y - sy) * s, v = -(x - sx) * s + (y - sy) * c;
              if (std::abs(u) >= half_len || std::abs(v) >= half_w) continue;
              // Across: a smooth bump; along: tapering ends (more paint where the brush landed).
              const double across = std::cos(0.5 * kPi * v / half_w);
              const double t = u / half_len;
              const double along = SmoothStep(1.0, 0.55, std::abs(t)) * (1.0 - 0.3 * t);
              const double ridges =
                  12e-6 * std::sin(2 * kPi * v / 0.9e-3 + 6 * Hash01(i, j, seed + 6));
              const double wgt = across * across * along;
              height += wgt * (peak + ridges);
              const double paint = 0.15 + 0.7 * Hash01(i, j, seed + 7);
              albedo = albedo * (1 - wgt) + paint * wgt;
            }
        *z = height;
        *a = albedo;
      });
}

SceneObject MakeHammeredMetal(double h) {
  constexpr int kMargin = 3;
  HeightField grid =
      MakeGrid(-kMaterialHalfM, kMaterialHalfM, -kMaterialHalfM, kMaterialHalfM, h, kMargin);
  constexpr double cell = kHammerCellM;
  return Generate("metal", std::move(grid), kMargin, [&](double x, double y, double* z, double* a) {
    if (std::abs(x) > kMaterialHalfM || std::abs(y) > kMaterialHalfM) return;
    // Hammer blows on a jittered grid: spherical dents of radius 1.1-1.6 cells, 15-35 um deep;
    // the surface is the lowest dent at each point (a later blow cuts an earlier one).
    const int ci = static_cast<int>(std::floor(x / cell)),
              cj = static_cast<int>(std::floor(y / cell));
    double dent = 0.0;
    for (int j = cj - 2; j <= cj + 2; ++j)
      for (int i = ci - 2; i <= ci + 2; ++i) {
        const double px = (i + Hash01(i, j, 1)) * cell, py = (j + Hash01(i, j, 2)) * cell;
        const double depth = 15e-6 + 20e-6 * Hash01(i, j, 4);
        const double rad = (1.1 + 0.5 * Hash01(i, j, 5)) * cell;
        // A spherical cap of chord radius `rad` and depth `depth`: sphere radius R.
        const double R = (rad * rad + depth * depth) / (2 * depth);
        const double r2 = (x - px) * (x - px) + (y - py) * (y - py);
        if (r2 >= rad * rad) continue;
        dent = std::min(dent, -(depth - (R - std::sqrt(R * R - r2))));
      }
    // Fine brushing marks along x, 1.5 um.
    const double brush = 1.5e-6 * std::sin(2 * kPi * y / 37e-6 + 3 * std::sin(x / 2e-3));
    *z = 0.8e-3 + dent + brush + SampleShape(x, y);
    *a = 0.70 + 0.05 * std::sin(x / 4e-3) * std::cos(y / 5e-3) + 0.04 * dent / 35e-6;
  });
}

SceneObject LoadHeightExrObject(const std::filesystem::path& path) {
  SceneObject obj;
  obj.name = path.filename().string();
  obj.height = ReadHeightExr(path);
  const HeightField& hf = obj.height;
  if (hf.width() < 2 || hf.height() < 2)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "Z: expected a height field of at least 2 x 2 pixels");
  bool any = false;
  for (float v : hf.z.data()) any = any || std::isfinite(v);
  if (!any) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "Z: no finite height");
  obj.height.confidence = ImageF();
  obj.albedo = ImageF(hf.width(), hf.height(), 1);
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      const double x = hf.X(i), y = hf.Y(j);
      obj.albedo(i, j) = static_cast<float>(0.5 + 0.1 * std::sin(2 * kPi * x / 9e-3) *
                                                      std::cos(2 * kPi * y / 7e-3));
    }
  return obj;
}

SceneObject MakeObject(const std::string& spec, double h, const std::string& option) {
  if (spec == "coin") return MakeCoin(h > 0 ? h : 10e-6);
  if (spec == "ramp") return MakePaperRamp(h > 0 ? h : 20e-6);
  if (spec == "plane") return MakeTiltedPlane(h > 0 ? h : 50e-6);
  if (spec == "leaf") return MakeLeaf(h > 0 ? h : 20e-6);
  if (spec == "mount") {  // the empty mount: a few zero cells (the plane z = 0 extends beyond)
    const double g = h > 0 ? h : 1e-3;
    return Generate("mount", MakeGrid(-g, g, -g, g, g, 1), 1,
                    [](double, double, double*, double*) {});
  }
  if (spec == "fabric") return MakeFabric(h > 0 ? h : 20e-6);
  if (spec == "metal") return MakeHammeredMetal(h > 0 ? h : 20e-6);
  if (spec == "impasto") return MakeImpasto(h > 0 ? h : 100e-6);
  if (spec.rfind("impasto:", 0) == 0) {
    double w = 0, ht = 0;
    char x = 0, extra = 0;
    const int n = std::sscanf(spec.c_str() + 8, "%lf%c%lf%c", &w, &x, &ht, &extra);
    if (n != 3 || x != 'x' || !(w >= 5 && w <= 2000) || !(ht >= 5 && ht <= 2000))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::Option(option),
                            "'" << spec << "': expected impasto:WxH, the canvas in mm (5..2000)");
    return MakeImpasto(h > 0 ? h : 100e-6, 0.5e-3 * w, 0.5e-3 * ht);
  }
  const std::filesystem::path p(spec);
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext == ".exr") return LoadHeightExrObject(p);
  MESOSCAN_BAD_INPUT_AT(ErrorSite::Option(option),
                        "unknown object '" << spec
                                           << "'; expected coin, plane, ramp, leaf, fabric, metal, "
                                              "impasto[:WxH], mount or a height .exr file");
}

}  // namespace mesoscan
