#pragma once
// A fast path for the frames of a session: single-channel 16-bit PNGs (what the virtual rig and
// `mesoscan capture` write) decoded with libpng straight into native-endian samples, skipping the
// CRC and Adler-32 checksums (libpng's own options; the samples are those OpenImageIO's reader
// gives: the same libpng inflate, the same byte swap). About 6% of the decode's CPU time. A
// corrupted chunk is still refused by its inflate stream or its length; checksum-only damage
// (a flipped bit in a sample) goes unnoticed, like in any PNG reader with checks off.
//
// Anything else (colour, 8 bits, palette, interlaced, a size other than expected, an error while
// decoding) returns false and leaves the caller to decode with OpenImageIO, which names the
// problem: the fast path never refuses a file itself.

#include <cstdint>
#include <filesystem>

namespace mesoscan {

// Decodes `path` into out[0 .. width * height) if it is a non-interlaced, single-channel
// (grey, no alpha) 16-bit PNG of exactly width x height pixels; returns false otherwise (out
// may then have been written).
bool ReadPngGray16(const std::filesystem::path& path, int width, int height, uint16_t* out);

}  // namespace mesoscan
