#pragma once
// The optional preview denoiser (`mesoscan render --denoise`): an edge-aware smoothing of the
// path tracer's linear radiance, guided by the camera rays' first-hit feature buffers (shading
// normal, depth, base colour; RenderResult), for a clean preview in a few seconds.
//
// It is biased: it trades noise for blur across features it cannot tell apart (a shadow edge
// on a flat field, the reflection of the coin's rim in the field). The raw render is always
// written next to it (preview.exr/png), and every figure of the renderer's accuracy (the bench's
// Cycles comparison, the unbiasedness tests) is measured on the raw render, never on this.
//
// Method: candidates are the raw pixel and OpenCV's guided filter (He et al. 2013,
// cv::ximgproc::guidedFilter) at radii 1, 2, 4, ... max_radius: within each window the
// demodulated radiance (radiance / base colour) is fitted as an affine function of the guide
// (normal x, normal y, depth scaled to [0, 1] plus 3 where the camera rays missed the height
// field, so the sample and the mount are never fitted together), so shading that follows the relief survives
// while the noise averages out. Each pixel takes the candidate with the least squared error,
// estimated by cross-validation on the renderer's two half-buffers (even / odd samples, whose
// noise is independent: a candidate filtered from one half is compared with the other half,
// both ways, averaged over a (2 window + 1)^2 neighbourhood; Rousselle et al. 2012 use the
// same dual-buffer idea). Where a filter would blur real detail (an edge, the coin's reeding)
// the raw pixel or a smaller window wins; a noise-free render comes back unchanged.

#include "core/image.h"
#include "render/path_tracer.h"

namespace mesoscan {

struct DenoiseOptions {
  int max_radius = 16;  // largest guided-filter radius tried, pixels, >= 1
  int window = 3;       // radius of the window the cross-validation error is averaged over, >= 0
  double eps = 1e-2;    // regularisation of the affine fit (guide units squared), > 0; tuned on
                        // the demo at 16 spp: 5e-3 to 1e-2 best, 1e-3 and 3e-2 worse
  double eps_low = 0;   // > 0: also candidates with this regularisation at every radius
  bool half_variance_correction = true;  // see DenoisePreview
  int blend = 0;        // > 0: soft selection over (2 blend + 1)^2 neighbours' choices
};

// The seconds of a `--time` budget to leave for DenoisePreview() at this image size: about
// 1.5 us per pixel (measured on the demo, 480x360, 2 cores), at most a quarter of the budget.
double DenoiseTimeReserve(int width, int height, double time_budget_s);

// Linear RGB, the same size as r.radiance. Needs r's feature buffers (Render() fills them).
ImageF DenoisePreview(const RenderResult& r, const DenoiseOptions& options = {});

}  // namespace mesoscan
