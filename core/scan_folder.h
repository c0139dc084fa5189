#pragma once
// The scan folder of docs/formats.md: points.exr, height.exr, normal.exr,
// report.json. Reader and writer; the writer builds the folder atomically.

#include <filesystem>

#include "core/height_field.h"
#include "core/json.h"

namespace mesoscan {

// points.exr: one sample per camera pixel.
struct ScanPoints {
  ImageF xyz;          // 3 channels X, Y, Z, world metres; NaN where no point
  ImageF confidence;   // [0, 1], 0 where xyz is NaN
  ImageF projector_u;  // decoded absolute projector column, NaN where unknown
  // Optional: which cue fixed the pixel, 0 lens shift, 1 phase shifting alone; NaN where xyz is
  // NaN. Empty: not recorded.
  ImageF source;
};

struct Scan {
  ScanPoints points;
  HeightField height;
  ImageF normals;  // 3 channels X, Y, Z on the height grid; computed from `height` if empty
  Json report = Json::object();
};

// Channel names and attribute keys (the contract).
inline constexpr const char* kAttrX0 = "mesoscan:x0";
inline constexpr const char* kAttrY0 = "mesoscan:y0";
inline constexpr const char* kAttrPixelSize = "mesoscan:pixel_size";

void WritePointsExr(const std::filesystem::path& path, const ScanPoints& points);
ScanPoints ReadPointsExr(const std::filesystem::path& path);
// height.exr (channels Z, confidence) with the grid attributes.
void WriteHeightExr(const std::filesystem::path& path, const HeightField& hf);
HeightField ReadHeightExr(const std::filesystem::path& path);
void WriteNormalExr(const std::filesystem::path& path, const HeightField& grid, const ImageF& n);

// Writes the whole folder atomically (existing folder replaced only on success).
void WriteScanFolder(const std::filesystem::path& dir, const Scan& scan);
// Reads points, height, normal and report; throws Error naming the missing file or channel.
Scan ReadScanFolder(const std::filesystem::path& dir);

}  // namespace mesoscan
