#pragma once
// Camera raw frames (.nef .cr2 .dng ...), decoded as session-format.md "Conventions" asks: no
// demosaicing, each 2x2 Bayer cell averaged into one grey pixel (the image is half the sensor
// size), the black level the file declares subtracted, linear.
//
// The mosaic comes from OpenImageIO's LibRaw plugin with "raw:Demosaic" = "none" (the sensor
// values of LibRaw's visible area, unscaled, black not subtracted). OIIO does not report LibRaw's
// black and white levels, so they are read from the DNG tags (BlackLevel with
// BlackLevelRepeatDim, WhiteLevel) of the raw IFD through libtiff. For other raw formats the
// file's levels are not accessible here: black 0 and white 65535 are assumed, and the session's
// `camera.black_level` is then the only black subtraction (frames.cc applies it after this).

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
  bool from_file = false;                   // read from DNG tags (else the defaults above)
};

// Levels declared by a DNG (TIFF-based) raw file's raw IFD (NewSubFileType 0, in IFD 0 or a
// SubIFD); the defaults for other formats or when the tags are absent.
RawLevels ReadRawLevels(const std::filesystem::path& path);

// The sensor mosaic as LibRaw sees it (visible area, one channel, codes as stored).
// Throws Error(kBadInput) "<label>: cannot read camera raw (<why>)".
ImageU16 ReadRawMosaic(const std::filesystem::path& path, const std::string& label = "");

// The grey half-size frame: pixel (x, y) = round(clamp((mean of the cell's 4 sensor codes - mean
// black) * 65535 / (white - mean black), 0, 65535)). Linear in the sensor signal; the white level
// maps to 65535 so saturation tests on 16-bit frames hold for raw frames too. An odd last row or
// column of the mosaic is dropped. Throws as ReadRawMosaic. `label` names the frame in messages
// (default: the path).
ImageU16 ReadRawGrey(const std::filesystem::path& path, const std::string& label = "");

// Writes a minimal uncompressed 16-bit CFA DNG (DNG 1.4, one IFD, Bayer RGGB unless `cfa` says
// otherwise: the colours of cell positions (0,0) (1,0) (0,1) (1,1), 0 = R, 1 = G, 2 = B) that
// LibRaw reads: for tests and the simulated camera. `levels.black` per cell position, white as
// given. Atomic (temp + rename). Throws Error naming the path on failure.
void WriteCfaDng(const std::filesystem::path& path, const ImageU16& mosaic,
                 const RawLevels& levels = {}, std::array<uint8_t, 4> cfa = {0, 1, 1, 2});

// LibRaw's version, e.g. "0.20.2-Release", as OIIO's raw plugin reports it ("" if OIIO has no raw
// plugin).
std::string LibRawVersion();

}  // namespace mesoscan
