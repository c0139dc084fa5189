#pragma once
// Coarse placement of one height field on another from their height images (docs/compare.md): a
// rotation about z and a shift in x-y, found by phase correlation (OpenCV) of the two fields'
// relief, downsampled, over a sweep of rotations. An object re-placed on the mount moves mostly
// so; the registration then refines each candidate in 3D (compare/registration_module.h).
// Unlike local features, the correlation of the whole relief tells apart the rotations of a
// near-symmetric object with low relief (a coin).

#include <vector>

#include "core/height_field.h"
#include "core/image.h"
#include "core/transform.h"

namespace mesoscan {

struct PlanarAlignmentOptions {
  int size = 256;         // side of the correlated images (pixels, a power of two >= 32)
  double step_deg = 3.0;  // the sweep's step, on images of half the size; refined to step / 8
  int candidates = 3;     // how many placements to return, >= 1
  void Check() const;
};

struct PlanarCandidate {
  Mat4d b_to_a = Mat4d::Identity();  // a rotation about z and a shift in x-y (z unchanged)
  double angle_deg = 0;              // the rotation, in (-180, 180]
  double response = 0;               // the phase correlation's peak, higher is better
};

// `in_a`, `in_b`: the pixels of each field that belong to the object (nonzero; same size as the
// field). Candidate placements of B on A, best first; empty if either has fewer than 64 pixels.
std::vector<PlanarCandidate> PlanarAlignment(const HeightField& a, const ImageU8& in_a,
                                             const HeightField& b, const ImageU8& in_b,
                                             const PlanarAlignmentOptions& options = {});

}  // namespace mesoscan
