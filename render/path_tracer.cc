#include "render/path_tracer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <sstream>

#include "core/error.h"
#include "core/image_io.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "render/embree_scene.h"

namespace mesoscan {

void RenderOptions::Check() const {
  if (width < 1 || height < 1) MESOSCAN_BAD_INPUT("render: --size must be at least 1x1");
  if (min_spp < 1 || max_spp < min_spp)
    MESOSCAN_BAD_INPUT("render: expected 1 <= min_spp <= max_spp, got " << min_spp << ", " << max_spp);
  if (!(relative_error > 0)) MESOSCAN_BAD_INPUT("render: relative_error must be > 0");
  if (max_depth < 1) MESOSCAN_BAD_INPUT("render: max_depth must be >= 1");
  if (!(elevation_deg > 0 && elevation_deg <= 90))
    MESOSCAN_BAD_INPUT("render: elevation must be in (0, 90] degrees");
  if (!(relief_scale > 0)) MESOSCAN_BAD_INPUT("render: relief_scale must be > 0");
}

std::string RenderSummary::BriefReport() const {
  std::ostringstream s;
  s << samples << " paths in " << seconds << " s, " << pixels_converged
    << " pixels converged before the sample limit";
  return s.str();
}

namespace {

// PCG32 (O'Neill 2014): a small, fast, per-pixel generator; no allocation.
struct Pcg32 {
  uint64_t state, inc;
  Pcg32(uint64_t seed, uint64_t stream) : state(0), inc((stream << 1u) | 1u) {
    Next();
    state += seed;
    Next();
  }
  uint32_t Next() {
    const uint64_t old = state;
    state = old * 6364136223846793005ULL + inc;
    const uint32_t xorshifted = static_cast<uint32_t>(((old >> 18u) ^ old) >> 27u);
    const uint32_t rot = static_cast<uint32_t>(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31));
  }
  double Uniform() { return std::min(Next() * 0x1p-32, 0x1.fffffffffffffp-1); }
  Vec2 Uniform2() {
    const double a = Uniform();
    return {a, Uniform()};
  }
};

// Orthonormal frame with z = n (Duff et al. 2017).
struct Frame {
  Vec3 s, t, n;
  explicit Frame(const Vec3& nn) : n(nn) {
    const double sign = std::copysign(1.0, n.z());
    const double a = -1.0 / (sign + n.z());
    const double b = n.x() * n.y() * a;
    s = Vec3(1 + sign * n.x() * n.x() * a, sign * b, -sign * n.x());
    t = Vec3(b, sign + n.y() * n.y() * a, -n.y());
  }
  Vec3 ToLocal(const Vec3& v) const { return {v.dot(s), v.dot(t), v.dot(n)}; }
  Vec3 FromLocal(const Vec3& v) const { return v.x() * s + v.y() * t + v.z() * n; }
};

double PowerHeuristic(double a, double b) {
  const double a2 = a * a, b2 = b * b;
  return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
}

struct Scene {
  EmbreeScene embree;
  int hf_id = -1;
  int plane_id = -1;
};

// Radiance along one camera ray.
Rgb TracePath(const Scene& scene, const Brdf& brdf, const LambertBrdf& mount,
              const EnvironmentMap& env, Vec3 origin, Vec3 dir, int max_depth, Pcg32& rng) {
  Rgb L = Rgb::Zero(), beta = Rgb::Ones();
  double prev_brdf_pdf = 0;  // 0: the previous direction was not BRDF-sampled (camera ray)
  for (int depth = 0;; ++depth) {
    const auto hit = scene.embree.Intersect(origin, dir, 1e-9);
    if (!hit) {
      const Rgb Le = env.Le(dir);
      const double w = (prev_brdf_pdf > 0 && !env.is_constant())
                           ? PowerHeuristic(prev_brdf_pdf, env.Pdf(dir))
                           : 1.0;
      L += beta * Le * w;
      break;
    }
    if (depth >= max_depth) break;
    Vec3 n = hit->normal;
    if (n.dot(dir) > 0) n = -n;  // seen from below (never for a height field from above)
    const Frame frame(n);
    const Vec3 wo = frame.ToLocal(-dir);
    const bool on_mount = hit->geometry == scene.plane_id;
    auto f = [&](const Vec3& wi) { return on_mount ? mount.f(wo, wi) : brdf.f(wo, wi); };
    auto pdf = [&](const Vec3& wi) { return on_mount ? mount.Pdf(wo, wi) : brdf.Pdf(wo, wi); };
    const Vec3 shadow_origin = EmbreeScene::ShadowRayOrigin(*hit);
    // Next-event estimation towards the environment.
    if (auto ls = env.Sample(rng.Uniform2())) {
      const Vec3 wi = frame.ToLocal(ls->wi);
      if (wi.z() > 0 && !scene.embree.Occluded(shadow_origin, ls->wi, 0.0, 1e30)) {
        const Rgb fv = f(wi);
        const double w = PowerHeuristic(ls->pdf, pdf(wi));
        L += beta * fv * ls->Le * (wi.z() * w / ls->pdf);
      }
    }
    // Continue by BRDF sampling.
    const Vec2 u = rng.Uniform2();
    const auto bs = on_mount ? mount.Sample(wo, u) : brdf.Sample(wo, u);
    if (!bs || !(bs->pdf > 0) || bs->wi.z() <= 0) break;
    beta *= bs->f * (bs->wi.z() / bs->pdf);
    if (!beta.allFinite()) break;
    // Russian roulette after two bounces.
    if (depth >= 2) {
      const double q = std::max(0.05, 1.0 - beta.maxCoeff());
      if (rng.Uniform() < q) break;
      beta /= 1.0 - q;
    }
    prev_brdf_pdf = bs->pdf;
    origin = shadow_origin;
    dir = frame.FromLocal(bs->wi).normalized();
  }
  return L.allFinite() ? L : Rgb::Zero();
}

}  // namespace

ImageF RenderHeightField(const HeightField& hf_in, const Brdf& brdf, const EnvironmentMap& env,
                         const RenderOptions& options, RenderSummary* summary) {
  options.Check();
  const auto start = std::chrono::steady_clock::now();
  // Heights are exaggerated around the mount plane for previews of low relief.
  HeightField hf = hf_in;
  double zmin = 1e30, zmax = -1e30;
  for (float& z : hf.z.data()) {
    if (!std::isfinite(z)) continue;
    z = static_cast<float>(z * options.relief_scale);
    zmin = std::min(zmin, static_cast<double>(z));
    zmax = std::max(zmax, static_cast<double>(z));
  }
  if (zmin > zmax) MESOSCAN_BAD_INPUT("render: the height field has no valid sample");

  Scene scene;
  scene.hf_id = scene.embree.AddHeightField(hf);
  const double ex = hf.width() * hf.pixel_size, ey = hf.height() * hf.pixel_size;
  const double extent = std::max(ex, ey);
  scene.plane_id = scene.embree.AddPlane(std::min(0.0, zmin) - 1e-6, 10 * extent + 1.0);
  scene.embree.Commit();

  // Pinhole camera framing the height field.
  const Vec3 centre(hf.X(0.5 * (hf.width() - 1)), hf.Y(0.5 * (hf.height() - 1)),
                    0.5 * (zmin + zmax));
  const double el = options.elevation_deg * kPi / 180, az = options.azimuth_deg * kPi / 180;
  const double fov = options.fov_deg > 0 ? options.fov_deg * kPi / 180 : 30.0 * kPi / 180;
  const double aspect = static_cast<double>(options.width) / options.height;
  // Distance so the larger extent fills ~90% of the view.
  const double half = 0.5 * std::max(ey, ex / aspect) / 0.9;
  const double dist = half / std::tan(0.5 * fov) + 0.5 * (zmax - zmin);
  const Vec3 eye = centre + dist * Vec3(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az),
                                        std::sin(el));
  const Vec3 fwd = (centre - eye).normalized();
  Vec3 right = fwd.cross(Vec3(0, 0, 1));
  if (right.norm() < 1e-9) right = Vec3(1, 0, 0);
  right.normalize();
  const Vec3 up = right.cross(fwd);
  const double tan_half = std::tan(0.5 * fov);

  const LambertBrdf mount(options.mount_albedo);
  ImageF out(options.width, options.height, 3, 0.0f);
  std::atomic<int64_t> samples{0}, converged{0};
  Progress progress("render", options.height);
  ParallelForRows(options.height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < options.width; ++x) {
        Pcg32 rng(options.seed, static_cast<uint64_t>(y) * options.width + x);
        Rgb sum = Rgb::Zero();
        double lum_sum = 0, lum_sq = 0;
        int n = 0;
        for (; n < options.max_spp; ++n) {
          if (n >= options.min_spp && n % 8 == 0) {
            const double mean = lum_sum / n;
            const double var = std::max(0.0, lum_sq / n - mean * mean) / (n - 1);
            if (std::sqrt(var) < options.relative_error * std::max(mean, 1e-4)) {
              converged.fetch_add(1, std::memory_order_relaxed);
              break;
            }
          }
          const double px = (x + rng.Uniform()) / options.width * 2 - 1;
          const double py = 1 - (y + rng.Uniform()) / options.height * 2;
          const Vec3 dir =
              (fwd + right * (px * tan_half * aspect) + up * (py * tan_half)).normalized();
          const Rgb L = TracePath(scene, brdf, mount, env, eye, dir, options.max_depth, rng);
          sum += L;
          const double l = Luminance(L);
          lum_sum += l;
          lum_sq += l * l;
        }
        samples.fetch_add(n, std::memory_order_relaxed);
        for (int c = 0; c < 3; ++c) out(x, y, c) = static_cast<float>(sum[c] / std::max(n, 1));
      }
      progress.Advance();
    }
  });
  progress.Finish();
  if (summary) {
    summary->samples = samples;
    summary->pixels_converged = converged;
    summary->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return out;
}

ImageU8 ToneMapForDisplay(const ImageF& radiance) {
  // Exposure from the log-average luminance (key 0.18, Reinhard et al. 2002), then the extended
  // Reinhard curve per channel with the white point at the 99.5th percentile, so a sun glint
  // neither blows out the image nor darkens everything else; sRGB encoding last.
  const size_t n = radiance.pixels();
  std::vector<float> lum(n);
  double log_sum = 0;
  for (size_t i = 0; i < n; ++i) {
    lum[i] = static_cast<float>(Luminance(
        Rgb(radiance.channel(0)[i], radiance.channel(1)[i], radiance.channel(2)[i])));
    log_sum += std::log(1e-6 + std::max(0.0f, lum[i]));
  }
  const double log_avg = n ? std::exp(log_sum / n) : 1.0;
  const double exposure = log_avg > 0 ? 0.18 / log_avg : 1.0;
  const size_t k = n ? static_cast<size_t>(0.995 * (n - 1)) : 0;
  if (n) std::nth_element(lum.begin(), lum.begin() + k, lum.end());
  const double white = std::max(1.0, n ? lum[k] * exposure : 1.0);
  ImageF mapped(radiance.width(), radiance.height(), 3);
  for (int c = 0; c < 3; ++c)
    for (size_t i = 0; i < n; ++i) {
      const double v = std::max(0.0, radiance.channel(c)[i] * exposure);
      mapped.channel(c)[i] = static_cast<float>(v * (1 + v / (white * white)) / (1 + v));
    }
  return QuantizeU8(mapped, /*srgb_encode=*/true);
}

}  // namespace mesoscan
