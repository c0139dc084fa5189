#include "sim/error_map_png.h"

#include "maps/colour_map_png.h"

namespace mesoscan {

void WriteErrorMapPng(const std::filesystem::path& path, const ImageF& error, double max_m) {
  ColourMapStyle style;  // sequential viridis, |Z error| in um, no scale bar (camera pixels)
  style.hi = max_m;
  WriteColourMapPng(path, error, style);
}

}  // namespace mesoscan
