#include "sim/virtual_rig.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <ctime>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>

#include <Eigen/Dense>

#include "assets/objects.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/scan_folder.h"
#include "render/embree_scene.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

constexpr int kTableSamplesPerPx = 128;  // light tables: samples per projector pixel
constexpr double kMaxSigmaStepPx = 0.02;  // light tables: largest blur step between levels
// zlib level of the frame PNGs: level 1 encodes noisy 16-bit frames ~2.5x faster than the
// default 6 for ~2% larger files (PNG encoding dominated the simulation's CPU time).
constexpr int kPngCompressionLevel = 1;

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

#define SIM_USAGE(expr) MESOSCAN_THROW(ErrorKind::kUsage, expr)

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
  double Uniform() { return (static_cast<double>(Next() >> 11) + 0.5) * (1.0 / 9007199254740992.0); }
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
  int n = 0;       // samples per level
  int x_lo = 0;    // x of sample 0 (integer projector px)
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
    k[i] = static_cast<float>((Phi((t + 0.5 * fill) / sigma) - Phi((t - 0.5 * fill) / sigma)) / fill);
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

std::string PeriodName(double period) {
  std::ostringstream os;
  if (period == std::round(period)) {
    os << std::setw(2) << std::setfill('0') << static_cast<int>(period);
  } else {
    os << period;
  }
  return os.str();
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

// Everything the frame stage needs per camera subsample (structure of arrays).
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

}  // namespace

// ---------------------------------------------------------------------------------------------

void SimulateOptions::Check() const {
  if (object.empty()) SIM_USAGE("--object: expected coin, plane, ramp, leaf or FILE.exr");
  if (object_pixel_size_m < 0 || !(object_pixel_size_m < 1e-3))
    SIM_USAGE("--object-pixel-size: expected 0 (default) or a spacing in (0, 1e-3) m");
  if (rig.empty()) SIM_USAGE("--rig: expected 'paper' or a RIG.json file");
  for (double p : ps_periods_px)
    if (!(p > 2.0) || !std::isfinite(p))
      SIM_USAGE("--ps-periods: expected periods > 2 px, got " << p);
  if (!ps_periods_px.empty() && ps_phases < 3)
    SIM_USAGE("--ps-phases: expected >= 3, got " << ps_phases);
  if (ls_frames != 0 && ls_frames < 4) SIM_USAGE("--ls-frames: expected 0 or >= 4, got " << ls_frames);
  if (ps_periods_px.empty() && ls_frames == 0 && !white && !black)
    SIM_USAGE("frame plan: no frames requested");
  if (axis != 'x' && axis != 'y') SIM_USAGE("--axis: expected x or y, got '" << axis << "'");
  if (supersample < 1 || supersample > 8)
    SIM_USAGE("--supersample: expected 1..8, got " << supersample);
  if (!(fill_factor > 0 && fill_factor <= 1))
    SIM_USAGE("--fill-factor: expected (0, 1], got " << fill_factor);
  if (!(blur_sigma_px > 0.05 && blur_sigma_px <= 20))
    SIM_USAGE("--blur: expected a sigma in (0.05, 20] px, got " << blur_sigma_px);
  if (!(defocus_px_per_m >= 0 && defocus_px_per_m <= 1e5))
    SIM_USAGE("--defocus: expected [0, 1e5] px/m, got " << defocus_px_per_m);
  if (!std::isnan(focus_height_m) && !(std::abs(focus_height_m) < 1.0))
    SIM_USAGE("--focus-height: expected |z| < 1 m, got " << focus_height_m);
  if (!(std::abs(shift_gain_x) + std::abs(shift_gain_y) + 2 * std::abs(shift_gain_r) < 0.5))
    SIM_USAGE("--shift-gain: expected |gx| + |gy| + 2|gr| < 0.5");
  if (!(projector_gamma > 0 && projector_gamma <= 5))
    SIM_USAGE("--projector-gamma: expected (0, 5], got " << projector_gamma);
  if (!(exposure > 0 && exposure <= 100)) SIM_USAGE("--exposure: expected (0, 100], got " << exposure);
  if (!(ambient >= 0 && ambient <= 10)) SIM_USAGE("--ambient: expected [0, 10], got " << ambient);
  if (!(noise >= 0 && noise <= 100)) SIM_USAGE("--noise: expected [0, 100], got " << noise);
  if (!(full_well_e > 0)) SIM_USAGE("--full-well: expected > 0 electrons, got " << full_well_e);
  if (!(read_noise_e >= 0)) SIM_USAGE("--read-noise: expected >= 0 electrons, got " << read_noise_e);
  if (adc_bits < 8 || adc_bits > 16) SIM_USAGE("--adc-bits: expected 8..16, got " << adc_bits);
  if (!(shift_position_error_px >= 0 && shift_position_error_px < 0.5))
    SIM_USAGE("--shift-position-error: expected [0, 0.5) px, got " << shift_position_error_px);
  if (!(gain_jitter >= 0 && gain_jitter < 0.2))
    SIM_USAGE("--gain-jitter: expected [0, 0.2), got " << gain_jitter);
  if (crop) {
    const auto& c = *crop;
    if (c[0] < 1 || c[1] < 1 || c[2] < 0 || c[3] < 0)
      SIM_USAGE("--crop: expected WxH+X+Y with W, H >= 1 and X, Y >= 0");
  }
}

double NoiseModel::Variance(double mean) const {
  const double q = 1.0 / ((1 << adc_bits) - 1);
  return scale * scale * (std::max(mean, 0.0) / full_well_e +
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

PinholeCamera CropCamera(const PinholeCamera& camera, const std::array<int, 4>& c) {
  if (c[0] < 1 || c[1] < 1 || c[2] < 0 || c[3] < 0 || c[2] + c[0] > camera.width ||
      c[3] + c[1] > camera.height)
    SIM_USAGE("--crop: " << c[0] << "x" << c[1] << "+" << c[2] << "+" << c[3]
                         << " does not lie inside the " << camera.width << "x" << camera.height
                         << " camera");
  PinholeCamera out = camera;
  out.width = c[0];
  out.height = c[1];
  out.K(0, 2) -= c[2];
  out.K(1, 2) -= c[3];
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

std::vector<Frame> MakeSimulationFrames(const SimulateOptions& o, const Rig& rig) {
  std::vector<Frame> frames;
  for (double period : o.ps_periods_px)
    for (int k = 0; k < o.ps_phases; ++k) {
      Frame f;
      f.file = "frames/ps" + PeriodName(period) + "_" + std::to_string(k) + ".png";
      f.pattern.type = PatternType::kSine;
      f.pattern.axis = o.axis;
      f.pattern.period_px = period;
      f.pattern.phase = 2 * kPi * k / o.ps_phases;
      frames.push_back(f);
    }
  if (o.ls_frames > 0) {
    if (!rig.lens_shifter)
      SIM_USAGE("--ls-frames " << o.ls_frames << ": the rig has no lens_shifter (use --ls-frames 0)");
    const auto r = rig.lens_shifter->range_steps;
    for (int k = 0; k < o.ls_frames; ++k) {
      Frame f;
      char name[32];
      std::snprintf(name, sizeof(name), "frames/ls_%03d.png", k);
      f.file = name;
      f.pattern.type = PatternType::kStripes;
      f.pattern.axis = o.axis;
      f.pattern.period_px = 2;
      f.shift_steps = static_cast<int>(
          std::lround(r[0] + static_cast<double>(k) * (r[1] - r[0]) / (o.ls_frames - 1)));
      frames.push_back(f);
    }
  }
  if (o.white) {
    Frame f;
    f.file = "frames/white.png";
    f.pattern.type = PatternType::kWhite;
    frames.push_back(f);
  }
  if (o.black) {
    Frame f;
    f.file = "frames/black.png";
    f.pattern.type = PatternType::kBlack;
    frames.push_back(f);
  }
  return frames;
}

std::string SimulateSummary::BriefReport() const {
  std::ostringstream os;
  os << std::fixed << std::setprecision(2) << "simulated " << frames << " frames of " << width
     << "x" << height << " (" << rays << " camera rays, " << lit_pixels
     << " lit pixels) in " << seconds_total << " s (scene " << seconds_scene << " s, ray cast "
     << seconds_raycast << " s, frames " << seconds_frames << " s)";
  return os.str();
}

SimulateSummary Simulate(const SimulateOptions& options, const fs::path& out_dir) {
  const auto t_start = std::chrono::steady_clock::now();
  options.Check();
  SimulateSummary summary;
  const Rig rig = ResolveRig(options);
  if (rig.lens_shifter && rig.lens_shifter->axis != options.axis && options.ls_frames > 0)
    SIM_USAGE("--rig: the lens shifter moves along axis \"" << rig.lens_shifter->axis
                                                           << "\", expected \"" << options.axis
                                                           << "\" as --axis");
  // Patterns vary along the fringe axis only: the cache holds the coordinate along it in `x`
  // and the one across it in `sub_v` (for axis 'y' the projector's v and u).
  const bool along_y = options.axis == 'y';
  const std::vector<Frame> frames = MakeSimulationFrames(options, rig);

  // ---- scene: the object on the mount plane z = 0 ----
  SceneObject object = MakeObject(options.object, options.object_pixel_size_m);
  EmbreeScene scene;
  scene.AddHeightField(object.height);
  double focus_z = options.focus_height_m;
  if (std::isnan(focus_z)) {  // the object's mid height
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (float z : object.height.z.data())
      if (std::isfinite(z)) {
        lo = std::min(lo, static_cast<double>(z));
        hi = std::max(hi, static_cast<double>(z));
      }
    focus_z = std::isfinite(lo) ? 0.5 * (lo + hi) : 0.0;
  }
  scene.AddPlane(0.0, 10.0);
  scene.Commit();
  summary.seconds_scene = Seconds(t_start);

  const PinholeCamera& cam = rig.camera;
  const PinholeCamera& prj = rig.projector;
  const Rigid3d prj_from_world = prj.world_from_device.Inverse();
  const Vec3d cam_centre = cam.CentreInWorld(), prj_centre = prj.CentreInWorld();
  const double r0 = prj_centre.norm();  // reference distance: projector centre to the origin
  const int W = cam.width, H = cam.height, S = options.supersample;
  const size_t n_sub = static_cast<size_t>(W) * H * S * S;
  summary.width = W;
  summary.height = H;
  summary.frames = static_cast<int>(frames.size());

  // ---- stage 1: one ray per camera subsample (and per pixel centre for ground truth) ----
  const auto t_ray = std::chrono::steady_clock::now();
  SubsampleCache cache;
  cache.Resize(n_sub);
  std::vector<float> sub_v(n_sub, 0.0f), sub_sigma(n_sub, 0.0f);
  std::vector<float> ambient_albedo(static_cast<size_t>(W) * H, 0.0f);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // X, Y, Z of the centre ray's hit, then the footprint: lit_fraction, relief (see sim/README.md).
  ImageF gt_points(W, H, 5, nan);
  std::atomic<int64_t> lit_pixels{0};

  struct Sample {
    bool hit = false, lit = false;
    Vec3d point;
    double albedo = 0, u = 0, v = 0, sigma = 0, shading = 0;
  };
  auto shade = [&](const Vec2d& uv) {
    Sample s;
    const Vec3d d = cam.RayDirectionInWorld(uv);
    const std::optional<RayHit> hit = scene.Intersect(cam_centre, d);
    if (!hit) return s;
    s.hit = true;
    s.point = hit->point;
    s.albedo = object.Albedo(s.point.x(), s.point.y());
    const Vec3d p_dev = prj_from_world * s.point;
    double uvp[2];
    if (!prj.ProjectDevice(p_dev.data(), uvp)) return s;
    s.u = uvp[0];
    s.v = uvp[1];
    Vec3d l = prj_centre - s.point;
    const double r = l.norm();
    l /= r;
    const double cos_i = hit->normal.dot(l);
    if (!(cos_i > 0)) return s;
    if (options.shadows && scene.Occluded(EmbreeScene::ShadowRayOrigin(*hit), l, 0.0, r)) return s;
    s.sigma = options.blur_sigma_px + options.defocus_px_per_m * std::abs(s.point.z() - focus_z);
    s.shading = s.albedo * cos_i * (r0 / r) * (r0 / r);
    s.lit = s.u >= -0.5 && s.u <= prj.width - 0.5 && s.v >= -0.5 && s.v <= prj.height - 0.5;
    return s;
  };
  {
    Progress progress("simulate: ray cast", H);
    ParallelForRows(H, [&](int y0, int y1) {
      for (int py = y0; py < y1; ++py) {
        for (int px = 0; px < W; ++px) {
          const size_t pix = static_cast<size_t>(py) * W + px;
          double albedo_sum = 0;
          Sample centre;
          int lit_subsamples = 0;
          std::vector<Vec3d> hits;
          hits.reserve(S * S);
          for (int b = 0; b < S; ++b)
            for (int a = 0; a < S; ++a) {
              const size_t k = (pix * S + b) * S + a;
              const Sample s = shade(Vec2d(px + (a + 0.5) / S - 0.5, py + (b + 0.5) / S - 0.5));
              if (2 * a + 1 == S && 2 * b + 1 == S) centre = s;
              albedo_sum += s.albedo;
              lit_subsamples += s.lit;
              if (s.hit) hits.push_back(s.point);
              if (s.shading > 0) {
                cache.x[k] = static_cast<float>(along_y ? s.v : s.u);
                sub_v[k] = static_cast<float>(along_y ? s.u : s.v);
                sub_sigma[k] = static_cast<float>(s.sigma);
                cache.shading[k] = static_cast<float>(s.shading);
              }
            }
          ambient_albedo[pix] = static_cast<float>(albedo_sum / (S * S));
          // The pixel centre is a subsample when S is odd.
          const Sample c = S % 2 == 1 ? centre : shade(Vec2d(px, py));
          if (c.lit) {
            gt_points(px, py, 0) = static_cast<float>(c.point.x());
            gt_points(px, py, 1) = static_cast<float>(c.point.y());
            gt_points(px, py, 2) = static_cast<float>(c.point.z());
            ++lit_pixels;
          }
          gt_points(px, py, 3) = static_cast<float>(lit_subsamples) / (S * S);
          gt_points(px, py, 4) = static_cast<float>(FootprintRelief(hits));
        }
        progress.Advance();
      }
    });
  }
  summary.rays = static_cast<int64_t>(n_sub) + (S % 2 == 1 ? 0 : static_cast<int64_t>(W) * H);
  summary.lit_pixels = lit_pixels.load();
  summary.unrefined_hits = scene.unrefined_hits();

  // ---- stage 2: blur levels, the row profile R_v(v) and the shifter gain per subsample ----
  BlurLevels levels;
  {
    double smin = std::numeric_limits<double>::infinity(), smax = -smin;
    for (size_t k = 0; k < n_sub; ++k)
      if (cache.shading[k] > 0) {
        smin = std::min<double>(smin, sub_sigma[k]);
        smax = std::max<double>(smax, sub_sigma[k]);
      }
    if (!std::isfinite(smin)) smin = smax = options.blur_sigma_px;
    levels.sigma_min = smin;
    levels.count = std::max(2, static_cast<int>(std::ceil((smax - smin) / kMaxSigmaStepPx)) + 1);
    levels.step = smax > smin ? (smax - smin) / (levels.count - 1) : kMaxSigmaStepPx;
    levels.half_support =
        static_cast<int>(std::ceil(0.5 * options.fill_factor + 6.0 * levels.Sigma(levels.count - 1)));
  }
  std::vector<std::vector<float>> kernels(levels.count);
  ParallelFor(levels.count, [&](int64_t l) {
    kernels[l] = Kernel(levels.Sigma(static_cast<int>(l)), options.fill_factor, levels.half_support);
  });
  {
    // Along v every pattern is uniform: the light is L(u) * R_v(v), R_v = sum_v w(v' - v).
    const LightTables rows =
        BuildTables(std::vector<double>(along_y ? prj.width : prj.height, 1.0), levels, kernels);
    ParallelFor(
        static_cast<int64_t>(n_sub),
        [&](int64_t k) {
          if (cache.shading[k] <= 0) return;
          const float level = levels.Level(sub_sigma[k]);
          cache.level[k] = level;
          cache.shading[k] *= rows.Lookup(sub_v[k], level);
          cache.gain[k] = static_cast<float>(along_y ? ShifterGain(options, prj, sub_v[k], cache.x[k])
                                                     : ShifterGain(options, prj, cache.x[k], sub_v[k]));
        },
        4096);
  }
  sub_v = {};
  sub_sigma = {};
  summary.seconds_raycast = Seconds(t_ray);

  // ---- stage 3: light tables per distinct pattern, then every frame ----
  const auto t_frames = std::chrono::steady_clock::now();
  std::map<std::tuple<int, double, double>, int> pattern_index;
  std::vector<int> frame_table(frames.size());
  std::vector<const Pattern*> table_patterns;
  for (size_t f = 0; f < frames.size(); ++f) {
    const Pattern& p = frames[f].pattern;
    const auto key = std::make_tuple(static_cast<int>(p.type), p.period_px, p.phase);
    auto it = pattern_index.find(key);
    if (it == pattern_index.end()) {
      it = pattern_index.emplace(key, static_cast<int>(table_patterns.size())).first;
      table_patterns.push_back(&p);
    }
    frame_table[f] = it->second;
  }
  std::vector<LightTables> tables(table_patterns.size());
  for (size_t t = 0; t < table_patterns.size(); ++t) {
    std::vector<double> p(along_y ? prj.height : prj.width);
    for (int u = 0; u < static_cast<int>(p.size()); ++u)
      p[u] = rig.projector_response.ToLinear(
          along_y ? table_patterns[t]->Value(0.0, u) : table_patterns[t]->Value(u, 0.0));
    tables[t] = BuildTables(p, levels, kernels);
  }

  const NoiseModel noise = MakeNoiseModel(options);
  const int dn_max = (1 << options.adc_bits) - 1;
  std::vector<double> frame_gains(frames.size(), 1.0);
  for (size_t f = 0; f < frames.size(); ++f) {
    Rng rng(MixSeed(options.seed, 2 * f + 1));
    frame_gains[f] = 1.0 + noise.GainJitterSigma() * rng.Normal();
  }
  std::vector<double> position_errors(frames.size(), 0.0);
  if (options.shift_position_error_px > 0)
    for (size_t f = 0; f < frames.size(); ++f) {
      if (frames[f].pattern.type != PatternType::kStripes) continue;
      Rng rng(MixSeed(options.seed ^ 0x5eedf00dULL, 2 * f + 1));
      position_errors[f] = options.shift_position_error_px * rng.Normal();
    }
  const double inv_ss = 1.0 / (S * S);

  auto fill = [&](const fs::path& dir) {
    fs::create_directories(dir / "frames");
    Progress progress("simulate: frames", static_cast<int64_t>(frames.size()));
    ParallelFor(static_cast<int64_t>(frames.size()), [&](int64_t f) {
      const Frame& frame = frames[f];
      const LightTables& tab = tables[frame_table[f]];
      const double shift_px =
          (rig.lens_shifter ? frame.shift_steps / rig.lens_shifter->steps_per_px : 0.0) +
          position_errors[f];
      const bool dark = frame.pattern.type == PatternType::kBlack;
      Rng rng(MixSeed(options.seed, 2 * f + 2));
      ImageU16 image(W, H, 1);
      uint16_t* out = image.channel(0);
      for (size_t pix = 0; pix < static_cast<size_t>(W) * H; ++pix) {
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
        const double mean = options.exposure * (acc * inv_ss + options.ambient * ambient_albedo[pix]);
        double value = mean * frame_gains[f];
        if (options.noise > 0) value += noise.Sigma(mean) * rng.Normal();
        const int dn = static_cast<int>(std::lround(std::clamp(value, 0.0, 1.0) * dn_max));
        out[pix] = ToPng16(dn, options.adc_bits);
      }
      WritePng16(dir / frame.file, image, kPngCompressionLevel);
      progress.Advance();
    });
    progress.Finish();

    // Ground truth: points on the camera grid, the height field on the camera footprint.
    WriteExr(dir / "gt_points.exr", gt_points, {"X", "Y", "Z", "lit_fraction", "relief"});
    HeightField gt;
    {
      // Footprint of the camera on z = 0: the rays through the image corners.
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
      // Pixel size: one camera pixel on the mount at the image centre.
      const Vec3d dc = cam.RayDirectionInWorld(Vec2d(cam.K(0, 2), cam.K(1, 2)));
      gt.pixel_size = (-cam_centre.z() / dc.z()) * dc.norm() / cam.K(0, 0);
      const int gw =
          std::max(1, static_cast<int>(std::floor((xmax - xmin) / gt.pixel_size + 1e-6)));
      const int gh =
          std::max(1, static_cast<int>(std::floor((ymax - ymin) / gt.pixel_size + 1e-6)));
      gt.x0 = xmin + 0.5 * gt.pixel_size;
      gt.y0 = ymax - 0.5 * gt.pixel_size;
      // The EXR header stores the grid in float: sample where the file says the pixels are.
      gt.x0 = StoredAsFloat(gt.x0);
      gt.y0 = StoredAsFloat(gt.y0);
      gt.pixel_size = StoredAsFloat(gt.pixel_size);
      gt.z = ImageF(gw, gh, 1);
      ParallelForRows(gh, [&](int j0, int j1) {
        for (int j = j0; j < j1; ++j)
          for (int i = 0; i < gw; ++i) gt.z(i, j) = static_cast<float>(object.SurfaceZ(gt.X(i), gt.Y(j)));
      });
    }
    WriteHeightExr(dir / "gt_height.exr", gt);

    Session session;
    session.root = dir;
    session.created = SessionTimeNow();
    session.object = options.object_label.empty() ? object.name : options.object_label;
    session.rig = rig;
    session.frames = frames;
    session.ground_truth = GroundTruth{"gt_points.exr", "gt_height.exr"};
    Json sim;
    sim["model"] = "mesoscan virtual rig 1 (sim/README.md)";
    sim["object"] = {{"name", object.name},
                     {"source", options.object},
                     {"grid_pixel_size_m", object.height.pixel_size},
                     {"grid_size", {object.height.width(), object.height.height()}}};
    sim["rig"] = options.rig;
    if (options.crop) sim["crop"] = *options.crop;
    sim["supersample"] = S;
    sim["axis"] = std::string(1, options.axis);
    sim["shadows"] = options.shadows;
    sim["projector"] = {{"fill_factor", options.fill_factor},
                        {"blur_sigma_px", options.blur_sigma_px},
                        {"defocus_px_per_m", options.defocus_px_per_m},
                        {"focus_height_m", focus_z},
                        {"gamma", options.projector_gamma},
                        {"blur_sigma_range_px", {levels.sigma_min, levels.Sigma(levels.count - 1)}}};
    sim["lens_shifter_gain"] = {
        {"formula", "g = 1 + gx*un + gy*vn + gr*(un^2 + vn^2), un = (u - cx)/(W/2), "
                    "vn = (v - cy)/(H/2), (u, v) projector pixel at shift 0"},
        {"gx", options.shift_gain_x},
        {"gy", options.shift_gain_y},
        {"gr", options.shift_gain_r}};
    sim["radiometry"] = {
        {"formula", "value = exposure * gain_f * (mean over subsamples of albedo * cos_i * "
                    "(r0/r)^2 * L(u - s*g) * R(v) + ambient * albedo)"},
        {"exposure", options.exposure},
        {"ambient", options.ambient},
        {"reference_distance_m", r0}};
    sim["noise"] = {{"scale", options.noise},
                    {"full_well_e", options.full_well_e},
                    {"read_noise_e", options.read_noise_e},
                    {"adc_bits", options.adc_bits},
                    {"gain_jitter", options.gain_jitter},
                    {"variance", "scale^2 * (m / full_well_e + (read_noise_e / full_well_e)^2) + "
                                 "q^2/12, q = 1/(2^adc_bits - 1), m in [0, 1]"},
                    {"png", "16-bit, DN replicated to 16 bits: png = DN << (16 - bits) | "
                            "DN >> (2*bits - 16); png / 65535 = DN / (2^bits - 1)"}};
    sim["frame_gains"] = frame_gains;
    sim["shift_position_errors_px"] = position_errors;
    sim["seed"] = options.seed;
    session.extra["simulation"] = sim;
    WriteSessionJson(session);
  };
  WriteFolderAtomically(out_dir, fill);
  summary.seconds_frames = Seconds(t_frames);
  summary.seconds_total = Seconds(t_start);
  return summary;
}

}  // namespace mesoscan
