#pragma once
// Colour-mapped pictures of a scalar map with a legend below: the colour bar with its range and
// what it shows, and optionally a scale bar of world length. The reconstruction's error map
// (sequential, |error|) and the comparison's deviation map (diverging, signed) are drawn by it.

#include <filesystem>
#include <string>

#include "core/image.h"

namespace mesoscan {

struct ColourMapStyle {
  enum class Kind {
    kSequential,  // 0 .. hi, OpenCV's viridis (|value| is shown)
    kDiverging,   // -hi .. +hi, blue - white - red (ColorBrewer RdBu), the sign shown
  } kind = Kind::kSequential;
  double hi = 0.0;                  // the range's end (value units); <= 0: the 99th percentile
  double label_scale = 1e6;         // labels show value * label_scale ...
  std::string unit = "um";          // ... followed by this unit
  std::string title = "|Z error|";  // printed in the middle of the colour bar's labels
  double pixel_size_m = 0.0;  // > 0: a scale bar of a round world length (0.1, 0.2, 0.5, 1, 2,
                              // 5 mm ...) under the map
};

// values: one channel, NaN drawn black. The legend (48 px; 70 with a scale bar or a diverging
// scale, whose title is on the second row) goes below the map; the picture is at least 320 px wide
// (the right of a narrow map is white). 8-bit RGB PNG.
void WriteColourMapPng(const std::filesystem::path& path, const ImageF& values,
                       const ColourMapStyle& style);

}  // namespace mesoscan
