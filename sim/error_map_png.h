#pragma once
// The error map a simulated session's reconstruction writes (error_map.png): |Z error| as a
// colour map (OpenCV's viridis) with a scale bar.

#include <filesystem>

#include "core/image.h"

namespace mesoscan {

// |error| from 0 to `max_m` (default: its 99th percentile) as a colour map with a scale bar below
// (at least 320 px wide); NaN black. 8-bit RGB PNG.
void WriteErrorMapPng(const std::filesystem::path& path, const ImageF& error, double max_m = 0.0);

}  // namespace mesoscan
