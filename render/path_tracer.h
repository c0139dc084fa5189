#pragma once
// The preview path tracer: a scanned height field (plus the mount plane under its holes) with
// one BRDF, lit by an environment map, seen by a pinhole camera. Unidirectional path tracing
// with next-event estimation towards the environment and multiple importance sampling (power
// heuristic) against BRDF sampling (pbrt-v4 PathIntegrator, reduced to what a preview needs).
// Adaptive: after `min_spp`, a pixel whose relative standard error falls below
// `relative_error` stops receiving samples.

#include <string>

#include "brdf/brdf.h"
#include "core/height_field.h"
#include "core/image.h"
#include "render/env_map.h"

namespace mesoscan {

struct RenderOptions {
  int width = 640, height = 480;  // output pixels, >= 1
  int min_spp = 16;               // samples per pixel before adaptivity starts, >= 1
  int max_spp = 256;              // upper bound per pixel, >= min_spp
  double relative_error = 0.02;   // stop a pixel when stderr(lum) / mean(lum) < this, > 0
  int max_depth = 4;              // path vertices on the surface, >= 1
  double elevation_deg = 50.0;    // camera elevation above the mount plane, (0, 90]
  double azimuth_deg = -90.0;     // camera azimuth from +x towards +y (-90: looking from -y)
  double fov_deg = 0.0;           // vertical field of view; 0 frames the height field
  double relief_scale = 1.0;      // multiplies heights (exaggerated relief for previews), > 0
  Rgb mount_albedo = Rgb::Constant(0.3);  // Lambert mount plane seen through holes
  uint64_t seed = 1;
  void Check() const;
};

struct RenderSummary {
  int64_t samples = 0;          // camera paths traced
  int64_t pixels_converged = 0; // pixels that stopped before max_spp
  double seconds = 0;
  std::string BriefReport() const;
};

// Renders linear RGB radiance (3 channels). Progress on stderr.
ImageF RenderHeightField(const HeightField& hf, const Brdf& brdf, const EnvironmentMap& env,
                         const RenderOptions& options, RenderSummary* summary = nullptr);

// Linear radiance -> display PNG: exposure from the log-average luminance, extended Reinhard
// tone curve (white at the 99.5th percentile), sRGB.
ImageU8 ToneMapForDisplay(const ImageF& radiance);

}  // namespace mesoscan
