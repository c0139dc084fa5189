#pragma once
// The preview path tracer: a scanned height field (plus the mount plane under its holes) with
// one BRDF, lit by an environment map, seen by a pinhole camera. Unidirectional path tracing
// with next-event estimation towards the environment and multiple importance sampling (power
// heuristic) against BRDF sampling (pbrt-v4 PathIntegrator, reduced to what a preview needs).
//
// Sampling: Owen-scrambled Sobol points in Morton order over the image (render/sampler.h).
// Adaptive: the image is rendered in rounds (min_spp, then doubling up to max_spp). After each
// round every pixel's standard error is estimated from two interleaved half-buffers (even and
// odd sample numbers: valid for correlated, stratified samples where the sample variance is
// not), averaged over its 3x3 neighbourhood, and converted to display units through the tone
// curve metered on the image; a pixel whose error is below `noise` (fraction of the display
// range) stops. `time_limit_s` ends the render after the round that reaches it (the last round
// is shortened so as not to overshoot).
//
// What the renderer takes: any HeightField. Which one (raw with holes, or the filled field of
// the artist-ready maps) is the caller's choice (app/cmd_render.cc).

#include <functional>
#include <optional>
#include <string>

#include "brdf/brdf.h"
#include "core/height_field.h"
#include "core/image.h"
#include "render/env_map.h"

namespace mesoscan {

struct CameraSpec {
  Vec3 eye = Vec3::Zero(), target = Vec3::Zero();  // world metres
};

struct RenderOptions {
  int width = 640, height = 480;  // output pixels, >= 1
  int min_spp = 16;               // samples per pixel before adaptivity starts, >= 1
  int max_spp = 256;              // upper bound per pixel, >= min_spp
  double noise = 0.01;            // adaptive threshold, fraction of the display range; 0 = off
  double time_limit_s = 0;        // wall-clock budget; 0 = none (the render is then reproducible)
  int max_depth = 4;              // path vertices on the surface, >= 1
  double elevation_deg = 50.0;    // camera elevation above the mount plane, (0, 90]
  double azimuth_deg = -90.0;     // camera azimuth from +x towards +y (-90: looking from -y)
  double fov_deg = 0.0;           // vertical field of view; 0: 30 degrees
  std::optional<CameraSpec> camera;  // explicit camera; else framed from elevation/azimuth
  double relief_scale = 1.0;         // multiplies heights (exaggerated relief for previews), > 0
  Rgb mount_albedo = Rgb::Constant(0.3);  // Lambert mount plane seen through holes
  // Spatially varying base colour: RGB (or 1-channel) on the height field's grid, multiplies the
  // surface BRDF (nearest sample). nullptr: the BRDF as given.
  const ImageF* albedo = nullptr;
  // Which of the height field's samples are the sample and which the bare mount it sits on, on
  // the height field's grid (nearest sample): nonzero = the sample (the BRDF, the albedo), zero =
  // the mount (Lambert with mount_albedo, as the plane under the holes). nullptr: all sample.
  // The camera rays' sample mask (RenderResult::sample_mask, the exposure's metering region)
  // counts the sample's hits only.
  const ImageU8* sample_material = nullptr;
  uint64_t seed = 1;
  // Camera rays skip the mount plane when the camera provably cannot see it (hole-free field
  // filling the view); false traces it anyway (for the bench's before/after).
  bool skip_invisible_mount = true;
  // Continuation rays also sample the environment mirrored in the field's plane, blurred by the
  // BRDF (render/mirror_guide.h), where the scene needs it (a non-Lambert BRDF under a
  // non-constant environment). false: BRDF sampling alone (the bench's before/after).
  bool mirror_guide = true;
  // At the camera ray's first vertex, where it uses the mirrored-environment sampler, draw this
  // many candidate directions from its mixture with BRDF sampling and keep one by resampling
  // towards the product of the vertex's BRDF x cosine and the field's reflected luminance (the
  // guide's table): resampled importance sampling (Talbot et al. 2005), unbiased. 0 or 1: off.
  // At most 16. Not used under error-driven allocation (allocate_* below), where it cost more
  // CPU than it saved.
  int resample_candidates = 8;
  // Under a time budget (time_limit_s > 0): after a uniform pilot of `allocate_pilot_spp`
  // samples per pixel, the remaining samples go where the error is: each pixel's share is
  // proportional to the per-sample standard deviation estimated over its neighbourhood
  // ((2 allocate_radius + 1)^2 pixels, leaving the pixel itself out, so that its sample count
  // does not depend on its own samples and its mean stays unbiased), with a floor of
  // `allocate_floor` times the image's mean deviation. 0 pilot spp: uniform rounds. While
  // allocating, pixels do not stop on `noise` (the budget is spent where the error is).
  // The same with a fixed budget of `allocate_spp` samples per pixel on average instead of a
  // time budget (0: none; then min_spp / max_spp / noise as above). Reproducible: the bench's
  // and the tests' way to compare allocations at equal cost.
  double allocate_spp = 0;
  int allocate_pilot_spp = 4;
  int allocate_radius = 3;
  double allocate_floor = 0.1;
  // Divide each pixel's share by sqrt(its neighbourhood's measured seconds per sample): the
  // optimum at a fixed cost rather than at a fixed sample count.
  bool allocate_by_cost = false;
  // For a render that will be denoised (render --denoise): the denoiser averages many pixels
  // where the first-hit features (normal, sample or mount) are uniform and few where they vary
  // (the rim, the slopes), so each pixel's share is also multiplied by sqrt(min(1 + v / tau^2,
  // max)), v the variance of the mean first-hit normal and hit fraction over the pixel's
  // neighbourhood (the pixel left out, as above): the optimum n ~ sigma / sqrt(m) for pixels
  // whose noise the denoiser divides by about m. Off: the raw render's optimum. Demo, 10 spp
  // allocated, two seeds: denoised relRMSE 3.20% -> 2.97% (tau 0.05-0.3 and max 9-100 alike,
  // 2.95-2.98%; CPU per spp +0-7%: the slopes' paths cost more).
  // Its pilot is allocate_denoise_pilot_spp (when allocate_pilot_spp > 0): the allocation starts
  // after 2 uniform spp instead of 4 (split, 10 spp: 2.97% -> 2.85% denoised at equal CPU; the
  // demo's --time 3, three alternated pairs: 3.02-3.16% -> 2.91-3.03%).
  bool allocate_for_denoiser = false;
  double allocate_denoise_tau = 0.1;
  double allocate_denoise_max = 9;
  int allocate_denoise_pilot_spp = 2;
  void Check() const;
};

struct RenderSummary {
  int64_t samples = 0;           // camera paths traced
  int64_t pixels_converged = 0;  // pixels that stopped before max_spp
  int rounds = 0;
  double seconds = 0;
  double mean_spp = 0;
  bool mount_visible = true;  // false: camera rays skipped the mount plane
  bool mirror_guide = false;  // the mirrored-environment sampler was used
  std::string BriefReport() const;
};

// Display mapping: radiance * balance * exposure, extended Reinhard curve with white point
// `white`, sRGB. `balance`: per-channel gains of luminance 1 (a white balance; Render() sets it
// to the inverse colour of the environment's sky (WhiteBalanceFor), so a glossy material's own
// colour shows under a blue sky or a red sunset).
struct ToneMapping {
  double exposure = 1.0, white = 1.0;
  Rgb balance = Rgb::Ones();
};

// The white balance for `env`: gains proportional to 1 / the mean colour of its upper
// hemisphere's radiance (solid-angle weighted, its brightest 2% left out: the sun disk), scaled
// to luminance 1; ones for a constant environment or one without light.
Rgb WhiteBalanceFor(const EnvironmentMap& env);

struct RenderResult {
  ImageF radiance;     // linear RGB
  ImageF sample_mask;  // 1 channel: fraction of each pixel's camera rays that hit the sample (the
                       // height field where RenderOptions::sample_material says sample)
  // Feature buffers of the camera rays' first hits, averaged over each pixel's samples (zero
  // where a ray escaped): for the optional preview denoiser (render/denoise.h).
  ImageF normal;     // 3 channels: world-space shading normal, facing the camera
  ImageF depth;      // 1 channel: distance from the eye, metres
  ImageF albedo;     // 3 channels: the base colour the hit multiplies (the scan's tint on the
                     // height field, the mount's albedo on the mount)
  ImageF half[2];    // 3 channels each: the means of the even and of the odd samples
  ImageF spp;        // 1 channel: samples taken per pixel
  ToneMapping tone;  // metered on the sample (mask > 0.5), not on the mount; white-balanced
  RenderSummary summary;
};

// Called after every round with the current estimate (for progressive previews).
using RenderProgressFn = std::function<void(const RenderResult&)>;

RenderResult Render(const HeightField& hf, const Brdf& brdf, const EnvironmentMap& env,
                    const RenderOptions& options, const RenderProgressFn& on_round = nullptr);

// The camera Render() uses for `options` on `hf`: options.camera if given, else the framing from
// elevation/azimuth/fov (relief_scale applied). To show several height fields through one camera.
CameraSpec FramingCamera(const HeightField& hf, const RenderOptions& options);

// Renders linear RGB radiance (3 channels). Progress on stderr.
ImageF RenderHeightField(const HeightField& hf, const Brdf& brdf, const EnvironmentMap& env,
                         const RenderOptions& options, RenderSummary* summary = nullptr);

// Exposure from the log-average luminance (key 0.18) of the pixels with mask > 0.5 (all pixels
// when mask is null or empty, or when no pixel has), white point at their 99.5th percentile;
// luminance after the white balance `balance` (kept in the result).
ToneMapping MeterExposure(const ImageF& radiance, const ImageF* mask = nullptr,
                          const Rgb& balance = Rgb::Ones());
ImageU8 ToneMapForDisplay(const ImageF& radiance, const ToneMapping& tone);

// A render's noise in the units of RenderOptions::noise (a fraction of the display range through
// r.tone's curve): the median over the sample's pixels (sample_mask > 0.5; all pixels if none) of
// each pixel's standard error (pixels of at least 2 samples), estimated from its half-buffers'
// luminance as the adaptive sampler does ((A - B)^2 / 4 averaged over the pixel's 3x3
// neighbourhood). For renders that should match another's noise (turntable frames, the still).
double DisplayNoise(const RenderResult& r);
// Meters on all pixels.
ImageU8 ToneMapForDisplay(const ImageF& radiance);

}  // namespace mesoscan
