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
// Method: candidates are the raw pixel, OpenCV's guided filter (He et al. 2013,
// cv::ximgproc::guidedFilter) at radii 1, 2, 4, ... max_radius, and joint bilateral filters
// (cv::ximgproc::jointBilateralFilter) at spatial sigmas 2, 4, .... All are guided by the
// first-hit features (normal x, normal y, depth scaled to [0, 1] plus 3 where the camera rays
// missed the height field, so the sample and the mount are never fitted together) and run on
// the demodulated radiance (radiance / base colour). The guided filter fits the radiance as an
// affine function of the guide within each window, so shading that follows the relief survives
// while the noise averages out; the bilateral filter averages the pixels whose features match,
// which follows the glossy rim (the same reeding phase has the same normal) where an affine fit
// cannot. Each candidate is linear in its input for a fixed guide.
// Selection: each pixel takes the candidate with the least squared error, estimated by
// cross-validation on the renderer's two half-buffers A and B (even / odd samples, independent
// noise; Rousselle et al. 2012 use the same dual-buffer idea): with F(A) the candidate filtered
// from A, E[(F(A) - B)^2] = bias^2 + var F(A) + var B, while the output F((A + B) / 2) has error
// bias^2 + var F(A) / 2; var B is the same for every candidate and var F(A) is estimated by
// (F(A) - F(B))^2 / 2, so the score is (F(A) - B)^2 + (F(B) - A)^2 - (F(A) - F(B))^2 / 2
// (luminance), averaged over a (2 window + 1)^2 neighbourhood (the factor 1/2 of the last term is
// DenoiseOptions::correction, 0.7 by default: see there). Without the last term the score
// weighs the candidates' noise twice as heavily as the output carries it and picks biased
// filters (on the demo's rim the denoised error exceeded the raw one). The per-pixel choices
// are then blended over a small neighbourhood. Where a filter would blur real detail (an edge,
// the coin's reeding) the raw pixel or a smaller filter wins; a noise-free render comes back
// unchanged.

#include "core/image.h"
#include "render/path_tracer.h"

namespace mesoscan {

struct DenoiseOptions {
  int max_radius = 8;  // largest guided-filter radius tried, pixels, >= 1 (demo, 9 spp: 16
                       // gained 0.01 points of relRMSE for 13% of the denoiser's time)
  int window = 3;      // radius of the window the cross-validation error is averaged over, >= 0
                       // (demo, 9 spp allocated: 2 beat 3 and 5 with blend 2 and the 0.5
                       // correction; 3 with blend 3 and 0.7 below)
  double eps = 1e-2;   // regularisation of the affine fit (guide units squared), > 0; tuned on
                       // the demo at 16 spp: 5e-3 to 1e-2 best, 1e-3 and 3e-2 worse
  // Joint bilateral candidates with spatial sigma 2, 4, ... pixels (their cost grows with the
  // square of the sigma) and range sigma `bilateral_sigma` (guide units; demo: 0.03 beat 0.1,
  // 0.3, 0.015 and 0.007). 0: none. Demo, 9 spp: none 4.13%, one 3.52% (0.27 CPU s for the
  // whole denoiser), two 3.42% (0.59 CPU s): at equal CPU the second is a tie, so one.
  int bilateral = 1;
  double bilateral_sigma = 0.03;
  // Each pixel's output mixes the candidates chosen over its (2 blend + 1)^2 neighbourhood, in
  // proportion to how many chose each (the per-pixel choice is itself noisy). 0: its own choice.
  int blend = 3;
  // The cross-validation score minus half the squared difference of the candidate's two
  // filtered halves (see DenoisePreview). false: the plain dual-buffer score (the before).
  bool half_variance_correction = true;
  // The factor of that correction. 0.5 makes the score an unbiased estimate of twice the
  // output's error (plus a constant) for each candidate; but the choice is the minimum of noisy
  // scores, which favours the smoother candidates' downward fluctuations (their bias is then
  // underrated), and a larger factor favours the less smoothed ones. Demo, 9 spp, two seeds,
  // window 3 / blend 3 / radius 8: 0.3 3.55%, 0.5 3.47%, 0.6 3.43%, 0.7 3.41%, 0.8 3.41%,
  // 0.9 3.51% relative RMSE (denoised, the reference's noise removed).
  double correction = 0.7;
};

// The seconds of a `--time` budget to leave for DenoisePreview() at this image size: about
// 2.2 us per pixel (the guided filters alone took 1.5 us idle on the demo, 480x360, 2 cores;
// the bilateral candidate and the blend add half again in CPU), at most a quarter of the budget.
double DenoiseTimeReserve(int width, int height, double time_budget_s);

// The same reserve measured on this machine now (its speed and its load): DenoisePreview() timed
// (wall) on a synthetic image of a sixteenth of the pixels (at least 64 x 48), after a warm-up
// call on 32 x 24 pixels (the first call's one-time costs, scaled 16x, overstated the demo's
// reserve by 1.3-1.6x), scaled to width x height, x 1.25, plus the measurement's own time (it
// comes out of the same budget; it includes loading the filters' module unless that is loaded
// already, as `render --denoise` does on another thread); at most a quarter of the budget.
// Costs about a sixteenth of a denoise (idle demo: ~0.02 s). The fixed figure above left the
// idle demo 0.23 s unused and overran under load (1.3 s wall against 0.38 s reserved, session
// 10).
double MeasureDenoiseTimeReserve(int width, int height, double time_budget_s,
                                 const DenoiseOptions& options = {});

// Linear RGB, the same size as r.radiance. Needs r's feature buffers (Render() fills them).
ImageF DenoisePreview(const RenderResult& r, const DenoiseOptions& options = {});

}  // namespace mesoscan
