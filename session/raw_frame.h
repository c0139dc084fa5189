#pragma once
// Camera raw frames (.nef .cr2 .dng ...), decoded with LibRaw as session-format.md "Conventions"
// asks: for reconstruction no demosaicing, each 2x2 Bayer cell averaged into one grey pixel (the
// image is half the sensor size), the black level subtracted, linear; for the colour texture the
// same half-size grid with each cell's R, mean G and B (LibRaw's half-size demosaic).
//
// LibRaw reads the black and white levels of every raw format it knows from the file itself
// (DNG BlackLevel/WhiteLevel tags, the maker notes and masked border of CR2, NEF, ARW ...): the
// common black, the per-colour black and the repeating black pattern are summed per position.

#include <array>
#include <filesystem>
#include <string>

#include "core/image.h"

namespace mesoscan {

// True for the camera raw extensions the session reader treats as raw (case-insensitive):
// .nef .nrw .cr2 .cr3 .crw .dng .arw .raf .orf .rw2 .pef .srw.
bool IsCameraRawPath(const std::filesystem::path& path);

// Levels of a raw file, in sensor codes.
struct RawLevels {
  std::array<double, 4> black{0, 0, 0, 0};  // per position in the 2x2 cell: (0,0) (1,0) (0,1) (1,1)
  double white = 65535.0;                   // saturation code, > max(black)
  bool from_file = false;                   // read from the file (LibRaw)
};

// The levels LibRaw reads from a raw file of any format it knows. Throws as ReadRawMosaic.
RawLevels ReadRawLevels(const std::filesystem::path& path, const std::string& label = "");

// The sensor mosaic as LibRaw sees it (visible area, one channel, codes as stored).
// Throws Error(kBadInput) "<label>: cannot read camera raw (<why>)".
ImageU16 ReadRawMosaic(const std::filesystem::path& path, const std::string& label = "");

// The grey half-size frame: pixel (x, y) = round(clamp((mean of the cell's 4 sensor codes - mean
// black) * 65535 / (white - mean black), 0, 65535)). Linear in the sensor signal; the white level
// maps to 65535 so saturation tests on 16-bit frames hold for raw frames too. An odd last row or
// column of the mosaic is dropped. Throws as ReadRawMosaic. `label` names the frame in messages
// (default: the path).
ImageU16 ReadRawGrey(const std::filesystem::path& path, const std::string& label = "");

// The colour texture on the grid of ReadRawGrey: channels R, G, B = (mean of the cell's sensor
// codes of that colour minus their black levels) / (white - mean black), linear, >= 0, in the
// camera's own RGB (no white balance, no colour matrix). Throws as ReadRawMosaic, and for a
// sensor whose 2x2 cell is not made of R, G and B filters (e.g. CMYG).
ImageF ReadRawColour(const std::filesystem::path& path, const std::string& label = "");

// Writes a minimal uncompressed 16-bit CFA DNG (DNG 1.4, one IFD, Bayer RGGB unless `cfa` says
// otherwise: the colours of cell positions (0,0) (1,0) (0,1) (1,1), 0 = R, 1 = G, 2 = B) that
// LibRaw reads: for tests and the simulated camera. `levels.black` per cell position, white as
// given. Atomic (temp + rename). Throws Error naming the path on failure.
void WriteCfaDng(const std::filesystem::path& path, const ImageU16& mosaic,
                 const RawLevels& levels = {}, std::array<uint8_t, 4> cfa = {0, 1, 1, 2});

// LibRaw's version, e.g. "0.20.2-Release" (the library linked).
std::string LibRawVersion();

}  // namespace mesoscan
