#pragma once
// The fast path for the frames of a session: grey PNGs (16-bit, what the virtual rig and
// `mesoscan capture` write; 8-bit, what many cameras' tools write) decoded straight into 16-bit
// native-endian samples, the same samples OpenImageIO gives (an 8-bit value v as v * 257).
//
// Only the narrow common case is decoded here: a non-interlaced grey 8- or 16-bit PNG of the
// expected size: signature, IHDR, consecutive IDATs, IEND, and ancillary chunks that do not change
// the samples (skipped). Every chunk's CRC-32 and the zlib stream's Adler-32 are checked; the
// zlib stream is inflated by libdeflate in one call (about 1.7x zlib's speed on our frames, which
// is what libpng would use) and the five row filters are undone here. Anything else (interlace,
// palette, colour, alpha, tRNS, sBIT, gamma or colour-space chunks, an unknown critical chunk, a
// damaged or truncated file, any doubt) returns false: the caller then decodes with OpenImageIO
// (libpng with its checks on), which decodes what it can and refuses the rest with its own
// message. So behaviour on odd or broken files is OpenImageIO's; only its speed differs.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

namespace mesoscan {

// Decodes `path` into out[0 .. width * height) if it is a PNG this fast path takes (above) of
// exactly width x height pixels; returns false otherwise (out may then have been written).
bool ReadPngGray16(const std::filesystem::path& path, int width, int height, uint16_t* out);

// The same at the size the file's IHDR declares: alloc(width, height, bit_depth) is called once
// the file is read and returns where the width x height samples go (nullptr: not decoded here). So
// a frame is decoded without opening it through OpenImageIO first (whose module is then never
// loaded, core/oiio_module.h).
bool ReadPngGray16(const std::filesystem::path& path,
                   const std::function<uint16_t*(int width, int height, int bit_depth)>& alloc);

// A PNG's header from the file's first 33 bytes: the signature, then a 13-byte IHDR chunk whose
// CRC matches. False if they are not that (nothing else of the header is checked).
struct PngHeader {
  uint32_t width = 0, height = 0;
  int bit_depth = 0, colour_type = 0;
};
constexpr size_t kPngHeaderBytes = 33;
bool ParsePngHeader(const uint8_t* first_bytes, PngHeader* header);

// The same on a PNG file held in memory, with the reason (for tests and the fuzzer).
enum class PngGrayStatus {
  kDecoded,
  kUnsupported,  // a valid-looking PNG outside the fast path (left to OpenImageIO)
  kDamaged,      // a checksum, length, filter or zlib stream is wrong, or the file is cut short
};
// `why` (optional) receives a short reason when the status is not kDecoded.
PngGrayStatus DecodePngGray(const uint8_t* file, size_t size, int width, int height, uint16_t* out,
                            std::string* why = nullptr);

}  // namespace mesoscan
