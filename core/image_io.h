#pragma once
// Image I/O through OpenImageIO. Every writer is atomic (temp file + rename): a failed or
// interrupted write never leaves a partial file under the final name.

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "core/image.h"

namespace mesoscan {

struct ImageInfo {
  int width = 0, height = 0, channels = 0;
  int bits_per_sample = 0;  // 8, 16, 32 (float) ...
  bool is_float = false;
  std::vector<std::string> channel_names;
  std::map<std::string, double> float_attributes;  // numeric header attributes
};

// Reads only the header. Throws Error(kBadInput) naming the file if unreadable.
ImageInfo ReadImageInfo(const std::filesystem::path& path);

// The header's size, channel count and names, and sample type only (float_attributes empty),
// with the checks ReadImageInfo makes; a grey, grey-alpha, RGB or RGBA 8- or 16-bit PNG (its
// IHDR) and a single-part OpenEXR file (its header, through OpenEXR's core) without OpenImageIO
// (core/oiio_module.h), other files through ReadImageInfo. An EXR's channel names are in the
// file's (alphabetical) order. For checking a session's files before reading them.
ImageInfo ReadImageLayout(const std::filesystem::path& path);

// Reads any format OIIO knows as float. Integer formats are normalised to [0, 1] (uint16 / 65535,
// uint8 / 255); float formats are returned as stored. All channels, planar.
ImageF ReadImage(const std::filesystem::path& path, ImageInfo* info = nullptr);

// Reads one image as a single grey channel: multi-channel images are averaged (RGB -> mean).
ImageF ReadImageGrey(const std::filesystem::path& path, ImageInfo* info = nullptr);

// Reads an EXR's named channels (throws naming the file and the missing channel). Without
// float_attributes an OpenEXR file is read through ReadExrPlanes (no interleaved copy).
ImageF ReadExrChannels(const std::filesystem::path& path, const std::vector<std::string>& names,
                       std::map<std::string, double>* float_attributes = nullptr);

// Reads the channels of `names` that an OpenEXR file has, in that order, straight into planes
// through OpenEXR (no interleaved copy, the other channels not decoded); every channel of
// `required` must be in the file (throws Error(kBadInput) naming the file and the channel).
// info gets the size and the names read. Returns false, reading nothing, if the file is not
// OpenEXR (the caller then reads it another way).
bool ReadExrPlanes(const std::filesystem::path& path, const std::vector<std::string>& names,
                   const std::vector<std::string>& required, ImageF* image, ImageInfo* info);

// float32 EXR with named channels (one per image channel) and float header attributes.
// compression: an OpenEXR compression name as OIIO takes it, default "zip" (lossless); "none"
// writes several times faster on noisy float data, where ZIP saves only ~20 % of the size.
void WriteExr(const std::filesystem::path& path, const ImageF& image,
              const std::vector<std::string>& channel_names,
              const std::map<std::string, double>& float_attributes = {},
              const std::map<std::string, std::string>& string_attributes = {},
              const std::string& compression = "zip");

// An uncompressed float32 EXR written from planes (channel `channel` of `image`; channel -1: the
// image's only channel, which it must be; all planes of one size) straight through OpenEXR, with
// float header attributes: no interleaved copy of the image (the scan folder's points.exr is 75 MB
// at full resolution). The same pixels and attributes as WriteExr with compression "none".
struct ExrPlane {
  std::string name;
  const ImageF* image = nullptr;
  int channel = -1;
};
void WriteExrPlanes(const std::filesystem::path& path, const std::vector<ExrPlane>& planes,
                    const std::map<std::string, double>& float_attributes = {});

// 16-bit PNG (1, 2, 3 or 4 channels), values already quantised. compression_level: zlib level
// 0..9, or -1 for the library default (6). Level 1 writes noisy 16-bit frames ~2.5x faster than
// the default for ~2% larger files.
void WritePng16(const std::filesystem::path& path, const ImageU16& image,
                int compression_level = -1);
// 8-bit PNG (1, 3 or 4 channels); compression_level as for WritePng16. filter_rows = false
// writes every row unfiltered instead of libpng's adaptive per-row choice, through
// core/png_write.h (deflated in parallel pieces, no OpenImageIO): for noisy false-colour images
// (error maps) at level 1 about 2x faster and smaller than libpng's filters (full-resolution
// coin error map: 0.40 -> 0.18 s, 8.6 -> 5.0 MB), and the pieces share the cores.
void WritePng8(const std::filesystem::path& path, const ImageU8& image, int compression_level = -1,
               bool filter_rows = true);

// Float [0, 1] -> 16-bit / 8-bit with clamping and rounding; NaN maps to 0.
ImageU16 QuantizeU16(const ImageF& image);
ImageU8 QuantizeU8(const ImageF& image, bool srgb_encode = false);

}  // namespace mesoscan
