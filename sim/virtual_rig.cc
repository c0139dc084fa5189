#include "sim/virtual_rig.h"

#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <ctime>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>

#include "assets/objects.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/scan_folder.h"
#include "core/stage_timer.h"
#include "render/embree_scene.h"
#include "session/patterns.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr int kTableSamplesPerPx = 128;   // light tables: samples per projector pixel
constexpr double kMaxSigmaStepPx = 0.02;  // light tables: largest blur step between levels
// zlib level of the frame PNGs: level 1 encodes noisy 16-bit frames ~2.5x faster than the
// default 6 for ~2% larger files (PNG encoding dominated the simulation's CPU time).
constexpr int kPngCompressionLevel = 1;

#define SIM_USAGE(expr) MESOSCAN_THROW(ErrorKind::kUsage, expr)
// A bad value of the SimulateOptions field `field`.
#define SIM_OPTION(field, expr) MESOSCAN_BAD_OPTION("SimulateOptions." field, expr)

// splitmix64: a small counter-based generator, deterministic per (seed, frame).
struct Rng {
  uint64_t state;
  explicit Rng(uint64_t seed) : state(seed) {}
  uint64_t Next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double Uniform() {
    return (static_cast<double>(Next() >> 11) + 0.5) * (1.0 / 9007199254740992.0);
  }
  // Standard normal by Box-Muller, two per call pair.
  double Normal() {
    if (has_spare) {
      has_spare = false;
      return spare;
    }
    const double r = std::sqrt(-2.0 * std::log(Uniform())), phi = 2 * kPi * Uniform();
    spare = r * std::sin(phi);
    has_spare = true;
    return r * std::cos(phi);
  }
  double spare = 0;
  bool has_spare = false;
};

uint64_t MixSeed(uint64_t seed, uint64_t stream) {
  Rng r(seed * 0x9E3779B97F4A7C15ull + stream);
  r.Next();
  return r.Next();
}

// Standard normal CDF.
double Phi(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }

// Tables of the light profile L(x) = sum_u p[u] w_sigma(x - u) of a 1-D pattern, for a set of
// blur levels sigma_l = sigma_min + l * step, on x = x_lo + k / R (sim/README.md "Light").
struct LightTables {
  int levels = 0;
  int n = 0;                // samples per level
  int x_lo = 0;             // x of sample 0 (integer projector px)
  std::vector<float> data;  // level-major

  // Bilinear in (x, level); 0 outside the table (far from any projector pixel).
  float Lookup(double x, float level) const {
    const double kf = (x - x_lo) * kTableSamplesPerPx;
    if (!(kf >= 0.0) || kf >= n - 1) return 0.0f;
    const int k = static_cast<int>(kf);
    const float t = static_cast<float>(kf - k);
    int l0 = static_cast<int>(level);
    l0 = std::clamp(l0, 0, levels - 2);
    const float s = level - static_cast<float>(l0);
    const float* a = data.data() + static_cast<size_t>(l0) * n + k;
    const float* b = a + n;
    const float la = a[0] + t * (a[1] - a[0]);
    const float lb = b[0] + t * (b[1] - b[0]);
    return la + s * (lb - la);
  }
};

struct BlurLevels {
  double sigma_min = 0.35, step = 0.02;
  int count = 2;
  int half_support = 4;  // T: kernel support [-T, T] in px (integer)
  double Sigma(int l) const { return sigma_min + l * step; }
  float Level(double sigma) const { return static_cast<float>((sigma - sigma_min) / step); }
};

// Kernel w_sigma(t) = [Phi((t + f/2) / sigma) - Phi((t - f/2) / sigma)] / f on t = -T + k / R.
std::vector<float> Kernel(double sigma, double fill, int half_support) {
  const int n = 2 * half_support * kTableSamplesPerPx + 1;
  std::vector<float> k(n);
  for (int i = 0; i < n; ++i) {
    const double t = -half_support + static_cast<double>(i) / kTableSamplesPerPx;
    k[i] =
        static_cast<float>((Phi((t + 0.5 * fill) / sigma) - Phi((t - 0.5 * fill) / sigma)) / fill);
  }
  return k;
}

LightTables BuildTables(const std::vector<double>& p, const BlurLevels& levels,
                        const std::vector<std::vector<float>>& kernels) {
  LightTables tab;
  const int count = static_cast<int>(p.size());
  const int T = levels.half_support;
  tab.levels = levels.count;
  tab.x_lo = -T - 1;
  const int x_hi = count - 1 + T + 1;
  tab.n = (x_hi - tab.x_lo) * kTableSamplesPerPx + 1;
  tab.data.assign(static_cast<size_t>(tab.levels) * tab.n, 0.0f);
  ParallelFor(tab.levels, [&](int64_t l) {
    float* row = tab.data.data() + static_cast<size_t>(l) * tab.n;
    const std::vector<float>& ker = kernels[l];
    const int klen = static_cast<int>(ker.size());
    for (int u = 0; u < count; ++u) {
      const float pu = static_cast<float>(p[u]);
      if (pu == 0.0f) continue;
      // x_k - u = -T + i / R  <=>  k = (u - T - x_lo) * R + i.
      const int k0 = (u - T - tab.x_lo) * kTableSamplesPerPx;
      for (int i = 0; i < klen; ++i) row[k0 + i] += pu * ker[i];
    }
  });
  return tab;
}

// The value a float32 header attribute will hold.
double StoredAsFloat(double v) {
  volatile float f = static_cast<float>(v);
  return f;
}

// 2^bits - 1 DN -> 16 bits by bit replication: reading back / 65535 gives DN / (2^bits - 1)
// within 1 / 65535.
uint16_t ToPng16(int dn, int bits) {
  if (bits == 16) return static_cast<uint16_t>(dn);
  return static_cast<uint16_t>((dn << (16 - bits)) | (dn >> (2 * bits - 16)));
}

// Largest distance (along z) of a pixel's subsample hits from their least-squares plane
// z = c0 + c1 x + c2 y: how far the footprint is from a single smooth surface (a step inside the
// footprint shows as a relief of about half the step). NaN with fewer than 3 hits.
double FootprintRelief(const std::vector<Vec3d>& hits) {
  if (hits.size() < 3) return std::numeric_limits<double>::quiet_NaN();
  Vec3d mean = Vec3d::Zero();
  for (const Vec3d& p : hits) mean += p;
  mean /= static_cast<double>(hits.size());
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (const Vec3d& p : hits) {
    const Eigen::Vector3d row(1.0, p.x() - mean.x(), p.y() - mean.y());
    ata += row * row.transpose();
    atb += row * (p.z() - mean.z());
  }
  const Eigen::Vector3d c = ata.completeOrthogonalDecomposition().solve(atb);
  double relief = 0;
  for (const Vec3d& p : hits)
    relief = std::max(relief, std::abs(p.z() - mean.z() - c(0) - c(1) * (p.x() - mean.x()) -
                                       c(2) * (p.y() - mean.y())));
  return relief;
}

// Everything the frame stage needs per camera subsample (structure of arrays), index
// (pixel * S + b) * S + a for subsample (a, b) of an S x S pixel.
struct SubsampleCache {
  std::vector<float> x;        // projector u at shift 0 (px)
  std::vector<float> gain;     // lens-shifter gain g(u, v) at that point
  std::vector<float> level;    // blur level (fractional index into BlurLevels)
  std::vector<float> shading;  // albedo * cos_i * (r0 / r)^2 * R_v(v); 0 = unlit
  void Resize(size_t n) {
    x.assign(n, 0.0f);
    gain.assign(n, 1.0f);
    level.assign(n, 0.0f);
    shading.assign(n, 0.0f);
  }
};

// What the ray cast reads: the rig's devices, the scene and the optics that shade a hit.
struct RigView {
  const PinholeCamera& cam;
  const PinholeCamera& prj;
  const EmbreeScene& scene;
  const SceneObject& object;
  const SimulateOptions& options;
  double focus_z = 0;  // world height of the projector's focus plane, m
  Rigid3d prj_from_world;
  Vec3d cam_centre, prj_centre;
  double r0 = 0;        // reference distance: projector centre to the world origin
  bool colour = false;  // the object has a colour (RGB frames)
};

RigView MakeRigView(const Rig& rig, const EmbreeScene& scene, const SceneObject& object,
                    const SimulateOptions& options, double focus_z) {
  RigView v{rig.camera, rig.projector, scene, object, options, focus_z, {}, {}, {}, 0, false};
  v.colour = !object.colour.empty();
  v.prj_from_world = rig.projector.world_from_device.Inverse();
  v.cam_centre = rig.camera.CentreInWorld();
  v.prj_centre = rig.projector.CentreInWorld();
  v.r0 = v.prj_centre.norm();
  return v;
}

// The height of the projector's focus plane: the option, or (NaN) the object's mid height.
double FocusHeight(const SceneObject& object, double focus_height_m) {
  if (!std::isnan(focus_height_m)) return focus_height_m;
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (float z : object.height.z.data())
    if (std::isfinite(z)) {
      lo = std::min(lo, static_cast<double>(z));
      hi = std::max(hi, static_cast<double>(z));
    }
  return std::isfinite(lo) ? 0.5 * (lo + hi) : 0.0;
}

// One camera ray: what it hits, where that lands in the projector, how it is lit.
struct Sample {
  bool hit = false, lit = false;
  Vec3d point;
  double albedo = 0, u = 0, v = 0, sigma = 0, shading = 0;
  std::array<double, 3> rgb{};  // per-channel albedo (coloured objects only)
};

Sample Shade(const RigView& view, const Vec2d& uv) {
  Sample s;
  const Vec3d d = view.cam.RayDirectionInWorld(uv);
  const std::optional<RayHit> hit = view.scene.Intersect(view.cam_centre, d);
  if (!hit) return s;
  s.hit = true;
  s.point = hit->point;
  s.albedo = view.object.Albedo(s.point.x(), s.point.y());
  if (view.colour) s.rgb = view.object.ColourAlbedo(s.point.x(), s.point.y());
  const Vec3d p_dev = view.prj_from_world * s.point;
  double uvp[2];
  if (!view.prj.ProjectDevice(p_dev.data(), uvp)) return s;
  s.u = uvp[0];
  s.v = uvp[1];
  Vec3d l = view.prj_centre - s.point;
  const double r = l.norm();
  l /= r;
  const double cos_i = hit->normal.dot(l);
  if (!(cos_i > 0)) return s;
  if (view.options.shadows && view.scene.Occluded(EmbreeScene::ShadowRayOrigin(*hit), l, 0.0, r))
    return s;
  const SimulateOptions& o = view.options;
  s.sigma = o.blur_sigma_px + o.defocus_px_per_m * std::abs(s.point.z() - view.focus_z);
  s.shading = s.albedo * cos_i * (view.r0 / r) * (view.r0 / r);
  if (o.projector_falloff != 0) {
    const double un = (s.u - view.prj.K(0, 2)) / (0.5 * view.prj.width),
                 vn = (s.v - view.prj.K(1, 2)) / (0.5 * view.prj.height);
    s.shading *= std::max(0.0, 1.0 - o.projector_falloff * (un * un + vn * vn));
  }
  s.lit = s.u >= -0.5 && s.u <= view.prj.width - 0.5 && s.v >= -0.5 && s.v <= view.prj.height - 0.5;
  return s;
}

// Stage 1 output: every camera subsample's projector position and shading, and the per-pixel
// ground truth.
struct RayCastResult {
  SubsampleCache cache;               // x and shading set; gain and level by PrepareSubsamples
  std::vector<float> v, sigma;        // per subsample: projector v, blur sigma (px)
  std::vector<float> ambient_albedo;  // per pixel: mean albedo of its subsamples
  // Coloured objects, 3 per pixel (channel-major: c * W * H + pixel): the pixel's colour over its
  // luminance, weighted by the subsamples' shading (the lit light's colour), and the mean albedo
  // per channel (the ambient light's colour). Empty for grey objects.
  std::vector<float> tint, ambient_colour;
  ImageF gt_points;        // per pixel: X, Y, Z of the centre ray's hit, lit_fraction, relief
  int64_t lit_pixels = 0;  // pixels whose centre sees a lit surface
  int64_t rays = 0;        // camera rays cast
};

// Stage 1: one ray per camera subsample (S x S per pixel) and per pixel centre.
RayCastResult RayCast(const RigView& view, int S) {
  const int W = view.cam.width, H = view.cam.height;
  const size_t n_sub = static_cast<size_t>(W) * H * S * S;
  RayCastResult rc;
  rc.cache.Resize(n_sub);
  rc.v.assign(n_sub, 0.0f);
  rc.sigma.assign(n_sub, 0.0f);
  rc.ambient_albedo.assign(static_cast<size_t>(W) * H, 0.0f);
  if (view.colour) {
    rc.tint.assign(3 * static_cast<size_t>(W) * H, 1.0f);
    rc.ambient_colour.assign(3 * static_cast<size_t>(W) * H, 0.0f);
  }
  const size_t plane = static_cast<size_t>(W) * H;
  rc.gt_points = ImageF(W, H, 5, std::numeric_limits<float>::quiet_NaN());
  std::atomic<int64_t> lit_pixels{0};
  Progress progress("simulate: ray cast", H);
  ParallelForRows(H, [&](int y0, int y1) {
    for (int py = y0; py < y1; ++py) {
      for (int px = 0; px < W; ++px) {
        const size_t pix = static_cast<size_t>(py) * W + px;
        double albedo_sum = 0, shading_sum = 0;
        std::array<double, 3> rgb_sum{}, tint_sum{};
        Sample centre;
        int lit_subsamples = 0;
        std::vector<Vec3d> hits;
        hits.reserve(S * S);
        for (int b = 0; b < S; ++b)
          for (int a = 0; a < S; ++a) {
            const size_t k = (pix * S + b) * S + a;
            const Sample s = Shade(view, Vec2d(px + (a + 0.5) / S - 0.5, py + (b + 0.5) / S - 0.5));
            if (2 * a + 1 == S && 2 * b + 1 == S) centre = s;
            albedo_sum += s.albedo;
            if (view.colour)
              for (int c = 0; c < 3; ++c) {
                rgb_sum[c] += s.rgb[c];
                if (s.shading > 0 && s.albedo > 0) tint_sum[c] += s.shading * s.rgb[c] / s.albedo;
              }
            if (s.shading > 0) shading_sum += s.shading;
            lit_subsamples += s.lit;
            if (s.hit) hits.push_back(s.point);
            if (s.shading > 0) {
              // Patterns vary along the fringe axis only: the cache holds the coordinate along
              // it in `x` and the one across it in `v` (for axis 'y' the projector's v and u).
              const bool along_y = view.options.axis == 'y';
              rc.cache.x[k] = static_cast<float>(along_y ? s.v : s.u);
              rc.v[k] = static_cast<float>(along_y ? s.u : s.v);
              rc.sigma[k] = static_cast<float>(s.sigma);
              rc.cache.shading[k] = static_cast<float>(s.shading);
            }
          }
        rc.ambient_albedo[pix] = static_cast<float>(albedo_sum / (S * S));
        if (view.colour)
          for (int c = 0; c < 3; ++c) {
            rc.ambient_colour[c * plane + pix] = static_cast<float>(rgb_sum[c] / (S * S));
            rc.tint[c * plane + pix] =
                shading_sum > 0  ? static_cast<float>(tint_sum[c] / shading_sum)
                : albedo_sum > 0 ? static_cast<float>(rgb_sum[c] / albedo_sum)
                                 : 1.0f;
          }
        // The pixel centre is a subsample when S is odd.
        const Sample c = S % 2 == 1 ? centre : Shade(view, Vec2d(px, py));
        ImageF& gt = rc.gt_points;
        if (c.lit) {
          gt(px, py, 0) = static_cast<float>(c.point.x());
          gt(px, py, 1) = static_cast<float>(c.point.y());
          gt(px, py, 2) = static_cast<float>(c.point.z());
          ++lit_pixels;
        }
        gt(px, py, 3) = static_cast<float>(lit_subsamples) / (S * S);
        gt(px, py, 4) = static_cast<float>(FootprintRelief(hits));
      }
      progress.Advance();
    }
  });
  rc.lit_pixels = lit_pixels.load();
  rc.rays = static_cast<int64_t>(n_sub) + (S % 2 == 1 ? 0 : static_cast<int64_t>(W) * H);
  return rc;
}

// Blur levels spanning the lit subsamples' sigmas in steps of at most kMaxSigmaStepPx.
BlurLevels ChooseBlurLevels(const RayCastResult& rc, const SimulateOptions& options) {
  BlurLevels levels;
  double smin = std::numeric_limits<double>::infinity(), smax = -smin;
  for (size_t k = 0; k < rc.sigma.size(); ++k)
    if (rc.cache.shading[k] > 0) {
      smin = std::min<double>(smin, rc.sigma[k]);
      smax = std::max<double>(smax, rc.sigma[k]);
    }
  if (!std::isfinite(smin)) smin = smax = options.blur_sigma_px;
  levels.sigma_min = smin;
  levels.count = std::max(2, static_cast<int>(std::ceil((smax - smin) / kMaxSigmaStepPx)) + 1);
  levels.step = smax > smin ? (smax - smin) / (levels.count - 1) : kMaxSigmaStepPx;
  levels.half_support =
      static_cast<int>(std::ceil(0.5 * options.fill_factor + 6.0 * levels.Sigma(levels.count - 1)));
  return levels;
}

std::vector<std::vector<float>> BlurKernels(const BlurLevels& levels, double fill_factor) {
  std::vector<std::vector<float>> kernels(levels.count);
  ParallelFor(levels.count, [&](int64_t l) {
    kernels[l] = Kernel(levels.Sigma(static_cast<int>(l)), fill_factor, levels.half_support);
  });
  return kernels;
}

// Stage 2: each lit subsample's blur level, the row profile R_v(v) folded into its shading and
// its lens-shifter gain; releases rc->v and rc->sigma.
void PrepareSubsamples(const BlurLevels& levels, const std::vector<std::vector<float>>& kernels,
                       const PinholeCamera& prj, const SimulateOptions& options,
                       RayCastResult* rc) {
  // Along v every pattern is uniform: the light is L(u) * R_v(v), R_v = sum_v w(v' - v).
  const bool along_y = options.axis == 'y';
  const LightTables rows =
      BuildTables(std::vector<double>(along_y ? prj.width : prj.height, 1.0), levels, kernels);
  SubsampleCache& cache = rc->cache;
  ParallelFor(
      static_cast<int64_t>(cache.shading.size()),
      [&](int64_t k) {
        if (cache.shading[k] <= 0) return;
        const float level = levels.Level(rc->sigma[k]);
        cache.level[k] = level;
        cache.shading[k] *= rows.Lookup(rc->v[k], level);
        cache.gain[k] =
            static_cast<float>(along_y ? ShifterGain(options, prj, rc->v[k], cache.x[k])
                                       : ShifterGain(options, prj, cache.x[k], rc->v[k]));
      },
      4096);
  rc->v = {};
  rc->sigma = {};
}

// Light tables of the distinct patterns of the frames (the same pattern at another shift
// shares its table).
struct PatternTables {
  std::vector<LightTables> tables;
  std::vector<int> frame_table;  // per frame: index into tables
};

// The light a displayed value v in [0, 1] emits: the rig's response, or the options' named curve
// (SimulateOptions::projector_curve).
double ProjectorLight(const SimulateOptions& o, const Rig& rig, double v) {
  if (o.projector_curve == "s-curve") {
    constexpr double kSlope = 7.0, kCentre = 0.6, kBlack = 0.03;
    const auto logistic = [](double x) { return 1.0 / (1.0 + std::exp(-x)); };
    const double lo = logistic(-kSlope * kCentre), hi = logistic(kSlope * (1 - kCentre));
    return kBlack + (1 - kBlack) * (logistic(kSlope * (v - kCentre)) - lo) / (hi - lo);
  }
  return rig.projector_response.ToLinear(v);
}

PatternTables BuildPatternTables(const std::vector<Frame>& frames, const Rig& rig,
                                 const SimulateOptions& options, const BlurLevels& levels,
                                 const std::vector<std::vector<float>>& kernels) {
  const char axis = options.axis;
  PatternTables out;
  out.frame_table.resize(frames.size());
  std::map<std::tuple<int, double, double, int, int, double, bool>, int> pattern_index;
  std::vector<const Pattern*> table_patterns;
  for (size_t f = 0; f < frames.size(); ++f) {
    const Pattern& p = frames[f].pattern;
    const auto key = std::make_tuple(static_cast<int>(p.type), p.period_px, p.phase, p.bits, p.bit,
                                     p.block_px, p.inverted);
    auto it = pattern_index.find(key);
    if (it == pattern_index.end()) {
      it = pattern_index.emplace(key, static_cast<int>(table_patterns.size())).first;
      table_patterns.push_back(&p);
    }
    out.frame_table[f] = it->second;
  }
  out.tables.resize(table_patterns.size());
  const PinholeCamera& prj = rig.projector;
  for (size_t t = 0; t < table_patterns.size(); ++t) {
    const bool along_y = axis == 'y';  // the cache's coordinate (RayCast)
    std::vector<double> p(along_y ? prj.height : prj.width);
    for (int u = 0; u < static_cast<int>(p.size()); ++u)
      p[u] = ProjectorLight(
          options, rig,
          along_y ? table_patterns[t]->Value(0.0, u) : table_patterns[t]->Value(u, 0.0));
    out.tables[t] = BuildTables(p, levels, kernels);
  }
  return out;
}

// The per-frame random draws: gain jitter (every frame) and shifter position error (lens-shift
// frames), each from its own seeded stream.
struct FrameDraws {
  std::vector<double> gains;            // multiplicative, 1 + N(0, jitter^2)
  std::vector<double> position_errors;  // projector px
};

FrameDraws DrawFrames(const std::vector<Frame>& frames, const SimulateOptions& options) {
  FrameDraws d;
  const NoiseModel noise = MakeNoiseModel(options);
  d.gains.assign(frames.size(), 1.0);
  for (size_t f = 0; f < frames.size(); ++f) {
    Rng rng(MixSeed(options.seed, 2 * f + 1));
    d.gains[f] = 1.0 + noise.GainJitterSigma() * rng.Normal();
  }
  d.position_errors.assign(frames.size(), 0.0);
  if (options.shift_position_error_px > 0)
    for (size_t f = 0; f < frames.size(); ++f) {
      if (frames[f].pattern.type != PatternType::kStripes) continue;
      Rng rng(MixSeed(options.seed ^ 0x5eedf00dULL, 2 * f + 1));
      d.position_errors[f] = options.shift_position_error_px * rng.Normal();
    }
  return d;
}

// Stage 3, one frame: the light of every pixel (mean over its subsamples of shading times the
// pattern's table at the shifted position), exposure and ambient, gain jitter, sensor noise
// (seeded per frame) and the ADC, as 16-bit PNG codes.
ImageU16 RenderFrame(const Frame& frame, size_t f, const LightTables& tab, const Rig& rig,
                     const RayCastResult& rc, const FrameDraws& draws,
                     const SimulateOptions& options) {
  const int W = rig.camera.width, H = rig.camera.height, S = options.supersample;
  const SubsampleCache& cache = rc.cache;
  const NoiseModel noise = MakeNoiseModel(options);
  const int dn_max = (1 << options.adc_bits) - 1;
  const double inv_ss = 1.0 / (S * S);
  const double shift_px =
      (rig.lens_shifter ? frame.shift_steps / rig.lens_shifter->steps_per_px : 0.0) +
      draws.position_errors[f];
  const bool dark = frame.pattern.type == PatternType::kBlack;
  Rng rng(MixSeed(options.seed, 2 * f + 2));
  // A coloured object's texture frames (white, black) are RGB; its pattern frames are their
  // luminance, which is what reconstruction decodes (grey frames: a third of the data).
  const bool colour = !rc.tint.empty() && (frame.pattern.type == PatternType::kWhite ||
                                           frame.pattern.type == PatternType::kBlack);
  const size_t plane = static_cast<size_t>(W) * H;
  ImageU16 image(W, H, colour ? 3 : 1);
  uint16_t* out = image.channel(0);
  for (size_t pix = 0; pix < plane; ++pix) {
    double acc = 0.0;
    if (!dark) {
      const size_t k0 = pix * S * S;
      for (int s = 0; s < S * S; ++s) {
        const size_t k = k0 + s;
        const float sh = cache.shading[k];
        if (sh <= 0.0f) continue;
        acc += sh * tab.Lookup(cache.x[k] - shift_px * cache.gain[k], cache.level[k]);
      }
    }
    if (colour) {
      // Each channel: the lit light tinted by the pixel's colour, the ambient by its albedo;
      // independent noise per channel.
      for (int c = 0; c < 3; ++c) {
        const size_t i = c * plane + pix;
        const double m =
            options.exposure * (acc * inv_ss * rc.tint[i] + options.ambient * rc.ambient_colour[i]);
        double value = m * draws.gains[f];
        if (options.noise > 0) value += noise.Sigma(m) * rng.Normal();
        const int dn = static_cast<int>(std::lround(std::clamp(value, 0.0, 1.0) * dn_max));
        image.channel(c)[pix] = ToPng16(dn, options.adc_bits);
      }
      continue;
    }
    const double mean =
        options.exposure * (acc * inv_ss + options.ambient * rc.ambient_albedo[pix]);
    double value = mean * draws.gains[f];
    if (options.noise > 0) value += noise.Sigma(mean) * rng.Normal();
    const int dn = static_cast<int>(std::lround(std::clamp(value, 0.0, 1.0) * dn_max));
    out[pix] = ToPng16(dn, options.adc_bits);
  }
  return image;
}

// The true reflectance per channel R, G, B on the grid of the true height field (the object's
// colour, the card, the mount), with its grid attributes.
void WriteGroundTruthAlbedo(const fs::path& path, const HeightField& grid,
                            const SceneObject& object) {
  ImageF a(grid.width(), grid.height(), 3);
  ParallelForRows(grid.height(), [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < grid.width(); ++i) {
        const std::array<double, 3> rgb = object.ColourAlbedo(grid.X(i), grid.Y(j));
        for (int c = 0; c < 3; ++c) a(i, j, c) = static_cast<float>(rgb[c]);
      }
  });
  WriteExr(path, a, {"R", "G", "B"},
           {{"mesoscan:x0", grid.x0},
            {"mesoscan:y0", grid.y0},
            {"mesoscan:pixel_size", grid.pixel_size}});
}

// The grey card's world square and the camera pixels wholly inside it (the rectangle of pixel
// centres whose footprint lies on the card, 2 px in from its projected edges).
Json GreyCardRecord(const SceneObject::Card& card, const PinholeCamera& cam) {
  double u0 = 1e30, v0 = 1e30, u1 = -1e30, v1 = -1e30;
  for (const double x : {card.x0, card.x1})
    for (const double y : {card.y0, card.y1}) {
      Vec2d uv;
      if (!cam.Project(Vec3d(x, y, 0.0), &uv)) continue;
      u0 = std::min(u0, uv.x()), u1 = std::max(u1, uv.x());
      v0 = std::min(v0, uv.y()), v1 = std::max(v1, uv.y());
    }
  // Inside the projected corners' box, less a margin (the box of a slightly rotated square is a
  // little larger than the square's image).
  const int x0 = std::max(0, static_cast<int>(std::ceil(u0)) + 2),
            y0 = std::max(0, static_cast<int>(std::ceil(v0)) + 2),
            x1 = std::min(cam.width - 1, static_cast<int>(std::floor(u1)) - 2),
            y1 = std::min(cam.height - 1, static_cast<int>(std::floor(v1)) - 2);
  Json j = {{"world_m", {card.x0, card.y0, card.x1, card.y1}}, {"reflectance", card.reflectance}};
  if (x1 >= x0 && y1 >= y0)
    j["camera_px"] = {x0, y0, x1 - x0 + 1, y1 - y0 + 1};
  else
    j["camera_px"] = nullptr;  // not in view
  return j;
}

// The true height field on the camera's footprint on z = 0 (the rays through the image
// corners), one camera pixel on the mount at the image centre per sample.
HeightField GroundTruthHeight(const PinholeCamera& cam, const SceneObject& object) {
  const int W = cam.width, H = cam.height;
  const Vec3d cam_centre = cam.CentreInWorld();
  HeightField gt;
  double xmin = 1e30, xmax = -1e30, ymin = 1e30, ymax = -1e30;
  for (double u : {-0.5, W - 0.5})
    for (double v : {-0.5, H - 0.5}) {
      const Vec3d d = cam.RayDirectionInWorld(Vec2d(u, v));
      const double t = -cam_centre.z() / d.z();
      const Vec3d p = cam_centre + t * d;
      xmin = std::min(xmin, p.x());
      xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y());
      ymax = std::max(ymax, p.y());
    }
  const Vec3d dc = cam.RayDirectionInWorld(Vec2d(cam.K(0, 2), cam.K(1, 2)));
  gt.pixel_size = (-cam_centre.z() / dc.z()) * dc.norm() / cam.K(0, 0);
  const int gw = std::max(1, static_cast<int>(std::floor((xmax - xmin) / gt.pixel_size + 1e-6)));
  const int gh = std::max(1, static_cast<int>(std::floor((ymax - ymin) / gt.pixel_size + 1e-6)));
  gt.x0 = xmin + 0.5 * gt.pixel_size;
  gt.y0 = ymax - 0.5 * gt.pixel_size;
  // The EXR header stores the grid in float: sample where the file says the pixels are.
  gt.x0 = StoredAsFloat(gt.x0);
  gt.y0 = StoredAsFloat(gt.y0);
  gt.pixel_size = StoredAsFloat(gt.pixel_size);
  gt.z = ImageF(gw, gh, 1);
  ParallelForRows(gh, [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < gw; ++i)
        gt.z(i, j) = static_cast<float>(object.SurfaceZ(gt.X(i), gt.Y(j)));
  });
  return gt;
}

// session.json's "simulation" block: every parameter of the model and the random draws.
Json SimulationRecord(const SimulateOptions& options, const SceneObject& object, double focus_z,
                      const BlurLevels& levels, double r0, const FrameDraws& draws) {
  Json sim;
  sim["model"] = "mesoscan virtual rig 1 (sim/README.md)";
  sim["object"] = {{"name", object.name},
                   {"source", options.object},
                   {"grid_pixel_size_m", object.height.pixel_size},
                   {"grid_size", {object.height.width(), object.height.height()}}};
  if (!options.change.empty()) sim["object_change"] = ObjectChangeRecord(options.change);
  sim["rig"] = options.rig;
  if (options.crop)  // [W, H, X, Y], as earlier sessions recorded it
    sim["crop"] = {options.crop->w, options.crop->h, options.crop->x, options.crop->y};
  sim["supersample"] = options.supersample;
  sim["axis"] = std::string(1, options.axis);
  sim["shadows"] = options.shadows;
  sim["projector"] = {
      {"fill_factor", options.fill_factor},
      {"blur_sigma_px", options.blur_sigma_px},
      {"defocus_px_per_m", options.defocus_px_per_m},
      {"focus_height_m", focus_z},
      {"gamma", options.projector_gamma},
      {"curve", options.projector_curve.empty() ? "power law (gamma)" : options.projector_curve},
      {"blur_sigma_range_px", {levels.sigma_min, levels.Sigma(levels.count - 1)}}};
  sim["lens_shifter_gain"] = {{"formula",
                               "g = 1 + gx*un + gy*vn + gr*(un^2 + vn^2), un = (u - cx)/(W/2), "
                               "vn = (v - cy)/(H/2), (u, v) projector pixel at shift 0"},
                              {"gx", options.shift_gain_x},
                              {"gy", options.shift_gain_y},
                              {"gr", options.shift_gain_r}};
  sim["radiometry"] = {
      {"formula",
       "value = exposure * gain_f * (mean over subsamples of albedo * cos_i * "
       "(r0/r)^2 * L(u - s*g) * R(v) + ambient * albedo)"},
      {"exposure", options.exposure},
      {"ambient", options.ambient},
      {"projector_falloff", "(albedo * cos_i * (r0/r)^2) times 1 - f*(un^2 + vn^2), f = " +
                                std::to_string(options.projector_falloff)},
      {"colour", object.colour.empty() ? "grey (one channel)"
                                       : "white and black frames RGB (each channel with its own "
                                         "albedo, noise per channel); pattern frames grey, the "
                                         "BT.709 luminance"},
      {"reference_distance_m", r0}};
  sim["noise"] = {{"scale", options.noise},
                  {"full_well_e", options.full_well_e},
                  {"read_noise_e", options.read_noise_e},
                  {"adc_bits", options.adc_bits},
                  {"gain_jitter", options.gain_jitter},
                  {"variance",
                   "scale^2 * (m / full_well_e + (read_noise_e / full_well_e)^2) + "
                   "q^2/12, q = 1/(2^adc_bits - 1), m in [0, 1]"},
                  {"png",
                   "16-bit, DN replicated to 16 bits: png = DN << (16 - bits) | "
                   "DN >> (2*bits - 16); png / 65535 = DN / (2^bits - 1)"}};
  sim["frame_gains"] = draws.gains;
  sim["shift_position_errors_px"] = draws.position_errors;
  sim["seed"] = options.seed;
  return sim;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

void SimulateOptions::Check() const {
  if (object.empty()) SIM_OPTION("object", "expected coin, plane, ramp, leaf or FILE.exr");
  if (!(projector_falloff >= 0 && projector_falloff < 0.5))
    SIM_OPTION("projector_falloff", "expected [0, 0.5), got " << projector_falloff);
  if (!(grey_card_size >= 0 && grey_card_size < 1) || !std::isfinite(grey_card_x) ||
      !std::isfinite(grey_card_y))
    SIM_OPTION("grey_card_size", "expected a finite centre and a side in [0, 1) m");
  if (!(grey_card_reflectance > 0 && grey_card_reflectance <= 1))
    SIM_OPTION("grey_card_reflectance", "expected (0, 1], got " << grey_card_reflectance);
  if (object_pixel_size_m < 0 || !(object_pixel_size_m < 1e-3))
    SIM_OPTION("object_pixel_size_m", "expected 0 (default) or a spacing in (0, 1e-3) m");
  if (rig.empty()) SIM_OPTION("rig", "expected 'paper' or a RIG.json file");
  for (double p : ps_periods_px)
    if (!(p > 2.0) || !std::isfinite(p))
      SIM_OPTION("ps_periods_px", "expected periods > 2 px, got " << p);
  if (!ps_periods_px.empty() && ps_phases < 3)
    SIM_OPTION("ps_phases", "expected >= 3, got " << ps_phases);
  if (ls_frames != 0 && ls_frames < 4)
    SIM_OPTION("ls_frames", "expected 0 or >= 4, got " << ls_frames);
  if (graycode_bits < 0 || graycode_bits > 30)
    SIM_OPTION("graycode_bits", "expected 0..30, got " << graycode_bits);
  if (!(graycode_block_px >= 1))
    SIM_OPTION("graycode_block_px", "expected >= 1, got " << graycode_block_px);
  if (ps_periods_px.empty() && ls_frames == 0 && graycode_bits == 0 && !white && !black)
    SIM_USAGE("frame plan: no frames requested");
  if (axis != 'x' && axis != 'y') SIM_OPTION("axis", "expected x or y, got '" << axis << "'");
  if (supersample < 1 || supersample > 8)
    SIM_OPTION("supersample", "expected 1..8, got " << supersample);
  if (!(fill_factor > 0 && fill_factor <= 1))
    SIM_OPTION("fill_factor", "expected (0, 1], got " << fill_factor);
  if (!(blur_sigma_px > 0.05 && blur_sigma_px <= 20))
    SIM_OPTION("blur_sigma_px", "expected a sigma in (0.05, 20] px, got " << blur_sigma_px);
  if (!(defocus_px_per_m >= 0 && defocus_px_per_m <= 1e5))
    SIM_OPTION("defocus_px_per_m", "expected [0, 1e5] px/m, got " << defocus_px_per_m);
  if (!std::isnan(focus_height_m) && !(std::abs(focus_height_m) < 1.0))
    SIM_OPTION("focus_height_m", "expected |z| < 1 m, got " << focus_height_m);
  if (!(std::abs(shift_gain_x) + std::abs(shift_gain_y) + 2 * std::abs(shift_gain_r) < 0.5))
    SIM_USAGE(OptionRef{"SimulateOptions.shift_gain_x"}
              << ", " << OptionRef{"SimulateOptions.shift_gain_y"} << ", "
              << OptionRef{"SimulateOptions.shift_gain_r"}
              << ": expected |gx| + |gy| + 2|gr| < 0.5");
  if (!(projector_gamma > 0 && projector_gamma <= 5))
    SIM_OPTION("projector_gamma", "expected (0, 5], got " << projector_gamma);
  if (!projector_curve.empty() && projector_curve != "s-curve")
    SIM_OPTION("projector_curve", "expected s-curve, got '" << projector_curve << "'");
  if (!projector_curve.empty() && projector_gamma != 1.0)
    SIM_OPTION("projector_curve", "a named curve replaces the gamma: not with --projector-gamma");
  if (!(exposure > 0 && exposure <= 100))
    SIM_OPTION("exposure", "expected (0, 100], got " << exposure);
  if (!(ambient >= 0 && ambient <= 100))
    SIM_OPTION("ambient", "expected [0, 100], got " << ambient);
  if (!(noise >= 0 && noise <= 100)) SIM_OPTION("noise", "expected [0, 100], got " << noise);
  if (!(full_well_e > 0)) SIM_OPTION("full_well_e", "expected > 0 electrons, got " << full_well_e);
  if (!(read_noise_e >= 0))
    SIM_OPTION("read_noise_e", "expected >= 0 electrons, got " << read_noise_e);
  if (adc_bits < 8 || adc_bits > 16) SIM_OPTION("adc_bits", "expected 8..16, got " << adc_bits);
  if (!(shift_position_error_px >= 0 && shift_position_error_px < 0.5))
    SIM_OPTION("shift_position_error_px", "expected [0, 0.5) px, got " << shift_position_error_px);
  if (!(gain_jitter >= 0 && gain_jitter < 0.2))
    SIM_OPTION("gain_jitter", "expected [0, 0.2), got " << gain_jitter);
  for (const Scratch& s : change.scratches)
    if (!(s.width_m > 0) || !(s.depth_m >= 0) || !std::isfinite(s.x0 + s.y0 + s.x1 + s.y1))
      SIM_OPTION("change", "a scratch needs finite ends, a width > 0 and a depth >= 0");
  for (const ErosionPatch& e : change.erosions)
    if (!(e.radius_m > kWearWallM) || !(e.depth_m >= 0) || !std::isfinite(e.cx + e.cy))
      SIM_OPTION("change", "an erosion patch needs a finite centre, a radius > "
                               << kWearWallM << " m and a depth >= 0");
  for (double v : change.pose)
    if (!std::isfinite(v)) SIM_OPTION("change", "the object pose must be finite");
  for (double v : change.field_offset)
    if (!(std::abs(v) < 10.0)) SIM_OPTION("change", "the field offset must be finite, |x| < 10 m");
  if (crop && (crop->w < 1 || crop->h < 1 || crop->x < 0 || crop->y < 0))
    SIM_OPTION("crop", "expected X,Y,W,H (or WxH+X+Y) with W, H >= 1 and X, Y >= 0");
}

double NoiseModel::Variance(double mean) const {
  const double q = 1.0 / ((1 << adc_bits) - 1);
  return scale * scale *
             (std::max(mean, 0.0) / full_well_e +
              (read_noise_e / full_well_e) * (read_noise_e / full_well_e)) +
         q * q / 12.0;
}

double NoiseModel::Sigma(double mean) const { return std::sqrt(Variance(mean)); }

NoiseModel MakeNoiseModel(const SimulateOptions& o) {
  return {o.noise, o.full_well_e, o.read_noise_e, o.adc_bits, o.gain_jitter};
}

Rig PaperRig() {
  Rig rig;
  PinholeCamera& cam = rig.camera;
  cam.width = 2176;
  cam.height = 1434;
  const double f = 0.25 / 55e-6;  // 55 um per pixel on the mount from 250 mm
  cam.K << f, 0, (cam.width - 1) / 2.0, 0, f, (cam.height - 1) / 2.0, 0, 0, 1;
  Mat4d m;
  m << 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0.25, 0, 0, 0, 1;
  cam.world_from_device = Rigid3d::FromMatrix(m);

  PinholeCamera& prj = rig.projector;
  prj.width = 800;
  prj.height = 600;
  prj.K << 1650, 0, (prj.width - 1) / 2.0, 0, 1650, (prj.height - 1) / 2.0, 0, 0, 1;
  // 20 degrees from the camera axis, 0.265 m from the mount centre, rotated about world y; the
  // projector's x axis is (cos a, 0, -sin a), so u grows along world +x.
  const double a = 20.0 * kPi / 180.0, dist = 0.265;
  prj.world_from_device.rotation.col(0) = Vec3d(std::cos(a), 0, -std::sin(a));
  prj.world_from_device.rotation.col(1) = Vec3d(0, -1, 0);
  prj.world_from_device.rotation.col(2) = Vec3d(-std::sin(a), 0, -std::cos(a));
  prj.world_from_device.translation = Vec3d(dist * std::sin(a), 0, dist * std::cos(a));

  LensShifter ls;
  ls.axis = 'x';
  ls.steps_per_px = 2048;
  ls.range_steps = {-2048, 2048};
  rig.lens_shifter = ls;
  return rig;
}

PinholeCamera CropCamera(const PinholeCamera& camera, const PixelRect& c) {
  if (c.w < 1 || c.h < 1 || c.x < 0 || c.y < 0 || int64_t{c.x} + c.w > camera.width ||
      int64_t{c.y} + c.h > camera.height)
    SIM_OPTION("crop", ToString(c) << " (X,Y,W,H) does not lie inside the " << camera.width << "x"
                                   << camera.height << " camera");
  PinholeCamera out = camera;
  out.width = c.w;
  out.height = c.h;
  out.K(0, 2) -= c.x;
  out.K(1, 2) -= c.y;
  return out;
}

Rig PortraitProjector(Rig rig) {
  PinholeCamera& prj = rig.projector;
  const PinholeCamera old = prj;
  prj.width = old.height;
  prj.height = old.width;
  prj.K(0, 0) = old.K(1, 1);
  prj.K(1, 1) = old.K(0, 0);
  prj.K(0, 2) = (old.height - 1) - old.K(1, 2);
  prj.K(1, 2) = old.K(0, 2);
  // device_old = M device_new, M = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]].
  Mat3d m;
  m << 0, 1, 0, -1, 0, 0, 0, 0, 1;
  prj.world_from_device.rotation = old.world_from_device.rotation * m;
  if (rig.lens_shifter) rig.lens_shifter->axis = 'y';
  return rig;
}

Rig ResolveRig(const SimulateOptions& o) {
  Rig rig = o.rig == "paper" ? PaperRig() : LoadRigFile(o.rig);
  if (o.rig == "paper" && o.axis == 'y') rig = PortraitProjector(rig);
  if (o.crop) rig.camera = CropCamera(rig.camera, *o.crop);
  if (o.projector_gamma != 1.0) {
    rig.projector_response.kind = Response::Kind::kGamma;
    rig.projector_response.gamma = o.projector_gamma;
  } else {
    rig.projector_response = Response();
  }
  return rig;
}

double ShifterGain(const SimulateOptions& o, const PinholeCamera& prj, double u, double v) {
  const double un = (u - prj.K(0, 2)) / (0.5 * prj.width);
  const double vn = (v - prj.K(1, 2)) / (0.5 * prj.height);
  return 1.0 + o.shift_gain_x * un + o.shift_gain_y * vn + o.shift_gain_r * (un * un + vn * vn);
}

FramePlanOptions SimulationFramePlan(const SimulateOptions& o, const Rig& rig) {
  FramePlanOptions plan;
  plan.periods_px = o.ps_periods_px;
  plan.phases = o.ps_phases;
  plan.axis = o.axis;
  plan.lens_shift_frames = o.ls_frames;
  plan.graycode_bits = o.graycode_bits;
  plan.graycode_block_px = o.graycode_block_px;
  plan.graycode_inverse = o.graycode_inverse;
  if (o.ls_frames > 0) {
    if (!rig.lens_shifter)
      SIM_OPTION("ls_frames", o.ls_frames << ": the rig has no lens_shifter (use 0)");
    plan.range_steps = rig.lens_shifter->range_steps;
    const int64_t positions = int64_t{plan.range_steps[1]} - plan.range_steps[0] + 1;
    if (o.ls_frames > positions)
      SIM_OPTION("ls_frames",
                 o.ls_frames << ": the rig's shifter has only " << positions << " positions");
  }
  plan.white = o.white;
  plan.black = o.black;
  return plan;
}

std::vector<Frame> MakeSimulationFrames(const SimulateOptions& o, const Rig& rig) {
  return MakeStandardFrames(SimulationFramePlan(o, rig));
}

std::string SimulateSummary::BriefReport() const {
  std::ostringstream os;
  os << std::fixed << std::setprecision(2) << "simulated " << frames << " frames of " << width
     << "x" << height << " (" << rays << " camera rays, " << lit_pixels << " lit pixels) in "
     << seconds_total << " s (scene " << seconds_scene << " s, ray cast " << seconds_raycast
     << " s, frames " << seconds_frames << " s)";
  return os.str();
}

SimulateSummary Simulate(const SimulateOptions& options, const fs::path& out_dir) {
  const Stopwatch total;
  options.Check();
  SimulateSummary summary;
  Rig rig = ResolveRig(options);
  rig.projector_falloff = options.projector_falloff;
  if (rig.lens_shifter && rig.lens_shifter->axis != options.axis && options.ls_frames > 0)
    SIM_OPTION("rig", "the lens shifter moves along axis \""
                          << rig.lens_shifter->axis << "\", expected \"" << options.axis << "\" as "
                          << OptionRef{"SimulateOptions.axis"});
  const std::vector<Frame> frames = MakeSimulationFrames(options, rig);

  // The scene: the object on the mount plane z = 0.
  SceneObject object =
      MakeObject(options.object, options.object_pixel_size_m, "SimulateOptions.object");
  ApplyObjectChange(options.change, &object);
  if (options.colour) ColourObject(&object);
  if (options.grey_card_size > 0) {
    const double h = 0.5 * options.grey_card_size;
    object.card =
        SceneObject::Card{options.grey_card_x - h, options.grey_card_y - h, options.grey_card_x + h,
                          options.grey_card_y + h, options.grey_card_reflectance};
  }
  EmbreeScene scene;
  scene.AddHeightField(object.height);
  const double focus_z = FocusHeight(object, options.focus_height_m);
  scene.AddPlane(0.0, 10.0);
  scene.Commit();
  summary.seconds_scene = total.Seconds();
  summary.width = rig.camera.width;
  summary.height = rig.camera.height;
  summary.frames = static_cast<int>(frames.size());

  // Stages 1 and 2: ray cast, blur levels, per-subsample light set-up.
  const Stopwatch t_ray;
  const RigView view = MakeRigView(rig, scene, object, options, focus_z);
  RayCastResult rc = RayCast(view, options.supersample);
  summary.rays = rc.rays;
  summary.lit_pixels = rc.lit_pixels;
  summary.unrefined_hits = scene.unrefined_hits();
  const BlurLevels levels = ChooseBlurLevels(rc, options);
  const std::vector<std::vector<float>> kernels = BlurKernels(levels, options.fill_factor);
  PrepareSubsamples(levels, kernels, rig.projector, options, &rc);
  summary.seconds_raycast = t_ray.Seconds();

  // Stage 3: light tables per distinct pattern, then every frame, ground truth and session.json.
  const Stopwatch t_frames;
  const PatternTables tables = BuildPatternTables(frames, rig, options, levels, kernels);
  const FrameDraws draws = DrawFrames(frames, options);
  WriteFolderAtomically(out_dir, [&](const fs::path& dir) {
    fs::create_directories(dir / "frames");
    Progress progress("simulate: frames", static_cast<int64_t>(frames.size()));
    ParallelFor(static_cast<int64_t>(frames.size()), [&](int64_t f) {
      const ImageU16 image =
          RenderFrame(frames[f], f, tables.tables[tables.frame_table[f]], rig, rc, draws, options);
      WritePng16(dir / frames[f].file, image, kPngCompressionLevel);
      progress.Advance();
    });
    progress.Finish();
    WriteExr(dir / "gt_points.exr", rc.gt_points, {"X", "Y", "Z", "lit_fraction", "relief"});
    const HeightField gt_height = GroundTruthHeight(rig.camera, object);
    WriteHeightExr(dir / "gt_height.exr", gt_height);
    const bool gt_albedo = !object.colour.empty() || object.card;
    if (gt_albedo) WriteGroundTruthAlbedo(dir / "gt_albedo.exr", gt_height, object);
    Session session;
    session.root = dir;
    session.created = SessionTimeNow();
    session.object = options.object_label.empty() ? object.name : options.object_label;
    session.rig = rig;
    session.frames = frames;
    session.ground_truth = GroundTruth{"gt_points.exr", "gt_height.exr"};
    session.extra["simulation"] =
        SimulationRecord(options, object, focus_z, levels, view.r0, draws);
    if (gt_albedo) session.extra["simulation"]["ground_truth_albedo"] = "gt_albedo.exr";
    if (object.card)
      session.extra["simulation"]["grey_card"] = GreyCardRecord(*object.card, rig.camera);
    WriteSessionJson(session);
  });
  summary.seconds_frames = t_frames.Seconds();
  summary.seconds_total = total.Seconds();
  return summary;
}

}  // namespace mesoscan
