#pragma once
// Maps derived from a height field for material artists: normals, ambient occlusion
// and curvature computed on the height field itself (so they stay consistent with the
// displacement and, for a tile, periodic), and the projector's falloff for the albedo.

#include "core/camera.h"
#include "core/height_field.h"

namespace mesoscan {

// Unit world normals from central differences of z (one-sided next to holes); NaN where z is.
// periodic: differences wrap around the grid's edges (a tile).
ImageF NormalsOf(const HeightField& hf, bool periodic);

struct AoOptions {
  int directions = 12;       // azimuths sampled, >= 4
  int steps = 12;            // samples per azimuth (quadratically spaced out to the radius), >= 2
  double radius_m = 1.0e-3;  // horizon search radius, metres, > 0
  void Check() const;
};

// Horizon-based ambient occlusion (after Bavoil et al., "Image-space horizon-based ambient
// occlusion", SIGGRAPH 2008 talks; the cosine-weighted integral of Jimenez et al., "Practical
// real-time strategies for accurate indirect occlusion", 2016, with the normal of the mount,
// +z): per azimuth the horizon elevation h = max over samples of atan((z(q) - z(p)) / |q - p|),
// clamped at 0, gives the visible cosine-weighted fraction cos^2 h; AO is its mean over the
// azimuths, in [0, 1], 1 for a flat surface. NaN where z is NaN; samples in holes are skipped.
ImageF AmbientOcclusion(const HeightField& hf, const AoOptions& options, bool periodic);

// Mean curvature of the surface z(x, y) in 1/m (positive on bumps, Monge patch formula
// H = -((1 + zy^2) zxx - 2 zx zy zxy + (1 + zx^2) zyy) / (2 (1 + zx^2 + zy^2)^(3/2))) after a
// Gaussian of sigma_px; NaN where z is NaN.
ImageF MeanCurvature(const HeightField& hf, double sigma_px, bool periodic);

// The projector's relative irradiance on each height sample, cos(incidence) / r^2 (Lambert and
// the inverse square law, the simulator's shading model), divided by its median over the grid;
// NaN where z or the normal is NaN or the sample faces away. Dividing the white frame's
// radiance by it leaves albedo.
ImageF ProjectorIrradiance(const HeightField& hf, const ImageF& normals,
                           const Vec3d& projector_centre);

}  // namespace mesoscan
