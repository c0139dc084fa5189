#pragma once
// The map-set options shared by `maps`, `export` and `reconstruct --export` (app/cmd_maps.cc).

#include <CLI/CLI.hpp>
#include <filesystem>
#include <string>

#include "maps/maps.h"

namespace mesoscan {

struct MapArgs {
  std::string fill, flatten, tile_method, tile_at, maps, grey_card;
  double fill_max_radius_mm = 0.0, tile_mm = 0.0, ao_radius_mm = 0.0;
  int size_px = 0;
  double roughness = -1.0;  // < 0: not given
  bool any() const;         // any map option given (export / reconstruct then write a map set)
  MapsOptions ToOptions(const std::string& name, const std::string& crop) const;
};

// The file-name prefix a scan folder gives its exports and maps: the folder's name without a
// ".scan" extension ("out/coin.scan/" -> "coin"); "scan" when the path has no name.
std::string ScanName(const std::filesystem::path& scan);

// Registers --fill, --flatten, --tile, --tile-method, --maps, ... on `cmd`.
void AddMapOptions(CLI::App* cmd, MapArgs* args, bool standalone);
// Prints the summary, the folder and the one line that loads it in Blender.
void PrintMapSet(const MapsSummary& summary, const std::filesystem::path& dir);
// The shell line that installs the add-on and imports `manifest` into Blender.
std::string BlenderLoadLine(const std::filesystem::path& manifest);

}  // namespace mesoscan
