#pragma once
// A picture of a BRDF a person can read: for a few incident elevations, a polar plot of f *
// cos(theta_i) in the plane of incidence (R, G, B curves, linear radius with labelled rings) above
// a false-colour hemisphere map (orthographic view from above) of f * cos in RGB.

#include <string>
#include <vector>

#include "brdf/brdf.h"
#include "core/image.h"

namespace mesoscan {

struct BrdfPlotOptions {
  // Elevations of the fixed direction wo, in degrees in [0, 89]; one column each.
  std::vector<double> theta_o_deg = {0, 30, 60, 75};
  // Width of one column in pixels, >= 200. The image is columns * panel_px wide.
  int panel_px = 360;
  // Title printed at the top (e.g. the file name and its description).
  std::string title;

  void Check() const;  // throws Error(kBadInput) naming the field
};

// 8-bit RGB image (3 channels) of the plots.
ImageU8 PlotBrdf(const Brdf& brdf, const BrdfPlotOptions& options);

}  // namespace mesoscan
