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
#include "render/mirror_guide.h"
#include "render/sampler.h"

namespace mesoscan {

void RenderOptions::Check() const {
  if (width < 1 || height < 1)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("RenderOptions.size"), "must be at least 1x1");
  if (min_spp < 1 || max_spp < min_spp)
    MESOSCAN_BAD_INPUT("render: expected 1 <= min_spp <= max_spp, got " << min_spp << ", "
                                                                        << max_spp);
  if (max_spp > (1 << 24))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("RenderOptions.max_spp"), "must be at most 16777216");
  if (!(noise >= 0) || !std::isfinite(noise))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("RenderOptions.noise"), "must be >= 0");
  if (!(time_limit_s >= 0) || !std::isfinite(time_limit_s))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("RenderOptions.time_limit_s"), "must be >= 0 seconds");
  if (max_depth < 1) MESOSCAN_BAD_INPUT("render: max_depth must be >= 1");
  if (!(allocate_spp >= 0) || !std::isfinite(allocate_spp) || allocate_spp > (1 << 24))
    MESOSCAN_BAD_INPUT("render: allocate_spp must be in [0, 16777216]");
  if (allocate_pilot_spp < 0 || allocate_radius < 1 || !(allocate_floor > 0 && allocate_floor <= 1))
    MESOSCAN_BAD_INPUT(
        "render: expected allocate_pilot_spp >= 0, allocate_radius >= 1, "
        "allocate_floor in (0, 1]");
  if (!(allocate_denoise_tau > 0) || !std::isfinite(allocate_denoise_tau) ||
      !(allocate_denoise_max >= 1) || !std::isfinite(allocate_denoise_max) ||
      allocate_denoise_pilot_spp < 1)
    MESOSCAN_BAD_INPUT(
        "render: expected allocate_denoise_tau > 0, allocate_denoise_max >= 1 and "
        "allocate_denoise_pilot_spp >= 1");
  if (resample_candidates < 0 || resample_candidates > 16)
    MESOSCAN_BAD_INPUT("render: resample_candidates must be in [0, 16]");
  if (!(elevation_deg > 0 && elevation_deg <= 90))
    MESOSCAN_BAD_INPUT("render: elevation must be in (0, 90] degrees");
  if (!(fov_deg >= 0 && fov_deg < 180))
    MESOSCAN_BAD_INPUT("render: fov must be in (0, 180) degrees");
  if (!(relief_scale > 0) || !std::isfinite(relief_scale))
    MESOSCAN_BAD_INPUT("render: relief_scale must be > 0");
  if (camera) {
    if (!camera->eye.allFinite() || !camera->target.allFinite() ||
        !((camera->target - camera->eye).norm() > 0))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::Option("RenderOptions.camera"),
                            "eye and target must be finite and distinct");
  }
}

std::string RenderSummary::BriefReport() const {
  std::ostringstream s;
  s << samples << " paths in " << seconds << " s (" << mean_spp << " spp on average, " << rounds
    << " rounds), " << pixels_converged << " pixels converged before the sample limit";
  if (!mount_visible) s << "; the camera cannot see the mount (camera rays skip it)";
  if (mirror_guide) s << "; mirrored-environment sampling on";
  return s.str();
}

namespace {

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

// Below this selection probability a vertex does not use the mirrored-environment sampler
// (preparing it costs 64 BRDF evaluations; it would hardly ever be chosen).
constexpr double kMinGuideSelect = 0.05;

double PowerHeuristic(double a, double b) {
  const double a2 = a * a, b2 = b * b;
  return a2 + b2 > 0 ? a2 / (a2 + b2) : 0.0;
}

struct Scene {
  EmbreeScene embree;
  int hf_id = -1;
  int plane_id = -1;
  const HeightField* hf = nullptr;
  const ImageF* albedo = nullptr;            // on hf's grid, or null
  const ImageU8* sample_material = nullptr;  // on hf's grid, or null (all sample)
  int max_depth = 4;
  Rgb mount_irradiance = Rgb::Zero();  // the environment's, on the mount from above
  // What camera rays see: kMaskHeightFields when the camera provably cannot see the mount.
  unsigned camera_mask = EmbreeScene::kMaskAll;
  // The mirrored-environment sampler for continuation rays (render/mirror_guide.h), or null.
  const MirrorGuide* guide = nullptr;
  int resample = 0;  // RenderOptions::resample_candidates (with the guide only)

  // False where RenderOptions::sample_material marks the height field's sample as bare mount.
  bool OnSample(const Vec3& p) const {
    if (!sample_material) return true;
    const int i =
        std::clamp(static_cast<int>(std::lround(hf->I(p.x()))), 0, sample_material->width() - 1);
    const int j =
        std::clamp(static_cast<int>(std::lround(hf->J(p.y()))), 0, sample_material->height() - 1);
    return (*sample_material)(i, j) != 0;
  }

  Rgb Tint(const Vec3& p) const {
    if (!albedo) return Rgb::Ones();
    const int i = std::clamp(static_cast<int>(std::lround(hf->I(p.x()))), 0, albedo->width() - 1);
    const int j = std::clamp(static_cast<int>(std::lround(hf->J(p.y()))), 0, albedo->height() - 1);
    if (albedo->channels() >= 3)
      return Rgb((*albedo)(i, j, 0), (*albedo)(i, j, 1), (*albedo)(i, j, 2));
    return Rgb::Constant((*albedo)(i, j, 0));
  }
};

// What a camera ray's first hit reports besides its radiance (the feature buffers).
struct FirstHit {
  bool sample = false;  // hit the height field
  Vec3 normal = Vec3::Zero();
  double depth = 0;
  Rgb albedo = Rgb::Zero();
};

// Radiance along one camera ray. `first` reports the camera ray's first hit.
//
// Control variate on the mount (a Lambert plane facing +z): its reflected radiance is
// f E_env - f int (Le - L_traced)(w) cos dw over the directions the sample (or a hole's
// underside) occludes, with E_env = EnvironmentMap::UpperHemisphereIrradiance() in closed form.
// So a mount vertex adds f E_env at once and then estimates only the difference: a light
// sample that is not occluded and a BRDF-sampled ray that escapes to the sky contribute nothing
// (they would add exactly the environment the closed form already counted); an occluded light
// sample subtracts its light, and a BRDF-sampled ray that hits the sample subtracts the
// environment behind it (with its MIS weight) and carries on with the sample's radiance. Same
// expectation, and zero variance wherever the mount sees the open sky (most of the preview's
// background, where the grain was).
Rgb TracePath(const Scene& scene, const Brdf& brdf, const LambertBrdf& mount,
              const EnvironmentMap& env, Vec3 origin, Vec3 dir, ZSobolSampler& sampler,
              FirstHit* first) {
  Rgb L = Rgb::Zero(), beta = Rgb::Ones();
  double prev_brdf_pdf = 0;  // 0: the previous direction was not BRDF-sampled (camera ray)
  bool prev_cv = false;      // the previous vertex was a mount vertex with the control variate
  const bool env_sampled = !env.is_constant();
  for (int depth = 0;; ++depth) {
    const auto hit = scene.embree.Intersect(origin, dir, 1e-9, 1e30,
                                            depth == 0 ? scene.camera_mask : EmbreeScene::kMaskAll);
    if (depth == 0)
      first->sample = hit && hit->geometry == scene.hf_id && scene.OnSample(hit->point);
    if (!hit) {
      if (!prev_cv) {
        double env_pdf = 0;
        const Rgb Le = env.LeAndPdf(dir, &env_pdf);
        const double w =
            (prev_brdf_pdf > 0 && env_sampled) ? PowerHeuristic(prev_brdf_pdf, env_pdf) : 1.0;
        L += beta * Le * w;
      }
      break;
    }
    if (prev_cv) {
      // The BRDF-sampled ray from the mount is blocked: take back the environment it would
      // have seen (the closed form counted it).
      double env_pdf = 0;
      const Rgb Le = env.LeAndPdf(dir, &env_pdf);
      const double w = env_sampled ? PowerHeuristic(prev_brdf_pdf, env_pdf) : 1.0;
      L -= beta * Le * w;
    }
    if (depth >= scene.max_depth) break;
    Vec3 n = hit->normal;
    if (n.dot(dir) > 0) n = -n;  // the underside of the height field, reached through a hole
    const Frame frame(n);
    const Vec3 wo = frame.ToLocal(-dir);
    const bool on_plane = hit->geometry == scene.plane_id;
    // The mount: the plane under the holes, or the height field where it is the bare mount
    // around the sample (RenderOptions::sample_material); both Lambert with the mount's albedo.
    const bool on_mount = on_plane || !scene.OnSample(hit->point);
    // The control variate needs the plane seen from above (the closed form is the upper
    // hemisphere's irradiance on a surface facing +z).
    const bool cv = on_plane && n.z() > 0;
    if (cv) L += beta * mount.albedo() * (kInvPi)*scene.mount_irradiance;
    const Rgb tint = on_mount ? Rgb::Ones() : scene.Tint(hit->point);
    if (depth == 0) {
      first->normal = n;
      first->depth = hit->t;
      first->albedo = on_mount ? mount.albedo() : tint;
    }
    auto f = [&](const Vec3& wi) -> Rgb {
      return on_mount ? mount.f(wo, wi) : Rgb(brdf.f(wo, wi) * tint);
    };
    // Continuation density: BRDF sampling, mixed with the mirrored-environment sampler with
    // probability cg at surface vertices whose tangent plane lets it aim somewhere (one-sample
    // mixture: the same mixture density in both MIS weights against the light sample).
    // The guide's density is re-weighted by this vertex's BRDF per block of directions
    // (MirrorGuide::Prepare), so it aims where the field's reflection and this lobe overlap.
    double cg = (scene.guide && !on_mount) ? scene.guide->SelectProbability(n) : 0.0;
    MirrorGuide::Local gl;
    if (cg < kMinGuideSelect || !scene.guide->Prepare(brdf, frame.s, frame.t, frame.n, wo, &gl))
      cg = 0;
    auto mix = [&](double pb, const Vec3& wi) {
      double p = pb;
      if (cg > 0) p = (1 - cg) * p + cg * scene.guide->Pdf(gl, frame.FromLocal(wi));
      return p;
    };
    auto pdf = [&](const Vec3& wi) {
      if (on_mount) return mount.Pdf(wo, wi);
      return mix(brdf.Pdf(wo, wi), wi);
    };
    // Continue (and test shadows) from the side the ray arrived on.
    const Vec3 next_origin = EmbreeScene::ShadowRayOrigin(*hit, dir);
    // Next-event estimation towards the environment (a constant one is not importance-sampled:
    // BRDF sampling alone is then exact for a Lambert surface and needs no shadow ray).
    if (env_sampled) {
      Vec2 ul;
      sampler.Get2D(&ul.x(), &ul.y());
      if (auto ls = env.Sample(ul)) {
        const Vec3 wi = frame.ToLocal(ls->wi);
        if (wi.z() > 0) {
          const Rgb fv = f(wi);
          if ((fv > 0).any()) {
            const bool occluded = scene.embree.Occluded(next_origin, ls->wi, 0.0, 1e30);
            // With the control variate only occluded light counts (negatively).
            if (occluded == cv) {
              const double w = PowerHeuristic(ls->pdf, pdf(wi));
              const Rgb c = beta * fv * ls->Le * (wi.z() * w / ls->pdf);
              L += cv ? Rgb(-c) : c;
            }
          }
        }
      }
    }
    // Continue by BRDF sampling.
    Vec2 u;
    sampler.Get2D(&u.x(), &u.y());
    const double u_rr = sampler.Get1D();
    std::optional<BrdfSample> bs;
    // A directed candidate from the mixture by u (rescaled, so each strategy keeps a
    // stratified uniform): its local direction, f and the mixture's density, or nullopt.
    auto candidate = [&](const Vec2& uc) -> std::optional<BrdfSample> {
      if (uc.x() >= cg) {
        auto b = brdf.Sample(wo, Vec2((uc.x() - cg) / (1 - cg), uc.y()));
        if (b) b->pdf = mix(b->pdf, b->wi);
        return b;
      }
      double pg = 0;
      const Vec3 d = scene.guide->Sample(gl, Vec2(uc.x() / cg, uc.y()), &pg);
      const Vec3 wi = frame.ToLocal(d);
      if (wi.z() <= 0) return std::nullopt;  // below the tangent plane: f = 0
      return BrdfSample{wi, brdf.f(wo, wi), mix(brdf.Pdf(wo, wi), wi)};
    };
    double ris_weight = 0;  // > 0: bs was resampled; its unbiased contribution weight
    if (cg > 0 && scene.resample > 1 && depth == 0) {
      // At the camera ray's vertex only (on the demo, resampling at every vertex lowered the
      // error no further: 12.3% either way at 16 spp, for more CPU).
      // Resampled importance sampling (Talbot et al. 2005) towards the product of this vertex's
      // BRDF x cosine and the field's reflected luminance from the guide's table (the sky's
      // mean above the horizon): M candidates from the mixture at rotated points of u (each
      // distributed like the mixture: the estimator's expectation needs only the marginals),
      // one kept with probability proportional to target / mixture density, weighted by
      // W = mean(target / density) / target(kept). Unbiased for any target that is positive
      // wherever the integrand is; the MIS weights against the light sample keep the mixture's
      // density (they only need to sum to one).
      const int M = scene.resample;
      std::optional<BrdfSample> cand[16];
      double w[16], target[16], wsum = 0;
      for (int j = 0; j < M; ++j) {
        double cx = u.x() + j * 0.7548776662466927, cy = u.y() + j * 0.5698402909980532;
        cx -= std::floor(cx);
        cy -= std::floor(cy);
        cand[j] = candidate(Vec2(cx, cy));
        w[j] = target[j] = 0;
        if (cand[j] && cand[j]->pdf > 0 && cand[j]->wi.z() > 0) {
          const Vec3 d = frame.FromLocal(cand[j]->wi);
          target[j] = Luminance(cand[j]->f) * cand[j]->wi.z() * scene.guide->Radiance(d);
          if (target[j] > 0 && std::isfinite(target[j]))
            w[j] = target[j] / cand[j]->pdf;
          else
            target[j] = 0;
        }
        wsum += w[j];
      }
      if (!(wsum > 0)) break;
      const double pick = sampler.Get1D() * wsum;
      int k = 0;
      double acc = w[0];
      while (k < M - 1 && (acc <= pick || !(w[k] > 0))) acc += w[++k];
      while (!(w[k] > 0)) --k;
      bs = cand[k];
      ris_weight = wsum / M / target[k];
    } else if (cg > 0) {
      bs = candidate(u);
    } else {
      bs = on_mount ? mount.Sample(wo, u) : brdf.Sample(wo, u);
    }
    if (!bs || !(bs->pdf > 0) || bs->wi.z() <= 0) break;
    const double weight = ris_weight > 0 ? ris_weight : 1.0 / bs->pdf;
    beta *= bs->f * (on_mount ? Rgb::Ones() : tint) * (bs->wi.z() * weight);
    if (!beta.allFinite() || !(beta > 0).any()) break;
    // Russian roulette only on long paths (max_depth > 4): within the first four vertices it
    // added variance for no saving (Cycles' default starts later too).
    if (depth >= 3) {
      const double q = std::max(0.05, 1.0 - beta.maxCoeff());
      if (u_rr < q) break;
      beta /= 1.0 - q;
    }
    prev_brdf_pdf = bs->pdf;
    prev_cv = cv;
    origin = next_origin;
    dir = frame.FromLocal(bs->wi).normalized();
  }
  return L.allFinite() ? L : Rgb::Zero();
}

struct PinholeCamera {
  Vec3 eye, fwd, right, up;
  double tan_half = 0, aspect = 1;
  Vec3 Direction(double px, double py) const {  // px, py in [-1, 1], py up
    return (fwd + right * (px * tan_half * aspect) + up * (py * tan_half)).normalized();
  }
};

PinholeCamera MakeCamera(const HeightField& hf, double zmin, double zmax, const RenderOptions& o) {
  PinholeCamera cam;
  const double fov = (o.fov_deg > 0 ? o.fov_deg : 30.0) * kPi / 180;
  cam.aspect = static_cast<double>(o.width) / o.height;
  cam.tan_half = std::tan(0.5 * fov);
  Vec3 target;
  if (o.camera) {
    cam.eye = o.camera->eye;
    target = o.camera->target;
  } else {
    // Frame the height field: the larger extent fills ~90% of the view.
    const double ex = hf.width() * hf.pixel_size, ey = hf.height() * hf.pixel_size;
    target = Vec3(hf.X(0.5 * (hf.width() - 1)), hf.Y(0.5 * (hf.height() - 1)), 0.5 * (zmin + zmax));
    const double el = o.elevation_deg * kPi / 180, az = o.azimuth_deg * kPi / 180;
    const double half = 0.5 * std::max(ey, ex / cam.aspect) / 0.9;
    const double dist = half / cam.tan_half + 0.5 * (zmax - zmin);
    cam.eye = target +
              dist * Vec3(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  }
  cam.fwd = (target - cam.eye).normalized();
  cam.right = cam.fwd.cross(Vec3(0, 0, 1));
  if (cam.right.norm() < 1e-9) cam.right = Vec3(1, 0, 0);
  cam.right.normalize();
  cam.up = cam.right.cross(cam.fwd);
  return cam;
}

// True if no camera ray can reach the mount plane at z = plane_z: the height field has no hole,
// the eye is above its highest point, every corner ray descends, and the frustum between
// z = zmax and z = plane_z lies inside the field's rectangle. (The frustum cut between two
// horizontal planes is convex with the eight corner points as vertices, so checking them
// suffices; a ray inside the rectangle's column is above the surface at zmax and below it at the
// plane, so it crosses the surface first.) Camera rays then skip the plane; secondary rays
// still see it (it shades the sample's lower hemisphere).
bool CameraCannotSeeMount(const HeightField& hf, double zmax, double plane_z,
                          const PinholeCamera& cam) {
  for (const float z : hf.z.data())
    if (!std::isfinite(z)) return false;
  if (!(cam.eye.z() > zmax)) return false;
  const double x_lo = hf.X(0), x_hi = hf.X(hf.width() - 1);
  const double y_lo = std::min(hf.Y(0), hf.Y(hf.height() - 1)),
               y_hi = std::max(hf.Y(0), hf.Y(hf.height() - 1));
  for (const double px : {-1.0, 1.0})
    for (const double py : {-1.0, 1.0}) {
      const Vec3 d = cam.Direction(px, py);
      if (!(d.z() < 0)) return false;
      for (const double z : {zmax, plane_z}) {
        const Vec3 p = cam.eye + (z - cam.eye.z()) / d.z() * d;
        if (!(p.x() >= x_lo && p.x() <= x_hi && p.y() >= y_lo && p.y() <= y_hi)) return false;
      }
    }
  return true;
}

// Per-pixel accumulators: two interleaved half-buffers (even / odd sample numbers).
struct PixelState {
  double a[3] = {0, 0, 0}, b[3] = {0, 0, 0};
  int n = 0;     // samples taken
  int hits = 0;  // camera rays that hit the height field
  double normal[3] = {0, 0, 0}, depth = 0, albedo[3] = {0, 0, 0};  // sums over the samples
  double cost = 0;  // seconds spent on its samples (for the error-driven allocation)
  bool done = false;
};

// Per-pixel sample goals for the next round of a time- or sample-budgeted render (RenderOptions::
// allocate_*): the optimal allocation for the sum of the pixels' squared errors gives each pixel
// samples in proportion to its per-sample standard deviation sigma. sigma^2 is estimated per
// pixel from the two half-buffers (n (mean_a - mean_b)^2 / 4, luminance) and averaged over the
// pixel's neighbourhood without the pixel itself: the noise that matters (a glossy reflection of
// a sunlit edge) is spatially coherent, a pixel's own few samples are a poor estimate of a
// heavy-tailed variance, and leaving the pixel out keeps its sample count independent of its
// samples (so its mean stays unbiased; they enter only through the image-wide sums below, as
// one of W x H terms). Each pixel's final share is total_final * w / sum(w)
// (w = max(sigma, floor x mean sigma)); this round's `budget` is spread over the deficits.
// Rounding is stochastic from a hash of (pixel, round, seed), not from the pixel's values.
void AllocateSamples(const std::vector<PixelState>& px, int W, int H, const RenderOptions& o,
                     double budget, double total_final, int round, std::vector<int>* goal) {
  const size_t n = px.size();
  std::vector<double> v(n), c(n), cost(n), count(n);
  // The first-hit features for the denoiser-aware share (allocate_for_denoiser): the mean
  // normal (3), its squared length, the hit fraction and its square.
  const bool features = o.allocate_for_denoiser;
  std::vector<std::vector<double>> f(features ? 6 : 0, std::vector<double>(n, 0.0));
  ParallelForRows(H, [&](int ya, int yb) {
    for (size_t i = static_cast<size_t>(ya) * W; i < static_cast<size_t>(yb) * W; ++i) {
      const PixelState& p = px[i];
      cost[i] = p.cost;
      count[i] = p.n;
      const int na = (p.n + 1) / 2, nb = p.n / 2;
      if (na == 0 || nb == 0) continue;
      const double d = Luminance(Rgb(p.a[0] / na, p.a[1] / na, p.a[2] / na)) -
                       Luminance(Rgb(p.b[0] / nb, p.b[1] / nb, p.b[2] / nb));
      v[i] = 0.25 * d * d * p.n;
      c[i] = 1;
      if (features) {  // the same pixels as c counts
        double nn = 0;
        for (int k = 0; k < 3; ++k) {
          f[k][i] = p.normal[k] / p.n;
          nn += f[k][i] * f[k][i];
        }
        f[3][i] = nn;
        f[4][i] = static_cast<double>(p.hits) / p.n;
        f[5][i] = f[4][i] * f[4][i];
      }
    }
  });
  // Box sums through summed-area tables (all of them at once on the pool).
  auto integral = [&](const std::vector<double>& a) {
    std::vector<double> s(static_cast<size_t>(W + 1) * (H + 1), 0.0);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        s[static_cast<size_t>(y + 1) * (W + 1) + x + 1] =
            a[static_cast<size_t>(y) * W + x] + s[static_cast<size_t>(y) * (W + 1) + x + 1] +
            s[static_cast<size_t>(y + 1) * (W + 1) + x] - s[static_cast<size_t>(y) * (W + 1) + x];
    return s;
  };
  std::vector<double> sv, sc, scost, scount;
  std::vector<std::vector<double>> sf(f.size());
  {
    std::vector<const std::vector<double>*> from = {&v, &c, &cost, &count};
    std::vector<std::vector<double>*> to = {&sv, &sc, &scost, &scount};
    for (size_t k = 0; k < f.size(); ++k) from.push_back(&f[k]), to.push_back(&sf[k]);
    ParallelFor(static_cast<int64_t>(from.size()), [&](int64_t k) { *to[k] = integral(*from[k]); });
  }
  const double tau2 = o.allocate_denoise_tau * o.allocate_denoise_tau;
  const int r = o.allocate_radius;
  std::vector<double> w(n, 0.0), cps(n, 0.0);  // deviation; cost per sample (seconds)
  ParallelForRows(H, [&](int ya, int yb) {
    for (int y = ya; y < yb; ++y)
      for (int x = 0; x < W; ++x) {
        const size_t i = static_cast<size_t>(y) * W + x;
        const int x0 = std::max(0, x - r), x1 = std::min(W, x + r + 1);
        const int y0 = std::max(0, y - r), y1 = std::min(H, y + r + 1);
        auto box = [&](const std::vector<double>& s) {
          return s[static_cast<size_t>(y1) * (W + 1) + x1] -
                 s[static_cast<size_t>(y0) * (W + 1) + x1] -
                 s[static_cast<size_t>(y1) * (W + 1) + x0] +
                 s[static_cast<size_t>(y0) * (W + 1) + x0];
        };
        const double cnt = box(sc) - c[i];
        w[i] = cnt > 0 ? std::sqrt(std::max(0.0, box(sv) - v[i]) / cnt) : 0.0;
        if (features && cnt > 0) {
          // The neighbours' feature variance: normal (trace of its covariance) and hit fraction.
          double mean2 = 0;
          for (int k = 0; k < 3; ++k) {
            const double m = (box(sf[k]) - f[k][i]) / cnt;
            mean2 += m * m;
          }
          const double hm = (box(sf[4]) - f[4][i]) / cnt;
          const double var = std::max(0.0, (box(sf[3]) - f[3][i]) / cnt - mean2) +
                             std::max(0.0, (box(sf[5]) - f[5][i]) / cnt - hm * hm);
          w[i] *= std::sqrt(std::min(1.0 + var / tau2, o.allocate_denoise_max));
        }
        const double samples = box(scount) - count[i];
        cps[i] = samples > 0 ? (box(scost) - cost[i]) / samples : 0.0;
      }
  });
  double wsum = 0;  // in pixel order, as before
  int64_t active = 0;
  for (size_t i = 0; i < n; ++i)
    if (!px[i].done) {
      wsum += w[i];
      ++active;
    }
  const double floor = o.allocate_floor * (active ? wsum / active : 0.0);
  // At a fixed cost the optimum is sigma / sqrt(cost per sample) (the sunlit rim's paths cost
  // several times the mount's).
  double mean_cps = 0;
  for (size_t i = 0; i < n; ++i) mean_cps += cps[i] / n;
  wsum = 0;
  for (size_t i = 0; i < n; ++i) {
    w[i] = std::max(w[i], floor);
    if (o.allocate_by_cost && mean_cps > 0)
      w[i] /= std::sqrt(std::max(cps[i], 0.05 * mean_cps) / mean_cps);
    if (!px[i].done) wsum += w[i];
  }
  if (!(wsum > 0)) wsum = 1, std::fill(w.begin(), w.end(), 1.0 / std::max<int64_t>(active, 1));
  std::vector<double> deficit(n, 0.0);
  double dsum = 0;
  for (size_t i = 0; i < n; ++i) {
    if (px[i].done) continue;
    deficit[i] = std::max(0.0, total_final * w[i] / wsum - px[i].n);
    dsum += deficit[i];
  }
  // Everyone at or above its share (the estimates moved): spread the round in proportion to w.
  const bool by_weight = !(dsum > 0.5);
  const double scale = by_weight ? budget / wsum : std::min(1.0, budget / dsum);
  goal->assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    const PixelState& p = px[i];
    if (p.done) continue;
    const double give = (by_weight ? w[i] : deficit[i]) * scale;
    uint64_t h = (static_cast<uint64_t>(i) << 20) ^ (static_cast<uint64_t>(round) << 8) ^
                 (o.seed * 0x9E3779B97F4A7C15ull);
    h ^= h >> 33, h *= 0xff51afd7ed558ccdull, h ^= h >> 33, h *= 0xc4ceb9fe1a85ec53ull,
        h ^= h >> 33;
    const double u = (h >> 11) * 0x1.0p-53;
    const double g = std::min<double>(o.max_spp, p.n + std::floor(give + u));
    (*goal)[i] = static_cast<int>(g);
  }
}

double ToneCurveSlope(double v, double white) {
  // d/dv of v (1 + v / w^2) / (1 + v).
  const double w2 = white * white;
  return (1 + 2 * v / w2 + v * v / w2) / ((1 + v) * (1 + v));
}

// ---- the steps of Render ---------------------------------------------------------------------

// Seconds since construction (the time budget's clock).
class Clock {
 public:
  double Seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

// The height field with its heights exaggerated around the mount plane (previews of low
// relief), and their range.
HeightField ScaleRelief(const HeightField& hf_in, const RenderOptions& options, double* zmin,
                        double* zmax) {
  HeightField hf = hf_in;
  *zmin = 1e30, *zmax = -1e30;
  for (float& z : hf.z.data()) {
    if (!std::isfinite(z)) continue;
    z = static_cast<float>(z * options.relief_scale);
    *zmin = std::min(*zmin, static_cast<double>(z));
    *zmax = std::max(*zmax, static_cast<double>(z));
  }
  if (*zmin > *zmax) MESOSCAN_BAD_INPUT("render: the height field has no valid sample");
  if (options.albedo &&
      (options.albedo->width() != hf.width() || options.albedo->height() != hf.height()))
    MESOSCAN_BAD_INPUT("render: the albedo map ("
                       << options.albedo->width() << "x" << options.albedo->height()
                       << ") does not match the height field (" << hf.width() << "x" << hf.height()
                       << ")");
  return hf;
}

// The Embree scene (the height field and the mount plane under it), what camera rays may skip,
// the mount's irradiance and the mirrored-environment sampler where it helps. Returns whether the
// camera can see the mount.
bool BuildScene(const HeightField& hf, double zmin, double zmax, const PinholeCamera& cam,
                const Brdf& brdf, const EnvironmentMap& env, const RenderOptions& options,
                Scene* scene, std::optional<MirrorGuide>* guide) {
  scene->hf = &hf;
  scene->albedo = options.albedo;
  if (options.sample_material) {
    MESOSCAN_CHECK(options.sample_material->width() == hf.width() &&
                   options.sample_material->height() == hf.height());
    scene->sample_material = options.sample_material;
  }
  scene->max_depth = options.max_depth;
  scene->hf_id = scene->embree.AddHeightField(hf);
  const double extent = std::max(hf.width(), hf.height()) * hf.pixel_size;
  scene->plane_id = scene->embree.AddPlane(std::min(0.0, zmin) - 1e-6, 10 * extent + 1.0);
  scene->embree.Commit();
  const bool mount_visible = !(options.skip_invisible_mount &&
                               CameraCannotSeeMount(hf, zmax, std::min(0.0, zmin) - 1e-6, cam));
  if (!mount_visible) scene->camera_mask = EmbreeScene::kMaskHeightFields;
  scene->mount_irradiance = env.UpperHemisphereIrradiance();
  if (options.mirror_guide && MirrorGuide::Useful(env, brdf)) {
    guide->emplace(env, brdf);
    scene->guide = &**guide;
  }
  // Not under error-driven allocation (RenderOptions::allocate_*): it already spends the samples
  // on the rim, and there the candidates cost more than they saved (demo, 8 spp allocated: MSE
  // -5% raw / -16% denoised for +27% CPU; uniform 16 spp: -33% for +17%).
  const bool allocates =
      (options.time_limit_s > 0 || options.allocate_spp > 0) && options.allocate_pilot_spp > 0;
  if (scene->guide && !allocates) scene->resample = std::min(options.resample_candidates, 16);
  return mount_visible;
}

// The result's images, zero, and what the summary knows before the first sample.
RenderResult NewRenderResult(int W, int H, bool mount_visible, bool mirror_guide) {
  RenderResult result;
  result.summary.mount_visible = mount_visible;
  result.summary.mirror_guide = mirror_guide;
  result.radiance = ImageF(W, H, 3, 0.0f);
  result.sample_mask = ImageF(W, H, 1, 0.0f);
  result.normal = ImageF(W, H, 3, 0.0f);
  result.depth = ImageF(W, H, 1, 0.0f);
  result.albedo = ImageF(W, H, 3, 0.0f);
  result.half[0] = ImageF(W, H, 3, 0.0f);
  result.half[1] = ImageF(W, H, 3, 0.0f);
  result.spp = ImageF(W, H, 1, 0.0f);
  return result;
}

// The images from the pixels' sums, on the pool (between rounds the other core would idle), and
// the exposure metered on them.
void UpdateImages(const std::vector<PixelState>& px, int W, int H, const Rgb& balance,
                  RenderResult* r) {
  RenderResult& result = *r;
  ParallelForRows(H, [&](int y0, int y1) {
    for (size_t i = static_cast<size_t>(y0) * W; i < static_cast<size_t>(y1) * W; ++i) {
      const PixelState& p = px[i];
      const int x = static_cast<int>(i % W), y = static_cast<int>(i / W);
      for (int c = 0; c < 3; ++c)
        result.radiance(x, y, c) = p.n ? static_cast<float>((p.a[c] + p.b[c]) / p.n) : 0.0f;
      result.sample_mask(x, y, 0) = p.n ? static_cast<float>(p.hits) / p.n : 0.0f;
      result.spp(x, y, 0) = static_cast<float>(p.n);
      const double inv = p.n ? 1.0 / p.n : 0.0;
      for (int c = 0; c < 3; ++c) {
        result.normal(x, y, c) = static_cast<float>(p.normal[c] * inv);
        result.albedo(x, y, c) = static_cast<float>(p.albedo[c] * inv);
      }
      result.depth(x, y, 0) = static_cast<float>(p.depth * inv);
      const int na = (p.n + 1) / 2, nb = p.n / 2;
      for (int c = 0; c < 3; ++c) {
        result.half[0](x, y, c) = na ? static_cast<float>(p.a[c] / na) : 0.0f;
        result.half[1](x, y, c) = nb ? static_cast<float>(p.b[c] / nb) : result.half[0](x, y, c);
      }
    }
  });
  result.tone = MeterExposure(result.radiance, &result.sample_mask, balance);
}

// How many samples each pixel takes in the next round: a uniform target doubling every round
// (shortened to fit a time budget), or per-pixel goals under error-driven allocation.
struct SampleSchedule {
  double sample_budget = 0;  // RenderOptions::allocate_spp * pixels (0: none)
  bool allocate = false;     // error-driven allocation under a time or sample budget
  bool allocating = false;   // the pilot is done: the goals decide
  int target = 0;            // the uniform target (samples per pixel)
  std::vector<int> goal;     // per-pixel goals while allocating
  // The last round's start: wall seconds, samples and the pixels' summed cost.
  double round_start_s = 0, round_start_samples = 0, round_start_cost = 0;
};

SampleSchedule StartSchedule(const RenderOptions& options, int W, int H) {
  SampleSchedule s;
  // Under a time budget the rounds start at 1 spp (so even the first round respects the
  // budget on a slow or loaded machine); adaptivity still waits for min_spp.
  // A sample budget (allocate_spp) is spent like a time budget, in rounds from 1 spp.
  s.sample_budget = options.allocate_spp * static_cast<double>(W) * H;
  s.target = options.time_limit_s > 0 || s.sample_budget > 0
                 ? 1
                 : std::min(options.min_spp, options.max_spp);
  // Error-driven allocation under a time or sample budget (RenderOptions::allocate_*): per-pixel
  // goals instead of one uniform target, once every pixel has the pilot's samples.
  s.allocate = (options.time_limit_s > 0 || s.sample_budget > 0) && options.allocate_pilot_spp > 0;
  return s;
}

// The largest sample count of the pixels still sampled.
int MaxActiveSamples(const std::vector<PixelState>& px) {
  int prev = 0;
  for (const auto& p : px) prev = std::max(prev, p.done ? 0 : p.n);
  return prev;
}

// Plans round `round` (> 0) from what the last rounds cost; false: the budget is spent.
bool PlanRound(const std::vector<PixelState>& px, int W, int H, const RenderOptions& options,
               int round, int active, int64_t samples, const Clock& clock, SampleSchedule* s) {
  // Shorten the round if it would overrun the time budget (paths/s measured so far).
  if (options.time_limit_s > 0) {
    const double rate = samples / std::max(clock.Seconds(), 1e-3);
    const double left = options.time_limit_s - clock.Seconds();
    if (left <= 0) return false;
    const int prev = MaxActiveSamples(px);
    const double affordable = left * rate / std::max(active, 1);
    s->target = std::min(s->target, prev + std::max(1, static_cast<int>(affordable)));
  }
  if (s->allocate) {
    const int prev = MaxActiveSamples(px);
    const int pilot = options.allocate_for_denoiser ? options.allocate_denoise_pilot_spp
                                                    : options.allocate_pilot_spp;
    if (prev >= pilot) s->allocating = true;
  }
  if (!s->allocating) return true;
  // What is left to spend, in samples (by the time left and the paths/s so far, or by the
  // sample budget), and this round's share: as many samples as so far (rounds double).
  // Paths per second of the last round (the allocated rounds' mix of cheap and costly
  // pixels differs from the uniform pilot's).
  const double done = static_cast<double>(samples);
  const double rate =
      (done - s->round_start_samples) / std::max(clock.Seconds() - s->round_start_s, 1e-3);
  const double left = s->sample_budget > 0 ? s->sample_budget - done
                                           : (options.time_limit_s - clock.Seconds()) * rate;
  const double budget = std::min(left, done);
  if (budget < 1) return false;
  AllocateSamples(px, W, H, options, budget, done + left, round, &s->goal);
  if (options.time_limit_s > 0) {
    // The goals' predicted wall time: each pixel's new samples at its measured seconds per
    // sample, times the last round's wall seconds per thread-second of pixel work. If the
    // round would overrun the budget (the goals favour costly pixels, so the paths/s above
    // are optimistic), shrink it once in proportion.
    double work = 0, cost_now = 0;
    for (size_t i = 0; i < px.size(); ++i) {
      const PixelState& p = px[i];
      cost_now += p.cost;
      if (!p.done && s->goal[i] > p.n && p.n > 0) work += (s->goal[i] - p.n) * p.cost / p.n;
    }
    const double wall_per_work =
        (clock.Seconds() - s->round_start_s) / std::max(cost_now - s->round_start_cost, 1e-9);
    const double predicted = work * wall_per_work,
                 time_left = options.time_limit_s - clock.Seconds();
    if (predicted > time_left && predicted > 0) {
      if (budget * time_left / predicted < 1) return false;
      AllocateSamples(px, W, H, options, budget * time_left / predicted,
                      done + left * time_left / predicted, round, &s->goal);
    }
  }
  return true;
}

// What one round traces: the scene and its camera, the sampler's dimension.
struct RoundTracer {
  const Scene& scene;
  const Brdf& brdf;
  const LambertBrdf& mount;
  const EnvironmentMap& env;
  const PinholeCamera& cam;
  int log2_spp = 0;
};

// Traces every active pixel up to its goal (or the target), on the pool; returns the samples
// taken. Each pixel's samples go to its two half-buffers, its features and its cost.
int64_t TraceRound(const RoundTracer& t, const RenderOptions& options, int round,
                   const SampleSchedule& s, const Clock& clock, std::vector<PixelState>* pixels) {
  std::vector<PixelState>& px = *pixels;
  const int W = options.width, H = options.height;
  std::atomic<int64_t> samples{0};
  ParallelForRows(H, [&](int y0, int y1) {
    int64_t local = 0;
    ZSobolSampler sampler(t.log2_spp, W, H, options.seed);
    for (int y = y0; y < y1; ++y) {
      if (options.time_limit_s > 0 && round > 0 &&
          clock.Seconds() > 1.05 * options.time_limit_s + 0.05)
        break;  // safety: the prediction was wrong (the load changed)
      for (int x = 0; x < W; ++x) {
        PixelState& p = px[static_cast<size_t>(y) * W + x];
        if (p.done) continue;
        const int goal_n = s.allocating ? s.goal[static_cast<size_t>(y) * W + x] : s.target;
        if (p.n >= goal_n) continue;
        const auto t_pixel = std::chrono::steady_clock::now();
        for (; p.n < goal_n; ++p.n) {
          sampler.StartPixelSample(x, y, static_cast<uint32_t>(p.n));
          double jx, jy;
          sampler.Get2D(&jx, &jy);
          const double sx = (x + jx) / W * 2 - 1;
          const double sy = 1 - (y + jy) / H * 2;
          FirstHit first;
          const Rgb L = TracePath(t.scene, t.brdf, t.mount, t.env, t.cam.eye,
                                  t.cam.Direction(sx, sy), sampler, &first);
          double* acc = (p.n & 1) ? p.b : p.a;
          for (int c = 0; c < 3; ++c) {
            acc[c] += L[c];
            p.normal[c] += first.normal[c];
            p.albedo[c] += first.albedo[c];
          }
          p.depth += first.depth;
          p.hits += first.sample;
          ++local;
        }
        p.cost += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_pixel).count();
      }
    }
    samples.fetch_add(local, std::memory_order_relaxed);
  });
  return samples.load();
}

// The variance of each pixel's mean, (mean_a - mean_b)^2 / 4 in luminance, then its 3x3 mean
// (the single-pixel estimate has one degree of freedom).
void EstimatePixelVariance(const std::vector<PixelState>& px, int W, int H,
                           std::vector<float>* var_out, std::vector<float>* smoothed) {
  std::vector<float>& var = *var_out;
  ParallelForRows(H, [&](int y0, int y1) {
    for (size_t i = static_cast<size_t>(y0) * W; i < static_cast<size_t>(y1) * W; ++i) {
      const PixelState& p = px[i];
      const int na = (p.n + 1) / 2, nb = p.n / 2;
      if (na == 0 || nb == 0) {
        var[i] = 0;
        continue;
      }
      const Rgb ma(p.a[0] / na, p.a[1] / na, p.a[2] / na),
          mb(p.b[0] / nb, p.b[1] / nb, p.b[2] / nb);
      const double d = Luminance(ma) - Luminance(mb);
      var[i] = static_cast<float>(0.25 * d * d);
    }
  });
  ParallelForRows(H, [&](int ya, int yb) {
    for (int y = ya; y < yb; ++y)
      for (int x = 0; x < W; ++x) {
        double s = 0;
        int k = 0;
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = x + dx, yy = y + dy;
            if (xx < 0 || yy < 0 || xx >= W || yy >= H) continue;
            s += var[static_cast<size_t>(yy) * W + xx];
            ++k;
          }
        (*smoothed)[static_cast<size_t>(y) * W + x] = static_cast<float>(s / k);
      }
  });
}

// Marks the pixels that are done (at max_spp, or their displayed error below options.noise)
// and returns how many are still sampled.
int RetireConvergedPixels(const std::vector<float>& var_s, const RenderOptions& options,
                          bool allocate, std::vector<PixelState>* pixels, RenderResult* result) {
  const int W = options.width;
  int active = 0;
  for (size_t i = 0; i < pixels->size(); ++i) {
    PixelState& p = (*pixels)[i];
    if (p.done) continue;
    const int x = static_cast<int>(i % W), y = static_cast<int>(i / W);
    if (p.n >= options.max_spp) {
      p.done = true;
      continue;
    }
    // With error-driven allocation the allocation decides (a pixel's own noise test would make
    // its sample count depend on its samples, and the display-space test stops the bright rim
    // that dominates the linear error first).
    if (options.noise > 0 && !allocate && p.n >= options.min_spp && p.n >= 4) {
      const ImageF& radiance = result->radiance;
      const double v = result->tone.exposure *
                       Luminance(Rgb(radiance(x, y, 0), radiance(x, y, 1), radiance(x, y, 2)));
      const double err = std::sqrt(var_s[i]) * result->tone.exposure *
                         ToneCurveSlope(std::max(0.0, v), result->tone.white);
      if (err < options.noise) {
        p.done = true;
        ++result->summary.pixels_converged;
        continue;
      }
    }
    ++active;
  }
  return active;
}

}  // namespace

RenderResult Render(const HeightField& hf_in, const Brdf& brdf, const EnvironmentMap& env,
                    const RenderOptions& options, const RenderProgressFn& on_round) {
  options.Check();
  const Clock clock;
  // 1. The scene: the height field (relief scaled), the mount, the camera.
  double zmin, zmax;
  const HeightField hf = ScaleRelief(hf_in, options, &zmin, &zmax);
  const PinholeCamera cam = MakeCamera(hf, zmin, zmax, options);
  Scene scene;
  std::optional<MirrorGuide> guide;
  const bool mount_visible = BuildScene(hf, zmin, zmax, cam, brdf, env, options, &scene, &guide);
  const LambertBrdf mount(options.mount_albedo);
  // 2. The pixels and the images; the sampler's dimension.
  const int W = options.width, H = options.height;
  int log2_spp = 0;
  while ((1 << log2_spp) < options.max_spp) ++log2_spp;
  log2_spp += log2_spp & 1;  // even: every prefix of 4^k samples of a pixel is a (0,2k,2)-net
  const RoundTracer tracer{scene, brdf, mount, env, cam, log2_spp};
  std::vector<PixelState> px(static_cast<size_t>(W) * H);
  RenderResult result = NewRenderResult(W, H, mount_visible, scene.guide != nullptr);
  const Rgb balance = WhiteBalanceFor(env);
  int64_t samples = 0;
  std::vector<float> var(px.size()), var_s(px.size());
  Progress progress("render (pixels done)", static_cast<int64_t>(W) * H);
  // 3. Rounds until every pixel is done or the budget is spent.
  SampleSchedule schedule = StartSchedule(options, W, H);
  int active = W * H;
  for (int round = 0; active > 0; ++round) {
    // Plan the round, trace it, then update the images and the pixels' error estimates.
    if (round > 0 && !PlanRound(px, W, H, options, round, active, samples, clock, &schedule)) break;
    schedule.round_start_s = clock.Seconds();
    schedule.round_start_samples = static_cast<double>(samples);
    schedule.round_start_cost = 0;
    for (const PixelState& p : px) schedule.round_start_cost += p.cost;
    samples += TraceRound(tracer, options, round, schedule, clock, &px);
    UpdateImages(px, W, H, balance, &result);
    EstimatePixelVariance(px, W, H, &var, &var_s);
    const int was_active = active;
    active = RetireConvergedPixels(var_s, options, schedule.allocate, &px, &result);
    // Report the round; stop at the budget; else double the target.
    result.summary.rounds = round + 1;
    result.summary.samples = samples;
    result.summary.mean_spp = static_cast<double>(result.summary.samples) / px.size();
    result.summary.seconds = clock.Seconds();
    progress.Advance(was_active - active);
    if (on_round) on_round(result);
    if (options.time_limit_s > 0 && clock.Seconds() >= options.time_limit_s) break;
    if (schedule.sample_budget > 0 && static_cast<double>(samples) >= schedule.sample_budget - 0.5)
      break;
    schedule.target = std::min(options.max_spp, 2 * schedule.target);
    // A sample budget without allocation: uniform rounds up to the budget's spp.
    if (schedule.sample_budget > 0 && !schedule.allocate)
      schedule.target =
          std::min(schedule.target, static_cast<int>(std::ceil(options.allocate_spp)));
  }
  progress.Finish();
  result.summary.seconds = clock.Seconds();
  return result;
}

CameraSpec FramingCamera(const HeightField& hf, const RenderOptions& options) {
  if (options.camera) return *options.camera;
  double zmin = 1e30, zmax = -1e30;
  for (const float z : hf.z.data()) {
    if (!std::isfinite(z)) continue;
    // As Render() scales them (in float).
    const double zs = static_cast<float>(z * options.relief_scale);
    zmin = std::min(zmin, zs);
    zmax = std::max(zmax, zs);
  }
  if (zmin > zmax) MESOSCAN_BAD_INPUT("render: the height field has no valid sample");
  const PinholeCamera cam = MakeCamera(hf, zmin, zmax, options);
  return CameraSpec{cam.eye, cam.eye + cam.fwd};
}

ImageF RenderHeightField(const HeightField& hf, const Brdf& brdf, const EnvironmentMap& env,
                         const RenderOptions& options, RenderSummary* summary) {
  RenderResult r = Render(hf, brdf, env, options);
  if (summary) *summary = r.summary;
  return std::move(r.radiance);
}

Rgb WhiteBalanceFor(const EnvironmentMap& env) {
  // The colour of the upper hemisphere's radiance, solid-angle weighted, without its brightest
  // 2% (a sun disk: its light falls on the mount, while a glossy sample mostly mirrors the sky).
  const ImageF& im = env.image();
  if (env.is_constant() || im.pixels() == 0) return Rgb::Ones();
  struct Texel {
    float lum;
    double weight;
    Rgb rgb;
  };
  std::vector<Texel> t;
  const int w = im.width(), h = im.height();
  double total = 0;
  for (int y = 0; y < (h + 1) / 2; ++y) {
    const double weight = std::sin(kPi * (y + 0.5) / h);
    for (int x = 0; x < w; ++x) {
      const Rgb c(std::max(0.0f, im(x, y, 0)), std::max(0.0f, im(x, y, 1)),
                  std::max(0.0f, im(x, y, 2)));
      t.push_back({static_cast<float>(Luminance(c)), weight, c});
      total += weight;
    }
  }
  std::sort(t.begin(), t.end(), [](const Texel& a, const Texel& b) { return a.lum < b.lum; });
  Rgb sum = Rgb::Zero();
  double acc = 0;
  for (const Texel& x : t) {
    if (acc > 0.98 * total) break;
    sum += x.rgb * x.weight;
    acc += x.weight;
  }
  if (!((sum > 0).all()) || !sum.allFinite()) return Rgb::Ones();
  const Rgb g = sum.inverse();
  return g / Luminance(g);
}

ToneMapping MeterExposure(const ImageF& radiance, const ImageF* mask, const Rgb& balance) {
  // Exposure from the log-average luminance (key 0.18, Reinhard et al. 2002) of the sample's
  // pixels, then the extended Reinhard curve with the white point at their 99.5th percentile, so
  // a sun glint neither blows out the image nor darkens everything else.
  const size_t n = radiance.pixels();
  std::vector<float> lum;
  lum.reserve(n);
  double log_sum = 0;
  for (int pass = 0; pass < 2 && lum.empty(); ++pass) {
    for (size_t i = 0; i < n; ++i) {
      if (pass == 0 && mask && mask->pixels() == n && !(mask->channel(0)[i] > 0.5f)) continue;
      if (pass == 0 && !(mask && mask->pixels() == n)) continue;
      const float l = static_cast<float>(Luminance(
          Rgb(radiance.channel(0)[i], radiance.channel(1)[i], radiance.channel(2)[i]) * balance));
      lum.push_back(l);
      log_sum += std::log(1e-6 + std::max(0.0f, l));
    }
  }
  ToneMapping t;
  t.balance = balance;
  if (lum.empty()) return t;
  // The key: the log-average, or the median where that is brighter (a sample that is mostly one
  // bright face with dark flanks: the log-average, pulled down by the flanks, overexposed the
  // face of a polished coin under a sunset).
  const double log_avg = std::exp(log_sum / lum.size());
  std::nth_element(lum.begin(), lum.begin() + lum.size() / 2, lum.end());
  const double key = std::max(log_avg, static_cast<double>(lum[lum.size() / 2]));
  t.exposure = key > 0 ? 0.18 / key : 1.0;
  const size_t k = static_cast<size_t>(0.995 * (lum.size() - 1));
  std::nth_element(lum.begin(), lum.begin() + k, lum.end());
  t.white = std::max(1.0, lum[k] * t.exposure);
  return t;
}

ImageU8 ToneMapForDisplay(const ImageF& radiance, const ToneMapping& tone) {
  const size_t n = radiance.pixels();
  ImageF mapped(radiance.width(), radiance.height(), 3);
  const double w2 = tone.white * tone.white;
  for (int c = 0; c < 3; ++c)
    for (size_t i = 0; i < n; ++i) {
      const double v = std::max(0.0, radiance.channel(c)[i] * tone.balance[c] * tone.exposure);
      mapped.channel(c)[i] = static_cast<float>(v * (1 + v / w2) / (1 + v));
    }
  return QuantizeU8(mapped, /*srgb_encode=*/true);
}

double DisplayNoise(const RenderResult& r) {
  const int W = r.radiance.width(), H = r.radiance.height();
  const auto lum = [&](const ImageF& im, int x, int y) {
    return Luminance(Rgb(im(x, y, 0), im(x, y, 1), im(x, y, 2)));
  };
  std::vector<double> var(static_cast<size_t>(W) * H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const double d = lum(r.half[0], x, y) - lum(r.half[1], x, y);
      var[static_cast<size_t>(y) * W + x] = 0.25 * d * d;
    }
  std::vector<double> err[2];
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      double sum = 0;
      int k = 0;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx < 0 || yy < 0 || xx >= W || yy >= H) continue;
          sum += var[static_cast<size_t>(yy) * W + xx];
          ++k;
        }
      const double v = r.tone.exposure * std::max(0.0, lum(r.radiance, x, y));
      const double e = std::sqrt(sum / k) * r.tone.exposure * ToneCurveSlope(v, r.tone.white);
      // A pixel of one sample has no second half to compare with.
      if (r.spp.pixels() == var.size() && r.spp(x, y, 0) < 2) continue;
      const bool on = r.sample_mask.pixels() == var.size() && r.sample_mask(x, y, 0) > 0.5f;
      err[on ? 0 : 1].push_back(e);
    }
  std::vector<double>& e = err[0].empty() ? err[1] : err[0];
  if (e.empty()) return 0;
  std::nth_element(e.begin(), e.begin() + e.size() / 2, e.end());
  return e[e.size() / 2];
}

ImageU8 ToneMapForDisplay(const ImageF& radiance) {
  return ToneMapForDisplay(radiance, MeterExposure(radiance));
}

}  // namespace mesoscan
