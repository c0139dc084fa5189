#pragma once
// Flattening a height field: removes the sample's shape so the map holds its
// meso-structure. The removed part is returned as its own map (z = flattened + removed), so
// nothing is lost.
//   plane       a robust plane fit (iteratively reweighted least squares, Huber weights with the
//               scale from the residuals' MAD), for a sample lying slightly tilted on the mount;
//   poly:N      the same with a bivariate polynomial of total degree N (1..6), for a warped one;
//   highpass:MM a robust quadratic plus a Gaussian low-pass of the rest (normalised convolution
//               over the valid pixels) whose transfer is 1/2 at wavelength MM millimetres:
//               sigma = MM * sqrt(ln 2 / 2) / pi, H(lambda) = exp(-2 pi^2 sigma^2 / lambda^2).

#include <string>
#include <vector>

#include "core/height_field.h"

namespace mesoscan {

enum class FlattenMethod { kNone, kPlane, kPoly, kHighpass };

struct FlattenOptions {
  FlattenMethod method = FlattenMethod::kNone;
  int poly_degree = 2;                  // kPoly: total degree, 1..6
  double highpass_wavelength_m = 5e-3;  // kHighpass: cutoff wavelength, metres, > 2 pixels
  int irls_iterations = 8;              // robust fit iterations, >= 1
  double huber_k = 1.5;                 // Huber threshold in robust sigmas, > 0
  void Check() const;
};

struct FlattenResult {
  HeightField field;                 // the flattened height (NaN where the input is NaN)
  ImageF removed;                    // the removed low-frequency part, metres, finite everywhere
  std::vector<double> coefficients;  // plane / polynomial (normalised coordinates, see .cc)
  std::string description;           // e.g. "plane: tilt 0.52 deg"
  double seconds = 0.0;
};

// `weight_mask` (optional, same size, may be empty): pixels with 0 are left out of the fits
// (e.g. filled pixels). Throws Error(kBadInput) if fewer valid pixels than unknowns.
FlattenResult Flatten(const HeightField& hf, const ImageU8& weight_mask,
                      const FlattenOptions& options);

// "none" | "plane" | "poly:N" | "highpass:MM"; throws Error(kUsage) at FlattenOptions.method.
FlattenOptions ParseFlatten(const std::string& text);
std::string FlattenName(const FlattenOptions& options);

// Normalised Gaussian blur of the finite pixels of `z` (sigma in pixels); NaN where no valid
// pixel is within reach. Periodic wrap if `periodic`, else the borders are mirrored.
ImageF NormalisedGaussianBlur(const ImageF& z, double sigma_px, bool periodic = false);

}  // namespace mesoscan
