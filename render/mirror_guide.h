#pragma once
// The mirrored-environment direction sampler: a third sampling strategy for the preview path
// tracer's continuation rays (besides BRDF sampling and the environment's next-event estimate).
//
// Why: a scan is a near-planar height field lying around z = 0. A flat glossy field reflects the
// environment, so from any point above it the field looks like the environment mirrored in
// z = 0 and blurred by the BRDF's lobe: the radiance arriving from a downward direction d is
// L_r(-d) = int f(-d, wi) Le(wi) cos(theta_i) dwi of the flat field, the same at every point.
// On the demo (GGX copper under a sun), the coin's rim is lit by the sun's reflection in the
// copper field; the rim's BRDF sampling rarely points at the field points that reflect the sun,
// and 89% of the preview's squared error came from those paths (camera -> rim -> field -> sun).
//
// What: a piecewise-constant density over the lower hemisphere of world directions (equal-area
// cells in (phi, z)), proportional to the luminance of L_r above (estimated once per render
// with stratified environment and BRDF samples, multiple importance sampled), plus a small
// uniform floor. Its Pdf() is exact for Sample(), so the renderer combines it with BRDF sampling
// as a one-sample mixture (pdf = (1 - c) p_brdf + c p_guide, the same mixture in the MIS weight
// against the environment's next-event estimate): unbiased whatever the table holds; the table
// only decides how well the samples land. Shadowing and the field's extent are ignored (they
// would only make the guide less apt, never wrong).
//
// Selection probability c per vertex: SelectProbability(n), `max_select` times the guide's mass
// in the hemisphere above the vertex's normal n (a direction below the tangent plane is wasted),
// tabulated over normals. Zero on a flat field (n = +z: every guided direction points into it).

#include <vector>

#include "brdf/brdf.h"
#include "render/env_map.h"

namespace mesoscan {

class MirrorGuide {
 public:
  struct Options {
    int phi_cells = 64, z_cells = 16;  // lower hemisphere, equal-area cells
    int env_samples = 64;              // per cell, for the L_r estimate (and as many BRDF samples)
    double floor = 0.02;               // uniform share of the density (defensive)
    double max_select = 0.5;           // selection probability with the whole guide above n
  };

  // Builds the table for `brdf` lying flat (normal +z) under `env` (with its rotation).
  MirrorGuide(const EnvironmentMap& env, const Brdf& brdf, const Options& options);
  MirrorGuide(const EnvironmentMap& env, const Brdf& brdf) : MirrorGuide(env, brdf, Options{}) {}

  // Whether the scene needs the strategy: a non-Lambert BRDF (a Lambert field reflects the same
  // radiance every way: nothing to aim at) under an importance-sampled (non-constant)
  // environment.
  static bool Useful(const EnvironmentMap& env, const Brdf& brdf);

  // A world direction with z < 0 from u in [0,1)^2 and its solid-angle density.
  Vec3 Sample(const Vec2& u, double* pdf) const;
  // Solid-angle density of Sample() at world direction w (unit); 0 for w.z >= 0.
  double Pdf(const Vec3& w) const;
  // Probability of choosing this strategy at a vertex with unit normal n.
  double SelectProbability(const Vec3& n) const;
  // The table's estimate of the flat field's reflected luminance arriving along world direction
  // w (z < 0, i.e. L_r(-w)), floor included; its mean over the lower hemisphere for w.z >= 0.
  // The target of the renderer's resampling (RenderOptions::resample_candidates).
  double Radiance(const Vec3& w) const { return w.z() < 0 ? lum_[Cell(w)] : mean_lum_; }

  // Product with the vertex's BRDF (coarsely): the density above, re-weighted per block of
  // kBlockPhi x kBlockZ cells by the BRDF's luminance x cosine at the block's centre for this
  // vertex's outgoing direction. Within a block the density stays proportional to the table.
  // Exact Pdf() for Sample(), so the mixture stays unbiased; a block whose centre lies below
  // the tangent plane gets no density (BRDF sampling covers it).
  static constexpr int kCoarsePhi = 16, kCoarseZ = 4, kCoarse = kCoarsePhi * kCoarseZ;
  struct Local {
    double cdf[kCoarse + 1];
  };
  // The vertex: world-to-local rows (s, t, n) and wo in local coordinates. False when no block
  // has density (then do not use the strategy at this vertex).
  bool Prepare(const Brdf& brdf, const Vec3& s, const Vec3& t, const Vec3& n, const Vec3& wo,
               Local* local) const;
  Vec3 Sample(const Local& local, const Vec2& u, double* pdf) const;
  double Pdf(const Local& local, const Vec3& w) const;

 private:
  int Cell(const Vec3& w) const;
  int Block(int cell) const;
  std::vector<double> block_mass_;  // kCoarse: the table's probability per block
  std::vector<Vec3> block_centre_;  // kCoarse: world direction at each block's centre
  int nphi_, nz_;
  std::vector<double> cdf_;  // nphi_ * nz_ + 1, over cells (z-major)
  std::vector<double> pdf_;  // per cell, per unit solid angle
  std::vector<double> lum_;  // per cell: reflected luminance + floor
  double mean_lum_ = 0;
  double cell_solid_angle_ = 0;
  // Selection probability over normals: n_theta x n_phi table (theta from +z in [0, pi],
  // nearest node).
  static constexpr int kSelTheta = 32, kSelPhi = 64;
  std::vector<float> select_;
};

}  // namespace mesoscan
