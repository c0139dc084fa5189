#pragma once
// Mixed pixels. A camera pixel integrates light over its footprint, so where the
// footprint spans two surfaces (a depth step) or a lit and a shadowed part, the decoded projector
// column is the brightness-weighted mean of what the pixel sees: the point lands between the two
// surfaces, or off the surface along the pixel's centre ray. Such points are rejected (NaN,
// confidence 0) rather than kept. Four tests, each along x and along y, on the camera grid:
//
//  - step: the point lies strictly between the linear extrapolations of its two sides
//    (e_s = 2 z_s1 - z_s2 from each side s) and differs from both by more than `max_sigmas` times
//    the noise of that difference, sqrt(s_p^2 + 4 s_s1^2 + s_s2^2) with s the per-pixel depth
//    sigma. A genuine local extreme (a ridge, a thread) lies outside both extrapolations and is
//    kept; so is a point that agrees with either side.
//  - outlier: the point disagrees with every side that has two valid neighbours by more than
//    max(outlier_footprints * camera footprint, 8 s_p) (the first, coarse test, kept for
//    isolated spikes and points next to holes).
//  - dimmed step: the point is darker (white level) than `dim_ratio` times the brighter of its
//    two neighbours, deviates from one side's extrapolation by more than `dim_sigmas`, and sits
//    at a sharp jump: the two sides' extrapolations differ at the point by more than
//    `dim_sharpness` times the sum of the sides' own changes per pixel (a smooth flank, even a
//    steep curved one whose shading varies, changes gradually and is kept). A
//    footprint across a step also sees the wall between the levels (or its shadow), lit at a
//    steeper angle than the faces, so the pixel is dimmer than both sides; its point is then off
//    the faces by a fraction of the step, often too little for the step test against the noise
//    of the extrapolations (a 40 um letter edge on the coin: the mixed point sits 14-26 um from
//    each side, the extrapolation noise is 4 um). A dark albedo spot on a smooth surface agrees
//    with both sides and is kept (rejected only when noise puts it beyond dim_sigmas of one of its
//    four extrapolations: ~5% of such spots).
//  - shadow edge: the point's neighbour is unlit (a cast shadow or the object's outline) and its
//    white level is below `shadow_edge_ratio` times that of its neighbour on the other side: part
//    of its footprint is in shadow, so the brightness centroid is off the pixel centre.

#include <cstdint>
#include <vector>

namespace mesoscan {

struct MixedPixelOptions {
  // Step test threshold, in sigmas of the extrapolation difference, > 0. Both sides must
  // disagree, with opposite signs, so noise alone triggers it with probability ~Q(k)^2.
  double max_sigmas = 3.0;
  // Outlier test threshold in camera footprints, >= 0; 0 disables the outlier test.
  double outlier_footprints = 0.5;
  // Shadow-edge test: white level ratio to the lit neighbour opposite an unlit one, in [0, 1];
  // 0 disables the test.
  double shadow_edge_ratio = 0.9;
  // Dimmed-step test: white level ratio to the brighter neighbour on the axis, in [0, 1]; 0
  // disables the test. And the deviation from a side's extrapolation, in sigmas, > 0.
  double dim_ratio = 0.85;
  double dim_sigmas = 2.5;
  // ... and the sharpness factor, >= 0 (0: any jump). 1.5 keeps the steep, textured rim flank of
  // ../shared/spec/examples/coin-edge (1: 0.26% of its pixels would go, 1.5: 0.05%).
  double dim_sharpness = 1.5;
  // Passes, >= 1: each further pass repeats the tests with the points rejected so far removed,
  // so a pixel whose side was bent by a mixed neighbour is judged by its clean side (a wall
  // two pixels wide). Stops early when a pass rejects nothing new.
  int passes = 2;

  void Check() const;
};

// All images are row-major width x height on the camera grid (or its ROI).
struct MixedPixelInput {
  int width = 0, height = 0;
  const float* z = nullptr;        // point height, m; NaN where there is no point
  const float* sigma_z = nullptr;  // predicted depth sigma, m (NaN or <= 0: unknown)
  const float* white = nullptr;    // white level (linear units); nullptr: no shadow-edge test
  const uint8_t* unlit = nullptr;  // 1 where the pixel is unlit; nullptr: no shadow-edge test
  double footprint_m = 0.0;        // camera footprint (pixel pitch on the surface), m
};

// Returns 1 for each point (finite z) that one of the tests rejects in one of the passes, 0
// elsewhere.
std::vector<uint8_t> FindMixedPixels(const MixedPixelInput& in, const MixedPixelOptions& options);

}  // namespace mesoscan
